"""lipsync_dialog.py
----
Tools ▸ Lip-sync from text…: type text, pick the language (English / Português (Brasil)), the start
time (the cursor by default) and whether to add blinks; :func:`core.lipsync.lipsync_tracks` runs on
a worker thread (eSpeak NG takes about a second), then the viseme (+ blink) tracks go on the
timeline as one undoable edit (:meth:`TimelineController.add_lipsync`, which also keeps the speech
clip so export can include the sound and extends the duration when the speech runs past the end).

Phoneme symbols eSpeak produced that have no viseme are listed in the dialog and the status bar
(their time went to the neighbouring visemes). The dialog is non-modal: the user can scrub and
play while it is open. Blink timing is seeded from the text, so the same text gives the same blinks.
"""

from __future__ import annotations

import hashlib
import threading
import traceback

from PySide6.QtCore import QObject, Qt, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDialog,
    QDialogButtonBox,
    QDoubleSpinBox,
    QFormLayout,
    QLabel,
    QPlainTextEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

LANGUAGES = (("English", "en"), ("Português (Brasil)", "pt-br"))
_ESPEAK_LOCK = threading.Lock()  # one synthesis at a time (eSpeak NG keeps global state)


class _Relay(QObject):
    done = Signal(int, object)
    failed = Signal(int, str)


class LipSyncDialog(QDialog):
    """The lip-sync dialog for a :class:`~app.timeline_controller.TimelineController`.

    Signals: ``added(object)`` with the ``LipSyncResult`` once its tracks are on the timeline.
    Attributes for callers/tests: ``text_edit``, ``language_combo``, ``start_spin``, ``blinks_check``,
    ``add_button``, ``status_label``, ``last_result``, ``busy``.
    """

    added = Signal(object)

    def __init__(self, controller, parent: QWidget | None = None):
        super().__init__(parent)
        self.c = controller
        self.setWindowTitle("Lip-sync from text")
        self.setObjectName("lipSyncDialog")
        self.setModal(False)
        self.last_result = None
        self.busy = False
        self._generation = 0
        self._relay = _Relay(self)
        self._relay.done.connect(self._on_done)
        self._relay.failed.connect(self._on_failed)

        self.text_edit = QPlainTextEdit(self)
        self.text_edit.setObjectName("lipSyncText")
        self.text_edit.setPlaceholderText("Type what the face should say, e.g. “Hello, how are you?”")
        self.text_edit.setMinimumSize(420, 110)
        self.language_combo = QComboBox(self)
        self.language_combo.setObjectName("lipSyncLanguage")
        for label, code in LANGUAGES:
            self.language_combo.addItem(label, code)
        self.start_spin = QDoubleSpinBox(self)
        self.start_spin.setObjectName("lipSyncStart")
        self.start_spin.setRange(0.0, 24 * 3600.0)
        self.start_spin.setDecimals(2)
        self.start_spin.setSuffix(" s")
        self.start_spin.setToolTip("Where the speech starts on the timeline (the cursor when the dialog opened)")
        self.blinks_check = QCheckBox("Add natural blinks (eyelid tracks)", self)
        self.blinks_check.setObjectName("lipSyncBlinks")
        self.blinks_check.setChecked(True)
        self.status_label = QLabel(self)
        self.status_label.setObjectName("lipSyncStatus")
        self.status_label.setWordWrap(True)
        self.status_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)

        form = QFormLayout()
        form.addRow("Language", self.language_combo)
        form.addRow("Start at", self.start_spin)
        form.addRow("", self.blinks_check)
        buttons = QDialogButtonBox(self)
        self.add_button = QPushButton("Add to timeline", self)
        self.add_button.setObjectName("lipSyncAdd")
        self.add_button.setDefault(True)
        buttons.addButton(self.add_button, QDialogButtonBox.ButtonRole.ActionRole)
        close = buttons.addButton(QDialogButtonBox.StandardButton.Close)
        close.clicked.connect(self.close)
        self.add_button.clicked.connect(self.generate)

        layout = QVBoxLayout(self)
        layout.addWidget(QLabel("Text", self))
        layout.addWidget(self.text_edit, 1)
        layout.addLayout(form)
        layout.addWidget(self.status_label)
        layout.addWidget(buttons)

    # ------------------------------------------------------------ API
    def set_start_time(self, t: float) -> None:
        self.start_spin.setValue(float(t))

    def set_language(self, code: str) -> None:
        for i in range(self.language_combo.count()):
            if self.language_combo.itemData(i) == code:
                self.language_combo.setCurrentIndex(i)
                return
        raise ValueError(f"unknown lip-sync language {code!r}; choose one of "
                         + ", ".join(c for _, c in LANGUAGES))

    def generate(self) -> bool:
        """Start the synthesis for the current inputs (False with a message if there is nothing to say)."""
        text = self.text_edit.toPlainText().strip()
        if not text:
            self._show("Type some text first.")
            return False
        if self.busy:
            return False
        lang = str(self.language_combo.currentData())
        start = float(self.start_spin.value())
        blinks = self.blinks_check.isChecked()
        seed = int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "little")
        self._generation += 1
        generation = self._generation
        self.busy = True
        self.add_button.setEnabled(False)
        self._show("Speaking the text with eSpeak NG…")
        relay = self._relay

        def work():
            try:
                from core.lipsync import lipsync_tracks

                with _ESPEAK_LOCK:
                    result = lipsync_tracks(text, lang, start_s=start, blinks=blinks, seed=seed)
            except Exception as exc:  # noqa: BLE001 - shown in the dialog
                if not isinstance(exc, ValueError):
                    traceback.print_exc()
                relay.failed.emit(generation, str(exc) or type(exc).__name__)
                return
            relay.done.emit(generation, (result, text, lang))

        threading.Thread(target=work, name="mimica-lipsync", daemon=True).start()
        return True

    # ------------------------------------------------------------ results
    def _on_done(self, generation: int, payload) -> None:
        if generation != self._generation:
            return
        self._idle()
        result, text, lang = payload
        grew = result.end_s > self.c.timeline.duration
        edit = self.c.add_lipsync(result, text, lang)
        if edit is None:
            self._show("The tracks could not be added (see the status bar).")
            return
        self.last_result = result
        n_vis = sum(1 for k in result.tracks if k.startswith("viseme:"))
        n_blink = len(result.tracks) - n_vis
        parts = [f"Added {n_vis} viseme track{'s' if n_vis != 1 else ''}"
                 + (f" and {n_blink} eyelid tracks (blinks)" if n_blink else "")
                 + f" from {result.start_s:.2f} s to {result.end_s:.2f} s."]
        if grew:
            parts.append(f"The timeline was extended to {self.c.timeline.duration:g} s.")
        if result.unmapped:
            parts.append("Phonemes without a viseme (their time went to the neighbours): "
                         + ", ".join(sorted(set(result.unmapped))) + ".")
        message = " ".join(parts)
        self._show(message)
        self.c.message.emit(message)
        self.added.emit(result)

    def _on_failed(self, generation: int, message: str) -> None:
        if generation != self._generation:
            return
        self._idle()
        self._show(f"Lip-sync failed: {message}")
        self.c.message.emit(f"Lip-sync failed: {message}")

    def _idle(self) -> None:
        self.busy = False
        self.add_button.setEnabled(True)

    def _show(self, text: str) -> None:
        self.status_label.setText(text)


__all__ = ["LipSyncDialog", "LANGUAGES"]
