"""face.py
----
The Face: a triangle mesh in millimetres with optional texture, per-vertex
colours and named landmarks stored as surface points.

A landmark is a :class:`SurfacePoint` (triangle index + barycentric
coordinates), never a free xyz: it stays on the surface and follows any
deformation that keeps the topology (:meth:`Face.with_vertices`).

Arrays are copied on construction and made read-only so that cached derived
data (normals, adjacency, edges, spatial index) can never go stale.
Topology-only caches (edges, adjacency, components) are shared between a face
and the deformed copies made by :meth:`Face.with_vertices`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Iterable, Mapping

import numpy as np
import scipy.sparse

from core import normal_kernels

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


@dataclass(frozen=True)
class SurfacePoint:
    """A point on a mesh surface.

    Attributes
    ----------
    triangle : int
        Index into ``Face.triangles``.
    barycentric : tuple of 3 float
        Weights of the triangle's three corners; non-negative, sum 1.
    """

    triangle: int
    barycentric: tuple[float, float, float]

    def __post_init__(self):
        bary = tuple(float(b) for b in self.barycentric)
        if len(bary) != 3 or not np.all(np.isfinite(bary)):
            raise ValueError(f"barycentric must be 3 finite numbers, got {self.barycentric!r}")
        total = sum(bary)
        if abs(total - 1.0) > 1e-4:
            raise ValueError(f"barycentric weights must sum to 1, got {total:.6f}")
        object.__setattr__(self, "triangle", int(self.triangle))
        object.__setattr__(self, "barycentric", bary)


@dataclass
class FaceMetadata:
    """Where a face came from and what was done to it on the way in.

    ``notes`` are human-readable messages (unit conversion, repairs) that the
    GUI shows after loading. ``landmark_status`` / ``landmark_confidence`` ({name: "auto" |
    "edited" | "confirmed"} / {name: 0..1}) say who vouches for landmarks a face inherited from
    the face it was derived from (a canonical face built from points the user corrected).
    """

    source: str | None = None
    units: str = "mm"
    notes: list[str] = field(default_factory=list)
    name: str = "face"
    landmark_status: dict[str, str] = field(default_factory=dict)
    landmark_confidence: dict[str, float] = field(default_factory=dict)


class _TopologyCache:
    """Derived data that depends on the triangles only (shared by deformed copies)."""

    def __init__(self, triangles: np.ndarray, n_vertices: int):
        self.triangles = triangles
        self.n_vertices = n_vertices
        self._edges = None
        self._adjacency = None
        self._components = None

    @property
    def edges(self) -> np.ndarray:
        if self._edges is None:
            from core.subdivision import unique_edges

            edges = unique_edges(self.triangles)[0]
            edges.setflags(write=False)
            self._edges = edges
        return self._edges

    @property
    def adjacency(self) -> scipy.sparse.csr_matrix:
        if self._adjacency is None:
            e = self.edges
            n = self.n_vertices
            data = np.ones(2 * len(e), dtype=np.int8)
            rows = np.concatenate([e[:, 0], e[:, 1]])
            cols = np.concatenate([e[:, 1], e[:, 0]])
            self._adjacency = scipy.sparse.csr_matrix((data, (rows, cols)), shape=(n, n))
        return self._adjacency

    @property
    def components(self) -> tuple[int, np.ndarray]:
        if self._components is None:
            from scipy.sparse.csgraph import connected_components   # here: ~0.3 s of the window's start-up

            self._components = connected_components(
                self.adjacency, directed=False
            )
        return self._components


def _frozen(array: np.ndarray | None, dtype, shape_tail: tuple, name: str) -> np.ndarray | None:
    if array is None:
        return None
    a = np.array(array, dtype=dtype, copy=True)
    if a.ndim != 1 + len(shape_tail) or tuple(a.shape[1:]) != shape_tail:
        expected = "(n, " + ", ".join(str(s) for s in shape_tail) + ")"
        raise ValueError(f"{name} must have shape {expected}, got {a.shape}")
    a.setflags(write=False)
    return a


class Face:
    """A textured triangle mesh of a face with named surface landmarks.

    Parameters
    ----------
    vertices : (n, 3) float
        Positions in millimetres. +x is the face's own left, +y up, +z out of
        the face (MPEG-4 convention).
    triangles : (m, 3) int
        Vertex indices, counter-clockwise seen from outside.
    uv : (n, 2) float, optional
        Texture coordinates in [0, 1], v = 0 at the bottom of the image.
    texture : (H, W, 3) uint8, optional
        RGB texture image, row 0 at the top.
    vertex_colors : (n, 3) uint8, optional
        RGB per vertex.
    landmarks : mapping of name -> SurfacePoint, optional
    metadata : FaceMetadata, optional
    parts : mapping of name -> (k,) int vertex indices, optional
        Named vertex sets that animation treats specially, e.g. ``eyeball_l``,
        ``eyeball_r`` (rotate with gaze), ``teeth_upper``, ``teeth_lower``
        (rigid with skull / jaw), ``mouth_cavity``. Vertices in no part are skin.
    """

    def __init__(
        self,
        vertices,
        triangles,
        *,
        uv=None,
        texture=None,
        vertex_colors=None,
        landmarks: Mapping[str, SurfacePoint] | None = None,
        metadata: FaceMetadata | None = None,
        parts: Mapping[str, np.ndarray] | None = None,
        _topology: _TopologyCache | None = None,
    ):
        self._vertices = _frozen(vertices, np.float64, (3,), "vertices")
        if _topology is not None:
            # A deformed copy: reuse the (read-only) triangles and their caches.
            self._triangles = _topology.triangles
        else:
            self._triangles = _frozen(triangles, np.int64, (3,), "triangles")
        n = len(self._vertices)
        if _topology is not None and _topology.n_vertices != n:
            raise ValueError(f"topology is for {_topology.n_vertices} vertices, got {n}")
        if len(self._triangles) and (self._triangles.min() < 0 or self._triangles.max() >= n):
            raise ValueError(
                f"triangles reference vertex {int(self._triangles.max())} but there are only {n} vertices"
            )
        self._uv = _frozen(uv, np.float64, (2,), "uv")
        if self._uv is not None and len(self._uv) != n:
            raise ValueError(f"uv has {len(self._uv)} rows for {n} vertices")
        if texture is not None:
            texture = np.array(texture, dtype=np.uint8, copy=True)
            if texture.ndim != 3 or texture.shape[2] != 3:
                raise ValueError(f"texture must be an (H, W, 3) RGB image, got shape {texture.shape}")
            texture.setflags(write=False)
        self._texture = texture
        self._vertex_colors = _frozen(vertex_colors, np.uint8, (3,), "vertex_colors")
        if self._vertex_colors is not None and len(self._vertex_colors) != n:
            raise ValueError(f"vertex_colors has {len(self._vertex_colors)} rows for {n} vertices")
        self.metadata = metadata if metadata is not None else FaceMetadata()
        self._parts: dict[str, np.ndarray] = {}
        for name, idx in (parts or {}).items():
            idx = np.unique(np.asarray(idx, dtype=np.int64).ravel())
            if len(idx) and (idx[0] < 0 or idx[-1] >= n):
                raise ValueError(f"part {name!r} references vertex {int(idx[-1])} but there are only {n} vertices")
            idx.setflags(write=False)
            self._parts[name] = idx
        self._landmarks: dict[str, SurfacePoint] = {}
        for name, point in (landmarks or {}).items():
            self.set_landmark(name, point)
        if _topology is None:
            _topology = _TopologyCache(self._triangles, n)
        self._topology = _topology
        self._face_normals = None
        self._vertex_normals = None
        self._kdtree = None
        self._trimesh = None

    # ------------------------------------------------------------------ data
    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float, mm, read-only."""
        return self._vertices

    @property
    def triangles(self) -> np.ndarray:
        """(m, 3) int, read-only."""
        return self._triangles

    @property
    def uv(self) -> np.ndarray | None:
        return self._uv

    @property
    def texture(self) -> np.ndarray | None:
        return self._texture

    @property
    def vertex_colors(self) -> np.ndarray | None:
        return self._vertex_colors

    @property
    def parts(self) -> dict[str, np.ndarray]:
        """Named vertex index sets (read-only arrays); see the class docstring."""
        return dict(self._parts)

    def part_mask(self, name: str) -> np.ndarray:
        """(n,) bool, True for the vertices of part ``name`` (all False if the face has no such part)."""
        mask = np.zeros(self.n_vertices, bool)
        if name in self._parts:
            mask[self._parts[name]] = True
        return mask

    @property
    def n_vertices(self) -> int:
        return len(self._vertices)

    @property
    def n_triangles(self) -> int:
        return len(self._triangles)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner, mm."""
        return np.stack([self._vertices.min(axis=0), self._vertices.max(axis=0)])

    # --------------------------------------------------------------- derived
    @property
    def edges(self) -> np.ndarray:
        """(e, 2) int unique undirected edges, smaller index first."""
        return self._topology.edges

    @property
    def adjacency(self) -> scipy.sparse.csr_matrix:
        """(n, n) sparse vertex adjacency (1 where an edge joins two vertices)."""
        return self._topology.adjacency

    @property
    def n_components(self) -> int:
        """Number of connected components (isolated vertices count as components)."""
        return self._topology.components[0]

    @property
    def component_labels(self) -> np.ndarray:
        """(n,) int component index per vertex."""
        return self._topology.components[1]

    @property
    def face_normals(self) -> np.ndarray:
        """(m, 3) unit triangle normals (zero for degenerate triangles)."""
        if self._face_normals is None:
            self._face_normals = triangle_normals(self._vertices, self._triangles)
            self._face_normals.setflags(write=False)
        return self._face_normals

    @property
    def vertex_normals(self) -> np.ndarray:
        """(n, 3) unit vertex normals, area-weighted mean of adjacent triangle normals."""
        if self._vertex_normals is None:
            self._vertex_normals = vertex_normals(self._vertices, self._triangles)
            self._vertex_normals.setflags(write=False)
        return self._vertex_normals

    @property
    def kdtree(self) -> cKDTree:
        """KD-tree over the vertices, for nearest-vertex queries."""
        if self._kdtree is None:
            from scipy.spatial import cKDTree   # here: scipy.spatial costs ~0.15 s of start-up

            self._kdtree = cKDTree(self._vertices)
        return self._kdtree

    def as_trimesh(self):
        """A cached ``trimesh.Trimesh`` view (no processing) for proximity and ray queries."""
        if self._trimesh is None:
            import trimesh

            self._trimesh = trimesh.Trimesh(self._vertices, self._triangles, process=False, validate=False)
        return self._trimesh

    # ------------------------------------------------------------ queries
    def closest_surface_points(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest points on the surface.

        Parameters
        ----------
        points : (k, 3) float, mm

        Returns
        -------
        closest : (k, 3) float, mm
        triangle : (k,) int
        barycentric : (k, 3) float
        """
        import trimesh

        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        closest, _distance, tri = trimesh.proximity.closest_point(self.as_trimesh(), pts)
        corners = self._vertices[self._triangles[tri]]
        bary = trimesh.triangles.points_to_barycentric(corners, closest)
        bary = np.clip(bary, 0.0, None)
        bary /= bary.sum(axis=1, keepdims=True)
        return closest, np.asarray(tri, dtype=np.int64), bary

    def surface_point(self, xyz) -> SurfacePoint:
        """The surface point closest to ``xyz`` (3,), mm."""
        _, tri, bary = self.closest_surface_points(np.asarray(xyz, dtype=float)[None])
        return SurfacePoint(int(tri[0]), tuple(bary[0]))

    def ray_hits(self, origins, directions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First intersection of rays with the surface.

        Returns (locations (h, 3), ray_index (h,), triangle (h,)); rays that miss
        are absent.
        """
        mesh = self.as_trimesh()
        locations, ray_index, tri = mesh.ray.intersects_location(
            np.asarray(origins, float).reshape(-1, 3),
            np.asarray(directions, float).reshape(-1, 3),
            multiple_hits=False,
        )
        return locations, ray_index, tri

    # ------------------------------------------------------------ landmarks
    @property
    def landmark_names(self) -> list[str]:
        return list(self._landmarks)

    @property
    def landmarks(self) -> dict[str, SurfacePoint]:
        """A copy of the name -> SurfacePoint mapping."""
        return dict(self._landmarks)

    def set_landmark(self, name: str, point: SurfacePoint) -> None:
        if not isinstance(point, SurfacePoint):
            raise TypeError(f"landmark {name!r} must be a SurfacePoint, got {type(point).__name__}")
        if not 0 <= point.triangle < len(self._triangles):
            raise ValueError(
                f"landmark {name!r} refers to triangle {point.triangle}, "
                f"but the face has {len(self._triangles)} triangles"
            )
        self._landmarks[str(name)] = point

    def remove_landmark(self, name: str) -> None:
        self._landmarks.pop(name, None)

    def landmark_position(self, name: str, vertices: np.ndarray | None = None) -> np.ndarray:
        """(3,) position of one landmark on the current (or the given) vertices, mm."""
        return self.landmark_positions([name], vertices)[0]

    def landmark_positions(self, names: Iterable[str] | None = None, vertices: np.ndarray | None = None) -> np.ndarray:
        """(k, 3) landmark positions, mm, in the order of ``names`` (all by default).

        ``vertices`` (n, 3) lets a deformed pose be evaluated without building a Face.
        """
        names = list(self._landmarks) if names is None else list(names)
        missing = [n for n in names if n not in self._landmarks]
        if missing:
            raise KeyError(f"face has no landmark(s) {', '.join(missing)}")
        verts = self._vertices if vertices is None else np.asarray(vertices)
        if not names:
            return np.zeros((0, 3))
        tri = np.array([self._landmarks[n].triangle for n in names])
        bary = np.array([self._landmarks[n].barycentric for n in names])
        return np.einsum("kj,kjd->kd", bary, verts[self._triangles[tri]])

    # ------------------------------------------------------------ copies
    def with_vertices(self, vertices) -> "Face":
        """A face with the same topology, uv, texture and landmarks at new positions."""
        vertices = np.asarray(vertices, dtype=np.float64)
        if vertices.shape != self._vertices.shape:
            raise ValueError(f"new vertices must have shape {self._vertices.shape}, got {vertices.shape}")
        return Face(
            vertices,
            self._triangles,
            uv=self._uv,
            texture=self._texture,
            vertex_colors=self._vertex_colors,
            landmarks=self._landmarks,
            metadata=dataclasses.replace(self.metadata, notes=list(self.metadata.notes)),
            parts=self._parts,
            _topology=self._topology,
        )

    def with_texture(self, texture) -> "Face":
        """The same face with another (H, W, 3) uint8 texture image; needs texture coordinates."""
        if self._uv is None:
            raise ValueError("this face has no texture coordinates (uv), so an image cannot be mapped onto it")
        return Face(
            self._vertices, self._triangles, uv=self._uv, texture=texture, vertex_colors=self._vertex_colors,
            landmarks=self._landmarks, metadata=self.metadata, parts=self._parts, _topology=self._topology,
        )

    def with_flipped_texture(self) -> "Face":
        """The same face with its texture image upside down (for texture coordinates that count rows
        from the other end); ValueError when it has no texture."""
        if self._texture is None:
            raise ValueError("this face has no texture image to flip")
        return self.with_texture(np.ascontiguousarray(self._texture[::-1]))

    def scaled(self, factor: float) -> "Face":
        """The face scaled by ``factor`` about the origin (e.g. to fix units); landmarks follow."""
        factor = float(factor)
        if not (np.isfinite(factor) and factor > 0):
            raise ValueError(f"a scale factor must be a positive number, got {factor}")
        return self.with_vertices(self._vertices * factor)

    def without_texture(self) -> "Face":
        return Face(
            self._vertices, self._triangles, uv=self._uv, vertex_colors=self._vertex_colors,
            landmarks=self._landmarks, metadata=self.metadata, parts=self._parts, _topology=self._topology,
        )

    def __repr__(self) -> str:
        tex = f", texture {self._texture.shape[1]}x{self._texture.shape[0]}" if self._texture is not None else ""
        return (
            f"Face({self.metadata.name!r}: {self.n_vertices} vertices, {self.n_triangles} triangles"
            f"{tex}, {len(self._landmarks)} landmarks)"
        )


def triangle_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m, 3) unit normals of triangles (m, 3) over vertices (n, 3); zero when degenerate."""
    v = vertices[triangles]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


class VertexNormals:
    """Area-weighted unit vertex normals for one fixed triangulation, fast enough per frame.

    Build once per triangulation; each call is one pass over the triangles
    (:mod:`core.normal_kernels`, ~1 ms for the 50k-vertex default face), or without numba one
    cross product per triangle and one precomputed sparse (vertex x triangle) product (~5-10 ms).
    """

    def __init__(self, triangles, n_vertices: int, welds: tuple[np.ndarray, np.ndarray] | None = None):
        tri = np.asarray(triangles, dtype=np.int64)
        m = len(tri)
        self.n_vertices = int(n_vertices)
        self._triangles = np.ascontiguousarray(tri)
        self._corners = [np.ascontiguousarray(tri[:, k]) for k in range(3)]
        self._incidence = scipy.sparse.csr_matrix(
            (np.ones(3 * m), (tri.ravel(), np.repeat(np.arange(m), 3))), shape=(self.n_vertices, m))
        self._welds = None
        if welds is not None and len(welds[0]):
            members, groups = (np.asarray(a, dtype=np.int64) for a in welds)
            first = np.full(groups.max() + 1, -1, dtype=np.int64)
            first[groups[::-1]] = members[::-1]      # each group's first member
            self._welds = (members, groups, first[groups], len(first))

    def __call__(self, vertices) -> np.ndarray:
        v = np.ascontiguousarray(vertices, dtype=np.float64)
        kernel = normal_kernels.kernel()
        if kernel is not None and v.shape == (self.n_vertices, 3):
            out = kernel(v, self._triangles, np.empty_like(v))
        else:
            out = self.with_numpy(v)
        if self._welds is not None:
            self._weld(v, out)
        return out

    def _weld(self, v: np.ndarray, normals: np.ndarray) -> None:
        """Give welded vertices that still coincide (within ``WELD_TOLERANCE_MM``) one normal: their
        sides' normals averaged (in place). Split vertices on a seam (a texture seam, the default
        face's front/head-shell seam) would otherwise show the seam as a shading crease; cut lips that
        parted are no longer together and keep their own normals."""
        members, groups, firsts, n_groups = self._welds
        apart = np.abs(v[members] - v[firsts]).max(axis=1) > WELD_TOLERANCE_MM
        groups = np.where(apart, n_groups + np.arange(len(members)), groups)   # apart: a group of its own
        n = normals[members]
        summed = np.stack([np.bincount(groups, n[:, k], minlength=n_groups + len(members)) for k in range(3)], axis=1)
        length = np.linalg.norm(summed, axis=1, keepdims=True)
        unit = np.divide(summed, length, out=np.zeros_like(summed), where=length > 0)
        normals[members] = unit[groups]

    def with_numpy(self, vertices) -> np.ndarray:
        """The same normals without the compiled kernel (the reference)."""
        v = np.asarray(vertices, dtype=np.float64)
        x, y, z = v[:, 0], v[:, 1], v[:, 2]
        i0, i1, i2 = self._corners
        ax, ay, az = x[i0], y[i0], z[i0]
        e1x, e1y, e1z = x[i1] - ax, y[i1] - ay, z[i1] - az
        e2x, e2y, e2z = x[i2] - ax, y[i2] - ay, z[i2] - az
        cross = np.empty((len(i0), 3))
        cross[:, 0] = e1y * e2z - e1z * e2y  # length = 2 * area: area weighting for free
        cross[:, 1] = e1z * e2x - e1x * e2z
        cross[:, 2] = e1x * e2y - e1y * e2x
        out = self._incidence @ cross
        length = np.sqrt(np.einsum("ij,ij->i", out, out))[:, None]
        return np.divide(out, length, out=np.zeros_like(out), where=length > 0)


WELD_TOLERANCE_MM = 0.01   # welded vertices farther apart than this shade on their own (a cut that opened)
WELD_MAX_ANGLE_DEG = 60.0  # coincident vertices whose rest normals differ more are a real crease: not welded


def coincident_skin_vertices(face: "Face") -> tuple[np.ndarray, np.ndarray]:
    """(members (k,), groups (k,)): the vertices that share their rest position with another one, each
    with the number of its group, among the vertices of no named part (skin: split on texture seams
    or where two surfaces are joined; rigid parts such as teeth keep their hard edges) and whose rest
    normals differ by less than ``WELD_MAX_ANGLE_DEG`` from their group's first one (where a lip
    folds into the mouth the fold is meant to show). For :class:`VertexNormals`' ``welds``."""
    skin = np.ones(face.n_vertices, dtype=bool)
    for idx in face.parts.values():
        skin[np.asarray(idx, dtype=np.int64)] = False
    ids = np.flatnonzero(skin)
    if not len(ids):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # Equal rows side by side (a stable lexsort keeps equal ones in index order; ~10x faster than
    # np.unique(axis=0), and this runs as a face is first shown).
    v = face.vertices[ids]
    order = np.lexsort(v.T[::-1])
    sorted_rows = v[order]
    starts = np.r_[True, (sorted_rows[1:] != sorted_rows[:-1]).any(axis=1)]
    position_group = np.cumsum(starts) - 1
    shared = np.bincount(position_group)[position_group] > 1
    members, groups = ids[order][shared], position_group[shared]
    first = members[np.searchsorted(groups, groups)]            # each group's first member
    normals = face.vertex_normals
    aligned = (normals[members] * normals[first]).sum(axis=1) >= np.cos(np.radians(WELD_MAX_ANGLE_DEG))
    members, groups = members[aligned], groups[aligned]
    _labels, groups, counts = np.unique(groups, return_inverse=True, return_counts=True)
    keep = counts[groups] > 1                                    # a group left alone welds nothing
    _labels, groups = np.unique(groups[keep], return_inverse=True)    # groups numbered 0..g-1
    return members[keep], groups.ravel()


UV_AGAINST_HEIGHT = -0.3   # correlation of v with height below which a texture reads upside down


def texture_runs_down(face: Face) -> bool:
    """True when ``face``'s texture coordinates run against its height (v falls as y rises: their
    correlation is below ``UV_AGAINST_HEIGHT``).

    Face textures are drawn upright (forehead at the top of the image) and Mimica samples row
    ``(1 - v) * H``; coordinates written for the other convention (v counted down from the top, as
    glTF and many tools do) then show the image upside down: such a face wants
    :meth:`Face.with_flipped_texture`. False without uv or when the evidence is weak.
    """
    if face.uv is None or face.n_vertices < 3:
        return False
    v, y = face.uv[:, 1], face.vertices[:, 1]
    if np.ptp(v) == 0 or np.ptp(y) == 0:
        return False
    return float(np.corrcoef(v, y)[0, 1]) < UV_AGAINST_HEIGHT


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n, 3) unit vertex normals: area-weighted sum of incident triangle normals."""
    return VertexNormals(triangles, len(vertices))(vertices)
