"""The input scan's side of the matcher: its candidates, HK colours and Colombo seeds (in the model
frame), and the points matched before the greedy loop (the user's fixed points and the seeds)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from core.face import Face
from core.registration.match_params import HK_SMOOTHING_MM, MatchingError, MatchParams
from core.registration.rasters import Side, sample_vertex_values


@dataclass
class InputFeatures:
    """The input's candidates (model frame) and seeds, plus messages about fallbacks."""

    side: Side
    triangle: np.ndarray
    bary: np.ndarray
    seeds: dict
    textured: bool
    report: list
    timings: dict = field(default_factory=dict)   # "candidates_s", "hk_s", "seeds_s"


def input_features(scan: Face, to_model: np.ndarray, params: MatchParams) -> InputFeatures:
    """Candidates (texture, or geometry when the scan has none), HK colours, Colombo seeds."""
    from core.registration.candidates import NoTextureError, geometry_candidates, texture_candidates
    from core.registration.curvature import CurvatureError, colombo_seeds, hk_maps
    from core.registration.icp import apply_transform

    report = []
    textured = True
    t0 = time.perf_counter()
    try:
        cand = texture_candidates(scan, count=params.candidates, quality=params.quality,
                                  min_distance_px=params.min_distance_px)
        if len(cand) < 50:
            report.append(f"the texture gave only {len(cand)} corner candidates; adding geometry candidates")
            geo = geometry_candidates(scan, count=params.candidates)
            cand = _concat_candidates(cand, geo)
    except NoTextureError:
        textured = False
        report.append("the scan has no texture: matching uses geometry candidates and curvature/shape "
                      "appearance only (expect lower accuracy; check the landmarks)")
        cand = geometry_candidates(scan, count=params.candidates)
    t1 = time.perf_counter()
    hk = hk_maps(scan, smoothing_mm=HK_SMOOTHING_MM)
    t2 = time.perf_counter()
    seeds = {}
    if params.seeds:
        try:
            seeds = {k: apply_transform(v[None], to_model)[0] for k, v in colombo_seeds(scan, hk).items()}
        except CurvatureError as exc:
            report.append(f"The eye corners and nose tip could not be found from the surface's curvature "
                          f"({exc}); the landmarks were placed from the face's overall shape alone")
    pts = apply_transform(cand.points, to_model)
    hkc = sample_vertex_values(scan, hk.colours / 255.0, cand.triangle, cand.bary)
    colour = cand.colour if textured else np.full((len(pts), 3), 0.5)
    t3 = time.perf_counter()
    return InputFeatures(Side(pts, colour, hkc), np.asarray(cand.triangle), np.asarray(cand.bary), seeds,
                         textured, report, {"candidates_s": t1 - t0, "hk_s": t2 - t1, "seeds_s": t3 - t2})


def _concat_candidates(a, b):
    from core.registration.candidates import Candidates

    return Candidates(*(np.concatenate([getattr(a, f), getattr(b, f)]) for f in
                        ("points", "triangle", "bary", "uv", "colour")))


SEED_POINTS = {"nose_tip": ("9.3",), "inner_eye_corner_left": ("3.11",), "inner_eye_corner_right": ("3.8",)}


def geometry_params(params: MatchParams) -> MatchParams:
    """Without texture d_A,UV carries no information: all appearance weight on the HK term."""
    return dataclasses.replace(params, lam_a=0.0)


def preset_points(ctx, feats: InputFeatures, fixed: dict[str, np.ndarray], to_model: np.ndarray,
                  report: list) -> dict[int, np.ndarray]:
    """Point index -> model-frame position (mm) matched before the greedy loop: the fixed points
    (name -> scan-frame position, in their order), then the Colombo seeds that lie within
    0.12 × scale of where the aligned model (``ctx``, a ModelContext) puts them (the others are
    reported and ignored). The order matters: the greedy order starts from these points."""
    from core.registration.icp import apply_transform

    tpl = ctx.template
    names = tpl.detected
    unknown = [n for n in fixed if n not in names]
    if unknown:
        raise MatchingError(f"fixed landmark(s) {', '.join(unknown)} are not points of template {tpl.name!r}")
    preset: dict[int, np.ndarray] = {}
    for n, p in fixed.items():
        preset[tpl.index(n)] = apply_transform(np.asarray(p, float)[None], to_model)[0]
    for key, pos in feats.seeds.items():
        for n in SEED_POINTS.get(key, ()):
            if n in names and tpl.index(n) not in preset:
                i = tpl.index(n)
                d = float(np.linalg.norm(pos - ctx.side.points[i]))
                if d <= 0.12 * ctx.scale:
                    preset[i] = pos
                else:
                    # Plain words: the report reaches users ("Colombo seed" is the thesis's term).
                    report.append(f"The surface's curvature suggested the {key.replace('_', ' ')} {d:.0f} mm "
                                  f"from where the face's overall shape puts it; that hint was not used")
    return preset
