"""A project's animation evaluated headless: the rig posed at any time, its .fap sequence, its speech.

The window and the command line export through the same :class:`ProjectAnimation`, on a rig of
their own (the window passes ``rig.copy()``), so the two make identical frames by construction
and an export never moves the face on screen.
"""

from __future__ import annotations

import hashlib
import os
import wave
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from core.layers.fap import tables
from core.formats.fap_file import FapSequence
from core.rig import FaceRig
from core.timeline import MuscleSimulationCache, Timeline, apply_to_rig, is_simulated

__all__ = ["ProjectAnimation", "mix_speech", "speech_wav", "sequence_from_rig"]


class ProjectAnimation:
    """A timeline on a rig, posed at any time.

    rig : a FaceRig this object may change (a fresh one, or ``window_rig.copy()``); layers the
        timeline needs but the rig lacks (the muscles) are built on it (``log`` says so).
    timeline : the animation; parameters it does not key keep the rig's values.
    """

    def __init__(self, rig: FaceRig, timeline: Timeline, *, log=None):
        self.rig, self.timeline = rig, timeline
        self.face = rig.face
        keys = list(timeline.tracks)
        missing = [k for k in keys if k not in set(rig.parameters())]
        if missing and log is not None and any(is_simulated(k) for k in missing):
            log("building the muscle model…")
        rig.ensure_layers(missing)
        self.simulation = None
        simulated = [k for k in keys if is_simulated(k)]
        if simulated:
            self.simulation = MuscleSimulationCache(timeline, rig.owner(simulated[0]))

    @classmethod
    def for_face(cls, face, timeline: Timeline, values: Mapping[str, float] | None = None, *, log=None):
        """On a new rig for ``face`` holding ``values`` ({key: value}, e.g. a project's rig settings)."""
        rig = FaceRig(face)
        if values:
            rig.ensure_layers(values)
            rig.set_values(values)
        return cls(rig, timeline, log=log)

    def close(self) -> None:
        if self.simulation is not None:
            self.simulation.close()

    def pose(self, t: float) -> None:
        """Put the rig in its state at ``t`` s (muscles simulated forward from 0, cached)."""
        values = self.timeline.evaluate(float(t))
        owned = set(self.rig.parameters())
        with self.rig.batch():
            apply_to_rig(self.rig, {k: v for k, v in values.items() if k in owned})
            if self.simulation is not None:
                self.simulation.seek(float(t))

    def vertices(self, t: float) -> np.ndarray:
        """(n, 3) mm: the face at ``t`` s (a copy)."""
        self.pose(t)
        return np.array(self.rig.vertices())

    def fap_values(self, t: float) -> np.ndarray:
        """(68,) the effective FAP values at ``t`` (presets folded into low-level FAPs)."""
        self.pose(t)
        return self.rig.effective_fap_values()

    def fap_sequence(self, fps: float, *, duration: float | None = None, name: str = "mimica") -> FapSequence:
        """The animation as an MPEG-4 .fap sequence at ``fps`` (FAPs it never moves are masked out)."""
        duration = self.timeline.duration if duration is None else float(duration)
        times = np.arange(max(1, int(round(duration * fps)))) / fps
        values = np.array([self.fap_values(t) for t in times])
        driven = np.abs(values).max(axis=0) > 0
        values[:, ~driven] = np.nan
        return FapSequence.from_values(values, fps, name=name)


def sequence_from_rig(rig: FaceRig, *, fps: float = 25.0, name: str = "mimica") -> FapSequence:
    """A one-frame .fap sequence of the rig's current pose: the user's non-zero FAPs 3..68, FAP 2
    with the active expressions and FAP 1 with the active visemes (intensities 0..63, half up)."""
    values = np.full((1, tables.N_FAPS), np.nan)
    user = rig.fap_values()
    nonzero = np.flatnonzero(user[2:]) + 2
    values[0, nonzero] = user[nonzero]
    expression = np.full((1, 6), -1, np.int64)
    active = [(int(e), w) for e, w in rig.expressions if e != 0 and w > 0]
    if active:
        row = [0, 0, 0, 0, 0, 0]
        for slot, (eid, weight) in enumerate(active[:2]):
            row[2 * slot], row[2 * slot + 1] = eid, _intensity63(weight)
        expression[0] = row
    viseme = np.full((1, 4), -1, np.int64)
    mix = list(rig.visemes)
    if any(v != 0 and w > 0 for v, w in mix):
        (s1, w1), (s2, _w2) = (mix + [(0, 0.0)])[:2]
        viseme[0] = [int(s1), int(s2), _intensity63(w1), 0]
    return FapSequence.from_values(values, fps, name=name, viseme=viseme, expression=expression)


def _intensity63(weight: float) -> int:
    return int(np.floor(float(weight) * 63 + 0.5))


# ---------------------------------------------------------------- speech
#: Speech audio is mixed and written in blocks of this many samples (memory stays bounded however
#: late a clip starts; a clip's own audio is bounded by ``core.lipsync``'s text limit).
SPEECH_BLOCK = 1 << 20


def _speech_pieces(clips: Sequence, duration_s: float | None):
    """([(start sample, float samples)], rate, total samples) of the clips; audio after ``duration_s``
    (the timeline's end, when given) is cut, clips starting after it are left out."""
    from core import lipsync

    pieces, rate = [], None
    for clip in clips:
        start_s = float(clip.start_s)
        if not (start_s >= 0 and np.isfinite(start_s)):
            raise ValueError(f"a speech clip starts at {clip.start_s!r} s; clips start at a time >= 0")
        if duration_s is not None and start_s > duration_s:
            continue
        path, sample_rate = lipsync.speech_audio(clip.text, clip.lang, rate_wpm=clip.rate_wpm)
        with wave.open(str(path), "rb") as w:
            samples = np.frombuffer(w.readframes(w.getnframes()), "<i2").astype(np.float64)
        rate = rate or int(sample_rate)
        if sample_rate != rate and len(samples):
            n = int(round(len(samples) * rate / sample_rate))
            samples = np.interp(np.arange(n) * (sample_rate / rate), np.arange(len(samples)), samples)
        pieces.append((int(round(start_s * rate)), samples))
    if not pieces:
        return [], rate, 0
    total = max(start + len(s) for start, s in pieces)
    if duration_s is not None:
        total = min(total, int(np.ceil(duration_s * rate)))
    return pieces, rate, total


def _speech_block(pieces, lo: int, hi: int) -> np.ndarray:
    block = np.zeros(hi - lo)
    for start, samples in pieces:
        a, b = max(start, lo), min(start + len(samples), hi)
        if a < b:
            block[a - lo:b - lo] += samples[a - start:b - start]
    return np.clip(np.round(block), -32768, 32767).astype(np.int16)


def mix_speech(clips: Sequence, duration_s: float | None = None) -> tuple[np.ndarray, int] | None:
    """((n,) int16 samples, rate Hz) of every speech clip (``core.formats.project.SpeechClip``) at its start
    time, time 0 = timeline 0; None without clips. ``duration_s``: the timeline's length; nothing
    after it is mixed (the buffer is sized by the project, not by a clip's start).

    One policy for clips synthesised at different rates: each is resampled (linear interpolation)
    to the first clip's rate, so nothing is dropped and nothing fails.
    """
    pieces, rate, total = _speech_pieces(clips, duration_s)
    if not pieces:
        return None
    return _speech_block(pieces, 0, total), rate


def speech_wav(clips: Sequence, folder: str | Path | None = None, *, duration_s: float | None = None) -> Path | None:
    """A WAV of :func:`mix_speech` (named by the clips, so it is written once per clip set); None
    without clips. ``folder``: the lip-sync cache by default. Written block by block, so memory
    stays bounded (a clip late in a long project writes silence, it does not allocate it)."""
    from core import lipsync

    pieces, rate, total = _speech_pieces(clips, duration_s)
    if not pieces:
        return None
    signature = repr(tuple((c.text, c.lang, float(c.start_s), int(c.rate_wpm)) for c in clips)) + repr(duration_s)
    digest = hashlib.sha256(signature.encode()).hexdigest()[:16]
    target = Path(folder) if folder is not None else lipsync.speech_cache_dir()
    path = target / f"speech-{digest}.wav"
    if not path.is_file():
        target.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(path.name + f".{os.getpid()}.part")
        try:
            with wave.open(str(partial), "wb") as w:
                w.setnchannels(1)
                w.setsampwidth(2)
                w.setframerate(int(rate))
                for lo in range(0, total, SPEECH_BLOCK):
                    w.writeframes(_speech_block(pieces, lo, min(lo + SPEECH_BLOCK, total)).astype("<i2").tobytes())
            os.replace(partial, path)
        finally:
            partial.unlink(missing_ok=True)
    return path
