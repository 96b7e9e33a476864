"""muscle_dock.py
----
The muscle dock (thesis C's interface, issue 4): one slider per muscle *per side* and the jaw
angle, driving a :class:`core.muscles.MuscleLayer` on the window's :class:`core.rig.FaceRig`.

* Rows: the 9 linear muscles as pairs (the name spans two lines, "left" and "right" below each
  other, so the two sides of a muscle sit together and every slider has the full width), then the
  orbicularis oris and the jaw opening. Each row: slider, spin box with units (thesis force units
  ``u``; degrees for the jaw), reset ↺. "Link left/right" moves a muscle's partner with it.
  "left"/"right" are the face's own sides (in the front view its left is on the screen's right).
* House rules of the FAP dock: widgets write through the layer's setters and never keep their
  own copy; every widget follows ``layer.changed`` with its signals blocked (no echo); the dock
  never renders: the layer's ``changed`` reaches ``rig.touch()`` (``layer.attach``) and the
  window redraws once per burst.
* Live quasi-static solve: an edit only sets the force; a 0 ms QTimer then calls
  ``layer.relax(budget_s=RELAX_BUDGET_S)`` once per event-loop pass (the window redraws in
  between) until the layer reports ``converged``. The status line says "settling… residual x %",
  then "equilibrium" (or "at rest" with every force 0). No call blocks the GUI thread for much
  more than the budget. When the window's last redraw took longer than two budgets (software
  OpenGL: about a second for the default face under Xvfb), the budget grows to half that redraw
  time, at most ``MAX_RELAX_BUDGET_S``, so settling is not slaved to the redraw rate.
* Animate: plays the transition from rest to the current forces with the layer's dynamic
  integrator in wall-clock time (QTimer at ~30 fps, each tick ``layer.advance(elapsed)``, an
  elapsed time above ``MAX_FRAME_S`` is cut so a stalled GUI slows the replay instead of jumping)
  for ``animation_s`` (default ``ANIMATION_S``) seconds, then the quasi-static solve finishes the
  pose. Stop ends it early.
* Rest (a choice): animated back — every force and the jaw go to 0 and the same dynamics play
  from the current pose, so the face relaxes visibly. "Reset all" is the instant version
  (``layer.reset()``).
* Presets (thesis C's test expressions), Save / Open of force sets (JSON): a malformed file shows
  its ``ForceFileError`` message in a warning box and leaves the forces alone.
* ``SolverDiverged``: timers stop, the message goes to the status line and the window's status
  bar; the layer has already restored its last good state, which the widgets then show.
* Undo: every edit from this dock (slider, spin box, reset, preset, file, Rest) is one rig event,
  which the window's :class:`app.undo.UndoableRigEdits` records as one step like any parameter
  change; the changes of one control during one gesture (a slider drag) merge into one step.
* The muscles can be drawn in the viewport ("Show muscles", :mod:`app.muscle_view`).

The layer takes seconds to build, so :func:`attach_muscle_dock` builds it on a worker thread
(``QThreadPool``) and re-builds it when the window's face changes.
"""

from __future__ import annotations

import contextlib
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from PySide6.QtCore import QEvent, QObject, QRunnable, QSignalBlocker, Qt, QThreadPool, QTimer, Signal, Slot
from PySide6.QtGui import QKeySequence
from PySide6.QtWidgets import (
    QAbstractSpinBox,
    QCheckBox,
    QComboBox,
    QDockWidget,
    QFileDialog,
    QFrame,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QMessageBox,
    QProgressBar,
    QPushButton,
    QScrollArea,
    QSizePolicy,
    QSlider,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from app.widgets import ScrollFriendlySlider, ScrollFriendlySpinBox

if TYPE_CHECKING:  # pragma: no cover
    from core.muscles import MuscleLayer

#: Wall-clock budget of one quasi-static update (s): well under a frame with the redraw.
RELAX_BUDGET_S = 0.02
#: When the window's redraw is slow (software OpenGL), the budget grows to half the last redraw
#: time, up to this (s): the solve then keeps a third of the time instead of a few percent.
MAX_RELAX_BUDGET_S = 0.1
#: Animation frame interval (ms) and the longest step one frame may integrate (s).
ANIMATION_INTERVAL_MS = 33
MAX_FRAME_S = 0.25
#: How long Animate / Rest play the dynamics (s) before the quasi-static solve takes over.
ANIMATION_S = 1.0
#: Slider steps per unit (force units and degrees): 0.1 resolution.
SLIDER_SCALE = 10
FORCE_SUFFIX = " u"
JAW = ("jaw", None)
FILE_FILTER = "Mimica force sets (*.json);;All files (*)"
BUILDING_MESSAGE = "Building the muscle model…"
NO_FACE_MESSAGE = "No face loaded yet."
NO_RIG_MESSAGE = ("The muscles need the face's MPEG-4 feature points: mark them (landmark picker), "
                  "then the muscle model is built.")


def _side_text(side: str | None) -> str:
    return "" if side is None else side


def _preset_title(name: str) -> str:
    return name.replace("_", " ").capitalize()


def _force_unit_dyn() -> float | None:
    try:
        from core.muscles.model import load_params

        return float(load_params().force_unit)
    except Exception:  # noqa: BLE001 - decorates a tooltip only
        return None


def _face_signature(face) -> tuple:
    """What the muscle model depends on: the same face object with corrected landmarks (Tools ▸
    Rebuild animation) must be built again."""
    import numpy as np

    names = tuple(face.landmark_names)
    try:
        marks = np.asarray(face.landmark_positions(list(names)), float).tobytes() if names else b""
    except Exception:  # noqa: BLE001 - a face whose landmarks cannot be placed: never re-used
        marks = object()
    v = np.asarray(face.vertices)
    return names, marks, v.shape, float(v.sum())


# ------------------------------------------------------------------ one control
class ControlRow(QObject):
    """Slider, spin box and reset button of one control (a muscle side, the orbicularis, the jaw).

    The widgets are laid out by the dock's grid; the value lives in the layer.
    """

    edited = Signal(object, float)  # key, new value (force units or degrees)
    reset_requested = Signal(object)  # key

    def __init__(self, key: tuple, minimum: float, maximum: float, suffix: str, tooltip: str,
                 parent: QWidget, *, side_text: str = ""):
        super().__init__(parent)
        self.key = key
        self.minimum, self.maximum = float(minimum), float(maximum)
        tag = "_".join(str(k) for k in key if k is not None)
        self.side_label = QLabel(side_text, parent)
        self.side_label.setObjectName(f"muscleSide_{tag}")
        self.side_label.setStyleSheet("QLabel { color: #6b7280; }")
        self.slider = ScrollFriendlySlider(Qt.Orientation.Horizontal, parent)
        self.slider.setObjectName(f"muscleSlider_{tag}")
        self.slider.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.slider.setRange(round(self.minimum * SLIDER_SCALE), round(self.maximum * SLIDER_SCALE))
        self.slider.setSingleStep(SLIDER_SCALE // 2)
        self.slider.setPageStep(SLIDER_SCALE * 5)
        self.slider.setTracking(True)
        self.slider.setMinimumWidth(100)
        self.slider.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)
        self.spin = ScrollFriendlySpinBox(parent)
        self.spin.setObjectName(f"muscleSpin_{tag}")
        self.spin.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.spin.setKeyboardTracking(False)
        self.spin.setAccelerated(True)
        self.spin.setDecimals(1)
        self.spin.setRange(self.minimum, self.maximum)
        self.spin.setSingleStep(0.5)
        self.spin.setSuffix(suffix)
        self.spin.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        self.spin.setButtonSymbols(QAbstractSpinBox.ButtonSymbols.UpDownArrows)
        self.reset_button = QToolButton(parent)
        self.reset_button.setObjectName(f"muscleReset_{tag}")
        self.reset_button.setText("↺")
        self.reset_button.setAutoRaise(True)
        self.reset_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)
        self.reset_button.setToolTip("Reset to 0")
        for w in (self.side_label, self.slider, self.spin):
            w.setToolTip(tooltip)
        self._value = 0.0
        self.slider.valueChanged.connect(lambda v: self.edited.emit(self.key, v / SLIDER_SCALE))
        self.spin.valueChanged.connect(self._spin_changed)
        self.reset_button.clicked.connect(lambda: self.reset_requested.emit(self.key))

    @property
    def value(self) -> float:
        """The value this row shows."""
        return self._value

    def show_value(self, value: float) -> None:
        """Show ``value`` (from the layer) without emitting anything."""
        self._value = float(value)
        with QSignalBlocker(self.slider), QSignalBlocker(self.spin):
            tick = round(self._value * SLIDER_SCALE)
            if self.slider.value() != tick:
                self.slider.setValue(tick)
            if abs(self.spin.value() - self._value) > 1e-9:
                self.spin.setValue(self._value)

    def _spin_changed(self, value: float) -> None:
        self.edited.emit(self.key, min(max(float(value), self.minimum), self.maximum))

    def widgets(self) -> list[QWidget]:
        return [self.side_label, self.slider, self.spin, self.reset_button]


# ------------------------------------------------------------------ building off the GUI thread
class _BuildSignals(QObject):
    built = Signal(int, object)  # generation, MuscleLayer
    failed = Signal(int, str)  # generation, message


class _BuildTask(QRunnable):
    """``MuscleLayer(face, level=level)`` on a worker thread; the result comes back by signal."""

    def __init__(self, generation: int, face, level: int, signals: _BuildSignals,
                 wanted: Callable[[int], bool], template_dense=None):
        super().__init__()
        self.generation, self.face, self.level, self.signals, self.wanted = generation, face, level, signals, wanted
        self.template_dense = template_dense
        self.setAutoDelete(True)

    def run(self) -> None:  # worker thread
        gen = self.generation
        if not self.wanted(gen):
            return
        try:
            from core.muscles import MuscleLayer

            layer = MuscleLayer(self.face, level=self.level, template_dense=self.template_dense)
        except ValueError as exc:  # the face does not fit the model: a message, not a bug
            self._emit(self.signals.failed, gen, f"The muscle model cannot be built for this face: {exc}")
            return
        except Exception as exc:  # noqa: BLE001 - reported in the dock, traceback on stderr
            traceback.print_exc()
            self._emit(self.signals.failed, gen, f"Could not build the muscle model: {type(exc).__name__}: {exc}")
            return
        if self.wanted(gen):
            self._emit(self.signals.built, gen, layer)

    @staticmethod
    def _emit(signal, *args) -> None:
        try:
            signal.emit(*args)
        except RuntimeError:  # the dock went away while we were building
            pass


# ------------------------------------------------------------------ the dock
class MuscleDock(QDockWidget):
    """The muscle dock (see the module docstring).

    Parameters
    ----------
    window : MainWindow, optional
        Gives the face, rig, plotter, status bar and undo stack; without one the dock drives
        whatever layer :meth:`set_layer` receives (no build, no viewport drawing, no undo).
    level : int
        Template level of the muscle model (passed to ``MuscleLayer``).

    Signals
    -------
    layer_changed(object)
        A new layer (or None) is driven.
    settled()
        The quasi-static solve reached equilibrium.
    """

    layer_changed = Signal(object)
    settled = Signal()

    def __init__(self, window=None, parent: QWidget | None = None, *, level: int = 3):
        super().__init__("Muscles", parent if parent is not None else window)
        self.setObjectName("muscleDock")
        self.setAllowedAreas(Qt.DockWidgetArea.LeftDockWidgetArea | Qt.DockWidgetArea.RightDockWidgetArea)
        self.window_ = window
        self.level = int(level)
        self.layer: "MuscleLayer | None" = None
        self.rig = None
        self.view = None  # MuscleView, while a layer and a plotter exist
        self.rows: dict[tuple, ControlRow] = {}
        self.name_labels: dict[str, QLabel] = {}
        self._syncing = False
        self._view_dirty = True
        self._layer_face = None  # the face self.layer was built for (kept for re-use)
        self._layer_signature: tuple | None = None  # its landmarks and vertices when built
        self._generation = 0
        self._latest = [0]  # read by worker threads
        self._pool = QThreadPool(self)
        self._pool.setMaxThreadCount(1)
        self._build_signals = _BuildSignals()
        self._build_signals.built.connect(self._on_built)
        self._build_signals.failed.connect(self._on_build_failed)
        self._animating = False
        self._anim_elapsed = 0.0
        self._anim_last = 0.0
        #: Seconds of dynamics Animate / Rest play.
        self.animation_s = ANIMATION_S
        #: Timing of the live loop: seconds of the last relax call and the edit -> settled time.
        self.last_relax: object | None = None
        self.last_settle_s: float | None = None
        self._edit_started: float | None = None
        self.relax_ticks = 0

        self._relax_timer = QTimer(self)
        self._relax_timer.setInterval(0)
        self._relax_timer.timeout.connect(self._relax_tick)
        self._anim_timer = QTimer(self)
        self._anim_timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._anim_timer.setInterval(ANIMATION_INTERVAL_MS)
        self._anim_timer.timeout.connect(self._anim_tick)

        self._build_ui()
        self.set_layer(None, NO_FACE_MESSAGE)

    # ============================================================ UI
    def _build_ui(self) -> None:
        root = QWidget(self)
        root.setObjectName("muscleDockContents")
        outer = QVBoxLayout(root)
        outer.setContentsMargins(6, 6, 6, 6)
        outer.setSpacing(6)

        self.message_label = QLabel(root)
        self.message_label.setObjectName("muscleMessage")
        self.message_label.setWordWrap(True)
        self.message_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.message_label.setStyleSheet("QLabel { color: #e0a030; }")
        outer.addWidget(self.message_label)
        self.busy_bar = QProgressBar(root)
        self.busy_bar.setRange(0, 0)  # indeterminate: the build reports no progress
        self.busy_bar.setTextVisible(False)
        self.busy_bar.setMaximumHeight(8)
        self.busy_bar.hide()
        outer.addWidget(self.busy_bar)

        outer.addWidget(self._build_presets(root))
        outer.addWidget(self._build_controls(root))
        outer.addWidget(self._build_playback(root))

        self.scroll = QScrollArea(root)
        self.scroll.setObjectName("muscleScroll")
        self.scroll.setWidgetResizable(True)
        self.scroll.setFrameShape(QFrame.Shape.NoFrame)
        self.scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.scroll.setWidget(self._build_rows())
        outer.addWidget(self.scroll, 1)
        outer.addStretch(0)
        self._outer = outer
        self.setWidget(root)

    def _build_presets(self, parent: QWidget) -> QGroupBox:
        from core.muscles import preset_names

        box = QGroupBox("Force sets", parent)
        grid = QGridLayout(box)
        grid.setContentsMargins(6, 4, 6, 4)
        grid.setHorizontalSpacing(6)
        grid.setVerticalSpacing(4)
        self.preset_combo = QComboBox(box)
        self.preset_combo.setObjectName("musclePresetCombo")
        for name in preset_names():
            self.preset_combo.addItem(_preset_title(name), name)
        self.preset_combo.setToolTip("Thesis C's test expressions (§5.2–5.6)")
        self.apply_button = QPushButton("Apply", box)
        self.apply_button.setObjectName("musclePresetApply")
        self.apply_button.setToolTip("Set the forces (and jaw) of the chosen expression")
        self.apply_button.clicked.connect(lambda: self.apply_preset(self.preset_combo.currentData()))
        self.save_button = QPushButton("Save…", box)
        self.save_button.setObjectName("muscleSave")
        self.save_button.setToolTip("Save the current forces and jaw angle as a JSON force set")
        self.save_button.clicked.connect(self.save_dialog)
        self.open_button = QPushButton("Open…", box)
        self.open_button.setObjectName("muscleOpen")
        self.open_button.setToolTip("Load a JSON force set")
        self.open_button.clicked.connect(self.open_dialog)
        grid.addWidget(QLabel("Expression", box), 0, 0)
        grid.addWidget(self.preset_combo, 0, 1)
        grid.addWidget(self.apply_button, 0, 2)
        grid.addWidget(self.save_button, 0, 3)
        grid.addWidget(self.open_button, 0, 4)
        grid.setColumnStretch(1, 1)
        return box

    def _build_controls(self, parent: QWidget) -> QWidget:
        w = QWidget(parent)
        row = QHBoxLayout(w)
        row.setContentsMargins(0, 0, 0, 0)
        row.setSpacing(10)
        self.link_check = QCheckBox("Link left/right", w)
        self.link_check.setObjectName("muscleLink")
        self.link_check.setToolTip("Moving one side of a muscle moves the other side to the same force")
        self.show_check = QCheckBox("Show muscles", w)
        self.show_check.setObjectName("muscleShow")
        self.show_check.setToolTip("Draw the muscles on the face, grey at rest to red at full force")
        self.show_check.toggled.connect(self.set_muscles_visible)
        self.reset_all_button = QPushButton("Reset all", w)
        self.reset_all_button.setObjectName("muscleResetAll")
        self.reset_all_button.setToolTip("Every force and the jaw to 0, the face at rest at once")
        self.reset_all_button.clicked.connect(self.reset_all)
        row.addWidget(self.link_check)
        row.addWidget(self.show_check)
        row.addStretch(1)
        row.addWidget(self.reset_all_button)
        return w

    def _build_playback(self, parent: QWidget) -> QWidget:
        w = QWidget(parent)
        row = QHBoxLayout(w)
        row.setContentsMargins(0, 0, 0, 0)
        row.setSpacing(6)
        self.animate_button = QPushButton("▶ Animate", w)
        self.animate_button.setObjectName("muscleAnimate")
        self.animate_button.setToolTip("Play the transition from rest to the current forces in real time "
                                       "(thesis C's Execute)")
        self.animate_button.clicked.connect(self.animate)
        self.stop_button = QPushButton("■ Stop", w)
        self.stop_button.setObjectName("muscleStop")
        self.stop_button.setToolTip("Stop the animation where it is")
        self.stop_button.clicked.connect(self.stop)
        self.rest_button = QPushButton("Rest", w)
        self.rest_button.setObjectName("muscleRest")
        self.rest_button.setToolTip("Every force and the jaw to 0, relaxing back in real time "
                                    "(thesis C's Initialise; Reset all does it at once)")
        self.rest_button.clicked.connect(self.rest)
        self.status_label = QLabel(w)
        self.status_label.setObjectName("muscleStatus")
        self.status_label.setStyleSheet("QLabel { color: #6b7280; }")
        self.status_label.setToolTip("State of the tissue simulation")
        self.status_label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
        row.addWidget(self.animate_button)
        row.addWidget(self.stop_button)
        row.addWidget(self.rest_button)
        row.addWidget(self.status_label, 1)
        return w

    def _build_rows(self) -> QWidget:
        from core.muscles import muscle_specs

        try:
            from core.muscles.muscles import jaw_range

            jaw_lo, jaw_hi = jaw_range()
        except Exception:  # noqa: BLE001 - the contract does not export it; thesis-like default
            jaw_lo, jaw_hi = 0.0, 25.0
        unit_dyn = _force_unit_dyn()
        unit_note = (f"Thesis force units: 1 u = {unit_dyn:g} dyn at the muscle's mobile end (per reference node)"
                     if unit_dyn else "Thesis force units")
        body = QWidget()
        body.setObjectName("muscleRows")
        grid = QGridLayout(body)
        grid.setContentsMargins(0, 0, 4, 0)
        grid.setHorizontalSpacing(6)
        grid.setVerticalSpacing(1)
        r = 0
        for spec in muscle_specs():
            tip = (f"<b>{spec.label}</b><br>{spec.description}<br>Range {spec.minimum:g} to {spec.maximum:g} u"
                   f"<br><i>{unit_note}</i>")
            name = QLabel(spec.label, body)
            name.setObjectName(f"muscleName_{spec.name}")
            name.setWordWrap(True)
            name.setToolTip(tip)
            name.setSizePolicy(QSizePolicy.Policy.Preferred, QSizePolicy.Policy.Preferred)
            self.name_labels[spec.name] = name
            sides = ("left", "right") if spec.paired else (None,)
            grid.addWidget(name, r, 0, len(sides), 1, Qt.AlignmentFlag.AlignVCenter)
            for side in sides:
                side_tip = tip
                if side is not None:
                    side_tip += ("<br>Sides are the face's own: its left is on the right of the screen "
                                 "in the front view.")
                row = ControlRow((spec.name, side), spec.minimum, spec.maximum, FORCE_SUFFIX, side_tip, body,
                                 side_text=_side_text(side))
                self._add_row(grid, r, row)
                r += 1
            if spec.paired:
                line = QFrame(body)
                line.setFrameShape(QFrame.Shape.HLine)
                line.setStyleSheet("QFrame { color: #3a3c40; }")
                grid.addWidget(line, r, 0, 1, 5)
                r += 1
        jaw_tip = ("<b>Jaw opening</b><br>Rotates the lower lip and chin about an axis behind the ears "
                   f"(thesis C §3.4).<br>Range {jaw_lo:g}° to {jaw_hi:g}°")
        name = QLabel("Jaw opening", body)
        name.setObjectName("muscleName_jaw")
        name.setToolTip(jaw_tip)
        self.name_labels["jaw"] = name
        grid.addWidget(name, r, 0)
        self._add_row(grid, r, ControlRow(JAW, jaw_lo, jaw_hi, "°", jaw_tip, body))
        r += 1
        grid.setRowStretch(r, 1)
        grid.setColumnStretch(2, 1)
        # One width for the name column (long names wrap onto the pair's two lines) and the spins.
        metrics = name.fontMetrics()
        grid.setColumnMinimumWidth(0, metrics.horizontalAdvance("Levator labii sup. ") + 4)
        for label in self.name_labels.values():
            label.setMaximumWidth(metrics.horizontalAdvance("Levator labii sup. alaeque") + 4)
        spin_w = max(row.spin.sizeHint().width() for row in self.rows.values())
        for row in self.rows.values():
            row.spin.setFixedWidth(spin_w)
        return body

    def _add_row(self, grid: QGridLayout, r: int, row: ControlRow) -> None:
        for c, w in enumerate(row.widgets(), start=1):
            grid.addWidget(w, r, c)
        row.edited.connect(self._row_edited)
        row.reset_requested.connect(self.reset_control)
        self.rows[row.key] = row

    def _set_controls_enabled(self, enabled: bool) -> None:
        for w in (self.preset_combo, self.apply_button, self.save_button, self.open_button, self.link_check,
                  self.reset_all_button, self.animate_button, self.rest_button, self.show_check):
            w.setEnabled(enabled)
        self.stop_button.setEnabled(enabled and self._animating)
        self.scroll.setEnabled(enabled)

    # ============================================================ messages
    def show_message(self, message: str) -> None:
        """Show ``message`` above the controls (empty hides it)."""
        self.message_label.setText(message)
        self.message_label.setVisible(bool(message))

    def set_status(self, text: str) -> None:
        self.status_label.setText(text)

    @property
    def status(self) -> str:
        return self.status_label.text()

    def _status_bar(self, text: str, ms: int = 8000) -> None:
        window = self.window_
        if window is not None:
            window.statusBar().showMessage(text, ms)

    # ============================================================ layer
    def set_layer(self, layer: "MuscleLayer | None", message: str = "", *, rig=None) -> None:
        """Drive ``layer`` (attached to ``rig`` when given); None disables the dock, ``message`` says why."""
        self.stop(relax=False)
        self._relax_timer.stop()
        if self.layer is not None:
            try:
                self.layer.changed.disconnect(self._on_layer_changed)
            except (ValueError, RuntimeError, TypeError):
                pass
        self._detach_from_rig()
        self.layer = layer
        if self.view is not None:
            self.view.remove()
            self.view = None
        if layer is not None:
            if rig is not None:
                layer.attach(rig)
                self.rig = rig
            layer.changed.connect(self._on_layer_changed)
            self._make_view()
        enabled = layer is not None
        self._set_controls_enabled(enabled)
        self.show_message(message)
        self.busy_bar.setVisible(message == BUILDING_MESSAGE)
        self.set_status("")
        if layer is not None:
            self._sync_from_layer()
            self._update_status(converged=bool(getattr(layer, "converged", True)))
            # No render here: attach() touched the rig, so the window redraws on its own.
        self.layer_changed.emit(layer)

    def _detach_from_rig(self) -> None:
        rig = self.rig
        self.rig = None
        if rig is not None:
            try:
                rig.remove_layer("muscles")
            except Exception:  # noqa: BLE001 - the rig may already be gone
                pass

    def _make_view(self) -> None:
        plotter = getattr(self.window_, "plotter", None)
        layer = self.layer
        triangles = getattr(getattr(layer, "model", None), "triangles", None)
        if plotter is None or layer is None or triangles is None:
            return
        from app.muscle_view import MuscleView

        self.view = MuscleView(plotter, triangles)
        self._view_dirty = True
        if self.show_check.isChecked():
            self._update_view()
            self.view.set_visible(True)

    # ============================================================ building for a window face
    def build_for_window(self) -> None:
        """Follow the window's current face and rig: re-use, build (in the background) or disable."""
        window = self.window_
        if window is None:
            return
        face, rig = getattr(window, "face", None), getattr(window, "rig", None)
        self._generation += 1
        self._latest[0] = self._generation
        self._pool.clear()  # builds still queued are for an older face
        if face is None:
            self._release_layer()
            self.set_layer(None, NO_FACE_MESSAGE)
            return
        if rig is None:
            self._release_layer()
            reason = getattr(window, "rig_message", "") or NO_RIG_MESSAGE
            self.set_layer(None, f"Muscles are not available for this face.\n\n{reason}")
            return
        signature = _face_signature(face)
        if self.layer is not None and self._layer_face is face and self._layer_signature == signature:
            layer = self.layer
            self.set_layer(None, "")
            layer.reset()
            self.set_layer(layer, "", rig=rig)
            return
        self._release_layer()
        self.set_layer(None, BUILDING_MESSAGE)
        self._layer_face, self._layer_signature = face, signature
        latest = self._latest
        self._pool.start(_BuildTask(self._generation, face, self.level, self._build_signals,
                                    wanted=lambda g: g == latest[0], template_dense=self._shared_template(rig)))

    def _shared_template(self, rig):
        """The rig's densified template when it is the one the layer needs: the layer then skips
        densifying (seconds) and adopts the FAP deformer's face binding (no 3 s bind on the first
        redraw)."""
        dense = getattr(getattr(rig, "deformer", None), "dense", None)
        if dense is None:
            return None
        try:
            from core.fap.template import load_template

            return dense if self.level == len(load_template().steps) else None
        except Exception:  # noqa: BLE001 - an optimisation only
            return None

    def _release_layer(self) -> None:
        """Forget the layer (a different face, or none, is coming)."""
        if self.layer is not None:
            self.set_layer(None, "")
        self._layer_face = None

    @Slot(int, object)
    def _on_built(self, generation: int, layer) -> None:
        if generation != self._generation:
            return
        rig = getattr(self.window_, "rig", None)
        if rig is None:  # cannot happen for the latest generation; be safe
            self.build_for_window()
            return
        self.set_layer(layer, "", rig=rig)
        self._status_bar("Muscle model ready", 4000)

    @Slot(int, str)
    def _on_build_failed(self, generation: int, message: str) -> None:
        if generation != self._generation:
            return
        self._layer_face = None
        self.set_layer(None, message)
        self._status_bar(message.splitlines()[0])

    @property
    def is_building(self) -> bool:
        return self.layer is None and self.message_label.text() == BUILDING_MESSAGE

    def shutdown(self) -> None:
        """Stop timers and ignore running builds (the window is closing)."""
        self._generation += 1
        self._latest[0] = self._generation
        self._pool.clear()
        self.stop(relax=False)
        self._relax_timer.stop()
        if self.view is not None:
            self.view.remove()
            self.view = None
        if self.layer is not None:
            try:
                self.layer.changed.disconnect(self._on_layer_changed)
            except (ValueError, RuntimeError, TypeError):
                pass
        self.rig = None

    # ============================================================ layer -> widgets
    def _on_layer_changed(self, *_args) -> None:
        if self.layer is None:
            return
        self._sync_from_layer()
        self._view_dirty = True
        if self.view is not None and self.view.visible:
            self._update_view()
        if self._animating or self._relax_timer.isActive():
            return
        if self.layer.converged:  # e.g. reset(): already an equilibrium
            self._update_status(converged=True)
        else:  # changed from code (a script, undo) as well as from the rows: settle it
            self._start_relax()

    def _sync_from_layer(self) -> None:
        layer = self.layer
        if layer is None:
            return
        self._syncing = True
        try:
            forces = layer.forces()
            for key, row in self.rows.items():
                value = float(layer.jaw_deg) if key == JAW else float(forces.get(key, 0.0))
                if row.value != value:
                    row.show_value(value)
        finally:
            self._syncing = False

    def _update_view(self) -> None:
        if self.view is None or self.layer is None:
            return
        try:
            from app.muscle_view import draw_muscles

            draw_muscles(self.view, self.layer)
        except Exception:  # noqa: BLE001 - a drawing problem must not stop the simulation
            traceback.print_exc()
            return
        self._view_dirty = False

    def set_muscles_visible(self, visible: bool) -> None:
        """Show or hide the muscles in the viewport (the "Show muscles" box)."""
        with QSignalBlocker(self.show_check):
            self.show_check.setChecked(bool(visible))
        if self.view is None:
            return
        if visible and self._view_dirty:
            self._update_view()
        self.view.set_visible(bool(visible))
        self._render()

    def _render(self) -> None:
        window = self.window_
        plotter = getattr(window, "plotter", None)
        if plotter is None or getattr(plotter, "_closed", False) or not plotter.isVisible():
            return
        alive = getattr(window, "_viewport_alive", None)
        if callable(alive) and not alive():
            return
        plotter.render()

    # ============================================================ widgets -> layer
    def state(self) -> tuple:
        """(forces in ``control_keys()`` order, jaw degrees): what an undo step restores."""
        from core.muscles import control_keys

        layer = self.layer
        if layer is None:
            return ()
        forces = layer.forces()
        return tuple(float(forces.get(k, 0.0)) for k in control_keys()), float(layer.jaw_deg)

    def _guarded(self, call) -> bool:
        """Run a layer call; bad values and a diverged solver become messages. Returns success."""
        from core.muscles import SolverDiverged

        try:
            call()
        except SolverDiverged as exc:
            self._diverged(exc)
            return False
        except ValueError as exc:
            self.show_message(str(exc))
            self._sync_from_layer()
            self._resync_rows()
            return False
        if self.message_label.isVisible() and self.layer is not None:
            self.show_message("")
        return True

    def _resync_rows(self) -> None:
        layer = self.layer
        if layer is None:
            return
        forces = layer.forces()
        for key, row in self.rows.items():
            row.show_value(float(layer.jaw_deg) if key == JAW else float(forces.get(key, 0.0)))

    def _edit(self, text: str, call, merge_key=None) -> bool:
        """An edit from this dock: apply, record one undo step, settle."""
        if self.layer is None:
            return False
        self.stop(relax=False)
        self._edit_started = time.perf_counter()
        # One rig event per edit (forces and jaw together): the window's rig recorder makes it one
        # undo step, merged with the rest of a slider drag.
        with self.rig.batch() if self.rig is not None else contextlib.nullcontext():
            ok = self._guarded(call)
        if ok:
            if not self.layer.converged:
                self._start_relax()
            elif not self._relax_timer.isActive():
                self._edit_started = None
                self._update_status(converged=True)
        return ok

    def _row_edited(self, key: tuple, value: float) -> None:
        layer = self.layer
        if layer is None or self._syncing:
            return
        if key == JAW:
            self._edit("jaw opening", lambda: layer.set_jaw(value), merge_key=JAW)
            return
        name, side = key
        label = self.name_labels[name].text()
        if side is not None and self.link_check.isChecked():
            other = (name, "right" if side == "left" else "left")
            self._edit(f"{label} (both sides)", lambda: layer.set_forces({key: value, other: value}),
                       merge_key=(name, "both"))
        else:
            what = f"{label} {side}" if side else label
            self._edit(what, lambda: layer.set_force(name, side, value), merge_key=key)

    def set_control(self, key: tuple, value: float) -> None:
        """Set one control as if its row was edited (link, undo and settling included)."""
        self._row_edited(key, float(value))

    def reset_control(self, key: tuple) -> None:
        """The row's ↺: that control to 0 (and its partner when linked)."""
        row = self.rows.get(key)
        if row is not None:
            self._row_edited(key, max(row.minimum, 0.0))

    def reset_all(self) -> None:
        """Every force and the jaw to 0, the tissue at rest at once (``layer.reset()``)."""
        layer = self.layer
        if layer is not None:
            self._edit("reset all muscles", layer.reset)

    def apply_preset(self, name: str | None) -> bool:
        """Apply one of ``core.muscles.preset_names()`` (one undo step)."""
        from core.muscles import preset

        layer = self.layer
        if layer is None or not name:
            return False
        try:
            force_set = preset(name)
        except (KeyError, ValueError) as exc:
            QMessageBox.warning(self, "Unknown expression", str(exc))
            return False
        index = self.preset_combo.findData(name)
        if index >= 0:
            with QSignalBlocker(self.preset_combo):
                self.preset_combo.setCurrentIndex(index)
        ok = self._edit(f"muscle preset {_preset_title(name).lower()}", lambda: layer.apply(force_set))
        if ok:
            self._status_bar(f"Applied the {_preset_title(name).lower()} forces", 4000)
        return ok

    def rest(self) -> None:
        """Forces and jaw to 0, relaxing back with the dynamics (animated; see the module docstring)."""
        from core.muscles import control_keys

        layer = self.layer
        if layer is None:
            return
        zero = {k: 0.0 for k in control_keys()}
        state = self.state()
        if not any(state[0]) and state[1] == 0.0 and layer.converged and not self._animating:
            return  # already at rest: nothing to play
        if self._edit("rest", lambda: (layer.set_forces(zero), layer.set_jaw(0.0))):
            self._relax_timer.stop()
            self._play(from_rest=False)

    # ============================================================ files
    def _last_dir(self) -> str:
        settings = getattr(self.window_, "settings", None)
        if settings is None:
            return str(Path.home())
        return str(settings.value("muscles/lastDirectory", settings.value("lastDirectory", str(Path.home()))))

    def _remember_dir(self, path: str) -> None:
        settings = getattr(self.window_, "settings", None)
        if settings is not None:
            settings.setValue("muscles/lastDirectory", str(Path(path).parent))

    def save_dialog(self) -> None:
        if self.layer is None:
            return
        default = str(Path(self._last_dir()) / "forces.json")
        path, _ = QFileDialog.getSaveFileName(self, "Save force set", default, FILE_FILTER)
        if path:
            if not Path(path).suffix:
                path += ".json"
            self._remember_dir(path)
            self.save_force_file(path)

    def open_dialog(self) -> None:
        if self.layer is None:
            return
        path, _ = QFileDialog.getOpenFileName(self, "Open force set", self._last_dir(), FILE_FILTER)
        if path:
            self._remember_dir(path)
            self.open_force_file(path)

    def save_force_file(self, path) -> bool:
        """Write the current forces and jaw to ``path`` (JSON); errors become a warning box."""
        from core.muscles import ForceSet, save_force_set

        layer = self.layer
        if layer is None:
            return False
        force_set = ForceSet(dict(layer.forces()), jaw_deg=float(layer.jaw_deg), name=Path(path).stem)
        try:
            save_force_set(path, force_set)
        except (OSError, ValueError) as exc:
            QMessageBox.warning(self, f"Could not save {Path(path).name}", str(exc))
            return False
        self._status_bar(f"Saved the force set {path}", 5000)
        return True

    def open_force_file(self, path) -> bool:
        """Load a force set from ``path`` and apply it; a bad file leaves the forces untouched."""
        from core.muscles import ForceFileError, load_force_set

        layer = self.layer
        if layer is None:
            return False
        try:
            force_set = load_force_set(path)
        except (ForceFileError, OSError) as exc:
            QMessageBox.warning(self, f"Could not open {Path(path).name}", str(exc))
            return False
        ok = self._edit(f"open force set {Path(path).name}", lambda: layer.apply(force_set))
        if ok:
            self._status_bar(f"Loaded the force set {Path(path).name}", 5000)
        return ok

    # ============================================================ quasi-static solve
    @property
    def settling(self) -> bool:
        """True while the relax timer runs."""
        return self._relax_timer.isActive()

    @property
    def animating(self) -> bool:
        return self._animating

    def relax_budget(self) -> float:
        """Seconds for the next ``layer.relax`` call (see the module docstring)."""
        last = getattr(self.window_, "last_tick_ms", None)
        if not last:
            return RELAX_BUDGET_S
        redraw_s = sum(last) / 1000.0
        return min(max(RELAX_BUDGET_S, 0.5 * redraw_s), MAX_RELAX_BUDGET_S)

    def _start_relax(self) -> None:
        if self.layer is None or self._animating:
            return
        if not self._relax_timer.isActive():
            self.relax_ticks = 0
            self._relax_timer.start()

    @Slot()
    def _relax_tick(self) -> None:
        from core.muscles import SolverDiverged

        layer = self.layer
        if layer is None or self._animating:
            self._relax_timer.stop()
            return
        try:
            report = layer.relax(budget_s=self.relax_budget())
        except SolverDiverged as exc:
            self._diverged(exc)
            return
        self.last_relax = report
        self.relax_ticks += 1
        if report.converged:
            self._relax_timer.stop()
            if self._edit_started is not None:
                self.last_settle_s = time.perf_counter() - self._edit_started
                self._edit_started = None
            self._update_status(converged=True)
            self.settled.emit()
        else:
            self._update_status(converged=False, residual=report.residual)

    def _update_status(self, *, converged: bool, residual: float | None = None) -> None:
        layer = self.layer
        if layer is None:
            self.set_status("")
            return
        if not converged:
            text = "settling…" if residual is None else f"settling… residual {100.0 * residual:.1f} %"
        else:
            state = self.state()
            at_rest = bool(state) and not any(state[0]) and state[1] == 0.0
            text = "at rest" if at_rest else "equilibrium"
        self.set_status(text)

    def _diverged(self, exc: Exception) -> None:
        self._relax_timer.stop()
        self._anim_timer.stop()
        self._animating = False
        self.stop_button.setEnabled(False)
        self._edit_started = None
        message = str(exc) or "The simulation diverged; the last good state was kept."
        self.set_status(f"⚠ {message.splitlines()[0]}")
        self.status_label.setToolTip(message)
        self._status_bar(f"Muscle simulation stopped: {message.splitlines()[0]}", 15000)
        self._sync_from_layer()
        self._view_dirty = True
        if self.view is not None and self.view.visible:
            self._update_view()

    # ============================================================ dynamics playback
    def animate(self) -> None:
        """Play the transition from rest to the current forces in wall-clock time."""
        self._play(from_rest=True)

    def _play(self, *, from_rest: bool) -> None:
        from core.muscles import SolverDiverged

        layer = self.layer
        if layer is None:
            return
        self._relax_timer.stop()
        self._animating = True  # before the layer emits: no relax may start meanwhile
        try:
            if from_rest:
                # start_animation plays from the *current* pose: put the tissue at rest first,
                # keeping the controls (reset() zeroes them, apply() puts them back).
                force_set = layer.force_set()
                layer.reset()
                layer.apply(force_set)
            layer.start_animation()
        except SolverDiverged as exc:
            self._diverged(exc)
            return
        self._anim_elapsed = 0.0
        self._anim_last = time.perf_counter()
        self.stop_button.setEnabled(True)
        self.set_status("animating… 0.00 s")
        self._anim_timer.start()

    @Slot()
    def _anim_tick(self) -> None:
        from core.muscles import SolverDiverged

        layer = self.layer
        if layer is None or not self._animating:
            self._anim_timer.stop()
            return
        now = time.perf_counter()
        dt = min(now - self._anim_last, MAX_FRAME_S)
        self._anim_last = now
        if dt <= 0.0:
            return
        try:
            layer.advance(dt)
        except SolverDiverged as exc:
            self._diverged(exc)
            return
        self._anim_elapsed += dt
        self.set_status(f"animating… {self._anim_elapsed:.2f} s")
        if self._anim_elapsed >= self.animation_s:
            self.stop()

    def stop(self, *, relax: bool = True) -> None:
        """End the animation (the quasi-static solve then finishes the pose unless ``relax`` is False)."""
        was = self._animating
        self._anim_timer.stop()
        self._animating = False
        self.stop_button.setEnabled(False)
        if was and relax and self.layer is not None:
            self._start_relax()


# ------------------------------------------------------------------ window integration
class _CloseWatcher(QObject):
    """Stops the dock's timers and builds when the window closes."""

    def __init__(self, dock: MuscleDock, window):
        super().__init__(dock)
        self.dock = dock
        window.installEventFilter(self)

    def eventFilter(self, watched, event) -> bool:  # noqa: N802 - Qt override
        if event.type() == QEvent.Type.Close:
            self.dock.shutdown()
        return False


def attach_muscle_dock(window, *, level: int = 3) -> MuscleDock:
    """Add the muscle dock to a :class:`app.main_window.MainWindow`.

    * the dock goes to the right dock area, tabified with the FAP dock ("Muscles" tab);
    * View ▸ Muscles (Ctrl+Shift+M) shows/hides it;
    * the muscle layer of ``window.face`` is built on a worker thread ("Building the muscle
      model…" in the dock meanwhile), attached to ``window.rig`` and re-built on
      ``window.face_changed``; without a rig the dock is disabled and says why.

    Returns the dock (also stored as ``window.muscle_dock``).
    """
    dock = MuscleDock(window, level=level)
    window.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, dock)
    fap_dock = getattr(window, "fap_dock", None)
    if fap_dock is not None:
        window.tabifyDockWidget(fap_dock, dock)
        fap_dock.raise_()
    toggle = dock.toggleViewAction()
    toggle.setText("&Muscles")
    toggle.setStatusTip("Show or hide the muscle dock (thesis C forces, jaw, presets)")
    toggle.setShortcut(QKeySequence("Ctrl+Shift+M"))
    toggle.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
    window.addAction(toggle)
    view_menu = getattr(window, "view_menu", None)
    if view_menu is not None:
        view_menu.addAction(toggle)
    window.muscle_dock = dock
    window.muscle_dock_action = toggle
    dock._close_watcher = _CloseWatcher(dock, window)  # noqa: SLF001
    window.face_changed.connect(lambda _face: dock.build_for_window())
    if getattr(window, "face", None) is not None:
        dock.build_for_window()
    return dock


__all__ = ["MuscleDock", "ControlRow", "attach_muscle_dock", "RELAX_BUDGET_S", "ANIMATION_S", "JAW"]
