"""Structural landmark matching (thesis A §3.2, Algorithm 1) with Mimica's refinements.

This module runs the match (``match``): it builds the context the passes read, runs each pass
and applies what the pass returns, in one place. Beside it: ``match_params`` (parameters),
``match_context`` (what the passes read), ``pass_results`` (what they return, and the match's
state), ``scan_features`` (the scan's candidates and seeds), ``rasters`` (frontal rasters),
``greedy`` (the thesis's greedy matcher), ``patches`` (NCC patch search), ``mouth_passes`` (lower
lip, mouth opening, lip order), ``surface_points`` (pixels onto the scan surface), ``lid_pass``,
``steep_pass`` and ``confidence``.

Order of the passes: greedy -> patch search round 1 and 2 -> lower lip -> mouth opening -> lip
order (closed mouths only; in the scan's frontal raster) -> onto the surface -> closest-point snap -> confidence ->
upper lid -> steep sides -> eyes (``eye_pass``) -> brows (``brow_pass``) -> outliers (``outlier_pass``; each followed by the confidence again) ->
flat evidence (``ambiguity``) -> fixed points' confidence 1.

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
  half their model distance below the lower lip are searched again on the right side. The points
  put on the opening's edges (inner lip, corners at its tips) get the source "opening": the
  outlier pass leaves them where the shape put them. A closed
  mouth (no step, or an opening under 1.5 mm) leaves the patch-search result, except that a lower
  inner-lip point found on the lower outer lip (pressed lips) goes back to the seam, at the
  model's offset below the upper outer lip;
* ``lid_depth`` (``lid_pass``): a doubtful upper-lid point (confidence < ``LID_RECHECK``; brows lowered onto the
  lid, as in anger, fit the lid patch) goes to the foot of the lid's depth fall onto the eyeball,
  searched in its column above the lower-lid point;
* ``steep_prediction`` (``steep_pass``): where the model's surface turns sideways away from the frontal view
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
* ``eyes`` (``eye_pass``): each eye found as a whole (its box of surface normals, NCC over a few
  sizes); eye points far from where it puts them go there, and a closed eye (its texture closer
  to the model's with the lids closed) gets its upper lid on the lid line; without texture, an eye
  whose region shows no eye shape (no lid or eyeball relief) has its points predicted from the
  confident non-eye points instead (source "prediction");
* ``brows`` (``brow_pass``, textured scans): the brow is a band that looks the same along its
  length, so the patch search slides along it; the band's middle row is followed both ways from
  the model's place relative to the eye's corners to its ends: the outer end 4.5/4.6 goes to the
  band's outer end, the top 4.3/4.4 to the model's own fraction of its band's length;
* no texture: geometry candidates (farthest-point samples) and appearance from HK and shape
  only; the caller reports it.

Confidence (0..1, heuristic, not a probability): the mean of the NCC peak (clipped to [0, 1])
and exp(−(d / 0.1·scale)²) where d is the distance of the final point from its structural
prediction (from the other matches); without refinement the NCC term is replaced by the greedy
cost margin between the best and the second-best candidate elsewhere (> 0.1 × scale away).
The reported confidence of a point still where the patch search put it has that NCC term scaled
by the peak's distinctness (``ambiguity``: a patch that fits as well 0.05-0.15 × scale away, as
along an untextured brow ridge, is no evidence of where the point is); positions are not changed.

Face scale: the distance between the outer eye corners 3.7 and 3.12 of the model (91 mm on the
default face); without them, 0.66 × the model's skin bounding-box width.
"""

from __future__ import annotations

import time

import numpy as np

from core.face import Face
from core.registration.rasters import (  # noqa: F401 - re-exported
    FrontalRaster, Grid, grid_for, frontal_raster, Side, sample_texture, sample_vertex_values)
from core.registration.greedy import (  # noqa: F401 - re-exported
    face_scale, match_order, graph_distances, greedy_match)
from core.registration.match_params import (  # noqa: F401 - re-exported
    HK_SMOOTHING_MM, MatchingError, MatchParams)
from core.registration.match_context import (  # noqa: F401 - re-exported
    MatchContext, ModelContext, match_context, model_context, pixel_context)
from core.registration.pass_results import (  # noqa: F401 - re-exported
    GreedyMatch, MatchResult, MatchState, PixelEstimates, PixelMoves, SurfaceMoves)
from core.registration.scan_features import (  # noqa: F401 - re-exported
    SEED_POINTS, InputFeatures, geometry_params, input_features, preset_points)
from core.registration.patches import search_near_greedy, search_near_prediction
from core.registration.mouth_passes import lip_order_pass, lower_lip_pass, mouth_opening_pass, opening_points
from core.registration.surface_points import pixels_to_surface, snap_to_surface
from core.registration.confidence import match_confidence
from core.registration.lid_pass import upper_lid_pass
from core.registration.steep_pass import steep_pass, steep_points  # noqa: F401 - re-exported
from core.registration.outlier_pass import outlier_pass
from core.registration.brow_pass import brow_pass
from core.registration.eye_pass import eye_pass
from core.registration.ambiguity import distinctness


def match(scan: Face, to_model: np.ndarray, ctx: ModelContext, params: MatchParams, *, rays,
          fixed: dict[str, np.ndarray] | None = None, features: InputFeatures | None = None,
          report: list | None = None, scan_raster: FrontalRaster | None = None) -> MatchResult:
    """Match ``ctx``'s template points on ``scan`` (aligned to the model by ``to_model``).

    features / scan_raster : precomputed (they do not depend on λ's; the evaluation sweeps λ).

    fixed : name -> position on the scan (scan frame, mm): kept as they are.
    rays : correspondence.SurfaceRays over the scan (its own frame).
    """
    report = report if report is not None else []
    timings = {}
    t0 = time.perf_counter()
    names = ctx.template.detected
    P = len(names)
    feats = features or input_features(scan, to_model, params)
    report += feats.report
    used = params if feats.textured else geometry_params(params)
    timings["features_s"] = time.perf_counter() - t0
    if features is None:
        timings.update(feats.timings)

    fixed = fixed or {}
    preset = preset_points(ctx, feats, fixed, to_model, report)
    is_fixed = np.array([n in fixed for n in names])
    t1 = time.perf_counter()
    gdist = graph_distances(ctx.template, ctx.side.points)
    greedy = greedy_match(ctx.template, ctx.side, feats.side, used, ctx.scale,
                          order=match_order(ctx.template, ctx.side.points, list(preset)), preset=preset, gdist=gdist)
    timings["greedy_s"] = time.perf_counter() - t1
    state = _greedy_state(greedy, feats, preset, is_fixed)

    t2 = time.perf_counter()
    if used.refine and scan_raster is None:
        scan_raster = frontal_raster(scan, rays, to_model, ctx.grid, texture=feats.textured)
    mctx = match_context(ctx, scan, to_model, rays, used, textured=feats.textured, fixed=is_fixed, gdist=gdist,
                         scan_raster=scan_raster if used.refine else None)
    if used.refine:
        pctx = pixel_context(mctx, greedy.positions)
        passes = [search_near_greedy, search_near_prediction, lower_lip_pass]
        if used.mouth_opening:
            passes += [mouth_opening_pass, lip_order_pass]
        est = PixelEstimates.empty(P)
        if is_fixed.any():
            # The user's points are where they were given, with full evidence: the passes that read a
            # neighbour's pixel see them there (the closed mouth's lip order reads the outer corners and
            # lips; with those fixed and left without a pixel it did nothing, and an inner corner stayed
            # 13 mm above its outer one on a Surrey Face Model scan), and predictions lean on them.
            pixel, peak = est.working()
            pixel[is_fixed], peak[is_fixed] = pctx.greedy_px[is_fixed], 1.0
            est = est.apply(PixelMoves.take(pixel, peak, np.nonzero(is_fixed)[0]))
        edge_points = opening_points(ctx.template)
        on_opening = np.zeros(P, bool)
        for pixel_pass in passes:
            if pixel_pass is lip_order_pass and on_opening.any():
                continue   # the lip order is for a closed mouth; an open one's lips are on its edges
            moves = pixel_pass(pctx, est)
            est = est.apply(moves)
            on_opening[moves.index] = (pixel_pass is mouth_opening_pass) & edge_points[moves.index]
            if pixel_pass is search_near_prediction:
                patch_pixel = est.pixel    # where the patch search itself put each point
        # Every point's evidence is its final NCC; those on the covered scan raster move there.
        state = _apply(mctx, state.replace(evidence=est.peak), pixels_to_surface(mctx, est))
        # Points on the mouth opening's edges are placed by the scan's shape: source "opening".
        state = state.replace(source=tuple("opening" if on_opening[i] and s == "refined" else s
                                           for i, s in enumerate(state.source)))
    timings["refine_s"] = time.perf_counter() - t2
    state = _apply(mctx, state, snap_to_surface(mctx, state))
    after_patches = state

    confidence = match_confidence(mctx, state.positions, state.evidence, greedy.margin)
    surface_passes = []
    if used.lid_depth and used.refine:
        surface_passes.append(upper_lid_pass)
    if used.steep_prediction and used.refine:
        surface_passes.append(steep_pass)
    if used.eyes and used.refine:
        surface_passes.append(eye_pass)      # before the brows: the brow pass starts from the eye corners
    if used.brows and used.refine:
        surface_passes.append(brow_pass)
    if used.outliers and used.refine:
        surface_passes.append(outlier_pass)
    for surface_pass in surface_passes:
        moves = surface_pass(mctx, state, confidence)
        if len(moves):
            state = _apply(mctx, state, moves)
            confidence = match_confidence(mctx, state.positions, state.evidence, greedy.margin)
    if used.refine and used.ambiguity:
        # Points still where the patch search put them: is their peak distinct (ambiguity module)?
        # Only the reported confidence changes; the passes above read the plain one.
        placed = (np.all(est.pixel == patch_pixel, axis=1) & (est.peak > 0) & ~is_fixed
                  & (state.triangle == after_patches.triangle) & np.all(state.bary == after_patches.bary, axis=1))
        distinct = distinctness(pctx.search, scan_raster.to_pixel(state.positions), placed, pctx.scale_px)
        confidence = match_confidence(mctx, state.positions, state.evidence * distinct, greedy.margin)
    confidence[is_fixed] = 1.0
    timings["match_s"] = time.perf_counter() - t0
    return MatchResult(names, state.positions.copy(), state.triangle.copy(), state.bary.copy(), confidence,
                       list(state.source), greedy.positions.copy(), timings)


def _greedy_state(greedy: GreedyMatch, feats: InputFeatures, preset: dict, is_fixed: np.ndarray) -> MatchState:
    """The match after the greedy pass: candidates' surface points, preset points (seeds, fixed)
    and predictions without one yet (triangle −1), no evidence."""
    P = len(greedy.candidate)
    tri = np.full(P, -1)
    bary = np.zeros((P, 3))
    has = greedy.candidate >= 0
    tri[has], bary[has] = feats.triangle[greedy.candidate[has]], feats.bary[greedy.candidate[has]]
    source = ["candidate" if h else "prediction" for h in has]
    for i in preset:
        source[i] = "fixed" if is_fixed[i] else "seed"
    return MatchState(greedy.positions.copy(), tri, bary, tuple(source), np.zeros(P))


def _apply(ctx: MatchContext, state: MatchState, moves: SurfaceMoves) -> MatchState:
    """The one place where a pass's moves change the match. Moves with surface points only (the lid
    pass) have every point's position derived again from its surface point, all in one batch."""
    out = state.apply(moves)
    if moves.position is None and len(moves):
        out = out.replace(positions=ctx.surface_positions(out.triangle, out.bary, out.positions))
    return out
