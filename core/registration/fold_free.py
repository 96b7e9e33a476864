"""A non-rigid fit of the canonical mesh onto a scan that never folds a triangle (issue 15).

The fit starts from a fold-free mesh (the template registered on Mimica's default face, brought
onto the scan's landmarks by a similarity: :func:`core.registration.folds.aligned_reference`) and
moves it onto the scan by as-similar-as-possible steps (ARAP with a rotation and a scale per
vertex, Sorkine & Alexa 2007, the reference's edges as rest shape) pulled by a data term: the
landmarks (soft, strong weight), the outline and the projection's points first, then each
vertex's closest scan point with robust weights (a non-rigid ICP in the manner of Amberg et al.
2007, stiff to supple).

Every step is *blocked*: the solver's proposal is taken per vertex, and a vertex whose move
would turn a triangle over or squash it (its area along the reference triangle's normal below
``MARGIN`` of the reference's area, or below what it already was) goes half the way, a quarter
..., or stays. Since the start has no folded triangle and no step makes one, the result has none;
where the landmarks or the scan itself would force a fold (a landmark across its neighbours, a
crease of the scan) the mesh stays a little short of them, and the landmarks' shift is reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from core.face import vertex_normals
from core.registration.folds import triangle_normals
from core.subdivision import unique_edges
from core.surface_query import TriangleSet

#: ARAP weight per stage (an edge's mismatch in mm against a vertex's distance to its target),
#: stiff first (the start may be centimetres from the scan) to supple (close to the scan).
STIFFNESS = (20.0, 6.0, 2.0, 0.7)
#: Local/global iterations per stage; closest points are updated after each.
ITERATIONS = 3
#: First-stage iterations, over which the targets move from the start to where they are (a large
#: move in one linear solve turns triangles over before the rotations catch up).
HOMOTOPY_STEPS = 8
#: Stages whose free vertices aim at ``first`` (the projection's points); later ones at closest points.
FIRST_STAGES = 2
#: Weight of a landmark's (and of the held outline's) target against a vertex's closest point.
LANDMARK_WEIGHT = 100.0
#: A triangle's area along its reference normal stays at least this fraction of its reference area.
MARGIN = 0.02
#: A blocked vertex tries half the way, a quarter ..., down to this fraction, then stays.
MIN_REACH = 1 / 16
#: ... and so do the vertices this many rings around it (a smooth brake, not a jam of torn neighbours).
BLOCK_RINGS = 2
#: A braking triangle's edges weigh this much more in the next steps, up to MAX_STIFFEN.
STIFFEN = 4.0
MAX_STIFFEN = 256.0
#: Robust data weights: Cauchy in the gap to the closest point (mm); a closest point whose surface
#: faces another way (cosine below MIN_FACING) is no correspondence.
ROBUST_GAP_MM = 1.0
MIN_FACING = 0.5


@dataclass
class FitResult:
    """vertices (N, 3) mm; blocked: vertices some step held back (N,) bool; landmark_shift (k,) mm:
    how far each target-held vertex (landmarks, outline) ended from its target."""

    vertices: np.ndarray
    blocked: np.ndarray
    landmark_shift: np.ndarray


def along_reference(x: np.ndarray, triangles: np.ndarray, reference_unit: np.ndarray) -> np.ndarray:
    """(T,) twice each triangle's area along its reference normal (negative: turned over)."""
    return np.einsum("kd,kd->k", triangle_normals(x, triangles), reference_unit)


def blocked_step(x: np.ndarray, proposal: np.ndarray, triangles: np.ndarray, reference_unit: np.ndarray,
                 floor: np.ndarray, adjacency: scipy.sparse.csr_matrix | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, reach (N,), braked (T,) bool: triangles that held a vertex back): as much of the move from ``x`` to ``proposal`` as keeps every triangle's
    area along its reference normal at least min(``floor``, what it is in ``x``).

    First the whole move, or half of it, a quarter ... (a uniform step keeps neighbours together);
    then from there each vertex goes ``reach`` of the rest of its way, and the vertices of a
    triangle that would drop below the limit go half as far, down to ``MIN_REACH``, then not at all.
    With every reach at 0 the result is the uniform step's, so this ends and never makes a triangle
    worse than the limit (each pass halves at least one reach: a few passes in practice)."""
    limit = np.minimum(floor, along_reference(x, triangles, reference_unit))
    step = proposal - x
    braked = along_reference(proposal, triangles, reference_unit) < limit
    fraction = 1.0
    while fraction >= MIN_REACH and (along_reference(x + fraction * step, triangles, reference_unit) < limit).any():
        fraction /= 2
    if fraction < MIN_REACH:
        fraction = 0.0
    start = x + fraction * step
    step = proposal - start
    reach = np.ones(len(x))
    while True:
        trial = start + reach[:, None] * step
        bad = along_reference(trial, triangles, reference_unit) < limit
        if not bad.any():
            return trial, fraction + (1.0 - fraction) * reach, braked
        braked |= bad
        ids = np.unique(triangles[bad])
        if adjacency is not None:     # their rings too: neighbours held back alike keep their triangles whole
            grown = np.zeros(len(x), bool)
            grown[ids] = True
            for _ in range(BLOCK_RINGS):
                grown |= adjacency @ grown.astype(float) > 0
            ids = np.nonzero(grown)[0]
        ids = ids[reach[ids] > 0]
        if not len(ids):          # only rounding left (reach 0 everywhere around): keep the start there
            return trial, fraction + (1.0 - fraction) * reach, braked
        reach[ids] = np.where(reach[ids] > MIN_REACH, reach[ids] / 2, 0.0)


def _laplacian(edges: np.ndarray, n: int, weight: np.ndarray) -> scipy.sparse.csr_matrix:
    i, j = edges[:, 0], edges[:, 1]
    adjacency = scipy.sparse.csr_matrix((np.r_[weight, weight], (np.r_[i, j], np.r_[j, i])), shape=(n, n))
    return (scipy.sparse.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()


def _rest_edges(x: np.ndarray, reference: np.ndarray, edges: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(n, 3) ARAP right-hand side: each edge of the reference turned and scaled by its two
    vertices' best similarity onto the current mesh ``x`` (summed per vertex, signed)."""
    n = len(x)
    i, j = edges[:, 0], edges[:, 1]
    d_ref = reference[i] - reference[j]
    d_cur = x[i] - x[j]
    cov = np.zeros((n, 3, 3))
    outer = weight[:, None, None] * d_ref[:, :, None] * d_cur[:, None, :]
    length2 = np.zeros(n)
    np.add.at(length2, i, weight * (d_ref * d_ref).sum(axis=1))
    np.add.at(length2, j, weight * (d_ref * d_ref).sum(axis=1))
    np.add.at(cov, i, outer)
    np.add.at(cov, j, outer)
    u, sigma, vt = np.linalg.svd(cov)
    flip = np.linalg.det(u @ vt) < 0
    u[flip, :, 2] *= -1
    sigma[flip, 2] *= -1
    # A scale per vertex (as-similar-as-possible): a nose or a chin smaller than the reference's
    # shrinks instead of buckling.
    scale = np.clip(sigma.sum(axis=1) / np.maximum(length2, 1e-12), 0.2, 5.0)
    rot = np.transpose(u @ vt, (0, 2, 1)) * scale[:, None, None]
    rotated = 0.5 * weight[:, None] * np.einsum("kab,kb->ka", rot[i] + rot[j], d_ref)
    rhs = np.zeros((n, 3))
    np.add.at(rhs, i, rotated)
    np.add.at(rhs, j, -rotated)
    return rhs


def fold_free_fit(reference: np.ndarray, triangles: np.ndarray, targets: dict[int, np.ndarray],
                  first: np.ndarray, surface: TriangleSet, surface_normals: np.ndarray,
                  free_ok: np.ndarray | None = None, target_weight: dict[int, float] | None = None) -> FitResult:
    """Fit the mesh (``reference`` (N, 3), aligned and fold-free, ``triangles`` (T, 3)) onto a surface.

    targets : {vertex: (3,) mm} held softly with ``LANDMARK_WEIGHT`` (landmarks, outline).
    first : (N, 3) the other vertices' targets in the first stage (the projection's points).
    surface, surface_normals : the scan (closest points) and its unit triangle normals (T_scan, 3).
    free_ok : (N,) bool vertices whose first targets count (e.g. not the projection's fallbacks);
    all by default; target_weight : {vertex: weight} for targets held more softly than landmarks.
    Returns a :class:`FitResult`; no triangle of ``vertices`` faces against its
    reference triangle or has less than ``MARGIN`` of its area along that normal (unless the
    reference itself had, then no less than there).
    """
    x = np.array(reference, float)
    n = len(x)
    edges, triangle_edges = unique_edges(triangles)
    edge_weight = np.ones(len(edges))
    adjacency = (_laplacian(edges, n, edge_weight) != 0).astype(float).tocsr()
    ref_normals = triangle_normals(reference, triangles)
    ref_area = np.linalg.norm(ref_normals, axis=1)
    unit = ref_normals / np.maximum(ref_area, 1e-300)[:, None]
    floor = MARGIN * ref_area

    held = np.fromiter(targets, np.int64, len(targets))
    held_at = np.array([targets[i] for i in held.tolist()]).reshape(-1, 3)
    is_held = np.zeros(n, bool)
    is_held[held] = True
    goal = np.array(first, float)
    weight = np.ones(n) if free_ok is None else free_ok.astype(float)
    goal[held], weight[held] = held_at, LANDMARK_WEIGHT
    for i, w in (target_weight or {}).items():
        weight[i] = w
    free = np.nonzero(~is_held)[0]
    blocked = np.zeros(n, bool)
    full_goal = goal.copy()
    for stage, stiffness in enumerate(STIFFNESS):
        for step in range(HOMOTOPY_STEPS if stage == 0 else ITERATIONS):
            if stage == 0:     # the targets come in gradually: small steps, whose rotations keep up
                goal = reference + (step + 1) / HOMOTOPY_STEPS * (full_goal - reference)
            system = (scipy.sparse.diags(weight) + stiffness * _laplacian(edges, n, edge_weight)).tocsc()
            solve = scipy.sparse.linalg.factorized(system)
            rhs = weight[:, None] * goal + stiffness * _rest_edges(x, reference, edges, edge_weight)
            proposal = np.column_stack([solve(rhs[:, k]) for k in range(3)])
            x, reach, braked = blocked_step(x, proposal, triangles, unit, floor, adjacency)
            blocked |= reach < 1
            # Stiffer where a triangle braked: the next proposal keeps its shape and moves its
            # neighbours out of the way instead of pushing it over again.
            edge_weight[np.unique(triangle_edges[braked])] *= STIFFEN
            np.minimum(edge_weight, MAX_STIFFEN, out=edge_weight)
            if stage + 1 < FIRST_STAGES:
                continue
            # Closest points for the next iteration; robust weights (a vertex beyond the scan's
            # border or over a hole follows its neighbours; the far side of a lip is no match).
            closest, tri, _ = surface.closest(x[free], k=12, widen=False)
            gap = np.linalg.norm(closest - x[free], axis=1)
            facing = np.einsum("kd,kd->k", surface_normals[tri], vertex_normals(x, triangles)[free])
            goal[free] = closest
            weight[free] = (facing > MIN_FACING) / (1.0 + (gap / ROBUST_GAP_MM) ** 2)
    # Last: onto the targets exactly (landmarks, outline, closest points) as far as no triangle folds.
    proposal = x.copy()
    proposal[held] = held_at
    goal = goal if FIRST_STAGES < len(STIFFNESS) else full_goal
    near = weight[free] > 0
    proposal[free[near]] = goal[free[near]]
    x, reach, _ = blocked_step(x, proposal, triangles, unit, floor, adjacency)
    blocked |= reach < 1
    return FitResult(x, blocked, np.linalg.norm(x[held] - held_at, axis=1))
