"""Lip-sync from text (thesis A §4.2.2): eSpeak NG phonemes with timings -> MPEG-4 visemes -> timeline tracks.

    result = lipsync_tracks("Olá, como vai você?", "pt-br", start_s=1.0, seed=3)
    timeline.replace_tracks(result.tracks)      # viseme:<id> tracks (+ fap:19..22 blinks)
    result.audio_path                           # WAV of the same synthesis, to play from start_s

- ``espeak``: speech and phoneme timings from one synthesis (see its docstring for why ctypes events).
- ``visemes``: phoneme -> viseme tables (``resources/lipsync/phonemes_<lang>.csv``); unmapped symbols
  are returned in ``LipSyncResult.unmapped``, never dropped silently.
- ``coarticulation``: crossfading viseme curves (no popping) and asymmetric blinks.

Languages: ``en`` (American voice), ``en-gb``, ``pt-br``. The speech WAV is written to
``audio_path`` or, by default, to a per-user cache (``$XDG_CACHE_HOME/mimica/speech``, named by a
hash of the text, language, rate and eSpeak version) — the project stores the text, so the audio
can always be regenerated.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
import wave
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.formats.atomic_files import write_atomic
from core.timeline import Track
from core.lipsync.coarticulation import blink_tracks, viseme_curves, viseme_tracks
from core.lipsync.espeak import (MAX_TEXT_CHARS, LanguageError, Phoneme, SpeechError, Synthesis, VOICES,
                                 espeak_version, synthesize, voice_for)
from core.lipsync.visemes import VisemeSegment, lookup, map_phonemes, phoneme_table

LANGUAGES = tuple(VOICES)
#: Speaking rates eSpeak NG is asked for (words per minute).
RATE_RANGE_WPM = (80, 450)


def check_clip_field(name: str, value, *, duration_s: float | None = None):
    """``value`` if it is allowed for a speech clip's field ``name`` (text, lang, start_s, rate_wpm);
    ValueError saying what is allowed otherwise. ``duration_s``: the timeline's length, which a
    clip's start may not pass (so its audio buffer stays within the project)."""
    import math

    if name == "text":
        if not isinstance(value, str) or not value.strip():
            raise ValueError("must be the text to speak (not empty)")
        if len(value) > MAX_TEXT_CHARS:
            raise ValueError(f"has {len(value)} characters; a clip holds at most {MAX_TEXT_CHARS}")
        return value
    if name == "lang":
        if not isinstance(value, str) or value.strip().lower() not in VOICES:
            raise ValueError(f"must be one of {', '.join(LANGUAGES)}, got {value!r}")
        return value
    if name == "rate_wpm":
        lo, hi = RATE_RANGE_WPM
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise ValueError(f"must be a whole number of words per minute from {lo} to {hi}, got {value!r}")
        return value
    if name == "start_s":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise ValueError(f"must be a number of seconds >= 0, got {value!r}")
        if duration_s is not None and value > duration_s:
            raise ValueError(f"is {value:g} s, after the end of the timeline ({duration_s:g} s); "
                             "a clip must start within the timeline")
        return float(value)
    raise ValueError(f"unknown speech clip field {name!r}")


@dataclass(frozen=True)
class LipSyncResult:
    """What ``lipsync_tracks`` made.

    tracks : canonical key -> Track (``viseme:<id>``, and ``fap:19``..``fap:22`` with blinks);
    audio_path : the speech WAV (starts playing at ``start_s``), None if not written;
    phonemes : timed phonemes, times on the timeline (shifted by ``start_s``);
    unmapped : phoneme symbols with no viseme (their time went to the neighbours);
    duration_s : length of the speech audio; the clip ends at ``start_s + duration_s``.
    """

    tracks: dict[str, Track]
    audio_path: Path | None
    phonemes: tuple[Phoneme, ...]
    unmapped: list[str]
    duration_s: float
    start_s: float = 0.0
    sample_rate: int = 22050
    segments: tuple[VisemeSegment, ...] = field(default=())

    @property
    def end_s(self) -> float:
        """The later of the audio's end and the last key (a viseme may fade out just after the sound)."""
        last = max((float(t.times[-1]) for t in self.tracks.values() if len(t)), default=0.0)
        return max(self.start_s + self.duration_s, last)


@functools.lru_cache(maxsize=8)
def _synthesis(text: str, lang: str, rate_wpm: int) -> Synthesis:
    syn = synthesize(text, lang, rate_wpm=rate_wpm)
    syn.samples.setflags(write=False)
    return syn


def phonemes(text: str, lang: str = "en", *, rate_wpm: int = 175) -> list[Phoneme]:
    """Timed phonemes of ``text`` spoken by eSpeak NG (IPA symbols, ``"_"`` = pause; times in s from 0)."""
    return list(_synthesis(text, lang, int(rate_wpm)).phonemes)


def speech_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "mimica" / "speech"


def _default_audio_path(text: str, lang: str, rate_wpm: int) -> Path:
    digest = hashlib.sha256(f"{espeak_version()}\0{lang}\0{rate_wpm}\0{text}".encode()).hexdigest()[:20]
    return speech_cache_dir() / f"speech-{digest}.wav"


def write_wav(path: str | Path, samples: np.ndarray, sample_rate: int) -> Path:
    """Write (n,) int16 mono samples as a WAV file (atomically); returns the path."""
    path = Path(path)
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(int(sample_rate))
        w.writeframes(np.asarray(samples, "<i2").tobytes())
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, buf.getvalue())
    return path


def speech_audio(text: str, lang: str = "en", path: str | Path | None = None, *,
                 rate_wpm: int = 175) -> tuple[Path, int]:
    """(WAV path, sample rate Hz) of ``text`` spoken — the same synthesis the phoneme timings come from."""
    syn = _synthesis(text, lang, int(rate_wpm))
    target = Path(path) if path is not None else _default_audio_path(text, lang, int(rate_wpm))
    if path is not None or not target.exists():
        write_wav(target, syn.samples, syn.sample_rate)
    return target, syn.sample_rate


def lipsync_tracks(text: str, lang: str = "en", *, start_s: float = 0.0, blinks: bool = True,
                   rng: np.random.Generator | None = None, seed: int | None = None,
                   transition_s: float = 0.1, rate_wpm: int = 175,
                   audio_path: str | Path | None = None, write_audio: bool = True) -> LipSyncResult:
    """Viseme (and blink) tracks for ``text`` spoken from ``start_s`` (s) on the timeline.

    transition_s : length of each viseme crossfade (s); rng / seed : blink timing (seed 0 if neither).
    audio_path : where to write the WAV (default: the speech cache); write_audio False skips it.
    """
    start_s = float(start_s)
    if not (np.isfinite(start_s) and start_s >= 0):
        raise ValueError(f"the speech must start at a time >= 0 s, got {start_s!r}")
    voice_for(lang)
    syn = _synthesis(text, lang, int(rate_wpm))
    segments, unmapped = map_phonemes(syn.phonemes, lang)
    tracks = viseme_tracks(segments, transition_s=transition_s, offset_s=start_s)
    if blinks:
        generator = rng if rng is not None else np.random.default_rng(0 if seed is None else seed)
        tracks.update(blink_tracks(start_s, start_s + syn.duration_s, generator))
    path = None
    if write_audio:
        path, _ = speech_audio(text, lang, audio_path, rate_wpm=rate_wpm)
    shifted = tuple(Phoneme(p.symbol, p.start_s + start_s, p.duration_s) for p in syn.phonemes)
    segs = tuple(VisemeSegment(s.viseme, s.start_s + start_s, s.end_s + start_s, s.phonemes) for s in segments)
    return LipSyncResult(tracks=tracks, audio_path=path, phonemes=shifted, unmapped=unmapped,
                         duration_s=syn.duration_s, start_s=start_s, sample_rate=syn.sample_rate, segments=segs)


__all__ = [
    "LANGUAGES", "LipSyncResult", "Phoneme", "VisemeSegment", "SpeechError", "LanguageError", "phonemes",
    "speech_audio", "lipsync_tracks", "map_phonemes", "lookup", "phoneme_table", "viseme_curves", "viseme_tracks",
    "blink_tracks", "synthesize", "write_wav", "speech_cache_dir",
]
