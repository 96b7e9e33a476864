"""Structural landmark matching (thesis A §3.2, Algorithm 1) with Mimica's refinements.

The model is a face whose landmarks are known (a template's points); the input is a scan already
rigidly aligned to it (ICP, done by ``pipeline.detect_landmarks``), so everything here works in
the model's frame, in mm.

Thesis part (kept as the thesis defines it):

* candidates: Shi-Tomasi corners of the input's texture lifted to 3-D (``candidates``);
* seeds: the Colombo nose tip and inner eye corners (HK classification) are matched first;
* cost E = λ·d_A + (1 − λ)·d_S (3.1); d_A = λ_A·d_A,UV + (1 − λ_A)·d_A,HK (3.2) with RGB
  distances of texture colour and HK-class colour divided by C_A = √3 (colours in [0, 1]);
  d_S = mean over the graph edges of the vertex of c_vec = λ_S·d_ang + (1 − λ_S)·d_mod (3.3,
  3.4), d_ang = |cos θ − 1| / 2, d_mod = min(||e_m| − |e_d|| / C_S, 1) with C_S = the model's
  median graph edge length;
* the deformation graph G_d starts as a copy of G_m and each accepted match replaces its vertex;
* greedy assignment: for each model vertex in turn the cheapest remaining candidate, which is
  then removed (Algorithm 1). Vectorised over candidates (one numpy pass per model vertex).
* order (the thesis does not say): seeds first, then breadth-first over G_m from the seeds,
  ties broken by distance from the seeds, so each vertex is matched after its neighbours.

Mimica's additions (each can be switched off in :class:`MatchParams`; all on by default because
the evaluation showed they are needed to reach the accuracy goals):

* ``propagate``: unmatched vertices of G_d follow the matched ones (Gaussian-weighted mean of the
  matched displacements over shortest-path distances along G_m, σ = ``sigma`` × face scale; graph
  distances respect the mouth opening), so the structure cost of a mouth vertex sees where the
  jaw has gone instead of the model's closed mouth;
* ``radius`` / ``position_weight``: candidates farther than ``radius`` × face scale from the
  vertex's predicted position (its G_d position) are not considered, and the normalised distance
  is added as a cost term: E' = (1 − w)·E + w·min(d / R, 1);
* ``refine``: each match is then refined on the scan surface (not only among candidates): a
  frontal raster of the aligned scan (0.75 mm pixels; colour, and the surface normal for shape)
  is searched around the match for the model's patch around the landmark (normalised
  cross-correlation, ``cv2.matchTemplate``), with a mild quadratic pull towards the structural
  prediction; the pixel's triangle and barycentric coordinates give the surface point. Round 2
  searches again around each point's prediction from the others (NCC-weighted); inner-lip and
  lid-margin points compare only the half patch on their own lip/lid (the other half may be the
  opening); lower-lip points are searched below their upper-lip partner, pulled to where the jaw
  (chin points) went; where the scan ends inside the patch (outline) the NCC is not trusted and
  the structural prediction is used;
* ``mouth_opening``: an open mouth seen from the front is an occluding edge. Along the column of
  each inner-lip point (placed at the model's horizontal fraction between the ends of the
  opening, measured on the row through its middle) the frontal depth steps back just below the
  upper lip and forward again just above the lower lip (or the scan has a hole there): the upper
  inner-lip points go to the last row above the opening, the lower ones to the first row below,
  so the order upper outer > upper inner > opening > lower inner > lower outer holds. Outer-lip
  points on the wrong side of the opening and chin points (2.10, 2.1, 2.11, 2.12) found less than
  half their model distance below the lower lip are searched again on the right side. A closed
  mouth (no step, or an opening under 1.5 mm) leaves the patch-search result, except that a lower
  inner-lip point found on the lower outer lip (pressed lips) goes back to the seam, at the
  model's offset below the upper outer lip;
* ``lid_depth``: a doubtful upper-lid point (confidence < ``LID_RECHECK``; brows lowered onto the
  lid, as in anger, fit the lid patch) goes to the foot of the lid's depth fall onto the eyeball,
  searched in its column above the lower-lid point;
* ``steep_prediction``: where the model's surface turns sideways away from the frontal view
  (normal z < ``STEEP_NZ`` and |x| >= |y|: temples, jaw-angle and face-border points, outer brow
  ends; not the mouth and eye points, textured contours that curl away from the view) the frontal
  raster is
  foreshortened and nearly textureless, so the patch search lands a few mm off laterally, which on
  a steep side is 10-20 mm along the surface (across people). These points are re-predicted from
  the confident non-steep, non-outline matches (confidence > ``ANCHOR_CONFIDENCE``; the same
  graph-distance Gaussian propagation as ``propagate``) and put on the scan: outline points at the
  closest scan point (the prediction's depth is trusted: the face border is where the side turns
  away), the others (brow ends) at the scan surface seen at the prediction's frontal pixel
  (measured on 3 synthetic people: closest point is better for the outline, the frontal ray for
  the brows). Their source is "prediction" and their evidence 0;
* no texture: geometry candidates (farthest-point samples) and appearance from HK and shape
  only; the caller reports it.

Confidence (0..1, heuristic, not a probability): the mean of the NCC peak (clipped to [0, 1])
and exp(−(d / 0.1·scale)²) where d is the distance of the final point from its structural
prediction (from the other matches); without refinement the NCC term is replaced by the greedy
cost margin between the best and the second-best candidate elsewhere (> 0.1 × scale away).

Face scale: the distance between the outer eye corners 3.7 and 3.12 of the model (91 mm on the
default face); without them, 0.66 × the model's skin bounding-box width.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..face import Face, SurfacePoint
from .templates import LandmarkTemplate

C_A = float(np.sqrt(3.0))   # RGB distance of colours in [0, 1] is at most sqrt(3)
# One HK map per scan serves both the HK appearance term and the Colombo seeds, which need the
# coarser 5 mm smoothing (curvature.colombo_seed_vertices); computing both would cost ~1 s more.
HK_SMOOTHING_MM = 5.0


class MatchingError(ValueError):
    """Matching cannot run (bad parameters, no candidates)."""


@dataclass(frozen=True)
class MatchParams:
    """Parameters of the structural matcher. λ's as in thesis A (3.1, 3.2, 3.4).

    lam : λ, appearance (1) vs structure (0).
    lam_a : λ_A, texture colour (1) vs HK class colour (0).
    lam_s : λ_S, edge angle (1) vs edge length (0).
    candidates, quality, min_distance_px : Shi-Tomasi n, l, d.
    radius : candidate search radius around the predicted position, × face scale (0 = no limit).
    position_weight : weight w of the distance-to-prediction cost (0 = the thesis cost).
    propagate : unmatched G_d vertices follow the matched ones.
    seeds : match the Colombo seeds first.
    refine : patch refinement on the scan surface; refine_radius × face scale; patch_mm side.
    pixel_mm : frontal raster pixel size.
    mouth_opening : put inner-lip points on the edges of a visible mouth opening (depth steps).
    steep_prediction : points on steep sides follow the confident matches (see the module docstring).
    lid_depth : a doubtful upper-lid point goes to the foot of the lid's depth fall (module docstring).
    """

    lam: float = 0.0     # sweep on 3 synthetic people (evaluate_landmarks): best over all tests at 0.0
    lam_a: float = 0.5
    lam_s: float = 0.5
    candidates: int = 1500
    quality: float = 0.003
    min_distance_px: float = 5.0
    radius: float = 0.3
    position_weight: float = 0.3
    propagate: bool = True
    seeds: bool = True
    refine: bool = True
    refine_radius: float = 0.1
    patch_mm: float = 14.0
    pixel_mm: float = 0.75
    pull: float = 0.15
    sigma: float = 0.2
    mouth_opening: bool = True
    steep_prediction: bool = True
    lid_depth: bool = True

    def __post_init__(self):
        for name in ("lam", "lam_a", "lam_s", "position_weight", "pull"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise MatchingError(f"{name} must be in [0, 1], got {v}")
        for name in ("radius", "refine_radius"):
            if not 0.0 <= getattr(self, name) <= 5.0:
                raise MatchingError(f"{name} must be in [0, 5] (x face scale), got {getattr(self, name)}")
        if self.candidates < 1:
            raise MatchingError(f"candidates must be >= 1, got {self.candidates}")
        if not (0.1 <= self.pixel_mm <= 5.0 and 2.0 <= self.patch_mm <= 60.0):
            raise MatchingError("pixel_mm must be in [0.1, 5] and patch_mm in [2, 60]")


# ------------------------------------------------------------------ frontal raster
@dataclass
class FrontalRaster:
    """A frontal (−z) orthographic raster of a face in the model frame.

    x0, y0 : model-frame coordinates of the centre of pixel (0, 0) (row 0 is the *top*, largest y).
    pixel : mm. triangle (H, W) face triangle or −1; bary (H, W, 3); channels (H, W, C) float32
    normalised to zero mean / unit std over the covered pixels (0 where uncovered).
    """

    x0: float
    y0: float
    pixel: float
    triangle: np.ndarray
    bary: np.ndarray
    channels: np.ndarray
    depth: np.ndarray | None = None    # (H, W) float, model-frame z of the surface, mm (NaN uncovered)

    def to_pixel(self, xyz) -> np.ndarray:
        """(k, 2) float (col, row) of model-frame points (k, 3)."""
        p = np.atleast_2d(np.asarray(xyz, float))
        return np.column_stack([(p[:, 0] - self.x0) / self.pixel, (self.y0 - p[:, 1]) / self.pixel])


@dataclass(frozen=True)
class Grid:
    x0: float
    y0: float
    pixel: float
    width: int
    height: int


def grid_for(points: np.ndarray, pixel: float, margin: float = 15.0) -> Grid:
    lo, hi = points.min(axis=0) - margin, points.max(axis=0) + margin
    w = int(np.ceil((hi[0] - lo[0]) / pixel)) + 1
    h = int(np.ceil((hi[1] - lo[1]) / pixel)) + 1
    return Grid(float(lo[0]), float(hi[1]), pixel, w, h)


def frontal_raster(face: Face, rays, to_model: np.ndarray, grid: Grid, *, texture: bool = True) -> FrontalRaster:
    """Rasterise ``face`` seen from +z of the model frame; ``to_model`` (4, 4) maps face -> model.

    ``rays`` is a ``correspondence.SurfaceRays`` over the face's own (unmoved) vertices: the rays
    are moved into the face's frame instead of moving the face (one Embree scene per scan)."""
    from .correspondence import _barycentric

    cols, rows = np.meshgrid(np.arange(grid.width), np.arange(grid.height))
    x = grid.x0 + cols.ravel() * grid.pixel
    y = grid.y0 - rows.ravel() * grid.pixel
    R, t = to_model[:3, :3], to_model[:3, 3]
    inv_R = R.T
    top = (face.vertices @ R.T + t)[:, 2].max() + 50.0
    origins = np.column_stack([x, y, np.full_like(x, top)])
    o_face = (origins - t) @ inv_R.T
    d_face = np.broadcast_to(np.array([0.0, 0.0, -1.0]) @ inv_R.T, o_face.shape)
    if rays.engine == "embree":
        pos, local, hit = rays.first_hits(o_face, np.ascontiguousarray(d_face))
        tri = np.where(hit, rays.ids[np.maximum(local, 0)], -1)
    else:  # no Embree: nearest vertex in the frontal plane (coarse but workable)
        from scipy.spatial import cKDTree

        vm = face.vertices @ R.T + t
        d, idx = cKDTree(vm[:, :2]).query(np.column_stack([x, y]), distance_upper_bound=2 * grid.pixel)
        hit = np.isfinite(d)
        vt = np.full(face.n_vertices, -1)
        vt[face.triangles[:, 0]] = np.arange(face.n_triangles)
        tri = np.where(hit, vt[np.minimum(idx, face.n_vertices - 1)], -1)
        hit &= tri >= 0
        pos = np.where(hit[:, None], face.vertices[np.minimum(idx, face.n_vertices - 1)], 0.0)
    bary = np.zeros((len(x), 3))
    if hit.any():
        bary[hit] = _barycentric(face.vertices[face.triangles[tri[hit]]], pos[hit])
    H, W = grid.height, grid.width
    chans = []
    corners = face.triangles[np.maximum(tri, 0)]
    nrm = np.einsum("kj,kjd->kd", bary, face.vertex_normals[corners]) @ R.T
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    chans += [nrm[:, 0], nrm[:, 1], nrm[:, 2]]
    if texture and face.texture is not None and face.uv is not None:
        import cv2

        uv = np.einsum("kj,kjd->kd", bary, face.uv[corners])
        th, tw = face.texture.shape[:2]
        mx = (uv[:, 0] * tw - 0.5).astype(np.float32).reshape(H, W)
        my = ((1.0 - uv[:, 1]) * th - 0.5).astype(np.float32).reshape(H, W)
        rgb = cv2.remap(face.texture.astype(np.float32) / 255.0, mx, my, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
        grey = rgb @ np.array([0.299, 0.587, 0.114])
        chroma = rgb[:, 0] - rgb[:, 1]
        chans += [grey, chroma]
    ch = np.column_stack(chans).astype(np.float32)
    ok = hit
    if ok.sum() > 10:
        mean = ch[ok].mean(axis=0)
        std = np.maximum(ch[ok].std(axis=0), 1e-6)
        ch = (ch - mean) / std
        # Shape weighs less than texture when both exist (3 normal channels vs 2 colour channels).
        if ch.shape[1] == 5:
            ch[:, :3] *= 0.5
    ch[~ok] = 0.0
    depth = np.full(len(x), np.nan)
    if hit.any():
        depth[hit] = pos[hit] @ R[2] + t[2]
    return FrontalRaster(grid.x0, grid.y0, grid.pixel, tri.reshape(H, W), bary.reshape(H, W, 3),
                         ch.reshape(H, W, -1), depth.reshape(H, W))


# ------------------------------------------------------------------ model / input features
@dataclass
class Side:
    """One side of the matching: points (k, 3) in the model frame, colours (k, 3) in [0, 1],
    HK colours (k, 3) in [0, 1]."""

    points: np.ndarray
    colour: np.ndarray
    hk: np.ndarray


def sample_texture(face: Face, triangle: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """(k, 3) RGB in [0, 1] of the texture (or vertex colours; 0.5 grey when none) at surface points."""
    triangle = np.asarray(triangle, np.int64)
    if face.texture is not None and face.uv is not None:
        import cv2

        uv = np.einsum("kj,kjd->kd", bary, face.uv[face.triangles[triangle]])
        th, tw = face.texture.shape[:2]
        mx = (uv[:, 0] * tw - 0.5).astype(np.float32)[None]
        my = ((1.0 - uv[:, 1]) * th - 0.5).astype(np.float32)[None]
        return cv2.remap(face.texture.astype(np.float32) / 255.0, mx, my, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)[0].astype(float)
    if face.vertex_colors is not None:
        return np.einsum("kj,kjd->kd", bary, face.vertex_colors[face.triangles[triangle]].astype(float) / 255.0)
    return np.full((len(triangle), 3), 0.5)


def sample_vertex_values(face: Face, values: np.ndarray, triangle, bary) -> np.ndarray:
    return np.einsum("kj,kjd->kd", bary, np.asarray(values, float)[face.triangles[np.asarray(triangle, np.int64)]])


def face_scale(positions: dict[str, np.ndarray], points: np.ndarray) -> float:
    if "3.7" in positions and "3.12" in positions:
        return float(np.linalg.norm(positions["3.7"] - positions["3.12"]))
    return 0.66 * float(np.ptp(points[:, 0]))


# ------------------------------------------------------------------ the matcher
@dataclass
class MatchResult:
    """positions (P, 3) model frame; triangle (P,) / bary (P, 3) on the input face; confidence (P,);
    source (P,) str: "seed", "candidate", "refined", "fixed", "prediction"; timings."""

    names: tuple[str, ...]
    positions: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    confidence: np.ndarray
    source: list[str]
    greedy_positions: np.ndarray
    timings: dict = field(default_factory=dict)


def match_order(template: LandmarkTemplate, model_points: np.ndarray, first: list[int]) -> list[int]:
    """Seeds (``first``) then breadth-first over G_m, ties by distance from the seeds' centroid."""
    nbrs = template.neighbours()
    n = len(template.detected)
    start = list(dict.fromkeys(first)) or [int(np.argmin(np.linalg.norm(model_points - model_points.mean(0), axis=1)))]
    centre = model_points[start].mean(axis=0)
    dist = np.linalg.norm(model_points - centre, axis=1)
    order, seen = list(start), set(start)
    frontier = list(start)
    while frontier:
        nxt = sorted({int(j) for i in frontier for j in nbrs[i] if int(j) not in seen}, key=lambda j: dist[j])
        order += nxt
        seen.update(nxt)
        frontier = nxt
    order += [i for i in np.argsort(dist) if i not in seen]  # disconnected vertices, if any
    return order


def graph_distances(template: LandmarkTemplate, model_points: np.ndarray) -> np.ndarray:
    """(P, P) shortest-path lengths (mm) along the edges of G_m on the model. Distances along the
    graph respect the mouth opening: the lower lip is far from the upper lip."""
    import scipy.sparse
    from scipy.sparse.csgraph import dijkstra

    e = template.edges
    P = len(model_points)
    w = np.linalg.norm(model_points[e[:, 0]] - model_points[e[:, 1]], axis=1) + 1e-9
    g = scipy.sparse.coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(P, P))
    d = dijkstra(g.tocsr(), directed=False)
    return np.where(np.isfinite(d), d, 1e6)


def _propagated(model: np.ndarray, gd: np.ndarray, matched: np.ndarray, sigma: float,
                dist: np.ndarray | None = None) -> np.ndarray:
    """(P, 3): matched vertices where they are, the others displaced by the Gaussian-weighted mean
    of the matched displacements; ``dist`` (P, P) the distances to weigh by (graph distances;
    Euclidean model distances when None)."""
    if not matched.any():
        return model.copy()
    disp = gd[matched] - model[matched]
    if dist is None:
        d2 = ((model[:, None, :] - model[None, matched, :]) ** 2).sum(-1)
    else:
        d2 = dist[:, matched] ** 2
    w = np.exp(-d2 / (2 * sigma * sigma)) + 1e-12
    out = model + (w @ disp) / w.sum(axis=1, keepdims=True)
    out[matched] = gd[matched]
    return out


def greedy_match(template: LandmarkTemplate, model: Side, cand: Side, params: MatchParams, scale: float, *,
                 order: list[int], preset: dict[int, np.ndarray] | None = None):
    """Algorithm 1, vectorised over candidates.

    preset : vertex index -> position (model frame) matched before the loop (seeds, fixed points).
    Returns (positions (P, 3), candidate index per vertex (P,) or −1, margin (P,), prediction (P, 3)).
    """
    P, C = len(template.detected), len(cand.points)
    nbrs = template.neighbours()
    e = template.edges
    c_s = float(np.median(np.linalg.norm(model.points[e[:, 0]] - model.points[e[:, 1]], axis=1))) if len(e) else 1.0
    # Appearance cost (P, C), thesis (3.2).
    d_uv = np.linalg.norm(model.colour[:, None, :] - cand.colour[None, :, :], axis=2) / C_A
    d_hk = np.linalg.norm(model.hk[:, None, :] - cand.hk[None, :, :], axis=2) / C_A
    d_a = params.lam_a * d_uv + (1 - params.lam_a) * d_hk
    R = params.radius * scale if params.radius > 0 else np.inf
    sigma = params.sigma * scale
    gdist = graph_distances(template, model.points)
    gd = model.points.copy()
    matched = np.zeros(P, bool)
    used = np.zeros(C, bool)
    chosen = np.full(P, -1)
    margin = np.zeros(P)
    prediction = model.points.copy()
    for i, pos in (preset or {}).items():
        gd[i] = pos
        matched[i] = True
    for k in order:
        if matched[k]:
            prediction[k] = gd[k]
            continue
        cur = _propagated(model.points, gd, matched, sigma, gdist) if params.propagate else gd
        pred = cur[k]
        prediction[k] = pred
        dist = np.linalg.norm(cand.points - pred, axis=1)
        ok = ~used & (dist <= R)
        if not ok.any():
            gd[k] = pred          # nothing near: keep the structural prediction
            matched[k] = True
            continue
        nb = nbrs[k]
        if len(nb):
            em = model.points[nb] - model.points[k]                        # (q, 3)
            ed = cur[nb][None, :, :] - cand.points[:, None, :]             # (C, q, 3)
            lm = np.linalg.norm(em, axis=1)
            ld = np.linalg.norm(ed, axis=2)
            cos = np.einsum("cqd,qd->cq", ed, em) / np.maximum(ld * lm, 1e-12)
            d_ang = np.abs(cos - 1.0) / 2.0
            d_mod = np.minimum(np.abs(ld - lm) / c_s, 1.0)
            d_s = (params.lam_s * d_ang + (1 - params.lam_s) * d_mod).mean(axis=1)
        else:
            d_s = np.zeros(C)
        cost = params.lam * d_a[k] + (1 - params.lam) * d_s
        if params.position_weight > 0:
            cost = (1 - params.position_weight) * cost + params.position_weight * np.minimum(dist / min(R, 1e12), 1.0)
        cost = np.where(ok, cost, np.inf)
        j = int(np.argmin(cost))
        far = ok & (np.linalg.norm(cand.points - cand.points[j], axis=1) > 0.1 * scale)
        margin[k] = float(cost[far].min() - cost[j]) if far.any() else 1.0
        chosen[k] = j
        used[j] = True
        gd[k] = cand.points[j]
        matched[k] = True
    return gd, chosen, margin, prediction


class PatchSearch:
    """Searches the scan raster for the model's patch around each landmark (NCC).

    halves : per landmark "full", "upper" or "lower": points on the inner lip contour and the lid
    margins are compared by the half of the patch on their own lip / lid (plus the seam row),
    because the other half may be the mouth or eye opening, which changes with the expression."""

    def __init__(self, model_points, model_raster: FrontalRaster, scan_raster: FrontalRaster, params: MatchParams,
                 halves: list[str], outline: list[bool] | None = None):
        self.px = params.pixel_mm
        self.h = max(2, int(round(params.patch_mm / 2 / self.px)))
        self.pad = 4 * self.h + 64
        pad = self.pad
        self.M = np.pad(model_raster.channels, ((pad, pad), (pad, pad), (0, 0)))
        self.S = np.pad(scan_raster.channels, ((pad, pad), (pad, pad), (0, 0)))
        self.Mv = np.pad(model_raster.triangle >= 0, pad)
        self.Sv = np.pad(scan_raster.triangle >= 0, pad)
        # At the outline the scan ends inside the patch; elsewhere only gaps (lip seam) do.
        self.min_cover = [0.9 if o else 0.4 for o in outline] if outline is not None else [0.4] * len(halves)
        self.mc = model_raster.to_pixel(model_points)
        self.scan_raster = scan_raster
        self.halves = halves
        self.pull = params.pull

    def nearest_covered(self, px) -> tuple[float, float]:
        """The covered scan pixel nearest to ``px`` (col, row) (NaN if none within 20 pixels)."""
        c, r = np.round(np.asarray(px, float)).astype(int) + self.pad
        win = self.Sv[max(r - 20, 0):r + 21, max(c - 20, 0):c + 21]
        yy, xx = np.nonzero(win)
        if not len(yy):
            return (np.nan, np.nan)
        r0, c0 = max(r - 20, 0), max(c - 20, 0)
        j = int(np.argmin((yy + r0 - r) ** 2 + (xx + c0 - c) ** 2))
        return (c0 + xx[j] - self.pad, r0 + yy[j] - self.pad)

    def search(self, k: int, centre_px, rx: int, ry: int, pull_px=None):
        """Best pixel (col, row) for landmark k within (2 rx + 1) x (2 ry + 1) around ``centre_px``,
        penalised by pull x (distance to ``pull_px`` / r)^2; and its NCC. (None, 0) if impossible."""
        h, pad = self.h, self.pad
        if not np.all(np.isfinite(centre_px)):
            return None, 0.0
        rx, ry = int(min(rx, pad - h - 2)), int(min(ry, pad - h - 2))
        mx, my = (np.round(self.mc[k]).astype(int) + pad)
        sx, sy = (np.round(np.asarray(centre_px)).astype(int) + pad)
        if not (0 <= mx - h and mx + h < self.M.shape[1] and 0 <= my - h and my + h < self.M.shape[0]
                and rx + h <= sx < self.S.shape[1] - rx - h and ry + h <= sy < self.S.shape[0] - ry - h):
            return None, 0.0
        top, bottom = -h, h
        if self.halves[k] == "upper":
            bottom = 1
        elif self.halves[k] == "lower":
            top = -1
        patch = self.M[my + top:my + bottom + 1, mx - h:mx + h + 1]
        if self.Mv[my + top:my + bottom + 1, mx - h:mx + h + 1].mean() < 0.5:
            return None, 0.0   # the model landmark is at the edge of its surface: no patch to compare
        win = self.S[sy - ry + top:sy + ry + bottom + 1, sx - rx - h:sx + rx + h + 1]
        res = _ncc(win, patch)                              # (2 ry + 1, 2 rx + 1)
        yy, xx = np.mgrid[-ry:ry + 1, -rx:rx + 1]
        if pull_px is not None:
            off = np.asarray(pull_px, float) - np.asarray(centre_px, float)
            xx, yy = xx - off[0], yy - off[1]
        score = res - self.pull * (xx * xx / float(max(rx, 1) ** 2) + yy * yy / float(max(ry, 1) ** 2))
        iy, ix = np.unravel_index(int(np.argmax(score)), score.shape)
        by, bx = sy - ry + iy, sx - rx + ix                  # padded pixel of the best match
        cover = self.Sv[by + top:by + bottom + 1, bx - h:bx + h + 1]
        if cover.mean() < self.min_cover[k]:
            return None, 0.0   # the scan ends inside the patch (outline, holes): NCC is not reliable there
        if not self.Sv[by, bx]:  # a gap (lip seam): the nearest covered pixel of the patch
            cy, cx = np.nonzero(cover)
            j = int(np.argmin((cy + top) ** 2 + (cx - h) ** 2))
            by, bx = by + top + cy[j], bx - h + cx[j]
        return (bx - pad, by - pad), float(res[iy, ix])


def patch_halves(template: LandmarkTemplate) -> list[str]:
    """Per detected point: "upper" / "lower" for inner-lip and lid-margin points, else "full"."""
    base = template.base
    corners = {base.mouth[0]} | {base.mouth[len(base.mouth) // 2]}
    upper_lids = {"3.1", "3.2"}
    lower_lids = {"3.3", "3.4"}
    out = []
    for n in template.detected:
        if n in base.mouth and n not in corners and n in base.upper_lip_points or n in upper_lids:
            out.append("upper")
        elif n in base.mouth and n not in corners and n in base.lower_lip_points or n in lower_lids:
            out.append("lower")
        else:
            out.append("full")
    return out


def refine_matches(template: LandmarkTemplate, greedy: np.ndarray, model_points: np.ndarray,
                   model_raster: FrontalRaster, scan_raster: FrontalRaster, params: MatchParams, scale: float,
                   skip: np.ndarray):
    """Two rounds of patch search (see the module docstring).

    Round 1 searches around each greedy match. Round 2 predicts every point from the others
    (graph-distance-weighted displacements, weighted by their round-1 NCC) and searches a window
    spanning the prediction with a pull towards it; mouth points get a taller window (the jaw
    moves them vertically). Returns (pixels (P, 2) (col, row) in the scan raster or NaN, NCC (P,))."""
    P = len(template.detected)
    search = PatchSearch(model_points, model_raster, scan_raster, params, patch_halves(template),
                         [n in template.base.outline for n in template.detected])
    r = max(1, int(round(params.refine_radius * scale / params.pixel_mm)))
    out = np.full((P, 2), np.nan)
    peak = np.zeros(P)
    sc = scan_raster.to_pixel(greedy)
    for k in range(P):
        if skip[k]:
            continue
        best, val = search.search(k, sc[k], r, r)
        if best is not None:
            out[k], peak[k] = best, val
    # Round 2: structural prediction from the others.
    pos_px = np.where(np.isfinite(out), out, sc)
    gdist = graph_distances(template, model_points)
    sigma = params.sigma * scale
    mouth = {template.index(n) for n in template.base.mouth if n in template.detected}
    mouth |= {template.index(n) for n in template.base.upper_lip_points | template.base.lower_lip_points
              if n in template.detected}
    model_px = model_raster.to_pixel(model_points)
    conf = np.clip(peak, 0.05, 1.0)
    conf[skip] = 1.0
    for k in range(P):
        if skip[k]:
            continue
        w = np.exp(-gdist[k] ** 2 / (2 * sigma * sigma)) * conf
        w[k] = 0.0
        if w.sum() < 1e-9:
            continue
        pred = model_px[k] + (w @ (pos_px - model_px)) / w.sum()
        centre = (pred + pos_px[k]) / 2
        span = np.abs(pred - pos_px[k]) / 2
        rx = int(np.ceil(span[0])) + r
        ry = int(np.ceil(span[1])) + (2 * r if k in mouth else r)
        best, val = search.search(k, centre, rx, ry, pull_px=pred)
        if best is not None and val >= peak[k] - 0.05:
            out[k], peak[k] = best, val
        elif best is None and not np.all(np.isfinite(out[k])):
            # No reliable patch (outline at the scan's edge): the structural prediction.
            out[k], peak[k] = search.nearest_covered(pred), 0.0
    _lower_lip_pass(template, search, out, peak, model_px, r, scale / params.pixel_mm, skip)
    if params.mouth_opening:
        _mouth_opening_pass(template, scan_raster, out, peak, model_px, scale, skip, search)
        _lip_order_pass(template, search, out, peak, model_px, skip)
    return out, peak


def _lip_order_pass(template, search, out, peak, model_px, skip):
    """A lower inner-lip point found on (or below) the lower outer lip goes back above it.

    On a pressed, closed mouth there is no opening and the lower-lip patch fits the lower outer
    lip's edge as well; the inner point then collapses onto the outer one. The inner point is kept
    at least half the model's inner-to-outer lip height above the outer point, at the model's
    offset below the upper outer lip (the lips touch: it is the seam)."""
    base = template.base
    names = template.detected
    loop = [template.index(n) for n in base.mouth if n in names]
    if len(loop) < 4:
        return
    corners = {loop[0], loop[len(loop) // 2]}
    upper = {template.index(n) for n in base.upper_lip_points if n in names}
    lower = {template.index(n) for n in base.lower_lip_points if n in names}
    lower_in = [i for i in loop if i not in corners and i not in upper]
    upper_out = [i for i in upper if i not in loop and np.all(np.isfinite(out[i]))]
    lower_out = [i for i in lower if i not in loop and np.all(np.isfinite(out[i]))]
    if not upper_out or not lower_out:
        return
    for k in lower_in:
        if skip[k] or not np.all(np.isfinite(out[k])):
            continue
        o = min(lower_out, key=lambda i: abs(model_px[i, 0] - model_px[k, 0]))
        u = min(upper_out, key=lambda i: abs(model_px[i, 0] - model_px[k, 0]))
        gap = model_px[o, 1] - model_px[k, 1]        # rows grow downwards
        if gap <= 1 or out[k, 1] <= out[o, 1] - 0.5 * gap:
            continue
        row = min(out[u, 1] + (model_px[k, 1] - model_px[u, 1]), out[o, 1] - 0.5 * gap)
        hit = search.nearest_covered((out[k, 0], row))
        if np.all(np.isfinite(hit)):
            out[k], peak[k] = hit, 0.0


OPENING_STEP_MM = 3.0     # a depth step this large between neighbouring pixel rows is an occluding edge
OPENING_MIN_MM = 1.5      # a mouth opening narrower than this is treated as closed
HOLE_MM = 3.0             # uncovered rows this tall between two lip rows: an unscanned opening


def _mouth_opening_pass(template, raster: FrontalRaster, out, peak, model_px, scale, skip, search=None):
    """Inner-lip points put on the edges of the mouth opening, when the scan shows one.

    Seen from the front an open mouth is an occluding edge: along a vertical line through the mouth
    the surface steps back by several mm (lip -> teeth or mouth cavity) or ends (a hole) just below
    the upper lip, and steps forward again just above the lower lip. The patch search alone
    confuses the lips (the lower-lip patch also fits the upper lip); the depth profile does not.

    - columns: each inner-lip point keeps the model's horizontal fraction between the two mouth
      corners (the corners are found reliably; the patch search drifts along the lip);
    - rows: the column is scanned downwards from the philtrum (half-way between the bottom of the
      nose 9.15 and the model's upper lip, shifted with the nose) -- the first step back is the
      upper lip's inner edge -- and upwards from the chin (``JAW_POINTS``) -- the first step back
      seen from below is the lower lip's inner edge. The order upper outer > upper inner >
      opening > lower inner > lower outer follows by construction; outer-lip points found on the
      wrong side of the opening are searched again (patch search) on their own side.

    With no step in a column, or an opening narrower than ``OPENING_MIN_MM`` (closed mouth), the
    points keep their patch-search estimates."""
    depth = raster.depth
    if depth is None:
        return
    base = template.base
    names = template.detected
    if not all(n in names for n in base.mouth) or NOSE_BOTTOM not in names:
        return
    ok = lambda i: bool(np.all(np.isfinite(out[i])))   # noqa: E731
    loop = [template.index(n) for n in base.mouth]
    c0, c1 = loop[0], loop[len(loop) // 2]                  # the two corners
    jaw = [template.index(n) for n in JAW_POINTS if n in names and ok(template.index(n))]
    nose = template.index(NOSE_BOTTOM)
    if not (ok(c0) and ok(c1) and ok(nose) and jaw):
        return
    upper_set = {template.index(n) for n in base.upper_lip_points if n in names}
    upper_in = [i for i in loop if i not in (c0, c1) and i in upper_set]
    lower_in = [i for i in loop if i not in (c0, c1) and i not in upper_set]
    upper_out = [i for i in upper_set if i not in loop]
    lower_out = [template.index(n) for n in base.lower_lip_points if n in names and template.index(n) not in loop]
    px = raster.pixel
    Hh, W = depth.shape
    mid_model = np.mean([model_px[i, 1] for i in upper_in])
    top = int(round(out[nose, 1] + 0.5 * (mid_model - model_px[nose, 1])))
    bottom = int(round(np.median([out[i, 1] for i in jaw])))   # the chin, below the lower lip
    top, bottom = max(top, 0), min(bottom, Hh - 1)
    if bottom - top < 4:
        return
    span_model = model_px[c1, 0] - model_px[c0, 0]
    if abs(span_model) < 1:
        return
    def opening_edges(c):
        """(last row above, first row below) the opening in column c (absolute rows), or None."""
        if not 0 <= c < W:
            return None
        zcol = depth[top:bottom + 1, c]
        rows = np.nonzero(np.isfinite(zcol))[0]
        if len(rows) < 2:
            return None
        z = zcol[rows]
        a, b = rows[:-1], rows[1:]               # consecutive covered rows (a above b)
        hole = (b - a - 1) * px >= HOLE_MM       # a hole in the scan (open mouth not scanned)
        back_down = a[(z[1:] < z[:-1] - OPENING_STEP_MM) | hole]   # last rows before a step back
        back_up = b[(z[:-1] < z[1:] - OPENING_STEP_MM) | hole]     # first rows after a step forward
        if not len(back_down) or not len(back_up):
            return None
        r_up, r_lo = int(back_down[0]), int(back_up[-1])
        if (r_lo - r_up - 1) * px < OPENING_MIN_MM:
            return None
        return top + r_up, top + r_lo

    # The opening's horizontal extent (through its middle) stands for the corners when found: the
    # corner points sit on the outer lip contour and drift outwards when the mouth rounds.
    ends = (out[c0, 0], out[c1, 0])
    c_mid = int(round((out[c0, 0] + out[c1, 0]) / 2))
    mid = opening_edges(c_mid)
    if mid is not None:
        row = (mid[0] + mid[1]) // 2
        cols = np.nonzero(np.isfinite(depth[row]))[0]
        z = depth[row, cols]
        fwd_right = cols[1:][(z[1:] > z[:-1] + OPENING_STEP_MM) & (cols[1:] > c_mid)]   # lip in front, right
        fwd_left = cols[:-1][(z[:-1] > z[1:] + OPENING_STEP_MM) & (cols[:-1] < c_mid)]
        if len(fwd_right) and len(fwd_left):
            lo_c, hi_c = int(fwd_left[-1]), int(fwd_right[0])
            width = abs(out[c1, 0] - out[c0, 0])
            if 0.3 * width <= hi_c - lo_c <= 1.2 * width:
                ends = (lo_c, hi_c) if out[c0, 0] < out[c1, 0] else (hi_c, lo_c)
    edges = {}
    for k in upper_in + lower_in:
        if skip[k]:
            continue
        frac = (model_px[k, 0] - model_px[c0, 0]) / span_model
        c = int(round(ends[0] + frac * (ends[1] - ends[0])))
        found = opening_edges(c)
        if found is None:
            continue
        r_up, r_lo = found
        edges[k] = (c, r_up, r_lo)
        out[k] = (float(c), float(r_up if k in upper_in else r_lo))
        peak[k] = max(peak[k], 0.5)
    if search is None or not edges:
        return
    # The jaw below the lower lip: a chin point found less than half its model distance below the
    # lower lip's inner edge (the patch search latched onto the lip) is searched again lower down.
    if mid is not None:
        lower_mid = min(lower_in, key=lambda i: abs(model_px[i, 0] - model_px[c0, 0] - span_model / 2))
        for k in [template.index(n) for n in JAW_POINTS if n in names]:
            if skip[k] or not ok(k):
                continue
            gap = model_px[k, 1] - model_px[lower_mid, 1]
            if gap <= 0 or out[k, 1] >= mid[1] + 0.5 * gap:
                continue
            lo_row, hi_row = mid[1] + 0.5 * gap, mid[1] + 1.2 * gap
            best, val = search.search(k, (out[k, 0], (lo_row + hi_row) / 2), max(2, int(round(0.05 * scale / px))),
                                      int(np.ceil((hi_row - lo_row) / 2)), pull_px=(out[k, 0], (lo_row + hi_row) / 2))
            if best is not None and lo_row <= best[1] <= hi_row:
                out[k], peak[k] = best, val
            else:
                out[k] = search.nearest_covered((out[k, 0], (lo_row + hi_row) / 2))
    # Outer-lip points on the wrong side of the opening: search again on their own side.
    r = max(2, int(round(0.05 * scale / px)))
    for group, side in ((upper_out, "upper"), (lower_out, "lower")):
        for k in group:
            if skip[k] or not ok(k):
                continue
            near = min(edges, key=lambda i: abs(edges[i][0] - out[k, 0]))
            c, r_up, r_lo = edges[near]
            gap = abs(model_px[k, 1] - model_px[near, 1])           # the lip's height on the model
            if side == "upper" and out[k, 1] >= r_up:
                lo_row, hi_row, pred = top, r_up - 1, r_up - gap
            elif side == "lower" and out[k, 1] <= r_lo:
                lo_row, hi_row, pred = r_lo + 1, bottom, r_lo + gap
            else:
                continue
            if hi_row - lo_row < 2:
                continue
            best, val = search.search(k, (out[k, 0], (lo_row + hi_row) / 2), r, int(np.ceil((hi_row - lo_row) / 2)),
                                      pull_px=(out[k, 0], pred))
            if best is not None and lo_row <= best[1] <= hi_row:
                out[k], peak[k] = best, val
            else:
                out[k] = (out[k, 0], float(np.clip(pred, lo_row, hi_row)))


JAW_POINTS = ("2.10", "2.1", "2.11", "2.12")
NOSE_BOTTOM = "9.15"


def _lower_lip_pass(template, search, out, peak, model_px, r, scale_px, skip):
    """Lower-lip points searched below their upper-lip partner, pulled to where the jaw went.

    An open mouth shows two lip bands; the lower-lip patches also fit the upper lip, and the
    structure of the other mouth points does not tell which (they move together). The jaw
    (chin points, found reliably) does: the lower lip moves down with it, by about 1-2x the chin's
    displacement, and it is never above the upper lip."""
    names = template.detected
    jaw = [template.index(n) for n in JAW_POINTS if n in names and np.all(np.isfinite(out[template.index(n)]))]
    upper = [template.index(n) for n in template.base.upper_lip_points if n in names]
    lower = [template.index(n) for n in template.base.lower_lip_points if n in names]
    if not jaw or not upper or not lower:
        return
    jaw_disp = np.median(out[jaw] - model_px[jaw], axis=0)
    drop = max(float(jaw_disp[1]), 0.0)          # rows grow downwards
    for k in sorted(lower, key=lambda i: model_px[i, 1]):   # inner lip first (higher up)
        if skip[k]:
            continue
        u = min(upper, key=lambda i: abs(model_px[i, 0] - model_px[k, 0]) + 0.01 * abs(model_px[i, 1] - model_px[k, 1]))
        if not np.all(np.isfinite(out[u])):
            continue
        top = float(out[u, 1]) + 1.0
        above = [i for i in lower if i != k and model_px[i, 1] < model_px[k, 1] - 1
                 and abs(model_px[i, 0] - model_px[k, 0]) < 0.05 * scale_px and np.all(np.isfinite(out[i]))]
        if above:  # the outer lower lip is below the inner one
            top = max(top, max(float(out[i, 1]) for i in above) + 1.0)
        bottom = max(top + 1.0, model_px[k, 1] + 2.5 * drop + r)
        pred = model_px[k] + np.array([jaw_disp[0], 1.5 * drop])
        cx = model_px[k, 0] + jaw_disp[0]
        best, val = search.search(k, (cx, (top + bottom) / 2), r, int(np.ceil((bottom - top) / 2)), pull_px=pred)
        if best is not None:
            out[k], peak[k] = best, val


def _ncc(win: np.ndarray, patch: np.ndarray) -> np.ndarray:
    """Multi-channel normalised cross-correlation: OpenCV's TM_CCOEFF_NORMED with the sums taken
    over all channels together (cv2.matchTemplate itself takes at most 4 channels).
    win (Hw, Ww, C), patch (h, w, C) float32 -> (Hw - h + 1, Ww - w + 1)."""
    import cv2

    ph, pw = patch.shape[:2]
    n = float(ph * pw)
    ones = np.ones((ph, pw), np.float32)
    num = 0.0
    w_energy = 0.0
    t_energy = 0.0
    for c in range(patch.shape[2]):
        t = (patch[..., c] - patch[..., c].mean()).astype(np.float32)
        w = np.ascontiguousarray(win[..., c], dtype=np.float32)
        num = num + cv2.matchTemplate(w, t, cv2.TM_CCORR)           # sum W * (T - mean T)
        s1 = cv2.matchTemplate(w, ones, cv2.TM_CCORR)
        s2 = cv2.matchTemplate(w * w, ones, cv2.TM_CCORR)
        w_energy = w_energy + np.maximum(s2 - s1 * s1 / n, 0.0)
        t_energy += float((t * t).sum())
    den = np.sqrt(w_energy * t_energy)
    return np.where(den > 1e-6, num / np.maximum(den, 1e-6), -1.0)


# ------------------------------------------------------------------ model context and full match
@dataclass
class ModelContext:
    """Everything about the model that does not change between inputs (build once per model)."""

    face: Face
    template: LandmarkTemplate
    side: Side
    scale: float
    grid: Grid
    raster: FrontalRaster
    surface: list            # per detected point: SurfacePoint on the model
    normals: np.ndarray | None = None   # (P, 3) unit model surface normals at the points


def model_context(model: Face, template: LandmarkTemplate, params: MatchParams) -> ModelContext:
    """Template points on ``model`` (its landmarks, derived points computed), their appearance, the
    model's frontal raster."""
    from .correspondence import SurfaceRays
    from .curvature import hk_maps
    from .templates import template_positions

    pos = template_positions(model, template.name)
    pts = np.array([pos[p] for p in template.detected])
    _, tri, bary = model.closest_surface_points(pts)
    hk = hk_maps(model, smoothing_mm=HK_SMOOTHING_MM)
    side = Side(pts, sample_texture(model, tri, bary), sample_vertex_values(model, hk.colours / 255.0, tri, bary))
    scale = face_scale(pos, pts)
    grid = grid_for(pts, params.pixel_mm, margin=0.25 * scale)
    rays = SurfaceRays(model.vertices, model.triangles)
    raster = frontal_raster(model, rays, np.eye(4), grid)
    surface = [SurfacePoint(int(t), tuple(b)) for t, b in zip(tri, bary)]
    nrm = (bary[:, :, None] * model.vertex_normals[model.triangles[tri]]).sum(axis=1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    return ModelContext(model, template, side, scale, grid, raster, surface, nrm)


@dataclass
class InputFeatures:
    """The input's candidates (model frame) and seeds, plus messages about fallbacks."""

    side: Side
    triangle: np.ndarray
    bary: np.ndarray
    seeds: dict
    textured: bool
    report: list
    timings: dict = field(default_factory=dict)   # "candidates_s", "hk_s", "seeds_s"


def input_features(scan: Face, to_model: np.ndarray, params: MatchParams) -> InputFeatures:
    """Candidates (texture, or geometry when the scan has none), HK colours, Colombo seeds."""
    from .candidates import NoTextureError, geometry_candidates, texture_candidates
    from .curvature import CurvatureError, colombo_seeds, hk_maps
    from .icp import apply_transform

    report = []
    textured = True
    t0 = time.perf_counter()
    try:
        cand = texture_candidates(scan, count=params.candidates, quality=params.quality,
                                  min_distance_px=params.min_distance_px)
        if len(cand) < 50:
            report.append(f"the texture gave only {len(cand)} corner candidates; adding geometry candidates")
            geo = geometry_candidates(scan, count=params.candidates)
            cand = _concat_candidates(cand, geo)
    except NoTextureError:
        textured = False
        report.append("the scan has no texture: matching uses geometry candidates and curvature/shape "
                      "appearance only (expect lower accuracy; check the landmarks)")
        cand = geometry_candidates(scan, count=params.candidates)
    t1 = time.perf_counter()
    hk = hk_maps(scan, smoothing_mm=HK_SMOOTHING_MM)
    t2 = time.perf_counter()
    seeds = {}
    if params.seeds:
        try:
            seeds = {k: apply_transform(v[None], to_model)[0] for k, v in colombo_seeds(scan, hk).items()}
        except CurvatureError as exc:
            report.append(f"Colombo seeds not found ({exc}); matching starts from the structure alone")
    pts = apply_transform(cand.points, to_model)
    hkc = sample_vertex_values(scan, hk.colours / 255.0, cand.triangle, cand.bary)
    colour = cand.colour if textured else np.full((len(pts), 3), 0.5)
    t3 = time.perf_counter()
    return InputFeatures(Side(pts, colour, hkc), np.asarray(cand.triangle), np.asarray(cand.bary), seeds,
                         textured, report, {"candidates_s": t1 - t0, "hk_s": t2 - t1, "seeds_s": t3 - t2})


def _concat_candidates(a, b):
    from .candidates import Candidates

    return Candidates(*(np.concatenate([getattr(a, f), getattr(b, f)]) for f in
                        ("points", "triangle", "bary", "uv", "colour")))


SEED_POINTS = {"nose_tip": ("9.3",), "inner_eye_corner_left": ("3.11",), "inner_eye_corner_right": ("3.8",)}


def match(scan: Face, to_model: np.ndarray, ctx: ModelContext, params: MatchParams, *, rays,
          fixed: dict[str, np.ndarray] | None = None, features: InputFeatures | None = None,
          report: list | None = None, scan_raster: FrontalRaster | None = None) -> MatchResult:
    """Match ``ctx``'s template points on ``scan`` (aligned to the model by ``to_model``).

    features / scan_raster : precomputed (they do not depend on λ's; the evaluation sweeps λ).

    fixed : name -> position on the scan (scan frame, mm): kept as they are.
    rays : correspondence.SurfaceRays over the scan (its own frame).
    """
    from .icp import apply_transform

    report = report if report is not None else []
    timings = {}
    t0 = time.perf_counter()
    tpl = ctx.template
    names = tpl.detected
    P = len(names)
    feats = features or input_features(scan, to_model, params)
    report += feats.report
    params_used = params if feats.textured else _geometry_params(params)
    timings["features_s"] = time.perf_counter() - t0
    if features is None:
        timings.update(feats.timings)

    preset: dict[int, np.ndarray] = {}
    fixed = fixed or {}
    unknown = [n for n in fixed if n not in names]
    if unknown:
        raise MatchingError(f"fixed landmark(s) {', '.join(unknown)} are not points of template {tpl.name!r}")
    for n, p in fixed.items():
        preset[tpl.index(n)] = apply_transform(np.asarray(p, float)[None], to_model)[0]
    seed_idx = []
    for key, pos in feats.seeds.items():
        for n in SEED_POINTS.get(key, ()):
            if n in names and tpl.index(n) not in preset:
                i = tpl.index(n)
                d = float(np.linalg.norm(pos - ctx.side.points[i]))
                if d <= 0.12 * ctx.scale:
                    preset[i] = pos
                    seed_idx.append(i)
                else:
                    report.append(f"Colombo seed {key} is {d:.0f} mm from where the aligned model puts {n}; ignored")
    order = match_order(tpl, ctx.side.points, list(preset))
    t1 = time.perf_counter()
    gd, chosen, margin, _pred = greedy_match(tpl, ctx.side, feats.side, params_used, ctx.scale, order=order,
                                             preset=preset)
    timings["greedy_s"] = time.perf_counter() - t1

    # Surface points of the greedy result (scan frame).
    inv = np.linalg.inv(to_model)
    tri = np.full(P, -1)
    bary = np.zeros((P, 3))
    source = ["prediction"] * P
    has = chosen >= 0
    tri[has], bary[has] = feats.triangle[chosen[has]], feats.bary[chosen[has]]
    for i in range(P):
        if has[i]:
            source[i] = "candidate"
    for i in preset:
        source[i] = "fixed" if names[i] in fixed else "seed"
    positions = gd.copy()
    peak = np.zeros(P)
    t2 = time.perf_counter()
    if params_used.refine:
        if scan_raster is None:
            scan_raster = frontal_raster(scan, rays, to_model, ctx.grid, texture=feats.textured)
        model_raster = ctx.raster if feats.textured else _shape_only(ctx.raster)
        skip = np.array([names[i] in fixed for i in range(P)])
        pix, peak = refine_matches(tpl, gd, ctx.side.points, model_raster, scan_raster, params_used, ctx.scale, skip)
        for i in range(P):
            if not np.all(np.isfinite(pix[i])):
                continue
            c, r = int(pix[i, 0]), int(pix[i, 1])
            if not (0 <= r < scan_raster.triangle.shape[0] and 0 <= c < scan_raster.triangle.shape[1]):
                continue
            t = scan_raster.triangle[r, c]
            if t < 0:
                continue
            tri[i], bary[i] = t, scan_raster.bary[r, c]
            positions[i] = apply_transform((bary[i] @ scan.vertices[scan.triangles[t]])[None], to_model)[0]
            source[i] = "refined" if peak[i] > 0 else "prediction"
    timings["refine_s"] = time.perf_counter() - t2
    # Points still without a surface point (prediction, seeds, fixed): closest scan point.
    need = np.nonzero(tri < 0)[0]
    if len(need):
        p_scan = apply_transform(positions[need], inv)
        pos, t, b = rays.closest(p_scan)
        tri[need], bary[need] = t, b
        positions[need] = apply_transform(pos, to_model)
    # Confidence: appearance evidence x structural consistency (leave-one-out prediction).
    gdist = graph_distances(tpl, ctx.side.points)
    confidence = _confidence(ctx, positions, peak, margin, params_used, gdist)
    if params_used.lid_depth and params_used.refine and scan_raster is not None and scan_raster.depth is not None:
        if _upper_lid_pass(tpl, ctx, scan_raster, positions, confidence, fixed, tri, bary, source, peak):
            positions = _positions_from(scan, tri, bary, to_model, positions)
            confidence = _confidence(ctx, positions, peak, margin, params_used, gdist)
    if params_used.steep_prediction and params_used.refine:
        steep = steep_points(ctx) & np.array([n not in fixed for n in names])
        outline = np.array([n in tpl.base.outline for n in names])
        anchor = (confidence > ANCHOR_CONFIDENCE) & ~steep & ~outline & np.array([s in ("refined", "seed", "fixed") for s in source])
        if steep.any() and anchor.sum() >= 3:
            pred = _propagated(ctx.side.points, positions, anchor, params.sigma * ctx.scale, gdist)
            for i in np.nonzero(steep)[0]:
                source[i] = "prediction"
                peak[i] = 0.0
                hit = None if outline[i] else _raster_hit(scan_raster, pred[i])
                if hit is None:
                    pos, t, b = rays.closest(apply_transform(pred[i][None], inv))
                    tri[i], bary[i], positions[i] = t[0], b[0], apply_transform(pos, to_model)[0]
                else:
                    tri[i], bary[i] = hit
                    positions[i] = apply_transform((bary[i] @ scan.vertices[scan.triangles[tri[i]]])[None], to_model)[0]
            confidence = _confidence(ctx, positions, peak, margin, params_used, gdist)
    for i in preset:
        if names[i] in fixed:
            confidence[i] = 1.0
    timings["match_s"] = time.perf_counter() - t0
    return MatchResult(names, positions, tri, bary, confidence, source, gd, timings)


STEEP_NZ = 0.65          # model normal z below this (> ~50 deg from the view): steep in the frontal raster
ANCHOR_CONFIDENCE = 0.6  # matches above this confidence anchor the prediction of the steep points


def steep_points(ctx: ModelContext) -> np.ndarray:
    """(P,) bool: points whose model surface normal turns sideways away from the frontal view
    (z < STEEP_NZ, |x| >= |y|), except the mouth and eye points: those are textured features (lip and lid contours curl away
    from the view) that the patch search and the opening passes place. The lips are the mouth
    loop, the lip points and every point within 0.1 x scale of the mouth loop (outer lip corners)."""
    base = ctx.template.base
    names = ctx.template.detected
    features = set(base.mouth) | base.upper_lip_points | base.lower_lip_points
    for loop in base.eye_margins.values():
        features |= set(loop)
    loop = [names.index(n) for n in base.mouth if n in names]
    if loop:
        d = np.linalg.norm(ctx.side.points[:, None, :] - ctx.side.points[None, loop, :], axis=2).min(axis=1)
        features |= {n for n, di in zip(names, d) if di < 0.1 * ctx.scale}
    if ctx.normals is None:
        return np.zeros(len(names), bool)
    sideways = np.abs(ctx.normals[:, 0]) >= np.abs(ctx.normals[:, 1])   # not the chin's or nose's underside
    return (ctx.normals[:, 2] < STEEP_NZ) & sideways & np.array([n not in features for n in names])


def _raster_hit(raster: FrontalRaster | None, p: np.ndarray):
    """(triangle, bary) of the scan surface seen at the frontal pixel of ``p`` (3,), or None."""
    if raster is None:
        return None
    c, r = np.round(raster.to_pixel(p)[0]).astype(int)
    if not (0 <= r < raster.triangle.shape[0] and 0 <= c < raster.triangle.shape[1]) or raster.triangle[r, c] < 0:
        return None
    return int(raster.triangle[r, c]), raster.bary[r, c]


LID_RECHECK = 0.5     # upper-lid matches below this confidence are checked against the depth profile
LID_FALL_MM = 0.5     # the lid's fall onto the eyeball is at least this steep (mm of depth per pixel row)


def _upper_lid_pass(tpl, ctx: ModelContext, raster: FrontalRaster, positions, confidence, fixed, tri, bary,
                    source, peak) -> bool:
    """Doubtful upper-lid points (confidence < LID_RECHECK) go to the foot of the lid's fall onto
    the eyeball, in the column at the model's horizontal offset from the lower-lid partner and
    within twice the model's lid gap above it: the steepest downward depth fall there (unscanned rows
    under an overhanging lid bridged linearly), followed down while it keeps falling (> 0.3 mm a row). Updates tri / bary / source / peak in place (the
    positions are recomputed by the caller); True if any point moved."""
    names = tpl.detected
    moved = False
    for loop in tpl.base.eye_margins.values():
        if len(loop) != 4 or loop[1] not in names or loop[3] not in names:
            continue
        i, j = names.index(loop[1]), names.index(loop[3])
        if confidence[i] >= LID_RECHECK or loop[1] in fixed:
            continue
        mu, ml = raster.to_pixel(ctx.side.points[[i, j]])
        pl = raster.to_pixel(positions[j])[0]
        gap = ml[1] - mu[1]
        col = int(round(pl[0] + mu[0] - ml[0]))
        top, bottom = int(round(pl[1] - 2 * gap)), int(round(pl[1] - 1))
        H, W = raster.depth.shape
        if gap < 2 or not (0 <= top and bottom < H and 0 <= col < W):
            continue
        d = raster.depth[top:bottom + 1, col].astype(float)
        ok = np.isfinite(d)
        if ok.sum() < 0.5 * len(d):
            continue
        # A few unscanned rows where the lid overhangs the eyeball: bridge them (the fall spans them).
        d = np.interp(np.arange(len(d)), np.nonzero(ok)[0], d[ok])
        g = np.diff(d)          # depth change going down one row (the viewer is at +z)
        s = int(np.argmin(g))
        if g[s] > -LID_FALL_MM:
            continue
        e = s
        while e + 1 < len(g) and g[e + 1] < -0.3:
            e += 1
        row = top + e + 1
        if raster.triangle[row, col] < 0:
            continue
        tri[i], bary[i] = raster.triangle[row, col], raster.bary[row, col]
        source[i], peak[i] = "refined", 0.5
        moved = True
    return moved


def _positions_from(scan: Face, tri, bary, to_model, positions) -> np.ndarray:
    """(P, 3) model-frame positions of the surface points (tri, bary) on ``scan`` (``positions`` where tri < 0)."""
    from .icp import apply_transform

    out = positions.copy()
    ok = tri >= 0
    p = np.einsum("pk,pkd->pd", bary[ok], scan.vertices[scan.triangles[tri[ok]]])
    out[ok] = apply_transform(p, to_model)
    return out


def _confidence(ctx: ModelContext, positions, peak, margin, params: MatchParams, gdist) -> np.ndarray:
    """(P,) the mean of the appearance evidence and the leave-one-out structural consistency."""
    P = len(positions)
    loo = np.zeros((P, 3))
    sigma = params.sigma * ctx.scale
    for i in range(P):
        m = np.ones(P, bool)
        m[i] = False
        loo[i] = _propagated(ctx.side.points, positions, m, sigma, gdist)[i]
    consistency = np.exp(-(np.linalg.norm(positions - loo, axis=1) / (0.1 * ctx.scale)) ** 2)
    evidence = np.clip(peak, 0, 1) if params.refine else np.clip(margin / 0.1, 0, 1)
    return 0.5 * evidence + 0.5 * consistency


def _geometry_params(params: MatchParams) -> MatchParams:
    """Without texture d_A,UV carries no information: all appearance weight on the HK term."""
    import dataclasses

    return dataclasses.replace(params, lam_a=0.0)


def _shape_only(r: FrontalRaster) -> FrontalRaster:
    return FrontalRaster(r.x0, r.y0, r.pixel, r.triangle, r.bary, np.ascontiguousarray(r.channels[..., :3]))
