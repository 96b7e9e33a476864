"""landmark_dock.py
----
The landmark-correction picker (thesis A §3.3, Fig. 3.28): a dock listing the
face's landmarks with their status, plus viewport picking to re-mark wrong
ones by clicking on the surface.

* :class:`LandmarkDock` — the widgets: the list (name and description,
  status chip, detector confidence, x/y/z in mm on the neutral face), Pick /
  Mirror / Names toggles, navigation and confirm buttons, detection and file
  buttons. It only shows state and emits requests; it never edits anything.
* :class:`LandmarkEditor` — the controller: owns the
  :class:`core.landmark_editing.LandmarkEditModel` of the current face, the
  viewport interaction (:mod:`app.picking`), the status-coloured markers, and
  pushes every edit onto the shared undo stack (:mod:`app.undo`).
* :func:`attach_landmark_editor` — installs all of it in a ``MainWindow``.

What a click does (written in the dock's help line and tooltips):

* a click (press and release without moving more than a few pixels) on a
  landmark's marker selects it; dragging always orbits the camera and never
  moves anything;
* with **Pick** on (button or M), a click on the surface moves the selected
  landmark to the exact point under the cursor. Without Pick, Shift+click
  does the same, so ordinary clicks never move a landmark by accident.
  Shift+click also moves when the cursor is over another landmark's marker
  (to place two landmarks close together);
* N / P select the next / previous landmark, C (or Enter in the list or the
  viewport) confirms the selected one and goes to the next, Esc leaves Pick
  mode. Every change is undoable (Edit ▸ Undo).

While the dock is showing (its tab is raised) the editor draws its own
markers (amber = auto, blue = edited, green = confirmed; the selected one
bigger with its description) and hides the scene's plain landmark markers;
when the dock is hidden or another tab is raised, picking is off and the
scene's markers come back.
"""

from __future__ import annotations

import contextlib
import re
import time
import traceback
from pathlib import Path

import numpy as np
from PySide6.QtCore import QAbstractTableModel, QItemSelectionModel, QModelIndex, QObject, QSignalBlocker, Qt, QTimer, Signal
from PySide6.QtGui import QAction, QBrush, QColor, QIcon, QKeySequence, QPainter, QPixmap
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QDockWidget,
    QFileDialog,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QMessageBox,
    QPushButton,
    QTableView,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from app import picking
from app.undo import LandmarkMoveCommand, LandmarkSetCommand
from core.landmark_editing import LandmarkEditModel, LandmarkFileError, LandmarkStatus

__all__ = ["LandmarkDock", "LandmarkEditor", "LandmarkTableModel", "attach_landmark_editor", "registration_available"]

HELP_TEXT = ("Select a landmark (list, N/P, or click its marker). Turn on <b>Pick</b> (M) and click the "
             "surface to move it there — or Shift+click without Pick. Dragging always turns the view. "
             "<b>C</b>/Enter confirms and goes to the next. Ctrl+Z undoes.")
STATUS_TIPS = {
    "auto": "auto: placed by the detector or loaded from a file; nobody has checked it yet",
    "edited": "edited: moved by you (kept fixed when matching is re-run)",
    "confirmed": "confirmed: checked by you (kept fixed when matching is re-run)",
}
FILE_FILTER = "Landmark files (*.json *.csv);;Mimica landmarks JSON (*.json);;CSV: name,x,y,z,status,confidence (*.csv)"
NEEDS_REGISTRATION = "needs core.registration (the detection pipeline is not installed yet)"
#: Markers within this many logical pixels of the cursor can be clicked / hovered.
MARKER_HIT_PX = 9
COLUMNS = ("Landmark", "Status", "Conf.", "x", "y", "z")


def registration_available() -> bool:
    """True when ``core.registration.pipeline`` (detect_landmarks, register_scan) imports."""
    try:
        import core.registration.pipeline  # noqa: F401
    except Exception:  # noqa: BLE001 - any failure means "not available"
        return False
    return True


def _descriptions() -> dict[str, str]:
    try:
        import resources

        return {r["fp"]: r["description"] for r in resources.get_table("mpeg4/feature_points.csv")}
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
            partner = self.model.mirror_partner(name)
            if partner:
                tip += f"<br>mirror partner: {partner}"
            return tip
        if role == Qt.ItemDataRole.TextAlignmentRole and col >= 2:
            return int(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        if role == Qt.ItemDataRole.ForegroundRole and col == 1:
            return QBrush(QColor(*picking.STATUS_COLORS[status]).darker(135))
        return None

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


# ------------------------------------------------------------------ the dock
class LandmarkDock(QDockWidget):
    """The landmark list and its buttons (see the module docstring). State comes from the editor.

    Signals
    -------
    detect_requested(dict)
        "Detect landmarks" (empty dict) or "Re-run matching keeping my edits fixed"
        (name -> SurfacePoint of the edited/confirmed landmarks): run
        ``core.registration.pipeline.detect_landmarks(scan, fixed=...)`` and give the result to
        :meth:`LandmarkEditor.apply_detection`.
    build_requested()
        "Build correspondence": run ``register_scan(...)`` with the current landmarks.
    """

    detect_requested = Signal(dict)
    build_requested = Signal()

    def __init__(self, parent: QWidget | None = None):
        super().__init__("Landmarks", parent)
        self.setObjectName("landmarkDock")
        self.setAllowedAreas(Qt.DockWidgetArea.LeftDockWidgetArea | Qt.DockWidgetArea.RightDockWidgetArea)
        root = QWidget(self)
        root.setObjectName("landmarkDockContents")
        outer = QVBoxLayout(root)
        outer.setContentsMargins(6, 6, 6, 6)
        outer.setSpacing(6)

        self.help_label = QLabel(HELP_TEXT, root)
        self.help_label.setObjectName("landmarkHelp")
        self.help_label.setWordWrap(True)
        self.help_label.setStyleSheet("QLabel { color: #5a5f66; }")
        outer.addWidget(self.help_label)

        self.message_label = QLabel(root)
        self.message_label.setObjectName("landmarkMessage")
        self.message_label.setWordWrap(True)
        self.message_label.setStyleSheet("QLabel { color: #e0a030; }")
        self.message_label.hide()
        outer.addWidget(self.message_label)

        # Mode toggles
        toggles = QHBoxLayout()
        toggles.setSpacing(10)
        self.pick_button = QToolButton(root)
        self.pick_button.setObjectName("landmarkPick")
        self.pick_button.setText("Pick on surface")
        self.pick_button.setCheckable(True)
        self.pick_button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextOnly)
        self.pick_button.setToolTip(
            "<b>Pick mode (M)</b><br>On: a click on the face moves the selected landmark to the exact point "
            "under the cursor. Off: clicks only select markers; Shift+click still moves.<br>"
            "Dragging always turns the view and never moves a landmark. Esc leaves Pick mode.")
        self.pick_button.setStyleSheet(
            "QToolButton { padding: 3px 10px; } QToolButton:checked { background: #2f6fd0; color: white; "
            "border: 1px solid #1d4f9e; border-radius: 3px; }")
        self.mirror_check = QCheckBox("Mirror edits", root)
        self.mirror_check.setObjectName("landmarkMirror")
        self.mirror_check.setToolTip(
            "Moving a left or right landmark also moves its mirror partner (e.g. 8.3 ↔ 8.4) to the mirror "
            "image across the face's mid-plane, projected onto the surface. One undo step undoes both.")
        self.names_check = QCheckBox("Names", root)
        self.names_check.setObjectName("landmarkNames")
        self.names_check.setChecked(True)
        self.names_check.setToolTip("Show every landmark's name in the view (the selected one always is)")
        toggles.addWidget(self.pick_button)
        toggles.addWidget(self.mirror_check)
        toggles.addWidget(self.names_check)
        toggles.addStretch(1)
        outer.addLayout(toggles)

        # The list
        self.table_model = LandmarkTableModel(self)
        self.table = QTableView(root)
        self.table.setObjectName("landmarkTable")
        self.table.setModel(self.table_model)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.DoubleClicked
                                   | QAbstractItemView.EditTrigger.EditKeyPressed)
        self.table.setAlternatingRowColors(True)
        self.table.setShowGrid(False)
        self.table.setWordWrap(False)
        self.table.setTextElideMode(Qt.TextElideMode.ElideRight)
        self.table.verticalHeader().hide()
        self.table.verticalHeader().setDefaultSectionSize(self.table.fontMetrics().height() + 6)
        header = self.table.horizontalHeader()
        header.setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        for col in range(1, len(COLUMNS)):
            header.setSectionResizeMode(col, QHeaderView.ResizeMode.Fixed)
        metrics = self.table.fontMetrics()
        header.resizeSection(1, metrics.horizontalAdvance("confirmed") + 34)
        header.resizeSection(2, metrics.horizontalAdvance("Conf.") + 14)
        for col in (3, 4, 5):
            header.resizeSection(col, metrics.horizontalAdvance("-188.8") + 14)
        header.setHighlightSections(False)
        self.table.setMinimumHeight(220)
        outer.addWidget(self.table, 1)

        # Navigation and confirmation
        nav = QHBoxLayout()
        nav.setSpacing(4)
        self.prev_button = QPushButton("◀ Prev", root)
        self.prev_button.setObjectName("landmarkPrev")
        self.prev_button.setToolTip("Select the previous landmark (P)")
        self.next_button = QPushButton("Next ▶", root)
        self.next_button.setObjectName("landmarkNext")
        self.next_button.setToolTip("Select the next landmark (N)")
        self.confirm_button = QPushButton("Confirm", root)
        self.confirm_button.setObjectName("landmarkConfirm")
        self.confirm_button.setToolTip("Mark the selected landmark as checked and go to the next one (C or Enter)")
        self.confirm_all_button = QPushButton("Confirm all", root)
        self.confirm_all_button.setObjectName("landmarkConfirmAll")
        self.confirm_all_button.setToolTip("Mark every landmark as checked (undoable)")
        for b in (self.prev_button, self.next_button, self.confirm_button, self.confirm_all_button):
            b.setFocusPolicy(Qt.FocusPolicy.NoFocus)  # keys keep going to the list / viewport
            nav.addWidget(b)
        nav.addStretch(1)
        outer.addLayout(nav)

        self.summary_label = QLabel(root)
        self.summary_label.setObjectName("landmarkSummary")
        self.summary_label.setTextFormat(Qt.TextFormat.RichText)
        outer.addWidget(self.summary_label)

        # Matching
        box = QGroupBox("Matching", root)
        grid = QGridLayout(box)
        grid.setContentsMargins(6, 4, 6, 6)
        grid.setSpacing(4)
        self.detect_button = QPushButton("Detect landmarks", box)
        self.detect_button.setObjectName("landmarkDetect")
        self.rerun_button = QPushButton("Re-run, keep my edits", box)
        self.rerun_button.setObjectName("landmarkRerun")
        self.build_button = QPushButton("Build correspondence", box)
        self.build_button.setObjectName("landmarkBuild")
        grid.addWidget(self.detect_button, 0, 0)
        grid.addWidget(self.rerun_button, 0, 1)
        grid.addWidget(self.build_button, 1, 0, 1, 2)
        outer.addWidget(box)

        files = QHBoxLayout()
        self.load_button = QPushButton("Load…", root)
        self.load_button.setObjectName("landmarkLoad")
        self.load_button.setToolTip("Load landmarks from a Mimica JSON or a CSV file (undoable)")
        self.save_button = QPushButton("Save…", root)
        self.save_button.setObjectName("landmarkSave")
        self.save_button.setToolTip("Save the landmarks with their status as JSON or CSV (name,x,y,z,status,confidence)")
        files.addWidget(self.load_button)
        files.addWidget(self.save_button)
        files.addStretch(1)
        outer.addLayout(files)

        self.setWidget(root)
        self._fixed_count = 0
        self.set_registration_available(registration_available())
        self.detect_button.clicked.connect(lambda: self.detect_requested.emit({}))
        self.build_button.clicked.connect(self.build_requested)

    # ------------------------------------------------------------ state shown
    def set_registration_available(self, available: bool) -> None:
        """Enable the matching buttons, or disable them with the reason as tooltip."""
        self._registration = bool(available)
        tips = {
            self.detect_button: "Find the landmarks automatically (replaces every auto landmark)",
            self.rerun_button: "Run the matching again, keeping the landmarks you edited or confirmed fixed",
            self.build_button: "Build the dense correspondence (subdivision + projection) from these landmarks",
        }
        for button, tip in tips.items():
            button.setToolTip(tip if available else NEEDS_REGISTRATION)
        self._update_buttons()

    def set_counts(self, counts: dict, n_total: int, has_selection: bool, *, has_face: bool = True) -> None:
        auto, edited, confirmed = (counts.get(s, 0) for s in LandmarkStatus)
        self._fixed_count = edited + confirmed

        def chip(status: str, n: int) -> str:
            r, g, b = picking.STATUS_COLORS[status]
            return f"<span style='color: rgb({r},{g},{b});'>●</span> {n} {status}"

        if n_total:
            self.summary_label.setText(f"{n_total} landmarks &nbsp; {chip('auto', auto)} &nbsp; "
                                       f"{chip('edited', edited)} &nbsp; {chip('confirmed', confirmed)}")
        elif has_face:
            self.summary_label.setText("This face has no landmarks yet: detect them or load a file.")
        else:
            self.summary_label.setText("No face loaded yet.")
        for b in (self.prev_button, self.next_button, self.confirm_all_button, self.save_button):
            b.setEnabled(n_total > 0)
        self.load_button.setEnabled(has_face)
        self.confirm_button.setEnabled(has_selection)
        self._update_buttons()

    def _update_buttons(self) -> None:
        available = getattr(self, "_registration", False)
        self.detect_button.setEnabled(available)
        self.build_button.setEnabled(available)
        self.rerun_button.setEnabled(available and self._fixed_count > 0)

    def show_message(self, text: str) -> None:
        self.message_label.setText(text)
        self.message_label.setVisible(bool(text))


# ------------------------------------------------------------------ the controller
class LandmarkEditor(QObject):
    """Landmark correction on a plotter: model, markers, picking, undo (see the module docstring).

    Parameters
    ----------
    plotter : pyvistaqt.QtInteractor
    dock : LandmarkDock
    stack : QUndoStack
    status_callback : callable(str, int ms) or None
        Where short messages go (the window's status bar).
    """

    #: The landmark set changed (any edit, undo, load): the rig/registration may want to know.
    landmarks_changed = Signal()

    def __init__(self, plotter, dock: LandmarkDock, stack, *, status_callback=None,
                 parent: QObject | None = None):
        super().__init__(parent)
        self.plotter = plotter
        self.dock = dock
        self.stack = stack
        self._status = status_callback or (lambda _text, _ms=0: None)
        self.model: LandmarkEditModel | None = None
        self.face = None
        self.face_actor = None
        self.picker: picking.SurfacePicker | None = None
        self.markers = picking.LandmarkMarkers(plotter)
        self._hovered: str | None = None
        self._active = True
        self._marker_mtime = -1
        self._last_dir = str(Path.home())
        self.last_pick_ms: float | None = None
        self._dpr = plotter.devicePixelRatioF() if hasattr(plotter, "devicePixelRatioF") else 1.0
        self.mouse = picking.ViewportMouse(plotter, self._on_click, self._on_hover, self._on_leave)
        self._render_observer = plotter.renderer.AddObserver("StartEvent", self._before_render)
        self._render_timer = QTimer(self)
        self._render_timer.setSingleShot(True)
        self._render_timer.setInterval(0)
        self._render_timer.timeout.connect(self._render_now)

        table = dock.table
        table.selectionModel().currentRowChanged.connect(self._row_changed)
        dock.table_model.edit_position.connect(self._typed_position)
        dock.pick_button.toggled.connect(self._pick_toggled)
        dock.names_check.toggled.connect(self._names_toggled)
        dock.prev_button.clicked.connect(lambda: self.select_next(-1))
        dock.next_button.clicked.connect(lambda: self.select_next(1))
        dock.confirm_button.clicked.connect(lambda: self.confirm_selected(advance=True))
        dock.confirm_all_button.clicked.connect(self.confirm_all)
        dock.rerun_button.clicked.connect(self._rerun)
        dock.load_button.clicked.connect(self.load_dialog)
        dock.save_button.clicked.connect(self.save_dialog)
        self._create_actions()

    # ------------------------------------------------------------ actions
    def _create_actions(self) -> None:
        def action(text, slot, keys, tip):
            act = QAction(text, self)
            act.setShortcuts([QKeySequence(k) for k in keys])
            act.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
            act.setStatusTip(tip)
            act.triggered.connect(slot)
            return act

        self.next_action = action("&Next landmark", lambda: self.select_next(1), ["N"], "Select the next landmark")
        self.prev_action = action("&Previous landmark", lambda: self.select_next(-1), ["P"],
                                  "Select the previous landmark")
        self.confirm_action = action("&Confirm landmark", lambda: self.confirm_selected(advance=True), ["C"],
                                     "Mark the selected landmark as checked and go to the next")
        self.pick_action = action("Pick on &surface", self.dock.pick_button.toggle, ["M"],
                                  "Clicks on the face move the selected landmark")
        self.window_actions = [self.next_action, self.prev_action, self.confirm_action, self.pick_action]
        # Enter / Esc only where they cannot clash with dialogs and spin boxes: the list and the viewport.
        self.local_actions = []
        for widget in (self.dock.table, self.plotter):
            enter = QAction(self)
            enter.setShortcuts([QKeySequence(Qt.Key.Key_Return), QKeySequence(Qt.Key.Key_Enter)])
            enter.setShortcutContext(Qt.ShortcutContext.WidgetShortcut)
            enter.triggered.connect(lambda: self.confirm_selected(advance=True))
            escape = QAction(self)
            escape.setShortcut(QKeySequence(Qt.Key.Key_Escape))
            escape.setShortcutContext(Qt.ShortcutContext.WidgetShortcut)
            escape.triggered.connect(lambda: self.dock.pick_button.setChecked(False))
            widget.addAction(enter)
            widget.addAction(escape)
            self.local_actions += [enter, escape]

    # ------------------------------------------------------------ face
    def set_face(self, face, face_actor=None) -> None:
        """Edit ``face``'s landmarks; ``face_actor`` (app.scene.FaceActor: ``.actor``, ``.mesh``) is what
        the user sees and clicks. Clears the undo stack (its commands belong to the old face)."""
        if self.model is not None:
            with contextlib.suppress(ValueError, RuntimeError, TypeError):
                self.model.changed.disconnect(self._model_changed)
                self.model.selection_changed.disconnect(self._selection_changed)
        self.stack.clear()
        self.face, self.face_actor = face, face_actor
        self._hovered = None
        self.model = LandmarkEditModel(face) if face is not None else None
        if self.model is not None:
            self.model.changed.connect(self._model_changed)
            self.model.selection_changed.connect(self._selection_changed)
        self.picker = None
        if face_actor is not None and face is not None:
            self.picker = picking.SurfacePicker(face_actor.actor, face_actor.mesh, face.triangles)
        self.dock.table_model.set_model(self.model)
        self.markers.set_names(self.model.names if self.model is not None else [], face_height_mm=self._face_height())
        self._marker_mtime = -1
        self._sync_all()

    # ------------------------------------------------------------ activity
    @property
    def active(self) -> bool:
        """True while the editor draws its markers and handles clicks (the dock is showing)."""
        return self._active

    def set_active(self, active: bool) -> None:
        self._active = bool(active)
        self.mouse.enabled = self._active
        for act in self.window_actions:
            act.setEnabled(self._active)
        self.markers.set_visible(self._active)
        if not self._active:
            self._set_hovered(None)
            self.plotter.unsetCursor()
        else:
            self._update_cursor()
        self._update_markers(force=True)
        self.request_render()

    # ------------------------------------------------------------ selection
    def select(self, name: str | None) -> None:
        if self.model is not None:
            self.model.select(name)

    def select_next(self, step: int = 1) -> None:
        if self.model is not None and len(self.model):
            self.model.select_next(step)

    def _row_changed(self, current: QModelIndex, _previous: QModelIndex) -> None:
        name = self.dock.table_model.name_at(current.row()) if current.isValid() else None
        if name is not None:
            self.select(name)

    def _selection_changed(self, name) -> None:
        table = self.dock.table
        row = self.dock.table_model.row_of(name)
        with QSignalBlocker(table.selectionModel()):
            if row < 0:
                table.selectionModel().clearSelection()
            else:
                index = self.dock.table_model.index(row, 0)
                table.selectionModel().setCurrentIndex(
                    index, QItemSelectionModel.SelectionFlag.ClearAndSelect | QItemSelectionModel.SelectionFlag.Rows)
                table.scrollTo(index, QAbstractItemView.ScrollHint.EnsureVisible)
        table.viewport().update()
        self._update_counts()
        self._update_markers(force=True)
        self.request_render()
        if name is not None:
            self._status(f"{self.dock.table_model.label(name)} ({self.model.status(name).value})", 4000)

    # ------------------------------------------------------------ edits (all undoable)
    def move(self, name: str, point, *, mirror: bool | None = None) -> None:
        """Move ``name`` to SurfacePoint ``point`` as one undo step (with its mirror partner when
        ``mirror``, default: the dock's "Mirror edits")."""
        model = self.model
        if model is None:
            return
        mirror = self.dock.mirror_check.isChecked() if mirror is None else mirror
        partner = model.mirror_partner(name) if mirror else None
        if partner is not None and partner in model:
            self.stack.beginMacro(f"move landmarks {name} and {partner} (mirrored)")
            try:
                self.stack.push(LandmarkMoveCommand(model, name, point))
                suggestion = model.suggest_mirror(name)
                self.stack.push(LandmarkMoveCommand(model, partner, suggestion))
            finally:
                self.stack.endMacro()
        else:
            self.stack.push(LandmarkMoveCommand(model, name, point))

    def confirm_selected(self, *, advance: bool = True) -> None:
        """Confirm the selected landmark (undoable) and select the next one."""
        model = self.model
        if model is None or model.selected is None:
            if model is not None and len(model):
                model.select(model.names[0])
            return
        name = model.selected
        if model.status(name) is not LandmarkStatus.CONFIRMED:
            before = model.snapshot()
            model.confirm(name)
            self.stack.push(LandmarkSetCommand.from_snapshots(model, f"confirm landmark {name}", before,
                                                              model.snapshot(), applied=True))
        if advance:
            model.select_next(1)

    def confirm_all(self) -> None:
        model = self.model
        if model is None:
            return
        before = model.snapshot()
        if model.confirm_all():
            self.stack.push(LandmarkSetCommand.from_snapshots(model, "confirm all landmarks", before,
                                                              model.snapshot(), applied=True))

    def apply_detection(self, points: dict, confidence: dict | None = None) -> list[str]:
        """Put a detector's result in (auto landmarks replaced, yours kept) as one undo step."""
        model = self.model
        if model is None:
            return []
        before = model.snapshot()
        changed = model.apply_detection(points, confidence)
        if changed:
            self.stack.push(LandmarkSetCommand.from_snapshots(model, "detect landmarks", before, model.snapshot(),
                                                              applied=True))
        return changed

    def _typed_position(self, name: str, xyz) -> None:
        if self.model is None or self.face is None:
            return
        _, tri, bary = self.face.closest_surface_points(np.asarray(xyz, float)[None])
        from core.face import SurfacePoint

        point = SurfacePoint(int(tri[0]), tuple(bary[0]))
        self.model.select(name)
        self.move(name, point)
        placed = self.model.position(name)
        if np.linalg.norm(placed - np.asarray(xyz, float)) > 0.05:
            self._status(f"{name} placed at the closest surface point ({placed[0]:.1f}, {placed[1]:.1f}, "
                         f"{placed[2]:.1f}) mm", 5000)

    def _rerun(self) -> None:
        if self.model is not None:
            self.dock.detect_requested.emit(self.model.fixed_points())

    # ------------------------------------------------------------ files
    def save_file(self, path) -> bool:
        """Save as JSON or CSV (by suffix); errors go to a message box. Returns success."""
        if self.model is None:
            return False
        try:
            self.model.save_file(path)
        except LandmarkFileError as exc:
            self._error("Could not save the landmarks", str(exc))
            return False
        self._status(f"Saved {len(self.model)} landmarks to {path}", 5000)
        return True

    def load_file(self, path) -> bool:
        """Load a JSON or CSV file as one undo step; errors go to a message box. Returns success."""
        model = self.model
        if model is None:
            return False
        notes: list[str] = []
        try:
            states = model.read_file(path, notes=notes)
        except LandmarkFileError as exc:
            self._error(f"Could not load {Path(path).name}", str(exc))
            return False
        before = model.snapshot()
        self.stack.push(LandmarkSetCommand(model, f"load landmarks from {Path(path).name}",
                                           {n: before[n] for n in states if n in before}, states))
        self._status(f"Loaded {len(states)} landmarks from {Path(path).name}", 5000)
        if notes:
            self.dock.show_message("\n".join(notes[:6]) + (f"\n… and {len(notes) - 6} more" if len(notes) > 6 else ""))
        else:
            self.dock.show_message("")
        return True

    def save_dialog(self) -> None:
        if self.model is None:
            return
        name = getattr(getattr(self.face, "metadata", None), "name", "face") or "face"
        default = str(Path(self._last_dir) / f"{name}-landmarks.json")
        path, chosen = QFileDialog.getSaveFileName(self.dock, "Save landmarks", default, FILE_FILTER)
        if path:
            if Path(path).suffix.lower() not in (".json", ".csv"):
                path += ".csv" if "(*.csv)" in chosen else ".json"
            self._last_dir = str(Path(path).parent)
            self.save_file(path)

    def load_dialog(self) -> None:
        if self.model is None:
            return
        path, _ = QFileDialog.getOpenFileName(self.dock, "Load landmarks", self._last_dir, FILE_FILTER)
        if path:
            self._last_dir = str(Path(path).parent)
            self.load_file(path)

    def _face_height(self) -> float:
        """mm the face spans vertically, for sizing labels: from its landmarks when it has several
        (a bust or a whole head is much taller than its face), else from the mesh."""
        face = self.face
        if face is None or not face.n_vertices:
            return 200.0
        if len(face.landmarks) >= 8:
            # The landmarks span from the hairline (11.1) to the chin (2.1): 0.89 of the default face.
            return float(np.ptp(face.landmark_positions()[:, 1])) / 0.89 or 200.0
        return float(np.ptp(face.vertices[:, 1])) or 200.0

    def _error(self, title: str, message: str) -> None:
        self._status(message.splitlines()[0][:140], 8000)
        QMessageBox.warning(self.dock, title, message)

    # ------------------------------------------------------------ model -> views
    def _model_changed(self, name: str) -> None:
        self.dock.table_model.refresh(name)
        if not name and self.model is not None:
            self.markers.set_names(self.model.names, face_height_mm=self._face_height())
            self._selection_changed(self.model.selected)  # rows may have moved
        self._update_counts()
        self._update_markers(force=True)
        self.request_render()
        self.landmarks_changed.emit()

    def _sync_all(self) -> None:
        self._selection_changed(self.model.selected if self.model is not None else None)

    def _update_counts(self) -> None:
        model = self.model
        if model is None:
            self.dock.set_counts({}, 0, False, has_face=False)
            return
        self.dock.set_counts(model.counts(), len(model), model.selected is not None)

    # ------------------------------------------------------------ markers
    def _displayed_vertices(self) -> np.ndarray | None:
        if self.face_actor is not None:
            return np.asarray(self.face_actor.mesh.points)
        return None if self.face is None else self.face.vertices

    def _landmark_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (k, 3), unit normals (k, 3)) of the landmarks on the displayed surface."""
        tri, bary = self.model.triangles_and_barycentrics()
        corners = self._displayed_vertices()[self.face.triangles[tri]]  # (k, 3, 3)
        positions = np.einsum("kj,kjd->kd", bary, corners)
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        return positions, np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)

    def _update_markers(self, force: bool = False) -> None:
        model = self.model
        if model is None or not len(model) or self.face is None:
            self.markers.update(np.zeros((0, 3)), np.zeros((0, 3)), [])
            return
        if self.face_actor is not None:
            mtime = self.face_actor.mesh.GetMTime()
            if not force and mtime == self._marker_mtime:
                return
            self._marker_mtime = mtime
        positions, normals = self._landmark_geometry()
        names = model.names
        selected = model.selected
        sel = names.index(selected) if selected in names else None
        hov = names.index(self._hovered) if self._hovered in names else None
        label = self.dock.table_model.label
        self.markers.update(positions, normals, [s.value for s in model.statuses()], sel, hov,
                            selected_text=label(selected) if sel is not None else "",
                            hovered_text=label(self._hovered) if hov is not None else "")

    def _before_render(self, _obj=None, _event=None) -> None:
        # The window moves the face's points in place before it renders (animation): follow them
        # here, inside the same render, instead of rendering a second time.
        if self._active and self.model is not None:
            self._update_markers()

    def request_render(self) -> None:
        if not self._render_timer.isActive():
            self._render_timer.start()

    def _render_now(self) -> None:
        plotter = self.plotter
        if plotter.isVisible() and not getattr(plotter, "_closed", False):
            plotter.render()

    # ------------------------------------------------------------ viewport interaction
    def marker_at(self, x: float, y: float, *, exclude: str | None = None) -> str | None:
        """The landmark whose marker is under display point (x, y) (device pixels), facing the camera."""
        model = self.model
        if model is None or not len(model) or self.face is None:
            return None
        positions, normals = self._landmark_geometry()
        markers = positions + picking.MARKER_OFFSET_MM * normals
        renderer = self.plotter.renderer
        screen = picking.world_to_display(renderer, markers)
        camera = np.array(renderer.GetActiveCamera().GetPosition())
        facing = np.einsum("kd,kd->k", normals, camera - positions) > 0
        distance = np.hypot(screen[:, 0] - x, screen[:, 1] - y)
        distance[~facing] = np.inf
        if exclude in model:
            distance[model.index(exclude)] = np.inf
        best = int(np.argmin(distance))
        return model.names[best] if distance[best] <= MARKER_HIT_PX * self._dpr else None

    def pick_surface(self, x: float, y: float) -> picking.SurfaceHit | None:
        """The face point under display point (x, y), or None."""
        if self.picker is None:
            return None
        start = time.perf_counter()
        hit = self.picker.pick(self.plotter.renderer, x, y)
        self.last_pick_ms = (time.perf_counter() - start) * 1e3
        return hit

    def _on_click(self, x: float, y: float, shift: bool, _ctrl: bool) -> None:
        model = self.model
        if not self._active or model is None:
            return
        try:
            pick_mode = self.dock.pick_button.isChecked()
            # In Pick mode a click on the selected landmark's own marker moves it (fine nudges).
            marker = None if shift else self.marker_at(x, y, exclude=model.selected if pick_mode else None)
            if marker is not None:
                model.select(marker)
                return
            if not (pick_mode or shift):
                if model.selected is not None and self.pick_surface(x, y) is not None:
                    self._status(f"To move {model.selected} here, turn on Pick (M) or Shift+click.", 4000)
                return
            if model.selected is None:
                self._status("Select a landmark first (list, N/P or click its marker), then click the surface.",
                             5000)
                return
            hit = self.pick_surface(x, y)
            if hit is None:
                self._status("Missed the face: click on the surface.", 3000)
                return
            self.move(model.selected, hit.surface_point())
        except Exception:  # noqa: BLE001 - a VTK callback must never raise into C++
            traceback.print_exc()

    def _on_hover(self, x: float, y: float) -> None:
        if not self._active or self.model is None:
            return
        try:
            pick_mode = self.dock.pick_button.isChecked()
            name = self.marker_at(x, y, exclude=self.model.selected if pick_mode else None)
            self._set_hovered(name)
        except Exception:  # noqa: BLE001
            traceback.print_exc()

    def _on_leave(self) -> None:
        self._set_hovered(None)

    def _set_hovered(self, name: str | None) -> None:
        if name == self._hovered:
            return
        self._hovered = name
        self._update_cursor()
        self._update_markers(force=True)
        self.request_render()
        if name is not None and self.model is not None:
            self._status(f"{self.dock.table_model.label(name)} ({self.model.status(name).value}) — click to select",
                         3000)

    def _update_cursor(self) -> None:
        if not self._active:
            return
        if self._hovered is not None:
            self.plotter.setCursor(Qt.CursorShape.PointingHandCursor)
        elif self.dock.pick_button.isChecked():
            self.plotter.setCursor(Qt.CursorShape.CrossCursor)
        else:
            self.plotter.unsetCursor()

    def _pick_toggled(self, on: bool) -> None:
        self._update_cursor()
        if on and self.model is not None and self.model.selected is None and len(self.model):
            self.model.select(self.model.names[0])
        self._status("Pick mode on: click the face to move the selected landmark (Esc to leave)." if on
                     else "Pick mode off: clicks select markers; Shift+click moves.", 4000)

    def _names_toggled(self, on: bool) -> None:
        self.markers.set_labels_visible(on)
        self.request_render()

    # ------------------------------------------------------------ teardown
    def close(self) -> None:
        """Remove observers and actors (the plotter stays)."""
        self._render_timer.stop()
        self.mouse.remove()
        with contextlib.suppress(Exception):
            self.plotter.renderer.RemoveObserver(self._render_observer)
        with contextlib.suppress(Exception):
            self.markers.remove()


# ------------------------------------------------------------------ window integration
def attach_landmark_editor(window) -> LandmarkEditor:
    """Add the landmark dock and picking to a :class:`app.main_window.MainWindow`.

    * the dock goes to the right dock area, tabified with the FAP dock (Landmarks tab);
    * landmark edits go on the document's one undo stack (``window.document.undo_stack``);
    * ``window.face_changed`` re-targets the editor at the new face;
    * the editor is active (markers drawn, clicks handled) while the dock is showing; the scene's
      own landmark markers are hidden meanwhile.

    Returns the editor (also stored as ``window.landmark_editor``; the dock as ``window.landmark_dock``).
    """
    stack = window.document.undo_stack

    dock = LandmarkDock(window)
    window.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, dock)
    fap_dock = getattr(window, "fap_dock", None)
    if fap_dock is not None:
        window.tabifyDockWidget(fap_dock, dock)

    def status(text: str, ms: int = 0) -> None:
        window.statusBar().showMessage(text, ms)

    editor = LandmarkEditor(window.plotter, dock, stack, status_callback=status, parent=window)
    for act in editor.window_actions:
        window.addAction(act)
    window.landmark_editor = editor
    window.landmark_dock = dock

    toggle = dock.toggleViewAction()
    toggle.setText("&Landmark picker")
    toggle.setStatusTip("Show or hide the landmark-correction dock")
    toggle.setShortcut(QKeySequence("Ctrl+Shift+L"))
    toggle.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
    window.addAction(toggle)
    view_menu = getattr(window, "view_menu", None)
    if view_menu is not None:
        view_menu.addAction(toggle)
        landmark_menu = view_menu.addMenu("Landmark &editing")
        for act in editor.window_actions:
            landmark_menu.addAction(act)
    window.landmark_dock_action = toggle

    def hide_scene_landmarks() -> None:
        actor = getattr(window, "face_actor", None)
        if actor is not None and editor.active and actor.landmarks_visible:
            actor.set_landmarks_visible(False)

    def show_scene_landmarks() -> None:
        actor = getattr(window, "face_actor", None)
        action = getattr(window, "landmarks_action", None)
        if actor is not None:
            actor.set_landmarks_visible(action is not None and action.isChecked())
            # The scene's markers were placed before the edits: re-place them from the face.
            actor.update_vertices(np.array(actor.mesh.points))

    def on_visibility(visible: bool) -> None:
        editor.set_active(visible)
        if visible:
            hide_scene_landmarks()
        else:
            show_scene_landmarks()
        editor.request_render()

    def on_face(face) -> None:
        editor.set_face(face, getattr(window, "face_actor", None))
        hide_scene_landmarks()
        if getattr(window, "rig", None) is None and face is not None:
            dock.raise_()  # nothing to animate: correcting landmarks is what this face needs

    dock.visibilityChanged.connect(on_visibility)
    window.face_changed.connect(on_face)
    landmarks_action = getattr(window, "landmarks_action", None)
    if landmarks_action is not None:
        landmarks_action.toggled.connect(lambda _on: hide_scene_landmarks())
    if getattr(window, "face", None) is not None:
        editor.set_face(window.face, getattr(window, "face_actor", None))
    editor.set_active(False)

    def initial_tab() -> None:
        # After the layout exists (a tab raised earlier is ignored): FAPs for an animatable face,
        # the landmarks for a face that cannot be animated yet.
        no_rig = getattr(window, "face", None) is not None and getattr(window, "rig", None) is None
        (dock if no_rig or fap_dock is None else fap_dock).raise_()
        on_visibility(_dock_showing(dock))

    QTimer.singleShot(0, window, initial_tab)
    return editor


def _dock_showing(dock: QDockWidget) -> bool:
    """True when the dock is on screen (not closed, not behind another tab)."""
    return dock.isVisible() and not dock.visibleRegion().isEmpty()
