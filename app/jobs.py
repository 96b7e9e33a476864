"""jobs.py
----
Background work for the window: one job class for every slow step (loading a face, building its
rig, detecting landmarks, building the dense correspondence, building the muscle model).

* ``work(job)`` runs on a worker thread. It may call ``job.progress(fraction, message)`` (fraction
  0..1, or None for a message alone) and should return early when ``job.cancelled()``.
* Results reach the GUI thread through Qt signals: ``done(result)``, ``failed(message)``,
  ``progress(fraction, message)`` — only for a job that is still current.
* A :class:`JobRunner` numbers its jobs (a generation counter). With ``supersede=True`` starting a
  job cancels the ones before it (a newer load wins); :meth:`JobRunner.cancel` cancels all (closing
  the window, an export's Cancel button). A cancelled job's result is dropped, never delivered to a
  window that moved on; a job cancelled before it started never runs its work.
* Who needs to know when a cancelled job has really stopped (an export removes its partial file
  first) passes ``cancelled`` to :meth:`JobRunner.start`: it is called on the GUI thread once the
  worker is done, with None — or with the result when the work ran to its end anyway (the cancel
  came too late: the export's file exists).
* Errors: a ``ValueError`` (the solvers' input errors) or one of the runner's ``user_errors`` (e.g.
  a mesh loader's) is a message for the user; any other exception is "Unexpected error: …" with its
  traceback on stderr. Errors of a cancelled job are dropped silently (cancelling may break its
  work on purpose). Nothing raises into Qt.
"""

from __future__ import annotations

import traceback
from typing import Callable

from PySide6.QtCore import QObject, QRunnable, QThreadPool, Signal

__all__ = ["Job", "JobRunner"]


class _Signals(QObject):
    progress = Signal(int, object, str)  # generation, fraction or None, message
    done = Signal(int, object)           # generation, result
    failed = Signal(int, str)            # generation, message for the user
    stopped = Signal(int, object)        # generation, result or None: the job was cancelled


class Job(QRunnable):
    """One piece of work off the GUI thread (see the module docstring)."""

    def __init__(self, generation: int, work: Callable[["Job"], object], signals: _Signals,
                 is_current: Callable[[int], bool], user_errors: tuple = (ValueError,)):
        super().__init__()
        self.generation, self.work, self.signals = generation, work, signals
        self._is_current = is_current
        self._user_errors = user_errors
        self.setAutoDelete(True)

    def cancelled(self) -> bool:
        """True once a newer job superseded this one or the runner was cancelled."""
        return not self._is_current(self.generation)

    def progress(self, fraction: float | None = None, message: str = "") -> None:
        if not self.cancelled():
            self._emit(self.signals.progress, self.generation, None if fraction is None else float(fraction),
                       str(message))

    def run(self) -> None:  # worker thread
        # Exactly one of done / failed / stopped ends every job (the runner forgets it then).
        if self.cancelled():  # cancelled while it waited for a thread
            self._emit(self.signals.stopped, self.generation, None)
            return
        try:
            result = self.work(self)
        except Exception as exc:  # noqa: BLE001 - every failure becomes a message
            if self.cancelled():   # cancelling may break the work on purpose: no message, no traceback
                self._emit(self.signals.stopped, self.generation, None)
                return
            if isinstance(exc, self._user_errors):   # input errors speak to the user
                self._emit(self.signals.failed, self.generation, str(exc))
                return
            traceback.print_exc()
            self._emit(self.signals.failed, self.generation, f"Unexpected error: {type(exc).__name__}: {exc}")
            return
        self._emit(self.signals.stopped if self.cancelled() else self.signals.done, self.generation, result)

    @staticmethod
    def _emit(signal, *args) -> None:
        try:
            signal.emit(*args)
        except RuntimeError:  # the runner (and its window) went away while the job ran
            pass


class JobRunner(QObject):
    """Starts :class:`Job` s on its own thread pool; delivers the results of current jobs only.

    supersede : a new job cancels the earlier ones (loads); otherwise they run side by side.
    user_errors : exception types whose message is for the user (besides ValueError: a loader's own).
    """

    def __init__(self, parent: QObject | None = None, *, supersede: bool = False, threads: int = 1,
                 user_errors: tuple = ()):
        super().__init__(parent)
        self.supersede = supersede
        self.user_errors = (ValueError, *user_errors)
        self._pool = QThreadPool(self)
        self._pool.setMaxThreadCount(threads)
        # The latest generation and the oldest still wanted, in a list the workers may read (a closed
        # window's wrappers are not safe to touch from another thread).
        self._state = [0, 1]
        self._running: dict[int, tuple] = {}      # generation -> (done, failed, progress, cancelled)
        self._stopping: dict[int, Callable] = {}  # cancelled jobs still working -> their ``cancelled``
        self._signals: dict[int, _Signals] = {}   # every job not ended yet

    @property
    def generation(self) -> int:
        """Number of the latest job started."""
        return self._state[0]

    @property
    def busy(self) -> bool:
        """True while a job that is still wanted runs (cancelled ones winding down do not count)."""
        return bool(self._running)

    def start(self, work: Callable[[Job], object], done: Callable[[object], None],
              failed: Callable[[str], None] | None = None,
              progress: Callable[[float | None, str], None] | None = None,
              cancelled: Callable[[object], None] | None = None) -> int:
        """Run ``work(job)`` in the background; returns the job's generation.

        ``cancelled(result or None)``: see the module docstring (default: a cancelled job ends quietly).
        """
        state = self._state
        if self.supersede:
            self._forget_running()  # jobs not started yet are for an older request: they will not run
            state[1] = state[0] + 1
        state[0] += 1
        generation = state[0]
        signals = _Signals(self)
        self._signals[generation] = signals
        self._running[generation] = (done, failed, progress, cancelled)
        signals.progress.connect(self._on_progress)
        signals.done.connect(self._on_done)
        signals.failed.connect(self._on_failed)
        signals.stopped.connect(self._on_stopped)
        self._pool.start(Job(generation, work, signals, lambda g: g >= state[1], self.user_errors))
        return generation

    def cancel(self) -> None:
        """Cancel every job started so far (their results are dropped; see ``cancelled`` of :meth:`start`)."""
        self._state[1] = self._state[0] + 1
        self._forget_running()

    def wait(self, msecs: int = 5000) -> bool:
        """Wait for running jobs to end (a worker must not outlive the window it reports to)."""
        return self._pool.waitForDone(msecs)

    def is_current(self, generation: int) -> bool:
        return generation >= self._state[1] and generation in self._running

    def _forget_running(self) -> None:
        for generation, entry in self._running.items():
            if entry[3] is not None:
                self._stopping[generation] = entry[3]
        self._running.clear()

    def _ended(self, generation: int):
        """The job's callbacks, or None when it was cancelled (its ``cancelled`` is called instead)."""
        signals = self._signals.pop(generation, None)
        if signals is not None:
            signals.deleteLater()
        entry = self._running.pop(generation, None)
        if entry is not None and generation >= self._state[1]:
            return entry
        return None

    def _on_progress(self, generation: int, fraction, message: str) -> None:
        entry = self._running.get(generation)
        if entry is not None and entry[2] is not None and self.is_current(generation):
            entry[2](fraction, message)

    def _on_done(self, generation: int, result) -> None:
        entry = self._ended(generation)
        if entry is not None:
            entry[0](result)
        else:   # cancelled after the work had ended
            self._on_stopped(generation, result)

    def _on_failed(self, generation: int, message: str) -> None:
        entry = self._ended(generation)
        if entry is not None:
            if entry[1] is not None:
                entry[1](message)
        else:
            self._on_stopped(generation, None)

    def _on_stopped(self, generation: int, result) -> None:
        self._ended(generation)
        callback = self._stopping.pop(generation, None)
        if callback is not None:
            callback(result)
