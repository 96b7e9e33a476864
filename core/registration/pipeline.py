"""High-level scan registration for the CLI and the GUI (thesis A ch. 3).

``detect_landmarks(scan)`` -> :class:`Detection` (the template's points on the scan, each with a
confidence), ``register_scan(scan, landmarks)`` -> ``correspondence.Registration`` (the canonical
face with the template's feature points as landmarks, ready for ``core.rig.FaceRig``).

Steps of ``detect_landmarks``: input checks (size, units) -> rigid ICP of the scan to the model
(point-to-plane, centroid start; when the model's skin does not lie on the result, e.g. a bust or
a file in other units, ``alignment.locate_face`` searches for the face and its size, and matching
runs on a copy scaled to millimetres, see ``Detection.scale_hint``) -> candidates, HK maps and
Colombo seeds -> greedy structural matching -> patch refinement on the surface -> confidence (see
``matching``). The model is the built-in default face unless given; its context (template points,
appearance, frontal raster) is cached per model object.

Input checks (clear ValueErrors rather than nonsense): fewer than ``MIN_VERTICES`` vertices or
triangles; a scan whose size differs from the model's by more than 4x (typically metres or
inches instead of millimetres: the message names the factor to apply with the loader's unit
option).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from core.landmark_editing import LOW_CONFIDENCE
from core.face import Face, SurfacePoint
from core.registration.correspondence import CorrespondenceError, Registration, SurfaceRays, dense_correspondence, landmark_positions_on
from core.registration.matching import MatchParams, ModelContext, match, model_context
from core.registration.templates import TEMPLATE_NAMES, get_template

MIN_VERTICES = 500


class ScanInputError(ValueError):
    """The scan cannot be matched as it is (too small, wrong units, empty)."""


@dataclass
class Detection:
    """Landmarks detected on a scan.

    landmarks : name -> SurfacePoint on the scan (the template's detected points).
    confidence : name -> 0..1 (heuristic; low values are worth checking in the picker).
    report : human-readable lines (fallbacks, rejected seeds, ICP quality).
    timings : seconds per stage ("icp_s", "features_s", "greedy_s", "refine_s", "total_s").
    positions : name -> (3,) mm on the scan.
    transform : (4, 4) scan -> model frame (ICP).
    sources : name -> "seed" | "candidate" | "refined" | "opening" | "fixed" | "prediction".
    scale_hint : the factor that gives the scan a human face's size in mm when its units are
        evidently not millimetres (None when they are); ``transform`` then includes that scale.
    """

    landmarks: dict[str, SurfacePoint]
    confidence: dict[str, float]
    report: list[str]
    timings: dict[str, float]
    template: str
    positions: dict[str, np.ndarray] = field(default_factory=dict)
    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    sources: dict[str, str] = field(default_factory=dict)
    rays: SurfaceRays | None = field(default=None, repr=False)
    scale_hint: float | None = None

    def low_confidence(self, threshold: float = LOW_CONFIDENCE) -> list[str]:
        return [n for n, c in self.confidence.items() if c < threshold]

    @property
    def scan_confidence(self) -> float:
        """0..1: the fraction of the landmarks found with confidence (not :meth:`low_confidence`);
        a scan whose detection failed as a whole scores low (most points disagree with the model)."""
        return 1.0 - len(self.low_confidence()) / max(len(self.confidence), 1)

    def face_with_landmarks(self, scan: Face) -> Face:
        """A copy of ``scan`` carrying the detected landmarks."""
        out = scan.with_vertices(scan.vertices)
        for n, p in self.landmarks.items():
            out.set_landmark(n, p)
        return out


_MODEL_CACHE: dict = {}
_DEFAULT_MODEL: list = []


def default_model() -> Face:
    """The built-in default face, its front only (loaded once)."""
    if not _DEFAULT_MODEL:
        from core.default_face import load_default_face

        _DEFAULT_MODEL.append(load_default_face(full_head=False))   # the generic model is the front of the face
    return _DEFAULT_MODEL[0]


def get_model_context(model: Face, template: str, params: MatchParams) -> ModelContext:
    key = (id(model), template, params.pixel_mm)
    hit = _MODEL_CACHE.get(key)
    if hit is not None and hit[0] is model:
        return hit[1]
    ctx = model_context(model, get_template(template), params)
    # Only the built-in face has a FAP rig to close its lids with (a given model, e.g. a person's
    # own scan, is looked at open-eyed).
    ctx.can_close_eyes = bool(_DEFAULT_MODEL) and model is _DEFAULT_MODEL[0]
    if len(_MODEL_CACHE) > 8:
        _MODEL_CACHE.clear()
    _MODEL_CACHE[key] = (model, ctx)
    return ctx


def check_scan(scan: Face, model: Face | None = None) -> None:
    """Raise ScanInputError for meshes that cannot be a face scan in millimetres."""
    if scan.n_vertices < MIN_VERTICES or scan.n_triangles < MIN_VERTICES:
        raise ScanInputError(
            f"the scan has only {scan.n_vertices} vertices and {scan.n_triangles} triangles; landmark detection "
            f"needs a face surface of at least {MIN_VERTICES} vertices (a range scan has about 50,000). "
            "Load the full scan, or mark the landmarks by hand")
    if not np.all(np.isfinite(scan.vertices)):
        raise ScanInputError("the scan has NaN or infinite vertex coordinates; clean it first")
    used = np.unique(scan.triangles)
    size = float(np.linalg.norm(np.ptp(scan.vertices[used], axis=0)))
    ref = 250.0
    if model is not None:
        ref = float(np.linalg.norm(np.ptp(model.vertices, axis=0)))
    ratio = size / ref
    if not 0.25 <= ratio <= 4.0:
        guess = ref / max(size, 1e-12)
        unit = ""
        for factor, name in ((1000.0, "metres"), (10.0, "centimetres"), (25.4, "inches"), (0.001, "micrometres")):
            if 0.4 <= guess / factor <= 2.5:
                unit = f" It looks like the scan is in {name}: scale it by {factor:g} to get millimetres."
                break
        raise ScanInputError(
            f"the scan is {size:.4g} units across but a face is about {ref:.0f} mm across (ratio {ratio:.3g}); "
            f"Mimica works in millimetres.{unit}")


# A scan found to be this much larger or smaller than the model is taken to be in other units
# (adult faces vary by about +-10 % in size).
UNIT_MISMATCH = 1.3


def _skin_off(scan: Face, model: Face, transform) -> bool:
    """True when much of the model's front skin does not lie on the ICP-aligned scan."""
    from core.registration.alignment import skin_fit

    return skin_fit(scan, model, transform)[1] < 0.6


def _locate(scan: Face, model: Face, report: list[str]):
    """(scan -> model rigid transform of the scan scaled by ``scale``, scale) from
    ``alignment.locate_face``, or None when no face is found there (the reason goes to report)."""
    from core.registration.alignment import FaceNotFoundError, locate_face

    try:
        found = locate_face(scan, model)
    except FaceNotFoundError as exc:
        report.append(str(exc))
        return None
    scale = found.scale
    if 1 / UNIT_MISMATCH <= scale <= UNIT_MISMATCH:
        scale = 1.0  # a big or small face, not other units: match at the scan's own size
        # (the rigid part was fitted at the face's own size; refit without the scale below)
        from core.registration.icp import icp

        refit = icp(scan.vertices[np.unique(scan.triangles)], model, initial=found.transform, max_iterations=50,
                    sample=3000)
        report.append(f"the face was found inside a larger scan ({100 * found.model_paired:.0f}% of the model "
                      f"paired, median distance {found.median_mm:.1f} mm)")
        return refit.transform, scale
    report.append(
        f"the scan's face is {scale:.2f} times {'smaller' if scale > 1 else 'larger'} than a human face: its units "
        f"are probably not millimetres. Landmarks were found on a copy scaled by {scale:.3g}; scale the face by "
        f"{scale:.3g} (Tools > Scale face in the window, --scale with mimica register) so distances and muscles "
        "are right")
    return found.transform, scale


def _progress(progress, fraction, message):
    if progress is not None:
        progress(float(fraction), message)


def detect_landmarks(scan: Face, *, template: str = "mpeg4_80", model: Face | None = None,
                     params: MatchParams | None = None, fixed: Mapping | None = None,
                     progress: Callable[[float, str], None] | None = None) -> Detection:
    """Find the points of ``template`` on ``scan`` (see the module docstring).

    model : a Face carrying the template's points as landmarks (derived a48 points are computed
        from the MPEG-4 feature points); the default face by default.
    fixed : name -> SurfacePoint on the scan or (3,) position: user-confirmed landmarks kept as they
        are ("re-run matching keeping my edits fixed"); they also steer their neighbours.
    progress : called as progress(fraction 0..1, message).
    """
    if template not in TEMPLATE_NAMES:
        from core.registration.templates import UnknownTemplateError

        raise UnknownTemplateError(f"unknown landmark template {template!r}; choose one of {', '.join(TEMPLATE_NAMES)}")
    params = params or MatchParams()
    t0 = time.perf_counter()
    model = model if model is not None else default_model()
    check_scan(scan, model)
    _progress(progress, 0.0, "finding which way the scan faces")
    from core.registration.alignment import find_orientation

    orientation = None
    if _face_sized(scan, model):   # a bust, or a scan in other units, is searched upright (see _locate)
        orientation = find_orientation(scan, model)
    if orientation is None or not orientation.turned:
        return _detect(scan, model, template, params, fixed, progress, t0)
    # Search on a turned copy (same triangles, so its surface points are the scan's own), then
    # give positions and transform in the scan's frame.
    R = orientation.rotation
    turned_fixed = None if not fixed else {
        n: p if isinstance(p, SurfacePoint) else np.asarray(p, float) @ R.T for n, p in fixed.items()}
    det = _detect(scan.with_vertices(scan.vertices @ R.T), model, template, params, turned_fixed, progress, t0)
    turn = np.eye(4)
    turn[:3, :3] = R
    det.positions = {n: p @ R for n, p in det.positions.items()}
    det.transform = det.transform @ turn
    det.rays = None
    det.report.insert(0, f"The scan did not face forward (+z, upright): it was turned by {orientation.angle_deg:.0f}° "
                         f"for the search (the face fits {orientation.median_mm:.1f} mm turned, "
                         f"{orientation.unturned_mm:.1f} mm as it lies); the landmarks are on the scan as it is")
    return det


# The orientation search places the model's face on the scan's centre at the model's size: it is
# tried on scans about a face's size (a face mask in mm), not on busts or scans in other units.
FACE_SIZED = (0.6, 1.6)


def _face_sized(scan: Face, model: Face) -> bool:
    used = np.unique(scan.triangles)
    ratio = np.linalg.norm(np.ptp(scan.vertices[used], axis=0)) / np.linalg.norm(np.ptp(model.vertices, axis=0))
    return bool(FACE_SIZED[0] <= ratio <= FACE_SIZED[1])


def _detect(scan: Face, model: Face, template: str, params: MatchParams, fixed: Mapping | None,
            progress, t0: float) -> Detection:
    """:func:`detect_landmarks` on a scan that faces +z, upright (or nearly)."""
    _progress(progress, 0.05, "preparing the model")
    ctx = get_model_context(model, template, params)
    timings = {"model_s": time.perf_counter() - t0}
    report: list[str] = []
    fixed_pos = landmark_positions_on(scan, dict(fixed)) if fixed else {}

    _progress(progress, 0.1, "aligning the scan to the model (ICP)")
    from core.registration.icp import icp

    t1 = time.perf_counter()
    res = icp(scan.vertices[np.unique(scan.triangles)], model, max_iterations=50, sample=3000)
    T, scale = res.transform, 1.0
    if res.rms_mm > 0.05 * ctx.scale or res.inlier_fraction < 0.5 or _skin_off(scan, model, T):
        # More than a face (a bust, a whole head) or not in millimetres: search for the face.
        _progress(progress, 0.15, "searching for the face in the scan (size and position)")
        located = _locate(scan, model, report)
        if located is not None:
            T, scale = located
        else:
            report.append(f"rigid alignment is poor (RMS {res.rms_mm:.1f} mm, {100 * res.inlier_fraction:.0f}% of "
                          "points paired): is the scan a frontal face? Landmarks may be wrong")
    timings["icp_s"] = time.perf_counter() - t1
    work = scan if scale == 1.0 else scan.scaled(scale)
    _progress(progress, 0.4, "building the ray scene")
    t2 = time.perf_counter()
    rays = SurfaceRays(work.vertices, work.triangles)
    timings["rays_s"] = time.perf_counter() - t2
    if rays.engine != "embree":
        report.append("embreex is not available: the surface raster uses a nearest-vertex approximation")
    _progress(progress, 0.5, "matching landmarks")
    fixed_work = {n: p * scale for n, p in fixed_pos.items()}
    result = match(work, T, ctx, params, rays=rays, fixed=fixed_work, report=report)
    timings.update(result.timings)
    inv = np.linalg.inv(T)
    pos_scan = (result.positions @ inv[:3, :3].T + inv[:3, 3]) / scale
    names = result.names
    landmarks = {n: SurfacePoint(int(result.triangle[i]), tuple(result.bary[i])) for i, n in enumerate(names)}
    for n, p in fixed_pos.items():  # fixed landmarks exactly as given
        if fixed and isinstance(fixed[n], SurfacePoint):
            landmarks[n] = fixed[n]
    timings["total_s"] = time.perf_counter() - t0
    _progress(progress, 1.0, "done")
    low = [n for i, n in enumerate(names) if result.confidence[i] < 0.5]
    if low:
        report.append(f"{len(low)} landmark(s) with low confidence, worth checking: {', '.join(low[:12])}"
                      f"{' ...' if len(low) > 12 else ''}")
    return Detection(landmarks, {n: float(result.confidence[i]) for i, n in enumerate(names)}, report, timings,
                     template, {n: pos_scan[i] for i, n in enumerate(names)}, T @ np.diag([scale] * 3 + [1.0]),
                     {n: result.source[i] for i, n in enumerate(names)}, rays if scale == 1.0 else None,
                     scale_hint=None if scale == 1.0 else scale)


def register_scan(scan: Face, landmarks: Mapping, *, template: str = "mpeg4_80",
                  rays: SurfaceRays | None = None) -> Registration:
    """Dense correspondence of ``scan`` from its landmarks (SurfacePoints or positions; e.g.
    ``Detection.landmarks`` or ``scan.landmarks``). Returns the Registration: ``.face`` is the
    canonical Face (same vertex count and meaning for every scan), ``.fallbacks`` the vertices
    whose normal ray missed, ``.carry_back()`` moves the full scan with the canonical face.
    ``rays`` reuses the Embree scene of a Detection (``Detection.rays``)."""
    if template not in TEMPLATE_NAMES:
        from core.registration.templates import UnknownTemplateError

        raise UnknownTemplateError(f"unknown landmark template {template!r}; choose one of {', '.join(TEMPLATE_NAMES)}")
    if scan.n_triangles == 0:
        raise CorrespondenceError("the scan has no triangles")
    positions = landmark_positions_on(scan, dict(landmarks))
    tpl = get_template(template)
    missing = [p for p in tpl.base.feature_points if p not in positions]
    if missing and template == "a48" and not [p for p in missing if p not in tpl.derived]:
        # a48 temple points are derivable from the MPEG-4 feature points the scan may carry.
        from core.registration.templates import template_positions

        src = scan.with_vertices(scan.vertices)
        for n, p in landmarks.items():
            if isinstance(p, SurfacePoint):
                src.set_landmark(n, p)
        positions.update({k: v for k, v in template_positions(src, "a48").items() if k not in positions})
    positions, notes = lids_in_order(positions)
    surfaces = (rays, rays) if rays is not None and not scan.parts else None
    registration = dense_correspondence(scan, positions, template=template, rays=surfaces)
    registration.report.extend(notes)
    return registration


#: (upper lid, lower lid, outer corner, inner corner, side) of each eye (MPEG-4: 3.1 / 3.3 left, 3.2 / 3.4 right).
LID_PAIRS = (("3.1", "3.3", "3.7", "3.11", "left"), ("3.2", "3.4", "3.12", "3.8", "right"))
# An eye whose upper lid is less than this fraction of the eye's width from its lower one is closed
# (1.5 mm on a 30 mm eye; an open adult eye: ~0.3-0.4, the built-in face 0.40; a squint ~0.1).
CLOSED_LID = 0.05


def lids_in_order(positions: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], list[str]]:
    """(positions, notes): an eye whose upper lid point lies below its lower one (a detection that
    swapped them — on a narrow eye they are a few millimetres apart) gets the two swapped back, with
    a note. Left as they were, the canonical face's eye triangles turn over and its FAP unit IRISD0
    (upper minus lower lid) is negative, so the registered face cannot animate. A closed eye (upper
    lid on the lid line, less than ``CLOSED_LID`` x the eye's width from the lower lid) has no
    IRISD0 either: its upper lid is put ``CLOSED_LID`` x the eye's width above the lower one, with
    a note, so the rig measures a small IRISD0 and the lid FAPs (units of IRISD0) keep the eye
    closed. Putting it where an open lid would be (the built-in face's gap, 12 mm on LeePerrySmith)
    made joy pull a flap of lid skin over the closed eye. "Up" is from the mouth to the eyes (the lip
    corners 8.3 / 8.4 to the outer eye corners 3.7 / 3.12)."""
    needed = ("8.3", "8.4", "3.7", "3.12")
    if any(name not in positions for name in needed):
        return positions, []
    up = (positions["3.7"] + positions["3.12"] - positions["8.3"] - positions["8.4"]) / 2.0
    up /= max(float(np.linalg.norm(up)), 1e-12)
    out, notes = dict(positions), []
    for upper, lower, outer, inner, side in LID_PAIRS:
        if upper not in out or lower not in out:
            continue
        gap = float(np.dot(out[upper] - out[lower], up))
        width = float(np.linalg.norm(out[outer] - out[inner])) if inner in out else 0.0
        if width > 0 and abs(gap) < CLOSED_LID * width:
            out[upper] = out[lower] + CLOSED_LID * width * up
            notes.append(f"the {side} eye is closed (its upper lid {upper} is on the lid line); the registered face "
                         f"keeps it closed, its upper lid {CLOSED_LID * width:.1f} mm above the lid line so that lid "
                         "movements stay that small")
        elif gap < 0:
            out[upper], out[lower] = positions[lower], positions[upper]
            notes.append(f"the {side} eye's upper lid point {upper} lay below its lower lid point {lower}; "
                         "they were swapped so the face animates — check both with the landmark picker")
    return out, notes
