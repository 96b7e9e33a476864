"""``FapLayer``: the MPEG-4 FAP values and presets of a face, as the rig's first layer.

State: the user's 68 low-level values (FAP units; index n - 1), the active expression presets
(FAP 2) and viseme presets (FAP 1) as ((id, intensity 0..1), ...), strongest first unless a
.fap-style FAP 2/1 blend gave them in its own order. The *effective* values that drive the Facial
Animation Table are the user's values plus the presets scaled by their intensities.

Parameters (``core.parameters``): ``fap:<n>`` for every FAP this face can animate,
``expression:<name>`` (1..6) and ``viseme:<id>`` (1..14) intensities. ``offset`` is the FAT's
displacement; ``finish`` applies the FAPs' non-additive steps (lid contact, eyeball and head
rotations) after every layer's offset.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Mapping

import numpy as np
from psygnal import Signal

from core import parameters as P
from core.layer import ParameterChange
from core.layers.fap import parameters as _kinds  # noqa: F401 - registers the fap/expression/viseme kinds
from core.layers.fap.parameters import CLOSED_LID_OPENING, UPPER_LIDS
from core.layers.fap import tables
from core.layers.fap.fat import FapDeformer

N_FAPS = tables.N_FAPS
Mix = tuple[tuple[int, float], ...]
NEUTRAL: Mix = ((0, 0.0),)


class FapLayer:
    """The FAP values and presets of one face (see the module docstring)."""

    name = "faps"
    parameters_changed = Signal(object)
    pose_changed = Signal()

    def __init__(self, deformer: FapDeformer):
        self.deformer = deformer
        self._values = np.zeros(N_FAPS)
        self._expressions: Mix = NEUTRAL
        self._visemes: Mix = NEUTRAL
        self._limited: np.ndarray | None = None
        self._presets = (tuple(f"expression:{e}" for e in tables.expression_names()[1:])
                         + tuple(f"viseme:{v}" for v in range(1, len(tables.viseme_names()))))

    # ------------------------------------------------------------ the layer protocol
    def parameters(self) -> tuple[str, ...]:
        """``fap:<n>`` for the FAPs this face animates, then every expression and viseme."""
        return tuple(f"fap:{n}" for n in sorted(self.deformer.animated_faps) if n > 2) + self._presets

    def value(self, key) -> float:
        k = P.parse(key)
        if k.kind == "fap":
            return float(self._values[int(k.id) - 1])
        mix, ident = self._mix_and_id(k)
        return float(sum(w for i, w in mix if i == ident))

    def set_values(self, values: Mapping) -> None:
        """Set parameters by key (all validated first; nothing changes when one is invalid)."""
        new = self._values.copy()
        mixes = {"expression": dict(self._expressions), "viseme": dict(self._visemes)}
        for spelling, value in values.items():
            k = P.parse(spelling)
            if k.kind == "fap":
                number, value = self.check_fap(int(k.id), value)
                new[number - 1] = value
            elif k.kind in mixes:
                mixes[k.kind][self._mix_and_id(k)[1]] = P.check_value(k, value)
            else:
                raise P.ParameterError(f"{k} is not a FAP, expression or viseme parameter")
        expressions = self._expressions if mixes["expression"] == dict(self._expressions) else _sorted_mix(
            mixes["expression"])
        visemes = self._visemes if mixes["viseme"] == dict(self._visemes) else _sorted_mix(mixes["viseme"])
        self._set_state(new, expressions, visemes)

    def offset(self, x: np.ndarray) -> np.ndarray:
        return self.deformer.displacement(self.limited_values())

    def add_offset(self, x: np.ndarray) -> None:
        """``x`` (n, 3) += :meth:`offset`, in place (the rig's working array)."""
        self.deformer.add_displacement(x, self.limited_values())

    def finish(self, x: np.ndarray, pinned: np.ndarray | None = None) -> np.ndarray:
        """``x`` after the FAPs' non-additive steps, edited in place (the rig passes its own working
        array; see ``core.rig.FaceRig.vertices``); the surface guard leaves ``pinned`` vertices alone."""
        return self.deformer.finish(x, self.limited_values(), in_place=True, pinned=pinned)

    def snapshot(self) -> tuple:
        return (tuple(self._values.tolist()), self._expressions, self._visemes)

    def restore(self, snapshot) -> None:
        values, expressions, visemes = snapshot
        self._set_state(np.asarray(values, dtype=float), tuple(expressions), tuple(visemes))

    def copy(self) -> "FapLayer":
        twin = FapLayer(self.deformer)
        twin.restore(self.snapshot())
        return twin

    # ------------------------------------------------------------ FAPs
    @property
    def animated_faps(self) -> tuple[int, ...]:
        return self.deformer.animated_faps

    def fap_values(self) -> np.ndarray:
        """(68,) the user's low-level FAP values (index n - 1), a copy."""
        return self._values.copy()

    def check_fap(self, number: int, value: float) -> tuple[int, float]:
        """(number, value) validated; ValueError with a message for the user otherwise."""
        spec = tables.fap_spec(number)
        if spec.number not in self.animated_faps:
            why = self.deformer.why_not_animated(spec.number)
            raise P.ParameterError(f"FAP {spec.number} ({spec.name}) cannot be animated on this face: {why}")
        key = f"fap:{spec.number}"
        return spec.number, P.check_value(key, value, self.describe(key))

    def describe(self, key) -> P.Parameter:
        """The registry's description of ``key``, with this face's own range: the upper-lid FAP of an
        eye closed at rest runs ``CLOSED_LID_OPENING`` further down than the table's -300 IRISD (which
        lifts a closed lid a tenth of the eye's width: a sleepy slit); closing it further does nothing
        (its lids already meet)."""
        p = P.describe(key)
        k = P.parse(key)
        if k.kind == "fap" and int(k.id) in UPPER_LIDS and int(k.id) in self.deformer.closed_lid_faps:
            low = p.outer[0]
            return dataclasses.replace(p, minimum=low, note=(
                f"this eye is closed at rest: -{CLOSED_LID_OPENING:g} opens it about as wide as an open "
                f"eye, down to {low:g} wider still (the table's {p.minimum:g} opens it to a slit)"))
        return p

    def reset_faps(self, numbers=None) -> None:
        new = self._values.copy()
        if numbers is None:
            new[:] = 0.0
        else:
            new[[tables.fap_spec(n).number - 1 for n in numbers]] = 0.0
        self._set_state(new, self._expressions, self._visemes)

    # ------------------------------------------------------------ presets
    @property
    def expressions(self) -> Mix:
        return self._expressions

    @property
    def visemes(self) -> Mix:
        return self._visemes

    def set_mixes(self, expressions: Mix | None = None, visemes: Mix | None = None) -> None:
        """Replace the expression and/or viseme mix exactly as given (order kept: FAP 2/1 blends)."""
        self._set_state(self._values, self._expressions if expressions is None else _neutral_if_empty(expressions),
                        self._visemes if visemes is None else _neutral_if_empty(visemes))

    def preset_values(self) -> np.ndarray:
        """(68,) FAP values contributed by the active expression and viseme presets."""
        out = np.zeros(N_FAPS)
        # Summed in id order, so the same weights give bit-identical values whatever the mix order
        # (a project stores weights by key, not a .fap blend's order).
        for eid, weight in sorted(self._expressions):
            out += tables.expression_table()[eid] * weight
        for vid, weight in sorted(self._visemes):
            out += tables.viseme_table()[vid] * weight
        return out

    def effective_values(self) -> np.ndarray:
        """(68,) user values + presets (what the user asked for)."""
        return self._values + self.preset_values()

    def limited_values(self) -> np.ndarray:
        """(68,) the effective values eased into the face's clean limits: what drives the
        deformation (equal to :meth:`effective_values` well inside the limits)."""
        if self._limited is None:   # offset and finish both ask, once per state
            self._limited = self.deformer.limited(self.effective_values(), self.preset_values())
            self._limited.setflags(write=False)   # shared by the product and finish (and memoised there)
        return self._limited

    # ------------------------------------------------------------ internals
    def _mix_and_id(self, k: P.ParamKey) -> tuple[Mix, int]:
        if k.kind == "expression":
            return self._expressions, tables.expression_id(k.id)
        if k.kind == "viseme":
            return self._visemes, tables.viseme_id(k.id)
        raise P.ParameterError(f"{k} is not a FAP, expression or viseme parameter")

    def _set_state(self, values: np.ndarray, expressions: Mix, visemes: Mix) -> None:
        if expressions == self._expressions and visemes == self._visemes:
            # Only FAP values (a slider tick, a timeline frame): the change names the FAPs that moved,
            # without listing every non-zero parameter twice.
            values = np.array(values, dtype=float)
            moved = np.flatnonzero(values != self._values)
            if not len(moved):
                return
            keys = [f"fap:{n + 1}" for n in moved.tolist()]
            change = ParameterChange(dict(zip(keys, values[moved].tolist())),
                                     dict(zip(keys, self._values[moved].tolist())), self.name)
            self._limited = None
            self._values = values
            self.parameters_changed.emit(change)
            return
        old = self._state_values()
        self._limited = None
        self._values = np.array(values, dtype=float)
        self._expressions, self._visemes = expressions, visemes
        new = self._state_values()
        # A reordered mix with the same weights changes nothing visible: no event.
        keys = sorted((k for k in old.keys() | new.keys() if old.get(k, 0.0) != new.get(k, 0.0)),
                      key=P.sort_key)
        if not keys:
            return
        self.parameters_changed.emit(ParameterChange({k: new.get(k, 0.0) for k in keys},
                                                     {k: old.get(k, 0.0) for k in keys}, self.name))

    def _state_values(self) -> dict:
        """{key: value} of every non-zero parameter."""
        out: dict = {f"fap:{n + 1}": float(self._values[n]) for n in np.flatnonzero(self._values)}
        names = tables.expression_names()
        for i, w in self._expressions:
            if i:
                out[f"expression:{names[i]}"] = out.get(f"expression:{names[i]}", 0.0) + w
        for i, w in self._visemes:
            if i:
                out[f"viseme:{i}"] = out.get(f"viseme:{i}", 0.0) + w
        return out


def _sorted_mix(weights: Mapping[int, float]) -> Mix:
    """{id: intensity} -> ((id, intensity), ...) strongest first, zeros dropped; neutral when empty."""
    items = sorted(((i, w) for i, w in weights.items() if i and w > 0), key=lambda e: -e[1])
    return tuple(items) or NEUTRAL


def _neutral_if_empty(mix: Mix) -> Mix:
    return tuple(mix) or NEUTRAL


def mix_from(mix: Mapping, to_id: Callable, what: str) -> Mix:
    """{name or id: intensity 0..1} -> a mix, strongest first, all validated before anything changes."""
    weights: dict[int, float] = {}
    for k, v in mix.items():
        weights[to_id(k)] = fraction(v, what)
    return _sorted_mix(weights)


def fraction(value, what: str) -> float:
    """``value`` as a float in [0, 1]; ParameterError naming ``what`` otherwise."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise P.ParameterError(f"{what} must be a number between 0 and 1, got {value!r}") from None
    if not (np.isfinite(value) and 0.0 <= value <= 1.0):
        raise P.ParameterError(f"{what} must be between 0 and 1 (0-100 %), got {value:g}")
    return value


__all__ = ["FapLayer", "mix_from", "fraction", "NEUTRAL"]
