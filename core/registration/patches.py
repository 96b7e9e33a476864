"""Patch refinement: each matched point moved to where its model patch correlates best (normalised
cross-correlation of surface-normal and texture patches) in the scan's frontal raster.

Two passes (``matching`` runs them, then the mouth passes): round 1 searches around each greedy
match, round 2 around each point's structural prediction from the others."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from core.registration.templates import LandmarkTemplate
from core.registration.rasters import FrontalRaster
from core.registration.match_params import MatchParams
from core.registration.pass_results import PixelEstimates, PixelMoves

if TYPE_CHECKING:
    from core.registration.match_context import PixelContext


class PatchSearch:
    """Searches the scan raster for the model's patch around each landmark (NCC).

    halves : per landmark "full", "upper" or "lower": points on the inner lip contour and the lid
    margins are compared by the half of the patch on their own lip / lid (plus the seam row),
    because the other half may be the mouth or eye opening, which changes with the expression."""

    def __init__(self, model_points, model_raster: FrontalRaster, scan_raster: FrontalRaster, params: MatchParams,
                 halves: list[str], outline: list[bool] | None = None):
        self.px = params.pixel_mm
        self.h = max(2, int(round(params.patch_mm / 2 / self.px)))
        self.pad = 4 * self.h + 64
        pad = self.pad
        self.M = np.pad(model_raster.channels, ((pad, pad), (pad, pad), (0, 0)))
        self.S = np.pad(scan_raster.channels, ((pad, pad), (pad, pad), (0, 0)))
        self.Mv = np.pad(model_raster.triangle >= 0, pad)
        self.Sv = np.pad(scan_raster.triangle >= 0, pad)
        # At the outline the scan ends inside the patch; elsewhere only gaps (lip seam) do.
        self.min_cover = [0.9 if o else 0.4 for o in outline] if outline is not None else [0.4] * len(halves)
        self.mc = model_raster.to_pixel(model_points)
        self.scan_raster = scan_raster
        self.halves = halves
        self.pull = params.pull

    def nearest_covered(self, px) -> tuple[float, float]:
        """The covered scan pixel nearest to ``px`` (col, row) (NaN if none within 20 pixels)."""
        c, r = np.round(np.asarray(px, float)).astype(int) + self.pad
        win = self.Sv[max(r - 20, 0):r + 21, max(c - 20, 0):c + 21]
        yy, xx = np.nonzero(win)
        if not len(yy):
            return (np.nan, np.nan)
        r0, c0 = max(r - 20, 0), max(c - 20, 0)
        j = int(np.argmin((yy + r0 - r) ** 2 + (xx + c0 - c) ** 2))
        return (c0 + xx[j] - self.pad, r0 + yy[j] - self.pad)

    def ncc_window(self, k: int, centre_px, rx: int, ry: int):
        """(NCC map (2 ry + 1, 2 rx + 1) of landmark k's model patch placed at each pixel within
        rx / ry of ``centre_px`` (col, row), padded centre (sx, sy), patch rows (top, bottom)), or
        None when the window leaves the raster or the model point has no patch (edge of its surface)."""
        h, pad = self.h, self.pad
        if not np.all(np.isfinite(centre_px)):
            return None
        rx, ry = int(min(rx, pad - h - 2)), int(min(ry, pad - h - 2))
        mx, my = (np.round(self.mc[k]).astype(int) + pad)
        sx, sy = (np.round(np.asarray(centre_px)).astype(int) + pad)
        if not (0 <= mx - h and mx + h < self.M.shape[1] and 0 <= my - h and my + h < self.M.shape[0]
                and rx + h <= sx < self.S.shape[1] - rx - h and ry + h <= sy < self.S.shape[0] - ry - h):
            return None
        top, bottom = -h, h
        if self.halves[k] == "upper":
            bottom = 1
        elif self.halves[k] == "lower":
            top = -1
        patch = self.M[my + top:my + bottom + 1, mx - h:mx + h + 1]
        if self.Mv[my + top:my + bottom + 1, mx - h:mx + h + 1].mean() < 0.5:
            return None
        win = self.S[sy - ry + top:sy + ry + bottom + 1, sx - rx - h:sx + rx + h + 1]
        return _ncc(win, patch), (sx, sy), (top, bottom)

    def search(self, k: int, centre_px, rx: int, ry: int, pull_px=None):
        """Best pixel (col, row) for landmark k within (2 rx + 1) x (2 ry + 1) around ``centre_px``,
        penalised by pull x (distance to ``pull_px`` / r)^2; and its NCC. (None, 0) if impossible."""
        h, pad = self.h, self.pad
        found = self.ncc_window(k, centre_px, rx, ry)
        if found is None:
            return None, 0.0
        res, (sx, sy), (top, bottom) = found
        ry, rx = (np.array(res.shape) - 1) // 2
        yy, xx = np.mgrid[-ry:ry + 1, -rx:rx + 1]
        if pull_px is not None:
            off = np.asarray(pull_px, float) - np.asarray(centre_px, float)
            xx, yy = xx - off[0], yy - off[1]
        score = res - self.pull * (xx * xx / float(max(rx, 1) ** 2) + yy * yy / float(max(ry, 1) ** 2))
        iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
        by, bx = sy - ry + iy, sx - rx + ix                  # padded pixel of the best match
        cover = self.Sv[by + top:by + bottom + 1, bx - h:bx + h + 1]
        if cover.mean() < self.min_cover[k]:
            return None, 0.0   # the scan ends inside the patch (outline, holes): NCC is not reliable there
        if not self.Sv[by, bx]:  # a gap (lip seam): the nearest covered pixel of the patch
            cy, cx = np.nonzero(cover)
            j = int(np.argmin((cy + top) ** 2 + (cx - h) ** 2))
            by, bx = by + top + cy[j], bx - h + cx[j]
        return (bx - pad, by - pad), float(res[iy, ix])


def patch_halves(template: LandmarkTemplate) -> list[str]:
    """Per detected point: "upper" / "lower" for inner-lip and lid-margin points, else "full"."""
    base = template.base
    corners = {base.mouth[0]} | {base.mouth[len(base.mouth) // 2]}
    upper_lids = {"3.1", "3.2"}
    lower_lids = {"3.3", "3.4"}
    out = []
    for n in template.detected:
        if n in base.mouth and n not in corners and n in base.upper_lip_points or n in upper_lids:
            out.append("upper")
        elif n in base.mouth and n not in corners and n in base.lower_lip_points or n in lower_lids:
            out.append("lower")
        else:
            out.append("full")
    return out


def search_near_greedy(ctx: PixelContext, est: PixelEstimates) -> PixelMoves:
    """Round 1: each point's patch searched within ``ctx.radius_px`` of its greedy match
    (``est`` is not read: round 1 starts the estimates)."""
    out, peak = est.working()
    moved = []
    r = ctx.radius_px
    for k in range(len(ctx.template.detected)):
        if ctx.skip[k]:
            continue
        best, val = ctx.search.search(k, ctx.greedy_px[k], r, r)
        if best is not None:
            out[k], peak[k] = best, val
            moved.append(k)
    return PixelMoves.take(out, peak, moved)


def search_near_prediction(ctx: PixelContext, est: PixelEstimates) -> PixelMoves:
    """Round 2: each point predicted from the others (graph-distance Gaussian weights × their
    round-1 NCC, σ = ``sigma`` × scale) and searched in a window spanning the prediction and its
    round-1 pixel, pulled towards the prediction; mouth points get a taller window (the jaw moves
    them vertically). A result replaces round 1's unless its NCC is more than 0.05 lower; a point
    with no reliable patch anywhere (outline at the scan's edge) takes the covered pixel nearest
    the prediction, with no evidence."""
    template, skip, model_px, r = ctx.template, ctx.skip, ctx.model_px, ctx.radius_px
    P = len(template.detected)
    out, peak = est.working()
    moved = []
    pos_px = np.where(np.isfinite(est.pixel), est.pixel, ctx.greedy_px)
    sigma = ctx.params.sigma * ctx.scale
    mouth = {template.index(n) for n in template.base.mouth if n in template.detected}
    mouth |= {template.index(n) for n in template.base.upper_lip_points | template.base.lower_lip_points
              if n in template.detected}
    conf = np.clip(est.peak, 0.05, 1.0)
    conf[skip] = 1.0
    for k in range(P):
        if skip[k]:
            continue
        w = np.exp(-ctx.gdist[k] ** 2 / (2 * sigma * sigma)) * conf
        w[k] = 0.0
        if w.sum() < 1e-9:
            continue
        pred = model_px[k] + (w @ (pos_px - model_px)) / w.sum()
        centre = (pred + pos_px[k]) / 2
        span = np.abs(pred - pos_px[k]) / 2
        rx = int(np.ceil(span[0])) + r
        ry = int(np.ceil(span[1])) + (2 * r if k in mouth else r)
        best, val = ctx.search.search(k, centre, rx, ry, pull_px=pred)
        if best is not None and val >= peak[k] - 0.05:
            out[k], peak[k] = best, val
            moved.append(k)
        elif best is None and not np.all(np.isfinite(out[k])):
            out[k], peak[k] = ctx.search.nearest_covered(pred), 0.0
            moved.append(k)
    return PixelMoves.take(out, peak, moved)


def _ncc(win: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """Multi-channel normalised cross-correlation: OpenCV's TM_CCOEFF_NORMED with the sums taken
    over all channels together (cv2.matchTemplate itself takes at most 4 channels).
    win (Hw, Ww, C), patch (h, w, C) float32 -> (Hw - h + 1, Ww - w + 1)."""
    import cv2

    ph, pw = patch.shape[:2]
    n = float(ph * pw)
    ones = np.ones((ph, pw), np.float32)
    num = 0.0
    w_energy = 0.0
    t_energy = 0.0
    for c in range(patch.shape[2]):
        t = (patch[..., c] - patch[..., c].mean()).astype(np.float32)
        w = np.ascontiguousarray(win[..., c], dtype=np.float32)
        num = num + cv2.matchTemplate(w, t, cv2.TM_CCORR)           # sum W * (T - mean T)
        s1 = cv2.matchTemplate(w, ones, cv2.TM_CCORR)
        s2 = cv2.matchTemplate(w * w, ones, cv2.TM_CCORR)
        w_energy = w_energy + np.maximum(s2 - s1 * s1 / n, 0.0)
        t_energy += float((t * t).sum())
    den = np.sqrt(w_energy * t_energy)
    return np.where(den > 1e-6, num / np.maximum(den, 1e-6), -1.0)
