"""muscle_simulation.py
----
:class:`MuscleSimulation`, the controller behind the muscle dock: it owns the
:class:`core.layers.muscles.MuscleLayer` of the window's face (built on a worker thread, re-built
when the face changes), the solver loops that move it, and every edit a user makes to it. The dock
only shows what it reports (signals) and forwards the user's gestures.

* Edits (``set_values``, ``reset_all``, ``apply_preset``, ``apply_force_set``, ``open_force_file``,
  ``rest``) are one rig event each (``rig.batch``), which the window's
  :class:`app.undo.UndoableRigEdits` records as one undo step like any parameter change; the
  changes of one control during one gesture (a slider drag) merge into one step. A refused value
  leaves the layer alone: ``refused(message)``, and ``message`` says why until the next good edit.
* Live quasi-static solve: an edit only sets the force; a 0 ms QTimer then calls
  ``layer.relax(budget_s=...)`` once per event-loop pass (the window redraws in between) until the
  layer reports ``converged``. The status says "settling… residual x %", then "equilibrium" (or
  "at rest" with every force 0). No call blocks the GUI thread for much more than the budget:
  ``RELAX_BUDGET_S``, or half the window's last redraw time when that is slow (software OpenGL:
  about a second for the default face under Xvfb), at most ``MAX_RELAX_BUDGET_S``, so settling is
  not slaved to the redraw rate. Changes from elsewhere (undo, the timeline, a script) settle too.
* Animate: plays the transition from rest to the current forces with the layer's dynamic
  integrator in wall-clock time (QTimer at ~30 fps, each tick ``layer.advance(elapsed)``, an
  elapsed time above ``MAX_FRAME_S`` is cut so a stalled GUI slows the replay instead of jumping)
  for ``animation_s`` seconds, then the quasi-static solve finishes the pose. ``stop`` ends it.
* Rest: every force and the jaw to 0, played back with the same dynamics from the current pose
  (``reset_all`` is the instant version, ``layer.reset()``).
* ``SolverDiverged``: the loops stop, ``diverged(message)`` and the status say so; the layer has
  already restored its last good state.
* ``preset``: the preset the forces match after any change (None: none), ``last_preset`` the one
  applied or matched last (what the dock's "Apply again" re-applies after edits).
* ``shutdown`` (the window really closes): timers stop, a running build is waited for.

Signals: ``layer_changed(layer or None)``, ``message_changed(text)`` (why there is no layer, a build
in progress, a refused value; "" none), ``values_changed()`` (forces or jaw changed, from anywhere),
``pose_changed()`` (the layer moved: redraw what shows it), ``status_changed(text)``,
``animating_changed(bool)``, ``settled()``, ``refused(message)``, ``diverged(message)``,
``notice(text, ms)`` (for the window's status bar).
"""

from __future__ import annotations

import contextlib
import functools
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Hashable, Mapping

from PySide6.QtCore import QObject, Qt, QTimer, Signal, Slot

from app.jobs import JobRunner
from core import parameters as P

if TYPE_CHECKING:  # pragma: no cover
    from core.layers.muscles import ForceSet, MuscleLayer

#: Wall-clock budget of one quasi-static update (s): well under a frame with the redraw.
RELAX_BUDGET_S = 0.02
#: When the window's redraw is slow (software OpenGL), the budget grows to half the last redraw
#: time, up to this (s): the solve then keeps a third of the time instead of a few percent.
MAX_RELAX_BUDGET_S = 0.1
#: Animation frame interval (ms) and the longest step one frame may integrate (s).
ANIMATION_INTERVAL_MS = 33
MAX_FRAME_S = 0.25
#: How long Animate / Rest play the dynamics (s) before the quasi-static solve takes over.
ANIMATION_S = 1.0
#: Two forces closer than this (thesis units / degrees) are the same (a preset matches the layer).
MATCH_TOLERANCE = 1e-6

BUILDING_MESSAGE = "Building the muscle model…"
NO_FACE_MESSAGE = "No face loaded yet."
NO_RIG_MESSAGE = ("The muscles need the face's MPEG-4 feature points: mark them (landmark picker), "
                  "then the muscle model is built.")


def face_signature(face) -> tuple:
    """What the muscle model depends on: the same face object with corrected landmarks (Tools ▸
    Rebuild animation) must be built again."""
    import numpy as np

    names = tuple(face.landmark_names)
    try:
        marks = np.asarray(face.landmark_positions(list(names)), float).tobytes() if names else b""
    except Exception:  # noqa: BLE001 - a face whose landmarks cannot be placed: never re-used
        marks = object()
    v = np.asarray(face.vertices)
    return names, marks, v.shape, float(v.sum())


@functools.cache
def _preset_controls() -> dict[str, tuple[dict, float]]:
    """{preset name: (all 19 forces, jaw degrees)}, read once (matched on every change)."""
    from core.layers.muscles import preset, preset_names

    return {name: (preset(name).full(), float(preset(name).jaw_deg)) for name in preset_names()}


def preset_title(name: str) -> str:
    """"discreet_smile" -> "Discreet smile"."""
    return name.replace("_", " ").capitalize()


class MuscleSimulation(QObject):
    """The muscle layer of a document's face, its solver loops and its edits (see the module docstring).

    Parameters
    ----------
    parent : QObject, optional
    level : int
        Template level of the muscle model (passed to ``MuscleLayer``).
    document : app.document.Document, optional
        Whose face and rig :meth:`follow_document` builds for; without one, :meth:`set_layer` only.
    redraw_ms : callable, optional
        () -> (compute ms, draw ms) of the window's last redraw, or None (the relax budget).
    """

    layer_changed = Signal(object)
    message_changed = Signal(str)
    values_changed = Signal()
    pose_changed = Signal()
    status_changed = Signal(str)
    animating_changed = Signal(bool)
    settled = Signal()
    refused = Signal(str)
    diverged = Signal(str)
    notice = Signal(str, int)

    def __init__(self, parent: QObject | None = None, *, level: int = 3, document=None,
                 redraw_ms: Callable[[], tuple | None] | None = None):
        super().__init__(parent)
        self.level = int(level)
        self.document = document
        self.redraw_ms = redraw_ms
        self.layer: "MuscleLayer | None" = None
        self.rig = None
        self.message = ""
        self.status = ""
        #: The preset the forces match now (None: none) and the one applied or matched last
        #: (what "Apply again" applies after edits).
        self.preset: str | None = None
        self.last_preset: str | None = None
        self._layer_face = None  # the face self.layer was built for (kept for re-use)
        self._layer_signature: tuple | None = None  # its landmarks and vertices when built
        self._builds = JobRunner(self, supersede=True)   # a newer face's build supersedes the older one
        self._pending_build: tuple | None = None   # (face, build) waiting for the event loop to start it
        self._closed = False
        self._animating = False
        self._anim_elapsed = 0.0
        self._anim_last = 0.0
        #: Seconds of dynamics Animate / Rest play.
        self.animation_s = ANIMATION_S
        #: Timing of the live loop: the last relax report and the edit -> settled time (s).
        self.last_relax: object | None = None
        self.last_settle_s: float | None = None
        self._edit_started: float | None = None
        self.relax_ticks = 0

        self._relax_timer = QTimer(self)
        self._relax_timer.setInterval(0)
        self._relax_timer.timeout.connect(self._relax_tick)
        self._anim_timer = QTimer(self)
        self._anim_timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._anim_timer.setInterval(ANIMATION_INTERVAL_MS)
        self._anim_timer.timeout.connect(self._anim_tick)

    # ============================================================ state
    @property
    def settling(self) -> bool:
        """True while the relax timer runs."""
        return self._relax_timer.isActive()

    @property
    def animating(self) -> bool:
        return self._animating

    @property
    def building(self) -> bool:
        return self.layer is None and self.message == BUILDING_MESSAGE

    def values(self) -> dict[str, float]:
        """{canonical key: value} of every control: the muscle forces, then "jaw" (degrees)."""
        layer = self.layer
        if layer is None:
            return {}
        return {key: float(layer.value(key)) for key in layer.parameters()}

    def state(self) -> tuple:
        """(forces in ``control_keys()`` order, jaw degrees): the controls as a plain tuple."""
        from core.layers.muscles import control_keys

        layer = self.layer
        if layer is None:
            return ()
        forces = layer.forces()
        return tuple(float(forces.get(k, 0.0)) for k in control_keys()), float(layer.jaw_deg)

    @property
    def at_rest(self) -> bool:
        """Every force and the jaw at 0."""
        state = self.state()
        return bool(state) and not any(state[0]) and state[1] == 0.0

    def matching_preset(self) -> str | None:
        """The preset whose forces and jaw the layer holds now (None: none does)."""
        layer = self.layer
        if layer is None:
            return None
        forces, jaw = layer.forces(), float(layer.jaw_deg)
        for name, (full, preset_jaw) in _preset_controls().items():
            if abs(preset_jaw - jaw) <= MATCH_TOLERANCE and all(
                    abs(full.get(k, 0.0) - v) <= MATCH_TOLERANCE for k, v in forces.items()):
                return name
        return None

    def _set_message(self, text: str) -> None:
        if text != self.message:
            self.message = text
            self.message_changed.emit(text)

    def _set_status(self, text: str) -> None:
        if text != self.status:
            self.status = text
            self.status_changed.emit(text)

    def _set_animating(self, animating: bool) -> None:
        if animating != self._animating:
            self._animating = animating
            self.animating_changed.emit(animating)

    # ============================================================ the layer
    def set_layer(self, layer: "MuscleLayer | None", message: str = "", *, rig=None) -> None:
        """Drive ``layer`` (attached to ``rig`` when given); None: no layer, ``message`` says why."""
        self.stop(relax=False)
        self._relax_timer.stop()
        self._disconnect_layer()
        self._detach_from_rig()
        if layer is not self.layer:
            self.last_preset = None
        self.layer = layer
        self._match_preset()
        if layer is not None:
            if rig is not None:
                layer.attach(rig)
                self.rig = rig
            layer.changed.connect(self._on_layer_changed)
            layer.parameters_changed.connect(self._on_values_changed)
        self._set_message(message)
        self._set_status("")
        self.layer_changed.emit(layer)
        if layer is not None:
            self._update_status(converged=bool(getattr(layer, "converged", True)))
            # No render here: attach() touched the rig, so the window redraws on its own.

    def _disconnect_layer(self) -> None:
        layer = self.layer
        if layer is None:
            return
        for signal, slot in ((layer.changed, self._on_layer_changed),
                             (layer.parameters_changed, self._on_values_changed)):
            with contextlib.suppress(ValueError, RuntimeError, TypeError):
                signal.disconnect(slot)

    def _detach_from_rig(self) -> None:
        rig, self.rig = self.rig, None
        if rig is not None:
            with contextlib.suppress(Exception):  # the rig may already be gone
                rig.remove_layer("muscles")

    def follow_document(self) -> None:
        """Follow the document's current face and rig: re-use the layer, build one (in the
        background) or drop it with the reason."""
        document = self.document
        if document is None or self._closed:
            return
        face, rig = document.face, document.rig
        self._builds.cancel()  # builds still running are for an older face
        self._pending_build = None
        if face is None:
            self._release_layer()
            self.set_layer(None, NO_FACE_MESSAGE)
            return
        if rig is None:
            self._release_layer()
            if document.rig_pending:   # the rig is on its way (document.rig_changed)
                self.set_layer(None, BUILDING_MESSAGE)
                return
            reason = document.rig_message or NO_RIG_MESSAGE
            self.set_layer(None, f"Muscles are not available for this face.\n\n{reason}")
            return
        signature = face_signature(face)
        if self.layer is not None and self._layer_face is face and self._layer_signature == signature:
            layer = self.layer
            self.set_layer(None, "")
            layer.reset()
            self.set_layer(layer, "", rig=rig)
            return
        self._release_layer()
        self.set_layer(None, BUILDING_MESSAGE)
        self._layer_face, self._layer_signature = face, signature
        level, template = self.level, self._shared_template(rig)

        def build(job):
            from core.layers.muscles import MuscleLayer

            try:
                return MuscleLayer(face, level=level, template_dense=template)
            except ValueError as exc:  # the face does not fit the model: a message, not a bug
                raise ValueError(f"The muscle model cannot be built for this face: {exc}") from None

        # Started from the event loop, after the handlers of this change (the FAP dock building its
        # rows, the first frame): a Python thread started now would take half of their time (GIL).
        self._pending_build = pending = (face, build)

        def start() -> None:
            if self._pending_build is pending and not self._closed:
                self._pending_build = None
                self._builds.start(build, self._on_built, self._on_build_failed)

        QTimer.singleShot(0, self, start)

    def _shared_template(self, rig):
        """The rig's densified template when it is the one the layer needs: the layer then skips
        densifying (seconds) and adopts the FAP deformer's face binding (no 3 s bind on the first
        redraw)."""
        dense = getattr(getattr(rig, "deformer", None), "dense", None)
        if dense is None:
            return None
        try:
            from core.layers.fap.template import load_template

            return dense if self.level == len(load_template().steps) else None
        except Exception:  # noqa: BLE001 - an optimisation only
            return None

    def _release_layer(self) -> None:
        """Forget the layer (a different face, or none, is coming)."""
        if self.layer is not None:
            self.set_layer(None, "")
        self._layer_face = None

    def _on_built(self, layer) -> None:
        rig = self.document.rig
        if rig is None:  # cannot happen for the latest generation; be safe
            self.follow_document()
            return
        self.set_layer(layer, "", rig=rig)
        self.notice.emit("Muscle model ready", 4000)

    def _on_build_failed(self, message: str) -> None:
        self._layer_face = None
        self.set_layer(None, message)
        self.notice.emit(message.splitlines()[0], 8000)

    def shutdown(self) -> None:
        """Stop the loops and drop running builds (the window is closing). A build still running is
        waited for: a worker must not outlive the window (nor the interpreter) it reports to."""
        self._closed = True
        self._builds.cancel()
        self._builds.wait(10_000)
        self.stop(relax=False)
        self._relax_timer.stop()
        self._disconnect_layer()
        self.rig = None

    @property
    def closed(self) -> bool:
        """True once :meth:`shutdown` ran."""
        return self._closed

    # ============================================================ layer events
    def _on_layer_changed(self, *_args) -> None:
        if self.layer is None:
            return
        self.pose_changed.emit()
        if self._animating or self._relax_timer.isActive():
            return
        if self.layer.converged:  # e.g. reset(): already an equilibrium
            self._update_status(converged=True)
        else:  # changed from code (a script, undo, the timeline) as well as by an edit: settle it
            self._start_relax()

    def _on_values_changed(self, *_args) -> None:
        if self.layer is not None:
            self._match_preset()
            self.values_changed.emit()

    def _match_preset(self) -> None:
        self.preset = self.matching_preset()
        if self.preset is not None:
            self.last_preset = self.preset

    # ============================================================ edits
    def _edit(self, call) -> bool:
        """Apply one edit as one rig event (one undo step), then settle. Returns success."""
        from core.layers.muscles import SolverDiverged

        layer = self.layer
        if layer is None:
            return False
        self.stop(relax=False)
        self._edit_started = time.perf_counter()
        with self.rig.batch() if self.rig is not None else contextlib.nullcontext():
            try:
                call()
                ok = True
            except SolverDiverged as exc:
                self._diverged(exc)
                return False
            except ValueError as exc:  # a refused value: nothing changed
                self._edit_started = None
                self._set_message(str(exc))
                self.refused.emit(str(exc))
                return False
        self._set_message("")
        if not layer.converged:
            self._start_relax()
        elif not self._relax_timer.isActive():
            self._edit_started = None
            self._update_status(converged=True)
        return ok

    def set_values(self, values: Mapping[Hashable, float]) -> bool:
        """Set controls by any parameter spelling ("muscle:risorius:left", ("risorius", "left"), "jaw")."""
        layer = self.layer
        if layer is None:
            return False
        keyed = {P.key_of(k): float(v) for k, v in values.items()}
        return self._edit(lambda: layer.set_values(keyed))

    def reset_all(self) -> bool:
        """Every force and the jaw to 0, the tissue at rest at once (``layer.reset()``)."""
        layer = self.layer
        return layer is not None and self._edit(layer.reset)

    def apply_force_set(self, force_set: "ForceSet") -> bool:
        layer = self.layer
        return layer is not None and self._edit(lambda: layer.apply(force_set))

    def apply_preset(self, name: str) -> bool:
        """Apply one of ``core.layers.muscles.preset_names()`` (one undo step); KeyError or
        ValueError for an unknown name."""
        from core.layers.muscles import preset

        if self.layer is None or not name:
            return False
        force_set = preset(name)
        self.last_preset = name
        ok = self.apply_force_set(force_set)
        if ok:
            self.notice.emit(f"Applied the {preset_title(name).lower()} forces", 4000)
        return ok

    def open_force_file(self, path) -> bool:
        """Load a force set from ``path`` and apply it (one undo step). A bad file raises
        ``ForceFileError`` or ``OSError`` and changes nothing."""
        from core.layers.muscles import load_force_set

        if self.layer is None:
            return False
        force_set = load_force_set(path)
        ok = self.apply_force_set(force_set)
        if ok:
            self.notice.emit(f"Loaded the force set {Path(path).name}", 5000)
        return ok

    def save_force_file(self, path) -> bool:
        """Write the current forces and jaw to ``path`` (JSON); ``OSError`` / ``ValueError`` on failure."""
        from core.layers.muscles import ForceSet, save_force_set

        layer = self.layer
        if layer is None:
            return False
        save_force_set(path, ForceSet(dict(layer.forces()), jaw_deg=float(layer.jaw_deg), name=Path(path).stem))
        self.notice.emit(f"Saved the force set {path}", 5000)
        return True

    def rest(self) -> None:
        """Forces and jaw to 0, relaxing back with the dynamics (animated)."""
        from core.layers.muscles import control_keys

        layer = self.layer
        if layer is None:
            return
        if self.at_rest and layer.converged and not self._animating:
            return  # already at rest: nothing to play
        zero = {k: 0.0 for k in control_keys()}
        if self._edit(lambda: (layer.set_forces(zero), layer.set_jaw(0.0))):
            self._relax_timer.stop()
            self._play(from_rest=False)

    # ============================================================ quasi-static solve
    def relax_budget(self) -> float:
        """Seconds for the next ``layer.relax`` call (see the module docstring)."""
        last = self.redraw_ms() if self.redraw_ms is not None else None
        if not last:
            return RELAX_BUDGET_S
        redraw_s = sum(last) / 1000.0
        return min(max(RELAX_BUDGET_S, 0.5 * redraw_s), MAX_RELAX_BUDGET_S)

    def _start_relax(self) -> None:
        if self.layer is None or self._animating or self._closed:
            return
        if not self._relax_timer.isActive():
            self.relax_ticks = 0
            self._relax_timer.start()

    @Slot()
    def _relax_tick(self) -> None:
        from core.layers.muscles import SolverDiverged

        layer = self.layer
        if layer is None or self._animating:
            self._relax_timer.stop()
            return
        try:
            report = layer.relax(budget_s=self.relax_budget())
        except SolverDiverged as exc:
            self._diverged(exc)
            return
        self.last_relax = report
        self.relax_ticks += 1
        if report.converged:
            self._relax_timer.stop()
            if self._edit_started is not None:
                self.last_settle_s = time.perf_counter() - self._edit_started
                self._edit_started = None
            self._update_status(converged=True)
            self.settled.emit()
        else:
            self._update_status(converged=False, residual=report.residual)

    def _update_status(self, *, converged: bool, residual: float | None = None) -> None:
        if self.layer is None:
            self._set_status("")
        elif not converged:
            self._set_status("settling…" if residual is None else f"settling… residual {100.0 * residual:.1f} %")
        else:
            self._set_status("at rest" if self.at_rest else "equilibrium")

    def _diverged(self, exc: Exception) -> None:
        self._relax_timer.stop()
        self._anim_timer.stop()
        self._set_animating(False)
        self._edit_started = None
        message = str(exc) or "The simulation diverged; the last good state was kept."
        self._set_status(f"⚠ {message.splitlines()[0]}")
        self.diverged.emit(message)
        self.notice.emit(f"Muscle simulation stopped: {message.splitlines()[0]}", 15000)
        self.values_changed.emit()   # the layer restored its last good state: show it
        self.pose_changed.emit()

    # ============================================================ dynamics playback
    def animate(self) -> None:
        """Play the transition from rest to the current forces in wall-clock time."""
        self._play(from_rest=True)

    def _play(self, *, from_rest: bool) -> None:
        from core.layers.muscles import SolverDiverged

        layer = self.layer
        if layer is None or self._closed:
            return
        self._relax_timer.stop()
        self._set_animating(True)  # before the layer emits: no relax may start meanwhile
        try:
            if from_rest:
                # start_animation plays from the *current* pose: put the tissue at rest first,
                # keeping the controls (reset() zeroes them, apply() puts them back).
                force_set = layer.force_set()
                layer.reset()
                layer.apply(force_set)
            layer.start_animation()
        except SolverDiverged as exc:
            self._diverged(exc)
            return
        self._anim_elapsed = 0.0
        self._anim_last = time.perf_counter()
        self._set_status("animating… 0.00 s")
        self._anim_timer.start()

    @Slot()
    def _anim_tick(self) -> None:
        from core.layers.muscles import SolverDiverged

        layer = self.layer
        if layer is None or not self._animating:
            self._anim_timer.stop()
            return
        now = time.perf_counter()
        dt = min(now - self._anim_last, MAX_FRAME_S)
        self._anim_last = now
        if dt <= 0.0:
            return
        try:
            layer.advance(dt)
        except SolverDiverged as exc:
            self._diverged(exc)
            return
        self._anim_elapsed += dt
        self._set_status(f"animating… {self._anim_elapsed:.2f} s")
        if self._anim_elapsed >= self.animation_s:
            self.stop()

    def stop(self, *, relax: bool = True) -> None:
        """End the animation (the quasi-static solve then finishes the pose unless ``relax`` is False)."""
        was = self._animating
        self._anim_timer.stop()
        self._set_animating(False)
        if was and relax and self.layer is not None:
            self._start_relax()


__all__ = ["MuscleSimulation", "RELAX_BUDGET_S", "MAX_RELAX_BUDGET_S", "ANIMATION_INTERVAL_MS", "MAX_FRAME_S",
           "ANIMATION_S", "BUILDING_MESSAGE", "NO_FACE_MESSAGE", "NO_RIG_MESSAGE", "face_signature",
           "preset_title"]
