"""export.py
----
Export an animated face as video (MP4 H.264, GIF, AVI Motion-JPEG), as a PNG
image sequence, or as one still (PNG/JPG), rendered off screen with the same
scene code as the window (:mod:`app.scene`). Qt-free: the Qt job and dialog
live in :mod:`app.export_dialog`. Settings and the frame plan are in
:mod:`app.export_plan`, encoders and staging in :mod:`app.export_sinks`; this
module renders, runs the child process and re-exports their public names.

Frame source
    ``frame_vertices(t) -> (n, 3)`` mm for a fixed :class:`core.face.Face`
    (topology, uv and texture fixed, only the vertices move).

Timing (a choice the theses leave open)
    Frames are taken at exact times ``t_k = start_s + k / fps`` for
    ``k = 0 .. N-1`` with ``N = round((end_s - start_s) * fps)``: the end time
    is *exclusive*, so 10 s at 30 fps is 300 frames and the video lasts exactly
    ``end_s - start_s`` seconds. A still is the frame at ``start_s``. Image
    sequences are numbered by ``k`` from 0 (``frame_0000.png`` is ``t_0``).

Formats (from the path's suffix, or :attr:`ExportSettings.format`)
    ``.mp4``  H.264 (libx264, yuv420p, CRF from ``quality``, ``+faststart``;
              preset :func:`app.export_sinks.x264_preset`),
              optional audio as AAC; width and height must be even (4:2:0).
    ``.avi``  Motion JPEG (as thesis B exported), optional audio as 16-bit PCM.
    ``.gif``  two-pass palette (palettegen / paletteuse) from a lossless FFV1
              intermediate, so memory stays flat however long the animation.
    folder, or a name with ``%04d`` (``name_%04d.png``): PNG sequence.
    ``.png`` / ``.jpg``: one still.
    The encoder is the ffmpeg binary bundled with imageio-ffmpeg (this build
    has libx264); raw RGB frames are piped to its stdin, so it encodes in its
    own process while the next frame renders. Audio (any file ffmpeg reads,
    typically WAV) is trimmed to start at ``start_s`` and padded with silence
    or cut so that it lasts exactly as long as the video (``apad`` +
    ``atrim``).

Files
    Everything is written under a temporary name in the target folder
    (``.name.mimica-<pid>-<host>-XXXX.part.mp4``; a hidden folder for sequences) and
    renamed into place only after the encoder succeeded: a cancelled or failed
    export never leaves a broken file under the final name, and the partial
    file is removed. Temporary names carry the owning process's id and machine,
    and every export first removes this machine's whose process no longer runs
    (an export killed with SIGKILL cannot clean up;
    :func:`app.export_sinks.sweep_stale`).

Never blocking the window: rendering runs in a child process
    Measured here (Xvfb, Mesa llvmpipe, 2 cores): a ``pv.Plotter(off_screen=True)``
    *can* render on a worker thread while the pyvistaqt window is alive (VTK
    releases the GIL while drawing; the GUI event loop kept a 10 ms median
    tick, 68 ms worst case), but VTK and pyvista keep unsynchronised global
    state, OpenGL/X11 threading depends on the driver (EGL contexts are
    thread-affine, macOS requires the main thread for Cocoa windows), and a
    crash in the renderer would take the user's unsaved work with it. So
    :func:`export_in_subprocess` runs :func:`export` in a child
    (``python -m app.export --child spec.json``): the parent saves the face
    once (an NPZ in a temporary folder) and streams each frame's vertices as
    raw float32 (n x 3 x 4 bytes, 0.65 MB for the 53k-vertex default face) to
    the child's stdin; the pipe's back-pressure keeps at most about one frame
    in flight, so nothing like the 190 MB of a precomputed 300-frame array is
    ever held. The child prints one ``progress k N`` line per frame and a
    ``result`` or ``error`` line at the end. Cancel = SIGTERM (the child
    removes its partial output and exits), then a hard kill after 5 s; the
    parent deletes the partial file in every case. Child start-up (imports of
    pyvista/VTK, the face, the first render) took 2-6 s here, small next to the frames.
    ``frame_vertices`` runs in the parent, on a thread of
    :func:`export_in_subprocess` (the Qt job can run it on the GUI thread
    instead, see :class:`app.export_dialog.ExportJob`).

Parallel rendering (:attr:`ExportSettings.workers`, default one per core)
    With more than one worker the frames are drawn by that many render
    processes (:mod:`app.export_workers`), each frame by whichever is free,
    each with its own off-screen renderer (this module's
    :class:`_FaceRenderer`, so the pixels are those of the serial path); the
    exporting process (the child above, or the caller of :func:`export`)
    computes or receives the vertices, hands them out and encodes the images
    in order. Short exports use fewer workers
    (:func:`app.export_plan.planned_workers`): each costs a start-up of 1-3 s.

Speed (measured here: Mesa llvmpipe, a 2-core VM shared with other jobs; benchmarks/bench_export.py)
    A renderer draws a whole 1280x720 frame of the default face (53,772 vertices, 105,594 textured
    triangles, FXAA) in 114-134 ms of CPU: FXAA ~30 of them, the gradient ~5, the rest the face,
    whose llvmpipe cost follows its triangles (most are 2-3 pixels). Animations therefore draw only
    the strip around the face (:class:`_FaceRenderer`; 496 px wide for the front view), ~92 ms, and
    read it back with one call. x264 runs "veryfast" two CRF steps lower instead of "fast" (the
    same PSNR/SSIM and size, :func:`app.export_sinks.x264_preset`): ~10 instead of ~19 ms a frame.
    CPU per frame for all the processes, 5 s (150 frames) at load average ~5: one worker 115 ms
    (the renderer 105 with its start-up, ffmpeg 10), two workers 134 (58 + 58 + exporter 7 +
    ffmpeg 10; each render process costs ~2 s of CPU to start). Before these changes the window's
    path took 148-161 ms a frame (bench_export, one worker). On an idle 2-core machine the cores
    bound an export at about 2 / (CPU per frame); one worker does not reach that, as llvmpipe's
    vertex processing and set-up run on one thread, so the default is a worker per core.
    With more cores N processes draw about N x 10 fps (an estimate, not measured on a bigger machine).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable

import numpy as np

from core.face import Face
from core.framing import portrait_points

from app.export_plan import (  # noqa: F401 - re-exported
    FORMATS, AUDIO_FORMATS, STILL_FORMATS, ExportError, ExportCancelled, ExportSettings, ExportResult,
    frame_times, export_frame_times, resolve_format, _Plan, _plan)
from app.export_sinks import (  # noqa: F401 - re-exported
    ffmpeg_exe, sweep_stale, _tail, _make_sink, _make_staging, _discard, _commit, sweep_for, temp_dir)

__all__ = [
    "FORMATS", "AUDIO_FORMATS", "ExportError", "ExportCancelled", "ExportSettings", "ExportResult",
    "frame_times", "export_frame_times", "resolve_format", "export", "export_in_subprocess", "camera_state", "apply_camera",
    "ffmpeg_exe", "sweep_stale",
]

_TERMINATE_GRACE_S = 5.0


# ------------------------------------------------------------------ camera and rendering
def camera_state(plotter) -> dict:
    """The plotter's camera as a plain dict (for :attr:`ExportSettings.camera`)."""
    cam = plotter.camera
    return {
        "position": [float(v) for v in cam.position],
        "focal_point": [float(v) for v in cam.focal_point],
        "view_up": [float(v) for v in cam.up],
        "view_angle": float(cam.view_angle),
        "parallel_projection": bool(cam.parallel_projection),
        "parallel_scale": float(cam.parallel_scale),
    }


def apply_camera(plotter, camera: dict) -> None:
    """Set ``plotter``'s camera from a :func:`camera_state` dict. Raises :class:`ExportError` when malformed."""
    try:
        position = np.asarray(camera["position"], float).reshape(3)
        focal = np.asarray(camera["focal_point"], float).reshape(3)
        up = np.asarray(camera.get("view_up", (0.0, 1.0, 0.0)), float).reshape(3)
    except (KeyError, TypeError, ValueError):
        raise ExportError("The camera must give 'position', 'focal_point' and 'view_up' as three numbers each.") from None
    if not (np.isfinite(position).all() and np.isfinite(focal).all() and np.isfinite(up).all()) \
            or np.allclose(position, focal):
        raise ExportError("The camera position must be finite and away from its focal point.")
    cam = plotter.camera
    cam.position = tuple(position)
    cam.focal_point = tuple(focal)
    cam.up = tuple(up)
    if "view_angle" in camera:
        cam.view_angle = float(camera["view_angle"])
    if camera.get("parallel_projection"):
        cam.parallel_projection = True
        cam.parallel_scale = float(camera.get("parallel_scale", 1.0))
    plotter.renderer.ResetCameraClippingRange()


class _FaceRenderer:
    """One off-screen plotter showing ``face``; :meth:`render` draws given vertices and reads the pixels.

    With ``strip`` (animations; a still does not pay the extra start-up render) only a vertical
    strip of the frame around the face is drawn, the rest copied from the background drawn once:
    on software OpenGL the full-frame passes (FXAA, the gradient, read-back) cost in proportion to
    the pixels, and the face covers about a third of a 16:9 frame (measured here at 1280x720, front
    view, a 496 px strip: 114-125 -> 86-99 ms of CPU a frame). The strip is the same camera with its window centre shifted
    (``vtkCamera.SetWindowCenter``), so the face's pixels are those of a full frame except for
    rounding; the gradient's dither noise inside the strip differs by at most one level. Its place
    is a function of the frame's vertices only, so serial and parallel exports give the same pixels.

    Unless ``settings.full_detail``, a face whose triangles are a few pixels on screen is drawn as its
    export level of detail (:mod:`app.export_lod`; ``lod_triangles`` overrides its triangle budget).
    """

    #: Pixels between the face and the strip's edges (FXAA samples a few pixels around an edge).
    STRIP_MARGIN = 24
    #: The strip's left edge and width are multiples of this many pixels (the width is fixed per
    #: export, from the face at rest; the left edge follows the face).
    STRIP_STEP = 16
    #: Drawing a strip wider than this share of the frame would save too little: the whole frame is drawn.
    STRIP_MAX_SHARE = 0.8

    def __init__(self, face: Face, settings: ExportSettings, size: tuple[int, int], *, strip: bool = True,
                 lod_triangles: int | None = None):
        import pyvista as pv
        from vtkmodules.vtkCommonCore import vtkUnsignedCharArray

        from app import render, scene

        render._prefer_egl_without_display()
        self.size = (int(size[0]), int(size[1]))
        self.plotter = pv.Plotter(off_screen=True, window_size=self.size)
        self._strip_width = self.size[0]      # width of the window: the strip's, or the frame's
        self._background = None               # (h, w, 3) uint8 frame without the face, when drawing strips
        self._pixels = vtkUnsignedCharArray()  # read-back buffer, reused
        try:
            # FXAA, not the window's multisampling: in software rendering (llvmpipe) 4x MSAA doubles the
            # CPU per frame (338 vs 156 ms at 1280x720 for the default face) for no visible gain in a
            # video. VTK's own FXAA is used directly because pyvista swaps it for SSAA (slower still)
            # whenever VTK can do EGL; it renders correctly through both the X and the EGL windows here.
            scene.setup_stage(self.plotter, anti_aliasing=None)
            self.plotter.render_window.SetMultiSamples(0)
            self.plotter.renderer.UseFXAAOn()
            # Bilinear texture sampling without mipmaps: ~30 % less render time on llvmpipe, frames within
            # PSNR 52 dB / SSIM 0.9987 of trilinear ones at 1280x720 (43 dB / 0.994 at 320x180).
            self.actor = scene.add_face_actor(self.plotter, face, settings.mode, mipmap=False)
            if settings.camera is not None:
                apply_camera(self.plotter, settings.camera)
            else:
                scene.set_camera_view(self.plotter, settings.view, portrait_points(face))
            self.plotter.show(auto_close=False)  # realises the window; later frames use render()
            if strip:
                self._plan_strip(np.asarray(face.vertices, dtype=np.float64))
            #: Triangles of the decimated face drawn instead of the full one; 0: the full face.
            self.lod_triangles = 0
            if not settings.full_detail:
                self._use_lod(face, lod_triangles)
        except BaseException:
            self.plotter.close()
            raise

    # ------------------------------------------------------------ level of detail
    def _use_lod(self, face: Face, target: int | None) -> None:
        """Draw the export's decimated face (:mod:`app.export_lod`, about ``target`` triangles) when the
        full face's triangles are at most ``LOD_MAX_PIXELS_PER_TRIANGLE`` pixels in this frame."""
        from app.export_lod import EXPORT_LOD_TRIANGLES, LOD_MAX_PIXELS_PER_TRIANGLE, export_lod

        if self.pixels_per_triangle(face) > LOD_MAX_PIXELS_PER_TRIANGLE:
            return
        lod = export_lod(face, target or EXPORT_LOD_TRIANGLES)
        if lod is None:
            return
        self.actor.set_preview(lod)
        if self.actor.use_preview(True):       # textured and shaded only: wireframes are drawn in full
            self.lod_triangles = lod.n_triangles
        else:
            self.actor.set_preview(None)

    def pixels_per_triangle(self, face: Face) -> float:
        """Median screen area (pixels) of ``face``'s triangles at rest in a full frame of this camera."""
        from app.export_lod import pixels_per_triangle

        width, height = self.size
        m = self.plotter.camera.GetCompositeProjectionTransformMatrix(width / height, -1.0, 1.0)
        projection = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
        return pixels_per_triangle(np.asarray(face.vertices, dtype=np.float64), np.asarray(face.triangles),
                                   projection, self.size)

    # ------------------------------------------------------------ the strip
    def _plan_strip(self, rest: np.ndarray) -> None:
        """Choose the strip's width from the face at rest (with room for the head to move) and draw
        the background, or keep drawing whole frames when a strip would not pay."""
        width, height = self.size
        camera = self.plotter.camera
        # Rows 0 and 3 of the full frame's projection (independent of the clipping range).
        m = camera.GetCompositeProjectionTransformMatrix(width / height, -1.0, 1.0)
        self._project = np.array([[m.GetElement(i, j) for j in range(4)] for i in (0, 3)])
        span = self._x_span(rest)
        if span is None or width < 8 * self.STRIP_STEP:
            return
        # Room for the rounding of the left edge and for a face that widens as it moves (a mouth
        # opening, a turn of the head); a frame that still does not fit is drawn whole.
        slack = max(self.STRIP_STEP, 0.05 * (span[1] - span[0]))
        need = span[1] - span[0] + 2 * (self.STRIP_MARGIN + slack)
        strip = int(np.ceil(need / self.STRIP_STEP)) * self.STRIP_STEP
        if strip > self.STRIP_MAX_SHARE * width:
            return
        self.actor.actor.SetVisibility(False)
        self.plotter.render()
        self._background = self._read(width)
        self.actor.actor.SetVisibility(True)
        self._strip_width = strip
        self._set_window_width(strip)

    def _x_span(self, vertices: np.ndarray) -> tuple[float, float] | None:
        """Pixel columns (left, right) ``vertices`` cover in the full frame; None when some are
        behind the camera."""
        clip = vertices @ self._project[:, :3].T + self._project[:, 3]
        if not (clip[:, 1] > 1e-9).all():
            return None
        x = (clip[:, 0] / clip[:, 1] + 1.0) * (self.size[0] / 2.0)
        return float(x.min()), float(x.max())

    def _strip_left(self, vertices: np.ndarray) -> int | None:
        """The strip's left column for the face at ``vertices`` (a function of the vertices only, so
        every render process places it alike); None when it does not fit: draw the whole frame."""
        span = self._x_span(vertices)
        if span is None:
            return None
        left, right = span[0] - self.STRIP_MARGIN, span[1] + self.STRIP_MARGIN
        width, strip = self.size[0], self._strip_width
        x0 = int(round(((left + right) / 2.0 - strip / 2.0) / self.STRIP_STEP)) * self.STRIP_STEP
        x0 = min(max(x0, 0), width - strip)
        return x0 if x0 <= left and right <= x0 + strip else None

    def _set_window_width(self, width: int) -> None:
        if self.plotter.render_window.GetSize()[0] != width:
            self.plotter.render_window.SetSize(width, self.size[1])

    def _read(self, width: int, out: np.ndarray | None = None) -> np.ndarray:
        """The window's (h, ``width``, 3) RGB pixels, top row first, into ``out`` if given.

        Straight from the front buffer (what pyvista's ``plotter.image`` reads, without its image
        filter and copies) into a reused array, flipped while copied into place."""
        from vtkmodules.util.numpy_support import vtk_to_numpy

        height = self.size[1]
        window = self.plotter.render_window
        if tuple(window.GetSize()) != (width, height):
            raise ExportError(f"The renderer produced a {window.GetSize()[0]}×{window.GetSize()[1]} image "
                              f"instead of {width}×{height}; try a smaller size.")
        window.GetPixelData(0, 0, width - 1, height - 1, 1, self._pixels, 0)
        pixels = vtk_to_numpy(self._pixels)
        if pixels.size != height * width * 3:
            raise ExportError(f"The renderer gave {pixels.size} bytes of pixels instead of {height * width * 3} "
                              f"({width}×{height} RGB); try a smaller size.")
        if out is None:
            out = np.empty((height, width, 3), dtype=np.uint8)
        out[...] = pixels.reshape(height, width, 3)[::-1]
        return out

    # ------------------------------------------------------------ frames
    def render(self, vertices: np.ndarray) -> np.ndarray:
        """(h, w, 3) uint8 RGB of the face at ``vertices`` (n, 3) mm, top row first."""
        self.actor.update_vertices(vertices)
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        # The face is the only prop: its bounds give VTK's own clipping range without VTK's prop walk.
        self.plotter.renderer.ResetCameraClippingRange(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])
        width = self.size[0]
        x0 = None if self._background is None else self._strip_left(vertices)
        if x0 is None:
            self._set_window_width(width)
            self.plotter.camera.SetWindowCenter(0.0, 0.0)
            self.plotter.render()
            return self._read(width)
        strip = self._strip_width
        self._set_window_width(strip)
        # Shifts the frustum so the strip's pixels are the frame's columns x0 .. x0 + strip.
        self.plotter.camera.SetWindowCenter((strip - width + 2.0 * x0) / strip, 0.0)
        self.plotter.render()
        image = self._background.copy()
        self._read(strip, image[:, x0:x0 + strip])
        return image

    def close(self) -> None:
        self.plotter.close()


def _checked_vertices(vertices, n: int, t: float) -> np.ndarray:
    v = np.asarray(vertices, dtype=np.float64)
    if v.shape != (n, 3):
        raise ExportError(f"The animation gave vertices of shape {v.shape} at t = {t:.3f} s; the face has "
                          f"{n} vertices, so (n, 3) = ({n}, 3) was expected.")
    if not np.isfinite(v).all():
        raise ExportError(f"The animation gave non-finite vertex positions (NaN or infinity) at t = {t:.3f} s.")
    return v


def _never() -> bool:
    return False


# ------------------------------------------------------------------ in-process export
def export(face: Face, frame_vertices: Callable[[float], np.ndarray], settings: ExportSettings, *,
           progress: Callable[[int, int], None] | None = None,
           cancelled: Callable[[], bool] | None = None) -> ExportResult:
    """Render and encode in this process (blocks the caller; see :func:`export_in_subprocess` for GUIs).

    ``frame_vertices(t)`` gives (n, 3) mm at time ``t`` s; ``progress(done, total)`` is called after
    each frame; ``cancelled()`` is polled before each frame and while the encoder finishes.

    Raises
    ------
    ExportError
        Bad settings, an unwritable folder, a missing or failing encoder (with its last messages),
        bad vertices from ``frame_vertices``.
    ExportCancelled
        ``cancelled()`` returned True; the partial output was removed.
    """
    plan = _plan(settings)
    sweep_for(plan)
    staging = _make_staging(plan)
    try:
        stats = _render_to_staging(face, lambda k, t: frame_vertices(float(t)), settings, plan, staging,
                                   progress=progress, cancelled=cancelled or _never)
        files = _commit(plan, staging)
    except BaseException:
        _discard(staging)
        raise
    return _result(plan, settings, files, stats)


def _result(plan: _Plan, settings: ExportSettings, files: list[Path], stats: dict) -> ExportResult:
    return ExportResult(
        path=plan.target, format=plan.format, frames=plan.n_frames, seconds=stats["seconds"], size=plan.size,
        fps=float(settings.fps), duration_s=plan.n_frames / float(settings.fps), has_audio=plan.audio is not None,
        render_seconds=stats["render_seconds"], encode_seconds=stats["encode_seconds"], files=files,
        notes=list(plan.notes), workers=int(stats.get("workers", plan.workers)))


def _render_to_staging(face: Face, next_vertices: Callable[[int, float], np.ndarray], settings: ExportSettings,
                       plan: _Plan, staging: Path, *, progress, cancelled, face_file: Path | None = None) -> dict:
    """Render every frame into the staging output; returns timing stats (seconds) and the workers used.

    One worker renders here, frame after frame; more render in parallel processes
    (:mod:`app.export_workers`) while this thread encodes, and ``next_vertices`` is then called on a
    helper thread (in frame order). ``face_file`` is the face as an NPZ if one exists already.
    """
    start = time.perf_counter()
    with temp_dir() as work:
        work = Path(work)
        sink = _make_sink(plan, settings, staging, work)
        try:
            if plan.workers > 1:
                if face_file is None:
                    face_file = work / "face.npz"
                    _save_face_npz(face, face_file)
                render_s, encode_s = _render_parallel(face, next_vertices, settings, plan, sink, face_file, work,
                                                      progress=progress, cancelled=cancelled)
            else:
                render_s, encode_s = _render_serial(face, next_vertices, settings, plan, sink,
                                                    progress=progress, cancelled=cancelled)
            t0 = time.perf_counter()
            sink.finish(cancelled)
            encode_s += time.perf_counter() - t0
        except BaseException:
            sink.abort()
            raise
    return {"seconds": time.perf_counter() - start, "render_seconds": render_s, "encode_seconds": encode_s,
            "workers": plan.workers}


def _render_serial(face: Face, next_vertices, settings: ExportSettings, plan: _Plan, sink, *, progress,
                   cancelled) -> tuple[float, float]:
    """Every frame rendered in this process; (render s, encoder-wait s)."""
    render_s = encode_s = 0.0
    n_vertices = face.n_vertices
    renderer = _FaceRenderer(face, settings, plan.size, strip=plan.n_frames > 1)
    try:
        total = plan.n_frames
        for k, t in enumerate(plan.times):
            if cancelled():
                raise ExportCancelled()
            vertices = _checked_vertices(next_vertices(k, float(t)), n_vertices, float(t))
            t0 = time.perf_counter()
            image = renderer.render(vertices)
            t1 = time.perf_counter()
            sink.write(image)
            t2 = time.perf_counter()
            render_s += t1 - t0
            encode_s += t2 - t1
            if progress is not None:
                progress(k + 1, total)
    finally:
        renderer.close()
    return render_s, encode_s


def _render_parallel(face: Face, next_vertices, settings: ExportSettings, plan: _Plan, sink, face_file: Path,
                     work: Path, *, progress, cancelled) -> tuple[float, float]:
    """Frames rendered by ``plan.workers`` processes (:class:`app.export_workers.RenderPool`), encoded here
    in order; ``next_vertices`` runs on a feeder thread. (s waiting for images, encoder-wait s)."""
    from app.export_workers import RenderPool

    n_vertices = face.n_vertices
    problems: list[BaseException] = []
    pool = RenderPool(face_file, settings, plan.size, n_vertices, plan.workers, work)

    def feed() -> None:
        try:
            for k, t in enumerate(plan.times):
                vertices = _checked_vertices(next_vertices(k, float(t)), n_vertices, float(t))
                if not pool.submit(k, vertices):
                    return  # closing
            pool.end_of_frames()
        except BaseException as exc:  # noqa: BLE001 - raised on the encoding thread
            problems.append(exc)

    def check() -> None:
        if problems:
            raise problems[0]

    feeder = threading.Thread(target=feed, name="mimica-export-feeder", daemon=True)
    render_s = encode_s = 0.0
    finished = False
    try:
        feeder.start()
        total = plan.n_frames
        for k in range(total):
            t0 = time.perf_counter()
            image = pool.take(k, cancelled, check)
            t1 = time.perf_counter()
            sink.write(image)
            t2 = time.perf_counter()
            render_s += t1 - t0
            encode_s += t2 - t1
            if progress is not None:
                progress(k + 1, total)
        finished = True
    finally:
        pool.close(wait=finished)
        feeder.join(timeout=1.0)  # it may be blocked in next_vertices (a pipe); it is a daemon
    return render_s, encode_s


# ------------------------------------------------------------------ export in a child process
def _save_face_npz(face: Face, path: Path) -> None:
    arrays = {"vertices": np.asarray(face.vertices, np.float64), "triangles": np.asarray(face.triangles, np.int64)}
    if face.uv is not None:
        arrays["uv"] = np.asarray(face.uv, np.float64)
    if face.texture is not None:
        arrays["texture"] = np.asarray(face.texture, np.uint8)
    if face.vertex_colors is not None:
        arrays["vertex_colors"] = np.asarray(face.vertex_colors, np.uint8)
    for name, idx in face.parts.items():     # the export's level of detail keeps the parts whole
        arrays[f"part:{name}"] = np.asarray(idx, np.int64)
    np.savez(path, **arrays)


def _load_face_npz(path: Path) -> Face:
    with np.load(path) as data:
        return Face(data["vertices"], data["triangles"],
                    uv=data["uv"] if "uv" in data.files else None,
                    texture=data["texture"] if "texture" in data.files else None,
                    vertex_colors=data["vertex_colors"] if "vertex_colors" in data.files else None,
                    parts={k[len("part:"):]: data[k] for k in data.files if k.startswith("part:")})


def _project_root() -> Path:
    return Path(__file__).resolve().parent.parent


def export_in_subprocess(face: Face, frame_vertices: Callable[[float], np.ndarray], settings: ExportSettings, *,
                         progress: Callable[[int, int], None] | None = None,
                         cancelled: Callable[[], bool] | None = None,
                         python: str | None = None) -> ExportResult:
    """Like :func:`export`, but render and encode in a child process (see the module docstring).

    Blocks the calling thread (run it on a worker thread in a GUI) while the child works;
    ``frame_vertices`` is called on a helper thread of this function, in time order, about one
    frame ahead of the renderer. ``progress`` and ``cancelled`` are called on the calling thread.
    Cancel reacts within about one frame's render time. Raises what :func:`export` raises; a
    renderer that dies is reported as an :class:`ExportError` with the end of its error output.
    """
    cancelled = cancelled or _never
    plan = _plan(settings)
    if plan.format not in STILL_FORMATS:
        ffmpeg_exe()  # fail before starting anything
    sweep_for(plan)
    staging = _make_staging(plan)
    proc = None
    try:
        with temp_dir() as tmp:
            tmp = Path(tmp)
            _save_face_npz(face, tmp / "face.npz")
            spec = {"settings": settings.to_json(), "staging": str(staging), "face": str(tmp / "face.npz"),
                    "n_vertices": int(face.n_vertices)}
            (tmp / "spec.json").write_text(json.dumps(spec), encoding="utf-8")
            env = dict(os.environ)
            root = str(_project_root())
            env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
            env["PYTHONUNBUFFERED"] = "1"
            with open(tmp / "child-stderr.log", "wb") as err:
                try:
                    proc = subprocess.Popen([python or sys.executable, "-m", "app.export", "--child",
                                             str(tmp / "spec.json")],
                                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, env=env,
                                            cwd=root)
                except OSError as exc:
                    raise ExportError(f"Could not start the export renderer: {exc.strerror or exc}.") from None
                message = _drive_child(proc, frame_vertices, plan, face.n_vertices, progress, cancelled)
            if message[0] == "error":
                raise ExportError(message[1])
            if message[0] != "result":
                tail = _tail(tmp / "child-stderr.log", 12)
                raise ExportError(
                    f"The export renderer stopped unexpectedly (exit status {proc.returncode})."
                    + (f"\nIts last messages:\n{tail}" if tail else ""))
            stats = message[1]
        files = _commit(plan, staging)
    except BaseException:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        _discard(staging)
        raise
    return _result(plan, settings, files, stats)


def _drive_child(proc: subprocess.Popen, frame_vertices, plan: _Plan, n_vertices: int, progress, cancelled):
    """Feed vertices, relay progress, handle cancel; returns ("result", stats), ("error", msg) or ("died", None)."""
    import queue

    messages: queue.Queue = queue.Queue()
    stop = threading.Event()
    problem: list[BaseException] = []

    def read_stdout():
        for raw in proc.stdout:
            line = raw.decode("utf-8", "replace").strip()
            kind, _, rest = line.partition(" ")
            if kind in ("progress", "result", "error"):
                messages.put((kind, rest))
        messages.put(("eof", ""))

    def write_frames():
        try:
            for k, t in enumerate(plan.times):
                if stop.is_set():
                    return
                vertices = _checked_vertices(frame_vertices(float(t)), n_vertices, float(t))
                proc.stdin.write(np.ascontiguousarray(vertices, dtype="<f4").tobytes())
                proc.stdin.flush()
        except (BrokenPipeError, OSError):
            pass  # the child ended early; its stdout says why
        except BaseException as exc:  # noqa: BLE001 - reported on the calling thread
            problem.append(exc)
        finally:
            with contextlib.suppress(OSError):
                proc.stdin.close()

    reader = threading.Thread(target=read_stdout, name="mimica-export-reader", daemon=True)
    writer = threading.Thread(target=write_frames, name="mimica-export-frames", daemon=True)
    reader.start()
    writer.start()
    outcome = ("died", None)
    try:
        while True:
            if cancelled():
                raise ExportCancelled()
            if problem:
                raise problem[0]
            try:
                kind, rest = messages.get(timeout=0.05)
            except queue.Empty:
                continue
            if kind == "progress" and progress is not None:
                done, total = (int(v) for v in rest.split()[:2])
                progress(done, total)
            elif kind == "result":
                outcome = ("result", json.loads(rest))
            elif kind == "error":
                outcome = ("error", json.loads(rest))
            elif kind == "eof":
                break
        proc.wait()
        if problem and outcome[0] != "result":
            raise problem[0]
        return outcome
    except BaseException:
        stop.set()
        _stop_child(proc)
        raise
    finally:
        stop.set()
        writer.join(timeout=_TERMINATE_GRACE_S)


def _stop_child(proc: subprocess.Popen) -> None:
    """Ask the child to stop (it removes its partial output), then kill it if it does not."""
    if proc.poll() is not None:
        return
    with contextlib.suppress(OSError):
        proc.terminate()
    try:
        proc.wait(timeout=_TERMINATE_GRACE_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


class _Terminated(BaseException):
    """Raised in the child by SIGTERM (the parent's cancel)."""


def _child_main(spec_path: str) -> int:
    """Entry of ``python -m app.export --child spec.json``: frames on stdin, progress on stdout."""
    out = sys.stdout

    def say(kind: str, text: str) -> None:
        try:
            out.write(f"{kind} {text}\n")
            out.flush()
        except (BrokenPipeError, OSError, ValueError):
            pass  # the parent went away; nothing to report to

    def on_term(signum, frame):
        raise _Terminated()

    signal.signal(signal.SIGTERM, on_term)
    staging = None
    try:
        spec = json.loads(Path(spec_path).read_text(encoding="utf-8"))
        settings = ExportSettings.from_json(spec["settings"])
        staging = Path(spec["staging"])
        plan = _plan(settings)
        face = _load_face_npz(Path(spec["face"]))
        n = int(spec["n_vertices"])
        buffer = bytearray(n * 3 * 4)
        stdin = sys.stdin.buffer

        def next_vertices(k: int, t: float) -> np.ndarray:
            view = memoryview(buffer)
            got = 0
            while got < len(buffer):
                chunk = stdin.readinto(view[got:])
                if not chunk:
                    raise _Terminated()  # the parent closed the pipe: it cancelled or went away
                got += chunk
            return np.frombuffer(buffer, dtype="<f4").reshape(n, 3).astype(np.float64)

        stats = _render_to_staging(face, next_vertices, settings, plan, staging,
                                    progress=lambda done, total: say("progress", f"{done} {total}"),
                                    cancelled=_never, face_file=Path(spec["face"]))
        say("result", json.dumps(stats))
        return 0
    except _Terminated:
        _discard(staging)
        return 3
    except ExportError as exc:
        _discard(staging)
        say("error", json.dumps(str(exc)))
        return 2
    except Exception as exc:  # noqa: BLE001 - the parent shows it; the traceback goes to the log
        import traceback

        traceback.print_exc()
        _discard(staging)
        say("error", json.dumps(f"The export renderer failed: {type(exc).__name__}: {exc}"))
        return 1


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        status = _child_main(sys.argv[2])
        # Leave at once: a feeder thread may still be blocked reading stdin, and the interpreter's
        # shutdown would wait on (or abort over) the lock of that stream.
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(status)
    print("usage: python -m app.export --child SPEC.json  (internal: used by export_in_subprocess)", file=sys.stderr)
    sys.exit(2)
