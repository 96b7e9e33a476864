"""Dense correspondence by subdivision and projection (thesis A §3.4), and carrying an animation
of the canonical face back to the full-resolution scan.

:func:`dense_correspondence` places a landmark template ("mpeg4_80" or "a48") on a scan from its
landmarks and subdivides it (the template's steps: linear, linear, Loop [, Loop]); after each
step the new vertices move along their normals onto the scan. This is the procedure of
``core.layers.fap.template.densify`` (same subdivision, creases, boundary and eye rules, same
``DenseTemplate`` result) with two changes, and it stays numerically the same algorithm:

* rays are cast with Embree (``trimesh.ray.ray_pyembree``, embreex) — one scene per scan, about
  0.1 s for 100k triangles, then millions of rays per second; without embreex it falls back to
  ``core.surface_query.TriangleSet.ray_nearest`` (reported in ``Registration.engine``);
* closest points (snapped outline/mouth/eye-margin vertices and ray misses) use
  ``TriangleSet.closest`` instead of trimesh's proximity query.

``densify`` itself is not called because it is 4x slower (trimesh closest points) and cannot
place a template without extras (a48): see the module notes in the report.

Choices the thesis leaves open (written down here):

* A ray counts when it hits within 1.5 median edge lengths, in either direction along the normal,
  on a triangle facing the same way (no far side); otherwise the vertex takes the closest
  surface point and is counted in ``fallbacks``.
* The mouth stays an opening (the template's inner-lip loop is a boundary); the eyes are covered
  by the template's eye-opening triangles, projected onto whatever the scan has there (eyeball or
  lid), because an annulus is the only topology the thesis's counts allow (see the templates).
* After projection the canonical mesh is fitted onto the scan without folds
  (:func:`fit_without_folds`, ``core.registration.fold_free``): from the template registered on
  the default face, ARAP-regularised, landmarks as soft targets; a landmark that would turn a
  triangle over stays short of where it was given (``Registration.landmark_shift``, reported).
  A landmark that contradicts its template neighbours by most of an edge (turning their
  triangles over: open mouths' lower-lip points detected on the upper lip) is released first
  (``core.registration.consistency``): no target, the scan and its neighbours place it; named in
  the report, its shift from where it was given counted like the others'.
* Texture coordinates come from the scan at each vertex's closest point; the texture is the scan's.
* Carry-back: each scan vertex is bound to its closest canonical surface point (triangle,
  barycentric); it moves by the interpolated displacement of that triangle, so the rest pose is
  reproduced exactly. Vertices farther than ``near_mm`` from the canonical surface (ears, neck,
  hair beyond the template's outline) fade to zero motion over ``fade_mm``.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse

from core.face import Face, FaceMetadata, SurfacePoint, vertex_normals
from core.layers.fap.template import DenseTemplate, TemplateError, _edge_vertices, skin_triangles
from core.subdivision import subdivide
from core.surface_query import TriangleSet
from core.registration.folds import (COLLAPSED_AREA_RATIO, aligned_reference, folded_triangles, forced_folds,
                                     triangle_normals, unfold)
from core.registration.templates import TEMPLATE_NAMES, get_template


class CorrespondenceError(ValueError):
    """Dense correspondence cannot be computed (missing landmarks, empty scan)."""


# ------------------------------------------------------------------ rays
class SurfaceRays:
    """Ray and closest-point queries on a subset of a face's triangles.

    ``engine`` is "embree" when embreex is available, else "numpy" (TriangleSet, much slower for
    long rays but exact for the short normal rays used here)."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, triangle_ids: np.ndarray | None = None):
        self.vertices = np.asarray(vertices, float)
        ids = np.arange(len(triangles)) if triangle_ids is None else np.asarray(triangle_ids, np.int64)
        self.ids = ids
        self.triangles = np.asarray(triangles, np.int64)[ids]
        self._set = None
        self.engine = "numpy"
        self._embree = None
        try:
            import trimesh
            from trimesh.ray.ray_pyembree import RayMeshIntersector

            mesh = trimesh.Trimesh(self.vertices, self.triangles, process=False, validate=False)
            self._embree = RayMeshIntersector(mesh)
            self._normals = np.asarray(mesh.face_normals)
            self.engine = "embree"
        except Exception:  # noqa: BLE001 - embreex missing or broken: use the numpy path
            self._embree = None

    @property
    def triangle_set(self) -> TriangleSet:
        if self._set is None:
            self._set = TriangleSet(self.vertices, self.triangles)
        return self._set

    def closest(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (k, 3), face triangle ids (k,), barycentric (k, 3))."""
        # Query points lie on or near the surface: the 24 nearest centroids hold the answer.
        pos, tri, bary = self.triangle_set.closest(np.asarray(points, float).reshape(-1, 3), k=24, widen=False)
        return pos, self.ids[tri], bary

    def first_hits(self, origins, directions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hit of each ray: (positions (k, 3), local triangle (k,) or -1, hit (k,) bool). Embree only."""
        o = np.asarray(origins, float).reshape(-1, 3)
        d = np.asarray(directions, float).reshape(-1, 3)
        pos = np.zeros_like(o)
        tri = np.full(len(o), -1, np.int64)
        if len(o):
            tri = np.asarray(self._embree.intersects_first(o, d), np.int64)
            hit = tri >= 0
            # Hit point from the ray-plane intersection (cheaper than trimesh's location query).
            n = self._normals[tri[hit]]
            a = self.vertices[self.triangles[tri[hit], 0]]
            den = np.einsum("ij,ij->i", d[hit], n)
            t = np.einsum("ij,ij->i", a - o[hit], n) / np.where(np.abs(den) > 1e-300, den, 1e-300)
            pos[hit] = o[hit] + t[:, None] * d[hit]
        return pos, tri, tri >= 0

    def ray_nearest(self, points, directions, max_distance: float):
        """Nearest hit along +-direction within max_distance on a triangle facing the same way.

        Returns (positions (k, 3), face triangle ids (k,) or -1, barycentric (k, 3), hit (k,))."""
        p = np.asarray(points, float).reshape(-1, 3)
        d = np.asarray(directions, float).reshape(-1, 3)
        d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
        if self._embree is None:
            pos, tri, bary, hit = self.triangle_set.ray_nearest(p, d, max_distance)
            return pos, np.where(hit, self.ids[np.maximum(tri, 0)], -1), bary, hit
        # Two rays from just behind the point (forward and backward), the nearer valid hit wins.
        eps = 1e-6 * max(1.0, float(np.abs(self.vertices).max()))
        best = np.full(len(p), np.inf)
        pos, tri = p.copy(), np.full(len(p), -1, np.int64)
        for sign in (1.0, -1.0):
            hp, ht, ok = self.first_hits(p - sign * eps * d, sign * d)
            dist = np.linalg.norm(hp - p, axis=1)
            ok &= dist <= max_distance
            ok &= np.einsum("ij,ij->i", self._normals[np.maximum(ht, 0)], d) > 0
            better = ok & (dist < best)
            best[better], pos[better], tri[better] = dist[better], hp[better], ht[better]
        hit = tri >= 0
        bary = np.zeros((len(p), 3))
        if hit.any():
            bary[hit] = _barycentric(self.vertices[self.triangles[tri[hit]]], pos[hit])
        return pos, np.where(hit, self.ids[np.maximum(tri, 0)], -1), bary, hit


def _barycentric(corners: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(k, 3) barycentric of points (k, 3) in triangles corners (k, 3, 3), clipped to the triangle."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) > 1e-300, den, 1e-300)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    bary = np.clip(np.column_stack([1 - v - w, v, w]), 0.0, None)
    return bary / np.maximum(bary.sum(1, keepdims=True), 1e-300)


# ------------------------------------------------------------------ placement
def template_base_positions(template_name: str, positions: dict[str, np.ndarray], skin: SurfaceRays) -> np.ndarray:
    """(n_base, 3) mm: the template's base points from landmark positions (extras computed and snapped)."""
    base = get_template(template_name).base
    missing = [p for p in base.feature_points if p not in positions]
    if missing:
        raise CorrespondenceError(
            f"dense correspondence with template {template_name!r} needs {len(base.feature_points)} landmarks; "
            f"{len(missing)} are missing ({', '.join(missing[:8])}{' ...' if len(missing) > 8 else ''}). "
            "Detect them (detect_landmarks) or mark them with the landmark picker first")
    pos = {p: np.asarray(positions[p], float) for p in base.feature_points}
    for name, weights in base.extras.items():  # extras only refer to earlier points
        pos[name] = sum(w * pos[k] for k, w in weights.items())
    if base.extras:
        names = list(base.extras)
        snapped, _, _ = skin.closest(np.array([pos[e] for e in names]))
        pos.update(zip(names, snapped))
    return np.array([pos[p] for p in base.points])


@dataclass
class Projection:
    """The dense template on a scan: ``dense`` (core.layers.fap.template.DenseTemplate) plus where each
    vertex lies on the scan (triangle (N,), barycentric (N, 3)), fallbacks per step and timings."""

    dense: DenseTemplate
    scan_triangle: np.ndarray
    scan_bary: np.ndarray
    fallbacks: list[int]
    engine: str
    seconds: dict = field(default_factory=dict)


def project_template(face: Face, template_name: str, positions: dict[str, np.ndarray], *,
                     steps=None, rays: tuple[SurfaceRays, SurfaceRays] | None = None) -> Projection:
    """Place template ``template_name`` on ``face`` at landmark ``positions`` (name -> (3,) mm)
    and subdivide/project it (see the module docstring). ``rays`` = (skin, whole) may be passed
    to reuse Embree scenes built for the same face."""
    t0 = time.perf_counter()
    template = get_template(template_name).base
    steps = tuple(steps) if steps is not None else template.steps
    if rays is None:
        rays = surfaces_of(face)
    skin, whole = rays
    t1 = time.perf_counter()
    base = template_base_positions(template_name, positions, skin)
    n_base = len(base)
    _, base_tri, base_bary = skin.closest(base)
    v, t = base, template.triangles
    coords = np.eye(n_base)
    creases = template.crease_edges()
    eye_tris = sorted(template.eye_opening_triangles)
    face_tri = base_tri
    bary_all = base_bary
    fallbacks, counts = [], [(len(v), len(t))]
    for scheme in steps:
        sub = subdivide(v, t, scheme=scheme, creases=creases, params=coords)
        v, t, coords, creases = sub.vertices, sub.triangles, sub.params, sub.creases
        moving = np.arange(n_base, len(v))
        edge = _edge_vertices(t, creases, len(v))
        staged = DenseTemplate(template, v, t, coords, np.full(len(v), -1))
        in_eye = staged.in_base_triangles(eye_tris) & ~edge if eye_tris else np.zeros(len(v), bool)
        normals = vertex_normals(v, t)
        spacing = float(np.median(np.linalg.norm(v[t[:, 0]] - v[t[:, 1]], axis=1)))
        new_v, new_tri, new_bary = v.copy(), np.full(len(v), -1), np.zeros((len(v), 3))
        rayed = moving[~edge[moving]]
        missed = 0
        for surface, sel in ((skin, rayed[~in_eye[rayed]]), (whole, rayed[in_eye[rayed]])):
            if not len(sel):
                continue
            pos, tri, bary, hit = surface.ray_nearest(v[sel], normals[sel], 1.5 * spacing)
            if (~hit).any():
                pos[~hit], tri[~hit], bary[~hit] = surface.closest(v[sel][~hit])
            missed += int((~hit).sum())
            new_v[sel], new_tri[sel], new_bary[sel] = pos, tri, bary
        snap = moving[edge[moving]]
        if len(snap):
            new_v[snap], new_tri[snap], new_bary[snap] = skin.closest(v[snap])
        new_v[:n_base], new_tri[:n_base], new_bary[:n_base] = base, base_tri, base_bary
        v, face_tri, bary_all = new_v, new_tri, new_bary
        fallbacks.append(missed)
        counts.append((len(v), len(t)))
    dense = DenseTemplate(template, v, t, coords, face_tri, counts=counts, fallbacks=fallbacks)
    return Projection(dense, face_tri, bary_all, fallbacks, skin.engine,
                      {"scene_s": t1 - t0, "project_s": time.perf_counter() - t1})


def surfaces_of(face: Face) -> tuple[SurfaceRays, SurfaceRays]:
    """(skin, whole) ray surfaces of ``face``; the same object twice when the face has no parts."""
    whole = SurfaceRays(face.vertices, face.triangles)
    if not face.parts:
        return whole, whole
    return SurfaceRays(face.vertices, face.triangles, skin_triangles(face)), whole


# ------------------------------------------------------------------ canonical face
@dataclass
class Registration:
    """A scan registered to a template.

    face : the canonical Face (same vertex count and meaning for every scan registered with this
        template: 4560 for mpeg4_80, 9648 for a48), uv and texture carried from the scan, the
        template's detected points as landmarks (base vertex i is canonical vertex i).
    fallbacks : vertices that took the closest point because their normal ray missed (all steps).
    projection : the Projection (dense template, where each canonical vertex lies on the scan).
    scan : the scan it was registered on (for :meth:`carry_back`).
    report : human-readable lines (fallbacks, engine, timings).
    landmark_shift : (n_base,) mm how far the fit left each given landmark from where it was given.
    released : landmarks that contradicted their template neighbours, placed by the fit instead
        (``core.registration.consistency``).
    """

    face: Face
    fallbacks: int
    projection: Projection
    scan: Face
    template: str
    report: list[str] = field(default_factory=list)
    _carry: "CarryBack | None" = None
    landmark_shift: np.ndarray = field(default_factory=lambda: np.zeros(0))
    released: list[str] = field(default_factory=list)

    def distances_to_scan(self) -> np.ndarray:
        """(T,) mm: how far each canonical triangle's centroid lies from the scan's surface (the fit's
        closeness; the issue's goal is mean <= 0.5 mm, 95th percentile <= 2 mm)."""
        c = self.face.vertices[self.face.triangles].mean(axis=1)
        closest, _, _ = TriangleSet(self.scan.vertices, self.scan.triangles).closest(c)
        return np.linalg.norm(closest - c, axis=1)

    def folded(self) -> np.ndarray:
        """(T,) bool: canonical triangles collapsed or facing the other way than on a face
        (``core.registration.folds.folded_triangles`` against :func:`reference_normals`)."""
        normals = reference_normals(self.template, self.face.vertices)
        if normals is None:     # no reference for this template: collapsed triangles only
            normals = triangle_normals(self.face.vertices, self.face.triangles)
        return folded_triangles(self.face.vertices, self.face.triangles, normals)

    def forced(self) -> np.ndarray:
        """(T,) bool: canonical triangles inside a template triangle the landmarks turn over (they
        must fold while the landmarks stay: ``core.registration.folds.forced_folds``)."""
        found = _reference_mesh(self.template)
        if found is None or len(found[0]) != self.face.n_vertices:
            return np.zeros(self.face.n_triangles, bool)
        base = get_template(self.template).base
        reference = aligned_reference(found[0], self.face.vertices, len(base.points))
        return forced_folds(self.face.vertices, reference, base.triangles, self.face.n_triangles)

    def summary(self) -> str:
        """One line: canonical size, folded triangles, closeness to the scan, normal rays that missed."""
        d = self.distances_to_scan()
        folded = self.folded()
        forced = int((folded & self.forced()).sum())
        return (f"{self.face.n_vertices} vertices / {self.face.n_triangles} triangles; {int(folded.sum())} folded "
                f"({forced} inside template triangles the landmarks turn over); distance to the scan mean "
                f"{d.mean():.2f} mm, 95th percentile {np.percentile(d, 95):.2f} mm; "
                f"{self.fallbacks} vertices took the closest point (normal ray missed)"
                + (f"; landmarks moved by the fit up to {self.landmark_shift.max():.2f} mm"
                   if len(self.landmark_shift) else ""))

    def carry_back(self, **kwargs) -> "CarryBack":
        """The CarryBack binding the scan's vertices to this canonical face (built once)."""
        if self._carry is None or kwargs:
            self._carry = CarryBack(bind_scan(self.scan, self.face, **kwargs))
        return self._carry


UNTANGLE_ROUNDS = 8


def untangle(scan: Face, projection: Projection, template_name: str) -> tuple[Projection, int, int]:
    """(projection, vertices moved, triangles still collapsed): vertices that the projection put onto
    (nearly) the same spot as a neighbour — zero-area canonical triangles, e.g. in the mouth corners
    or a scan's folds — are moved to the mean of their neighbours and snapped back onto the scan,
    a few rounds (the base vertices, which are the landmarks, stay)."""
    v = np.array(projection.dense.vertices, float)
    t = projection.dense.triangles
    n_base = len(get_template(template_name).base.points)

    def collapsed() -> np.ndarray:
        c = v[t]
        area = np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
        return area < COLLAPSED_AREA_RATIO * np.median(area)

    bad = collapsed()
    if not bad.any():
        return projection, 0, 0
    adjacency, degree = _adjacency(t, len(v))
    surface = TriangleSet(scan.vertices, scan.triangles)
    scan_triangle = np.array(projection.scan_triangle)
    scan_bary = np.array(projection.scan_bary, float)
    moved: set[int] = set()
    for _ in range(UNTANGLE_ROUNDS):
        idx = np.unique(t[bad])
        idx = idx[idx >= n_base]
        if not len(idx):
            break
        mean = (adjacency[idx] @ v) / degree[idx, None]
        pos, tri, bary = surface.closest(mean)
        v[idx], scan_triangle[idx], scan_bary[idx] = pos, tri, bary
        moved.update(idx.tolist())
        bad = collapsed()
        if not bad.any():
            break
    for _ in range(UNTANGLE_ROUNDS if bad.any() else 0):
        # Where the scan itself folds, snapping brings neighbours back together: leave these few
        # vertices at their neighbours' mean, just off the surface (their uv stays the closest point's).
        idx = np.unique(t[bad])
        idx = idx[idx >= n_base]
        if not len(idx):
            break
        v[idx] = (adjacency[idx] @ v) / degree[idx, None]
        moved.update(idx.tolist())
        bad = collapsed()
        if not bad.any():
            break
    dense = dataclasses.replace(projection.dense, vertices=v, face_triangle=scan_triangle)
    return (dataclasses.replace(projection, dense=dense, scan_triangle=scan_triangle, scan_bary=scan_bary),
            len(moved), int(bad.sum()))


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """The boundary of a triangle mesh as ordered vertex loops, each following the triangles'
    orientation (a boundary edge is a directed edge whose reverse no triangle has)."""
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    n = int(triangles.max()) + 1
    edges = scipy.sparse.csr_matrix((np.ones(len(directed)), (directed[:, 0], directed[:, 1])), shape=(n, n))
    boundary = directed[np.asarray(edges[directed[:, 1], directed[:, 0]]).ravel() == 0]
    following = dict(zip(boundary[:, 0].tolist(), boundary[:, 1].tolist()))
    loops, seen = [], set()
    for start in following:            # a few hundred boundary vertices, once per registration
        if start in seen:
            continue
        loop = [start]
        seen.add(start)
        while following.get(loop[-1], start) != start and following[loop[-1]] not in seen:
            loop.append(following[loop[-1]])
            seen.add(loop[-1])
        loops.append(np.array(loop, np.int64))
    return loops


def _catmull_rom(p0, p1, p2, p3, fraction: np.ndarray) -> np.ndarray:
    """(k, 3) points of the centripetal Catmull-Rom segment p1 -> p2 at ``fraction`` (k,) in [0, 1]."""
    t1 = np.linalg.norm(p1 - p0) ** 0.5 + 1e-9
    t2 = t1 + np.linalg.norm(p2 - p1) ** 0.5 + 1e-9
    t3 = t2 + np.linalg.norm(p3 - p2) ** 0.5 + 1e-9
    t = (t1 + fraction * (t2 - t1))[:, None]
    a1 = ((t1 - t) * p0 + t * p1) / t1
    a2 = ((t2 - t) * p1 + (t - t1) * p2) / (t2 - t1)
    a3 = ((t3 - t) * p2 + (t - t2) * p3) / (t3 - t2)
    b1 = ((t2 - t) * a1 + t * a2) / t2
    b2 = ((t3 - t) * a2 + (t - t1) * a3) / (t3 - t1)
    return ((t2 - t) * b1 + (t - t1) * b2) / (t2 - t1)


def _forehead_arc(v: np.ndarray, top: int, sides: set[int], start: int, end: int,
                  fraction: np.ndarray) -> np.ndarray:
    """(k, 3) points of the quarter ellipse between a hairline side point (11.2 / 11.3) and its top
    (11.1): rising straight up from the side, level at the top, like a forehead (a spline through
    the three points still peaks at 11.1, whose neighbours sit low at the temples)."""
    left, right = (v[i] for i in sorted(sides))
    up = v[top] - (left + right) / 2.0
    up /= max(float(np.linalg.norm(up)), 1e-12)
    side = v[start] if start != top else v[end]
    rise = float(np.dot(v[top] - side, up)) * up
    centre = v[top] - rise                                  # level with the side point, under the top
    angle = (fraction if start != top else 1.0 - fraction)[:, None] * (np.pi / 2)
    return centre + (side - centre) * np.cos(angle) + rise * np.sin(angle)


#: The outline passes a landmark next to it (the third corner of an outline template triangle) at
#: least this fraction of that landmark's distance from the outline on the reference.
OUTLINE_CLEARANCE = 0.5


def _around_inner_landmark(v: np.ndarray, prior: np.ndarray, start: int, end: int, fraction: np.ndarray,
                           curve: np.ndarray, third: dict) -> np.ndarray:
    """(k, 3) ``curve`` (the outline from landmark ``start`` to ``end`` at ``fraction``) pushed out
    where the landmark inside it lies beyond it: on generated faces the brow's outer end 4.5 / 4.6
    lies 9 mm outside the line from the hairline side 11.3 / 11.2 to the temple 10.9 / 10.10 (the
    default face has it 3.5 mm inside), so their template triangle turned over and folded. The
    curve moves outward (in the plane of that triangle on the aligned reference ``prior``) along a
    smooth bump peaking at the landmark, until the landmark is ``OUTLINE_CLEARANCE`` of its
    reference distance inside; the caller snaps it onto the scan."""
    inner = third.get((start, end))
    if inner is None:
        return curve
    chord, chord_ref = v[end] - v[start], prior[end] - prior[start]
    normal = np.cross(prior[end] - prior[start], prior[inner] - prior[start])     # reference triangle's normal
    across = np.cross(normal, chord)
    across /= max(float(np.linalg.norm(across)), 1e-12)                           # in-plane, towards the inside
    across_ref = np.cross(normal, chord_ref)
    depth_ref = float(np.dot(prior[inner] - prior[start], across_ref)) / max(float(np.linalg.norm(across_ref)), 1e-12)
    depth = float(np.dot(v[inner] - v[start], across))
    at = float(np.clip(np.dot(v[inner] - v[start], chord) / max(float(np.dot(chord, chord)), 1e-12), 0.05, 0.95))
    offset = (curve - v[start]) @ across                      # where the curve runs across the chord
    near = int(np.argmin(np.abs(fraction - at)))
    push = offset[near] - (depth - OUTLINE_CLEARANCE * depth_ref)
    if depth_ref <= 0 or push <= 0:
        return curve
    ramp = np.where(fraction < at, fraction / at, (1.0 - fraction) / (1.0 - at))
    bump = ramp * ramp * (3.0 - 2.0 * ramp)                   # smoothstep up to the landmark and down again
    return curve - push * bump[:, None] * across[None, :]


def rounded_outline(scan: Face, projection: Projection, template_name: str) -> dict[int, np.ndarray]:
    """{canonical vertex: (3,) mm on the scan}: the canonical face's outer outline as a smooth curve
    through the template's outline landmarks (centripetal Catmull-Rom, each vertex at its arc-length
    fraction between its two landmarks), snapped onto the scan. The template's outline is straight
    between its landmarks, so every registered face had a pointed forehead at 11.1 (and corners at
    the temples and the jaw); the fit (:func:`fit_without_folds`) aims at these positions."""
    v = np.asarray(projection.dense.vertices, float)
    n_base = len(get_template(template_name).base.points)
    loops = boundary_loops(np.asarray(projection.dense.triangles))
    if not loops:
        return {}
    outline = max(loops, key=len)
    at = np.nonzero(outline < n_base)[0]              # the outline's landmarks, in loop order
    if len(at) < 4:
        return {}
    chord = np.linalg.norm(v[np.roll(outline, -1)] - v[outline], axis=1)
    base = get_template(template_name).base
    names = set(base.points)
    found = _reference_mesh(template_name)
    prior = aligned_reference(found[0], v, n_base) if found is not None and len(found[0]) == len(v) else None
    third = {}        # base outline edge (a, b) -> the third landmark of its base triangle
    for a, b, c in base.triangles.tolist():
        for e0, e1, e2 in ((a, b, c), (b, c, a), (c, a, b)):
            third[(e0, e1)] = third[(e1, e0)] = e2
    top = base.index("11.1") if "11.1" in names else None
    sides = {base.index(p) for p in ("11.2", "11.3") if p in names}
    if len(sides) != 2:
        top = None
    targets: dict[int, np.ndarray] = {}
    for k in range(len(at)):
        i, j = at[k], at[(k + 1) % len(at)]
        between = (np.arange(i + 1, j) if j > i else np.arange(i + 1, j + len(outline))) % len(outline)
        if not len(between):
            continue
        steps = chord[np.concatenate([[i], between])]
        walked = np.cumsum(steps)
        fraction = walked[:-1] / max(walked[-1], 1e-12)      # arc length from landmark i, over i -> j
        p0, p1, p2, p3 = (v[outline[at[(k + d) % len(at)]]] for d in (-1, 0, 1, 2))
        ends = {int(outline[i]), int(outline[j])}
        if top is not None and top in ends and ends & sides:
            curve = _forehead_arc(v, top, sides, int(outline[i]), int(outline[j]), fraction)
        else:
            curve = _catmull_rom(p0, p1, p2, p3, fraction)
        if prior is not None:
            curve = _around_inner_landmark(v, prior, int(outline[i]), int(outline[j]), fraction, curve, third)
        for vertex, point in zip(outline[between].tolist(), curve):
            targets[vertex] = point
    if not targets:
        return {}
    ids = list(targets)
    snapped, _, _ = TriangleSet(scan.vertices, scan.triangles).closest(np.array([targets[i] for i in ids]))
    return dict(zip(ids, snapped))


@functools.cache
def _reference_mesh(template_name: str) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices (N, 3), triangles) of ``template_name`` registered on Mimica's default face: a
    fold-free face of that topology, the start and shape prior of :func:`fit_without_folds`; None when
    the default face lacks the template's landmarks."""
    from core.default_face import load_default_face
    from core.registration.templates import template_positions

    face = load_default_face(full_head=False)
    try:
        positions = template_positions(face, template_name)   # a48's derived points from the MPEG-4 ones
        proj = project_template(face, template_name, positions)
    except (ValueError, KeyError):   # TemplateError / CorrespondenceError: landmarks it does not have
        return None
    proj, _, _ = untangle(face, proj, template_name)
    v, t = np.array(proj.dense.vertices, float), np.array(proj.dense.triangles)
    # Projection folds the template even on the default face (167 triangles facing against the
    # face's surface: nostrils, nose tip, eye corners); as the prior and the measure of folds it
    # must face the way the face does. Those patches get a harmonic fill, put back on the face
    # where that keeps them facing like its surface (167 -> 32 left, in the nostrils' sliver
    # template triangles, 9.5-9.1-9.3 has a 2.6 degree corner).
    surface = TriangleSet(face.vertices, face.triangles)
    _, tri, _ = surface.closest(v[t].mean(axis=1))
    held = _base_mask(len(v), len(get_template(template_name).base.points))
    v, _, _, _ = unfold(v, t, None, face.face_normals[tri], held, surface)
    return v, t


def _adjacency(triangles: np.ndarray, n: int) -> tuple[scipy.sparse.csr_matrix, np.ndarray]:
    """(n, n) 0/1 vertex adjacency of a triangle mesh and each vertex's degree."""
    rows = np.concatenate([triangles[:, 0], triangles[:, 1], triangles[:, 2], triangles[:, 1], triangles[:, 2],
                           triangles[:, 0]])
    cols = np.concatenate([triangles[:, 1], triangles[:, 2], triangles[:, 0], triangles[:, 0], triangles[:, 1],
                           triangles[:, 2]])
    adjacency = scipy.sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    adjacency.data[:] = 1.0
    return adjacency, np.asarray(adjacency.sum(axis=1)).ravel()


#: A landmark the fit moves farther than this (mm) from where it was given is named in the report.
LANDMARK_SHIFT_NOTE_MM = 1.0
#: Weight of the mouth rim's targets (a landmark's is fold_free.LANDMARK_WEIGHT, a closest point's 1).
RIM_WEIGHT = 10.0


def fit_without_folds(scan: Face, projection: Projection, template_name: str,
                      held: dict[int, np.ndarray] | None = None
                      ) -> tuple[Projection, int, int, np.ndarray, list[str]]:
    """(projection, triangles turned over by projection, after the fit (0), landmark shift (n_base,) mm,
    released landmarks): the canonical mesh fitted onto the scan from the fold-free reference
    (:func:`core.registration.fold_free.fold_free_fit`): the landmarks (the projection's base
    vertices) and ``held`` (the rounded outline) are soft targets, the projection's points the first
    targets of the others, then their closest scan points. Landmarks that turn template triangles
    over (:func:`core.registration.consistency.inconsistent_landmarks`) are released: no target,
    their neighbours' prediction as first target, then the scan like any vertex. Without a
    reference for the template the projection is returned as it is."""
    from core.registration.consistency import inconsistent_landmarks
    from core.registration.fold_free import fold_free_fit

    v = np.array(projection.dense.vertices, float)
    t = projection.dense.triangles
    base = get_template(template_name).base
    n_base = len(base.points)
    found = _reference_mesh(template_name)
    if found is None or len(found[0]) != len(v) or not np.array_equal(found[1], t):
        return projection, 0, 0, np.zeros(n_base), []
    given = np.array([name not in base.extras for name in base.points])
    outline = np.array([name in base.outline for name in base.points])
    released, corrected = inconsistent_landmarks(v[:n_base], aligned_reference(found[0][:n_base], v, n_base),
                                                 base.triangles, given, outline)
    # The prior faces the way the consistent landmarks say: aligned with the released ones at
    # their prediction (where the fit will put them, about), so the fold measure's alignment on
    # the result (Registration.folded) is the one the fit guarded against.
    prior = aligned_reference(found[0], corrected, n_base)
    before = int(folded_triangles(v, t, triangle_normals(prior, t)).sum())
    first = v.copy()
    first[released] = corrected[released]
    # The detected landmarks are soft targets; the template's extras (points computed from them)
    # and the released landmarks are free like any other vertex.
    targets = {i: v[i] for i in np.nonzero(given)[0].tolist() if i not in released}
    # The mouth's rim (the inner lip line; every boundary loop but the outline) stays where
    # projection snapped it: the scan is cut there to open the mouth (core.registration.scan_mouth).
    loops = sorted(boundary_loops(np.asarray(t)), key=len)[:-1]
    rim = {i: RIM_WEIGHT for i in (np.concatenate(loops).tolist() if loops else [])
           if i not in targets and i not in released}
    targets.update({i: v[i] for i in rim})
    targets.update(held or {})
    surface = TriangleSet(scan.vertices, scan.triangles)
    fit = fold_free_fit(prior, t, targets, first, surface, scan.face_normals, target_weight=rim)
    x = fit.vertices
    shift = np.linalg.norm(x[:n_base] - v[:n_base], axis=1)
    shift[~given] = 0.0
    after = int(folded_triangles(x, t, triangle_normals(prior, t)).sum())
    tri, bary = surface.closest(x, k=24, widen=False)[1:]
    dense = dataclasses.replace(projection.dense, vertices=x, face_triangle=tri)
    return (dataclasses.replace(projection, dense=dense, scan_triangle=tri, scan_bary=bary), before, after,
            shift, [base.points[i] for i in released])


def _base_mask(n: int, n_base: int) -> np.ndarray:
    mask = np.zeros(n, bool)
    mask[:n_base] = True
    return mask


def reference_normals(template_name: str, vertices: np.ndarray) -> np.ndarray | None:
    """(T, 3) how each canonical triangle faces on a face: the triangle's normal on the (fold-free)
    reference mesh brought onto ``vertices``' landmarks by a similarity; None when the template has
    no reference (see :func:`_reference_mesh`)."""
    found = _reference_mesh(template_name)
    if found is None or len(found[0]) != len(vertices):
        return None
    n_base = len(get_template(template_name).base.points)
    return triangle_normals(aligned_reference(found[0], vertices, n_base), found[1])


def canonical_face(scan: Face, projection: Projection, template_name: str) -> Face:
    """The canonical Face of a projection (see :class:`Registration`)."""
    dense = projection.dense
    uv = None
    if scan.uv is not None:
        uv = np.einsum("kj,kjd->kd", projection.scan_bary, scan.uv[scan.triangles[projection.scan_triangle]])
    colours = None
    if scan.vertex_colors is not None:
        c = np.einsum("kj,kjd->kd", projection.scan_bary,
                      scan.vertex_colors[scan.triangles[projection.scan_triangle]].astype(float))
        colours = np.clip(np.round(c), 0, 255).astype(np.uint8)
    t = dense.triangles
    landmarks = _base_vertex_landmarks(template_name, t)
    meta = FaceMetadata(source=scan.metadata.source, units="mm",
                        notes=[f"registered to template {template_name} ({len(dense.vertices)} vertices)"],
                        name=f"{scan.metadata.name} ({template_name})")
    return Face(dense.vertices, t, uv=uv, texture=scan.texture if uv is not None else None,
                vertex_colors=colours, landmarks=landmarks, metadata=meta)


def _base_vertex_landmarks(template_name: str, triangles: np.ndarray) -> dict[str, SurfacePoint]:
    """The template's landmarks on a canonical face: base vertex i keeps index i, so a landmark is
    that vertex, as a corner of the first triangle using it."""
    tpl = get_template(template_name)
    n_base = len(tpl.base.points)
    first_tri = np.full(n_base, -1)
    corner = np.zeros(n_base, np.int64)
    for k in range(3):
        ids = np.nonzero(triangles[:, k] < n_base)[0]
        vv = triangles[ids, k]
        unset = first_tri[vv] < 0
        first_tri[vv[unset]], corner[vv[unset]] = ids[unset], k
    landmarks = {}
    for name in tpl.detected:
        i = tpl.base.index(name)
        bary = [0.0, 0.0, 0.0]
        bary[corner[i]] = 1.0
        landmarks[name] = SurfacePoint(int(first_tri[i]), tuple(bary))
    return landmarks


@functools.lru_cache(maxsize=None)
def canonical_triangles(template_name: str) -> np.ndarray:
    """(T, 3) triangles of every canonical face of ``template_name`` (they depend on the template's
    subdivision steps only, not on the scan)."""
    template = get_template(template_name).base
    v = np.random.default_rng(0).random((len(template.points), 3))  # any non-degenerate positions
    t, creases, coords = template.triangles, template.crease_edges(), np.eye(len(v))
    for scheme in template.steps:
        sub = subdivide(v, t, scheme=scheme, creases=creases, params=coords)
        v, t, coords, creases = sub.vertices, sub.triangles, sub.params, sub.creases
    t.setflags(write=False)
    return t


def canonical_template_of(n_vertices: int, triangles: np.ndarray) -> str | None:
    """The template whose canonical faces have exactly this vertex count and these triangles, else
    None (compared by size first: cheap for every other mesh). For ``load_face(keep_topology=)``."""
    for name in TEMPLATE_NAMES:
        size = _CANONICAL_SIZES.get(name)
        if size is not None and size != (n_vertices, len(triangles)):
            continue
        expected = canonical_triangles(name)
        _CANONICAL_SIZES[name] = (int(expected.max()) + 1, len(expected))
        if _CANONICAL_SIZES[name] == (n_vertices, len(triangles)) and np.array_equal(triangles, expected):
            return name
    return None


_CANONICAL_SIZES: dict[str, tuple[int, int]] = {}   # template -> (vertices, triangles) of its canonical faces


def load_face_or_canonical(path, **kwargs) -> Face:
    """``core.formats.mesh_io.load_face`` for a file that may be a saved canonical face: its
    triangles are kept as they are and its landmarks restored (:func:`with_canonical_landmarks`)."""
    from core.formats.mesh_io import load_face

    return with_canonical_landmarks(load_face(path, keep_topology=canonical_template_of, **kwargs))


def with_canonical_landmarks(face: Face) -> Face:
    """``face`` with its template landmarks restored when it is a canonical face saved without them
    (mesh files carry no landmarks; same vertex count and triangles as a template's canonical
    faces), else ``face`` unchanged."""
    if face.landmarks:
        return face
    for name in TEMPLATE_NAMES:
        tri = canonical_triangles(name)
        if face.n_triangles == len(tri) and face.n_vertices == int(tri.max()) + 1 \
                and np.array_equal(face.triangles, tri):
            out = face.with_vertices(face.vertices)
            for n, p in _base_vertex_landmarks(name, tri).items():
                out.set_landmark(n, p)
            out.metadata.notes.append(f"Recognised as a canonical face of template {name}: its "
                                      f"{len(out.landmarks)} landmarks were restored.")
            return out
    return face


def dense_correspondence(scan: Face, positions: dict[str, np.ndarray], *, template: str = "mpeg4_80",
                         rays=None) -> Registration:
    """Register ``scan`` from landmark ``positions`` (name -> (3,) mm on the scan); see the module."""
    if scan.n_triangles == 0:
        raise CorrespondenceError("the scan has no triangles")
    proj = project_template(scan, template, positions, rays=rays)
    proj, untangled, left = untangle(scan, proj, template)
    proj, turned_before, turned_after, shift, released = fit_without_folds(scan, proj, template,
                                                                           rounded_outline(scan, proj, template))
    face = canonical_face(scan, proj, template)
    total = int(sum(proj.fallbacks))
    report = [f"dense correspondence ({template}): {face.n_vertices} vertices, {face.n_triangles} triangles; "
              f"rays by {proj.engine}; {total} vertices took the closest point because their normal ray missed "
              f"(per step {proj.fallbacks})"]
    if untangled or left:
        report.append(f"{untangled} vertices projected onto the same spot as a neighbour were moved apart"
                      + (f"; {left} triangles still have (almost) no area: check the landmarks near them" if left else ""))
    if turned_before:
        report.append(f"{turned_before} canonical triangles faced the other way than on a face after projection; "
                      f"the fold-free fit left {turned_after}")
    base = get_template(template).base
    if released:
        names = ", ".join(f"{name} {shift[base.index(name)]:.1f} mm" for name in released)
        report.append(f"{len(released)} landmark(s) turned template triangles over, far from where their neighbours "
                      f"put them; the fit placed them from the scan and their neighbours instead, this far from "
                      f"where they were given ({names}): check them with the landmark picker")
    held_shift = shift.copy()
    held_shift[[base.index(name) for name in released]] = 0.0
    moved = np.nonzero(held_shift > LANDMARK_SHIFT_NOTE_MM)[0]
    if len(moved):
        names = ", ".join(f"{base.points[i]} {shift[i]:.1f} mm" for i in moved[np.argsort(-shift[moved])][:6])
        report.append(f"{len(moved)} landmark(s) could not be reached without folding the mesh and moved by more "
                      f"than {LANDMARK_SHIFT_NOTE_MM:g} mm ({names}{' ...' if len(moved) > 6 else ''}): "
                      "check them with the landmark picker")
    if proj.engine != "embree":
        report.append("embreex is not available: projection used the slower numpy ray test")
    registration = Registration(face, total, proj, scan, template, report, landmark_shift=shift,
                                released=released)
    forced = registration.forced()
    if forced.any():
        base = get_template(template).base
        names = sorted({"-".join(base.points[i] for i in base.triangles[k % len(base.triangles)])
                        for k in np.nonzero(forced)[0]})
        report.append(f"the landmarks turn {len(names)} template triangle(s) over ({', '.join(names[:6])}"
                      f"{' ...' if len(names) > 6 else ''}): the fit bends the canonical mesh around them (or moves them, "
                      "see above) so that it does not fold; check those landmarks")
    return registration


# ------------------------------------------------------------------ carry-back
@dataclass(frozen=True)
class Binding:
    """Scan vertices bound to a canonical face: matrix (n_scan, N) sparse, rows = weight x barycentric
    of the closest canonical point; rest_scan (n_scan, 3); rest_canonical (N, 3); distance (n_scan,) mm."""

    matrix: scipy.sparse.csr_matrix
    rest_scan: np.ndarray
    rest_canonical: np.ndarray
    distance: np.ndarray


#: Scan vertices beyond the canonical face fade from its motion to none over this distance, mm. The
#: fade's steepest slope (1.5 / FADE_MM per mm) times the border's motion is how much the skin there
#: is squeezed or stretched: a Surrey Face Model scan's temple, 6 mm up with the brows in surprise,
#: collapsed to 0.01 of its height over 10 mm (0.39 over 20 mm; open_jaw's chin 2.06x -> 1.80x).
FADE_MM = 20.0


def bind_scan(scan: Face, canonical: Face, *, near_mm: float = 2.0, fade_mm: float = FADE_MM) -> Binding:
    """Bind every scan vertex to the closest point of ``canonical`` (see the module docstring)."""
    ts = TriangleSet(canonical.vertices, canonical.triangles)
    # Exact for vertices near the canonical surface (k nearest centroids); far ones fade out anyway.
    pos, tri, bary = ts.closest(scan.vertices, k=16, widen=False)
    dist = np.linalg.norm(pos - scan.vertices, axis=1)
    s = np.clip((dist - near_mm) / max(fade_mm, 1e-9), 0.0, 1.0)
    weight = 1.0 - s * s * (3 - 2 * s)                      # smoothstep fade
    rows = np.repeat(np.arange(scan.n_vertices), 3)
    cols = canonical.triangles[tri].ravel()
    data = (bary * weight[:, None]).ravel()
    m = scipy.sparse.csr_matrix((data, (rows, cols)), shape=(scan.n_vertices, canonical.n_vertices))
    return Binding(m, scan.vertices.copy(), canonical.vertices.copy(), dist)


class CarryBack:
    """Moves the full-resolution scan with its canonical face: ``apply(canonical_vertices)``."""

    def __init__(self, binding: Binding):
        self.binding = binding

    def apply(self, canonical_vertices) -> np.ndarray:
        """(n_scan, 3) mm: scan vertices for canonical vertices (N, 3) (rest -> the scan exactly)."""
        c = np.asarray(canonical_vertices, float)
        if c.shape != self.binding.rest_canonical.shape:
            raise ValueError(f"canonical vertices must have shape {self.binding.rest_canonical.shape}, got {c.shape}")
        return self.binding.rest_scan + self.binding.matrix @ (c - self.binding.rest_canonical)


def landmark_positions_on(scan: Face, landmarks) -> dict[str, np.ndarray]:
    """name -> (3,) mm from a mapping of SurfacePoints (on ``scan``) or positions."""
    out = {}
    for name, p in landmarks.items():
        if isinstance(p, SurfacePoint):
            if not 0 <= p.triangle < scan.n_triangles:
                raise CorrespondenceError(f"landmark {name!r} refers to triangle {p.triangle}, "
                                          f"but the scan has {scan.n_triangles}")
            out[name] = np.einsum("j,jd->d", np.array(p.barycentric), scan.vertices[scan.triangles[p.triangle]])
        else:
            a = np.asarray(p, float)
            if a.shape != (3,) or not np.all(np.isfinite(a)):
                raise CorrespondenceError(f"landmark {name!r} must be a SurfacePoint or an (x, y, z) position")
            out[name] = a
    return out


__all__ = ["SurfaceRays", "Projection", "project_template", "surfaces_of", "canonical_face", "dense_correspondence",
           "Registration", "Binding", "bind_scan", "CarryBack", "CorrespondenceError", "TemplateError",
           "landmark_positions_on", "template_base_positions"]
