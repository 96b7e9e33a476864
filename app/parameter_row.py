"""parameter_row.py
----
The controls of one rig parameter — slider, spin box with its unit, reset button — shared by the
FAP dock and the muscle dock. The value lives in the rig: the controls show it (``show_value``,
no signal) and report the user's edits (``edited(key, value)``, ``reset_requested(key)``); the
dock lays the widgets out.

Units: the slider moves in steps of ``1 / slider_scale`` value units; the spin box shows
``value × display_scale`` (degrees for the FAPs measured in 1e-5 rad) with ``decimals`` decimals.
A value typed in the spin box is converted back and kept within the range (the conversion's
rounding only; the spin box itself refuses anything outside it).
"""

from __future__ import annotations

from typing import Hashable

from PySide6.QtCore import QObject, QSignalBlocker, Qt, Signal
from PySide6.QtWidgets import QAbstractSpinBox, QSizePolicy, QToolButton, QWidget

from app.widgets import ScrollFriendlySlider, ScrollFriendlySpinBox

__all__ = ["ParameterControls"]


class ParameterControls(QObject):
    """Slider, spin box and reset button of one parameter (see the module docstring).

    key : emitted with every signal (a FAP number, a muscle's (name, side), ...)
    minimum, maximum : the parameter's range, in value units
    suffix : the spin box's unit text, e.g. " MNS", "°", " u"
    slider_scale : slider ticks per value unit; slider_step : ticks per arrow key
    display_scale, decimals, spin_step : the spin box shows value × display_scale
    name : object-name stem (``<name>Slider``, ``<name>Spin``, ``<name>Reset``) for tests and styles
    """

    edited = Signal(object, float)       # key, new value
    reset_requested = Signal(object)     # key

    def __init__(self, key: Hashable, minimum: float, maximum: float, parent: QWidget, *, suffix: str = "",
                 slider_scale: float = 1.0, slider_step: int = 1, display_scale: float = 1.0, decimals: int = 0,
                 spin_step: float = 1.0, name: str = "parameter", reset_tip: str = "Reset to 0"):
        super().__init__(parent)
        self.key = key
        self.minimum, self.maximum = float(minimum), float(maximum)
        self.slider_scale, self.display_scale = float(slider_scale), float(display_scale)

        self.slider = ScrollFriendlySlider(Qt.Orientation.Horizontal, parent)
        self.slider.setObjectName(f"{name}Slider")
        self.slider.setFocusPolicy(Qt.FocusPolicy.StrongFocus)  # no focus (and no value change) by wheel
        self.slider.setRange(round(self.minimum * self.slider_scale), round(self.maximum * self.slider_scale))
        self.slider.setSingleStep(max(1, int(slider_step)))
        self.slider.setPageStep(max(1, int(slider_step)) * 10)
        self.slider.setTracking(True)  # live: every move goes to the rig
        self.slider.setMinimumWidth(100)
        self.slider.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)

        self.spin = ScrollFriendlySpinBox(parent)
        self.spin.setObjectName(f"{name}Spin")
        self.spin.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self.spin.setKeyboardTracking(False)  # typed numbers go to the rig on Enter / focus out
        self.spin.setAccelerated(True)
        self.spin.setDecimals(int(decimals))
        self.spin.setRange(self.minimum * self.display_scale, self.maximum * self.display_scale)
        self.spin.setSingleStep(spin_step)
        self.spin.setSuffix(suffix)
        self.spin.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        self.spin.setButtonSymbols(QAbstractSpinBox.ButtonSymbols.UpDownArrows)

        self.reset_button = QToolButton(parent)
        self.reset_button.setObjectName(f"{name}Reset")
        self.reset_button.setText("↺")
        self.reset_button.setToolTip(reset_tip)
        self.reset_button.setAutoRaise(True)
        self.reset_button.setFocusPolicy(Qt.FocusPolicy.NoFocus)

        self._value = 0.0
        self.slider.valueChanged.connect(lambda tick: self.edited.emit(self.key, tick / self.slider_scale))
        self.spin.valueChanged.connect(self._spin_changed)
        self.reset_button.clicked.connect(lambda: self.reset_requested.emit(self.key))

    @property
    def value(self) -> float:
        """The value these controls show (value units)."""
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

    def set_tooltip(self, text: str) -> None:
        for w in (self.slider, self.spin):
            w.setToolTip(text)

    def widgets(self) -> list[QWidget]:
        return [self.slider, self.spin, self.reset_button]

    def _spin_changed(self, shown: float) -> None:
        value = shown / self.display_scale
        # The display conversion's rounding may step just outside the range: keep it inside.
        self.edited.emit(self.key, min(max(value, self.minimum), self.maximum))
