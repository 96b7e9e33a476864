"""mouth.py
----
The inside of the mouth behind the lip seam, so that parted lips and an open
jaw show a mouth rather than the background. Three separate components:

- the mouth cavity: a dark bowl facing the opening (+z), a height field over
  a footprint wider than the mouth (out to near the scan's side edge) and
  reaching from the nose base to below the chin boss. A gently concave floor
  whose walls rise near the footprint's edge until they meet the skin
  envelope less ``CAVITY_CLEARANCE``. The envelope is the lowest of the rest
  skin and the lower face (below the mouth line) dropped by up to
  ``JAW_DROP`` and moved back ``JAW_BACK`` per mm (the jaw moves the lower
  face, the cavity stays with the skull), so the cavity stays behind the face
  however far the jaw opens, and lines of sight through the opening end on
  it rather than passing beside it;
- the upper and lower teeth: closed tubes swept along a parabolic dental arch
  (a rounded incisal edge, labial and lingual faces, the gum along the top),
  the incisors' labial face ``INCISOR_SETBACK`` behind the skin of the mouth
  line at the midline.

All lengths in mm. Triangles are counter-clockwise seen from outside (the
cavity from the front, the teeth from outside the tube).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.default_face.params import FaceLayout
from core.default_face.shape import OUTLINE_T, FaceShape, _smooth_max, _smoothstep

JAW_DROP = 25.0            # mm, how far the lower face may move down with the jaw
JAW_BACK = 0.3             # mm the lower face may move back per mm down (the jaw rotates)
CAVITY_SPACING = 2.0       # mm, grid spacing of the cavity
CAVITY_CLEARANCE = 2.5     # mm, cavity behind the (rest or dropped) skin at least this much
CAVITY_MARGIN_X = 24.0     # mm, cavity beyond each mouth corner
CAVITY_FLOOR_DEPTH = 36.0  # mm, deepest part of the cavity behind the incisors' front
CAVITY_WALL = 9.0          # mm, width of the cavity's rising walls at the sides
CAVITY_WALL_TOP = 6.0      # mm, at the top (under the nose, above the upper teeth)
CAVITY_WALL_BOTTOM = 7.0   # mm, at the bottom (below the chin boss)
INCISOR_SETBACK = 3.5      # mm, upper incisor front behind the inner lip contour (mouth line) at the midline
OVERJET = 1.5              # mm, lower incisors behind the upper ones
ARCH_DEPTH = 12.7          # mm, the arch (z = z0 - k x^2) is this much further back at the mouth corners
ARCH_END_BEYOND_CORNER = 2.0  # mm, the arch ends this far laterally of the mouth corners
ARCH_STEP = 0.8            # mm, ring spacing along the arch
TEETH_CLEARANCE = 2.0      # mm, teeth behind the skin at least this much

# Tooth widths along the arch from the midline (central incisor first), mm.
UPPER_TOOTH_WIDTHS = (8.5, 6.6, 7.6, 7.0, 6.6, 10.0)
LOWER_TOOTH_WIDTHS = (5.4, 5.9, 6.9, 7.0, 7.1, 11.0)


def _softmin(a, b, k):
    """Smooth minimum, never above min(a, b)."""
    return -_smooth_max(-np.asarray(a, float), -np.asarray(b, float), k)


@dataclass(frozen=True)
class TeethRow:
    """One row of teeth: a closed tube along the arch.

    vertices (n, 3), triangles (m, 3) with local indices; ``local`` (n, 2) is
    (arc length from the midline, loop length around the cross-section) in mm,
    the texture parametrisation; ``points`` maps "edge" / "gum" to the local
    vertex index at the midline of the incisal edge and of the labial gum line.
    """

    upper: bool
    vertices: np.ndarray
    triangles: np.ndarray
    local: np.ndarray
    local_rect: tuple[float, float, float, float]   # (s0, v0, width, height)
    gum_lines: tuple[float, float]                  # loop length of the labial and lingual gum lines
    edge_loop: float                                # loop length of the incisal edge
    tooth_boundaries: np.ndarray                    # arc lengths between teeth (both sides, sorted)
    points: dict[str, int]


class MouthInterior:
    """Geometry of the mouth cavity and the teeth for one layout."""

    def __init__(self, layout: FaceLayout, shape: FaceShape):
        self.L = layout
        self.shape = shape
        L = layout
        self.incisor_z = float(shape.skin_depth(0.0, L.mouth_line(0.0))) - INCISOR_SETBACK
        self.cavity_top = L.subnasale_y + 1.0
        self.cavity_bottom = L.chin_y - 7.0
        self.cavity_half_width = L.mouth_half_width + CAVITY_MARGIN_X
        self.cavity_floor = self.incisor_z - CAVITY_FLOOR_DEPTH
        self.arch_curvature = ARCH_DEPTH / L.mouth_half_width**2   # 1/mm

    # ------------------------------------------------------------ cavity
    def skin_envelope(self, x, y):
        """Lowest z the face's skin takes at (x, y): at rest, or the lower face (below the mouth
        line) moved down by up to JAW_DROP and back by JAW_BACK per mm down."""
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        # The rest skin's minimum over a grid cell around (x, y) (at most 1.5 mm
        # deeper: the sides fall away fast), so that the cavity's flat triangles
        # stay behind narrow features (nostrils, lip crease).
        r = CAVITY_SPACING / 2
        env = self.shape.skin_depth(x, y)
        around = np.min([self.shape.skin_depth(x + dx, y + dy) for dx in (-r, 0, r) for dy in (-r, 0, r)], axis=0)
        env = np.maximum(around, env - 1.5)
        line = self.L.mouth_line(x)
        for s in np.linspace(0.0, JAW_DROP, 26)[1:]:
            moved = self.shape.skin_depth(x, y + s) - JAW_BACK * s
            env = np.where(y + s < line, np.minimum(env, moved), env)
        return env

    def cavity_half_width_at(self, y):
        """Half-width of the cavity footprint at height y: beyond the mouth corners, inside the jaw."""
        return np.minimum(self.cavity_half_width, (OUTLINE_T - 0.04) * self.shape.half_width(y))

    def cavity_inside(self, x, y):
        """Mask of the cavity footprint."""
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        return ((np.abs(x) <= self.cavity_half_width_at(y) + 1e-9)
                & (y >= self.cavity_bottom - 1e-9) & (y <= self.cavity_top + 1e-9))

    def cavity_depth(self, x, y):
        """z of the cavity surface at (x, y).

        A gently concave floor whose walls rise steeply near the footprint's
        edge until they meet the skin envelope (less the clearance): a bowl
        that closes the mouth behind the lips. The floor never goes behind the
        scan's side edge at that height, so the profile view cannot see it.
        """
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        L = self.L
        floor = self.cavity_floor + 0.006 * x**2 + 0.003 * (y - L.stomion_y) ** 2
        edge_z = self.shape.skin_depth(OUTLINE_T * self.shape.half_width(y), y)
        floor = _smooth_max(floor, edge_z + 6.0, 1.0)
        wall = (_smoothstep(CAVITY_WALL, 0.0, self.cavity_half_width_at(y) - np.abs(x))
                + _smoothstep(CAVITY_WALL_TOP, 0.0, self.cavity_top - y)
                + _smoothstep(CAVITY_WALL_BOTTOM, 0.0, y - self.cavity_bottom))
        return _softmin(floor + 80.0 * wall, self.skin_envelope(x, y) - CAVITY_CLEARANCE, 1.0)

    def cavity(self):
        """Vertices (n, 3), triangles (m, 3) (counter-clockwise from +z) and local (x, y) (n, 2).

        A grid whose columns are spread, row by row, between the footprint's
        sides (so the side edges follow the jaw without a staircase).
        """
        h = CAVITY_SPACING
        nx = int(np.ceil(self.cavity_half_width / h))
        ny = int(np.ceil((self.cavity_top - self.cavity_bottom) / h))
        ys = np.linspace(self.cavity_bottom, self.cavity_top, ny + 1)
        X = np.linspace(-1.0, 1.0, 2 * nx + 1)[None, :] * self.cavity_half_width_at(ys)[:, None]
        Y = np.broadcast_to(ys[:, None], X.shape)
        index = np.arange(X.size).reshape(X.shape)
        a, b = index[:-1, :-1], index[:-1, 1:]
        d, c = index[1:, :-1], index[1:, 1:]
        left = X[:-1, :-1] < -1e-9
        t1 = np.where(left[..., None], np.stack([a, b, c], -1), np.stack([a, b, d], -1)).reshape(-1, 3)
        t2 = np.where(left[..., None], np.stack([a, c, d], -1), np.stack([b, c, d], -1)).reshape(-1, 3)
        tris = np.concatenate([t1, t2])
        xy = np.column_stack([X.ravel(), Y.ravel()])
        verts = np.column_stack([xy, self.cavity_depth(xy[:, 0], xy[:, 1])])
        return verts, tris, xy

    @property
    def cavity_rect(self) -> tuple[float, float, float, float]:
        """(x0, y0, width, height) of the cavity's local (x, y) coordinates."""
        w = self.cavity_half_width
        return (-w, self.cavity_bottom, 2 * w, self.cavity_top - self.cavity_bottom)

    # ------------------------------------------------------------ teeth
    def arch_z(self, x, upper: bool = True):
        """z of the labial face of the incisal edge along the arch."""
        x = np.asarray(x, float)
        return self.incisor_z - (0.0 if upper else OVERJET) - self.arch_curvature * x**2

    def edge_y(self, x, upper: bool = True):
        """y of the incisal edge: upper just below the mouth line, lower just below that."""
        x = np.asarray(x, float)
        return self.L.stomion_y + 0.0011 * x**2 - (2.0 if upper else 2.6)

    def teeth(self, upper: bool) -> TeethRow:
        L = self.L
        k = self.arch_curvature
        # Arc length of the parabola x -> (x, -k x^2), inverted by a dense table.
        # The arch ends beyond the mouth corners, but before the cavity's side walls rise.
        x_end = min(L.mouth_half_width + ARCH_END_BEYOND_CORNER,
                    float(self.cavity_half_width_at(L.stomion_y)) - CAVITY_WALL - 1.0)
        xt = np.linspace(0.0, x_end, 2001)
        st = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xt), np.diff(k * xt**2)))])
        m = int(np.ceil(st[-1] / ARCH_STEP))
        s = np.linspace(-st[-1], st[-1], 2 * m + 1)       # odd: one ring exactly at the midline
        x = np.sign(s) * np.interp(np.abs(s), st, xt)
        normal = np.column_stack([2 * k * x, np.zeros_like(x), np.ones_like(x)])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        up = np.array([0.0, 1.0 if upper else -1.0, 0.0])

        # Cross-section (n along the outward normal, h from the edge toward the gum).
        # Strip height (crown + gum band): the upper teeth end below the cavity's top wall.
        room = self.cavity_top - CAVITY_WALL_TOP - 1.0 - float(self.edge_y(x_end, True)) - 0.8
        H, G = (min(10.0, room), 2.2) if upper else (9.0, 2.0)
        r, tilt, T = 0.8, (0.18 if upper else 0.25), 6.0
        arc = np.linspace(0.0, np.pi, 7)
        n_c = -tilt * r - r
        labial_h = np.array([H, H - G, 0.55 * (H - G), r])
        lingual_h = labial_h[::-1][1:]
        thick = lambda h: 2 * r + (T - 2 * r) * np.clip((h - r) / (H - r), 0, 1) ** 0.6  # noqa: E731
        prof = np.concatenate([
            np.column_stack([-tilt * labial_h, labial_h]),
            np.column_stack([n_c + r * np.cos(arc[1:-1]), r - r * np.sin(arc[1:-1])]),
            np.column_stack([-tilt * lingual_h - thick(lingual_h), lingual_h]),
            [[-tilt * H - T / 2, H + 0.8]],
            [[-tilt * H, H]],                                 # closes the loop (uv seam)
        ])
        loop = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(prof, axis=0), axis=1))])
        n_prof = len(prof)
        i_gum_labial, i_edge = 1, len(labial_h) + (len(arc) - 2) // 2
        i_gum_lingual = len(labial_h) + len(arc) - 2 + len(lingual_h) - 2

        base = np.column_stack([x, self.edge_y(x, upper), self.arch_z(x, upper)])
        verts = (base[:, None, :] + prof[None, :, 0, None] * normal[:, None, :]
                 + prof[None, :, 1, None] * up[None, None, :])
        verts = verts.reshape(-1, 3)
        # Safety for unusual identities: never closer than TEETH_CLEARANCE to the skin.
        skin = self.shape.skin_depth(verts[:, 0], verts[:, 1])
        verts[:, 2] = _softmin(verts[:, 2], skin - TEETH_CLEARANCE - 0.3, 0.3)
        local = np.column_stack([np.repeat(s, n_prof), np.tile(loop, len(s))])

        ring = lambda i, j: i * n_prof + j  # noqa: E731
        i = np.arange(len(s) - 1)[:, None]
        j = np.arange(n_prof - 1)[None, :]
        q = np.stack([ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)], -1).reshape(-1, 4)
        tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
        # End caps: a fan from each end ring's centre.
        caps, cap_local = [], []
        nv = len(verts)
        for e, ring_i in enumerate((0, len(s) - 1)):
            idx = ring(ring_i, np.arange(n_prof - 1))
            centre = verts[idx].mean(axis=0)
            c = nv + e
            caps.append(np.column_stack([np.full(n_prof - 1, c), np.roll(idx, -1), idx]))
            verts = np.concatenate([verts, centre[None]])
            cap_local.append([s[ring_i], loop[-1]])        # gum colour
        local = np.concatenate([local, cap_local])
        tris = np.concatenate([tris, caps[0][:, [0, 2, 1]], caps[1]])
        tris = _orient_outward(verts, tris)

        widths = np.asarray(UPPER_TOOTH_WIDTHS if upper else LOWER_TOOTH_WIDTHS)
        bounds = np.cumsum(widths)
        bounds = np.concatenate([-bounds[::-1], [0.0], bounds])
        mid = m
        return TeethRow(
            upper=upper, vertices=verts, triangles=tris, local=local,
            local_rect=(-st[-1], 0.0, 2 * st[-1], loop[-1]),
            gum_lines=(float(loop[i_gum_labial]), float(loop[i_gum_lingual])),
            edge_loop=float(loop[i_edge]),
            tooth_boundaries=bounds,
            points={"edge": ring(mid, i_edge), "gum": ring(mid, i_gum_labial)},
        )


def _orient_outward(verts: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Flip all triangles if the closed surface's signed volume is negative (normals inward)."""
    v = verts[tris]
    volume = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0
    return tris if volume > 0 else tris[:, [0, 2, 1]]
