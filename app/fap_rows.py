"""The FAP dock's rows and groups: one FAP's row (the shared :class:`app.parameter_row.ParameterRow`
of its ``fap:<n>`` key) with its tooltip (feature point, direction, unit in mm), and collapsible groups."""

from __future__ import annotations

from typing import TYPE_CHECKING

from PySide6.QtCore import QSignalBlocker, Qt, Signal
from PySide6.QtWidgets import QFrame, QHBoxLayout, QToolButton, QVBoxLayout, QWidget

from app.parameter_row import DEG_PER_AU, ParameterRow
from core.layers.fap import tables
from core.layers.fap.parameters import fap_label as row_label  # noqa: F401 - re-exported

if TYPE_CHECKING:  # pragma: no cover
    from core import parameters as P
    from core.layers.fap.tables import FapSpec

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


def fap_tooltip(spec: "FapSpec", fapu: dict, fp_names: dict[str, str] | None = None,
                limit_note: str | None = None, param: "P.Parameter | None" = None) -> str:
    """Rich-text tooltip: full MPEG-4 name, feature point, direction, range and unit size on this face,
    and ``limit_note`` when the face eases the FAP before a slider end (``FapDeformer.limit_note``).
    ``param``: the face's own description (``FaceRig.describe``) when its range is not the table's."""
    fp_names = fp_names if fp_names is not None else _feature_point_descriptions()
    low, high = (param.minimum, param.maximum) if param is not None else (spec.minimum, spec.maximum)
    fps = [p for p in spec.fp.split(";") if p]
    where = ", ".join(f"{p} ({fp_names[p].rstrip('.')})" if p in fp_names else p for p in fps)
    lines = [f"<b>FAP {spec.number} {spec.name}</b>",
             f"Moves feature point {where}" if not spec.is_rotation else f"Rotates about feature point {where}"]
    sign = "−/+" if spec.bidirectional else "+"
    lines.append(f"Positive direction: {spec.direction} ({'bidirectional' if spec.bidirectional else 'one-way'},"
                 f" {sign})")
    if spec.is_rotation:
        lines.append(f"Range {low:g} to {high:g} AU = {low * DEG_PER_AU:.1f}° to {high * DEG_PER_AU:.1f}°")
        lines.append(f"1 AU = 10⁻⁵ rad = {DEG_PER_AU:.5f}°; the box shows degrees, the slider AU")
    else:
        unit_mm = float(fapu.get(spec.unit, float("nan")))
        lines.append(f"Range {low:g} to {high:g} {spec.unit} = {_mm(low * unit_mm)} to {_mm(high * unit_mm)} mm")
        lines.append(f"1 {spec.unit} unit = {_mm(unit_mm)} mm on this face")
    if param is not None and param.note:
        lines.append(f"On this face: {param.note}")
    if limit_note:
        lines.append(f"On this face: {limit_note}")
    if spec.pair is not None:
        lines.append(f"Mirror: FAP {spec.pair} {tables.fap_spec(spec.pair).name} (moves too with Link left/right)")
    lines.append("<i>Double-click the name or press ↺ to reset</i>")
    return "<br>".join(lines)


# ------------------------------------------------------------------ one FAP
def fap_row(spec: "FapSpec", fapu: dict, fp_names: dict[str, str], parent: QWidget | None = None,
            limit_note: str | None = None, param: "P.Parameter | None" = None) -> ParameterRow:
    """The row of one FAP (``fap:<n>``): the registry's label, the face's range (``param``, from
    ``FaceRig.describe``; the registry's when None) and tooltip."""
    return ParameterRow(f"fap:{spec.number}", parent, param=param, name=f"fap{spec.number}",
                        tooltip=fap_tooltip(spec, fapu, fp_names, limit_note, param))


def fap_number(row: ParameterRow) -> int:
    """The FAP number of a FAP row."""
    return int(row.key.split(":")[1])


# ------------------------------------------------------------------ a group
class FapGroup(QWidget):
    """A collapsible group of FAP rows with a header (arrow + title) and a Reset button."""

    reset_requested = Signal(str)

    def __init__(self, name: str, parent: QWidget | None = None):
        super().__init__(parent)
        self.name = name
        self.rows: list[ParameterRow] = []
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
        return [fap_number(r) for r in self.rows]

    def add_row(self, row: ParameterRow) -> None:
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
