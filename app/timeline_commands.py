"""The timeline's undo commands and parameter helpers: labels and lane ranges from the parameter
registry (core.parameters), and TimelineEditCommand, one undo step of a timeline edit (with the rig
values around it for auto-key)."""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping

from PySide6.QtGui import QUndoCommand

from core import parameters as P
from core.timeline import Edit, Track


# ------------------------------------------------------------------ parameters
def parameter_label(key: str) -> str:
    """Short readable name of a parameter key, e.g. "3 open jaw", "joy", "1 p b m" (``core.parameters``)."""
    return P.label(key)


def parameter_range(key: str, track: Track | None = None) -> tuple[float, float]:
    """(low, high) to scale a parameter's curve in its lane: its range, or the track's span."""
    try:
        p = P.describe(key)
        if math.isfinite(p.minimum) and math.isfinite(p.maximum):
            return p.minimum, p.maximum
    except P.ParameterError:
        pass
    if track is not None and len(track):
        lo, hi = float(track.values.min()), float(track.values.max())
        return (min(lo, 0.0), hi if hi > lo else lo + 1.0)
    return 0.0, 1.0


def muscle_keys() -> tuple[str, ...]:
    """The muscle layer's 19 force keys, then ``jaw``."""
    from core.layers.muscles import control_keys

    return tuple(P.key_of(k) for k in control_keys()) + ("jaw",)


# ------------------------------------------------------------------ undo
_MERGE_IDS: dict = {}  # merge key -> QUndoCommand.id() (an int; app.undo uses 1000 + n)


def _describe_change(rows: Mapping[str, Any]) -> str:
    keys = list(rows)
    return parameter_label(keys[0]) if len(keys) == 1 else f"{len(keys)} parameters"


def _merge_edits(first: Edit, second: Edit, label: str) -> Edit:
    """One edit doing ``first`` then ``second`` (same before/after key sets, as ``Edit`` requires)."""
    keys = list(dict.fromkeys([*first.after, *second.after]))
    before = {k: first.before[k] if k in first.before else second.before[k] for k in keys}
    after = {k: second.after[k] if k in second.after else first.after[k] for k in keys}
    sb = first.settings_before if first.settings_before is not None else second.settings_before
    sa = second.settings_after if second.settings_after is not None else first.settings_after
    return Edit(label, before, after, sb, sa)


class TimelineEditCommand(QUndoCommand):
    """One undo step of the timeline: an applied ``Edit``, optionally with extra state around it.

    rig_before / rig_after : {parameter key: value} put back on the rig after the edit is undone /
    redone (auto-key: the slider change and its keys are one step). extra_undo / extra_redo :
    callables run after the timeline part (e.g. the speech clip list of a lip-sync edit).
    merge_key : commands with the same key in the same user gesture merge (a drag with auto-key = one step).
    """

    def __init__(self, controller, edit: Edit, text: str | None = None, *,
                 applied: bool = True, rig_before: Mapping | None = None, rig_after: Mapping | None = None,
                 extra_undo: Callable[[], None] | None = None, extra_redo: Callable[[], None] | None = None,
                 merge_key=None):
        super().__init__(text or edit.label)
        self.controller = controller
        self.timeline = controller.timeline
        self.edit = edit
        self.rig_before, self.rig_after = rig_before, rig_after
        self.extra_undo, self.extra_redo = extra_undo, extra_redo
        self.merge_key = merge_key
        from app.undo import gestures

        self._merge_id = -1 if merge_key is None else _MERGE_IDS.setdefault(merge_key, 500_000 + len(_MERGE_IDS))
        self.gesture = gestures().number
        self._skip = bool(applied)

    def id(self) -> int:  # noqa: A003 - Qt API
        return self._merge_id

    def redo(self) -> None:
        if self._skip:
            self._skip = False
            return
        self.controller._run_command(self.timeline, self.edit, self.rig_after, self.extra_redo)

    def undo(self) -> None:
        self.controller._run_command(self.timeline, self.edit.inverse(), self.rig_before, self.extra_undo)

    def mergeWith(self, other: QUndoCommand) -> bool:  # noqa: N802 - Qt API
        if (not isinstance(other, TimelineEditCommand) or other.merge_key != self.merge_key
                or other.gesture != self.gesture or other.timeline is not self.timeline):
            return False
        self.edit = _merge_edits(self.edit, other.edit, self.edit.label)
        if other.rig_after is not None:
            self.rig_after = {**(self.rig_after or {}), **other.rig_after}
        if other.rig_before is not None:
            self.rig_before = {**other.rig_before, **(self.rig_before or {})}
        return True
