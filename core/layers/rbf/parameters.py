"""The ``cp:<feature point>:<x|y|z>`` parameter kind: an RBF control point's displacement in mm along one axis
(thesis B §4.1.1). The id is an MPEG-4 feature point (resources/mpeg4/feature_points.csv); a control-point
name of resources/rbf/influence.csv is accepted too (``cp:mouth_corner_l:y`` is ``cp:8.3:y``). "Link
left/right" moves the mirror partner's y and z with it (x would need the opposite sign, so it has none)."""

from __future__ import annotations

import functools

from core.layer import register_layer
from core.parameters import Parameter, ParameterError, ParameterKind, ParamKey, register_kind

_SYNTAX = "cp:<feature point>:<x|y|z>"
RANGE_MM = 50.0


@functools.cache
def _tables() -> tuple[dict[str, str], dict[str, str], dict[str, str], dict[str, str]]:
    """({fp: description}, {fp: control-point name}, {name: fp}, {fp: mirror fp})."""
    import resources

    desc = {r["fp"]: r["description"] for r in resources.get_table("mpeg4/feature_points.csv")}
    names = {r["fp"]: r["name"] for r in resources.get_table("rbf/influence.csv")}
    mirror = {}
    for r in resources.get_table("mpeg4/landmark_pairs.csv"):
        mirror[r["left"]], mirror[r["right"]] = r["right"], r["left"]
    return desc, names, {n: f for f, n in names.items()}, mirror


def _key(args: list[str]) -> ParamKey:
    usage = ("control-point keys are 'cp:<feature point>:<x|y|z>', e.g. 'cp:8.3:y' (the left mouth corner, "
             "up)")
    if len(args) != 2 or not all(args):
        raise ParameterError(usage)
    point, axis = args[0], args[1].lower()
    desc, _, by_name, _ = _tables()
    point = by_name.get(point.lower(), point)
    if point not in desc:
        raise ParameterError(f"{args[0]!r} is not an MPEG-4 feature point or control-point name; {usage}")
    if axis not in ("x", "y", "z"):
        raise ParameterError(f"the axis of a control point is x, y or z, got {args[1]!r}; {usage}")
    return ParamKey("cp", point, axis)


def _describe(key: ParamKey) -> Parameter:
    desc, names, _, mirror = _tables()
    name = names.get(key.id, f"fp {key.id}")
    partner = mirror.get(key.id)
    return Parameter(str(key), f"{name} {key.side}", "mm", -RANGE_MM, RANGE_MM, 0.0, "control points",
                     description=f"Moves the RBF control point on feature point {key.id} ({desc[key.id]}) along "
                                 f"{key.side}, in mm (thesis B §4.1.1)",
                     mirror=str(ParamKey("cp", partner, key.side)) if partner and key.side != "x" else None)


def _layer_for(rig):
    from core.layers.rbf.layer import ControlPointLayer

    return ControlPointLayer(rig.face)


register_kind(ParameterKind("cp", _SYNTAX, _key, _describe, order=6))
register_layer("control_points", ("cp",), _layer_for)
