"""``ControlPointLayer``: thesis B's RBF control points as a rig layer.

Parameters ``cp:<feature point>:<x|y|z>``: each control point's displacement from its rest position, mm.
The layer's offset is U = (R ∘ Ω) D: D (c, 3) the displacements, R (k, c) the RBF response of the active
vertices (``RbfSystem.response``: every control point interpolated, the others held at 0) and Ω (k, c) the
influence regions (``regions.influence``). R ∘ Ω is built once per kernel (cached per Kernel), so a drag
is one small product: (k, c) @ (c, 3), or only the moved points' columns (``Pose``). Kernel and control-point placement are layer settings, not animatable; they
are part of the snapshot (undo).
"""

from __future__ import annotations

import numpy as np

from core import parameters as P
from core.face import Face
from core.layer import ValueLayer
from core.layers.rbf import parameters as _kinds  # noqa: F401 - registers the cp kind
from core.layers.rbf.kernels import Kernel, RbfSystem
from core.layers.rbf.regions import ControlPoints, influence

__all__ = ["ControlPointDeformer", "ControlPointLayer", "Pose", "AXES"]

AXES = ("x", "y", "z")


class ControlPointDeformer:
    """RBF deformation of one face by one set of control points (immutable but for its kernel cache).

    points : ControlPoints on ``face``; reach_mm, blend_mm : see ``regions.influence``;
    regions=False: no influence regions (every vertex is moved by every point, a plain RBF).
    """

    CACHE = 6

    def __init__(self, face: Face, points: ControlPoints | None = None, *, reach_mm: float = 35.0,
                 blend_mm: float = 20.0, regions: bool = True):
        self.face = face
        self.points = points if points is not None else ControlPoints.on_face(face)
        if regions:
            self.active, self.omega = influence(face, self.points, reach_mm=reach_mm, blend_mm=blend_mm)
        else:
            self.active, self.omega = np.arange(face.n_vertices), None
        self.centres = face.vertices[self.points.vertices]
        self._rest = face.vertices[self.active]
        self._matrices: dict[Kernel, np.ndarray] = {}

    def matrix(self, kernel: Kernel) -> np.ndarray:
        """(k, c) R ∘ Ω for ``kernel`` (factorised and cached on first use; ParameterError if singular)."""
        m = self._matrices.pop(kernel, None)
        if m is None:
            m = RbfSystem(self.centres, kernel).response(self._rest)
            if self.omega is not None:
                m *= self.omega
            m = np.asfortranarray(m)   # column j (one control point) contiguous for incremental drags
            m.setflags(write=False)
        self._matrices[kernel] = m   # most recent last
        while len(self._matrices) > self.CACHE:
            self._matrices.pop(next(iter(self._matrices)))
        return m

    def displacement(self, displacements: np.ndarray, kernel: Kernel) -> np.ndarray:
        """(n, 3) mm for control-point displacements (c, 3) mm."""
        out = np.zeros((self.face.n_vertices, 3))
        out[self.active] = self.matrix(kernel) @ np.asarray(displacements, dtype=float).reshape(-1, 3)
        return out


class Pose:
    """The active vertices' displacement (k, 3) for the latest control-point displacements, updated by the
    columns of the points that changed (a drag moves one point: one (k, 1) @ (1, 3) product) and recomputed
    in full when many changed or every ``REFRESH`` updates (no drift)."""

    REFRESH = 64

    def __init__(self, deformer: ControlPointDeformer, kernel: Kernel):
        self.deformer, self.matrix = deformer, deformer.matrix(kernel)
        self._d: np.ndarray | None = None
        self._u: np.ndarray | None = None
        self._updates = 0

    def __call__(self, displacements: np.ndarray) -> np.ndarray:
        """(n, 3) mm for control-point displacements (c, 3) mm."""
        d = np.array(displacements, dtype=float).reshape(-1, 3)
        m = self.matrix
        if self._u is not None and self._updates < self.REFRESH:
            delta = d - self._d
            rows = np.nonzero(delta.any(axis=1))[0]
            if len(rows) <= max(1, m.shape[1] // 8):
                if len(rows):
                    self._u += m[:, rows] @ delta[rows]
                    self._updates += 1
                self._d = d
                return self._scatter()
        self._u, self._d, self._updates = m @ d, d, 0
        return self._scatter()

    def _scatter(self) -> np.ndarray:
        out = np.zeros((self.deformer.face.n_vertices, 3))
        out[self.deformer.active] = self._u
        return out


class ControlPointLayer(ValueLayer):
    """Thesis B's RBF control points (see the module docstring). ``deformer`` may be shared between layers."""

    name = "control_points"

    def __init__(self, face: Face, kernel: Kernel | None = None, *, deformer: ControlPointDeformer | None = None):
        self.face = face
        self.deformer = deformer if deformer is not None else ControlPointDeformer(face)
        self._kernel = kernel if kernel is not None else Kernel()
        self._pose = Pose(self.deformer, self._kernel)   # factorise now: a singular setting fails here
        fps = self.deformer.points.feature_points
        self._keys = tuple(f"cp:{fp}:{a}" for fp in fps for a in AXES)
        super().__init__(self._keys)
        self._d: np.ndarray | None = None

    # ------------------------------------------------------------ values
    @property
    def points(self) -> ControlPoints:
        return self.deformer.points

    def set_values(self, values) -> None:
        self._d = None
        super().set_values(values)

    def displacements(self) -> np.ndarray:
        """(c, 3) mm, the control points' displacements in point order (read-only)."""
        if self._d is None:
            d = np.array([self._values[k] for k in self._keys]).reshape(-1, 3)
            d.setflags(write=False)
            self._d = d
        return self._d

    def set_displacements(self, displacements) -> None:
        """Set points by name or feature point: {name: (dx, dy, dz) mm}, or a (c, 3) array in point order."""
        if isinstance(displacements, dict):
            index = {n: i for i, n in enumerate(self.points.names)}
            index.update({fp: i for i, fp in enumerate(self.points.feature_points)})
            values = {}
            for name, d in displacements.items():
                if name not in index:
                    raise P.ParameterError(f"{name!r} is not a control point of this layer "
                                           f"({', '.join(self.points.names)})")
                d = np.asarray(d, dtype=float).reshape(3)
                values.update({self._keys[3 * index[name] + a]: float(d[a]) for a in range(3)})
        else:
            d = np.asarray(displacements, dtype=float)
            if d.shape != (len(self.points), 3):
                raise P.ParameterError(f"displacements must have shape ({len(self.points)}, 3), got {d.shape}")
            values = dict(zip(self._keys, d.ravel().tolist()))
        self.set_values(values)

    def offset(self, x: np.ndarray) -> np.ndarray | None:
        d = self.displacements()
        if not d.any():
            return None
        return self._pose(d)

    def pinned_vertices(self) -> np.ndarray:
        """(k,) the vertices of the control points the user moved: they go exactly where they were
        dragged (the FAP layer's surface guard would smooth a steep drag 1.7 mm short of the pointer)."""
        return np.asarray(self.points.vertices, np.int64)[self.displacements().any(axis=1)]

    # ------------------------------------------------------------ settings
    @property
    def kernel(self) -> Kernel:
        return self._kernel

    def set_kernel(self, kernel: Kernel) -> None:
        """Switch kernel or its parameters (factorised once, then cached); ParameterError, and nothing
        changes, when the new system is singular."""
        if kernel == self._kernel:
            return
        pose = Pose(self.deformer, kernel)
        self._kernel, self._pose = kernel, pose
        self.pose_changed.emit()

    def place_points(self, positions, *, reach_mm: float = 35.0, blend_mm: float = 20.0) -> None:
        """Put the control points at ``positions`` ({name: (3,) mm}, e.g. ``read_ppc(path).as_dict()``): names
        from resources/rbf/influence.csv, a subset allowed (e.g. the 8 mouth points). Everything is checked
        and factorised first; on any error (ParameterError) nothing changes. Displacements of points that
        stay are kept."""
        from core.layers.rbf.regions import control_point_specs

        specs = {s.name: s for s in control_point_specs()}
        unknown = [n for n in positions if n not in specs]
        if unknown:
            raise P.ParameterError(f"unknown control points {', '.join(unknown)}: the RBF layer's points are "
                                   f"{', '.join(specs)}")
        chosen = tuple(specs[n] for n in specs if n in positions)
        points = ControlPoints.on_face(self.face, dict(positions), chosen)
        deformer = ControlPointDeformer(self.face, points, reach_mm=reach_mm, blend_mm=blend_mm)
        Pose(deformer, self._kernel)   # factorise before anything changes
        self._swap(deformer)

    def set_deformer(self, deformer: ControlPointDeformer) -> None:
        """Use another placement of the control points on this face (e.g. back to one before
        :meth:`place_points`, for undo); displacements of points that stay are kept."""
        if deformer.face is not self.face:
            raise P.ParameterError("that control-point placement belongs to another face")
        Pose(deformer, self._kernel)
        self._swap(deformer)

    def _swap(self, deformer: ControlPointDeformer) -> None:
        if deformer is self.deformer:
            return
        old = self._values
        self.deformer = deformer
        self._pose = Pose(deformer, self._kernel)
        self._keys = tuple(f"cp:{fp}:{a}" for fp in deformer.points.feature_points for a in AXES)
        self._values = {k: old.get(k, 0.0) for k in self._keys}
        self._d = None
        self.pose_changed.emit()

    def positions(self) -> dict[str, np.ndarray]:
        """{name: (3,) mm} the control points' rest positions (what a PPC file stores)."""
        return {n: self.deformer.centres[i].copy() for i, n in enumerate(self.points.names)}

    def snapshot(self):
        return (super().snapshot(), self._kernel, self.deformer)

    def restore(self, snapshot) -> None:
        values, kernel, deformer = snapshot
        self._swap(deformer)
        self.set_kernel(kernel)
        self.set_values(dict(values))

    def copy(self) -> "ControlPointLayer":
        twin = super().copy()
        twin._d = None
        twin._pose = Pose(self.deformer, self._kernel)
        return twin

    # ------------------------------------------------------------ presets
    def apply_emotion(self, emotion, intensity: float = 1.0) -> None:
        """Set the control points to an emotion preset (a name of ``emotions.EMOTIONS`` or an ``EpcEmotion``)
        scaled by ``intensity`` in [0, 1]; points the emotion does not move go back to 0."""
        from core.layers.rbf.emotions import emotion_displacements

        if isinstance(intensity, bool) or not isinstance(intensity, (int, float)) or not 0 <= intensity <= 1:
            raise P.ParameterError(f"an emotion's intensity is a number from 0 to 1, got {intensity!r}")
        moves = emotion_displacements(emotion)
        d = np.zeros((len(self.points), 3))
        for i, name in enumerate(self.points.names):
            if name in moves:
                d[i] = moves[name] * float(intensity)
        self.set_displacements(d)
