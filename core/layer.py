"""The rig-layer protocol and what layers share.

A rig layer (``core.rig.FaceRig`` composes them) is one animation method: the FAP table, the
SABiom muscles, and the ones to come (blend shapes, RBF control points, vector muscles). It has

- ``name``: unique in a rig (``"faps"``, ``"muscles"``, ...);
- ``parameters() -> tuple[str, ...]``: the canonical keys (``core.parameters``) it owns on this
  face; ``value(key)`` and ``set_values({key: value})`` (all validated first, no clamping);
- ``offset(x) -> (n, 3)`` mm added to the vertices ``x`` of the layers before it (None: nothing);
- ``snapshot()`` / ``restore(snap)``: an opaque, immutable copy of its whole state;
- ``copy()``: an independent layer in the same state (export evaluates its own rig);
- signals ``parameters_changed(ParameterChange)`` after its values changed and ``pose_changed()``
  when its offset changed without a parameter change (a dynamic layer settling); a layer whose
  offset follows its parameters only through a simulation sets ``dynamic = True``;
- optionally ``finish(x, pinned) -> x``: a non-additive step applied after every layer's offset;
  ``pinned`` ((k,) int) are the vertices the layers place exactly, which it must leave where they are;
- optionally ``pinned_vertices() -> (k,) int``: the vertices this layer places exactly (a dragged
  control point): no other layer's finish step moves them;
- optionally ``add_offset(x)``: adds its offset into ``x`` in place (what ``offset`` gives, without
  an (n, 3) temporary; the rig prefers it).

:class:`ValueLayer` implements everything for layers whose state is just their values: a new
layer subclasses it, lists its keys and writes ``offset``. :func:`register_layer` makes a layer
available to rigs that meet one of its parameters (a project file, a timeline track).
"""

from __future__ import annotations

import abc
import copy as _copy
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping, Protocol, runtime_checkable

import numpy as np
from psygnal import Signal

from core import parameters as P

__all__ = ["ParameterChange", "RigLayer", "ValueLayer", "register_layer", "layer_factory", "fresh_signals"]


@dataclass(frozen=True)
class ParameterChange:
    """What one change did: ``values`` {key: new value} and ``previous`` {key: old value}, for the
    keys whose value really changed (both empty when only the pose moved); ``layer``: its name."""

    values: Mapping[str, float] = field(default_factory=dict)
    previous: Mapping[str, float] = field(default_factory=dict)
    layer: str = ""

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(self.values)


@runtime_checkable
class RigLayer(Protocol):
    name: str

    def parameters(self) -> tuple[str, ...]: ...

    def value(self, key: str) -> float: ...

    def set_values(self, values: Mapping[str, float]) -> None: ...

    def offset(self, x: np.ndarray) -> np.ndarray | None: ...

    def snapshot(self) -> Any: ...

    def restore(self, snapshot: Any) -> None: ...

    def copy(self) -> "RigLayer": ...


def fresh_signals(obj) -> None:
    """Drop psygnal signal instances cached on ``obj`` (after ``copy.copy``, so the copy does not
    share its original's listeners)."""
    for name in [n for n, v in vars(obj).items() if type(v).__name__ == "SignalInstance"]:
        del obj.__dict__[name]


class ValueLayer(abc.ABC):
    """A layer whose whole state is its parameter values (snapshot = the values).

    Subclasses set ``name``, pass their keys to ``__init__`` and implement ``offset``.
    """

    name = "layer"
    parameters_changed = Signal(object)
    pose_changed = Signal()

    def __init__(self, keys: Iterable[str]):
        self._values = {P.key_of(k): P.describe(k).default for k in keys}

    def parameters(self) -> tuple[str, ...]:
        return tuple(self._values)

    def value(self, key: str) -> float:
        return self._values[self._own(key)]

    def set_values(self, values: Mapping[str, float]) -> None:
        checked = {self._own(k): P.check_value(k, v) for k, v in values.items()}
        previous = {k: self._values[k] for k, v in checked.items() if self._values[k] != v}
        if not previous:
            return
        self._values.update({k: checked[k] for k in previous})
        self.parameters_changed.emit(ParameterChange({k: checked[k] for k in previous}, previous, self.name))

    @abc.abstractmethod
    def offset(self, x: np.ndarray) -> np.ndarray | None:
        """(n, 3) mm to add to ``x`` (the vertices of the layers before this one)."""

    def snapshot(self) -> tuple[tuple[str, float], ...]:
        return tuple(self._values.items())

    def restore(self, snapshot) -> None:
        self.set_values(dict(snapshot))

    def copy(self) -> "ValueLayer":
        twin = _copy.copy(self)
        fresh_signals(twin)
        twin._values = dict(self._values)
        return twin

    def _own(self, key) -> str:
        k = P.key_of(key)
        if k not in self._values:
            raise P.ParameterError(f"{k} is not a parameter of the {self.name} layer")
        return k


# ---------------------------------------------------------------- layers a rig can add on demand
_FACTORIES: dict[str, tuple[str, Callable, bool]] = {}  # kind -> (layer name, factory(rig) -> layer, slow)


def register_layer(name: str, kinds: Iterable[str], factory: Callable, *, slow: bool = False) -> None:
    """Let rigs build layer ``name`` when they meet a parameter of one of ``kinds``
    (``factory(rig) -> layer``; e.g. when a project or a timeline track uses it). ``slow``: the
    build takes seconds (the muscle model), so a GUI builds it in the background itself."""
    for kind in kinds:
        _FACTORIES[kind] = (name, factory, bool(slow))


def layer_factory(kind: str) -> tuple[str, Callable, bool] | None:
    """(layer name, factory, slow) registered for a parameter kind, or None."""
    if kind not in _FACTORIES:
        P.kinds()   # the built-in kinds' modules register their layers on import
    return _FACTORIES.get(kind)
