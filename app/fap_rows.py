"""The FAP dock's rows and groups: one FAP's label, slider, spin box and reset (on the shared
ParameterControls), its tooltip (feature point, direction, unit in mm), and collapsible groups."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from PySide6.QtCore import QEvent, QObject, QSignalBlocker, Qt, Signal
from PySide6.QtWidgets import QFrame, QHBoxLayout, QLabel, QToolButton, QVBoxLayout, QWidget

from app.parameter_row import ParameterControls
from core.layers.fap import tables
from core.layers.fap.parameters import fap_label as row_label

if TYPE_CHECKING:  # pragma: no cover
    from core.layers.fap.tables import FapSpec

#: Degrees per AU (1 AU = 1e-5 rad).
DEG_PER_AU = math.degrees(tables.ANGLE_UNIT)
_GROUP_TITLES = {"jaw & chin": "Jaw && chin"}  # QToolButton text: '&' marks a mnemonic


# ------------------------------------------------------------------ naming
def _feature_point_descriptions() -> dict[str, str]:
    try:
        return tables.feature_point_descriptions()
    except Exception:  # noqa: BLE001 - descriptions only decorate the list
        return {}


def _mm(value: float) -> str:
    a = abs(value)
    return f"{value:.3f}" if a < 0.1 else f"{value:.2f}" if a < 10 else f"{value:.1f}"


def fap_tooltip(spec: "FapSpec", fapu: dict, fp_names: dict[str, str] | None = None) -> str:
    """Rich-text tooltip: full MPEG-4 name, feature point, direction, range and unit size on this face."""
    fp_names = fp_names if fp_names is not None else _feature_point_descriptions()
    fps = [p for p in spec.fp.split(";") if p]
    where = ", ".join(f"{p} ({fp_names[p].rstrip('.')})" if p in fp_names else p for p in fps)
    lines = [f"<b>FAP {spec.number} {spec.name}</b>",
             f"Moves feature point {where}" if not spec.is_rotation else f"Rotates about feature point {where}"]
    sign = "−/+" if spec.bidirectional else "+"
    lines.append(f"Positive direction: {spec.direction} ({'bidirectional' if spec.bidirectional else 'one-way'},"
                 f" {sign})")
    if spec.is_rotation:
        lo, hi = spec.minimum * DEG_PER_AU, spec.maximum * DEG_PER_AU
        lines.append(f"Range {spec.minimum:g} to {spec.maximum:g} AU = {lo:.1f}° to {hi:.1f}°")
        lines.append(f"1 AU = 10⁻⁵ rad = {DEG_PER_AU:.5f}°; the box shows degrees, the slider AU")
    else:
        unit_mm = float(fapu.get(spec.unit, float("nan")))
        lines.append(f"Range {spec.minimum:g} to {spec.maximum:g} {spec.unit}"
                     f" = {_mm(spec.minimum * unit_mm)} to {_mm(spec.maximum * unit_mm)} mm")
        lines.append(f"1 {spec.unit} unit = {_mm(unit_mm)} mm on this face")
    if spec.pair is not None:
        lines.append(f"Mirror: FAP {spec.pair} {tables.fap_spec(spec.pair).name} (moves too with Link left/right)")
    lines.append("<i>Double-click the name or press ↺ to reset</i>")
    return "<br>".join(lines)


def _nice_step(span: float) -> float:
    """A 1-2-5 step of about span / 100."""
    raw = max(span / 100.0, 1e-12)
    exp = math.floor(math.log10(raw))
    for m in (1, 2, 5, 10):
        if m * 10 ** exp >= raw:
            return m * 10 ** exp
    return 10 ** (exp + 1)


# ------------------------------------------------------------------ one FAP
class FapRow(QWidget):
    """Name, slider, spin box and reset button of one FAP (values are in the rig)."""

    edited = Signal(int, float)  # FAP number, new value in FAP units (AU for rotations)
    reset_requested = Signal(int)
    hover_changed = Signal(int, bool)  # FAP number, mouse entered (True) / left (False)
    focus_changed = Signal(int, bool)  # FAP number, slider or spin box got (True) / lost (False) focus

    def __init__(self, spec: "FapSpec", fapu: dict, fp_names: dict[str, str], parent: QWidget | None = None):
        super().__init__(parent)
        self.spec = spec
        self.number = spec.number
        lo, hi = int(math.floor(spec.minimum)), int(math.ceil(spec.maximum))
        step = max(1, int(_nice_step(hi - lo)))
        self.label = QLabel(row_label(spec), self)
        self.label.setObjectName(f"fapLabel{spec.number}")
        rotation = spec.is_rotation
        self.controls = ParameterControls(
            spec.number, lo, hi, self, suffix="°" if rotation else f" {spec.unit}", slider_step=step,
            display_scale=DEG_PER_AU if rotation else 1.0, decimals=1 if rotation else 0,
            spin_step=0.5 if rotation else step, name=f"fap{spec.number}", reset_tip=f"Reset FAP {spec.number} to 0")
        self.slider, self.spin, self.reset_button = self.controls.widgets()
        self.slider.setMinimumWidth(110)

        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(6)
        layout.addWidget(self.label)
        layout.addWidget(self.slider, 1)
        layout.addWidget(self.spin)
        layout.addWidget(self.reset_button)

        tip = fap_tooltip(spec, fapu, fp_names)
        for w in (self, self.label, self.slider, self.spin):
            w.setToolTip(tip)

        self.controls.edited.connect(lambda _key, value: self.edited.emit(self.number, float(value)))
        self.controls.reset_requested.connect(lambda _key: self.reset_requested.emit(self.number))
        for w in (self.slider, self.spin):
            w.installEventFilter(self)

    # ----------------------------------------------------------- values
    @property
    def value(self) -> float:
        """The value this row shows (FAP units; AU for rotations)."""
        return self.controls.value

    def show_value(self, value: float) -> None:
        """Show ``value`` (from the rig) without emitting anything."""
        self.controls.show_value(value)

    # ----------------------------------------------------------- hover / focus
    def enterEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().enterEvent(event)
        self.hover_changed.emit(self.number, True)

    def leaveEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().leaveEvent(event)
        self.hover_changed.emit(self.number, False)

    def mouseDoubleClickEvent(self, event) -> None:  # noqa: N802 - Qt override
        if self.label.geometry().contains(event.position().toPoint()):
            self.reset_requested.emit(self.number)
            event.accept()
            return
        super().mouseDoubleClickEvent(event)

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:  # noqa: N802 - Qt override
        if event.type() in (QEvent.Type.FocusIn, QEvent.Type.FocusOut):
            self.focus_changed.emit(self.number, event.type() == QEvent.Type.FocusIn)
        return False


# ------------------------------------------------------------------ a group
class FapGroup(QWidget):
    """A collapsible group of FAP rows with a header (arrow + title) and a Reset button."""

    reset_requested = Signal(str)

    def __init__(self, name: str, parent: QWidget | None = None):
        super().__init__(parent)
        self.name = name
        self.rows: list[FapRow] = []
        self.toggle = QToolButton(self)
        self.toggle.setObjectName(f"group:{name}")
        self.toggle.setText(_GROUP_TITLES.get(name, name.capitalize()))
        self.toggle.setCheckable(True)
        self.toggle.setChecked(True)
        self.toggle.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
        self.toggle.setArrowType(Qt.ArrowType.DownArrow)
        self.toggle.setAutoRaise(True)
        self.toggle.setStyleSheet("QToolButton { border: none; padding: 2px 0px; }")
        self.toggle.setToolTip("Click to fold or unfold this group")
        font = self.toggle.font()
        font.setBold(True)
        self.toggle.setFont(font)
        self.toggle.toggled.connect(self.set_expanded)
        self.reset_button = QToolButton(self)
        self.reset_button.setText("Reset")
        self.reset_button.setToolTip(f"Set the {name} FAPs to 0")
        self.reset_button.setAutoRaise(True)
        self.reset_button.clicked.connect(lambda: self.reset_requested.emit(self.name))

        header = QHBoxLayout()
        header.setContentsMargins(0, 0, 0, 0)
        header.addWidget(self.toggle)
        header.addStretch(1)
        header.addWidget(self.reset_button)
        line = QFrame(self)
        line.setFrameShape(QFrame.Shape.HLine)
        line.setFrameShadow(QFrame.Shadow.Sunken)

        self.body = QWidget(self)
        self.body_layout = QVBoxLayout(self.body)
        self.body_layout.setContentsMargins(4, 0, 0, 4)
        self.body_layout.setSpacing(2)

        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        layout.addLayout(header)
        layout.addWidget(line)
        layout.addWidget(self.body)

    @property
    def numbers(self) -> list[int]:
        return [r.number for r in self.rows]

    def add_row(self, row: FapRow) -> None:
        self.rows.append(row)
        self.body_layout.addWidget(row)
        self.toggle.setText(f"{_GROUP_TITLES.get(self.name, self.name.capitalize())}  ({len(self.rows)})")

    @property
    def expanded(self) -> bool:
        return self.toggle.isChecked()

    def set_expanded(self, expanded: bool) -> None:
        with QSignalBlocker(self.toggle):
            self.toggle.setChecked(bool(expanded))
        self.toggle.setArrowType(Qt.ArrowType.DownArrow if expanded else Qt.ArrowType.RightArrow)
        self.body.setVisible(bool(expanded))
