"""mesh_quality.py
----
Does a deformed face still hold up? Counts, for one pose of a face, what a viewer sees as broken:

* **lip** intersections: skin triangles around the mouth passing through each other (the lips
  crossing), **lid** intersections: skin triangles around an eye passing through each other or into
  the eyeball (the eyeball showing through the lid), **teeth** intersections: mouth skin passing
  through the teeth;
* **folded** triangles: skin triangles whose normal turned more than 90 degrees from its rest
  direction (the surface folded over itself);
* **texture stretch**: per skin triangle the principal stretches of the map rest -> pose (the
  texture is glued to the rest surface, so a stretch of 2 shows each texel twice as long); the
  largest and the smallest over the face;
* **eye openness**: the share of the eyeball's front (seen from the front) not hidden by the skin,
  per eye; a pose that closes a lid completely should leave 0.

A registered scan can cross itself at rest (its closed lips' seam, flaps in the creases by its nose
wings: ~100 pairs on every scan tried). Those pairs are the face's, not a pose's: each pose reports
how many of its crossings the rest face has too (``PoseQuality.at_rest``), and
:meth:`PoseQuality.failures` counts them only for the rest pose (``count_rest``), as the sliders'
crossing limits do (``core.layers.fap.limits.new_crossings``).

:class:`FaceQualityProbe` precomputes per face what does not change with the pose (regions, rest
frames, candidate radii) so a pose costs a few tens of ms at 54k vertices. Intersections are exact
segment/triangle tests on candidate pairs whose bounding spheres overlap; triangles that share a
vertex, or a seam's copies of one (the closed mouth's two sides), are never counted (they touch by
construction).

Regions come from the MPEG-4 feature points (lip corners 8.3/8.4, eye corners 3.7/3.11 and
3.8/3.12); a face without them (a raw scan) gets no lip/lid counts (``None``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Where a pose stops looking like skin. Real facial skin strains by up to about 30-40 % in
# expressions (skin-strain studies of smiling/mouth opening); twice the rest length is well past
# that and is where a texture's pixels visibly smear; a triangle squeezed to a quarter of its rest
# size is a crumple the eye reads as a crease artefact.
MAX_STRETCH = 2.0
MIN_STRETCH = 0.25
# Eye openness that still counts as closed: the few grazing rays at the lid margin.
CLOSED_EYE_OPENNESS = 0.01

_EPS = 1e-12


@dataclass(frozen=True)
class PoseQuality:
    """What is broken in one pose. Counts are triangle pairs (intersections) or triangles."""

    lip_intersections: int | None
    lid_intersections: int | None
    teeth_intersections: int | None
    folded_triangles: int
    max_stretch: float
    min_stretch: float
    eye_openness: dict[str, float] = field(default_factory=dict)
    # Mouth skin crossing the mouth cavity's lining (a region pulled in through the lips); None
    # when the face has no cavity.
    cavity_intersections: int | None = None
    # Of each kind's crossing pairs ("lip", "lid", "teeth", "mouth cavity"), how many cross in the rest
    # face too (a registered scan's own; 0 on Mimica's faces): not the pose's doing.
    at_rest: dict[str, int] = field(default_factory=dict)

    def failures(self, *, eyes_closed: tuple[str, ...] = (), count_rest: bool = False) -> list[str]:
        """Human-readable reasons this pose breaks the surface ([] when it holds up).

        ``eyes_closed``: the eyes ("left", "right") this pose must close completely. Crossings that the
        rest face already has are the face's, not the pose's: counted only with ``count_rest`` (the
        rest pose itself)."""
        out = []
        for what, n in (("lip", self.lip_intersections), ("lid", self.lid_intersections),
                        ("teeth", self.teeth_intersections), ("mouth cavity", self.cavity_intersections)):
            rest = self.at_rest.get(what, 0)
            new = (n or 0) - (0 if count_rest else rest)
            if new:
                out.append(f"{new} {what} intersections" + (f" ({rest} already at rest)" if count_rest and rest else ""))
        if self.folded_triangles:
            out.append(f"{self.folded_triangles} folded triangles")
        if self.max_stretch > MAX_STRETCH:
            out.append(f"texture stretch {self.max_stretch:.2f} > {MAX_STRETCH}")
        if self.min_stretch < MIN_STRETCH:
            out.append(f"texture squeeze {self.min_stretch:.2f} < {MIN_STRETCH}")
        for side in eyes_closed:
            openness = self.eye_openness.get(side)
            if openness is not None and openness > CLOSED_EYE_OPENNESS:
                out.append(f"{side} eye {100 * openness:.0f} % open, should be closed")
        return out


# ---------------------------------------------------------------------------- geometry kernels
def segments_cross_triangles(p0: np.ndarray, p1: np.ndarray, a: np.ndarray, b: np.ndarray,
                             c: np.ndarray) -> np.ndarray:
    """Row-wise: does segment p0-p1 cross triangle abc (Moller-Trumbore)? All (k, 3) -> (k,) bool."""
    d = p1 - p0
    e1, e2 = b - a, c - a
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > _EPS
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p0 - a
    u = inv * np.einsum("ij,ij->i", s, h)
    q = np.cross(s, e1)
    v = inv * np.einsum("ij,ij->i", d, q)
    t = inv * np.einsum("ij,ij->i", e2, q)
    # Strict inside: surfaces that only touch (lips closed on each other, a seam's coincident
    # vertices) do not cross.
    tol = 1e-9
    return ok & (u > tol) & (v > tol) & (u + v < 1 - tol) & (t > tol) & (t < 1 - tol)


def triangles_intersect(tri_a: np.ndarray, tri_b: np.ndarray) -> np.ndarray:
    """Row-wise: do triangles (k, 3, 3) and (k, 3, 3) intersect? (k,) bool.

    Two triangles that cross have an edge of one passing through the other (the ends of their
    intersection segment lie on edges), so six segment tests decide it; coplanar overlaps, which a
    deformation practically never produces exactly, are not counted."""
    hit = np.zeros(len(tri_a), dtype=bool)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        hit |= segments_cross_triangles(tri_a[:, i], tri_a[:, j], tri_b[:, 0], tri_b[:, 1], tri_b[:, 2])
        hit |= segments_cross_triangles(tri_b[:, i], tri_b[:, j], tri_a[:, 0], tri_a[:, 1], tri_a[:, 2])
    return hit


def count_intersections(vertices: np.ndarray, tris_a: np.ndarray, tris_b: np.ndarray | None = None,
                        welded: np.ndarray | None = None) -> int:
    """How many triangle pairs of :func:`intersecting_pairs` cross."""
    return len(intersecting_pairs(vertices, tris_a, tris_b, welded)[0])


def welded_vertices(rest: np.ndarray) -> np.ndarray:
    """(n,) for each vertex of a rest mesh (n, 3) the first vertex at exactly its position: a seam's
    copies (the two sides of a closed mouth, a head shell's copy of the face's rim) map to one."""
    _, first, inverse = np.unique(np.asarray(rest), axis=0, return_index=True, return_inverse=True)
    return first[np.ravel(inverse)]


def intersecting_pairs(vertices: np.ndarray, tris_a: np.ndarray, tris_b: np.ndarray | None = None,
                       welded: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rows (ia, ib) of crossing triangle pairs between ``tris_a`` and ``tris_b`` ((k, 3) vertex
    indices), or within ``tris_a`` when ``tris_b`` is None; pairs sharing a vertex are skipped, and
    with ``welded`` ((n,) from :func:`welded_vertices`) also pairs sharing a seam's copy of a vertex
    (they touch there by construction: the exact test, on triangles meeting at one point, counted the
    closed mouth's corner triangles of a corner FAP as crossing; shrunk 1 % they did not)."""
    same = tris_b is None
    tris_b = tris_a if same else tris_b
    if not len(tris_a) or not len(tris_b):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    va, vb = vertices[tris_a], vertices[tris_b]
    ca, cb = va.mean(axis=1), vb.mean(axis=1)
    rad_a = np.linalg.norm(va - ca[:, None], axis=2).max(axis=1)
    rad_b = rad_a if same else np.linalg.norm(vb - cb[:, None], axis=2).max(axis=1)
    ia, ib = _candidate_pairs(ca, rad_a, cb, rad_b, same)
    # Bounding spheres first (most candidates of the shared radius are too far apart), then
    # triangles that share a vertex (they touch by construction), then the exact test.
    keep = np.linalg.norm(ca[ia] - cb[ib], axis=1) <= rad_a[ia] + rad_b[ib]
    ia, ib = ia[keep], ib[keep]
    ids_a, ids_b = (tris_a, tris_b) if welded is None else (welded[tris_a], welded[tris_b])
    shared = (ids_a[ia][:, :, None] == ids_b[ib][:, None, :]).any(axis=(1, 2))
    ia, ib = ia[~shared], ib[~shared]
    hit = triangles_intersect(va[ia], vb[ib])
    return ia[hit], ib[hit]


# Triangles above this percentile of their set's bounding radii are searched apart (see
# _candidate_pairs).
_LARGE_PERCENTILE = 90.0


def _candidate_pairs(ca: np.ndarray, rad_a: np.ndarray, cb: np.ndarray, rad_b: np.ndarray,
                     same: bool) -> tuple[np.ndarray, np.ndarray]:
    """(ia, ib) pairs of triangles (centroids ``ca``/``cb``, bounding radii) whose centroids are
    close enough for their bounding spheres to meet (each unordered pair once when ``same``).

    Searched per size class (the largest tenth of each set apart): one search radius of twice the
    largest triangle's made a dense mouth region yield ten times the pairs it needs."""
    def classes(rad):
        large = rad > np.percentile(rad, _LARGE_PERCENTILE)
        return [idx for idx in (np.flatnonzero(~large), np.flatnonzero(large)) if len(idx)]

    from scipy.spatial import cKDTree   # here: the window imports this module (through the FAP limits)
                                        # at start-up, and scipy.spatial costs ~0.3 s to import
    classes_a = classes(rad_a)
    classes_b = classes_a if same else classes(rad_b)
    found_a, found_b = [], []
    for i, A in enumerate(classes_a):
        tree = cKDTree(ca[A])
        for j, B in enumerate(classes_b):
            reach = float(rad_a[A].max() + rad_b[B].max())
            if same and j < i:
                continue            # the same pairs as (j, i)
            if same and i == j:
                pairs = tree.query_pairs(reach, output_type="ndarray")
                found_a.append(A[pairs[:, 0]])
                found_b.append(A[pairs[:, 1]])
            else:
                pairs = tree.sparse_distance_matrix(cKDTree(cb[B]), reach, output_type="ndarray")
                found_a.append(A[pairs["i"].astype(np.int64)])
                found_b.append(B[pairs["j"].astype(np.int64)])
    ia, ib = np.concatenate(found_a), np.concatenate(found_b)
    if same:   # unordered, as query_pairs gives them
        ia, ib = np.minimum(ia, ib), np.maximum(ia, ib)
    return ia, ib


def _local_frames(corners: np.ndarray) -> np.ndarray:
    """(k, 2, 2) upper-triangular edge matrices of triangles (k, 3, 3) in their own plane."""
    e1 = corners[:, 1] - corners[:, 0]
    e2 = corners[:, 2] - corners[:, 0]
    l1 = np.linalg.norm(e1, axis=1)
    u = e1 / np.maximum(l1, _EPS)[:, None]
    along = np.einsum("ij,ij->i", e2, u)
    across = np.linalg.norm(e2 - along[:, None] * u, axis=1)
    frames = np.zeros((len(corners), 2, 2))
    frames[:, 0, 0], frames[:, 0, 1], frames[:, 1, 1] = l1, along, across
    return frames


def principal_stretches(rest_frames: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Largest and smallest principal stretch (k,) of the maps rest -> pose, from the rest
    edge matrices :func:`_local_frames` and the posed corners (k, 3, 3)."""
    pose = _local_frames(corners)
    det = rest_frames[:, 0, 0] * rest_frames[:, 1, 1]
    safe = np.abs(det) > _EPS
    inv = np.zeros_like(rest_frames)
    inv[safe, 0, 0] = 1.0 / rest_frames[safe, 0, 0]
    inv[safe, 0, 1] = -rest_frames[safe, 0, 1] / det[safe]
    inv[safe, 1, 1] = 1.0 / rest_frames[safe, 1, 1]
    f = pose @ inv
    # Singular values of a 2x2 matrix in closed form.
    a, b, c, d = f[:, 0, 0], f[:, 0, 1], f[:, 1, 0], f[:, 1, 1]
    s1 = a * a + b * b + c * c + d * d
    s2 = np.sqrt(np.maximum((a * a + b * b - c * c - d * d) ** 2 + 4 * (a * c + b * d) ** 2, 0.0))
    big = np.sqrt(np.maximum((s1 + s2) / 2, 0.0))
    small = np.sqrt(np.maximum((s1 - s2) / 2, 0.0))
    big[~safe], small[~safe] = 1.0, 1.0
    return big, small


def _normals(corners: np.ndarray) -> np.ndarray:
    n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1), _EPS)[:, None]


def height_ratios(corners: np.ndarray) -> np.ndarray:
    """(m,) each triangle's height over its longest edge divided by that edge, for ``corners``
    (m, 3, 3): 0.87 equilateral, 0 collinear (a sliver covers no texture however it is posed)."""
    twice_area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    return twice_area / np.maximum(longest, _EPS) ** 2


# ---------------------------------------------------------------------------- per-face probe
class FaceQualityProbe:
    """Measures poses of one face (see the module docstring).

    Parameters
    ----------
    face : core.face.Face
        The rest face; its parts ``eyeball_l/r``, ``teeth_upper/lower`` are used when present.
    """

    def __init__(self, face):
        self.face = face
        tris = face.triangles
        n = face.n_vertices
        part_of = np.full(n, "", dtype=object)
        for name, idx in face.parts.items():
            part_of[idx] = name
        in_part = part_of != ""
        skin = ~in_part[tris].any(axis=1)
        self.skin_tris = tris[skin]
        rest = face.vertices
        self.welded = welded_vertices(rest)
        self._rest_frames = _local_frames(rest[self.skin_tris])
        self._rest_normals = _normals(rest[self.skin_tris])
        area = 0.5 * np.abs(self._rest_frames[:, 0, 0] * self._rest_frames[:, 1, 1])
        self._measurable = area > 1e-6 * max(np.median(area), _EPS)   # slivers have no direction

        def part_tris(*names):
            mask = np.zeros(n, dtype=bool)
            for name in names:
                if name in face.parts:
                    mask[face.parts[name]] = True
            return tris[mask[tris].all(axis=1)] if mask.any() else None

        self.teeth_tris = part_tris("teeth_upper", "teeth_lower")
        self.cavity_tris = part_tris("mouth_cavity")
        self.eyeball_tris = {side: part_tris(f"eyeball_{side[0]}") for side in ("left", "right")}
        self.eyeball_vertices = {side: face.parts.get(f"eyeball_{side[0]}") for side in ("left", "right")}

        names = set(face.landmark_names)
        centroids = rest[self.skin_tris].mean(axis=1)

        def region(a, b, scale):
            if not {a, b} <= names:
                return None
            pa, pb = face.landmark_position(a), face.landmark_position(b)
            centre, radius = (pa + pb) / 2, scale * np.linalg.norm(pa - pb)
            return self.skin_tris[np.linalg.norm(centroids - centre, axis=1) <= radius]

        # Lips: within 0.9 mouth widths of the mouth's centre (both lips, corners and philtrum).
        self.lip_tris = region("8.3", "8.4", 0.9)
        # Skin that can reach into the mouth cavity: within 1.5 mouth widths (cheeks, chin).
        self.mouth_skin_tris = region("8.3", "8.4", 1.5)
        # Lids: within 0.85 eye widths of each eye's centre (both lids and their folds).
        self.lid_tris = {"left": region("3.7", "3.11", 0.85), "right": region("3.8", "3.12", 0.85)}
        self._n_tris = max(len(tris), 1)
        self._rest_pairs: dict[str, np.ndarray | None] | None = None   # the rest face's, at the first measure

    def measure(self, vertices: np.ndarray, *, eyes: bool = False) -> PoseQuality:
        """Quality of the pose ``vertices`` ((n, 3) mm, the face's topology).

        ``eyes``: also measure eye openness (ray casts; ~50 ms per eye)."""
        folded, max_stretch, min_stretch = self.surface(vertices)

        pairs = self._crossing_pairs(vertices)
        if self._rest_pairs is None:
            self._rest_pairs = self._crossing_pairs(self.face.vertices)
        count = {what: None if keys is None else len(keys) for what, keys in pairs.items()}
        at_rest = {what: int(np.isin(keys, self._rest_pairs[what]).sum())
                   for what, keys in pairs.items() if keys is not None and len(keys)}
        openness = self.eye_openness(vertices) if eyes else {}
        return PoseQuality(count["lip"], count["lid"], count["teeth"], folded, max_stretch, min_stretch, openness,
                           count["mouth cavity"], {what: n for what, n in at_rest.items() if n})

    def _crossing_pairs(self, vertices: np.ndarray) -> dict[str, np.ndarray | None]:
        """Per kind ("lip", "lid", "teeth", "mouth cavity") the crossing triangle pairs of a pose as
        integer keys (a pair of the same triangles has the same key in every pose), None where the
        face has no such region."""
        def keys(tag: int, tris_a, tris_b=None) -> np.ndarray:
            ia, ib = intersecting_pairs(vertices, tris_a, tris_b, self.welded)
            return (tag * self._n_tris + ia.astype(np.int64)) * self._n_tris + ib

        out: dict[str, np.ndarray | None] = {"lip": None, "lid": None, "teeth": None, "mouth cavity": None}
        if self.lip_tris is not None:
            out["lip"] = keys(0, self.lip_tris)
            if self.teeth_tris is not None:
                out["teeth"] = keys(1, self.lip_tris, self.teeth_tris)
        if self.mouth_skin_tris is not None and self.cavity_tris is not None:
            out["mouth cavity"] = keys(2, self.mouth_skin_tris, self.cavity_tris)
        if all(t is not None for t in self.lid_tris.values()):
            found = []
            for k, (side, lid_tris) in enumerate(self.lid_tris.items()):
                found.append(keys(3 + 2 * k, lid_tris))
                if self.eyeball_tris[side] is not None:
                    found.append(keys(4 + 2 * k, lid_tris, self.eyeball_tris[side]))
            out["lid"] = np.concatenate(found)
        return out

    def surface(self, vertices: np.ndarray) -> tuple[int, float, float]:
        """(folded skin triangles, largest stretch, smallest stretch) of a pose: the cheap part of
        :meth:`measure` (a few ms at 54k vertices)."""
        corners = vertices[self.skin_tris]
        turned = np.einsum("ij,ij->i", _normals(corners), self._rest_normals) < 0
        big, small = principal_stretches(self._rest_frames, corners)
        big, small = big[self._measurable], small[self._measurable]
        return (int((turned & self._measurable).sum()), float(big.max(initial=1.0)),
                float(small.min(initial=1.0)))

    def surface_holds(self, vertices: np.ndarray) -> bool:
        """No folded skin triangle and every stretch within [MIN_STRETCH, MAX_STRETCH]."""
        folded, big, small = self.surface(vertices)
        return not folded and big <= MAX_STRETCH and small >= MIN_STRETCH

    def eye_openness(self, vertices: np.ndarray) -> dict[str, float]:
        """Per eye, the share of its front-facing eyeball vertices that a ray toward the viewer
        (+z) leaves without hitting the skin around that eye."""
        import trimesh   # core dependency; imported here as only this check needs rays

        out = {}
        for side, lid_tris in self.lid_tris.items():
            ball = self.eyeball_vertices[side]
            if ball is None or lid_tris is None:
                continue
            centre = vertices[ball].mean(axis=0)
            outward = vertices[ball] - centre
            front = ball[outward[:, 2] > 0.3 * np.linalg.norm(outward, axis=1)]
            if not len(front):
                continue
            skin = trimesh.Trimesh(vertices, lid_tris, process=False)
            origins = vertices[front] + np.array([0.0, 0.0, 1e-3])
            directions = np.tile([0.0, 0.0, 1.0], (len(front), 1))
            hidden = skin.ray.intersects_any(origins, directions)
            out[side] = float(1.0 - hidden.mean())
        return out
