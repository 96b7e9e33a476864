"""widgets.py
----
Small input widgets shared by the docks.
"""

from __future__ import annotations

from PySide6.QtCore import QPoint, QPointF, Qt, Signal
from PySide6.QtGui import QColor, QPainter, QPolygonF, QValidator
from PySide6.QtWidgets import QDoubleSpinBox, QSlider, QStyle, QStyleOptionSlider, QToolTip


class ScrollFriendlySlider(QSlider):
    """A slider that lets the mouse wheel scroll the dock unless it has keyboard focus.

    Without this, scrolling a long dock of sliders changes whichever slider passes under the mouse.
    ``set_ghost(value)`` marks a second value on the groove (e.g. where the active expression preset
    puts this parameter); None removes the mark.
    """

    ghost: int | None = None

    def set_ghost(self, value: int | None) -> None:
        value = None if value is None else int(round(value))
        if value != self.ghost:
            self.ghost = value
            self.update()

    def paintEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().paintEvent(event)
        if self.ghost is None or not self.minimum() <= self.ghost <= self.maximum():
            return
        option = QStyleOptionSlider()
        self.initStyleOption(option)
        groove = self.style().subControlRect(QStyle.ComplexControl.CC_Slider, option,
                                             QStyle.SubControl.SC_SliderGroove, self)
        handle = self.style().subControlRect(QStyle.ComplexControl.CC_Slider, option,
                                             QStyle.SubControl.SC_SliderHandle, self)
        span = groove.width() - handle.width()
        x = groove.x() + handle.width() / 2 + QStyle.sliderPositionFromValue(
            self.minimum(), self.maximum(), self.ghost, max(span, 1))
        painter = QPainter(self)
        painter.setRenderHint(QPainter.RenderHint.Antialiasing)
        painter.setPen(Qt.PenStyle.NoPen)
        painter.setBrush(QColor(230, 120, 20))
        top = groove.center().y() + 4
        painter.drawPolygon(QPolygonF([QPointF(x, top), QPointF(x - 4, top + 6), QPointF(x + 4, top + 6)]))
        painter.end()

    def wheelEvent(self, event) -> None:  # noqa: N802 - Qt override
        if self.hasFocus():
            super().wheelEvent(event)
        else:
            event.ignore()  # goes to the scroll area


class ScrollFriendlySpinBox(QDoubleSpinBox):
    """A spin box that changes by wheel only when it has keyboard focus (see ScrollFriendlySlider),
    and that never changes a typed number behind the user's back.

    Qt's own box refuses keystrokes that would leave the range, so typing 500 into a 0–400 box
    gives 50. Here any number can be typed; on Enter or leaving the box a number outside the range
    is refused with a note under the box ("500 is outside 0 to 400 MNS"; ``refused`` is emitted)
    and the box shows the value it had.
    """

    refused = Signal(str)  # the note shown

    def wheelEvent(self, event) -> None:  # noqa: N802 - Qt override
        if self.hasFocus():
            super().wheelEvent(event)
        else:
            event.ignore()

    def validate(self, text: str, pos: int):  # noqa: D102 - Qt override
        state, text, pos = super().validate(text, pos)
        if state == QValidator.State.Invalid and self._number(text) is not None:
            return QValidator.State.Intermediate, text, pos   # a number, maybe out of range: let it be typed
        return state, text, pos

    def fixup(self, text: str) -> str:  # noqa: D102 - Qt override
        number = self._number(text)
        if number is not None and not self.minimum() <= number <= self.maximum():
            unit = self.suffix().strip()
            note = (f"{number:g} is outside {self.minimum():g} to {self.maximum():g} {unit}".rstrip()
                    + "; the value stays as it was")
            self.refused.emit(note)
            if self.isVisible():
                QToolTip.showText(self.mapToGlobal(QPoint(0, self.height())), note, self)
            return self.textFromValue(self.value())
        return super().fixup(text)

    def _number(self, text: str) -> float | None:
        core = text.strip()
        if self.suffix() and core.endswith(self.suffix().strip()):
            core = core[: len(core) - len(self.suffix().strip())].strip()
        if self.prefix() and core.startswith(self.prefix().strip()):
            core = core[len(self.prefix().strip()):].strip()
        try:
            return float(core.replace(self.locale().groupSeparator(), "").replace(self.locale().decimalPoint(), "."))
        except ValueError:
            return None
