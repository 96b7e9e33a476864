"""The inverse of the Waters muscles: which strengths bring skin points to given positions.

Each muscle's response is linear at the rest face (``WatersModel.response``, mm per unit strength), so for
skin vertices v_1..v_k with targets t_j the strengths s solve the bounded least-squares problem

    min ‖B_v s − d‖² + ρ ‖s − s₀‖²,   0 ≤ s ≤ 1

B_v (3k, m) the vertices' rows of the response, d (3k,) the displacements from the Waters layer wanted,
s₀ the current strengths (the regulariser ρ keeps muscles that do not help where they are and picks the
nearest solution when many reach the target). Solved with ``scipy.optimize.lsq_linear`` (BVLS). The
combine rule is taken as 'sum' (a 'limit' below the reached displacement does not change the answer).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

from core.parameters import ParameterError

__all__ = ["solve_strengths", "reach"]


def solve_strengths(response: np.ndarray, target: np.ndarray, current: np.ndarray, *,
                    regularization: float = 1e-4, upper: float = 1.0) -> np.ndarray:
    """(m,) strengths in [0, upper] minimising ‖response·s − target‖² + ρ‖s − current‖².

    response : (3k, m) mm per unit; target : (3k,) mm; current : (m,); regularization ρ ≥ 0 (mm²)."""
    a = np.asarray(response, dtype=float)
    b = np.asarray(target, dtype=float).ravel()
    s0 = np.clip(np.asarray(current, dtype=float).ravel(), 0.0, upper)
    if a.ndim != 2 or a.shape[0] != len(b) or a.shape[1] != len(s0):
        raise ParameterError(f"the inverse needs a (3k, m) response, (3k,) targets and (m,) strengths, got "
                             f"{a.shape}, {b.shape}, {s0.shape}")
    if not regularization >= 0:
        raise ParameterError(f"the inverse's regulariser must be ≥ 0, got {regularization}")
    r = np.sqrt(regularization)
    lhs = np.vstack([a, r * np.eye(len(s0))])
    rhs = np.concatenate([b, r * s0])
    return lsq_linear(lhs, rhs, bounds=(0.0, upper), method="bvls").x


def reach(rig, layer, vertices, positions, *, regularization: float = 1e-4, apply: bool = True) -> dict[str, float]:
    """Strengths of ``layer`` (a WatersLayer in ``rig``) that bring skin ``vertices`` (k,) to ``positions``
    (k, 3) mm as nearly as they can, from the current pose; set on the rig when ``apply`` (one change).
    Returns {waters key: strength}."""
    v = np.asarray(vertices, dtype=np.int64).ravel()
    p = np.asarray(positions, dtype=float).reshape(len(v), 3)
    current = layer.strengths()
    now = rig.vertices()[v]
    own = layer.offset(None)
    base = now - (own[v] if own is not None else 0.0)
    s = solve_strengths(layer.model.vertex_response(v), (p - base).ravel(), current,
                        regularization=regularization)
    values = dict(zip(layer.model.keys, s.tolist()))
    if apply:
        rig.set_values(values)
    return values
