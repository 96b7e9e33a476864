"""Time integration and equilibrium of the tissue model (thesis C eq. 3.1), fit for a live tool.

    m ẍ + γ ẋ + g + q + s + h = f        (per node; CGS units: cm, g, s, dyn)

Three solvers share one force model (``TissueSolver.forces``):

1. ``relax`` — quasi-static pose: the equilibrium of the current forces, by projective dynamics
   (Bouaziz 2014 / Liu 2013). Every spring's energy k/2 (|x_i - x_j| - l0)^2 is the distance to
   the set of spring states of length l0; the local step projects on it (numba kernel), the
   global step solves one constant sparse SPD system L x = b per coordinate (L = spring
   Laplacian + prism k2 matrix + restoring diagonal, factorised once per model with SuperLU).
   The step x_{k+1} - x_k = L^-1 r(x_k) is a preconditioned force residual, so each iteration
   lowers the elastic energy (no step size, no divergence) and warm starts from the last pose.
   The k1 volume term is not an energy gradient and is lagged (evaluated at x_k); it is tiny in
   CGS. Work per call is bounded by a wall-clock budget; the error is estimated from the
   contraction of successive steps, err <= rho/(1 - rho) |x_{k+1} - x_k|.

2. ``advance_stable`` — dynamics for playback: symplectic Euler with implicit damping,
       v <- (v + h F(x)/m) / (1 + h γ/m),   x <- x + h v,
   one force evaluation per substep. Because damping/mass c = γ/m = 60 1/s is the same on every
   node (both scale with node area), the modes of M^-1 K decouple exactly and the scheme is
   stable iff h^2 λ < 4 + 2 h c for the largest eigenvalue λ of M^-1 K. The solver computes λ
   (Lanczos on the PD matrix L, an upper bound of the tangent stiffness) at build time and takes
   ceil(dt / (0.9 h_max)) substeps per call.

3. ``advance_explicit`` — the thesis reference (eq. 3.2 / algorithm 6): a = F(x, v)/m with the
   damping force explicit, v += Δt a, x += Δt v, and the activation by explicit Euler
   (algorithm 5), Δt = 0.01 s by default.

Stability of the thesis scheme at Δt = 0.01 s (written down as the issue asks). For one mode
(ω^2 = λ) the update matrix has characteristic polynomial z^2 - (2 - hc - h^2 λ) z + (1 - hc);
it is stable iff h < 2/c (= 33 ms for c = 60 1/s: the damping term sets a hard limit) and
h^2 λ < 4 - 2hc. With Δt = 0.01 s the second condition reads λ < 28,000 s^-2.
Measured λ_max(M^-1 L) on the default face (after the mass floor, see ``model``): about
4,800 s^-2 at the 1160-vertex level (Δt limit 19 ms: Δt = 0.01 s is stable with a 1.9x margin)
and about 15,200 s^-2 at the 4560-vertex level (limit 12.7 ms, margin 1.27). Without the mass
floor the template's tiny corner triangles gave 27,000 and 207,000 s^-2, and Δt = 0.01 s
diverged on the 4560 level (limit 4 ms). perf.md §2 found 1,142 s^-2 (33 ms) for springs
alone: the prism k2 term and the unscaled in-layer springs over small node masses are what
shrink the margin. The explicit reference keeps Δt = 0.01 s; if a model is ever outside its
limit, the run diverges, is caught, and the user is told to lower the step. The stable
integrator allows h^2 λ < 4 + 2hc: h_max = 44 ms at level 2 (one step per 1/30 s frame) and
21 ms at level 3 (2 substeps per frame). Settling is slow by physics (slowest mode about 3 s:
1 % after ~12 s of simulated time), which is why the quasi-static solve exists.

No NaN escapes: after every call the state is checked (finite, no node farther than
``MAX_DISPLACEMENT_CM`` from rest); on failure the state is restored to what it was before the
call and ``SolverDiverged`` (a ValueError) is raised with advice.

Activation (eq. 3.16) τ² f̈ + 2τ ḟ + f = f_user is critically damped; ``advance_stable``
integrates it exactly per substep (constant target), the explicit reference by explicit Euler as
the thesis did. The jaw angle ramps with the same law, and the jaw-dependent rest frame is
updated once per call.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from core.layers.muscles.kernels import SpringKernels
from core.layers.muscles.model import TissueModel
from core.layers.muscles.muscles import MuscleSet, skull_projection

MAX_DISPLACEMENT_CM = 4.0      # no facial expression moves tissue 4 cm: beyond this the run diverged
TOLERANCE = 0.01               # "within 1 % of equilibrium"
ABS_FLOOR_CM = 1e-4            # 1 µm: below this displacement the pose counts as converged
ANDERSON = 4                   # Anderson acceleration window of the quasi-static solve
ERROR_FACTOR = 40.0            # |x - x*| <= ERROR_FACTOR |L^-1 r| (see ``TissueSolver.relax``)


class SolverDiverged(ValueError):
    """The simulation blew up; the state has been restored to the last good one."""


@dataclass
class RelaxReport:
    """Result of one budgeted quasi-static update."""

    converged: bool
    residual: float     # estimated distance to equilibrium / displacement (fraction; 0.01 = 1 %)
    iterations: int
    seconds: float


@dataclass
class State:
    """What changes in time. x, v : (2N, 3) cm, cm/s (skin then fascia); act, act_rate : (C,)
    thesis force units (and per second); jaw, jaw_rate : rad, rad/s; time : s."""

    x: np.ndarray
    v: np.ndarray
    act: np.ndarray
    act_rate: np.ndarray
    jaw: float = 0.0
    jaw_rate: float = 0.0
    time: float = 0.0
    error: float = np.inf        # last estimate of the distance to equilibrium (fraction)
    rho: float = 0.5             # last contraction ratio of the relaxation

    def copy(self) -> "State":
        return State(self.x.copy(), self.v.copy(), self.act.copy(), self.act_rate.copy(), self.jaw,
                     self.jaw_rate, self.time, self.error, self.rho)


@dataclass
class Frame:
    """Rest quantities for one jaw angle (rad): everything that does not change per iteration."""

    angle: float
    X0: np.ndarray          # (3N, 3) cm rest positions of all nodes
    l0: np.ndarray          # (E,) cm rest lengths
    b_lin: np.ndarray       # (2N, 3) K_lin @ X0_free: prism and restoring anchors
    b_bone: np.ndarray      # (2N, 3) PD right-hand side of the fascia-bone springs (k x_bone)
    normals: np.ndarray     # (N, 3) outward skin normals at rest
    V0: np.ndarray          # (M,) cm^3 prism rest volumes
    r0: np.ndarray          # (M, 6, 3) cm prism rest vectors (node - centroid)
    field: scipy.sparse.csr_matrix  # (3N, C) dyn per force unit
    x_all: np.ndarray = field(repr=False, default=None)  # (3N, 3) work array, bone rows = X0 bone


class TissueSolver:
    """Force model and integrators for one ``TissueModel`` with its ``MuscleSet``."""

    def __init__(self, model: TissueModel, muscles: MuscleSet, *, backend: str | None = None):
        self.model = model
        self.muscles = muscles
        self.kernels = SpringKernels(backend)
        N = model.n
        self.N = N
        self.n_free = 2 * N
        i, j, k = model.springs_i, model.springs_j, model.springs_k
        free_j = j < 2 * N
        # PD matrix: spring Laplacian over free nodes (bone ends only add to the diagonal) + K_lin.
        rows = np.concatenate([i, j[free_j], i[free_j], j[free_j]])
        cols = np.concatenate([i, j[free_j], j[free_j], i[free_j]])
        vals = np.concatenate([k, k[free_j], -k[free_j], -k[free_j]])
        Ls = scipy.sparse.coo_matrix((vals, (rows, cols)), shape=(2 * N, 2 * N)).tocsr()
        self.L = (Ls + model.K_lin).tocsc()
        self._L_csr = self.L.tocsr()
        t0 = time.perf_counter()
        # L is SPD: symmetric ordering, no pivoting (half the fill and solve time of the default).
        self._lu = scipy.sparse.linalg.splu(self.L, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                            options=dict(SymmetricMode=True))
        self.factor_seconds = time.perf_counter() - t0
        self._bone_springs = ~free_j
        self.c = float(model.params.damping / model.params.mass)   # 1/s, same on every node
        self._aa = None
        self.lambda_max = self._largest_eigenvalue()
        c, lam = self.c, self.lambda_max
        self.h_max_stable = (c + np.sqrt(c * c + 4 * lam)) / lam
        self.h_max_explicit = min((-c + np.sqrt(c * c + 4 * lam)) / lam, 2.0 / c)
        self._frame: Frame | None = None
        self._m = model.mass[:, None]
        self._gamma = model.damping[:, None]

    # ------------------------------------------------------------ analysis
    def _largest_eigenvalue(self) -> float:
        """λ_max of M^-1 L (s^-2), via Lanczos on M^-1/2 L M^-1/2."""
        d = 1.0 / np.sqrt(self.model.mass)
        A = scipy.sparse.diags(d) @ self.L @ scipy.sparse.diags(d)
        try:
            val = scipy.sparse.linalg.eigsh(A, k=1, which="LA", tol=1e-3, return_eigenvectors=False,
                                            v0=np.ones(A.shape[0]))
            return float(val[0]) * 1.02
        except Exception:  # fall back to a Gershgorin bound (safe, pessimistic)
            A = abs(A).tocsr()
            return float(np.asarray(A.sum(axis=1)).max())

    def stability_report(self, dt: float = 0.01) -> dict:
        """Numbers for the stability analysis (see the module docstring)."""
        c, lam = self.c, self.lambda_max
        return {
            "lambda_max_per_s2": lam, "damping_rate_per_s": c,
            "explicit_dt_limit_s": self.h_max_explicit, "explicit_stable_at_dt": dt < self.h_max_explicit,
            "explicit_margin": self.h_max_explicit / dt, "stable_dt_limit_s": self.h_max_stable,
        }

    # ------------------------------------------------------------ rest frame
    def frame(self, angle: float) -> Frame:
        """The rest frame for a jaw angle (rad); the last one is cached."""
        f = self._frame
        if f is not None and f.angle == angle:
            return f
        m, N = self.model, self.N
        X0 = m.rest_positions(angle)
        l0 = np.linalg.norm(X0[m.springs_i] - X0[m.springs_j], axis=1)
        b_lin = m.K_lin @ X0[:2 * N]
        b_bone = np.zeros((2 * N, 3))
        bs = self._bone_springs
        for c in range(3):
            b_bone[:, c] = np.bincount(m.springs_i[bs], m.springs_k[bs] * X0[m.springs_j[bs], c], minlength=2 * N)
        normals = m.skin_normals(X0)
        V0 = self._prism_volumes(X0)
        P = X0[m.prisms]
        r0 = np.ascontiguousarray(P - P.mean(axis=1, keepdims=True))
        x_all = X0.copy()
        self._frame = Frame(angle, X0, l0, b_lin, b_bone, normals, V0, r0, self.muscles.field(X0), x_all)
        return self._frame

    def forget_frame(self) -> None:
        """Drop the cached rest frame (after the model's jaw weights changed)."""
        self._frame = None
        self._aa = None

    def _prism_volumes(self, x: np.ndarray) -> np.ndarray:
        """(M,) right-prism volumes (thesis C): skin triangle area x mean skin-fascia edge length."""
        t, N = self.model.triangles, self.N
        a, b, c = x[t[:, 0]], x[t[:, 1]], x[t[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        h = np.linalg.norm(x[t] - x[N + t], axis=2).mean(axis=1)
        return area * h

    # ------------------------------------------------------------ forces
    def muscle_force(self, frame: Frame, act: np.ndarray) -> np.ndarray:
        """(2N, 3) dyn: muscle forces on the skin for activations ``act`` (thesis units), skull-projected."""
        out = np.zeros((2 * self.N, 3))
        if np.any(act):
            f = (frame.field @ act).reshape(self.N, 3)
            out[:self.N] = skull_projection(f, frame.normals)
        return out

    def _add_volume_force(self, x_all: np.ndarray, frame: Frame, out: np.ndarray) -> None:
        """Add the k1 term of eq. 3.7 to ``out`` (2N, 3)."""
        k1 = self.model.params.k1
        if k1 == 0.0:
            return
        N = self.N
        S = np.zeros(N)
        self.kernels.prism_dv(x_all, self.model.triangles, N, frame.V0, S)
        g = (k1 * S)[:, None] * frame.normals
        out[:N] -= g    # an inflated prism pushes its skin nodes in ...
        out[N:] += g    # ... and its fascia nodes out

    def internal_force(self, x: np.ndarray, frame: Frame) -> np.ndarray:
        """(2N, 3) dyn: -(g + q + h) at free positions ``x`` (springs, prisms, restoring, volume)."""
        m = self.model
        x_all = frame.x_all
        x_all[:2 * self.N] = x
        out = np.zeros((3 * self.N, 3))
        self.kernels.forces(x_all, m.springs_i, m.springs_j, m.springs_k, frame.l0, out)
        f = out[:2 * self.N]
        self.kernels.prism_shape(x_all, m.prisms, m.prism_k2, frame.r0, f)   # -K2 (x - X0)
        f -= m.restore[:, None] * (x - frame.X0[:2 * self.N])                 # -h
        self._add_volume_force(x_all, frame, f)
        return f

    def forces(self, x: np.ndarray, frame: Frame, act: np.ndarray) -> np.ndarray:
        """(2N, 3) dyn: total static force (internal + muscle) at ``x``."""
        return self.internal_force(x, frame) + self.muscle_force(frame, act)

    def energy(self, x: np.ndarray, v: np.ndarray, frame: Frame) -> float:
        """Kinetic + elastic energy (erg) of springs, prisms and restoring (k1 term excluded)."""
        m = self.model
        x_all = frame.x_all
        x_all[:2 * self.N] = x
        e = self.kernels.energy(x_all, m.springs_i, m.springs_j, m.springs_k, frame.l0)
        d = x - frame.X0[:2 * self.N]
        e += 0.5 * float(np.sum(d * (m.K_lin @ d)))
        e += 0.5 * float(np.sum(m.mass[:, None] * v * v))
        return e

    def _static_energy(self, x: np.ndarray, frame: Frame, f_ext: np.ndarray) -> float:
        """Elastic energy minus the work of the (constant) muscle forces, erg; k1 term excluded."""
        m = self.model
        x_all = frame.x_all
        x_all[:2 * self.N] = x
        d = x - frame.X0[:2 * self.N]
        return (self.kernels.elastic_energy(x_all, m.springs_i, m.springs_j, m.springs_k, frame.l0, m.prisms,
                                            m.prism_k2, frame.r0)
                + 0.5 * float(np.einsum("i,ij,ij->", m.restore, d, d)) - float(np.einsum("ij,ij->", f_ext, d)))

    # ------------------------------------------------------------ quasi-static
    def _pd_residual(self, x: np.ndarray, frame: Frame, f_ext: np.ndarray) -> np.ndarray:
        """r = b(x) - L x, the force imbalance at x (dyn); L^-1 r is the PD step.

        With the springs projected at x, b(x) - L x is exactly minus the energy gradient, i.e. the
        total force, so it is computed by the force kernels (no product with L)."""
        return self.internal_force(x, frame) + f_ext

    def relax(self, state: State, frame: Frame, *, budget_s: float = 0.02, max_iterations: int = 10_000,
              tolerance: float = TOLERANCE) -> RelaxReport:
        """Move ``state.x`` toward the equilibrium of ``state.act`` for ``frame`` (in place).

        Projective-dynamics iterations with Anderson acceleration (window ``ANDERSON``; an
        accelerated iterate is taken only if it lowers the energy, so the solve descends to a
        minimum and never settles on a saddle of the non-convex spring energy), until the estimated error |x - x*| <= ``tolerance`` x |x - rest|
        (max over nodes) or ``budget_s`` seconds have passed (at least one iteration). The
        acceleration history survives between calls while the controls and the pose are unchanged.

        Error estimate: the PD step g = L^-1 r relates to the error by e = (L^-1 K)^-1 g, and L
        overestimates the stiffness of the slowest modes (springs have no transverse stiffness at
        rest, PD gives them full). The worst case, 1/min eig(L^-1 K), is about 150 on the 4560
        level -- far too pessimistic, and costly to compute; the measured ratio |e| / |g| near
        convergence is about 6 (1160 level) and 26 (4560 level) for the thesis presets, so the
        estimate is ERROR_FACTOR |g| with ERROR_FACTOR = 40 (``benchmarks/bench_muscles.py``
        checks the true error against a tightly converged pose).
        Raises SolverDiverged (state restored) on a non-finite or runaway pose.
        """
        t0 = time.perf_counter()
        backup = state.copy()
        f_ext = self.muscle_force(frame, state.act)
        X0 = frame.X0[:2 * self.N]
        key = (id(frame), frame.angle, state.act.tobytes())
        aa = self._aa
        if aa is None or aa["key"] != key or not np.array_equal(aa["x"], state.x):
            aa = self._aa = {"key": key, "x": None, "F": [], "G": [], "energy": None}
        x = state.x.copy()
        # Energy of the current iterate (for the safeguard); unknown at a fresh start, where the
        # first iteration is a plain PD step anyway.
        energy = aa["energy"] if aa["energy"] is not None else np.inf
        err, it = np.inf, 0
        converged = False
        while it < max_iterations:
            t_it = time.perf_counter()
            g = self._lu.solve(self._pd_residual(x, frame, f_ext))   # PD step from x
            it += 1
            step = float(np.sqrt(np.einsum("ij,ij->i", g, g)).max())
            if not np.isfinite(step) or step > MAX_DISPLACEMENT_CM:
                x = x + g
                break
            u = x + g - X0
            scale = max(float(np.sqrt(np.einsum("ij,ij->i", u, u)).max()), ABS_FLOOR_CM)
            err = ERROR_FACTOR * step / scale
            x_pd = x + g
            if err <= tolerance or step < 1e-10:
                x = x_pd           # the PD step never increases the energy
                energy = None
                converged = True
                break
            # Anderson mixing of the fixed-point map G(x) = x + g(x), accepted only if it lowers
            # the energy (Peng et al. 2018); otherwise the plain PD step, which always does.
            aa["F"].append(g.ravel().copy())
            aa["G"].append(x_pd.ravel())
            if len(aa["F"]) > ANDERSON + 1:
                aa["F"].pop(0)
                aa["G"].pop(0)
            x_next = None
            if len(aa["F"]) > 1:
                dF = np.diff(np.array(aa["F"]), axis=0)
                dG = np.diff(np.array(aa["G"]), axis=0)
                A = dF @ dF.T
                A += 1e-12 * np.trace(A) * np.eye(len(A))
                gamma = np.linalg.solve(A, dF @ aa["F"][-1])
                x_aa = (aa["G"][-1] - gamma @ dG).reshape(-1, 3)
                e_aa = self._static_energy(x_aa, frame, f_ext)
                if e_aa < energy:
                    x_next, energy = x_aa, e_aa
            if x_next is None:
                aa["F"], aa["G"] = aa["F"][-1:], aa["G"][-1:]
                x_next, energy = x_pd, self._static_energy(x_pd, frame, f_ext)
            x = x_next
            now = time.perf_counter()
            if now - t0 + (now - t_it) > budget_s:   # the next iteration would overrun the budget
                break
        aa["energy"] = energy
        state.x[:] = x
        state.v[:] = 0.0
        state.error = err
        aa["x"] = state.x.copy()
        try:
            self._check(state, frame, backup, "relaxing the pose")
        except SolverDiverged:
            self._aa = None
            raise
        return RelaxReport(converged, float(err), it, time.perf_counter() - t0)

    # ------------------------------------------------------------ dynamics
    def substeps(self, dt: float, method: str = "stable") -> int:
        limit = self.h_max_stable if method == "stable" else self.h_max_explicit
        # 0.9: lambda_max is already an upper bound (PD matrix >= tangent stiffness, +2 %).
        return max(1, int(np.ceil(dt / (0.9 * limit))))

    def advance_stable(self, state: State, targets: np.ndarray, jaw_target: float, dt: float,
                       frame_for) -> None:
        """Integrate ``dt`` seconds with symplectic Euler + implicit damping (in place)."""
        backup = state.copy()
        tau = self.model.params.tau
        n = self.substeps(dt, "stable")
        h = dt / n
        # Jaw: one rest frame per call, at the angle reached at the end of the call.
        state.jaw, state.jaw_rate = critically_damped(state.jaw, state.jaw_rate, jaw_target, tau, dt)
        frame = frame_for(state.jaw)
        inv_m = 1.0 / self._m
        damp = 1.0 / (1.0 + h * self.c)
        with np.errstate(over="ignore", invalid="ignore"):  # a blow-up is caught by _check
            self._stable_steps(state, targets, frame, n, h, tau, inv_m, damp)
        state.error = np.inf
        self._check(state, frame, backup, "playing the animation")

    def _stable_steps(self, state, targets, frame, n, h, tau, inv_m, damp) -> None:
        for _ in range(n):
            state.act, state.act_rate = critically_damped(state.act, state.act_rate, targets, tau, h)
            F = self.forces(state.x, frame, state.act)
            state.v += h * F * inv_m
            state.v *= damp
            state.x += h * state.v
            state.time += h
            if not np.isfinite(state.x).all():
                break

    def advance_explicit(self, state: State, targets: np.ndarray, jaw_target: float, dt: float,
                         frame_for, step: float = 0.01) -> None:
        """Thesis C reference: explicit Euler (eq. 3.2, algorithms 5-6) with step ``step`` s (in place).

        ``dt`` is split into ceil(dt / step) equal steps."""
        backup = state.copy()
        tau = self.model.params.tau
        n = max(1, int(np.ceil(dt / step - 1e-9)))
        h = dt / n
        state.jaw, state.jaw_rate = critically_damped(state.jaw, state.jaw_rate, jaw_target, tau, dt)
        frame = frame_for(state.jaw)
        with np.errstate(over="ignore", invalid="ignore"):  # a blow-up is caught by _check
            self._explicit_steps(state, targets, frame, n, h, tau)
        state.error = np.inf
        self._check(state, frame, backup, "running the explicit reference integrator")

    def _explicit_steps(self, state, targets, frame, n, h, tau) -> None:
        for _ in range(n):
            acc = (targets - 2 * tau * state.act_rate - state.act) / (tau * tau)  # algorithm 5
            state.act_rate = state.act_rate + h * acc
            state.act = state.act + h * state.act_rate
            F = self.forces(state.x, frame, state.act) - self._gamma * state.v
            state.v += h * F / self._m
            state.x += h * state.v
            state.time += h
            if not np.isfinite(state.x).all():
                break

    # ------------------------------------------------------------ safety
    def _check(self, state: State, frame: Frame, backup: State, what: str) -> None:
        x = state.x
        ok = bool(np.isfinite(x).all() and np.isfinite(state.v).all())
        if ok:
            d = x - frame.X0[:2 * self.N]
            ok = float(np.einsum("ij,ij->i", d, d).max()) < MAX_DISPLACEMENT_CM ** 2
        if not ok:
            for name in ("x", "v", "act", "act_rate"):
                getattr(state, name)[...] = getattr(backup, name)
            state.jaw, state.jaw_rate, state.time = backup.jaw, backup.jaw_rate, backup.time
            state.error, state.rho = backup.error, backup.rho
            raise SolverDiverged(
                f"The muscle simulation became unstable while {what} (tissue moved more than "
                f"{MAX_DISPLACEMENT_CM * 10:.0f} mm or became undefined). The face was put back to its last "
                "stable pose. Lower the muscle forces or the time step and try again.")


def critically_damped(f, rate, target, tau: float, h: float):
    """Exact step of τ² f̈ + 2τ ḟ + f = target over h seconds (target constant): (f, ḟ)."""
    e = f - target
    a = rate + e / tau
    decay = np.exp(-h / tau)
    e_new = (e + a * h) * decay
    rate_new = (rate - a * h / tau) * decay
    return target + e_new, rate_new
