"""texture.py
----
Procedural colour image of the default face, registered to the mesh by the
orthographic projection (x, y) -> (u, v) of the texture frame.

Painted layers, in order: skin (tone, mottling, fine grain, redness over
cheeks/nose/chin, darkening in creases from the surface's Laplacian), hair
above the hairline, eyebrows (anisotropic strands), lips, lid lashes,
nostrils. The eyeballs are painted in a separate square of the image (the
"eye atlas", in the frame's unused right margin) so that lid skin and the
eyeball behind it never share texels. The mouth interior (upper teeth, lower
teeth, cavity) has its own patches stacked in the unused left margin (the
"mouth atlas"), each a linear map of the component's local coordinates.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from core.default_face.params import FaceLayout
from core.default_face.shape import _smoothstep

# Skin colours (sRGB) from very light to very dark, interpolated by skin_tone.
_SKIN_TONES = np.array([[240, 205, 185], [224, 178, 148], [190, 138, 102], [140, 94, 64], [92, 60, 42]], float)
_IRIS = np.array([[70, 110, 160], [95, 120, 70], [110, 80, 40], [60, 38, 22]], float)  # blue, green, hazel, brown


HAIRLINE_SOFT_MM = 8.0   # the full head's hair thins out over this band at the hairline
HAIRLINE_WISPS_MM = 2.0  # ... its edge moved hair by hair by about this much


#: Relative amplitude of the full head's skin blotches at 9, 3 and 0.7 texels (3.6, 1.2, 0.3 mm).
FACE_SKIN_NOISE = (0.04, 0.012, 0.0)


def _lerp_table(table: np.ndarray, t: float) -> np.ndarray:
    pos = np.clip(t, 0, 1) * (len(table) - 1)
    i = min(int(pos), len(table) - 2)
    return table[i] + (table[i + 1] - table[i]) * (pos - i)


def _soft(d, width):
    """1 inside (d < 0), 0 outside, smooth over ``width`` mm."""
    return 1.0 / (1.0 + np.exp(np.clip(d / (0.25 * width), -50, 50)))


def eye_atlas_centre(frame) -> tuple[float, float]:
    """(x, y) in mm, inside the texture frame, where the eyeball painting is centred."""
    x0, y0, w, h = frame
    return (x0 + w - 20.0, y0 + h / 2)


ATLAS_GAP = 3.0  # mm between mouth-atlas patches and from the skin / frame edges


def mouth_atlas(frame, skin_half_width: float) -> dict[str, tuple[float, float, float, float]]:
    """Rectangles (x0, y0, width, height) in mm of the frame for the mouth patches.

    They are stacked from the top of the frame's left margin, between the
    frame's left edge and the skin (which spans |x| <= ``skin_half_width``).
    """
    x0, y0, w, h = frame
    left, right = x0 + ATLAS_GAP, -skin_half_width - 2 * ATLAS_GAP
    width = right - left
    if width < 10.0:
        raise ValueError("no room left of the skin for the mouth atlas")
    rects, top = {}, y0 + h - ATLAS_GAP
    for name, height in (("teeth_upper", 26.0), ("teeth_lower", 26.0), ("mouth_cavity", 50.0)):
        rects[name] = (left, top - height, width, height)
        top -= height + ATLAS_GAP
    return rects


def atlas_map(local, local_rect, atlas_rect) -> np.ndarray:
    """(k, 2) local coordinates -> (k, 2) frame mm inside ``atlas_rect`` (linear, per axis)."""
    local = np.asarray(local, float)
    lx, ly, lw, lh = local_rect
    ax, ay, aw, ah = atlas_rect
    return np.column_stack([ax + (local[:, 0] - lx) / lw * aw, ay + (local[:, 1] - ly) / lh * ah])


def paint_texture(layout: FaceLayout, shape, frame, size, mouth=None, full_head: bool = False) -> np.ndarray:
    """(H, W, 3) uint8 image for the frame (x0, y0, width, height) in mm; size = (W, H) pixels.

    ``mouth`` = (MouthInterior, upper TeethRow, lower TeethRow, atlas rects) paints the mouth atlas.
    ``full_head=True`` paints for a face whose outline is where the head shell joins on: the crease
    darkening fades out toward the scan's outline (where the depth steps off the scan and paints a
    dark line), and the band along the outline and under the chin, where the orthographic mapping
    stretches a texel over millimetres of steep skin (streaks), is blurred. The front-only face
    keeps the old image.
    """
    p = layout.p
    W, H = size
    x0, y0, fw, fh = frame
    px = fw / W
    X, Y = np.meshgrid(x0 + (np.arange(W) + 0.5) * px, y0 + fh - (np.arange(H) + 0.5) * (fh / H))
    AX = np.abs(X)
    rng = np.random.default_rng(p.texture_seed)
    noise = lambda sigma: _unit(ndimage.gaussian_filter(rng.standard_normal((H, W)), sigma))  # noqa: E731

    # --- skin
    base = _lerp_table(_SKIN_TONES, p.skin_tone)
    img = np.broadcast_to(base, (H, W, 3)).copy()
    coarse, medium, fine = noise(9.0), noise(3.0), noise(0.7)
    if full_head:
        # The head shell's skin has soft blotches and a faint grain (head.paint_head_atlas); with the
        # front-only face's stronger 0.3 mm grain the face read as a dirty mask on a clean head.
        img *= (1.0 + FACE_SKIN_NOISE[0] * coarse + FACE_SKIN_NOISE[1] * medium + FACE_SKIN_NOISE[2] * fine)[..., None]
    else:
        img *= (1.0 + 0.045 * coarse + 0.025 * medium + 0.018 * fine)[..., None]
    red = (0.55 * _gauss(AX, Y, 38, layout.subnasale_y + 4, 16, 12) + 0.45 * _gauss(AX, Y, 0, layout.nose_tip_y, 9, 8)
           + 0.25 * _gauss(AX, Y, 0, layout.chin_y, 14, 9) + 0.2 * _gauss(AX, Y, 0, layout.nasion_y + 30, 30, 14))
    img += red[..., None] * np.array([18.0, -8.0, -6.0]) * (1 - 0.5 * p.skin_tone)
    z = shape.skin_depth(X, Y)
    inside = np.isfinite(z) & shape.inside_scan(X, Y)
    z = np.where(inside, z, np.nanmin(np.where(inside, z, np.nan)))
    curvature = ndimage.gaussian_laplace(z, sigma=2.0 / px) * (1.0 / px) ** 0  # mm/px^2 scale irrelevant: normalised
    crease = np.clip(_unit_pos(curvature), 0, 3)
    if full_head:
        from core.default_face.shape import OUTLINE_T

        crease *= _smoothstep(OUTLINE_T - 0.02, OUTLINE_T - 0.12, shape.outline_t(X, Y))
        crease *= _smoothstep(layout.menton_y + 1.0, layout.menton_y + 8.0, Y)
    img *= (1.0 - 0.06 * crease)[..., None]
    under_eye = _gauss(AX, Y, layout.pupil_x - 2, layout.eye_line_y - 9, 11, 4)
    img += under_eye[..., None] * np.array([-10.0, -14.0, -4.0])

    # --- hair above the hairline (dips at the temples)
    hairline = layout.hairline_y - 9.0 * (AX / 45.0) ** 2 + 6.0 * np.exp(-(((AX - 50) / 9) ** 2))
    if full_head:
        # A hairline is no drawn line: the hair thins out over ~8 mm, in wisps (a fine noise, long
        # along the hair's fall, moves the edge by a few mm). Its own generator: the layers after
        # keep their noise.
        wisps = _unit(ndimage.gaussian_filter(np.random.default_rng(p.texture_seed + 211).standard_normal((H, W)),
                                              (2.5, 0.6)))
        hair = _soft(hairline - Y + HAIRLINE_WISPS_MM * wisps, HAIRLINE_SOFT_MM)
    else:
        hair = _soft(hairline - Y, 2.5)
    strands = 0.75 + 0.25 * _unit(ndimage.gaussian_filter(rng.standard_normal((H, W)), (3.0, 0.6)))
    hair_colour = np.array([52.0, 36.0, 26.0]) * (1 - 0.4 * p.skin_tone)
    img = _blend(img, hair_colour * strands[..., None], hair * 0.97)

    # --- eyebrows: thick at the head, tapering to the tail; strands run laterally
    xi, xt, xo = layout.brow_x
    s = np.clip((AX - xi) / (xo - xi), 0, 1)
    centre = layout.brow_curve(AX)
    half = 4.2 * (1 - s) + 1.4 * s
    inside_brow = (AX > xi - 1.5) & (AX < xo + 1.0)
    brow = _soft(np.abs(Y - centre) - half, 2.4) * inside_brow * _soft(xi - 0.5 - AX, 2.0) * _soft(AX - xo, 3.0)
    hairs = np.clip(0.78 + 0.25 * _unit(ndimage.gaussian_filter(rng.standard_normal((H, W)), (0.6, 2.0))), 0, 1)
    brow_colour = np.array([58.0, 40.0, 30.0]) * (1 - 0.35 * p.skin_tone)
    img = _blend(img, brow_colour, brow * hairs * 0.85)

    # --- lips (vermilion), slightly darker toward the mouth line
    hw = layout.mouth_half_width
    ub, lb, ml = layout.upper_lip_border(X), layout.lower_lip_border(X), layout.mouth_line(X)
    lips = _soft(Y - ub, 0.8) * _soft(lb - Y, 1.0) * _soft(AX - hw, 1.5)
    lip_colour = np.array([196.0, 112.0, 110.0]) * (1 - 0.45 * p.skin_tone) + base * 0.25 * p.skin_tone
    lip_shade = 1.0 - 0.25 * np.exp(-(((Y - ml) / 0.8) ** 2)) + 0.05 * noise(1.2)
    img = _blend(img, lip_colour * lip_shade[..., None], lips * 0.85)

    # --- lids: lashes along the upper margin, a fainter line along the lower
    up, lo = layout.lid_margins(AX)
    in_eye = (AX > layout.eye_inner_x - 0.5) & (AX < layout.eye_outer_x + 1.5)
    s_eye = np.clip((AX - layout.eye_inner_x) / (layout.eye_outer_x - layout.eye_inner_x), 0, 1)
    lash_w = 0.5 + 1.1 * s_eye
    lashes = _soft(np.abs(Y - up - 0.35 - lash_w / 2) - lash_w / 2, 0.4) * in_eye
    img = _blend(img, np.array([30.0, 22.0, 20.0]), lashes * 0.9)
    lower_lash = _soft(np.abs(Y - lo + 0.4) - 0.3, 0.3) * in_eye * (0.2 + 0.5 * s_eye)
    img = _blend(img, np.array([70.0, 50.0, 46.0]), lower_lash)
    crease_y = up + 4.5
    img *= (1.0 - 0.10 * np.exp(-(((Y - crease_y) / 1.0) ** 2)) * in_eye)[..., None]

    # --- nostrils: the front-only face's are painted dark spots; the full head's are pockets in the
    # nose (nostrils.py), darker the deeper inside
    if full_head:
        from core.default_face.nostrils import shade

        img = _blend(img, np.array([52.0, 28.0, 25.0]) * (1 - 0.4 * p.skin_tone), 0.95 * shade(shape, X, Y))
    else:
        nostril = _gauss(AX, Y, layout.alar_half_width * 0.42, layout.subnasale_y + 2.4, 2.6, 1.3)
        img = _blend(img, np.array([60.0, 35.0, 30.0]), np.clip(1.6 * nostril, 0, 1))

    if full_head:
        steep = np.maximum(_smoothstep(0.80, 0.93, shape.outline_t(X, Y)),
                           _smoothstep(layout.menton_y + 12.0, layout.menton_y + 2.0, Y))
        blurred = ndimage.gaussian_filter(img, (12.0, 12.0, 0))   # (the atlases are painted after this)
        img = img * (1 - steep[..., None]) + blurred * steep[..., None]

    # --- eye atlas
    cx, cy = eye_atlas_centre(frame)
    _paint_eye(img, X - cx, Y - cy, layout, rng)
    if mouth is not None:
        _paint_mouth(img, X, Y, px, layout, *mouth)
    return np.clip(img, 0, 255).astype(np.uint8)


def _patch_local(X, Y, px, local_rect, atlas_rect):
    """Mask of the texels of a patch (with a 2-texel skirt for filtering) and their local coordinates."""
    ax, ay, aw, ah = atlas_rect
    lx, ly, lw, lh = local_rect
    pad = 2.0 * px
    mask = (X > ax - pad) & (X < ax + aw + pad) & (Y > ay - pad) & (Y < ay + ah + pad)
    u = lx + np.clip((X[mask] - ax) / aw, 0, 1) * lw
    v = ly + np.clip((Y[mask] - ay) / ah, 0, 1) * lh
    return mask, u, v


def _paint_mouth(img, X, Y, px, layout: FaceLayout, mouth, upper, lower, rects):
    """Cavity (red-brown mucosa darkening to near black at the back, a hint of tongue) and teeth."""
    p = layout.p
    mask, x, y = _patch_local(X, Y, px, mouth.cavity_rect, rects["mouth_cavity"])
    depth = np.clip(mouth.shape.skin_depth(x, y) - mouth.cavity_depth(x, y), 0, None)
    dark = _smoothstep(3.0, 20.0, depth)[:, None]
    mucosa = np.array([126.0, 54.0, 52.0]) * (1 - dark) + np.array([24.0, 10.0, 10.0]) * dark
    tongue = 0.55 * _gauss(x, y, 0.0, layout.stomion_y - 17.0, 15.0, 8.0)[:, None]
    mucosa = mucosa * (1 - tongue) + np.array([112.0, 46.0, 48.0]) * (1 - 0.5 * dark) * tongue
    img[mask] = mucosa
    gum = np.array([198.0, 100.0, 102.0]) * (1 - 0.35 * p.skin_tone)
    for row, name in ((upper, "teeth_upper"), (lower, "teeth_lower")):
        mask, s, v = _patch_local(X, Y, px, row.local_rect, rects[name])
        d = np.min(np.abs(s[:, None] - row.tooth_boundaries[None, :]), axis=1)
        papilla = 1.4 * np.exp(-((d / 1.1) ** 2))
        lab, lin = row.gum_lines
        to_gum = np.minimum(v - (lab + papilla), (lin - papilla) - v)     # < 0 on the gum
        enamel = np.array([236.0, 230.0, 212.0])
        cervical = np.exp(-np.clip(to_gum, 0, None) / 2.5)[:, None]
        tooth = enamel * (1 - 0.6 * cervical) + np.array([220.0, 204.0, 168.0]) * 0.6 * cervical
        edge = 0.35 * np.exp(-(((v - row.edge_loop) / 1.2) ** 2))[:, None]
        tooth = tooth * (1 - edge) + np.array([200.0, 205.0, 212.0]) * edge
        tooth *= (1.0 - 0.45 * np.exp(-((d / 0.4) ** 2)))[:, None]
        on_gum = _smoothstep(0.25, -0.25, to_gum)[:, None]
        img[mask] = tooth * (1 - on_gum) + gum * on_gum


def _paint_eye(img, dx, dy, layout: FaceLayout, rng):
    """Sclera, iris with radial fibres and a limbal ring, pupil (1/3 of the iris: MPEG-4 neutral)."""
    p = layout.p
    r = np.hypot(dx, dy)
    region = (np.abs(dx) < 18) & (np.abs(dy) < 15)
    sclera = np.array([236.0, 230.0, 222.0]) - np.clip(np.abs(dx) - 6, 0, None)[..., None] * np.array([0.6, 1.4, 1.4])
    angle = np.arctan2(dy, dx)
    fibres = np.sin(angle * 37) * 0.5 + np.sin(angle * 23 + 1.3) * 0.5
    iris_base = _lerp_table(_IRIS, p.iris_hue)
    radial = (r / layout.iris_radius)
    iris = iris_base * (0.85 + 0.15 * fibres[..., None]) * (1.15 - 0.35 * radial)[..., None]
    iris += np.array([40.0, 30.0, 10.0]) * np.exp(-(((radial - 0.45) / 0.12) ** 2))[..., None]  # collarette
    limbus = np.exp(-(((r - layout.iris_radius) / 0.45) ** 2))
    pupil_r = layout.iris_radius / 3
    eye = np.where((r < layout.iris_radius)[..., None], iris, sclera)
    eye = eye * (1 - 0.6 * limbus)[..., None]
    eye = np.where((r < pupil_r)[..., None], np.array([12.0, 10.0, 10.0]), eye)
    img[region] = eye[region]


def _gauss(x, y, cx, cy, sx, sy):
    return np.exp(-(((x - cx) / sx) ** 2) - ((y - cy) / sy) ** 2)


def _unit(a: np.ndarray) -> np.ndarray:
    """Scale a zero-mean field to unit standard deviation."""
    return (a - a.mean()) / (a.std() + 1e-12)


def _unit_pos(a: np.ndarray) -> np.ndarray:
    s = np.std(a)
    return a / (s + 1e-12)


def _blend(img, colour, alpha):
    alpha = np.clip(alpha, 0, 1)[..., None]
    return img * (1 - alpha) + np.asarray(colour) * alpha
