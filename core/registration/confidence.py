"""Confidence of each match (0..1; a heuristic, not a probability).

The mean of the appearance evidence (the NCC peak clipped to [0, 1]; without patch refinement the
greedy cost margin / 0.1, clipped) and the structural consistency exp(−(d / 0.1·scale)²), d = mm
from the point to where the others put it (leave-one-out Gaussian propagation over the graph
distances, σ = ``sigma`` × scale, as ``greedy.propagated``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.registration.greedy import propagated

if TYPE_CHECKING:
    from core.registration.match_context import MatchContext


def match_confidence(ctx: MatchContext, positions: np.ndarray, evidence: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """(P,) confidence of model-frame positions (P, 3) mm, given evidence (P,) and greedy margin (P,)."""
    model, scale = ctx.model.side.points, ctx.model.scale
    P = len(positions)
    loo = np.zeros((P, 3))
    sigma = ctx.params.sigma * scale
    for i in range(P):
        m = np.ones(P, bool)
        m[i] = False
        loo[i] = propagated(model, positions, m, sigma, ctx.gdist)[i]
    consistency = np.exp(-(np.linalg.norm(positions - loo, axis=1) / (0.1 * scale)) ** 2)
    evidence = np.clip(evidence, 0, 1) if ctx.params.refine else np.clip(margin / 0.1, 0, 1)
    return 0.5 * evidence + 0.5 * consistency
