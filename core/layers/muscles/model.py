"""The tissue model of thesis C (SABiom), built once per face: the static ``TissueModel``.

Geometry
    The skin surface is the canonical dense MPEG-4 template placed on the face
    (``core.layers.fap.template.densify``; level 2 = 1160 vertices, about thesis C's 1857-vertex head,
    level 3 = 4560 vertices, the full canonical face). It keeps the mouth as an open boundary, so
    the lips can part. Fascia and bone are copies of the skin moved *radially* toward a head centre
    c (the mean of the four ear contact points, 0.3 ES further back) by constant thicknesses
    (fat 3 mm, muscle 5 mm; ``resources/muscles/tissue.json``): p' = p - t (p - c) / |p - c|.
    Thesis C scaled the skin toward the centroid instead, which gives a thickness proportional to
    |p - c|. The radial offset keeps the thickness constant and still never self-intersects: it
    maps every ray from c onto itself, shrinking the radius by t, so it is injective for
    |p - c| > t (min |p - c| is about 49 mm here) and even where the face is not star-shaped
    from c (under the nose, on the lip folds) the layers keep their order along each ray.
    A normal offset would fold over in concave places (nostrils, mouth corners).

Nodes and springs
    Nodes 0..N-1 are skin, N..2N-1 fascia, 2N..3N-1 bone (column i of the three layers lies on
    one ray). Springs: every skin edge (60 dyn/cm), every fascia edge (80), skin-fascia per
    column (fat, 30) and fascia-bone per column (bone, 10). Bone nodes are fixed.

Volume preservation (thesis C eq. 3.7) over the skin-fascia prism of every skin triangle:
    q_ij = k1 (V_j - V_j0) n_i + k2 (r_ij - r_ij0). The k2 part is linear in the positions
    (r_ij = p_i - centroid_j) and is the gradient of the energy k2/2 sum |r_ij - r_ij0|^2, so it
    is assembled once as a constant sparse matrix K2 (per coordinate). The k1 part uses the right
    prism volume of thesis C (skin triangle area x mean fat-edge length) with n_i the outward
    normal on skin nodes and the inward one on fascia nodes (so an inflated prism is squeezed
    from both sides). In CGS a prism's volume change is ~1e-3 cm^3, so the k1 force is below
    0.1 dyn: kept as written, but the volume is in practice held by k2.

Restoring force (Lucero-Munhall, eq. 3.12): h_i = k (p_i - p_i0), k = 20 dyn/cm, on fascia nodes
    (thesis C's algorithm 4 applies it to the fascia layer).

Units
    Input faces are in mm. Inside the model everything is CGS (cm, g, s, dyn): positions are
    mm / 10, forces dyn, stiffness dyn/cm, mass g, damping dyn·s/cm. Offsets returned to the rig
    are mm again.

Resolution scaling (a choice the thesis leaves open): the thesis constants are per node of its
    mesh. Here they hold for a node of reference skin area A_ref = 0.2 cm^2 (the mean of the
    1160-vertex level on the default face) and every per-node quantity (mass, damping,
    restoring k, fat and bone springs, muscle force) is multiplied by s_i = A_i / A_ref, A_i the
    node's skin area (a third of its triangles). In-layer springs are not scaled (a 2-D spring
    lattice has a stiffness independent of its spacing). The prism k2 weight scales with the
    square root of the area ratio (its energy is partly in-plane, partly slip; measured best
    agreement between levels). Masses and k2 weights have a floor of half their mean (the
    template's tiny corner triangles). The smile's mouth corner then moves 6.1 mm (level 2) and
    7.1 mm (level 3); time constants (damping/mass = 60 1/s) do not change with the level.

Jaw (thesis C §3.4): a weight w_i in [0, 1] per column (1 on the lower lip and chin, fading
    inside the FAP-3 jaw region of the template, 0.4 at the mouth corners, 0 on the upper lip,
    blended smoothly into the corners' weight around each corner) and a hinge axis through two
    points behind the ears. Attached to a rig, the model takes FAP 3 open_jaw's own weights instead
    (``use_jaw_weights``: graded along the lower lip, tapered to 0 at the region's border), so both
    jaws move the skin alike. Opening by theta rotates column i (all
    three layers) by w_i theta and moves it by w_i glide(theta), the forward-down slide of the
    condyle on the articular eminence (0.4 mm forward, 0.25 mm down per degree): without it the
    chin of a depth-compressed scan swings back more than down. The rotated configuration becomes the rest configuration (anchors,
    rest lengths, bone), so a jaw angle alone is an equilibrium and muscles act on top of it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse
from scipy.sparse.csgraph import dijkstra

import resources

from core.face import Face, vertex_normals
from core.layers.fap import tables
from core.layers.fap.template import DenseTemplate, densify, mouth_side
from core.layers.muscles.specs import load_definitions
from core.subdivision import unique_edges
from core.surface_query import TriangleSet

OUTSIDE_FADE_MM = 6.0  # face skin beyond the template outline follows it, fading over this distance
# Around a mouth corner the jaw weights blend into the corner's weight within this distance (mouth
# widths, 12 mm on the default face): the lower lip's full weight and the upper lip's none met in a
# step at the corner (jaw at 8 degrees: texture stretch 10.5 there, 3.4 with the blend).
JAW_CORNER_TAPER_MW = 0.25
# The face shows the tissue's skin displacement filtered by a Gaussian of this width (mm), never
# across the mouth (upper and lower lip nodes do not mix). The spring lattice has no bending
# stiffness and the template is a fan of slivers at the mouth corners, so its solution carries
# element-scale artefacts that the face's finer, regular skin showed as they were: the kiss's
# sphincter buckled the lips into millimetre wrinkles (default face: 94 folded triangles, 35 lip
# crossings), a smile piled its strain into the corner's slivers (texture stretch 6.9). Measured on
# the default and a generated face (thesis presets): 1 mm left stretch 2.4-4.1 and 4 kiss folds;
# 1.5 mm no kiss fold or crossing, stretch 2.0-3.2; 2 mm stretch 1.9-2.9. The price is the peak of
# the displacement: 2 mm takes 0.5-0.9 mm off the kiss's protrusion (9.1 -> 8.4 mm at 8.1) and
# 1.3-1.7 mm off a smiling corner's 10-11 mm (1.5 mm: 0.4-0.6 and 0.9-1.3).
SKIN_FILTER_MM = 2.0
# The filter's Gaussian is cut at this many widths, and only the skin within that reach of a node a
# muscle or the jaw acts on is filtered (elsewhere the displacement is smooth): 232k weights cut at 3
# widths everywhere cost 0.36 ms per pose, 18 % of a playback frame; at 2.5 widths the stretch of the
# thesis presets is within 0.08 of the 3-width filter's.
FILTER_CUT = 2.5
# The filter keeps the lips apart by their side labels relaxed along the mesh (``_lip_side``: this
# many Jacobi steps; the mesh has no edge across the mouth, so the labels stay +-1 along it and fade
# only toward the corners, where the lips meet), a pair of nodes weighted by
# clip(1 + side_i side_j / OPPOSITE_SIDES, 0, 1). Hard labels left a step at the corners between the
# nodes of one lip (which average that lip only) and their unlabelled neighbours (which average both):
# stretch 2.7 there in the discreet smile; relaxed (10 steps, 0.5): 2.4, the generated face's sadness
# and disgust 2.14/2.03 -> 1.92/1.68, no lip crossing anywhere (5 steps: 2.5; 20 steps: same as 10).
LIP_SIDE_STEPS = 10
OPPOSITE_SIDES = 0.5
LAYERS = ("skin", "fascia", "bone")


# ------------------------------------------------------------------ parameters (data)
@dataclass(frozen=True)
class TissueParams:
    """Physical constants (CGS) from ``resources/muscles/tissue.json``."""

    k_skin: float            # dyn/cm, skin edges
    k_fat: float             # dyn/cm, skin-fascia per reference node
    k_fascia: float          # dyn/cm, fascia edges
    k_bone: float            # dyn/cm, fascia-bone per reference node
    mass: float              # g per reference node
    damping: float           # dyn·s/cm per reference node
    k1: float                # volume term, dyn/cm^3
    k2: float                # prism shape term, dyn/cm per reference prism vertex
    k_restore: float         # dyn/cm per reference node
    restoring_layers: tuple[str, ...]
    reference_area: float    # cm^2
    mass_floor: float        # minimum node mass and prism k2 scale, fraction of the mean
    fat_mm: float
    muscle_mm: float
    head_centre: dict
    force_unit: float        # dyn per thesis force unit
    tau: float               # s, activation time constant (eq. 3.16)


@functools.cache
def load_params() -> TissueParams:
    d = resources.get_json("muscles/tissue.json")
    k = d["spring_stiffness_dyn_per_cm"]
    return TissueParams(
        k_skin=float(k["skin"]), k_fat=float(k["fat"]), k_fascia=float(k["fascia"]), k_bone=float(k["bone"]),
        mass=float(d["node_mass_g"]), damping=float(d["node_damping_dyn_s_per_cm"]),
        k1=float(d["volume_k1"]), k2=float(d["volume_k2"]), k_restore=float(d["restoring_k_dyn_per_cm"]),
        restoring_layers=tuple(d["restoring_layers"]), reference_area=float(d["reference_node_area_cm2"]),
        mass_floor=float(d["mass_floor_fraction_of_mean"]),
        fat_mm=float(d["layer_thickness_mm"]["fat"]), muscle_mm=float(d["layer_thickness_mm"]["muscle"]),
        head_centre=d["head_centre"], force_unit=float(d["force_unit_dyn"]), tau=float(d["activation_tau_s"]),
    )


class MuscleModelError(ValueError):
    """The muscle model cannot be built on this face (missing feature points, bad definition)."""


# ------------------------------------------------------------------ feature-point anchored points
def fapu_distances(face: Face) -> dict[str, float]:
    """Full FAPU distances in mm (MW mouth width, MNS, ENS, ES, IRISD), not divided by 1024."""
    positions = {n: face.landmark_position(n) for n in face.landmark_names}
    try:
        units = tables.measure_fapu(positions)
    except ValueError as exc:
        raise MuscleModelError(f"cannot place the muscles: {exc}") from None
    return {k: v * 1024.0 for k, v in units.items() if k != "AU"}


def resolve_point(spec: dict, face: Face, fapu: dict[str, float], mirror: dict[str, str] | None = None) -> np.ndarray:
    """(3,) mm: a point spec {"at": {fp: weight}, "offset": [dx, dy, dz], "unit": FAPU} on ``face``.

    With ``mirror`` (left FP -> right FP), the spec is mirrored: FPs mapped and x offset negated.
    """
    at = spec["at"]
    total = sum(at.values())
    if abs(total - 1.0) > 1e-6:
        raise MuscleModelError(f"point weights {at} must sum to 1 (they sum to {total:g})")
    names = {n: (mirror.get(n, n) if mirror is not None else n) for n in at}
    if mirror is not None:
        unknown = [n for n in at if n not in mirror]
        if unknown:
            raise MuscleModelError(f"feature point(s) {', '.join(unknown)} have no mirror partner in muscles.json")
    missing = sorted({names[n] for n in at} - set(face.landmark_names))
    if missing:
        raise MuscleModelError(
            f"this face lacks feature point(s) {', '.join(missing)} that the muscle model needs; "
            "mark them with the landmark picker first")
    p = sum(w * face.landmark_position(names[n]) for n, w in at.items())
    offset = np.array(spec.get("offset", (0.0, 0.0, 0.0)), float)
    if offset.any():
        unit = spec.get("unit", "MW")
        if unit not in fapu:
            raise MuscleModelError(f"unknown offset unit {unit!r}; use one of {', '.join(sorted(fapu))}")
        if mirror is not None:
            offset[0] = -offset[0]
        p = p + offset * fapu[unit]
    return np.asarray(p, float)


# ------------------------------------------------------------------ the model
class TissueModel:
    """Three-layer mass-spring tissue of one face (static data; see the module docstring).

    Attributes (N skin vertices, E springs, M skin triangles; CGS unless the name says mm):
    n : N.  triangles : (M, 3) skin triangles.  rest : (3N, 3) cm, neutral positions of all nodes.
    skin_mm : (N, 3) neutral skin in mm.  area_scale : (N,) s_i = A_i / A_ref.
    springs_i, springs_j : (E,) node ids; springs_k : (E,) dyn/cm; spring_kind : (E,) 0 skin,
    1 fascia, 2 fat, 3 bone.  mass, damping : (2N,) per free node.  K_lin : (2N, 2N) csr per
    coordinate, the k2 prism matrix plus the restoring diagonal.  prisms : (M, 6) node ids.
    lip : (N,) +1 upper lip, -1 lower lip, 0 elsewhere.  jaw_weight : (N,).  hinge : (2, 3) cm.
    binding : (n_face, N) csr, face skin vertex = binding @ tissue skin (lazy).  teeth_lower : (k,) face ids.
    skin_filter(acted_on) : the filter the face sees the tissue's displacement through (lazy).
    """

    def __init__(self, face: Face, dense: DenseTemplate, params: TissueParams | None = None):
        p = params or load_params()
        self.params = p
        self.face = face
        self.dense = dense
        self.template = dense.template
        self.fapu = fapu_distances(face)
        skin_mm = np.asarray(dense.vertices, float)
        tri = np.asarray(dense.triangles, np.int64)
        N = len(skin_mm)
        self.n = N
        self.triangles = tri
        self.skin_mm = skin_mm

        # Layers: radial offset toward the head centre (see module docstring).
        self.centre_mm = resolve_point(p.head_centre, face, self.fapu)
        ray = skin_mm - self.centre_mm
        dist = np.linalg.norm(ray, axis=1)
        depth = p.fat_mm + p.muscle_mm
        if dist.min() <= 1.5 * depth:
            raise MuscleModelError(
                f"the head centre is only {dist.min():.1f} mm from the skin; the tissue layers ({depth:g} mm) "
                "need more room: check the ear feature points (10.7-10.10)")
        unit = ray / dist[:, None]
        fascia_mm = skin_mm - p.fat_mm * unit
        bone_mm = skin_mm - depth * unit
        self.rest = np.concatenate([skin_mm, fascia_mm, bone_mm]) / 10.0  # cm

        # Node areas and scale factors.
        v = skin_mm / 10.0
        tri_area = 0.5 * np.linalg.norm(np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]]), axis=1)
        node_area = np.bincount(tri.ravel(), np.repeat(tri_area / 3.0, 3), minlength=N)
        self.node_area = node_area                                 # cm^2
        self.area_scale = node_area / p.reference_area
        # A reference node has ~2 triangles. Like the masses, the prism weights have a floor: the
        # template's tiny corner triangles would otherwise carry almost no k2 and leave a pure
        # spring lattice there, which has no bending stiffness and buckles under compression
        # (several equilibria at the mouth corners in the kiss).
        # The k2 energy mixes an in-plane part (resolution independent, like the springs) and a
        # skin-over-fascia slip part (per area); scaling each prism by its edge length (the square
        # root of its area ratio) keeps the 1160 and 4560 levels within ~15 % of each other on the
        # thesis presets (area scaling: 70 %, none: 25 %; measured, see the module docstring).
        tscale = np.sqrt(tri_area / (p.reference_area / 2.0))
        self.triangle_scale = np.maximum(tscale, p.mass_floor * tscale.mean())

        # Springs.
        edges = unique_edges(tri)[0]
        col = np.arange(N)
        s = self.area_scale
        self.springs_i = np.ascontiguousarray(np.concatenate([edges[:, 0], N + edges[:, 0], col, N + col]))
        self.springs_j = np.ascontiguousarray(np.concatenate([edges[:, 1], N + edges[:, 1], N + col, 2 * N + col]))
        self.springs_k = np.ascontiguousarray(np.concatenate([
            np.full(len(edges), p.k_skin), np.full(len(edges), p.k_fascia), p.k_fat * s, p.k_bone * s]))
        self.spring_kind = np.concatenate([np.zeros(len(edges), np.int8), np.ones(len(edges), np.int8),
                                           np.full(N, 2, np.int8), np.full(N, 3, np.int8)])
        self.n_edges = len(edges)

        # Mass and damping per free node (skin and fascia of one column share its area). The
        # template has a few tiny triangles (eye and mouth corners); their nodes get at least
        # mass_floor x the mean node mass ("mass scaling" as in explicit FE codes): it changes
        # the dynamics of those few nodes only, never an equilibrium, and keeps the stable step
        # size set by the typical node. Damping follows the mass, so γ/m = 60 1/s everywhere.
        self.mass_scale = np.maximum(s, p.mass_floor * s.mean())
        self.mass = np.concatenate([p.mass * self.mass_scale] * 2)
        self.damping = np.concatenate([p.damping * self.mass_scale] * 2)

        # Linear terms: k2 prism matrix + restoring diagonal (per coordinate).
        self.prisms = np.concatenate([tri, N + tri], axis=1)                      # (M, 6)
        blk = np.eye(6) - 1.0 / 6.0
        w = p.k2 * self.triangle_scale
        self.prism_k2 = np.ascontiguousarray(w)                          # (M,) dyn/cm
        rows = np.repeat(self.prisms, 6, axis=1).ravel()
        cols = np.tile(self.prisms, (1, 6)).ravel()
        vals = (w[:, None, None] * blk[None]).reshape(len(tri), 36).ravel()
        K2 = scipy.sparse.coo_matrix((vals, (rows, cols)), shape=(2 * N, 2 * N)).tocsr()
        restore = np.zeros(2 * N)
        for layer in p.restoring_layers:
            if layer not in ("skin", "fascia"):
                raise MuscleModelError(f"restoring_layers: unknown layer {layer!r} (skin or fascia)")
            k = LAYERS.index(layer)
            restore[k * N:(k + 1) * N] = p.k_restore * s
        self.restore = restore
        self.K_lin = (K2 + scipy.sparse.diags(restore)).tocsr()

        # Labels, jaw, binding.
        self.lip = self._lip_labels()
        self.jaw_weight = self._jaw_weights()
        self.hinge = self._hinge() / 10.0
        jaw = load_definitions()["jaw"]
        self.glide_per_rad = np.degrees(np.array(jaw.get("glide_mm_per_degree", (0.0, 0.0, 0.0)), float)) / 10.0
        self.skin_set = TriangleSet(skin_mm, tri)
        self._skin_binding: scipy.sparse.csr_matrix | None = None    # skin rows only
        self._cavity_follow: scipy.sparse.csr_matrix | None = None   # (n_face, n_face), see follow_cavity
        self._binding: scipy.sparse.csr_matrix | None = None         # the two composed
        self._skin_filter: tuple | None = None      # (mask key, rows, filter, mask), see skin_filter
        self.teeth_lower = np.asarray(face.parts.get("teeth_lower", np.zeros(0, np.int64)), np.int64)
        self.fixed_parts = tuple(sorted(n for n in face.parts if n != "teeth_lower"))

    # ------------------------------------------------------------ binding to the full face
    @property
    def binding(self) -> scipy.sparse.csr_matrix:
        """(n_face, N) csr: face vertex offset = binding @ tissue skin offset (built on first use): the
        skin's rows, and the mouth cavity's when it follows the skin (:meth:`follow_cavity`)."""
        if self._binding is None:
            if self._skin_binding is None:
                self._skin_binding = self._bind()
            B = self._skin_binding
            self._binding = B if self._cavity_follow is None else (B + self._cavity_follow @ B).tocsr()
        return self._binding

    def skin_filter(self, acted_on: np.ndarray) -> tuple[np.ndarray, scipy.sparse.csr_matrix]:
        """(rows (k,), F (k, N) csr with rows summing to 1): the Gaussian filter (``SKIN_FILTER_MM``)
        the face sees the tissue's skin displacement through, u[rows] <- F @ u: node-area weighted,
        cut at ``FILTER_CUT`` widths, keeping the lips apart (``_lip_side``, ``OPPOSITE_SIDES``), for
        the skin nodes within that cut of a node in ``acted_on`` ((N,) bool; built once per mask)."""
        cached = self._skin_filter
        if cached is not None and cached[3] is acted_on:      # the same mask as last time (each tick)
            return cached[1], cached[2]
        key = np.packbits(acted_on).tobytes()
        if cached is None or cached[0] != key:
            from scipy.spatial import cKDTree

            reach = FILTER_CUT * SKIN_FILTER_MM
            sources = self.skin_mm[acted_on]
            near = np.zeros(self.n, bool)
            if len(sources):
                near = np.isfinite(cKDTree(sources).query(self.skin_mm, distance_upper_bound=reach)[0])
            rows = np.flatnonzero(near)
            F = smoothing_matrix(self.skin_mm, self.node_area, self._lip_side(), SKIN_FILTER_MM)[rows]
            cached = (key, rows, F.tocsr())
        self._skin_filter = cached[:3] + (acted_on,)
        return cached[1], cached[2]

    def _lip_side(self) -> np.ndarray:
        """(N,) the lip labels (+1 upper, -1 lower, 0 elsewhere) relaxed by ``LIP_SIDE_STEPS`` Jacobi
        steps along the mesh's edges, which do not cross the mouth: deep in a lip and along the mouth
        they stay near +-1, toward a corner, where the lips meet, they fade through 0."""
        edges = unique_edges(self.triangles)[0]
        both = (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])
        A = scipy.sparse.coo_matrix((np.ones(2 * len(edges)), both), shape=(self.n, self.n)).tocsr()
        A = A + scipy.sparse.identity(self.n, format="csr")
        A = scipy.sparse.diags(1.0 / np.asarray(A.sum(axis=1)).ravel()) @ A
        side = self.lip.astype(float)
        for _ in range(LIP_SIDE_STEPS):
            side = A @ side
        return side

    def follow_cavity(self, follow: scipy.sparse.csr_matrix | None) -> None:
        """Let the mouth cavity's lining follow the skin in front of it: ``follow`` (n_face, n_face) as
        ``FapDeformer.cavity_follow()`` (a lining vertex's row holds its closest skin point's weights,
        fading with its distance behind the skin; None: the lining stays still). Held still, the lining
        let the lips the orbicularis pulls forward and inward pass through it (default face, kiss:
        265 crossing pairs), as it did for the FAPs before they got the same rows."""
        if follow is not None and follow.shape != (self.face.n_vertices,) * 2:
            raise ValueError(f"cavity follow must have shape {(self.face.n_vertices,) * 2}, got {follow.shape}")
        self._cavity_follow = None if follow is None or follow.nnz == 0 else scipy.sparse.csr_matrix(follow)
        self._binding = None

    def use_binding(self, binding) -> bool:
        """Adopt a prebuilt binding of the face on this same template (e.g. ``FapDeformer.binding``).

        Returns False (and keeps its own) if the shape does not match."""
        if binding is None or binding.shape != (self.face.n_vertices, self.n):
            return False
        self._skin_binding = scipy.sparse.csr_matrix(binding)
        self._binding = None
        return True

    def use_jaw_weights(self, weights) -> bool:
        """Adopt (N,) jaw weights on this same template, e.g. FAP 3 open_jaw's (``FapDeformer.template_weights[3]``):
        the muscle jaw then moves the skin as the FAP jaw does, with its weights graded along the lower
        lip toward the corners and tapered to 0 at the region's border (this model's own stop at about
        half weight at the jaw's ends, a seam: jaw at 8 degrees, texture stretch 3.4 there, 2.4 with
        FAP 3's). Returns False (and keeps its own) if the shape does not match."""
        if weights is None or np.shape(weights) != (self.n,):
            return False
        w = np.clip(np.asarray(weights, float), 0.0, None)
        if w.max() <= 0:
            return False
        self.jaw_weight = w / w.max()
        return True

    # ------------------------------------------------------------ counts
    @property
    def n_nodes(self) -> int:
        return 3 * self.n

    @property
    def n_free(self) -> int:
        return 2 * self.n

    @property
    def n_springs(self) -> int:
        return len(self.springs_k)

    # ------------------------------------------------------------ jaw-dependent rest configuration
    def jaw_rotation(self, angle_rad: float) -> tuple[np.ndarray, np.ndarray]:
        """(R (N, 3, 3), pivot (3,) cm): per-column rotation by w_i·angle about the hinge axis."""
        a, b = self.hinge
        axis = (b - a) / np.linalg.norm(b - a)
        return _rotations(axis, self.jaw_weight * angle_rad), a

    def jaw_glide(self, angle_rad: float) -> np.ndarray:
        """(3,) cm: the condylar glide (translation of the whole mandible) at ``angle_rad``."""
        return self.glide_per_rad * angle_rad

    def rest_positions(self, angle_rad: float) -> np.ndarray:
        """(3N, 3) cm: the rest configuration with the jaw open by ``angle_rad`` (positive opens).

        Column i turns by w_i·angle about the hinge and moves by w_i·glide (all three layers)."""
        if angle_rad == 0.0:
            return self.rest.copy()
        R, pivot = self.jaw_rotation(angle_rad)
        shift = self.jaw_weight[:, None] * self.jaw_glide(angle_rad)[None]
        N = self.n
        out = np.empty_like(self.rest)
        for k in range(3):
            seg = self.rest[k * N:(k + 1) * N] - pivot
            out[k * N:(k + 1) * N] = np.einsum("nij,nj->ni", R, seg) + pivot + shift
        return out

    def rigid_jaw(self, points_mm: np.ndarray, angle_rad: float) -> np.ndarray:
        """(k, 3) mm: points moved rigidly with the mandible (weight 1), e.g. the lower teeth."""
        pivot, axis = self.hinge_axis()
        R = rotation(axis, angle_rad)
        p = np.asarray(points_mm, float) - pivot * 10.0
        return p @ R.T + pivot * 10.0 + self.jaw_glide(angle_rad) * 10.0

    def hinge_axis(self) -> tuple[np.ndarray, np.ndarray]:
        """(point (3,) cm, unit axis (3,)): the jaw hinge; positive angles open the mouth."""
        a, b = self.hinge
        return a, (b - a) / np.linalg.norm(b - a)

    # ------------------------------------------------------------ building helpers
    def _lip_labels(self) -> np.ndarray:
        """(N,) +1 upper lip, -1 lower lip, 0 elsewhere, from the base triangle each vertex lies in."""
        t = self.template
        support = self.dense.base_coords > 1e-12
        up = np.zeros(len(t.points), bool)
        lo = np.zeros(len(t.points), bool)
        up[[t.index(q) for q in t.upper_lip_points]] = True
        lo[[t.index(q) for q in t.lower_lip_points]] = True
        has_up = (support & up).any(axis=1)
        has_lo = (support & lo).any(axis=1)
        return np.where(has_up & ~has_lo, 1, np.where(has_lo & ~has_up, -1, 0)).astype(np.int8)

    def _jaw_weights(self) -> np.ndarray:
        spec = load_definitions()["jaw"]
        d, t = self.dense, self.template
        N = self.n
        edges = np.concatenate([self.triangles[:, [0, 1]], self.triangles[:, [1, 2]], self.triangles[:, [2, 0]]])
        adj = scipy.sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(N, N)).tocsr()
        adj = ((adj + adj.T) > 0).astype(float)
        weight = np.zeros(N)
        lower_lip = self.lip < 0
        for entry in spec["regions"]:
            region = d.in_base_triangles(entry["triangles"])
            core = np.zeros(N, bool)
            core[[t.index(c) for c in entry["core"]]] = True
            if entry.get("scale", 1.0) == 1.0:
                core |= lower_lip  # the whole lower lip moves rigidly with the mandible
            core &= region
            ids = np.nonzero(region)[0]
            sub = adj[ids][:, ids]
            sources = np.nonzero(core[ids])[0]
            if not len(sources):
                continue
            dist = dijkstra(sub, indices=sources, unweighted=True, min_only=True)
            reach = np.isfinite(dist)
            dmax = max(float(dist[reach].max()), 1.0)
            w = np.where(reach, np.exp(-np.where(reach, dist, 0.0) ** 2 / (2.0 * dmax * entry["w"])), 0.0)
            weight[ids] = np.maximum(weight[ids], w * entry.get("scale", 1.0))
        weight[self.lip > 0] = 0.0  # the upper lip never follows the jaw
        corners = [t.index(c) for c in spec["corners"]]
        corner_weight = spec["corner_weight"]
        # Around each mouth corner the weights blend into the corner's: the lower lip (weight 1) and
        # the upper lip (0) meet there a fraction of a millimetre apart (JAW_CORNER_TAPER_MW).
        reach = JAW_CORNER_TAPER_MW * self.fapu["MW"]
        near = np.linalg.norm(self.skin_mm[:, None, :] - self.skin_mm[corners][None], axis=2).min(axis=1)
        s = np.clip(near / reach, 0.0, 1.0)
        blend = s * s * (3.0 - 2.0 * s)
        weight = corner_weight + (weight - corner_weight) * blend
        return weight

    def _hinge(self) -> np.ndarray:
        spec = load_definitions()["jaw"]["hinge"]
        a = resolve_point(spec["left"], self.face, self.fapu)
        b = resolve_point(spec["right"], self.face, self.fapu)
        # Positive rotation about (right - left)... oriented so that positive angles open the mouth.
        axis = b - a
        lip = self.face.landmark_position("8.2") if "8.2" in self.face.landmark_names else self.skin_mm.mean(axis=0)
        test = np.cross(axis, lip - a)  # velocity of the lower lip for a positive rotation
        if test[1] > 0:  # would move the lip up: flip the axis
            a, b = b, a
        return np.array([a, b])

    def _bind(self) -> scipy.sparse.csr_matrix:
        """(n_face, N) barycentric weights of face skin vertices on the tissue skin.

        Lip vertices bind only to triangles of their own lip (plus neutral ones), so the lower lip
        never drags the upper one; skin beyond the template fades out over OUTSIDE_FADE_MM.
        Named parts (eyeballs, teeth, mouth cavity) get no rows.
        """
        face = self.face
        n, N = face.n_vertices, self.n
        in_part = np.zeros(n, bool)
        for idx in face.parts.values():
            in_part[idx] = True
        skin = np.nonzero(~in_part)[0]
        side = mouth_side(face, skin)
        lip_t = self.lip[self.triangles]
        tri_upper = (lip_t > 0).any(axis=1)
        tri_lower = (lip_t < 0).any(axis=1)
        rows, cols, vals = [], [], []
        for label, allowed in ((0, np.ones(len(self.triangles), bool)), (1, ~tri_lower), (-1, ~tri_upper)):
            sel = skin[side == label]
            if not len(sel):
                continue
            tri_ids = np.nonzero(allowed)[0]
            ts = TriangleSet(self.skin_mm, self.triangles[tri_ids])
            # 12 candidate triangles: exact for every vertex near the template (FapDeformer uses 24;
            # the only differences are vertices far outside the outline, which fade to 0 anyway).
            pos, t_loc, bary = ts.closest(face.vertices[sel], k=12, widen=False)
            dist = np.linalg.norm(pos - face.vertices[sel], axis=1)
            fade = np.exp(-(np.maximum(dist - 1.0, 0.0) / OUTSIDE_FADE_MM) ** 2)
            corners = self.triangles[tri_ids[t_loc]]
            rows.append(np.repeat(sel, 3))
            cols.append(corners.ravel())
            vals.append((bary * fade[:, None]).ravel())
        B = scipy.sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                    shape=(n, N)).tocsr()
        B.eliminate_zeros()
        return B

    def skin_normals(self, positions_cm: np.ndarray) -> np.ndarray:
        """(N, 3) outward unit normals of the skin nodes for (>= N, 3) positions."""
        return vertex_normals(positions_cm[:self.n], self.triangles)

    def summary(self) -> str:
        return (f"{self.n} skin vertices x 3 layers = {self.n_nodes} nodes ({self.n_free} free), "
                f"{self.n_springs} springs, {len(self.triangles)} prisms")


# ------------------------------------------------------------------ helpers
def smoothing_matrix(points: np.ndarray, area: np.ndarray, side: np.ndarray, width: float) -> scipy.sparse.csr_matrix:
    """(n, n) csr with rows summing to 1: row i averages the points within ``FILTER_CUT`` x ``width`` of point i
    ((n, 3) mm) with Gaussian weights of that width times their ``area`` (n,) times
    clip(1 + side_i side_j / OPPOSITE_SIDES, 0, 1), ``side`` (n,) in [-1, 1] the lip each point is on
    (+1 upper, -1 lower, 0 neither): points of the other lip are left out. ``width`` <= 0: the identity."""
    n = len(points)
    if width <= 0:
        return scipy.sparse.identity(n, format="csr")
    from scipy.spatial import cKDTree

    pairs = cKDTree(points).query_pairs(FILTER_CUT * width, output_type="ndarray")
    i = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)])
    j = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n)])
    side = np.asarray(side, float)
    apart = np.clip(1.0 + side[i] * side[j] / OPPOSITE_SIDES, 0.0, 1.0)
    keep = apart > 0
    i, j, apart = i[keep], j[keep], apart[keep]
    w = np.exp(-np.sum((points[i] - points[j]) ** 2, axis=1) / (2.0 * width * width)) * np.maximum(area[j], 1e-12) * apart
    W = scipy.sparse.coo_matrix((w, (i, j)), shape=(n, n)).tocsr()
    return (scipy.sparse.diags(1.0 / np.asarray(W.sum(axis=1)).ravel()) @ W).tocsr()


def _rotations(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations by ``angles`` (n,) rad about the unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s = np.sin(angles)[:, None, None]
    c = (1.0 - np.cos(angles))[:, None, None]
    return np.eye(3)[None] + s * K[None] + c * (K @ K)[None]


def rotation(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` rad about unit ``axis``."""
    return _rotations(np.asarray(axis, float), np.array([float(angle)]))[0]


def dense_template(face: Face, level: int = 3) -> DenseTemplate:
    """The canonical template on ``face`` at subdivision ``level`` (2: 1160 vertices, 3: 4560)."""
    from core.layers.fap.template import load_template

    steps = load_template().steps
    if not 1 <= level <= len(steps):
        raise ValueError(f"template level must be 1..{len(steps)} (2 = 1160 vertices, 3 = 4560), got {level}")
    return densify(face, steps=steps[:level])
