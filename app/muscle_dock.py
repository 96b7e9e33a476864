"""muscle_dock.py
----
The muscle dock (thesis C's interface): one slider per muscle *per side* and the jaw
angle, driving a :class:`core.layers.muscles.MuscleLayer` on the window's :class:`core.rig.FaceRig`.

* Rows: the shared :class:`app.parameter_row.ParameterRow` of each control's registry key
  ("muscle:risorius:left", "jaw"): the 9 linear muscles as pairs (the name spans two lines, "left"
  and "right" below each other, so the two sides of a muscle sit together and every slider has the
  full width), then the orbicularis oris and the jaw opening. Each row: slider, spin box with units
  (thesis force units ``u``; degrees for the jaw), reset ↺. "Link left/right" moves a control's
  mirror (from the registry) with it.
  "left"/"right" are the face's own sides (in the front view its left is on the screen's right).
* House rules of the FAP dock: widgets write through the layer's setters and never keep their
  own copy; every widget follows ``layer.changed`` with its signals blocked (no echo); the dock
  never renders: the layer's ``changed`` reaches ``rig.touch()`` (``layer.attach``) and the
  window redraws once per burst.
* Live quasi-static solve: an edit only sets the force; a 0 ms QTimer then calls
  ``layer.relax(budget_s=RELAX_BUDGET_S)`` once per event-loop pass (the window redraws in
  between) until the layer reports ``converged``. The status line says "settling… residual x %",
  then "equilibrium" (or "at rest" with every force 0). No call blocks the GUI thread for much
  more than the budget. When the window's last redraw took longer than two budgets (software
  OpenGL: about a second for the default face under Xvfb), the budget grows to half that redraw
  time, at most ``MAX_RELAX_BUDGET_S``, so settling is not slaved to the redraw rate.
* Animate: plays the transition from rest to the current forces with the layer's dynamic
  integrator in wall-clock time (QTimer at ~30 fps, each tick ``layer.advance(elapsed)``, an
  elapsed time above ``MAX_FRAME_S`` is cut so a stalled GUI slows the replay instead of jumping)
  for ``animation_s`` (default ``ANIMATION_S``) seconds, then the quasi-static solve finishes the
  pose. Stop ends it early.
* Rest (a choice): animated back — every force and the jaw go to 0 and the same dynamics play
  from the current pose, so the face relaxes visibly. "Reset all" is the instant version
  (``layer.reset()``).
* Presets (thesis C's test expressions), Save / Open of force sets (JSON): a malformed file shows
  its ``ForceFileError`` message in a warning box and leaves the forces alone.
* ``SolverDiverged``: timers stop, the message goes to the status line and the window's status
  bar; the layer has already restored its last good state, which the widgets then show.
* Undo: every edit from this dock (slider, spin box, reset, preset, file, Rest) is one rig event,
  which the window's :class:`app.undo.UndoableRigEdits` records as one step like any parameter
  change; the changes of one control during one gesture (a slider drag) merge into one step.
* The muscles can be drawn in the viewport ("Show muscles", :mod:`app.muscle_view`).

The layer takes seconds to build, so :func:`attach_muscle_dock` builds it on a worker thread
(:mod:`app.jobs`) and re-builds it when the window's face changes. The widgets are built in
:mod:`app.muscle_dock_ui`, the solver loops run in :mod:`app.muscle_simulation`.
"""

from __future__ import annotations

import contextlib
import time
import traceback
from typing import TYPE_CHECKING, Hashable

from PySide6.QtCore import QEvent, QObject, QSignalBlocker, Qt, QTimer, Signal
from PySide6.QtGui import QKeySequence
from PySide6.QtWidgets import QDockWidget, QLabel, QMessageBox, QWidget

from app.jobs import JobRunner
from app.muscle_dock_ui import JAW, MuscleDockLayout, _preset_title
from app.muscle_simulation import (  # noqa: F401 - the tests tune these
    ANIMATION_INTERVAL_MS, ANIMATION_S, RELAX_BUDGET_S, MuscleSimulationMixin)
from app.parameter_row import ParameterRow
from core import parameters as P

if TYPE_CHECKING:  # pragma: no cover
    from core.layers.muscles import MuscleLayer

BUILDING_MESSAGE = "Building the muscle model…"
NO_FACE_MESSAGE = "No face loaded yet."
NO_RIG_MESSAGE = ("The muscles need the face's MPEG-4 feature points: mark them (landmark picker), "
                  "then the muscle model is built.")


def _face_signature(face) -> tuple:
    """What the muscle model depends on: the same face object with corrected landmarks (Tools ▸
    Rebuild animation) must be built again."""
    import numpy as np

    names = tuple(face.landmark_names)
    try:
        marks = np.asarray(face.landmark_positions(list(names)), float).tobytes() if names else b""
    except Exception:  # noqa: BLE001 - a face whose landmarks cannot be placed: never re-used
        marks = object()
    v = np.asarray(face.vertices)
    return names, marks, v.shape, float(v.sum())


# ------------------------------------------------------------------ one control


# ------------------------------------------------------------------ building off the GUI thread
# ------------------------------------------------------------------ the dock
class MuscleDock(MuscleDockLayout, MuscleSimulationMixin, QDockWidget):
    """The muscle dock (see the module docstring).

    Parameters
    ----------
    window : MainWindow, optional
        Gives the face, rig, plotter, status bar and undo stack; without one the dock drives
        whatever layer :meth:`set_layer` receives (no build, no viewport drawing, no undo).
    level : int
        Template level of the muscle model (passed to ``MuscleLayer``).

    Signals
    -------
    layer_changed(object)
        A new layer (or None) is driven.
    settled()
        The quasi-static solve reached equilibrium.
    """

    layer_changed = Signal(object)
    settled = Signal()

    def __init__(self, window=None, parent: QWidget | None = None, *, level: int = 3):
        super().__init__("Muscles", parent if parent is not None else window)
        self.setObjectName("muscleDock")
        self.setAllowedAreas(Qt.DockWidgetArea.LeftDockWidgetArea | Qt.DockWidgetArea.RightDockWidgetArea)
        self.window_ = window
        self.level = int(level)
        self.layer: "MuscleLayer | None" = None
        self.rig = None
        self.view = None  # MuscleView, while a layer and a plotter exist
        self.rows: dict[str, ParameterRow] = {}   # by canonical key: "muscle:risorius:left", "jaw"
        self.name_labels: dict[str, QLabel] = {}
        self._syncing = False
        self._view_dirty = True
        self._layer_face = None  # the face self.layer was built for (kept for re-use)
        self._layer_signature: tuple | None = None  # its landmarks and vertices when built
        self._builds = JobRunner(self, supersede=True)   # a newer face's build supersedes the older one
        self._animating = False
        self._anim_elapsed = 0.0
        self._anim_last = 0.0
        #: Seconds of dynamics Animate / Rest play.
        self.animation_s = ANIMATION_S
        #: Timing of the live loop: seconds of the last relax call and the edit -> settled time.
        self.last_relax: object | None = None
        self.last_settle_s: float | None = None
        self._edit_started: float | None = None
        self.relax_ticks = 0

        self._relax_timer = QTimer(self)
        self._relax_timer.setInterval(0)
        self._relax_timer.timeout.connect(self._relax_tick)
        self._anim_timer = QTimer(self)
        self._anim_timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._anim_timer.setInterval(ANIMATION_INTERVAL_MS)
        self._anim_timer.timeout.connect(self._anim_tick)

        self._build_ui()
        self.set_layer(None, NO_FACE_MESSAGE)


    # ============================================================ messages
    def show_message(self, message: str) -> None:
        """Show ``message`` above the controls (empty hides it)."""
        self.message_label.setText(message)
        self.message_label.setVisible(bool(message))

    def set_status(self, text: str) -> None:
        self.status_label.setText(text)

    @property
    def status(self) -> str:
        return self.status_label.text()

    def _status_bar(self, text: str, ms: int = 8000) -> None:
        window = self.window_
        if window is not None:
            window.statusBar().showMessage(text, ms)

    # ============================================================ layer
    def set_layer(self, layer: "MuscleLayer | None", message: str = "", *, rig=None) -> None:
        """Drive ``layer`` (attached to ``rig`` when given); None disables the dock, ``message`` says why."""
        self.stop(relax=False)
        self._relax_timer.stop()
        if self.layer is not None:
            try:
                self.layer.changed.disconnect(self._on_layer_changed)
            except (ValueError, RuntimeError, TypeError):
                pass
        self._detach_from_rig()
        self.layer = layer
        if self.view is not None:
            self.view.remove()
            self.view = None
        if layer is not None:
            if rig is not None:
                layer.attach(rig)
                self.rig = rig
            layer.changed.connect(self._on_layer_changed)
            self._make_view()
        enabled = layer is not None
        self._set_controls_enabled(enabled)
        self.show_message(message)
        self.busy_bar.setVisible(message == BUILDING_MESSAGE)
        self.set_status("")
        if layer is not None:
            self._sync_from_layer()
            self._update_status(converged=bool(getattr(layer, "converged", True)))
            # No render here: attach() touched the rig, so the window redraws on its own.
        self.layer_changed.emit(layer)

    def _detach_from_rig(self) -> None:
        rig = self.rig
        self.rig = None
        if rig is not None:
            try:
                rig.remove_layer("muscles")
            except Exception:  # noqa: BLE001 - the rig may already be gone
                pass

    def _make_view(self) -> None:
        plotter = (self.window_.plotter if self.window_ is not None else None)
        layer = self.layer
        triangles = getattr(getattr(layer, "model", None), "triangles", None)
        if plotter is None or layer is None or triangles is None:
            return
        from app.muscle_view import MuscleView

        self.view = MuscleView(plotter, triangles)
        self._view_dirty = True
        if self.show_check.isChecked():
            self._update_view()
            self.view.set_visible(True)

    # ============================================================ building for a window face
    def build_for_window(self) -> None:
        """Follow the window's current face and rig: re-use, build (in the background) or disable."""
        window = self.window_
        if window is None:
            return
        face, rig = window.document.face, window.document.rig
        self._builds.cancel()  # builds still running are for an older face
        if face is None:
            self._release_layer()
            self.set_layer(None, NO_FACE_MESSAGE)
            return
        if rig is None:
            self._release_layer()
            reason = window.document.rig_message or NO_RIG_MESSAGE
            self.set_layer(None, f"Muscles are not available for this face.\n\n{reason}")
            return
        signature = _face_signature(face)
        if self.layer is not None and self._layer_face is face and self._layer_signature == signature:
            layer = self.layer
            self.set_layer(None, "")
            layer.reset()
            self.set_layer(layer, "", rig=rig)
            return
        self._release_layer()
        self.set_layer(None, BUILDING_MESSAGE)
        self._layer_face, self._layer_signature = face, signature
        level, template = self.level, self._shared_template(rig)

        def build(job):
            from core.layers.muscles import MuscleLayer

            try:
                return MuscleLayer(face, level=level, template_dense=template)
            except ValueError as exc:  # the face does not fit the model: a message, not a bug
                raise ValueError(f"The muscle model cannot be built for this face: {exc}") from None

        self._builds.start(build, self._on_built, self._on_build_failed)

    def _shared_template(self, rig):
        """The rig's densified template when it is the one the layer needs: the layer then skips
        densifying (seconds) and adopts the FAP deformer's face binding (no 3 s bind on the first
        redraw)."""
        dense = getattr(getattr(rig, "deformer", None), "dense", None)
        if dense is None:
            return None
        try:
            from core.layers.fap.template import load_template

            return dense if self.level == len(load_template().steps) else None
        except Exception:  # noqa: BLE001 - an optimisation only
            return None

    def _release_layer(self) -> None:
        """Forget the layer (a different face, or none, is coming)."""
        if self.layer is not None:
            self.set_layer(None, "")
        self._layer_face = None

    def _on_built(self, layer) -> None:
        rig = self.window_.document.rig
        if rig is None:  # cannot happen for the latest generation; be safe
            self.build_for_window()
            return
        self.set_layer(layer, "", rig=rig)
        self._status_bar("Muscle model ready", 4000)

    def _on_build_failed(self, message: str) -> None:
        self._layer_face = None
        self.set_layer(None, message)
        self._status_bar(message.splitlines()[0])

    @property
    def is_building(self) -> bool:
        return self.layer is None and self.message_label.text() == BUILDING_MESSAGE

    def shutdown(self) -> None:
        """Stop timers and drop running builds (the window is closing). A build still running is
        waited for: a worker must not outlive the window (nor the interpreter) it reports to."""
        self._builds.cancel()
        self._builds.wait(10_000)
        self.stop(relax=False)
        self._relax_timer.stop()
        if self.view is not None:
            self.view.remove()
            self.view = None
        if self.layer is not None:
            try:
                self.layer.changed.disconnect(self._on_layer_changed)
            except (ValueError, RuntimeError, TypeError):
                pass
        self.rig = None

    # ============================================================ layer -> widgets
    def _on_layer_changed(self, *_args) -> None:
        if self.layer is None:
            return
        self._sync_from_layer()
        self._view_dirty = True
        if self.view is not None and self.view.visible:
            self._update_view()
        if self._animating or self._relax_timer.isActive():
            return
        if self.layer.converged:  # e.g. reset(): already an equilibrium
            self._update_status(converged=True)
        else:  # changed from code (a script, undo) as well as from the rows: settle it
            self._start_relax()

    def _sync_from_layer(self) -> None:
        layer = self.layer
        if layer is None:
            return
        self._syncing = True
        try:
            for key, row in self.rows.items():
                value = float(layer.value(key))
                if row.value != value:
                    row.show_value(value)
        finally:
            self._syncing = False

    def _update_view(self) -> None:
        if self.view is None or self.layer is None:
            return
        try:
            from app.muscle_view import draw_muscles

            draw_muscles(self.view, self.layer)
        except Exception:  # noqa: BLE001 - a drawing problem must not stop the simulation
            traceback.print_exc()
            return
        self._view_dirty = False

    def set_muscles_visible(self, visible: bool) -> None:
        """Show or hide the muscles in the viewport (the "Show muscles" box)."""
        with QSignalBlocker(self.show_check):
            self.show_check.setChecked(bool(visible))
        if self.view is None:
            return
        if visible and self._view_dirty:
            self._update_view()
        self.view.set_visible(bool(visible))
        self._render()

    def _render(self) -> None:
        """Ask the window's viewport to redraw the muscles (once, with whatever else changed)."""
        if self.window_ is not None:
            self.window_.viewport.request("muscles")

    # ============================================================ widgets -> layer
    def state(self) -> tuple:
        """(forces in ``control_keys()`` order, jaw degrees): what an undo step restores."""
        from core.layers.muscles import control_keys

        layer = self.layer
        if layer is None:
            return ()
        forces = layer.forces()
        return tuple(float(forces.get(k, 0.0)) for k in control_keys()), float(layer.jaw_deg)

    def _guarded(self, call) -> bool:
        """Run a layer call; bad values and a diverged solver become messages. Returns success."""
        from core.layers.muscles import SolverDiverged

        try:
            call()
        except SolverDiverged as exc:
            self._diverged(exc)
            return False
        except ValueError as exc:
            self.show_message(str(exc))
            self._sync_from_layer()
            self._resync_rows()
            return False
        if self.message_label.isVisible() and self.layer is not None:
            self.show_message("")
        return True

    def _resync_rows(self) -> None:
        layer = self.layer
        if layer is None:
            return
        for key, row in self.rows.items():
            row.show_value(float(layer.value(key)))

    def _edit(self, text: str, call, merge_key=None) -> bool:
        """An edit from this dock: apply, record one undo step, settle."""
        if self.layer is None:
            return False
        self.stop(relax=False)
        self._edit_started = time.perf_counter()
        # One rig event per edit (forces and jaw together): the window's rig recorder makes it one
        # undo step, merged with the rest of a slider drag.
        with self.rig.batch() if self.rig is not None else contextlib.nullcontext():
            ok = self._guarded(call)
        if ok:
            if not self.layer.converged:
                self._start_relax()
            elif not self._relax_timer.isActive():
                self._edit_started = None
                self._update_status(converged=True)
        return ok

    def _row_edited(self, key: str, value: float) -> None:
        layer = self.layer
        if layer is None or self._syncing:
            return
        values = {key: value}
        mirror = self.rows[key].mirror
        if mirror in self.rows and self.link_check.isChecked():
            values[mirror] = self.rows[mirror].clamp(value)
        self._edit(key, lambda: layer.set_values(values))

    def row(self, key: Hashable) -> ParameterRow:
        """The row of a control by any spelling: ("risorius", "left"), "muscle:risorius:left", "jaw"."""
        return self.rows[P.key_of(key)]

    def set_control(self, key: Hashable, value: float) -> None:
        """Set one control as if its row was edited (link, undo and settling included)."""
        self._row_edited(P.key_of(key), float(value))

    def reset_control(self, key: Hashable) -> None:
        """The row's ↺: that control to its default, 0 (and its mirror when linked)."""
        row = self.rows.get(P.key_of(key))
        if row is not None:
            self._row_edited(row.key, row.default)

    def reset_all(self) -> None:
        """Every force and the jaw to 0, the tissue at rest at once (``layer.reset()``)."""
        layer = self.layer
        if layer is not None:
            self._edit("reset all muscles", layer.reset)

    def apply_preset(self, name: str | None) -> bool:
        """Apply one of ``core.layers.muscles.preset_names()`` (one undo step)."""
        from core.layers.muscles import preset

        layer = self.layer
        if layer is None or not name:
            return False
        try:
            force_set = preset(name)
        except (KeyError, ValueError) as exc:
            QMessageBox.warning(self, "Unknown expression", str(exc))
            return False
        index = self.preset_combo.findData(name)
        if index >= 0:
            with QSignalBlocker(self.preset_combo):
                self.preset_combo.setCurrentIndex(index)
        ok = self._edit(f"muscle preset {_preset_title(name).lower()}", lambda: layer.apply(force_set))
        if ok:
            self._status_bar(f"Applied the {_preset_title(name).lower()} forces", 4000)
        return ok

    def rest(self) -> None:
        """Forces and jaw to 0, relaxing back with the dynamics (animated; see the module docstring)."""
        from core.layers.muscles import control_keys

        layer = self.layer
        if layer is None:
            return
        zero = {k: 0.0 for k in control_keys()}
        state = self.state()
        if not any(state[0]) and state[1] == 0.0 and layer.converged and not self._animating:
            return  # already at rest: nothing to play
        if self._edit("rest", lambda: (layer.set_forces(zero), layer.set_jaw(0.0))):
            self._relax_timer.stop()
            self._play(from_rest=False)


# ------------------------------------------------------------------ window integration
class _CloseWatcher(QObject):
    """Stops the dock's timers and builds when the window closes."""

    def __init__(self, dock: MuscleDock, window):
        super().__init__(dock)
        self.dock = dock
        window.installEventFilter(self)

    def eventFilter(self, watched, event) -> bool:  # noqa: N802 - Qt override
        if event.type() == QEvent.Type.Close:
            self.dock.shutdown()
        return False


def attach_muscle_dock(window, *, level: int = 3) -> MuscleDock:
    """Add the muscle dock to a :class:`app.main_window.MainWindow`.

    * the dock goes to the right dock area, tabified with the FAP dock ("Muscles" tab);
    * View ▸ Muscles (Ctrl+Shift+M) shows/hides it;
    * the muscle layer of ``window.face`` is built on a worker thread ("Building the muscle
      model…" in the dock meanwhile), attached to ``window.rig`` and re-built on
      ``window.face_changed``; without a rig the dock is disabled and says why.

    Returns the dock (also stored as ``window.muscle_dock``).
    """
    dock = MuscleDock(window, level=level)
    window.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, dock)
    fap_dock = window.fap_dock
    if fap_dock is not None:
        window.tabifyDockWidget(fap_dock, dock)
        fap_dock.raise_()
    toggle = dock.toggleViewAction()
    toggle.setText("&Muscles")
    toggle.setStatusTip("Show or hide the muscle dock (thesis C forces, jaw, presets)")
    toggle.setShortcut(QKeySequence("Ctrl+Shift+M"))
    toggle.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
    window.addAction(toggle)
    view_menu = window.view_menu
    if view_menu is not None:
        view_menu.addAction(toggle)
    window.muscle_dock = dock
    window.muscle_dock_action = toggle
    dock._close_watcher = _CloseWatcher(dock, window)  # noqa: SLF001
    window.face_changed.connect(lambda _face: dock.build_for_window())
    if window.document.face is not None:
        dock.build_for_window()
    return dock


__all__ = ["MuscleDock", "attach_muscle_dock", "RELAX_BUDGET_S", "ANIMATION_S", "JAW"]
