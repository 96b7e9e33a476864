"""main_window.py
----
The Mimica main window: a pyvistaqt viewport showing one :class:`core.face.Face`, the docks, the
menus, a status bar and persisted settings.

Its state lives in ``window.document`` (:mod:`app.document`: face, rig with its layers, landmark
model, timeline, the one undo stack, the rig recorder and the project path); ``window.face``,
``window.rig``, ``window.undo_stack``, ``window.timeline`` read it. The window builds the document
first, then the docks, each constructed with the document (and the window, where it adds its
actions and menus). The window's other parts each have their module:

* :mod:`app.face_files`  loading faces in the background (:mod:`app.jobs`), recent files, Open/Save,
  drag and drop
* :mod:`app.face_view`   what the viewport shows of the face (pose, overlays), view modes, cameras
* :mod:`app.viewport`    one scheduler: ``rig.changed`` only requests ``"mesh"``; one 0 ms timer
  pulls ``rig.vertices()`` once, writes it into the actor in place and renders once, so a burst of
  slider events costs one redraw; the status bar shows its compute and draw times
* :mod:`app.scan_tools`  landmark detection, correspondence, scale and texture tools
* :mod:`app.error_hook`  unexpected exceptions become a dialog, never a traceback in the user's face

Anything the user can trigger that fails shows a message box with a one-line explanation.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable

from app.deferred_imports import prepare_startup_imports

prepare_startup_imports()   # ~0.8 s of start-up: modules deferred, numpy/scipy/pyvista before PySide6

from PySide6.QtCore import QEvent, QSettings, Qt, QTimer, Signal
from PySide6.QtGui import QAction, QActionGroup, QKeySequence
from PySide6.QtWidgets import (
    QAbstractSpinBox,
    QApplication,
    QDialog,
    QLabel,
    QLineEdit,
    QMainWindow,
    QMessageBox,
    QProgressBar,
    QWidget,
)

from app import __version__

from app.error_hook import APP_NAME, ExceptionDialogHook, install_excepthook  # noqa: F401 - re-exported
from app.document import build_rig
from app.face_files import (  # noqa: F401 - re-exported
    MAX_RECENT, OPEN_FILTER, OPEN_SUFFIXES, SAVE_FILTERS, SCREENSHOT_FILTER, FaceFilesMixin)
from app.face_view import MODE_LABELS, VIEW_LABELS, FaceViewMixin, _nice_ceiling  # noqa: F401 - re-exported
from app.scan_tools import ScanToolsMixin

#: set_face's default: build the rig for the face there.
_BUILD_RIG = object()


# ------------------------------------------------------------------ window
class MainWindow(FaceFilesMixin, FaceViewMixin, ScanToolsMixin, QMainWindow):
    """The Mimica window.

    Parameters
    ----------
    face : Face, optional
        Shown immediately. Otherwise ``path`` is loaded, or the default face
        when ``load_default`` is true.
    path : str or Path, optional
        A face file to load (in the background) at start.
    settings : QSettings, optional
        Where geometry and recent files live; defaults to ``QSettings("Mimica", "Mimica")``.
    """

    face_changed = Signal(object)  # the new Face
    load_failed = Signal(str)  # user-facing message
    load_finished = Signal(bool)  # True on success
    closing = Signal()  # the window really closes (any Save / Discard / Cancel question answered)

    _kernels_warming = False   # the per-tick numba kernels are being (or were) built in this process

    def __init__(self, face=None, *, path=None, settings: QSettings | None = None,
                 load_default: bool = True, tools: bool = True, parent: QWidget | None = None):
        super().__init__(parent)
        from core import lazy_numba

        # The first frames in numpy: numba (~1 s to import and load its machine code) is loaded in the
        # background once the face is animatable (_on_rig_arrived), not before the face can be seen.
        lazy_numba.defer_until_warm()
        from pyvistaqt import QtInteractor

        from app import scene

        self._scene = scene
        self.settings = settings if settings is not None else QSettings(APP_NAME, APP_NAME)
        from app.document import Document

        self.document = Document(self)
        self.document.face_changed.connect(self.face_changed)   # the window's signal follows the document's
        self.document.rig_changed.connect(self._on_rig_arrived)
        self.face_actor = None
        self._mode = "textured"
        self._closing = False
        self._shown_overlay: tuple = (None, None)
        self._view = "front"
        from app.jobs import JobRunner

        self._loading = False
        # Loads (a newer one wins) and other background work (detection) on separate runners.
        from core.formats.mesh_io import MeshLoadError

        self.loads = JobRunner(self, supersede=True, user_errors=(MeshLoadError,))
        self.jobs = JobRunner(self)
        self.previews = JobRunner(self, supersede=True)   # the face's draft copy (app.preview)
        # The tool docks (a window built with tools=False, as some tests do, has none).
        self.landmark_dock = self.landmark_editor = self.muscle_dock = self.timeline_dock = None
        self._notes_box: QMessageBox | None = None
        self._notes_seen: list[str] | None = None  # notes of the face an edited copy replaces
        self._framed_when_shown = False

        self.setWindowTitle(APP_NAME)
        self.resize(1400, 900)
        self.setAcceptDrops(True)
        self._setup_dock_areas()

        # auto_update=False: we render when something changes; the default
        # 5 Hz timer would re-render a 50k-triangle face forever for nothing.
        self.plotter = QtInteractor(self, off_screen=False, auto_update=False)
        # Keys follow the mouse into the viewport, and drops on it go to our loader, not pv.read
        # (both in eventFilter).
        self.plotter.installEventFilter(self)
        self._disable_vtk_keys()
        self.renderer_name = scene.renderer_name(self.plotter)
        scene.setup_stage(self.plotter, anti_aliasing=scene.anti_aliasing_for(self.renderer_name))
        self.setCentralWidget(self.plotter)
        from app.viewport import Viewport

        self.viewport = Viewport(self.plotter, self._viewport_alive, self)
        self.viewport.add_updater(("mesh", "overlay"), self._update_face)
        self.viewport.timed.connect(self._show_timing)
        self.viewport.set_draft = self._set_draft
        self.viewport.watch_camera(self.plotter.iren.interactor)
        self._tick_timer = self.viewport.timer   # tests wait on it
        # Camera zoom narrows the view angle; presets and Reset camera restore it.
        self._default_view_angle = float(self.plotter.camera.view_angle)

        self._create_actions()
        self._create_docks()
        self._create_menus()
        self._create_status_bar()
        if tools:  # tests of one dock build it alone (tools=False)
            self._create_tool_docks()
        self._restore_window_state()
        self._take_drops()

        if face is not None:
            self.set_face(face)
        elif path is not None:
            self.load_face_file(path, fallback_to_default=load_default)
        elif load_default:
            self.load_default_face()

    # ------------------------------------------------------------ setup
    def _setup_dock_areas(self) -> None:
        # Left/right docks run full height; a bottom timeline sits between them.
        self.setDockNestingEnabled(True)
        self.setDockOptions(QMainWindow.DockOption.AnimatedDocks | QMainWindow.DockOption.AllowNestedDocks
                            | QMainWindow.DockOption.AllowTabbedDocks)
        self.setCorner(Qt.Corner.TopLeftCorner, Qt.DockWidgetArea.LeftDockWidgetArea)
        self.setCorner(Qt.Corner.BottomLeftCorner, Qt.DockWidgetArea.LeftDockWidgetArea)
        self.setCorner(Qt.Corner.TopRightCorner, Qt.DockWidgetArea.RightDockWidgetArea)
        self.setCorner(Qt.Corner.BottomRightCorner, Qt.DockWidgetArea.RightDockWidgetArea)

    def _disable_vtk_keys(self) -> None:
        """Drop VTK/pyvista single-key bindings ('q' closes the render window,
        'w'/'s' restyle every actor, '3' toggles stereo...): the menus own the keyboard."""
        iren = getattr(self.plotter, "iren", None)
        if iren is None:
            return
        iren.clear_key_event_callbacks()
        iren.interactor.RemoveObservers("CharEvent")

    def _action(self, text: str, slot=None, shortcut=None, *, checkable=False, tip: str = "") -> QAction:
        action = QAction(text, self)
        if shortcut:
            action.setShortcut(QKeySequence(shortcut))
            # Window-wide, so the keys work while the viewport has focus.
            action.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
        action.setCheckable(checkable)
        if tip:
            action.setStatusTip(tip)
        if slot is not None:
            action.triggered.connect(slot)
        self.addAction(action)
        return action

    def _create_actions(self) -> None:
        # Ctrl+O / Ctrl+S belong to projects (the timeline's File actions); faces are imported with Ctrl+I.
        self.open_action = self._action("&Open face…", self.open_face_dialog, "Ctrl+I",
                                        tip="Open a face mesh (OBJ, PLY, STL, glTF)")
        self.save_action = self._action("&Save face as…", self.save_face_dialog,
                                        tip="Save the current face as OBJ, PLY or GLB")
        self.screenshot_action = self._action("&Export screenshot…", self.export_screenshot_dialog,
                                              tip="Save an image of the 3-D view")
        self.quit_action = self._action("&Quit", self.close, "Ctrl+Q")
        self.quit_action.setMenuRole(QAction.MenuRole.QuitRole)

        self.mode_group = QActionGroup(self)
        self.mode_group.setExclusive(True)
        self.mode_actions: dict[str, QAction] = {}
        for mode, label in MODE_LABELS.items():
            act = self._action(label, checkable=True, tip=f"Display the face {mode}")
            act.setData(mode)
            act.triggered.connect(lambda _checked=False, m=mode: self.set_view_mode(m))
            self.mode_group.addAction(act)
            self.mode_actions[mode] = act
        self.mode_actions[self._mode].setChecked(True)

        self.landmarks_action = self._action("Show &landmarks", self.set_landmarks_visible, "L",
                                             checkable=True, tip="Show landmark points with their names")
        self.view_actions: dict[str, QAction] = {}
        for view, (label, key) in VIEW_LABELS.items():
            self.view_actions[view] = self._action(label, lambda _c=False, v=view: self.set_camera_view(v), key)
        self.reset_camera_action = self._action("&Reset camera", self.reset_camera, "R",
                                                tip="Frame the whole face")
        self.about_action = self._action("&About Mimica", self.show_about)
        self.about_action.setMenuRole(QAction.MenuRole.AboutRole)

    def _create_docks(self) -> None:
        from app.fap_dock import FapDock

        self.fap_dock = FapDock(self.document, self, message="No face loaded yet.")
        self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self.fap_dock)
        self.resizeDocks([self.fap_dock], [520], Qt.Orientation.Horizontal)
        self.fap_dock.feature_points_toggled.connect(self.set_landmarks_visible)
        self.fap_dock.overlay_changed.connect(self._on_overlay_changed)
        self.landmarks_action.toggled.connect(lambda on: self.fap_dock.set_feature_points_checked(on))
        self.fap_dock_action = self.fap_dock.toggleViewAction()
        self.fap_dock_action.setText("&FAP sliders")
        self.fap_dock_action.setStatusTip("Show or hide the FAP dock (sliders, presets, overlays)")
        self.fap_dock_action.setShortcut(QKeySequence("Ctrl+Shift+F"))
        self.fap_dock_action.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
        self.addAction(self.fap_dock_action)

    def _create_menus(self) -> None:
        bar = self.menuBar()
        file_menu = bar.addMenu("&File")
        file_menu.addAction(self.open_action)
        self.recent_menu = file_menu.addMenu("Open &recent")
        self._create_recent_actions()
        file_menu.addAction(self.save_action)
        file_menu.addSeparator()
        file_menu.addAction(self.screenshot_action)
        file_menu.addSeparator()
        file_menu.addAction(self.quit_action)
        self._rebuild_recent_menu()

        from app.undo import make_undo_actions

        self.undo_action, self.redo_action = make_undo_actions(self.document.undo_stack, self)
        self.addAction(self.undo_action)
        self.addAction(self.redo_action)
        self.edit_menu = bar.addMenu("&Edit")
        self.edit_menu.addAction(self.undo_action)
        self.edit_menu.addAction(self.redo_action)
        self.edit_menu.addSeparator()

        view_menu = bar.addMenu("&View")
        for act in self.mode_actions.values():
            view_menu.addAction(act)
        view_menu.addSeparator()
        view_menu.addAction(self.landmarks_action)
        view_menu.addSeparator()
        for act in self.view_actions.values():
            view_menu.addAction(act)
        view_menu.addAction(self.reset_camera_action)
        view_menu.addSeparator()
        view_menu.addAction(self.fap_dock_action)
        self.view_menu = view_menu

        self.tools_menu = bar.addMenu("&Tools")
        self.rebuild_animation_action = self._action(
            "Rebuild animation from landmarks", self.rebuild_animation,
            tip="Rebuild the FAP and muscle rigs from the current (corrected) landmarks")
        self.tools_menu.addAction(self.rebuild_animation_action)
        self.scale_face_action = self._action(
            "&Scale face…", self.scale_face_dialog,
            tip="Scale the face (e.g. when its file's units were guessed wrong); the rig is rebuilt")
        self.load_texture_action = self._action(
            "Load &texture image…", self.load_texture_dialog,
            tip="Map an image onto the face through its texture coordinates (e.g. a scan's separate JPEG)")
        self.flip_texture_action = self._action(
            "&Flip texture vertically", self.flip_texture,
            tip="Turn the texture image upside down (for files whose texture coordinates count rows from the "
                "other end, e.g. a glTF made from an OBJ)")
        self.save_canonical_action = self._action(
            "Save &canonical face…", self.save_canonical_face_dialog,
            tip="Save the 4560-vertex canonical face behind the animated scan (after Build correspondence), "
                "the same topology for every registered scan")
        self.tools_menu.addAction(self.save_canonical_action)
        self.tools_menu.addAction(self.scale_face_action)
        self.tools_menu.addAction(self.load_texture_action)
        self.tools_menu.addAction(self.flip_texture_action)

        help_menu = bar.addMenu("&Help")
        help_menu.addAction(self.about_action)

    def _create_status_bar(self) -> None:
        status = self.statusBar()
        self.progress_bar = QProgressBar(self)
        self.progress_bar.setRange(0, 1000)
        self.progress_bar.setMaximumWidth(220)
        self.progress_bar.setTextVisible(False)
        self.progress_bar.hide()
        self.file_label = QLabel(self)
        self.counts_label = QLabel(self)
        self.units_label = QLabel(self)
        self.texture_label = QLabel(self)
        self.tick_label = QLabel(self)
        self.tick_label.setToolTip(
            "Last viewport update: compute = rig vertices + normals + overlay values; "
            "draw = upload to the GPU + render")
        status.addPermanentWidget(self.progress_bar)
        status.addPermanentWidget(self.tick_label)
        for label in (self.file_label, self.counts_label, self.units_label, self.texture_label):
            label.setContentsMargins(6, 0, 6, 0)
            status.addPermanentWidget(label)
        self._update_status_labels()

    # ------------------------------------------------------------ state
    def _restore_window_state(self) -> None:
        geometry = self.settings.value("window/geometry")
        if geometry is not None:
            self.restoreGeometry(geometry)
        state = self.settings.value("window/state")
        if state is not None:
            self.restoreState(state)
        mode = self.settings.value("view/mode", "textured")
        if mode in MODE_LABELS:
            self._mode = str(mode)
            self.mode_actions[self._mode].setChecked(True)

    def showEvent(self, event) -> None:  # noqa: N802 - Qt override
        super().showEvent(event)
        if not self._framed_when_shown and self.face_actor is not None:
            # Framing before the first show used a guessed viewport aspect;
            # redo it once the real size is known.
            self._framed_when_shown = True
            QTimer.singleShot(0, self, self._frame_after_show)

    def _frame_after_show(self) -> None:
        if self.isVisible() and not getattr(self.plotter, "_closed", False):
            self.set_camera_view(self._view)

    def closeEvent(self, event) -> None:  # noqa: N802 - Qt override
        self.settings.setValue("window/geometry", self.saveGeometry())
        self.settings.setValue("window/state", self.saveState())
        self.settings.setValue("view/mode", self._mode)
        self.settings.sync()
        self.loads.cancel()  # ignore loads and jobs still running
        self.jobs.cancel()
        self.previews.cancel()
        self._closing = True
        self.closing.emit()
        self.viewport.stop()
        self._disconnect_rig()
        self.fap_dock.set_rig(None, "")
        self.loads.wait(5000)  # a worker must not outlive the window it reports to
        self.jobs.wait(5000)
        self.previews.wait(5000)
        if self._notes_box is not None:
            self._notes_box.close()
        self.plotter.close()
        super().closeEvent(event)

    # ------------------------------------------------------------ messages
    def show_error(self, title: str, message: str) -> None:
        """A modal warning; the single place errors reach the user (tests patch it)."""
        first = message.splitlines()[0] if message else title
        self.statusBar().showMessage(first if len(first) <= 140 else first[:139] + "…", 8000)
        QMessageBox.warning(self, title, message)

    def _show_notes(self, notes: list[str], name: str, heading: str | None = None) -> None:
        """Non-modal list of what the loader (or another tool, with its ``heading``) did."""
        if self._notes_box is not None:
            self._notes_box.close()
            self._notes_box.deleteLater()
        box = QMessageBox(QMessageBox.Icon.Information, "Notes on loading" if heading is None else "Notes",
                          heading or f"While loading {name}:", QMessageBox.StandardButton.Ok, self)
        box.setInformativeText("\n".join(f"• {n}" for n in notes))
        box.setModal(False)
        box.setWindowModality(Qt.WindowModality.NonModal)
        box.show()
        self._notes_box = box

    # ------------------------------------------------------------ face
    def set_face(self, face, *, path: str | None = None, rig=_BUILD_RIG, rig_message: str = "",
                 rig_pending: bool = False) -> None:
        """Display ``face`` (replacing the current one), framed from the front.

        ``rig`` is the face's :class:`core.rig.FaceRig` when already built; by default it is built
        here. ``None`` means the face cannot be animated, ``rig_message`` says why, or with
        ``rig_pending`` that it is being built (``document.set_rig`` follows: the loader does that).
        """
        if rig is _BUILD_RIG:
            QApplication.setOverrideCursor(Qt.CursorShape.WaitCursor)
            try:
                rig, rig_message = build_rig(face)
            finally:
                QApplication.restoreOverrideCursor()
        self.viewport.stop()
        if self.face_actor is not None:
            self.face_actor.remove()
        self._disconnect_rig()
        self.document.set_face(face, path=path if path is not None else getattr(face.metadata, "source", None),
                               rig=rig, rig_message=rig_message, rig_pending=rig_pending)
        self.face_actor = self._scene.add_face_actor(
            self.plotter, face, self._mode, show_landmarks=self.landmarks_action.isChecked())
        self.landmarks_action.setEnabled(bool(face.landmark_names))
        self.fap_dock.set_feature_points_checked(self.face_actor.landmarks_visible, bool(face.landmark_names))
        self._set_rig(rig, rig_message)
        self.setWindowTitle(f"{APP_NAME} — {face.metadata.name}")
        self._update_status_labels()
        self.set_camera_view("front")
        self._start_preview(face)
        self.document.announce_face()   # face_changed, now that the viewport shows it

    # ------------------------------------------------------------ animation
    def _disconnect_rig(self) -> None:
        if self.rig is not None:
            try:
                self.rig.changed.disconnect(self._on_rig_changed)
            except (ValueError, RuntimeError):
                pass

    def _on_rig_arrived(self, rig) -> None:
        """The shown face's rig, built in the background after the face appeared."""
        self._disconnect_rig()
        self._set_rig(rig)   # the dock shows document.rig_message; the loader words the status bar
        if rig is not None and not MainWindow._kernels_warming:
            # From the event loop, after the docks have taken the rig (the FAP rows are built on this
            # thread): a Python thread started now would take half of their time (GIL).
            QTimer.singleShot(0, self, self._warm_up_kernels)

    def _warm_up_kernels(self) -> None:
        from app.document import warm_up_kernels

        if self._closing or MainWindow._kernels_warming:
            return
        MainWindow._kernels_warming = True     # once per process: the kernels are shared
        self.jobs.start(lambda _job: warm_up_kernels(), lambda _result: None)

    def _set_rig(self, rig, message: str = "") -> None:
        self._shown_overlay = (None, None)
        if rig is not None:
            rig.changed.connect(self._on_rig_changed)
            # The actor starts at the neutral face; show the rig's state if it is not neutral.
            if rig.values(nondefault=True):
                self.viewport.request("mesh")
        if rig is None and message:
            self.statusBar().showMessage(message.splitlines()[0], 15000)
        elif rig is not None:
            self.statusBar().clearMessage()
        self.viewport.request("overlay")

    def eventFilter(self, watched, event) -> bool:  # noqa: N802 - Qt override
        kind = event.type()
        if kind in (QEvent.Type.DragEnter, QEvent.Type.DragMove, QEvent.Type.Drop) and watched.property("mimicaDrops"):
            {QEvent.Type.DragEnter: self.dragEnterEvent, QEvent.Type.DragMove: self.dragMoveEvent,
             QEvent.Type.Drop: self.dropEvent}[kind](event)
            return True
        # As in Blender, keys go where the mouse is: entering the 3-D view takes the keyboard from a
        # number box (its typed value is committed), so 1/2/3, L, R... act on the view instead of
        # typing into the last box used.
        if watched is self.plotter and kind == QEvent.Type.Enter:
            focus = QApplication.focusWidget()
            if isinstance(focus, (QAbstractSpinBox, QLineEdit)) and not isinstance(focus.window(), QDialog):
                self.plotter.setFocus(Qt.FocusReason.MouseFocusReason)
        return super().eventFilter(watched, event)

    # The document's state, read through the window (the window's own parts and scripts).
    face = property(lambda self: self.document.face)
    face_path = property(lambda self: self.document.face_path,
                         lambda self, path: setattr(self.document, "face_path", path))
    rig = property(lambda self: self.document.rig)
    rig_message = property(lambda self: self.document.rig_message)
    undo_stack = property(lambda self: self.document.undo_stack)
    rig_edits = property(lambda self: self.document.rig_edits)
    timeline = property(lambda self: self.document.timeline)   # TimelineController, once its dock exists

    @property
    def muscle_layer(self):
        """The muscle layer of the current face (built by the muscle dock in the background), or None."""
        return self.document.muscle_layer

    def play_demo(self) -> None:
        """Open the built-in showcase (``mimica demo``) on the timeline and play it in a loop."""
        import tempfile

        from app.demo import demo_project
        from core.formats.project import save_project

        _face, project = demo_project()
        path = Path(tempfile.mkdtemp(prefix="mimica-demo-")) / "demo.mimica"
        save_project(path, project)
        if self.timeline.project.open_project(path, ask=False):
            self.timeline.loop = True
            self.timeline.play()
            self.statusBar().showMessage("Playing the Mimica demo (Space pauses).", 8000)

    # ------------------------------------------------------------ tool docks (landmarks, muscles, timeline)
    def _create_tool_docks(self) -> None:
        """The docks of their own modules, each built with the document (and this window, where it
        adds its dock, actions and menus)."""
        from app.landmark_dock import LandmarkDock
        from app.muscle_dock import MuscleDock
        from app.timeline_dock import TimelineDock

        self.landmark_dock = LandmarkDock(self.document, self)
        self.landmark_editor = self.landmark_dock.editor
        self.muscle_dock = MuscleDock(self.document, self)
        from app.control_point_dock import ControlPointDock   # thesis B: RBF control points, Waters muscles
        self.control_point_dock = ControlPointDock(self.document, self)
        self.timeline_dock = TimelineDock(self.document, self)   # registers document.timeline / .project
        from app.blend_dock import BlendDock

        self.blend_dock = BlendDock(self.document, self)         # expression library: poses, caricature
        # The timeline starts tall enough to show a few tracks.
        self.resizeDocks([self.timeline_dock], [260], Qt.Orientation.Vertical)
        self.landmark_dock.detect_requested.connect(self.detect_landmarks)
        self.landmark_dock.build_requested.connect(self.build_correspondence)

    def run_job(self, work: Callable[[], object], done: Callable[[object], None], title: str,
                message: str) -> None:
        """Run ``work()`` in the background with a busy indicator; errors go to a message box."""
        def finish() -> None:
            if not self.jobs.busy and not self._loading:
                self.progress_bar.setRange(0, 1000)
                self.progress_bar.hide()

        def ok(result) -> None:
            finish()
            if not self._closing:
                done(result)

        def failed(text: str) -> None:
            finish()
            if not self._closing:
                self.show_error(title, text)

        self.progress_bar.setRange(0, 0)  # busy
        self.progress_bar.show()
        self.statusBar().showMessage(message)
        self.jobs.start(lambda job: work(), ok, failed)

    def _on_rig_changed(self, _change=None) -> None:
        self.viewport.request("mesh")

    def _on_overlay_changed(self) -> None:
        self.viewport.request("overlay")

    def _viewport_alive(self) -> bool:
        return not self._closing and not getattr(self.plotter, "_closed", False)

    def flush_updates(self) -> None:
        """Run a pending viewport update now (tests and scripts; the timer does it otherwise)."""
        self.viewport.flush()

    @property
    def last_tick_ms(self) -> tuple[float, float] | None:
        """(compute ms, draw ms) of the last viewport update that moved the face."""
        return self.viewport.last_tick_ms

    # ------------------------------------------------------------ help
    def about_text(self) -> str:
        import PySide6
        import pyvista as pv
        from PySide6.QtCore import qVersion
        from vtkmodules.vtkCommonCore import vtkVersion

        return (
            f"<h3>Mimica {__version__}</h3>"
            "<p>A desktop workbench for 3-D facial animation.</p>"
            "<p>"
            f"Python {sys.version.split()[0]}<br>"
            f"Qt {qVersion()} / PySide6 {PySide6.__version__}<br>"
            f"VTK {vtkVersion.GetVTKVersion()}<br>"
            f"PyVista {pv.__version__}"
            "</p>"
            "<p><b>Data credits</b><br>"
            "Default face: generated procedurally by Mimica.<br>"
            "MPEG-4 feature point and FAP tables after ISO/IEC 14496-2.</p>"
        )

    def show_about(self) -> None:
        QMessageBox.about(self, "About Mimica", self.about_text())


# ------------------------------------------------------------------ entry
def run_gui(face_path: str | None = None, argv: list[str] | None = None, *, demo: bool = False) -> int:
    """Create the application and window, run the event loop; returns the exit status.

    With ``demo``, the showcase plays as soon as the default face is ready.
    """
    app = QApplication.instance() or QApplication(argv if argv is not None else sys.argv[:1])
    app.setOrganizationName(APP_NAME)
    app.setApplicationName(APP_NAME)
    app.setApplicationVersion(__version__)
    hook = install_excepthook()
    window = MainWindow(path=face_path) if face_path else MainWindow()
    hook.parent = window
    if window.document.project is not None:
        window.document.project.ask_on_close = True   # unsaved changes: Save / Discard / Cancel on close
    if demo:
        def start_demo(ok: bool) -> None:
            window.load_finished.disconnect(start_demo)
            if ok:
                QTimer.singleShot(1500, window.play_demo)  # let the muscle model build first

        window.load_finished.connect(start_demo)
    window.show()
    _close_on_termination(window)
    # Ctrl+C in the terminal: the Python handler only runs when the
    # interpreter gets control, so wake it periodically.
    timer = QTimer(window)
    timer.timeout.connect(lambda: None)
    timer.start(250)
    return int(app.exec())


def _close_on_termination(window: MainWindow) -> None:
    """SIGTERM and SIGHUP (a logout, ``kill``, a closed terminal) close the window as its close button
    does, without asking: unsaved work goes to the autosave (offered at the next start), loads and
    exports are cancelled and their temporary files removed. Without this the process just died."""
    import signal

    def close(_signum, _frame) -> None:
        if window.document.project is not None:
            window.document.project.ask_on_close = False   # nobody is there to answer
        QTimer.singleShot(0, window.close)

    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), close)


__all__ = ["MainWindow", "ExceptionDialogHook", "install_excepthook", "run_gui"]
