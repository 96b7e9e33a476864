"""Landmarks put on the scan surface: pixels of the scan's frontal raster lifted to the surface seen
there, and points still without a surface point snapped to the closest one."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.registration.pass_results import MatchState, PixelEstimates, SurfaceMoves

if TYPE_CHECKING:
    from core.registration.match_context import MatchContext


def pixels_to_surface(ctx: MatchContext, est: PixelEstimates) -> SurfaceMoves:
    """Each point with a pixel (col, row; truncated to the pixel holding it) on the covered scan
    raster moves to the surface point seen there; source "refined" when it has evidence (peak > 0),
    else "prediction". Evidence is not part of the moves (the caller takes ``est.peak`` for all).
    Fixed points keep their given place (their pixel is only for the passes to read)."""
    raster = ctx.scan_raster
    H, W = raster.triangle.shape
    index, tri, bary, pos, source = [], [], [], [], []
    for i in range(len(est.pixel)):
        if ctx.fixed[i] or not np.all(np.isfinite(est.pixel[i])):
            continue
        c, r = int(est.pixel[i, 0]), int(est.pixel[i, 1])
        if not (0 <= r < H and 0 <= c < W):
            continue
        t = raster.triangle[r, c]
        if t < 0:
            continue
        b = raster.bary[r, c]
        index.append(i)
        tri.append(t)
        bary.append(b)
        pos.append(ctx.surface_position(t, b))
        source.append("refined" if est.peak[i] > 0 else "prediction")
    return SurfaceMoves(index, tri, bary, pos, source=source)


def snap_to_surface(ctx: MatchContext, state: MatchState) -> SurfaceMoves:
    """Points without a surface point (predictions, seeds, fixed points) go to the closest scan
    point (sources and evidence unchanged)."""
    need = np.nonzero(state.triangle < 0)[0]
    if not len(need):
        return SurfaceMoves.none()
    tri, bary, pos = ctx.closest(state.positions[need])
    return SurfaceMoves(need, tri, bary, pos)
