"""control_point_drag.py
----
Dragging RBF control points in the viewport (issue 17, item 2), for :mod:`app.control_point_dock`.

* :class:`ControlPointDrag` — a Qt event filter on the viewport widget. A left press within
  ``PICK_PX`` logical pixels of a visible control-point marker (not hidden behind the face) starts a drag
  and the press, moves and release are consumed, so the camera does not orbit; any other press goes to
  the camera as before. The point moves in the plane through it parallel to the screen, or along the
  X/Y/Z axis chosen in the dock (the line's point nearest the pointer's ray). Until the pointer has moved
  more than ``CLICK_SLOP_PX`` nothing moves (a click on a marker only selects the point). Each move is one
  ``rig.set_values`` (the viewport's scheduler draws at most one frame per pass of the event loop); the
  whole drag is one undo macro, "Move control point <name>" (the rig's own per-gesture steps, and
  auto-keys, inside it). Esc during the drag puts the point back and leaves no undo step; X, Y or Z
  during the drag constrain it to that axis (pressed again: the view plane), as in Blender. With "Link
  left/right" the mirror partner gets the dock's mirrored values (``control_point_dock.mirrored``).
* The inverse, live (issue 17, item 5): in the dock's inverse mode a press on the skin grabs that skin point
  and each move solves the Waters activations that bring it nearest the pointer (``core.inverse.reach``,
  regularised toward the current pose); one undo step per drag, Esc cancels. A click without a drag is
  still the two-click inverse (skin point, then target); a drag off the face turns the camera.
* :class:`RegionHighlight` — the influence region of the hovered (or dragged) point as a translucent
  overlay whose opacity is the region weight Ω, and the point itself bigger; each point's sub-mesh is built
  once and cached.
"""

from __future__ import annotations

import traceback

import numpy as np
from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtGui import QUndoCommand

from app.picking import CLICK_SLOP_PX, qt_to_display
from app.projection import closest_on_line, display_ray, display_to_world, world_to_display

__all__ = ["ControlPointDrag", "RegionHighlight", "PICK_PX"]

#: A press this close (logical pixels) to a marker grabs the control point.
PICK_PX = 10.0
#: A marker whose pick ray meets the face this much (mm) before reaching it is hidden behind the face.
OCCLUDED_MM = 3.0
REGION_RGB = (40, 200, 255)
REGION_LIFT_MM = 0.5   # above the skin, so the face does not hide it
#: Keys during a drag: Esc cancels, X/Y/Z constrain to that axis (again: the view plane), as in Blender.
AXIS_KEYS = {Qt.Key.Key_Escape: None, Qt.Key.Key_X: "x", Qt.Key.Key_Y: "y", Qt.Key.Key_Z: "z"}
HOT_RGB = (1.0, 0.35, 0.15)   # the hovered / dragged point, bigger, as in the reference chart
HOT_SIZE_PX = 17
HOT_LIFT_MM = 1.5


class RegionHighlight:
    """The influence region of one control point drawn over the face, and the point bigger (see the module
    docstring).

    Two copies of the region: on the full face, and on the face's draft copy (``app.preview``) that the
    viewport draws while things move; :meth:`use_draft` shows the one matching the face (a translucent
    full-resolution region would double a drag frame's draw time on software GL).
    """

    def __init__(self, plotter):
        self.plotter = plotter
        self.index: int | None = None
        self.draft = False
        self.actors: dict[str, object] = {}     # "full" / "draft" region, "marker"
        self.meshes: dict[str, object] = {}
        self._verts: dict[str, np.ndarray] = {}
        self._cache: dict[tuple, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def region(self, rbf, index: int, triangles: np.ndarray | None = None, tag: str = "full"
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices (k,), triangles (m, 3) into them, weights (k,) in (0, 1]) of control point ``index``:
        the ``triangles`` (face vertex ids; default the face's) whose corners it may all move."""
        deformer = rbf.deformer
        key = (id(deformer), index, tag)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        face = deformer.face
        if deformer.omega is None:   # no regions: every vertex
            vertices, weights = np.asarray(deformer.active), np.ones(len(deformer.active))
        else:
            w = np.asarray(deformer.omega[:, index])
            keep = w > 0.02
            vertices, weights = np.asarray(deformer.active)[keep], w[keep]
        local = np.full(face.n_vertices, -1, dtype=np.int64)
        local[vertices] = np.arange(len(vertices))
        tri = local[face.triangles if triangles is None else triangles]
        tri = tri[(tri >= 0).all(axis=1)]
        used = np.unique(tri)                     # only the vertices these triangles use
        hit = (vertices[used], np.searchsorted(used, tri), weights[used])
        if len(self._cache) > 200:
            self._cache.clear()
        self._cache[key] = hit
        return hit

    def show(self, rbf, index: int | None, vertices: np.ndarray, preview=None) -> bool:
        """Show the region of ``index`` (None: hide) on the posed ``vertices`` (n, 3), also on ``preview``'s
        triangles when given (app.preview.PreviewMesh); True if the picture changed."""
        if index is None or rbf is None:
            return self.hide()
        if index != self.index:
            self.remove()
        import pyvista as pv

        parts = {"full": None} if preview is None else {"full": None, "draft": preview.index[preview.triangles]}
        for tag, triangles in parts.items():
            verts, tri, weights = self.region(rbf, index, triangles, tag)
            points = vertices[verts] + REGION_LIFT_MM * rbf.face.vertex_normals[verts]
            mesh = self.meshes.get(tag)
            if mesh is not None:
                mesh.points[:] = points
                mesh.Modified()
                continue
            mesh = pv.PolyData(points, np.c_[np.full(len(tri), 3), tri].ravel())
            rgba = np.empty((len(verts), 4), dtype=np.uint8)
            rgba[:, :3] = REGION_RGB
            rgba[:, 3] = (30 + 120 * np.clip(weights, 0.0, 1.0)).astype(np.uint8)   # the skin shows through
            mesh.point_data["rgba"] = rgba
            self.meshes[tag], self._verts[tag] = mesh, verts
            self.actors[tag] = self.plotter.add_mesh(
                mesh, scalars="rgba", rgba=True, pickable=False, reset_camera=False, render=False,
                show_scalar_bar=False, lighting=False, name=f"control_point_region_{tag}")
        v = rbf.points.vertices[index]
        marker = (vertices[v] + HOT_LIFT_MM * rbf.face.vertex_normals[v])[None]
        if "marker" in self.meshes:
            self.meshes["marker"].points[:] = marker
            self.meshes["marker"].Modified()
        else:
            self.meshes["marker"] = pv.PolyData(marker)
            self.actors["marker"] = self.plotter.add_mesh(
                self.meshes["marker"], color=HOT_RGB, point_size=HOT_SIZE_PX, render_points_as_spheres=True,
                pickable=False, reset_camera=False, render=False, name="control_point_hot")
        self.index = index
        self._apply_draft()
        return True

    def use_draft(self, on: bool) -> bool:
        """Show the region on the draft copy (``on``) or the full face; True if that changed what is drawn."""
        on = bool(on)
        changed = on != self.draft and self.index is not None and "draft" in self.actors
        self.draft = on
        self._apply_draft()
        return changed

    def _apply_draft(self) -> None:
        draft = self.draft and "draft" in self.actors
        if "full" in self.actors:
            self.actors["full"].SetVisibility(not draft)
        if "draft" in self.actors:
            self.actors["draft"].SetVisibility(draft)

    def hide(self) -> bool:
        changed = bool(self.actors)
        self.remove()
        return changed

    def remove(self) -> None:
        for actor in self.actors.values():
            self.plotter.remove_actor(actor, reset_camera=False, render=False)
        self.actors.clear()
        self.meshes.clear()
        self._verts.clear()
        self.index = None

    @property
    def mesh(self):
        """The full-face region mesh shown, or None."""
        return self.meshes.get("full")

    @property
    def weights(self) -> np.ndarray | None:
        """(k,) the shown region's per-vertex opacity (0-255), or None (tests)."""
        return None if self.mesh is None else np.asarray(self.mesh.point_data["rgba"][:, 3])


class _Drag:
    """One drag in progress: a control point (``index``), or a skin ``vertex`` in inverse mode."""

    def __init__(self, index: int | None, name: str, keys: list[str], start: dict, origin: np.ndarray,
                 grab: np.ndarray, press, axis: str | None, link: bool, available: set, *, vertex: int | None = None,
                 response=None, x: float = 0.0, y: float = 0.0):
        self.index, self.name, self.keys, self.start = index, name, keys, start
        self.origin, self.grab, self.press = origin, grab, press
        self.axis, self.link, self.available = axis, link, available
        self.vertex, self.response = vertex, response
        self.x, self.y = x, y              # display pixel of the press
        self.moved = False
        self.macro = False
        self.last = None                   # (x, y, pos) of the latest move


class ControlPointDrag(QObject):
    """Drags control points on the viewport widget of ``dock`` (a ControlPointDock; see the module docstring).

    ``hovered`` is the control point index under the pointer (or being dragged), ``drag`` the drag in progress.
    """

    def __init__(self, dock):
        widget = dock.window_.plotter
        super().__init__(widget)
        self.dock = dock
        self.widget = widget
        self.hovered: int | None = None
        self.drag: _Drag | None = None
        self.claimed_press = False    # the last press grabbed a point (the dock's click modes ignore it)
        self._response = None         # (Waters layer, its core.inverse.LinearResponse) for inverse drags
        self.miss: float | None = None   # mm between the last inverse drag's skin point and its target
        widget.setMouseTracking(True)
        widget.installEventFilter(self)

    # ------------------------------------------------------------ geometry
    @property
    def renderer(self):
        return self.dock.window_.plotter.renderer

    def point_at(self, x: float, y: float) -> int | None:
        """The control point whose marker is under display pixel (x, y) and not hidden by the face, or None."""
        dock = self.dock
        if not dock.markers_shown():
            return None
        markers = dock._point_positions()
        screen = world_to_display(self.renderer, markers)
        radius = PICK_PX * self.widget.devicePixelRatioF()
        dist = np.hypot(screen[:, 0] - x, screen[:, 1] - y)
        near = np.nonzero((dist <= radius) & (screen[:, 2] > 0.0) & (screen[:, 2] < 1.0))[0]
        if not len(near):
            return None
        camera = np.array(self.renderer.GetActiveCamera().GetPosition())
        for i in near[np.argsort(screen[near, 2])]:      # front-most first
            hit = dock.pick(*screen[i, :2])
            if hit is None or np.linalg.norm(np.array(hit.position) - camera) > \
                    np.linalg.norm(markers[i] - camera) - OCCLUDED_MM:
                return int(i)
        return None

    def _delta(self, d: _Drag, x: float, y: float) -> np.ndarray | None:
        """World displacement (3,) of the point for the pointer at display (x, y), or None (axis along the view)."""
        x, y = x + d.grab[0], y + d.grab[1]
        if d.axis is None:
            depth = world_to_display(self.renderer, d.origin)[0, 2]
            return display_to_world(self.renderer, x, y, depth) - d.origin
        axis = np.zeros(3)
        axis["xyz".index(d.axis)] = 1.0
        t = closest_on_line(d.origin, axis, *display_ray(self.renderer, x, y))
        return None if t is None else t * axis

    # ------------------------------------------------------------ drag
    def start(self, index: int, x: float, y: float, press) -> None:
        dock, rig = self.dock, self.dock.rig
        rbf = dock.rbf
        fp, name = rbf.points.feature_points[index], rbf.points.names[index]
        keys = [f"cp:{fp}:{a}" for a in "xyz"]
        link = dock.link_check.isChecked()
        available = set(rig.parameters())
        partner = [k for key in keys for k in (dock.mirrored_keys(key, available) if link else ())]
        start = {k: rig.value(k) for k in keys + partner}
        origin = np.array(rig.vertices()[rbf.points.vertices[index]])
        grab = world_to_display(self.renderer, origin)[0, :2] - (x, y)   # the point keeps its offset from the pointer
        self.drag = _Drag(index, name, keys, start, origin, grab, press, dock.drag_axis(), link, available)
        self.hovered = index
        combo = dock.point_combo
        if combo.findData(fp) >= 0 and combo.currentData() != fp:
            combo.setCurrentIndex(combo.findData(fp))
        dock.show_hover(index)
        self.widget.setFocus(Qt.FocusReason.MouseFocusReason)   # for Esc

    def start_inverse(self, x: float, y: float, press) -> bool:
        """Inverse mode: grab the skin under display (x, y) (False: the face is not there)."""
        dock = self.dock
        waters = dock.waters
        hit = dock.pick(x, y) if waters is not None else None
        if hit is None:
            return False
        from core.inverse import LinearResponse

        corners = dock.rig.face.triangles[hit.triangle]
        vertex = int(corners[int(np.argmax(hit.barycentric))])
        if self._response is None or self._response[0] is not waters:
            self._response = (waters, LinearResponse.of_waters(waters))
        response = self._response[1]
        origin = np.array(dock.rig.vertices()[vertex])
        grab = world_to_display(self.renderer, origin)[0, :2] - (x, y)
        start = {k: dock.rig.value(k) for k in response.keys}
        self.miss = None
        self.drag = _Drag(None, "skin point", [], start, origin, grab, press, dock.drag_axis(), False, set(),
                          vertex=vertex, response=response, x=x, y=y)
        self.widget.setFocus(Qt.FocusReason.MouseFocusReason)
        return True

    def _move_inverse(self, d: _Drag, delta: np.ndarray) -> None:
        from core.inverse import reach

        stack = self.dock.undo_stack()
        if not d.macro and stack is not None:
            stack.beginMacro("Inverse drag of a skin point")
            d.macro = True
        target = d.origin + delta
        reach(self.dock.rig, self.dock.waters, d.response, [d.vertex], target[None])
        self.miss = float(np.linalg.norm(self.dock.rig.vertices()[d.vertex] - target))

    def move(self, x: float, y: float, pos) -> None:
        d = self.drag
        d.last = (x, y, pos)
        if not d.moved:
            if np.hypot(pos.x() - d.press.x(), pos.y() - d.press.y()) <= CLICK_SLOP_PX:
                return       # a click, so far
            d.moved = True
        delta = self._delta(d, x, y)
        if delta is None:
            return
        if d.vertex is not None:
            self._move_inverse(d, delta)
            return
        values = {}
        for a, key in enumerate(d.keys):
            values[key] = d.start[key] + float(delta[a])
        if d.link:
            for key in d.keys:
                values.update(self.dock.mirrored_values(key, values[key], d.available))
        stack = self.dock.undo_stack()
        if not d.macro and stack is not None:
            stack.beginMacro(f"Move control point {d.name}")
            d.macro = True
        self.dock._apply(values)

    def finish(self, cancel: bool = False) -> None:
        """End the drag: one undo step, or (``cancel``) the point back where it was and no step."""
        d, self.drag = self.drag, None
        if d is None:
            return
        stack = self.dock.undo_stack()
        if d.macro and stack is not None and stack.count() == 0:
            d.macro = False            # the history was cleared under the drag (a new face): no macro left to end
        if d.macro:
            stack.endMacro()
            top = stack.command(stack.index() - 1)
            # Cancelled, or nothing left (a drag back to its start): undo the macro (the rig, and any auto-keys,
            # back as they were), then drop it from the redo side: pushing an obsolete command clears that side
            # and is not kept. (Esc is a new gesture, so a cancel cannot simply merge away.)
            if top is not None and (cancel or top.childCount() == 0):
                stack.undo()
                drop = QUndoCommand("")
                drop.setObsolete(True)
                stack.push(drop)
        if cancel and d.moved and not d.macro:
            self.dock._apply(dict(d.start))      # no undo stack to do it
        status = self.dock.window_.statusBar()
        if cancel:
            status.showMessage(f"Drag of the {d.name} cancelled" if d.index is None else
                               f"Drag of {d.name} cancelled", 3000)
        elif d.vertex is not None and not d.moved:      # a click in inverse mode: the two-click inverse
            self.claimed_press = False
            self.dock.on_click(d.x, d.y)
        elif d.vertex is not None and self.miss is not None:
            status.showMessage(f"The Waters muscles reach within {self.miss:.1f} mm of the target"
                               + (": it is beyond what they can do" if self.miss > 1.0 else ""), 6000)

    # ------------------------------------------------------------ events
    def eventFilter(self, watched, event) -> bool:  # noqa: N802 - Qt override
        kind = event.type()
        try:
            if self.drag is not None:
                return self._while_dragging(kind, event)
            if kind == QEvent.Type.MouseButtonPress:
                self.claimed_press = False
                if event.button() != Qt.MouseButton.LeftButton or event.buttons() != Qt.MouseButton.LeftButton:
                    return False
                pos = event.position()
                x, y = qt_to_display(self.widget, pos.x(), pos.y())
                index = self.point_at(x, y)
                if index is not None:
                    self.claimed_press = True
                    self.start(index, x, y, pos)
                    return True
                if self.dock.click_combo.currentData() == "inverse" and self.dock.inverse_vertex is None \
                        and self.start_inverse(x, y, pos):
                    self.claimed_press = True
                    return True
                return False                     # the camera's press
            if kind == QEvent.Type.MouseMove and event.buttons() == Qt.MouseButton.NoButton:
                pos = event.position()
                index = self.point_at(*qt_to_display(self.widget, pos.x(), pos.y()))
                if index != self.hovered:
                    self.hovered = index
                    self.dock.show_hover(index)
            elif kind == QEvent.Type.Leave and self.hovered is not None:
                self.hovered = None
                self.dock.show_hover(None)
        except Exception as exc:  # noqa: BLE001 - an event filter must not raise into Qt
            traceback.print_exc()
            self._abandon(exc)
        return False

    def _while_dragging(self, kind, event) -> bool:
        if kind == QEvent.Type.MouseMove:
            pos = event.position()
            self.move(*qt_to_display(self.widget, pos.x(), pos.y()), pos)
            return True
        if kind == QEvent.Type.MouseButtonRelease:
            if event.button() == Qt.MouseButton.LeftButton:
                self.finish()
            return True
        if kind in (QEvent.Type.ShortcutOverride, QEvent.Type.KeyPress) and event.key() in AXIS_KEYS:
            event.accept()               # take Esc and X/Y/Z from the window's shortcuts for the drag
            if kind == QEvent.Type.KeyPress and event.key() == Qt.Key.Key_Escape:
                self.finish(cancel=True)
            elif kind == QEvent.Type.KeyPress and not event.isAutoRepeat():
                self._switch_axis(AXIS_KEYS[event.key()])
            return True
        if kind in (QEvent.Type.MouseButtonPress, QEvent.Type.MouseButtonDblClick):
            return True                  # other buttons while dragging: not the camera's
        return False

    def _switch_axis(self, axis: str) -> None:
        """X, Y or Z during a drag: along that axis from where the drag started (again: the view plane)."""
        d = self.drag
        d.axis = None if d.axis == axis else axis
        if d.last is not None:
            self.move(*d.last)
        self.dock.window_.statusBar().showMessage(
            f"Dragging along {d.axis.upper()}" if d.axis else "Dragging in the view plane", 3000)

    def _abandon(self, exc: Exception) -> None:
        """After an error: end any drag (its values so far stay, one step) and say what happened."""
        try:
            if self.drag is not None:
                self.finish()
        except Exception:  # noqa: BLE001
            traceback.print_exc()
            self.drag = None
        self.dock.show_message(f"Control-point drag failed: {exc}")

    def remove(self) -> None:
        if self.drag is not None:
            self.finish(cancel=True)
        self.widget.removeEventFilter(self)
