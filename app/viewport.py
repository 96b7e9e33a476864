"""viewport.py
----
One scheduler for everything drawn in the 3-D view.

Anything that changes the picture calls ``viewport.request(part)`` — ``"mesh"`` (the rig moved),
``"overlay"`` (heat map or influence region), ``"landmarks"``, ``"muscles"``, or ``"render"`` (only
redraw) — instead of rendering itself. One zero-delay single-shot timer then runs each updater
registered for one of the requested parts once (in registration order, with the set of parts
requested) and renders once: a burst of slider
ticks, muscle settling steps and timeline frames costs one redraw per pass of the event loop, and
input events get handled in between (software OpenGL takes 25-400 ms per frame).

``last_tick_ms`` is (compute ms, draw ms) of the last update that moved the mesh: compute is the
updaters' time, draw the render's.

Level of detail while things move (ParaView's "LOD while interacting"): a pass that moved the
mesh, and a camera drag or wheel zoom (VTK's start/end interaction events), draw the face's draft
copy (:mod:`app.preview`, through the ``set_draft`` callback); ``SETTLE_MS`` after the last such
input the full face is drawn once. ``last_full_ms`` is the time of that full-quality render.
"""

from __future__ import annotations

import time
from typing import Callable

from PySide6.QtCore import QObject, QTimer, Signal
from PySide6.QtOpenGLWidgets import QOpenGLWidget

__all__ = ["Viewport", "PARTS"]

PARTS = ("mesh", "overlay", "landmarks", "muscles", "render")
SETTLE_MS = 150   # input pause after which the full-quality frame is drawn


class Viewport(QObject):
    """Schedules updates and renders of ``plotter`` (a pyvistaqt QtInteractor).

    alive() -> False once the window closes (nothing is drawn then).
    Signals: ``timed(compute_ms, draw_ms)`` after an update that moved the mesh.
    """

    timed = Signal(float, float)
    settled = Signal(float)   # ms of the full-quality render drawn once input paused

    def __init__(self, plotter, alive: Callable[[], bool], parent: QObject | None = None):
        super().__init__(parent)
        self.plotter = plotter
        self._alive = alive
        self._updaters: list[tuple[frozenset, Callable[[frozenset], bool]]] = []
        self._pending: set[str] = set()
        self.timer = QTimer(self)
        self.timer.setSingleShot(True)
        self.timer.setInterval(0)
        self.timer.timeout.connect(self.tick)
        self.last_tick_ms: tuple[float, float] | None = None
        self.last_full_ms: float | None = None
        # set_draft(on) -> True if what is drawn changed; None: no draft level of detail
        self.set_draft: Callable[[bool], bool] | None = None
        self.settle_timer = QTimer(self)
        self.settle_timer.setSingleShot(True)
        self.settle_timer.setInterval(SETTLE_MS)
        self.settle_timer.timeout.connect(self.settle)
        self._interacting = False

    def watch_camera(self, interactor) -> None:
        """Draw drafts while the camera is dragged or zoomed with ``interactor`` (a vtkRenderWindowInteractor)."""
        interactor.AddObserver("StartInteractionEvent", lambda *_: self._camera_moves(True))
        interactor.AddObserver("EndInteractionEvent", lambda *_: self._camera_moves(False))

    def _camera_moves(self, started: bool) -> None:
        self._interacting = started
        if started:
            self.settle_timer.stop()
            self._draft(True)   # VTK renders the drag itself
        else:
            self.settle_timer.start()

    def _draft(self, on: bool) -> bool:
        return bool(self.set_draft(on)) if self.set_draft is not None else False

    def settle(self) -> None:
        """Draw the full-quality frame now (the settle timer does it once input pauses)."""
        self.settle_timer.stop()
        if self._interacting or not self._alive():
            return
        if self.timer.isActive():   # an update is still queued: settle after it
            self.settle_timer.start()
            return
        if self._draft(False):
            start = time.perf_counter()
            self.render()
            self.last_full_ms = (time.perf_counter() - start) * 1e3
            self.settled.emit(self.last_full_ms)

    def add_updater(self, parts: tuple[str, ...], update: Callable[[frozenset], bool]) -> None:
        """Run ``update(requested)`` when one of ``parts`` was requested; it returns True when it
        changed the picture."""
        for part in parts:
            if part not in PARTS:
                raise ValueError(f"viewport parts are {', '.join(PARTS)}, got {part!r}")
        self._updaters.append((frozenset(parts), update))

    def request(self, *parts: str) -> None:
        """Mark parts of the picture as out of date; they are updated on the next pass of the event loop."""
        for part in parts:
            if part not in PARTS:
                raise ValueError(f"viewport parts are {', '.join(PARTS)}, got {part!r}")
        self._pending.update(parts)
        if self._alive() and not self.timer.isActive():
            self.timer.start()

    def pending(self, part: str) -> bool:
        return part in self._pending

    def flush(self) -> None:
        """Run a pending update now and draw the full face (tests and scripts; timers do it otherwise)."""
        if self.timer.isActive():
            self.timer.stop()
            self.tick()
        if self.settle_timer.isActive():
            self.settle()

    def stop(self) -> None:
        self.timer.stop()
        self.settle_timer.stop()
        self._pending.clear()

    def tick(self) -> None:
        parts, self._pending = frozenset(self._pending), set()
        if not parts or not self._alive():
            return
        start = time.perf_counter()
        changed = "render" in parts
        for wanted, update in self._updaters:
            if wanted & parts:
                changed = bool(update(parts)) or changed
        computed = time.perf_counter()
        if not changed:
            return
        if "mesh" in parts:   # something moves: draft now, the full face once it pauses
            self._draft(True)
            self.settle_timer.start()
        self.render()
        drawn = time.perf_counter()
        if "mesh" in parts:
            self.last_tick_ms = ((computed - start) * 1e3, (drawn - computed) * 1e3)
            self.timed.emit(*self.last_tick_ms)

    def render(self) -> None:
        """Render now, once. A never-shown VTK widget has no GL context to draw into; its first paint renders."""
        plotter = self.plotter
        if self._alive() and plotter.isVisible() and not getattr(plotter, "_closed", False):
            if isinstance(plotter, QOpenGLWidget):
                # pyvistaqt's QOpenGLWidget interactor renders in every paint, and a VTK render
                # schedules a paint: plotter.render() drew each frame twice. A synchronous repaint
                # renders and shows it once.
                plotter.repaint()
            else:
                plotter.render()
