"""The inverse of a muscle layer: which activations bring skin points to given positions (issue 17 §5).

A layer's response is taken as linear: B (3n, m), mm of skin displacement per unit of each of its m
parameters. For the Waters muscles it is exact (``WatersModel.response``); for SABiom's simulated muscles
it is measured once by finite differences on a copy of the layer (each parameter alone at a probe value,
settled), a linearisation at rest. For skin vertices v_1..v_k with wanted displacements d (from the layer)
the activations s solve the bounded least-squares problem

    min ‖B_v s − d‖² + ρ ‖s − s₀‖²,   lower ≤ s ≤ upper   (lower ≥ 0: muscles only pull)

B_v the vertices' rows, s₀ the current activations (ρ keeps the muscles that do not help where they are and
picks the nearest of many solutions), with ``scipy.optimize.lsq_linear`` (BVLS). ``refine`` repeats the
solve with the target corrected by what the real layer did (a secant step per round), for layers whose
response is not quite linear.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import scipy.sparse
from scipy.optimize import lsq_linear

from core import parameters as P

__all__ = ["LinearResponse", "solve_activations", "reach"]


def solve_activations(response: np.ndarray, target: np.ndarray, current: np.ndarray, lower: np.ndarray,
                      upper: np.ndarray, regularization: float = 1e-4) -> np.ndarray:
    """(m,) activations in [lower, upper] minimising ‖response·s − target‖² + ρ‖s − current‖².

    response : (3k, m) mm per unit; target : (3k,) mm; current, lower, upper : (m,); ρ ≥ 0 (mm² per unit²)."""
    a = np.asarray(response, dtype=float)
    b = np.asarray(target, dtype=float).ravel()
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    s0 = np.clip(np.asarray(current, dtype=float).ravel(), lo, hi)
    if a.ndim != 2 or a.shape[0] != len(b) or a.shape[1] != len(s0):
        raise P.ParameterError(f"the inverse needs a (3k, m) response, (3k,) targets and (m,) activations, got "
                               f"{a.shape}, {b.shape}, {s0.shape}")
    if not regularization >= 0:
        raise P.ParameterError(f"the inverse's regulariser must be ≥ 0, got {regularization}")
    r = np.sqrt(regularization)
    lhs = np.vstack([a, r * np.eye(len(s0))])
    rhs = np.concatenate([b, r * s0])
    # BVLS can end a rounding error outside a bound (-1e-17 for a muscle at 0), which the registry refuses.
    return np.clip(lsq_linear(lhs, rhs, bounds=(lo, hi), method="bvls").x, lo, hi)


class LinearResponse:
    """keys (m,) canonical parameter keys; matrix (3n, m) mm per unit (dense or sparse; rows x, y, z of each
    vertex); bounds from the registry, the lower one at least 0."""

    def __init__(self, keys: Sequence[str], matrix):
        self.keys = tuple(keys)
        self.matrix = matrix if scipy.sparse.issparse(matrix) else np.asarray(matrix, dtype=float)
        if self.matrix.shape[1] != len(self.keys):
            raise ValueError(f"a response of {self.matrix.shape[1]} columns for {len(self.keys)} keys")
        params = [P.describe(k) for k in self.keys]
        self.lower = np.array([max(0.0, p.minimum) for p in params])
        self.upper = np.array([p.maximum for p in params])

    @classmethod
    def of_waters(cls, layer) -> "LinearResponse":
        """The Waters layer's exact response (its model's)."""
        return cls(layer.model.keys, layer.model.response)

    @classmethod
    def measured(cls, layer, *, probe: float = 0.25, settle: Callable | None = None,
                 keys: Sequence[str] | None = None) -> "LinearResponse":
        """Finite differences on a copy of ``layer`` (the layer itself is untouched): each key alone at
        ``probe`` × its maximum, settled by ``settle(copy)`` (default ``copy.solve()`` when it has one),
        its offset divided by that value. About 0.2 s per key for SABiom's muscles."""
        twin = layer.copy()
        keys = tuple(layer.parameters() if keys is None else (P.key_of(k) for k in keys))
        settle = settle or (lambda lay: lay.solve() if hasattr(lay, "solve") else None)
        twin.set_values({k: P.describe(k).default for k in twin.parameters()})
        settle(twin)
        base = twin.offset(None)
        base = 0.0 if base is None else np.array(base)
        columns = []
        for k in keys:
            value = probe * P.describe(k).maximum
            twin.set_values({k: value})
            settle(twin)
            off = twin.offset(None)
            columns.append(((0.0 if off is None else off) - base).reshape(-1) / value)
            twin.set_values({k: P.describe(k).default})
        settle(twin)
        return cls(keys, np.column_stack(columns))

    def rows(self, vertices) -> np.ndarray:
        """(3k, m) the rows of skin vertices (k,)."""
        v = np.asarray(vertices, dtype=np.int64).ravel()
        rows = (3 * v[:, None] + np.arange(3)).ravel()
        out = self.matrix[rows]
        return out.toarray() if scipy.sparse.issparse(out) else np.asarray(out)

    def solve(self, vertices, displacements, current, *, regularization: float = 1e-4) -> np.ndarray:
        """(m,) activations giving ``vertices`` (k,) the displacements (k, 3) mm as nearly as they can."""
        return solve_activations(self.rows(vertices), np.asarray(displacements, dtype=float).ravel(), current,
                                 self.lower, self.upper, regularization)


def reach(rig, layer, response: LinearResponse, vertices, positions, *, regularization: float = 1e-4,
          refine: int = 0, settle: Callable | None = None) -> dict[str, float]:
    """Activations of ``layer`` (in ``rig``) that bring skin ``vertices`` (k,) to ``positions`` (k, 3) mm from
    the current pose, set on the rig (one change). ``refine`` rounds: settle the layer (``settle(layer)``),
    see where the vertices went, correct the target by the linear model's error and solve again.
    Returns {key: value}."""
    v = np.asarray(vertices, dtype=np.int64).ravel()
    p = np.asarray(positions, dtype=float).reshape(len(v), 3)
    current = np.array([layer.value(k) for k in response.keys])
    own = layer.offset(None)
    base = rig.vertices()[v] - (0.0 if own is None else np.asarray(own)[v])
    wanted = p - base
    target = wanted.copy()
    s = current
    for round_ in range(refine + 1):
        s = response.solve(v, target, current, regularization=regularization)
        rig.set_values(dict(zip(response.keys, s.tolist())))
        if round_ == refine:
            break
        if settle is not None:
            settle(layer)
        off = layer.offset(None)
        got = np.zeros_like(wanted) if off is None else np.asarray(off)[v]
        predicted = (response.rows(v) @ s).reshape(-1, 3)
        target = wanted + (predicted - got)        # the linear model's error at s, taken off the target
    return dict(zip(response.keys, s.tolist()))
