"""Radial basis functions and the RBF interpolation system of thesis B §4.1.1 (eqs. 4.5-4.15).

Per coordinate k the map is f_k(x) = P_k(x) + Σ_i A_ik g(‖x − x_i‖), P_k(x) = a_0k + a_1k x + a_2k y + a_3k z
(optional), solved from [[G + λI, P], [Pᵀ, 0]] W = [Y; 0] (B eqs. 4.7-4.12).

Kernels (r in mm):

    multiquadric          g = (r² + δ)^μ,  δ > 0 (mm²), μ > 0     (B eq. 4.14)
    inverse_multiquadric  g = (r² + δ)^μ,  δ > 0 (mm²), μ < 0     (B §4.1.1)
    gaussian              g = exp(−r²/σ),  σ > 0 (mm²)            (B eq. 4.15)
    thin_plate_spline     g = r² log r                            (Wirth 2000; needs the polynomial)
    linear                g = r

Against ``scipy.interpolate.RBFInterpolator`` (whose kernels take εr): multiquadric with μ = ½ is scipy's
−sqrt(1 + (εr)²) times −1/ε with ε = 1/√δ; inverse multiquadric with μ = −½ is scipy's times ε; Gaussian is
scipy's with ε = 1/√σ; thin plate spline is scipy's with ε = 1; linear is −1 times scipy's. A kernel scaled
by a constant s gives the same interpolant with λ scaled by s, so :meth:`Kernel.scipy_arguments` also maps λ
to scipy's ``smoothing``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.spatial.distance import cdist

from core.parameters import ParameterError

__all__ = ["KERNELS", "MAIN_PARAMETER", "Kernel", "RbfSystem", "squared_distances"]

KERNELS = ("multiquadric", "inverse_multiquadric", "gaussian", "thin_plate_spline", "linear")
#: The parameter a user tunes per kernel (thesis B §5.4: "the RBF type and its main parameter"), or None.
MAIN_PARAMETER = {"multiquadric": "delta", "inverse_multiquadric": "delta", "gaussian": "sigma",
                  "thin_plate_spline": None, "linear": None}
#: A system whose condition number is above this is refused (the coefficients would be noise).
MAX_CONDITION = 1e13


@dataclass(frozen=True)
class Kernel:
    """An RBF kernel and its settings (hashable: the deformer caches one factorisation per Kernel).

    name : one of :data:`KERNELS`; delta : δ in mm² (multiquadrics); mu : μ (> 0 multiquadric, < 0 inverse;
    None: ±½); sigma : σ in mm² (Gaussian); polynomial : add the linear term P(x); smoothing : λ ≥ 0 added to
    G's diagonal (0: exact interpolation of the control points).
    """

    name: str = "multiquadric"
    delta: float = 400.0
    mu: float | None = None
    sigma: float = 400.0
    polynomial: bool = True
    smoothing: float = 0.0

    def __post_init__(self):
        if self.name not in KERNELS:
            raise ParameterError(f"unknown RBF kernel {self.name!r}: choose one of {', '.join(KERNELS)}")
        mu = self.mu
        if mu is None:
            mu = -0.5 if self.name == "inverse_multiquadric" else 0.5
        for what, value in (("delta", self.delta), ("mu", mu), ("sigma", self.sigma), ("smoothing", self.smoothing)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ParameterError(f"the RBF {what} must be a finite number, got {value!r}")
        object.__setattr__(self, "mu", float(mu))
        for what in ("delta", "sigma", "smoothing"):
            object.__setattr__(self, what, float(getattr(self, what)))
        object.__setattr__(self, "polynomial", bool(self.polynomial))
        if self.name in ("multiquadric", "inverse_multiquadric") and not self.delta > 0:
            raise ParameterError(f"the {self.name} needs δ > 0 mm² (its locality), got {self.delta:g}; try 400")
        if self.name == "multiquadric" and not self.mu > 0:
            raise ParameterError(f"the multiquadric needs μ > 0 (μ < 0 is the inverse multiquadric), got {self.mu:g}")
        if self.name == "inverse_multiquadric" and not self.mu < 0:
            raise ParameterError(f"the inverse multiquadric needs μ < 0 (μ > 0 is the multiquadric), got {self.mu:g}")
        if self.name == "gaussian" and not self.sigma > 0:
            raise ParameterError(f"the Gaussian needs σ > 0 mm² (its width), got {self.sigma:g}; try 400")
        if self.smoothing < 0:
            raise ParameterError(f"the RBF regulariser λ must be ≥ 0, got {self.smoothing:g}")
        if self.name == "thin_plate_spline" and not self.polynomial:
            raise ParameterError("the thin plate spline needs the linear polynomial term: turn it on, or pick "
                                 "another kernel")

    @property
    def main_parameter(self) -> str | None:
        return MAIN_PARAMETER[self.name]

    def __call__(self, r2: np.ndarray) -> np.ndarray:
        """g at squared distances ``r2`` (any shape, mm²)."""
        r2 = np.asarray(r2, dtype=float)
        if self.name in ("multiquadric", "inverse_multiquadric"):
            if self.mu == 0.5:
                return np.sqrt(r2 + self.delta)
            if self.mu == -0.5:
                return 1.0 / np.sqrt(r2 + self.delta)
            return (r2 + self.delta) ** self.mu
        if self.name == "gaussian":
            return np.exp(r2 * (-1.0 / self.sigma))
        if self.name == "linear":
            return np.sqrt(r2)
        out = np.zeros_like(r2)
        pos = r2 > 0
        out[pos] = 0.5 * r2[pos] * np.log(r2[pos])   # r² log r
        return out

    def scipy_arguments(self) -> dict:
        """Keyword arguments of ``scipy.interpolate.RBFInterpolator`` giving the same interpolant (see the
        module docstring); ValueError for a μ scipy has no kernel for (only ±½)."""
        degree = 1 if self.polynomial else -1
        if self.name in ("multiquadric", "inverse_multiquadric"):
            if abs(self.mu) != 0.5:
                raise ValueError(f"scipy has no multiquadric with μ = {self.mu:g} (only ±½)")
            eps = 1.0 / math.sqrt(self.delta)
            scale = -1.0 / eps if self.name == "multiquadric" else eps   # g = scale · scipy kernel
            return dict(kernel=self.name, epsilon=eps, degree=degree, smoothing=self.smoothing / scale)
        if self.name == "gaussian":
            return dict(kernel="gaussian", epsilon=1.0 / math.sqrt(self.sigma), degree=degree,
                        smoothing=self.smoothing)
        if self.name == "linear":
            return dict(kernel="linear", epsilon=1.0, degree=degree, smoothing=-self.smoothing)
        return dict(kernel="thin_plate_spline", epsilon=1.0, degree=degree, smoothing=self.smoothing)


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) squared Euclidean distances, mm² (from the coordinate differences: no cancellation)."""
    return cdist(np.asarray(a, dtype=float), np.asarray(b, dtype=float), "sqeuclidean")


class RbfSystem:
    """The factorised system of one kernel on one set of centres (control points).

    centres : (c, 3) mm. Raises ParameterError when the system is singular or too ill-conditioned
    (coincident control points, too few for the polynomial), saying what to change.
    """

    def __init__(self, centres, kernel: Kernel):
        x = np.array(centres, dtype=float)
        if x.ndim != 2 or x.shape[1] != 3 or not np.isfinite(x).all():
            raise ParameterError(f"control points must be finite (c, 3) positions in mm, got shape {x.shape}")
        self.centres, self.kernel = x, kernel
        c = len(x)
        self.n = c
        # The polynomial is written in shifted and scaled coordinates (same span, better conditioned).
        self._shift = x.mean(axis=0) if c else np.zeros(3)
        span = float(np.ptp(x, axis=0).max()) if c > 1 else 1.0
        self._scale = span / 2 if span > 0 else 1.0
        m = 4 if kernel.polynomial else 0
        if c == 0 or c < m:
            raise ParameterError(f"the linear polynomial needs at least 4 control points, got {c}; add points or "
                                 "turn the polynomial off")
        lhs = np.zeros((c + m, c + m))
        lhs[:c, :c] = kernel(squared_distances(x, x))
        lhs[np.arange(c), np.arange(c)] += kernel.smoothing
        if m:
            p = self._poly(x)
            lhs[:c, c:] = p
            lhs[c:, :c] = p.T
        cond = np.linalg.cond(lhs)
        if not np.isfinite(cond) or cond > MAX_CONDITION:
            hint = ("two control points coincide or" if c > 1 and (squared_distances(x, x) + np.eye(c)).min() < 1e-12
                    else "")
            raise ParameterError(f"the {kernel.name} RBF system of these {c} control points is singular "
                                 f"(condition {cond:.1e}): {hint} set the regulariser λ > 0, change the kernel's "
                                 "parameter, or turn the linear polynomial on")
        self._lu = scipy.linalg.lu_factor(lhs, check_finite=False)
        self._m = m

    def _poly(self, points: np.ndarray) -> np.ndarray:
        return np.column_stack([np.ones(len(points)), (points - self._shift) / self._scale])

    def basis(self, points) -> np.ndarray:
        """(m, c + 4 or c) [g(‖p − x_i‖), P(p)] at ``points`` (m, 3)."""
        points = np.asarray(points, dtype=float)
        k = self.kernel(squared_distances(points, self.centres))
        return np.hstack([k, self._poly(points)]) if self._m else k

    def coefficients(self, values) -> np.ndarray:
        """(c + 4 or c, k) W for the values (c, k) at the centres (B eq. 4.7)."""
        values = np.asarray(values, dtype=float).reshape(self.n, -1)
        rhs = np.zeros((self.n + self._m, values.shape[1]))
        rhs[:self.n] = values
        return scipy.linalg.lu_solve(self._lu, rhs, check_finite=False)

    def evaluate(self, points, values) -> np.ndarray:
        """(m, k) the interpolant of ``values`` (c, k) at ``points`` (m, 3)."""
        return self.basis(points) @ self.coefficients(values)

    def response(self, points) -> np.ndarray:
        """(m, c) R with interpolant(points) = R @ values for any values (c, k): the basis times the first c
        columns of the system's inverse. Precomputed once, every later evaluation is one matrix product."""
        eye = np.zeros((self.n + self._m, self.n))
        eye[np.arange(self.n), np.arange(self.n)] = 1.0
        inverse = scipy.linalg.lu_solve(self._lu, eye, check_finite=False)   # (c + m, c)
        return self.basis(points) @ inverse
