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
"""

from __future__ import annotations

import time
from typing import Callable

from PySide6.QtCore import QObject, QTimer, Signal

__all__ = ["Viewport", "PARTS"]

PARTS = ("mesh", "overlay", "landmarks", "muscles", "render")


class Viewport(QObject):
    """Schedules updates and renders of ``plotter`` (a pyvistaqt QtInteractor).

    alive() -> False once the window closes (nothing is drawn then).
    Signals: ``timed(compute_ms, draw_ms)`` after an update that moved the mesh.
    """

    timed = Signal(float, float)

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
        """Run a pending update now (tests and scripts; the timer does it otherwise)."""
        if self.timer.isActive():
            self.timer.stop()
            self.tick()

    def stop(self) -> None:
        self.timer.stop()
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
        self.render()
        drawn = time.perf_counter()
        if "mesh" in parts:
            self.last_tick_ms = ((computed - start) * 1e3, (drawn - computed) * 1e3)
            self.timed.emit(*self.last_tick_ms)

    def render(self) -> None:
        """Render now. A never-shown VTK widget has no GL context to draw into; its first paint renders."""
        plotter = self.plotter
        if self._alive() and plotter.isVisible() and not getattr(plotter, "_closed", False):
            plotter.render()
