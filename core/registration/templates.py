"""Landmark templates for matching and dense correspondence: "mpeg4_80" and "a48".

Both are stored as data (``resources/templates/<name>.json``) and loaded by
:func:`core.layers.fap.template.load_template`; this module adds what matching needs on top:

* ``detected``: the points the matcher looks for. For "a48" all 48 points (46 MPEG-4 feature
  points and 2 temple points). For "mpeg4_80" the 64 feature points; its 16 eye extras are affine
  combinations of feature points and are recomputed on placement (``core.layers.fap.template``).
* ``edges``: the graph G_m over the detected points (thesis A Fig. 3.4): the template's triangle
  edges; for "mpeg4_80" an extra point is contracted (its feature-point neighbours are joined).
* ground-truth positions on any face carrying the MPEG-4 feature points (every synthetic and the
  default face): feature points from the landmarks; an a48 derived point is a fixed barycentric
  position on an mpeg4_80 base triangle placed on the face, snapped to the closest skin point.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from core.face import Face, SurfacePoint
from core.layers.fap.template import BaseTemplate, TemplateError, base_positions, load_template, skin_triangles

TEMPLATE_NAMES = ("mpeg4_80", "a48")


class UnknownTemplateError(ValueError):
    """The template name is not one Mimica ships."""


@dataclass(frozen=True)
class LandmarkTemplate:
    """A base template plus the matching graph.

    base : the BaseTemplate (points, triangles, outline, mouth, eye margins, subdivision steps).
    detected : names of the points the matcher finds (in template order).
    edges : (e, 2) int indices into ``detected``: the graph G_m.
    derived : a48 non-FP point -> {"triangle": mpeg4_80 triangle, "corners": names, "barycentric": 3}.
    mirror : name -> mirrored name (left/right), for points whose MPEG-4 pair is not implied.
    """

    name: str
    base: BaseTemplate
    detected: tuple[str, ...]
    edges: np.ndarray
    derived: dict
    counts: tuple[tuple[int, int], ...]

    @property
    def required_feature_points(self) -> tuple[str, ...]:
        """MPEG-4 feature points a face needs for ground truth / placement of this template."""
        if self.name == "a48":
            fps = [p for p in self.base.points if p not in self.derived]
            return tuple(dict.fromkeys(fps + list(load_template("mpeg4_80").feature_points)))
        return self.base.feature_points

    def index(self, name: str) -> int:
        return self.detected.index(name)

    def neighbours(self) -> list[np.ndarray]:
        """Per detected point, the indices of its graph neighbours."""
        n = len(self.detected)
        out = [[] for _ in range(n)]
        for a, b in self.edges:
            out[a].append(b)
            out[b].append(a)
        return [np.array(sorted(set(x)), dtype=np.int64) for x in out]


def expected_counts(base: BaseTemplate) -> list[tuple[int, int]]:
    """(vertices, triangles) after each subdivision step, base first: V' = V + E, F' = 4F.

    For a mesh with Euler characteristic chi and B boundary edges: E = V + F - chi and B doubles each
    step (each boundary edge splits in two)."""
    from core.subdivision import boundary_edges, unique_edges

    v, f = len(base.points), len(base.triangles)
    e = len(unique_edges(base.triangles)[0])
    b = len(boundary_edges(base.triangles))
    out = [(v, f)]
    for _ in base.steps:
        v, f, e, b = v + e, 4 * f, 2 * e + 3 * f, 2 * b
        out.append((v, f))
    return out


@functools.cache
def get_template(name: str = "mpeg4_80") -> LandmarkTemplate:
    """The named template (cached). Raises UnknownTemplateError for other names."""
    if name not in TEMPLATE_NAMES:
        raise UnknownTemplateError(f"unknown landmark template {name!r}; choose one of {', '.join(TEMPLATE_NAMES)}")
    import resources

    base = load_template(name)
    raw = resources.get_json(f"templates/{name}.json")
    derived = dict(raw.get("derived", {}))
    detected = tuple(p for p in base.points if p not in base.extras)
    index = {p: i for i, p in enumerate(base.points)}
    det_index = {p: i for i, p in enumerate(detected)}
    pairs = set()
    t = base.triangles
    for a, b in np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]):
        pa, pb = base.points[a], base.points[b]
        if pa in det_index and pb in det_index:
            pairs.add(tuple(sorted((det_index[pa], det_index[pb]))))
    # Contract the extras: join the detected neighbours of each extra (they share its triangles).
    for extra in base.extras:
        i = index[extra]
        ring = {base.points[v] for v in t[(t == i).any(axis=1)].ravel()} - {extra}
        ring = sorted(det_index[p] for p in ring if p in det_index)
        for k, a in enumerate(ring):
            for b in ring[k + 1:]:
                pairs.add((a, b))
    edges = np.array(sorted(pairs), dtype=np.int64)
    counts = tuple(tuple(c) for c in raw.get("counts", expected_counts(base)))
    return LandmarkTemplate(name, base, detected, edges, derived, counts)


# ------------------------------------------------------------------ ground truth on a face
def _missing(face: Face, names) -> list[str]:
    have = set(face.landmark_names)
    return [n for n in names if n not in have]


def template_positions(face: Face, name: str = "a48", *, vertices: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Ground-truth positions (mm) of the template's detected points on ``face``.

    Points the face carries as landmarks are taken as they are (so a face whose landmarks were
    detected with this template returns them); a missing a48 derived point is computed from the
    mpeg4_80 feature points. ``vertices`` evaluates on a deformed pose of ``face``.
    """
    tpl = get_template(name)
    have = set(face.landmark_names)
    need = [p for p in tpl.detected if p not in have]
    out = {}
    lm = [p for p in tpl.detected if p in have]
    if lm:
        out.update(zip(lm, face.landmark_positions(lm, vertices)))
    derived = [p for p in need if p in tpl.derived]
    plain = [p for p in need if p not in tpl.derived]
    if plain:
        raise TemplateError(
            f"this face lacks {len(plain)} of the points of template {name!r} ({', '.join(plain[:8])}"
            f"{' ...' if len(plain) > 8 else ''}); mark them with the landmark picker or detect them first")
    if derived:
        src = face if vertices is None else face.with_vertices(vertices)
        m80 = load_template("mpeg4_80")
        base = base_positions(m80, src)
        # Corners by name (robust to a re-triangulated mpeg4_80 file); "triangle" is informative.
        raw = np.array([(np.array(tpl.derived[p]["barycentric"])[:, None]
                         * base[[m80.index(c) for c in tpl.derived[p]["corners"]]]).sum(axis=0) for p in derived])
        skin = skin_triangles(src)
        from core.surface_query import TriangleSet

        pos, _tri, _bary = TriangleSet(src.vertices, src.triangles[skin]).closest(raw)
        out.update(zip(derived, pos))
    return {p: out[p] for p in tpl.detected}


def template_array(face: Face, name: str = "a48", *, vertices=None) -> np.ndarray:
    """(k, 3) mm: :func:`template_positions` in ``detected`` order."""
    pos = template_positions(face, name, vertices=vertices)
    return np.array([pos[p] for p in get_template(name).detected])


def with_template_landmarks(face: Face, name: str = "a48") -> Face:
    """A copy of ``face`` that also carries the template's derived points as landmarks."""
    pos = template_positions(face, name)
    missing = [p for p in get_template(name).detected if p not in face.landmark_names]
    out = face.with_vertices(face.vertices)
    if missing:
        _, tri, bary = face.closest_surface_points(np.array([pos[p] for p in missing]))
        for p, t, b in zip(missing, tri, bary):
            out.set_landmark(p, SurfacePoint(int(t), tuple(b)))
    return out
