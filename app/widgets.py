"""widgets.py
----
Small input widgets shared by the docks.
"""

from __future__ import annotations

from PySide6.QtCore import QPoint, QPointF, QRect, QSize, Qt, Signal
from PySide6.QtGui import QColor, QPainter, QPolygonF, QValidator
from PySide6.QtWidgets import QDoubleSpinBox, QLayout, QSlider, QStyle, QStyleOptionSlider, QToolTip, QWidget


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


class FlowLayout(QLayout):
    """Items left to right, wrapping onto a new row when the width runs out (the toolbar of a
    narrow dock shows every control instead of scrolling them out of sight). Qt's flow-layout
    example, for widgets only."""

    def __init__(self, parent: QWidget | None = None, spacing: int = 4):
        super().__init__(parent)
        self._items: list = []
        self.setSpacing(spacing)
        self.setContentsMargins(0, 0, 0, 0)

    def addItem(self, item) -> None:  # noqa: N802 - Qt API
        self._items.append(item)

    def count(self) -> int:
        return len(self._items)

    def itemAt(self, index: int):  # noqa: N802 - Qt API
        return self._items[index] if 0 <= index < len(self._items) else None

    def takeAt(self, index: int):  # noqa: N802 - Qt API
        return self._items.pop(index) if 0 <= index < len(self._items) else None

    def expandingDirections(self):  # noqa: N802 - Qt API
        return Qt.Orientation(0)

    def hasHeightForWidth(self) -> bool:  # noqa: N802 - Qt API
        return True

    def heightForWidth(self, width: int) -> int:  # noqa: N802 - Qt API
        return self._arrange(QRect(0, 0, width, 0), move=False)

    def setGeometry(self, rect: QRect) -> None:  # noqa: N802 - Qt API
        super().setGeometry(rect)
        self._arrange(rect, move=True)

    def sizeHint(self) -> QSize:  # noqa: N802 - Qt API
        return self.minimumSize()

    def minimumSize(self) -> QSize:  # noqa: N802 - Qt API
        size = QSize()
        for item in self._items:
            size = size.expandedTo(item.minimumSize())
        margins = self.contentsMargins()
        return size + QSize(margins.left() + margins.right(), margins.top() + margins.bottom())

    def _arrange(self, rect: QRect, *, move: bool) -> int:
        """Place the items in ``rect`` (when ``move``); returns the height they need."""
        margins = self.contentsMargins()
        area = rect.adjusted(margins.left(), margins.top(), -margins.right(), -margins.bottom())
        x, y, row_height, gap = area.x(), area.y(), 0, self.spacing()
        for item in self._items:
            hint = item.sizeHint()
            if x + hint.width() > area.right() + 1 and row_height > 0:
                x, y, row_height = area.x(), y + row_height + gap, 0
            if move:
                item.setGeometry(QRect(QPoint(x, y), hint))
            x += hint.width() + gap
            row_height = max(row_height, hint.height())
        return y + row_height - rect.y() + margins.bottom()
