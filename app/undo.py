"""undo.py
----
The one undo stack of Mimica (a ``QUndoStack``) and its commands.

* :class:`SetValueCommand` — generic "apply old / apply new" command. Commands
  with the same ``merge_id`` pushed within one *gesture* merge into one undo
  step, so a slider drag (hundreds of value changes) undoes in one go.
* :class:`LandmarkMoveCommand` / :class:`LandmarkSetCommand` — landmark edits
  (one landmark / the before and after states of the landmarks a change
  touched) on a :class:`core.landmark_editing.LandmarkEditModel`.
* :class:`UndoableRigEdits` — records every change of a
  :class:`core.rig.FaceRig` (FAP values, expression and viseme presets) as
  undo steps, whoever made it (FAP dock, scripts), merging per gesture. A
  step holds only the parameters it changed, so undoing an old step never
  reverts later, unrelated changes.
* :func:`make_undo_actions` — Edit ▸ Undo/Redo actions ("Undo <what>") with
  the platform's standard shortcuts.

Gestures: :class:`GestureTracker` watches the application's input events. A
mouse-button press, a wheel turn after a pause, or a key press that is not an
auto-repeat starts a new gesture; everything that happens until the next one
(a drag, an auto-repeating arrow key, a wheel spin) is the same gesture.
Changes made with no user input in between (a script, a test) share one
gesture, so callers that need separate steps call ``GestureTracker.new()``.

Choices: undo history is per face: when the face is replaced the stack is
cleared, because its commands point at the old face and rig. Playback (the
.fap player, later the timeline) must not fill the stack: wrap it in
``UndoableRigEdits.suspended()`` or call ``pause()``/``resume()``.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any, Callable, Hashable, Mapping

from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtGui import QAction, QKeySequence, QUndoCommand, QUndoStack
from PySide6.QtWidgets import QApplication

__all__ = [
    "GestureTracker", "SetValueCommand", "LandmarkMoveCommand", "LandmarkSetCommand", "UndoableRigEdits",
    "make_undo_stack", "make_undo_actions", "gestures",
]

#: A wheel event this long (s) after the previous one starts a new gesture.
WHEEL_PAUSE_S = 0.6

_MERGE_IDS: dict[Hashable, int] = {}


def _merge_number(key: Hashable | None) -> int:
    """A stable positive int per merge key (QUndoCommand.id() must be an int; -1 = never merge)."""
    if key is None:
        return -1
    return _MERGE_IDS.setdefault(key, 1000 + len(_MERGE_IDS))


# ------------------------------------------------------------------ gestures
class GestureTracker(QObject):
    """Counts user gestures (see the module docstring) with an application-wide event filter."""

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        self.number = 0
        self._last_wheel = 0.0
        self._last_press: tuple | None = None
        self._installed = False

    def install(self) -> None:
        app = QApplication.instance()
        if app is not None and not self._installed:
            app.installEventFilter(self)
            self._installed = True

    def new(self) -> int:
        """Start a new gesture now; returns its number."""
        self.number += 1
        return self.number

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:  # noqa: N802 - Qt override
        kind = event.type()
        if kind in (QEvent.Type.MouseButtonPress, QEvent.Type.MouseButtonDblClick) or (
                kind == QEvent.Type.KeyPress and not event.isAutoRepeat()):
            # One physical press reaches several receivers (the window, the widget, its
            # parents when ignored), all with the same timestamp: count it once.
            stamp = (kind, event.timestamp())
            if stamp != self._last_press:
                self._last_press = stamp
                self.new()
        elif kind == QEvent.Type.Wheel:
            now = time.monotonic()
            if now - self._last_wheel > WHEEL_PAUSE_S:
                self.new()
            self._last_wheel = now
        return False


_GESTURES: GestureTracker | None = None


def gestures() -> GestureTracker:
    """The application's gesture tracker (created and installed on first use)."""
    global _GESTURES
    if _GESTURES is None:
        _GESTURES = GestureTracker(QApplication.instance())
    _GESTURES.install()
    return _GESTURES


# ------------------------------------------------------------------ commands
class SetValueCommand(QUndoCommand):
    """Undo/redo one value change through ``apply_fn(value)``.

    Parameters
    ----------
    description : str
        What changed, for "Undo <description>".
    apply_fn : callable(value)
        Puts a value into effect (a setter).
    old, new : any
        The values before and after.
    merge_id : hashable, optional
        Commands with the same ``merge_id`` pushed during the same gesture merge into one
        (the first one's ``old``, the last one's ``new``). None never merges.
    applied : bool
        True when the change is already in effect (the usual case for widgets that already
        wrote to the model): the push does not apply it again.
    gesture : int, optional
        The gesture number; default: the current one of :func:`gestures`.
    """

    def __init__(self, description: str, apply_fn: Callable[[Any], None], old, new, merge_id: Hashable | None = None,
                 *, applied: bool = False, gesture: int | None = None, same: Callable[[Any, Any], bool] | None = None):
        super().__init__(description)
        self.apply_fn = apply_fn
        self.old, self.new = old, new
        self.merge_key = merge_id
        self.gesture = gestures().number if gesture is None else gesture
        self._skip_redo = bool(applied)
        self._same = same or (lambda a, b: a == b)

    def id(self) -> int:  # noqa: A003 - Qt API
        return _merge_number(self.merge_key)

    def redo(self) -> None:
        if self._skip_redo:
            self._skip_redo = False
            return
        self.apply_fn(self.new)

    def undo(self) -> None:
        self.apply_fn(self.old)

    def mergeWith(self, other: QUndoCommand) -> bool:  # noqa: N802 - Qt API
        if not isinstance(other, SetValueCommand) or other.merge_key != self.merge_key:
            return False
        if other.gesture != self.gesture:
            return False
        self.new = other.new
        if other.text():
            self.setText(other.text())
        # A drag that ends where it started is no step at all: the stack drops it.
        self.setObsolete(bool(self._same(self.old, self.new)))
        return True


class LandmarkSetCommand(QUndoCommand):
    """Any change of a landmark set, as before/after states of the landmarks it touches.

    ``before``/``after`` map name -> LandmarkState; a name missing from ``before`` did not
    exist (undo removes it). ``applied``: the change is already in effect.
    """

    def __init__(self, model, description: str, before: Mapping, after: Mapping, *, applied: bool = False):
        super().__init__(description)
        self.model = model
        self.before, self.after = dict(before), dict(after)
        self._skip_redo = bool(applied)

    def redo(self) -> None:
        if self._skip_redo:
            self._skip_redo = False
            return
        self.model.update_states(self.after)

    def undo(self) -> None:
        removed = [n for n in self.after if n not in self.before]
        if removed:
            snapshot = self.model.snapshot()
            for name in removed:
                snapshot.pop(name, None)
            snapshot.update(self.before)
            self.model.restore(snapshot)
        else:
            self.model.update_states(self.before)

    @classmethod
    def from_snapshots(cls, model, description: str, before: Mapping, after: Mapping, **kw) -> "LandmarkSetCommand":
        """A command holding only the landmarks that differ between two full snapshots."""
        names = [n for n in after if before.get(n) != after[n]]
        return cls(model, description, {n: before[n] for n in names if n in before},
                   {n: after[n] for n in names}, **kw)


class LandmarkMoveCommand(LandmarkSetCommand):
    """Move one landmark to a SurfacePoint (it becomes ``edited``); undo restores it exactly."""

    def __init__(self, model, name: str, point, *, description: str | None = None):
        from core.landmark_editing import LandmarkState, LandmarkStatus

        before = model.state(name)
        after = LandmarkState(point, LandmarkStatus.EDITED, None)
        super().__init__(model, description or f"move landmark {name}", {name: before}, {name: after})
        self.name = name


def make_undo_stack(parent: QObject | None = None, *, limit: int = 500) -> QUndoStack:
    """The application's undo stack (``limit`` steps; 0 = unlimited)."""
    stack = QUndoStack(parent)
    stack.setUndoLimit(limit)
    gestures()
    return stack


def make_undo_actions(stack: QUndoStack, parent: QObject) -> tuple[QAction, QAction]:
    """(undo_action, redo_action): texts follow the stack ("Undo move landmark 8.3"),
    standard shortcuts (Ctrl+Z / Ctrl+Shift+Z or Ctrl+Y), window-wide."""
    undo = stack.createUndoAction(parent, "&Undo")
    redo = stack.createRedoAction(parent, "&Redo")
    undo.setShortcuts(QKeySequence.keyBindings(QKeySequence.StandardKey.Undo))
    redo.setShortcuts(QKeySequence.keyBindings(QKeySequence.StandardKey.Redo))
    for action, what in ((undo, "Undo the last change"), (redo, "Redo the last undone change")):
        action.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
        action.setStatusTip(what)
    return undo, redo


# ------------------------------------------------------------------ rig edits
class UndoableRigEdits(QObject):
    """Turns every change of a FaceRig's parameters into undo steps on ``stack``.

    It listens to ``rig.changed`` and diffs the rig's state (the 68 low-level FAP values and
    the expression/viseme presets) against the last one it saw, so it needs no hook in the
    widgets: the FAP dock's sliders, spin boxes, resets and presets are all recorded. Changes
    of the same parameters during one gesture (a slider drag) merge into one step.

    Parameters
    ----------
    stack : QUndoStack
    rig : FaceRig or None
        Change with :meth:`set_rig` when the face changes.
    """

    def __init__(self, stack: QUndoStack, rig=None, parent: QObject | None = None):
        super().__init__(parent if parent is not None else stack)
        self.stack = stack
        self.rig = None
        self._state = None
        self._applying = False
        self._paused = 0
        gestures()
        self.set_rig(rig)

    # ------------------------------------------------------------ wiring
    def set_rig(self, rig) -> None:
        """Follow ``rig`` (None: record nothing)."""
        if self.rig is not None:
            with contextlib.suppress(ValueError, RuntimeError, TypeError):
                self.rig.changed.disconnect(self._on_changed)
        self.rig = rig
        self._state = None if rig is None else self.state_of(rig)
        if rig is not None:
            rig.changed.connect(self._on_changed)

    def pause(self) -> None:
        """Stop recording (nested calls need as many :meth:`resume`)."""
        self._paused += 1

    def resume(self) -> None:
        """Record again; what changed while paused is taken as the new starting point (no step)."""
        self._paused = max(0, self._paused - 1)
        if not self._paused and self.rig is not None:
            self._state = self.state_of(self.rig)

    @contextlib.contextmanager
    def suspended(self):
        """``with edits.suspended(): play()`` — changes inside are not recorded."""
        self.pause()
        try:
            yield
        finally:
            self.resume()

    def follow_player(self, player) -> None:
        """Record nothing while ``player`` (app.fap_player.FapPlayer: ``state_changed(bool playing)``)
        plays; the pose it stops on becomes the starting point of the next step."""
        playing = [False]

        def on_state(is_playing: bool) -> None:
            if bool(is_playing) != playing[0]:
                playing[0] = bool(is_playing)
                self.pause() if is_playing else self.resume()

        player.state_changed.connect(on_state)

    @property
    def recording(self) -> bool:
        return self.rig is not None and not self._paused

    # ------------------------------------------------------------ state
    @staticmethod
    def state_of(rig) -> tuple:
        """(FAP values tuple (68,), expressions, visemes): everything a FAP-dock edit can change."""
        return (tuple(float(v) for v in rig.fap_values()), tuple(rig.expressions), tuple(rig.visemes))

    def apply_state(self, part: dict) -> None:
        """Put the parameters in ``part`` back into the rig (undo/redo; not recorded).

        ``part`` maps FAP numbers to values and/or "expressions"/"visemes" to preset mixes: only
        what one step changed, so undoing an old step never reverts later, unrelated changes.
        """
        rig = self.rig
        if rig is None:
            return
        self._applying = True
        try:
            faps = {k: v for k, v in part.items() if isinstance(k, int)}
            current = rig.fap_values()
            faps = {n: v for n, v in faps.items() if current[n - 1] != v}
            if faps:
                rig.set_faps(faps)
            if "expressions" in part and tuple(rig.expressions) != part["expressions"]:
                _restore_presets(rig, "_expressions", part["expressions"], rig.set_expression, rig.set_fap2)
            if "visemes" in part and tuple(rig.visemes) != part["visemes"]:
                _restore_presets(rig, "_visemes", part["visemes"], rig.set_viseme, None)
        finally:
            self._applying = False
            self._state = self.state_of(rig)

    def _on_changed(self) -> None:
        rig = self.rig
        if rig is None or self._applying:
            return
        new = self.state_of(rig)
        old = self._state
        self._state = new
        if self._paused or old is None or new == old:
            return
        before, after, text = _difference(old, new)
        command = SetValueCommand(text, self.apply_state, before, after,
                                  merge_id=("rig", id(rig), tuple(after)), applied=True)
        self.stack.push(command)


def _restore_presets(rig, attribute: str, mix: tuple, single_setter, fap2_setter) -> None:
    public = attribute.lstrip("_")  # "expressions" / "visemes"
    if len(mix) == 1:
        pid, intensity = mix[0]
        single_setter(None if pid == 0 else pid, intensity)
        if tuple(getattr(rig, public)) == mix:
            return
    if fap2_setter is not None and len(mix) == 2:
        (s1, i1), (s2, i2) = mix
        k1, k2 = round(i1 * 63), round(i2 * 63)
        if abs(k1 / 63 - i1) < 1e-12 and abs(k2 / 63 - i2) < 1e-12:
            fap2_setter(s1, k1, s2, k2)
            if tuple(getattr(rig, public)) == mix:
                return
    # A mix no public setter reproduces exactly (e.g. a .fap FAP 1 blend): restore it as stored.
    # FaceRig has no public "set this preset mix" yet (asked for in the issue-6 report).
    rig._set_presets(attribute, tuple(mix))  # noqa: SLF001


def _difference(old: tuple, new: tuple) -> tuple[dict, dict, str]:
    """(what changed, before), (after) as partial states, and "what" for the Undo text."""
    from core.fap import tables

    changed_faps = [i + 1 for i, (a, b) in enumerate(zip(old[0], new[0])) if a != b]
    before = {n: old[0][n - 1] for n in changed_faps}
    after = {n: new[0][n - 1] for n in changed_faps}
    for key, i in (("expressions", 1), ("visemes", 2)):
        if old[i] != new[i]:
            before[key], after[key] = old[i], new[i]
    parts = []
    if len(changed_faps) == 1:
        try:
            from app.fap_dock import readable_name

            parts.append(f"FAP {changed_faps[0]} {readable_name(tables.fap_spec(changed_faps[0]))}")
        except Exception:  # noqa: BLE001 - the text is decoration
            parts.append(f"FAP {changed_faps[0]}")
    elif changed_faps:
        parts.append(f"{len(changed_faps)} FAPs")
    if "expressions" in after:
        parts.append("expression")
    if "visemes" in after:
        parts.append("viseme")
    return before, after, " and ".join(parts) or "animation"
