"""The structural greedy matcher (thesis A ch. 3): template points matched in graph order to scan
candidates by their features and the positions their matched neighbours predict."""

from __future__ import annotations

import numpy as np
from core.registration.templates import LandmarkTemplate
from core.registration.rasters import Side
from core.registration.match_params import MatchParams
from core.registration.pass_results import GreedyMatch


C_A = float(np.sqrt(3.0))   # RGB distance of colours in [0, 1] is at most sqrt(3)


def face_scale(positions: dict[str, np.ndarray], points: np.ndarray) -> float:
    if "3.7" in positions and "3.12" in positions:
        return float(np.linalg.norm(positions["3.7"] - positions["3.12"]))
    return 0.66 * float(np.ptp(points[:, 0]))


# ------------------------------------------------------------------ the matcher
def match_order(template: LandmarkTemplate, model_points: np.ndarray, first: list[int]) -> list[int]:
    """Seeds (``first``) then breadth-first over G_m, ties by distance from the seeds' centroid."""
    nbrs = template.neighbours()
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


def propagated(model: np.ndarray, gd: np.ndarray, matched: np.ndarray, sigma: float,
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
                 order: list[int], preset: dict[int, np.ndarray] | None = None,
                 gdist: np.ndarray | None = None) -> GreedyMatch:
    """Algorithm 1, vectorised over candidates.

    preset : vertex index -> position (model frame) matched before the loop (seeds, fixed points).
    gdist : (P, P) graph distances on the model (``graph_distances``; computed when not given).
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
    if gdist is None:
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
        cur = propagated(model.points, gd, matched, sigma, gdist) if params.propagate else gd
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
    return GreedyMatch(gd, chosen, margin, prediction)
