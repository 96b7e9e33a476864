"""Control points and their influence regions on a face (thesis B §4.1.1, Figs. 4.3-4.4).

Data: ``resources/rbf/influence.csv`` (which regions each control point may move) and
``resources/rbf/regions.csv`` (the regions and their side seams). On a face:

1. each control point sits on the skin vertex nearest its MPEG-4 feature point (or its PPC position), so the
   RBF reproduces its displacement exactly on the mesh;
2. every skin vertex is labelled with a region: that of its nearest control point which may move it (a
   vertex above the mouth line never takes a lower-lip or chin label, a lid vertex only its own lid's); skin
   farther than ``reach_mm`` from every such point is *static*; eyeballs, teeth and the mouth cavity are
   never moved;
3. the labels are blended over ``blend_mm`` (smoothstep of the distance to each region's vertices), never
   across a side seam (a seam fades out over ``SEAM_FADE_MM`` beyond its ends, e.g. past the eye corners,
   so it leaves no crease where it stops), into weights W (n, R) that sum to 1 with the static share;
4. the influence of control point c on vertex v is Ω(v, c) = Σ_{R ∈ regions(c)} W(v, R), divided by its value
   at c's own vertex and capped at 1 — so Ω = 1 at the point (exact interpolation) and 0 in every region it
   does not list (it never moves them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from core.face import Face
from core.parameters import ParameterError

__all__ = ["ControlPointSpec", "ControlPoints", "control_point_specs", "region_table", "influence"]

_INFLUENCE = "rbf/influence.csv"
_REGIONS = "rbf/regions.csv"


@dataclass(frozen=True)
class ControlPointSpec:
    """One row of influence.csv: ``name``, MPEG-4 feature point ``fp`` and the ``regions`` it may move."""

    name: str
    fp: str
    regions: tuple[str, ...]


def control_point_specs() -> tuple[ControlPointSpec, ...]:
    """The default control points in file order (the DPC/EPC/PPC order)."""
    import resources

    return tuple(ControlPointSpec(r["name"], r["fp"], tuple(r["regions"].split())) for r in
                 resources.get_table(_INFLUENCE))


def region_table() -> dict[str, str]:
    """{region: side seam} from regions.csv ('-' for none)."""
    import resources

    return {r["region"]: r["side"] for r in resources.get_table(_REGIONS)}


@dataclass(frozen=True, eq=False)
class ControlPoints:
    """Control points placed on one face.

    specs : the points (names, feature points, regions); vertices : (c,) int skin vertex of each point;
    positions : (c, 3) mm, the rest positions of those vertices (the RBF centres).
    """

    specs: tuple[ControlPointSpec, ...]
    vertices: np.ndarray

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.specs)

    @property
    def feature_points(self) -> tuple[str, ...]:
        return tuple(s.fp for s in self.specs)

    def __len__(self) -> int:
        return len(self.specs)

    @classmethod
    def on_face(cls, face: Face, positions: dict[str, np.ndarray] | None = None,
                specs: tuple[ControlPointSpec, ...] | None = None) -> "ControlPoints":
        """The control points on ``face``: at ``positions`` {name: (3,) mm} (e.g. a PPC file) when given, else
        at the face's landmarks of their feature points; each snapped to the nearest skin vertex.
        ParameterError naming the missing points when the face lacks some."""
        specs = control_point_specs() if specs is None else tuple(specs)
        if positions is None:
            missing = [s.fp for s in specs if s.fp not in face.landmark_names]
            if missing:
                raise ParameterError(f"this face lacks the feature points {', '.join(missing)} the control points "
                                     "sit on; mark them with the landmark picker or load a PPC file")
            xyz = np.array([face.landmark_position(s.fp) for s in specs]).reshape(-1, 3)
        else:
            missing = [s.name for s in specs if s.name not in positions]
            if missing:
                raise ParameterError(f"no position for the control points {', '.join(missing)}")
            xyz = np.array([positions[s.name] for s in specs], dtype=float).reshape(-1, 3)
        skin = skin_vertices(face)
        _, nearest = cKDTree(face.vertices[skin]).query(xyz)
        vertices = skin[np.asarray(nearest, dtype=np.int64)]
        if len(set(vertices.tolist())) != len(vertices):
            dup = next(i for i, v in enumerate(vertices.tolist()) if vertices.tolist().count(v) > 1)
            raise ParameterError(f"control point {specs[dup].name} lands on the same vertex as another one; "
                                 "move one of them")
        vertices.setflags(write=False)
        return cls(specs, vertices)


def skin_vertices(face: Face) -> np.ndarray:
    """(k,) indices of the vertices in no named part (not eyeballs, teeth or mouth cavity)."""
    in_part = np.zeros(face.n_vertices, bool)
    for idx in face.parts.values():
        in_part[idx] = True
    return np.nonzero(~in_part)[0]


#: Beyond its ends a side seam fades out over this distance (mm), so it leaves no crease where it stops.
SEAM_FADE_MM = 10.0


def _seam(v: np.ndarray, line: np.ndarray, lo: float, hi: float, band: float, exact=None
          ) -> tuple[np.ndarray, np.ndarray]:
    """(side (k,) +1 above / −1 below the polyline ``line`` (p, 2) of x, y; strength (k,) in [0, 1]): 1
    for x in [lo, hi] within ``band`` mm of the line, fading to 0 over SEAM_FADE_MM beyond the ends.
    ``exact``: (k,) ±1 side to use where it is nonzero (the mouth's own rim test)."""
    order = np.argsort(line[:, 0])
    y_line = np.interp(v[:, 0], line[order, 0], line[order, 1])
    side = np.where(v[:, 1] >= y_line, 1, -1)
    if exact is not None:
        side = np.where(exact != 0, exact, side)
    outside = np.maximum(lo - v[:, 0], v[:, 0] - hi).clip(min=0.0)
    t = np.clip(1.0 - outside / SEAM_FADE_MM, 0.0, 1.0)
    strength = t * t * (3.0 - 2.0 * t) * (np.abs(v[:, 1] - y_line) < band)
    return side, strength


def _sides(face: Face, skin: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{seam: (side, strength)} (see :func:`_seam`) for 'mouth', 'eye_l', 'eye_r'; strength 0 without the
    feature points that place the seam."""
    from core.layers.fap.template import mouth_side

    v = face.vertices[skin]
    none = (np.zeros(len(skin), np.int64), np.zeros(len(skin)))
    out = {}
    lips = ("2.5", "2.7", "2.2", "2.6", "2.4", "2.9", "2.3", "2.8", "8.3", "8.4")
    if all(p in face.landmark_names for p in lips):
        up = np.array([face.landmark_position(p) for p in ("2.5", "2.7", "2.2", "2.6", "2.4")])
        lo = np.array([face.landmark_position(p) for p in ("2.5", "2.9", "2.3", "2.8", "2.4")])
        corner_x = max(abs(face.landmark_position("8.3")[0]), abs(face.landmark_position("8.4")[0]))
        out["mouth"] = _seam(v, ((up + lo) / 2)[:, :2], -corner_x - 2.0, corner_x + 2.0, 30.0,
                             exact=mouth_side(face, skin))
    else:
        out["mouth"] = none
    for side, (outer, inner) in (("l", ("3.7", "3.11")), ("r", ("3.12", "3.8"))):
        if outer not in face.landmark_names or inner not in face.landmark_names:
            out[f"eye_{side}"] = none
            continue
        a, b = face.landmark_position(outer), face.landmark_position(inner)
        out[f"eye_{side}"] = _seam(v, np.array([a[:2], b[:2]]), min(a[0], b[0]) - 3.0, max(a[0], b[0]) + 3.0,
                                   20.0)
    return out


def _allowed(side: str, sides: dict, n: int) -> np.ndarray:
    """(n,) in [0, 1]: how much a region with this side rule may weigh at each vertex (0 across its seam)."""
    if side in ("-", ""):
        return np.ones(n)
    where, _, seam = side.partition("_")
    if seam not in sides or where not in ("above", "below"):
        raise ValueError(f"regions.csv: unknown side {side!r} (above_/below_ mouth, eye_l, eye_r, or -)")
    sign, strength = sides[seam]
    wrong = sign < 0 if where == "above" else sign > 0
    return np.where(wrong, 1.0 - strength, 1.0)


def influence(face: Face, points: ControlPoints, *, reach_mm: float = 35.0, blend_mm: float = 20.0
              ) -> tuple[np.ndarray, np.ndarray]:
    """(active vertices (k,), Ω (k, c)): the vertices some control point moves and how much each point may
    move each of them, in [0, 1] (see the module docstring)."""
    if not reach_mm > 0 or not blend_mm > 0:
        raise ParameterError(f"reach and blend must be > 0 mm, got {reach_mm:g} and {blend_mm:g}")
    table = region_table()
    regions = list(table)
    unknown = sorted({r for s in points.specs for r in s.regions} - set(regions))
    if unknown:
        raise ParameterError(f"unknown influence regions {', '.join(unknown)}: regions are {', '.join(regions)}")
    skin = skin_vertices(face)
    v = face.vertices[skin]
    sides = _sides(face, skin)
    soft = np.column_stack([_allowed(table[r], sides, len(skin)) for r in regions])        # (k, R) in [0, 1]
    allowed = soft > 0.5
    member = np.zeros((len(points), len(regions)), bool)                                 # (c, R)
    for i, spec in enumerate(points.specs):
        member[i, [regions.index(r) for r in spec.regions]] = True
    centres = face.vertices[points.vertices]
    # 1. label: the nearest control point that may move the vertex, its first region allowed there.
    d2 = ((v[:, None, :] - centres[None, :, :]) ** 2).sum(-1)                             # (k, c)
    may = (allowed.astype(np.int8) @ member.T.astype(np.int8)) > 0                        # (k, c)
    d2[~may] = np.inf
    nearest = np.argmin(d2, axis=1)
    dist = np.sqrt(d2[np.arange(len(skin)), nearest])
    label = np.full(len(skin), -1)
    for i, spec in enumerate(points.specs):
        rows = nearest == i
        for r in reversed(spec.regions):   # the first allowed region in the point's order wins
            j = regions.index(r)
            label[rows & allowed[:, j]] = j
    label[dist > reach_mm] = -1
    # 2. blend: smoothstep of the distance to each region's vertices (static is a region too), no seams crossed.
    weights = np.zeros((len(skin), len(regions) + 1))
    for j in range(len(regions) + 1):
        inside = label == (j if j < len(regions) else -1)
        if not inside.any():
            continue
        d, _ = cKDTree(v[inside]).query(v, distance_upper_bound=blend_mm)
        s = np.clip(1.0 - d / blend_mm, 0.0, 1.0)
        w = s * s * (3.0 - 2.0 * s)
        if j < len(regions):
            w *= soft[:, j]
        weights[:, j] = w
    weights /= weights.sum(axis=1, keepdims=True)
    # 3. each point's influence: the weights of its regions, 1 at its own vertex.
    omega = weights[:, :-1] @ member.T.astype(float)                                      # (k, c)
    row_of = np.full(face.n_vertices, -1)
    row_of[skin] = np.arange(len(skin))
    own = row_of[points.vertices]
    at_point = omega[own, np.arange(len(points))]
    omega /= np.where(at_point > 0, at_point, 1.0)
    np.minimum(omega, 1.0, out=omega)
    omega[own, np.arange(len(points))] = 1.0
    active = omega.max(axis=1) > 0
    return skin[active], np.ascontiguousarray(omega[active])
