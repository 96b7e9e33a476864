"""nostrils.py
----
The nostrils of the full head: two openings on the underside of the nose with a modelled inside.

A single-view scanner sees the underside of the nose edge-on and the nostrils as shallow dents (the
front-of-face height field keeps those). The full head opens them: the skin inside each nostril's
outline on the underside is pushed up into the nose (the vestibule), a pocket with steep walls
under a domed roof. The outline, seen from below in the (x, z) plane, is a teardrop whose long axis
runs from the narrow front end by the tip back and out to the round end by the alar base. The
pocket is a graph over that plane (each point only moves up), so it stays embedded, and it stays
inside the nose (``open_nostrils`` checks the wall in front of it). The texture darkens
with the pocket's depth (``texture.paint_texture``), in place of the painted dark spot of the
front-only face. All lengths in mm; +x the face's left, +y up, +z forward.
"""

from __future__ import annotations

import numpy as np

from core.default_face.params import FaceLayout
from core.default_face.shape import FaceShape, _smoothstep

POCKET_DEPTH = 5.5     # mm: how far the nostril's roof lies above its rim (nose projection 17 mm)
WALL = 0.55            # share of the outline's radius over which the wall rises to the roof
UNDERSIDE_SLOPE = 1.0  # dz/dy beyond which the height field is the nose's underside (seen from below)
MIN_WALL = 0.4         # the nose's wall in front of a pocket: at least this share of its depth (up to 1 mm)


def _outline_frame(layout: FaceLayout):
    """(centre x, centre z, unit long axis in (x, z), half-length, half-width) of the left nostril."""
    p = layout.p
    tip_z = -1.0 + (p.nose_projection - 17.0)
    sub_z = tip_z - p.nose_projection
    front, back = tip_z - 0.40 * p.nose_projection, sub_z + 0.10 * p.nose_projection
    medial, lateral = 0.20 * layout.alar_half_width, 0.55 * layout.alar_half_width
    a = np.array([medial + 0.25 * (lateral - medial), front])     # the narrow front end
    b = np.array([lateral - 0.20 * (lateral - medial), back])     # the round back end
    axis = (a - b) / np.linalg.norm(a - b)
    centre = 0.5 * (a + b)
    return centre, axis, 0.5 * np.linalg.norm(a - b), 0.5 * (lateral - medial)


def outline_radius(layout: FaceLayout, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(k,) where the points (x, z) (k,) lie seen from below relative to the nearer nostril's
    outline: 0 at its middle, 1 on the outline (both nostrils, mirrored in x)."""
    centre, axis, half_length, half_width = _outline_frame(layout)
    dx, dz = np.abs(x) - centre[0], z - centre[1]
    along = (dx * axis[0] + dz * axis[1]) / half_length              # -1 at the back, +1 at the front
    across = (-dx * axis[1] + dz * axis[0]) / half_width
    # Teardrop: narrower toward the front end.
    taper = 1.0 - 0.45 * np.clip(along, 0.0, 1.0)
    return np.sqrt(along ** 2 + (across / np.maximum(taper, 1e-6)) ** 2)


def _underside(shape: FaceShape, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,) depth z of the height field at (x, y) (k,) and (k,) in [0, 1]: is it the nose's underside."""
    L = shape.L
    h = 0.05
    z = shape.skin_depth(x, y)
    slope = (shape.skin_depth(x, y + h) - shape.skin_depth(x, y - h)) / (2 * h)
    underside = _smoothstep(UNDERSIDE_SLOPE, 1.6 * UNDERSIDE_SLOPE, slope)
    return z, underside * ((y > L.subnasale_y - 0.5) & (y < L.nose_tip_y))


def pocket_depth(shape: FaceShape, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(k,) mm: how far the skin at (x, y) (k,) of the front-of-face height field rises into a
    nostril (0 off the nose's underside and outside the outlines): a bowl, steepest near the rim."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    z, underside = _underside(shape, x, y)
    bowl = _smoothstep(1.0, 1.0 - WALL, outline_radius(shape.L, x, z))
    return POCKET_DEPTH * (shape.L.p.nose_projection / 17.0) * bowl * underside


def shade(shape: FaceShape, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(k,) in [0, 1]: how dark the texture is at (x, y) (k,): the whole inside of each nostril,
    fading out just past the rim (the rim's vertices carry it onto the pocket's walls, which
    would otherwise show skin-coloured streaks between rim and inside)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    z, underside = _underside(shape, x, y)
    return _smoothstep(1.4, 0.8, outline_radius(shape.L, x, z)) * underside


def open_nostrils(shape: FaceShape, vertices: np.ndarray, movable: np.ndarray) -> np.ndarray:
    """(n, 3) skin ``vertices`` (n, 3) of the front-of-face height field with the nostrils opened
    (only ``movable`` (n,) bool ones move, each straight up by ``pocket_depth``).

    Raises ValueError where the nose's wall in front of a pocket would be thinner than
    ``MIN_WALL`` of the pocket's depth there (up to 1 mm): these identity parameters leave no room
    for the nostrils."""
    depth = np.where(movable, pocket_depth(shape, vertices[:, 0], vertices[:, 1]), 0.0)
    moved = depth > 0
    out = vertices.copy()
    out[moved, 1] += depth[moved]
    wall = pocket_clearance(shape, out[moved])
    thin = wall < MIN_WALL * np.minimum(depth[moved], 1.0 / MIN_WALL)
    if thin.any():
        raise ValueError(f"a nostril pocket comes within {wall[thin].min():.2f} mm of the nose's skin")
    return out


def pocket_clearance(shape: FaceShape, points: np.ndarray) -> np.ndarray:
    """(k,) mm: how far behind the outer skin (the height field in front of them) points (k, 3) lie."""
    return shape.skin_depth(points[:, 0], points[:, 1]) - points[:, 2]
