"""document.py
----
The window's editing state in one place.

A :class:`Document` owns the face shown (and the file it came from), its rig (FAPs, muscles and any
later layer, ``core.rig.FaceRig``), the face's landmark model (positions, auto / edited / confirmed,
detector confidences, the selected landmark: :class:`core.landmark_editing.LandmarkEditModel`), the
one undo stack, the recorder that turns every rig parameter change into undo steps
(:class:`app.undo.UndoableRigEdits`) and the project's path. The main window builds it before any
dock and passes it to each dock's constructor; the timeline controller and the project actions
register themselves on it (``document.timeline``, ``document.project``).

Replacing the face (:meth:`Document.set_face`) gives it a new landmark model, retargets the recorder
and clears the undo history, whose commands point at the old face and rig. The window announces the
new face (:meth:`Document.announce_face`, signal ``face_changed``) once the viewport shows it, so
listeners that draw on it find it there.

Signals: ``face_changed(face)``, ``landmarks_changed(name)`` (a landmark of the current face moved or
changed status / confidence; ``""`` when several did or names came or went) and
``landmark_selected(name or None)``.
"""

from __future__ import annotations

import contextlib
import traceback
from pathlib import Path

from PySide6.QtCore import QObject, Signal

from app.undo import LandmarkSetCommand, UndoableRigEdits, make_undo_stack
from core.cache import DiskCache
from core.landmark_editing import LandmarkEditModel

PREPARING_MESSAGE = "Preparing the face for animation…"
NO_RIG_MESSAGE = "This face has no MPEG-4 feature points yet: mark them (landmark picker) to animate it."


def warm_up_kernels() -> None:
    """Build the per-tick numba kernels (vertex normals, the FAP layer's steps) now: the window runs
    this in the background once the face is animatable (it defers them, ``core.lazy_numba``), and
    ``mimica prepare`` at install, which fills numba's disk cache for later starts."""
    from core import normal_kernels
    from core.layers.fap import kernels as fap_kernels

    normal_kernels.warm_up()
    fap_kernels.warm_up()


def build_rig(face, cache: DiskCache | None = None, progress=None) -> tuple[object | None, str]:
    """(FaceRig for ``face``, "") or (None, a message for the user saying why not).

    The FAP table comes from ``cache`` (default: the user's cache folder) when this face was
    animated before (else it is built, reporting to ``progress(fraction, message)``); what the cache
    had to say (a damaged entry rebuilt) joins the face's notes.
    Never raises: a face without the MPEG-4 feature points is a normal state (the user marks them
    later), and anything unexpected is reported on stderr.
    """
    from core.layers.fap.template import TemplateError

    try:
        from core.rig import FaceRig
    except Exception as exc:  # noqa: BLE001 - animation is optional; the viewer must still work
        traceback.print_exc()
        return None, f"Animation is not available in this installation ({type(exc).__name__}: {exc})."
    cache = cache if cache is not None else DiskCache()
    try:
        rig = FaceRig(face, cache=cache, progress=progress)
        notes = getattr(face.metadata, "notes", None)
        if cache.notes and isinstance(notes, list):
            notes.extend(n for n in cache.notes if n not in notes)
        return rig, ""
    except ValueError as exc:  # missing/misplaced feature points: a message, not a bug
        first = NO_RIG_MESSAGE if isinstance(exc, TemplateError) else "This face cannot be animated yet."
        return None, f"{first}\n\nDetails: {exc}"
    except Exception as exc:  # noqa: BLE001
        traceback.print_exc()
        return None, f"Could not prepare this face for animation: {type(exc).__name__}: {exc}"


class Document(QObject):
    """Face, rig, landmark model, undo stack and project path (see the module docstring)."""

    face_changed = Signal(object)       # the new Face, once it is shown
    rig_changed = Signal(object)        # the face's rig arrived later (a background build), or None
    landmarks_changed = Signal(str)     # a landmark's name, or "" for several / added / removed
    landmark_selected = Signal(object)  # the selected landmark's name, or None

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        self.face = None
        self.face_path: str | None = None
        self.rig = None
        self.rig_message = ""
        self.rig_pending = False   # the face is shown and its rig is being built (set_rig follows)
        self.landmarks: LandmarkEditModel | None = None
        self.project_path: Path | None = None   # the open project's file (None: untitled)
        self.undo_stack = make_undo_stack(self)
        self.rig_edits = UndoableRigEdits(self.undo_stack, None, self)
        self.timeline = None   # app.timeline_controller.TimelineController, once its dock exists
        self.project = None    # app.project_actions.ProjectActions, once they exist

    def set_face(self, face, *, path: str | None, rig, rig_message: str = "", rig_pending: bool = False) -> None:
        """Make ``face`` (with its ``rig``, None when it cannot be animated and ``rig_message`` says
        why, or ``rig_pending``: it is being built and :meth:`set_rig` follows) the document's face,
        with a new landmark model; clears the undo history. Announced later by :meth:`announce_face`."""
        self.face, self.face_path = face, path
        self.rig = rig
        self.rig_message = "" if rig is not None else rig_message
        self.rig_pending = rig is None and rig_pending
        self.rig_edits.set_rig(rig)
        self._set_landmarks(LandmarkEditModel(face) if face is not None else None)
        self.undo_stack.clear()

    def set_rig(self, rig, message: str = "") -> None:
        """Give the current face its rig once built in the background (``None`` and ``message``:
        it cannot be animated, and why); announced by ``rig_changed``."""
        self.rig = rig
        self.rig_message = "" if rig is not None else message
        self.rig_pending = False
        self.rig_edits.set_rig(rig)
        self.rig_changed.emit(rig)

    def announce_face(self) -> None:
        """Emit ``face_changed`` (the window calls it once the viewport shows the new face)."""
        self.face_changed.emit(self.face)

    @property
    def muscle_layer(self):
        """The rig's muscle layer (built by the muscle dock in the background), or None."""
        return None if self.rig is None else self.rig.layer("muscles")

    # ------------------------------------------------------------ landmarks
    def _set_landmarks(self, model: LandmarkEditModel | None) -> None:
        old = self.landmarks
        if old is not None:
            with contextlib.suppress(ValueError, RuntimeError, TypeError):
                old.changed.disconnect(self._on_landmark_changed)
                old.selection_changed.disconnect(self._on_landmark_selected)
        self.landmarks = model
        if model is not None:
            model.changed.connect(self._on_landmark_changed)
            model.selection_changed.connect(self._on_landmark_selected)

    def _on_landmark_changed(self, name: str) -> None:
        self.landmarks_changed.emit(name)

    def _on_landmark_selected(self, name) -> None:
        self.landmark_selected.emit(name)

    def apply_landmark_detection(self, points: dict, confidence: dict | None = None) -> list[str]:
        """Put a detector's result into the landmark model (auto landmarks replaced, the user's
        edited / confirmed ones kept) as one undo step; returns the names that changed."""
        model = self.landmarks
        if model is None:
            return []
        before = model.snapshot()
        changed = model.apply_detection(points, confidence)
        if changed:
            self.undo_stack.push(LandmarkSetCommand.from_snapshots(model, "detect landmarks", before,
                                                                   model.snapshot(), applied=True))
        return changed


__all__ = ["Document", "build_rig", "warm_up_kernels", "NO_RIG_MESSAGE", "PREPARING_MESSAGE"]
