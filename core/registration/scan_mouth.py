"""The registered scan itself, animated (issue 15 item 3): its lips cut apart along the lip line and
a mouth cavity with teeth behind them, so the jaw opens the scan's own full-resolution mouth.

A scan is one closed sheet across the mouth; carried back from the canonical face (whose inner-lip
loop is an opening), scan vertices on either side of the lip line follow different lips and the
triangles between them stretch into a skin web instead of opening. :func:`animated_scan`:

* labels each canonical vertex within ``LIP_RINGS`` rings of the inner-lip loop as upper or lower lip
  (whichever half of the loop — split at the inner corners 2.4 / 2.5 — is fewer rings away);
* labels each scan vertex by the canonical triangle it is bound to (:func:`bind_scan`);
* cuts every scan triangle that has vertices of both lips: it keeps the lip most of its corners
  are on, and its corners of the other lip are replaced by copies (same position and texture
  coordinates) that move like its own lip's corners — a cut along the scan's edges, closed at rest;
* adds the default face's mouth cavity and teeth, placed by a similarity on the mouth and chin
  landmarks; the cavity and upper teeth stay with the skull, the lower teeth follow the rigid
  motion (Kabsch) of the canonical chin, jaw points and lower lip, as on the default face.

The texture of the added parts is the default face's, appended below the scan's texture image.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from core.face import Face, SurfacePoint
from core.layers.fap.template import DenseTemplate
from core.registration.correspondence import Registration, _adjacency, boundary_loops
from core.registration.folds import similarity
from core.registration.templates import get_template
from core.surface_query import TriangleSet

#: Canonical vertices up to this many rings from the inner-lip loop are labelled upper or lower lip
#: (4 rings of the 4560-vertex template are about 10 mm: the lips' height, not the nose or chin).
LIP_RINGS = 10
#: Landmarks placing the default face's mouth cavity and teeth on the scan (lips, chin, nose base).
MOUTH_POINTS = ("8.1", "8.2", "8.3", "8.4", "2.2", "2.3", "2.4", "2.5", "2.10", "9.15")
#: Canonical landmarks whose rigid motion moves the lower teeth, with the lower lip's vertices (chin
#: and jaw line: with the chin alone the teeth swing out through the lower lip as the jaw opens).
JAW_POINTS = ("2.1", "2.10", "2.11", "2.12", "2.13", "2.14")
MOUTH_PARTS = ("mouth_cavity", "teeth_upper", "teeth_lower")
#: The registration template whose canonical face is the FAP rig's dense template.
FAP_TEMPLATE = "mpeg4_80"
#: How far behind the scan's skin the placed mouth parts must stay, mm (a scan's upper lip can sit
#: further back than the donor's, and the cavity's rim would show through it as dark slits).
BEHIND_SKIN_MM = 1.0
PUSH_ROUNDS = 4
#: A scan's own mouth interior: its triangles more than INTERIOR_MM behind the canonical lips (within
#: INTERIOR_REACH_MM of them) are hidden.
INTERIOR_MM = 1.5
INTERIOR_RINGS = 10
INTERIOR_REACH_MM = 30.0


class ScanMouthError(ValueError):
    """The canonical face has no inner-lip opening to cut the scan along."""


def inner_lip_halves(triangles: np.ndarray, template_name: str) -> tuple[np.ndarray, np.ndarray]:
    """(upper, lower) canonical vertex ids of the inner-lip boundary loop, without the inner corners."""
    base = get_template(template_name).base
    upper_mid, lower_mid = base.index("2.2"), base.index("2.3")
    corners = {base.index("2.4"), base.index("2.5")}
    found = [loop for loop in boundary_loops(triangles) if upper_mid in loop]
    if not found:
        raise ScanMouthError("the canonical face has no mouth opening (its inner-lip loop is closed)")
    loop = found[0].tolist()
    loop = loop[loop.index(upper_mid):] + loop[:loop.index(upper_mid)]
    cut = [i for i, v in enumerate(loop) if v in corners]
    if len(cut) != 2 or lower_mid not in loop:
        raise ScanMouthError("the canonical face's mouth opening does not pass both inner lip corners (2.4, 2.5)")
    lower = loop[cut[0] + 1:cut[1]]
    upper = loop[cut[1] + 1:] + loop[:cut[0]]
    if lower_mid in upper:
        upper, lower = lower, upper
    return np.array(upper, np.int64), np.array(lower, np.int64)


def lip_labels(triangles: np.ndarray, template_name: str, rings: int = LIP_RINGS) -> np.ndarray:
    """(N,) +1 upper lip, -1 lower lip, 0 neither (or as far from both) for canonical vertices."""
    n = int(triangles.max()) + 1
    adjacency, _ = _adjacency(triangles, n)
    distance = []
    for seeds in inner_lip_halves(triangles, template_name):
        reached = np.zeros(n, bool)
        reached[seeds] = True
        rings_away = np.where(reached, 0, rings + 1)
        for ring in range(1, rings + 1):
            reached = reached | (adjacency @ reached.astype(float) > 0)
            rings_away = np.where(reached & (rings_away > rings), ring, rings_away)
        distance.append(rings_away)
    upper, lower = distance
    return np.where(upper < lower, 1, np.where(lower < upper, -1, 0)).astype(np.int8)


@dataclass(frozen=True)
class AnimatedScan:
    """The scan with cut lips and mouth parts, moved by its canonical face.

    face : the scan (n_scan vertices, then ``n_copies`` cut copies, then the mouth parts), with the
        registration's landmarks on its skin (inner-lip points on their own lip's side of the cut).
    matrix : (n_scan + n_copies, N) sparse binding of the skin vertices to canonical vertices.
    rest_canonical : (N, 3) mm.  jaw_vertices : canonical ids whose rigid motion moves the lower teeth.
    dense : the FAP template as the registration fitted it on the scan (canonical vertex i is dense
        vertex i), for ``FapDeformer(face, dense=...)``; None when registered with another template.
    """

    face: Face
    matrix: scipy.sparse.csr_matrix
    rest_canonical: np.ndarray
    jaw_vertices: np.ndarray
    n_scan: int
    n_copies: int
    dense: DenseTemplate | None = None

    def vertices(self, canonical_vertices) -> np.ndarray:
        """(n, 3) mm: the face's vertices for canonical vertices (N, 3) (rest -> the scan exactly)."""
        c = np.asarray(canonical_vertices, float)
        if c.shape != self.rest_canonical.shape:
            raise ValueError(f"canonical vertices must have shape {self.rest_canonical.shape}, got {c.shape}")
        out = np.array(self.face.vertices, float)
        n_skin = self.n_scan + self.n_copies
        out[:n_skin] += self.matrix @ (c - self.rest_canonical)
        lower = self.face.parts.get("teeth_lower")
        if lower is not None and len(lower):
            rotation, shift = _rigid(self.rest_canonical[self.jaw_vertices], c[self.jaw_vertices])
            out[lower] = out[lower] @ rotation.T + shift
        return out


def _rigid(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotation (3, 3), translation (3,)) least-squares rigid motion of points source -> target."""
    ms, mt = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((target - mt).T @ (source - ms))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ d @ vt
    return rotation, mt - ms @ rotation.T


def _mouth_interior(scan: Face, canonical: Face, template_name: str) -> np.ndarray:
    """(T,) bool: triangles of the scan's own mouth interior (LeePerrySmith has one): every corner
    more than INTERIOR_MM behind the canonical face where it is within INTERIOR_RINGS of the lips,
    and facing away from it.
    Bound to the lips, they would be dragged across the opened mouth as a curtain in front of the
    teeth; the added cavity replaces them."""
    zone = np.nonzero(lip_labels(canonical.triangles, template_name, INTERIOR_RINGS) != 0)[0]
    in_zone = np.zeros(canonical.n_vertices, bool)
    in_zone[zone] = True
    box_low = canonical.vertices[zone].min(axis=0) - INTERIOR_REACH_MM
    box_high = canonical.vertices[zone].max(axis=0) + INTERIOR_REACH_MM
    near = np.nonzero(((scan.vertices >= box_low) & (scan.vertices <= box_high)).all(axis=1))[0]
    inside = np.zeros(scan.n_vertices, bool)
    facing = np.ones(scan.n_vertices)
    if len(near):
        closest, tri, _ = TriangleSet(canonical.vertices, canonical.triangles).closest(scan.vertices[near])
        depth = np.einsum("kd,kd->k", closest - scan.vertices[near], canonical.face_normals[tri])
        inside[near] = in_zone[canonical.triangles[tri]].any(axis=1) & (depth > INTERIOR_MM)
        facing[near] = np.einsum("kd,kd->k", scan.vertex_normals[near], canonical.face_normals[tri])
    # Facing away from the canonical face as well: where the fit holds the canonical mouth corners
    # off a fold of the scan, the scan's own outer skin there lies behind it too (it must stay).
    return inside[scan.triangles].all(axis=1) & (facing[scan.triangles].sum(axis=1) < 0)


def _cut_lips(scan: Face, matrix: scipy.sparse.csr_matrix, canonical_labels: np.ndarray):
    """(triangles, copy_of (k,), copy rows (k, N)) of the scan cut between upper and lower lip."""
    total = np.asarray(matrix.sum(axis=1)).ravel()
    score = (matrix @ canonical_labels.astype(float)) / np.maximum(total, 1e-12)
    label = np.where(score > 0.5, 1, np.where(score < -0.5, -1, 0))
    triangles = np.array(scan.triangles)
    corner_labels = label[triangles]
    seam = np.nonzero((corner_labels == 1).any(axis=1) & (corner_labels == -1).any(axis=1))[0]
    if not len(seam):
        return triangles, np.zeros(0, np.int64), scipy.sparse.csr_matrix((0, matrix.shape[1]))
    side = np.where(corner_labels[seam].sum(axis=1) >= 0, 1, -1)          # the lip most corners are on
    minority = corner_labels[seam] == -side[:, None]
    majority = corner_labels[seam] == side[:, None]
    # One copy per (vertex, side) pair: key = vertex * 2 + (side > 0).
    k_tri, k_corner = np.nonzero(minority)
    vertex = triangles[seam[k_tri], k_corner]
    keys, copy_id = np.unique(vertex * 2 + (side[k_tri] > 0), return_inverse=True)
    triangles[seam[k_tri], k_corner] = scan.n_vertices + copy_id
    # A copy moves like the mean of its triangles' own-lip corners.
    m_tri, m_corner = np.nonzero(majority[k_tri])
    rows = copy_id[m_tri]
    cols = triangles[seam[k_tri[m_tri]], m_corner]
    average = scipy.sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(keys), scan.n_vertices))
    average = scipy.sparse.diags(1.0 / np.maximum(np.asarray(average.sum(axis=1)).ravel(), 1)) @ average
    return triangles, keys // 2, (average @ matrix).tocsr()


def _mouth_parts(skin: Face, scan_points: np.ndarray, donor: Face, donor_points: np.ndarray):
    """(vertices, triangles, uv, {part: local ids}) of the donor's mouth parts placed on the scan."""
    keep = np.zeros(donor.n_vertices, bool)
    for name in MOUTH_PARTS:
        keep |= donor.part_mask(name)
    ids = np.nonzero(keep)[0]
    local = np.full(donor.n_vertices, -1)
    local[ids] = np.arange(len(ids))
    triangles = local[donor.triangles[keep[donor.triangles].all(axis=1)]]
    scale, rotation, shift = similarity(donor_points, scan_points)
    vertices = scale * donor.vertices[ids] @ rotation.T + shift
    forward = rotation @ np.array([0.0, 0.0, 1.0])    # the donor faces +z
    teeth = (donor.part_mask("teeth_upper") | donor.part_mask("teeth_lower"))[ids]
    vertices = _behind(skin, vertices, teeth, forward)
    parts = {name: local[donor.parts[name]] for name in MOUTH_PARTS if name in donor.parts}
    uv = None if donor.uv is None else donor.uv[ids]
    return vertices, triangles, uv, parts, forward


def _depth_below(skin: Face, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(depth (k,) mm, > 0 behind the skin; closest skin points (k, 3); their normals (k, 3)).
    ``skin`` is the canonical face, not the scan: a scan may have its own mouth interior
    (LeePerrySmith does), whose backward-facing triangles would put the whole cavity in front of it."""
    closest, tri, _ = TriangleSet(skin.vertices, skin.triangles).closest(points)
    normal = skin.face_normals[tri]
    return np.einsum("kd,kd->k", closest - points, normal), closest, normal


def _behind(skin: Face, points: np.ndarray, teeth: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """(k, 3) mm: mouth-part ``points`` at least BEHIND_SKIN_MM behind ``skin``: all move back
    together along -``forward`` as far as the 99th-percentile tooth point (``teeth``: bool (k,))
    needs, so the teeth keep their shape and stay inside the cavity; points still too shallow (the
    cavity's rim) then go that depth below their closest skin point."""
    points = points.copy()
    depth, _, _ = _depth_below(skin, points[teeth])
    needed = float(np.percentile(BEHIND_SKIN_MM - depth, 99)) if len(depth) else 0.0
    if needed > 0:
        points -= needed * forward
    for _ in range(PUSH_ROUNDS):   # a pushed point can come nearer another triangle (a crease): again
        depth, closest, normal = _depth_below(skin, points)
        shallow = depth < BEHIND_SKIN_MM - 1e-6
        if not shallow.any():
            break
        points[shallow] = closest[shallow] - BEHIND_SKIN_MM * normal[shallow]
    return points


def _seen_from_the_front(skin_vertices, skin_triangles, points, forward) -> np.ndarray:
    """(k,) bool: points whose ray towards the face's front leaves without crossing the skin — a few
    cavity-rim points pushed behind a crease of the canonical face can still be in front of the scan
    (a dark dot by a nostril); their triangles are left out. All False without Embree."""
    from core.registration.correspondence import SurfaceRays

    rays = SurfaceRays(skin_vertices, skin_triangles)
    if rays.engine != "embree" or not len(points):
        return np.zeros(len(points), bool)
    direction = np.tile(forward, (len(points), 1))
    _, _, hit = rays.first_hits(points, direction)
    return ~hit


def _stacked_texture(scan_texture: np.ndarray, donor_texture: np.ndarray) -> tuple[np.ndarray, float]:
    """(image, scan share of its height): the donor's texture resized to the scan's width, below it."""
    height, width = scan_texture.shape[:2]
    rows = int(round(donor_texture.shape[0] * width / donor_texture.shape[1]))
    r = (np.arange(rows) * donor_texture.shape[0] / rows).astype(int)
    c = (np.arange(width) * donor_texture.shape[1] / width).astype(int)
    return np.concatenate([scan_texture, donor_texture[r][:, c]]), height / (height + rows)


def animated_scan(registration: Registration, donor: Face | None = None) -> AnimatedScan:
    """The registered scan with cut lips, a mouth cavity and teeth (see the module docstring).
    ``donor``: the face whose mouth parts are used (default: Mimica's default face)."""
    if donor is None:
        from core.default_face import load_default_face

        donor = load_default_face(full_head=False)
    scan, canonical = registration.scan, registration.face
    matrix = registration.carry_back().binding.matrix
    labels = lip_labels(canonical.triangles, registration.template)
    triangles, copy_of, copy_rows = _cut_lips(scan, matrix, labels)
    interior = _mouth_interior(scan, canonical, registration.template)
    triangles = triangles[~interior]
    n_scan, n_copies = scan.n_vertices, len(copy_of)
    vertices = [scan.vertices, scan.vertices[copy_of]]
    skin_uv = None if scan.uv is None else np.concatenate([scan.uv, scan.uv[copy_of]])
    colours = None if scan.vertex_colors is None else np.concatenate([scan.vertex_colors, scan.vertex_colors[copy_of]])
    all_triangles = [triangles]
    parts = {name: np.array(idx) for name, idx in scan.parts.items()}
    texture = scan.texture
    present = [p for p in MOUTH_POINTS if p in canonical.landmarks and p in donor.landmarks]
    has_mouth = not any(name in scan.parts for name in MOUTH_PARTS) and len(present) >= 4
    if has_mouth:
        part_vertices, part_triangles, part_uv, part_ids, forward = _mouth_parts(
            canonical, canonical.landmark_positions(present), donor, donor.landmark_positions(present))
        offset = n_scan + n_copies
        vertices.append(part_vertices)
        seen = _seen_from_the_front(np.concatenate(vertices[:2]), triangles, part_vertices, forward)
        all_triangles.append(part_triangles[~seen[part_triangles].any(axis=1)] + offset)
        parts.update({name: idx + offset for name, idx in part_ids.items()})
        if skin_uv is not None and texture is not None and part_uv is not None and donor.texture is not None:
            texture, share = _stacked_texture(scan.texture, donor.texture)
            skin_uv = np.column_stack([skin_uv[:, 0], 1.0 - share * (1.0 - skin_uv[:, 1])])
            skin_uv = np.concatenate([skin_uv, np.column_stack([part_uv[:, 0], (1.0 - share) * part_uv[:, 1]])])
        elif skin_uv is not None:
            skin_uv = np.concatenate([skin_uv, np.zeros((len(part_vertices), 2))])
        if colours is not None:
            colours = np.concatenate([colours, _part_colours(donor, part_uv, len(part_vertices))])
    skin_matrix = scipy.sparse.vstack([matrix, copy_rows]).tocsr()
    all_vertices = np.concatenate(vertices)
    face = Face(all_vertices, np.concatenate(all_triangles), uv=skin_uv,
                texture=texture if skin_uv is not None else None, vertex_colors=colours,
                landmarks=_landmarks_on_skin(all_vertices, triangles, skin_matrix, canonical, labels,
                                             registration.template),
                metadata=scan.metadata, parts=parts)
    base = get_template(registration.template).base
    jaw = np.union1d([base.index(p) for p in JAW_POINTS if p in base.points], np.nonzero(labels == -1)[0])
    dense = None
    if registration.template == FAP_TEMPLATE and registration.projection is not None:
        fitted = registration.projection.dense
        if len(fitted.vertices) == canonical.n_vertices and np.array_equal(fitted.triangles, canonical.triangles):
            dense = dataclasses.replace(fitted, vertices=np.array(canonical.vertices, float))
    return AnimatedScan(face, skin_matrix, np.array(canonical.vertices, float), jaw, n_scan, n_copies, dense)


def _landmarks_on_skin(vertices, skin_triangles, skin_matrix, canonical: Face, canonical_labels,
                       template_name: str) -> dict[str, SurfacePoint]:
    """{name: SurfacePoint} of the canonical face's landmarks on the cut scan's skin. The scan's own
    triangles under an inner-lip point may belong to either lip after the cut (they touch at rest), so
    upper-lip points are placed only on triangles with no lower-lip corner and the other way round —
    else the point would ride on the wrong lip when the jaw opens."""
    total = np.asarray(skin_matrix.sum(axis=1)).ravel()
    score = (skin_matrix @ canonical_labels.astype(float)) / np.maximum(total, 1e-12)
    corner = np.where(score > 0.5, 1, np.where(score < -0.5, -1, 0))[skin_triangles]
    base = get_template(template_name).base
    names = list(canonical.landmarks)
    positions = canonical.landmark_positions(names)
    side_of = np.array([1 if n in base.upper_lip_points else -1 if n in base.lower_lip_points else 0 for n in names])
    out: dict[str, SurfacePoint] = {}
    for side in (0, 1, -1):
        chosen = np.nonzero(side_of == side)[0]
        if not len(chosen):
            continue
        allowed = np.nonzero(~(corner == -side).any(axis=1))[0] if side else np.arange(len(skin_triangles))
        _, tri, bary = TriangleSet(vertices, skin_triangles[allowed]).closest(positions[chosen])
        for i, t, b in zip(chosen, tri, bary):
            b = np.clip(b, 0.0, None)
            out[names[i]] = SurfacePoint(int(allowed[t]), tuple(b / b.sum()))
    return out


def scan_animation(registration: Registration, cache=None, progress=None) -> Face:
    """The Face to show and animate for a registered scan: :func:`animated_scan`'s face, with the
    registration's report and what was done in its notes. Its FAP deformer is built on the
    registration's fitted template and stored in ``cache`` (a ``core.cache.DiskCache``), where a
    rig built later for this face finds it (without a cache the rig densifies the template itself).
    Falls back to the canonical face, saying why in its notes, when the scan cannot be cut."""
    canonical = registration.face
    report = [f"Registration: {line}" for line in registration.report]
    try:
        animated = animated_scan(registration)
    except ScanMouthError as exc:
        notes = [*canonical.metadata.notes, *report,
                 f"Showing the canonical face ({canonical.n_vertices} vertices), not the scan: {exc}."]
        canonical.metadata = dataclasses.replace(canonical.metadata, notes=notes)
        return canonical
    shown = animated.face
    n_mouth = shown.n_vertices - animated.n_scan - animated.n_copies
    notes = [*shown.metadata.notes, *report,
             f"Animated at full resolution ({animated.n_scan} vertices) through a {canonical.n_vertices}-vertex "
             f"canonical face; lips cut along the lip line ({animated.n_copies} vertices copied)"
             + (f", mouth cavity and teeth added ({n_mouth} vertices)." if n_mouth else ".")]
    shown.metadata = dataclasses.replace(shown.metadata, notes=notes)
    if animated.dense is not None and cache is not None:
        from core.layers.fap.fat import FapDeformer

        FapDeformer.for_face(shown, cache, progress, dense=animated.dense)
    return shown


def _part_colours(donor: Face, part_uv, count: int) -> np.ndarray:
    """(count, 3) uint8 colours of the donor's mouth parts for a scan coloured per vertex."""
    if donor.texture is None or part_uv is None:
        return np.full((count, 3), 200, np.uint8)
    h, w = donor.texture.shape[:2]
    col = np.clip((part_uv[:, 0] * (w - 1)).round().astype(int), 0, w - 1)
    row = np.clip(((1.0 - part_uv[:, 1]) * (h - 1)).round().astype(int), 0, h - 1)
    return donor.texture[row, col]


__all__ = ["AnimatedScan", "ScanMouthError", "animated_scan", "inner_lip_halves", "lip_labels", "scan_animation"]
