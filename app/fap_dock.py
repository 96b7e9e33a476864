"""fap_dock.py
----
The FAP dock: sliders for the MPEG-4 facial animation parameters of a
:class:`core.rig.FaceRig`, expression and viseme presets, and the overlay
toggles of the viewport (feature points, influence of the hovered FAP,
displacement heat map).

House rules:

* widgets write through the rig's setters (``set_fap``/``set_faps``,
  ``set_expression``, ``set_viseme``, ``reset_faps``) and never keep their
  own copy of the values;
* every widget follows ``rig.changed``: when anything changes the rig (these
  sliders, a preset, a reset, later a timeline or a .fap player) all widgets
  are set to the rig's values with their signals blocked, so nothing is
  written back;
* the dock never redraws the viewport: the main window marks itself dirty on
  ``rig.changed`` and redraws once per event-loop pass. The dock only tells
  the window which overlay it wants (:meth:`FapDock.overlay`,
  ``overlay_changed``).

Units: translation FAPs are shown in their FAP units (MNS, MW, ENS, ES,
IRISD; one unit is 1/1024 of a distance measured on the neutral face, the
tooltip says how many mm that is on this face). Rotation FAPs (gaze, head;
unit AU = 1e-5 rad) are shown in degrees in the spin box while the slider
runs over AU.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from PySide6.QtCore import QSignalBlocker, Qt, Signal
from PySide6.QtWidgets import (
    QCheckBox, QComboBox, QDockWidget, QFrame, QGridLayout, QGroupBox, QLabel, QPushButton, QScrollArea,
    QSlider, QSpinBox, QVBoxLayout, QWidget)

from app.document import NO_RIG_MESSAGE

from app.fap_rows import (  # noqa: F401 - re-exported
    FapGroup, _feature_point_descriptions, fap_number, fap_row, fap_tooltip, row_label)
from app.parameter_row import ParameterRow, align_rows
from core import parameters as P
from core.layers.fap import tables
from core.layers.fap.parameters import readable_name  # noqa: F401 - re-exported

if TYPE_CHECKING:  # pragma: no cover
    from core.rig import FaceRig



# ------------------------------------------------------------------ the dock
class FapDock(QDockWidget):
    """The FAP dock of the document's rig (an :class:`app.document.Document`, followed on its
    ``face_changed`` and ``rig_changed``), or of the ``rig`` given to ``set_rig`` without one.

    Signals
    -------
    feature_points_toggled(bool)
        The "Feature points" box was clicked (the main window shows its landmarks).
    overlay_changed()
        What :meth:`overlay` returns changed (a toggle, or the hovered/focused FAP row).
    """

    feature_points_toggled = Signal(bool)
    overlay_changed = Signal()

    def __init__(self, document=None, parent: QWidget | None = None, *, rig: "FaceRig | None" = None,
                 message: str = ""):
        super().__init__("FAPs", parent)
        self.setObjectName("fapDock")
        self.setAllowedAreas(Qt.DockWidgetArea.LeftDockWidgetArea | Qt.DockWidgetArea.RightDockWidgetArea)
        self.rig: "FaceRig | None" = None
        self.rows: dict[str, ParameterRow] = {}  # by canonical key, "fap:3"
        self.groups: dict[str, FapGroup] = {}
        self._fp_names = _feature_point_descriptions()
        self._hovered: int | None = None
        self._focused: int | None = None
        self._last_overlay: tuple = (None, None)
        self._syncing = False

        root = QWidget(self)
        root.setObjectName("fapDockContents")
        outer = QVBoxLayout(root)
        outer.setContentsMargins(6, 6, 6, 6)
        outer.setSpacing(6)

        self.message_label = QLabel(root)
        self.message_label.setObjectName("fapMessage")
        self.message_label.setWordWrap(True)
        self.message_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.message_label.setStyleSheet("QLabel { color: #e0a030; }")
        self.message_label.hide()
        outer.addWidget(self.message_label)

        outer.addWidget(self._build_presets(root))
        outer.addWidget(self._build_controls(root))

        self.scroll = QScrollArea(root)
        self.scroll.setObjectName("fapScroll")
        self.scroll.setWidgetResizable(True)
        self.scroll.setFrameShape(QFrame.Shape.NoFrame)
        self.scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self._groups_widget = QWidget()
        self._groups_layout = QVBoxLayout(self._groups_widget)
        self._groups_layout.setContentsMargins(0, 0, 4, 0)
        self._groups_layout.setSpacing(6)
        self._groups_layout.addStretch(1)
        self.scroll.setWidget(self._groups_widget)
        outer.addWidget(self.scroll, 1)
        # Takes the free space instead of the (hidden) scroll area when there is no rig,
        # so the presets and toggles stay compact at the top.
        outer.addStretch(0)
        self._outer = outer

        self.setWidget(root)
        self.set_rig(rig, message)
        self.document = document
        if document is not None:   # follow the document's face and its rig (also one built later)
            document.face_changed.connect(lambda _face: self._follow_document())
            document.rig_changed.connect(lambda _rig: self._follow_document())

    def _follow_document(self) -> None:
        self.set_rig(self.document.rig, self.document.rig_message)

    # ----------------------------------------------------------- building
    def _build_presets(self, parent: QWidget) -> QGroupBox:
        box = QGroupBox("Presets", parent)
        grid = QGridLayout(box)
        grid.setContentsMargins(6, 4, 6, 4)
        grid.setHorizontalSpacing(6)
        grid.setVerticalSpacing(4)

        self.expression_combo = QComboBox(box)
        self.expression_combo.setObjectName("expressionCombo")
        for i, name in enumerate(tables.expression_names()):
            self.expression_combo.addItem(name.capitalize(), i)
        self.expression_combo.setToolTip("MPEG-4 FAP 2 expression preset (thesis A Table B.1)")
        self.expression_slider, self.expression_spin = self._intensity_widgets(box, "expression")

        self.viseme_combo = QComboBox(box)
        self.viseme_combo.setObjectName("visemeCombo")
        for i, (name, phonemes) in enumerate(zip(tables.viseme_names(), tables.viseme_phonemes())):
            text = f"{i} {name}" if i == 0 else f"{i} {name}  {phonemes.replace(',', '')}"
            self.viseme_combo.addItem(text, i)
        self.viseme_combo.setToolTip("MPEG-4 FAP 1 viseme preset: id, name and example phonemes (SAMPA)")
        self.viseme_slider, self.viseme_spin = self._intensity_widgets(box, "viseme")

        for row, (title, combo, slider, spin) in enumerate((
                ("Expression", self.expression_combo, self.expression_slider, self.expression_spin),
                ("Viseme", self.viseme_combo, self.viseme_slider, self.viseme_spin))):
            grid.addWidget(QLabel(title, box), row, 0)
            grid.addWidget(combo, row, 1)
            grid.addWidget(slider, row, 2)
            grid.addWidget(spin, row, 3)
        grid.setColumnStretch(2, 1)

        self.expression_combo.currentIndexChanged.connect(lambda _i: self._expression_edited())
        self.expression_slider.valueChanged.connect(lambda _v: self._expression_edited("slider"))
        self.expression_spin.valueChanged.connect(lambda _v: self._expression_edited("spin"))
        self.viseme_combo.currentIndexChanged.connect(lambda _i: self._viseme_edited())
        self.viseme_slider.valueChanged.connect(lambda _v: self._viseme_edited("slider"))
        self.viseme_spin.valueChanged.connect(lambda _v: self._viseme_edited("spin"))
        return box

    def _intensity_widgets(self, parent: QWidget, what: str) -> tuple[QSlider, QSpinBox]:
        slider = QSlider(Qt.Orientation.Horizontal, parent)
        slider.setObjectName(f"{what}Intensity")
        slider.setRange(0, 100)
        slider.setValue(100)
        slider.setTracking(True)
        slider.setPageStep(10)
        slider.setMinimumWidth(80)
        slider.setToolTip(f"Intensity of the {what} preset")
        spin = QSpinBox(parent)
        spin.setObjectName(f"{what}IntensitySpin")
        spin.setRange(0, 100)
        spin.setValue(100)
        spin.setSuffix(" %")
        spin.setKeyboardTracking(False)
        spin.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        spin.setToolTip(f"Intensity of the {what} preset")
        return slider, spin

    def _build_controls(self, parent: QWidget) -> QWidget:
        w = QWidget(parent)
        grid = QGridLayout(w)
        grid.setContentsMargins(0, 0, 0, 0)
        grid.setHorizontalSpacing(10)
        grid.setVerticalSpacing(2)

        self.link_check = QCheckBox("Link left/right", w)
        self.link_check.setObjectName("linkLeftRight")
        self.link_check.setToolTip("Moving a left or right FAP moves its mirror FAP to the same value")
        self.reset_all_button = QPushButton("Reset all", w)
        self.reset_all_button.setObjectName("resetAll")
        self.reset_all_button.setToolTip("Every FAP to 0, expression and viseme to neutral")
        self.reset_all_button.clicked.connect(self.reset_all)

        self.feature_points_check = QCheckBox("Feature points", w)
        self.feature_points_check.setObjectName("showFeaturePoints")
        self.feature_points_check.setToolTip("Show the face's MPEG-4 feature points (View ▸ Show landmarks)")
        self.feature_points_check.toggled.connect(self.feature_points_toggled)
        self.influence_check = QCheckBox("Influence of hovered FAP", w)
        self.influence_check.setObjectName("showInfluence")
        self.influence_check.setToolTip(
            "Colour the face by how strongly the FAP under the mouse (or with a focused slider) moves each point")
        self.influence_check.toggled.connect(lambda _c: self._overlay_maybe_changed())
        self.heat_check = QCheckBox("Displacement heat map", w)
        self.heat_check.setObjectName("showHeatMap")
        self.heat_check.setToolTip("Colour the face by how far each point moved from the neutral face, in mm")
        self.heat_check.toggled.connect(lambda _c: self._overlay_maybe_changed())

        grid.addWidget(self.link_check, 0, 0)
        grid.addWidget(self.feature_points_check, 0, 1)
        grid.addWidget(self.reset_all_button, 0, 2, Qt.AlignmentFlag.AlignRight)
        grid.addWidget(self.influence_check, 1, 0)
        grid.addWidget(self.heat_check, 1, 1, 1, 2)
        grid.setColumnStretch(2, 1)
        return w

    def _clear_groups(self) -> None:
        for group in self.groups.values():
            self._groups_layout.removeWidget(group)
            group.setParent(None)
            group.deleteLater()
        self.groups.clear()
        self.rows.clear()

    def _build_groups(self, rig: "FaceRig") -> None:
        animated = set(rig.animated_faps)
        specs = [s for s in tables.fap_specs() if s.number in animated and s.dock]
        fapu = dict(rig.fapu)
        for name in tables.DOCK_GROUPS:
            members = [s for s in specs if s.dock == name]
            if not members:
                continue
            group = FapGroup(name, self._groups_widget)
            group.reset_requested.connect(self.reset_group)
            for spec in members:
                row = fap_row(spec, fapu, self._fp_names, group.body, rig.deformer.limit_note(spec.number),
                              rig.describe(f"fap:{spec.number}"))
                row.edited.connect(self._row_edited)
                row.reset_requested.connect(self.reset_fap)
                row.hover_changed.connect(self._row_hover)
                row.focus_changed.connect(self._row_focus)
                group.add_row(row)
                self.rows[row.key] = row
            self._groups_layout.insertWidget(self._groups_layout.count() - 1, group)
            self.groups[name] = group
        align_rows(self.rows.values())  # sliders line up across groups

    # ----------------------------------------------------------- rig
    def set_rig(self, rig: "FaceRig | None", message: str = "") -> None:
        """Drive ``rig`` (None: no animation for this face; ``message`` says why)."""
        if self.rig is not None:
            try:
                self.rig.parameters_changed.disconnect(self._on_parameters_changed)
            except (ValueError, RuntimeError):
                pass
        self.rig = rig
        self._hovered = self._focused = None
        self._clear_groups()
        if rig is not None:
            self._build_groups(rig)
            # Only parameter changes move the widgets (a muscle settling step does not), and only the
            # rows the change names.
            rig.parameters_changed.connect(self._on_parameters_changed)
        enabled = rig is not None
        for w in (self.expression_combo, self.expression_slider, self.expression_spin, self.viseme_combo,
                  self.viseme_slider, self.viseme_spin, self.link_check, self.reset_all_button,
                  self.influence_check, self.heat_check):
            w.setEnabled(enabled)
        self.scroll.setVisible(enabled)
        self._outer.setStretch(self._outer.count() - 1, 0 if enabled else 1)
        if not enabled and not message:
            message = NO_RIG_MESSAGE
        self.show_message(message)
        if rig is not None:
            self._on_rig_changed()
        self._overlay_maybe_changed()

    def show_message(self, message: str) -> None:
        """Show ``message`` above the presets (empty hides it)."""
        self.message_label.setText(message)
        self.message_label.setVisible(bool(message))

    def _on_parameters_changed(self, change) -> None:
        """The rows of the FAPs in ``change`` and, when a preset changed, the preset boxes."""
        rig = self.rig
        if rig is None:
            return
        self._syncing = True
        try:
            presets = False
            for key, value in change.values.items():
                kind = key.partition(":")[0]
                if kind == "fap":
                    row = self.rows.get(key)
                    if row is not None and row.value != value:
                        row.show_value(value)
                elif kind in ("expression", "viseme"):
                    presets = True
            if presets:
                self._show_presets()
        finally:
            self._syncing = False

    def _show_presets(self) -> None:
        eid, eint = self.rig.expression
        self._show_preset(self.expression_combo, self.expression_slider, self.expression_spin, eid, eint)
        vid, vint = self.rig.viseme
        self._show_preset(self.viseme_combo, self.viseme_slider, self.viseme_spin, vid, vint)
        # Where the active presets put each FAP: a mark on its slider, so a user sees what Joy does.
        presets = self.rig.preset_values()
        for row in self.rows.values():
            value = float(presets[fap_number(row) - 1])
            row.set_mark(value if value else None, f"The active preset puts it at {value:g}.")

    def _on_rig_changed(self, force: bool = False) -> None:
        """Every widget to the rig's values, emitting nothing (``force``: rows that think
        they already show the value too, e.g. after the rig refused an edit)."""
        rig = self.rig
        if rig is None:
            return
        self._syncing = True
        try:
            values = rig.fap_values()
            for row in self.rows.values():
                value = float(values[fap_number(row) - 1])
                if force or row.value != value:
                    row.show_value(value)
            self._show_presets()
        finally:
            self._syncing = False

    @staticmethod
    def _show_preset(combo: QComboBox, slider: QSlider, spin: QSpinBox, pid: int, intensity: float) -> None:
        with QSignalBlocker(combo), QSignalBlocker(slider), QSignalBlocker(spin):
            if combo.currentIndex() != pid:
                combo.setCurrentIndex(pid)
            if pid != 0:  # neutral/none: keep the intensity ready for the next pick
                percent = int(round(intensity * 100))
                slider.setValue(percent)
                spin.setValue(percent)
        slider.setEnabled(combo.isEnabled() and pid != 0)
        spin.setEnabled(combo.isEnabled() and pid != 0)

    # ----------------------------------------------------------- edits -> rig
    def _apply(self, call, *args) -> bool:
        """Run a rig setter; a refused value becomes a message and the widgets go back to the rig."""
        try:
            call(*args)
        except ValueError as exc:
            self.show_message(str(exc))
            self._on_rig_changed(force=True)
            return False
        if self.message_label.isVisible() and self.rig is not None:
            self.show_message("")
        return True

    def _row_edited(self, key: str, value: float) -> None:
        if self.rig is None or self._syncing:
            return
        values = {key: value}
        mirror = self.rows[key].mirror
        if self.link_check.isChecked() and mirror in self.rows:
            values[mirror] = self.rows[mirror].clamp(value)
        self._apply(self.rig.set_values, values)  # one call: one rig.changed, one redraw

    def _expression_edited(self, source: str = "combo") -> None:
        if self.rig is None or self._syncing:
            return
        self._preset_edited(self.rig.set_expression, self.expression_combo, self.expression_slider,
                            self.expression_spin, source)

    def _viseme_edited(self, source: str = "combo") -> None:
        if self.rig is None or self._syncing:
            return
        self._preset_edited(self.rig.set_viseme, self.viseme_combo, self.viseme_slider, self.viseme_spin, source)

    def _preset_edited(self, setter, combo: QComboBox, slider: QSlider, spin: QSpinBox, source: str) -> None:
        pid = int(combo.currentData())
        percent = spin.value() if source == "spin" else slider.value()
        if source == "combo" and pid != 0 and percent == 0:
            percent = 100  # picking an expression at 0 % would show nothing
        self._apply(setter, pid, percent / 100.0)
        if pid == 0:  # the rig ignores neutral's intensity, so _on_rig_changed leaves these alone
            self._show_preset(combo, slider, spin, 0, 0.0)

    def reset_fap(self, fap: int | str) -> None:
        """One FAP (a number, a name or a key) back to 0."""
        if self.rig is not None:
            self._apply(self.rig.reset_faps, [int(P.parse(fap).id)])

    def reset_group(self, name: str) -> None:
        group = self.groups.get(name)
        if self.rig is not None and group is not None:
            self._apply(self.rig.reset_faps, group.numbers)

    def reset_all(self) -> None:
        """Every FAP to 0 and the presets to neutral."""
        rig = self.rig
        if rig is None:
            return
        self._apply(rig.reset_faps)
        self._apply(rig.set_expression, None)
        self._apply(rig.set_viseme, None)

    # ----------------------------------------------------------- overlays
    def set_feature_points_checked(self, checked: bool, enabled: bool | None = None) -> None:
        """Mirror the window's landmark display without emitting ``feature_points_toggled``."""
        with QSignalBlocker(self.feature_points_check):
            self.feature_points_check.setChecked(bool(checked))
        if enabled is not None:
            self.feature_points_check.setEnabled(bool(enabled))

    @property
    def influence_fap(self) -> int | None:
        """The FAP whose influence is wanted: the row under the mouse, else the row with focus."""
        return self._hovered if self._hovered is not None else self._focused

    def overlay(self) -> tuple[str | None, int | None]:
        """("influence", n) while the influence toggle is on and a FAP row is hovered/focused,
        else ("heat", None) when the heat map is on, else (None, None)."""
        if self.rig is None:
            return None, None
        n = self.influence_fap
        if self.influence_check.isChecked() and n is not None:
            return "influence", n
        if self.heat_check.isChecked():
            return "heat", None
        return None, None

    def _row_hover(self, key: str, inside: bool) -> None:
        number = int(P.parse(key).id)
        if inside:
            self._hovered = number
        elif self._hovered == number:
            self._hovered = None
        self._overlay_maybe_changed()

    def _row_focus(self, key: str, focused: bool) -> None:
        number = int(P.parse(key).id)
        if focused:
            self._focused = number
        elif self._focused == number:
            self._focused = None
        self._overlay_maybe_changed()

    def _overlay_maybe_changed(self) -> None:
        current = self.overlay()
        if current != self._last_overlay:
            self._last_overlay = current
            self.overlay_changed.emit()

    # ----------------------------------------------------------- helpers for callers/tests
    def row(self, fap: int | str) -> ParameterRow:
        """The row of a FAP by number, name or key (KeyError if this face does not animate it)."""
        key = fap if isinstance(fap, str) and fap.startswith("fap:") else f"fap:{tables.fap_spec(fap).number}"
        return self.rows[key]

    def group_of(self, fap: int | str) -> FapGroup:
        return self.groups[tables.fap_spec(fap).dock]


__all__ = ["FapDock", "FapGroup", "NO_RIG_MESSAGE", "fap_tooltip", "readable_name", "row_label"]
