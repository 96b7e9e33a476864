"""build.py
----
Assemble the default face mesh from the height field, like a single-view
range scanner delivers it: a regular (x, y) grid of ~50,000 vertices over the
front of the face, triangulated cell by cell, with a registered 640x480
texture mapped by orthographic projection.

Beyond a raw scan, the mesh is cut where a face opens:
- the mouth line between the corners is a seam of duplicated vertices (upper
  lip above, lower lip below), so the lips can part;
- each palpebral opening is a hole whose rim follows the lid margins exactly;
  an eyeball (ellipsoidal cap, its front pole at the pupil) sits behind it;
- behind the mouth seam sit the mouth cavity and the upper and lower teeth
  (see mouth.py), so that parted lips show the inside of a mouth.
Components, in vertex order: skin, left (+x) eyeball, right eyeball, mouth
cavity, upper teeth, lower teeth; all but the skin are named ``Face.parts``.
With ``full_head`` (the default) the head shell (skin, stitched to the front's
outer rim) and the ears (parts ``ear_l`` / ``ear_r``) follow (``with_head``).
The MPEG-4 feature points on the front of the face (and the teeth points on
the built-in teeth) are placed by construction as surface points of this mesh
(ground truth for landmarking).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from core.face import Face, FaceMetadata, SurfacePoint
from core.default_face.mouth import MouthInterior
from core.default_face.params import FaceLayout, FaceParameters
from core.default_face.rim_slivers import remove_rim_slivers
from core.default_face.shape import OUTLINE_T, FaceShape, polar_cap_triangles
from core.default_face.texture import atlas_map, eye_atlas_centre, mouth_atlas, paint_texture

GRID_SPACING = 0.645  # mm: gives ~50k vertices over the face, like the thesis's scans
TEXTURE_SIZE = (640, 480)  # (width, height) pixels, the Vivid 910 colour image
EYE_RINGS, EYE_SEGMENTS, EYE_CAP_DEG = 20, 64, 78.0
# The full head's front stops where the skin turns more than this from the view axis (z), as a
# frontal scanner's would: under the chin and along the jaw the height field falls back 10-14 mm
# within one grid row there, and those rows were needles (1 mm wide, 18 mm long) that any jaw motion
# stretched over 2x (face_quality: the open jaw, visemes aa, oh, E). The head shell covers that skin.
# The front-only face (the scan-like model of detection and registration) keeps its rim.
MAX_VIEW_ANGLE_DEG = 80.0


def generate_face(params: FaceParameters | None = None, *, grid_spacing: float = GRID_SPACING,
                  full_head: bool = True) -> Face:
    """Build a face from identity parameters. Deterministic: same input, identical arrays.

    ``full_head=False``: the front of the face only, like a single-view range scan (the synthetic
    scan database and the registration protocol use it). ``True`` appends the rest of the head
    (``head.py``) to a front that stops short of the steep rim a frontal scanner cannot see
    (``MAX_VIEW_ANGLE_DEG``; so its skin has fewer vertices than the front-only face's), its outer rim
    smoothed (the grid's staircase) where the head shell is stitched on; the feature points, eyeballs
    and mouth are the same.
    """
    params = params or FaceParameters()
    layout = FaceLayout.from_parameters(params)
    shape = FaceShape(layout)

    xy, tris, seam_upper, seam_lower = _skin_grid(layout, shape, grid_spacing, cut_unseen_rim=full_head)
    xy = _smooth_outer_rim(shape, xy, tris, grid_spacing)
    xy, tris = _cut_eye_openings(layout, xy, tris)
    xy, tris, keep = _drop_unused(xy, tris)
    remap = np.full(len(keep), -1)
    remap[keep] = np.arange(keep.sum())
    seam_upper, seam_lower = remap[seam_upper], remap[seam_lower]
    skin = np.column_stack([xy, shape.skin_depth(xy[:, 0], xy[:, 1])])
    n_skin_tris = len(tris)

    eye_verts, eye_tris, poles = _eyeballs(shape, offset=len(skin))
    mouth = MouthInterior(layout, shape)
    cavity_verts, cavity_tris, cavity_local = mouth.cavity()
    upper, lower = mouth.teeth(upper=True), mouth.teeth(upper=False)
    blocks = [("skin", skin, tris), ("eyes", eye_verts, eye_tris - len(skin)),
              ("mouth_cavity", cavity_verts, cavity_tris), ("teeth_upper", upper.vertices, upper.triangles),
              ("teeth_lower", lower.vertices, lower.triangles)]
    starts = np.cumsum([0] + [len(v) for _, v, _ in blocks])
    start = {name: int(st) for (name, _, _), st in zip(blocks, starts)}
    vertices = np.concatenate([v for _, v, _ in blocks])
    triangles = np.concatenate([t + st for (_, _, t), st in zip(blocks, starts)])
    n_eye = len(eye_verts) // 2
    parts = {
        "eyeball_l": np.arange(start["eyes"], start["eyes"] + n_eye),
        "eyeball_r": np.arange(start["eyes"] + n_eye, start["mouth_cavity"]),
        "mouth_cavity": np.arange(start["mouth_cavity"], start["teeth_upper"]),
        "teeth_upper": np.arange(start["teeth_upper"], start["teeth_lower"]),
        "teeth_lower": np.arange(start["teeth_lower"], len(vertices)),
    }

    frame = _texture_frame(layout)
    # Skin: orthographic projection. Eyeballs: their own square of the image
    # (the eye atlas), so lid skin and the eyeball behind it never share texels.
    # Mouth interior: its own patches (the mouth atlas) in the left margin.
    projected = vertices[:, :2].copy()
    atlas = np.asarray(eye_atlas_centre(frame))
    for k, centre in enumerate(shape.eyeball_centres()):
        part = parts["eyeball_l" if k == 0 else "eyeball_r"]
        projected[part] = projected[part] - centre[:2] + atlas
    rects = mouth_atlas(frame, float(np.abs(skin[:, 0]).max()))
    for name, local, local_rect in (("mouth_cavity", cavity_local, mouth.cavity_rect),
                                    ("teeth_upper", upper.local, upper.local_rect),
                                    ("teeth_lower", lower.local, lower.local_rect)):
        projected[parts[name]] = atlas_map(local, local_rect, rects[name])
    uv = np.column_stack([(projected[:, 0] - frame[0]) / frame[2], (projected[:, 1] - frame[1]) / frame[3]])
    texture = paint_texture(layout, shape, frame, TEXTURE_SIZE, mouth=(mouth, upper, lower, rects))

    face = Face(
        vertices, triangles, uv=uv, texture=texture, parts=parts,
        metadata=FaceMetadata(source="built-in", units="mm", name="Mimica default face"),
    )
    teeth_vertices = {
        "9.8": start["teeth_upper"] + upper.points["gum"],    # top of the upper teeth (midline, gum line)
        "9.10": start["teeth_upper"] + upper.points["edge"],  # bottom of the upper teeth (incisal edge)
        "9.11": start["teeth_lower"] + lower.points["edge"],  # top of the lower teeth (incisal edge)
        "9.9": start["teeth_lower"] + lower.points["gum"],    # bottom of the lower teeth (gum line)
    }
    landmarks = _place_feature_points(layout, shape, face, n_skin_tris, poles, teeth_vertices)
    for name, point in landmarks.items():
        face.set_landmark(name, point)
    face.metadata.notes.append(
        f"Generated by Mimica from identity parameters; {len(seam_upper)} mouth-seam vertex pairs."
    )
    if full_head:
        texture = paint_texture(layout, shape, frame, TEXTURE_SIZE, mouth=(mouth, upper, lower, rects),
                                full_head=True)
        face = with_head(face, layout, n_skin_tris, texture)
    return face


def with_head(face: Face, layout: FaceLayout, n_skin_tris: int, front_texture: np.ndarray) -> Face:
    """The front-of-face ``face`` with the head shell and the ears appended (see ``head.py``).

    Vertex and triangle order: the front's first (unchanged but for its smoothed outer rim and the
    nostrils, opened into the nose: ``nostrils.py``), then
    the shell (its first vertices are copies of the rim, in loop order), then the ears (parts
    ``ear_l`` / ``ear_r``). The texture gets the head atlas to the right of the face's image.
    """
    from core.default_face.head import (ATLAS_WIDTH, EAR_PATCH, HeadBuilder, outer_boundary_loop,
                                        paint_head_atlas, shell_atlas_map, smoothed_rim)
    from core.default_face.texture import _SKIN_TONES, _lerp_table

    p = layout.p
    n0 = face.n_vertices
    loop = outer_boundary_loop(face.triangles[:n_skin_tris])
    front = face.vertices.copy()
    # Feature points stay where they are: the corners of their triangles do not move.
    held = np.zeros(n0, bool)
    held[face.triangles[[point.triangle for point in face.landmarks.values()]].ravel()] = True
    guide = smoothed_rim(front[loop])
    front[loop] = smoothed_rim(front[loop], pinned=held[loop])
    # The nostrils get a modelled inside (the front-only face keeps the scanner's shallow dents).
    from core.default_face.nostrils import open_nostrils
    from core.default_face.shape import FaceShape

    skin = np.ones(n0, bool)
    for idx in face.parts.values():
        skin[idx] = False
    front = open_nostrils(FaceShape(layout), front, movable=skin & ~held)
    builder = HeadBuilder(layout)
    shell = builder.shell(front, loop, guide=guide)
    shell_vertices = _faired_shell(front, face.triangles[:n_skin_tris], loop, shell, builder.model.centre)
    ear_v, ear_t, ear_tex = builder.ears()
    n_shell = len(shell.vertices)
    vertices = np.concatenate([front, shell_vertices, ear_v])
    triangles = np.concatenate([face.triangles, shell.triangles + n0, ear_t + n0 + n_shell])
    n_ear = len(ear_v) // 2
    parts = dict(face.parts)
    parts["ear_l"] = np.arange(n0 + n_shell, n0 + n_shell + n_ear)
    parts["ear_r"] = np.arange(n0 + n_shell + n_ear, len(vertices))

    h, w0, _ = face.texture.shape
    width = w0 + ATLAS_WIDTH
    q = shell.q
    q_box = (float(q[:, 0].min()), float(q[:, 1].min()), float(np.ptp(q[:, 0])), float(np.ptp(q[:, 1])))
    shell_px = shell_atlas_map(q, q_box)
    ex, ey, ew, eh = EAR_PATCH
    ear_px = np.column_stack([ex + ear_tex[:, 0] * ew, ey + (1.0 - ear_tex[:, 1]) * eh])
    pixels = np.concatenate([shell_px, ear_px])
    uv = np.concatenate([
        face.uv * [w0 / width, 1.0],
        np.column_stack([(w0 + pixels[:, 0]) / width, 1.0 - pixels[:, 1] / h]),
    ])
    base = _lerp_table(_SKIN_TONES, p.skin_tone)
    hair = np.array([52.0, 36.0, 26.0]) * (1 - 0.4 * p.skin_tone)
    # Next to the seam the atlas takes the face texture's colour at the nearest rim vertex, so the
    # colour is continuous across the seam (the two sides have different texture coordinates).
    # (Smoothed along the rim: each texel copies its nearest rim vertex, so rim noise would become streaks.)
    from scipy.ndimage import gaussian_filter1d

    rim_colour = gaussian_filter1d(_sample(front_texture, face.uv[loop]), 8.0, axis=0, mode="wrap")
    atlas = paint_head_atlas(layout, builder, q_box, base, hair, p.texture_seed,
                             seam=(shell_px[:len(loop)], rim_colour))
    texture = np.concatenate([front_texture, atlas], axis=1)
    head = Face(vertices, triangles, uv=uv, texture=texture, parts=parts, landmarks=face.landmarks,
                metadata=face.metadata)
    head.metadata.notes.append(
        f"Full head: {n_shell} shell vertices ({len(loop)} copies of the front's outer rim), "
        f"{len(ear_v)} ear vertices appended."
    )
    return head


def _faired_shell(front: np.ndarray, skin_triangles: np.ndarray, loop: np.ndarray, shell, centre: np.ndarray) -> np.ndarray:
    """(k, 3) the shell's vertices with those within ``FAIR_BAND_MM`` of the seam faired into the
    face's slope (``head.fair_radially`` over the front skin and the shell joined at the seam)."""
    from core.default_face.head import FAIR_BAND_MM, fair_radially

    n0, n_seam = len(front), len(loop)
    # Shell vertex k < n_seam is a copy of front vertex loop[k]: join the two meshes there.
    index = np.concatenate([loop, n0 + np.arange(len(shell.vertices) - n_seam)])
    joined = np.concatenate([front, shell.vertices[n_seam:]])
    triangles = np.concatenate([skin_triangles, index[shell.triangles]])
    near, _ = cKDTree(front[loop]).query(shell.vertices[n_seam:], distance_upper_bound=FAIR_BAND_MM)
    free = np.zeros(len(joined), bool)
    free[n0:] = np.isfinite(near)
    faired = fair_radially(joined, triangles, free, centre)
    return np.concatenate([shell.vertices[:n_seam], faired[n0:]])


def _sample(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(k, 3) float colours of ``image`` (H, W, 3) at texture coordinates (k, 2) (nearest texel)."""
    h, w, _ = image.shape
    col = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
    row = np.clip(((1.0 - uv[:, 1]) * h).astype(int), 0, h - 1)
    return image[row, col].astype(float)


# ---------------------------------------------------------------- skin grid
def _skin_grid(layout: FaceLayout, shape: FaceShape, h: float, *, cut_unseen_rim: bool = False):
    """Grid vertices (x, y) inside the scan outline and their triangles.

    ``cut_unseen_rim``: also leave out the steep rim a frontal scanner cannot see
    (:func:`_unseen_rim`; the full head's shell covers it).

    The rows are warped near the mouth so that one grid row lies exactly on
    the mouth line; the columns are spaced so that two columns fall exactly on
    the mouth corners. Returns xy (n, 2), triangles (m, 3), and the seam's
    upper and lower vertex indices (k,) each.
    """
    hw = layout.mouth_half_width
    hx = hw / round(hw / h)
    nx = int(np.ceil(80.0 / hx))
    xs = np.arange(-nx, nx + 1) * hx
    y_lo, y_hi = layout.menton_y - 2.0, layout.nasion_y + 63.0
    j_lo, j_hi = int(np.floor((y_lo - layout.stomion_y) / h)), int(np.ceil((y_hi - layout.stomion_y) / h))
    vs = layout.stomion_y + np.arange(j_lo, j_hi + 1) * h
    j_mouth = -j_lo
    X, V = np.meshgrid(xs, vs)                       # rows = y, columns = x
    shift = (layout.mouth_line(X) - layout.stomion_y) * np.exp(-(((V - layout.stomion_y) / 6.0) ** 2))
    Y = V + shift
    ny, nxx = X.shape
    inside = shape.inside_scan(X, Y)
    if cut_unseen_rim:
        inside &= ~_unseen_rim(shape, X, Y, inside)
    index = np.arange(ny * nxx).reshape(ny, nxx)

    # Two triangles per cell; the diagonal mirrors across the midline so the
    # triangulation is left-right symmetric. Counter-clockwise seen from +z.
    a, b = index[:-1, :-1], index[:-1, 1:]
    d, c = index[1:, :-1], index[1:, 1:]
    left = (X[:-1, :-1] < -1e-9)
    t1 = np.where(left[..., None], np.stack([a, b, c], -1), np.stack([a, b, d], -1))
    t2 = np.where(left[..., None], np.stack([a, c, d], -1), np.stack([b, c, d], -1))
    cell_row = np.broadcast_to(np.arange(ny - 1)[:, None], a.shape)
    tris = np.concatenate([t1.reshape(-1, 3), t2.reshape(-1, 3)])
    rows = np.concatenate([cell_row.ravel(), cell_row.ravel()])
    flat_inside = inside.ravel()
    ok = flat_inside[tris].all(axis=1)
    tris, rows = tris[ok], rows[ok]

    # Mouth seam: duplicate the mouth-row vertices strictly between the corners;
    # cells just below the row use the duplicates.
    seam_cols = np.nonzero(np.abs(xs) < hw - 1e-6)[0]
    seam_upper = index[j_mouth, seam_cols]
    n = ny * nxx
    seam_lower = n + np.arange(len(seam_cols))
    lut = np.arange(n + len(seam_cols))
    lut[seam_upper] = seam_lower
    below = rows == j_mouth - 1
    tris[below] = lut[tris[below]]

    xy = np.column_stack([X.ravel(), Y.ravel()])
    xy = np.concatenate([xy, xy[seam_upper]])
    return xy, tris, seam_upper, seam_lower


def _unseen_rim(shape: FaceShape, X: np.ndarray, Y: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """(rows, cols) bool: grid points (X, Y) inside the outline where the skin turns more than
    MAX_VIEW_ANGLE_DEG from the view axis and that connect through such points to the outline (steep
    pits inside the face, the nostrils, stay: cutting them would hole the surface)."""
    from scipy import ndimage

    d = 0.25 * float(abs(X[0, 1] - X[0, 0]))     # mm, central differences well inside a cell
    gx = (shape.skin_depth(X + d, Y) - shape.skin_depth(X - d, Y)) / (2 * d)
    gy = (shape.skin_depth(X, Y + d) - shape.skin_depth(X, Y - d)) / (2 * d)
    steep = inside & (np.hypot(gx, gy) > np.tan(np.radians(MAX_VIEW_ANGLE_DEG)))
    labels, _ = ndimage.label(steep, structure=np.ones((3, 3)))
    at_outline = np.unique(labels[steep & ndimage.binary_dilation(~inside, structure=np.ones((3, 3)))])
    return np.isin(labels, at_outline[at_outline > 0])


def _boundary_vertices(tris: np.ndarray) -> np.ndarray:
    """Indices of vertices on boundary edges (edges used by one triangle)."""
    edges = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    return np.unique(uniq[count == 1])


def _smooth_outer_rim(shape: FaceShape, xy: np.ndarray, tris: np.ndarray, h: float) -> np.ndarray:
    """Move the side rim vertices horizontally onto the outline, removing the grid's staircase."""
    rim = _boundary_vertices(tris)
    x, y = xy[rim, 0], xy[rim, 1]
    target = np.sign(x) * OUTLINE_T * shape.half_width(y)
    movable = (np.abs(target - x) < 1.2 * h) & (np.abs(x) > 2 * h)
    xy = xy.copy()
    xy[rim[movable], 0] = target[movable]
    return xy


def _cut_eye_openings(layout: FaceLayout, xy: np.ndarray, tris: np.ndarray):
    """Remove skin inside the palpebral openings and move the rim onto the lid margins (then the
    slivers that leaves, ``rim_slivers``)."""
    centroid = xy[tris].mean(axis=1)
    hole = layout.inside_fissure(centroid[:, 0], centroid[:, 1])
    kept = tris[~hole]
    rim = np.intersect1d(np.unique(tris[hole]), np.unique(kept))
    outline = layout.fissure_outline(600)
    outline = np.concatenate([outline, outline * [-1, 1]])
    _, nearest = cKDTree(outline).query(xy[rim])
    xy = xy.copy()
    xy[rim] = outline[nearest]
    # The eye corners are exact: the rim vertex nearest each canthus goes there.
    y_in, _ = layout.lid_margins(np.array([layout.eye_inner_x, layout.eye_outer_x]))
    corners = np.zeros(len(xy), bool)
    for sx in (-1.0, 1.0):
        for cx, cy in zip((layout.eye_inner_x, layout.eye_outer_x), y_in):
            k = rim[np.argmin(np.hypot(xy[rim, 0] - sx * cx, xy[rim, 1] - cy))]
            xy[k] = (sx * cx, cy)
            corners[k] = True
    # Three neighbouring rim vertices snapped onto the margin almost in a line span slivers.
    on_rim = np.zeros(len(xy), bool)
    on_rim[rim] = True
    return xy, remove_rim_slivers(xy, kept, on_rim, pinned=corners)


def _drop_unused(xy: np.ndarray, tris: np.ndarray):
    keep = np.zeros(len(xy), bool)
    keep[tris.ravel()] = True
    remap = np.cumsum(keep) - 1
    return xy[keep], remap[tris], keep


# ---------------------------------------------------------------- eyeballs
# Least depth (mm, along the ball's normal) of a cap's open rim behind the skin's height field.
# The lids are draped LID_THICKNESS in front of the ball along z, which is as much along the normal
# only where the ball faces forward: at the default face's outer eye corners its steep side (70-78
# degrees off the gaze axis) ended 0.01 mm behind the skin's triangles, and blend poses moving that
# skin 0.15 mm put the rim's edge through them (rebuilt library: joy 7, anger 9, sadness 4, disgust
# 14 lid/eyeball crossing pairs; with 0.5 mm, the rim 0.25 mm behind the triangles: disgust 8, the
# others none). A deeper tuck (rim 0.66 mm behind) added 8 folded triangles to the FAP poses (cheek
# lift, joy) and moved the pitch pivot fitted to the ball 0.75 mm: the lid guard reads the ball's
# dent as room for the skin. With 0.5 mm the pivot moves 0.13 mm, the FAP poses keep their numbers.
RIM_CLEARANCE_MM = 0.5
# The tuck starts this far beyond the eye corner's angle off the gaze axis, so the ball inside the
# palpebral opening stays on its ellipsoid.
RIM_TUCK_MARGIN_DEG = 5.0


def _eyeballs(shape: FaceShape, offset: int):
    """Two ellipsoidal caps facing +z; returns vertices, triangles and pole indices.

    Behind the skin beyond the eye corners the cap's last rings curl in toward the centre (radially,
    by what the skin's distance along the ball's normal falls short of ``RIM_CLEARANCE_MM``), so the
    open rim sits about that deep behind the skin. Only the outer corners' steep side moves (the
    socket skin above, below and at the inner corner is 3-7 mm in front of it; the default face's
    ball's 82 outer vertices move up to 0.23 mm, a generated identity's (seed 7) 0.03 mm); inside the
    opening the ball is the ellipsoid, so the pivots fitted to it barely move."""
    theta = np.radians(np.linspace(0, EYE_CAP_DEG, EYE_RINGS + 1)[1:])
    phi = np.linspace(0, 2 * np.pi, EYE_SEGMENTS, endpoint=False)
    T, P = np.meshgrid(theta, phi, indexing="ij")
    unit = np.column_stack([np.sin(T).ravel() * np.cos(P).ravel(), np.sin(T).ravel() * np.sin(P).ravel(),
                            np.cos(T).ravel()])
    unit = np.concatenate([[[0.0, 0.0, 1.0]], unit])
    cap = polar_cap_triangles(EYE_RINGS, EYE_SEGMENTS)
    verts, tris, poles = [], [], []
    radii = shape.eyeball_radii()
    L = shape.L
    corner = np.degrees(np.arcsin(min(1.0, (L.eye_outer_x - L.eye_inner_x) / 2 / radii[0])))
    start = np.radians(min(corner + RIM_TUCK_MARGIN_DEG, EYE_CAP_DEG - 1.0))
    s = np.clip((np.arccos(np.clip(unit[:, 2], -1.0, 1.0)) - start) / (np.radians(EYE_CAP_DEG) - start), 0.0, 1.0)
    s = s * s * (3.0 - 2.0 * s)
    normal = unit / radii
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    offsets = unit * radii
    length = np.linalg.norm(offsets, axis=1)
    for k, centre in enumerate(shape.eyeball_centres()):
        base = offset + k * len(unit)
        tuck = s * np.maximum(RIM_CLEARANCE_MM - _skin_along(shape, centre + offsets, normal), 0.0)
        verts.append(centre + offsets * (1.0 - tuck / length)[:, None])
        tris.append(cap + base)
        poles.append(base)
    return np.concatenate(verts), np.concatenate(tris), poles


def _skin_along(shape: FaceShape, points: np.ndarray, directions: np.ndarray, reach: float = 6.0) -> np.ndarray:
    """(k,) mm: how far along the unit ``directions`` (k, 3) from ``points`` (k, 3) mm the skin's
    height field lies (negative: the point is in front of the skin; clipped to +-``reach``), by bisection."""
    def above(t):        # the skin is still in front of the point moved t mm along its direction
        q = points + t[:, None] * directions
        return shape.skin_depth(q[:, 0], q[:, 1]) > q[:, 2]

    lo, hi = np.full(len(points), -reach), np.full(len(points), reach)
    for _ in range(30):
        mid = (lo + hi) / 2
        ahead = above(mid)
        lo, hi = np.where(ahead, mid, lo), np.where(ahead, hi, mid)
    return (lo + hi) / 2


# ---------------------------------------------------------------- texture frame
def _texture_frame(layout: FaceLayout) -> tuple[float, float, float, float]:
    """(x0, y0, width, height) in mm of the rectangle the texture image covers (4:3)."""
    y_lo, y_hi = layout.menton_y - 6.0, layout.nasion_y + 66.0
    height = y_hi - y_lo
    width = height * TEXTURE_SIZE[0] / TEXTURE_SIZE[1]
    return (-width / 2, y_lo, width, height)


# ---------------------------------------------------------------- landmarks
def feature_point_layout(layout: FaceLayout, shape: FaceShape) -> dict[str, tuple[float, float, str]]:
    """(x, y, part) of every frontal MPEG-4 feature point of the generated face's skin and eyes.

    (The teeth points 9.8-9.11 are vertices of the teeth, placed in ``generate_face``.)

    part is "skin", "upper" / "lower" (the two sides of the mouth seam),
    "rim_up" / "rim_low" (just outside the lid margins) or "eye_l" / "eye_r" (pupil).
    +x is the face's own left: "left" points have x > 0.
    """
    L = layout
    fp: dict[str, tuple[float, float, str]] = {}

    def pair(left: str, right: str, x: float, y: float, part: str = "skin"):
        fp[left] = (abs(x), y, part)
        fp[right] = (-abs(x), y, part)

    hw = L.mouth_half_width
    line = L.mouth_line
    # Group 2: chin, inner lips, jaw.
    fp["2.1"] = (0.0, L.menton_y + 1.0, "skin")
    fp["2.2"] = (0.0, float(line(0.0)), "upper")
    fp["2.3"] = (0.0, float(line(0.0)), "lower")
    inner = hw - 1.5
    pair("2.4", "2.5", inner, float(line(inner)), "upper")
    mid = hw / 2
    pair("2.6", "2.7", mid, float(line(mid)), "upper")
    pair("2.8", "2.9", mid, float(line(mid)), "lower")
    fp["2.10"] = (0.0, L.chin_y, "skin")
    pair("2.11", "2.12", 15.0, L.chin_y - 5.0)
    jaw_y = L.sulcus_y - 4.0
    pair("2.13", "2.14", 0.92 * float(shape.half_width(jaw_y)), jaw_y)
    # Group 3: eyes. Lid centres at the pupil's x, outer-lid points 4 mm beyond the margins.
    up, lo = L.lid_margins(np.array([L.pupil_x]))
    pair("3.1", "3.2", L.pupil_x, float(up[0]), "rim_up")
    pair("3.3", "3.4", L.pupil_x, float(lo[0]), "rim_low")
    fp["3.5"] = (L.pupil_x, L.eye_line_y, "eye_l")
    fp["3.6"] = (-L.pupil_x, L.eye_line_y, "eye_r")
    corners = L.lid_margins(np.array([L.eye_inner_x, L.eye_outer_x]))[0]
    fp["3.7"] = (L.eye_outer_x, float(corners[1]), "skin")
    fp["3.12"] = (-L.eye_outer_x, float(corners[1]), "skin")
    fp["3.11"] = (L.eye_inner_x, float(corners[0]), "skin")
    fp["3.8"] = (-L.eye_inner_x, float(corners[0]), "skin")
    pair("3.9", "3.10", L.pupil_x, float(lo[0]) - 4.0)
    pair("3.13", "3.14", L.pupil_x, float(up[0]) + 4.0)
    # Group 4: eyebrows (4.1 inner left, 4.3 top left, 4.5 outer left).
    for (left, right), bx, by in zip((("4.1", "4.2"), ("4.3", "4.4"), ("4.5", "4.6")), L.brow_x, L.brow_y):
        pair(left, right, bx, float(L.brow_curve(np.array([bx]))[0]))
    # Group 5: cheeks.
    pair("5.1", "5.2", 38.0, L.subnasale_y - 4.0)
    pair("5.3", "5.4", 45.0, L.eye_line_y - 18.0)
    # Group 8: outer lip contour.
    fp["8.1"] = (0.0, float(L.upper_lip_border(0.0)), "skin")
    fp["8.2"] = (0.0, float(L.lower_lip_border(0.0)), "skin")
    pair("8.3", "8.4", hw, float(line(hw)), "skin")
    pair("8.5", "8.6", mid, float(L.upper_lip_border(mid)))
    pair("8.7", "8.8", mid, float(L.lower_lip_border(mid)))
    bow = 5.5
    fp["8.10"] = (bow, float(L.upper_lip_border(bow)), "skin")
    fp["8.9"] = (-bow, float(L.upper_lip_border(-bow)), "skin")
    # Group 9: nose.
    pair("9.1", "9.2", L.alar_half_width - 4.0, L.subnasale_y + 4.0)
    fp["9.3"] = (0.0, L.nose_tip_y, "skin")
    fp["9.5"] = (L.alar_half_width - 5.0, L.subnasale_y + 3.5, "skin")
    fp["9.4"] = (-(L.alar_half_width - 5.0), L.subnasale_y + 3.5, "skin")
    pair("9.7", "9.6", 7.0, L.nasion_y - 10.0)
    fp["9.12"] = (0.0, (L.nasion_y + L.nose_tip_y) / 2, "skin")
    pair("9.13", "9.14", 8.0, (L.nasion_y + L.nose_tip_y) / 2 - 4.0)
    fp["9.15"] = (0.0, L.subnasale_y, "skin")
    # Group 10: where the ears meet the face, at the side edge of the scan (inside it):
    # upper contact between the eye corners and the brow, lower at the nose base.
    ear_t = OUTLINE_T - 0.05
    for (left, right), ey in ((("10.9", "10.10"), L.eye_line_y + 5.0), (("10.7", "10.8"), L.subnasale_y)):
        pair(left, right, ear_t * float(shape.half_width(ey)), ey)
    # Group 11: hairline.
    fp["11.1"] = (0.0, L.hairline_y, "skin")
    pair("11.3", "11.2", 38.0, L.hairline_y - 7.0)
    return fp


def _vertex_point(face: Face, vertex: int) -> SurfacePoint:
    """The surface point exactly at ``vertex`` (on the first triangle that uses it)."""
    tri = int(np.nonzero((face.triangles == vertex).any(axis=1))[0][0])
    return SurfacePoint(tri, tuple((face.triangles[tri] == vertex).astype(float)))


def _place_feature_points(layout, shape, face: Face, n_skin_tris: int, poles,
                          teeth_vertices: dict[str, int]) -> dict[str, SurfacePoint]:
    """Surface points of the feature points: located in the flattened skin mesh (exact by construction);
    pupils and teeth points are vertices of their components."""
    import trimesh

    skin_tris = face.triangles[:n_skin_tris]
    flat = face.vertices.copy()
    flat[:, 2] = 0.0
    flat_mesh = trimesh.Trimesh(flat, skin_tris, process=False, validate=False)
    nudge = {"upper": 0.05, "lower": -0.05, "rim_up": 0.05, "rim_low": -0.05, "skin": 0.0}
    out: dict[str, SurfacePoint] = {name: _vertex_point(face, v) for name, v in teeth_vertices.items()}
    names, queries, exact = [], [], []
    for name, (x, y, part) in feature_point_layout(layout, shape).items():
        if part in ("eye_l", "eye_r"):
            out[name] = _vertex_point(face, poles[0 if part == "eye_l" else 1])
            continue
        names.append(name)
        queries.append((x, y + nudge[part], 0.0))
        exact.append((x, y, 0.0))
    # The nudge picks the side of a seam or rim; the barycentric weights are
    # then taken at the exact point (on the shared edge for seam points).
    _closest, _dist, tri = trimesh.proximity.closest_point(flat_mesh, np.array(queries))
    bary = trimesh.triangles.points_to_barycentric(flat[skin_tris[tri]], np.array(exact))
    bary = np.clip(bary, 0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    for name, t, b in zip(names, tri, bary):
        out[name] = SurfacePoint(int(t), tuple(b))
    return dict(sorted(out.items(), key=lambda kv: tuple(int(s) for s in kv[0].split("."))))
