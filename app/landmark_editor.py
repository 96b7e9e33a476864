"""The landmark editor: a controller over the document's landmark model (:class:`app.document.Document`
``.landmarks``) — the picker's markers and labels in the viewport, clicks and hovers on them, moving
a landmark to the exact surface point clicked, mirror edits, confirm, files, and their undo steps on
the document's stack. It keeps no landmark state of its own: it shows and edits the document's."""

from __future__ import annotations

import contextlib
import time
import traceback
from pathlib import Path

import numpy as np
from PySide6.QtCore import QItemSelectionModel, QModelIndex, QObject, QSignalBlocker, Qt, QTimer
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import QAbstractItemView, QFileDialog, QMessageBox

from app import picking
from app.undo import LandmarkMoveCommand, LandmarkSetCommand
from core.landmark_editing import LandmarkEditModel, LandmarkFileError, LandmarkStatus


#: Markers within this many logical pixels of the cursor can be clicked / hovered.
MARKER_HIT_PX = 9
FILE_FILTER = "Landmark files (*.json *.csv);;Mimica landmarks JSON (*.json);;CSV: name,x,y,z,status,confidence (*.csv)"


# ------------------------------------------------------------------ the controller
class LandmarkEditor(QObject):
    """Landmark correction of the document's face on a plotter: markers, picking, undo (see the
    module docstring).

    Parameters
    ----------
    document : app.document.Document
        Its ``landmarks`` are edited, its ``undo_stack`` gets the steps.
    dock : LandmarkDock
    plotter : pyvistaqt.QtInteractor
    status_callback : callable(str, int ms) or None
        Where short messages go (the window's status bar).

    ``model`` and ``face`` are the document's landmark model and face as last shown
    (:meth:`show_face`): between the document taking a new face and the viewport showing it,
    the markers keep following the face on screen.
    """

    def __init__(self, document, dock, plotter, *, status_callback=None, viewport=None,
                 parent: QObject | None = None):
        super().__init__(parent)
        self.document = document
        self.plotter = plotter
        self.viewport = viewport
        self.dock = dock
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
        document.landmarks_changed.connect(self._model_changed)
        document.landmark_selected.connect(self._selection_changed)
        self._create_actions()

    @property
    def stack(self):
        """The document's undo stack (every edit is a step there)."""
        return self.document.undo_stack

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
    def show_face(self, face_actor=None) -> None:
        """Follow the document's face and landmark model, shown by ``face_actor`` (app.scene.FaceActor:
        ``.actor``, ``.mesh``: what the user sees and clicks)."""
        face = self.document.face
        self.face, self.face_actor = face, face_actor
        self._hovered = None
        self.model = self.document.landmarks
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
        name = self.dock.name_at(current)
        if name is not None:
            self.select(name)

    def _selection_changed(self, name) -> None:
        if self.document.landmarks is not self.model:
            return  # the document's next face, not shown yet (show_face syncs everything)
        table = self.dock.table
        index = self.dock.view_index(name)
        with QSignalBlocker(table.selectionModel()):
            if not index.isValid():   # none selected, or filtered out of the list
                table.selectionModel().clearSelection()
            else:
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
        return self.document.apply_landmark_detection(points, confidence)

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
        if self.document.landmarks is not self.model:
            return  # the document's next face, not shown yet
        self.dock.table_model.refresh(name)
        if not name and self.model is not None:
            self.markers.set_names(self.model.names, face_height_mm=self._face_height())
            self._selection_changed(self.model.selected)  # rows may have moved
        self._update_counts()
        self._update_markers(force=True)
        self.request_render()

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
        """Redraw soon: through the window's viewport scheduler when there is one (one render per
        event-loop pass with everything else that changed), else on the editor's own timer."""
        if self.viewport is not None:
            self.viewport.request("landmarks")
        elif not self._render_timer.isActive():
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
