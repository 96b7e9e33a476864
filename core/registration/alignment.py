"""Finding the face in a scan that is more than a face, or in unknown units (a head-and-shoulders
bust, a full head, a file in inches or arbitrary units).

The thesis's rigid ICP starts from the centroids, which works for face-only range scans in
millimetres (the synthetic protocol, most scanners) but not when the scan's centroid is at the
neck or its units are not millimetres: the ICP then pairs under half of the points and the
landmarks land anywhere. :func:`locate_face` searches instead:

1. **Starts.** The scan is assumed upright (+y up) and facing +z, as scanners and exporters
   deliver faces (the same assumption as the matcher's frontal raster). The model's nose tip is
   put on the front-most scan point of each horizontal band of the scan's central third (the
   nose tip, chin, forehead, chest ... one of them is the nose), tilted by each of
   ``PITCHES_DEG``, at each model size of ``SCALES``. Each start is scored without ICP by the
   median distance from the moved model's skin to the scan, in model mm.
2. **ICP, model -> scan, at a fixed size.** The best starts run point-to-plane ICP moving the
   model's front skin (no eyeballs, teeth or mouth cavity) onto the scan: the face is the part
   both share, so the model is the source; scan points on the shoulders or the back of the head
   are simply never paired. (A free scale inside the ICP shrinks the model onto a patch of the
   head: a small model always fits a smooth surface, so the size is searched instead.)
3. **Size.** The best fit (lowest median distance, most of the model paired) is refined by
   re-running the ICP at sizes 12 %, 4 % and 1.5 % either side. The result must fit to a median of
   ``MAX_MEDIAN_MM``, or nothing face-like was found. ``scale`` is then how many times larger the
   scan must become to have the model's size (5.1 for the LeePerrySmith bust read as
   centimetres).

Positions are in the scan's units; transforms are (4, 4) matrices on column vectors.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.face import Face
from core.face import triangle_normals
from core.registration.icp import IcpError, _iterate, boundary_vertex_mask, rotation_about_axis

# Model sizes tried (model -> scan): scans from 0.4x to 7x the model's size, a factor 1.27 apart.
SCALES = tuple(float(s) for s in np.geomspace(0.14, 2.5, 13))
PITCHES_DEG = (-20.0, 0.0, 20.0)  # head tilts tried at each start (a bust often looks down)
N_BANDS = 32          # horizontal bands of the scan searched for the nose tip
STARTS_PER_SCALE = 2  # best starts kept at each scale (scored without ICP) ...
N_REFINE = 10         # ... of which the best refined by ICP
MODEL_SAMPLE = 1000   # model skin points used
MIN_PAIRED = 0.6      # fraction of the model that must find the scan
# A face fits a face to a median of 0.3 mm (the same person re-meshed) to 2.4 mm (another person on
# a coarse 9k-vertex bust); a sphere or a box fits the model no better than 4.4 mm.
MAX_MEDIAN_MM = 3.5
FIT_MM = 5.0          # skin_fit: a model point is on the scan when this close (model mm)


class FaceNotFoundError(ValueError):
    """No placement of the model fits the scan (not a face, or not facing +z)."""


@dataclass(frozen=True)
class FaceAlignment:
    """Result of :func:`locate_face`.

    transform : (4, 4) rigid scan -> model, to apply after scaling the scan by ``scale``.
    scale : scan size factor (the scan times ``scale`` has the model's size).
    median_mm : median distance from the fitted model's skin to the scan, model mm.
    model_paired : fraction of the model's skin sample paired with the scan in the last iteration.
    """

    transform: np.ndarray
    scale: float
    median_mm: float
    model_paired: float

    @property
    def scale_transform(self) -> np.ndarray:
        """(4, 4) similarity scan -> model (rigid part after uniform scaling)."""
        return self.transform @ np.diag([self.scale, self.scale, self.scale, 1.0])


def locate_face(scan: Face, model: Face, *, scales=SCALES, iterations: int = 30, rng=0) -> FaceAlignment:
    """Place ``model`` (a face facing +z, mm) on ``scan`` (upright, facing +z, any units); see the
    module docstring. Raises FaceNotFoundError when no placement pairs most of the model."""
    target = _dense_target(scan)
    sample, nose = _model_skin_sample(model, np.random.default_rng(rng))
    candidates = _nose_candidates(scan.vertices[np.unique(scan.triangles)])
    probe = sample[:: max(1, len(sample) // 250)]
    rotations = [rotation_about_axis((1.0, 0.0, 0.0), a) for a in PITCHES_DEG]

    def start(s, R, cand):
        T = np.eye(4)
        T[:3, :3] = s * R
        T[:3, 3] = cand - s * R @ nose
        return T

    def fit(T):
        T, paired = _rigid_icp(T, sample, target, iterations)
        return _median_distance(T, sample, target), paired, T

    coarse = []
    for s in scales:
        scored = sorted((_median_distance(start(s, R, c), probe, target), i, j)
                        for i, R in enumerate(rotations) for j, c in enumerate(candidates))
        coarse += [(score, s, i, j) for score, i, j in scored[:STARTS_PER_SCALE]]
    coarse.sort()
    fits = [fit(start(s, rotations[i], candidates[j])) for _, s, i, j in coarse[:N_REFINE]]
    good = [f for f in fits if f[1] >= MIN_PAIRED]
    if not good:
        raise FaceNotFoundError(
            f"no placement of the model face fits this scan (at best {100 * max(f[1] for f in fits):.0f}% of the "
            "model's skin finds the scan); is it a face, upright (+y up) and facing +z? Rotate it so, or place "
            "the landmarks by hand")
    best = min(good, key=lambda f: f[0])
    for step in (1.12, 1.04, 1.015):  # refine the size between the grid's steps
        T0 = best[2]
        tries = [fit(_rescaled(T0, k, nose)) for k in (1 / step, step)]
        best = min([best] + [f for f in tries if f[1] >= MIN_PAIRED], key=lambda f: f[0])
    median, paired, T = best
    if median > MAX_MEDIAN_MM:
        raise FaceNotFoundError(
            f"nothing in this scan has the shape of a face (the model face fits it no closer than {median:.1f} mm); "
            "is it a face, upright (+y up) and facing +z? Rotate it so, or place the landmarks by hand")
    s = float(np.cbrt(np.linalg.det(T[:3, :3])))
    R = T[:3, :3] / s
    # model -> scan is x -> s R x + t, so scan -> model is y -> R^T (y / s - t / s): the rigid
    # part below acts on the scan scaled by 1 / s.
    inv = np.eye(4)
    inv[:3, :3] = R.T
    inv[:3, 3] = -R.T @ T[:3, 3] / s
    return FaceAlignment(inv, 1.0 / s, median, paired)


def cube_rotations() -> np.ndarray:
    """(24, 3, 3): the proper rotations that map the coordinate axes onto themselves (every way a
    scan can face: +z, -z, +x, ... each with any of four "up" directions)."""
    out = []
    for perm in ((0, 1, 2), (1, 2, 0), (2, 0, 1), (0, 2, 1), (2, 1, 0), (1, 0, 2)):
        for signs in np.ndindex(2, 2, 2):
            R = np.zeros((3, 3))
            R[np.arange(3), perm] = np.where(np.array(signs) == 1, -1.0, 1.0)
            if np.linalg.det(R) > 0:
                out.append(R)
    return np.array(out)


@dataclass(frozen=True)
class Orientation:
    """How a scan faces. ``rotation`` (3, 3) turns the scan to face +z, upright, as the model does;
    ``median_mm`` is the model's fit after that turn, ``unturned_mm`` its fit as the scan lies."""

    rotation: np.ndarray
    median_mm: float
    unturned_mm: float

    @property
    def turned(self) -> bool:
        return not np.allclose(self.rotation, np.eye(3), atol=1e-9)

    @property
    def angle_deg(self) -> float:
        return float(np.degrees(np.arccos(np.clip((np.trace(self.rotation) - 1.0) / 2.0, -1.0, 1.0))))


# The model fits a face scan in its own orientation to ~0.3 mm (the same face) to ~3 mm (other people,
# expressions); started 90 degrees or more off, ICP stops at 2.5-10 mm, often still turned. The search
# runs unless the fit as the scan lies is good and barely rotated; a turn is taken when the best fit
# is rotated by more than ORIENTATION_TURN_DEG and is clearly better (ORIENTATION_GAIN) than the fit
# as the scan lies, or that fit itself turned that far.
ORIENTATION_GAIN = 0.9
ORIENTATION_GOOD_MM = 2.0
ORIENTATION_TURN_DEG = 30.0
ORIENTATION_FINALISTS = 3
# Before a turn is taken, the fit as the scan lies is also started tilted this far (degrees) up,
# down, left and right, and the best of the five is what the turn must beat: one ICP from the
# scan's own orientation stops 3.0-3.5 mm from a face of other proportions, depending on its sample
# of the model's points (a Surrey Face Model person posed 5 degrees: a 38 degree turn fitting 3.0 mm
# was taken in 3 of 6 samples against 3.4-3.5 mm as it lay, and put every landmark 26 mm off).
ORIENTATION_TILT_DEG = 15.0


def find_orientation(scan: Face, model: Face, *, iterations: int = 20, rng=0) -> Orientation:
    """Which way ``scan`` faces: the model's front skin is placed on the scan's centre in each of the
    24 axis-aligned orientations (:func:`cube_rotations`), each refined by a 3-step ICP of 250 model
    points, the best ``ORIENTATION_FINALISTS`` by ``iterations`` steps of the whole sample; the best
    fit becomes a turn under the rules above ``ORIENTATION_GAIN``. A scan that faces +z and fits
    within ``ORIENTATION_GOOD_MM`` costs one fit (~0.3 s for 100k vertices; a search ~1 s)."""
    rng = np.random.default_rng(rng)
    target = _dense_target(scan)
    sample, _ = _model_skin_sample(model, rng)
    # Fitted against 8000 of the scan's points: far from the surface, a query of the full scan's tree
    # costs ~20 ms per point set, and a few thousand points place a face as well.
    keep = rng.choice(len(target[0]), size=min(8000, len(target[0])), replace=False)
    coarse_target = (*(a[keep] for a in target[:3]), cKDTree(target[0][keep]))
    coarse = sample[:: max(1, len(sample) // 250)]
    centre_scan = target[0].mean(axis=0)
    centre_model = sample.mean(axis=0)

    def fit(R: np.ndarray, points: np.ndarray, steps: int, on=target) -> tuple[float, np.ndarray]:
        """(score mm, model -> scan transform) of the model points started in orientation R (scan -> model)."""
        T = np.eye(4)
        T[:3, :3] = R.T
        T[:3, 3] = centre_scan - R.T @ centre_model
        T, paired = _rigid_icp(T, points, on, steps)
        if paired < MIN_PAIRED / 2:
            return np.inf, T
        # Mean distance with misses counted at FIT_MM: a median would let a face mask lying askew on
        # part of another face score as well as the right placement.
        d, _ = on[3].query(points @ T[:3, :3].T + T[:3, 3], k=1)
        return float(np.mean(np.minimum(d, FIT_MM))), T

    def angle(T: np.ndarray) -> float:
        return float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))

    unturned, T_id = fit(np.eye(3), sample, iterations, coarse_target)
    if unturned <= ORIENTATION_GOOD_MM and angle(T_id) < ORIENTATION_TURN_DEG:
        return Orientation(np.eye(3), unturned, unturned)
    starts = sorted(((fit(R, coarse, 3, coarse_target)[0], k) for k, R in enumerate(cube_rotations())),
                    key=lambda x: x[0])
    best, best_T = unturned, T_id
    for _, k in starts[:ORIENTATION_FINALISTS]:
        if np.allclose(cube_rotations()[k], np.eye(3)):
            continue   # the fit as the scan lies, done above
        score, T = fit(cube_rotations()[k], sample, iterations, coarse_target)
        if score < best:
            best, best_T = score, T
    # Turn when the best fit is a turn, and either clearly better than the scan as it lies or what
    # the scan as it lies converged to anyway (its own ICP rotated the model by that much).
    if not np.isfinite(best) or angle(best_T) < ORIENTATION_TURN_DEG:
        return Orientation(np.eye(3), unturned, unturned)
    if angle(T_id) < ORIENTATION_TURN_DEG and best < ORIENTATION_GAIN * unturned:
        # Clearly better than one fit as the scan lies: also than the best fit started near it?
        near = [fit(rotation_about_axis(axis, sign * ORIENTATION_TILT_DEG), sample, iterations, coarse_target)
                for axis in ((1, 0, 0), (0, 1, 0)) for sign in (1, -1)]
        unturned = min([unturned] + [score for score, T in near if angle(T) < ORIENTATION_TURN_DEG])
    if not (best < ORIENTATION_GAIN * unturned or angle(T_id) >= ORIENTATION_TURN_DEG):
        return Orientation(np.eye(3), unturned, unturned)
    return Orientation(best_T[:3, :3].T, best, unturned)


def skin_fit(scan: Face, model: Face, transform, rng=0) -> tuple[float, float]:
    """How well the model's front skin lies on ``scan`` placed by ``transform`` (4, 4 scan -> model):
    (median distance in model mm, fraction of the skin sample within ``FIT_MM``). A face-only scan in
    mm aligned by ICP gives about (0.5, 0.95); a bust or a scan in other units far less."""
    target = _dense_target(scan)
    sample, _ = _model_skin_sample(model, np.random.default_rng(rng))
    T = np.linalg.inv(np.asarray(transform, dtype=np.float64))  # model -> scan
    d, _ = target[3].query(sample @ T[:3, :3].T + T[:3, 3], k=1)
    s = float(np.cbrt(np.linalg.det(T[:3, :3])))
    return float(np.median(d)) / s, float(np.mean(d / s < FIT_MM))


def _rescaled(T, k, nose):
    """T (model -> scan) with the model k times larger about its nose tip."""
    S = np.eye(4)
    S[:3, :3] *= k
    S[:3, 3] = nose - k * nose
    return T @ S


def _model_skin_sample(model: Face, rng) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) points of the model's front skin (no eyeballs, teeth or mouth cavity: a scan has none
    of them; within 75 mm of the nose tip and facing forward) and the (3,) nose tip."""
    nose = _nose_tip(model)
    skin = np.zeros(model.n_vertices, bool)
    skin[model.triangles.ravel()] = True
    for idx in model.parts.values():
        skin[idx] = False
    v = model.vertices
    skin &= (model.vertex_normals[:, 2] > 0.2) & (np.linalg.norm((v - nose)[:, :2], axis=1) < 75.0)
    pts = v[skin]
    return pts[rng.choice(len(pts), size=min(MODEL_SAMPLE, len(pts)), replace=False)], nose


def _nose_tip(model: Face) -> np.ndarray:
    if "9.3" in model.landmarks:
        return model.landmark_position("9.3")
    used = np.unique(model.triangles)
    return model.vertices[used[np.argmax(model.vertices[used, 2])]]


def _nose_candidates(points: np.ndarray) -> np.ndarray:
    """(k, 3): the front-most point of each horizontal band of the central third of the scan."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre_x = float(np.median(points[:, 0]))
    central = points[np.abs(points[:, 0] - centre_x) < (hi[0] - lo[0]) / 6]
    if len(central) == 0:
        central = points
    band = np.clip(((central[:, 1] - lo[1]) / max(hi[1] - lo[1], 1e-12) * N_BANDS).astype(int), 0, N_BANDS - 1)
    order = np.lexsort((-central[:, 2], band))
    first = np.ones(len(order), bool)
    first[1:] = band[order[1:]] != band[order[:-1]]
    return central[order[first]]


def _dense_target(scan: Face):
    """(points, normals, boundary, KD-tree) of the scan's vertices and triangle centroids: a coarse
    scan's vertices alone are several mm apart, which would hide the fit's quality. The last scan's
    target is kept (weakly): detection asks for it twice (orientation search, then the skin check)."""
    last = _LAST_TARGET[0] if _LAST_TARGET else None
    if last is not None and last[0]() is scan and last[1] is scan.vertices and last[2] is scan.triangles:
        return last[3]
    target = _build_dense_target(scan)
    _LAST_TARGET[:] = [(weakref.ref(scan), scan.vertices, scan.triangles, target)]
    return target


_LAST_TARGET: list = []


def _build_dense_target(scan: Face):
    used = np.unique(scan.triangles)
    tri = scan.triangles
    boundary_v = boundary_vertex_mask(tri, scan.n_vertices)
    centroids = scan.vertices[tri].mean(axis=1)
    normals = triangle_normals(scan.vertices, tri)
    pts = np.concatenate([scan.vertices[used], centroids])
    nrm = np.concatenate([scan.vertex_normals[used], normals])
    boundary = np.concatenate([boundary_v[used], boundary_v[tri].any(axis=1)])
    return pts, nrm, boundary, cKDTree(pts)


def _median_distance(T, src, target) -> float:
    """Median distance from the moved model points to the scan, in model units."""
    s = float(np.cbrt(np.linalg.det(T[:3, :3])))
    d, _ = target[3].query(src @ T[:3, :3].T + T[:3, 3], k=1)
    return float(np.median(d)) / s


def _rigid_icp(T, src, target, iterations):
    """Point-to-plane ICP of the model points (src) onto the scan at T's fixed scale.
    Returns (T, paired fraction of the last iteration)."""
    pts, normals, boundary, tree = target
    s = float(np.cbrt(np.linalg.det(T[:3, :3])))
    rigid = np.eye(4)
    rigid[:3, :3] = T[:3, :3] / s
    rigid[:3, 3] = T[:3, 3]
    try:
        result = _iterate(rigid, iterations, src * s, pts, normals, boundary, tree, 3.0, 0.2, 1e-6 * s)
    except IcpError:  # lost the scan: not a placement
        return T, 0.0
    out = result.transform.copy()
    out[:3, :3] = out[:3, :3] * s
    return out, result.inlier_fraction
