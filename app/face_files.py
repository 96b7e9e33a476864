"""face_files.py
----
Faces in and out of the main window: loading a face file or the built-in face in the background
(the rig is built there too, so the GUI thread never waits; a newer load supersedes an older one),
the recent-files menu, Open / Save as / Export screenshot dialogs, and files dropped anywhere on the
window (opened by what they are: :meth:`FaceFilesMixin.open_path`). Every failure is a message box
naming the file and what to do; the face shown stays.

A mixin of :class:`app.main_window.MainWindow` (it uses the window's settings, status bar, progress
bar and ``set_face``).
"""

from __future__ import annotations

import traceback
from pathlib import Path
from typing import Callable

from PySide6.QtCore import Qt
from PySide6.QtGui import QAction
from PySide6.QtWidgets import QApplication, QDockWidget, QFileDialog

from app.document import PREPARING_MESSAGE, build_rig

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
PROJECT_SUFFIX = ".mimica"
ANIMATION_SUFFIXES = (".fap", ".dpc")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _is_mesh_save_error(exc: BaseException) -> bool:
    from core.formats.mesh_io import MeshSaveError

    return isinstance(exc, MeshSaveError)


class FaceFilesMixin:
    """Loading, recent files and the face file dialogs of the main window."""

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
        """Open a recent file (a face or a project); a missing one is dropped from the list with a message."""
        if not Path(path).is_file():
            self._set_recent_files([f for f in self.recent_files() if f != path])
            self.show_error("File not found", f"{path}\n\nno longer exists and was removed from the recent files.")
            return
        self.open_path(path)

    def open_path(self, path) -> bool:
        """Open whatever ``path`` is, by its suffix: a face mesh, a project, an animation (.fap, DPC:
        onto the timeline) or an image (the face's texture). Anything else: a message naming what
        Mimica opens. Returns True when it was taken."""
        path = str(path)
        suffix = Path(path).suffix.lower()
        project, timeline = self.document.project, self.document.timeline
        if suffix in OPEN_SUFFIXES:
            self.load_face_file(path)
        elif suffix == PROJECT_SUFFIX and project is not None:
            project.open_project(path)
        elif suffix in ANIMATION_SUFFIXES and timeline is not None:
            timeline.import_animation(path, warn=self.show_error)   # a refused file says why in a box
        elif suffix in IMAGE_SUFFIXES:
            if self.face is None:
                self.show_error("No face for this image", f"{Path(path).name} is an image: open a face first, then "
                                "drop the image on it (or use Tools ▸ Load texture image…) to use it as its texture.")
                return False
            self.load_texture(path)
        else:
            self.show_error("Cannot open this file", f"{Path(path).name}: Mimica opens faces ({', '.join(OPEN_SUFFIXES)}), "
                            f"projects ({PROJECT_SUFFIX}), animations ({', '.join(ANIMATION_SUFFIXES)}) and texture "
                            f"images ({', '.join(IMAGE_SUFFIXES)}).")
            return False
        return True

    # ------------------------------------------------------------ loading
    # ------------------------------------------------------------ drag & drop
    def _take_drops(self) -> None:
        """Drops anywhere in the window (viewport, any dock) reach :meth:`dropEvent` (through the
        window's event filter): Qt would otherwise hand them to whichever child happens to accept
        drops, or to nobody."""
        for widget in (self.plotter, *self.findChildren(QDockWidget)):
            if not widget.property("mimicaDrops"):
                widget.setProperty("mimicaDrops", True)
                widget.setAcceptDrops(True)
                widget.installEventFilter(self)

    @staticmethod
    def _dropped_files(mime) -> list[str]:
        if not mime.hasUrls():
            return []
        return [u.toLocalFile() for u in mime.urls() if u.isLocalFile() and Path(u.toLocalFile()).is_file()]

    def dragEnterEvent(self, event) -> None:  # noqa: N802 - Qt override
        # Any local file is taken: what it is decides on drop, and a file Mimica cannot open gets a
        # message there instead of a silent "no entry" cursor.
        if self._dropped_files(event.mimeData()):
            event.acceptProposedAction()
        else:
            event.ignore()

    def dragMoveEvent(self, event) -> None:  # noqa: N802 - Qt override
        self.dragEnterEvent(event)

    def dropEvent(self, event) -> None:  # noqa: N802 - Qt override
        files = self._dropped_files(event.mimeData())
        if not files:
            event.ignore()
            return
        event.acceptProposedAction()
        if len(files) > 1:
            self.statusBar().showMessage(f"Opening the first of {len(files)} dropped files", 5000)
        self.open_path(files[0])

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
            from core.registration.correspondence import load_face_or_canonical

            # A canonical face saved by Build correspondence or 'mimica register' is kept whole and gets
            # its landmarks back.
            return load_face_or_canonical(path, progress=progress)

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
        """Run ``loader(progress)`` in the background and show the face as soon as it is loaded;
        then build its rig in the background too (from the disk cache in a moment, else seconds for
        a 50k-vertex face, with progress), and hand it to the docks. A newer load supersedes this one."""
        self._loading = True
        self.progress_bar.setRange(0, 1000)
        self.progress_bar.setValue(0)
        self.progress_bar.show()
        self.statusBar().showMessage(message)

        def work(job):
            return loader(job.progress)

        self.loads.start(work, lambda face: self._on_loaded(face, path),
                         lambda text: self._on_load_failed(text, path), self._on_load_progress)

    def _on_load_progress(self, fraction: float | None, message: str) -> None:
        if fraction is not None:
            self.progress_bar.setValue(int(max(0.0, min(1.0, fraction)) * 1000))
        if message:
            self.statusBar().showMessage(message)

    def _finish_load(self) -> None:
        self._loading = False
        self.progress_bar.hide()

    def _on_loaded(self, face, path: str) -> None:
        if face is None:
            return
        notes = list(getattr(face.metadata, "notes", []) or [])
        notes_before_build = list(notes)   # what the rig build adds (the cache's news) is told after it
        seen, self._notes_seen = self._notes_seen, None
        if seen is not None:  # an edited copy of the shown face: only what is new is news
            notes = [n for n in notes if n not in seen]
        shown = Path(path).name if path else face.metadata.name

        def work(job):
            return build_rig(face, progress=job.progress)   # build_rig never raises

        # The rig builds (or loads from the cache) on the loader thread while this thread shows the
        # face: its result arrives through the event loop, after set_face below.
        self.loads.start(work, lambda result: self._on_rig_built(face, result, shown, notes, notes_before_build),
                         lambda text: self._on_load_failed(text, path), self._on_load_progress)
        self.set_face(face, path=path or None, rig=None, rig_message=PREPARING_MESSAGE, rig_pending=True)
        if path:
            self.add_recent_file(path)
        if notes:
            self.statusBar().showMessage(f"Loaded {shown} — " + "; ".join(notes), 15000)
            if path:  # the built-in face's notes are not news: status bar only
                self._show_notes(notes, shown)
        self.progress_bar.setValue(0)

    def _on_rig_built(self, face, result, shown: str, notes: list[str], notes_before_build: list[str]) -> None:
        self._finish_load()
        if self.face is not face:   # the user moved on
            return
        rig, message = result
        self.document.set_rig(rig, message)
        build_notes = [n for n in getattr(face.metadata, "notes", []) or [] if n not in notes_before_build]
        if build_notes:   # e.g. a damaged cache entry was rebuilt (build_rig adds the cache's notes)
            self.statusBar().showMessage(build_notes[0], 15000)
        elif notes:   # back to the load notes, after the build's progress messages
            self.statusBar().showMessage(f"Loaded {shown} — " + "; ".join(notes), 15000)
        elif rig is None and message:
            self.statusBar().showMessage(f"Loaded {shown} — {message.splitlines()[0]}", 15000)
        else:
            self.statusBar().showMessage(f"Loaded {shown}", 5000)
        self.load_finished.emit(True)

    def _on_load_failed(self, message: str, path: str) -> None:
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

    # ------------------------------------------------------------ file dialogs
    def _last_dir(self) -> str:
        return str(self.settings.value("lastDirectory", str(Path.home())))

    def open_face_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open face", self._last_dir(), OPEN_FILTER)
        if path:
            self.settings.setValue("lastDirectory", str(Path(path).parent))
            self.load_face_file(path)

    def save_face_dialog(self) -> None:
        """File ▸ Save face as…: the displayed face."""
        if self.face is not None:
            self.ask_and_save_face(self.face, "Save face as", self.face.metadata.name or "face")

    def ask_and_save_face(self, face, title: str, name: str) -> None:
        """Ask where to save ``face`` (suggesting ``name``.obj in the last folder) and save it there."""
        default = str(Path(self._last_dir()) / f"{name}.obj")
        path, chosen = QFileDialog.getSaveFileName(self, title, default, ";;".join(SAVE_FILTERS))
        if path:
            if Path(path).suffix.lower() not in SAVE_FILTERS.values():
                path += SAVE_FILTERS.get(chosen, ".obj")
            self.settings.setValue("lastDirectory", str(Path(path).parent))
            self.save_face_file(path, face)

    def save_face_file(self, path, face=None) -> bool:
        """Save ``face`` (default: the displayed face); errors become a message box. Returns success."""
        face = face if face is not None else self.face
        if face is None:
            return False
        try:
            from core.formats.mesh_io import save_face

            QApplication.setOverrideCursor(Qt.CursorShape.WaitCursor)
            try:
                save_face(face, path)
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

        self.viewport.flush()   # the full-quality face, never the draft drawn while things move
        self.plotter.render()
        image = self.plotter.screenshot(None, return_img=True)[..., :3]
        if path is not None:
            save_image(image, path)
        return image


__all__ = ["FaceFilesMixin", "MAX_RECENT", "OPEN_SUFFIXES", "SAVE_FILTERS", "OPEN_FILTER", "SCREENSHOT_FILTER"]
