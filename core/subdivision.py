"""1-to-4 triangle subdivision: linear (midpoints) and Loop, with boundary and crease rules.

Used to densify a landmark triangulation placed on a face (thesis A §3.4 and §5): each step
splits every triangle into four through its edge midpoints; the caller then projects the new
vertices onto the face. Vertex counts grow as V' = V + E, triangles as F' = 4F.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse


@dataclass(frozen=True)
class Subdivided:
    """Result of one step. New vertex ``n_old + k`` is the midpoint of ``edges[k]`` (old indices)."""

    vertices: np.ndarray   # (n_old + n_edges, 3)
    triangles: np.ndarray  # (4 m, 3)
    edges: np.ndarray      # (n_edges, 2) old vertex indices, sorted per row
    params: np.ndarray | None  # (n_old + n_edges, p): per-vertex attributes carried linearly (midpoints)
    creases: np.ndarray    # (k, 2) crease edges of the new mesh (the halves of the old creases)


def unique_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(edges (E, 2) sorted rows, tri_edge (m, 3) edge index of edges ab, bc, ca of each triangle)."""
    t = np.asarray(triangles, dtype=np.int64)
    half = np.sort(np.stack([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]], axis=1).reshape(-1, 2), axis=1)
    # One integer per edge (rows in the same order as np.unique(axis=0) gives, ~10x faster: that
    # one sorts the rows as opaque byte strings).
    n = int(t.max()) + 1 if t.size else 1
    keys, inverse = np.unique(half[:, 0] * n + half[:, 1], return_inverse=True)
    edges = np.column_stack([keys // n, keys % n])
    return edges, inverse.reshape(-1, 3)


def boundary_edges(triangles: np.ndarray) -> np.ndarray:
    """(k, 2) edges used by exactly one triangle."""
    edges, tri_edge = unique_edges(triangles)
    count = np.bincount(tri_edge.ravel(), minlength=len(edges))
    return edges[count == 1]


def subdivide(vertices, triangles, *, scheme: str = "linear", creases=None, params=None) -> Subdivided:
    """One 1-to-4 step.

    vertices : (n, 3); triangles : (m, 3); scheme : "linear" or "loop".
    creases : (k, 2) vertex pairs treated like boundary edges by Loop (kept sharp); the mesh
        boundary is always a crease.
    params : (n, p) optional per-vertex attributes interpolated linearly at midpoints (e.g. the
        position in the base mesh, texture coordinates), whatever the scheme.
    """
    if scheme not in ("linear", "loop"):
        raise ValueError(f"scheme must be 'linear' or 'loop', got {scheme!r}")
    v = np.asarray(vertices, dtype=float)
    t = np.asarray(triangles, dtype=np.int64)
    n = len(v)
    edges, tri_edge = unique_edges(t)
    n_edges = len(edges)

    crease_mask = np.bincount(tri_edge.ravel(), minlength=n_edges) == 1
    if creases is not None and len(creases):
        c = np.sort(np.asarray(creases, dtype=np.int64), axis=1)
        lookup = {tuple(e): i for i, e in enumerate(map(tuple, edges))}
        idx = [lookup[tuple(e)] for e in map(tuple, c) if tuple(e) in lookup]
        crease_mask[idx] = True

    mid = (v[edges[:, 0]] + v[edges[:, 1]]) / 2
    if scheme == "linear":
        odd, even = mid, v
    else:
        odd, even = _loop_positions(v, t, edges, tri_edge, crease_mask, mid)

    m = n + tri_edge  # new vertex index of each triangle edge: ab, bc, ca
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    ab, bc, ca = m[:, 0], m[:, 1], m[:, 2]
    new_tris = np.concatenate([
        np.column_stack([a, ab, ca]), np.column_stack([b, bc, ab]),
        np.column_stack([c, ca, bc]), np.column_stack([ab, bc, ca]),
    ])
    new_params = None
    if params is not None:
        p = np.asarray(params, dtype=float)
        new_params = np.concatenate([p, (p[edges[:, 0]] + p[edges[:, 1]]) / 2])
    ce = np.nonzero(crease_mask)[0]
    new_creases = np.concatenate([np.column_stack([edges[ce, 0], n + ce]), np.column_stack([n + ce, edges[ce, 1]])])
    return Subdivided(np.concatenate([even, odd]), new_tris, edges, new_params, new_creases)


def _loop_positions(v, t, edges, tri_edge, crease_mask, mid):
    """Loop's masks: odd = 3/8 (a + b) + 1/8 (c + d), even = (1 - k beta) v + beta sum(neighbours);
    on creases and boundaries odd = midpoint, even = 3/4 v + 1/8 (two crease neighbours); crease
    corners (other than 2 crease edges) stay fixed."""
    n, n_edges = len(v), len(edges)
    # Opposite vertex of each triangle edge.
    opposite = np.stack([t[:, 2], t[:, 0], t[:, 1]], axis=1)
    opp_sum = np.zeros((n_edges, 3))
    np.add.at(opp_sum, tri_edge.ravel(), v[opposite.ravel()])
    odd = np.where(crease_mask[:, None], mid, 0.375 * (v[edges[:, 0]] + v[edges[:, 1]]) + 0.125 * opp_sum)

    adj = scipy.sparse.coo_matrix((np.ones(2 * n_edges), (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])),
                                  shape=(n, n)).tocsr()
    valence = np.asarray(adj.sum(axis=1)).ravel()
    nbr_sum = adj @ v
    k = np.maximum(valence, 1)
    beta = (0.625 - (0.375 + 0.25 * np.cos(2 * np.pi / k)) ** 2) / k
    even = (1 - k * beta)[:, None] * v + beta[:, None] * nbr_sum

    ce = edges[crease_mask]
    cadj = scipy.sparse.coo_matrix((np.ones(2 * len(ce)), (np.r_[ce[:, 0], ce[:, 1]], np.r_[ce[:, 1], ce[:, 0]])),
                                   shape=(n, n)).tocsr()
    cval = np.asarray(cadj.sum(axis=1)).ravel()
    csum = cadj @ v
    even = np.where((cval == 2)[:, None], 0.75 * v + 0.125 * csum, even)
    even = np.where(((cval == 1) | (cval > 2))[:, None], v, even)
    return odd, even
