"""Outlier pass: a point the evidence does not support, far from where the confident matches put
it, follows them.

Without texture (the geometry-only path) the patch search compares shape alone, and a featureless
point such as an outer eye corner can latch onto the brow ridge or the temple 12-20 mm away (SFM
virtual scans, untextured: 3.7/3.12 at confidence 0.18-0.3). Such a point is re-predicted from the
anchors (the steep pass's propagation of the confident matches' displacements along the template
graph) and put on the scan at the point closest to that prediction; its source becomes
"prediction" and its evidence 0, so it stays low confidence and the picker lists it for checking."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.registration.greedy import propagated
from core.registration.pass_results import MatchState, SurfaceMoves
from core.registration.steep_pass import ANCHOR_CONFIDENCE, predictions_on_scan, steep_points

if TYPE_CHECKING:
    from core.registration.match_context import MatchContext

OUTLIER_CONFIDENCE = 0.3   # below this a point's evidence is weak (its confidence is a mean of NCC and distance terms)
OUTLIER_DISTANCE = 0.1     # x face scale: farther than this from its prediction (the evaluation's tolerance)
# A point this far from its prediction (x face scale: three tolerances, ~27 mm on an adult) has lost
# its place unless its evidence is strong (confidence >= LOST_CONFIDENCE, the level below which the
# picker lists a point as low confidence): steep and outline points too, which are otherwise left to
# the steep pass and the outline. SFM person 2, textured neutral: the lower face's patch matches landed
# ~65 mm high, and the chin 2.1 (an outline point, confidence 0.42 there) stayed on the upper lip 70 mm
# off, the nose wing 9.5 (0.39) on the brow 58 mm off.
GROSS_DISTANCE = 0.3
LOST_CONFIDENCE = 0.5


def outlier_pass(ctx: MatchContext, state: MatchState, confidence: np.ndarray) -> SurfaceMoves:
    """Points (not fixed, not steep: the steep pass places those; not on the mouth opening's
    edges: source "opening") with confidence (P,) below
    OUTLIER_CONFIDENCE and more than OUTLIER_DISTANCE x scale from their prediction by the anchors
    (confidence > ANCHOR_CONFIDENCE, refined / seed / fixed, and every "opening" point) go to that
    prediction on the scan.
    No moves with fewer than 3 anchors."""
    m = ctx.model
    names = m.template.detected
    steep = steep_points(m)
    outline = np.array([n in m.template.base.outline for n in names])
    # Points on the mouth opening's edges are placed by the scan's shape: they anchor the
    # prediction whatever their confidence (an open mouth's lower lip follows them, not the closed
    # model's; SFM surprise, untextured: 8.2 10 -> 5.5 mm) and are never moved themselves.
    opening = np.array([s == "opening" for s in state.source])
    anchor = ((confidence > ANCHOR_CONFIDENCE) & ~steep & ~outline & np.array(
        [s in ("refined", "opening", "seed", "fixed") for s in state.source])) | opening
    if anchor.sum() < 3:
        return SurfaceMoves.none()
    pred = propagated(m.side.points, state.positions, anchor, ctx.params.sigma * m.scale, ctx.gdist)
    off = np.linalg.norm(state.positions - pred, axis=1)
    far, lost = off > OUTLIER_DISTANCE * m.scale, off > GROSS_DISTANCE * m.scale
    weak = (((confidence < OUTLIER_CONFIDENCE) & far & ~steep) | ((confidence < LOST_CONFIDENCE) & lost)) \
        & ~anchor & ~ctx.fixed
    if not weak.any():
        return SurfaceMoves.none()
    # At the closest scan point, not the frontal ray: beside the eye the surface turns away from the
    # view, and a ray through a prediction a few mm off lands far back on the temple.
    return predictions_on_scan(ctx, np.nonzero(weak)[0], pred, np.ones(len(names), bool))
