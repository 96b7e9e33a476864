"""The muscle layer's parameter kinds: ``muscle:<name>[:<side>]`` forces and the ``jaw`` angle
(see ``core.parameters``). Names, pairing and ranges come from ``resources/muscles/muscles.json``;
both kinds are simulated (their effect at time t depends on the force history)."""

from __future__ import annotations

from core.layer import register_layer
from core.parameters import Parameter, ParameterError, ParameterKind, ParamKey, parse, register_kind
from core.layers.muscles.specs import SIDES, jaw_range, spec_by_name

_SYNTAX = "muscle:<name>:<left|right>"


def _muscle_key(args: list[str]) -> ParamKey:
    if not 1 <= len(args) <= 2 or not args[0]:
        raise ParameterError("muscle keys are 'muscle:<name>:<left|right>' or 'muscle:<name>' for an unpaired "
                             "muscle, e.g. 'muscle:zygomatic_major:left' or 'muscle:orbicularis_oris'")
    name = args[0].lower()
    side = args[1].lower() if len(args) == 2 and args[1] else None
    specs = spec_by_name()
    if name not in specs:
        raise ParameterError(f"unknown muscle {name!r}; muscles are {', '.join(sorted(specs))}")
    if specs[name].paired and side not in SIDES:
        raise ParameterError(f"{name} is a left/right pair: use 'muscle:{name}:left' or 'muscle:{name}:right'")
    if not specs[name].paired and side is not None:
        raise ParameterError(f"{name} is a single muscle: use 'muscle:{name}' without a side")
    return ParamKey("muscle", name, side)


def _muscle_describe(key: ParamKey) -> Parameter:
    spec = spec_by_name()[key.id]
    label = spec.label + (f" ({key.side[0].upper()})" if key.side else "")
    mirror = None if key.side is None else str(ParamKey("muscle", key.id, "right" if key.side == "left" else "left"))
    return Parameter(str(key), label, "force", float(spec.minimum), float(spec.maximum), 0.0, "muscles",
                     simulated=True, description=spec.description, mirror=mirror)


def _jaw_key(args: list[str]) -> ParamKey:
    if args:
        raise ParameterError("the jaw key is just 'jaw' (angle in degrees)")
    return ParamKey("jaw")


def _jaw_describe(key: ParamKey) -> Parameter:
    lo, hi = jaw_range()
    return Parameter("jaw", "jaw angle (°)", "°", lo, hi, 0.0, "muscles", simulated=True,
                     description="Opens the jaw: rotates the lower lip and chin about an axis behind the ears "
                                 "(thesis C §3.4)")


def control_of(key: str) -> tuple[str, str | None]:
    """(name, side) of a ``muscle:`` key, as ``MuscleLayer.set_forces`` takes it."""
    k = parse(key)
    if k.kind != "muscle":
        raise ParameterError(f"{key!r} is not a muscle force")
    return k.id, k.side


def _layer_for(rig):
    """A muscle layer for ``rig``'s face, on its FAP deformer's dense template (a few seconds)."""
    from core.layers.muscles.layer import MuscleLayer

    layer = MuscleLayer(rig.face, template_dense=getattr(rig.deformer, "dense", None))
    layer.attach(rig)
    return layer


register_kind(ParameterKind("muscle", _SYNTAX, _muscle_key, _muscle_describe, simulated=True, order=3))
register_kind(ParameterKind("jaw", "jaw", _jaw_key, _jaw_describe, simulated=True, order=4))
register_layer("muscles", ("muscle", "jaw"), _layer_for, slow=True)

__all__ = ["control_of"]
