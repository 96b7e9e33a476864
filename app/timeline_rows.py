"""The timeline's rows: which parameters get a lane (animated, or all with Show all), grouped like the
docks (FAP groups, expressions, visemes, muscles), their order, colours and value labels."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from PySide6.QtGui import QColor

from core.layers.fap import tables

from app.timeline_controller import TimelineController, muscle_keys, parameter_label


GROUP_TITLES = {"jaw & chin": "Jaw & chin", "other": "Other FAPs", "expressions": "Expressions",
                "visemes": "Visemes", "muscles": "Muscles", "control points": "Control points",
                "waters": "Waters muscles", "blends": "Blends", "layers": "Other layers"}
_LAYER_GROUPS = ("control points", "waters", "blends")
# Parameter kinds (core.parameters) -> their timeline group, after the FAP groups.
_KIND_GROUPS = {"expression": "expressions", "viseme": "visemes", "muscle": "muscles", "jaw": "muscles",
                "cp": "control points", "waters": "waters", "blend": "blends", "caricature": "blends"}


KEY_COLOR = QColor(222, 222, 222)


KEY_SELECTED = QColor(255, 150, 30)


KEY_BORDER = QColor(40, 40, 40)


CURSOR_COLOR = QColor(224, 64, 42)


def group_of(key: str) -> str:
    kind, _, rest = key.partition(":")
    if kind == "fap":
        dock = tables.fap_spec(int(rest)).dock
        return dock if dock in tables.DOCK_GROUPS else "other"
    return _KIND_GROUPS.get(kind, "layers")


def group_order() -> tuple[str, ...]:
    return (*tables.DOCK_GROUPS, "other", "expressions", "visemes", "muscles", "control points", "waters",
            "blends", "layers")


def all_parameters(controller: TimelineController) -> list[str]:
    """Every parameter the face can animate now (the rows of "Show all")."""
    keys = []
    rig = controller.rig
    if rig is not None:
        animated = set(rig.animated_faps)
        for spec in tables.fap_specs():
            if spec.number in animated and spec.dock and math.isfinite(spec.minimum) and spec.number > 2:
                keys.append(f"fap:{spec.number}")
        keys += [f"expression:{n}" for n in tables.expression_names()[1:]]
        keys += [f"viseme:{i}" for i in range(1, len(tables.viseme_names()))]
    if controller.document.muscle_layer is not None:
        keys += list(muscle_keys())
    if rig is not None:   # the other layers the face has now: control points, Waters muscles, blends
        seen = set(keys)
        keys += [k for k in rig.parameters() if k not in seen and group_of(k) in _LAYER_GROUPS]
    return keys


@dataclass
class Row:
    """One line of the track view: a group header (key None) or a parameter."""

    group: str
    key: str | None = None
    label: str = ""
    members: tuple[str, ...] = field(default=())  # group rows: the parameter keys listed under it

    @property
    def is_group(self) -> bool:
        return self.key is None


def build_rows(controller: TimelineController, show_all: bool, collapsed: set[str]) -> list[Row]:
    tracked = [k for k, tr in controller.timeline.tracks.items() if len(tr)]
    keys = list(dict.fromkeys((all_parameters(controller) if show_all else []) + tracked
                              + sorted(controller.selected_tracks)))
    by_group: dict[str, list[str]] = {}
    for k in keys:
        by_group.setdefault(group_of(k), []).append(k)
    rows: list[Row] = []
    for g in group_order():
        members = by_group.get(g)
        if not members:
            continue
        members.sort(key=_param_order)
        n_tracked = sum(1 for m in members if m in controller.timeline.tracks)
        title = GROUP_TITLES.get(g, g.capitalize())
        label = f"{title}  ({n_tracked}/{len(members)})" if show_all else f"{title}  ({len(members)})"
        rows.append(Row(g, None, label, tuple(members)))
        if g not in collapsed:
            rows += [Row(g, m, parameter_label(m)) for m in members]
    return rows


def _param_order(key: str):
    kind, _, rest = key.partition(":")
    if kind in ("fap", "viseme"):
        return (0, int(rest), "")
    if kind == "expression":
        return (0, tables.expression_id(rest), "")
    return (1, 0, key)


def _format_value(key: str, v: float) -> str:
    kind = key.split(":")[0]
    if kind in ("expression", "viseme"):
        return f"{v * 100:.0f} %"
    if kind == "fap":
        spec = tables.fap_spec(int(key[4:]))
        if spec.is_rotation:
            return f"{math.degrees(v * tables.ANGLE_UNIT):.1f}°"
        return f"{v:.0f}"
    if kind == "jaw":
        return f"{v:.1f}°"
    return f"{v:.3g}"
