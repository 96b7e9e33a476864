"""What goes in and out of the timeline: .fap and DPC animations imported as tracks, .fap export,
lip-sync clips with their speech audio, and the animation on a copy of the rig that export renders."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from core import timeline as tl
from core.timeline import Edit, TimelineError, Track

from app.timeline_commands import TimelineEditCommand


def _shorten(text: str, n: int = 24) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[: n - 1] + "…"


class TimelineIO:
    """What goes in and out of the timeline: .fap and DPC animations imported as tracks, .fap export,"""

    # ------------------------------------------------------------ lip-sync
    def import_animation(self, path, *, warn=None) -> Edit | None:
        """Add a .fap or thesis B DPC file's animation as FAP (and preset) tracks from the cursor, one
        undoable edit (``core.formats.animation_import``; a DPC file plays at the timeline's fps). Errors and
        notes go to ``message``; with ``warn(title, text)`` (a window's message box) a refusal goes there too."""
        said: list[str] = []
        self.message.connect(said.append)
        try:
            done = self._import_animation(path)
        finally:
            self.message.disconnect(said.append)
        if done is None and said and warn is not None:
            warn(f"Could not import {Path(path).name}", said[-1])
        return done

    def _import_animation(self, path) -> Edit | None:
        from pathlib import Path

        from core.formats.animation_import import tracks_from_dpc, tracks_from_fap
        from core.formats.dpc_file import read_dpc
        from core.formats.fap_file import read_fap

        path = Path(path)
        start = float(self.current_time)
        try:
            if path.suffix.lower() == ".fap":
                tracks, notes = tracks_from_fap(read_fap(path), start_s=start)
            else:
                if self._rig is None:
                    self.message.emit("This face has no rig: a DPC file needs its FAP units.")
                    return None
                tracks, notes = tracks_from_dpc(read_dpc(path), self._rig.fapu, fps=self.timeline.fps,
                                                start_s=start)
        except (ValueError, OSError) as exc:
            self.message.emit(str(exc))
            return None
        except Exception as exc:  # noqa: BLE001 - a file must never reach the user as a traceback
            self.message.emit(f"Could not import '{path.name}': it is damaged or not an animation file "
                              f"({type(exc).__name__}).")
            return None
        if not tracks:
            self.message.emit(f"'{path.name}' holds nothing Mimica can animate. " + " ".join(notes))
            return None
        tl_ = self.timeline
        end = max(float(tr.times[-1]) for tr in tracks.values())
        if end > tl.MAX_DURATION_S:
            self.message.emit(f"Could not import '{path.name}': from the cursor at {start:g} s it would end at "
                              f"{end:g} s, past the timeline's limit of {tl.MAX_DURATION_S / 3600:g} h "
                              f"({tl.MAX_DURATION_S:g} s). Move the cursor earlier or shorten the file.")
            return None
        settings = None
        if end > tl_.duration + tl.TIME_TOLERANCE:
            settings = ((tl_.duration, tl_.fps), (min(float(math.ceil(end + 0.5)), tl.MAX_DURATION_S), tl_.fps))
        edit = Edit(f"import {path.name}", {k: tl_.tracks.get(k) for k in tracks}, dict(tracks),
                    settings[0] if settings else None, settings[1] if settings else None)
        done = self.push(lambda: tl_.apply_edit(edit), f"import {path.name}")
        if done is not None:
            self.message.emit(f"Imported {len(tracks)} tracks from '{path.name}'. " + " ".join(notes))
        return done

    def export_fap(self, path) -> bool:
        """Write the timeline as an MPEG-4 .fap file at its frame rate (the rig's current pose as one
        frame when nothing is keyed). Errors go to ``message``; returns success."""
        from core.animation import sequence_from_rig
        from core.formats.fap_file import FapFileError, check_fap_size, write_fap

        path = Path(path)
        if self._rig is None:
            self.message.emit("This face has no rig: there is no FAP animation to export.")
            return False
        try:
            if self.timeline.tracks:
                check_fap_size(self.timeline.n_frames)  # before minutes of evaluation, not after
                sequence = self.animation().fap_sequence(self.timeline.fps, name=path.stem or "mimica")
            else:
                sequence = sequence_from_rig(self._rig, fps=self.timeline.fps, name=path.stem or "mimica")
            write_fap(path, sequence)
        except (FapFileError, ValueError, OSError) as exc:
            self.message.emit(f"Could not export '{path.name}': {exc}")
            return False
        self.message.emit(f"Wrote '{path.name}': {sequence.n_frames} frame{'s' if sequence.n_frames != 1 else ''} "
                          f"at {sequence.fps:g} fps.")
        return True

    def add_lipsync(self, result, text: str, lang: str, *, rate_wpm: int = 175) -> Edit | None:
        """Add a ``core.lipsync.LipSyncResult``'s tracks as one undoable edit (with its speech clip).

        Keys of existing tracks inside the clip's time span are replaced, keys outside it are kept;
        the duration grows to fit the clip (rounded up to a whole second).
        """
        from core.formats.project import SpeechClip

        tl_ = self.timeline
        tracks = dict(result.tracks)
        if not tracks:
            self.message.emit("The lip-sync produced no tracks (empty text?).")
            return None
        lo = min(float(tr.times[0]) for tr in tracks.values() if len(tr))
        hi = max(max(float(tr.times[-1]) for tr in tracks.values() if len(tr)), float(result.end_s))
        after: dict[str, Track | None] = {}
        for key, new in tracks.items():
            old = tl_.tracks.get(key)
            if old is not None and len(old):
                keep = (old.times < lo - tl.TIME_TOLERANCE) | (old.times > hi + tl.TIME_TOLERANCE)
                merged = new.with_keys(np.concatenate([old.times[keep], new.times]),
                                       np.concatenate([old.values[keep], new.values]),
                                       np.concatenate([old.codes[keep], new.codes]))
                after[key] = merged
            else:
                after[key] = new
        before = {k: tl_.tracks.get(k) for k in after}
        settings_before = settings_after = None
        if hi > tl_.duration + tl.TIME_TOLERANCE:
            settings_before = (tl_.duration, tl_.fps)
            settings_after = (min(float(math.ceil(hi + 0.5)), tl.MAX_DURATION_S), tl_.fps)
        edit = Edit("lip-sync", before, after, settings_before, settings_after)
        clip = SpeechClip(text=text, lang=lang, start_s=float(result.start_s), rate_wpm=int(rate_wpm))
        speech_before = list(self.speech)
        speech_after = [*self.speech, clip]

        def set_speech(value):
            return lambda: self._set_speech(value)

        try:
            tl_.apply_edit(edit)
        except TimelineError as exc:
            self.message.emit(str(exc))
            return None
        self._set_speech(speech_after)
        self.undo_stack.push(TimelineEditCommand(
            self, edit, f"lip-sync “{_shorten(text)}”", extra_undo=set_speech(speech_before),
            extra_redo=set_speech(speech_after)))
        return edit

    def _set_speech(self, clips: list) -> None:
        self.speech = list(clips)
        self._audio_cache = None
        self.speech_changed.emit()

    def content_end(self, audio_path: Path | None = None) -> float | None:
        """Seconds where the animation's content ends: its last key, or the end of its speech
        (``audio_path``'s length); None without keys or speech."""
        ends = [float(track.times[-1]) for track in self.timeline.tracks.values() if len(track)]
        if audio_path is not None:
            import wave

            with wave.open(str(audio_path), "rb") as w:
                ends.append(w.getnframes() / float(w.getframerate()))
        return max(ends) if ends else None

    def audio_path(self) -> Path | None:
        """A WAV with every speech clip at its start time, time 0 = timeline 0 (None without speech;
        ``core.animation.speech_wav``: written once per clip set)."""
        from core.animation import speech_wav

        return speech_wav(self.speech, duration_s=self.timeline.duration) if self.speech else None

    # ------------------------------------------------------------ export
    def animation(self):
        """The timeline on a copy of the rig (``core.animation.ProjectAnimation``): what export renders,
        evaluated apart from the face on screen (and from another thread) without moving it."""
        from core.animation import ProjectAnimation

        return ProjectAnimation(self._rig.copy(), self.timeline.copy())

    def frame_vertices(self, t: float) -> np.ndarray:
        """(n, 3) mm: the face at time ``t``, on a copy of the rig (the face on screen does not move).
        The copy is kept while the rig's values and the timeline stay as they are."""
        state = (self._rig, self.timeline, tuple(self._rig.values().items()) if self._rig is not None else (),
                 tuple(self.timeline.tracks.items()), self.timeline.duration, self.timeline.fps)
        if self._export_animation is None or self._export_animation[0] != state:
            self._export_animation = (state, self.animation())
        return self._export_animation[1].vertices(float(t))
