"""timeline_controller.py
----
Ties a :class:`core.timeline.Timeline` to the document's rig (:class:`app.document.Document`), a
playback clock and the document's undo stack.
No widgets here: :mod:`app.timeline_dock` draws it, :mod:`app.project_actions` saves it; its undo
commands are in :mod:`app.timeline_commands`, its imports, exports and speech in :mod:`app.timeline_io`.

* **Posing.** :meth:`TimelineController.seek` evaluates the timeline at t and applies it to the rig
  (``core.timeline.apply_to_rig``; the muscle layer through ``MuscleSimulationCache`` when the rig
  has one). Everything one time step changes reaches the rig with ``rig.changed``
  blocked and is announced by one ``rig.touch()``, so the viewport redraws once per step. FAP tracks
  the rig cannot animate (a face without eyeballs has no gaze) are skipped, not an error.
  Posing is never recorded as an undo step (the document's ``UndoableRigEdits`` is suspended).
* **Edits.** Every change of the timeline (keys, interpolation, settings, lip-sync) is a
  :class:`TimelineEditCommand` on the document's one ``QUndoStack``; it holds the ``core.timeline.Edit``
  (whole tracks before/after) and undoes with ``edit.inverse()``. After an edit the rig is posed
  again for the tracks that edit touched (other tracks keep what the user did to the rig).
* **Set key** (button, K) keys the *selected controls* at the cursor, with the rig's current values:
  the tracks selected in the timeline when any are, otherwise every parameter that already has a
  track or is away from neutral in the rig (FAP != 0, an active expression / viseme preset, a muscle
  force or jaw angle != 0 when the muscle layer exposes ``forces`` / ``jaw``). Keying tracked
  parameters too makes a slider returned to 0 get a 0 key instead of silently holding its old key.
* **Auto-key**: while it is on and nothing plays, every user change of the rig (FAP dock sliders,
  presets) keys the parameters that changed at the cursor. The rig change and its keys are one undo
  step (merged per gesture, so a slider drag is one step); the document's rig recorder is paused
  meanwhile so the change is not recorded twice.
* **Playback** keeps wall-clock time: a ``QTimer`` ticks about once per frame, the time shown is
  ``start + elapsed × speed`` from a ``QElapsedTimer``, snapped to the frame grid; frames that are
  late are dropped, never slowed down. ``fps_measured`` reports the frames actually shown per
  second. Speeds 0.25×–4×.
* **Speech.** Lip-sync clips (:class:`core.formats.project.SpeechClip`) live here with the timeline; their
  audio is mixed into one WAV aligned with timeline time 0 (:meth:`TimelineController.audio_path`),
  which is what video export wants. Audio is not played back in the app: this PySide6 build has no
  QtMultimedia.

Choices: the cursor always sits on a frame (seeking snaps); keys set from the UI land on the cursor,
so on frames. The key selection is ``{parameter key: set of key times}``; it survives edits for the
keys that still exist.
"""

from __future__ import annotations

import collections
import contextlib
import math
import time
from typing import Callable, Iterable, Mapping

from PySide6.QtCore import QElapsedTimer, QObject, Qt, QTimer, Signal

from core import parameters as P
from core import timeline as tl
from core.timeline import Edit, Timeline, TimelineError

from app.timeline_io import TimelineIO
from app.timeline_commands import (  # noqa: F401 - re-exported
    parameter_label, parameter_range, muscle_keys, _describe_change, TimelineEditCommand)

SPEEDS = (0.25, 0.5, 1.0, 1.5, 2.0, 4.0)
MIN_TICK_MS = 5
FPS_WINDOW_S = 1.0  # achieved fps = frames shown during the last second


# ------------------------------------------------------------------ controller
class TimelineController(TimelineIO, QObject):
    """The timeline of the document's project, its cursor and playback.

    Parameters
    ----------
    document : app.document.Document
        Its rig is posed (followed through ``face_changed``), its ``rig_edits`` paused while the
        timeline poses, its ``undo_stack`` gets the edits.
    timeline : Timeline, optional (a 10 s, 30 fps one by default)

    Signals
    -------
    time_changed(float)      the cursor moved (s, on a frame)
    playing_changed(bool)
    edited(object)           the timeline changed (the ``core.timeline.Edit``)
    timeline_replaced()      a different Timeline object (new / opened project)
    selection_changed()      key or track selection changed
    fps_measured(float)      frames shown per second during playback
    message(str)             a one-line notice for the status bar
    """

    time_changed = Signal(float)
    playing_changed = Signal(bool)
    edited = Signal(object)
    timeline_replaced = Signal()
    selection_changed = Signal()
    fps_measured = Signal(float)
    message = Signal(str)
    auto_key_changed = Signal(bool)
    speech_changed = Signal()
    rig_values_changed = Signal()  # the user changed the rig (not the timeline posing it)

    def __init__(self, document, timeline: Timeline | None = None, parent: QObject | None = None):
        super().__init__(parent if parent is not None else document)
        self.document = document
        self.undo_stack = document.undo_stack
        self.timeline: Timeline = timeline if timeline is not None else Timeline()
        self.timeline.changed.connect(self._on_timeline_changed)
        self.current_time = 0.0
        self.selected_keys: dict[str, set[float]] = {}
        self.selected_tracks: set[str] = set()
        self.clipboard: tl.Clipboard | None = None
        self.speech: list = []  # core.formats.project.SpeechClip
        self._auto_key = False
        self._auto_key_paused_recorder = None
        self._applying = 0
        self._rig = None
        self._export_animation = None
        self._simulation = None
        self._sim_layer = None
        self._audio_cache: tuple | None = None
        # playback
        self.loop = False
        self._speed = 1.0
        self.playing = False
        self._timer = QTimer(self)
        self._timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._timer.timeout.connect(self._tick)
        self._clock = QElapsedTimer()
        self._origin = 0.0
        self._shown_frame: int | None = None
        self._frame_stamps: collections.deque = collections.deque()
        self.achieved_fps = 0.0
        self.frames_shown = 0
        self.dock = None   # the TimelineDock showing this controller (it sets itself)
        document.face_changed.connect(self._on_face_changed)
        document.rig_changed.connect(self._on_face_changed)
        self.set_rig(document.rig)

    # ------------------------------------------------------------ wiring
    @property
    def rig(self):
        return self._rig

    def set_rig(self, rig) -> None:
        """Follow ``rig`` (the document's, after a face change) and pose it at the cursor."""
        if self._rig is not None:
            with contextlib.suppress(ValueError, RuntimeError, TypeError):
                self._rig.parameters_changed.disconnect(self._on_rig_changed)
        self._rig = rig
        self._drop_simulation()
        if rig is not None:
            rig.parameters_changed.connect(self._on_rig_changed)
            self.apply_time(self.current_time)

    def _on_face_changed(self, _face=None) -> None:
        self.set_rig(self.document.rig)

    def set_timeline(self, timeline: Timeline, *, time: float = 0.0) -> None:
        """Replace the timeline (new / opened project): stops playback, clears selections."""
        self.stop(rewind=False)
        with contextlib.suppress(ValueError, RuntimeError, TypeError):
            self.timeline.changed.disconnect(self._on_timeline_changed)
        self._drop_simulation()
        self.timeline = timeline
        timeline.changed.connect(self._on_timeline_changed)
        self.selected_keys.clear()
        self.selected_tracks.clear()
        self._audio_cache = None
        self.timeline_replaced.emit()
        self.selection_changed.emit()
        self.seek(time)

    @contextlib.contextmanager
    def _not_recorded(self):
        """Rig changes inside are the timeline's doing: no undo step, no auto-key."""
        rec = self.document.rig_edits
        self._applying += 1
        rec.pause()
        try:
            yield
        finally:
            rec.resume()
            self._applying -= 1

    # ------------------------------------------------------------ muscle layer
    def _muscle_layer(self):
        """The rig's simulated layer (the muscles), or None."""
        return None if self._rig is None else self._rig.layer("muscles")

    def _drop_simulation(self) -> None:
        if self._simulation is not None:
            with contextlib.suppress(Exception):
                self._simulation.close()
        self._simulation = None
        self._sim_layer = None

    def _simulation_for(self):
        layer = self._muscle_layer()
        if layer is None:
            self._drop_simulation()
            return None
        if layer is not self._sim_layer:
            self._drop_simulation()
            self._simulation = tl.MuscleSimulationCache(self.timeline, layer)
            self._sim_layer = layer
        return self._simulation

    # ------------------------------------------------------------ posing
    def _animatable_values(self, values: Mapping[str, float]) -> dict[str, float]:
        """The values of parameters this rig animates and that are not simulated (quick layers a
        track needs are added to the rig; slow ones, the muscles, are the muscle dock's to build)."""
        if self._rig is None:
            return {}
        owned = set(self._rig.parameters())
        missing = [k for k in values if k not in owned]
        if missing and self._rig.ensure_layers(missing, slow=False):
            owned = set(self._rig.parameters())
        return {k: v for k, v in values.items() if k in owned and not tl.is_simulated(k)}

    def apply_time(self, t: float, keys: Iterable[str] | None = None) -> None:
        """Pose the rig at time ``t`` from the timeline (all tracks, or the given parameter keys).

        Parameters this face cannot animate (gaze without eyeballs, muscles before their layer is
        built) are skipped, not an error. One ``rig.changed`` at most; never an undo step.
        """
        rig = self._rig
        if rig is None:
            return
        values = self.timeline.evaluate(t)
        if keys is not None:
            wanted = set(keys)
            values = {k: v for k, v in values.items() if k in wanted}
        values = self._animatable_values(values)
        with self._not_recorded(), rig.batch():
            try:
                rig.set_values(values)
                sim_keys = [k for k in self.timeline.tracks if tl.is_simulated(k)]
                if sim_keys and (keys is None or any(tl.is_simulated(k) for k in keys)):
                    sim = self._simulation_for()
                    if sim is not None:
                        sim.seek(t)
            except ValueError as exc:
                self.message.emit(f"Could not pose the face at {t:.2f} s: {exc}")

    def seek(self, t: float, *, snap: bool = True) -> float:
        """Move the cursor to ``t`` (s; snapped to the nearest frame, clamped) and pose the rig there."""
        tl_ = self.timeline
        t = min(max(float(t), 0.0), tl_.duration)
        if snap:
            t = tl_.frame_of(t) / tl_.fps
        self.current_time = t
        self._shown_frame = tl_.frame_of(t)
        if self.playing:
            self._origin, _ = t, self._clock.restart()
        self.apply_time(t)
        self.time_changed.emit(t)
        return t

    def step(self, frames: int) -> None:
        """Move the cursor by whole frames."""
        self.seek(self.current_time + frames / self.timeline.fps)

    # ------------------------------------------------------------ playback
    @property
    def speed(self) -> float:
        return self._speed

    def set_speed(self, speed: float) -> None:
        speed = float(speed)
        if not (math.isfinite(speed) and 0.25 <= speed <= 4.0):
            raise ValueError(f"playback speed must be between 0.25× and 4×, got {speed!r}")
        if self.playing:
            self._origin = self.current_time
            self._clock.restart()
        self._speed = speed

    def play(self) -> None:
        """Play from the cursor (from 0 when at the end without loop)."""
        if self.playing or self._rig is None:
            return
        tl_ = self.timeline
        if self.current_time >= tl_.duration - 0.5 / tl_.fps and not self.loop:
            self.seek(0.0)
        self._origin = self.current_time
        self._shown_frame = tl_.frame_of(self.current_time)
        self._frame_stamps.clear()
        self.frames_shown = 0
        self._clock.start()
        self._timer.setInterval(max(MIN_TICK_MS, int(1000.0 / tl_.fps)))
        self._timer.start()
        self.playing = True
        self.playing_changed.emit(True)

    def pause(self) -> None:
        if not self.playing:
            return
        self._timer.stop()
        self.playing = False
        self.playing_changed.emit(False)

    def stop(self, *, rewind: bool = True) -> None:
        """Pause and go back to 0."""
        self.pause()
        if rewind and self.current_time != 0.0:
            self.seek(0.0)

    def toggle_play(self) -> None:
        if self.playing:
            self.pause()
        else:
            self.play()

    def _tick(self) -> None:
        if not self.playing:
            return
        tl_ = self.timeline
        t = self._origin + self._clock.nsecsElapsed() * 1e-9 * self._speed
        end = (tl_.n_frames - 1) / tl_.fps
        finished = False
        if t > end:
            if self.loop and end > 0:
                t = math.fmod(t, end + 1.0 / tl_.fps)
                self._origin = t
                self._clock.restart()
            else:
                t, finished = end, True
        frame = tl_.frame_of(t)
        if frame != self._shown_frame:
            self._shown_frame = frame
            self.current_time = frame / tl_.fps
            self.apply_time(self.current_time)
            self.time_changed.emit(self.current_time)
            self._count_frame()
        if finished:
            self.pause()

    def _count_frame(self) -> None:
        now = time.perf_counter()
        stamps = self._frame_stamps
        stamps.append(now)
        self.frames_shown += 1
        while stamps and now - stamps[0] > FPS_WINDOW_S:
            stamps.popleft()
        if len(stamps) >= 2 and stamps[-1] > stamps[0]:
            self.achieved_fps = (len(stamps) - 1) / (stamps[-1] - stamps[0])
            self.fps_measured.emit(self.achieved_fps)

    # ------------------------------------------------------------ edits
    def _run_command(self, timeline: Timeline, edit: Edit, rig_after: Mapping | None,
                     extra: Callable[[], None] | None) -> None:
        """Undo/redo body: apply the edit to the timeline it was made on, then the extra state."""
        try:
            timeline.apply_edit(edit)
        except TimelineError as exc:  # a timeline replaced since (should not happen: the stack is cleared)
            self.message.emit(str(exc))
            return
        if extra is not None:
            extra()
        if rig_after and self._rig is not None and timeline is self.timeline:
            with self._not_recorded():
                self._rig.set_values({k: v for k, v in rig_after.items() if k in set(self._rig.parameters())})

    def push(self, make_edit: Callable[[], Edit], text: str | None = None, **command_kw) -> Edit | None:
        """Run a ``core.timeline`` edit and put it on the undo stack; a refused edit -> ``message``."""
        try:
            edit = make_edit()
        except TimelineError as exc:
            self.message.emit(str(exc))
            return None
        if edit.is_empty:
            return edit
        self.undo_stack.push(TimelineEditCommand(self, edit, text, **command_kw))
        return edit

    def _on_timeline_changed(self, edit: Edit) -> None:
        self._prune_selection()
        if edit.settings_after is not None and self.current_time > self.timeline.duration:
            self.current_time = self.timeline.duration
        if edit.settings_after is not None:
            self.current_time = self.timeline.frame_of(self.current_time) / self.timeline.fps
            self.apply_time(self.current_time)
            self.time_changed.emit(self.current_time)
        elif edit.keys:
            self.apply_time(self.current_time, edit.keys)
        self.edited.emit(edit)

    def _prune_selection(self) -> None:
        tracks = self.timeline.tracks
        changed = False
        for key in list(self.selected_keys):
            track = tracks.get(key)
            keep = {t for t in self.selected_keys[key] if track is not None and track.index_at(t) is not None}
            if keep != self.selected_keys[key]:
                changed = True
            if keep:
                self.selected_keys[key] = keep
            else:
                del self.selected_keys[key]
        if changed:
            self.selection_changed.emit()

    # ------------------------------------------------------------ values of the rig
    def rig_value(self, key: str) -> float | None:
        """The rig's current value of a parameter (any layer); None when the rig does not animate it."""
        rig = self._rig
        if rig is None or key not in set(rig.parameters()):
            return None
        return rig.value(key)

    def non_neutral_parameters(self) -> list[str]:
        """Parameters away from their default in the rig (every layer)."""
        return [] if self._rig is None else list(self._rig.values(nondefault=True))

    def keyable_controls(self) -> list[str]:
        """The "selected controls" Set key keys (see the module docstring)."""
        if self.selected_tracks:
            return sorted(self.selected_tracks, key=_sort_key)
        keys = set(self.timeline.tracks) | set(self.non_neutral_parameters())
        return sorted(keys, key=_sort_key)

    def set_key(self, keys: Iterable[str] | None = None, t: float | None = None) -> Edit | None:
        """Key ``keys`` (default: :meth:`keyable_controls`) at ``t`` (default: the cursor) with the rig's values."""
        keys = self.keyable_controls() if keys is None else list(keys)
        t = self.current_time if t is None else float(t)
        rows = {}
        skipped = []
        for key in keys:
            value = self.rig_value(key)
            if value is None:
                skipped.append(key)
            else:
                rows[key] = [(t, value, None)]
        if not rows:
            self.message.emit("Nothing to key: move a slider (or pick a preset), or select tracks in the timeline."
                              if not skipped else f"Cannot read the current value of {', '.join(skipped)}.")
            return None
        edit = self.push(lambda: self.timeline.add_keys(rows, label="set key"),
                         f"set key at {t:.2f} s ({len(rows)} track{'s' if len(rows) != 1 else ''})")
        if edit is not None:
            self.message.emit(f"Keyed {len(rows)} parameter{'s' if len(rows) != 1 else ''} at {t:.2f} s.")
        return edit

    # ------------------------------------------------------------ auto-key
    @property
    def auto_key(self) -> bool:
        return self._auto_key

    def set_auto_key(self, on: bool) -> None:
        on = bool(on)
        if on == self._auto_key:
            return
        self._auto_key = on
        rec = self.document.rig_edits
        if on:
            rec.pause()
            self._auto_key_paused_recorder = rec
        elif not on and self._auto_key_paused_recorder is not None:
            self._auto_key_paused_recorder.resume()
            self._auto_key_paused_recorder = None
        self.auto_key_changed.emit(on)

    def _on_rig_changed(self, change) -> None:
        """A parameter changed (the event names the keys, new and previous values): tell the views,
        and key it at the cursor when auto-key is on (one undo step with the change itself)."""
        if self._rig is None or self._applying:
            return
        self.rig_values_changed.emit()
        if not self._auto_key or self.playing or not change.values:
            return
        t = self.current_time
        rows = {k: [(t, v, None)] for k, v in change.values.items()}
        try:
            edit = self.timeline.add_keys(rows, label="auto-key")
        except TimelineError as exc:
            self.message.emit(f"Auto-key: {exc}")
            return
        what = _describe_change(rows)
        self.undo_stack.push(TimelineEditCommand(self, edit, f"{what} (auto-key)", rig_before=dict(change.previous),
                                                 rig_after=dict(change.values),
                                                 merge_key=("auto-key", id(self.timeline), frozenset(rows))))

    # ------------------------------------------------------------ key selection operations
    def selection(self) -> dict[str, tuple[float, ...]]:
        return {k: tuple(sorted(v)) for k, v in self.selected_keys.items() if v}

    def set_selection(self, selection: Mapping[str, Iterable[float]]) -> None:
        new = {k: set(map(float, v)) for k, v in selection.items() if v}
        if new != self.selected_keys:
            self.selected_keys = new
            self.selection_changed.emit()

    def select_all_keys(self) -> None:
        self.set_selection({k: tr.times.tolist() for k, tr in self.timeline.tracks.items()})

    def set_selected_tracks(self, keys: Iterable[str]) -> None:
        keys = set(keys)
        if keys != self.selected_tracks:
            self.selected_tracks = keys
            self.selection_changed.emit()

    def delete_selected(self) -> Edit | None:
        sel = self.selection()
        if not sel:
            self.message.emit("No keys selected: click keys in the timeline (Shift adds, drag a box for many).")
            return None
        n = sum(len(v) for v in sel.values())
        edit = self.push(lambda: self.timeline.delete_keys(sel), f"delete {n} key{'s' if n != 1 else ''}")
        if edit is not None:
            self.set_selection({})
        return edit

    def copy_selected(self) -> bool:
        sel = self.selection()
        if not sel:
            self.message.emit("No keys selected to copy.")
            return False
        self.clipboard = self.timeline.copy_keys(sel)
        n = sum(len(v) for v in sel.values())
        self.message.emit(f"Copied {n} key{'s' if n != 1 else ''}.")
        return True

    def paste(self, at: float | None = None) -> Edit | None:
        """Paste the copied keys with the earliest at ``at`` (default: the cursor); the pasted keys get selected."""
        clip = self.clipboard
        if clip is None or not clip.keys:
            self.message.emit("Nothing to paste: copy keys first (Ctrl+C).")
            return None
        at = self.current_time if at is None else float(at)
        edit = self.push(lambda: self.timeline.paste_keys(clip, at), "paste keys")
        if edit is not None:
            self.set_selection({k: [at + key.time for key in keys] for k, keys in clip.keys.items()})
        return edit

    def move_selected(self, dt: float) -> Edit | None:
        """Shift the selected keys by ``dt`` s (keys keep their values); the selection follows."""
        sel = self.selection()
        if not sel or dt == 0:
            return None
        edit = self.push(lambda: self.timeline.move_keys(sel, dt), "move keys")
        if edit is not None:
            self.set_selection({k: [t + dt for t in v] for k, v in sel.items()})
        return edit

    def set_interpolation(self, interpolation: str, selection: Mapping | None = None) -> Edit | None:
        sel = self.selection() if selection is None else selection
        if not sel:
            self.message.emit("No keys selected.")
            return None
        return self.push(lambda: self.timeline.set_interpolation(sel, interpolation),
                         f"interpolation {interpolation}")

    # ------------------------------------------------------------ settings
    def set_settings(self, duration: float | None = None, fps: int | None = None) -> Edit | None:
        text = "timeline duration" if fps is None else "frame rate" if duration is None else "timeline settings"
        return self.push(lambda: self.timeline.set_settings(duration, fps), text)


def _sort_key(key: str):
    try:
        return P.sort_key(key)
    except P.ParameterError:
        return (99, key, 0, key, "")


__all__ = ["TimelineController", "TimelineEditCommand", "SPEEDS", "parameter_label", "parameter_range",
           "muscle_keys"]
