"""document.py
----
The window's editing state in one place.

A :class:`Document` owns the face shown (and the file it came from), its rig (FAPs, muscles and any
later layer, ``core.rig.FaceRig``), the one undo stack and the recorder that turns every rig
parameter change into undo steps (:class:`app.undo.UndoableRigEdits`). The main window builds it
before any dock and every dock reads it as ``window.document``; the timeline controller and the
project actions register themselves on it (``document.timeline``, ``document.project``).

Replacing the face (:meth:`Document.set_face`) retargets the recorder and clears the undo history,
whose commands point at the old face and rig.
"""

from __future__ import annotations

import traceback

from PySide6.QtCore import QObject

from app.undo import UndoableRigEdits, make_undo_stack
from core.cache import DiskCache

NO_RIG_MESSAGE = "This face has no MPEG-4 feature points yet: mark them (landmark picker) to animate it."


def build_rig(face, cache: DiskCache | None = None) -> tuple[object | None, str]:
    """(FaceRig for ``face``, "") or (None, a message for the user saying why not).

    The FAP table comes from ``cache`` (default: the user's cache folder) when this face was
    animated before; what the cache had to say (a damaged entry rebuilt) joins the face's notes.
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
        from core.normal_kernels import warm_up

        warm_up()   # build_rig runs on a loader thread: compile the per-tick normals there
        rig = FaceRig(face, cache=cache)
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
    """Face, rig, undo stack and the parts of the window that hold the rest of the project.
    The window announces a new face with its own ``face_changed`` once the viewport shows it."""

    def __init__(self, parent: QObject | None = None):
        super().__init__(parent)
        self.face = None
        self.face_path: str | None = None
        self.rig = None
        self.rig_message = ""
        self.undo_stack = make_undo_stack(self)
        self.rig_edits = UndoableRigEdits(self.undo_stack, None, self)
        self.timeline = None   # app.timeline_controller.TimelineController, once attached
        self.project = None    # app.project_actions.ProjectActions, once attached

    def set_face(self, face, *, path: str | None, rig, rig_message: str = "") -> None:
        """Make ``face`` (with its ``rig``, None when it cannot be animated and ``rig_message`` says
        why) the document's face; clears the undo history."""
        self.face, self.face_path = face, path
        self.rig = rig
        self.rig_message = "" if rig is not None else rig_message
        self.rig_edits.set_rig(rig)
        self.undo_stack.clear()

    @property
    def muscle_layer(self):
        """The rig's muscle layer (built by the muscle dock in the background), or None."""
        return None if self.rig is None else self.rig.layer("muscles")


__all__ = ["Document", "build_rig", "NO_RIG_MESSAGE"]
