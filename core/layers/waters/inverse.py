"""The inverse of the Waters muscles (``core.inverse`` with the Waters model's exact linear response):
which strengths bring skin points to given positions.

Each muscle's response is linear at the rest face (``WatersModel.response``, mm per unit strength), so for
skin vertices v_1..v_k with targets t_j the strengths s solve min ‖B_v s − d‖² + ρ‖s − s₀‖², 0 ≤ s ≤ 1
(bounded least squares, BVLS). The combine rule is taken as 'sum' (a 'limit' above the reached
displacement does not change the answer).
"""

from __future__ import annotations

import numpy as np

from core import inverse

__all__ = ["solve_strengths", "reach"]


def solve_strengths(response: np.ndarray, target: np.ndarray, current: np.ndarray, *,
                    regularization: float = 1e-4, upper: float = 1.0) -> np.ndarray:
    """(m,) strengths in [0, upper] minimising ‖response·s − target‖² + ρ‖s − current‖².

    response : (3k, m) mm per unit; target : (3k,) mm; current : (m,); regularization ρ ≥ 0 (mm²)."""
    m = np.asarray(response).shape[1]
    return inverse.solve_activations(response, target, current, np.zeros(m), np.full(m, float(upper)),
                                     regularization)


def reach(rig, layer, vertices, positions, *, regularization: float = 1e-4) -> dict[str, float]:
    """Strengths of ``layer`` (a WatersLayer in ``rig``) that bring skin ``vertices`` (k,) to ``positions``
    (k, 3) mm as nearly as they can, from the current pose; set on the rig (one change).
    Returns {waters key: strength}."""
    return inverse.reach(rig, layer, inverse.LinearResponse.of_waters(layer), vertices, positions,
                         regularization=regularization)
