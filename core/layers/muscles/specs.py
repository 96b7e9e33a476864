"""The 19 muscle controls and the jaw as data: names, sides, force ranges, validation.

Read from ``resources/muscles/muscles.json`` without building anything: the window lists the
controls and presets at start-up without importing the tissue model (scipy's graph and sparse
solvers, the dense template), which loads in the background once the face is animatable.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

import resources


@functools.cache
def load_definitions() -> dict:
    """The muscle/jaw definitions (``resources/muscles/muscles.json``), parsed once (do not mutate)."""
    return resources.get_json("muscles/muscles.json")


def force_unit_dyn() -> float:
    """One thesis force unit in dyn (``resources/muscles/tissue.json``)."""
    return float(resources.get_json("muscles/tissue.json")["force_unit_dyn"])


ORBICULARIS = "orbicularis_oris"
SIDES = ("left", "right")


@dataclass(frozen=True)
class MuscleSpec:
    """One muscle (a pair counts once). Forces in thesis units; see ``tissue.json`` force_unit_dyn."""

    name: str            # snake_case id
    label: str           # human name
    paired: bool         # True: one control per side
    minimum: float
    maximum: float
    description: str
    radius_mm: float = 0.0
    lip: str = "both"


@functools.cache
def muscle_specs() -> tuple[MuscleSpec, ...]:
    """The 10 muscles: 9 linear pairs then the orbicularis oris."""
    d = load_definitions()
    out = [MuscleSpec(m["name"], m["label"], True, float(m["minimum"]), float(m["maximum"]), m["description"],
                      float(m["radius_mm"]), m.get("lip", "both")) for m in d["linear"]]
    o = d["orbicularis"]
    out.append(MuscleSpec(o["name"], o["label"], False, float(o["minimum"]), float(o["maximum"]), o["description"],
                          float(o["radius_mm"]), "both"))
    return tuple(out)


@functools.cache
def control_keys() -> tuple[tuple[str, str | None], ...]:
    """The 19 controls: (name, "left"|"right") per linear muscle, then ("orbicularis_oris", None)."""
    keys: list[tuple[str, str | None]] = []
    for s in muscle_specs():
        if s.paired:
            keys += [(s.name, "left"), (s.name, "right")]
        else:
            keys.append((s.name, None))
    return tuple(keys)


@functools.cache
def spec_by_name() -> dict[str, MuscleSpec]:
    return {s.name: s for s in muscle_specs()}


def jaw_range() -> tuple[float, float]:
    """(minimum, maximum) jaw opening in degrees."""
    j = load_definitions()["jaw"]
    return float(j["minimum"]), float(j["maximum"])


def check_control(name, side, value) -> tuple[tuple[str, str | None], float]:
    """((name, side), value) validated; ValueError with a message for the user otherwise (no clamping)."""
    specs = spec_by_name()
    if name not in specs:
        raise ValueError(f"unknown muscle {name!r}; muscles are: {', '.join(specs)}")
    spec = specs[name]
    if spec.paired:
        if side not in SIDES:
            raise ValueError(f"{spec.label}: side must be 'left' or 'right' (the face's own sides), got {side!r}")
    elif side is not None:
        raise ValueError(f"{spec.label} is a single muscle around the mouth: its side must be None, got {side!r}")
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{spec.label}: force must be a number, got {value!r}")
    value = float(value)
    if not np.isfinite(value):
        raise ValueError(f"{spec.label}: force must be a finite number, got {value}")
    if not spec.minimum <= value <= spec.maximum:
        raise ValueError(f"{spec.label} force {value:g} is outside its range {spec.minimum:g} to {spec.maximum:g}")
    return (name, side), value
