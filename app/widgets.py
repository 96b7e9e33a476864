"""widgets.py
----
Small input widgets shared by the docks.
"""

from __future__ import annotations

from PySide6.QtWidgets import QDoubleSpinBox, QSlider


class ScrollFriendlySlider(QSlider):
    """A slider that lets the mouse wheel scroll the dock unless it has keyboard focus.

    Without this, scrolling a long dock of sliders changes whichever slider passes under the mouse.
    """

    def wheelEvent(self, event) -> None:  # noqa: N802 - Qt override
        if self.hasFocus():
            super().wheelEvent(event)
        else:
            event.ignore()  # goes to the scroll area


class ScrollFriendlySpinBox(QDoubleSpinBox):
    """A spin box that changes by wheel only when it has keyboard focus (see ScrollFriendlySlider)."""

    def wheelEvent(self, event) -> None:  # noqa: N802 - Qt override
        if self.hasFocus():
            super().wheelEvent(event)
        else:
            event.ignore()
