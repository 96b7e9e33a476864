"""Autosave and crash recovery of projects: the open project is written to its autosave file while
it is modified (on a timer and on close); at start-up an autosave left by a Mimica that is no longer
running (its process is gone) is offered back."""

from __future__ import annotations

import contextlib
import traceback
from pathlib import Path

from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QMessageBox

from core.formats import project as cp
from core.formats.atomic_files import sweep_stale_staging
from core.processes import process_alive


def _owner_pid(path: Path) -> int | None:
    """The pid in ``untitled-<pid>-<n>.mimica.autosave`` (None for other names)."""
    parts = path.name.split("-")
    if len(parts) >= 3 and parts[0] == "untitled" and parts[1].isdigit():
        return int(parts[1])
    return None


class ProjectRecoveryMixin:
    """The autosave and recovery half of :class:`app.project_actions.ProjectActions` (a mixin)."""

    # ------------------------------------------------------------ autosave / recovery
    def autosave_path(self) -> Path:
        return cp.autosave_path(self.path, untitled_id=self.untitled_id, state_dir=self.state_dir)

    def _autosave_project(self) -> tuple[cp.Project, Path] | None:
        """What the autosave holds, captured on the GUI thread (the timeline as an immutable copy, so
        the worker never sees an edit half done); None without a face."""
        if self.document.face is None:
            return None
        target = self.autosave_path()
        target.parent.mkdir(parents=True, exist_ok=True)
        project = self.current_project(target)
        project.timeline = project.timeline.copy()
        return project, target

    def _write_autosave(self, project: cp.Project) -> Path:
        return cp.write_autosave(project, self.path, untitled_id=self.untitled_id, state_dir=self.state_dir)

    def _autosave_failed(self, exc: BaseException) -> None:
        if not isinstance(exc, (cp.ProjectError, OSError)):
            traceback.print_exception(exc)
        self.window.statusBar().showMessage(f"Autosave failed: {exc}", 10000)

    def autosave_now(self) -> Path | None:
        """Write the autosave now, on this thread (whatever the modified state; after any autosave still
        being written in the background); None if there is nothing to save or it failed."""
        self.wait_for_autosave()
        try:
            captured = self._autosave_project()
            if captured is None:
                return None
            written = self._write_autosave(captured[0])
        except Exception as exc:  # noqa: BLE001 - an autosave must never take the session down
            self._autosave_failed(exc)
            return None
        self._autosaved = (self.stack.index(), self._dirty)
        return written

    def autosave_if_needed(self) -> Path | None:
        if not self.is_modified or self._autosaved == (self.stack.index(), self._dirty):
            return None
        return self.autosave_now()

    def autosave_in_background(self) -> bool:
        """The autosave timer's slot: capture the project here, serialise and write it on a worker
        thread (a 45,000-key project is ~0.5 s of JSON), so the window never freezes. True when a write
        was started (not when nothing changed or one is still running)."""
        if not self.is_modified or self._autosaved == (self.stack.index(), self._dirty):
            return False
        worker = getattr(self, "_autosave_thread", None)
        if worker is not None and worker.is_alive():
            return False
        try:
            captured = self._autosave_project()
        except Exception as exc:  # noqa: BLE001
            self._autosave_failed(exc)
            return False
        if captured is None:
            return False
        marker = (self.stack.index(), self._dirty)
        self._autosaved = marker
        project = captured[0]

        def run():
            try:
                self._write_autosave(project)
            except Exception as exc:  # noqa: BLE001 - reported on the GUI thread
                self._autosave_error = exc

        import threading

        self._autosave_error = None
        self._autosave_thread = threading.Thread(target=run, name="mimica-autosave", daemon=False)
        self._autosave_thread.start()
        QTimer.singleShot(0, self, self._poll_autosave)
        return True

    def _poll_autosave(self) -> None:
        worker = getattr(self, "_autosave_thread", None)
        if worker is None:
            return
        if worker.is_alive():
            QTimer.singleShot(50, self, self._poll_autosave)
            return
        self._after_background_autosave()

    def _after_background_autosave(self) -> None:
        error, self._autosave_error = getattr(self, "_autosave_error", None), None
        self._autosave_thread = None
        if error is not None:
            self._autosaved = None
            self._autosave_failed(error)

    def wait_for_autosave(self) -> None:
        """Let an autosave being written in the background finish (before another write, or quitting)."""
        worker = getattr(self, "_autosave_thread", None)
        if worker is not None:
            worker.join()
            self._after_background_autosave()

    def _discard_own_autosave(self, *, untitled_only: bool = False) -> None:
        self.wait_for_autosave()  # a write still running would bring it back
        cp.discard_autosave(None, untitled_id=self.untitled_id, state_dir=self.state_dir)
        if not untitled_only and self.path is not None:
            cp.discard_autosave(self.path)

    def offer_recovery(self, path: Path) -> bool:
        """Ask about ``path``'s autosave when it is newer than the file; True when it was recovered."""
        found = cp.find_autosave(path)
        if found is None:
            return False
        return self._ask_recover(found, original=path)

    def _ask_recover(self, autosave: Path, *, original: Path | None) -> bool:
        import datetime

        when = datetime.datetime.fromtimestamp(autosave.stat().st_mtime).strftime("%Y-%m-%d %H:%M")
        what = f"“{original.name}”" if original is not None else "an untitled project"
        answer = QMessageBox.question(
            self.window, "Recover unsaved work?",
            f"Mimica found unsaved changes to {what}, autosaved {when}.\n\n"
            "Recover them? (Yes opens the autosaved version; Discard deletes it.)",
            QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.Discard, QMessageBox.StandardButton.Yes)
        if answer == QMessageBox.StandardButton.Discard:
            with contextlib.suppress(OSError):
                autosave.unlink()
            return False
        if answer != QMessageBox.StandardButton.Yes:
            return False
        try:
            project = cp.load_project(autosave)
        except cp.ProjectError as exc:
            self._warn("Could not recover the autosave", str(exc))
            return False
        # Nothing is deleted yet: the autosave stays until the recovered project is applied (its face may
        # load in the background for seconds) and written again as this session's autosave.
        self._recovering = (autosave, project)
        self._apply_project(project, original, dirty=True)
        return True

    def _recovery_applied(self, project: cp.Project) -> None:
        """``project`` is on screen: if it is a recovery, write it as this session's autosave, and only
        then remove the autosave it came from (when that is another file)."""
        recovering, self._recovering = getattr(self, "_recovering", None), None
        if recovering is None or recovering[1] is not project:
            self._recovering = recovering
            return
        source = recovering[0]
        written = self.autosave_now()
        if written is None:
            self.window.statusBar().showMessage(
                f"The recovered work could not be autosaved again; '{source}' is kept.", 15000)
            return
        with contextlib.suppress(OSError):
            if Path(written).resolve() != Path(source).resolve():
                Path(source).unlink()  # its content lives on in this session's autosave

    def _recovery_abandoned(self) -> None:
        """The recovered project could not be applied (its face failed to load): keep its autosave."""
        self._recovering = None

    def startup_candidates(self) -> list[Path]:
        """Untitled autosaves left by Mimica processes that are not running any more (newest first)."""
        out = []
        for p in cp.untitled_autosaves(self.state_dir):
            pid = _owner_pid(p)
            if pid is not None and process_alive(pid):
                continue
            out.append(p)
        return out

    def check_startup_recovery(self) -> bool:
        from app.export_sinks import sweep_at_start

        sweep_stale_staging(self.state_dir)   # half-written autosaves of killed runs
        sweep_at_start()                      # what killed exports left (temporary and target folders)
        found = self.startup_candidates()
        if not found:
            return False
        return self._ask_recover(found[0], original=None)

    def check_startup_recovery_when_ready(self) -> None:
        """Offer recovery once the event loop runs and no face is loading (never during a load)."""
        QTimer.singleShot(0, self, self._recovery_when_idle)

    def _recovery_when_idle(self) -> None:
        w = self.window
        if self._closed:
            return
        if w.is_loading:
            def once(_ok):
                with contextlib.suppress(RuntimeError, TypeError):
                    w.load_finished.disconnect(once)
                QTimer.singleShot(0, self, self._recovery_when_idle)

            w.load_finished.connect(once)
            return
        self.check_startup_recovery()
