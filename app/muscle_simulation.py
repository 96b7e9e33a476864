"""The muscle dock's solver loops: after an edit a zero-delay timer relaxes the layer a budget at a time
until it settles (the budget grows with slow redraws); Animate and Rest play the dynamic integrator in
wall-clock time; a diverged solve stops the loops and says so."""

from __future__ import annotations

import time

from PySide6.QtCore import Slot


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


class MuscleSimulationMixin:
    """The solver-loop half of :class:`app.muscle_dock.MuscleDock` (a mixin)."""

    # ============================================================ quasi-static solve
    @property
    def settling(self) -> bool:
        """True while the relax timer runs."""
        return self._relax_timer.isActive()

    @property
    def animating(self) -> bool:
        return self._animating

    def relax_budget(self) -> float:
        """Seconds for the next ``layer.relax`` call (see the module docstring)."""
        last = (self.window_.last_tick_ms if self.window_ is not None else None)
        if not last:
            return RELAX_BUDGET_S
        redraw_s = sum(last) / 1000.0
        return min(max(RELAX_BUDGET_S, 0.5 * redraw_s), MAX_RELAX_BUDGET_S)

    def _start_relax(self) -> None:
        if self.layer is None or self._animating:
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
        layer = self.layer
        if layer is None:
            self.set_status("")
            return
        if not converged:
            text = "settling…" if residual is None else f"settling… residual {100.0 * residual:.1f} %"
        else:
            state = self.state()
            at_rest = bool(state) and not any(state[0]) and state[1] == 0.0
            text = "at rest" if at_rest else "equilibrium"
        self.set_status(text)

    def _diverged(self, exc: Exception) -> None:
        self._relax_timer.stop()
        self._anim_timer.stop()
        self._animating = False
        self.stop_button.setEnabled(False)
        self._edit_started = None
        message = str(exc) or "The simulation diverged; the last good state was kept."
        self.set_status(f"⚠ {message.splitlines()[0]}")
        self.status_label.setToolTip(message)
        self._status_bar(f"Muscle simulation stopped: {message.splitlines()[0]}", 15000)
        self._sync_from_layer()
        self._view_dirty = True
        if self.view is not None and self.view.visible:
            self._update_view()

    # ============================================================ dynamics playback
    def animate(self) -> None:
        """Play the transition from rest to the current forces in wall-clock time."""
        self._play(from_rest=True)

    def _play(self, *, from_rest: bool) -> None:
        from core.layers.muscles import SolverDiverged

        layer = self.layer
        if layer is None:
            return
        self._relax_timer.stop()
        self._animating = True  # before the layer emits: no relax may start meanwhile
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
        self.stop_button.setEnabled(True)
        self.set_status("animating… 0.00 s")
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
        self.set_status(f"animating… {self._anim_elapsed:.2f} s")
        if self._anim_elapsed >= self.animation_s:
            self.stop()

    def stop(self, *, relax: bool = True) -> None:
        """End the animation (the quasi-static solve then finishes the pose unless ``relax`` is False)."""
        was = self._animating
        self._anim_timer.stop()
        self._animating = False
        self.stop_button.setEnabled(False)
        if was and relax and self.layer is not None:
            self._start_relax()
