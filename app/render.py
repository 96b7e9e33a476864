"""render.py
----
Off-screen rendering of a face to an image file, with the same scene code as
the interactive window (:mod:`app.scene`). Needs no display: VTK renders
through its off-screen (EGL/OSMesa) path.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from core.face import Face

DEFAULT_SIZE = (1200, 900)


def _headless() -> bool:
    return not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _prefer_egl_without_display() -> None:
    """Without a display, ask VTK for its EGL window straight away.

    Otherwise VTK first tries X, logs "bad X server connection" on stderr and
    only then falls back to EGL.
    """
    if _headless():
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def render_face_image(face: Face, *, view: str = "front", size: tuple[int, int] = DEFAULT_SIZE,
                      mode: str = "textured", show_landmarks: bool = False, frame_points=None) -> np.ndarray:
    """Render ``face`` off screen and return the (h, w, 3) uint8 RGB image. ``frame_points`` (k, 3) mm:
    what the camera frames (default: the head down to just below the chin, ``core.framing``)."""
    import pyvista as pv

    from app import scene

    if view not in scene.VIEWS:
        raise ValueError(f"unknown view {view!r}; choose one of {', '.join(scene.VIEWS)}")
    width, height = (int(s) for s in size)
    if width < 16 or height < 16:
        raise ValueError(f"image size {width}x{height} is too small (minimum 16x16)")
    _prefer_egl_without_display()
    plotter = pv.Plotter(off_screen=True, window_size=(width, height))
    try:
        scene.setup_stage(plotter)
        actor = scene.add_face_actor(plotter, face, mode, show_landmarks=show_landmarks)
        if frame_points is None:
            from core.framing import portrait_points

            frame_points = portrait_points(face)
        scene.set_camera_view(plotter, view, np.asarray(frame_points))
        image = plotter.screenshot(None, return_img=True)
    finally:
        plotter.close()
    return np.asarray(image)[..., :3].astype(np.uint8, copy=False)


def save_image(image: np.ndarray, out_path) -> Path:
    """Write an RGB image; the format follows the suffix (png, jpg, ...)."""
    from PIL import Image

    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    pil = Image.fromarray(np.ascontiguousarray(image[..., :3]))
    if out_path.suffix.lower() in (".jpg", ".jpeg"):
        pil.save(out_path, quality=92)
    else:
        pil.save(out_path)
    return out_path


def render_face_png(face: Face, out_path, *, view: str = "front", size: tuple[int, int] = DEFAULT_SIZE,
                    mode: str = "textured", show_landmarks: bool = False) -> Path:
    """Render ``face`` off screen and write it to ``out_path``; returns the path."""
    image = render_face_image(face, view=view, size=size, mode=mode, show_landmarks=show_landmarks)
    return save_image(image, out_path)
