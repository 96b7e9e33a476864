"""shape.py
----
The skin of the default face as a height field z = skin_depth(x, y), like a
single-view range scanner sees it, plus the eyeballs behind the lid openings.

The surface is a sum of smooth terms, each one a piece of anatomy:
a superelliptic head whose half-width follows the face outline, a midline
profile (forehead, glabella, philtrum, chin), the muzzle (dental arches),
orbits, brow ridge, nose (dorsum, tip, alae, nostrils), cheekbones,
nasolabial folds, lips with a crease at the mouth line, mentolabial sulcus
and chin. The lids are the skin pushed out by the eyeball (a smooth maximum
of the orbit and the eyeball plus lid thickness). All lengths in mm.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from core.default_face.params import FaceLayout

LID_THICKNESS = 1.3  # mm, skin of the lid margin in front of the eyeball
OUTLINE_T = 0.95  # the scan stops where |x| reaches this fraction of the outline half-width (steep sides)


def _gauss(x, y, cx, cy, sx, sy):
    return np.exp(-(((x - cx) / sx) ** 2) - ((y - cy) / sy) ** 2)


def _smooth_max(a, b, k):
    """Smooth maximum of a and b with blending width k (mm); exact max when far apart."""
    m = np.maximum(a, b)
    return m + k * np.log(np.exp((a - m) / k) + np.exp((b - m) / k))


def _smoothstep(e0, e1, v):
    t = np.clip((v - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


class FaceShape:
    """Evaluates the skin height field and the eyeballs for one layout."""

    def __init__(self, layout: FaceLayout):
        self.L = layout
        p = layout.p
        L = layout
        # Half-width of the face outline as a function of height (the jaw line
        # below the mouth narrows to the chin). Control points scale with the
        # width parameters.
        zy, go = p.face_width / 2, p.jaw_width / 2
        ys = [L.menton_y - 1.5, L.menton_y + 3, L.menton_y + 10, L.chin_y + 6, L.sulcus_y,
              L.stomion_y - 2, L.subnasale_y, L.eye_line_y - 20, L.eye_line_y, L.nasion_y + 20,
              L.nasion_y + 45, L.nasion_y + 70]
        ws = [0.0, 18.0, 28.0, 0.78 * go, 0.90 * go, 0.96 * go, 0.93 * zy, 0.99 * zy, 1.0 * zy,
              0.95 * zy, 0.90 * zy, 0.84 * zy]
        self._half_width = PchipInterpolator(ys, ws, extrapolate=True)
        # Midline profile of the head (without nose, lips and chin details).
        my = [L.nasion_y + 70, L.nasion_y + 45, L.nasion_y + 25, L.nasion_y + 9, L.nasion_y,
              L.eye_line_y - 12, L.subnasale_y + 4, L.stomion_y, L.sulcus_y, L.chin_y,
              L.menton_y + 6, L.menton_y - 2]
        mz = [-45.0, -29.0, -22.0, -21.0, -22.5,
              -26.0, -21.0, -21.5, -25.5, -27.0,
              -33.0, -44.0]
        self._midline = PchipInterpolator(my[::-1], mz[::-1], extrapolate=True)

    # ------------------------------------------------------------ outline
    def half_width(self, y):
        """Half-width of the face outline at height y (mm); 0 below the chin."""
        return np.maximum(self._half_width(np.asarray(y, dtype=float)), 0.0)

    def outline_t(self, x, y):
        """|x| / half_width(y): 0 on the midline, 1 on the outline (inf outside below the chin)."""
        w = self.half_width(y)
        return np.divide(np.abs(x), w, out=np.full(np.shape(x), np.inf), where=w > 1e-6)

    def inside_scan(self, x, y):
        """Mask of (x, y) that the frontal scan covers."""
        t = self.outline_t(x, y)
        return (t < OUTLINE_T) & (y > self.L.menton_y - 1.0) & (y < self.L.nasion_y + 62.0)

    # ------------------------------------------------------------ eyeballs
    def eyeball_centres(self) -> np.ndarray:
        """(2, 3) centres of the left (+x) and right eyeballs, mm."""
        L = self.L
        c = np.array([L.pupil_x, L.eye_line_y, L.eyeball_apex_z - L.eyeball_radius])
        return np.stack([c, c * [-1, 1, 1]])

    def eyeball_radii(self) -> np.ndarray:
        """(3,) semi-axes of each eyeball, mm: wide enough to fill the palpebral opening."""
        L = self.L
        half_len = (L.eye_outer_x - L.eye_inner_x) / 2
        return np.array([max(L.eyeball_radius, half_len + 1.5), L.eyeball_radius, L.eyeball_radius])

    def eyeball_front_z(self, x, y):
        """z of the front of the eyeballs at (x, y), -inf where no eyeball is in front."""
        c = self.eyeball_centres()[0]
        r = self.eyeball_radii()
        q = ((np.abs(x) - c[0]) / r[0]) ** 2 + ((y - c[1]) / r[1]) ** 2
        return np.where(q < 1, c[2] + r[2] * np.sqrt(np.clip(1 - q, 0, None)), -np.inf)

    # ------------------------------------------------------------ skin
    def skin_depth(self, x, y):
        """z of the skin at (x, y), mm. Arrays of any matching shape."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        L, p = self.L, self.L.p
        ax = np.abs(x)

        # Head: superellipse across, whose sides fall back 75 mm at the outline.
        t = np.clip(self.outline_t(x, y), 0, 1.2)
        tt = np.clip(t, 0, 1)
        p_exp = 2.6
        across = 1.0 - np.clip(1.0 - tt**p_exp, 0, None) ** (1.0 / p_exp) + np.clip(t - 1, 0, None)
        z = self._midline(y) - 75.0 * across

        # Muzzle: the dental arches push the mouth region forward, more at the
        # midline; broad in y so that it blends without a visible edge.
        muzzle_y = np.exp(-(((y - (L.stomion_y - 4)) / 24.0) ** 2))
        z += 9.0 * muzzle_y * (np.exp(-((x / 22.0) ** 2)) - 1.0)

        # Forehead: frontal eminences, temple hollows, glabella and brow ridge.
        z += 1.5 * (_gauss(ax, y, 28, L.nasion_y + 32, 14, 12))
        z -= 4.0 * _gauss(ax, y, 58, L.eye_line_y + 22, 9, 14)
        brow_x = L.brow_x
        ridge_y = np.interp(ax, [0, brow_x[0], brow_x[1], brow_x[2] + 6],
                            [L.nasion_y + 6, L.brow_y[0] - 2, L.brow_y[1] - 3.5, L.brow_y[2] - 5])
        ridge = np.exp(-(((y - ridge_y) / 5.5) ** 2)) * np.exp(-((np.clip(ax - 40, 0, None) / 14) ** 2))
        z += p.brow_ridge * 2.6 * ridge

        # Orbits: a broad hollow around each eye, deepest at the inner corner.
        z -= 13.0 * _gauss(ax, y, L.pupil_x - 1.5, L.eye_line_y - 1.0, 15.0, 11.0)
        z -= 3.0 * _gauss(ax, y, L.eye_inner_x + 1.5, L.eye_line_y + 1, 5, 6)
        # Lower lid / tear trough and the upper lid crease.
        z -= 1.4 * _gauss(ax, y, L.pupil_x - 4, L.eye_line_y - 12, 10, 2.8)

        # Cheeks: malar eminence and the fullness below it.
        z += p.cheekbone_prominence * 5.0 * _gauss(ax, y, 43, L.eye_line_y - 20, 16, 11)
        z += 2.5 * _gauss(ax, y, 35, L.subnasale_y - 6, 14, 12)
        # Nasolabial fold: a groove from the ala to beyond the mouth corner.
        z += self._nasolabial(ax, y)

        # Lids: skin draped over the eyeball.
        lids = self.eyeball_front_z(x, y) + LID_THICKNESS
        crease_y = L.lid_margins(ax)[0] + 4.5
        in_eye = (ax > L.eye_inner_x - 3) & (ax < L.eye_outer_x + 3)
        lids = lids - 0.9 * np.exp(-(((y - crease_y) / 1.2) ** 2)) * in_eye
        z = _smooth_max(z, lids, 0.8)

        z += self._lips_and_chin(x, y)
        z = _smooth_max(z, self._nose(x, y), 1.2)
        return z

    def _nasolabial(self, ax, y):
        L = self.L
        # Line from above the ala outward and down past the mouth corner.
        y0, y1 = L.subnasale_y + 4, L.stomion_y - 10
        x0, x1 = L.alar_half_width + 2.0, L.mouth_half_width + 8.0
        s = np.clip((y0 - y) / (y0 - y1), 0, 1)
        fold_x = x0 + (x1 - x0) * s ** 0.8
        along = _smoothstep(y0 + 4, y0 - 2, y) * _smoothstep(y1 - 6, y1 + 2, y)
        d = ax - fold_x
        groove = -0.8 * np.exp(-((d / 2.6) ** 2))
        bulge = 0.9 * np.exp(-(((d - 5.0) / 4.5) ** 2))
        return (groove + bulge) * along

    def _lips_and_chin(self, x, y):
        L, p = self.L, self.L.p
        ax = np.abs(x)
        line = L.mouth_line(x)
        hw = L.mouth_half_width
        lateral = np.exp(-((np.clip(ax - hw * 0.55, 0, None) / (hw * 0.30)) ** 2))
        upper_h = np.maximum(L.upper_lip_border(np.minimum(ax, hw)) - L.mouth_line(np.minimum(ax, hw)), 1.0)
        lower_h = np.maximum(L.mouth_line(np.minimum(ax, hw)) - L.lower_lip_border(np.minimum(ax, hw)), 1.0)
        u = (y - line) / upper_h            # 0 at the mouth line, 1 at the upper border
        v = (line - y) / lower_h            # 0 at the mouth line, 1 at the lower border
        z = np.zeros_like(x)
        # Vermilion: rolled forward, highest about half-way, a crisp edge at the border.
        upper = 3.6 * p.lip_thickness * np.exp(-(((u - 0.55) / 0.5) ** 2)) * (u > 0)
        upper += 0.5 * np.exp(-(((u - 1.0) / 0.12) ** 2))   # white roll
        lower = 4.2 * p.lip_thickness * np.exp(-(((v - 0.45) / 0.55) ** 2)) * (v > 0)
        z += (upper + lower) * lateral
        # Mouth line crease: lips meet in a groove.
        z -= 1.6 * np.exp(-(((y - line) / 0.9) ** 2)) * np.exp(-((np.clip(ax - hw, 0, None) / 2.5) ** 2))
        # Modiolus: slight hollow just outside each corner.
        z -= 1.8 * _gauss(ax, y, hw + 3.0, line, 3.5, 4.5)
        # Philtrum: a shallow groove between two ridges from the nose to the lip.
        ph_y = _smoothstep(L.subnasale_y + 1, L.subnasale_y - 3, y) * _smoothstep(
            line + upper_h + 0.5, line + upper_h + 3.0, y)
        z += ph_y * (0.7 * np.exp(-(((ax - 5.0) / 1.8) ** 2)) - 0.5 * np.exp(-((x / 2.3) ** 2)))
        z += 1.6 * _gauss(ax, y, 0, L.subnasale_y - 6, 12, 6) * (y < L.subnasale_y)
        # Mentolabial sulcus and chin boss.
        z -= 2.4 * _gauss(ax, y, 0, L.sulcus_y, 16, 4.0)
        z += p.chin_prominence * 4.5 * _gauss(ax, y, 0, L.chin_y, 14, 8.5)
        return z

    def _nose(self, x, y):
        """Height field of the external nose; combined with the face by a smooth maximum.

        Body (dorsum to tip) with a rounded cross-section, a tip lobule, two
        alae (wings) and the columella; nostrils are dents on the underside.
        """
        L, p = self.L, self.L.p
        ax = np.abs(x)
        tip_z = -1.0 + (p.nose_projection - 17.0)
        sub_z = tip_z - p.nose_projection
        # Dorsum profile from the nasion down to just above the tip.
        prof_y = [L.nose_tip_y - 3.0, L.nose_tip_y + 1.0, L.nose_tip_y + 7, (L.nose_tip_y + L.nasion_y) / 2,
                  L.nasion_y - 4, L.nasion_y + 3]
        prof_z = [tip_z - 3.0, tip_z - 0.4, tip_z - 3.2, tip_z - 10.5, -19.5, -24.0]
        ridge = PchipInterpolator(prof_y, prof_z, extrapolate=True)(y)
        # Half-width of the body: narrow bridge widening toward the tip.
        s = np.clip((L.nasion_y - y) / (L.nasion_y - L.nose_tip_y), 0, 1)
        half = 6.5 + 5.0 * s**1.5
        body = ridge - 9.0 * (ax / half) ** 2
        # Below the tip the body curls under smoothly (no cut edge).
        body -= 2.5 * np.clip((L.nose_tip_y - 1.0 - y) / 2.0, 0, None) ** 2
        # Tip lobule: a rounded cap at the tip.
        tip = tip_z - 9.0 * ((ax / 8.0) ** 2 + ((y - (L.nose_tip_y + 0.5)) / 7.0) ** 2)
        # Columella: narrow bridge from the tip down to the subnasale.
        t = np.clip((L.nose_tip_y - y) / (L.nose_tip_y - L.subnasale_y), 0, 1)
        col_z = tip_z - 2.0 - (p.nose_projection - 2.0) * t**1.3
        columella = np.where((y < L.nose_tip_y) & (y > L.subnasale_y - 1), col_z - 6.0 * (ax / 4.5) ** 2, -np.inf)
        # Alae: rounded wings either side, their base on the cheek.
        ala_x, ala_y = L.alar_half_width - 5.0, L.subnasale_y + 6.0
        ala = sub_z + 0.5 - 6.0 * (((ax - ala_x) / 6.0) ** 2 + ((y - ala_y) / 6.5) ** 2)
        nose = _smooth_max(_smooth_max(body, tip, 1.5), columella, 0.8)
        nose = _smooth_max(nose, ala, 1.4)
        # Nostrils: openings on the underside between the columella and each ala.
        nostril = _gauss(ax, y, L.alar_half_width * 0.40, L.subnasale_y + 2.6, 2.8, 1.5)
        nose -= 3.0 * nostril
        foot = (y < L.nasion_y + 8) & (y > L.subnasale_y - 5) & (ax < L.alar_half_width + 9)
        return np.where(foot, nose, -np.inf)


def polar_cap_triangles(rings: int, segments: int) -> np.ndarray:
    """(k, 3) triangles of a polar cap: vertex 0 the pole, then ``rings`` rings of ``segments``
    vertices (ring r, segment s is vertex 1 + r * segments + s), a fan round the pole and two
    triangles per quad between rings (the eyeballs' caps, the ears' sides)."""
    def ring(r, k):
        return 1 + r * segments + (k % segments)

    k = np.arange(segments)
    cap = [np.column_stack([np.zeros(segments, int), ring(0, k), ring(0, k + 1)])]
    for r in range(rings - 1):
        cap.append(np.column_stack([ring(r, k), ring(r + 1, k), ring(r + 1, k + 1)]))
        cap.append(np.column_stack([ring(r, k), ring(r + 1, k + 1), ring(r, k + 1)]))
    return np.concatenate(cap)


def plane_signed_area2(xy: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(m,) twice the signed area of each triangle ``tris`` (m, 3) in the plane ``xy`` (n, 2)
    (positive: counter-clockwise)."""
    a, b, c = xy[tris[:, 0]], xy[tris[:, 1]], xy[tris[:, 2]]
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
