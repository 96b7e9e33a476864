"""The face rig: the one model of a face's animation, composed of layers.

Composition order (``FaceRig.vertices``; each layer's offset adds to the result so far):

    x = rest
    for layer in layers:   x = x + layer.offset(x)       FAPs first (the Facial Animation Table),
                                                          then muscles, then later layers in the
                                                          order they were added
    for layer in layers:   x = layer.finish(x, pinned)   non-additive steps (in place), FAP layer only today:
                                                          lids stop on each other and slide over the
                                                          eyeballs, lips pressed into each other give
                                                          way, skin that would fold or smear is
                                                          smoothed (not the ``pinned`` vertices other
                                                          layers place exactly: dragged control
                                                          points), skin stays outside the teeth,
                                                          eyeballs (FAPs 23-26) and the head (48-50)
                                                          rotate

The FAP values that drive the FAT are the *effective* values: the user's low-level values plus
the active expression (FAP 2) and viseme (FAP 1) presets scaled by their intensities. Several
FAPs acting on one point add their displacements (linear superposition, as in the MPEG-4
players and thesis A's "combine FAT entries like keyframes"), except the eyelids (see
``core.layers.fap.fat.lid_contact``).

Every parameter of every layer is reachable by its canonical key (``core.parameters``):
``rig.value(key)``, ``rig.set_values({key: value})``, ``rig.parameters()``. The whole state is
captured by ``rig.snapshot()`` and put back by ``rig.restore(snap)`` — the only capture/restore,
used by undo, the timeline, project files and export. ``rig.copy()`` is an independent rig in the
same state (export evaluates its own copy).

Events (psygnal, no Qt): ``parameters_changed(change)`` after parameter values changed, with a
:class:`core.layer.ParameterChange` naming the keys, their new and previous values, so nobody
diffs; ``changed(change)`` after anything that moves the vertices (the same change, or an empty
one when a dynamic layer only settled). A layer with ``dynamic = True`` (the muscles) moves only
when it settles: setting its forces emits ``parameters_changed`` alone. ``vertices()`` is cached until the next change.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from typing import Callable, Iterable, Mapping

import numpy as np
from psygnal import Signal

from core import parameters as P
from core.cache import DiskCache
from core.face import Face
from core.layers.fap import tables
from core.layers.fap.fat import FapDeformer
from core.layers.fap.layer import FapLayer, fraction, mix_from
from core.layer import ParameterChange, RigLayer, layer_factory

N_FAPS = tables.N_FAPS

__all__ = ["FaceRig", "RigSnapshot", "ParameterChange", "N_FAPS"]


@dataclass(frozen=True)
class RigSnapshot:
    """The state of every layer of a rig: ((layer name, layer snapshot), ...) in layer order."""

    layers: tuple[tuple[str, object], ...]

    def of(self, name: str):
        return dict(self.layers).get(name)


def _described_by(layer, key) -> P.Parameter:
    """``key``'s description by ``layer`` when it has its own (``describe``: a face's range), else the
    registry's."""
    describe = getattr(layer, "describe", None)
    return describe(key) if describe is not None else P.describe(key)

class FaceRig:
    """Animation parameters of one face and the resulting vertex positions.

    Parameters
    ----------
    face : Face
        The neutral face, with at least the 64 MPEG-4 feature points of the base template.
    deformer : FapDeformer, optional
        A prebuilt FAP deformer for ``face`` (built here otherwise: seconds for 50k vertices).
    cache : core.cache.DiskCache, optional
        Where to find the deformer built on an earlier run, and to store it (no cache: always built).
    progress : callable(fraction, message), optional
        Hears how a deformer build goes (not called when it comes from the cache).
    """

    changed = Signal(object)             # ParameterChange (empty when only a dynamic layer moved)
    parameters_changed = Signal(object)  # ParameterChange with the keys whose values changed

    def __init__(self, face: Face, deformer: FapDeformer | None = None, *, cache: DiskCache | None = None,
                 progress: Callable[[float, str], None] | None = None):
        self.face = face
        self.deformer = deformer if deformer is not None else FapDeformer.for_face(face, cache, progress)
        self.specs = tables.fap_specs()
        self.fapu = self.deformer.fapu
        self.faps = FapLayer(self.deformer)
        self._layers: dict[str, RigLayer] = {}
        self._cache: np.ndarray | None = None
        self._batch: list[ParameterChange] | None = None
        self.add_layer(self.faps)

    # ------------------------------------------------------------ layers
    @property
    def layers(self) -> tuple[RigLayer, ...]:
        return tuple(self._layers.values())

    def layer(self, name: str) -> RigLayer | None:
        return self._layers.get(name)

    def add_layer(self, layer: RigLayer) -> RigLayer:
        """Append ``layer`` (replacing one of the same name, in its place) and listen to it."""
        joined = getattr(layer, "joined", None)
        if joined is not None:   # a layer that reads other layers (correctives follow this rig's FAPs)
            joined(self)
        old = self._layers.get(layer.name)
        if old is not None:
            self._disconnect(old)
        self._layers[layer.name] = layer
        layer.parameters_changed.connect(self._on_layer_parameters)
        layer.pose_changed.connect(self._on_layer_pose)
        self._touch(ParameterChange(layer=layer.name))
        return layer

    def remove_layer(self, name: str) -> None:
        layer = self._layers.pop(name, None) if name != self.faps.name else None
        if layer is not None:
            self._disconnect(layer)
            self._touch(ParameterChange(layer=name))

    def ensure_layers(self, keys: Iterable, *, slow: bool = True) -> list[str]:
        """Add the registered layers (``core.layer.register_layer``) that own ``keys`` but are missing;
        returns the names of the layers added (e.g. the muscle layer for a ``muscle:`` track).
        ``slow=False`` skips layers whose build takes seconds (a GUI builds those in the background)."""
        added = []
        for kind in dict.fromkeys(P.parse(k).kind for k in keys):
            entry = layer_factory(kind)
            if entry is not None and entry[0] not in self._layers and (slow or not entry[2]):
                layer = entry[1](self)
                if self._layers.get(entry[0]) is not layer:
                    self.add_layer(layer)
                added.append(entry[0])
        return added

    def _disconnect(self, layer: RigLayer) -> None:
        with contextlib.suppress(Exception):
            layer.parameters_changed.disconnect(self._on_layer_parameters)
        with contextlib.suppress(Exception):
            layer.pose_changed.disconnect(self._on_layer_pose)

    # ------------------------------------------------------------ the parameter registry
    def parameters(self) -> tuple[str, ...]:
        """Canonical keys of every parameter this rig can animate, layer by layer."""
        return tuple(self._owners())

    def _owners(self) -> dict[str, str]:
        """{key: layer name}, asked of the layers each time (what a layer animates may change)."""
        return {k: name for name, layer in self._layers.items() for k in layer.parameters()}

    def describe(self, key) -> P.Parameter:
        """``key``'s description on this face: its layer's when the layer has its own (a range that
        depends on the face), else the registry's."""
        name = self._owners().get(P.key_of(key))
        return _described_by(self._layers.get(name) if name is not None else None, key)

    def owner(self, key) -> RigLayer:
        """The layer that animates ``key``; ParameterError saying why when none does."""
        k = P.key_of(key)
        name = self._owners().get(k)
        if name is None:
            entry = layer_factory(P.parse(k).kind)
            if entry is not None and entry[0] not in self._layers:
                raise P.ParameterError(f"{k} needs the {entry[0]} layer, which this face does not have yet")
            if P.parse(k).kind == "fap":
                self.faps.check_fap(int(P.parse(k).id), 0.0)   # raises the reason this FAP is not animated
            raise P.ParameterError(f"{k} is not animated on this face")
        return self._layers[name]

    def value(self, key) -> float:
        return self.owner(key).value(P.key_of(key))

    def values(self, keys: Iterable | None = None, *, nondefault: bool = False) -> dict[str, float]:
        """{key: value} for ``keys`` (all parameters when None); only those away from their default
        when ``nondefault``."""
        out = {}
        for k in (self.parameters() if keys is None else [P.key_of(k) for k in keys]):
            v = self.value(k)
            if not nondefault or v != P.describe(k).default:
                out[k] = v
        return out

    def set_values(self, values: Mapping) -> None:
        """Set parameters of any layers by key; everything is validated before anything changes.
        One ``changed`` at most."""
        groups: dict[str, dict[str, float]] = {}
        owners = self._owners()
        for spelling, value in values.items():
            k = P.key_of(spelling)
            name = owners.get(k) or self.owner(k).name   # owner() raises the reason
            groups.setdefault(name, {})[k] = P.check_value(k, value, _described_by(self._layers[name], k))
        if "faps" in groups:   # FAPs have a face-specific check beyond the range (animated here?)
            for k, v in groups["faps"].items():
                if k.startswith("fap:"):
                    self.faps.check_fap(int(k[4:]), v)
        with self.batch():
            for name, group in groups.items():
                self._layers[name].set_values(group)

    def reset(self, keys: Iterable | None = None) -> None:
        """Put parameters (all when None) back to their defaults."""
        keys = self.parameters() if keys is None else [P.key_of(k) for k in keys]
        self.set_values({k: P.describe(k).default for k in keys})

    # ------------------------------------------------------------ snapshots
    def snapshot(self) -> RigSnapshot:
        return RigSnapshot(tuple((name, layer.snapshot()) for name, layer in self._layers.items()))

    def restore(self, snapshot: RigSnapshot) -> None:
        """Put a :meth:`snapshot` back (layers it does not know keep their state). One ``changed``."""
        with self.batch():
            for name, snap in snapshot.layers:
                layer = self._layers.get(name)
                if layer is not None:
                    layer.restore(snap)

    def copy(self) -> "FaceRig":
        """An independent rig in the same state (shares the immutable deformer and layer models)."""
        twin = FaceRig(self.face, self.deformer)
        twin.faps.restore(self.faps.snapshot())
        for name, layer in self._layers.items():
            if name != self.faps.name:
                twin.add_layer(layer.copy())
        return twin

    @contextlib.contextmanager
    def batch(self):
        """Merge every change inside the block into one event (emitted at its end)."""
        if self._batch is not None:
            yield
            return
        self._batch = []
        try:
            yield
        finally:
            changes, self._batch = self._batch, None
            if changes:
                self._emit(_merged([c for c, _ in changes]), any(moves for _, moves in changes))

    # ------------------------------------------------------------ FAPs (the FAP layer's API)
    @property
    def animated_faps(self) -> tuple[int, ...]:
        """FAP numbers this face can animate (the 46 of thesis A, plus gaze and head when possible)."""
        return self.deformer.animated_faps

    def fap_value(self, number: int) -> float:
        return float(self.faps.fap_values()[tables.fap_spec(number).number - 1])

    def fap_values(self) -> np.ndarray:
        """(68,) the user's low-level FAP values (index n - 1), a copy."""
        return self.faps.fap_values()

    def check_fap(self, number: int, value: float) -> tuple[int, float]:
        """(number, value) validated; ValueError with a message for the user otherwise."""
        return self.faps.check_fap(number, value)

    def set_fap(self, number: int, value: float) -> None:
        self.set_faps({number: value})

    def set_faps(self, values: Mapping[int, float]) -> None:
        """Set several FAPs at once (all validated first; nothing changes if one is invalid)."""
        checked = dict(self.check_fap(n, v) for n, v in values.items())
        self.faps.set_values({f"fap:{n}": v for n, v in checked.items()})

    def reset_faps(self, numbers: Iterable[int] | None = None) -> None:
        """Zero the given FAPs (all when None)."""
        self.faps.reset_faps(numbers)

    # ------------------------------------------------------------ presets (FAP 2, FAP 1)
    @property
    def expression(self) -> tuple[int, float]:
        """(expression id 0..6, intensity 0..1) of the main FAP 2 preset."""
        return self.faps.expressions[0]

    @property
    def expressions(self) -> tuple[tuple[int, float], ...]:
        """All active expression presets (FAP 2 can blend two), as (id, intensity)."""
        return self.faps.expressions

    def set_expression(self, expression: str | int | None, intensity: float = 1.0) -> None:
        """Activate one expression preset (thesis A Table B.1) at ``intensity`` in [0, 1]; None = neutral."""
        eid = 0 if expression is None else tables.expression_id(expression)
        self.faps.set_mixes(expressions=((eid, fraction(intensity, "expression intensity")),) if eid else ())

    def set_fap2(self, select1: int, intensity1: int, select2: int = 0, intensity2: int = 0) -> None:
        """MPEG-4 FAP 2 as in a .fap file: expression1·i1/63 + expression2·i2/63 (intensities 0..63)."""
        mix = []
        for sel, inten in ((select1, intensity1), (select2, intensity2)):
            if not 0 <= inten <= 63:
                raise ValueError(f"FAP 2 expression intensity must be 0..63, got {inten}")
            mix.append((tables.expression_id(int(sel)), inten / 63.0))
        self.faps.set_mixes(expressions=tuple(mix))

    @property
    def viseme(self) -> tuple[int, float]:
        """(viseme id 0..14, intensity 0..1) of the main FAP 1 preset."""
        return self.faps.visemes[0]

    @property
    def visemes(self) -> tuple[tuple[int, float], ...]:
        return self.faps.visemes

    def set_viseme(self, viseme: str | int | None, intensity: float = 1.0) -> None:
        """Activate one viseme preset (resources/mpeg4/viseme_presets.csv) at ``intensity`` in [0, 1]."""
        vid = 0 if viseme is None else tables.viseme_id(viseme)
        self.faps.set_mixes(visemes=((vid, fraction(intensity, "viseme intensity")),) if vid else ())

    def set_fap1(self, select1: int, select2: int, blend: int) -> None:
        """MPEG-4 FAP 1 as in a .fap file: viseme1·b/63 + viseme2·(1 - b/63), blend 0..63."""
        if not 0 <= blend <= 63:
            raise ValueError(f"FAP 1 viseme_blend must be 0..63, got {blend}")
        mix = ((tables.viseme_id(int(select1)), blend / 63.0), (tables.viseme_id(int(select2)), 1 - blend / 63.0))
        self.faps.set_mixes(visemes=mix)

    def set_expression_mix(self, mix: Mapping[str | int, float]) -> None:
        """Several expression presets at once, {name or id: intensity 0..1} (they add linearly)."""
        self.faps.set_mixes(expressions=mix_from(mix, tables.expression_id, "expression intensity"))

    def set_viseme_mix(self, mix: Mapping[str | int, float]) -> None:
        """Several viseme presets at once, {name or id: intensity 0..1} (e.g. coarticulated lip-sync)."""
        self.faps.set_mixes(visemes=mix_from(mix, tables.viseme_id, "viseme intensity"))

    def preset_values(self) -> np.ndarray:
        """(68,) FAP values contributed by the active expression and viseme presets."""
        return self.faps.preset_values()

    def effective_fap_values(self) -> np.ndarray:
        """(68,) user values + presets: what drives the deformation."""
        return self.faps.effective_values()

    # ------------------------------------------------------------ results
    def touch(self) -> None:
        """Tell the rig that its vertices must be recomputed (a layer moved without an event)."""
        self._touch(ParameterChange())

    def vertices(self) -> np.ndarray:
        """(n, 3) mm: the current face (read-only array, cached until the next change)."""
        if self._cache is None:
            # One working array for the whole tick: offsets add into it and the layers' finish steps
            # edit it in place (a full copy of a 50k-vertex face costs ~0.15 ms, a third of the goal).
            x = np.array(self.face.vertices, dtype=float)
            layers = self.layers
            for layer in layers:
                add_offset: Callable | None = getattr(layer, "add_offset", None)
                if add_offset is not None:
                    add_offset(x)
                    continue
                offset = layer.offset(x)
                if offset is not None:
                    x += offset
            pins = [layer.pinned_vertices() for layer in layers if hasattr(layer, "pinned_vertices")]
            pinned = np.concatenate([np.zeros(0, np.int64)] + [np.asarray(p, np.int64) for p in pins])
            for layer in layers:
                finish: Callable | None = getattr(layer, "finish", None)
                if finish is not None:
                    x = finish(x, pinned)
            x = np.asarray(x, dtype=float)
            x.setflags(write=False)
            self._cache = x
        return self._cache

    def displacement_magnitude(self) -> np.ndarray:
        """(n,) mm: distance of every vertex from its neutral position (thesis A Fig. 5.6 heat map)."""
        return np.linalg.norm(self.vertices() - self.face.vertices, axis=1)

    def fap_influence(self, number: int) -> np.ndarray:
        """(n,) in [0, 1]: how strongly FAP ``number`` moves each vertex (its influence region)."""
        return self.deformer.influence(tables.fap_spec(number).number)

    # ------------------------------------------------------------ events
    def _on_layer_parameters(self, change: ParameterChange) -> None:
        # A dynamic layer (muscles) moves only when it settles (pose_changed): a new force alone
        # changes a parameter, not the vertices.
        moves = not getattr(self._layers.get(change.layer), "dynamic", False)
        self._touch(change, moves=moves)

    def _on_layer_pose(self) -> None:
        self._touch(ParameterChange())

    def _touch(self, change: ParameterChange, *, moves: bool = True) -> None:
        if moves:
            self._cache = None
        if self._batch is not None:
            self._batch.append((change, moves))
        else:
            self._emit(change, moves)

    def _emit(self, change: ParameterChange, moves: bool) -> None:
        if change.values:
            self.parameters_changed.emit(change)
        if moves:
            self.changed.emit(change)


def _merged(changes: list[ParameterChange]) -> ParameterChange:
    """One change for a batch: last new value and first previous value per key; keys that came
    back to where they started are dropped."""
    values: dict[str, float] = {}
    previous: dict[str, float] = {}
    for c in changes:
        for k, v in c.values.items():
            previous.setdefault(k, c.previous.get(k, v))
            values[k] = v
    keys = [k for k in values if values[k] != previous[k]]
    layers = dict.fromkeys(c.layer for c in changes if c.layer)
    return ParameterChange({k: values[k] for k in keys}, {k: previous[k] for k in keys}, "+".join(layers))
