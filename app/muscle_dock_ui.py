"""The muscle dock's widgets: presets and force-set files, link and show toggles, Animate / Rest /
Stop, and the grid of per-side rows (the shared :class:`app.parameter_row.ParameterRow`; a muscle's
two sides together, then the orbicularis oris and the jaw), built once; and the force-set file
dialogs (the files themselves are read and written by :class:`app.muscle_simulation.MuscleSimulation`)."""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt
from PySide6.QtGui import QStandardItemModel
from PySide6.QtWidgets import (
    QCheckBox, QComboBox, QFileDialog, QFrame, QGridLayout, QGroupBox, QHBoxLayout, QLabel, QMessageBox,
    QProgressBar, QPushButton, QScrollArea, QSizePolicy, QVBoxLayout, QWidget)

from app.parameter_row import ParameterRow, align_rows, parameter_tooltip
from app.muscle_simulation import preset_title
from core import parameters as P

#: The jaw's parameter key (the muscle forces are "muscle:<name>:<side>").
JAW = "jaw"
FILE_FILTER = "Mimica force sets (*.json);;All files (*)"
#: The preset box's first entry, shown when the forces match no preset (at rest / edited).
NO_PRESET_AT_REST = "None"
NO_PRESET_EDITED = "Custom"


def _force_unit_dyn() -> float | None:
    try:
        from core.layers.muscles.specs import force_unit_dyn

        return force_unit_dyn()
    except Exception:  # noqa: BLE001 - decorates a tooltip only
        return None


class MuscleDockLayout:
    """The widget-building and file-dialog half of :class:`app.muscle_dock.MuscleDock` (a mixin)."""

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
        from core.layers.muscles import preset_names

        box = QGroupBox("Force sets", parent)
        grid = QGridLayout(box)
        grid.setContentsMargins(6, 4, 6, 4)
        grid.setHorizontalSpacing(6)
        grid.setVerticalSpacing(4)
        self.preset_combo = QComboBox(box)
        self.preset_combo.setObjectName("musclePresetCombo")
        # First entry: "None" / "Custom", shown while the forces match no preset; not a choice.
        self.preset_combo.addItem(NO_PRESET_AT_REST, None)
        model = self.preset_combo.model()
        if isinstance(model, QStandardItemModel):
            model.item(0).setEnabled(False)
        for name in preset_names():
            self.preset_combo.addItem(preset_title(name), name)
        self.preset_combo.setToolTip("Thesis C's test expressions (§5.2–5.6): choosing one applies it, "
                                     "as the FAP dock's presets do. The box shows the preset the forces "
                                     "match, or Custom.")
        # One rule for presets in both docks: choosing one applies it (an undo step).
        self.preset_combo.activated.connect(lambda index: self.apply_preset(self.preset_combo.itemData(index)))
        self.apply_button = QPushButton("Apply again", box)
        self.apply_button.setObjectName("musclePresetApply")
        self.apply_button.setToolTip("Set the forces (and jaw) of the chosen expression again (after edits)")
        self.apply_button.clicked.connect(lambda: self.apply_preset(self.preset_target()))
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
        self.reset_all_button.clicked.connect(self.simulation.reset_all)
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
        self.animate_button.clicked.connect(self.simulation.animate)
        self.stop_button = QPushButton("■ Stop", w)
        self.stop_button.setObjectName("muscleStop")
        self.stop_button.setToolTip("Stop the animation where it is")
        self.stop_button.clicked.connect(lambda: self.simulation.stop())
        self.rest_button = QPushButton("Rest", w)
        self.rest_button.setObjectName("muscleRest")
        self.rest_button.setToolTip("Every force and the jaw to 0, relaxing back in real time "
                                    "(thesis C's Initialise; Reset all does it at once)")
        self.rest_button.clicked.connect(self.simulation.rest)
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
        from core.layers.muscles import muscle_specs

        unit_dyn = _force_unit_dyn()
        unit_note = (f"<i>Thesis force units: 1 u = {unit_dyn:g} dyn at the muscle's mobile end (per reference "
                     "node)</i>" if unit_dyn else "<i>Thesis force units</i>")
        sides_note = "Sides are the face's own: its left is on the right of the screen in the front view."
        body = QWidget()
        body.setObjectName("muscleRows")
        grid = QGridLayout(body)
        grid.setContentsMargins(0, 0, 4, 0)
        grid.setHorizontalSpacing(6)
        grid.setVerticalSpacing(1)
        r = 0
        for spec in muscle_specs():
            tip = (f"<b>{spec.label}</b><br>{spec.description}<br>Range {spec.minimum:g} to {spec.maximum:g} u"
                   f"<br>{unit_note}")
            name = QLabel(spec.label, body)
            name.setObjectName(f"muscleName_{spec.name}")
            name.setWordWrap(True)
            name.setToolTip(tip)
            name.setSizePolicy(QSizePolicy.Policy.Preferred, QSizePolicy.Policy.Preferred)
            self.name_labels[spec.name] = name
            sides = ("left", "right") if spec.paired else (None,)
            grid.addWidget(name, r, 0, len(sides), 1, Qt.AlignmentFlag.AlignVCenter)
            for side in sides:
                key = str(P.ParamKey("muscle", spec.name, side))
                notes = [unit_note] + ([sides_note] if side else [])
                self._add_row(grid, r, key, side or "", notes)
                r += 1
            if spec.paired:
                line = QFrame(body)
                line.setFrameShape(QFrame.Shape.HLine)
                line.setStyleSheet("QFrame { color: #3a3c40; }")
                grid.addWidget(line, r, 0, 1, 2)
                r += 1
        jaw = P.describe(JAW)
        name = QLabel("Jaw opening", body)
        name.setObjectName("muscleName_jaw")
        name.setToolTip(parameter_tooltip(jaw))
        self.name_labels["jaw"] = name
        grid.addWidget(name, r, 0)
        self._add_row(grid, r, JAW, "", [])
        r += 1
        grid.setRowStretch(r, 1)
        grid.setColumnStretch(1, 1)
        # One width for the name column (long names wrap onto the pair's two lines), the side labels
        # and the spin boxes, so every slider has the same length.
        metrics = name.fontMetrics()
        grid.setColumnMinimumWidth(0, metrics.horizontalAdvance("Levator labii sup. ") + 4)
        for label in self.name_labels.values():
            label.setMaximumWidth(metrics.horizontalAdvance("Levator labii sup. alaeque") + 4)
        side_width = max(row.label.sizeHint().width() for row in self.rows.values())
        align_rows(self.rows.values(), label_width=side_width)
        return body

    def _add_row(self, grid: QGridLayout, r: int, key: str, side_text: str, notes: list[str]) -> None:
        tag = key.replace(":", "_")
        row = ParameterRow(key, grid.parentWidget(), text=side_text, name=tag,
                           tooltip=parameter_tooltip(P.describe(key), notes))
        row.label.setObjectName(f"muscleSide_{tag}")
        row.label.setStyleSheet("QLabel { color: #6b7280; }")
        grid.addWidget(row, r, 1)
        row.edited.connect(self._row_edited)
        row.reset_requested.connect(self.reset_control)
        self.rows[row.key] = row

    def _set_controls_enabled(self, enabled: bool) -> None:
        for w in (self.preset_combo, self.apply_button, self.save_button, self.open_button, self.link_check,
                  self.reset_all_button, self.animate_button, self.rest_button, self.show_check):
            w.setEnabled(enabled)
        self.stop_button.setEnabled(enabled and self.simulation.animating)
        self.scroll.setEnabled(enabled)

    # ============================================================ files
    def _last_dir(self) -> str:
        settings = (self.window_.settings if self.window_ is not None else None)
        if settings is None:
            return str(Path.home())
        return str(settings.value("muscles/lastDirectory", settings.value("lastDirectory", str(Path.home()))))

    def _remember_dir(self, path: str) -> None:
        settings = (self.window_.settings if self.window_ is not None else None)
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
        try:
            return self.simulation.save_force_file(path)
        except (OSError, ValueError) as exc:
            QMessageBox.warning(self, f"Could not save {Path(path).name}", str(exc))
            return False

    def open_force_file(self, path) -> bool:
        """Load a force set from ``path`` and apply it; a bad file is a warning box and changes nothing."""
        from core.layers.muscles import ForceFileError

        try:
            return self.simulation.open_force_file(path)
        except (ForceFileError, OSError) as exc:
            QMessageBox.warning(self, f"Could not open {Path(path).name}", str(exc))
            return False
