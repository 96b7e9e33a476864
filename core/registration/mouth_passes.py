"""Mouth passes of the matcher, in the scan's frontal raster (after the patch search, in this
order): the lower lip searched below the upper lip where the jaw went (``lower_lip_pass``), the
inner lip points of an open mouth put on the opening's depth steps (``mouth_opening_pass``), a
closed mouth's lip order restored (``lip_order_pass``: an upper outer-lip point below the seam searched
again above it, a lower inner-lip point collapsed onto the outer lip brought back to the seam, the
inner-lip points spaced along the seam as on the model and the inner corners kept beside the outer ones).

Each reads a ``PixelContext`` and the current ``PixelEstimates`` and returns ``PixelMoves``; pixels
are (col, row), rows grow downwards. A pass works on a copy of the estimates because its later
points read where its earlier ones went (e.g. an outer lower-lip point stays below the inner one)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from core.registration.pass_results import PixelEstimates, PixelMoves

if TYPE_CHECKING:
    from core.registration.match_context import PixelContext


def lip_order_pass(ctx: PixelContext, est: PixelEstimates) -> PixelMoves:
    """Closed-mouth lip order: an upper outer-lip point found below the seam (the upper inner-lip
    point nearest its column) is searched again above it, at the model's lip height (its patch
    within half that height; where none fits above the seam, the covered pixel at that height with
    evidence 0); a lower inner-lip point found on (or below) the lower outer lip goes back above it.

    On a pressed, closed mouth there is no opening and the lower-lip patch fits the lower outer
    lip's edge as well; the inner point then collapses onto the outer one. The inner point is kept
    at least half the model's inner-to-outer lip height above the outer point, at the model's
    offset below the upper outer lip (the lips touch: it is the seam); its evidence becomes 0.
    Then the inner-lip points go where the model spaces them along the seam (:func:`_on_the_seam`)."""
    template, search, model_px, skip = ctx.template, ctx.search, ctx.model_px, ctx.skip
    out, peak = est.working()
    moved = []
    base = template.base
    names = template.detected
    loop = [template.index(n) for n in base.mouth if n in names]
    if len(loop) < 4:
        return PixelMoves.take(out, peak, moved)
    corners = {loop[0], loop[len(loop) // 2]}
    upper = {template.index(n) for n in base.upper_lip_points if n in names}
    lower = {template.index(n) for n in base.lower_lip_points if n in names}
    lower_in = [i for i in loop if i not in corners and i not in upper]
    upper_out = [i for i in upper if i not in loop and np.all(np.isfinite(out[i]))]
    lower_out = [i for i in lower if i not in loop and np.all(np.isfinite(out[i]))]
    if not upper_out or not lower_out:
        return PixelMoves.take(out, peak, moved)
    upper_in = [i for i in loop if i not in corners and i in upper and np.all(np.isfinite(out[i]))]
    for u in upper_out if upper_in else []:
        # An upper outer-lip point below the seam is on the lower lip (whose rounded edge fits the
        # upper lip's patch in shape alone): searched again at the model's height above the seam.
        if skip[u]:
            continue
        k = min(upper_in, key=lambda i: abs(model_px[i, 0] - model_px[u, 0]))
        height = model_px[k, 1] - model_px[u, 1]       # rows grow downwards
        if height <= 1 or out[u, 1] <= out[k, 1]:
            continue
        centre = (out[u, 0], out[k, 1] - height)
        best, val = search.search(u, centre, 2, max(1, int(height // 2)), pull_px=centre)
        if best is None or best[1] >= out[k, 1]:
            best, val = search.nearest_covered(centre), 0.0
        if np.all(np.isfinite(best)):
            out[u], peak[u] = best, val
            moved.append(u)
    for k in lower_in:
        if skip[k] or not np.all(np.isfinite(out[k])):
            continue
        o = min(lower_out, key=lambda i: abs(model_px[i, 0] - model_px[k, 0]))
        u = min(upper_out, key=lambda i: abs(model_px[i, 0] - model_px[k, 0]))
        gap = model_px[o, 1] - model_px[k, 1]        # rows grow downwards
        if gap <= 1 or out[k, 1] <= out[o, 1] - 0.5 * gap:
            continue
        row = min(out[u, 1] + (model_px[k, 1] - model_px[u, 1]), out[o, 1] - 0.5 * gap)
        hit = search.nearest_covered((out[k, 0], row))
        if np.all(np.isfinite(hit)):
            out[k], peak[k] = hit, 0.0
            moved.append(k)
    _on_the_seam(template, out, peak, moved, skip, model_px, loop, corners, upper_in, lower_in, search)
    return PixelMoves.take(out, peak, moved)


def _on_the_seam(template, out, peak, moved, skip, model_px, loop, corners, upper_in, lower_in, search) -> None:
    """A closed mouth's inner-lip points, spaced as on the model: each at the model's horizontal
    fraction between the inner corners, on its contour's line (through the corners and that
    contour's points) -- where the lips touch both lines are the seam, and an upper point and the
    lower one below it on the model become one point.

    The patch search leaves the lower inner-lip points wherever along the seam a patch fitted best
    (Mimica's synthetic scans: 2.8 / 2.9 3.7-4.1 mm mean error, up to 11 mm); registered with the
    upper ones elsewhere along the same line, the two lips' rows interleave and pass through each
    other. An inner corner farther than ``CORNER_SLACK`` x the mouth's width from where the model
    puts it beside its outer corner goes there first (evidence 0)."""
    c0, c1 = loop[0], loop[len(loop) // 2]
    span_model = model_px[c1, 0] - model_px[c0, 0]
    names = template.detected
    outer = [template.index(n) for n in OUTER_CORNERS if n in names]
    for c in (c0, c1) if outer else ():
        # Closed, the inner corner is at the commissure, next to the outer one (the model's offset):
        # found farther from there than CORNER_SLACK x the mouth's width it is somewhere else. (A
        # safeguard, as _place_corners is for open mouths: it moved no corner on the synthetic or SFM
        # scans measured; SFM's 2.5 that ends 10 mm below 8.4 gets there in a later pass.)
        o = min(outer, key=lambda i: abs(model_px[i, 0] - model_px[c, 0]))
        expected = out[o] + (model_px[c] - model_px[o])
        if skip[c] or not np.all(np.isfinite(expected)):
            continue
        if not np.all(np.isfinite(out[c])) or np.linalg.norm(out[c] - expected) > CORNER_SLACK * abs(span_model):
            hit = search.nearest_covered(expected) if search is not None else expected
            if np.all(np.isfinite(hit)):
                out[c], peak[c] = hit, 0.0
                moved.append(c)
    if abs(span_model) < 1 or not (np.all(np.isfinite(out[c0])) and np.all(np.isfinite(out[c1]))):
        return
    for contour in (upper_in, lower_in):
        # Each contour stays on its own line (through the corners and its points): where the lips
        # touch both lines are the seam; a mouth parted by less than an opening's step keeps its gap.
        on_line = [c0, c1] + [i for i in contour if np.all(np.isfinite(out[i]))]
        if len(on_line) < 3:
            continue
        cols = np.array([out[i, 0] for i in on_line])
        rows = np.array([out[i, 1] for i in on_line])
        order = np.argsort(cols)
        targets = {}
        for k in contour:
            if skip[k] or k in corners:
                continue
            frac = (model_px[k, 0] - model_px[c0, 0]) / span_model
            col = out[c0, 0] + frac * (out[c1, 0] - out[c0, 0])
            targets[k] = (col, float(np.interp(col, cols[order], rows[order])))
        for k, px in targets.items():
            hit = search.nearest_covered(px) if search is not None else np.array(px)
            if np.all(np.isfinite(hit)) and np.abs(np.asarray(hit) - out[k]).max() > 0.5:
                out[k] = hit
                moved.append(k)


OPENING_STEP_MM = 3.0     # a depth step this large between neighbouring pixel rows is an occluding edge


OPENING_MIN_MM = 1.5      # a mouth opening narrower than this is treated as closed


HOLE_MM = 3.0             # uncovered rows this tall between two lip rows: an unscanned opening


def mouth_opening_pass(ctx: PixelContext, est: PixelEstimates) -> PixelMoves:
    """Inner-lip points put on the edges of the mouth opening, when the scan shows one.

    Seen from the front an open mouth is an occluding edge: along a vertical line through the mouth
    the surface steps back by several mm (lip -> teeth or mouth cavity) or ends (a hole) just below
    the upper lip, and steps forward again just above the lower lip. The patch search alone
    confuses the lips (the lower-lip patch also fits the upper lip); the depth profile does not.

    - columns: each inner-lip point keeps the model's horizontal fraction between the two mouth
      corners (the corners are found reliably; the patch search drifts along the lip);
    - rows: the column is scanned downwards from the philtrum (half-way between the bottom of the
      nose 9.15 and the model's upper lip, shifted with the nose) -- the first step back is the
      upper lip's inner edge -- and upwards from the chin (``JAW_POINTS``) -- the first step back
      seen from below is the lower lip's inner edge. The order upper outer > upper inner >
      opening > lower inner > lower outer follows by construction; outer-lip points found on the
      wrong side of the opening are searched again (patch search) on their own side.

    With no step in a column, or an opening narrower than ``OPENING_MIN_MM`` (closed mouth), the
    points keep their patch-search estimates. Without ``ctx.search`` (tests) only the inner-lip
    points move. Inner-lip points on an edge get evidence of at least 0.5."""
    template, raster, model_px, scale, skip, search = (ctx.template, ctx.raster, ctx.model_px, ctx.scale,
                                                       ctx.skip, ctx.search)
    out, peak = est.working()
    moved = []
    done = lambda: PixelMoves.take(out, peak, moved)   # noqa: E731
    depth = raster.depth
    if depth is None:
        return done()
    base = template.base
    names = template.detected
    if not all(n in names for n in base.mouth) or NOSE_BOTTOM not in names:
        return done()
    ok = lambda i: bool(np.all(np.isfinite(out[i])))   # noqa: E731
    loop = [template.index(n) for n in base.mouth]
    c0, c1 = loop[0], loop[len(loop) // 2]                  # the two corners
    jaw = [template.index(n) for n in JAW_POINTS if n in names and ok(template.index(n))]
    nose = template.index(NOSE_BOTTOM)
    if not (ok(c0) and ok(c1) and ok(nose) and jaw):
        return done()
    upper_set = {template.index(n) for n in base.upper_lip_points if n in names}
    upper_in = [i for i in loop if i not in (c0, c1) and i in upper_set]
    lower_in = [i for i in loop if i not in (c0, c1) and i not in upper_set]
    upper_out = [i for i in upper_set if i not in loop]
    lower_out = [template.index(n) for n in base.lower_lip_points if n in names and template.index(n) not in loop]
    px = raster.pixel
    Hh, W = depth.shape
    mid_model = np.mean([model_px[i, 1] for i in upper_in])
    top = int(round(out[nose, 1] + 0.5 * (mid_model - model_px[nose, 1])))
    bottom = int(round(np.median([out[i, 1] for i in jaw])))   # the chin, below the lower lip
    top, bottom = max(top, 0), min(bottom, Hh - 1)
    if bottom - top < 4:
        return done()
    span_model = model_px[c1, 0] - model_px[c0, 0]
    if abs(span_model) < 1:
        return done()
    def opening_edges(c, min_mm=OPENING_MIN_MM, rows_from=None, rows_to=None, hole_mm=HOLE_MM):
        """(last row above, first row below) the opening in column c (absolute rows), or None when
        it has none at least ``min_mm`` tall; rows searched ``rows_from``..``rows_to`` (default:
        the philtrum to the chin), uncovered runs of at least ``hole_mm`` (and one row) count as holes."""
        lo = top if rows_from is None else max(int(rows_from), 0)
        hi = bottom if rows_to is None else min(int(rows_to), Hh - 1)
        if not 0 <= c < W or hi - lo < 2:
            return None
        zcol = depth[lo:hi + 1, c]
        rows = np.nonzero(np.isfinite(zcol))[0]
        if len(rows) < 2:
            return None
        z = zcol[rows]
        a, b = rows[:-1], rows[1:]               # consecutive covered rows (a above b)
        hole = (b - a - 1) >= max(1.0, hole_mm / px)   # a hole in the scan (open mouth not scanned)
        back_down = a[(z[1:] < z[:-1] - OPENING_STEP_MM) | hole]   # last rows before a step back
        back_up = b[(z[:-1] < z[1:] - OPENING_STEP_MM) | hole]     # first rows after a step forward
        if not len(back_down) or not len(back_up):
            return None
        r_up, r_lo = int(back_down[0]), int(back_up[-1])
        if r_lo <= r_up or (r_lo - r_up - 1) * px < min_mm:
            return None
        return lo + r_up, lo + r_lo

    # The opening's horizontal extent (through its middle) stands for the corners when found: the
    # corner points sit on the outer lip contour and drift outwards when the mouth rounds.
    ends = (out[c0, 0], out[c1, 0])
    c_mid = int(round((out[c0, 0] + out[c1, 0]) / 2))
    mid = opening_edges(c_mid)
    if mid is not None:
        row = (mid[0] + mid[1]) // 2
        cols = np.nonzero(np.isfinite(depth[row]))[0]
        z = depth[row, cols]
        fwd_right = cols[1:][(z[1:] > z[:-1] + OPENING_STEP_MM) & (cols[1:] > c_mid)]   # lip in front, right
        fwd_left = cols[:-1][(z[:-1] > z[1:] + OPENING_STEP_MM) & (cols[:-1] < c_mid)]
        if len(fwd_right) and len(fwd_left):
            lo_c, hi_c = int(fwd_left[-1]), int(fwd_right[0])
            width = abs(out[c1, 0] - out[c0, 0])
            if 0.3 * width <= hi_c - lo_c <= 1.2 * width:
                ends = (lo_c, hi_c) if out[c0, 0] < out[c1, 0] else (hi_c, lo_c)
        tips = _opening_tips(opening_edges, c_mid, mid, W, abs(span_model), TIP_REACH * scale / px)
        if tips is not None:
            ends = _place_corners(template, names, out, peak, moved, skip, model_px, c0, c1, tips, search,
                                  TIP_REACH * scale / px)
    edges = {}
    for k in upper_in + lower_in:
        if skip[k]:
            continue
        frac = (model_px[k, 0] - model_px[c0, 0]) / span_model
        c = int(round(ends[0] + frac * (ends[1] - ends[0])))
        found = opening_edges(c)
        if found is None:
            continue
        r_up, r_lo = found
        edges[k] = (c, r_up, r_lo)
        out[k] = (float(c), float(r_up if k in upper_in else r_lo))
        peak[k] = max(peak[k], 0.5)
        moved.append(k)
    if search is None or not edges:
        return done()
    # The jaw below the lower lip: a chin point found less than half its model distance below the
    # lower lip's inner edge (the patch search latched onto the lip) is searched again lower down.
    if mid is not None:
        lower_mid = min(lower_in, key=lambda i: abs(model_px[i, 0] - model_px[c0, 0] - span_model / 2))
        for k in [template.index(n) for n in JAW_POINTS if n in names]:
            if skip[k] or not ok(k):
                continue
            gap = model_px[k, 1] - model_px[lower_mid, 1]
            if gap <= 0 or out[k, 1] >= mid[1] + 0.5 * gap:
                continue
            lo_row, hi_row = mid[1] + 0.5 * gap, mid[1] + 1.2 * gap
            best, val = search.search(k, (out[k, 0], (lo_row + hi_row) / 2), max(2, int(round(0.05 * scale / px))),
                                      int(np.ceil((hi_row - lo_row) / 2)), pull_px=(out[k, 0], (lo_row + hi_row) / 2))
            if best is not None and lo_row <= best[1] <= hi_row:
                out[k], peak[k] = best, val
            else:
                out[k] = search.nearest_covered((out[k, 0], (lo_row + hi_row) / 2))
            moved.append(k)
    # Outer-lip points on the wrong side of the opening: search again on their own side.
    r = max(2, int(round(0.05 * scale / px)))
    for group, side in ((upper_out, "upper"), (lower_out, "lower")):
        for k in group:
            if skip[k] or not ok(k):
                continue
            near = min(edges, key=lambda i: abs(edges[i][0] - out[k, 0]))
            c, r_up, r_lo = edges[near]
            gap = abs(model_px[k, 1] - model_px[near, 1])           # the lip's height on the model
            if side == "upper" and out[k, 1] >= r_up:
                lo_row, hi_row, pred = top, r_up - 1, r_up - gap
            elif side == "lower" and out[k, 1] <= r_lo:
                lo_row, hi_row, pred = r_lo + 1, bottom, r_lo + gap
            else:
                continue
            if hi_row - lo_row < 2:
                continue
            best, val = search.search(k, (out[k, 0], (lo_row + hi_row) / 2), r, int(np.ceil((hi_row - lo_row) / 2)),
                                      pull_px=(out[k, 0], pred))
            if best is not None and lo_row <= best[1] <= hi_row:
                out[k], peak[k] = best, val
            else:
                out[k] = (out[k, 0], float(np.clip(pred, lo_row, hi_row)))
            moved.append(k)
    return done()


def _opening_tips(opening_edges, c_mid: int, mid: tuple[int, int], width_px: int, model_span_px: float,
                  reach_px: float):
    """The open mouth's two lateral tips, ((col, row, row above, row below) left, (...) right) in
    pixels (the rows: the opening's edges in the tip's last column), or None.

    From the opening's middle column the opening is followed sideways, column by column, while the
    column still has one (a hole of any size or a depth step back of any height) overlapping the
    previous column's, searched within ``reach_px`` rows above and below it (a smile's ends rise
    above the philtrum row where the middle's search starts, and narrow to a slit thinner than a
    hole in the middle): its last column is where the lips meet, the commissure. Tips implausibly
    near or far from the middle (outside ``TIP_SPAN`` x the model's mouth width, e.g. an opening
    that runs into a nostril or the scan's border) give None."""
    tips = []
    reach = max(1, int(round(reach_px)))
    for step in (-1, 1):
        band, last = mid, None
        c = c_mid
        while 0 <= c < width_px:
            found = opening_edges(c, 0.0, band[0] - reach, band[1] + reach, 0.0)
            if found is None or found[1] < band[0] or found[0] > band[1]:
                break
            last, band = (c, found), found
            c += step
        if last is None:
            return None
        col, (r_up, r_lo) = last
        half = abs(col + 0.5 * step - c_mid)
        if not TIP_SPAN[0] * model_span_px <= 2 * half <= TIP_SPAN[1] * model_span_px:
            return None
        tips.append((col + 0.5 * step, 0.5 * (r_up + r_lo), r_up, r_lo))
    return tips[0], tips[1]


def _place_corners(template, names, out, peak, moved, skip, model_px, c0: int, c1: int, tips,
                   search, reach_px: float) -> tuple[float, float]:
    """Put the inner-lip corners ``c0``/``c1`` on the opening's tips and the outer-lip corners
    (``OUTER_CORNERS``) at the model's offset from them (the default face's: 1.5 mm sideways; put
    on the tip itself, SFM smiles' outer corners went 10-15 mm astray in the later passes, which
    read the pair's offset); returns the corners' columns (c0's, c1's).

    In an open mouth both lip contours meet at the commissure, the opening's lateral tip; the patch
    search alone leaves a smiling mouth's corners where the model's (closed, level) corners were,
    5-9 mm medial and low on a wide smile. The opening's tip is where the corner is at the least:
    lips parted only in the middle (anger) meet farther out, so a corner already beyond its tip,
    within ``reach_px`` rows of the opening's edges there (on the lip line, not on the cheek
    above: SFM surprise, 18 mm up), stays with its outer corner (which must be there too). With
    ``search``, each point goes to the covered scan pixel nearest to its place (a pixel in the
    opening has no surface: the point would keep its greedy match, on SFM anger once 25 mm away)."""
    left, right = tips
    on_scan = (lambda px: px) if search is None else search.nearest_covered   # noqa: E731
    ends = []
    outer = [template.index(n) for n in OUTER_CORNERS if n in names]
    centre = 0.5 * (left[0] + right[0])
    for inner in (c0, c1):
        found = np.asarray(left if model_px[inner, 0] <= model_px[c0 if inner == c1 else c1, 0] else right, float)
        tip, (r_up, r_lo) = found[:2], found[2:]
        k = min(outer, key=lambda i: abs(model_px[i, 0] - model_px[inner, 0])) if outer else None

        def beyond(i: int) -> bool:   # out past the tip, on the lip line
            return bool(np.all(np.isfinite(out[i])) and abs(out[i, 0] - centre) >= abs(tip[0] - centre)
                        and r_up - reach_px <= out[i, 1] <= r_lo + reach_px)

        if beyond(inner) and (k is None or beyond(k)):
            ends.append(float(out[inner, 0]))   # already beyond the opening: lips that touch there
            continue
        if not skip[inner]:
            out[inner], peak[inner] = on_scan(tip), max(peak[inner], 0.5)
            moved.append(inner)
        ends.append(float(tip[0]))
        if k is not None:
            if not skip[k]:
                out[k] = on_scan(tip + (model_px[k] - model_px[inner]))
                peak[k] = max(peak[k], 0.5)
                moved.append(k)
    return ends[0], ends[1]


def opening_points(template) -> np.ndarray:
    """(P,) bool: the points ``mouth_opening_pass`` puts on the opening's edges when it moves them
    (the inner-lip loop and the outer corners ``OUTER_CORNERS``), not those it searches again."""
    names = template.detected
    return np.array([n in template.base.mouth or n in OUTER_CORNERS for n in names])


TIP_SPAN = (0.5, 1.8)            # an opening's tip-to-tip width, as a share of the model's mouth width


TIP_REACH = 0.05                 # x face scale: rows an opening's end is followed up or down per column,
                                 # and a corner beyond a tip is taken to be on the lip line (half the tolerance)


OUTER_CORNERS = ("8.3", "8.4")   # outer-lip corners, at the commissure with the inner ones


CORNER_SLACK = 0.1               # x the model's mouth width: a closed mouth's inner corner this far from
                                 # its outer corner's place for it is misplaced (about the tolerance)


JAW_POINTS = ("2.10", "2.1", "2.11", "2.12")


NOSE_BOTTOM = "9.15"


def lower_lip_pass(ctx: PixelContext, est: PixelEstimates) -> PixelMoves:
    """Lower-lip points searched below their upper-lip partner, pulled to where the jaw went.

    An open mouth shows two lip bands; the lower-lip patches also fit the upper lip, and the
    structure of the other mouth points does not tell which (they move together). The jaw
    (chin points, found reliably) does: the lower lip moves down with it, by about 1-2x the chin's
    displacement, and it is never above the upper lip. Inner lip first: an outer point is searched
    below where its inner one went."""
    template, search, model_px, skip = ctx.template, ctx.search, ctx.model_px, ctx.skip
    r, scale_px = ctx.radius_px, ctx.scale_px
    out, peak = est.working()
    moved = []
    names = template.detected
    jaw = [template.index(n) for n in JAW_POINTS if n in names and np.all(np.isfinite(out[template.index(n)]))]
    upper = [template.index(n) for n in template.base.upper_lip_points if n in names]
    lower = [template.index(n) for n in template.base.lower_lip_points if n in names]
    if not jaw or not upper or not lower:
        return PixelMoves.take(out, peak, moved)
    jaw_disp = np.median(out[jaw] - model_px[jaw], axis=0)
    drop = max(float(jaw_disp[1]), 0.0)          # rows grow downwards
    for k in sorted(lower, key=lambda i: model_px[i, 1]):   # inner lip first (higher up)
        if skip[k]:
            continue
        u = min(upper, key=lambda i: abs(model_px[i, 0] - model_px[k, 0]) + 0.01 * abs(model_px[i, 1] - model_px[k, 1]))
        if not np.all(np.isfinite(out[u])):
            continue
        top = float(out[u, 1]) + 1.0
        above = [i for i in lower if i != k and model_px[i, 1] < model_px[k, 1] - 1
                 and abs(model_px[i, 0] - model_px[k, 0]) < 0.05 * scale_px and np.all(np.isfinite(out[i]))]
        if above:  # the outer lower lip is below the inner one
            top = max(top, max(float(out[i, 1]) for i in above) + 1.0)
        bottom = max(top + 1.0, model_px[k, 1] + 2.5 * drop + r)
        pred = model_px[k] + np.array([jaw_disp[0], 1.5 * drop])
        cx = model_px[k, 0] + jaw_disp[0]
        best, val = search.search(k, (cx, (top + bottom) / 2), r, int(np.ceil((bottom - top) / 2)), pull_px=pred)
        if best is not None:
            out[k], peak[k] = best, val
            moved.append(k)
    return PixelMoves.take(out, peak, moved)
