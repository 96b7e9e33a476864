"""Scan clean-up (thesis A §2.2): fill small holes, drop small components, smooth noisy spots.

The thesis fills the scanner's shadow holes "with a dilation operator", drops connected components
"smaller than 1000 elements" and smooths "regions where the points in a 6x6 neighbourhood exceed a
threshold". It works on the range image; this module works on any mesh, so each step is restated:

- **Small components** (first, so their holes are not filled): connected components (mesh
  connectivity) with fewer than ``min_component`` vertices are removed.
- **Holes**: boundary loops (chains of edges used by one triangle) with at most ``max_hole_edges``
  edges are closed; the longest loop of each component (its outer rim) never is, nor are larger
  loops (the lid openings of a mesh without eyeballs, an open mouth). A loop is filled with
  concentric rings shrinking to its centroid (as many rings as the hole radius holds mean edges;
  ring vertices interpolate between rim and centroid), which needs the loop to be star-shaped
  about its centroid in its best-fit plane; otherwise it is ear-clipped. The new interior
  positions (and uv, vertex colours) are then the solution of the discrete Laplace equation with
  the rim and the 1-ring outside it fixed (a membrane: smooth, no bulge). This plays the role of
  the thesis's dilation: the hole is grown shut from its rim.
- **Spikes**: a vertex is noisy when the normal component of its umbrella vector (its offset from
  the mean of its neighbours) exceeds ``spike_threshold_mm``; the region is the noisy vertices
  grown by two rings (the thesis's 6x6 window at scan resolution). Only that region is smoothed
  by Laplacian (Jacobi) iterations with everything else fixed, until the region's umbrella vectors
  are below a tenth of the threshold (at most 50 iterations). Boundary vertices are never flagged (their
  one-sided neighbourhoods look like spikes), but may be smoothed as part of a region.
- **Bookkeeping.** uv, texture, vertex colours and parts are carried over (new hole vertices
  belong to no part). A landmark whose triangle survives keeps its barycentric coordinates on the
  renumbered triangle; a landmark on a removed component is re-bound to the closest point of the
  cleaned surface, and the report says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg

from core.face import Face, FaceMetadata, SurfacePoint


class CleanupError(ValueError):
    """Bad parameters for :func:`clean_scan`."""


@dataclass
class CleanResult:
    """face: the cleaned Face; report: human-readable lines; counts: numbers per step
    (components_removed, vertices_removed, holes_filled, holes_skipped, vertices_added,
    spike_vertices, smoothed_vertices, landmarks_rebound)."""

    face: Face
    report: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)


def clean_scan(face: Face, *, fill_holes: bool = True, max_hole_edges: int = 40, min_component: int = 1000,
               smooth_spikes: bool = True, spike_threshold_mm: float = 1.0) -> CleanResult:
    """Clean a raw scan. Each step can be switched off; see the module docstring.

    Parameters
    ----------
    face : Face
    fill_holes : bool
    max_hole_edges : int, largest boundary loop filled, edges (40 edges ~ an 8 mm hole at 0.65 mm)
    min_component : int, components with fewer vertices are removed (0 = keep all)
    smooth_spikes : bool
    spike_threshold_mm : float, umbrella-vector normal component that marks a noisy vertex, mm

    Returns
    -------
    CleanResult
    """
    if max_hole_edges < 3:
        raise CleanupError(f"max_hole_edges must be >= 3, got {max_hole_edges}")
    if min_component < 0:
        raise CleanupError(f"min_component must be >= 0, got {min_component}")
    if not spike_threshold_mm > 0:
        raise CleanupError(f"spike_threshold_mm must be > 0, got {spike_threshold_mm}")
    counts = dict(components_removed=0, vertices_removed=0, holes_filled=0, holes_skipped=0,
                  vertices_added=0, spike_vertices=0, smoothed_vertices=0, landmarks_rebound=0)
    report: list[str] = []
    m = _Mesh.from_face(face)

    if min_component > 0:
        labels = face.component_labels
        sizes = np.bincount(labels)
        used = np.zeros(face.n_vertices, bool)
        used[face.triangles.ravel()] = True
        used_sizes = np.bincount(labels[used], minlength=len(sizes))
        small = (used_sizes > 0) & (used_sizes < min_component)
        if small.any():
            drop_vertex = small[labels]
            keep_tri = ~drop_vertex[m.t[:, 0]]
            counts["components_removed"] = int(small.sum())
            counts["vertices_removed"] = int(drop_vertex.sum())
            m.keep_triangles(keep_tri)
            report.append(f"Removed {int(small.sum())} small component(s) (< {min_component} vertices): "
                          f"{int(drop_vertex.sum())} vertices.")
        else:
            report.append(f"No component smaller than {min_component} vertices.")
        m.drop_unused()

    if fill_holes:
        filled, skipped, added = _fill_holes(m, max_hole_edges)
        counts.update(holes_filled=filled, holes_skipped=skipped, vertices_added=added)
        msg = f"Filled {filled} hole(s) of <= {max_hole_edges} edges ({added} vertices added)."
        if skipped:
            msg += f" {skipped} small loop(s) could not be filled (non-manifold rim or not triangulable)."
        report.append(msg)

    if smooth_spikes:
        flagged, smoothed = _smooth_spikes(m, spike_threshold_mm)
        counts.update(spike_vertices=flagged, smoothed_vertices=smoothed)
        report.append(f"Smoothed {smoothed} vertices around {flagged} noisy vertex(es) "
                      f"(umbrella offset > {spike_threshold_mm} mm)." if flagged else
                      f"No noisy vertex above {spike_threshold_mm} mm.")

    out, rebound = m.to_face(face)
    counts["landmarks_rebound"] = len(rebound)
    if rebound:
        report.append(f"Re-bound {len(rebound)} landmark(s) whose triangles were removed: {', '.join(rebound)}.")
    out.metadata.notes.extend(report)
    return CleanResult(out, report, counts)


class _Mesh:
    """Mutable working copy: vertices, triangles and per-vertex attributes, with provenance."""

    def __init__(self, v, t, uv, colours, tri_origin, vert_origin):
        self.v, self.t, self.uv, self.colours = v, t, uv, colours
        self.tri_origin = tri_origin      # original triangle index, -1 for new
        self.vert_origin = vert_origin    # original vertex index, -1 for new

    @classmethod
    def from_face(cls, face: Face) -> "_Mesh":
        return cls(face.vertices.copy(), face.triangles.copy(),
                   None if face.uv is None else face.uv.copy(),
                   None if face.vertex_colors is None else face.vertex_colors.astype(np.float64),
                   np.arange(face.n_triangles), np.arange(face.n_vertices))

    def keep_triangles(self, keep):
        self.t, self.tri_origin = self.t[keep], self.tri_origin[keep]

    def drop_unused(self):
        used = np.zeros(len(self.v), bool)
        used[self.t.ravel()] = True
        remap = np.cumsum(used) - 1
        self.t = remap[self.t]
        self.v, self.vert_origin = self.v[used], self.vert_origin[used]
        if self.uv is not None:
            self.uv = self.uv[used]
        if self.colours is not None:
            self.colours = self.colours[used]

    def add(self, verts, uv, colours, tris):
        base = len(self.v)
        self.v = np.concatenate([self.v, verts])
        self.vert_origin = np.concatenate([self.vert_origin, np.full(len(verts), -1)])
        if self.uv is not None:
            self.uv = np.concatenate([self.uv, uv])
        if self.colours is not None:
            self.colours = np.concatenate([self.colours, colours])
        self.t = np.concatenate([self.t, tris])
        self.tri_origin = np.concatenate([self.tri_origin, np.full(len(tris), -1)])
        return base

    def adjacency(self):
        n = len(self.v)
        e = np.concatenate([self.t[:, [0, 1]], self.t[:, [1, 2]], self.t[:, [2, 0]]])
        A = scipy.sparse.csr_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
        return ((A + A.T) > 0).astype(np.float64).tocsr()

    def to_face(self, original: Face):
        new_tri = np.full(original.n_triangles, -1)
        new_tri[self.tri_origin[self.tri_origin >= 0]] = np.nonzero(self.tri_origin >= 0)[0]
        new_vert = np.full(original.n_vertices, -1)
        new_vert[self.vert_origin[self.vert_origin >= 0]] = np.nonzero(self.vert_origin >= 0)[0]
        parts = {}
        for name, idx in original.parts.items():
            mapped = new_vert[idx]
            parts[name] = mapped[mapped >= 0]
        colours = None if self.colours is None else np.clip(np.rint(self.colours), 0, 255).astype(np.uint8)
        face = Face(self.v, self.t, uv=self.uv, texture=original.texture, vertex_colors=colours, parts=parts,
                    metadata=FaceMetadata(source=original.metadata.source, units=original.metadata.units,
                                          notes=list(original.metadata.notes), name=original.metadata.name))
        rebound = []
        lost = []
        for name, sp in original.landmarks.items():
            t = new_tri[sp.triangle]
            if t >= 0:
                face.set_landmark(name, SurfacePoint(int(t), sp.barycentric))
            else:
                lost.append(name)
        if lost and face.n_triangles:
            from core.surface_query import TriangleSet

            pos = original.landmark_positions(lost)
            _, tri, bary = TriangleSet(face.vertices, face.triangles).closest(pos)
            for name, t, b in zip(lost, tri, bary):
                face.set_landmark(name, SurfacePoint(int(t), tuple(b)))
            rebound = lost
        return face, rebound


# ---------------------------------------------------------------- holes
def _boundary_loops(t: np.ndarray):
    """Directed boundary loops [(k,) vertex arrays] following the mesh's half-edges, and the
    number of ambiguous (non-manifold) rim vertices that stopped a loop."""
    he = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    n = int(t.max()) + 1 if len(t) else 0
    key = he[:, 0] * n + he[:, 1]
    rev = he[:, 1] * n + he[:, 0]
    boundary = he[~np.isin(key, rev)]
    nxt: dict[int, int] = {}
    ambiguous = set()
    for a, b in boundary.tolist():  # rim edges only (a few thousand), not a per-vertex loop
        if a in nxt:
            ambiguous.add(a)
        nxt[a] = b
    loops, seen, broken = [], set(), 0
    for start in list(nxt):
        if start in seen:
            continue
        loop, cur, ok = [], start, True
        while cur not in seen:
            seen.add(cur)
            loop.append(cur)
            if cur in ambiguous or cur not in nxt:
                ok = False
                break
            cur = nxt[cur]
        if ok and cur == start and len(loop) >= 3:
            loops.append(np.array(loop))
        else:
            broken += 1
    return loops, broken


def _fill_holes(m: _Mesh, max_edges: int):
    if len(m.t) == 0:
        return 0, 0, 0
    loops, broken = _boundary_loops(m.t)
    if not loops:
        return 0, 0, 0
    # The longest loop of each component is its outer rim.
    A = m.adjacency()
    _, labels = scipy.sparse.csgraph.connected_components(A, directed=False)
    longest: dict[int, int] = {}
    for i, loop in enumerate(loops):
        c = labels[loop[0]]
        if c not in longest or len(loop) > len(loops[longest[c]]):
            longest[c] = i
    rims = set(longest.values())
    e = np.concatenate([m.t[:, [0, 1]], m.t[:, [1, 2]]])
    mean_edge = float(np.mean(np.linalg.norm(m.v[e[:, 0]] - m.v[e[:, 1]], axis=1)))
    filled = skipped = added = 0
    new_interior = []
    for i, loop in enumerate(loops):
        if i in rims or len(loop) > max_edges:
            continue
        res = _patch(m.v[loop], loop, mean_edge, len(m.v))
        if res is None:
            skipped += 1
            continue
        verts, tris, weights = res
        uv = None if m.uv is None else weights @ m.uv[loop]
        col = None if m.colours is None else weights @ m.colours[loop]
        base = m.add(verts, uv, col, tris)
        new_interior.append(np.arange(base, base + len(verts)))
        filled += 1
        added += len(verts)
    if new_interior:
        _membrane(m, np.concatenate(new_interior))
    return filled, skipped, added


def _patch(P, loop, mean_edge, base):
    """Triangles (and new interior vertices) closing one loop; None when not possible.

    Returns (new vertices (k, 3), triangles (f, 3) in global indices, weights (k, L) of the new
    vertices over the loop vertices, for interpolating attributes)."""
    L = len(loop)
    c = P.mean(axis=0)
    X = P - c
    _, _, Vt = np.linalg.svd(X, full_matrices=False)
    q = X @ Vt[:2].T  # loop in its best-fit plane
    # Orientation in the plane: rim half-edges run the loop; the patch must run it the other way.
    area = 0.5 * np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1])
    if abs(area) < 1e-12:
        return None
    # Star-shaped about the centroid: every fan triangle (p_i, p_i+1, c) has the loop's orientation.
    cross = q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]
    if np.all(np.sign(cross) == np.sign(area)):
        radius = float(np.mean(np.linalg.norm(X, axis=1)))
        rings = int(max(0, round(radius / max(mean_edge, 1e-12)) - 1))
        verts, weights, tris = [], [], []
        prev = loop
        k = base
        uniform = np.full(L, 1.0 / L)
        for r in range(1, rings + 1):
            s = r / (rings + 1)
            w = (1 - s) * np.eye(L) + s * uniform[None, :]
            verts.append(w @ P)
            weights.append(w)
            ring = np.arange(k, k + L)
            k += L
            nxt = np.roll(np.arange(L), -1)
            # Rim half-edge prev[i] -> prev[i+1]; patch uses the reverse.
            tris.append(np.column_stack([prev[nxt], prev, ring]))
            tris.append(np.column_stack([prev[nxt], ring, ring[nxt]]))
            prev = ring
        centre = k
        verts.append(c[None])
        weights.append(uniform[None])
        nxt = np.roll(np.arange(L), -1)
        tris.append(np.column_stack([prev[nxt], prev, np.full(L, centre)]))
        return np.concatenate(verts), np.concatenate(tris), np.concatenate(weights)
    tris = _ear_clip(q, area)
    if tris is None:
        return None
    # Ear clipping keeps the loop's orientation; reverse for the patch.
    return np.zeros((0, 3)), loop[tris][:, [0, 2, 1]], np.zeros((0, L))


def _ear_clip(q, area):
    """Triangulate a simple polygon q (L, 2) by ear clipping; (L-2, 3) local indices or None."""
    sign = np.sign(area)
    idx = list(range(len(q)))
    out = []
    guard = 0
    while len(idx) > 3 and guard < 10 * len(q) ** 2:  # small loops only (<= max_hole_edges)
        guard += 1
        found = False
        for j in range(len(idx)):
            i0, i1, i2 = idx[j - 1], idx[j], idx[(j + 1) % len(idx)]
            a, b, c = q[i0], q[i1], q[i2]
            cr = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
            if np.sign(cr) != sign or cr == 0:
                continue
            others = [k for k in idx if k not in (i0, i1, i2)]
            if others and _any_inside(q[others], a, b, c):
                continue
            out.append((i0, i1, i2))
            idx.pop(j)
            found = True
            break
        if not found:
            return None
    out.append(tuple(idx))
    return np.array(out)


def _any_inside(p, a, b, c) -> bool:
    def side(p, u, v):
        return (v[0] - u[0]) * (p[:, 1] - u[1]) - (v[1] - u[1]) * (p[:, 0] - u[0])

    s1, s2, s3 = side(p, a, b), side(p, b, c), side(p, c, a)
    inside = ((s1 > 0) & (s2 > 0) & (s3 > 0)) | ((s1 < 0) & (s2 < 0) & (s3 < 0))
    return bool(inside.any())


def _membrane(m: _Mesh, free: np.ndarray):
    """Solve the uniform Laplace equation for the ``free`` vertices (others fixed)."""
    A = m.adjacency()
    n = len(m.v)
    deg = np.asarray(A.sum(axis=1)).ravel()
    L = scipy.sparse.diags(deg) - A
    is_free = np.zeros(n, bool)
    is_free[free] = True
    fixed = ~is_free
    Lff = L[is_free][:, is_free].tocsc()
    Lfb = L[is_free][:, fixed]
    solve = scipy.sparse.linalg.factorized(Lff)
    for name in ("v", "uv", "colours"):
        arr = getattr(m, name)
        if arr is None:
            continue
        rhs = -(Lfb @ arr[fixed])
        arr = arr.copy()
        arr[is_free] = np.column_stack([solve(np.ascontiguousarray(rhs[:, j])) for j in range(arr.shape[1])])
        setattr(m, name, arr)


# ---------------------------------------------------------------- spikes
def _smooth_spikes(m: _Mesh, threshold: float):
    from core.face import vertex_normals
    from core.registration.icp import boundary_vertex_mask

    if len(m.t) == 0:
        return 0, 0
    A = m.adjacency()
    n = len(m.v)
    deg = np.asarray(A.sum(axis=1)).ravel()
    W = scipy.sparse.diags(np.divide(1.0, deg, out=np.zeros(n), where=deg > 0)) @ A
    boundary = boundary_vertex_mask(m.t, n)

    def offsets(v):
        normals = vertex_normals(v, m.t)
        return np.abs(np.einsum("ij,ij->i", v - W @ v, normals))

    off = offsets(m.v)
    spikes = (off > threshold) & ~boundary & (deg > 0)
    if not spikes.any():
        return 0, 0
    region = spikes.copy()
    for _ in range(2):  # grow by two rings: the thesis's 6x6 window at scan resolution
        region |= (A @ region.astype(np.float64)) > 0
    v = m.v.copy()
    for _ in range(50):  # Jacobi: region vertices move to their neighbours' mean, others fixed
        v[region] = (W @ v)[region]
        if not np.any(offsets(v)[region & ~boundary] > 0.1 * threshold):
            break
    m.v = v
    return int(spikes.sum()), int(region.sum())
