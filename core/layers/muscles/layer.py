"""``MuscleLayer``: the SABiom muscle model as a layer of the face rig.

Composition order (the rig adds layers after the FAP layer, see ``core.rig``):

    x = rest + FAP offsets (FAT) + muscle offsets + (other layers), then eyeball and head rotations

The muscles are simulated on the *neutral* tissue (the template placed on the neutral face) and
their skin displacement, carried to the full-resolution face by a sparse barycentric binding,
is *added* to the FAP-deformed skin. ``offset(x)`` ignores ``x``. This is linear superposition:
exact for small motions; for large combined ones (a FAP smile plus a muscle smile) the two
displacements add as vectors, so the corner moves by their sum, without the stiffening or the
change of muscle direction a coupled simulation would show, and a FAP jaw opening plus a muscle
jaw opening add their rotations. Use one of the two for the jaw.

The face sees the tissue's skin displacement through a Gaussian filter of 2 mm that never mixes
the lips (``model.SKIN_FILTER_MM``): the spring lattice's element-scale artefacts (buckled wrinkles,
strain piled into the template's slivers at the mouth corners) stay in the simulation.

Binding: face skin vertices on the upper / lower lip bind only to tissue triangles of their own
lip, so the lower lip never drags the upper one; vertices beyond the template's outline fade
out over 6 mm. Eyeballs and upper teeth do not move; the lower teeth follow the jaw rotation
rigidly; attached to a rig, the mouth cavity's lining follows the skin in front of it as it does
for the FAPs (``FapDeformer.cavity_follow``), so lips pulled inward do not pass through it.

Controls are validated (ValueError with a message, never clamped); ``changed`` (psygnal) is
emitted after every control change and every pose update; call ``relax`` from a timer until
``converged`` to follow sliders, or ``start_animation`` + ``advance`` to play the transition
with the thesis's timing.
"""

from __future__ import annotations

import copy as _copy
import time
from dataclasses import dataclass

import numpy as np
from psygnal import Signal

from core import parameters as P
from core.face import Face
from core.layer import ParameterChange, fresh_signals
from core.layers.muscles.force_file import ForceSet, _check_jaw
from core.layers.muscles.model import TissueModel, dense_template
from core.layers.muscles.muscles import MuscleSet, check_control, control_keys, jaw_range, spec_by_name
from core.layers.muscles.solver import TOLERANCE, RelaxReport, SolverDiverged, State, TissueSolver


@dataclass
class LayerSnapshot:
    """A full copy of the layer's state (for timeline caching)."""

    state: State
    controls: np.ndarray
    jaw_deg: float
    mode: str
    relaxed_for: tuple | None


class MuscleLayer:
    """Biomechanical muscles of one face (thesis C), as a rig layer.

    Parameters
    ----------
    face : Face
        The neutral face with the 64 MPEG-4 feature points of the template (mm).
    level : int
        Template subdivision level of the skin mesh: 2 = 1160 vertices (thesis C's size),
        3 = 4560 (the full canonical face, default).
    template_dense : DenseTemplate, optional
        A template already densified on ``face`` (e.g. ``rig.deformer.dense``); skips densifying.
    backend : "numba" | "numpy", optional
        Spring kernel backend (numba when installed).
    """

    name = "muscles"
    dynamic = True            # the face moves when the tissue settles (pose_changed), not on set_forces
    changed = Signal()        # controls or pose changed (widgets listen)
    pose_changed = Signal()   # the tissue moved: the face must be redrawn (the rig listens)
    parameters_changed = Signal(object)  # core.layer.ParameterChange of the forces / jaw set

    def __init__(self, face: Face, *, level: int = 3, template_dense=None, backend: str | None = None):
        t0 = time.perf_counter()
        dense = template_dense if template_dense is not None else dense_template(face, level)
        self.face = face
        self.model = TissueModel(face, dense)
        self.muscles = MuscleSet(self.model)
        self.solver = TissueSolver(self.model, self.muscles, backend=backend)
        self._keys = control_keys()
        self._index = {k: i for i, k in enumerate(self._keys)}
        self._param_keys = tuple(P.key_of(k) for k in self._keys)
        self._controls = np.zeros(len(self._keys))
        self._jaw_deg = 0.0
        self._state = self._rest_state()
        self._mode = "static"
        self._relaxed_for: tuple | None = self._signature()   # rest is the equilibrium of zero forces
        self._state.error = 0.0
        self._offsets: np.ndarray | None = None
        self.integrator = "stable"    # "stable" (symplectic Euler + implicit damping) or "explicit" (thesis)
        self.explicit_step = 0.01     # s, the thesis's Δt for the explicit reference
        self._rig = None
        self.build_seconds = time.perf_counter() - t0

    # ------------------------------------------------------------ info
    @property
    def node_count(self) -> int:
        return self.model.n_nodes

    @property
    def spring_count(self) -> int:
        return self.model.n_springs

    @property
    def jaw_range(self) -> tuple[float, float]:
        return jaw_range()

    @property
    def mode(self) -> str:
        """"static" (following the controls by ``relax``) or "dynamic" (``advance``)."""
        return self._mode

    @property
    def time(self) -> float:
        """Simulated time (s) since the last ``start_animation``."""
        return self._state.time

    # ------------------------------------------------------------ controls
    def set_force(self, name: str, side: str | None, value: float) -> None:
        """Set one muscle force (thesis units); side "left"/"right", None for the orbicularis oris."""
        self.set_forces({(name, side): value})

    def set_forces(self, mapping) -> None:
        """Set several forces {(name, side): value}; all are validated first (nothing changes on error)."""
        checked = [check_control(k[0], k[1], v) if isinstance(k, tuple) and len(k) == 2 else _bad_key(k)
                   for k, v in dict(mapping).items()]
        new = self._controls.copy()
        for key, value in checked:
            new[self._index[key]] = value
        self._set_controls(new, self._jaw_deg)

    def forces(self) -> dict[tuple[str, str | None], float]:
        """All 19 controls {(name, side): force}."""
        return {k: float(v) for k, v in zip(self._keys, self._controls)}

    @property
    def jaw_deg(self) -> float:
        return self._jaw_deg

    def set_jaw(self, degrees: float) -> None:
        """Jaw opening in degrees (range from ``resources/muscles/muscles.json``)."""
        self._set_controls(self._controls, _check_jaw(degrees, ValueError, "jaw"))

    def apply(self, force_set: ForceSet) -> None:
        """Set all controls from a force set (missing muscles 0), validated first."""
        jaw = _check_jaw(force_set.jaw_deg, ValueError, force_set.name or "force set")
        full = {k: 0.0 for k in self._keys}
        for k, v in force_set.forces.items():
            key, value = check_control(k[0], k[1], v) if isinstance(k, tuple) and len(k) == 2 else _bad_key(k)
            full[key] = value
        self._set_controls(np.array([full[k] for k in self._keys]), jaw)

    def force_set(self, name: str = "") -> ForceSet:
        """The current controls as a ForceSet (non-zero forces only)."""
        return ForceSet({k: float(v) for k, v in zip(self._keys, self._controls) if v}, self._jaw_deg, name)

    def reset(self) -> None:
        """Zero forces, jaw 0, tissue back at rest (thesis C's "Initialise")."""
        self._set_controls(np.zeros(len(self._keys)), 0.0)
        self._state = self._rest_state()
        self._state.error = 0.0
        self._mode = "static"
        self._relaxed_for = self._signature()
        self._pose_changed()

    # ------------------------------------------------------------ quasi-static
    @property
    def converged(self) -> bool:
        """True when the pose is the equilibrium of the current controls within 1 %."""
        return self._relaxed_for == self._signature() and self._state.error <= TOLERANCE

    def relax(self, budget_s: float = 0.02) -> RelaxReport:
        """Move toward the equilibrium of the current controls, for about ``budget_s`` seconds.

        Warm-started from the current pose; call repeatedly (e.g. from a GUI timer) until
        ``converged``. Raises SolverDiverged (pose restored) if the solve blows up.
        """
        if not (np.isfinite(budget_s) and budget_s >= 0):
            raise ValueError(f"relax budget must be a non-negative number of seconds, got {budget_s!r}")
        sig = self._signature()
        st = self._state
        if self._relaxed_for == sig and st.error <= TOLERANCE:
            return RelaxReport(True, float(st.error), 0, 0.0)
        angle = np.radians(self._jaw_deg)
        if st.jaw != angle:  # warm start: carry the displacement over to the new jaw rest frame
            old = self.model.rest_positions(st.jaw)[:self.model.n_free]
            new = self.model.rest_positions(angle)[:self.model.n_free]
            st.x += new - old
        st.jaw, st.jaw_rate = angle, 0.0
        st.act[:] = self._controls
        st.act_rate[:] = 0.0
        if self._relaxed_for != sig:
            st.error = np.inf
        self._mode = "static"
        frame = self.solver.frame(angle)
        report = self.solver.relax(st, frame, budget_s=budget_s)
        self._relaxed_for = sig
        self._pose_changed()
        return report

    def solve(self, timeout_s: float = 10.0) -> RelaxReport:
        """Relax until converged (or ``timeout_s``); for scripts and tests."""
        t0 = time.perf_counter()
        report = self.relax(0.05)
        iterations = report.iterations
        while not report.converged and time.perf_counter() - t0 < timeout_s:
            report = self.relax(0.05)
            iterations += report.iterations
        return RelaxReport(report.converged, report.residual, iterations, time.perf_counter() - t0)

    # ------------------------------------------------------------ dynamics
    def start_animation(self) -> None:
        """Play from the current state toward the current controls: activations ramp (eq. 3.16)."""
        self._mode = "dynamic"
        self._state.time = 0.0
        self._state.error = np.inf
        self._relaxed_for = None

    def advance(self, dt: float) -> None:
        """Integrate ``dt`` seconds (substeps as stability needs). Raises SolverDiverged (state restored)."""
        if not (isinstance(dt, (int, float)) and np.isfinite(dt) and dt > 0):
            raise ValueError(f"time step must be a positive number of seconds, got {dt!r}")
        if self._mode != "dynamic":
            self.start_animation()
        jaw = float(np.radians(self._jaw_deg))
        if self.integrator == "explicit":
            self.solver.advance_explicit(self._state, self._controls, jaw, float(dt), self.solver.frame,
                                         step=self.explicit_step)
        elif self.integrator == "stable":
            self.solver.advance_stable(self._state, self._controls, jaw, float(dt), self.solver.frame)
        else:
            raise ValueError(f"unknown integrator {self.integrator!r}; use 'stable' or 'explicit'")
        self._pose_changed()

    def activations(self) -> dict[tuple[str, str | None], float]:
        """Current (ramped) force of every control, thesis units."""
        return {k: float(v) for k, v in zip(self._keys, self._state.act)}

    # ------------------------------------------------------------ snapshots
    def snapshot(self) -> LayerSnapshot:
        return LayerSnapshot(self._state.copy(), self._controls.copy(), self._jaw_deg, self._mode, self._relaxed_for)

    def restore(self, snap: LayerSnapshot) -> None:
        if not isinstance(snap, LayerSnapshot) or snap.state.x.shape != self._state.x.shape:
            raise ValueError("this snapshot does not belong to this muscle layer")
        self._state = snap.state.copy()
        self._mode = snap.mode
        self._relaxed_for = snap.relaxed_for
        self._set_controls(snap.controls.copy(), snap.jaw_deg)
        self._pose_changed()

    # ------------------------------------------------------------ output
    def skin_offsets(self) -> np.ndarray:
        """(n_face, 3) mm offsets of the full-resolution face for the current state (read-only)."""
        if self._offsets is None:
            m = self.model
            u = (self._state.x[:m.n] - m.rest[:m.n]) * 10.0   # cm -> mm
            rows, F = m.skin_filter(self._acted_on())   # without the lattice's element-scale artefacts
            if len(rows):
                u[rows] = self.solver.kernels.matvec3(F, u)
            out = self.solver.kernels.matvec3(m.binding, u)
            if len(m.teeth_lower) and self._state.jaw != 0.0:
                p = self.face.vertices[m.teeth_lower]
                out[m.teeth_lower] = m.rigid_jaw(p, self._state.jaw) - p
            out.setflags(write=False)
            self._offsets = out
        return self._offsets

    def offset(self, x: np.ndarray) -> np.ndarray:
        """The rig layer function: the muscle offsets (``x`` is ignored: linear superposition)."""
        return self.skin_offsets()

    def finish(self, x: np.ndarray, pinned: np.ndarray | None = None) -> np.ndarray:
        return x

    def attach(self, rig) -> None:
        """Add this layer to a ``FaceRig`` (after its FAP layer); the rig listens to its events."""
        dense = getattr(getattr(rig, "deformer", None), "dense", None)
        if dense is not None and (dense is self.model.dense or (
                dense.vertices.shape == self.model.skin_mm.shape and np.allclose(dense.vertices, self.model.skin_mm))):
            self.model.use_binding(getattr(rig.deformer, "binding", None))
            if self.model.use_jaw_weights(getattr(rig.deformer, "template_weights", {}).get(3)):
                self.solver.forget_frame()
                if self._state.jaw != 0.0:    # a pose opened with the old weights: settle it again
                    self._relaxed_for = None
        follow = getattr(getattr(rig, "deformer", None), "cavity_follow", None)
        if follow is not None:
            self.model.follow_cavity(follow())
            self._offsets = None
        rig.add_layer(self)
        self._rig = rig

    # ------------------------------------------------------------ the rig-layer protocol (core.layer)
    def parameters(self) -> tuple[str, ...]:
        return self._param_keys + ("jaw",)

    def value(self, key) -> float:
        k = P.parse(key)
        if k.kind == "jaw":
            return float(self._jaw_deg)
        return float(self._controls[self._index[(k.id, k.side)]])

    def set_values(self, values) -> None:
        """Set forces and the jaw by parameter key (all validated first)."""
        forces, jaw = {}, self._jaw_deg
        for spelling, value in values.items():
            k = P.parse(spelling)
            if k.kind == "jaw":
                jaw = _check_jaw(value, ValueError, "jaw")
            elif k.kind == "muscle":
                forces[(k.id, k.side)] = value
            else:
                raise P.ParameterError(f"{k} is not a muscle force or the jaw")
        checked = [check_control(n, s, v) for (n, s), v in forces.items()]
        new = self._controls.copy()
        for key, value in checked:
            new[self._index[key]] = value
        self._set_controls(new, jaw)

    def copy(self) -> "MuscleLayer":
        """An independent layer on the same (immutable) tissue model, in the same state."""
        twin = _copy.copy(self)
        fresh_signals(twin)
        twin._rig = None
        # The solver's matrices are shared; its per-solve caches (frame, Anderson history) are not.
        twin.solver = _copy.copy(self.solver)
        twin.solver._aa = None
        twin._state = self._state.copy()
        twin._controls = self._controls.copy()
        twin._offsets = None
        return twin

    def muscle_segments(self) -> list[tuple[str, str | None, np.ndarray, np.ndarray, float]]:
        """[(name, side, P (3,), R (3,), activation 0..1)] in face mm for drawing the linear muscles."""
        st = self._state
        rest = self.model.rest_positions(st.jaw)
        specs = spec_by_name()
        out = []
        for (key, p, r) in self.muscles.segments(st.x, rest):
            a = st.act[self._index[key]] / specs[key[0]].maximum
            out.append((key[0], key[1], p * 10.0, r * 10.0, float(np.clip(a, 0.0, 1.0))))
        return out

    def muscle_ring(self) -> tuple[np.ndarray, float]:
        """((k, 3) mm closed polyline of the orbicularis oris on the skin, activation 0..1)."""
        key = self.muscles.sphincter.key
        a = self._state.act[self._index[key]] / spec_by_name()[key[0]].maximum
        return self.muscles.ring(self._state.x) * 10.0, float(np.clip(a, 0.0, 1.0))

    def tissue_skin(self) -> np.ndarray:
        """(N, 3) mm: the simulated skin surface (tissue triangles: ``model.triangles``)."""
        return self._state.x[:self.model.n] * 10.0

    # ------------------------------------------------------------ internals
    def _rest_state(self) -> State:
        C = len(self._keys)
        x = self.model.rest[:self.model.n_free].copy()
        return State(x, np.zeros_like(x), np.zeros(C), np.zeros(C))

    def _acted_on(self) -> np.ndarray:
        """(N,) bool: skin nodes a muscle pulls or the jaw turns (kept while the jaw weights are the same)."""
        m = self.model
        cached = self.__dict__.get("_acted")
        if cached is not None and cached[0] is m.jaw_weight:
            return cached[1]
        acted = m.jaw_weight > 0
        for nodes in [mus.nodes for mus in self.muscles.linear] + [self.muscles.sphincter.nodes]:
            acted[nodes] = True
        self._acted = (m.jaw_weight, acted)
        return acted

    def _signature(self) -> tuple:
        return (self._controls.tobytes(), self._jaw_deg)

    def _set_controls(self, controls: np.ndarray, jaw_deg: float) -> None:
        """Take new forces and jaw angle; announce the ones that changed."""
        changed = np.flatnonzero(controls != self._controls)
        previous = {self._param_keys[i]: float(self._controls[i]) for i in changed}
        values = {self._param_keys[i]: float(controls[i]) for i in changed}
        if jaw_deg != self._jaw_deg:
            previous["jaw"], values["jaw"] = float(self._jaw_deg), float(jaw_deg)
        if not values:
            return
        self._controls, self._jaw_deg = np.array(controls, dtype=float), float(jaw_deg)
        self.changed.emit()
        self.parameters_changed.emit(ParameterChange(values, previous, self.name))

    def _pose_changed(self) -> None:
        self._offsets = None
        self.changed.emit()
        self.pose_changed.emit()


def _bad_key(key):
    raise ValueError(f"muscle controls are (name, side) pairs such as ('risorius', 'left'), got {key!r}")


__all__ = ["MuscleLayer", "LayerSnapshot", "SolverDiverged"]
