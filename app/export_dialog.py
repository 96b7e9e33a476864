"""export_dialog.py
----
The Qt side of export (:mod:`app.export` does the work):

* :class:`ExportJob` (:mod:`app.export_job`) runs :func:`app.export.export_in_subprocess`
  as a job of the window's shared job class (:mod:`app.jobs`: cancellation, generation
  counter, user-facing errors) and reports through Qt signals on the GUI thread:
  ``progress(done, total)``, ``finished(ExportResult)``, ``failed(message)``,
  ``cancelled()``; :meth:`ExportJob.cancel` stops it within about one frame.
  The frame source ``frame_vertices(t)`` is called on the GUI thread by
  default (``evaluate_in="gui"``), one frame per event-loop pass and at most
  :data:`PREFETCH` frames ahead of the renderer, so it may read the window's
  rig or timeline safely; pass ``evaluate_in="worker"`` for a thread-safe
  pure function (faster when evaluation is expensive).
* :class:`ExportDialog`: format (MP4, GIF, AVI, PNG sequence, still PNG/JPG),
  size presets (1280×720, 1920×1080, 640×480, custom), fps (24/25/30/60 or the
  project's), range (whole or start–end; a time for stills), camera (the
  window's current view or a preset), display mode, quality, sound, and the
  output path with a file chooser. Settings are checked (by
  :func:`app.export.export_frame_times`) before the dialog closes; problems
  appear in the dialog in words.
* :func:`start_export` shows a window-modal progress dialog with Cancel driven
  by an :class:`ExportJob` (the window keeps repainting: nothing runs on the
  GUI thread but the frame source) saying the frame, the speed (frames per
  second over the last few seconds, :class:`FrameRate`) and the time left, a
  message box on failure, and a status-bar message saying where the file went
  and how fast it was made.
* :func:`run_export_dialog` does all of it for the main window's
  File ▸ Export video… / Export still… actions.

Window-modal progress is a choice: the export renders the animation as it is
when the export starts, and a frame source that reads the window's rig must
not see the user's edits halfway through.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import numpy as np
import shiboken6
from PySide6.QtCore import QSettings, Qt
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDialog,
    QDialogButtonBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QMessageBox,
    QProgressDialog,
    QPushButton,
    QRadioButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from app.export import AUDIO_FORMATS, STILL_FORMATS, ExportError, ExportResult, ExportSettings, export_frame_times
from app.export_job import (  # noqa: F401 - re-exported
    ExportJob)
from app.export_job import (  # noqa: F401 - re-exported
    PREFETCH)

__all__ = ["ExportJob", "ExportDialog", "start_export", "run_export_dialog", "PREFETCH", "FrameRate", "progress_text"]

#: (format, label, file-dialog filter) in menu order.
FORMAT_CHOICES = (
    ("mp4", "MP4 video (H.264)", "MP4 video (*.mp4)"),
    ("gif", "GIF animation", "GIF animation (*.gif)"),
    ("avi", "AVI video (Motion JPEG)", "AVI video (*.avi)"),
    ("png-sequence", "PNG image sequence (folder)", ""),
    ("png", "Still image (PNG)", "PNG image (*.png)"),
    ("jpg", "Still image (JPEG)", "JPEG image (*.jpg *.jpeg)"),
)
_SUFFIX = {"mp4": ".mp4", "gif": ".gif", "avi": ".avi", "png": ".png", "jpg": ".jpg"}
SIZE_PRESETS = ((1280, 720), (1920, 1080), (640, 480))
FPS_PRESETS = (24.0, 25.0, 30.0, 60.0)
VIEW_CHOICES = (("current", "Current view"), ("front", "Front"), ("side", "Side"),
                ("three-quarter", "Three-quarter"), ("back", "Back"))
MODE_CHOICES = (("textured", "Textured"), ("shaded", "Shaded"), ("wireframe", "Wireframe"), ("points", "Points"))


# ------------------------------------------------------------------ dialog
class ExportDialog(QDialog):
    """Choose what to export. ``settings()`` gives the :class:`ExportSettings` after ``exec()``.

    Parameters
    ----------
    duration_s : float
        Length of the animation (the whole range is 0..duration_s, end exclusive).
    fps : float
        The animation's frame rate (preselected).
    default_path : str or Path
        Suggested output; its suffix is adapted to the chosen format.
    has_audio : bool
        Whether a sound track exists (enables "Include sound" for MP4/AVI).
    still : bool
        Preselect a still image (File ▸ Export still…).
    current_time_s : float
        Time of the still (and of "current" frames).
    mode : str
        Display mode preselected (the window's).
    camera : dict, optional
        The window's camera (:func:`app.export.camera_state`); adds "Current view".
    content_end_s : float, optional
        Where the animation's content ends (its last key, or the end of its speech): when it ends
        before ``duration_s``, the range 0 – content end is preselected (still editable).
    """

    def __init__(self, parent: QWidget | None = None, *, duration_s: float, fps: float, default_path,
                 has_audio: bool = False, still: bool = False, current_time_s: float = 0.0,
                 mode: str = "textured", camera: dict | None = None, content_end_s: float | None = None):
        super().__init__(parent)
        self.setWindowTitle("Export still image" if still else "Export animation")
        self.duration_s = max(float(duration_s), 0.0)
        self.camera = camera
        self.has_audio = bool(has_audio)
        self._path_by_format: dict[str, str] = {}
        default_path = Path(default_path)

        form = QFormLayout()
        self.format_combo = QComboBox(self)
        for fmt, label, _ in FORMAT_CHOICES:
            self.format_combo.addItem(label, fmt)
        form.addRow("&Format:", self.format_combo)

        self.path_edit = QLineEdit(str(default_path), self)
        self.browse_button = QPushButton("&Browse…", self)
        row = QHBoxLayout()
        row.addWidget(self.path_edit, 1)
        row.addWidget(self.browse_button)
        save_label = QLabel("&Save to:", self)
        save_label.setBuddy(self.path_edit)
        form.addRow(save_label, row)

        self.size_combo = QComboBox(self)
        for w, h in SIZE_PRESETS:
            self.size_combo.addItem(f"{w} × {h}", (w, h))
        self.size_combo.addItem("Custom", None)
        self.width_spin = QSpinBox(self)
        self.height_spin = QSpinBox(self)
        for spin in (self.width_spin, self.height_spin):
            spin.setRange(16, 8192)
            spin.setSuffix(" px")
        self.width_spin.setValue(SIZE_PRESETS[0][0])
        self.height_spin.setValue(SIZE_PRESETS[0][1])
        size_row = QHBoxLayout()
        size_row.addWidget(self.size_combo)
        size_row.addWidget(self.width_spin)
        size_row.addWidget(QLabel("×", self))
        size_row.addWidget(self.height_spin)
        size_label = QLabel("Si&ze:", self)
        size_label.setBuddy(self.size_combo)
        form.addRow(size_label, size_row)

        self.fps_combo = QComboBox(self)
        presets = list(FPS_PRESETS)
        if float(fps) not in presets and 1 <= float(fps) <= 120:
            presets.append(float(fps))
            presets.sort()
        for value in presets:
            self.fps_combo.addItem(f"{value:g} fps", value)
        index = self.fps_combo.findData(float(fps))
        self.fps_combo.setCurrentIndex(index if index >= 0 else self.fps_combo.findData(30.0))
        form.addRow("Frame &rate:", self.fps_combo)

        self.whole_radio = QRadioButton(f"Whole animation (0 – {self.duration_s:.2f} s)", self)
        self.part_radio = QRadioButton("From", self)
        self.start_spin = self._time_spin(0.0)
        self.end_spin = self._time_spin(self.duration_s)
        self.whole_radio.setChecked(True)
        frame = 1.0 / max(float(fps), 1.0)
        if content_end_s is not None and 0.0 <= content_end_s < self.duration_s - frame:
            # The animation ends early: export what there is (the end frame included), not seconds of
            # a still face. The whole timeline stays one click away.
            end = min(self.duration_s, math.ceil((float(content_end_s) + frame) / frame - 1e-9) * frame)
            self.end_spin.setValue(max(end, frame))
            self.part_radio.setChecked(True)
            self.part_radio.setToolTip(f"The animation's last key is at {content_end_s:.2f} s")
        range_box = QVBoxLayout()
        range_box.addWidget(self.whole_radio)
        part_row = QHBoxLayout()
        part_row.addWidget(self.part_radio)
        part_row.addWidget(self.start_spin)
        part_row.addWidget(QLabel("to", self))
        part_row.addWidget(self.end_spin)
        part_row.addStretch(1)
        range_box.addLayout(part_row)
        self.range_widget = QWidget(self)
        self.range_widget.setLayout(range_box)
        range_box.setContentsMargins(0, 0, 0, 0)
        form.addRow("Range:", self.range_widget)
        self.range_label = form.labelForField(self.range_widget)

        self.time_spin = self._time_spin(min(max(float(current_time_s), 0.0), self.duration_s))
        form.addRow("&Time:", self.time_spin)
        self.time_label = form.labelForField(self.time_spin)

        self.view_combo = QComboBox(self)
        for key, label in VIEW_CHOICES:
            if key == "current" and camera is None:
                continue
            self.view_combo.addItem(label, key)
        form.addRow("&Camera:", self.view_combo)
        self.mode_combo = QComboBox(self)
        for key, label in MODE_CHOICES:
            self.mode_combo.addItem(label, key)
        self.mode_combo.setCurrentIndex(max(self.mode_combo.findData(mode), 0))
        form.addRow("&Display:", self.mode_combo)
        self.quality_spin = QSpinBox(self)
        self.quality_spin.setRange(1, 100)
        self.quality_spin.setValue(80)
        self.quality_spin.setToolTip("Higher is sharper and bigger (MP4, AVI and JPEG)")
        form.addRow("&Quality:", self.quality_spin)
        self.audio_check = QCheckBox("Include the sound track", self)
        self.audio_check.setChecked(self.has_audio)
        form.addRow("", self.audio_check)
        self.full_detail_check = QCheckBox("Full detail", self)
        self.full_detail_check.setToolTip(
            "Draw every triangle of the face in every frame. Off (the default), where the face's triangles "
            "are only a few pixels on screen, a decimated face that gives the same picture is drawn: a "
            "faster export on computers without a graphics card.")
        form.addRow("", self.full_detail_check)

        self.summary_label = QLabel(self)
        self.error_label = QLabel(self)
        self.error_label.setWordWrap(True)
        self.error_label.setStyleSheet("color: #d9534f;")
        self.buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel,
                                        self)
        self.buttons.button(QDialogButtonBox.StandardButton.Ok).setText("&Export")
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.summary_label)
        layout.addWidget(self.error_label)
        layout.addWidget(self.buttons)

        initial = "png" if still or self.duration_s <= 0 else _format_of_path(default_path) or "mp4"
        if initial in STILL_FORMATS and not still and self.duration_s > 0:
            initial = "mp4"
        self.format_combo.setCurrentIndex(self.format_combo.findData(initial))
        self._last_format = initial

        self.format_combo.currentIndexChanged.connect(self._on_format_changed)
        self.browse_button.clicked.connect(self.browse)
        self.size_combo.currentIndexChanged.connect(self._on_size_changed)
        self.part_radio.toggled.connect(self._update)
        for widget in (self.start_spin, self.end_spin, self.time_spin):
            widget.valueChanged.connect(self._update)
        for widget in (self.width_spin, self.height_spin):
            widget.valueChanged.connect(self._update)
        self.fps_combo.currentIndexChanged.connect(self._update)
        self.path_edit.textChanged.connect(self._update)
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        self._adapt_path(initial)
        self._on_size_changed()

    def _time_spin(self, value: float) -> QDoubleSpinBox:
        spin = QDoubleSpinBox(self)
        spin.setDecimals(3)
        spin.setRange(0.0, max(self.duration_s, 0.0) if self.duration_s > 0 else 1e6)
        spin.setSingleStep(0.1)
        spin.setSuffix(" s")
        spin.setValue(value)
        return spin

    # ------------------------------------------------------------ state
    @property
    def format(self) -> str:
        return self.format_combo.currentData()

    @property
    def size(self) -> tuple[int, int]:
        return self.width_spin.value(), self.height_spin.value()

    @property
    def fps(self) -> float:
        return float(self.fps_combo.currentData())

    @property
    def include_audio(self) -> bool:
        return self.audio_check.isEnabled() and self.audio_check.isChecked()

    def range_s(self) -> tuple[float, float]:
        """(start, end) seconds of the export (start = the time of a still)."""
        if self.format in STILL_FORMATS:
            return self.time_spin.value(), self.time_spin.value()
        if self.part_radio.isChecked():
            return self.start_spin.value(), self.end_spin.value()
        return 0.0, self.duration_s

    def set_size(self, width: int, height: int) -> None:
        """Select the preset for (width, height), or Custom with those numbers."""
        index = self.size_combo.findData((int(width), int(height)))
        if index < 0:
            index = self.size_combo.count() - 1
        self.size_combo.setCurrentIndex(index)
        self.width_spin.setValue(int(width))
        self.height_spin.setValue(int(height))

    def set_format(self, fmt: str) -> None:
        index = self.format_combo.findData(fmt)
        if index < 0:
            raise ValueError(f"unknown export format {fmt!r}")
        self.format_combo.setCurrentIndex(index)

    def settings(self, *, audio_path=None) -> ExportSettings:
        """The chosen settings; ``audio_path`` is used when the sound track is included."""
        start, end = self.range_s()
        view = self.view_combo.currentData()
        camera = self.camera if view == "current" else None
        return ExportSettings(
            path=Path(self.path_edit.text().strip()).expanduser(), end_s=end, size=self.size, fps=self.fps,
            start_s=start, mode=self.mode_combo.currentData(), view="front" if view == "current" else view,
            camera=camera, audio_path=Path(audio_path) if (audio_path is not None and self.include_audio) else None,
            quality=self.quality_spin.value(), format=self.format, full_detail=self.full_detail_check.isChecked())

    # ------------------------------------------------------------ reactions
    def _on_format_changed(self) -> None:
        self._path_by_format[self._last_format] = self.path_edit.text()
        self._last_format = self.format
        self._adapt_path(self.format)
        self._update()

    def _adapt_path(self, fmt: str) -> None:
        """Give the path the suffix of ``fmt`` (a folder for a PNG sequence), keeping folder and name."""
        remembered = self._path_by_format.get(fmt)
        if remembered:
            self.path_edit.setText(remembered)
            return
        text = self.path_edit.text().strip()
        if not text:
            return
        path = Path(text)
        stem = path.stem if path.suffix else path.name
        if "%" in stem:
            stem = stem.split("%")[0].rstrip("_-") or "mimica"
        if fmt == "png-sequence":
            new = path.parent / stem if path.suffix else path
        else:
            new = path.parent / f"{stem}{_SUFFIX[fmt]}"
        self.path_edit.setText(str(new))

    def _on_size_changed(self) -> None:
        preset = self.size_combo.currentData()
        custom = preset is None
        self.width_spin.setEnabled(custom)
        self.height_spin.setEnabled(custom)
        if preset is not None:
            self.width_spin.setValue(preset[0])
            self.height_spin.setValue(preset[1])
        self._update()

    def _update(self) -> None:
        fmt = self.format
        still = fmt in STILL_FORMATS
        for widget in (self.range_widget, self.range_label):
            if widget is not None:
                widget.setVisible(not still)
        for widget in (self.time_spin, self.time_label):
            if widget is not None:
                widget.setVisible(still)
        self.start_spin.setEnabled(self.part_radio.isChecked())
        self.end_spin.setEnabled(self.part_radio.isChecked())
        self.fps_combo.setEnabled(not still)
        self.audio_check.setEnabled(self.has_audio and fmt in AUDIO_FORMATS)
        self.quality_spin.setEnabled(fmt in ("mp4", "avi", "jpg"))
        start, end = self.range_s()
        if still:
            self.summary_label.setText(f"One image at {start:.3f} s, {self.size[0]} × {self.size[1]} px")
        else:
            n = int(round((end - start) * self.fps))
            self.summary_label.setText(f"{max(n, 0)} frames, {max(end - start, 0):.2f} s at {self.fps:g} fps, "
                                       f"{self.size[0]} × {self.size[1]} px")
        self.error_label.clear()

    def browse(self) -> None:
        """Pick the output with a file (or folder) chooser."""
        fmt = self.format
        current = self.path_edit.text().strip()
        if fmt == "png-sequence":
            folder = QFileDialog.getExistingDirectory(self, "Folder for the PNG images", current)
            if folder:
                self.path_edit.setText(folder)
            return
        label = next(filt for f, _, filt in FORMAT_CHOICES if f == fmt)
        path, _ = QFileDialog.getSaveFileName(self, "Export to", current, label)
        if path:
            if Path(path).suffix.lower() not in (_SUFFIX[fmt], ".jpeg" if fmt == "jpg" else _SUFFIX[fmt]):
                path += _SUFFIX[fmt]
            self.path_edit.setText(path)

    def validate(self) -> str | None:
        """The problem with the current choices (a sentence), or None when they can be exported."""
        if not self.path_edit.text().strip():
            return "Choose where to save the export."
        try:
            export_frame_times(self.settings())
        except ExportError as exc:
            return str(exc)
        return None

    def accept(self) -> None:  # noqa: D401 - Qt override
        problem = self.validate()
        if problem:
            self.error_label.setText(problem)
            return
        super().accept()


def _format_of_path(path: Path) -> str | None:
    return {".mp4": "mp4", ".gif": "gif", ".avi": "avi", ".png": "png", ".jpg": "jpg", ".jpeg": "jpg"}.get(
        Path(path).suffix.lower())


# ------------------------------------------------------------------ running it
class FrameRate:
    """Frames per second of the last few seconds of an export, from its progress counts."""

    WINDOW_S = 4.0

    def __init__(self, clock: Callable[[], float] | None = None):
        import time

        self.clock = clock or time.monotonic
        self.samples: list[tuple[float, int]] = []

    def add(self, done: int) -> float | None:
        """Record ``done`` frames now; the rate (frames/s) once it spans half a second, else None."""
        now = self.clock()
        self.samples.append((now, int(done)))
        while len(self.samples) > 2 and now - self.samples[1][0] >= self.WINDOW_S:
            self.samples.pop(0)
        (t0, d0), (t1, d1) = self.samples[0], self.samples[-1]
        return (d1 - d0) / (t1 - t0) if t1 - t0 >= 0.5 and d1 > d0 else None


def progress_text(done: int, total: int, fps: float | None) -> str:
    """The progress dialog's line: the frame, the speed and the time left."""
    if done >= total:
        return "Finishing the file…"
    if fps is None or fps <= 0:
        return f"Rendering frame {done} of {total}…"
    left = (total - done) / fps
    left_text = f"{left:.0f} s" if left < 90 else f"{left / 60:.0f} min"
    return f"Rendering frame {done} of {total} — {fps:.1f} fps, about {left_text} left…"


def _show_error(parent, title: str, message: str) -> None:
    show = getattr(parent, "show_error", None)
    if callable(show):
        show(title, message)
    else:
        QMessageBox.warning(parent, title, message)


def _show_status(parent, message: str, ms: int = 10000) -> None:
    status_bar = getattr(parent, "statusBar", None)
    if callable(status_bar):
        status_bar().showMessage(message, ms)


def start_export(parent: QWidget | None, face, frame_vertices: Callable[[float], np.ndarray],
                 settings: ExportSettings, *, evaluate_in: str = "gui") -> ExportJob:
    """Start an :class:`ExportJob` with a window-modal progress dialog (Cancel stops it).

    On success the parent's status bar says where the file went; a failure becomes a message box
    (``parent.show_error`` when the parent has one). Returns the running job.
    """
    # The job has no Qt parent (the running-jobs set keeps it alive), so closing the window cannot
    # delete it under its worker thread; the window's destruction cancels it instead.
    job = ExportJob(face, frame_vertices, settings, evaluate_in=evaluate_in)
    if parent is not None:
        parent.destroyed.connect(job.cancel)
    still = settings.format in STILL_FORMATS
    dialog = QProgressDialog("Rendering the still image…" if still else "Rendering the animation…",
                             "Cancel", 0, 0, parent)
    dialog.setWindowTitle("Exporting")
    dialog.setWindowModality(Qt.WindowModality.WindowModal)
    dialog.setMinimumDuration(0)
    dialog.setAutoClose(False)
    dialog.setAutoReset(False)
    job.progress_dialog = dialog

    rate = FrameRate()

    def on_progress(done: int, total: int) -> None:
        if not shiboken6.isValid(dialog):
            return
        if dialog.maximum() != total:
            dialog.setMaximum(total)
        dialog.setValue(done)
        fps = rate.add(done)
        dialog.setLabelText(progress_text(done, total, fps))

    def on_cancel() -> None:
        dialog.setLabelText("Cancelling…")
        job.cancel()

    def close_dialog() -> bool:
        """Close the progress dialog; False when the window is gone (nothing left to tell)."""
        if shiboken6.isValid(dialog):
            dialog.canceled.disconnect(on_cancel)
            dialog.close()
            dialog.deleteLater()
        return parent is None or shiboken6.isValid(parent)

    def on_finished(result: ExportResult) -> None:
        if close_dialog():
            message = result.describe()
            if result.frames > 1:
                message += f" in {result.seconds:.1f} s ({result.frames_per_second:.1f} fps)"
            if result.notes:
                message += " — " + " ".join(result.notes)
            _show_status(parent, message)

    def on_failed(message: str) -> None:
        if close_dialog():
            _show_error(parent, "Export failed", message)

    def on_cancelled() -> None:
        if close_dialog():
            _show_status(parent, "Export cancelled; nothing was written.", 5000)

    job.progress.connect(on_progress)
    job.finished.connect(on_finished)
    job.failed.connect(on_failed)
    job.cancelled.connect(on_cancelled)
    dialog.canceled.connect(on_cancel)
    dialog.show()
    job.start()
    return job


def run_export_dialog(window, face, frame_vertices: Callable[[float], np.ndarray], duration_s: float, fps: float,
                      audio_path=None, *, still: bool = False, current_time_s: float = 0.0,
                      evaluate_in: str = "gui", content_end_s: float | None = None) -> ExportJob | None:
    """Ask what to export (:class:`ExportDialog`), then export it with progress (:func:`start_export`).

    ``window`` is the main window (its plotter gives "Current view" and its display mode is
    preselected; its ``settings`` remember the last export folder). Returns the running job, or
    None when the user cancelled the dialog.
    """
    from app.export import camera_state

    plotter = window.plotter
    camera = None
    if plotter is not None:
        try:
            camera = camera_state(plotter)
        except Exception:  # noqa: BLE001 - a closed viewport: presets only
            camera = None
    settings_store = window.settings
    if not isinstance(settings_store, QSettings):
        settings_store = None
    folder = Path.home()
    if settings_store is not None:
        folder = Path(str(settings_store.value("exportDirectory", settings_store.value("lastDirectory", folder))))
    name = "mimica_still.png" if still else "mimica.mp4"
    mode = window.view_mode
    dialog = ExportDialog(window, duration_s=duration_s, fps=fps, default_path=folder / name,
                          has_audio=audio_path is not None, still=still, current_time_s=current_time_s,
                          mode=mode if isinstance(mode, str) else "textured", camera=camera,
                          content_end_s=content_end_s)
    try:
        if dialog.exec() != QDialog.DialogCode.Accepted:
            return None
        settings = dialog.settings(audio_path=audio_path)
    finally:
        dialog.deleteLater()
    if settings_store is not None:
        settings_store.setValue("exportDirectory", str(settings.path.parent))
    return start_export(window, face, frame_vertices, settings, evaluate_in=evaluate_in)
