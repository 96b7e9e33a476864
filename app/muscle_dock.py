"""muscle_dock.py
----
The muscle dock (thesis C's interface): one slider per muscle *per side* and the jaw angle, a view
of :class:`app.muscle_simulation.MuscleSimulation` (``dock.simulation``), which owns the
:class:`core.layers.muscles.MuscleLayer` on the window's :class:`core.rig.FaceRig`, its solver
loops (live settling, Animate, Rest), the edits and their undo steps, and the force-set files.

* Rows: the shared :class:`app.parameter_row.ParameterRow` of each control's registry key
  ("muscle:risorius:left", "jaw"): the 9 linear muscles as pairs (the name spans two lines, "left"
  and "right" below each other, so the two sides of a muscle sit together and every slider has the
  full width), then the orbicularis oris and the jaw opening. Each row: slider, spin box with units
  (thesis force units ``u``; degrees for the jaw), reset ↺. "Link left/right" moves a control's
  mirror (from the registry) with it. "left"/"right" are the face's own sides (in the front view its
  left is on the screen's right).
* House rules of the FAP dock: widgets forward edits to the controller and never keep their own
  copy; every widget follows ``simulation.values_changed`` with its signals blocked (no echo); the
  dock never renders: the layer's changes reach the rig and the window redraws once per burst.
* Presets (thesis C's test expressions): choosing one applies it. The box follows the forces from
  anywhere (an edit, undo, the timeline): it shows the preset they match, else "Custom" ("None" at
  rest). "Apply again" applies the shown preset, or the one applied last after edits, whose values
  are then marked on the sliders (``ParameterRow.set_mark``), as the FAP dock marks its presets'.
* Save / Open of force sets (JSON): dialogs here, the files in the controller; a malformed file
  shows its ``ForceFileError`` message in a warning box and leaves the forces alone.
* The muscles can be drawn in the viewport ("Show muscles", :mod:`app.muscle_view`).

``MuscleDock(document, window)`` joins the window: the controller builds the layer on a worker
thread and re-builds it when the document's face changes, and shuts down when the window really
closes (``MainWindow.closing``: after any Save / Discard / Cancel question, not on a cancelled close).
The widgets are built in :mod:`app.muscle_dock_ui`.
"""

from __future__ import annotations

import traceback
from typing import TYPE_CHECKING, Hashable

from PySide6.QtCore import QSignalBlocker, Qt, Signal
from PySide6.QtGui import QKeySequence
from PySide6.QtWidgets import QDockWidget, QLabel, QMessageBox, QWidget

from app.muscle_dock_ui import JAW, NO_PRESET_AT_REST, NO_PRESET_EDITED, MuscleDockLayout
from app.muscle_simulation import (  # noqa: F401 - some re-exported
    ANIMATION_S, BUILDING_MESSAGE, NO_FACE_MESSAGE, NO_RIG_MESSAGE, RELAX_BUDGET_S, MuscleSimulation, preset_title)
from app.parameter_row import ParameterRow
from core import parameters as P

if TYPE_CHECKING:  # pragma: no cover
    from core.layers.muscles import MuscleLayer


class MuscleDock(MuscleDockLayout, QDockWidget):
    """The muscle dock (see the module docstring).

    Parameters
    ----------
    document : app.document.Document, optional
        The face and rig whose muscle layer the dock builds and drives; without one the dock
        drives whatever layer ``dock.simulation.set_layer`` receives (no build).
    window : MainWindow, optional
        The window the dock joins (see :meth:`_join`): its plotter, status bar, settings, View menu.
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

    def __init__(self, document=None, window=None, *, level: int = 3):
        super().__init__("Muscles", window)
        self.setObjectName("muscleDock")
        self.setAllowedAreas(Qt.DockWidgetArea.LeftDockWidgetArea | Qt.DockWidgetArea.RightDockWidgetArea)
        self.window_ = window
        self.document = document
        self.simulation = sim = MuscleSimulation(
            self, level=level, document=document,
            redraw_ms=(lambda: window.last_tick_ms) if window is not None else None)
        self.view = None  # MuscleView, while a layer and a plotter exist
        self.rows: dict[str, ParameterRow] = {}   # by canonical key: "muscle:risorius:left", "jaw"
        self.name_labels: dict[str, QLabel] = {}
        self._syncing = False
        self._view_dirty = True

        self._build_ui()
        sim.layer_changed.connect(self._on_layer_changed)
        sim.message_changed.connect(self.show_message)
        sim.values_changed.connect(self._show_values)
        sim.refused.connect(lambda _message: self._show_values(force=True))
        sim.pose_changed.connect(self._on_pose_changed)
        sim.status_changed.connect(self.status_label.setText)
        sim.animating_changed.connect(lambda on: self.stop_button.setEnabled(on and self.layer is not None))
        sim.diverged.connect(self.status_label.setToolTip)
        sim.notice.connect(self._status_bar)
        sim.settled.connect(self.settled)
        sim.set_layer(None, NO_FACE_MESSAGE)
        if window is not None and document is not None:
            self._join(window)

    def _join(self, window) -> None:
        """Take the dock's place in the window: the right dock area, tabified with the FAP dock
        ("Muscles" tab); View ▸ Muscles (Ctrl+Shift+M); the layer is built on a worker thread for
        each new face (``document.face_changed``); the controller shuts down on ``window.closing``
        (a close that really happens, after any Save / Discard / Cancel question)."""
        window.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self)
        fap_dock = window.fap_dock
        if fap_dock is not None:
            window.tabifyDockWidget(fap_dock, self)
            fap_dock.raise_()
        toggle = self.toggleViewAction()
        toggle.setText("&Muscles")
        toggle.setStatusTip("Show or hide the muscle dock (thesis C forces, jaw, presets)")
        toggle.setShortcut(QKeySequence("Ctrl+Shift+M"))
        toggle.setShortcutContext(Qt.ShortcutContext.WindowShortcut)
        window.addAction(toggle)
        if window.view_menu is not None:
            window.view_menu.addAction(toggle)
        self.toggle_action = toggle
        window.closing.connect(self.shutdown)
        self.document.face_changed.connect(lambda _face: self.simulation.follow_document())
        self.document.rig_changed.connect(lambda _rig: self.simulation.follow_document())
        if self.document.face is not None:
            self.simulation.follow_document()

    # ============================================================ what the controller holds
    @property
    def layer(self) -> "MuscleLayer | None":
        return self.simulation.layer

    @property
    def rig(self):
        return self.simulation.rig

    @property
    def status(self) -> str:
        return self.status_label.text()

    @property
    def is_building(self) -> bool:
        return self.simulation.building

    def row(self, key: Hashable) -> ParameterRow:
        """The row of a control by any spelling: ("risorius", "left"), "muscle:risorius:left", "jaw"."""
        return self.rows[P.key_of(key)]

    # ============================================================ messages
    def show_message(self, message: str) -> None:
        """Show ``message`` above the controls (empty hides it)."""
        self.message_label.setText(message)
        self.message_label.setVisible(bool(message))
        self.busy_bar.setVisible(message == BUILDING_MESSAGE and self.layer is None)

    def _status_bar(self, text: str, ms: int = 8000) -> None:
        window = self.window_
        if window is not None:
            window.statusBar().showMessage(text, ms)

    # ============================================================ controller -> widgets
    def _on_layer_changed(self, layer) -> None:
        if self.view is not None:
            self.view.remove()
            self.view = None
        if layer is not None:
            self._make_view()
        self._set_controls_enabled(layer is not None)
        self.busy_bar.setVisible(self.simulation.building)
        self.status_label.setToolTip("State of the tissue simulation")
        self._show_values()
        self.layer_changed.emit(layer)

    def _show_values(self, force: bool = False) -> None:
        """Every row, the preset box and the marks to the layer's values, emitting nothing
        (``force``: rows that think they already show the value too, after a refused edit)."""
        values = self.simulation.values()
        if not values:
            return
        self._syncing = True
        try:
            for key, row in self.rows.items():
                value = values.get(key, 0.0)
                if force or row.value != value:
                    row.show_value(value)
            self._show_preset()
        finally:
            self._syncing = False

    def _show_preset(self) -> None:
        """The box shows the preset the forces match (else None / Custom); while they differ from
        the preset "Apply again" would apply, its values are marked on the sliders."""
        from core.layers.muscles import preset

        sim, combo = self.simulation, self.preset_combo
        combo.setItemText(0, NO_PRESET_AT_REST if sim.at_rest else NO_PRESET_EDITED)
        with QSignalBlocker(combo):
            combo.setCurrentIndex(max(combo.findData(sim.preset), 0) if sim.preset is not None else 0)
        target = self.preset_target()
        self.apply_button.setEnabled(self.layer is not None and target is not None)
        self.apply_button.setToolTip(f"Set the forces (and jaw) of {preset_title(target).lower()} again"
                                     if target else "Choose an expression in the list first")
        marks: dict[str, float] = {}
        if target is not None and sim.preset != target:
            force_set = preset(target)
            marks = {P.key_of(k): v for k, v in force_set.full().items()}
            marks[JAW] = force_set.jaw_deg
        note = f"{preset_title(target)} puts it at {{:g}} (Apply again)." if target else ""
        for key, row in self.rows.items():
            value = marks.get(key) or None   # as in the FAP dock: only where the preset moves it
            row.set_mark(value, note.format(value) if value is not None else "")

    def preset_target(self) -> str | None:
        """What "Apply again" applies: the preset the box shows, else the one applied last."""
        return self.preset_combo.currentData() or self.simulation.last_preset

    def _on_pose_changed(self) -> None:
        self._view_dirty = True
        if self.view is not None and self.view.visible:
            self._update_view()

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
        if self.window_ is not None:   # redraw once, with whatever else changed
            self.window_.viewport.request("muscles")

    # ============================================================ widgets -> controller
    def _row_edited(self, key: str, value: float) -> None:
        if self.layer is None or self._syncing:
            return
        values = {key: value}
        mirror = self.rows[key].mirror
        if mirror in self.rows and self.link_check.isChecked():
            values[mirror] = self.rows[mirror].clamp(value)
        self.simulation.set_values(values)

    def set_control(self, key: Hashable, value: float) -> None:
        """Set one control as if its row was edited (link, undo and settling included)."""
        self._row_edited(P.key_of(key), float(value))

    def reset_control(self, key: Hashable) -> None:
        """The row's ↺: that control to its default, 0 (and its mirror when linked)."""
        row = self.rows.get(P.key_of(key))
        if row is not None:
            self._row_edited(row.key, row.default)

    def apply_preset(self, name: str | None) -> bool:
        """Apply one of ``core.layers.muscles.preset_names()`` (one undo step)."""
        if self.layer is None or not name:
            return False
        try:
            return self.simulation.apply_preset(name)
        except (KeyError, ValueError) as exc:
            QMessageBox.warning(self, "Unknown expression", str(exc))
            return False

    def shutdown(self) -> None:
        """The window closes: the controller stops, the muscles leave the viewport."""
        self.simulation.shutdown()
        if self.view is not None:
            self.view.remove()
            self.view = None


__all__ = ["MuscleDock", "MuscleSimulation", "RELAX_BUDGET_S", "ANIMATION_S", "JAW",
           "BUILDING_MESSAGE", "NO_FACE_MESSAGE", "NO_RIG_MESSAGE"]
