"""Upper-lid depth pass: a doubtful upper-lid match goes to the foot of the lid's fall onto the eyeball.

Brows lowered onto the lid (as in anger) fit the lid's patch, so the patch search can put the
upper-lid point on the brow; the frontal depth profile does not confuse them: going down the
column the surface falls steeply from the lid onto the eyeball."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.registration.pass_results import MatchState, SurfaceMoves

if TYPE_CHECKING:
    from core.registration.match_context import MatchContext

LID_RECHECK = 0.5     # upper-lid matches below this confidence are checked against the depth profile
LID_FALL_MM = 0.5     # the lid's fall onto the eyeball is at least this steep (mm of depth per pixel row)


def upper_lid_pass(ctx: MatchContext, state: MatchState, confidence: np.ndarray) -> SurfaceMoves:
    """Doubtful upper-lid points (confidence (P,) < LID_RECHECK, not fixed) go to the foot of the
    lid's fall onto the eyeball, in the column at the model's horizontal offset from the lower-lid
    partner and within twice the model's lid gap above it: the steepest downward depth fall there
    (unscanned rows under an overhanging lid bridged linearly), followed down while it keeps
    falling (> 0.3 mm a row). Moves give surface points only (source "refined", evidence 0.5)."""
    raster = ctx.scan_raster
    if raster is None or raster.depth is None:
        return SurfaceMoves.none()
    tpl = ctx.model.template
    names = tpl.detected
    points = ctx.model.side.points
    index, tri, bary = [], [], []
    for loop in tpl.base.eye_margins.values():
        if len(loop) != 4 or loop[1] not in names or loop[3] not in names:
            continue
        i, j = names.index(loop[1]), names.index(loop[3])
        if confidence[i] >= LID_RECHECK or ctx.fixed[i]:
            continue
        mu, ml = raster.to_pixel(points[[i, j]])
        pl = raster.to_pixel(state.positions[j])[0]
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
        index.append(i)
        tri.append(raster.triangle[row, col])
        bary.append(raster.bary[row, col])
    return SurfaceMoves(index, tri, bary, source=["refined"] * len(index), evidence=[0.5] * len(index))
