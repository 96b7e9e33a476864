"""picking.py
----
Viewport interaction for the landmark editor, on a pyvistaqt/VTK plotter:

* :class:`ViewportMouse` tells a click from a camera drag (MNE's
  ``_mouse_no_mvt``, napari's ``DRAG_DIST_THRESHOLD``): ``on_click`` fires
  only when the left button went down and up without the pointer moving more
  than ``slop`` logical pixels in between, so orbiting the camera never moves
  a landmark. It never consumes events: the camera still gets every press
  and drag.
* :class:`SurfacePicker` casts the ray under a pixel through a
  ``vtkCellPicker`` restricted to the face actor, with a
  ``vtkStaticCellLocator`` built once per mesh state (rebuilt lazily, on the
  next pick, after the displayed vertices change). The result is the exact
  hit point with its triangle and barycentric weights on the *displayed*
  mesh, never a snapped vertex; triangle + barycentric are the same on the
  neutral face, which is where landmarks are stored.
* :func:`world_to_display` / :func:`display_to_qt` project points the way
  the renderer does (tests click at projected landmarks with them).
* :class:`LandmarkMarkers` draws status-coloured landmark markers, their
  names, and the selected/hovered landmark bigger and brighter with a label
  box; every update writes into existing arrays (no actor is re-created on
  an edit).

Measured pick times are in ``benchmarks/landmark_pick.py``.
"""

from __future__ import annotations

import traceback
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import pyvista as pv
# The VTK classes used here only: `import vtk` loads every VTK module (~0.5 s of start-up).
from vtkmodules.vtkCommonDataModel import vtkStaticCellLocator
from vtkmodules.vtkRenderingCore import vtkCellPicker, vtkCoordinate, vtkTextActor
from PySide6.QtCore import QEvent, QObject, QPointF, Qt

from app.label_layout import LabelLayout
from app.projection import world_to_display
from core.face import SurfacePoint

__all__ = [
    "CLICK_SLOP_PX", "STATUS_COLORS", "SurfaceHit", "SurfacePicker", "ViewportMouse", "LandmarkMarkers",
    "world_to_display", "display_to_qt", "qt_to_display", "barycentric_of",
]

#: A press and release this close (logical pixels, both ways) is a click, not a drag.
CLICK_SLOP_PX = 4
#: Status colours (RGB 0-255): auto = amber, edited = blue, confirmed = green.
STATUS_COLORS = {"auto": (245, 166, 35), "edited": (64, 148, 255), "confirmed": (60, 200, 100)}
MARKER_SIZE_PX = 11.0
SELECTED_SIZE_PX = 19.0
HOVER_SIZE_PX = 15.0
# Markers float above the surface so it does not swallow half of each sphere;
# the (bigger) selected one a little more. Labels further out.
MARKER_OFFSET_MM = 0.8
SELECTED_OFFSET_MM = 2.0
LABEL_OFFSET_MM = 2.0
#: Font sizes of the selected and hovered landmarks' own label boxes.
SELECTED_LABEL_PT = 14
HOVER_LABEL_PT = 13


# ------------------------------------------------------------------ projections
def qt_to_display(widget, x: float, y: float) -> tuple[float, float]:
    """Widget (logical, origin top-left) -> VTK display (device pixels, origin bottom-left), as pyvistaqt maps."""
    scale = widget.devicePixelRatioF()
    return x * scale, (widget.height() - y - 1) * scale


def display_to_qt(widget, x: float, y: float) -> tuple[float, float]:
    """Inverse of :func:`qt_to_display`."""
    scale = widget.devicePixelRatioF()
    return x / scale, widget.height() - 1 - y / scale


def barycentric_of(corners: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(3,) barycentric weights of ``point`` (3,) projected into the triangle ``corners`` (3, 3);
    clipped to the triangle and summing to 1."""
    a, b, c = np.asarray(corners, dtype=np.float64)
    v0, v1, v2 = b - a, c - a, np.asarray(point, dtype=np.float64) - a
    d00, d01, d11 = v0 @ v0, v0 @ v1, v1 @ v1
    d20, d21 = v2 @ v0, v2 @ v1
    denom = d00 * d11 - d01 * d01
    if denom <= 0:  # degenerate triangle: its first corner
        return np.array([1.0, 0.0, 0.0])
    v = (d11 * d20 - d01 * d21) / denom
    w = (d00 * d21 - d01 * d20) / denom
    bary = np.clip(np.array([1.0 - v - w, v, w]), 0.0, None)
    return bary / bary.sum()


# ------------------------------------------------------------------ surface picks
@dataclass(frozen=True)
class SurfaceHit:
    """Where the ray under a pixel first meets the face.

    ``position`` (3,) mm on the displayed mesh; ``triangle`` and ``barycentric`` (3,) locate
    it on any pose of the same topology.
    """

    triangle: int
    barycentric: tuple[float, float, float]
    position: tuple[float, float, float]

    def surface_point(self) -> SurfacePoint:
        return SurfacePoint(self.triangle, self.barycentric)


class SurfacePicker:
    """Exact ray picks on one face actor's displayed mesh (see the module docstring).

    Parameters
    ----------
    actor : vtkActor
        The face actor (the only prop picked: markers and labels are ignored).
    mesh : pyvista.PolyData
        Its triangle mesh, updated in place when the face animates.
    triangles : (m, 3) int
        The face's triangles (cell i of ``mesh`` is triangle i).
    """

    def __init__(self, actor, mesh: pv.PolyData, triangles: np.ndarray):
        self.actor = actor
        self.mesh = mesh
        self.triangles = np.asarray(triangles)
        self.locator = vtkStaticCellLocator()
        self.locator.SetDataSet(mesh)
        self.locator.BuildLocator()
        self.picker = vtkCellPicker()
        self.picker.PickFromListOn()
        self.picker.AddPickList(actor)
        self.picker.SetTolerance(1e-6)
        self.picker.AddLocator(self.locator)

    def pick(self, renderer, x: float, y: float) -> SurfaceHit | None:
        """The surface under display pixel (x, y) (VTK device pixels), or None when the ray misses."""
        self.locator.BuildLocator()  # no-op unless the mesh changed since the last build
        # VTK skips hidden actors; the face is hidden while its draft copy is drawn (app.preview),
        # and its mesh is current then too.
        visible = self.actor.GetVisibility()
        self.actor.SetVisibility(True)
        try:
            hit = self.picker.Pick(float(x), float(y), 0.0, renderer)
        finally:
            self.actor.SetVisibility(visible)
        if not hit:
            return None
        cell = int(self.picker.GetCellId())
        if cell < 0 or cell >= len(self.triangles):
            return None
        position = np.array(self.picker.GetPickPosition(), dtype=np.float64)
        corners = np.asarray(self.mesh.points)[self.triangles[cell]]
        bary = barycentric_of(corners, position)
        return SurfaceHit(cell, tuple(float(b) for b in bary), tuple(float(p) for p in bary @ corners))


# ------------------------------------------------------------------ click vs drag
class ViewportMouse(QObject):
    """Left-button clicks (not drags) and hovering on the viewport widget.

    A Qt event filter on the widget, not a VTK observer: once the camera style starts a
    rotation it grabs VTK's event focus and the interactor's other observers no longer see the
    moves and the release. The filter never consumes an event, so the camera works as usual.

    Parameters
    ----------
    widget : QWidget
        The pyvistaqt interactor widget.
    on_click : callable(x, y, shift: bool, ctrl: bool)
        VTK display coordinates (device pixels, origin bottom-left) of a click.
    on_hover : callable(x, y) or None
        The pointer moved with no button down.
    on_leave : callable() or None
        The pointer left the viewport.
    slop_px : float
        Click tolerance in logical pixels, measured over the whole press (the largest distance
        from the press point), so a drag that comes back to its start is still a drag.
    """

    def __init__(self, widget, on_click: Callable, on_hover: Callable | None = None,
                 on_leave: Callable | None = None, *, slop_px: float = CLICK_SLOP_PX):
        super().__init__(widget)
        self.widget = widget
        self.on_click, self.on_hover, self.on_leave = on_click, on_hover, on_leave
        self.slop_px = float(slop_px)
        self.enabled = True
        self._down: QPointF | None = None
        self._travel = 0.0
        self._other_buttons = False
        widget.setMouseTracking(True)  # hover events without a button down
        widget.installEventFilter(self)

    @property
    def dragging(self) -> bool:
        return self._down is not None and self._travel > self.slop_px

    def _distance(self, pos: QPointF) -> float:
        return float(np.hypot(pos.x() - self._down.x(), pos.y() - self._down.y()))

    def eventFilter(self, watched, event) -> bool:  # noqa: N802 - Qt override
        kind = event.type()
        try:
            if kind == QEvent.Type.MouseButtonPress:
                if event.button() == Qt.MouseButton.LeftButton:
                    self._down = event.position()
                    self._travel = 0.0
                    self._other_buttons = bool(event.buttons() & ~Qt.MouseButton.LeftButton)
                else:
                    self._other_buttons = True
            elif kind == QEvent.Type.MouseMove:
                if self._down is not None:
                    self._travel = max(self._travel, self._distance(event.position()))
                elif event.buttons() == Qt.MouseButton.NoButton and self.enabled and self.on_hover is not None:
                    self.on_hover(*qt_to_display(self.widget, event.position().x(), event.position().y()))
            elif kind == QEvent.Type.MouseButtonRelease:
                if event.button() == Qt.MouseButton.LeftButton and self._down is not None:
                    travel = max(self._travel, self._distance(event.position()))
                    self._down = None
                    if travel <= self.slop_px and self.enabled and not self._other_buttons:
                        mods = event.modifiers()
                        x, y = qt_to_display(self.widget, event.position().x(), event.position().y())
                        self.on_click(x, y, bool(mods & Qt.KeyboardModifier.ShiftModifier),
                                      bool(mods & Qt.KeyboardModifier.ControlModifier))
                if not (event.buttons() & ~Qt.MouseButton.LeftButton):
                    self._other_buttons = False
            elif kind == QEvent.Type.Leave and self.on_leave is not None:
                self.on_leave()
        except Exception:  # noqa: BLE001 - a filter must not break the viewport's event handling
            traceback.print_exc()
        return False

    def remove(self) -> None:
        self.widget.removeEventFilter(self)


# ------------------------------------------------------------------ markers
def _rgb(status: str, bright: float = 0.0) -> np.ndarray:
    c = np.array(STATUS_COLORS[status], dtype=np.float64)
    return c + (255.0 - c) * bright


class LandmarkMarkers:
    """Status-coloured landmark markers with names, a selected and a hovered landmark.

    All actors are created once per set of names (:meth:`set_names`); :meth:`update` only writes
    positions and colours into their arrays. Call ``plotter.render()`` afterwards.
    """

    def __init__(self, plotter, *, name: str = "landmark-editor"):
        self.plotter = plotter
        self.name = name
        self.names: list[str] = []
        self.mesh: pv.PolyData | None = None
        self.label_mesh: pv.PolyData | None = None
        self._markers = None
        self._labels = None
        self._visible = True
        self._labels_visible = True
        self._label_lift = 0.0
        # The selected and hovered markers: one point each, moved in place.
        self.selected_mesh = pv.PolyData(np.zeros((1, 3)))
        self.hover_mesh = pv.PolyData(np.zeros((1, 3)))
        self._selected_actor = plotter.add_mesh(
            self.selected_mesh, color="white", point_size=SELECTED_SIZE_PX, render_points_as_spheres=True,
            name=f"{name}-selected", reset_camera=False, render=False, pickable=False)
        self._hover_actor = plotter.add_mesh(
            self.hover_mesh, color="white", point_size=HOVER_SIZE_PX, render_points_as_spheres=True,
            name=f"{name}-hover", reset_camera=False, render=False, pickable=False)
        for actor in (self._selected_actor, self._hover_actor):
            actor.prop.ambient = 0.45
            actor.prop.diffuse = 0.8
            actor.SetVisibility(False)
        self._anchors: dict[int, object] = {}
        scale = self.plotter.devicePixelRatioF() if hasattr(self.plotter, "devicePixelRatioF") else 1.0
        self._box_dx = 16.0 * scale   # display pixels from a landmark to its own label box
        self._layout: LabelLayout | None = None   # which name labels fit (and which have a box of their own)
        self.selected_label = self._text_actor(bold=True, size=SELECTED_LABEL_PT)
        self.hover_label = self._text_actor(bold=False, size=HOVER_LABEL_PT)
        self.selected_index: int | None = None
        self.hovered_index: int | None = None

    def _text_actor(self, *, bold: bool, size: int):
        """A 2-D label box that follows a world point, drawn beside it (offset in pixels)."""
        actor = vtkTextActor()
        prop = actor.GetTextProperty()
        prop.SetFontSize(size)
        prop.SetBold(bold)
        prop.SetColor(1.0, 1.0, 1.0)
        prop.SetBackgroundColor(0.07, 0.07, 0.09)
        prop.SetBackgroundOpacity(0.8)
        prop.SetFrame(True)
        prop.SetFrameWidth(2)
        prop.SetJustificationToLeft()
        prop.SetVerticalJustificationToCentered()
        anchor = vtkCoordinate()
        anchor.SetCoordinateSystemToWorld()
        position = actor.GetPositionCoordinate()
        position.SetCoordinateSystemToDisplay()
        position.SetReferenceCoordinate(anchor)
        position.SetValue(self._box_dx, 0.0)
        actor.SetPickable(False)
        actor.SetVisibility(False)
        self.plotter.renderer.AddViewProp(actor)
        self._anchors[id(actor)] = anchor
        return actor

    # ------------------------------------------------------------ build
    def set_names(self, names: Sequence[str], *, face_height_mm: float = 200.0) -> None:
        """(Re)create the marker and name actors for ``names`` (only when the names change)."""
        names = list(names)
        if names == self.names and self.mesh is not None:
            return
        self._remove_set()
        self.names = names
        self.selected_index = self.hovered_index = None
        self._label_lift = 0.028 * face_height_mm
        if not names:
            return
        k = len(names)
        self.mesh = pv.PolyData(np.zeros((k, 3)))
        self.mesh.point_data["rgb"] = np.zeros((k, 3), dtype=np.uint8)
        self._markers = self.plotter.add_mesh(
            self.mesh, scalars="rgb", rgb=True, point_size=MARKER_SIZE_PX, render_points_as_spheres=True,
            name=f"{self.name}-markers", reset_camera=False, render=False, pickable=False,
            show_scalar_bar=False)
        self._markers.prop.ambient = 0.35
        self.label_mesh = pv.PolyData(np.zeros((k, 3)))
        self.label_mesh.point_data["landmark"] = np.array(names, dtype=str)
        # always_visible: VTK's z-buffer visibility test drops labels in off-screen renders;
        # the placement mapper still hides overlapping ones.
        self._labels = self.plotter.add_point_labels(
            self.label_mesh, "landmark", font_size=11, text_color="white", shape_color=(0.07, 0.07, 0.09),
            shape_opacity=0.55, margin=2, show_points=False, name=f"{self.name}-labels",
            reset_camera=False, render=False, always_visible=True, bold=False, pickable=False)
        self._layout = LabelLayout(self.plotter.renderer, self.label_mesh, "landmark", names, font_size=11)
        self._apply_visibility()

    def _remove_set(self) -> None:
        for actor in (self._markers, self._labels):
            if actor is not None:
                self.plotter.remove_actor(actor, reset_camera=False, render=False)
        self._markers = self._labels = None
        if self._layout is not None:
            self._layout.detach()
            self._layout = None
        self.mesh = self.label_mesh = None
        self.names = []

    # ------------------------------------------------------------ update
    def update(self, positions: np.ndarray, normals: np.ndarray, statuses: Sequence[str],
               selected: int | None = None, hovered: int | None = None,
               selected_text: str = "", hovered_text: str = "") -> None:
        """Write marker positions (k, 3) mm (on the displayed surface), unit normals (k, 3) and
        status colours; show ``selected``/``hovered`` (indices into the names) bigger, with labels."""
        if self.mesh is None:
            self._set_single(self._selected_actor, self.selected_label, None, None, "", 0.0)
            self._set_single(self._hover_actor, self.hover_label, None, None, "", 0.0)
            return
        positions = np.asarray(positions, dtype=np.float64)
        normals = np.asarray(normals, dtype=np.float64)
        markers = positions + MARKER_OFFSET_MM * normals
        self.mesh.points[:] = markers
        colors = np.array([STATUS_COLORS[s] for s in statuses], dtype=np.uint8)
        self.mesh.point_data["rgb"][:] = colors
        self.mesh.Modified()
        lift = np.array([0.0, self._label_lift, 0.0])
        self.label_mesh.points[:] = markers + LABEL_OFFSET_MM * normals + lift
        self._layout.set_points(normals)
        self.selected_index, self.hovered_index = selected, hovered
        own_boxes = [(i, t, size, offset) for i, t, size, offset in (
            (selected, selected_text, SELECTED_LABEL_PT, SELECTED_OFFSET_MM), (hovered, hovered_text, HOVER_LABEL_PT, MARKER_OFFSET_MM))
            if i is not None and t]
        self._blank_labels({i for i, *_ in own_boxes},
                           [(positions[i] + offset * normals[i], f" {t} ", size, (self._box_dx, 0.0))
                            for i, t, size, offset in own_boxes])
        if hovered == selected:
            hovered = None
        for index, actor, label, text, bright, offset in (
                (selected, self._selected_actor, self.selected_label, selected_text, 0.12, SELECTED_OFFSET_MM),
                (hovered, self._hover_actor, self.hover_label, hovered_text, 0.6, MARKER_OFFSET_MM)):
            if index is None:
                self._set_single(actor, label, None, None, "", 0.0)
            else:
                where = positions[index] + offset * normals[index]
                self._set_single(actor, label, where, statuses[index], text, bright)

    def _set_single(self, actor, label, where, status, text: str, bright: float) -> None:
        show = where is not None and self._visible
        actor.SetVisibility(show)
        label.SetVisibility(show and bool(text))
        if where is None:
            return
        mesh = actor.mapper.dataset
        mesh.points[:] = np.asarray(where)[None]
        mesh.Modified()
        actor.prop.color = tuple(_rgb(status, bright) / 255.0)
        if text:
            label.SetInput(f" {text} ")
            self._anchors[id(label)].SetValue(*np.asarray(where, dtype=float))
            label.GetTextProperty().SetFrameColor(*(_rgb(status, 0.1) / 255.0))

    def _blank_labels(self, indices: set[int], boxes: Sequence[tuple] = ()) -> None:
        """Hide the small name labels of ``indices`` (the selected and hovered landmarks have their
        own ``boxes``, see :meth:`app.label_layout.LabelLayout.set_reserved`, which the other labels keep clear of)."""
        if self._layout is not None:
            self._layout.set_reserved(indices, boxes)

    # ------------------------------------------------------------ visibility
    def set_visible(self, visible: bool) -> None:
        self._visible = bool(visible)
        self._apply_visibility()

    def set_labels_visible(self, visible: bool) -> None:
        self._labels_visible = bool(visible)
        self._apply_visibility()

    @property
    def visible(self) -> bool:
        return self._visible

    @property
    def labels_visible(self) -> bool:
        return self._labels_visible

    def _apply_visibility(self) -> None:
        if self._markers is not None:
            self._markers.SetVisibility(self._visible)
        if self._labels is not None:
            self._labels.SetVisibility(self._visible and self._labels_visible)
        if self._layout is not None:
            self._layout.active = self._visible and self._labels_visible   # hidden labels: no layout per render
        if not self._visible:
            for actor in (self._selected_actor, self._hover_actor, self.selected_label, self.hover_label):
                actor.SetVisibility(False)
        else:
            if self.selected_index is not None:
                self._selected_actor.SetVisibility(True)
                self.selected_label.SetVisibility(bool(self.selected_label.GetInput()))
            if self.hovered_index is not None and self.hovered_index != self.selected_index:
                self._hover_actor.SetVisibility(True)
                self.hover_label.SetVisibility(bool(self.hover_label.GetInput()))

    def remove(self) -> None:
        """Take every actor off the plotter."""
        self._remove_set()
        for actor in (self._selected_actor, self._hover_actor):
            self.plotter.remove_actor(actor, reset_camera=False, render=False)
        for label in (self.selected_label, self.hover_label):
            self.plotter.renderer.RemoveViewProp(label)
