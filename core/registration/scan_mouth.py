"""The registered scan itself, animated (issue 15 item 3): its lips cut apart along the lip line and
a mouth cavity with teeth behind them, so the jaw opens the scan's own full-resolution mouth;
closed eyes cut along the lid line with eyeballs behind them.

A scan is one closed sheet across the mouth; carried back from the canonical face (whose inner-lip
loop is an opening), scan vertices on either side of the lip line follow different lips and the
triangles between them stretch into a skin web instead of opening. :func:`animated_scan`:

* labels each canonical vertex within ``LIP_RINGS`` rings of the inner-lip loop as upper or lower lip
  (whichever half of the loop — split at the inner corners 2.4 / 2.5 — is fewer rings away);
* labels each scan vertex by the canonical triangle it is bound to (:func:`bind_scan`);
* closes the slits a scanner left between the closed lips (small holes with vertices of both lips;
  where the slit's two sides are on different lips, each lip closes its half up to the slit's middle);
* cuts every scan triangle that has vertices of both lips: it keeps the lip most of its corners
  are on, and its corners of the other lip are replaced by copies (same position and texture
  coordinates) that move like its own lip's corners — a cut along the scan's edges, closed at rest;
* adds the default face's mouth cavity and teeth, placed by a similarity on the mouth and chin
  landmarks; the cavity and upper teeth stay with the skull, the lower teeth follow the rigid
  motion (Kabsch) of the canonical chin, jaw points and lower lip, as on the default face.

A scan taken with the eyes shut gets the same treatment at each closed eye (``closed_eyes``: lid
centres closer than a share of the eye's width): canonical vertices go with the nearer lid margin
(:func:`canonical_lid_labels`; the template's squashed eye-opening covers split along their middle),
the scan is cut along the lid line moved onto its own lid crease (``core.registration.lid_crease``;
not into the walls of the eye's corners, the cut's margin moving smoothed along the line), skin
bound to a cover follows its own lid's margin (the FAPs do not move covers), and the default face's
eyeball sits behind the closed lid (the canonical face's and the scan's own), so the lid FAPs open
the scan's own eye onto it. (The FAP units measure a closed eye's IRISD0 as an open eye's of its
width, and the lid's opening shape is an open eye's: ``core.layers.fap``.)

An open eye's own surface (scanned eyeball, or the smooth sheet of a model without eyes) is bound to
the template's eye-opening covers, which the FAPs do not move: it stood still while the lids closed
onto it. It is hidden (scan triangles mostly on the covers), the skin still partly on them follows
its own lid's margin, and the default face's eyeball sits behind the opening, placed by the eye's
corners and lid centres, so the lids close over it and gaze turns it.

The texture of the added parts is the default face's, appended below the scan's texture image.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import scipy.sparse
from scipy.spatial import cKDTree

from core.face import Face, SurfacePoint
from core.layers.fap.closed_eyes import LidLine, closed_eye_side, closed_lid_lines, lid_point_sides, open_eye_lines
from core.layers.fap.template import DenseTemplate
from core.registration.correspondence import Registration, _adjacency, boundary_loops
from core.mesh_quality import height_ratios
from core.registration.folds import similarity
from core.registration.lid_crease import along_crease
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
#: The donor's eyeball of each eye (``closed_eyes.EYES`` keys), added behind a scan's closed lids.
EYEBALL_PARTS = {"l": "eyeball_l", "r": "eyeball_r"}
#: Landmarks placing a donor eyeball: the eye's corners and the brow above it (the lid centres are
#: not used: the donor's eye is open, the scan's closed).
EYE_POINTS = {"l": ("3.7", "3.11", "4.1", "4.3", "4.5"), "r": ("3.12", "3.8", "4.2", "4.4", "4.6")}
#: ... behind an open eye: its corners and lid centres (the opening it shows through; by the brows, a
#: Surrey Face Model scan's eyeball sat 2-3 mm high, its iris half under the upper lid).
OPEN_EYE_POINTS = {"l": ("3.7", "3.11", "3.1", "3.3"), "r": ("3.12", "3.8", "3.2", "3.4")}
#: Canonical vertices up to this many rings from a closed eye's lid margins go with the nearer lid.
LID_RINGS = 8
#: A closed eye's cut stays on skin less than this far behind its crease, mm: LeePerrySmith's lids on
#: the line lie up to 2.6 mm behind the crease's depth (smoothed along u, it sits in front of the skin
#: where the eye curves back to its corners), the walls of its eye corners down to 12 mm. At 2 mm the
#: cut stopped short of the outer corners (skin flaps across the opened eye, lid crossings 760 in
#: surprise), at 3 mm 597.
CUT_BEHIND_CREASE_MM = 3.0
#: A closed eye's cut margin moves smoothed along the lid line over this width, mm (2-3 crossing
#: points of LeePerrySmith's ~3 mm triangles either side: the floor / top alternation averages out).
MARGIN_SMOOTH_MM = 1.5
#: How far behind a closed lid's skin the added eyeball stays at rest, mm.
EYEBALL_BEHIND_MM = 0.5
#: The registration template whose canonical face is the FAP rig's dense template.
FAP_TEMPLATE = "mpeg4_80"
#: How far behind the scan's skin the placed mouth parts must stay, mm (a scan's upper lip can sit
#: further back than the donor's, and the cavity's rim would show through it as dark slits).
BEHIND_SKIN_MM = 1.0
PUSH_ROUNDS = 4
#: Scanner gaps between a closed mouth's lips this small (boundary loops of at most HOLE_MAX_VERTICES
#: vertices, no wider than HOLE_MM in any direction, mm; ~5 mm on a Surrey Face Model scan) are closed
#: before it is animated; a scanned open mouth is wider.
HOLE_MM = 15.0
HOLE_MAX_VERTICES = 60
#: A closing triangle lower than this share of its longest edge joins collinear vertices of one
#: scanner row: it covers nothing and is left out (zipped greedily, the synthetic scan's two 0.82 mm
#: slits gave 4, 0.007 mm high, whose "stretch" capped open_jaw's slider at 44 MNS and read 3.8x in
#: joy; the best-shaped strip, _strip, makes none there).
ZIP_MIN_HEIGHT_SHARE = 0.01
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
    return _nearer_side(triangles, *inner_lip_halves(triangles, template_name), rings)


def _nearer_side(triangles: np.ndarray, upper_seeds, lower_seeds, rings: int) -> np.ndarray:
    """(N,) +1 where the upper seeds are fewer rings away than the lower ones, -1 the other way, 0 on
    ties or beyond ``rings`` of both."""
    n = int(triangles.max()) + 1
    adjacency, _ = _adjacency(triangles, n)
    distance = []
    for seeds in (upper_seeds, lower_seeds):
        reached = np.zeros(n, bool)
        reached[seeds] = True
        rings_away = np.where(reached, 0, rings + 1)
        for ring in range(1, rings + 1):
            reached = reached | (adjacency @ reached.astype(float) > 0)
            rings_away = np.where(reached & (rings_away > rings), ring, rings_away)
        distance.append(rings_away)
    upper, lower = distance
    return np.where(upper < lower, 1, np.where(lower < upper, -1, 0)).astype(np.int8)


def canonical_lid_labels(canonical: Face, dense: DenseTemplate | None,
                         lines: list[LidLine]) -> tuple[np.ndarray, scipy.sparse.csr_matrix]:
    """(labels, carry) for the canonical vertices around closed eyes.

    labels (N,): +1 upper lid, -1 lower lid, 0 elsewhere. With the fitted template (``dense``,
    canonical vertex i = dense vertex i) the split follows the mesh: each vertex goes with the lid
    margin fewer rings away (the squashed eye-opening covers split along their middle, the lid line),
    within the eye's lid band; without it, the side of the geometric lid line (:func:`closed_eye_side`).

    carry (N, N): what moves a canonical vertex for the scan bound to it — itself, except inside an
    eye-opening cover, which the FAPs do not move (the lids slide over it): there the nearest vertex
    of its own lid's margin, so the scan's skin bound to the squashed cover opens with its lid."""
    n = canonical.n_vertices
    identity = scipy.sparse.identity(n, format="csr")
    if not lines:
        return np.zeros(n, np.int8), identity
    if dense is None or len(dense.vertices) != n:
        return closed_eye_side(canonical, lines=lines).astype(np.int8), identity
    base = dense.template
    support = dense.base_coords > 1e-12
    cover = _eye_covers(canonical, dense)
    target = np.arange(n)
    labels = np.zeros(n, np.int8)
    for line in lines:
        margin = base.eye_margins[line.eye]        # corner, upper lid (3 points), corner, lower lid (3)
        halves = []
        for points in (margin[0:5], margin[4:] + margin[:1]):
            ids = [base.index(p) for p in points]
            on = np.zeros(canonical.n_vertices, bool)
            for a, b in zip(ids, ids[1:]):   # vertices on the base edge a-b, not the corners themselves
                pair = support[:, [a, b]]
                on |= pair.all(axis=1) & (support.sum(axis=1) == 2)
            on |= support[:, [base.index(p) for p in points[1:-1]]].any(axis=1) & (support.sum(axis=1) == 1)
            halves.append(np.nonzero(on)[0])
        side = _nearer_side(canonical.triangles, halves[0], halves[1], LID_RINGS)
        above, inside = line.height(canonical.vertices)
        # The middle of a squashed cover is as many rings from both margins: the lid line decides
        # (left at 0, its vertices would hold the scan's skin half-way across the opened eye).
        side = np.where(side == 0, np.where(above > 0, 1, -1), side)
        labels = np.where(inside, side, labels).astype(np.int8)
        for margin_ids, lid in zip(halves, (1, -1)):
            snapped = np.nonzero(cover & inside & (labels == lid))[0]
            if len(snapped) and len(margin_ids):
                gaps = np.linalg.norm(canonical.vertices[snapped, None] - canonical.vertices[margin_ids][None], axis=2)
                target[snapped] = margin_ids[gaps.argmin(axis=1)]
    carry = scipy.sparse.csr_matrix((np.ones(n), (np.arange(n), target)), shape=(n, n))
    return labels, carry


def _eye_covers(canonical: Face, dense: DenseTemplate, lines: list[LidLine] | None = None) -> np.ndarray:
    """(N,) bool: canonical vertices inside the template's eye-opening covers (on no other template
    triangle), within the lid band of one of ``lines`` when given."""
    base = dense.template
    covered = sorted(base.eye_opening_triangles)
    others = [i for i in range(len(base.triangles)) if i not in base.eye_opening_triangles]
    cover = dense.in_base_triangles(covered) & ~dense.in_base_triangles(others)
    if lines is None:
        return cover
    return cover & np.any([line.height(canonical.vertices)[1] for line in lines], axis=0)


@dataclass(frozen=True)
class AnimatedScan:
    """The scan with cut lips and mouth parts, moved by its canonical face.

    face : the scan (n_scan vertices, then ``n_copies`` vertices of the cuts: copies along the lip
        line, two per crossing along closed eyes' lid lines; then the added mouth parts and eyeballs),
        with the registration's landmarks on its skin (inner-lip and lid points on their own side).
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

    def binding(self) -> scipy.sparse.csr_matrix:
        """(n, N) the face's vertices on the canonical (dense template) vertices: the skin's rows of
        ``matrix`` (the cut copies on their own lip or lid), none for the added parts."""
        n_skin = self.n_scan + self.n_copies
        return scipy.sparse.vstack([self.matrix, scipy.sparse.csr_matrix((self.face.n_vertices - n_skin,
                                                                          self.matrix.shape[1]))]).tocsr()

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


def _with_lip_slits_closed(scan: Face, lip_side: np.ndarray,
                           matrix: scipy.sparse.csr_matrix) -> tuple[Face, np.ndarray, scipy.sparse.csr_matrix]:
    """(scan, lip_side, matrix) with the slits along its closed mouth's lip line closed: small holes
    (boundary loops no wider than HOLE_MM) with vertices of both lips (``lip_side`` per scan vertex,
    :func:`_scan_lip_labels`; ``matrix`` (n, N) the scan's binding). A scanner leaves them where it
    cannot see into the lips' fold (a Surrey Face Model scan: 5 mm slits every few mm, through which
    the added teeth showed white at rest). (Gaps elsewhere, e.g. in the nose wings' creases, stay:
    closed across a crease whose sides move apart, their triangles stretched 2.3x in joy.)

    A slit whose two sides (:func:`_zip_closed`) are on different lips (by most of each side's
    vertices) is where the lips part: its vertices take their side's lip, and the closing triangles are
    split along the slit's middle, each side's part going to its own lip, with a vertex per lip on the
    middle line that moves with its side's vertex. The lips meet there at rest and part there, as
    Mimica's own lips do. (Kept whole and then cut, a closing triangle reached across to the other
    lip's rim and was passed through by it as soon as a FAP pressed the lips.) A slit with both sides
    on one lip is that lip's skin: its closing triangles are cut like the rest of the scan.

    The scan's own vertices keep their ids; the middle-line vertices are appended, with their labels
    and binding rows."""
    n = scan.n_vertices
    fills: list[tuple[int, int, int]] = []
    edges: list[tuple[int, int]] = []       # per middle-line vertex: its slit edge's two scan vertices
    sources: list[int] = []                 # ... and the one of its own side (its binding row)
    labels: list[int] = []
    side = np.array(lip_side)
    for loop in boundary_loops(scan.triangles):
        points = scan.vertices[loop]
        if (len(loop) < 3 or len(loop) > HOLE_MAX_VERTICES or np.ptp(points, axis=0).max() > HOLE_MM
                or not ((lip_side[loop] == 1).any() and (lip_side[loop] == -1).any())):
            continue
        local, chain = _zip_closed(points, scan.vertex_normals[loop].sum(axis=0))
        score = [lip_side[loop][chain == c].mean() if (chain == c).any() else 0.0 for c in (1, -1)]
        if score[0] * score[1] >= 0:
            # Both sides on one lip (a Surrey Face Model scan's slits inside its upper lip, by the
            # binding): the closing triangles are that lip's skin, cut like the rest where they reach
            # a vertex of the other. (Split there too, its lip's underside squeezed 0.2x in surprise + oh.)
            fills += [tuple(loop[t]) for t in local]
            continue
        lip_of = {1: 1, -1: -1} if score[0] >= score[1] else {1: -1, -1: 1}
        for c, lip in lip_of.items():
            side[loop[chain == c]] = lip
        middle: dict[tuple[int, int, int], int] = {}

        def on_middle(u: int, v: int, c: int) -> int:
            """The id of the middle of slit edge (u, v) (loop positions) on chain c's lip."""
            key = (min(u, v), max(u, v), c)
            if key not in middle:
                middle[key] = n + len(sources)
                edges.append((loop[u], loop[v]))
                sources.append(loop[u] if chain[u] == c else loop[v])
                labels.append(lip_of[c])
            return middle[key]

        # Each closing triangle clipped at the middle of its edges across the slit: chain c's part
        # keeps its own corners and the slit's ends (chain 0), in the triangle's order (its facing).
        for triangle in local:
            for c in (1, -1):
                polygon = []
                for k in range(3):
                    u, v = triangle[k], triangle[(k + 1) % 3]
                    if chain[u] * c >= 0:
                        polygon.append(loop[u])
                    if chain[u] * chain[v] < 0:
                        polygon.append(on_middle(u, v, c))
                fills += [(polygon[0], polygon[i], polygon[i + 1]) for i in range(1, len(polygon) - 1)]
    if not fills:
        return scan, lip_side, matrix
    matrix = _rebound_to_their_lip(matrix, scan.triangles, lip_side, side)
    pairs = np.array(edges, np.int64).reshape(-1, 2)
    vertices = np.concatenate([scan.vertices, scan.vertices[pairs].mean(axis=1)])
    triangles = np.array(fills, np.int64)
    triangles = triangles[height_ratios(vertices[triangles]) >= ZIP_MIN_HEIGHT_SHARE]
    uv = None if scan.uv is None else np.concatenate([scan.uv, scan.uv[pairs].mean(axis=1)])
    colours = None
    if scan.vertex_colors is not None:
        halves = scan.vertex_colors[pairs].astype(float).mean(axis=1)
        colours = np.concatenate([scan.vertex_colors, halves.round().astype(scan.vertex_colors.dtype)])
    closed = Face(vertices, np.concatenate([scan.triangles, triangles]), uv=uv, texture=scan.texture,
                  vertex_colors=colours, landmarks=scan.landmarks, metadata=scan.metadata, parts=scan.parts)
    return (closed, np.concatenate([side, labels]).astype(lip_side.dtype),
            scipy.sparse.vstack([matrix, matrix[np.array(sources, np.int64)]]).tocsr())


def _rebound_to_their_lip(matrix: scipy.sparse.csr_matrix, triangles: np.ndarray, was: np.ndarray,
                          now: np.ndarray) -> scipy.sparse.csr_matrix:
    """(n, N) ``matrix`` with each scan vertex whose lip label changed (``was`` -> ``now``, (n,)) bound
    as the mean of its neighbours already on its new lip (unchanged where it has none). Still bound to
    the other lip's canonical skin, it would keep moving with that lip (tried on the synthetic scan's
    slits, split as if their sides were on different lips: a relabelled rim vertex stretched its
    triangle 3.3x as the jaw opened 30 MNS)."""
    n = len(was)
    changed = np.flatnonzero(now != was)
    if not len(changed):
        return matrix
    adjacency, _ = _adjacency(triangles, n)
    near = adjacency[changed].multiply(was[None, :] == now[changed][:, None]).tocsr()
    count = np.asarray(near.sum(axis=1)).ravel()
    rows = scipy.sparse.diags(1.0 / np.maximum(count, 1)) @ near @ matrix
    found = np.flatnonzero(count > 0)
    keep = np.ones(n)
    keep[changed[found]] = 0.0
    placed = scipy.sparse.csr_matrix((np.ones(len(found)), (changed[found], found)), shape=(n, len(changed)))
    return (scipy.sparse.diags(keep) @ matrix + placed @ rows).tocsr()


def _strip(points: np.ndarray, side_a: list[int], side_b: list[int]) -> list[tuple[int, int, int]]:
    """The strip of triangles between two chains of ``points`` (m, 3) that start and end together
    (side_a[0] == side_b[0], side_a[-1] == side_b[-1]) with the best-shaped triangles: the least sum
    over its triangles of (squared edges) / area (a dynamic programme over the two chains). Zipped
    greedily by the shorter diagonal, a slit whose end lies in one lip's scanner row fanned from that
    end along the row: 1-3 % high slivers, crossed by the lip's own skin at the least motion."""
    la, lb = len(side_a), len(side_b)

    def shape(a: int, b: int, c: int) -> float:
        if len({a, b, c}) < 3:
            return 0.0                      # the chains' shared ends: no triangle
        p = points[[a, b, c]]
        area = np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0])) / 2
        return float(((p - np.roll(p, 1, axis=0)) ** 2).sum() / max(area, 1e-12))

    cost = np.full((la, lb), np.inf)
    came = np.zeros((la, lb), np.int8)      # 1: reached by a step along side_a, 2: along side_b
    cost[0, 0] = 0.0
    for i in range(la):
        for j in range(lb):
            along_a = cost[i - 1, j] + shape(side_a[i - 1], side_a[i], side_b[j]) if i else np.inf
            along_b = cost[i, j - 1] + shape(side_a[i], side_b[j], side_b[j - 1]) if j else np.inf
            if min(along_a, along_b) < cost[i, j]:
                cost[i, j], came[i, j] = (along_a, 1) if along_a <= along_b else (along_b, 2)
    triangles = []
    i, j = la - 1, lb - 1
    while i or j:
        if came[i, j] == 1:
            triangles.append((side_a[i - 1], side_a[i], side_b[j]))
            i -= 1
        else:
            triangles.append((side_a[i], side_b[j], side_b[j - 1]))
            j -= 1
    return triangles[::-1]


def _zip_closed(points: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(triangles (k, 3), chain (m,)) closing a boundary loop of points (m, 3) mm: its two sides
    between the ends of its longest extent are joined by a strip of triangles (:func:`_strip`; a
    slit's triangles span it across, not along), facing along ``normal`` (the surface's around
    it), as positions in the loop; ``chain`` is +1 on one side, -1 on the other, 0 at the two ends.
    Triangles lower than ZIP_MIN_HEIGHT_SHARE of their longest edge are left out."""
    centred = points - points.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    along = centred @ axis
    first, last = int(np.argmin(along)), int(np.argmax(along))
    m = len(points)
    side_a = [(first + k) % m for k in range((last - first) % m + 1)]
    side_b = [(first - k) % m for k in range((first - last) % m + 1)]
    chain = np.zeros(m, np.int64)
    chain[side_a[1:-1]], chain[side_b[1:-1]] = 1, -1
    triangles = _strip(points, side_a, side_b)
    local = np.array([t for t in triangles if len(set(t)) == 3], np.int64).reshape(-1, 3)
    local = local[height_ratios(points[local]) >= ZIP_MIN_HEIGHT_SHARE]
    corners = points[local]
    facing = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) @ normal
    local[facing < 0] = local[facing < 0][:, ::-1]
    return local, chain


def _scan_lip_labels(matrix: scipy.sparse.csr_matrix, canonical_labels: np.ndarray) -> np.ndarray:
    """(n_scan,) +1 upper lip, -1 lower lip, 0 neither: the side most of a scan vertex's binding
    (``matrix``, scan x canonical) is on (``canonical_labels``, :func:`lip_labels`)."""
    total = np.asarray(matrix.sum(axis=1)).ravel()
    score = (matrix @ canonical_labels.astype(float)) / np.maximum(total, 1e-12)
    return np.where(score > 0.5, 1, np.where(score < -0.5, -1, 0))


def _cut_lips(scan: Face, matrix: scipy.sparse.csr_matrix, label: np.ndarray):
    """(triangles, copy_of (k,), copy rows (k, N)) of the scan cut between upper and lower lip
    (``label`` per scan vertex: :func:`_scan_lip_labels`)."""
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


@dataclass
class SkinPoints:
    """The skin of the animated scan as it grows: positions (n, 3) mm, texture coordinates (n, 2) or
    None, colours (n, 3) or None, binding rows (n, N) on the canonical vertices."""

    positions: np.ndarray
    uv: np.ndarray | None
    colours: np.ndarray | None
    rows: scipy.sparse.csr_matrix

    def append(self, positions, uv, colours, rows) -> None:
        self.positions = np.concatenate([self.positions, positions])
        self.uv = None if self.uv is None else np.concatenate([self.uv, uv])
        self.colours = None if self.colours is None else np.concatenate([self.colours, colours])
        self.rows = scipy.sparse.vstack([self.rows, rows]).tocsr()


def _cut_lids(skin: SkinPoints, triangles: np.ndarray, lines: list[LidLine]) -> tuple[np.ndarray, np.ndarray]:
    """(triangles, lid side per skin vertex (+1 upper, -1 lower, 0 elsewhere)) of the skin cut along
    each closed eye's lid line; ``skin`` gets the cut's new vertices.

    The cut follows the line itself, not the scan's edges (a scan's 2-3 mm triangles would leave a
    saw-toothed lid margin): every triangle the line crosses is split where the line crosses its two
    edges, into one triangle on the lone corner's side and two on the other, and each crossing point
    is two vertices, one per lid, moving like that lid's corner of the crossed edge."""
    n = len(skin.positions)
    height = np.zeros(n)
    in_band = np.zeros(n, bool)
    for line in lines:
        above, inside = line.height(skin.positions)
        # Not into the walls of the eye's corners behind the crease (where the lid line runs along
        # them, a cut there zig-zags down the wall and opens a slit into it).
        inside &= line.off_crease(skin.positions) > -CUT_BEHIND_CREASE_MM
        height = np.where(inside, above, height)
        in_band |= inside
    height = np.where(in_band & (np.abs(height) < 1e-6), 1e-6, height)   # no crossing at a corner
    side = np.where(in_band, np.sign(height), 0).astype(np.int64)
    corner = side[triangles]
    seam = np.nonzero((corner != 0).all(axis=1) & (corner == 1).any(axis=1) & (corner == -1).any(axis=1))[0]
    if not len(seam):
        return triangles, side
    lone_sign = -np.sign(corner[seam].sum(axis=1))                         # the side with one corner
    k = np.argmax(corner[seam] == lone_sign[:, None], axis=1)
    tri = triangles[seam]
    rows = np.arange(len(seam))
    a, b, c = tri[rows, k], tri[rows, (k + 1) % 3], tri[rows, (k + 2) % 3]  # a alone; order kept
    edges = np.concatenate([np.sort(np.column_stack([a, b]), axis=1), np.sort(np.column_stack([a, c]), axis=1)])
    unique, which = np.unique(edges, axis=0, return_inverse=True)
    which = which.ravel()
    e0, e1 = unique[:, 0], unique[:, 1]
    t = height[e0] / (height[e0] - height[e1])                             # where the line crosses, 0..1
    points = skin.positions[e0] + t[:, None] * (skin.positions[e1] - skin.positions[e0])
    upper_end = np.where(side[e0] > 0, e0, e1)
    lower_end = np.where(side[e0] > 0, e1, e0)
    m = len(unique)
    # New vertices: the upper copies of the crossing points, then the lower copies.
    uv = None if skin.uv is None else skin.uv[e0] + t[:, None] * (skin.uv[e1] - skin.uv[e0])
    colours = None if skin.colours is None else np.round(
        skin.colours[e0] + t[:, None] * (skin.colours[e1].astype(float) - skin.colours[e0])).astype(skin.colours.dtype)
    along = _along_margin(points, lines)
    skin.append(np.concatenate([points, points]), None if uv is None else np.concatenate([uv, uv]),
                None if colours is None else np.concatenate([colours, colours]),
                scipy.sparse.vstack([along @ skin.rows[upper_end], along @ skin.rows[lower_end]]))
    ab, ac = which[:len(seam)], which[len(seam):]

    def copy(edge, lid_side):
        return n + edge + np.where(lid_side > 0, 0, m)

    side_a = side[a]
    lone = np.column_stack([a, copy(ab, side_a), copy(ac, side_a)])
    pair_first = np.column_stack([copy(ab, -side_a), b, c])
    pair_second = np.column_stack([copy(ab, -side_a), c, copy(ac, -side_a)])
    keep = np.ones(len(triangles), bool)
    keep[seam] = False
    new_side = np.concatenate([side, np.ones(m, np.int64), -np.ones(m, np.int64)])
    return np.concatenate([triangles[keep], lone, pair_first, pair_second]), new_side


def _along_margin(points: np.ndarray, lines: list[LidLine]) -> scipy.sparse.csr_matrix:
    """(m, m) row-stochastic: each of a cut's crossing points (m, 3) mm averaged with its eye's
    others by a Gaussian of MARGIN_SMOOTH_MM along the lid line. A crossing point moves like its
    edge's corner on its own lid; a scan's ~3 mm triangles span the 1-2 mm crease, so those corners
    alternate between the crease's floor and the lid's top, which a pose moves differently (the
    margin rises more than the lid above it): the opened margin would be saw-toothed."""
    m = len(points)
    rows, cols, vals = [np.arange(m)], [np.arange(m)], [np.ones(m)]
    taken = np.zeros(m, bool)
    for line in lines:
        _, inside = line.height(points)
        ids = np.nonzero(inside & ~taken)[0]
        taken[ids] = True
        if len(ids) < 2:
            continue
        s = (points[ids] - line.start) @ line.u
        weight = np.exp(-0.5 * ((s[:, None] - s[None, :]) / MARGIN_SMOOTH_MM) ** 2)
        weight[np.arange(len(ids)), np.arange(len(ids))] = 0.0
        keep = weight > 1e-3
        i, j = np.nonzero(keep)
        rows.append(ids[i]), cols.append(ids[j]), vals.append(weight[keep])
    smooth = scipy.sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                     shape=(m, m))
    return scipy.sparse.diags(1.0 / np.asarray(smooth.sum(axis=1)).ravel()) @ smooth


def _donor_parts(donor: Face, names) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(donor vertex ids (k,), donor id -> local id or -1 (n,), local triangles (m, 3)) of the donor's
    parts ``names``."""
    keep = np.zeros(donor.n_vertices, bool)
    for name in names:
        keep |= donor.part_mask(name)
    ids = np.nonzero(keep)[0]
    local = np.full(donor.n_vertices, -1)
    local[ids] = np.arange(len(ids))
    return ids, local, local[donor.triangles[keep[donor.triangles].all(axis=1)]]


def _mouth_parts(skin: Face, scan_points: np.ndarray, donor: Face, donor_points: np.ndarray):
    """(vertices, triangles, uv, {part: local ids}) of the donor's mouth parts placed on the scan."""
    ids, local, triangles = _donor_parts(donor, MOUTH_PARTS)
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
    needs, so the teeth keep their shape and stay inside the cavity; the cavity's points still too
    shallow (its rim) then go that depth below their closest skin point. The teeth are not pushed
    one by one: behind a closed mouth, the skin closest to a tooth is often the lips' inner surface,
    facing down or up, and "below" it is not "behind the face" (LeePerrySmith: 373 of 2216 tooth
    points pushed up to 12 mm toward the lip line, the arches torn into shards between parted lips)."""
    points = points.copy()
    depth, _, _ = _depth_below(skin, points[teeth])
    needed = float(np.percentile(BEHIND_SKIN_MM - depth, 99)) if len(depth) else 0.0
    if needed > 0:
        points -= needed * forward
    rim = np.flatnonzero(~teeth)
    for _ in range(PUSH_ROUNDS):   # a pushed point can come nearer another triangle (a crease): again
        depth, closest, normal = _depth_below(skin, points[rim])
        shallow = depth < BEHIND_SKIN_MM - 1e-6
        if not shallow.any():
            break
        points[rim[shallow]] = closest[shallow] - BEHIND_SKIN_MM * normal[shallow]
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


def _own_lid_rows(matrix: scipy.sparse.csr_matrix, side: np.ndarray, lid_labels: np.ndarray,
                  canonical: Face) -> scipy.sparse.csr_matrix:
    """``matrix`` (skin vertices x canonical vertices) with the weights of each lid vertex (``side``
    +1 / -1 per row, 0 for others) on the other lid's canonical vertices dropped (the rest scaled to
    the row's sum); a row left with nothing (a vertex above the lid line bound only to canonical lower
    lid, where the landmarks put the line a little off the scan's) takes the nearest canonical vertex
    of its own lid. At rest a closed eye's lids touch: scan vertices at the lid line are bound to
    canonical triangles of both lids and would stay between them, a strip of skin across the opened eye."""
    if not lid_labels.any() or not side.any():
        return matrix
    labels = lid_labels.astype(float)
    total = np.asarray(matrix.sum(axis=1)).ravel()
    coo = matrix.tocoo()
    keep = ~((side[coo.row] != 0) & (labels[coo.col] == -side[coo.row]))
    rows, cols, data = coo.row[keep], coo.col[keep], coo.data[keep]
    kept_total = np.bincount(rows, weights=data, minlength=matrix.shape[0])
    scale = np.where(kept_total > 1e-12, total / np.maximum(kept_total, 1e-12), 1.0)
    data = data * scale[rows]
    empty = np.nonzero((side != 0) & (kept_total <= 1e-12) & (total > 1e-12))[0]
    if len(empty):
        centre = matrix[empty] @ canonical.vertices / total[empty, None]   # where the row put the vertex
        nearest = np.zeros(len(empty), np.int64)
        for lid in (1, -1):
            own = np.nonzero(lid_labels == lid)[0]
            pick = side[empty] == lid
            if len(own) and pick.any():
                nearest[pick] = own[cKDTree(canonical.vertices[own]).query(centre[pick])[1]]
        rows, cols, data = (np.concatenate([rows, empty]), np.concatenate([cols, nearest]),
                            np.concatenate([data, total[empty]]))
    return scipy.sparse.csr_matrix((data, (rows, cols)), shape=matrix.shape)


def _eyeball_part(canonical: Face, donor: Face, line: LidLine, scan: Face | None = None, open_eye: bool = False):
    """(vertices, triangles, uv, {part: local ids}) of the donor's eyeball for the closed eye of
    ``line``, placed by a similarity on the eye's corners and brow and moved straight back until it
    is EYEBALL_BEHIND_MM behind the closed lid everywhere: the canonical face's and the ``scan``'s
    own lid skin (:func:`_lid_points`). The scan's crease lies 2-3 mm behind the canonical face,
    which spans it: placed by the canonical face alone, the eyeball reached 1.7 mm through
    LeePerrySmith's crease, and the FAP layer's lid guard pushed the crease's vertices out of it one
    by one as the lid opened, a saw-toothed margin. ``open_eye``: placed by the eye's corners and
    lid centres instead (behind the scan's own eye surface, which the caller hides). None when the
    donor lacks it."""
    name = EYEBALL_PARTS[line.eye]
    points = [p for p in (OPEN_EYE_POINTS if open_eye else EYE_POINTS)[line.eye]
              if p in canonical.landmarks and p in donor.landmarks]
    if name not in donor.parts or len(points) < 3:
        return None
    ids, _, triangles = _donor_parts(donor, (name,))
    scale, rotation, shift = similarity(donor.landmark_positions(points), canonical.landmark_positions(points))
    vertices = scale * donor.vertices[ids] @ rotation.T + shift
    depth, _, _ = _depth_below(canonical, vertices)
    needed = float((EYEBALL_BEHIND_MM - depth).max())
    if needed > 0:   # rigidly, so the eyeball keeps its round front
        vertices = vertices - needed * line.w
    lid = _lid_points(scan, line) if scan is not None else np.zeros((0, 3))
    for _ in range(PUSH_ROUNDS if len(lid) else 0):
        # The scan's lid points outside the ball's surface (signed: + outside); moving the ball back
        # by the shortfall gains less where the surface is not square to w: again.
        closest, _, _ = TriangleSet(vertices, triangles).closest(lid)
        centre = vertices.mean(axis=0)
        gap = np.linalg.norm(lid - closest, axis=1) * np.sign(np.einsum("kd,kd->k", lid - closest, lid - centre))
        short = EYEBALL_BEHIND_MM - float(gap.min())
        if short <= 1e-3:
            break
        vertices = vertices - short * line.w
    uv = None if donor.uv is None else donor.uv[ids]
    return vertices, triangles, uv, {name: np.arange(len(ids))}


def _lid_points(scan: Face, line: LidLine) -> np.ndarray:
    """(k, 3) mm: the scan's vertices on the closed eye's lids (inside the lid band of ``line``, not
    in the walls of the eye's corners behind the crease, where the cut does not go either)."""
    _, inside = line.height(scan.vertices)
    inside &= line.off_crease(scan.vertices) > -CUT_BEHIND_CREASE_MM
    return scan.vertices[inside]


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
    canonical = registration.face
    matrix = registration.carry_back().binding.matrix
    labels = lip_labels(canonical.triangles, registration.template)
    lip_side = _scan_lip_labels(matrix, labels)
    scan, lip_side, matrix = _with_lip_slits_closed(registration.scan, lip_side, matrix)
    # Closed eyes are cut along their lid line (after the lips: the cut splits the triangles it
    # crosses) and get the donor's eyeballs behind the lids. cut_labels (lips and lids: far apart, no
    # triangle spans both) keep each lip's and lid's landmarks on its own side.
    lid_lines = [along_crease(line, scan.vertices, scan.triangles)
                 for line in closed_lid_lines(canonical) if EYEBALL_PARTS[line.eye] not in scan.parts]
    fitted = registration.projection.dense if registration.projection is not None else None
    # Open eyes get the donor's eyeball too, behind the scan's own eye surface, which is hidden: bound
    # to the template's eye-opening covers (which the FAPs do not move) it stood still while the lids
    # closed onto it and squeezed the skin between (a Surrey Face Model scan's lower lids 0.04x in joy).
    open_lines = [line for line in open_eye_lines(canonical)
                  if EYEBALL_PARTS[line.eye] not in scan.parts and EYEBALL_PARTS[line.eye] in donor.parts] \
        if fitted is not None and len(fitted.vertices) == canonical.n_vertices else []
    lid_labels, lid_carry = canonical_lid_labels(canonical, fitted, lid_lines + open_lines)
    cut_labels = np.where(labels != 0, labels, lid_labels).astype(np.int8)
    triangles, copy_of, copy_rows = _cut_lips(scan, matrix, lip_side)
    interior = _mouth_interior(scan, canonical, registration.template)
    triangles = triangles[~interior]
    skin = SkinPoints(np.concatenate([scan.vertices, scan.vertices[copy_of]]),
                      None if scan.uv is None else np.concatenate([scan.uv, scan.uv[copy_of]]),
                      None if scan.vertex_colors is None else np.concatenate([scan.vertex_colors,
                                                                               scan.vertex_colors[copy_of]]),
                      scipy.sparse.vstack([matrix, copy_rows]).tocsr())
    lid_side = np.zeros(len(skin.positions), np.int64)
    if lid_lines:
        triangles, lid_side = _cut_lids(skin, triangles, lid_lines)
    if open_lines:
        on_cover = _eye_covers(canonical, fitted, open_lines).astype(float)
        share = (skin.rows @ on_cover) / np.maximum(np.asarray(skin.rows.sum(axis=1)).ravel(), 1e-12)
        # Hidden where every corner is mostly on the covers (hiding a triangle with any such corner, or
        # by the corners' mean share, squeezed the lid margin's skin more as the lids closed; clipping
        # the triangles along share 0.5 left slivers that stretched 800x).
        triangles = triangles[~(share[triangles] > 0.5).all(axis=1)]
    n_scan, n_copies = scan.n_vertices, len(skin.positions) - scan.n_vertices
    vertices = [skin.positions]
    skin_uv, colours = skin.uv, skin.colours
    all_triangles = [triangles]
    parts = {name: np.array(idx) for name, idx in scan.parts.items()}
    added = []   # (vertices, local triangles, uv, {part: local ids}) of the donor's parts
    present = [p for p in MOUTH_POINTS if p in canonical.landmarks and p in donor.landmarks]
    if not any(name in scan.parts for name in MOUTH_PARTS) and len(present) >= 4:
        part_vertices, part_triangles, part_uv, part_ids, forward = _mouth_parts(
            canonical, canonical.landmark_positions(present), donor, donor.landmark_positions(present))
        seen = _seen_from_the_front(skin.positions, triangles, part_vertices, forward)
        added.append((part_vertices, part_triangles[~seen[part_triangles].any(axis=1)], part_uv, part_ids))
    for line, open_eye in [(line, False) for line in lid_lines] + [(line, True) for line in open_lines]:
        eyeball = _eyeball_part(canonical, donor, line, scan, open_eye=open_eye)
        if eyeball is not None:
            added.append(eyeball)
    offset = n_scan + n_copies
    for part_vertices, part_triangles, _uv, part_ids in added:
        vertices.append(part_vertices)
        all_triangles.append(part_triangles + offset)
        parts.update({name: idx + offset for name, idx in part_ids.items()})
        offset += len(part_vertices)
    texture = scan.texture
    if added:
        part_uv = None if any(uv is None for _v, _t, uv, _p in added) else np.concatenate([a[2] for a in added])
        n_added = sum(len(a[0]) for a in added)
        if skin_uv is not None and texture is not None and part_uv is not None and donor.texture is not None:
            texture, share = _stacked_texture(scan.texture, donor.texture)
            skin_uv = np.column_stack([skin_uv[:, 0], 1.0 - share * (1.0 - skin_uv[:, 1])])
            skin_uv = np.concatenate([skin_uv, np.column_stack([part_uv[:, 0], (1.0 - share) * part_uv[:, 1]])])
        elif skin_uv is not None:
            skin_uv = np.concatenate([skin_uv, np.zeros((n_added, 2))])
        if colours is not None:
            colours = np.concatenate([colours, _part_colours(donor, part_uv, n_added)])
    skin_matrix = (_own_lid_rows(skin.rows, lid_side, lid_labels, canonical) @ lid_carry).tocsr()
    all_vertices = np.concatenate(vertices)
    face = Face(all_vertices, np.concatenate(all_triangles), uv=skin_uv,
                texture=texture if skin_uv is not None else None, vertex_colors=colours,
                landmarks=_landmarks_on_skin(all_vertices, triangles, skin_matrix, canonical, cut_labels,
                                             registration.template, lid_point_sides(canonical, lid_lines)),
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
                       template_name: str, lid_sides: dict[str, int] | None = None) -> dict[str, SurfacePoint]:
    """{name: SurfacePoint} of the canonical face's landmarks on the cut scan's skin. The scan's own
    triangles under an inner-lip point may belong to either lip after the cut (they touch at rest), so
    upper-lip points are placed only on triangles with no lower-lip corner and the other way round —
    else the point would ride on the wrong lip when the jaw opens. ``lid_sides`` ({point: +1 / -1})
    does the same for the lid points of closed eyes cut along their lid line."""
    total = np.asarray(skin_matrix.sum(axis=1)).ravel()
    score = (skin_matrix @ canonical_labels.astype(float)) / np.maximum(total, 1e-12)
    corner = np.where(score > 0.5, 1, np.where(score < -0.5, -1, 0))[skin_triangles]
    base = get_template(template_name).base
    names = list(canonical.landmarks)
    positions = canonical.landmark_positions(names)
    lid_sides = lid_sides or {}
    side_of = np.array([1 if n in base.upper_lip_points else -1 if n in base.lower_lip_points
                        else lid_sides.get(n, 0) for n in names])
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
    n_mouth = sum(len(shown.parts.get(name, ())) for name in MOUTH_PARTS)
    added = {eye for eye, part in EYEBALL_PARTS.items() if part in shown.parts and part not in registration.scan.parts}
    closed = [line.eye for line in closed_lid_lines(canonical) if line.eye in added]
    opened = sorted(added - set(closed))
    eyes = {("l",): "the left eye was closed: it is cut along its lid line and has an eyeball behind it",
            ("r",): "the right eye was closed: it is cut along its lid line and has an eyeball behind it",
            ("l", "r"): "both eyes were closed: they are cut along their lid lines and have eyeballs behind them"}
    notes = [*shown.metadata.notes, *report,
             f"Animated at full resolution ({animated.n_scan} vertices) through a {canonical.n_vertices}-vertex "
             f"canonical face; lips cut along the lip line ({animated.n_copies} vertices copied)"
             + (f", mouth cavity and teeth added ({n_mouth} vertices)." if n_mouth else ".")]
    if closed:
        notes.append(f"The scan's {eyes[tuple(sorted(closed))]}; the eyelid sliders (FAPs 19-22) open them.")
    if opened:
        which = {("l",): "left eye shows", ("r",): "right eye shows", ("l", "r"): "eyes show"}[tuple(opened)]
        notes.append(f"The scan's open {which} Mimica's eyeball behind the lids (its own eye surface is hidden), "
                     "so the eyelid sliders close over it and the gaze sliders (FAPs 23-26) turn it.")
    shown.metadata = dataclasses.replace(shown.metadata, notes=notes)
    if animated.dense is not None and cache is not None:
        from core.layers.fap.fat import FapDeformer

        FapDeformer.for_face(shown, cache, progress, dense=animated.dense, binding=animated.binding())
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
