"""Structural landmark matching (thesis A §3.2, Algorithm 1) with Mimica's refinements.

This module runs the match (``match``) and scores it; its passes live beside it: ``rasters``
(frontal rasters and surface sampling), ``greedy`` (the thesis's greedy structural matcher),
``patches`` (NCC patch refinement), ``mouth_passes`` (lip order, mouth opening, lower lip) and
``match_params`` (parameters).

The model is a face whose landmarks are known (a template's points); the input is a scan already
rigidly aligned to it (ICP, done by ``pipeline.detect_landmarks``), so everything here works in
the model's frame, in mm.

Thesis part (kept as the thesis defines it):

* candidates: Shi-Tomasi corners of the input's texture lifted to 3-D (``candidates``);
* seeds: the Colombo nose tip and inner eye corners (HK classification) are matched first;
* cost E = λ·d_A + (1 − λ)·d_S (3.1); d_A = λ_A·d_A,UV + (1 − λ_A)·d_A,HK (3.2) with RGB
  distances of texture colour and HK-class colour divided by C_A = √3 (colours in [0, 1]);
  d_S = mean over the graph edges of the vertex of c_vec = λ_S·d_ang + (1 − λ_S)·d_mod (3.3,
  3.4), d_ang = |cos θ − 1| / 2, d_mod = min(||e_m| − |e_d|| / C_S, 1) with C_S = the model's
  median graph edge length;
* the deformation graph G_d starts as a copy of G_m and each accepted match replaces its vertex;
* greedy assignment: for each model vertex in turn the cheapest remaining candidate, which is
  then removed (Algorithm 1). Vectorised over candidates (one numpy pass per model vertex).
* order (the thesis does not say): seeds first, then breadth-first over G_m from the seeds,
  ties broken by distance from the seeds, so each vertex is matched after its neighbours.

Mimica's additions (each can be switched off in :class:`MatchParams`; all on by default because
the evaluation showed they are needed to reach the accuracy goals):

* ``propagate``: unmatched vertices of G_d follow the matched ones (Gaussian-weighted mean of the
  matched displacements over shortest-path distances along G_m, σ = ``sigma`` × face scale; graph
  distances respect the mouth opening), so the structure cost of a mouth vertex sees where the
  jaw has gone instead of the model's closed mouth;
* ``radius`` / ``position_weight``: candidates farther than ``radius`` × face scale from the
  vertex's predicted position (its G_d position) are not considered, and the normalised distance
  is added as a cost term: E' = (1 − w)·E + w·min(d / R, 1);
* ``refine``: each match is then refined on the scan surface (not only among candidates): a
  frontal raster of the aligned scan (0.75 mm pixels; colour, and the surface normal for shape)
  is searched around the match for the model's patch around the landmark (normalised
  cross-correlation, ``cv2.matchTemplate``), with a mild quadratic pull towards the structural
  prediction; the pixel's triangle and barycentric coordinates give the surface point. Round 2
  searches again around each point's prediction from the others (NCC-weighted); inner-lip and
  lid-margin points compare only the half patch on their own lip/lid (the other half may be the
  opening); lower-lip points are searched below their upper-lip partner, pulled to where the jaw
  (chin points) went; where the scan ends inside the patch (outline) the NCC is not trusted and
  the structural prediction is used;
* ``mouth_opening``: an open mouth seen from the front is an occluding edge. Along the column of
  each inner-lip point (placed at the model's horizontal fraction between the ends of the
  opening, measured on the row through its middle) the frontal depth steps back just below the
  upper lip and forward again just above the lower lip (or the scan has a hole there): the upper
  inner-lip points go to the last row above the opening, the lower ones to the first row below,
  so the order upper outer > upper inner > opening > lower inner > lower outer holds. Outer-lip
  points on the wrong side of the opening and chin points (2.10, 2.1, 2.11, 2.12) found less than
  half their model distance below the lower lip are searched again on the right side. A closed
  mouth (no step, or an opening under 1.5 mm) leaves the patch-search result, except that a lower
  inner-lip point found on the lower outer lip (pressed lips) goes back to the seam, at the
  model's offset below the upper outer lip;
* ``lid_depth``: a doubtful upper-lid point (confidence < ``LID_RECHECK``; brows lowered onto the
  lid, as in anger, fit the lid patch) goes to the foot of the lid's depth fall onto the eyeball,
  searched in its column above the lower-lid point;
* ``steep_prediction``: where the model's surface turns sideways away from the frontal view
  (normal z < ``STEEP_NZ`` and |x| >= |y|: temples, jaw-angle and face-border points, outer brow
  ends; not the mouth and eye points, textured contours that curl away from the view) the frontal
  raster is
  foreshortened and nearly textureless, so the patch search lands a few mm off laterally, which on
  a steep side is 10-20 mm along the surface (across people). These points are re-predicted from
  the confident non-steep, non-outline matches (confidence > ``ANCHOR_CONFIDENCE``; the same
  graph-distance Gaussian propagation as ``propagate``) and put on the scan: outline points at the
  closest scan point (the prediction's depth is trusted: the face border is where the side turns
  away), the others (brow ends) at the scan surface seen at the prediction's frontal pixel
  (measured on 3 synthetic people: closest point is better for the outline, the frontal ray for
  the brows). Their source is "prediction" and their evidence 0;
* no texture: geometry candidates (farthest-point samples) and appearance from HK and shape
  only; the caller reports it.

Confidence (0..1, heuristic, not a probability): the mean of the NCC peak (clipped to [0, 1])
and exp(−(d / 0.1·scale)²) where d is the distance of the final point from its structural
prediction (from the other matches); without refinement the NCC term is replaced by the greedy
cost margin between the best and the second-best candidate elsewhere (> 0.1 × scale away).

Face scale: the distance between the outer eye corners 3.7 and 3.12 of the model (91 mm on the
default face); without them, 0.66 × the model's skin bounding-box width.
"""

from __future__ import annotations

import time

import numpy as np

from core.face import Face
from core.registration.rasters import (  # noqa: F401 - re-exported
    FrontalRaster, Grid, grid_for, frontal_raster, Side, sample_texture, sample_vertex_values, _raster_hit)
from core.registration.greedy import (  # noqa: F401 - re-exported
    face_scale, match_order, graph_distances, _propagated, greedy_match)
from core.registration.pass_results import (  # noqa: F401 - re-exported
    GreedyMatch, MatchResult, PixelEstimates, PixelMoves)
from core.registration.patches import search_near_greedy, search_near_prediction
from core.registration.mouth_passes import lip_order_pass, lower_lip_pass, mouth_opening_pass
from core.registration.match_params import (  # noqa: F401 - re-exported
    HK_SMOOTHING_MM, MatchingError, MatchParams)
from core.registration.match_context import ModelContext, model_context, pixel_context  # noqa: F401 - re-exported
from core.registration.scan_features import (  # noqa: F401 - re-exported
    SEED_POINTS, InputFeatures, geometry_params, input_features, preset_points)


def match(scan: Face, to_model: np.ndarray, ctx: ModelContext, params: MatchParams, *, rays,
          fixed: dict[str, np.ndarray] | None = None, features: InputFeatures | None = None,
          report: list | None = None, scan_raster: FrontalRaster | None = None) -> MatchResult:
    """Match ``ctx``'s template points on ``scan`` (aligned to the model by ``to_model``).

    features / scan_raster : precomputed (they do not depend on λ's; the evaluation sweeps λ).

    fixed : name -> position on the scan (scan frame, mm): kept as they are.
    rays : correspondence.SurfaceRays over the scan (its own frame).
    """
    from core.registration.icp import apply_transform

    report = report if report is not None else []
    timings = {}
    t0 = time.perf_counter()
    tpl = ctx.template
    names = tpl.detected
    P = len(names)
    feats = features or input_features(scan, to_model, params)
    report += feats.report
    params_used = params if feats.textured else geometry_params(params)
    timings["features_s"] = time.perf_counter() - t0
    if features is None:
        timings.update(feats.timings)

    fixed = fixed or {}
    preset = preset_points(ctx, feats, fixed, to_model, report)
    order = match_order(tpl, ctx.side.points, list(preset))
    t1 = time.perf_counter()
    gdist = graph_distances(tpl, ctx.side.points)
    greedy = greedy_match(tpl, ctx.side, feats.side, params_used, ctx.scale, order=order, preset=preset,
                          gdist=gdist)
    gd, chosen, margin = greedy.positions, greedy.candidate, greedy.margin
    timings["greedy_s"] = time.perf_counter() - t1

    # Surface points of the greedy result (scan frame).
    inv = np.linalg.inv(to_model)
    tri = np.full(P, -1)
    bary = np.zeros((P, 3))
    source = ["prediction"] * P
    has = chosen >= 0
    tri[has], bary[has] = feats.triangle[chosen[has]], feats.bary[chosen[has]]
    for i in range(P):
        if has[i]:
            source[i] = "candidate"
    for i in preset:
        source[i] = "fixed" if names[i] in fixed else "seed"
    positions = gd.copy()
    peak = np.zeros(P)
    t2 = time.perf_counter()
    if params_used.refine:
        if scan_raster is None:
            scan_raster = frontal_raster(scan, rays, to_model, ctx.grid, texture=feats.textured)
        skip = np.array([names[i] in fixed for i in range(P)])
        pctx = pixel_context(ctx, scan_raster, params_used, textured=feats.textured, fixed=skip, gdist=gdist,
                             greedy_positions=gd)
        passes = [search_near_greedy, search_near_prediction, lower_lip_pass]
        if params_used.mouth_opening:
            passes += [mouth_opening_pass, lip_order_pass]
        est = PixelEstimates.empty(P)
        for pixel_pass in passes:
            est = est.apply(pixel_pass(pctx, est))
        pix, peak = est.pixel, est.peak.copy()
        for i in range(P):
            if not np.all(np.isfinite(pix[i])):
                continue
            c, r = int(pix[i, 0]), int(pix[i, 1])
            if not (0 <= r < scan_raster.triangle.shape[0] and 0 <= c < scan_raster.triangle.shape[1]):
                continue
            t = scan_raster.triangle[r, c]
            if t < 0:
                continue
            tri[i], bary[i] = t, scan_raster.bary[r, c]
            positions[i] = apply_transform((bary[i] @ scan.vertices[scan.triangles[t]])[None], to_model)[0]
            source[i] = "refined" if peak[i] > 0 else "prediction"
    timings["refine_s"] = time.perf_counter() - t2
    # Points still without a surface point (prediction, seeds, fixed): closest scan point.
    need = np.nonzero(tri < 0)[0]
    if len(need):
        p_scan = apply_transform(positions[need], inv)
        pos, t, b = rays.closest(p_scan)
        tri[need], bary[need] = t, b
        positions[need] = apply_transform(pos, to_model)
    # Confidence: appearance evidence x structural consistency (leave-one-out prediction).
    confidence = _confidence(ctx, positions, peak, margin, params_used, gdist)
    if params_used.lid_depth and params_used.refine and scan_raster is not None and scan_raster.depth is not None:
        if _upper_lid_pass(tpl, ctx, scan_raster, positions, confidence, fixed, tri, bary, source, peak):
            positions = _positions_from(scan, tri, bary, to_model, positions)
            confidence = _confidence(ctx, positions, peak, margin, params_used, gdist)
    if params_used.steep_prediction and params_used.refine:
        steep = steep_points(ctx) & np.array([n not in fixed for n in names])
        outline = np.array([n in tpl.base.outline for n in names])
        anchor = (confidence > ANCHOR_CONFIDENCE) & ~steep & ~outline & np.array([s in ("refined", "seed", "fixed") for s in source])
        if steep.any() and anchor.sum() >= 3:
            pred = _propagated(ctx.side.points, positions, anchor, params.sigma * ctx.scale, gdist)
            for i in np.nonzero(steep)[0]:
                source[i] = "prediction"
                peak[i] = 0.0
                hit = None if outline[i] else _raster_hit(scan_raster, pred[i])
                if hit is None:
                    pos, t, b = rays.closest(apply_transform(pred[i][None], inv))
                    tri[i], bary[i], positions[i] = t[0], b[0], apply_transform(pos, to_model)[0]
                else:
                    tri[i], bary[i] = hit
                    positions[i] = apply_transform((bary[i] @ scan.vertices[scan.triangles[tri[i]]])[None], to_model)[0]
            confidence = _confidence(ctx, positions, peak, margin, params_used, gdist)
    for i in preset:
        if names[i] in fixed:
            confidence[i] = 1.0
    timings["match_s"] = time.perf_counter() - t0
    return MatchResult(names, positions, tri, bary, confidence, source, gd, timings)


STEEP_NZ = 0.65          # model normal z below this (> ~50 deg from the view): steep in the frontal raster
ANCHOR_CONFIDENCE = 0.6  # matches above this confidence anchor the prediction of the steep points


def steep_points(ctx: ModelContext) -> np.ndarray:
    """(P,) bool: points whose model surface normal turns sideways away from the frontal view
    (z < STEEP_NZ, |x| >= |y|), except the mouth and eye points: those are textured features (lip and lid contours curl away
    from the view) that the patch search and the opening passes place. The lips are the mouth
    loop, the lip points and every point within 0.1 x scale of the mouth loop (outer lip corners)."""
    base = ctx.template.base
    names = ctx.template.detected
    features = set(base.mouth) | base.upper_lip_points | base.lower_lip_points
    for loop in base.eye_margins.values():
        features |= set(loop)
    loop = [names.index(n) for n in base.mouth if n in names]
    if loop:
        d = np.linalg.norm(ctx.side.points[:, None, :] - ctx.side.points[None, loop, :], axis=2).min(axis=1)
        features |= {n for n, di in zip(names, d) if di < 0.1 * ctx.scale}
    if ctx.normals is None:
        return np.zeros(len(names), bool)
    sideways = np.abs(ctx.normals[:, 0]) >= np.abs(ctx.normals[:, 1])   # not the chin's or nose's underside
    return (ctx.normals[:, 2] < STEEP_NZ) & sideways & np.array([n not in features for n in names])


LID_RECHECK = 0.5     # upper-lid matches below this confidence are checked against the depth profile
LID_FALL_MM = 0.5     # the lid's fall onto the eyeball is at least this steep (mm of depth per pixel row)


def _upper_lid_pass(tpl, ctx: ModelContext, raster: FrontalRaster, positions, confidence, fixed, tri, bary,
                    source, peak) -> bool:
    """Doubtful upper-lid points (confidence < LID_RECHECK) go to the foot of the lid's fall onto
    the eyeball, in the column at the model's horizontal offset from the lower-lid partner and
    within twice the model's lid gap above it: the steepest downward depth fall there (unscanned rows
    under an overhanging lid bridged linearly), followed down while it keeps falling (> 0.3 mm a row). Updates tri / bary / source / peak in place (the
    positions are recomputed by the caller); True if any point moved."""
    names = tpl.detected
    moved = False
    for loop in tpl.base.eye_margins.values():
        if len(loop) != 4 or loop[1] not in names or loop[3] not in names:
            continue
        i, j = names.index(loop[1]), names.index(loop[3])
        if confidence[i] >= LID_RECHECK or loop[1] in fixed:
            continue
        mu, ml = raster.to_pixel(ctx.side.points[[i, j]])
        pl = raster.to_pixel(positions[j])[0]
        gap = ml[1] - mu[1]
        col = int(round(pl[0] + mu[0] - ml[0]))
        top, bottom = int(round(pl[1] - 2 * gap)), int(round(pl[1] - 1))
        H, W = raster.depth.shape
        if gap < 2 or not (0 <= top and bottom < H and 0 <= col < W):
            continue
        d = raster.depth[top:bottom + 1, col].astype(float)
        ok = np.isfinite(d)
        if ok.sum() < 0.5 * len(d):
            continue
        # A few unscanned rows where the lid overhangs the eyeball: bridge them (the fall spans them).
        d = np.interp(np.arange(len(d)), np.nonzero(ok)[0], d[ok])
        g = np.diff(d)          # depth change going down one row (the viewer is at +z)
        s = int(np.argmin(g))
        if g[s] > -LID_FALL_MM:
            continue
        e = s
        while e + 1 < len(g) and g[e + 1] < -0.3:
            e += 1
        row = top + e + 1
        if raster.triangle[row, col] < 0:
            continue
        tri[i], bary[i] = raster.triangle[row, col], raster.bary[row, col]
        source[i], peak[i] = "refined", 0.5
        moved = True
    return moved


def _positions_from(scan: Face, tri, bary, to_model, positions) -> np.ndarray:
    """(P, 3) model-frame positions of the surface points (tri, bary) on ``scan`` (``positions`` where tri < 0)."""
    from core.registration.icp import apply_transform

    out = positions.copy()
    ok = tri >= 0
    p = np.einsum("pk,pkd->pd", bary[ok], scan.vertices[scan.triangles[tri[ok]]])
    out[ok] = apply_transform(p, to_model)
    return out


def _confidence(ctx: ModelContext, positions, peak, margin, params: MatchParams, gdist) -> np.ndarray:
    """(P,) the mean of the appearance evidence and the leave-one-out structural consistency."""
    P = len(positions)
    loo = np.zeros((P, 3))
    sigma = params.sigma * ctx.scale
    for i in range(P):
        m = np.ones(P, bool)
        m[i] = False
        loo[i] = _propagated(ctx.side.points, positions, m, sigma, gdist)[i]
    consistency = np.exp(-(np.linalg.norm(positions - loo, axis=1) / (0.1 * ctx.scale)) ** 2)
    evidence = np.clip(peak, 0, 1) if params.refine else np.clip(margin / 0.1, 0, 1)
    return 0.5 * evidence + 0.5 * consistency
