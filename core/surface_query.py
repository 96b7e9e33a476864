"""Fast local surface queries on a triangle set: closest points and short normal rays.

trimesh's generic queries are slow without Embree (tens of seconds for a few thousand points on
a 100k-triangle face). Here, candidates come from a KD-tree over triangle centroids and the exact
tests run vectorised over (points x candidates).
"""

from __future__ import annotations

import numpy as np


# From this many (point, candidate) pairs on, a query builds the compiled loop even where the window
# defers kernels: numpy takes ~1.5 us a pair, loading numba's cached code ~0.3 s once per process.
COMPILE_WORTH_PAIRS = 200_000


class TriangleSet:
    """Triangles ``triangles`` (m, 3) over ``vertices`` (n, 3), mm, with a centroid KD-tree."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray):
        self.vertices = np.asarray(vertices, float)
        self.triangles = np.asarray(triangles, np.int64)
        self.corners = self.vertices[self.triangles]                    # (m, 3, 3)
        from scipy.spatial import cKDTree   # here: importing scipy.spatial costs ~0.3 s of the window's start-up

        self.tree = cKDTree(self.corners.mean(axis=1))
        edges = np.linalg.norm(self.corners - self.corners.mean(axis=1, keepdims=True), axis=2)
        self.reach = float(edges.max()) if len(edges) else 0.0          # centroid-to-corner bound
        n = np.cross(self.corners[:, 1] - self.corners[:, 0], self.corners[:, 2] - self.corners[:, 0])
        self.normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    def _candidates(self, points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(distances (p, k) of the k nearest centroids, their triangles (p, k)), nearest first."""
        k = min(k, len(self.triangles))
        dist, idx = self.tree.query(points, k=k)
        return dist.reshape(len(points), k), idx.reshape(len(points), k)

    def closest(self, points, *, k: int = 16, widen: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points: (positions (p, 3), triangle (p,), barycentric (p, 3)).

        Exact when the closest triangle is among the ``k`` with the nearest centroids; to make that
        safe (``widen``), the candidate set is widened for points whose answer is farther than the
        k-th centroid distance minus the triangle reach."""
        pts = np.asarray(points, float).reshape(-1, 3)
        centroid_dist, cand = self._candidates(pts, k)
        pos, tri, bary, dist = self._closest_among(pts, cand)
        if not widen:
            return pos, tri, bary
        unsure = dist > centroid_dist[:, -1] - self.reach
        if unsure.any() and k < len(self.triangles):
            sub = np.nonzero(unsure)[0]
            _, wider = self._candidates(pts[sub], min(8 * k, len(self.triangles)))
            pos[sub], tri[sub], bary[sub], _ = self._closest_among(pts[sub], wider)
        return pos, tri, bary

    def _closest_among(self, pts: np.ndarray, cand: np.ndarray):
        """(positions (p, 3), triangle (p,), barycentric (p, 3), distance (p,)) of the closest point
        of each point's candidate triangles ``cand`` (p, k)."""
        from core.surface_query_kernels import kernel

        compiled = kernel(load=cand.size >= COMPILE_WORTH_PAIRS)
        if compiled is not None:
            pos, bary = np.empty((len(pts), 3)), np.empty((len(pts), 3))
            tri, dist = np.empty(len(pts), np.int64), np.empty(len(pts))
            compiled(pts, self.corners, np.ascontiguousarray(cand, dtype=np.int64), pos, tri, bary, dist)
            return pos, tri, bary, dist
        corners = self.corners[cand]                                     # (p, k, 3, 3)
        q, bary = _closest_on_triangles(pts[:, None, :], corners[:, :, 0], corners[:, :, 1], corners[:, :, 2])
        d = np.linalg.norm(q - pts[:, None, :], axis=2)
        j = d.argmin(axis=1)
        r = np.arange(len(pts))
        return q[r, j], cand[r, j], bary[r, j], d[r, j]

    def ray_nearest(self, points, directions, max_distance: float, *, same_facing: bool = True):
        """Nearest hit along +-direction within ``max_distance``.

        Returns (positions (p, 3), triangle (p,) or -1, barycentric (p, 3), hit (p,) bool). With
        ``same_facing`` only triangles whose normal agrees with the direction count (no far side)."""
        pts = np.asarray(points, float).reshape(-1, 3)
        dirs = np.asarray(directions, float).reshape(-1, 3)
        dirs = dirs / np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-300)
        _, cand = self._candidates(pts, 64)
        corners = self.corners[cand]
        a, b, c = corners[:, :, 0], corners[:, :, 1], corners[:, :, 2]
        t, u, v, ok = _ray_triangles(pts[:, None, :], dirs[:, None, :], a, b, c)
        ok &= np.abs(t) <= max_distance
        if same_facing:
            ok &= np.einsum("pkj,pj->pk", self.normals[cand], dirs) > 0
        score = np.where(ok, np.abs(t), np.inf)
        j = score.argmin(axis=1)
        r = np.arange(len(pts))
        hit = np.isfinite(score[r, j])
        tt = np.where(hit, t[r, j], 0.0)
        pos = pts + tt[:, None] * dirs
        bary = np.column_stack([1 - u[r, j] - v[r, j], u[r, j], v[r, j]])
        tri = np.where(hit, cand[r, j], -1)
        return pos, tri, bary, hit


def _closest_on_triangles(p, a, b, c):
    """Closest points on triangles (Ericson, Real-Time Collision Detection §5.1.5), vectorised.

    p (..., 3) broadcast against a, b, c (..., 3). Returns (points, barycentric (..., 3))."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(-1), (ac * ap).sum(-1)
    bp = p - b
    d3, d4 = (ab * bp).sum(-1), (ac * bp).sum(-1)
    cp = p - c
    d5, d6 = (ab * cp).sum(-1), (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = np.where(np.abs(va + vb + vc) > 1e-300, va + vb + vc, 1e-300)
    v = vb / denom
    w = vc / denom
    bary = np.stack([1 - v - w, v, w], axis=-1)
    # Regions, from the last assigned to the first so the earliest test wins.
    e_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    w_bc = _safe_div(d4 - d3, (d4 - d3) + (d5 - d6))
    e_ca = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    w_ca = _safe_div(d2, d2 - d6)
    e_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    v_ab = _safe_div(d1, d1 - d3)
    in_c = (d6 >= 0) & (d5 <= d6)
    in_b = (d3 >= 0) & (d4 <= d3)
    in_a = (d1 <= 0) & (d2 <= 0)
    for mask, value in (
        (e_bc, np.stack([np.zeros_like(w_bc), 1 - w_bc, w_bc], -1)),
        (e_ca, np.stack([1 - w_ca, np.zeros_like(w_ca), w_ca], -1)),
        (e_ab, np.stack([1 - v_ab, v_ab, np.zeros_like(v_ab)], -1)),
        (in_c, np.broadcast_to([0.0, 0.0, 1.0], bary.shape)),
        (in_b, np.broadcast_to([0.0, 1.0, 0.0], bary.shape)),
        (in_a, np.broadcast_to([1.0, 0.0, 0.0], bary.shape)),
    ):
        bary = np.where(mask[..., None], value, bary)
    q = bary[..., :1] * a + bary[..., 1:2] * b + bary[..., 2:] * c
    return q, bary


def _safe_div(num, den):
    ok = np.abs(den) > 1e-300
    return np.where(ok, num / np.where(ok, den, 1.0), 0.0)


def _ray_triangles(o, d, a, b, c):
    """Möller-Trumbore for lines o + t d (either sign of t). Returns (t, u, v, valid)."""
    e1, e2 = b - a, c - a
    h = np.cross(np.broadcast_to(d, e2.shape), e2)
    det = (e1 * h).sum(-1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - a
    u = (s * h).sum(-1) * inv
    q = np.cross(s, e1)
    v = (np.broadcast_to(d, q.shape) * q).sum(-1) * inv
    t = (e2 * q).sum(-1) * inv
    eps = 1e-9
    ok &= (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps)
    return t, u, v, ok
