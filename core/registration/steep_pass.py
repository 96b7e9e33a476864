"""Steep-side pass: points where the model's surface turns sideways away from the frontal view
follow the confident matches instead of the patch search.

There the frontal raster is foreshortened and nearly textureless, so the patch search lands a few
mm off laterally, which on a steep side is 10-20 mm along the surface (temples, jaw angle, face
border, outer brow ends). Their prediction from the confident non-steep matches is put on the
scan: outline points at the closest scan point (the prediction's depth is trusted: the face border
is where the side turns away), the others at the scan surface seen at the prediction's frontal
pixel (measured on 3 synthetic people: closest point is better for the outline, the frontal ray
for the brows)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.registration.greedy import propagated
from core.registration.pass_results import MatchState, SurfaceMoves
from core.registration.rasters import raster_hit

if TYPE_CHECKING:
    from core.registration.match_context import MatchContext, ModelContext

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


def steep_pass(ctx: MatchContext, state: MatchState, confidence: np.ndarray) -> SurfaceMoves:
    """The steep, non-fixed points re-predicted from the anchors (confidence (P,) > ANCHOR_CONFIDENCE,
    not steep, not outline, source refined / seed / fixed; the graph-distance Gaussian propagation
    of ``greedy``, σ = ``sigma`` × scale) and put on the scan; source "prediction", evidence 0.
    No moves unless there are steep points and at least 3 anchors."""
    m = ctx.model
    steep = steep_points(m) & ~ctx.fixed
    if not steep.any():
        return SurfaceMoves.none()
    pred = anchor_prediction(ctx, state, confidence, steep)
    if pred is None:
        return SurfaceMoves.none()
    outline = np.array([n in m.template.base.outline for n in m.template.detected])
    return predictions_on_scan(ctx, np.nonzero(steep)[0], pred, outline)


def anchor_prediction(ctx: MatchContext, state: MatchState, confidence: np.ndarray,
                      excluded: np.ndarray) -> np.ndarray | None:
    """(P, 3) model frame, mm: every point predicted from the anchors (confidence (P,) >
    ANCHOR_CONFIDENCE, source refined / opening / seed / fixed, not on the outline, not ``excluded``
    (P,) bool) by the graph-distance Gaussian propagation of ``greedy``, σ = ``sigma`` × scale;
    None with fewer than 3 anchors."""
    m = ctx.model
    outline = np.array([n in m.template.base.outline for n in m.template.detected])
    anchor = (confidence > ANCHOR_CONFIDENCE) & ~excluded & ~outline & np.array(
        [s in ("refined", "opening", "seed", "fixed") for s in state.source])
    if anchor.sum() < 3:
        return None
    return propagated(m.side.points, state.positions, anchor, ctx.params.sigma * m.scale, ctx.gdist)


def predictions_on_scan(ctx: MatchContext, points, pred: np.ndarray, closest: np.ndarray) -> SurfaceMoves:
    """Moves putting each of ``points`` at its prediction ``pred`` (P, 3) on the scan: those marked
    in ``closest`` (P,) bool (the steep pass: outline points) at the closest scan point, the others
    at the surface seen at the prediction's frontal pixel (the closest point where none is); source
    "prediction", evidence 0."""
    index, tri, bary, pos = [], [], [], []
    for i in points:
        hit = None if closest[i] else raster_hit(ctx.scan_raster, pred[i])
        if hit is None:
            t, b, p = ctx.closest(pred[i][None])
            t, b, p = t[0], b[0], p[0]
        else:
            t, b = hit
            p = ctx.surface_position(t, b)
        index.append(i)
        tri.append(t)
        bary.append(b)
        pos.append(p)
    n = len(index)
    return SurfaceMoves(index, tri, bary, pos, source=["prediction"] * n, evidence=[0.0] * n)
