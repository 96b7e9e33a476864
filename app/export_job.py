"""A running export in the GUI: frames computed on the GUI thread a few ahead (prefetch), handed to
the off-screen render and encode in a child process (app.export), with progress, cancel and a result
or a message; the window stays responsive throughout."""

from __future__ import annotations

import queue
import threading
import traceback
from typing import Callable

import numpy as np
from PySide6.QtCore import QObject, Qt, QTimer, Signal, Slot

from app.export import (
    ExportCancelled, ExportError, ExportResult, ExportSettings, export_frame_times, export_in_subprocess)


# ------------------------------------------------------------------ job
#: Frames the GUI-thread frame source may run ahead of the renderer.
PREFETCH = 3
#: Jobs still running (a job must outlive the function that started it).
_RUNNING: set = set()


class ExportJob(QObject):
    """One export in the background; create, connect, :meth:`start`.

    Parameters
    ----------
    face : Face
        The face (fixed topology) whose vertices animate.
    frame_vertices : callable
        ``frame_vertices(t) -> (n, 3)`` mm.
    settings : ExportSettings
    evaluate_in : "gui" or "worker"
        Thread that calls ``frame_vertices`` (see the module docstring).
    """

    progress = Signal(int, int)  # frames done, total
    finished = Signal(object)  # ExportResult
    failed = Signal(str)  # user-facing message
    cancelled = Signal()
    _frames_wanted = Signal()

    def __init__(self, face, frame_vertices: Callable[[float], np.ndarray], settings: ExportSettings, *,
                 evaluate_in: str = "gui", parent: QObject | None = None):
        super().__init__(parent)
        if evaluate_in not in ("gui", "worker"):
            raise ValueError(f"evaluate_in must be 'gui' or 'worker', got {evaluate_in!r}")
        self.face = face
        self.frame_vertices = frame_vertices
        self.settings = settings
        self.evaluate_in = evaluate_in
        self.result: ExportResult | None = None
        self.error: str | None = None
        self._cancel = threading.Event()
        self._done = threading.Event()
        self._thread: threading.Thread | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=PREFETCH)
        self._times = np.zeros(0)
        self._next = 0
        self._frames_wanted.connect(self._pump, Qt.ConnectionType.QueuedConnection)

    # ------------------------------------------------------------ control
    def start(self) -> None:
        """Start the export (returns at once). Bad settings are reported through ``failed``."""
        if self._thread is not None:
            raise RuntimeError("an ExportJob runs once; create a new one")
        try:
            self._times = export_frame_times(self.settings)
        except ExportError as exc:
            self.error = str(exc)
            self._done.set()
            QTimer.singleShot(0, lambda: self.failed.emit(self.error))
            return
        _RUNNING.add(self)
        self._thread = threading.Thread(target=self._run, name="mimica-export", daemon=True)
        self._thread.start()
        if self.evaluate_in == "gui":
            self._pump()

    def cancel(self) -> None:
        """Ask the export to stop; ``cancelled`` follows once the partial output is removed."""
        self._cancel.set()

    @property
    def is_running(self) -> bool:
        return self._thread is not None and not self._done.is_set()

    @property
    def is_cancelling(self) -> bool:
        return self._cancel.is_set() and not self._done.is_set()

    # ------------------------------------------------------------ GUI-thread frame source
    @Slot()
    def _pump(self) -> None:
        """Compute the next frame's vertices (GUI thread) while the prefetch queue has room."""
        if self._cancel.is_set() or self._done.is_set() or self._next >= len(self._times):
            return
        if self._queue.full():
            return  # the worker asks again after taking a frame
        t = float(self._times[self._next])
        try:
            item = np.array(self.frame_vertices(t), dtype=np.float64)
        except Exception as exc:  # noqa: BLE001 - becomes the job's failure message
            traceback.print_exc()
            item = ExportError(f"The animation could not be computed at t = {t:.3f} s: {exc}")
        self._queue.put(item)
        self._next += 1
        if not isinstance(item, Exception) and not self._queue.full():
            QTimer.singleShot(0, self._pump)  # one frame per event-loop pass keeps the window live

    def _take(self, t: float) -> np.ndarray:
        """Worker side of the GUI-thread source: the next queued frame (in time order)."""
        while True:
            if self._cancel.is_set():
                raise ExportCancelled()
            try:
                item = self._queue.get(timeout=0.05)
                break
            except queue.Empty:
                continue
        self._frames_wanted.emit()
        if isinstance(item, Exception):
            raise item
        return item

    # ------------------------------------------------------------ worker thread
    def _run(self) -> None:
        source = self._take if self.evaluate_in == "gui" else self.frame_vertices
        try:
            result = export_in_subprocess(self.face, source, self.settings,
                                          progress=lambda done, total: self.progress.emit(done, total),
                                          cancelled=self._cancel.is_set)
        except ExportCancelled:
            self._finish()
            self.cancelled.emit()
        except ExportError as exc:
            self.error = str(exc)
            self._finish()
            self.failed.emit(self.error)
        except Exception as exc:  # noqa: BLE001 - a bug; the user still gets a message
            traceback.print_exc()
            self.error = f"The export failed: {type(exc).__name__}: {exc}"
            self._finish()
            self.failed.emit(self.error)
        else:
            self.result = result
            self._finish()
            self.finished.emit(result)

    def _finish(self) -> None:
        self._done.set()
        _RUNNING.discard(self)
