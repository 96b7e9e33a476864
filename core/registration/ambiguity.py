"""Flat evidence: a patch match that fits as well somewhere else does not say where the point is.

The confidence's appearance term is the NCC peak of the point's model patch at its place. Along a
feature that looks the same over a length (an untextured brow ridge, a cheek) the peak is high
wherever the point lands on it: on Surrey Face Model scans without texture the brow tops 4.3/4.4
slid 5-13 mm along the ridge with NCC ~0.9 and confidence ~0.8, unflagged. This module measures
how distinct a point's peak is: its best NCC within ``EXCLUDE`` x scale minus the best NCC of the same patch in the ring
between ``EXCLUDE`` and ``REACH`` x face scale around it. A rival place as good as the chosen one
farther than half the evaluation's tolerance (0.1 x scale) means the evidence does not pin the
point; its appearance evidence is then scaled down by ``distinctness`` (0 when a rival is as
good, 1 when the peak stands ``MARGIN`` above every rival), so the point is reported low
confidence. Positions are not changed."""

from __future__ import annotations

import numpy as np

EXCLUDE = 0.05   # x face scale: rivals nearer than this are the same place (half the tolerance)
REACH = 0.15     # x face scale: rivals searched up to this far (the patch search's own reach, 0.1, and beyond)
MARGIN = 0.05    # NCC: a peak this much above its best rival is distinct


def distinctness(search, pixels: np.ndarray, placed: np.ndarray, scale_px: float) -> np.ndarray:
    """(P,) 0..1 per point: how much its best NCC within EXCLUDE x ``scale_px`` of ``pixels`` (P, 2)
    (col, row) stands above its best rival in the ring EXCLUDE..REACH x ``scale_px`` around it,
    / MARGIN, clipped; 1 where not
    ``placed`` (P,) bool or where no NCC window fits (nothing measured, nothing changed).
    ``search`` is the match's ``patches.PatchSearch``."""
    out = np.ones(len(pixels))
    reach = max(2, int(round(REACH * scale_px)))
    exclude = EXCLUDE * scale_px
    yy, xx = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    radius = np.hypot(xx, yy)
    near, ring = radius <= exclude, (radius > exclude) & (radius <= reach)
    for k in np.nonzero(placed)[0]:   # one small NCC window per landmark (~80), not per vertex
        found = search.ncc_window(int(k), pixels[k], reach, reach)
        if found is None:
            continue
        res = found[0]
        if res.shape != ring.shape:   # clipped at the raster's padding: measure what fits
            continue
        here = float(res[near].max())   # the place itself: its best pixel (the pull may have left it off the peak)
        rival = float(res[ring].max())
        out[k] = float(np.clip((here - rival) / MARGIN, 0.0, 1.0))
    return out
