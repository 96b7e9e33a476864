"""Autosave and crash recovery of projects: the open project is written to its autosave file while
it is modified (on a timer and on close); at start-up an autosave left by a Mimica that is no longer
running (its process is gone) is offered back."""

from __future__ import annotations

import contextlib
import traceback
import os
from pathlib import Path

from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QMessageBox

from core.formats import project as cp


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return False
    return True


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

    def autosave_now(self) -> Path | None:
        """Write the autosave now (whatever the modified state); None if there is nothing to save."""
        if self.document.face is None:
            return None
        try:
            target = self.autosave_path()
            target.parent.mkdir(parents=True, exist_ok=True)
            written = cp.write_autosave(self.current_project(target), self.path, untitled_id=self.untitled_id,
                                        state_dir=self.state_dir)
        except Exception as exc:  # noqa: BLE001 - an autosave must never take the session down
            if not isinstance(exc, (cp.ProjectError, OSError)):
                traceback.print_exc()
            status = self.window.statusBar
            if status is not None:
                self.window.statusBar().showMessage(f"Autosave failed: {exc}", 10000)
            return None
        self._autosaved = (self.stack.index(), self._dirty)
        return written

    def autosave_if_needed(self) -> Path | None:
        if not self.is_modified or self._autosaved == (self.stack.index(), self._dirty):
            return None
        return self.autosave_now()

    def _discard_own_autosave(self, *, untitled_only: bool = False) -> None:
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
        if original is None:
            with contextlib.suppress(OSError):
                autosave.unlink()  # its content lives on in this session's autosave
        self._apply_project(project, original, dirty=True)
        return True

    def startup_candidates(self) -> list[Path]:
        """Untitled autosaves left by Mimica processes that are not running any more (newest first)."""
        out = []
        for p in cp.untitled_autosaves(self.state_dir):
            pid = _owner_pid(p)
            if pid is not None and _pid_alive(pid):
                continue
            out.append(p)
        return out

    def check_startup_recovery(self) -> bool:
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
        if getattr(w, "is_loading", False):
            def once(_ok):
                with contextlib.suppress(RuntimeError, TypeError):
                    w.load_finished.disconnect(once)
                QTimer.singleShot(0, self, self._recovery_when_idle)

            w.load_finished.connect(once)
            return
        self.check_startup_recovery()
