"""Brow pass (texture): the brow's top and outer end placed on the brow band, not by the patch search alone.

A brow is a dark band that looks the same all along its length, so the patch search slides along
it: on Surrey Face Model scans the top point 4.3/4.4 landed up to 10 mm along the brow, and the
outer end 4.5/4.6 (a steep-side prediction, nothing marks it in the shape) sat a few mm too far
out, where the temple turns away, ~6 mm behind the truth. Across the brow the band is sharp and
along it the band has two ends, so this pass follows the band in the scan's frontal raster:

* from the model's place of the top point relative to the eye's corners (where the brow is,
  whatever the patch search did) the band's middle row is followed both ways to its ends (the
  centre of the darkest run across it, column by column);
* the outer end goes to where the band ends outwards;
* the top point goes to the band's middle row at the model's fraction of the brow's length (from
  the inner brow point 4.1/4.2 to the outer end 4.5/4.6: 0.53 on the default face), measured
  between the band's two ends; left as it is when the band's ends are not both found.

Without texture (or with no dark band in the searched rows: fair brows) nothing moves: the shape
alone does not say where along the brow ridge the points are (placing them on the ridge at the
model's place relative to the untextured eye corners measured worse on SFM scans than the patch
search). Only the MPEG-4 brow points 4.3-4.6 move; a side is left alone when its eye corners or
brow points are not in the template or the eye width on the scan is not within 0.6-1.6 x the
model's; fixed points never move."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.registration.pass_results import MatchState, SurfaceMoves
from core.registration.rasters import FrontalRaster

if TYPE_CHECKING:
    from core.registration.match_context import MatchContext

#: Per side (MPEG-4 names): (brow top, brow outer end, outer eye corner, inner eye corner, brow inner end).
BROWS = (("4.3", "4.5", "3.7", "3.11", "4.1"), ("4.4", "4.6", "3.12", "3.8", "4.2"))
BROW_WINDOW = 0.1        # x face scale: rows searched above and below the point's current height
BAND_CONTRAST = 1.0      # the band is at least this much darker than the column's median (grey in std units)
END_WALK = 0.45          # x face scale: farthest the band's ends are followed from the top point (raised
                         # inner brows in fear reach ~30 mm in from the model's top point)
EYE_RATIO = (0.6, 1.6)   # scan / model eye width outside this: the eye corners are wrong, leave the side
BAND_EVIDENCE = 0.6      # a band seen in the texture (its place along the brow partly predicted)


def _column(values: np.ndarray, covered: np.ndarray, col: int, rows: np.ndarray) -> np.ndarray:
    """Mean of ``values`` over columns col-1..col+1 at ``rows``, NaN where uncovered; (len(rows),)."""
    W = values.shape[1]
    cols = np.clip(np.arange(col - 1, col + 2), 0, W - 1)
    ok = covered[np.ix_(rows, cols)] & np.isfinite(values[np.ix_(rows, cols)])
    total = np.where(ok, values[np.ix_(rows, cols)], 0.0).sum(axis=1)
    count = ok.sum(axis=1)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _smooth(profile: np.ndarray) -> np.ndarray:
    """3-row running mean ignoring NaN rows (they stay NaN)."""
    ok = np.isfinite(profile)
    v = np.where(ok, profile, 0.0)
    num = np.convolve(v, np.ones(3), "same")
    den = np.convolve(ok.astype(float), np.ones(3), "same")
    out = num / np.maximum(den, 1)
    out[~ok] = np.nan
    return out


def band_row(grey: np.ndarray, covered: np.ndarray, col: int, rows: np.ndarray) -> tuple[float, float] | None:
    """(row, contrast) of the centre of the darkest band in column ``col`` among ``rows``: the mean
    row of the run below half the contrast around the darkest row; contrast = median - darkest (grey
    std units). None when under BAND_CONTRAST or mostly uncovered."""
    p = _smooth(_column(grey, covered, col, rows))
    ok = np.isfinite(p)
    if ok.sum() < 0.6 * len(p):
        return None
    m = int(np.nanargmin(p))
    contrast = float(np.nanmedian(p) - p[m])
    if contrast < BAND_CONTRAST:
        return None
    return float(rows[0]) + _run_centre(p, m, float(np.nanmedian(p)) - contrast / 2), contrast


def _run_centre(p: np.ndarray, m: int, level: float) -> float:
    """Centre (index into ``p``) of the run of values below ``level`` that contains index ``m``."""
    lo = m
    while lo > 0 and p[lo - 1] < level:
        lo -= 1
    hi = m
    while hi + 1 < len(p) and p[hi + 1] < level:
        hi += 1
    return (lo + hi) / 2.0


def follow_band(grey: np.ndarray, covered: np.ndarray, col: int, row: float, contrast: float, step: int,
                max_cols: int) -> tuple[list[tuple[int, float]], bool]:
    """([(col, centre row)] from (col, row) going ``step`` (+1 / -1) column by column while the band
    is still darker than half ``contrast`` below the skin, ended): the band's middle row is followed
    (the darkest of +-3 rows of the previous one, then the centre of its dark run); ended is False
    when the band goes on beyond ``max_cols`` columns or the raster's edge."""
    H, W = grey.shape
    r = int(round(row))
    skin = None
    path = [(col, float(row))]
    for k in range(1, max_cols + 1):
        c = col + step * k
        if not 0 <= c < W:
            return path, False
        rows = np.arange(max(r - 12, 0), min(r + 13, H))
        p = _smooth(_column(grey, covered, c, rows))
        if not np.isfinite(p).any():
            return path, True
        if skin is None:
            skin = float(np.nanmedian(p))
        q = np.where(np.abs(rows - r) <= 3, p, np.nan)
        if not np.isfinite(q).any():
            return path, True
        m = int(np.nanargmin(q))
        if skin - q[m] < contrast / 2:
            return path, True
        centre = float(rows[0]) + _run_centre(p, m, skin - contrast / 2)   # the band's middle, not its edge
        r = int(round(centre))
        path.append((c, centre))
    return path, False


def band_ends(raster: FrontalRaster, grey: np.ndarray, point: np.ndarray, step: int, reach: int,
              half: int) -> tuple[int, int, list, list] | None:
    """(start col, start row, inwards path, outwards path) of the brow band through the column of
    ``point`` (model frame, its row +-``half`` searched), followed ``step`` (outwards) and back,
    ``reach`` columns at most each way; None when there is no band or either end is not found."""
    H, W = grey.shape
    covered = raster.triangle >= 0
    col, r = np.round(raster.to_pixel(point)[0]).astype(int)
    rows = np.arange(max(r - half, 0), min(r + half + 1, H))
    if not 0 <= col < W or len(rows) < 3:
        return None
    band = band_row(grey, covered, col, rows)
    if band is None:
        return None
    outwards, out_ended = follow_band(grey, covered, col, band[0], band[1], step, reach)
    inwards, in_ended = follow_band(grey, covered, col, band[0], band[1], -step, reach)
    return col, r, inwards if in_ended else None, outwards if out_ended else None


def model_band_fraction(model_ctx) -> float | None:
    """Where the model's brow top points lie along its own brow bands, 0 (inner end) .. 1 (outer
    end), measured on the model's frontal raster exactly as on the scan (so the template's
    convention and the band-end measurement's bias carry over), the mean of the sides where a band
    is found (a texture's two brows are not drawn exactly alike; faces are taken as symmetric);
    None without a band. Cached per model raster (the model context is cached per model)."""
    raster = model_ctx.raster
    hit = _MODEL_FRACTION.get(id(raster))
    if hit is not None and hit[0] is raster:
        return hit[1]
    if len(_MODEL_FRACTION) > 8:
        _MODEL_FRACTION.clear()
    fraction = _model_band_fraction(model_ctx)
    _MODEL_FRACTION[id(raster)] = (raster, fraction)
    return fraction


_MODEL_FRACTION: dict = {}


def _model_band_fraction(model_ctx) -> float | None:
    raster = model_ctx.raster
    if raster.channels.shape[-1] < 5:
        return None
    names = model_ctx.template.detected
    points = model_ctx.side.points
    scale = model_ctx.scale
    fractions = []
    for top_name, end_name, *_ in BROWS:
        if top_name not in names or end_name not in names:
            continue
        top, end = names.index(top_name), names.index(end_name)
        step = 1 if points[end, 0] > points[top, 0] else -1
        found = band_ends(raster, raster.channels[..., 3], points[top], step,
                          int(round(END_WALK * scale / raster.pixel)),
                          max(2, int(round(BROW_WINDOW * scale / raster.pixel))))
        if found is None or found[2] is None or found[3] is None:
            continue
        col, _, inwards, outwards = found
        c0, c1 = inwards[-1][0], outwards[-1][0]
        if c1 != c0:
            fractions.append((col - c0) / (c1 - c0))
    return float(np.mean(fractions)) if fractions else None


def brow_pass(ctx: MatchContext, state: MatchState, confidence: np.ndarray) -> SurfaceMoves:
    """Moves of the brow tops and outer ends onto the texture's brow band (see the module
    docstring); surface points from the scan's frontal raster, source "refined", evidence
    BAND_EVIDENCE. ``confidence`` (P,) is not used (every brow top is checked)."""
    raster: FrontalRaster | None = ctx.scan_raster
    if raster is None or not ctx.textured or raster.channels.shape[-1] < 5:
        return SurfaceMoves.none()
    tpl = ctx.model.template
    names = tpl.detected
    model = ctx.model.side.points
    scale = ctx.model.scale
    covered = raster.triangle >= 0
    grey = raster.channels[..., 3]        # normalised luminance (frontal_raster: grey after the 3 normals)
    H, W = raster.triangle.shape
    half = max(2, int(round(BROW_WINDOW * scale / raster.pixel)))
    index, tri, bary = [], [], []

    def place(i: int, col: int, row: float) -> None:
        r = int(round(row))
        if 0 <= r < H and 0 <= col < W and covered[r, col] and not ctx.fixed[i]:
            index.append(i)
            tri.append(int(raster.triangle[r, col]))
            bary.append(raster.bary[r, col])

    for side in BROWS:
        if any(n not in names for n in side):
            continue
        top, end, outer, inner, brow_inner = (names.index(n) for n in side)
        model_width = model[outer, 0] - model[inner, 0]
        scan_width = state.positions[outer, 0] - state.positions[inner, 0]
        if abs(model_width) < 1e-6 or not EYE_RATIO[0] <= scan_width / model_width <= EYE_RATIO[1]:
            continue
        # Search around the model's place relative to the eye's corners (not the patch search's,
        # which may have slid along the band), at the point's current height.
        x_eye = state.positions[inner, 0] + (model[top, 0] - model[inner, 0]) * scan_width / model_width
        step = 1 if model[end, 0] > model[top, 0] else -1
        found = band_ends(raster, grey, np.array([x_eye, state.positions[top, 1], 0.0]), step,
                          int(round(END_WALK * scale / raster.pixel)), half)
        if found is None:
            continue
        _, _, inwards, outwards = found
        if outwards is not None:
            place(end, *outwards[-1])
        frac = model_band_fraction(ctx.model)
        if frac is None:   # the model has no brow band: its template points' fraction instead
            frac = (model[top, 0] - model[brow_inner, 0]) / (model[end, 0] - model[brow_inner, 0])
        if inwards is not None and outwards is not None:
            # The top at the model's fraction of the brow band's length (inner to outer end).
            band_cols = dict(inwards[::-1] + outwards)
            c0, c1 = inwards[-1][0], outwards[-1][0]
            c = int(round(c0 + frac * (c1 - c0)))
            if c in band_cols:
                place(top, c, band_cols[c])
    n = len(index)
    return SurfaceMoves(index, tri, bary, source=["refined"] * n, evidence=[BAND_EVIDENCE] * n)
