"""A closed eye's lid line moved onto the scan's own lid crease.

``closed_eyes.closed_lid_lines`` draws a closed eye's lid line as a parabola through the eye's
corners and the lid centres' middle (landmarks). On a scan the lids meet in a crease of the skin
whose course the parabola only approximates: on LeePerrySmith it runs up to 4 mm below the
parabola near the outer corners and 1.5 mm above it at the inner ones. Cut along the parabola, the
scan opens beside its crease: a strip of one lid stays on the other, and where the parabola runs
along the crease's wall it crosses the wall back and forth, so the opened margin is saw-toothed.

:func:`along_crease` finds the crease in a depth raster of the scan seen along the eye's ``-w``
(rays from the front): per column (``CREASE_COLUMN_MM`` along u) the row within
``CREASE_BAND`` x the eye's width of the parabola where the skin is most concave across the lid
line (the second difference of depth over +-``CREASE_REACH_MM``), weighted by that concavity; the
course is those rows smoothed along u (Gaussian, ``CREASE_SMOOTH_MM``), which the LidLine keeps as
offsets from its parabola (and the crease's depth, so a cut can stay off the walls of the eye's
corners). Without Embree, or without a crease along most of the eye (``CREASE_COVERAGE``: lids that
meet smoothly, as FAP-closed lids do), the line is returned as it was.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from core.layers.fap.closed_eyes import LidLine

#: Rows searched for the crease, x the eye's width either side of the parabola (LeePerrySmith's
#: crease lies up to 4.25 mm = 0.14 x 30 mm from it; the upper lid's fold is ~8-10 mm above the margin).
CREASE_BAND = 0.17
#: Raster steps along u and across the lid line, mm (a scan's triangles there are ~3 mm).
CREASE_COLUMN_MM = 0.5
CREASE_ROW_MM = 0.25
#: Half-width of the concavity measure across the lid line, mm (the crease is ~1-2 mm wide).
CREASE_REACH_MM = 0.75
#: A column's crease counts when its skin is at least this concave (mm: depth above the chord over
#: +-CREASE_REACH_MM; LeePerrySmith's crease 1.3-5 mm in mid-eye, the smooth lid beside it ~0.15 mm;
#: a scan of the default face with its lids closed by the FAPs has no crease, its lids meet smoothly,
#: and the lower lid's fold 2 mm below reaches 0.3-0.5 mm) ...
CREASE_MIN_MM = 1.0
#: ... and at most this (a ray through a gap in the scan's slit, to the back of the head, reads 40-60).
CREASE_MAX_MM = 10.0
#: An eye has a crease when it is found in at least this share of its columns (LeePerrySmith's eyes
#: 85-92 %; the lids of generated person 2 closed by the FAPs, which meet smoothly, 10-26 %: its lower
#: lid's fold and the scanner's depth noise here and there).
CREASE_COVERAGE = 0.5
#: Skin more than this share of the eye's width behind the corners' chord is not the lid (a gap in the slit).
CREASE_DEEPEST = 0.3
#: Width of the crease's smoothing along u, mm (the crease curves over the eye's ~30 mm).
CREASE_SMOOTH_MM = 3.0


def along_crease(line: LidLine, vertices: np.ndarray, triangles: np.ndarray, rays=None) -> LidLine:
    """``line`` with its course moved onto the crease of the skin (vertices (n, 3) mm, triangles
    (m, 3)) where one is found (see the module docstring); ``rays``: a SurfaceRays of that skin."""
    from core.registration.correspondence import SurfaceRays

    rays = rays if rays is not None else SurfaceRays(vertices, triangles)
    if rays.engine != "embree":
        return line
    width = line.width
    s = np.arange(CREASE_COLUMN_MM / 2, width, CREASE_COLUMN_MM)
    across = np.arange(-CREASE_BAND * width, CREASE_BAND * width + 1e-9, CREASE_ROW_MM)
    t = line.parabola(s)[:, None] + across[None, :]
    front = line.start + s[:, None, None] * line.u + t[..., None] * line.v + width * line.w
    pos, _, hit = rays.first_hits(front.reshape(-1, 3), np.tile(-line.w, (front.size // 3, 1)))
    depth = ((pos - line.start) @ line.w).reshape(t.shape)
    depth[~hit.reshape(t.shape) | (depth < -CREASE_DEEPEST * width)] = np.nan
    k = int(round(CREASE_REACH_MM / CREASE_ROW_MM))
    concave = depth[:, 2 * k:] + depth[:, :-2 * k] - 2 * depth[:, k:-k]   # NaN where any row is missing
    concave = np.where(np.isfinite(concave) & (concave <= CREASE_MAX_MM), concave, -np.inf)
    row = np.argmax(concave, axis=1)
    strength = concave[np.arange(len(s)), row]
    found = strength >= CREASE_MIN_MM
    if found.sum() < CREASE_COVERAGE * len(s):
        return line
    offset = across[row + k][found]
    crease_depth = depth[np.arange(len(s)), row + k][found]
    weight = np.minimum(strength[found], 5.0)       # a deep crease is no more certain than a clear one
    kernel = np.exp(-0.5 * ((s[:, None] - s[found][None, :]) / CREASE_SMOOTH_MM) ** 2) * weight[None, :]
    total = kernel.sum(axis=1)
    smooth_t = kernel @ offset / total
    smooth_depth = kernel @ crease_depth / total
    return dataclasses.replace(line, crease_s=tuple(s), crease_t=tuple(smooth_t), crease_depth=tuple(smooth_depth))


__all__ = ["along_crease"]
