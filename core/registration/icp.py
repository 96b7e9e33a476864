"""Rigid ICP (Besl & McKay 1992) for aligning an input scan to the model (thesis A §3.2, first step).

Choices the thesis leaves open (it only says "ICP, initialised with a rough R and t"):

- **Error metric.** Point-to-plane (Chen & Medioni 1992) by default: a Face target gives its vertex
  normals, a bare point target gets normals from a PCA of its 12 nearest neighbours. Besl-McKay
  point-to-point (closed-form Kabsch/SVD step) is available as ``method="point"`` but slides very
  slowly along a face: on the 30 %-cropped default face with a 10 deg / 15 mm offset it had not
  converged after 300 iterations (4-19 mm residual), where point-to-plane converges exactly in ~28.
- **Correspondences.** Nearest target vertex through a KD-tree (target built once). Pairs are then
  rejected (a) when the target vertex lies on the target's mesh boundary (Turk & Levoy 1994: at
  partial overlap such pairs pull the scans toward each other's rims), (b) beyond
  ``reject_k`` x the median pair distance and (c) the worst ``trim_fraction`` of what is left
  (trimmed ICP, Chetverikov 2002). Together they make the fit robust to partial overlap (a cropped
  scan, a different hair line) and to outliers.
- **Speed.** A fixed random subsample of ``sample`` source points (the same points each iteration,
  so the iteration reaches an exact fixed point); the full 50k-point cost is ~65 ms per iteration
  (research/perf.md), a 5k sample ~9 ms.
- **Initial alignment.** ``initial`` if given; otherwise the source centroid is moved onto the
  target centroid (``init="centroid"``), or with ``init="pca"`` the principal axes are matched
  too: each of the four proper sign flips gets 10 iterations and the best (RMS / inlier fraction)
  continues. PCA is for scans in an arbitrary orientation; under heavy cropping the principal axes
  of the two clouds differ and it can pick a wrong flip, so faces already roughly facing +z should
  use "centroid".
- **Stopping.** After ``max_iterations``, or when one iteration moves every sample point by less
  than ``tolerance`` mm + 0.1 % of the current RMS (so exact data converge exactly and noisy data
  stop once the steps are far below the noise), or when the trimmed RMS changes by less than
  ``tolerance`` x RMS.

All positions are millimetres; transforms are (4, 4) homogeneous matrices acting on column
vectors (x' = R x + t).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


class IcpError(ValueError):
    """Bad input to :func:`icp` (shapes, too few points, bad initial transform)."""


@dataclass(frozen=True)
class IcpResult:
    """Result of :func:`icp`.

    Attributes
    ----------
    transform : (4, 4) float
        Maps source points onto the target: ``apply_transform(source, transform)``.
    rms_mm : float
        Root-mean-square distance of the kept (inlier) pairs in the last iteration, mm. With a
        Face target and point-to-plane this is still the point-to-point (nearest vertex) distance.
    iterations : int
        Iterations run.
    inlier_fraction : float
        Fraction of the sampled source points kept as pairs in the last iteration.
    converged : bool
        False when ``max_iterations`` was reached before the tolerance.
    """

    transform: np.ndarray
    rms_mm: float
    iterations: int
    inlier_fraction: float
    converged: bool = True


def apply_transform(points, transform) -> np.ndarray:
    """(n, 3) points mapped by a (4, 4) transform: R @ p + t. Returns a new float array."""
    p = np.asarray(points, dtype=np.float64)
    T = _check_transform(transform, "transform")
    if p.ndim != 2 or p.shape[1] != 3:
        raise IcpError(f"points must have shape (n, 3), got {p.shape}")
    return p @ T[:3, :3].T + T[:3, 3]


def rigid_transform(rotation=None, translation=None) -> np.ndarray:
    """(4, 4) transform from a (3, 3) rotation and a (3,) translation (identity parts by default)."""
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = rotation
    if translation is not None:
        T[:3, 3] = translation
    return T


def rotation_about_axis(axis, angle_deg: float) -> np.ndarray:
    """(3, 3) rotation by ``angle_deg`` degrees about ``axis`` (3,) (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    norm = np.linalg.norm(a)
    if norm == 0:
        raise IcpError("rotation axis must be non-zero")
    a = a / norm
    th = np.radians(angle_deg)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def icp(source_points, target, *, initial=None, max_iterations: int = 50, tolerance: float = 1e-6,
        trim_fraction: float = 0.2, sample: int = 5000, rng=None, method: str = "auto",
        init: str = "centroid", reject_k: float = 3.0, reject_boundary: bool = True) -> IcpResult:
    """Rigidly align ``source_points`` to ``target``.

    Parameters
    ----------
    source_points : (n, 3) float, mm
        Points to move (e.g. the input scan's vertices).
    target : Face or (m, 3) float, mm
        What to align to (e.g. the model face). A Face enables point-to-plane and boundary rejection.
    initial : (4, 4) float, optional
        Starting transform; replaces the ``init`` guess.
    max_iterations : int
    tolerance : float
        mm; see the module docstring for the stopping rule.
    trim_fraction : float in [0, 0.9]
        Fraction of the worst remaining pairs dropped each iteration.
    sample : int
        Number of source points used (all when ``n <= sample``); ``0`` means all.
    rng : numpy Generator or int, optional
        For the subsample (default: a fixed seed, so results are reproducible).
    method : "auto" | "point" | "plane"
        "auto" = "plane" (point-to-plane; normals estimated for a bare point target).
    init : "centroid" | "pca" | "none"
        Initial guess when ``initial`` is None.
    reject_k : float
        Pairs farther than ``reject_k`` x the median distance are rejected (``inf`` disables).
    reject_boundary : bool
        Reject pairs whose target vertex is on the target mesh boundary (Face targets only).

    Returns
    -------
    IcpResult
    """
    src = np.asarray(source_points, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3:
        raise IcpError(f"source_points must have shape (n, 3), got {src.shape}")
    if not np.all(np.isfinite(src)):
        raise IcpError("source_points contain NaN or inf; drop invalid samples first")
    tgt_pts, tgt_normals, boundary, tree = _target_arrays(target, reject_boundary)
    if len(src) < 3 or len(tgt_pts) < 3:
        raise IcpError(f"ICP needs at least 3 source and 3 target points, got {len(src)} and {len(tgt_pts)}")
    if not 0.0 <= trim_fraction <= 0.9:
        raise IcpError(f"trim_fraction must be in [0, 0.9], got {trim_fraction}")
    if max_iterations < 1:
        raise IcpError(f"max_iterations must be >= 1, got {max_iterations}")
    if method not in ("auto", "point", "plane"):
        raise IcpError(f"method must be 'auto', 'point' or 'plane', got {method!r}")
    use_plane = method in ("auto", "plane")
    if use_plane and tgt_normals is None:
        tgt_normals = estimate_normals(tgt_pts, tree)

    rng = np.random.default_rng(0 if rng is None else rng)
    if sample and len(src) > sample:
        src_s = src[np.sort(rng.choice(len(src), size=int(sample), replace=False))]
    else:
        src_s = src

    if initial is not None:
        starts = [_check_transform(initial, "initial").copy()]
    elif init == "centroid":
        starts = [rigid_transform(translation=tgt_pts.mean(axis=0) - src.mean(axis=0))]
    elif init == "pca":
        starts = _pca_candidates(src_s, tgt_pts)
    elif init == "none":
        starts = [np.eye(4)]
    else:
        raise IcpError(f"init must be 'centroid', 'pca' or 'none', got {init!r}")

    args = (src_s, tgt_pts, tgt_normals if use_plane else None, boundary, tree, reject_k, trim_fraction,
            tolerance)
    if len(starts) > 1:
        # Several guesses (PCA sign flips): a few iterations each, then continue from the best.
        trials = [_iterate(T0, min(10, max_iterations), *args) for T0 in starts]
        best = min(trials, key=lambda r: r.rms_mm / max(r.inlier_fraction, 1e-9))
        rest = max_iterations - best.iterations
        if best.converged or rest <= 0:
            return best
        more = _iterate(best.transform, rest, *args)
        return IcpResult(more.transform, more.rms_mm, best.iterations + more.iterations,
                         more.inlier_fraction, more.converged)
    return _iterate(starts[0], max_iterations, *args)


def _iterate(T, max_iterations, src_s, tgt_pts, tgt_normals, boundary, tree, reject_k, trim_fraction,
             tolerance) -> IcpResult:
    """The ICP loop from transform T; point-to-plane when ``tgt_normals`` is given."""
    prev_rms = np.inf
    rms, inlier_fraction, converged = np.inf, 0.0, False
    iteration = 0
    bound = np.inf
    for iteration in range(1, max_iterations + 1):
        moved = apply_transform(src_s, T)
        keep, idx, dist = _pairs(moved, tree, boundary, reject_k, trim_fraction, bound)
        if keep.sum() < 6:
            raise IcpError(
                f"ICP lost overlap: only {int(keep.sum())} pairs left after rejection at iteration {iteration}; "
                "give a better initial transform or lower trim_fraction/reject_k")
        p, q = moved[keep], tgt_pts[idx[keep]]
        rms = float(np.sqrt(np.mean(dist[keep] ** 2)))
        inlier_fraction = float(keep.mean())
        if np.isfinite(reject_k):
            bound = 2.0 * reject_k * max(float(np.median(dist)), 1e-6)  # inf when most are unbound
        step = _plane_step(p, q, tgt_normals[idx[keep]]) if tgt_normals is not None else _kabsch(p, q)
        T = step @ T
        # Largest motion of a sample point caused by this increment (rotation about the centroid
        # bounded by angle x radius, plus the centroid's own motion).
        c = p.mean(axis=0)
        radius = float(np.max(np.linalg.norm(p - c, axis=1)))
        motion = _rotation_angle(step[:3, :3]) * radius + float(np.linalg.norm(apply_transform(c[None], step)[0] - c))
        # Also stop once an increment moves points by < 0.1 % of the residual: on noisy scans the
        # trimmed set keeps flickering and the exact fixed point is never reached.
        if motion < tolerance + 1e-3 * rms or abs(prev_rms - rms) <= tolerance * max(rms, 1e-12):
            converged = True
            break
        prev_rms = rms
    return IcpResult(transform=T, rms_mm=rms, iterations=iteration,
                     inlier_fraction=inlier_fraction, converged=converged)


# ---------------------------------------------------------------- internals
def _check_transform(T, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise IcpError(f"{name} must be a finite (4, 4) matrix, got shape {T.shape}")
    return T


def _target_arrays(target, reject_boundary: bool):
    """(points, normals or None, boundary mask or None, KD-tree) of the target."""
    from core.face import Face

    if isinstance(target, Face):
        pts = target.vertices
        used = np.zeros(target.n_vertices, bool)
        used[target.triangles.ravel()] = True
        normals = target.vertex_normals
        boundary = boundary_vertex_mask(target.triangles, target.n_vertices) if reject_boundary else None
        if not used.all():
            # Unreferenced vertices have no normal and no surface: leave them out.
            keep = np.nonzero(used)[0]
            pts, normals = pts[keep], normals[keep]
            boundary = boundary[keep] if boundary is not None else None
        return pts, normals, boundary, cKDTree(pts)
    pts = np.asarray(target, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise IcpError(f"target must be a Face or an (m, 3) array, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise IcpError("target points contain NaN or inf")
    return pts, None, None, cKDTree(pts)


def estimate_normals(points, tree=None, k: int = 12) -> np.ndarray:
    """(m, 3) unit normals of a point cloud (smallest principal axis of the k nearest neighbours;
    the sign is arbitrary, which point-to-plane ICP does not mind)."""
    pts = np.asarray(points, dtype=np.float64)
    tree = tree if tree is not None else cKDTree(pts)
    k = int(min(k, len(pts)))
    _, idx = tree.query(pts, k=k)
    nb = pts[idx.reshape(len(pts), k)]
    nb = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    return vecs[:, :, 0]


def boundary_vertex_mask(triangles, n_vertices: int) -> np.ndarray:
    """(n,) bool: vertices on an edge used by exactly one triangle."""
    t = np.asarray(triangles, dtype=np.int64)
    pairs = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    key = pairs[:, 0] * np.int64(n_vertices) + pairs[:, 1]
    uniq, counts = np.unique(key, return_counts=True)
    once = uniq[counts == 1]
    mask = np.zeros(n_vertices, bool)
    mask[once // n_vertices] = True
    mask[once % n_vertices] = True
    return mask


def _pairs(moved, tree, boundary, reject_k, trim_fraction, bound=np.inf):
    # A distance bound (from the previous iteration's rejection radius) keeps far outliers from
    # making the KD-tree search them exhaustively (8x faster with 10 % junk points).
    dist, idx = tree.query(moved, k=1, distance_upper_bound=bound)
    found = np.isfinite(dist)
    idx = np.where(found, idx, 0)
    # Points beyond the bound count as infinitely far in the median (they are not inliers).
    eligible = ~boundary[idx] | ~found if boundary is not None else np.ones(len(dist), bool)
    keep = found & eligible
    if keep.sum() == 0:
        return keep, idx, dist
    if np.isfinite(reject_k):
        keep &= dist <= reject_k * max(float(np.median(dist[eligible])), 1e-9)
    if trim_fraction > 0 and keep.sum() > 10:
        cut = np.quantile(dist[keep], 1.0 - trim_fraction)
        keep &= dist <= cut
    return keep, idx, dist


def _kabsch(p, q) -> np.ndarray:
    """Best rigid T (4, 4) with T p ~ q (least squares, Arun/Umeyama without scale)."""
    cp, cq = p.mean(axis=0), q.mean(axis=0)
    H = (p - cp).T @ (q - cq)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return rigid_transform(R, cq - R @ cp)


def _plane_step(p, q, n) -> np.ndarray:
    """Linearised point-to-plane step: minimise sum(((R p + t - q) . n)^2), small-angle R."""
    c = p.mean(axis=0)
    pc = p - c  # rotate about the centroid: better conditioned
    A = np.hstack([np.cross(pc, n), n])
    b = np.einsum("ij,ij->i", q - p, n)
    AtA = A.T @ A
    # A tiny ridge keeps the 6x6 system solvable on symmetric patches (e.g. a sphere cap: spin is free).
    AtA += np.eye(6) * 1e-9 * np.trace(AtA)
    x = np.linalg.solve(AtA, A.T @ b)
    w, t = x[:3], x[3:]
    angle = np.linalg.norm(w)
    R = rotation_about_axis(w, np.degrees(angle)) if angle > 1e-15 else np.eye(3)
    # x' = R (x - c) + c + t
    return rigid_transform(R, c + t - R @ c)


def _rotation_angle(R) -> float:
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def _pca_candidates(src, tgt) -> list[np.ndarray]:
    """Transforms matching centroids and principal axes, one per proper sign flip (4)."""
    cs, ct = src.mean(axis=0), tgt.mean(axis=0)
    _, _, Vs = np.linalg.svd(src - cs, full_matrices=False)
    sub = tgt if len(tgt) <= 20000 else tgt[:: len(tgt) // 20000 + 1]
    _, _, Vt = np.linalg.svd(sub - ct, full_matrices=False)
    out = []
    for signs in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)):
        R = Vt.T @ np.diag(signs) @ Vs
        if np.linalg.det(R) < 0:
            R = Vt.T @ np.diag([signs[0], signs[1], -signs[2]]) @ Vs
        out.append(rigid_transform(R, ct - R @ cs))
    return out
