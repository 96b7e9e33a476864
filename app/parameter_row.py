"""parameter_row.py
----
One rig parameter's row — label, slider, spin box with its unit, reset button — built from its
registry key (``core.parameters``: "fap:3", "muscle:risorius:left", "jaw"), used by the FAP dock
and the muscle dock alike. The label, range, default, left/right mirror and tooltip come from the
registry; how the value is shown (unit text, resolution, degrees for angles) from its unit
(:func:`row_format`).

The value lives in the rig: the row shows it (``show_value``, no signal) and reports the user's
edits (``edited(key, value)``, ``reset_requested(key)``); the dock applies them. A second value
can be marked on the slider's groove (``set_mark``: where the active preset puts this parameter).

Units: the slider moves in steps of ``1 / slider_scale`` value units; the spin box shows
``value × display_scale`` (degrees for the FAPs measured in 1e-5 rad) with ``decimals`` decimals.
A value typed in the spin box is converted back and kept within the range (the conversion's
rounding only; the spin box itself refuses anything outside it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Hashable, Iterable

from PySide6.QtCore import QEvent, QObject, QSignalBlocker, Qt, Signal
from PySide6.QtGui import QFocusEvent, QFontMetrics
from PySide6.QtWidgets import QAbstractSpinBox, QHBoxLayout, QLabel, QSizePolicy, QToolButton, QWidget

from app.widgets import ScrollFriendlySlider, ScrollFriendlySpinBox
from core import parameters as P
from core.layers.fap.tables import ANGLE_UNIT

__all__ = ["ParameterRow", "RowFormat", "row_format", "parameter_tooltip", "align_rows", "DEG_PER_AU"]

#: Degrees per AU (1 AU = 1e-5 rad): the FAP rotations are shown in degrees.
DEG_PER_AU = math.degrees(ANGLE_UNIT)
#: The FAP units (1/1024 of a distance on the neutral face): whole units are fine enough.
_FAP_UNITS = ("MNS", "MW", "ENS", "ES", "IRISD")


@dataclass(frozen=True)
class RowFormat:
    """How a parameter's value is shown: range (value units), spin box suffix, slider ticks per
    unit and per arrow key, spin box scale, decimals and step."""

    minimum: float
    maximum: float
    suffix: str = ""
    slider_scale: float = 1.0
    slider_step: int = 1
    display_scale: float = 1.0
    decimals: int = 0
    spin_step: float = 1.0


def _nice_step(span: float) -> float:
    """A 1-2-5 step of about span / 100."""
    raw = max(span / 100.0, 1e-12)
    exp = math.floor(math.log10(raw))
    for m in (1, 2, 5, 10):
        if m * 10 ** exp >= raw:
            return m * 10 ** exp
    return 10 ** (exp + 1)


def row_format(param: P.Parameter) -> RowFormat:
    """The display of a parameter, by its unit: FAP units in whole units (slider step about 1 % of
    the range), FAP angles (AU) in degrees with one decimal, muscle forces (thesis units ``u``)
    and degrees in tenths, anything else (0..1 intensities) in hundredths."""
    lo, hi, unit = param.minimum, param.maximum, param.unit
    if unit == "AU":
        lo, hi = math.floor(lo), math.ceil(hi)
        return RowFormat(lo, hi, "°", slider_step=max(1, int(_nice_step(hi - lo))), display_scale=DEG_PER_AU,
                         decimals=1, spin_step=0.5)
    if unit in _FAP_UNITS:
        lo, hi = math.floor(lo), math.ceil(hi)
        step = max(1, int(_nice_step(hi - lo)))
        return RowFormat(lo, hi, f" {unit}", slider_step=step, spin_step=step)
    if unit in ("force", "°"):
        return RowFormat(lo, hi, " u" if unit == "force" else "°", slider_scale=10, slider_step=5, decimals=1,
                         spin_step=0.5)
    return RowFormat(lo, hi, f" {unit}" if unit else "", slider_scale=100, slider_step=1, decimals=2, spin_step=0.01)


def parameter_tooltip(param: P.Parameter, notes: Iterable[str] = ()) -> str:
    """Rich-text tooltip from the registry: label, description, range; then ``notes`` (one line each)."""
    fmt = row_format(param)
    unit = fmt.suffix if fmt.display_scale == 1.0 else f" {param.unit}"
    lines = [f"<b>{param.label}</b>"]
    if param.description:
        lines.append(param.description)
    lines.append(f"Range {param.minimum:g} to {param.maximum:g}{unit}")
    if param.note:
        lines.append(f"On this face: {param.note}")
    lines += [n for n in notes if n]
    return "<br>".join(lines)


class ParameterRow(QWidget):
    """Label, slider, spin box and reset button of one registry parameter (see the module docstring).

    key : any spelling of the parameter (``core.parameters.key_of``); ``row.key`` is the canonical one
    text : the label's text (the registry's label by default; the muscle dock shows the side only)
    tooltip : rich text for the row (``parameter_tooltip(param)`` by default)
    name : object-name stem (``<name>Slider``, ``<name>Spin``, ``<name>Reset``, ``<name>Label``)
    param : the parameter's description on the face shown (``FaceRig.describe``: its own range) when
        it is not the registry's
    """

    edited = Signal(str, float)          # key, new value
    reset_requested = Signal(str)        # key
    hover_changed = Signal(str, bool)    # key, mouse entered (True) / left (False)
    focus_changed = Signal(str, bool)    # key, slider or spin box got (True) / lost (False) focus

    def __init__(self, key: Hashable, parent: QWidget | None = None, *, text: str | None = None,
                 tooltip: str | None = None, name: str | None = None, param: P.Parameter | None = None):
        super().__init__(parent)
        self.param = param if param is not None else P.describe(key)
        self.key: str = self.param.key
        self.format = fmt = row_format(self.param)
        self.minimum, self.maximum = float(fmt.minimum), float(fmt.maximum)
        self.slider_scale, self.display_scale = float(fmt.slider_scale), float(fmt.display_scale)
        name = name or self.key.replace(":", "_")

        self.label = QLabel(self.param.label if text is None else text, self)
        self.label.setObjectName(f"{name}Label")

        self.slider = ScrollFriendlySlider(Qt.Orientation.Horizontal, self)
        self.slider.setObjectName(f"{name}Slider")
        self.slider.setFocusPolicy(Qt.FocusPolicy.StrongFocus)  # no focus (and no value change) by wheel
        self.slider.setRange(round(self.minimum * self.slider_scale), round(self.maximum * self.slider_scale))
        self.slider.setSingleStep(max(1, int(fmt.slider_step)))
        self.slider.setPageStep(max(1, int(fmt.slider_step)) * 10)
        self.slider.setTracking(True)  # live: every move goes to the rig
        self.slider.setMinimumWidth(110)
        self.slider.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)

        self.spin = ScrollFriendlySpinBox(self)
        self.spin.setObjectName(f"{name}Spin")
        self.spin.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.spin.setKeyboardTracking(False)  # typed numbers go to the rig on Enter / focus out
        self.spin.setAccelerated(True)
        self.spin.setDecimals(int(fmt.decimals))
        self.spin.setRange(self.minimum * self.display_scale, self.maximum * self.display_scale)
        self.spin.setSingleStep(fmt.spin_step)
        self.spin.setSuffix(fmt.suffix)
        self.spin.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        self.spin.setButtonSymbols(QAbstractSpinBox.ButtonSymbols.UpDownArrows)

        self.reset_button = QToolButton(self)
        self.reset_button.setObjectName(f"{name}Reset")
        self.reset_button.setText("↺")
        self.reset_button.setToolTip(f"Reset {self.param.label} to {self.param.default:g}")
        self.reset_button.setAutoRaise(True)
        self.reset_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)

        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(6)
        layout.addWidget(self.label)
        layout.addWidget(self.slider, 1)
        layout.addWidget(self.spin)
        layout.addWidget(self.reset_button)

        self._value = float(self.param.default)
        self._mark_note = ""
        self.set_tooltip(tooltip if tooltip is not None else parameter_tooltip(self.param))
        self.show_value(self._value)
        self.slider.valueChanged.connect(lambda tick: self.edited.emit(self.key, tick / self.slider_scale))
        self.spin.valueChanged.connect(self._spin_changed)
        self.reset_button.clicked.connect(lambda: self.reset_requested.emit(self.key))
        for w in (self.slider, self.spin):
            w.installEventFilter(self)

    # ----------------------------------------------------------- registry
    @property
    def mirror(self) -> str | None:
        """The key of the left/right partner ("Link left/right"), or None."""
        return self.param.mirror

    @property
    def default(self) -> float:
        return float(self.param.default)

    def clamp(self, value: float) -> float:
        """``value`` within this row's range (a linked partner may have a narrower one)."""
        return min(max(float(value), self.minimum), self.maximum)

    # ----------------------------------------------------------- value
    @property
    def value(self) -> float:
        """The value this row shows (value units; AU for FAP angles)."""
        return self._value

    def show_value(self, value: float) -> None:
        """Show ``value`` (from the rig) without emitting anything."""
        self._value = float(value)
        shown = self._value * self.display_scale
        with QSignalBlocker(self.slider), QSignalBlocker(self.spin):
            tick = round(self._value * self.slider_scale)
            if self.slider.value() != tick:
                self.slider.setValue(tick)
            if abs(self.spin.value() - shown) > 1e-9:
                self.spin.setValue(shown)

    def set_mark(self, value: float | None, note: str = "") -> None:
        """Mark ``value`` on the slider's groove (None: no mark); ``note`` joins the slider's tooltip."""
        self.slider.set_ghost(None if value is None else value * self.slider_scale)
        note = note if value is not None else ""
        if note != self._mark_note:
            self._mark_note = note
            self.slider.setToolTip(self.toolTip() + (f"<br><br>▲ {note}" if note else ""))

    @property
    def mark(self) -> float | None:
        """The marked value (None: no mark)."""
        ghost = self.slider.ghost
        return None if ghost is None else ghost / self.slider_scale

    def set_tooltip(self, text: str) -> None:
        for w in (self, self.label, self.spin):
            w.setToolTip(text)
        self.slider.setToolTip(text + (f"<br><br>▲ {self._mark_note}" if self._mark_note else ""))

    def _spin_changed(self, shown: float) -> None:
        # The display conversion's rounding may step just outside the range: keep it inside.
        self.edited.emit(self.key, self.clamp(shown / self.display_scale))

    # ----------------------------------------------------------- hover / focus / double-click
    def enterEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().enterEvent(event)
        self.hover_changed.emit(self.key, True)

    def leaveEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().leaveEvent(event)
        self.hover_changed.emit(self.key, False)

    def mouseDoubleClickEvent(self, event) -> None:  # noqa: N802 - Qt override
        if self.label.geometry().contains(event.position().toPoint()):
            self.reset_requested.emit(self.key)   # double-click the name: reset, as ↺ does
            event.accept()
            return
        super().mouseDoubleClickEvent(event)

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:  # noqa: N802 - Qt override
        if isinstance(event, QFocusEvent) and event.type() in (QEvent.Type.FocusIn, QEvent.Type.FocusOut):
            self.focus_changed.emit(self.key, event.type() == QEvent.Type.FocusIn)
        return False


def align_rows(rows: Iterable[ParameterRow], *, label_width: int | None = None) -> None:
    """One label width and one spin box width for every row, so the sliders line up (the label
    as wide as the longest text unless ``label_width`` is given)."""
    rows = list(rows)
    if not rows:
        return
    if label_width is None:
        metrics = QFontMetrics(rows[0].label.font())
        label_width = max(metrics.horizontalAdvance(r.label.text()) for r in rows) + 8
    spin_width = max(r.spin.sizeHint().width() for r in rows)
    for r in rows:
        r.label.setFixedWidth(label_width)
        r.spin.setFixedWidth(spin_width)
