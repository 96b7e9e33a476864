"""``BlendLayer``: an expression library's poses and the caricature slider as a rig layer.

Offset (mm, added to the layers before it; the rig composes it after the FAPs and muscles):

    offset = M · ( Σ_k (w_k / 100) · D_k  +  (e / 100) · (rest − mean) )

w_k the ``blend:<pose>`` weights in %, e the ``caricature`` exaggeration in % (only when the
library has a mean face), D_k (n_lib, 3) the library's displacements, and M the map from the
library's vertices to the face's: the identity when the face *is* on the library's topology
(same vertex count: a registered face), else the sparse (n_face, n_lib) binding of the face to
its registered canonical face (``core.registration.correspondence.bind_scan`` / a Registration's
``carry_back()``), each face vertex moving with the closest canonical surface point.

The offset is one dense product over the non-zero weights (k ≤ a few dozen), cached until a
value changes.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from core import parameters as P
from core.layer import ValueLayer
from core.layers.blend import parameters as _kinds  # noqa: F401 - registers blend:/caricature
from core.layers.blend.library import ExpressionLibrary, LibraryError, rigid_align

__all__ = ["BlendLayer", "correspondence_matrix"]


def correspondence_matrix(mapping, n_face: int, n_library: int):
    """The sparse (n_face, n_library) matrix of ``mapping``: a Binding, CarryBack, Registration or
    a sparse matrix; LibraryError when its shape does not connect the face to the library."""
    m = mapping
    if hasattr(m, "carry_back"):
        m = m.carry_back()
    if hasattr(m, "binding"):
        m = m.binding
    if hasattr(m, "matrix"):
        m = m.matrix
    if not scipy.sparse.issparse(m):
        raise LibraryError("the correspondence must be a Registration, CarryBack, Binding or sparse matrix")
    if m.shape != (n_face, n_library):
        raise LibraryError(f"the correspondence maps {m.shape[1]} canonical vertices onto {m.shape[0]} face vertices; "
                           f"the library has {n_library} and the face {n_face}")
    return scipy.sparse.csr_matrix(m)


class BlendLayer(ValueLayer):
    """Poses of ``library`` (and its caricature, when it has a mean face) on ``face``.

    face : the rig's neutral Face (n vertices); library : ExpressionLibrary (n_lib vertices);
    correspondence : needed when n ≠ n_lib (see the module docstring), else ignored.
    Raises LibraryError saying what to do when the face and the library do not connect.
    """

    name = "blend"

    def __init__(self, face, library: ExpressionLibrary | None = None, *, correspondence=None):
        library = library if library is not None else ExpressionLibrary(np.zeros((0, 3)), (), np.zeros((0, 0, 3)))
        n_face = face.n_vertices if hasattr(face, "n_vertices") else len(face)
        self.library = library
        self._map = None
        self._face_rest = np.asarray(getattr(face, "vertices", face), float)   # (n_face, 3) mm
        if library.names or library.mean is not None:
            if n_face != library.n_vertices:
                if correspondence is None:
                    raise LibraryError(
                        f"this face has {n_face} vertices and the expression library {library.n_vertices} "
                        f"(template {library.template!r}): register the face to {library.template!r} and give its "
                        "correspondence, or transfer the library onto a registered copy of the face")
                self._map = correspondence_matrix(correspondence, n_face, library.n_vertices)
        keys = [f"blend:{n}" for n in library.names]
        if library.mean is not None:
            keys.append("caricature")
            self._identity = (library.rest - rigid_align(library.mean, library.rest, robust=False)[0]).reshape(-1)
        else:
            self._identity = None
        super().__init__(keys)
        self._flat = library.displacements.reshape(len(library.names), -1)
        self._cached: tuple | None = None

    @classmethod
    def for_rig(cls, rig) -> "BlendLayer":
        """The layer a rig gets on demand (a ``blend:`` key in a project or a track): the built-in
        library when there is one that fits the face, else an empty layer (no poses yet)."""
        try:
            from core.layers.blend.builtin import builtin_library_for
        except ImportError:
            return cls(rig.face)
        found = builtin_library_for(rig.face, getattr(rig, "deformer", None))
        return cls(rig.face) if found is None else cls(rig.face, found[0], correspondence=found[1])

    @property
    def poses(self) -> tuple[str, ...]:
        return self.library.names

    def weights(self) -> np.ndarray:
        """(k,) pose weights as fractions (the ``blend:`` values / 100)."""
        return np.array([self.value(f"blend:{n}") for n in self.library.names]) / 100.0

    def library_offset(self) -> np.ndarray:
        """(n_lib, 3) mm: the layer's offset on the library's vertices."""
        values = tuple(self._values.values())
        if self._cached is not None and self._cached[0] == values:
            return self._cached[1]
        w = self.weights()
        nz = np.flatnonzero(w)
        out = np.zeros(self._flat.shape[1]) if not len(nz) else w[nz] @ self._flat[nz]
        if self._identity is not None:
            e = self.value("caricature") / 100.0
            if e:
                out = out + e * self._identity
        out = out.reshape(-1, 3)
        out.setflags(write=False)
        self._cached = (values, out)
        return out

    def offset(self, x: np.ndarray) -> np.ndarray | None:
        if not any(self._values.values()):
            return None
        d = self.library_offset()
        return d if self._map is None else self._map @ d

    def pose_from_face(self, vertices: np.ndarray, *, smoothing: float = 1e-6) -> np.ndarray:
        """(n_lib, 3) mm: the face posed as ``vertices`` (n_face, 3) mm, on the library's vertices
        (what "add the current face as a pose" stores). Through a correspondence M the library's
        displacement d is the least-squares solution of M d = vertices − rest (normal equations with a
        tiny ``smoothing`` × trace-scaled identity, so canonical vertices no face vertex follows stay put)."""
        vertices = np.asarray(vertices, float)
        if vertices.shape != self._face_rest.shape:
            raise LibraryError(f"expected the face's {len(self._face_rest)} vertices, got an array of shape {vertices.shape}")
        moved = vertices - self._face_rest
        if self._map is None:
            return self.library.rest + moved
        import scipy.sparse.linalg

        normal = (self._map.T @ self._map).tocsc()
        ridge = smoothing * max(normal.diagonal().mean(), 1e-12)
        solve = scipy.sparse.linalg.factorized(normal + ridge * scipy.sparse.identity(normal.shape[0], format="csc"))
        rhs = self._map.T @ moved
        return self.library.rest + np.column_stack([solve(np.ascontiguousarray(rhs[:, a])) for a in range(3)])

    def copy(self) -> "BlendLayer":
        twin = super().copy()
        twin._cached = None
        return twin

    def _own(self, key) -> str:
        k = P.key_of(key)
        if k not in self._values:
            poses = ", ".join(self.library.names) or "none (open or build an expression library first)"
            raise P.ParameterError(f"{k} is not a pose of this face's expression library; its poses are {poses}")
        return k
