"""The ``waters:<muscle>:<left|right>`` parameter kind: a Waters vector muscle's strength 0..1 (thesis B
§4.1.2; muscles from resources/waters/muscles.csv). Distinct from the SABiom ``muscle:`` forces; both layers
compose in one rig."""

from __future__ import annotations

import functools

from core.layer import register_layer
from core.parameters import Parameter, ParameterError, ParameterKind, ParamKey, register_kind

_SYNTAX = "waters:<muscle>:<left|right>"


@functools.cache
def _labels() -> dict[str, str]:
    import resources

    return {r["name"]: r["label"] for r in resources.get_table("waters/muscles.csv")}


def _key(args: list[str]) -> ParamKey:
    usage = "Waters muscle keys are 'waters:<muscle>:<left|right>', e.g. 'waters:zygomatic_major:left'"
    if len(args) != 2 or not all(args):
        raise ParameterError(usage)
    name, side = args[0].lower(), args[1].lower()
    if name not in _labels():
        raise ParameterError(f"unknown Waters muscle {args[0]!r}; they are {', '.join(_labels())}")
    if side not in ("left", "right"):
        raise ParameterError(f"{usage} (side {args[1]!r} is neither)")
    return ParamKey("waters", name, side)


def _describe(key: ParamKey) -> Parameter:
    other = "right" if key.side == "left" else "left"
    return Parameter(str(key), f"{_labels()[key.id]} ({key.side[0].upper()}, Waters)", "contraction", 0.0, 1.0,
                     0.0, "Waters muscles",
                     description=f"Contracts Waters' vector muscle {_labels()[key.id]} on the {key.side}: skin in "
                                 "its zone moves toward its attachment (thesis B eqs. 4.16-4.19)",
                     mirror=str(ParamKey("waters", key.id, other)))


def _layer_for(rig):
    from core.layers.waters.layer import WatersLayer

    return WatersLayer(rig.face)


register_kind(ParameterKind("waters", _SYNTAX, _key, _describe, order=5))
register_layer("waters", ("waters",), _layer_for)
