"""face_view.py
----
What the main window's viewport shows of the face: the rig's pose and the overlays (displacement
heat map, a FAP's influence region), pulled in by the viewport scheduler (:mod:`app.viewport`) once
per pass of the event loop; display modes, camera presets and the status-bar labels.

A mixin of :class:`app.main_window.MainWindow` (it uses the window's face actor, rig, FAP dock
and status bar).
"""

from __future__ import annotations

import math
from pathlib import Path

from app.face_files import OPEN_SUFFIXES
from core.formats.project import is_embedded_face


MODE_LABELS = {"textured": "&Textured", "shaded": "&Shaded", "wireframe": "&Wireframe", "points": "&Points"}
VIEW_LABELS = {"front": ("&Front view", "1"), "side": ("&Side view", "2"),
               "three-quarter": ("T&hree-quarter view", "3"), "back": ("&Back view", "4")}


def _nice_ceiling(value: float, floor: float = 1.0) -> float:
    """The next of 1, 1.5, 2, 3, 4, 5, 6, 8 x 10^k at or above ``value`` (at least ``floor``):
    a heat map range that does not jump with every slider step."""
    value = max(float(value), floor)
    exp = math.floor(math.log10(value))
    for m in (1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        if m * 10 ** exp >= value * (1 - 1e-12):
            return m * 10 ** exp
    return 10.0 ** (exp + 1)


class FaceViewMixin:
    """Viewport updates, view modes and camera presets of the main window."""

    def _update_face(self, parts) -> bool:
        """Pull the rig's pose and the overlay into the face actor (the viewport renders after)."""
        actor, rig = self.face_actor, self.rig
        if actor is None:
            return False
        vertices = normals = None
        if "mesh" in parts and rig is not None:
            vertices = rig.vertices()
            normals = actor.compute_normals(vertices)
        kind, number = self.fap_dock.overlay() if rig is not None else (None, None)
        scalars = None
        if kind == "heat" and (vertices is not None or "overlay" in parts or self._shown_overlay != (kind, number)):
            scalars = rig.displacement_magnitude()
        elif kind == "influence" and self._shown_overlay != (kind, number):
            scalars = rig.fap_influence(number)
        if vertices is None and scalars is None and (kind is not None or not actor.scalars_visible):
            return False  # nothing to draw
        if vertices is not None:
            actor.update_vertices(vertices, normals)
        if kind is None:
            actor.clear_scalars()
        elif scalars is not None:
            if kind == "heat":
                actor.show_scalars(scalars, cmap="YlOrRd", clim=(0.0, _nice_ceiling(float(scalars.max()))),
                                   title="Displacement (mm)", fmt="%.1f")
            else:
                from core.layers.fap.tables import fap_spec

                actor.show_scalars(scalars, cmap="PuBu", clim=(0.0, 1.0), title=f"FAP {number} influence",
                                   fmt="%.1f")
                self.statusBar().showMessage(
                    f"Influence of FAP {number} {fap_spec(number).name}: 1 = moves fully, 0 = not at all", 4000)
        self._shown_overlay = (kind, number)
        return True

    def _set_draft(self, on: bool) -> bool:
        """Draw the face's draft copy (while things move) or the full face (app.viewport)."""
        return self.face_actor.use_preview(on) if self.face_actor is not None else False

    def _start_preview(self, face) -> None:
        """Build (or read from the disk cache) the face's draft copy in the background."""
        from app.preview import cached_preview

        def done(preview) -> None:
            if self.face_actor is not None and self.face_actor.face is face:
                self.face_actor.set_preview(preview)

        self.previews.start(lambda job: cached_preview(face), done, lambda _text: None)

    def _show_timing(self, compute_ms: float, draw_ms: float) -> None:
        self.tick_label.setText(f"update: compute {compute_ms:.1f} ms · draw {draw_ms:.1f} ms")

    def _render(self) -> None:
        self.viewport.render()

    def update_vertices(self, vertices) -> None:
        """Move the displayed face to new vertex positions in place (for animation)."""
        if self.face_actor is None:
            return
        self.face_actor.update_vertices(vertices)
        self.viewport.request("render")

    def _update_status_labels(self) -> None:
        face = self.face
        if face is None:
            for label in (self.file_label, self.counts_label, self.units_label, self.texture_label):
                label.setText("")
            self.file_label.setText("no face")
            return
        # A "source" like "built-in" is not a file, and a project's own copy of its face (a recovered
        # autosave's) is named after the project: show the face's name then.
        is_file = (bool(self.face_path) and Path(self.face_path).suffix.lower() in OPEN_SUFFIXES
                   and not is_embedded_face(self.face_path))
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
        from core.framing import portrait_points

        # The head, not the neck under it: the face fills the view.
        self._scene.set_camera_view(self.plotter, view, portrait_points(self.face_actor.face, self.face_actor.mesh.points))
        self._render()

    # ------------------------------------------------------------ view state (saved in projects)
    def view_state(self) -> dict:
        """Camera, display mode, landmarks, overlays and link left/right, as plain JSON types."""
        view: dict = {}
        pos, focal, up = self.plotter.camera_position
        view["camera"] = {"position": [float(v) for v in pos], "focal_point": [float(v) for v in focal],
                          "up": [float(v) for v in up], "view_angle": float(self.plotter.camera.view_angle)}
        view["display_mode"] = self.view_mode
        view["landmarks_visible"] = bool(self.landmarks_action.isChecked())
        dock = self.fap_dock
        view["overlays"] = {"heat_map": bool(dock.heat_check.isChecked()),
                            "influence": bool(dock.influence_check.isChecked())}
        view["link_left_right"] = {"faps": bool(dock.link_check.isChecked())}
        if self.muscle_dock is not None:
            view["link_left_right"]["muscles"] = bool(self.muscle_dock.link_check.isChecked())
        return view

    def apply_view(self, view: dict) -> None:
        """Restore :meth:`view_state` output; missing or odd entries are skipped."""
        mode = view.get("display_mode")
        if isinstance(mode, str) and mode in MODE_LABELS:
            self.set_view_mode(mode)
        if "landmarks_visible" in view:
            self.set_landmarks_visible(bool(view["landmarks_visible"]))
        overlays = view.get("overlays")
        if isinstance(overlays, dict):
            self.fap_dock.heat_check.setChecked(bool(overlays.get("heat_map", False)))
            self.fap_dock.influence_check.setChecked(bool(overlays.get("influence", False)))
        links = view.get("link_left_right")
        if isinstance(links, dict):
            for name, target in (("faps", self.fap_dock), ("muscles", self.muscle_dock)):
                if target is not None and isinstance(links.get(name), bool):
                    target.link_check.setChecked(links[name])
        camera = view.get("camera")
        if isinstance(camera, dict):
            pos, focal, up = camera.get("position"), camera.get("focal_point"), camera.get("up")
            if all(isinstance(v, list) and len(v) == 3 for v in (pos, focal, up)):
                self.plotter.camera_position = [tuple(map(float, pos)), tuple(map(float, focal)),
                                                tuple(map(float, up))]
                if isinstance(camera.get("view_angle"), (int, float)):
                    self.plotter.camera.view_angle = float(camera["view_angle"])
                self.viewport.request("render")

    def reset_camera(self) -> None:
        """Frame the whole face, keeping the viewing direction."""
        if self.face_actor is None:
            return
        self.plotter.camera.view_angle = self._default_view_angle
        self._scene.frame_points(self.plotter, self.face_actor.mesh.points)
        self._render()


__all__ = ["FaceViewMixin", "MODE_LABELS", "VIEW_LABELS"]
