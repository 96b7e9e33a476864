"""Folded canonical triangles: how they are counted and how the registration removes them (issue 15).

A canonical triangle is *folded* when it has (almost) no area — below ``COLLAPSED_AREA_RATIO`` of
the median — or when it faces against the same triangle of a reference mesh: the template
registered on Mimica's default face, brought onto the scan's landmarks by a similarity (so a
scan that is merely turned or larger has no folds).

:func:`unfold` removes most of them from a mesh that has them (it builds the reference itself,
from the projection on the default face; registration no longer needs it: its fit starts from
the reference and never folds, ``core.registration.fold_free``): each round takes the
folded triangles' vertices and a few rings around them (growing each round), lets that patch
take the reference's local shape as-rigidly-as-possible (ARAP with a scale per vertex; the rest
of the mesh, the landmarks and the outline held), then puts each patch vertex back onto its
closest scan point unless that turns one of its triangles over again (then half the way, a
quarter, an eighth, or it stays where ARAP left it, a little off the scan — where the scan
itself folds, e.g. a nostril's rim or a lip corner's crease). A round is kept only when it leaves
fewer folds. Folds inside a template triangle whose landmarks are themselves turned over
(:func:`forced_folds`) cannot all go while the landmarks stay: they are reported, not hidden.
Without a reference shape (building the reference itself) the patches get a harmonic fill.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from core.surface_query import TriangleSet

#: A canonical triangle is taken as collapsed when its area is below this fraction of the median.
COLLAPSED_AREA_RATIO = 1e-3
#: Untangling rounds; the patch around the folds grows by one ring per round from FIRST_RINGS.
UNFOLD_ROUNDS = 12
FIRST_RINGS = 1
#: A vertex whose way back onto the surface refolds a triangle tries half the way, down to this.
MIN_REACH = 1 / 8
#: Local/global ARAP iterations per round.
ARAP_ITERATIONS = 6


def triangle_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(T, 3) unnormalised triangle normals (twice the area long)."""
    c = vertices[triangles]
    return np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])


def similarity(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(scale, rotation (3, 3), translation (3,)) taking points ``source`` (k, 3) onto ``target`` (Umeyama)."""
    ms, mt = source.mean(axis=0), target.mean(axis=0)
    a, b = source - ms, target - mt
    u, sigma, vt = np.linalg.svd(b.T @ a)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ d @ vt
    scale = float((sigma * np.diag(d)).sum() / max((a * a).sum(), 1e-12))
    return scale, rotation, mt - scale * ms @ rotation.T


def aligned_reference(reference: np.ndarray, vertices: np.ndarray, n_base: int) -> np.ndarray:
    """(N, 3) the reference mesh's vertices moved by the similarity that takes its first ``n_base``
    vertices (the landmarks) onto those of ``vertices``."""
    scale, rotation, shift = similarity(reference[:n_base], vertices[:n_base])
    return scale * reference @ rotation.T + shift


def folded_triangles(vertices: np.ndarray, triangles: np.ndarray, reference_normals: np.ndarray) -> np.ndarray:
    """(T,) bool: collapsed triangles and triangles facing against ``reference_normals`` (T, 3), the
    way each triangle faces on a face (e.g. :func:`triangle_normals` of an aligned reference)."""
    normals = triangle_normals(vertices, triangles)
    area = np.linalg.norm(normals, axis=1)
    collapsed = area < COLLAPSED_AREA_RATIO * np.median(area)
    return collapsed | (np.einsum("kd,kd->k", normals, reference_normals) < 0)


def _edges(triangles: np.ndarray) -> np.ndarray:
    """(E, 2) unique undirected edges."""
    from core.subdivision import unique_edges

    return unique_edges(triangles)[0]


def _grow(mask: np.ndarray, adjacency: scipy.sparse.csr_matrix, rings: int) -> np.ndarray:
    for _ in range(rings):
        mask = mask | (adjacency @ mask.astype(float) > 0)
    return mask


def arap_patch(x: np.ndarray, reference: np.ndarray | None, edges: np.ndarray, free: np.ndarray,
               iterations: int = ARAP_ITERATIONS) -> np.ndarray:
    """(N, 3): ``x`` with the vertices ``free`` (bool (N,)) moved so every edge touching them keeps
    the reference's edge as well as it can after a rotation and a scale per vertex (as-rigid-as-
    possible with a local scale, uniform weights); the other vertices stay. Starts from the
    reference's shape on the patch (aligned by the similarity of the held ring), so a turned-over
    start cannot stay turned.
    Without a reference the patch is relaxed to the harmonic (uniform Laplacian) fill of its
    held ring: a membrane, fold-free over a patch whose rim is roughly convex (Tutte)."""
    x = np.array(x, float)
    touching = free[edges[:, 0]] | free[edges[:, 1]]
    e = edges[touching]
    i, j = e[:, 0], e[:, 1]
    n = len(x)
    adjacency = scipy.sparse.csr_matrix((np.ones(2 * len(e)), (np.r_[i, j], np.r_[j, i])), shape=(n, n))
    laplacian = (scipy.sparse.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()
    ids = np.nonzero(free)[0]
    ring = np.unique(np.r_[i, j])
    held = ring[~free[ring]]
    solve = scipy.sparse.linalg.factorized(laplacian[ids][:, ids].tocsc())
    coupling = laplacian[ids][:, ~free]
    if reference is None:
        b = -(coupling @ x[~free])
        x[ids] = np.column_stack([solve(b[:, k]) for k in range(3)])
        return x
    if len(held) >= 3:
        s, r, t = similarity(reference[held], x[held])
        x[ids] = s * reference[ids] @ r.T + t
    d_ref = reference[i] - reference[j]
    length2 = np.zeros(n)
    np.add.at(length2, i, (d_ref * d_ref).sum(axis=1))
    np.add.at(length2, j, (d_ref * d_ref).sum(axis=1))
    for _ in range(iterations):
        d_cur = x[i] - x[j]
        cov = np.zeros((n, 3, 3))
        outer = d_ref[:, :, None] * d_cur[:, None, :]
        np.add.at(cov, i, outer)
        np.add.at(cov, j, outer)
        u, sigma, vt = np.linalg.svd(cov[ring])
        flip = np.linalg.det(u @ vt) < 0
        u[flip, :, 2] *= -1
        sigma[flip, 2] *= -1
        # A rotation and a scale per vertex (as-similar-as-possible): a patch that is smaller on
        # the scan than on the reference (a nostril, a raised lip corner) shrinks instead of buckling.
        scale = np.clip(sigma.sum(axis=1) / np.maximum(length2[ring], 1e-12), 0.2, 5.0)
        rot = np.tile(np.eye(3), (n, 1, 1))
        rot[ring] = np.transpose(u @ vt, (0, 2, 1)) * scale[:, None, None]   # s_i R_i: reference edge -> current
        rotated = 0.5 * np.einsum("kab,kb->ka", rot[i] + rot[j], d_ref)
        rhs = np.zeros((n, 3))
        np.add.at(rhs, i, rotated)
        np.add.at(rhs, j, -rotated)
        b = rhs[ids] - coupling @ x[~free]
        x[ids] = np.column_stack([solve(b[:, k]) for k in range(3)])
    return x


def unfold(x: np.ndarray, triangles: np.ndarray, shape: np.ndarray | None, reference_normals: np.ndarray,
           held: np.ndarray, surface: TriangleSet) -> tuple[np.ndarray, np.ndarray, int, int]:
    """(vertices, on_surface, folded before, folded after): removes folded triangles (see the module).

    x : (N, 3) canonical vertices; shape : (N, 3) aligned fold-free reference whose local shape the
    patches take (:func:`aligned_reference`), or None for a harmonic fill; reference_normals :
    (T, 3) how each triangle faces (:func:`folded_triangles`); held : (N,) bool vertices that never
    move (the landmarks, the outline); surface : the surface to go back onto (the scan).
    on_surface : (N,) bool, False for the vertices left off the surface to keep their triangles unfolded.
    A round is kept only when it leaves fewer folds; rounds stop after two without progress.
    """
    x = np.array(x, float)
    on_surface = np.ones(len(x), bool)
    bad = folded_triangles(x, triangles, reference_normals)
    before = int(bad.sum())
    if not before:
        return x, on_surface, 0, 0
    edges = _edges(triangles)
    n = len(x)
    adjacency = scipy.sparse.csr_matrix((np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]],
                                                                    np.r_[edges[:, 1], edges[:, 0]])), shape=(n, n))
    stalled = 0
    for round_ in range(UNFOLD_ROUNDS):
        seed = np.zeros(n, bool)
        seed[triangles[bad].ravel()] = True
        free = _grow(seed, adjacency, FIRST_RINGS + round_) & ~held
        if not free.any():
            break
        relaxed = arap_patch(x, shape, edges, free)
        # Back onto the surface where that keeps every triangle the right way round.
        ids = np.nonzero(free)[0]
        snapped, _, _ = surface.closest(relaxed[ids], k=12, widen=False)
        step = snapped - relaxed[ids]
        reach = np.ones(len(ids))        # how far along the way to the surface each vertex goes
        trial = relaxed.copy()
        while True:      # each pass halves the reach of at least one vertex: ends within ~5 len(ids) passes
            trial[ids] = relaxed[ids] + reach[:, None] * step
            touching = np.zeros(n, bool)
            touching[triangles[folded_triangles(trial, triangles, reference_normals)].ravel()] = True
            undo = touching[ids] & (reach > 0)
            if not undo.any():
                break
            # Halfway first: a vertex off a crease of the scan stays as near it as the fold allows.
            reach[undo] = np.where(reach[undo] > MIN_REACH, reach[undo] / 2, 0.0)
        now = folded_triangles(trial, triangles, reference_normals)
        if now.sum() >= bad.sum():
            stalled += 1
            if stalled == 2:
                break
            continue            # the next round tries a wider patch
        stalled = 0
        on_surface[ids] = reach == 1.0
        x, bad = trial, now
        if not bad.any():
            break
    return x, on_surface, before, int(bad.sum())


def forced_folds(vertices: np.ndarray, reference: np.ndarray, base_triangles: np.ndarray,
                 n_triangles: int) -> np.ndarray:
    """(T,) bool: canonical triangles inside a template base triangle whose three landmarks
    (``vertices[:n_base]``) are turned over relative to ``reference`` (aligned): with the landmarks
    held, part of such a triangle must fold. (Canonical triangle k lies in base triangle
    k mod len(base_triangles): each subdivision step numbers the children corner by corner.)"""
    n_base = int(base_triangles.max()) + 1
    turned = np.einsum("kd,kd->k", triangle_normals(vertices[:n_base], base_triangles),
                       triangle_normals(reference[:n_base], base_triangles)) < 0
    return turned[np.arange(n_triangles) % len(base_triangles)]
