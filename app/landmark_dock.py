"""landmark_dock.py
----
The landmark-correction picker (thesis A §3.3, Fig. 3.28): a dock listing the
face's landmarks with their status, plus viewport picking to re-mark wrong
ones by clicking on the surface.

* :class:`LandmarkDock` (here) — the widgets: the list (name and description,
  status chip, detector confidence, x/y/z in mm on the neutral face), Pick /
  Mirror / Names toggles, navigation and confirm buttons, detection and file
  buttons. It only shows state and emits requests; it never edits anything.
  Built by the main window with the document and the window
  (``LandmarkDock(document, window)``), it creates its editor and takes its
  place in the window: right dock area (a tab beside the FAP dock), View ▸
  Landmark picker and View ▸ Landmark editing.
* :class:`app.landmark_editor.LandmarkEditor` (``dock.editor``) — the
  controller over the document's landmark model
  (:class:`core.landmark_editing.LandmarkEditModel`, ``document.landmarks``):
  the viewport interaction (:mod:`app.picking`), the status-coloured markers,
  and every edit pushed onto the document's undo stack (:mod:`app.undo`).
* :class:`app.landmark_table.LandmarkTableModel` — the list's model.

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

import numpy as np
from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtGui import QKeySequence
from PySide6.QtWidgets import (
    QAbstractItemView, QCheckBox, QDockWidget, QGridLayout, QGroupBox, QHBoxLayout, QHeaderView, QLabel,
    QPushButton, QTableView, QToolButton, QVBoxLayout, QWidget)

from app import picking
from app.landmark_editor import LandmarkEditor
from app.landmark_table import COLUMNS, LandmarkFilter, LandmarkTableModel
from core.landmark_editing import LOW_CONFIDENCE, LandmarkStatus

__all__ = ["LandmarkDock", "LandmarkEditor", "LandmarkTableModel", "registration_available"]

HELP_TEXT = ("Select a landmark (list, N/P, or click its marker). Turn on <b>Pick</b> (M) and click the "
             "surface to move it there — or Shift+click without Pick. Dragging always turns the view. "
             "<b>C</b>/Enter confirms and goes to the next. Ctrl+Z undoes.")
NEEDS_REGISTRATION = "needs core.registration (the detection pipeline is not installed yet)"


def registration_available() -> bool:
    """True when ``core.registration.pipeline`` (detect_landmarks, register_scan) is installed.

    Found, not imported: importing the pipeline (and the scipy modules it needs) costs ~0.3 s of the
    window's start-up; it is imported when detection or registration first runs."""
    import importlib.util

    try:
        return importlib.util.find_spec("core.registration.pipeline") is not None
    except (ImportError, ValueError):
        return False


# ------------------------------------------------------------------ the dock
class LandmarkDock(QDockWidget):
    """The landmark list and its buttons (see the module docstring). State comes from the editor.

    Parameters
    ----------
    document : app.document.Document
    window : app.main_window.MainWindow
        Gives the viewport (plotter, scheduler, face actor), the status bar and the menus.

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

    def __init__(self, document, window):
        super().__init__("Landmarks", window)
        self.document = document
        self.main_window = window
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
        self.low_only_check = QCheckBox("Low confidence only", root)
        self.low_only_check.setObjectName("landmarkLowOnly")
        self.low_only_check.setToolTip(
            "List only the unchecked landmarks the detector was unsure of (confidence below "
            f"{LOW_CONFIDENCE:g}, highlighted): the ones worth checking. Click a column header to sort.")
        toggles.addWidget(self.pick_button)
        toggles.addWidget(self.mirror_check)
        toggles.addWidget(self.names_check)
        toggles.addWidget(self.low_only_check)
        toggles.addStretch(1)
        outer.addLayout(toggles)

        # The list
        self.table_model = LandmarkTableModel(self)
        self.table_filter = LandmarkFilter(self.table_model, self)
        self.low_only_check.toggled.connect(self.table_filter.set_low_only)
        self.table = QTableView(root)
        self.table.setObjectName("landmarkTable")
        self.table.setModel(self.table_filter)
        self.table.setSortingEnabled(True)
        self.table.sortByColumn(0, Qt.SortOrder.AscendingOrder)   # the template's order
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

        self.editor = LandmarkEditor(document, self, window.plotter, viewport=window.viewport, parent=self,
                                     status_callback=lambda text, ms=0: window.statusBar().showMessage(text, ms))
        self._install(window)

    # ------------------------------------------------------------ state shown
    def name_at(self, view_index) -> str | None:
        """The landmark of a row of the list as shown (sorted, filtered)."""
        if not view_index.isValid():
            return None
        return self.table_model.name_at(self.table_filter.mapToSource(view_index).row())

    def view_index(self, name: str | None, column: int = 0):
        """The list's index (as shown) of ``name``'s row; invalid when filtered out or unknown."""
        row = self.table_model.row_of(name)
        if row < 0:
            return self.table_filter.index(-1, -1)
        return self.table_filter.mapFromSource(self.table_model.index(row, column))

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
            model = self.table_model
            low = sum(model.is_low(n) for n in (model.model.names if model.model is not None else ()))
            worth = f" &nbsp; <span style='color: #a01e0a;'>{low} low confidence</span>" if low else ""
            self.summary_label.setText(f"{n_total} landmarks &nbsp; {chip('auto', auto)} &nbsp; "
                                       f"{chip('edited', edited)} &nbsp; {chip('confirmed', confirmed)}{worth}")
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


    # ------------------------------------------------------------ place in the window
    def _install(self, window) -> None:
        """Right dock area (tabified with the FAP dock), View menu entries and window shortcuts; the
        editor follows the document's face and is active (markers drawn, clicks handled) while the
        dock is showing, the scene's own landmark markers hidden meanwhile."""
        editor = self.editor
        window.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self)
        window.tabifyDockWidget(window.fap_dock, self)
        for act in editor.window_actions:
            window.addAction(act)
        toggle = self.toggleViewAction()
        toggle.setText("&Landmark picker")
        toggle.setStatusTip("Show or hide the landmark-correction dock")
        toggle.setShortcut(QKeySequence("Ctrl+Shift+L"))
        toggle.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
        window.addAction(toggle)
        window.view_menu.addAction(toggle)
        landmark_menu = window.view_menu.addMenu("Landmark &editing")
        for act in editor.window_actions:
            landmark_menu.addAction(act)
        self.toggle_action = toggle

        self.visibilityChanged.connect(self._on_visibility)
        self.document.face_changed.connect(self._on_face)
        self.document.rig_changed.connect(self._on_rig)
        window.landmarks_action.toggled.connect(lambda _on: self._hide_scene_landmarks())
        if self.document.face is not None:
            editor.show_face(window.face_actor)
        editor.set_active(False)
        # After the layout exists (a tab raised earlier is ignored): FAPs for an animatable face,
        # the landmarks for a face that cannot be animated yet.
        QTimer.singleShot(0, self, self._initial_tab)

    def _hide_scene_landmarks(self) -> None:
        actor = self.main_window.face_actor
        if actor is not None and self.editor.active and actor.landmarks_visible:
            actor.set_landmarks_visible(False)

    def _show_scene_landmarks(self) -> None:
        actor = self.main_window.face_actor
        if actor is not None:
            actor.set_landmarks_visible(self.main_window.landmarks_action.isChecked())
            # The scene's markers were placed before the edits: re-place them from the face.
            actor.update_vertices(np.array(actor.mesh.points))

    def _on_visibility(self, visible: bool) -> None:
        self.editor.set_active(visible)
        if visible:
            self._hide_scene_landmarks()
        else:
            self._show_scene_landmarks()
        self.editor.request_render()

    def _on_face(self, face) -> None:
        self.editor.show_face(self.main_window.face_actor)
        self._hide_scene_landmarks()
        if self.document.rig is None and face is not None and not self.document.rig_pending:
            self.raise_()  # nothing to animate: correcting landmarks is what this face needs

    def _on_rig(self, rig) -> None:
        if rig is None and self.document.face is not None:
            self.raise_()  # the rig could not be built: the landmarks are what to fix

    def _initial_tab(self) -> None:
        no_rig = self.document.face is not None and self.document.rig is None and not self.document.rig_pending
        (self if no_rig else self.main_window.fap_dock).raise_()
        self._on_visibility(_dock_showing(self))


def _dock_showing(dock: QDockWidget) -> bool:
    """True when the dock is on screen (not closed, not behind another tab)."""
    return dock.isVisible() and not dock.visibleRegion().isEmpty()
