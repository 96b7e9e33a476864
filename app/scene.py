"""scene.py
----
The one place where a :class:`core.face.Face` becomes VTK/PyVista objects.

Used both by the interactive window (pyvistaqt ``QtInteractor``) and by the
off-screen renderer (:mod:`app.render`), so screenshots and the GUI look the
same.

A face is drawn by a single actor whose ``pv.PolyData`` is kept for the life
of the face: :meth:`FaceActor.update_vertices` writes new positions into the
existing point array (and fresh normals from :mod:`core.face`) so animation
sliders can run at interactive rates without re-adding meshes. Display modes
only toggle actor/mapper properties for the same reason, and so do scalar
overlays (:meth:`FaceActor.show_scalars`: a heat map or an influence map
coloured through a lookup table, with a scalar bar), whose values are written
into one point array in place.

Coordinate convention (see ``core.face``): +x is the face's own left, +y up,
+z out of the face; the face looks along +z.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pyvista as pv

from app.label_layout import LabelLayout
from core.face import Face, VertexNormals, coincident_skin_vertices

if TYPE_CHECKING:  # pragma: no cover
    from pyvista.plotting.plotter import BasePlotter

MODES = ("textured", "shaded", "wireframe", "points")
VIEWS = ("front", "side", "three-quarter", "back")

#: Neutral dark-grey gradient (bottom, top).
BACKGROUND_BOTTOM = "#1b1c1e"
BACKGROUND_TOP = "#4a4d52"
#: Skin tone for the untextured shaded surface.
SKIN_COLOR = (0.86, 0.69, 0.60)
WIREFRAME_COLOR = (0.80, 0.84, 0.90)
LANDMARK_COLOR = (1.0, 0.78, 0.18)

_RGB_ARRAY = "rgb"
_NORMALS_ARRAY = "Normals"
_UV_ARRAY = "uv"
_LABEL_ARRAY = "landmark"
_OVERLAY_ARRAY = "overlay"
# Markers float just above the surface so the surface does not swallow half
# of each sphere; labels a little further out.
_MARKER_OFFSET_MM = 0.8
_LABEL_OFFSET_MM = 2.0


# --------------------------------------------------------------------- data
def face_to_polydata(face: Face, normals: np.ndarray | None = None) -> pv.PolyData:
    """A ``pv.PolyData`` with points, triangles, normals (``normals`` (n, 3), default the face's own),
    uv and vertex colours.

    ``uv`` becomes the active texture coordinates; vertex colours (if any) are
    stored as uint8 RGB point data named ``"rgb"``.
    """
    tris = np.asarray(face.triangles, dtype=np.int64)
    cells = np.hstack([np.full((len(tris), 1), 3, dtype=np.int64), tris]).ravel()
    mesh = pv.PolyData(np.array(face.vertices, dtype=np.float64), faces=cells)
    normals = np.array(face.vertex_normals if normals is None else normals, dtype=np.float32)
    mesh.point_data[_NORMALS_ARRAY] = normals
    mesh.point_data.active_normals_name = _NORMALS_ARRAY
    if face.uv is not None:
        mesh.point_data[_UV_ARRAY] = np.array(face.uv, dtype=np.float32)
        mesh.point_data.active_texture_coordinates_name = _UV_ARRAY
    if face.vertex_colors is not None:
        mesh.point_data[_RGB_ARRAY] = np.array(face.vertex_colors, dtype=np.uint8)
    return mesh


def face_texture(face: Face, *, mipmap: bool = True) -> pv.Texture | None:
    """The face's texture image as a ``pv.Texture`` (``None`` without one or without uv).

    ``pv.Texture`` treats row 0 of a numpy image as the top row, which is
    exactly ``Face.texture``'s convention (and uv v=0 maps to the bottom), so
    no flip is needed here; ``tests/app/test_scene.py`` pins this down.
    ``mipmap=False``: bilinear sampling of the image alone (the draft's: on software GL
    trilinear mipmap sampling costs a quarter of a frame).
    """
    if face.texture is None or face.uv is None:
        return None
    tex = pv.Texture(np.ascontiguousarray(face.texture))
    tex.interpolate = True
    tex.mipmap = mipmap
    return tex


# ------------------------------------------------------------------- stage
SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swrast", "software rasterizer", "swr", "basic render")


def renderer_name(plotter) -> str:
    """The OpenGL renderer string of ``plotter``'s render window ("" when it cannot be read)."""
    try:
        report = plotter.render_window.ReportCapabilities()
    except Exception:  # noqa: BLE001 - informative only
        return ""
    for line in str(report).splitlines():
        if "renderer string" in line.lower():
            return line.split(":", 1)[1].strip()
    return ""


def anti_aliasing_for(renderer: str) -> str | None:
    """MSAA where the GPU is real; none on software OpenGL, where every sample costs CPU time."""
    name = renderer.lower()
    return None if any(s in name for s in SOFTWARE_RENDERERS) else "msaa"


def setup_stage(plotter: "BasePlotter", *, anti_aliasing: str | None = "msaa") -> None:
    """Background gradient, a camera-attached three-point light rig and anti-aliasing.

    ``anti_aliasing`` is passed to ``enable_anti_aliasing``; None disables it (see
    :func:`anti_aliasing_for`: on software OpenGL MSAA triples the cost of a frame).
    MSAA is the default because SSAA (what VTK's EGL build substitutes for
    FXAA) renders at twice the size and so halves landmark marker sizes.
    """
    plotter.set_background(BACKGROUND_BOTTOM, top=BACKGROUND_TOP)
    plotter.remove_all_lights()
    # Camera lights move with the camera, so the face stays well lit however
    # the user orbits. Positions are in camera space (+z toward the viewer).
    rig = [
        ((-0.9, 0.9, 1.0), 0.80, (1.00, 0.97, 0.92)),  # key: upper left, warm
        ((1.0, 0.1, 0.8), 0.35, (0.90, 0.94, 1.00)),  # fill: right, cool
        ((0.2, 1.0, -1.0), 0.35, (1.00, 1.00, 1.00)),  # rim: behind, above
        ((0.0, -0.6, 1.0), 0.15, (1.00, 0.98, 0.95)),  # soft bounce from below
    ]
    for position, intensity, color in rig:
        light = pv.Light(position=position, focal_point=(0, 0, 0), color=color,
                         intensity=intensity, light_type="camera light")
        plotter.add_light(light)
    try:
        if anti_aliasing == "msaa":
            plotter.enable_anti_aliasing("msaa", multi_samples=8)
        elif anti_aliasing:
            plotter.enable_anti_aliasing(anti_aliasing)
        else:  # pyvista's theme turns MSAA on by default: off means off
            plotter.disable_anti_aliasing()
    except Exception:  # noqa: BLE001 - anti-aliasing is cosmetic, never fatal
        pass


# ------------------------------------------------------------------- actor
class FaceActor:
    """A face on a plotter: mesh, actor, landmarks; updated in place.

    Create with :func:`add_face_actor`.
    """

    def __init__(self, plotter: "BasePlotter", face: Face, mode: str = "textured",
                 *, show_landmarks: bool = False, name: str = "face", mipmap: bool = True):
        self.plotter = plotter
        self.face = face
        self.name = name
        # Skin split on seams (texture seams, the default face's front/head-shell join) shades as one
        # surface: no crease along the seam.
        self._normals = VertexNormals(face.triangles, face.n_vertices, welds=coincident_skin_vertices(face))
        self.mesh = face_to_polydata(face, self._normals(face.vertices))
        self.texture = face_texture(face, mipmap=mipmap)
        self._draft_texture: pv.Texture | None = None    # the draft's copy (no mipmaps), made when needed
        mapper = pv.DataSetMapper(self.mesh)
        mapper.color_mode = "direct"
        if _RGB_ARRAY in self.mesh.point_data:
            mapper.SetScalarModeToUsePointFieldData()
            mapper.SelectColorArray(_RGB_ARRAY)
        mapper.scalar_visibility = False
        self.actor = pv.Actor(mapper=mapper)
        prop = self.actor.prop
        prop.interpolation = "phong"
        plotter.add_actor(self.actor, reset_camera=False, name=name, render=False)

        self._landmark_names = list(face.landmark_names)
        self.landmark_mesh: pv.PolyData | None = None
        self.label_mesh: pv.PolyData | None = None
        self._label_lift = 0.0
        self._landmark_actors: list = []
        self._label_layout: LabelLayout | None = None   # shows only the labels that fit
        self._landmarks_visible = False
        self._overlay: dict | None = None  # cmap, title, fmt, clim of the scalars shown
        self._scalar_bar_title: str | None = None
        self.preview = None                # app.preview.PreviewMesh: the draft level of detail
        self.preview_mesh: pv.PolyData | None = None
        self.preview_actor: pv.Actor | None = None
        self._showing_preview = False
        self.mode = ""
        self.set_mode(mode)
        self.set_landmarks_visible(show_landmarks)

    # ----------------------------------------------------------- queries
    @property
    def has_texture(self) -> bool:
        return self.texture is not None

    @property
    def has_vertex_colors(self) -> bool:
        return _RGB_ARRAY in self.mesh.point_data

    @property
    def label_layout(self) -> LabelLayout | None:
        """Which feature-point labels the last render showed (None until landmarks are shown)."""
        return self._label_layout

    @property
    def landmarks_visible(self) -> bool:
        return self._landmarks_visible

    @property
    def scalars_visible(self) -> bool:
        """True while the surface is coloured by :meth:`show_scalars` values."""
        return self._overlay is not None

    @property
    def scalars(self) -> np.ndarray | None:
        """(n,) the overlay values shown (a view of the mesh array), or None."""
        if self._overlay is None:
            return None
        return self.mesh.point_data[_OVERLAY_ARRAY]

    @property
    def scalar_bar_title(self) -> str | None:
        return self._scalar_bar_title

    @property
    def scalar_range(self) -> tuple[float, float] | None:
        return None if self._overlay is None else tuple(self._overlay["clim"])

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) current min/max corner of the displayed mesh, mm."""
        pts = self.mesh.points
        return np.stack([pts.min(axis=0), pts.max(axis=0)])

    # ----------------------------------------------------------- modes
    def set_mode(self, mode: str) -> None:
        """Switch display mode: textured, shaded, wireframe or points.

        "textured" falls back to vertex colours, then to the shaded skin look.
        """
        mode = mode.lower()
        if mode not in MODES:
            raise ValueError(f"unknown display mode {mode!r}; choose one of {', '.join(MODES)}")
        for actor in self._surface_actors():
            self._style(actor, mode)
        self.mode = mode
        self.use_preview(self._showing_preview)  # wireframe and points are always drawn in full
        if self._overlay is not None:
            self._apply_overlay_look()

    def _surface_actors(self) -> list:
        return [self.actor] + ([self.preview_actor] if self.preview_actor is not None else [])

    def _style(self, actor, mode: str) -> None:
        """The look of display ``mode`` on one surface actor (the face or its draft copy)."""
        prop = actor.prop
        mapper = actor.mapper
        use_texture = mode == "textured" and self.has_texture
        use_colors = mode == "textured" and not use_texture and self.has_vertex_colors
        texture = self.texture
        if actor is self.preview_actor and texture is not None:
            # The draft is drawn while something moves: bilinear sampling, no mipmaps (measured off
            # screen at 1280x720 on llvmpipe: ~225 instead of ~305 ms a frame; the full frame keeps them).
            if self._draft_texture is None:
                self._draft_texture = face_texture(self.face, mipmap=False)
            texture = self._draft_texture
        actor.texture = texture if use_texture else None
        mapper.scalar_visibility = use_colors
        prop.style = {"wireframe": "wireframe", "points": "points"}.get(mode, "surface")
        if mode in ("textured", "shaded"):
            # Textures/vertex colours carry their own shading in the albedo,
            # so keep specular low; the bare skin gets a bit more sheen.
            prop.color = (1.0, 1.0, 1.0) if (use_texture or use_colors) else SKIN_COLOR
            prop.ambient = 0.18
            prop.diffuse = 0.85
            prop.specular = 0.06 if (use_texture or use_colors) else 0.18
            prop.specular_power = 18.0
        elif mode == "wireframe":
            prop.color = WIREFRAME_COLOR
            prop.line_width = 1.0
            prop.ambient = 0.35
            prop.diffuse = 0.7
            prop.specular = 0.0
        else:  # points
            prop.color = SKIN_COLOR
            prop.point_size = 2.5
            prop.ambient = 0.3
            prop.diffuse = 0.75
            prop.specular = 0.0
        # Light wireframes/points from both sides: back faces show through.
        prop.backface_culling = False

    # ----------------------------------------------------------- scalar overlays
    def show_scalars(self, values, *, cmap: str = "inferno", clim=None, title: str = "",
                     fmt: str = "%.1f") -> None:
        """Colour the surface by per-vertex ``values`` (n,) through ``cmap`` with a scalar bar.

        ``clim`` = (low, high) fixes the colour range (default: the values' min/max).
        Call again to update the values: they are written into the existing point array
        (no new actor, no new array); the lookup table and scalar bar are only rebuilt
        when ``cmap``/``title``/``fmt`` change. The display mode's style (surface,
        wireframe, points) is kept; :meth:`clear_scalars` returns to the normal look.
        """
        values = np.asarray(values, dtype=np.float32).reshape(-1)
        self.use_preview(False)  # overlays are drawn on the full face only
        if values.shape != (self.mesh.n_points,):
            raise ValueError(f"expected {self.mesh.n_points} scalar values, got {values.shape[0]}")
        if clim is None:
            lo, hi = (float(values.min()), float(values.max())) if len(values) else (0.0, 1.0)
            clim = (lo, hi if hi > lo else lo + 1.0)
        clim = (float(clim[0]), float(clim[1]))
        data = self.mesh.point_data
        if _OVERLAY_ARRAY in data:
            data[_OVERLAY_ARRAY][:] = values
        else:
            data.set_array(values.copy(), _OVERLAY_ARRAY)
        look = {"cmap": cmap, "title": title, "fmt": fmt}
        first = self._overlay is None
        rebuild = first or any(self._overlay[k] != v for k, v in look.items())
        self._overlay = {**look, "clim": clim}
        mapper = self.actor.mapper
        if rebuild:
            mapper.lookup_table = pv.LookupTable(cmap=cmap)
        mapper.scalar_range = clim
        mapper.lookup_table.scalar_range = clim
        if first:
            self._apply_overlay_look()
        if rebuild:
            self._set_scalar_bar(title, fmt)

    def clear_scalars(self) -> None:
        """Back to the display mode's normal look (texture, vertex colours or skin)."""
        if self._overlay is None:
            return
        self._overlay = None
        self._set_scalar_bar(None, "")
        mapper = self.actor.mapper
        mapper.color_mode = "direct"
        if _RGB_ARRAY in self.mesh.point_data:
            mapper.SetScalarModeToUsePointFieldData()
            mapper.SelectColorArray(_RGB_ARRAY)
        else:
            mapper.SetScalarModeToDefault()
        self.set_mode(self.mode)

    def _apply_overlay_look(self) -> None:
        mapper = self.actor.mapper
        mapper.SetScalarModeToUsePointFieldData()
        mapper.SelectColorArray(_OVERLAY_ARRAY)
        mapper.color_mode = "map"
        mapper.SetUseLookupTableScalarRange(False)
        mapper.scalar_range = self._overlay["clim"]
        mapper.scalar_visibility = True
        self.actor.texture = None
        prop = self.actor.prop
        prop.color = (1.0, 1.0, 1.0)
        prop.specular = 0.06

    def _set_scalar_bar(self, title: str | None, fmt: str) -> None:
        if self._scalar_bar_title is not None:
            try:
                self.plotter.remove_scalar_bar(self._scalar_bar_title, render=False)
            except (KeyError, ValueError, AttributeError):  # already gone with the plotter
                pass
            self._scalar_bar_title = None
        if title is None:
            return
        # pyvista keys scalar bars by title; a blank one would collide with others.
        key = title or f"{self.name} values"
        self.plotter.add_scalar_bar(
            key, mapper=self.actor.mapper, n_labels=5, fmt=fmt, vertical=True,
            position_x=0.88, position_y=0.25, width=0.07, height=0.5,
            title_font_size=14, label_font_size=12, color="white", shadow=True, render=False)
        self._scalar_bar_title = key

    # ----------------------------------------------------------- draft level of detail
    @property
    def showing_preview(self) -> bool:
        """True while the draft copy (:mod:`app.preview`) is drawn instead of the full face."""
        return self._showing_preview

    def set_preview(self, preview) -> None:
        """Give the face a draft level of detail (an :class:`app.preview.PreviewMesh`; None drops it)."""
        self.use_preview(False)
        if self.preview_actor is not None:
            self.plotter.remove_actor(self.preview_actor, reset_camera=False, render=False)
        self.preview, self.preview_mesh, self.preview_actor = None, None, None
        if preview is None:
            return
        index = preview.index
        tris = np.asarray(preview.triangles, dtype=np.int64)
        cells = np.hstack([np.full((len(tris), 1), 3, dtype=np.int64), tris]).ravel()
        mesh = pv.PolyData(np.array(self.mesh.points[index], dtype=np.float64), faces=cells)
        for name in (_NORMALS_ARRAY, _UV_ARRAY, _RGB_ARRAY):
            if name in self.mesh.point_data:
                mesh.point_data[name] = np.array(self.mesh.point_data[name][index])
        mesh.point_data.active_normals_name = _NORMALS_ARRAY
        if _UV_ARRAY in mesh.point_data:
            mesh.point_data.active_texture_coordinates_name = _UV_ARRAY
        mapper = pv.DataSetMapper(mesh)
        mapper.color_mode = "direct"
        if _RGB_ARRAY in mesh.point_data:
            mapper.SetScalarModeToUsePointFieldData()
            mapper.SelectColorArray(_RGB_ARRAY)
        mapper.scalar_visibility = False
        actor = pv.Actor(mapper=mapper)
        actor.prop.interpolation = "phong"
        actor.SetVisibility(False)
        actor.SetPickable(False)
        self.plotter.add_actor(actor, reset_camera=False, name=f"{self.name}-preview", render=False)
        self.preview, self.preview_mesh, self.preview_actor = preview, mesh, actor
        self._style(actor, self.mode)

    def use_preview(self, on: bool) -> bool:
        """Draw the draft copy (True) or the full face (False). The draft is used only where it looks
        the same: textured or shaded, no overlay. Returns True if what is drawn changed."""
        on = bool(on) and self.preview_actor is not None and self._overlay is None \
            and self.mode in ("textured", "shaded")
        if on == self._showing_preview:
            return False
        self._showing_preview = on
        self.actor.SetVisibility(not on)
        if self.preview_actor is not None:
            self.preview_actor.SetVisibility(on)
        return True

    # ----------------------------------------------------------- landmarks
    def _landmark_points(self, vertices: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(marker positions, label anchor positions, unit surface normals at the points), each (k, 3)."""
        face = self.face
        pos = face.landmark_positions(self._landmark_names, vertices)
        tri = np.array([face.landmarks[n].triangle for n in self._landmark_names], dtype=np.int64)
        bary = np.array([face.landmarks[n].barycentric for n in self._landmark_names])
        nrm = np.einsum("kj,kjd->kd", bary, normals[face.triangles[tri]])
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.divide(nrm, length, out=np.zeros_like(nrm), where=length > 0)
        markers = pos + _MARKER_OFFSET_MM * nrm
        # Labels are centred on their anchor, so lift the anchor a little
        # (toward +y, the face's up) to keep the marker itself visible.
        lift = self._label_lift * np.array([0.0, 1.0, 0.0])
        return markers, markers + _LABEL_OFFSET_MM * nrm + lift, nrm

    def _build_landmarks(self) -> None:
        verts = np.asarray(self.mesh.points, dtype=np.float64)
        normals = np.asarray(self.mesh.point_data[_NORMALS_ARRAY], dtype=np.float64)
        height = float(np.ptp(verts[:, 1])) or 1.0
        self._label_lift = 0.028 * height
        markers, anchors, point_normals = self._landmark_points(verts, normals)
        self.landmark_mesh = pv.PolyData(markers)
        self.label_mesh = pv.PolyData(anchors)
        self.label_mesh.point_data[_LABEL_ARRAY] = np.array(self._landmark_names, dtype=str)
        spheres = self.plotter.add_mesh(
            self.landmark_mesh, color=LANDMARK_COLOR, point_size=10,
            render_points_as_spheres=True, name=f"{self.name}-landmarks",
            reset_camera=False, render=False,
        )
        spheres.prop.ambient = 0.35
        # always_visible: VTK's z-buffer visibility filter drops every label
        # in off-screen renders; the placement mapper still hides overlaps.
        labels = self.plotter.add_point_labels(
            self.label_mesh, _LABEL_ARRAY, font_size=12, text_color="white",
            shape_color=(0.07, 0.07, 0.09), shape_opacity=0.6, margin=2, show_points=False,
            name=f"{self.name}-labels", reset_camera=False, render=False,
            always_visible=True, bold=False,
        )
        self._landmark_actors = [spheres, labels]
        self._label_layout = LabelLayout(self.plotter.renderer, self.label_mesh, _LABEL_ARRAY,
                                         self._landmark_names, font_size=12)
        self._label_layout.set_points(point_normals)

    def set_landmarks_visible(self, visible: bool) -> None:
        """Show/hide landmark spheres and their name labels (no-op without landmarks)."""
        visible = bool(visible) and bool(self._landmark_names)
        if visible and self.landmark_mesh is None:
            self._build_landmarks()
        elif visible and not self._landmarks_visible and self.landmark_mesh is not None:
            # Hidden landmarks do not follow the face (update_vertices skips them): catch up.
            self._move_landmarks(np.asarray(self.mesh.points, dtype=np.float64),
                                 np.asarray(self.mesh.point_data[_NORMALS_ARRAY], dtype=np.float64))
        for actor in self._landmark_actors:
            actor.SetVisibility(visible)
        if self._label_layout is not None:
            self._label_layout.active = visible     # no label layout before each render while hidden
        self._landmarks_visible = visible

    def _move_landmarks(self, vertices: np.ndarray, normals: np.ndarray) -> None:
        markers, anchors, point_normals = self._landmark_points(vertices, normals)
        self.landmark_mesh.points[:] = markers
        self.label_mesh.points[:] = anchors
        self._label_layout.set_points(point_normals)

    # ----------------------------------------------------------- updates
    def compute_normals(self, vertices) -> np.ndarray:
        """(n, 3) unit vertex normals of this face's triangles at ``vertices`` (see :class:`VertexNormals`)."""
        return self._normals(vertices)

    def update_vertices(self, vertices, normals=None) -> None:
        """Move the displayed surface to ``vertices`` (n, 3) mm, in place.

        Normals are recomputed (:meth:`compute_normals`, same result as
        :func:`core.face.vertex_normals`) unless given. Does not render; call
        ``plotter.render()`` when convenient.
        """
        vertices = np.asarray(vertices, dtype=np.float64)
        if vertices.shape != (self.mesh.n_points, 3):
            raise ValueError(f"expected vertices of shape {(self.mesh.n_points, 3)}, got {vertices.shape}")
        if normals is None:
            normals = self._normals(vertices)
        self.mesh.points[:] = vertices
        self.mesh.point_data[_NORMALS_ARRAY][:] = normals
        if self.preview_mesh is not None:
            # The full face's normals at the kept vertices: the draft is shaded like the face.
            self.preview_mesh.points[:] = vertices[self.preview.index]
            self.preview_mesh.point_data[_NORMALS_ARRAY][:] = np.asarray(normals)[self.preview.index]
        if self.landmark_mesh is not None and self._landmarks_visible:
            self._move_landmarks(vertices, np.asarray(normals, float))

    def remove(self) -> None:
        """Take the face (and its landmarks and scalar bar) off the plotter."""
        self._set_scalar_bar(None, "")
        self._overlay = None
        self.set_preview(None)
        for actor in [self.actor, *self._landmark_actors]:
            self.plotter.remove_actor(actor, reset_camera=False, render=False)
        self._landmark_actors = []
        if self._label_layout is not None:
            self._label_layout.detach()
            self._label_layout = None
        self.landmark_mesh = None
        self.label_mesh = None


def add_face_actor(plotter: "BasePlotter", face: Face, mode: str = "textured",
                   *, show_landmarks: bool = False, name: str = "face", mipmap: bool = True) -> FaceActor:
    """Add ``face`` to ``plotter`` in display ``mode`` and return its :class:`FaceActor`.

    ``name`` keys the actors on the plotter: adding another face under the
    same name replaces the first one's actor. ``mipmap=False``: bilinear texture
    sampling without mipmaps (see :func:`face_texture`).
    """
    return FaceActor(plotter, face, mode, show_landmarks=show_landmarks, name=name, mipmap=mipmap)


# ------------------------------------------------------------------ camera
def _view_direction(view: str) -> tuple[np.ndarray, np.ndarray]:
    """(direction from focal point to camera, view-up) for a named preset."""
    if view == "front":
        return np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    if view == "side":
        # Camera on the face's left (+x): a clean profile.
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    if view == "back":
        # Behind the head: the full head's back, hair and neck.
        return np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
    if view == "three-quarter":
        yaw, pitch = math.radians(38.0), math.radians(12.0)
        d = np.array([math.sin(yaw) * math.cos(pitch), math.sin(pitch), math.cos(yaw) * math.cos(pitch)])
        return d, np.array([0.0, 1.0, 0.0])
    raise ValueError(f"unknown view {view!r}; choose one of {', '.join(VIEWS)}")


def frame_points(plotter: "BasePlotter", points, direction=None, view_up=None, *, margin: float = 1.1) -> None:
    """Point the camera along ``direction`` so that ``points`` (k, 3) fill the view snugly.

    Unlike ``reset_camera`` (which fits the bounding *sphere* of all actors),
    this centres the projected silhouette and fits it to the viewport's
    aspect ratio. ``direction`` (focal point -> camera) and ``view_up``
    default to the camera's current ones.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(pts) == 0:
        return
    cam = plotter.camera
    if direction is None:
        direction = np.asarray(cam.position) - np.asarray(cam.focal_point)
    if view_up is None:
        view_up = np.asarray(cam.up)
    d = np.asarray(direction, float)
    d = d / (np.linalg.norm(d) or 1.0)
    up = np.asarray(view_up, float)
    up = up - d * np.dot(up, d)
    if np.linalg.norm(up) < 1e-9:  # looking straight along view_up
        up = np.array([0.0, 0.0, -1.0]) if abs(d[1]) > 0.9 else np.array([0.0, 1.0, 0.0])
        up = up - d * np.dot(up, d)
    up = up / np.linalg.norm(up)
    right = np.cross(up, d)  # screen right when looking along -d
    coords = pts @ np.stack([right, up, d], axis=1)  # (k, 3) in camera axes
    lo, hi = coords.min(axis=0), coords.max(axis=0)
    mid = (lo + hi) / 2.0
    half_w, half_h = (hi[:2] - lo[:2]) / 2.0
    center = mid[0] * right + mid[1] * up + mid[2] * d
    w, h = plotter.window_size
    aspect = max(w, 1) / max(h, 1)
    tan_half = math.tan(math.radians(cam.view_angle) / 2.0)
    # Distance from the nearest depth plane of the points, plus half depth.
    distance = max(half_h / tan_half, half_w / (tan_half * aspect), 1e-3) * margin + (hi[2] - lo[2]) / 2.0
    cam.focal_point = tuple(center)
    cam.position = tuple(center + d * distance)
    cam.up = tuple(up)
    plotter.renderer.ResetCameraClippingRange()


def set_camera_view(plotter: "BasePlotter", view: str, points) -> None:
    """Apply a camera preset (front, side, three-quarter, back) framed on ``points`` (k, 3)."""
    direction, up = _view_direction(view)
    frame_points(plotter, points, direction, up)
