"""A running export in the GUI: frames computed on the GUI thread a few ahead (prefetch), handed to
the off-screen render and encode in a child process (app.export), with progress, cancel and a result
or a message; the window stays responsive throughout.

The worker side runs as one :class:`app.jobs.Job` (the window's shared job class: cancellation,
generation counter, user-facing errors): an :class:`ExportJob` owns a one-thread
:class:`app.jobs.JobRunner`, :meth:`ExportJob.cancel` cancels its job, and the runner says when
the cancelled worker has stopped (after the child removed its partial output)."""

from __future__ import annotations

import queue
import traceback
from typing import Callable

import numpy as np
from PySide6.QtCore import QObject, Qt, QTimer, Signal, Slot

from app.export import (
    ExportCancelled, ExportError, ExportResult, ExportSettings, export_frame_times, export_in_subprocess)
from app.jobs import JobRunner


# ------------------------------------------------------------------ job
#: Frames the GUI-thread frame source may run ahead of the renderer.
PREFETCH = 3
#: Jobs still running (a job must outlive the function that started it).
_RUNNING: set = set()
#: Jobs that just ended, kept for one more event-loop pass: their runner's slot is still on the stack,
#: and the runner is the job's child (it must not be deleted inside its own slot).
_ENDING: set = set()


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
        Thread that calls ``frame_vertices`` (see :mod:`app.export_dialog`).

    Signals: ``progress(frames done, total)``, then one of ``finished(ExportResult)``,
    ``failed(message for the user)`` or ``cancelled()``.
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
        self.generation: int | None = None   # the runner's number for this export's job
        self._runner = JobRunner(self)
        self._started = self._done = self._cancel_requested = False
        self._queue: queue.Queue = queue.Queue(maxsize=PREFETCH)
        self._times = np.zeros(0)
        self._next = 0
        self._frames_wanted.connect(self._pump, Qt.ConnectionType.QueuedConnection)

    # ------------------------------------------------------------ control
    def start(self) -> None:
        """Start the export (returns at once). Bad settings are reported through ``failed``."""
        if self._started:
            raise RuntimeError("an ExportJob runs once; create a new one")
        self._started = True
        try:
            self._times = export_frame_times(self.settings)
        except ExportError as exc:
            self.error = str(exc)
            self._done = True
            QTimer.singleShot(0, lambda: self.failed.emit(self.error))
            return
        _RUNNING.add(self)
        self.generation = self._runner.start(self._work, self._on_done, self._on_failed, self._on_progress,
                                             cancelled=self._on_stopped)
        if self.evaluate_in == "gui":
            self._pump()

    def cancel(self) -> None:
        """Ask the export to stop; ``cancelled`` follows once the partial output is removed."""
        if self._started and not self._done:
            self._cancel_requested = True
            self._runner.cancel()

    @property
    def total_frames(self) -> int:
        return len(self._times)

    @property
    def is_running(self) -> bool:
        return self._started and not self._done

    @property
    def is_cancelling(self) -> bool:
        return self._cancel_requested and not self._done

    # ------------------------------------------------------------ GUI-thread frame source
    @Slot()
    def _pump(self) -> None:
        """Compute the next frame's vertices (GUI thread) while the prefetch queue has room."""
        if self._cancel_requested or self._done or self._next >= len(self._times):
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

    def _take(self, job) -> np.ndarray:
        """Worker side of the GUI-thread source: the next queued frame (in time order)."""
        while True:
            if job.cancelled():
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

    # ------------------------------------------------------------ worker thread (the job's work)
    def _work(self, job) -> ExportResult:
        source = (lambda _t: self._take(job)) if self.evaluate_in == "gui" else self.frame_vertices

        def progress(done: int, total: int) -> None:
            # The job's progress is a fraction: the total is the plan's frame count, known here too.
            job.progress(done / total if total else 1.0, f"{done} of {total}")

        try:
            return export_in_subprocess(self.face, source, self.settings, progress=progress,
                                        cancelled=job.cancelled)
        except ExportError:
            raise   # a message for the user (the job class reports it)
        except ExportCancelled:
            raise
        except Exception as exc:  # noqa: BLE001 - a bug; the user still gets a sentence, the log the traceback
            traceback.print_exc()
            raise ExportError(f"The export failed: {type(exc).__name__}: {exc}") from exc

    # ------------------------------------------------------------ results (GUI thread)
    def _on_progress(self, fraction, _message: str) -> None:
        total = self.total_frames
        self.progress.emit(int(round((fraction or 0.0) * total)), total)

    def _finish(self) -> None:
        self._done = True
        _RUNNING.discard(self)
        _ENDING.add(self)
        QTimer.singleShot(0, lambda: _ENDING.discard(self))

    def _on_done(self, result: ExportResult) -> None:
        self.result = result
        self._finish()
        self.finished.emit(result)

    def _on_failed(self, message: str) -> None:
        self.error = message
        self._finish()
        self.failed.emit(message)

    def _on_stopped(self, result: ExportResult | None) -> None:
        if result is not None:   # cancelled as the file was being committed: it is there
            self._on_done(result)
            return
        self._finish()
        self.cancelled.emit()
