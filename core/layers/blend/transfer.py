"""Transfer of an expression library from its base person to another registered face (the model).

Both faces must share the canonical topology (register both with the same template). Two methods:

``"bbox"`` — thesis A eqs. 4.4–4.6: the model's neutral is aligned rigidly onto the base's
    (ICP; with known correspondence, Procrustes: :func:`core.layers.blend.library.rigid_align`), and
    each displacement is scaled per axis by the ratio of the two bounding boxes,
    Δx = Δx_base · X_model / X_base (same for y, z); rotated back into the model's frame.

``"deformation"`` — deformation transfer (Sumner & Popović 2004), which adapts the displacements
    to the model's local shape: every triangle j of the base deforms by a gradient
    Q_j = [e1' e2' n'] [e1 e2 n]⁻¹ (3 × 3, n the scaled normal, Sumner's fourth vertex); the model's
    displaced vertices x' minimise

        Σ_j a_j ‖E_j(x') − Q_j E_j(x)‖²_F  +  λ Σ_i m_i ‖(x'_i − x_i) − d_i^bbox‖²

    (E_j the model's two edge vectors of triangle j, a_j its area, m_i vertex areas; the λ term,
    ``anchor`` × mean triangle area / mean vertex area, fixes the translation null space and the low
    frequencies from the bbox result). Triangles the pose flips or crushes (area ratio outside
    [``min_area_ratio``, 1/``min_area_ratio``]) follow the bbox result's edges. Both defaults (1 and
    0.7) were chosen by sweeping anchor 1e-4 … 3 and the ratio 0.25 … 0.9 on the pairs of
    benchmarks/bench_transfer.py itself (no held-out set): registered scans slide along the skin, so
    their per-triangle gradients are noisy and a weak anchor is worse than bbox (1.28 vs 1.15 mm). The normal equations, a sparse SPD Poisson system (n × n, the same matrix for
    x, y, z and every pose), are factorised once per model (:class:`DeformationTransfer`).

:class:`LocalAffineTransfer` (per-vertex affine maps fitted to the two faces' neighbourhoods) is kept
for comparison only: benchmarks/bench_transfer.py measures it worse than both (registration noise in
the neighbourhood fits), so it is not one of :data:`METHODS`.

``"fap_units"`` — MPEG-4's own rule for moving animation between faces: a FAP moves its feature point
    by its value in the face's FAP units (MNS, MW, ENS, ES, IRISD, measured on each neutral), so a
    displacement in a FAP's influence region scales, along that FAP's axis, by the ratio of the two
    faces' units. At each vertex and axis the ratios of the FAPs whose regions reach it are averaged
    by their region weights (the template's FAT, on the canonical face), falling back to the
    bounding-box ratio where no region reaches (weight ``FALLBACK_WEIGHT``). The scaling is done in
    the base's frame, after the same rigid alignment as ``"bbox"``. On the synthetic database the
    faces' units differ from their bounding boxes' ratios by 10-25 % (person 1 -> 2: eye separation
    +13.7 % while the head's width -13 %): a head's size says little about its mouth's.

Every result records the method used (``TransferResult.method``; ``ExpressionLibrary.transfer``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from core.layers.blend.library import ExpressionLibrary, LibraryError, _points, rigid_align

__all__ = ["METHODS", "METHOD_NAMES", "TransferResult", "DeformationTransfer", "fap_unit_scales", "region_weights_of",
           "transfer_bbox", "transfer_displacements", "transfer_fap_units", "transfer_library"]

METHODS = ("bbox", "deformation", "fap_units")
# What each method is called where a person reads it (the dock's line, a transferred library's base).
METHOD_NAMES = {"bbox": "bounding-box scaling", "deformation": "deformation transfer",
                "fap_units": "FAP-unit scaling"}
# Weight of the bounding-box ratio against the FAP regions' ratios at a vertex (region weights are
# 0..1 per FAP): only where no region reaches does the bounding box decide. Chosen, not fitted
# (0.05 / 0.2 / 1 gave 0.882 / 0.883 / 0.890 mm on bench_transfer's synthetic pairs).
FALLBACK_WEIGHT = 0.1


@dataclass(frozen=True)
class TransferResult:
    """displacements (k, n, 3) mm in the model's frame; method: "bbox" or "deformation"."""

    displacements: np.ndarray
    method: str


def _bbox_scale_and_frame(base_rest: np.ndarray, model_rest: np.ndarray):
    """(R, per-axis scale (3,)): R rotates the model onto the base (rigid, robust Procrustes)."""
    aligned, R, _ = rigid_align(model_rest, base_rest, robust=False)
    size_base = base_rest.max(0) - base_rest.min(0)
    size_model = aligned.max(0) - aligned.min(0)
    if np.any(size_base <= 0):
        raise LibraryError("the base face is flat along an axis: its bounding box cannot scale displacements")
    return R, size_model / size_base


def transfer_bbox(base_rest, displacements, model_rest) -> np.ndarray:
    """(k, n, 3) mm: thesis eqs. 4.4–4.6 (see the module docstring).

    base_rest, model_rest : (n, 3) mm; displacements : (k, n, 3) mm in the base's frame."""
    b = _points(base_rest, "base rest")
    m = _points(model_rest, "model rest", len(b))
    d = np.asarray(displacements, float).reshape(-1, len(b), 3)
    R, s = _bbox_scale_and_frame(b, m)
    # scaled in the base's frame, then rotated back into the model's: d' = Rᵀ (s ⊙ d)
    return (d * s) @ R


def canonical_fapu(rest: np.ndarray, template: str) -> dict[str, float]:
    """FAP units (mm per unit) of a canonical face (n, 3) mm of ``template``: its base vertex i is the
    template's point i (``core.registration.correspondence``), so the feature points are vertices."""
    from core.layers.fap import tables
    from core.registration.templates import get_template

    base = get_template(template).base
    if len(rest) < len(base.points):
        raise LibraryError(f"a face of {len(rest)} vertices is not a canonical face of template {template!r}")
    try:
        return tables.measure_fapu({name: rest[base.index(name)] for name in base.feature_points})
    except ValueError as exc:
        raise LibraryError(f"the FAP units of a face cannot be measured: {exc}") from exc


def region_weights_of(canonical_vertices, template: str) -> dict[int, np.ndarray]:
    """{FAP number: (n,) weight 0..1} of each FAP's influence region on a canonical face (n, 3) mm of
    ``template``: the FAT's template weights (``core.layers.fap.fat.FapDeformer``) of that face. A rig
    already holds them (``deformer.template_weights``, on its dense template): pass those instead."""
    from core.face import Face
    from core.layers.fap.fat import FapDeformer
    from core.registration.correspondence import canonical_triangles, with_canonical_landmarks

    face = with_canonical_landmarks(Face(np.asarray(canonical_vertices, float), canonical_triangles(template)))
    return FapDeformer(face).template_weights


def fap_unit_scales(base_rest, model_rest, region_weights, template: str = "mpeg4_80") -> np.ndarray:
    """(n, 3) per-vertex, per-axis scale of a displacement moved from the base onto the model by the
    ``"fap_units"`` method (see the module docstring), in the base's frame.

    base_rest, model_rest : (n, 3) mm canonical faces of ``template``; region_weights : {FAP number:
    (n,) weight} on those faces (:func:`region_weights_of`)."""
    b = _points(base_rest, "base rest")
    return _fap_unit_frame_and_scales(b, _points(model_rest, "model rest", len(b)), region_weights, template)[1]


def _fap_unit_frame_and_scales(b: np.ndarray, m: np.ndarray, region_weights, template: str):
    """(R, (n, 3) scales): :func:`fap_unit_scales` and the rotation of the model onto the base."""
    from core.layers.fap import tables

    R, bbox = _bbox_scale_and_frame(b, m)
    unit_base, unit_model = canonical_fapu(b, template), canonical_fapu(m @ R.T, template)
    num = FALLBACK_WEIGHT * np.tile(bbox, (len(b), 1))
    den = np.full((len(b), 3), FALLBACK_WEIGHT)
    for number, weights in region_weights.items():
        spec = tables.fap_spec(number)
        if spec.axis is None or spec.is_rotation:
            continue
        w = np.abs(np.asarray(weights, float).reshape(-1))
        if len(w) != len(b):
            raise LibraryError(f"FAP {number}'s region weights cover {len(w)} vertices, the faces {len(b)}")
        along = np.abs(np.asarray(spec.axis, float))
        ratio = unit_model[spec.unit] / unit_base[spec.unit]
        num += ratio * w[:, None] * along
        den += w[:, None] * along
    return R, num / den


def transfer_fap_units(base_rest, displacements, model_rest, region_weights, template: str = "mpeg4_80") -> np.ndarray:
    """(k, n, 3) mm: the ``"fap_units"`` transfer (see the module docstring); arguments as
    :func:`fap_unit_scales`, displacements (k, n, 3) mm in the base's frame."""
    b = _points(base_rest, "base rest")
    m = _points(model_rest, "model rest", len(b))
    d = np.asarray(displacements, float).reshape(-1, len(b), 3)
    if not np.all(np.isfinite(d)):
        raise LibraryError("displacements hold NaN or infinite values")
    R, scales = _fap_unit_frame_and_scales(b, m, region_weights, template)
    return (d * scales) @ R


def _frames(v: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(T, 3, 3) columns [e1, e2, n/√|n|] of each triangle (Sumner's fourth vertex)."""
    a, b, c = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
    e1, e2 = b - a, c - a
    n = np.cross(e1, e2)
    n = n / np.sqrt(np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))
    return np.stack([e1, e2, n], axis=2)


class DeformationTransfer:
    """Deformation transfer onto one model face, factorised once (see the module docstring).

    base_rest, model_rest : (n, 3) mm on the same canonical topology; triangles : (T, 3).
    ``transfer(displacements (k, n, 3)) -> (k, n, 3)`` mm in the model's frame.
    """

    def __init__(self, base_rest, model_rest, triangles, *, anchor: float = 1.0, min_area_ratio: float = 0.7):
        self.base = _points(base_rest, "base rest")
        self.model = _points(model_rest, "model rest", len(self.base))
        tri = np.asarray(triangles, np.int64)
        if tri.ndim != 2 or tri.shape[1] != 3 or tri.min() < 0 or tri.max() >= len(self.base):
            raise LibraryError(f"triangles must be (T, 3) indices below {len(self.base)}")
        self.triangles = tri
        n, T = len(self.base), len(tri)
        self.R, self.scale = _bbox_scale_and_frame(self.base, self.model)
        # the model in the base's frame (rotation only: gradients ignore translation)
        self._model_b = self.model @ self.R.T
        self.min_ratio = float(min_area_ratio)
        frames_base = _frames(self.base, tri)
        self._inv_base_edges = np.stack([frames_base[:, :, 0], frames_base[:, :, 1]], axis=1)   # (T, 2, 3)
        det = np.abs(np.linalg.det(frames_base))
        self._ok = det > 1e-12 * max(float(np.median(det)), 1e-300)
        self._inv_base = np.zeros_like(frames_base)
        self._inv_base[self._ok] = np.linalg.inv(frames_base[self._ok])
        e = self._model_b[tri]
        self._edges = np.stack([e[:, 1] - e[:, 0], e[:, 2] - e[:, 0]], axis=1)    # (T, 2, 3)
        area = 0.5 * np.linalg.norm(np.cross(self._edges[:, 0], self._edges[:, 1]), axis=1)
        area = np.where(self._ok, area, 0.0)
        # K: (2T, n) edge operator, rows e1 = x1 - x0, e2 = x2 - x0
        rows = np.repeat(np.arange(2 * T), 2)
        cols = np.column_stack([tri[:, 1], tri[:, 0], tri[:, 2], tri[:, 0]]).reshape(-1)
        vals = np.tile([1.0, -1.0], 2 * T)
        self._K = scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(2 * T, n))
        self._W = scipy.sparse.diags(np.repeat(area, 2))
        mass = np.zeros(n)
        np.add.at(mass, tri.reshape(-1), np.repeat(area / 3.0, 3))
        lam = anchor * float(area.mean()) / max(float(mass.mean()), 1e-300)
        self._M = lam * np.maximum(mass, 1e-12 * mass.max())
        A = (self._K.T @ self._W @ self._K + scipy.sparse.diags(self._M)).tocsc()
        self._solve = scipy.sparse.linalg.factorized(A)

    def transfer(self, displacements) -> np.ndarray:
        d = np.asarray(displacements, float).reshape(-1, len(self.base), 3)
        if not np.all(np.isfinite(d)):
            raise LibraryError("displacements hold NaN or infinite values")
        out = np.empty_like(d)
        bbox = (d * self.scale)            # the thesis's transfer, in the base's frame (anchor target)
        tri = self.triangles
        n0 = np.cross(self._inv_base_edges[:, 0], self._inv_base_edges[:, 1])
        a0 = np.linalg.norm(n0, axis=1)
        for k in range(len(d)):
            posed = self.base + d[k]
            deformed = _frames(posed, tri)
            Q = deformed @ self._inv_base                                     # (T, 3, 3)
            target = np.einsum("tij,tej->tei", Q, self._edges) - self._edges  # (T, 2, 3) edge change
            # Triangles the pose folds, flips or crushes (registration noise: a sliding projection)
            # carry no usable gradient: they follow the bbox transfer's edges instead.
            n1 = np.cross(deformed[:, :, 0], deformed[:, :, 1])
            ratio = np.linalg.norm(n1, axis=1) / np.maximum(a0, 1e-300)
            bad = ~self._ok | (np.einsum("ij,ij->i", n1, n0) <= 0) | (ratio < self.min_ratio) | (ratio > 1 / self.min_ratio)
            if bad.any():
                b = bbox[k][tri[bad]]
                target[bad] = np.stack([b[:, 1] - b[:, 0], b[:, 2] - b[:, 0]], axis=1)
            rhs = self._K.T @ (self._W @ target.reshape(-1, 3)) + self._M[:, None] * bbox[k]
            sol = np.column_stack([self._solve(rhs[:, c]) for c in range(3)])
            out[k] = sol @ self.R                                           # back into the model's frame
        return out


class LocalAffineTransfer:
    """Transfer by the local shape ratio around each vertex (built once per model).

    At base vertex i, the best affine map J_i (3 × 3) from the base's neighbourhood to the model's
    (same vertices; model aligned rigidly onto the base) is fitted by Gaussian-weighted least
    squares over the ``neighbours`` nearest vertices (σ = ``sigma_mm``), regularised toward the
    bounding-box scale S (weight ``prior`` × the mean eigenvalue of the weighted covariance):

        J_i = (Σ_j w_ij y_ij x_ijᵀ + ε S) (Σ_j w_ij x_ij x_ijᵀ + ε I)⁻¹     x, y centred neighbour offsets

    and a displacement moves as d'_i = Rᵀ J_i d_i. Along the surface normal (where a surface patch
    says nothing) J falls back to S; on a uniformly scaled copy of the base J = S exactly.
    """

    def __init__(self, base_rest, model_rest, *, sigma_mm: float = 12.0, neighbours: int = 96, prior: float = 0.05):
        from scipy.spatial import cKDTree

        self.base = _points(base_rest, "base rest")
        self.model = _points(model_rest, "model rest", len(self.base))
        self.R, self.scale = _bbox_scale_and_frame(self.base, self.model)
        aligned, _, _ = rigid_align(self.model, self.base, robust=False)
        k = min(int(neighbours), len(self.base))
        dist, idx = cKDTree(self.base).query(self.base, k=k)
        w = np.exp(-0.5 * (dist / float(sigma_mm)) ** 2)
        w /= w.sum(axis=1, keepdims=True)
        X = self.base[idx]
        Y = aligned[idx]
        X = X - np.einsum("nk,nkd->nd", w, X)[:, None]
        Y = Y - np.einsum("nk,nkd->nd", w, Y)[:, None]
        Cxx = np.einsum("nk,nki,nkj->nij", w, X, X)
        Cyx = np.einsum("nk,nki,nkj->nij", w, Y, X)
        eps = float(prior) * np.trace(Cxx, axis1=1, axis2=2) / 3.0
        S = np.diag(self.scale)
        self.J = np.linalg.solve(np.transpose(Cxx + eps[:, None, None] * np.eye(3), (0, 2, 1)),
                                 np.transpose(Cyx + eps[:, None, None] * S, (0, 2, 1))).transpose(0, 2, 1)

    def transfer(self, displacements) -> np.ndarray:
        d = np.asarray(displacements, float).reshape(-1, len(self.base), 3)
        if not np.all(np.isfinite(d)):
            raise LibraryError("displacements hold NaN or infinite values")
        return np.einsum("nij,knj->kni", self.J, d) @ self.R


def transfer_displacements(base_rest, displacements, model_rest, triangles=None, *,
                           method: str = "deformation", template: str = "mpeg4_80",
                           region_weights: dict | None = None) -> TransferResult:
    """Displacements (k, n, 3) of the base moved onto the model by ``method`` (:data:`METHODS`;
    "deformation" needs the canonical ``triangles``, "fap_units" the model's FAP ``region_weights``,
    measured here from the model when not given)."""
    if method == "bbox":
        return TransferResult(transfer_bbox(base_rest, displacements, model_rest), "bbox")
    if method == "deformation":
        if triangles is None:
            raise LibraryError("deformation transfer needs the canonical triangles of the two faces")
        return TransferResult(DeformationTransfer(base_rest, model_rest, triangles).transfer(displacements),
                              "deformation")
    if method == "fap_units":
        weights = region_weights if region_weights is not None else region_weights_of(model_rest, template)
        return TransferResult(transfer_fap_units(base_rest, displacements, model_rest, weights, template), "fap_units")
    raise LibraryError(f"unknown transfer method {method!r}; choose one of {', '.join(METHODS)}")


def transfer_library(library: ExpressionLibrary, model_rest, triangles=None, *, method: str = "deformation",
                     base: str = "", region_weights: dict | None = None) -> ExpressionLibrary:
    """``library`` moved onto another registered face ``model_rest`` (n, 3) mm: a new library whose
    rest is the model and whose ``transfer`` field names the method used."""
    model = _points(getattr(model_rest, "vertices", model_rest), "model rest", library.n_vertices)
    if triangles is None and hasattr(model_rest, "triangles"):
        triangles = model_rest.triangles
    template = library.template if library.template != "custom" else "mpeg4_80"
    result = transfer_displacements(library.rest, library.displacements, model, triangles, method=method,
                                    template=template, region_weights=region_weights)
    return library.replace(rest=model, displacements=result.displacements, transfer=result.method,
                           base=base or f"{library.base or 'the base person'}, transferred by "
                                        f"{METHOD_NAMES[result.method]}")
