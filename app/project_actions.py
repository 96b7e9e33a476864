"""project_actions.py
----
File ▸ New / Open… / Save / Save As… for Mimica projects (``.mimica``, :mod:`core.formats.project`), the
window title, autosave and crash recovery.

* A project is the face (the built-in default face is stored by name; a face from a file by its
  path; a face that exists only in memory is written beside the project by ``core.formats.project.embed_face``),
  its landmarks, the rig's values, the timeline, the speech clips and the view: camera
  (position, focal point, up, view angle), display mode, landmarks shown, FAP-dock overlays, and the
  timeline's cursor / loop / speed / "show all" / folded groups.
* Opening restores all of it. When the project's face is the face already shown (same built-in
  face or same file, same landmarks) the face and its rig are kept (no rebuild); otherwise the face
  is loaded and its rig built on a worker thread (seconds for a 50k-vertex face), then shown. The rig
  values are applied *after* the cursor is placed, so values the user set by hand on tracked
  parameters come back exactly as saved. A corrupt file, a file from a newer Mimica or a missing
  face file shows ``core.formats.project``'s message in a warning and leaves the open project untouched.
* Modified = the undo stack is not at its clean index, or something not on the stack changed (a
  different face, a recovered autosave). The title is ``<project>[*] — <face> — Mimica``.
* Autosave every 3 minutes (when modified since the last one) through ``core.formats.project.write_autosave``,
  captured on the GUI thread and serialised and written on a worker thread (no freeze): beside a saved project, or ``<state dir>/untitled-<pid>-<n>.mimica.autosave`` for an untitled one.
  Saving deletes the autosave. After opening a project whose autosave is newer, and at start-up for
  untitled autosaves left by a Mimica process that is no longer running, a question offers to
  recover it (Yes = recover, Discard = delete it; anything else keeps it for later). A recovered
  autosave is removed only once the recovered project is on screen and written again as this
  session's autosave (a crash or a quit at any moment of a recovery loses nothing).
* Choice: closing the window never blocks on a question. Unsaved work is written to the autosave
  on close and offered at the next start (``ask_on_close = True`` asks Save / Discard / Cancel
  instead). New and Open do ask before dropping unsaved changes.
* The state dir defaults to ``autosave/`` beside the window's settings file (so isolated settings,
  e.g. in tests, isolate autosaves too); pass ``state_dir`` to choose another.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import traceback
from pathlib import Path

import shiboken6
from PySide6.QtCore import QEvent, QObject, QSettings, Qt, QTimer, Signal
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import QApplication, QFileDialog, QMessageBox

from core.formats import project as cp
from core.timeline import Timeline
from app.jobs import JobRunner
from app.project_recovery import ProjectRecoveryMixin

AUTOSAVE_MS = 3 * 60 * 1000
PROJECT_FILTER = "Mimica project (*.mimica);;All files (*)"
_UNTITLED = itertools.count(1)


def _fingerprint(face) -> str:
    """What a face shows (geometry, uv, texture, colours), hashed: tells a face read from a file from
    one derived from it in memory (~3 ms for the default face)."""
    import hashlib

    import numpy as np

    h = hashlib.blake2b(digest_size=16)
    for array in (face.vertices, face.triangles, face.uv, face.texture, getattr(face, "vertex_colors", None)):
        if array is not None:
            array = np.ascontiguousarray(array)
            h.update(str(array.shape).encode() + array.dtype.str.encode())
            h.update(memoryview(array).cast("B"))
        else:
            h.update(b"-")
    return h.hexdigest()


def default_state_dir(window) -> Path:
    settings = window.settings
    if isinstance(settings, QSettings) and settings.fileName():
        return Path(settings.fileName()).resolve().parent / "autosave"
    return cp.default_state_dir()


class ProjectActions(ProjectRecoveryMixin, QObject):
    """The project of a :class:`app.document.Document` with its
    :class:`~app.timeline_controller.TimelineController`, in a MainWindow (menus, view, status bar).

    Attributes: ``path`` (the document's ``project_path``: Path or None = untitled), ``new_action``,
    ``open_action``, ``save_action``, ``save_as_action``, ``autosave_timer``, ``ask_on_close``.
    """

    project_opened = Signal(object)  # Path or None

    def __init__(self, document, window, controller, *, state_dir=None, autosave_ms: int = AUTOSAVE_MS):
        super().__init__(window)
        self.document = document
        self.window = window
        self.c = controller
        self.stack = document.undo_stack
        self.path = None
        self.state_dir = Path(state_dir) if state_dir is not None else default_state_dir(window)
        self.untitled_id = f"untitled-{os.getpid()}-{next(_UNTITLED)}"
        self.ask_on_close = False
        self._dirty = False
        self._autosaved = None  # (stack index, dirty) at the last autosave
        self._face_ref: tuple | None = None  # (id(face), FaceRef) of a face loaded from / embedded for a project
        self._applying_face = False
        # An opened project's face loads (with its rig) in the background; a newer open supersedes it.
        self._loads = JobRunner(self, supersede=True)
        self._pending: tuple | None = None
        self._accepted_face: str | None = None   # a face path outside the project the user agreed to open
        self._pending_values: dict[str, float] = {}  # opened values of layers not built yet
        self._closed = False
        self._had_face = document.face is not None
        self._recovering: tuple | None = None  # (autosave path, project) while a recovery is applied
        self._source_face: tuple | None = None  # (face path, fingerprint) of the face as read from its file
        if document.face is not None and document.face_path:
            self._source_face = (document.face_path, _fingerprint(document.face))

        self._create_actions()
        self.stack.cleanChanged.connect(self._on_stack_changed)
        self.stack.indexChanged.connect(self._on_stack_changed)
        document.face_changed.connect(self._on_face_changed)
        self.autosave_timer = QTimer(self)
        self.autosave_timer.setInterval(int(autosave_ms))
        self.autosave_timer.timeout.connect(self.autosave_in_background)
        self.autosave_timer.start()
        window.installEventFilter(self)
        self.update_title()

    # ------------------------------------------------------------ actions / menu
    def _create_actions(self) -> None:
        w = self.window

        def action(text, slot, shortcut, tip):
            act = QAction(text, w)
            if shortcut is not None:
                act.setShortcut(QKeySequence(shortcut))
                act.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
            act.setStatusTip(tip)
            act.triggered.connect(lambda _c=False: slot())
            w.addAction(act)
            return act

        # The project takes the usual document shortcuts (the window gives faces Ctrl+I).
        self.new_action = action("&New project", self.new_project, QKeySequence.StandardKey.New,
                                 "Start an empty project (keeps the face)")
        self.open_action = action("&Open project…", self.open_dialog, QKeySequence.StandardKey.Open,
                                  "Open a Mimica project (.mimica)")
        self.save_action = action("&Save project", self.save, QKeySequence.StandardKey.Save,
                                  "Save the project (face reference, landmarks, rig, timeline, view)")
        self.save_as_action = action("Save project &as…", self.save_as_dialog, "Ctrl+Shift+S",
                                     "Save the project under a new name")
        file_menu = None
        for act in w.menuBar().actions():
            if act.menu() is not None and act.text().replace("&", "") == "File":
                file_menu = act.menu()
                break
        if file_menu is None:
            file_menu = w.menuBar().addMenu("&File")
        first = file_menu.actions()[0] if file_menu.actions() else None
        for act in (self.new_action, self.open_action, self.save_action, self.save_as_action):
            file_menu.insertAction(first, act)
        if first is not None:
            file_menu.insertSeparator(first)

    # ------------------------------------------------------------ state
    @property
    def path(self) -> Path | None:
        """The open project's file (None: untitled); kept by the document."""
        return self.document.project_path

    @path.setter
    def path(self, path) -> None:
        self.document.project_path = Path(path) if path is not None else None

    @property
    def is_modified(self) -> bool:
        return self._dirty or not self.stack.isClean()

    @property
    def name(self) -> str:
        return self.path.name.removesuffix(cp.SUFFIX) if self.path is not None else "Untitled"

    def _on_stack_changed(self, *_args) -> None:
        self.update_title()

    def update_title(self) -> None:
        w = self.window
        if self._closed or not shiboken6.isValid(w):
            return  # the stack emits while the window is being destroyed
        face = self.document.face
        face_name = f" — {face.metadata.name}" if face is not None else ""
        w.setWindowTitle(f"{self.name}[*]{face_name} — Mimica")
        w.setWindowModified(self.is_modified)

    def _on_face_changed(self, _face=None) -> None:
        # The first face of a session (the start-up load) is not an edit; replacing it is.
        if not self._applying_face and self._had_face:
            self._dirty = True
        self._had_face = self.document.face is not None
        face, path = self.document.face, self.document.face_path
        if face is not None and path and (self._source_face is None or self._source_face[0] != path):
            # The first face shown for a path is that file's (or the built-in face) as read; a face
            # derived from it later (scaled, retextured, flipped) keeps the path but not the content.
            self._source_face = (path, _fingerprint(face))
        self.update_title()

    def _mark_clean(self) -> None:
        self.stack.setClean()
        self._dirty = False
        self.update_title()

    # ------------------------------------------------------------ project <-> window
    def _face_ref_for(self, target: Path):
        """How to reference the shown face from a project written at ``target``: by name (the built-in
        face) or by its file when it is that file's content; a face derived in memory (a scan scaled,
        retextured or flipped) is written beside the project, so reopening it (or recovering its
        autosave) restores exactly what was shown, not the raw file."""
        face = self.document.face
        to_autosave = Path(target).name.endswith(cp.AUTOSAVE_SUFFIX)

        def usable(path) -> bool:
            # A face embedded for an autosave lives in the state folder and goes when that autosave is
            # recovered or discarded: a saved project gets its own copy (a recovered session's face is
            # read from there).
            return Path(path).is_file() and (to_autosave or not Path(path).name.endswith(cp.AUTOSAVE_SUFFIX + ".face.ply"))

        if self._face_ref is not None and self._face_ref[0] == id(face) and (
                self._face_ref[1].builtin is not None or usable(self._face_ref[1].path)):
            return self._face_ref[1]
        source = self.document.face_path
        as_read = self._source_face is not None and self._source_face == (source, _fingerprint(face))
        if as_read and getattr(face.metadata, "source", None) == "built-in":
            ref = cp.FaceRef.default_face()
        elif as_read and source and usable(source):
            ref = cp.FaceRef.for_file(source)
        else:
            ref = cp.embed_face(face, target)
        self._face_ref = (id(face), ref)
        return ref

    def current_project(self, target: Path | None = None) -> cp.Project:
        """The open project as a :class:`core.formats.project.Project` (``target``: where it will be written)."""
        doc = self.document
        if doc.face is None:
            raise cp.ProjectError("there is no face to save yet; wait until it is loaded")
        target = Path(target) if target is not None else (self.path or cp.autosave_path(
            None, untitled_id=self.untitled_id, state_dir=self.state_dir))
        model = doc.landmarks
        status = ({n: (model.status(n).value, model.confidence(n)) for n in model.names}
                  if model is not None and model.face is doc.face else None)
        project = cp.Project.from_state(doc.face, self._face_ref_for(target), doc.rig, self.c.timeline,
                                        speech=self.c.speech, view=self.view_state(), landmark_status=status)
        if self._pending_values and doc.rig is not None:   # opened, but their layer is still being built
            project.rig.values.update(self._pending_values)
        return project

    def view_state(self) -> dict:
        """The window's view (camera, display mode, overlays: ``MainWindow.view_state``) and the
        timeline's UI state, as plain JSON types."""
        c = self.c
        view = self.window.view_state()
        view["timeline"] = {"time": float(c.current_time), "loop": bool(c.loop), "speed": float(c.speed),
                            "auto_key": bool(c.auto_key)}
        if c.dock is not None:
            view["timeline"]["show_all"] = bool(c.dock.view.show_all)
            view["timeline"]["collapsed"] = sorted(c.dock.view.collapsed)
        return view

    def apply_view(self, view: dict) -> None:
        """Restore :meth:`view_state` output; missing or odd entries are skipped (the view is decoration)."""
        c = self.c
        try:
            self.window.apply_view(view)
            tview = view.get("timeline")
            if isinstance(tview, dict):
                c.loop = bool(tview.get("loop", False))
                with contextlib.suppress(ValueError, TypeError):
                    c.set_speed(float(tview.get("speed", 1.0)))
                if c.dock is not None:
                    c.dock.view.collapsed = {str(g) for g in tview.get("collapsed", []) if isinstance(g, str)}
                    c.dock.show_all_check.setChecked(bool(tview.get("show_all", False)))
                    c.dock.view.rebuild_rows()
                    c.dock.sync()
        except Exception:  # noqa: BLE001 - a bad view entry must not stop the project from opening
            traceback.print_exc()

    # ------------------------------------------------------------ new / open
    def new_project(self) -> bool:
        """Empty timeline, neutral rig, untitled (the face stays)."""
        if not self._maybe_save("starting a new project"):
            return False
        self._discard_own_autosave()
        rig = self.document.rig
        if rig is not None:
            with self.c._not_recorded():  # noqa: SLF001 - the controller's own guard
                rig.reset_faps()
                rig.set_expression(None)
                rig.set_viseme(None)
        self.c._set_speech([])  # noqa: SLF001
        self.c.set_timeline(Timeline())
        self.path = None
        self.untitled_id = f"untitled-{os.getpid()}-{next(_UNTITLED)}"
        self.stack.clear()
        self._mark_clean()
        self._autosaved = None
        self.project_opened.emit(None)
        return True

    def open_dialog(self) -> bool:
        start = str(self.window.settings.value("projectDirectory", str(Path.home())))
        path, _ = QFileDialog.getOpenFileName(self.window, "Open project", start, PROJECT_FILTER)
        if not path:
            return False
        return self.open_project(path)

    def open_project(self, path, *, ask: bool = True) -> bool:
        """Open ``path``. Errors -> a warning with core.formats.project's message; the open project stays.

        Returns True when the project is open (False when refused, cancelled, or still loading its face
        in the background — ``project_opened`` is emitted when done).
        """
        path = Path(path)
        if ask and not self._maybe_save(f"opening {path.name}"):
            return False
        try:
            project = cp.load_project(path)
        except cp.ProjectError as exc:
            self._warn(f"Could not open {path.name}", str(exc))
            return False
        outside = cp.face_outside_folder(project, path)
        if outside is not None and QMessageBox.question(
                self.window, "Face file outside the project's folder",
                f"{path.name} uses a face file outside its own folder:\n\n{outside}\n\nOpen the project with "
                "this face? (Choose No if you did not expect this path; the open project stays.)",
                QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No,
                QMessageBox.StandardButton.No) != QMessageBox.StandardButton.Yes:
            return False
        if outside is not None:   # asked and answered: no note repeating it after the open
            drop = str(outside)
            project.notes[:] = [n for n in project.notes if drop not in n]
            self._accepted_face = drop
        self.window.settings.setValue("projectDirectory", str(path.resolve().parent))
        return self._apply_project(project, path, offer_recovery=True)

    def _same_face(self, project: cp.Project) -> bool:
        face = self.document.face
        if face is None or self.document.rig is None:
            return False
        ref = project.face
        if ref.builtin is not None:
            same = getattr(face.metadata, "source", None) == "built-in"
        else:
            known = self._face_ref[1] if self._face_ref is not None and self._face_ref[0] == id(face) else None
            shown = self.document.face_path
            same = ((known is not None and known.path is not None and Path(known.path) == Path(ref.path)
                     and known.sha256 == ref.sha256)
                    or (shown is not None and Path(shown).is_file() and Path(shown).resolve() == Path(ref.path)
                        and (ref.sha256 is None or cp.file_sha256(shown) == ref.sha256)))
        if not same:
            return False
        return project.landmarks is None or dict(project.landmarks) == dict(face.landmarks)

    def _apply_project(self, project: cp.Project, path: Path | None, *, offer_recovery: bool = False,
                       dirty: bool = False) -> bool:
        if self._same_face(project):
            self._finish_open(project, path, list(project.notes), dirty=dirty, offer_recovery=offer_recovery)
            return True
        # Another face: load it and build its rig off the GUI thread (app.jobs: a ProjectError is a
        # message, a newer open wins), then finish on it.
        self._pending = (project, path, dirty, offer_recovery)
        self.window.statusBar().showMessage("Opening the project: loading its face and preparing the rig…")

        def work(_job):
            from app.document import build_rig

            notes: list[str] = []
            face = cp.open_face(project, notes)
            rig, message = build_rig(face)
            return face, rig, message, notes

        self._loads.start(work, self._on_face_opened, self._on_face_failed)
        return False

    def _on_face_opened(self, result) -> None:
        if self._pending is None or self._closed:
            return
        project, path, dirty, offer = self._pending
        self._pending = None
        face, rig, message, notes = result
        self._applying_face = True
        try:
            self.window.set_face(face, path=str(project.face.path) if project.face.path is not None else None,
                                 rig=rig, rig_message=message)
        finally:
            self._applying_face = False
        if project.face.path is not None:
            self._face_ref = (id(face), project.face)
        self._finish_open(project, path, notes, dirty=dirty, offer_recovery=offer)

    def _apply_landmark_status(self, project: cp.Project) -> None:
        """Give the landmark editor the statuses (auto / edited / confirmed) and confidences saved."""
        model = self.document.landmarks
        if model is None or not project.landmark_status:
            return
        from core.landmark_editing import LandmarkState, LandmarkStatus

        states = {n: LandmarkState(model.point(n), LandmarkStatus(s), c)
                  for n, (s, c) in project.landmark_status.items() if n in model}
        if states:
            model.update_states(states)

    def _apply_pending_values(self, _change=None) -> None:
        """A layer joined the rig (the muscles, built in the background): give it the opened values."""
        rig = self.document.rig
        if rig is None or not self._pending_values:
            return
        ready = {k: v for k, v in self._pending_values.items() if k in set(rig.parameters())}
        if not ready:
            return
        for k in ready:
            del self._pending_values[k]
        if not self._pending_values:
            rig.changed.disconnect(self._apply_pending_values)
        with self.c._not_recorded():  # noqa: SLF001
            try:
                rig.set_values(ready)
            except ValueError as exc:
                self._warn("Some rig values could not be restored", str(exc))

    def _on_face_failed(self, message: str) -> None:
        name = self._pending[1].name if self._pending is not None and self._pending[1] is not None else "the project"
        self._pending = None
        self._recovery_abandoned()
        self._warn(f"Could not open {name}", message)

    def _finish_open(self, project: cp.Project, path: Path | None, notes: list[str], *, dirty: bool,
                     offer_recovery: bool) -> None:
        c, w = self.c, self.window
        accepted, self._accepted_face = self._accepted_face, None
        notes = [n for n in notes if not (accepted and accepted in n)]
        time = 0.0
        tview = project.view.get("timeline") if isinstance(project.view, dict) else None
        if isinstance(tview, dict) and isinstance(tview.get("time"), (int, float)):
            time = float(tview["time"])
        c._set_speech(list(project.speech))  # noqa: SLF001
        c.set_timeline(project.timeline, time=time)
        rig = self.document.rig
        self._pending_values = {}
        if rig is not None:
            with c._not_recorded():  # noqa: SLF001
                try:
                    # Layers still building (the muscles) get their values when they join the rig.
                    self._pending_values = project.rig.apply(rig, slow_layers=False)
                except ValueError as exc:
                    notes.append(f"Some rig values could not be restored: {exc}")
            if self._pending_values:
                rig.changed.connect(self._apply_pending_values)
        self.apply_view(project.view)
        self._apply_landmark_status(project)
        if isinstance(tview, dict) and bool(tview.get("auto_key", False)) != c.auto_key:
            c.set_auto_key(bool(tview.get("auto_key", False)))
        self.path = Path(path) if path is not None else None
        if self.path is not None and self.path.suffix == cp.SUFFIX:
            self.window.add_recent_file(str(self.path))   # File ▸ Open recent lists projects too
        self.stack.clear()
        self._mark_clean()
        self._dirty = dirty
        self._autosaved = None
        self.update_title()
        shown = self.path.name if self.path is not None else "the recovered project"
        w.statusBar().showMessage(f"Opened {shown}" + (" — " + " ".join(notes) if notes else ""), 10000)
        if notes:
            QMessageBox.information(w, "Notes on opening the project", "\n".join(f"• {n}" for n in notes))
        self._recovery_applied(project)
        self.project_opened.emit(self.path)
        if offer_recovery and self.path is not None:
            self.offer_recovery(self.path)

    # ------------------------------------------------------------ save
    def save(self) -> bool:
        if self.path is None:
            return self.save_as_dialog()
        return self.save_project(self.path)

    def save_as_dialog(self) -> bool:
        w = self.window
        folder = str(w.settings.value("projectDirectory", str(Path.home())))
        face = self.document.face
        name = self.path.name if self.path is not None else (
            f"{face.metadata.name}{cp.SUFFIX}" if face is not None else f"untitled{cp.SUFFIX}")
        path, _ = QFileDialog.getSaveFileName(w, "Save project as", str(Path(folder) / name), PROJECT_FILTER)
        if not path:
            return False
        if not path.endswith(cp.SUFFIX):
            path += cp.SUFFIX
        return self.save_project(path)

    def save_project(self, path) -> bool:
        """Write the project to ``path``; errors -> a warning. Returns success."""
        path = Path(path)
        self.wait_for_autosave()  # it must not land after the save and its clean-up
        try:
            QApplication.setOverrideCursor(Qt.CursorShape.WaitCursor)
            try:
                cp.save_project(path, self.current_project(path))
            finally:
                QApplication.restoreOverrideCursor()
        except cp.ProjectError as exc:
            self._warn(f"Could not save {path.name}", str(exc))
            return False
        old_untitled = self.path is None
        if self.path is not None and self.path != path:
            cp.discard_autosave(self.path)
        self.path = path
        self.window.add_recent_file(str(path))
        cp.discard_autosave(path)
        if old_untitled:
            self._discard_own_autosave(untitled_only=True)
        self.window.settings.setValue("projectDirectory", str(path.resolve().parent))
        self._mark_clean()
        self._autosaved = None
        status = self.window.statusBar
        if status is not None:
            self.window.statusBar().showMessage(f"Saved {path}", 5000)
        return True


    # ------------------------------------------------------------ asking / closing
    def _maybe_save(self, doing: str) -> bool:
        """True when it is fine to drop the open project (saved, discarded, or unmodified)."""
        if not self.is_modified:
            return True
        answer = QMessageBox.question(
            self.window, "Unsaved changes", f"Save the changes to {self.name} before {doing}?",
            QMessageBox.StandardButton.Save | QMessageBox.StandardButton.Discard | QMessageBox.StandardButton.Cancel,
            QMessageBox.StandardButton.Save)
        if answer == QMessageBox.StandardButton.Save:
            return self.save()
        if answer == QMessageBox.StandardButton.Discard:
            self._discard_own_autosave()
            return True
        return False

    def eventFilter(self, watched, event) -> bool:  # noqa: N802 - Qt override
        if watched is self.window and event.type() == QEvent.Type.Close:
            if self.ask_on_close and self.is_modified and not self._maybe_save("closing"):
                event.ignore()
                return True
            self.autosave_timer.stop()
            self.wait_for_autosave()
            self.c.pause()
            self._loads.cancel()   # a project's face still loading is not shown any more
            self._closed = True
            if self.is_modified:
                self.autosave_now()  # offered at the next start
            else:
                self._discard_own_autosave(untitled_only=True)
        return False

    def _warn(self, title: str, message: str) -> None:
        status = self.window.statusBar
        if status is not None:
            first = message.splitlines()[0] if message else title
            self.window.statusBar().showMessage(first[:140], 8000)
        QMessageBox.warning(self.window, title, message)


__all__ = ["ProjectActions", "AUTOSAVE_MS", "PROJECT_FILTER", "default_state_dir"]
