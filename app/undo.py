"""undo.py
----
The one undo stack of Mimica (a ``QUndoStack``) and its commands.

* :class:`SetValueCommand` — generic "apply old / apply new" command. Commands
  with the same ``merge_id`` pushed within one *gesture* merge into one undo
  step, so a slider drag (hundreds of value changes) undoes in one go.
* :class:`LandmarkMoveCommand` / :class:`LandmarkSetCommand` — landmark edits
  (one landmark / the before and after states of the landmarks a change
  touched) on a :class:`core.landmark_editing.LandmarkEditModel`.
* :class:`UndoableRigEdits` — records every parameter change of a
  :class:`core.rig.FaceRig` (any layer: FAPs, presets, muscles, jaw, ...) as
  undo steps, whoever made it (a dock, a script), from the rig's change
  events, merging per gesture. A step holds only the parameters it changed,
  so undoing an old step never reverts later, unrelated changes.
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
timeline posing the rig) must not fill the stack: wrap it in
``UndoableRigEdits.suspended()`` or call ``pause()``/``resume()``.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any, Callable, Hashable, Mapping

from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtGui import QAction, QInputEvent, QKeySequence, QUndoCommand, QUndoStack
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
        if not isinstance(event, QInputEvent):
            # Every event of the application passes here: most are not input, and asking their
            # type (a Python enum made per call) would cost ~10 us each, ~0.1 s of start-up.
            return False
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
    """Turns every parameter change of a FaceRig (any layer: FAPs, presets, muscles, jaw, ...) into
    undo steps on ``stack``.

    It listens to ``rig.parameters_changed``, whose event names the keys with their new and previous
    values, so it needs no hook in the widgets and diffs nothing. A step holds only the keys it
    changed (undoing an old step never reverts later, unrelated changes); changes of the same keys
    during one gesture (a slider drag) merge into one step.

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
        self._applying = False
        self._paused = 0
        gestures()
        self.set_rig(rig)

    # ------------------------------------------------------------ wiring
    def set_rig(self, rig) -> None:
        """Follow ``rig`` (None: record nothing)."""
        if self.rig is not None:
            with contextlib.suppress(ValueError, RuntimeError, TypeError):
                self.rig.parameters_changed.disconnect(self._on_changed)
        self.rig = rig
        if rig is not None:
            rig.parameters_changed.connect(self._on_changed)

    def pause(self) -> None:
        """Stop recording (nested calls need as many :meth:`resume`)."""
        self._paused += 1

    def resume(self) -> None:
        """Record again (what changed while paused is no step)."""
        self._paused = max(0, self._paused - 1)

    @contextlib.contextmanager
    def suspended(self):
        """``with edits.suspended(): play()`` — changes inside are not recorded."""
        self.pause()
        try:
            yield
        finally:
            self.resume()

    @property
    def recording(self) -> bool:
        return self.rig is not None and not self._paused

    # ------------------------------------------------------------ steps
    def apply_state(self, part: Mapping[str, float]) -> None:
        """Put the parameters of one step back into the rig (undo/redo; not recorded)."""
        rig = self.rig
        if rig is None:
            return
        self._applying = True
        try:
            rig.set_values({k: v for k, v in part.items() if k in set(rig.parameters())})
        finally:
            self._applying = False

    def _on_changed(self, change) -> None:
        if self.rig is None or self._applying or self._paused or not change.values:
            return
        before, after = dict(change.previous), dict(change.values)
        command = SetValueCommand(describe_keys(after), self.apply_state, before, after,
                                  merge_id=("rig", id(self.rig), tuple(after)), applied=True)
        self.stack.push(command)


def describe_keys(keys) -> str:
    """"3 open jaw", "joy", "Risorius (L)" for one parameter; "4 parameters" for several."""
    from core import parameters

    keys = list(keys)
    if len(keys) == 1:
        return parameters.label(keys[0])
    return f"{len(keys)} parameters"
