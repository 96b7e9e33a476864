"""The landmark list's model: one row per landmark with its status chip, confidence and position,
short MPEG-4 descriptions as tooltips; sorting by any column (confidence: the doubtful first) and
a "low confidence only" filter through :class:`LandmarkFilter`; low confidences highlighted."""

from __future__ import annotations

import re

import numpy as np
from PySide6.QtCore import QAbstractTableModel, QModelIndex, QObject, QSortFilterProxyModel, Qt, Signal
from PySide6.QtGui import QBrush, QColor, QIcon, QPainter, QPixmap

from app import picking
from core.landmark_editing import LOW_CONFIDENCE, LandmarkEditModel, LandmarkStatus
from core.layers.fap import tables


STATUS_TIPS = {
    "auto": "auto: placed by the detector or loaded from a file; nobody has checked it yet",
    "edited": "edited: moved by you (kept fixed when matching is re-run)",
    "confirmed": "confirmed: checked by you (kept fixed when matching is re-run)",
}


COLUMNS = ("Landmark", "Status", "Conf.", "x", "y", "z")
SORT_ROLE = Qt.ItemDataRole.UserRole + 1   # what a column sorts by (numbers, template order)
LOW_BACKGROUND = QColor(255, 214, 204)
LOW_FOREGROUND = QColor(160, 30, 10)


def _descriptions() -> dict[str, str]:
    try:
        return tables.feature_point_descriptions()
    except Exception:  # noqa: BLE001 - descriptions only decorate the list
        return {}


def _lower_first(text: str) -> str:
    return text[:1].lower() + text[1:] if text[:2] != text[:2].upper() else text


_MIDPOINT = re.compile(r"^Midpoint between f\.p\. (\S+) and (\S+) in (?:the )?(.+?)$")


def short_description(description: str) -> str:
    """The list's wording of an MPEG-4 description: lower-case start, and the midpoints put
    what they are first ("Midpoint between f.p. 2.2 and 2.4 in the inner upper lip contour"
    -> "inner upper lip contour, between 2.2 and 2.4"), so a narrow column still says it."""
    m = _MIDPOINT.match(description.strip())
    if m:
        return f"{m.group(3)}, between {m.group(1)} and {m.group(2)}"
    return _lower_first(description.strip())


def _chip(status: str, size: int = 10) -> QIcon:
    pixmap = QPixmap(size, size)
    pixmap.fill(Qt.GlobalColor.transparent)
    painter = QPainter(pixmap)
    painter.setRenderHint(QPainter.RenderHint.Antialiasing)
    painter.setPen(Qt.PenStyle.NoPen)
    painter.setBrush(QColor(*picking.STATUS_COLORS[status]))
    painter.drawEllipse(0, 0, size - 1, size - 1)
    painter.end()
    return QIcon(pixmap)


# ------------------------------------------------------------------ table model
class LandmarkTableModel(QAbstractTableModel):
    """The rows of the landmark list, read live from a :class:`LandmarkEditModel`.

    x/y/z cells are editable: a typed value goes to ``edit_position(name, xyz)``.
    """

    edit_position = Signal(str, object)  # name, (3,) mm wanted

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        self.model: LandmarkEditModel | None = None
        self._names: list[str] = []
        self._positions = np.zeros((0, 3))
        self._descriptions = _descriptions()
        self._chips = {s.value: _chip(s.value) for s in LandmarkStatus}

    def set_model(self, model: LandmarkEditModel | None) -> None:
        self.beginResetModel()
        self.model = model
        self._reload()
        self.endResetModel()

    def _reload(self) -> None:
        self._names = self.model.names if self.model is not None else []
        self._positions = self.model.positions() if self._names else np.zeros((0, 3))

    def refresh(self, name: str = "") -> None:
        """Re-read one landmark's row (or everything when ``name`` is "")."""
        if self.model is None:
            return
        if not name or name not in self._names or self.model.names != self._names:
            self.beginResetModel()
            self._reload()
            self.endResetModel()
            return
        row = self._names.index(name)
        self._positions[row] = self.model.position(name)
        self.dataChanged.emit(self.index(row, 0), self.index(row, len(COLUMNS) - 1))

    def name_at(self, row: int) -> str | None:
        return self._names[row] if 0 <= row < len(self._names) else None

    def row_of(self, name: str | None) -> int:
        return self._names.index(name) if name in self._names else -1

    def label(self, name: str) -> str:
        description = self._descriptions.get(name)
        return f"{name}  –  {short_description(description)}" if description else name

    # ------------------------------------------------------------ Qt model API
    def rowCount(self, parent=QModelIndex()) -> int:  # noqa: N802, B008 - Qt API
        return 0 if parent.isValid() else len(self._names)

    def columnCount(self, parent=QModelIndex()) -> int:  # noqa: N802, B008 - Qt API
        return 0 if parent.isValid() else len(COLUMNS)

    def headerData(self, section, orientation, role=Qt.ItemDataRole.DisplayRole):  # noqa: N802 - Qt API
        if orientation == Qt.Orientation.Horizontal:
            if role == Qt.ItemDataRole.DisplayRole:
                return COLUMNS[section]
            if role == Qt.ItemDataRole.ToolTipRole:
                return ("MPEG-4 feature point and what it marks", "auto (amber) / edited (blue) / confirmed (green)",
                        "Detector confidence (blank: unknown)", "mm, neutral face; double-click to type",
                        "mm, neutral face; double-click to type", "mm, neutral face; double-click to type")[section]
            if role == Qt.ItemDataRole.TextAlignmentRole and section >= 2:
                return int(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        return None

    def flags(self, index):
        base = Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable
        if index.column() >= 3:
            base |= Qt.ItemFlag.ItemIsEditable
        return base

    def data(self, index, role=Qt.ItemDataRole.DisplayRole):
        if self.model is None or not index.isValid():
            return None
        name = self._names[index.row()]
        col = index.column()
        state = self.model.state(name)
        status = state.status.value
        if role == Qt.ItemDataRole.DisplayRole:
            if col == 0:
                return self.label(name)
            if col == 1:
                return status
            if col == 2:
                return "" if state.confidence is None else f"{state.confidence:.2f}"
            return f"{self._positions[index.row(), col - 3] + 0.0:.1f}".replace("-0.0", "0.0")
        if role == Qt.ItemDataRole.EditRole and col >= 3:
            return float(round(self._positions[index.row(), col - 3], 3))
        if role == Qt.ItemDataRole.DecorationRole and col == 1:
            return self._chips[status]
        if role == Qt.ItemDataRole.ToolTipRole:
            x, y, z = self._positions[index.row()]
            tip = f"<b>{self.label(name)}</b><br>{STATUS_TIPS[status]}<br>x {x:.2f}, y {y:.2f}, z {z:.2f} mm"
            if state.confidence is not None:
                tip += f"<br>detector confidence {state.confidence:.3f}"
                if self.is_low(name):
                    tip += " — <b>low: check where it is</b>"
            partner = self.model.mirror_partner(name)
            if partner:
                tip += f"<br>mirror partner: {partner}"
            return tip
        if role == SORT_ROLE:
            if col == 0:
                return index.row()   # the template's order
            if col == 1:
                return [s.value for s in LandmarkStatus].index(status)
            if col == 2:   # the doubtful first; unknown last
                return float("inf") if state.confidence is None else float(state.confidence)
            return float(self._positions[index.row(), col - 3])
        low = self.is_low(name)
        if role == Qt.ItemDataRole.TextAlignmentRole and col >= 2:
            return int(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        if role == Qt.ItemDataRole.ForegroundRole and col == 1:
            return QBrush(QColor(*picking.STATUS_COLORS[status]).darker(135))
        if role == Qt.ItemDataRole.ForegroundRole and col == 2 and low:
            return QBrush(LOW_FOREGROUND)
        if role == Qt.ItemDataRole.BackgroundRole and col == 2 and low:
            return QBrush(LOW_BACKGROUND)
        return None

    def is_low(self, name: str) -> bool:
        """True for an unchecked landmark the detector was unsure of (confidence < LOW_CONFIDENCE)."""
        state = self.model.state(name) if self.model is not None else None
        return (state is not None and state.confidence is not None and state.confidence < LOW_CONFIDENCE
                and state.status == LandmarkStatus.AUTO)

    def setData(self, index, value, role=Qt.ItemDataRole.EditRole) -> bool:  # noqa: N802 - Qt API
        if self.model is None or role != Qt.ItemDataRole.EditRole or index.column() < 3:
            return False
        try:
            value = float(value)
        except (TypeError, ValueError):
            return False
        if not np.isfinite(value):
            return False
        xyz = self._positions[index.row()].copy()
        xyz[index.column() - 3] = value
        self.edit_position.emit(self._names[index.row()], xyz)
        return True


class LandmarkFilter(QSortFilterProxyModel):
    """What the list shows of a :class:`LandmarkTableModel`: sorted by :data:`SORT_ROLE`, and only
    the low-confidence landmarks while ``low_only``."""

    def __init__(self, source: LandmarkTableModel, parent: QObject | None = None):
        super().__init__(parent)
        self.setSourceModel(source)
        self.setSortRole(SORT_ROLE)
        self.low_only = False

    def set_low_only(self, on: bool) -> None:
        if hasattr(self, "beginFilterChange"):   # Qt 6.10+ (invalidateFilter is deprecated there)
            self.beginFilterChange()
            self.low_only = bool(on)
            self.endFilterChange(QSortFilterProxyModel.Direction.Rows)
        else:
            self.low_only = bool(on)
            self.invalidateFilter()

    def filterAcceptsRow(self, row: int, parent) -> bool:  # noqa: N802 - Qt API
        if not self.low_only:
            return True
        source = self.sourceModel()
        name = source.name_at(row)
        return name is not None and source.is_low(name)
