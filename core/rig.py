"""The face rig: one object that owns the animation parameters and gives the current vertices.

Composition order (each layer adds to the previous one's output):

    x = rest
        + F · (fap_values ∘ fapu)         FAP layer: one sparse product (the Facial Animation Table)
        + later layers' offsets           e.g. muscles (issue 4), blends; added via ``add_layer``
    then rigid motions: eyeballs rotate about their centres (gaze FAPs 23-26) and the whole
    head about the top of the spine (FAPs 48-50).

The FAP values that drive the FAT are the *effective* values: the user's low-level values plus
the active expression (FAP 2) and viseme (FAP 1) presets scaled by their intensities. Several
FAPs acting on one point add their displacements (linear superposition, as in the MPEG-4
players and thesis A's "combine FAT entries like keyframes"), except the eyelids: an upper and a
lower lid that together close more than the opening stop where they meet (see
``core.fap.fat.lid_contact``).

The rig emits ``changed`` (psygnal, no Qt) after every parameter change; ``vertices()`` is
cached until the next change.
"""

from __future__ import annotations

from typing import Callable, Iterable, Mapping

import numpy as np
from psygnal import Signal

from .face import Face
from .fap import tables
from .fap.fat import FapDeformer

N_FAPS = tables.N_FAPS


class FaceRig:
    """Animation parameters of one face and the resulting vertex positions.

    Parameters
    ----------
    face : Face
        The neutral face, with at least the 64 MPEG-4 feature points of the base template.
    deformer : FapDeformer, optional
        A prebuilt FAP deformer for ``face`` (built here otherwise; about a second for 50k vertices).
    """

    changed = Signal()

    def __init__(self, face: Face, deformer: FapDeformer | None = None):
        self.face = face
        self.deformer = deformer if deformer is not None else FapDeformer(face)
        self.specs = tables.fap_specs()
        self.fapu = self.deformer.fapu
        self._values = np.zeros(N_FAPS)
        self._expressions: tuple[tuple[int, float], ...] = ((0, 0.0),)
        self._visemes: tuple[tuple[int, float], ...] = ((0, 0.0),)
        self._layers: dict[str, Callable[[np.ndarray], np.ndarray]] = {}
        self._cache: np.ndarray | None = None

    # ------------------------------------------------------------ FAPs
    @property
    def animated_faps(self) -> tuple[int, ...]:
        """FAP numbers this face can animate (the 46 of thesis A, plus gaze and head when possible)."""
        return self.deformer.animated_faps

    def fap_value(self, number: int) -> float:
        return float(self._values[tables.fap_spec(number).number - 1])

    def fap_values(self) -> np.ndarray:
        """(68,) the user's low-level FAP values (index n - 1), a copy."""
        return self._values.copy()

    def check_fap(self, number: int, value: float) -> tuple[int, float]:
        """(number, value) validated; ValueError with a message for the user otherwise."""
        spec = tables.fap_spec(number)
        if spec.number not in self.animated_faps:
            why = self.deformer.why_not_animated(spec.number)
            raise ValueError(f"FAP {spec.number} ({spec.name}) cannot be animated on this face: {why}")
        value = float(value)
        if not np.isfinite(value):
            raise ValueError(f"{spec.name}: value must be a finite number, got {value}")
        if not spec.minimum <= value <= spec.maximum:
            raise ValueError(
                f"{spec.name} = {value:g} is outside its range {spec.minimum:g} to {spec.maximum:g} {spec.unit}"
            )
        return spec.number, value

    def set_fap(self, number: int, value: float) -> None:
        self.set_faps({number: value})

    def set_faps(self, values: Mapping[int, float]) -> None:
        """Set several FAPs at once (all validated first; nothing changes if one is invalid)."""
        checked = [self.check_fap(n, v) for n, v in values.items()]
        changed = False
        for n, v in checked:
            if self._values[n - 1] != v:
                self._values[n - 1] = v
                changed = True
        if changed:
            self._touch()

    def reset_faps(self, numbers: Iterable[int] | None = None) -> None:
        """Zero the given FAPs (all when None)."""
        if numbers is None:
            if not self._values.any():
                return
            self._values[:] = 0.0
        else:
            idx = [tables.fap_spec(n).number - 1 for n in numbers]
            if not self._values[idx].any():
                return
            self._values[idx] = 0.0
        self._touch()

    # ------------------------------------------------------------ presets (FAP 2, FAP 1)
    @property
    def expression(self) -> tuple[int, float]:
        """(expression id 0..6, intensity 0..1) of the main FAP 2 preset."""
        return self._expressions[0]

    @property
    def expressions(self) -> tuple[tuple[int, float], ...]:
        """All active expression presets (FAP 2 can blend two), as (id, intensity)."""
        return self._expressions

    def set_expression(self, expression: str | int | None, intensity: float = 1.0) -> None:
        """Activate one expression preset (thesis A Table B.1) at ``intensity`` in [0, 1]; None = neutral."""
        eid = 0 if expression is None else tables.expression_id(expression)
        self._set_presets("_expressions", ((eid, _fraction(intensity, "expression intensity")),))

    def set_fap2(self, select1: int, intensity1: int, select2: int = 0, intensity2: int = 0) -> None:
        """MPEG-4 FAP 2 as in a .fap file: expression1·i1/63 + expression2·i2/63 (intensities 0..63)."""
        mix = []
        for sel, inten in ((select1, intensity1), (select2, intensity2)):
            if not 0 <= inten <= 63:
                raise ValueError(f"FAP 2 expression intensity must be 0..63, got {inten}")
            mix.append((tables.expression_id(int(sel)), inten / 63.0))
        self._set_presets("_expressions", tuple(mix))

    @property
    def viseme(self) -> tuple[int, float]:
        """(viseme id 0..14, intensity 0..1) of the main FAP 1 preset."""
        return self._visemes[0]

    @property
    def visemes(self) -> tuple[tuple[int, float], ...]:
        return self._visemes

    def set_viseme(self, viseme: str | int | None, intensity: float = 1.0) -> None:
        """Activate one viseme preset (resources/mpeg4/viseme_presets.csv) at ``intensity`` in [0, 1]."""
        vid = 0 if viseme is None else tables.viseme_id(viseme)
        self._set_presets("_visemes", ((vid, _fraction(intensity, "viseme intensity")),))

    def set_fap1(self, select1: int, select2: int, blend: int) -> None:
        """MPEG-4 FAP 1 as in a .fap file: viseme1·b/63 + viseme2·(1 - b/63), blend 0..63."""
        if not 0 <= blend <= 63:
            raise ValueError(f"FAP 1 viseme_blend must be 0..63, got {blend}")
        mix = ((tables.viseme_id(int(select1)), blend / 63.0), (tables.viseme_id(int(select2)), 1 - blend / 63.0))
        self._set_presets("_visemes", mix)

    def set_expression_mix(self, mix: Mapping[str | int, float]) -> None:
        """Several expression presets at once, {name or id: intensity 0..1} (they add linearly)."""
        self._set_presets("_expressions", _mix(mix, tables.expression_id, "expression intensity"))

    def set_viseme_mix(self, mix: Mapping[str | int, float]) -> None:
        """Several viseme presets at once, {name or id: intensity 0..1} (e.g. coarticulated lip-sync)."""
        self._set_presets("_visemes", _mix(mix, tables.viseme_id, "viseme intensity"))

    def _set_presets(self, attribute: str, mix: tuple[tuple[int, float], ...]) -> None:
        if getattr(self, attribute) != mix:
            setattr(self, attribute, mix)
            self._touch()

    def preset_values(self) -> np.ndarray:
        """(68,) FAP values contributed by the active expression and viseme presets."""
        out = np.zeros(N_FAPS)
        for eid, weight in self._expressions:
            out += tables.expression_table()[eid] * weight
        for vid, weight in self._visemes:
            out += tables.viseme_table()[vid] * weight
        return out

    def effective_fap_values(self) -> np.ndarray:
        """(68,) user values + presets: what drives the deformation."""
        return self._values + self.preset_values()

    # ------------------------------------------------------------ layers
    def add_layer(self, name: str, offset: Callable[[np.ndarray], np.ndarray]) -> None:
        """Add a layer: ``offset(x)`` gets the FAP-deformed (n, 3) vertices and returns (n, 3) mm to add.

        The layer calls ``rig.touch()`` when its own parameters change.
        """
        self._layers[name] = offset
        self._touch()

    def remove_layer(self, name: str) -> None:
        if self._layers.pop(name, None) is not None:
            self._touch()

    def touch(self) -> None:
        """Tell the rig that a layer's parameters changed."""
        self._touch()

    # ------------------------------------------------------------ results
    def vertices(self) -> np.ndarray:
        """(n, 3) mm: the current face (read-only array, cached until the next change)."""
        if self._cache is None:
            x = self.deformer.deform(self.effective_fap_values(), layers=tuple(self._layers.values()))
            x.setflags(write=False)
            self._cache = x
        return self._cache

    def displacement_magnitude(self) -> np.ndarray:
        """(n,) mm: distance of every vertex from its neutral position (thesis A Fig. 5.6 heat map)."""
        return np.linalg.norm(self.vertices() - self.face.vertices, axis=1)

    def fap_influence(self, number: int) -> np.ndarray:
        """(n,) in [0, 1]: how strongly FAP ``number`` moves each vertex (its influence region)."""
        return self.deformer.influence(tables.fap_spec(number).number)

    def _touch(self) -> None:
        self._cache = None
        self.changed.emit()


def _mix(mix: Mapping, to_id: Callable, what: str) -> tuple[tuple[int, float], ...]:
    """{name or id: intensity} -> ((id, intensity), ...), strongest first (so ``expression``/``viseme``
    name the main preset); all validated before anything changes; neutral when empty."""
    items = sorted(((to_id(k), _fraction(v, what)) for k, v in mix.items()), key=lambda e: -e[1])
    return tuple(e for e in items if e[0] and e[1] > 0) or ((0, 0.0),)


def _fraction(value: float, what: str) -> float:
    value = float(value)
    if not (np.isfinite(value) and 0.0 <= value <= 1.0):
        raise ValueError(f"{what} must be between 0 and 1 (0-100 %), got {value:g}")
    return value
