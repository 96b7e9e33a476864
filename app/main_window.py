"""main_window.py
----
The Mimica main window: a pyvistaqt viewport showing one :class:`core.face.Face`
with File / View / Help menus, drag-and-drop loading, a status bar and
persisted settings.

Mesh loading runs on a worker thread (``QThreadPool``) so the window stays
responsive; results come back through queued Qt signals. Anything the user
can trigger that fails shows a message box with a one-line explanation, never
a traceback (tracebacks go to stderr via :func:`install_excepthook`).

Animation: the window owns a :class:`core.rig.FaceRig` for the current face
(``window.rig``; None, with a message in the FAP dock and the status bar, when
the face cannot be animated yet) and the FAP dock (:mod:`app.fap_dock`) on
the right. The viewport never redraws per parameter change: ``rig.changed``
only marks the view dirty and starts one single-shot 0 ms timer, whose tick
pulls ``rig.vertices()`` once, computes normals and writes both into the
existing actor in place (:meth:`app.scene.FaceActor.update_vertices`), so a
burst of slider events costs one redraw. The status bar shows the last
tick's compute time (vertices + normals + overlay values) and draw time
(upload + render) separately.

The dock areas are left free (nesting enabled, corners assigned) for the
muscle, landmark and timeline docks that come later.
"""

from __future__ import annotations

import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Callable

import numpy as np

from PySide6.QtCore import QObject, QRunnable, QSettings, Qt, QThreadPool, QTimer, Signal, Slot
from PySide6.QtGui import QAction, QActionGroup, QKeySequence
from PySide6.QtWidgets import (
    QApplication,
    QDockWidget,
    QFileDialog,
    QLabel,
    QMainWindow,
    QMessageBox,
    QProgressBar,
    QWidget,
)

from app import __version__

APP_NAME = "Mimica"
MAX_RECENT = 8
#: Suffixes accepted by Open / drag-and-drop, and by Save as.
OPEN_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")
SAVE_FILTERS = {
    "Wavefront OBJ (*.obj)": ".obj",
    "Stanford PLY (*.ply)": ".ply",
    "glTF binary (*.glb)": ".glb",
}
OPEN_FILTER = (
    "Face meshes (*.obj *.ply *.stl *.glb *.gltf);;Wavefront OBJ (*.obj);;Stanford PLY (*.ply);;"
    "STL (*.stl);;glTF (*.glb *.gltf);;All files (*)"
)
SCREENSHOT_FILTER = "PNG image (*.png);;JPEG image (*.jpg *.jpeg)"
MODE_LABELS = {"textured": "&Textured", "shaded": "&Shaded", "wireframe": "&Wireframe", "points": "&Points"}
VIEW_LABELS = {"front": ("&Front view", "1"), "side": ("&Side view", "2"),
               "three-quarter": ("T&hree-quarter view", "3")}


#: set_face's default: build the rig for the face there.
_BUILD_RIG = object()


def _nice_ceiling(value: float, floor: float = 1.0) -> float:
    """The next of 1, 1.5, 2, 3, 4, 5, 6, 8 x 10^k at or above ``value`` (at least ``floor``):
    a heat map range that does not jump with every slider step."""
    import math

    value = max(float(value), floor)
    exp = math.floor(math.log10(value))
    for m in (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * 10 ** exp >= value * (1 - 1e-12):
            return m * 10 ** exp
    return 10.0 ** (exp + 1)


def _is_mesh_load_error(exc: BaseException) -> bool:
    try:
        from core.mesh_io import MeshLoadError
    except ImportError:
        return False
    return isinstance(exc, MeshLoadError)


def _is_mesh_save_error(exc: BaseException) -> bool:
    try:
        from core.mesh_io import MeshSaveError
    except ImportError:
        return False
    return isinstance(exc, MeshSaveError)


# ------------------------------------------------------------------ worker
class _LoadSignals(QObject):
    progress = Signal(int, float, str)  # generation, fraction, message
    status = Signal(int, str)  # generation, message (no progress fraction)
    loaded = Signal(int, object, str)  # generation, (Face, (rig, rig message)), path ("" for the default face)
    failed = Signal(int, str, str)  # generation, message, path


def _no_feature_points(exc: BaseException) -> bool:
    try:
        from core.fap.template import TemplateError
    except ImportError:
        return False
    return isinstance(exc, TemplateError)


def build_rig(face) -> tuple[object | None, str]:
    """(FaceRig for ``face``, "") or (None, a message for the user saying why not).

    Never raises: a face without the MPEG-4 feature points is a normal state
    (the user marks them later), and anything unexpected is reported on stderr.
    """
    from app.fap_dock import NO_RIG_MESSAGE

    try:
        from core.rig import FaceRig
    except Exception as exc:  # noqa: BLE001 - animation is optional; the viewer must still work
        traceback.print_exc()
        return None, f"Animation is not available in this installation ({type(exc).__name__}: {exc})."
    try:
        return FaceRig(face), ""
    except ValueError as exc:  # missing/misplaced feature points: a message, not a bug
        first = NO_RIG_MESSAGE if _no_feature_points(exc) else "This face cannot be animated yet."
        return None, f"{first}\n\nDetails: {exc}"
    except Exception as exc:  # noqa: BLE001
        traceback.print_exc()
        return None, f"Could not prepare this face for animation: {type(exc).__name__}: {exc}"


class _LoadTask(QRunnable):
    """Runs ``loader(progress)`` off the GUI thread and reports through signals.

    With ``prepare``, the loaded face's rig is built here too (about a second
    for a 50k-vertex face), so the GUI thread never waits for it.
    """

    def __init__(self, generation: int, path: str, loader: Callable, signals: _LoadSignals,
                 prepare: Callable | None = None, wanted: Callable[[int], bool] | None = None):
        super().__init__()
        self.generation, self.path, self.loader, self.signals = generation, path, loader, signals
        self.prepare = prepare
        # wanted(generation): False once the window moved on (newer load, or closing), so a
        # superseded load skips the rig build and does not report to a closing window.
        self.wanted = wanted or (lambda _generation: True)
        self.setAutoDelete(True)

    def run(self) -> None:  # worker thread
        gen = self.generation

        def progress(fraction, message=""):
            self.signals.progress.emit(gen, float(fraction), str(message))

        try:
            face = self.loader(progress)
        except Exception as exc:  # noqa: BLE001 - every failure becomes a message box
            if _is_mesh_load_error(exc) or isinstance(exc, ValueError):  # input errors speak to the user
                message = str(exc)
            else:
                traceback.print_exc()
                message = f"Unexpected error while loading: {type(exc).__name__}: {exc}"
            self.signals.failed.emit(gen, message, self.path)
            return
        if not self.wanted(gen):
            return
        rig = None
        if self.prepare is not None:
            self.signals.status.emit(gen, "Preparing the face for animation…")
            rig = self.prepare(face)  # never raises
        if self.wanted(gen):
            self.signals.loaded.emit(gen, (face, rig), self.path)


class _JobSignals(QObject):
    done = Signal(object)
    failed = Signal(str)


class _BackgroundJob(QRunnable):
    """Runs ``work()`` off the GUI thread; ``done(result)`` or ``failed(message)`` on the GUI thread.

    ``ValueError`` messages are meant for the user (the solvers' input errors); anything else is
    reported as unexpected, with its traceback on stderr.
    """

    def __init__(self, work: Callable[[], object]):
        super().__init__()
        self.work = work
        self.signals = _JobSignals()
        self.setAutoDelete(True)

    def run(self) -> None:  # worker thread
        try:
            result = self.work()
        except ValueError as exc:
            self.signals.failed.emit(str(exc))
            return
        except Exception as exc:  # noqa: BLE001 - every failure becomes a message box
            traceback.print_exc()
            self.signals.failed.emit(f"Unexpected error: {type(exc).__name__}: {exc}")
            return
        self.signals.done.emit(result)


# ------------------------------------------------------------ excepthook
class _ExceptionRelay(QObject):
    """Carries exception reports to the GUI thread (excepthook may run on any thread)."""

    report = Signal(str, str)  # short message, traceback text


class ExceptionDialogHook:
    """``sys.excepthook`` replacement: traceback to stderr, short message in a dialog."""

    def __init__(self, parent: QWidget | None = None):
        self.parent = parent
        self.previous = sys.excepthook
        self.previous_thread_hook = threading.excepthook
        self.last_dialog: QMessageBox | None = None
        self.reports: list[str] = []
        self._relay = _ExceptionRelay()
        self._relay.report.connect(self._show, Qt.ConnectionType.QueuedConnection)

    def __call__(self, etype, value, tb) -> None:
        text = "".join(traceback.format_exception(etype, value, tb))
        sys.stderr.write(text)
        if issubclass(etype, KeyboardInterrupt):
            app = QApplication.instance()
            if app is not None:
                app.quit()
            return
        message = f"{etype.__name__}: {value}" if str(value) else etype.__name__
        if threading.current_thread() is threading.main_thread():
            self._show(message, text)
        else:
            self._relay.report.emit(message, text)

    @Slot(str, str)
    def _show(self, message: str, details: str) -> None:
        self.reports.append(message)
        if QApplication.instance() is None:
            return
        if self.last_dialog is not None and self.last_dialog.isVisible():
            return  # one dialog at a time: an error in a paint loop must not spawn hundreds
        box = QMessageBox(QMessageBox.Icon.Critical, f"{APP_NAME} — unexpected error",
                          f"Something went wrong:\n\n{message}", QMessageBox.StandardButton.Ok,
                          self.parent)
        box.setInformativeText("The details were written to the terminal. "
                               "Mimica keeps running; saving your work is a good idea.")
        box.setDetailedText(details)
        box.open()  # window-modal but non-blocking: no nested event loop inside the hook
        self.last_dialog = box

    def thread_hook(self, args) -> None:
        """``threading.excepthook`` adapter (Python threads report here, not to sys.excepthook)."""
        if args.exc_type is SystemExit:
            return
        self(args.exc_type, args.exc_value if args.exc_value is not None else args.exc_type(),
             args.exc_traceback)

    def uninstall(self) -> None:
        if sys.excepthook is self:
            sys.excepthook = self.previous
        if threading.excepthook == self.thread_hook:
            threading.excepthook = self.previous_thread_hook


def install_excepthook(parent: QWidget | None = None) -> ExceptionDialogHook:
    """Install (and return) an :class:`ExceptionDialogHook` as ``sys.excepthook``
    (and ``threading.excepthook``)."""
    hook = ExceptionDialogHook(parent)
    sys.excepthook = hook
    threading.excepthook = hook.thread_hook
    return hook


# ------------------------------------------------------------------ window
class MainWindow(QMainWindow):
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

    def __init__(self, face=None, *, path=None, settings: QSettings | None = None,
                 load_default: bool = True, tools: bool = True, parent: QWidget | None = None):
        super().__init__(parent)
        from pyvistaqt import QtInteractor

        from app import scene

        self._scene = scene
        self.settings = settings if settings is not None else QSettings(APP_NAME, APP_NAME)
        from app.document import Document

        self.document = Document(self)
        self.face_actor = None
        self._mode = "textured"
        self._geometry_dirty = False
        self._overlay_dirty = False
        self._closing = False
        self._shown_overlay: tuple = (None, None)
        #: (compute ms, draw ms) of the last viewport tick.
        self.last_tick_ms: tuple[float, float] | None = None
        self._tick_timer = QTimer(self)
        self._tick_timer.setSingleShot(True)
        self._tick_timer.setInterval(0)
        self._tick_timer.timeout.connect(self._tick)
        self._view = "front"
        # The latest load's number, in a plain list the worker threads may read (a closed
        # window's wrapper is not safe to touch from another thread).
        self._latest_load = [0]
        self._loading = False
        self._pool = QThreadPool(self)
        self._pool.setMaxThreadCount(1)
        self._signals = _LoadSignals(self)
        self._signals.progress.connect(self._on_load_progress)
        self._signals.status.connect(self._on_load_status)
        self._signals.loaded.connect(self._on_loaded)
        self._signals.failed.connect(self._on_load_failed)
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
        self.plotter.setAcceptDrops(False)  # drops go to the window (our loader), not pv.read
        self._disable_vtk_keys()
        scene.setup_stage(self.plotter)
        self.setCentralWidget(self.plotter)
        # Camera zoom narrows the view angle; presets and Reset camera restore it.
        self._default_view_angle = float(self.plotter.camera.view_angle)

        self._create_actions()
        self._create_docks()
        self._create_menus()
        self._create_status_bar()
        self._jobs: list[_BackgroundJob] = []
        if tools:  # tests of one dock attach it alone (tools=False)
            self._attach_tools()
        self._restore_window_state()

        if face is not None:
            self.set_face(face)
        elif path is not None:
            self.load_face_file(path, fallback_to_default=load_default)
        elif load_default:
            self.load_default_face()

    @property
    def _generation(self) -> int:
        """Number of the latest load request; results of older ones are ignored."""
        return self._latest_load[0]

    @_generation.setter
    def _generation(self, value: int) -> None:
        self._latest_load[0] = value

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

        self.fap_dock = FapDock(parent=self, message="No face loaded yet.")
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
        self._generation += 1  # ignore loads still running
        self._closing = True
        self._tick_timer.stop()
        self._disconnect_rig()
        self.fap_dock.set_rig(None, "")
        self._pool.clear()
        self._pool.waitForDone(5000)  # a worker must not outlive the window it reports to
        if self._notes_box is not None:
            self._notes_box.close()
        self.plotter.close()
        super().closeEvent(event)

    # ------------------------------------------------------------ recent files
    def recent_files(self) -> list[str]:
        value = self.settings.value("recentFiles", [])
        if value is None:
            return []
        if isinstance(value, str):  # QSettings flattens one-element lists on some backends
            value = [value]
        return [str(v) for v in value if v][:MAX_RECENT]

    def _set_recent_files(self, files: list[str]) -> None:
        self.settings.setValue("recentFiles", list(files)[:MAX_RECENT])
        self._rebuild_recent_menu()

    def add_recent_file(self, path) -> None:
        path = str(Path(path).resolve())
        files = [f for f in self.recent_files() if f != path]
        self._set_recent_files([path, *files])

    def _create_recent_actions(self) -> None:
        # A fixed set of actions, updated in place: QMenu.clear() deletes
        # actions behind Shiboken's back and crashes when an address is reused.
        menu = self.recent_menu
        self.recent_actions: list[QAction] = []
        for _ in range(MAX_RECENT):
            act = QAction(self)
            act.setVisible(False)
            act.triggered.connect(lambda _c=False, a=act: self.open_recent(str(a.data())))
            menu.addAction(act)
            self.recent_actions.append(act)
        self._recent_empty_action = QAction("(no recent files)", self)
        self._recent_empty_action.setEnabled(False)
        menu.addAction(self._recent_empty_action)
        self._recent_separator = menu.addSeparator()
        self._recent_clear_action = QAction("Clear list", self)
        self._recent_clear_action.triggered.connect(lambda: self._set_recent_files([]))
        menu.addAction(self._recent_clear_action)

    def _rebuild_recent_menu(self) -> None:
        files = self.recent_files()
        for i, act in enumerate(self.recent_actions):
            if i < len(files):
                act.setText(f"&{i + 1}  {Path(files[i]).name}")
                act.setData(files[i])
                act.setToolTip(files[i])
                act.setStatusTip(files[i])
            act.setVisible(i < len(files))
        self._recent_empty_action.setVisible(not files)
        self._recent_separator.setVisible(bool(files))
        self._recent_clear_action.setVisible(bool(files))

    def open_recent(self, path: str) -> None:
        """Open a recent file; a missing one is dropped from the list with a message."""
        if not Path(path).is_file():
            self._set_recent_files([f for f in self.recent_files() if f != path])
            self.show_error("File not found", f"{path}\n\nno longer exists and was removed from the recent files.")
            return
        self.load_face_file(path)

    # ------------------------------------------------------------ messages
    def show_error(self, title: str, message: str) -> None:
        """A modal warning; the single place errors reach the user (tests patch it)."""
        first = message.splitlines()[0] if message else title
        self.statusBar().showMessage(first if len(first) <= 140 else first[:139] + "…", 8000)
        QMessageBox.warning(self, title, message)

    def _show_notes(self, notes: list[str], name: str) -> None:
        """Non-modal list of what the loader did (repairs, unit conversion)."""
        if self._notes_box is not None:
            self._notes_box.close()
            self._notes_box.deleteLater()
        box = QMessageBox(QMessageBox.Icon.Information, "Notes on loading",
                          f"While loading {name}:", QMessageBox.StandardButton.Ok, self)
        box.setInformativeText("\n".join(f"• {n}" for n in notes))
        box.setModal(False)
        box.setWindowModality(Qt.WindowModality.NonModal)
        box.show()
        self._notes_box = box

    # ------------------------------------------------------------ loading
    @property
    def is_loading(self) -> bool:
        return self._loading

    def load_face_file(self, path, *, fallback_to_default: bool = False) -> None:
        """Load ``path`` in the background; the path used by File ▸ Open, recent files and drops.

        On success the face is shown (:meth:`set_face`), added to recent files
        and its load notes are shown; on failure a message box explains why
        and the current face stays.
        """
        path = str(path)

        def loader(progress):
            from core.mesh_io import load_face
            from core.registration.correspondence import with_canonical_landmarks

            # A canonical face saved by Build correspondence or 'mimica register' gets its landmarks back.
            return with_canonical_landmarks(load_face(path, progress=progress))

        self._fallback_to_default = fallback_to_default
        self._start_load(path, loader, f"Loading {Path(path).name}…")

    def load_default_face(self) -> None:
        """Load the built-in default face in the background."""

        def loader(progress):
            from core.default_face import load_default_face

            progress(0.0, "Building the default face…")
            return load_default_face()

        self._fallback_to_default = False
        self._start_load("", loader, "Loading the default face…")

    def _start_load(self, path: str, loader: Callable, message: str) -> None:
        self._generation += 1
        self._loading = True
        self.progress_bar.setValue(0)
        self.progress_bar.show()
        self.statusBar().showMessage(message)
        latest = self._latest_load
        self._pool.start(_LoadTask(self._generation, path, loader, self._signals, prepare=build_rig,
                                   wanted=lambda generation: generation == latest[0]))

    @Slot(int, float, str)
    def _on_load_progress(self, generation: int, fraction: float, message: str) -> None:
        if generation != self._generation:
            return
        self.progress_bar.setValue(int(max(0.0, min(1.0, fraction)) * 1000))
        if message:
            self.statusBar().showMessage(message)

    @Slot(int, str)
    def _on_load_status(self, generation: int, message: str) -> None:
        if generation == self._generation:
            self.statusBar().showMessage(message)

    def _finish_load(self) -> None:
        self._loading = False
        self.progress_bar.hide()

    @Slot(int, object, str)
    def _on_loaded(self, generation: int, result, path: str) -> None:
        if generation != self._generation:
            return  # superseded by a newer request
        self._finish_load()
        face, rig = result
        if rig is None:
            self.set_face(face, path=path or None)
        else:
            self.set_face(face, path=path or None, rig=rig[0], rig_message=rig[1])
        if path:
            self.add_recent_file(path)
        notes = list(getattr(face.metadata, "notes", []) or [])
        seen, self._notes_seen = self._notes_seen, None
        if seen is not None:  # an edited copy of the shown face: only what is new is news
            notes = [n for n in notes if n not in seen]
        shown = Path(path).name if path else face.metadata.name
        if notes:
            self.statusBar().showMessage(f"Loaded {shown} — " + "; ".join(notes), 15000)
            if path:  # the built-in face's notes are not news: status bar only
                self._show_notes(notes, shown)
        elif self.rig is None and self.rig_message:
            self.statusBar().showMessage(f"Loaded {shown} — {self.rig_message.splitlines()[0]}", 15000)
        else:
            self.statusBar().showMessage(f"Loaded {shown}", 5000)
        self.load_finished.emit(True)

    @Slot(int, str, str)
    def _on_load_failed(self, generation: int, message: str, path: str) -> None:
        if generation != self._generation:
            return
        self._finish_load()
        self._notes_seen = None
        title = f"Could not open {Path(path).name}" if path else "Could not load the default face"
        if self.face is None and getattr(self, "_fallback_to_default", False):
            # Start the fallback before the (blocking) message box, so the
            # default face is already on screen while the user reads it.
            self.load_default_face()
        self.load_failed.emit(message)
        self.load_finished.emit(False)
        self.show_error(title, message)

    # ------------------------------------------------------------ face
    def set_face(self, face, *, path: str | None = None, rig=_BUILD_RIG, rig_message: str = "") -> None:
        """Display ``face`` (replacing the current one), framed from the front.

        ``rig`` is the face's :class:`core.rig.FaceRig` when already built (the
        background loader builds it); by default it is built here. ``None``
        means the face cannot be animated, ``rig_message`` says why.
        """
        if rig is _BUILD_RIG:
            QApplication.setOverrideCursor(Qt.CursorShape.WaitCursor)
            try:
                rig, rig_message = build_rig(face)
            finally:
                QApplication.restoreOverrideCursor()
        self._tick_timer.stop()
        if self.face_actor is not None:
            self.face_actor.remove()
        self._disconnect_rig()
        self.document.set_face(face, path=path if path is not None else getattr(face.metadata, "source", None),
                               rig=rig, rig_message=rig_message)
        self.face_actor = self._scene.add_face_actor(
            self.plotter, face, self._mode, show_landmarks=self.landmarks_action.isChecked())
        self.landmarks_action.setEnabled(bool(face.landmark_names))
        self.fap_dock.set_feature_points_checked(self.face_actor.landmarks_visible, bool(face.landmark_names))
        self._set_rig(rig, rig_message)
        self.setWindowTitle(f"{APP_NAME} — {face.metadata.name}")
        self._update_status_labels()
        self.set_camera_view("front")
        self.face_changed.emit(face)

    # ------------------------------------------------------------ animation
    def _disconnect_rig(self) -> None:
        if self.rig is not None:
            try:
                self.rig.changed.disconnect(self._on_rig_changed)
            except (ValueError, RuntimeError):
                pass

    def _set_rig(self, rig, message: str = "") -> None:
        self._shown_overlay = (None, None)
        self._geometry_dirty = False
        if rig is not None:
            rig.changed.connect(self._on_rig_changed)
            # The actor starts at the neutral face; show the rig's state if it is not neutral.
            self._geometry_dirty = bool(rig.effective_fap_values().any())
        self.fap_dock.set_rig(rig, self.document.rig_message)
        if rig is None and message:
            self.statusBar().showMessage(message.splitlines()[0], 15000)
        elif rig is not None:
            self.statusBar().clearMessage()
        self._overlay_dirty = True
        self._schedule_tick()

    # The document's state, read through the window by the docks' older code paths.
    face = property(lambda self: self.document.face)
    face_path = property(lambda self: self.document.face_path,
                         lambda self, path: setattr(self.document, "face_path", path))
    rig = property(lambda self: self.document.rig)
    rig_message = property(lambda self: self.document.rig_message)
    undo_stack = property(lambda self: self.document.undo_stack)
    rig_edits = property(lambda self: self.document.rig_edits)

    @property
    def muscle_layer(self):
        """The muscle layer of the current face (built by the muscle dock in the background), or None."""
        return self.document.muscle_layer

    def play_demo(self) -> None:
        """Open the built-in showcase (``mimica demo``) on the timeline and play it in a loop."""
        import tempfile

        from app.demo import demo_project
        from core.project import save_project

        _face, project = demo_project()
        path = Path(tempfile.mkdtemp(prefix="mimica-demo-")) / "demo.mimica"
        save_project(path, project)
        if self.timeline.project.open_project(path, ask=False):
            self.timeline.loop = True
            self.timeline.play()
            self.statusBar().showMessage("Playing the Mimica demo (Space pauses).", 8000)

    # ------------------------------------------------------------ tools (landmarks, muscles, timeline)
    def _attach_tools(self) -> None:
        """Docks that live in their own modules attach themselves (menus and signals included)."""
        from app.landmark_dock import attach_landmark_editor

        from app.muscle_dock import attach_muscle_dock

        self.landmark_editor = attach_landmark_editor(self)
        self.muscle_dock = attach_muscle_dock(self)  # after the landmark editor: it uses window.undo_stack
        from app.timeline_dock import attach_timeline

        attach_timeline(self)  # sets self.timeline; reuses the undo stack and Edit menu
        # The timeline starts tall enough to show a few tracks.
        self.resizeDocks([self.timeline.dock], [260], Qt.Orientation.Vertical)
        self.landmark_dock.detect_requested.connect(self.detect_landmarks)
        self.landmark_dock.build_requested.connect(self.build_correspondence)

    def _run_job(self, work: Callable[[], object], done: Callable[[object], None], title: str,
                 message: str) -> None:
        """Run ``work`` in the background with a busy indicator; errors go to a message box."""
        job = _BackgroundJob(work)
        self._jobs.append(job)

        def finish(*_):
            if job in self._jobs:
                self._jobs.remove(job)
            if not self._jobs:
                self.progress_bar.setRange(0, 1000)
                self.progress_bar.hide()

        def ok(result):
            finish()
            if not self._closing:
                done(result)

        def failed(text):
            finish()
            if not self._closing:
                self.show_error(title, text)

        job.signals.done.connect(ok)
        job.signals.failed.connect(failed)
        self.progress_bar.setRange(0, 0)  # busy
        self.progress_bar.show()
        self.statusBar().showMessage(message)
        self._pool.start(job)

    def detect_landmarks(self, fixed: dict | None = None) -> None:
        """Detect the MPEG-4 landmarks on the current face (keeping ``fixed`` ones), in the background."""
        if self.face is None:
            return
        face = self.face

        def work():
            from core.registration.pipeline import detect_landmarks

            return detect_landmarks(face, fixed=fixed or None)

        def done(detection):
            if self.face is not face:
                return  # the face changed meanwhile
            if detection.scale_hint and self._accept_scale_hint(detection.scale_hint):
                self._rescale_with_detection(detection)
                return
            self.landmark_editor.apply_detection(detection.landmarks, detection.confidence)
            self._report_detection(detection)

        what = "Re-running matching with your edits fixed…" if fixed else "Detecting landmarks…"
        self._run_job(work, done, "Cannot detect landmarks", what)

    def _accept_scale_hint(self, factor: float) -> bool:
        """Ask whether to scale a face whose units are evidently not millimetres."""
        width = float(np.ptp(self.face.vertices[:, 0]))
        answer = QMessageBox.question(
            self, "Scale the face?",
            f"This face is {factor:.2f} times {'smaller' if factor > 1 else 'larger'} than a human face "
            f"({width:.0f} mm wide as loaded): its file's units are probably not millimetres.\n\n"
            f"Scale it by {factor:.3g}? Distances in mm and the muscle model need the real size; the "
            "landmarks were found either way.",
            QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No, QMessageBox.StandardButton.Yes)
        return answer == QMessageBox.StandardButton.Yes

    def _rescale_with_detection(self, detection) -> None:
        """Scale the face by the detection's factor, then put the detection (with its confidences) on
        the scaled face: surface points do not change with scale."""
        factor = detection.scale_hint

        def reapply(ok: bool) -> None:
            self.load_finished.disconnect(reapply)
            if ok:
                self.landmark_editor.apply_detection(detection.landmarks, detection.confidence)
                self._report_detection(detection)

        self.load_finished.connect(reapply)
        self.scale_face(factor)

    def _report_detection(self, detection) -> None:
        low = detection.low_confidence()
        note = f"; {len(low)} with low confidence are worth checking" if low else ""
        self.statusBar().showMessage(
            f"Detected {len(detection.landmarks)} landmarks in {detection.timings.get('total_s', 0):.1f} s{note}.",
            15000)
        if detection.report:
            self._show_notes(detection.report, "landmark detection")

    def build_correspondence(self) -> None:
        """Register the current face to the MPEG-4 template and switch the view to the canonical face."""
        if self.face is None:
            return
        face = self.face
        landmarks = dict(face.landmarks)

        def loader(progress):
            from core.registration.pipeline import register_scan

            progress(0.1, "Building the dense correspondence…")
            registration = register_scan(face, landmarks)
            return registration.face

        self._fallback_to_default = False
        self._start_load("", loader, "Building the canonical face from the landmarks…")

    def replace_face(self, face, message: str) -> None:
        """Show an edited copy of the current face; its rig is rebuilt in the background."""
        self._fallback_to_default = False
        self._notes_seen = list(self.face.metadata.notes) if self.face is not None else None
        self._start_load(self.face_path or "", lambda progress: face, message)

    def scale_face(self, factor: float) -> None:
        """Scale the current face by ``factor`` (ValueError with a message for a bad factor)."""
        if self.face is None:
            return
        face = self.face.scaled(factor)
        face.metadata.notes.append(f"Scaled by {factor:.4g} in Mimica.")  # scaled() copied the notes
        self.replace_face(face, f"Scaling the face by {factor:g}…")

    def scale_face_dialog(self) -> None:
        from PySide6.QtWidgets import QInputDialog

        if self.face is None:
            return
        width = float(self.face.bounds[1, 0] - self.face.bounds[0, 0])
        factor, ok = QInputDialog.getDouble(
            self, "Scale face",
            f"The face is {width:.0f} mm wide (an adult face is about 140 mm across the cheeks).\n"
            "Scale factor (10 turns centimetres into millimetres):", 1.0, 0.001, 1000.0, 4)
        if ok and factor != 1.0:
            try:
                self.scale_face(factor)
            except ValueError as exc:
                self.show_error("Cannot scale the face", str(exc))

    def load_texture(self, path) -> None:
        """Map the image at ``path`` onto the current face (errors in a message box)."""
        from core.mesh_io import MeshLoadError, load_texture_image

        if self.face is None:
            return
        try:
            face = self.face.with_texture(load_texture_image(path))
        except (MeshLoadError, ValueError) as exc:
            self.show_error("Cannot load the texture", str(exc))
            return
        self.replace_face(face, f"Applying the texture {Path(path).name}…")

    def flip_texture(self) -> None:
        """Show the current face with its texture image upside down (an undo is flipping again)."""
        if self.face is None:
            return
        if self.face.texture is None or self.face.uv is None:
            self.show_error("Cannot flip the texture", "This face has no texture image. Load one first with "
                            "Tools > Load texture image…")
            return
        self.replace_face(self.face.with_flipped_texture(), "Flipping the texture…")

    def load_texture_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Load texture image", "",
                                              "Images (*.png *.jpg *.jpeg *.bmp *.tif *.tiff);;All files (*)")
        if path:
            self.load_texture(path)

    def rebuild_animation(self) -> None:
        """Rebuild the animation rig (FAPs, muscles) from the current, corrected landmarks."""
        if self.face is None:
            return
        self.replace_face(self.face, "Rebuilding the animation from the corrected landmarks…")

    def _on_rig_changed(self) -> None:
        self._geometry_dirty = True
        self._schedule_tick()

    def _on_overlay_changed(self) -> None:
        self._overlay_dirty = True
        self._schedule_tick()

    def _viewport_alive(self) -> bool:
        return not self._closing and not getattr(self.plotter, "_closed", False)

    def _schedule_tick(self) -> None:
        # One pending single-shot timer at most: a burst of changes costs one redraw.
        if self._viewport_alive() and not self._tick_timer.isActive():
            self._tick_timer.start()

    def flush_updates(self) -> None:
        """Run a pending viewport update now (tests and scripts; the timer does it otherwise)."""
        if self._tick_timer.isActive():
            self._tick_timer.stop()
            self._tick()

    @Slot()
    def _tick(self) -> None:
        """Pull the rig's state into the viewport once (see the module docstring)."""
        actor, rig = self.face_actor, self.rig
        geometry, overlay_dirty = self._geometry_dirty, self._overlay_dirty
        self._geometry_dirty = self._overlay_dirty = False
        if actor is None or not self._viewport_alive():
            return
        start = time.perf_counter()
        vertices = normals = None
        if geometry and rig is not None:
            vertices = rig.vertices()
            normals = actor.compute_normals(vertices)
        kind, number = self.fap_dock.overlay() if rig is not None else (None, None)
        scalars = None
        if kind == "heat" and (vertices is not None or overlay_dirty or self._shown_overlay != (kind, number)):
            scalars = rig.displacement_magnitude()
        elif kind == "influence" and self._shown_overlay != (kind, number):
            scalars = rig.fap_influence(number)
        computed = time.perf_counter()
        if vertices is None and scalars is None and (kind is not None or not actor.scalars_visible):
            return  # nothing to draw
        if vertices is not None:
            actor.update_vertices(vertices, normals)
        if kind is None:
            actor.clear_scalars()
        elif scalars is not None:
            if kind == "heat":
                actor.show_scalars(scalars, cmap="YlOrRd", clim=(0.0, _nice_ceiling(float(scalars.max()))),
                                   title="Displacement (mm)", fmt="%.1f")
            else:
                from core.fap.tables import fap_spec

                actor.show_scalars(scalars, cmap="PuBu", clim=(0.0, 1.0), title=f"FAP {number} influence",
                                   fmt="%.1f")
                self.statusBar().showMessage(
                    f"Influence of FAP {number} {fap_spec(number).name}: 1 = moves fully, 0 = not at all", 4000)
        self._shown_overlay = (kind, number)
        self._render()
        drawn = time.perf_counter()
        if vertices is not None:
            self.last_tick_ms = ((computed - start) * 1e3, (drawn - computed) * 1e3)
            compute_ms, draw_ms = self.last_tick_ms
            self.tick_label.setText(f"update: compute {compute_ms:.1f} ms · draw {draw_ms:.1f} ms")

    def _render(self) -> None:
        # Rendering a never-shown VTK widget has no GL context to draw into;
        # the first paint event renders it anyway.
        if self.plotter.isVisible() and not getattr(self.plotter, "_closed", False):
            self.plotter.render()

    def update_vertices(self, vertices) -> None:
        """Move the displayed face to new vertex positions in place (for animation)."""
        if self.face_actor is None:
            return
        self.face_actor.update_vertices(vertices)
        self._render()

    def _update_status_labels(self) -> None:
        face = self.face
        if face is None:
            for label in (self.file_label, self.counts_label, self.units_label, self.texture_label):
                label.setText("")
            self.file_label.setText("no face")
            return
        # A "source" like "built-in" is not a file: show the face's name then.
        is_file = bool(self.face_path) and Path(self.face_path).suffix.lower() in OPEN_SUFFIXES
        name = Path(self.face_path).name if is_file else face.metadata.name
        self.file_label.setText(name)
        self.file_label.setToolTip(self.face_path or "")
        self.counts_label.setText(f"{face.n_vertices:,} vertices · {face.n_triangles:,} triangles")
        self.units_label.setText(f"units: {face.metadata.units}")
        has_tex = face.texture is not None and face.uv is not None
        self.texture_label.setText("texture: yes" if has_tex else "texture: no")

    # ------------------------------------------------------------ view
    @property
    def view_mode(self) -> str:
        return self._mode

    def set_view_mode(self, mode: str) -> None:
        """textured, shaded, wireframe or points."""
        mode = mode.lower()
        if mode not in MODE_LABELS:
            raise ValueError(f"unknown display mode {mode!r}")
        self._mode = mode
        self.mode_actions[mode].setChecked(True)
        if self.face_actor is not None:
            self.face_actor.set_mode(mode)
            if mode == "textured" and not self.face_actor.has_texture:
                fallback = "vertex colours" if self.face_actor.has_vertex_colors else "skin shading"
                self.statusBar().showMessage(f"This face has no texture; showing {fallback}.", 5000)
            self._render()

    def set_landmarks_visible(self, visible: bool) -> None:
        self.landmarks_action.setChecked(bool(visible))
        if self.face_actor is not None:
            self.face_actor.set_landmarks_visible(visible)
            self._render()

    def set_camera_view(self, view: str) -> None:
        """front, side or three-quarter, framed on the face."""
        self._view = view
        if self.face_actor is None:
            return
        self.plotter.camera.view_angle = self._default_view_angle
        self._scene.set_camera_view(self.plotter, view, self.face_actor.mesh.points)
        self._render()

    def reset_camera(self) -> None:
        """Frame the whole face, keeping the viewing direction."""
        if self.face_actor is None:
            return
        self.plotter.camera.view_angle = self._default_view_angle
        self._scene.frame_points(self.plotter, self.face_actor.mesh.points)
        self._render()

    # ------------------------------------------------------------ file dialogs
    def _last_dir(self) -> str:
        return str(self.settings.value("lastDirectory", str(Path.home())))

    def open_face_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open face", self._last_dir(), OPEN_FILTER)
        if path:
            self.settings.setValue("lastDirectory", str(Path(path).parent))
            self.load_face_file(path)

    def save_face_dialog(self) -> None:
        if self.face is None:
            return
        default = str(Path(self._last_dir()) / f"{self.face.metadata.name}.obj")
        path, chosen = QFileDialog.getSaveFileName(self, "Save face as", default, ";;".join(SAVE_FILTERS))
        if path:
            if Path(path).suffix.lower() not in SAVE_FILTERS.values():
                path += SAVE_FILTERS.get(chosen, ".obj")
            self.settings.setValue("lastDirectory", str(Path(path).parent))
            self.save_face_file(path)

    def save_face_file(self, path) -> bool:
        """Save the displayed face; errors become a message box. Returns success."""
        if self.face is None:
            return False
        try:
            from core.mesh_io import save_face

            QApplication.setOverrideCursor(Qt.CursorShape.WaitCursor)
            try:
                save_face(self.face, path)
            finally:
                QApplication.restoreOverrideCursor()
        except Exception as exc:  # noqa: BLE001
            if _is_mesh_save_error(exc):
                message = str(exc)
            else:
                traceback.print_exc()
                message = f"{type(exc).__name__}: {exc}"
            self.show_error(f"Could not save {Path(path).name}", message)
            return False
        self.statusBar().showMessage(f"Saved {path}", 5000)
        return True

    def export_screenshot_dialog(self) -> None:
        default = str(Path(self._last_dir()) / "mimica.png")
        path, chosen = QFileDialog.getSaveFileName(self, "Export screenshot", default, SCREENSHOT_FILTER)
        if path:
            if Path(path).suffix.lower() not in (".png", ".jpg", ".jpeg"):
                path += ".jpg" if chosen.startswith("JPEG") else ".png"
            try:
                self.screenshot(path)
            except (OSError, ValueError) as exc:
                self.show_error("Could not export screenshot", str(exc))
                return
            self.statusBar().showMessage(f"Saved screenshot {path}", 5000)

    def screenshot(self, path=None):
        """Render the viewport; write it to ``path`` (png/jpg) if given. Returns the RGB image."""
        from app.render import save_image

        self.plotter.render()
        image = self.plotter.screenshot(None, return_img=True)[..., :3]
        if path is not None:
            save_image(image, path)
        return image

    # ------------------------------------------------------------ drag & drop
    @staticmethod
    def _dropped_face_files(mime) -> list[str]:
        if not mime.hasUrls():
            return []
        paths = [u.toLocalFile() for u in mime.urls() if u.isLocalFile()]
        return [p for p in paths if Path(p).suffix.lower() in OPEN_SUFFIXES and Path(p).is_file()]

    def dragEnterEvent(self, event) -> None:  # noqa: N802 - Qt override
        if self._dropped_face_files(event.mimeData()):
            event.acceptProposedAction()
        else:
            event.ignore()

    def dragMoveEvent(self, event) -> None:  # noqa: N802 - Qt override
        self.dragEnterEvent(event)

    def dropEvent(self, event) -> None:  # noqa: N802 - Qt override
        files = self._dropped_face_files(event.mimeData())
        if not files:
            event.ignore()
            return
        event.acceptProposedAction()
        if len(files) > 1:
            self.statusBar().showMessage(f"Opening the first of {len(files)} dropped files", 5000)
        self.load_face_file(files[0])

    # ------------------------------------------------------------ help
    def about_text(self) -> str:
        import PySide6
        import pyvista as pv
        import vtk
        from PySide6.QtCore import qVersion

        return (
            f"<h3>Mimica {__version__}</h3>"
            "<p>A desktop workbench for 3-D facial animation.</p>"
            "<p>"
            f"Python {sys.version.split()[0]}<br>"
            f"Qt {qVersion()} / PySide6 {PySide6.__version__}<br>"
            f"VTK {vtk.vtkVersion.GetVTKVersion()}<br>"
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
    if demo:
        def start_demo(ok: bool) -> None:
            window.load_finished.disconnect(start_demo)
            if ok:
                QTimer.singleShot(1500, window.play_demo)  # let the muscle model build first

        window.load_finished.connect(start_demo)
    window.show()
    # Ctrl+C in the terminal: the Python handler only runs when the
    # interpreter gets control, so wake it periodically.
    timer = QTimer(window)
    timer.timeout.connect(lambda: None)
    timer.start(250)
    return int(app.exec())


__all__ = ["MainWindow", "ExceptionDialogHook", "install_excepthook", "run_gui"]
