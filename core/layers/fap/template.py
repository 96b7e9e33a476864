"""The MPEG-4 base template: 80 named points and 140 triangles, placed on a face and densified.

The template (``resources/templates/mpeg4_80.json``, built by ``tools/build_mpeg4_template.py``)
holds the 64 feature points thesis A keeps plus 8 extra points around each eye. Placing it on a
face takes the feature points from the face's landmarks and computes the extras as fixed affine
combinations of them, snapped onto the skin. Densifying follows thesis A §5: linear, linear, Loop,
projecting the vertices onto the face after each step: 80/140 -> 300/560 -> 1160/2240 -> 4560/8960.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

import resources

from core.face import Face
from core.subdivision import subdivide
from core.surface_query import TriangleSet


class TemplateError(ValueError):
    """The template cannot be placed on this face (missing feature points)."""


@dataclass(frozen=True)
class BaseTemplate:
    """A landmark triangulation (data). ``points[i]`` names vertex i of ``triangles``."""

    name: str
    points: tuple[str, ...]
    triangles: np.ndarray                      # (140, 3)
    extras: dict[str, dict[str, float]]        # extra point -> {point: weight}, affine (weights sum to 1)
    outline: tuple[str, ...]
    mouth: tuple[str, ...]
    eye_margins: dict[str, tuple[str, ...]]
    eye_opening_triangles: frozenset[int]
    upper_lip_points: frozenset[str]
    lower_lip_points: frozenset[str]
    steps: tuple[str, ...]
    regions: tuple[dict, ...]

    @property
    def feature_points(self) -> tuple[str, ...]:
        return tuple(p for p in self.points if p not in self.extras)

    def index(self, name: str) -> int:
        return self.points.index(name)

    def crease_edges(self) -> np.ndarray:
        """(k, 2) base edges kept sharp by Loop: the eye margins (the mesh boundary always is)."""
        pairs = []
        for loop in self.eye_margins.values():
            pairs += [(self.index(a), self.index(b)) for a, b in zip(loop, loop[1:] + loop[:1])]
        return np.array(pairs, dtype=np.int64)


@functools.cache
def load_template(name: str = "mpeg4_80") -> BaseTemplate:
    d = resources.get_json(f"templates/{name}.json")
    tri = np.array(d["triangles"], dtype=np.int64)
    tri.setflags(write=False)
    return BaseTemplate(
        name=d["name"], points=tuple(d["points"]), triangles=tri, extras=d["extras"],
        outline=tuple(d["outline"]), mouth=tuple(d["mouth"]),
        eye_margins={k: tuple(v) for k, v in d["eye_margins"].items()},
        eye_opening_triangles=frozenset(t for ts in d["eye_opening_triangles"].values() for t in ts),
        upper_lip_points=frozenset(d["upper_lip_points"]), lower_lip_points=frozenset(d["lower_lip_points"]),
        steps=tuple(d["subdivision"]), regions=tuple(d["regions"]),
    )


# ------------------------------------------------------------------ target surfaces
class _Surface:
    """Closest-point and ray queries restricted to a subset of a face's triangles."""

    def __init__(self, face: Face, triangle_ids: np.ndarray):
        self.face = face
        self.ids = np.asarray(triangle_ids, dtype=np.int64)
        self.local = TriangleSet(face.vertices, face.triangles[self.ids])

    def closest(self, points):
        """(closest surface points (k, 3), face triangle ids (k,)): exact (centroid KD-tree candidates,
        widened where unsure; trimesh's rtree build alone took ~1 s per 100k triangles)."""
        closest, tri, _bary = self.local.closest(np.asarray(points, float))
        return closest, self.ids[tri]

    def ray_nearest(self, points, directions, max_distance: float):
        """Nearest hit along +-direction within max_distance on a triangle facing the same way.

        Returns (positions (k, 3), face triangle ids (k,), hit mask (k,))."""
        pos, tri, _bary, hit = self.local.ray_nearest(points, directions, max_distance)
        return pos, np.where(hit, self.ids[np.maximum(tri, 0)], -1), hit


def skin_triangles(face: Face) -> np.ndarray:
    """Indices of triangles with no vertex in a named part (eyeballs, teeth, mouth cavity)."""
    in_part = np.zeros(face.n_vertices, bool)
    for idx in face.parts.values():
        in_part[idx] = True
    return np.nonzero(~in_part[face.triangles].any(axis=1))[0]


# ------------------------------------------------------------------ placement
def base_positions(template: BaseTemplate, face: Face, skin: "_Surface | None" = None) -> np.ndarray:
    """(P, 3) mm: the template's points on ``face`` (feature points from its landmarks, extras snapped
    onto ``skin``, the face's skin surface, built here when not given)."""
    missing = [p for p in template.feature_points if p not in face.landmark_names]
    if missing:
        raise TemplateError(
            f"this face lacks {len(missing)} of the {len(template.feature_points)} MPEG-4 feature points the "
            f"animation template needs ({', '.join(missing[:8])}{' ...' if len(missing) > 8 else ''}); "
            "mark them with the landmark picker first"
        )
    pos = {p: face.landmark_position(p) for p in template.feature_points}
    for name, weights in template.extras.items():  # extras only refer to earlier points
        pos[name] = sum(w * pos[k] for k, w in weights.items())
    extras = list(template.extras)
    if extras:  # templates made only of feature points (e.g. a48) have nothing to snap
        skin = skin if skin is not None else _Surface(face, skin_triangles(face))
        snapped, _ = skin.closest(np.array([pos[e] for e in extras]))
        pos.update(zip(extras, snapped))
    return np.array([pos[p] for p in template.points])


def mouth_side(face: Face, skin: np.ndarray) -> np.ndarray:
    """(len(skin),) +1 upper-lip side, -1 lower-lip side, 0 elsewhere (between the mouth corners).

    Skin vertices on the mouth opening's rim (a seam of duplicated vertices on a closed mouth) take
    the side their own triangles lie on. All 0 when the face lacks the lip feature points.
    Deformers bind each side only to its own lip, so the jaw never drags the upper lip.
    """
    from core.subdivision import boundary_edges

    need = ("2.5", "2.7", "2.2", "2.6", "2.4", "2.9", "2.3", "2.8", "8.3", "8.4")
    if any(p not in face.landmark_names for p in need):
        return np.zeros(len(skin), np.int64)
    up = np.array([face.landmark_position(p) for p in ("2.5", "2.7", "2.2", "2.6", "2.4")])
    lo = np.array([face.landmark_position(p) for p in ("2.5", "2.9", "2.3", "2.8", "2.4")])
    line = (up + lo) / 2
    order = np.argsort(line[:, 0])
    x, y = face.vertices[skin, 0], face.vertices[skin, 1]
    corner_x = max(abs(face.landmark_position("8.3")[0]), abs(face.landmark_position("8.4")[0]))
    y_line = np.interp(x, line[order, 0], line[order, 1])
    near = (np.abs(x) < corner_x + 2.0) & (np.abs(y - y_line) < 30.0)
    side = np.where(y > y_line, 1, -1)
    rim = np.zeros(face.n_vertices, bool)
    rim[boundary_edges(face.triangles).ravel()] = True
    on = near & rim[skin] & (np.abs(y - y_line) < 3.0)
    if on.any():
        adj = face.adjacency[skin[on]]
        mean_y = (adj @ face.vertices[:, 1]) / np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1)
        side[on] = np.where(mean_y > y[on], 1, -1)
    return np.where(near, side, 0)


@dataclass
class DenseTemplate:
    """The template densified on one face.

    vertices : (N, 3) mm on the face surface; triangles : (M, 3).
    base_coords : (N, 80) each vertex as an affine combination of the base points (its place in
        the base mesh; at most 3 non-zeros, all within one base triangle).
    face_triangle : (N,) the face triangle each vertex lies on.
    counts : [(vertices, triangles)] after each step, base first.
    fallbacks : per step, how many vertices missed their normal ray and took the closest point.
    """

    template: BaseTemplate
    vertices: np.ndarray
    triangles: np.ndarray
    base_coords: np.ndarray
    face_triangle: np.ndarray
    counts: list[tuple[int, int]] = field(default_factory=list)
    fallbacks: list[int] = field(default_factory=list)

    def in_base_triangles(self, base_triangles) -> np.ndarray:
        """(N,) bool: vertices inside (or on the border of) any of the given base triangles."""
        t = self.template.triangles[np.asarray(sorted(base_triangles), dtype=np.int64)]
        support = self.base_coords > 1e-12
        inside = np.zeros(len(self.vertices), bool)
        for tri in t:  # <= 140 base triangles, vectorised over vertices
            outside = support.copy()
            outside[:, tri] = False
            inside |= ~outside.any(axis=1)
        return inside

    def on_chain(self, names) -> np.ndarray:
        """(N,) bool: vertices on the base edges between consecutive points of ``names``."""
        idx = [self.template.index(n) for n in names]
        support = self.base_coords > 1e-12
        on = np.zeros(len(self.vertices), bool)
        for a, b in zip(idx, idx[1:]):
            outside = support.copy()
            outside[:, [a, b]] = False
            on |= ~outside.any(axis=1)
        return on


def densify(face: Face, template: BaseTemplate | None = None, *, steps=None) -> DenseTemplate:
    """Place ``template`` on ``face`` and subdivide it, projecting onto the face after each step.

    New vertices move along their normal to the nearest skin surface facing the same way (within
    1.5 edge lengths); when the ray misses or only finds the far side, they take the closest skin
    point instead (counted in ``fallbacks``). Vertices on the outline, the mouth and the eye margins
    always take the closest point (a ray there can slip through the opening), and vertices inside
    the eye openings project onto the whole face (eyeballs included).
    """
    template = template or load_template()
    steps = tuple(steps) if steps is not None else template.steps
    skin = _Surface(face, skin_triangles(face))   # one search structure for placing and projecting
    base = base_positions(template, face, skin)
    n_base = len(base)
    whole = _Surface(face, np.arange(face.n_triangles))

    v, t = base, template.triangles
    coords = np.eye(n_base)
    creases = template.crease_edges()
    eye_tris = sorted(template.eye_opening_triangles)
    _, base_face_tri = skin.closest(base)
    face_tri = base_face_tri
    counts, fallbacks = [(len(v), len(t))], []
    for scheme in steps:
        sub = subdivide(v, t, scheme=scheme, creases=creases, params=coords)
        v, t, coords, creases = sub.vertices, sub.triangles, sub.params, sub.creases
        moving = np.arange(n_base, len(v))
        edge = _edge_vertices(t, creases, len(v))
        staged = DenseTemplate(template, v, t, coords, np.full(len(v), -1))
        in_eye = staged.in_base_triangles(eye_tris) & ~edge
        normals = _vertex_normals(v, t)
        spacing = float(np.median(np.linalg.norm(v[t[:, 0]] - v[t[:, 1]], axis=1)))
        new_v, face_tri = v.copy(), np.full(len(v), -1)
        rayed = moving[~edge[moving]]
        missed = 0
        for surface, sel in ((skin, rayed[~in_eye[rayed]]), (whole, rayed[in_eye[rayed]])):
            if not len(sel):
                continue
            pos, tri, hit = surface.ray_nearest(v[sel], normals[sel], 1.5 * spacing)
            if (~hit).any():
                pos[~hit], tri[~hit] = surface.closest(v[sel][~hit])
            missed += int((~hit).sum())
            new_v[sel], face_tri[sel] = pos, tri
        snap = moving[edge[moving]]
        if len(snap):
            new_v[snap], face_tri[snap] = skin.closest(v[snap])
        new_v[:n_base], face_tri[:n_base] = base, base_face_tri
        v = new_v
        counts.append((len(v), len(t)))
        fallbacks.append(missed)
    return DenseTemplate(template, v, t, coords, face_tri, counts=counts, fallbacks=fallbacks)


def _edge_vertices(triangles: np.ndarray, creases: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: vertices on the mesh boundary or on a crease (eye margins)."""
    from core.subdivision import boundary_edges

    mask = np.zeros(n, bool)
    mask[boundary_edges(triangles).ravel()] = True
    if len(creases):
        mask[np.asarray(creases).ravel()] = True
    return mask


def _vertex_normals(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    from core.face import vertex_normals

    return vertex_normals(v, t)
