"""error_hook.py
----
Unexpected exceptions in a running window: the traceback goes to stderr, a short message to a
non-blocking dialog (one at a time), whatever thread raised it.
"""

from __future__ import annotations

import sys
import threading
import traceback

from PySide6.QtCore import QObject, Qt, Signal, Slot
from PySide6.QtWidgets import QApplication, QMessageBox, QWidget

APP_NAME = "Mimica"


class _ExceptionRelay(QObject):
    """Carries exception reports to the GUI thread (excepthook may run on any thread)."""

    report = Signal(str, str)  # short message, traceback text


class ExceptionDialogHook:
    """``sys.excepthook`` replacement: traceback to stderr, short message in a dialog."""

    def __init__(self, parent: QWidget | None = None):
        self.parent = parent
        self.previous = sys.excepthook
        self.previous_thread_hook = threading.excepthook
        self.last_dialog: QMessageBox | None = None
        self.reports: list[str] = []
        self._relay = _ExceptionRelay()
        self._relay.report.connect(self._show, Qt.ConnectionType.QueuedConnection)

    def __call__(self, etype, value, tb) -> None:
        text = "".join(traceback.format_exception(etype, value, tb))
        sys.stderr.write(text)
        if issubclass(etype, KeyboardInterrupt):
            app = QApplication.instance()
            if app is not None:
                app.quit()
            return
        message = f"{etype.__name__}: {value}" if str(value) else etype.__name__
        if threading.current_thread() is threading.main_thread():
            self._show(message, text)
        else:
            self._relay.report.emit(message, text)

    @Slot(str, str)
    def _show(self, message: str, details: str) -> None:
        self.reports.append(message)
        if QApplication.instance() is None:
            return
        if self.last_dialog is not None and self.last_dialog.isVisible():
            return  # one dialog at a time: an error in a paint loop must not spawn hundreds
        box = QMessageBox(QMessageBox.Icon.Critical, f"{APP_NAME} — unexpected error",
                          f"Something went wrong:\n\n{message}", QMessageBox.StandardButton.Ok,
                          self.parent)
        box.setInformativeText("The details were written to the terminal. "
                               "Mimica keeps running; saving your work is a good idea.")
        box.setDetailedText(details)
        box.open()  # window-modal but non-blocking: no nested event loop inside the hook
        self.last_dialog = box

    def thread_hook(self, args) -> None:
        """``threading.excepthook`` adapter (Python threads report here, not to sys.excepthook)."""
        if args.exc_type is SystemExit:
            return
        self(args.exc_type, args.exc_value if args.exc_value is not None else args.exc_type(),
             args.exc_traceback)

    def uninstall(self) -> None:
        if sys.excepthook is self:
            sys.excepthook = self.previous
        if threading.excepthook == self.thread_hook:
            threading.excepthook = self.previous_thread_hook


def install_excepthook(parent: QWidget | None = None) -> ExceptionDialogHook:
    """Install (and return) an :class:`ExceptionDialogHook` as ``sys.excepthook``
    (and ``threading.excepthook``)."""
    hook = ExceptionDialogHook(parent)
    sys.excepthook = hook
    threading.excepthook = hook.thread_hook
    return hook


__all__ = ["APP_NAME", "ExceptionDialogHook", "install_excepthook"]
