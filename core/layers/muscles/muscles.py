"""The 19 muscles of thesis C as data, placed on a tissue model, and their force fields.

Definitions live in ``resources/muscles/muscles.json``: each linear muscle's mobile end P (at the
lips) and fixed end R as feature-point combinations plus offsets in FAPU distances, its radius d,
force range and the lip it may act on; left side given, right side mirrored. The orbicularis oris
is a ring through the outer lip contour (FPs 8.x).

Linear muscle (thesis C eqs. 3.13-3.15): for a skin vertex Q with foot S on segment PR,
    f_Q = (cos(pi |QS| / d) + 1)/2 · (cos(pi |PS| / |PR|) + 1)/2 · f_P,
directed along the muscle toward R; vertices outside the finite cylinder (|QS| >= d, or S beyond
P or R) get nothing. f_P = force (thesis units) x ``force_unit_dyn`` x s_Q (the node's area
scale, see ``model``), so the total pull does not depend on the mesh resolution.

Insertion (beyond thesis C, ``insertion`` in the data): the cylinder continues past P, away from R,
over a length e (0.2 MW) with the along-falloff (cos(pi |PS| / e) + 1)/2, and all weights are scaled
so the muscle's total pull (sum of weight x s_Q) is the thesis's. The corner muscles insert into the
modiolus and blend with the orbicularis oris; ending at P put their whole pull on the corner's few
nodes, and the corner's skin stretched 2.2-2.4x in the smiles. e = 0 is eqs. 3.13-3.15 exactly.

Orbicularis oris (eqs. 3.17-3.18): vertices within d of the ring are pulled toward the centre
c = (corner_l + corner_r)/2 moved forward by ``protrusion`` (0.6 MW) with
    f_Q = gain · (d_c / d_m) · s_Q · ring falloff · f,
d_c = |Q - c|, d_m = |P_m - c| for the reference vertex P_m at FP 8.1. Thesis C's link-count
factor v/v_m compensated its uneven mesh; the area scale s_Q does that here. The ring falloff
reaches d = 5 mm into the lips but only ``outside_fraction`` x d into the surrounding skin (the
sphincter lies in the lips; pulling the skin under the nose sideways buckles the spring
lattice, which has no bending stiffness). The vertical component of the direction is scaled
by ``vertical_scale`` (0): the model has no lip-lip contact, and a vertical pull toward the
centre pushes the upper lip through the lower one; protrusion and narrowing remain. ``gain``
(data) converts the sphincter's thesis units: its eq. 3.18 normalises by the reference vertex,
so one unit is not the linear muscles' unit (the kiss uses 8, the smile's risorius 42).

Skull non-penetration (eq. 3.11, thesis C's sign): where f·n < 0 (n the outward skin normal) the
inward part is removed, f <- f - (f·n) n.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from core.layers.muscles.model import MuscleModelError, TissueModel, resolve_point
from core.layers.muscles.specs import (  # noqa: F401 - re-exported
    ORBICULARIS, SIDES, MuscleSpec, check_control, control_keys, jaw_range, load_definitions, muscle_specs,
    spec_by_name,
)

# ------------------------------------------------------------------ placement on a tissue model
@dataclass
class SurfaceAnchor:
    """A point on the tissue skin: triangle id and barycentric coordinates (moves with the skin)."""

    triangle: int
    bary: np.ndarray  # (3,)

    def position(self, model: TissueModel, x: np.ndarray) -> np.ndarray:
        """(3,) position on node positions ``x`` (>= N, 3) (units of x)."""
        return self.bary @ x[model.triangles[self.triangle]]


@dataclass
class LinearMuscle:
    key: tuple[str, str]
    P: SurfaceAnchor
    R: SurfaceAnchor
    radius_cm: float
    nodes: np.ndarray    # (k,) skin node ids inside the cylinder
    weight: np.ndarray   # (k,) falloff along x across (eq. 3.15), in (0, 1]


@dataclass
class Sphincter:
    key: tuple[str, None]
    ring: list[SurfaceAnchor]     # through the outer lip contour FPs
    corners: tuple[SurfaceAnchor, SurfaceAnchor]
    reference: SurfaceAnchor      # P_m (FP 8.1)
    protrusion_cm: float
    vertical_scale: float
    gain: float                   # force per thesis unit relative to the linear muscles
    radius_cm: float
    nodes: np.ndarray
    weight: np.ndarray            # ring falloff


class MuscleSet:
    """The 19 muscles placed on one tissue model (weights computed once, at the neutral pose)."""

    def __init__(self, model: TissueModel):
        self.model = model
        d = load_definitions()
        face, fapu = model.face, model.fapu
        mirror = d["mirror"]
        self.keys = control_keys()
        insertion = d.get("insertion", {"spread": 0.0, "unit": "MW"})
        self.insertion_cm = float(insertion["spread"]) * fapu[insertion["unit"]] / 10.0
        self.linear: list[LinearMuscle] = []
        for m in d["linear"]:
            for side in SIDES:
                mir = None if side == "left" else mirror
                P = self._anchor(resolve_point(m["P"], face, fapu, mir))
                R = self._anchor(resolve_point(m["R"], face, fapu, mir))
                radius = float(m["radius_mm"]) / 10.0
                nodes, weight = self._cylinder(P, R, radius, m.get("lip", "both"))
                if not len(nodes):
                    raise MuscleModelError(f"{m['label']} ({side}) acts on no skin vertex: its radius is too small")
                self.linear.append(LinearMuscle((m["name"], side), P, R, radius, nodes, weight))
        o = d["orbicularis"]
        ring = [self._anchor(face.landmark_position(n)) for n in o["ring"]]
        corners = tuple(self._anchor(face.landmark_position(n)) for n in o["corners"])
        ref = self._anchor(face.landmark_position(o["reference"]))
        radius = float(o["radius_mm"]) / 10.0
        nodes, weight = self._ring_weights(ring, radius, float(o.get("outside_fraction", 1.0)))
        self.sphincter = Sphincter((o["name"], None), ring, corners, ref,
                                   float(o["protrusion"]) * fapu[o.get("protrusion_unit", "MW")] / 10.0,
                                   float(o.get("vertical_scale", 1.0)), float(o.get("gain", 1.0)),
                                   radius, nodes, weight)
        order = {k: i for i, k in enumerate(self.keys)}
        assert [order[m.key] for m in self.linear] + [order[self.sphincter.key]] == list(range(len(self.keys)))

    def _anchor(self, point_mm: np.ndarray) -> SurfaceAnchor:
        _pos, tri, bary = self.model.skin_set.closest(np.asarray(point_mm, float)[None])
        return SurfaceAnchor(int(tri[0]), bary[0])

    def _cylinder(self, P: SurfaceAnchor, R: SurfaceAnchor, radius: float, lip: str):
        """(nodes (k,), weights (k,)): eq. 3.15's falloff in the cylinder P -> R and over the insertion
        behind P, scaled so the total pull (sum of weight x area scale) is the thesis cylinder's."""
        m = self.model
        x = m.rest
        p, r = P.position(m, x), R.position(m, x)
        q = x[:m.n]
        axis = r - p
        length = float(np.linalg.norm(axis))
        u = axis / length
        t = (q - p) @ u                      # |PS| (signed: < 0 behind P)
        foot = p + t[:, None] * u
        across = np.linalg.norm(q - foot, axis=1)  # |QS|
        behind = self.insertion_cm
        inside = (t >= -behind) & (t <= length) & (across < radius)
        if lip == "upper":
            inside &= m.lip >= 0
        elif lip == "lower":
            inside &= m.lip <= 0
        elif lip != "both":
            raise MuscleModelError(f"muscle lip must be 'upper', 'lower' or 'both', got {lip!r}")
        along = (np.cos(np.pi * t / length) + 1) / 2
        if behind > 0:
            along = np.where(t < 0, (np.cos(np.pi * t / behind) + 1) / 2, along)
        w = (np.cos(np.pi * across / radius) + 1) / 2 * along * inside
        area = m.area_scale[:m.n]
        pull = (w * (t >= 0) * area).sum()
        if not pull > 0:             # nothing in the thesis cylinder: the caller says so
            return np.zeros(0, int), np.zeros(0)
        w = w * (pull / (w * area).sum())
        nodes = np.nonzero(w > 1e-9)[0]
        return nodes, w[nodes]

    def _ring_weights(self, ring: list[SurfaceAnchor], radius: float, outside_fraction: float):
        """Vertices near the ring: cosine falloff over ``radius`` on the lip side (inside the ring,
        seen from the front) and over ``outside_fraction`` x radius on the skin side."""
        m = self.model
        pts = np.array([a.position(m, m.rest) for a in ring])
        samples = []
        for a, b in zip(pts, np.roll(pts, -1, axis=0)):
            s = np.linspace(0.0, 1.0, 24, endpoint=False)[:, None]
            samples.append(a + s * (b - a))
        samples = np.concatenate(samples)
        q = m.rest[:m.n]
        dist = np.sqrt(((q[:, None, :] - samples[None]) ** 2).sum(axis=2)).min(axis=1)
        reach = np.where(_inside_polygon(q[:, :2], pts[:, :2]), radius, radius * outside_fraction)
        w = (np.cos(np.pi * np.minimum(dist / reach, 1.0)) + 1) / 2
        nodes = np.nonzero(dist < reach)[0]
        return nodes, w[nodes]

    # ------------------------------------------------------------ force field for a rest frame
    def field(self, rest: np.ndarray) -> scipy.sparse.csr_matrix:
        """(3N, 19) csr: skin force (dyn, row 3i + c) per thesis force unit of each control.

        ``rest`` (3N, 3) cm: the rest configuration (jaw applied); directions follow it.
        """
        m = self.model
        U = m.params.force_unit
        rows, cols, vals = [], [], []
        for c, mus in enumerate(self.linear):
            p, r = mus.P.position(m, rest), mus.R.position(m, rest)
            u = (r - p) / np.linalg.norm(r - p)
            f = (U * mus.weight * m.area_scale[mus.nodes])[:, None] * u[None]
            rows.append((3 * mus.nodes[:, None] + np.arange(3)).ravel())
            cols.append(np.full(3 * len(mus.nodes), c))
            vals.append(f.ravel())
        s = self.sphincter
        centre = (s.corners[0].position(m, rest) + s.corners[1].position(m, rest)) / 2
        centre = centre + np.array([0.0, 0.0, s.protrusion_cm])
        q = rest[s.nodes]
        d_c = np.linalg.norm(centre - q, axis=1)
        d_m = float(np.linalg.norm(centre - s.reference.position(m, rest)))
        direction = (centre - q) * np.array([1.0, s.vertical_scale, 1.0])
        direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
        mag = U * s.gain * (d_c / d_m) * s.weight * m.area_scale[s.nodes]
        rows.append((3 * s.nodes[:, None] + np.arange(3)).ravel())
        cols.append(np.full(3 * len(s.nodes), len(self.linear)))
        vals.append((mag[:, None] * direction).ravel())
        return scipy.sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                       shape=(3 * m.n, len(self.keys))).tocsr()

    def segments(self, x: np.ndarray, rest: np.ndarray):
        """[(key, P (3,), R (3,))] in cm: P follows the skin ``x``, R stays at its rest place."""
        m = self.model
        return [(mus.key, mus.P.position(m, x), mus.R.position(m, rest)) for mus in self.linear]

    def ring(self, x: np.ndarray) -> np.ndarray:
        """(k, 3) cm: the orbicularis ring through the lip contour on the skin ``x`` (closed: first != last)."""
        m = self.model
        return np.array([a.position(m, x) for a in self.sphincter.ring])


def _inside_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(n,) bool: 2-D points inside a closed polygon (even-odd rule, vectorised over points)."""
    x, y = points[:, 0][:, None], points[:, 1][:, None]
    a, b = polygon, np.roll(polygon, -1, axis=0)
    crosses = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (crosses & (x < xi)).sum(axis=1) % 2 == 1


def skull_projection(f: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(N, 3) muscle forces with the part pushing into the skull removed (thesis C eq. 3.11)."""
    fn = np.einsum("ij,ij->i", f, normals)
    return f - np.minimum(fn, 0.0)[:, None] * normals
