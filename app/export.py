"""export.py
----
Export an animated face as video (MP4 H.264, GIF, AVI Motion-JPEG), as a PNG
image sequence, or as one still (PNG/JPG), rendered off screen with the same
scene code as the window (:mod:`app.scene`). Qt-free: the Qt job and dialog
live in :mod:`app.export_dialog`.

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
    ``.mp4``  H.264 (libx264, yuv420p, CRF from ``quality``, ``+faststart``),
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
    (``.name.XXXX.part.mp4``; a hidden folder for sequences) and renamed into
    place only after the encoder succeeded: a cancelled or failed export never
    leaves a broken file under the final name, and the partial file is removed.

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

Speed (measured here: software rendering, Mesa llvmpipe, a 2-core machine shared with other jobs)
    10 s of 1280x720 at 30 fps of the default face (53,772 vertices, textured): 300 frames in 134 s wall
    through :func:`export_in_subprocess` at load average ~7 (not measured on an idle machine; the CPU
    cost below suggests about a minute). Per frame: rendering (vertex upload + draw + read-back) 408 ms wall / 184 ms CPU; the
    renderer waited 13 ms for the encoder, which used 27-32 ms CPU per frame in its own process (x264
    preset medium). Rendering is about 93% of the time; with the window's 4x MSAA it cost 338-398 ms
    CPU a frame, hence FXAA for export (see :class:`_FaceRenderer`).
"""

from __future__ import annotations

import abc
import contextlib
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from core.face import Face

__all__ = [
    "FORMATS", "AUDIO_FORMATS", "ExportError", "ExportCancelled", "ExportSettings", "ExportResult",
    "frame_times", "export_frame_times", "resolve_format", "export", "export_in_subprocess", "camera_state", "apply_camera",
    "ffmpeg_exe",
]

#: Export formats (values of :attr:`ExportSettings.format`).
FORMATS = ("mp4", "gif", "avi", "png-sequence", "png", "jpg")
#: Formats that can carry a sound track.
AUDIO_FORMATS = ("mp4", "avi")
#: Formats that write one image.
STILL_FORMATS = ("png", "jpg")
#: Human names, for messages.
FORMAT_NAMES = {"mp4": "MP4 video", "gif": "GIF animation", "avi": "AVI video", "png-sequence": "PNG sequence",
                "png": "PNG image", "jpg": "JPEG image"}
SEQUENCE_PATTERN = "frame_%04d.png"
MIN_SIZE, MAX_SIZE = 16, 8192
MIN_FPS, MAX_FPS = 1.0, 120.0
_PATTERN = re.compile(r"%0?(\d*)d")
_SUFFIXES = {".mp4": "mp4", ".m4v": "mp4", ".gif": "gif", ".avi": "avi", ".png": "png", ".jpg": "jpg", ".jpeg": "jpg"}
_TERMINATE_GRACE_S = 5.0


class ExportError(ValueError):
    """An export could not be done; ``str(error)`` is a user-facing message."""


class ExportCancelled(Exception):
    """The export was cancelled by the user; nothing was written under the final name."""

    def __init__(self, message: str = "Export cancelled."):
        super().__init__(message)


# ------------------------------------------------------------------ settings
@dataclass
class ExportSettings:
    """What to export and how.

    Attributes
    ----------
    path : Path
        Output file (suffix picks the format), a folder or ``name_%04d.png`` (PNG sequence).
    end_s : float
        End of the range, seconds, exclusive (ignored by stills).
    size : (width, height) int
        Output pixels.
    fps : float
        Frames per second, 1..120.
    start_s : float
        Start of the range, seconds (the time of a still).
    mode : str
        Display mode (:data:`app.scene.MODES`).
    view : str
        Camera preset (:data:`app.scene.VIEWS`) framed on the face, used when ``camera`` is None.
    camera : dict, optional
        A camera taken from the window (:func:`camera_state`): position, focal_point, view_up,
        view_angle, parallel_projection, parallel_scale.
    audio_path : Path, optional
        Sound track (MP4 and AVI only), starting at time 0 of the animation.
    quality : int
        1..100: x264 CRF 35..15, MJPEG q 31..2, JPEG quality.
    format : str, optional
        One of :data:`FORMATS`; default: from ``path``.
    """

    path: Path
    end_s: float = 0.0
    size: tuple[int, int] = (1280, 720)
    fps: float = 30.0
    start_s: float = 0.0
    mode: str = "textured"
    view: str = "front"
    camera: dict | None = None
    audio_path: Path | None = None
    quality: int = 80
    format: str | None = None

    def to_json(self) -> dict:
        data = asdict(self)
        data["path"] = str(self.path)
        data["audio_path"] = None if self.audio_path is None else str(self.audio_path)
        data["size"] = list(self.size)
        return data

    @classmethod
    def from_json(cls, data: dict) -> ExportSettings:
        data = dict(data)
        data["path"] = Path(data["path"])
        data["audio_path"] = None if data.get("audio_path") is None else Path(data["audio_path"])
        data["size"] = tuple(data["size"])
        return cls(**data)


@dataclass
class ExportResult:
    """What an export wrote.

    ``path`` is the file, or for a PNG sequence the pattern (``.../frame_%04d.png``) with the
    written files in ``files``. ``seconds`` is the wall time; ``render_seconds`` (update + draw +
    read-back) and ``encode_seconds`` (time the renderer waited for the encoder, including the
    final flush) split it.
    """

    path: Path
    format: str
    frames: int
    seconds: float
    size: tuple[int, int]
    fps: float
    duration_s: float
    has_audio: bool = False
    render_seconds: float = 0.0
    encode_seconds: float = 0.0
    files: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def describe(self) -> str:
        """One line for a status bar."""
        if self.format == "png-sequence":
            first, last = (self.files[0].name, self.files[-1].name) if self.files else ("", "")
            return f"Exported {self.frames} PNG frames to {self.path.parent} ({first} … {last})"
        if self.format in STILL_FORMATS:
            return f"Exported {self.path}"
        return (f"Exported {FORMAT_NAMES[self.format]} {self.path} ({self.frames} frames, "
                f"{self.duration_s:.2f} s{', with sound' if self.has_audio else ''})")


def frame_times(start_s: float, end_s: float, fps: float) -> np.ndarray:
    """(N,) times ``start_s + k / fps``, ``N = round((end_s - start_s) * fps)`` (end exclusive), seconds."""
    n = int(round((float(end_s) - float(start_s)) * float(fps)))
    return float(start_s) + np.arange(max(n, 0)) / float(fps)


def export_frame_times(settings: ExportSettings) -> np.ndarray:
    """(N,) frame times (s) ``settings`` will render, after checking everything that can be checked
    before rendering (format, size, fps, range, mode, view, quality, folder, audio file).

    Raises
    ------
    ExportError
        What is wrong, in words for the user.
    """
    return _plan(settings).times.copy()


def resolve_format(settings: ExportSettings) -> str:
    """The export format of ``settings`` (explicit, else from the path). Raises :class:`ExportError`."""
    if settings.format is not None:
        if settings.format not in FORMATS:
            raise ExportError(f"Unknown export format {settings.format!r}; choose one of {', '.join(FORMATS)}.")
        return settings.format
    path = Path(settings.path)
    suffix = path.suffix.lower()
    if _PATTERN.search(path.name):
        if suffix != ".png":
            raise ExportError(f"An image sequence must be PNG: use a name like 'frame_%04d.png', not '{path.name}'.")
        return "png-sequence"
    if path.is_dir() or not suffix:
        return "png-sequence"
    fmt = _SUFFIXES.get(suffix)
    if fmt is None:
        raise ExportError(
            f"Mimica cannot export '{path.name}': choose a name ending in .mp4, .gif, .avi, .png or .jpg, "
            "or a folder (or 'name_%04d.png') for a PNG sequence.")
    return fmt


@dataclass
class _Plan:
    """Validated settings: format, frame times and the final target."""

    format: str
    times: np.ndarray
    size: tuple[int, int]
    target: Path  # the file, or the pattern path of a sequence
    audio: Path | None
    notes: list[str]

    @property
    def n_frames(self) -> int:
        return len(self.times)

    @property
    def folder(self) -> Path:
        return self.target.parent


def _plan(settings: ExportSettings) -> _Plan:
    """Check ``settings`` and work out what to write; every problem is an :class:`ExportError`."""
    from app import scene

    fmt = resolve_format(settings)
    notes: list[str] = []
    try:
        width, height = (float(v) for v in settings.size)
        if not (width.is_integer() and height.is_integer()):
            raise ValueError
        width, height = int(width), int(height)
    except (TypeError, ValueError):
        raise ExportError(f"The image size must be two whole numbers (width, height), got {settings.size!r}.") from None
    for label, value in (("width", width), ("height", height)):
        if not MIN_SIZE <= value <= MAX_SIZE:
            raise ExportError(f"The image {label} must be between {MIN_SIZE} and {MAX_SIZE} pixels, got {value}.")
    if fmt == "mp4" and (width % 2 or height % 2):
        raise ExportError(f"MP4 (H.264) video needs an even width and height; {width}×{height} is odd. "
                          f"Use e.g. {width + width % 2}×{height + height % 2}.")
    fps = float(settings.fps)
    if not (math.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise ExportError(f"The frame rate must be between {MIN_FPS:g} and {MAX_FPS:g} frames per second, "
                          f"got {settings.fps}.")
    start, end = float(settings.start_s), float(settings.end_s)
    if not math.isfinite(start) or start < 0:
        raise ExportError(f"The start time must be 0 s or later, got {settings.start_s} s.")
    if fmt in STILL_FORMATS:
        times = np.array([start])
    else:
        if not math.isfinite(end) or end <= start:
            raise ExportError(f"The end time ({settings.end_s} s) must be after the start time ({start} s).")
        times = frame_times(start, end, fps)
        if len(times) < 1:
            raise ExportError(f"The range {start:g}–{end:g} s is shorter than one frame at {fps:g} fps; "
                              "choose a longer range.")
    if settings.mode not in scene.MODES:
        raise ExportError(f"Unknown display mode {settings.mode!r}; choose one of {', '.join(scene.MODES)}.")
    if settings.camera is None and settings.view not in scene.VIEWS:
        raise ExportError(f"Unknown view {settings.view!r}; choose one of {', '.join(scene.VIEWS)}.")
    quality = settings.quality
    if not (isinstance(quality, (int, np.integer)) and 1 <= quality <= 100):
        raise ExportError(f"The quality must be a whole number from 1 to 100, got {quality!r}.")

    path = Path(settings.path).expanduser()
    if fmt == "png-sequence":
        if _PATTERN.search(path.name):
            target = path
        elif path.suffix.lower() == ".png":
            target = path.with_name(f"{path.stem}_%04d.png")
        else:
            target = path / SEQUENCE_PATTERN
        if len(_PATTERN.findall(target.name)) != 1:
            raise ExportError(f"The sequence name '{target.name}' must contain exactly one frame-number "
                              "placeholder such as %04d.")
        folder = target.parent
        if folder.exists() and not folder.is_dir():
            raise ExportError(f"Cannot write the images into '{folder}': it is a file, not a folder.")
        if not folder.exists() and not folder.parent.is_dir():
            raise ExportError(f"Cannot export into '{folder}': the folder '{folder.parent}' does not exist.")
    else:
        target = path
        if target.is_dir():
            raise ExportError(f"'{target}' is a folder; choose a file name for the {FORMAT_NAMES[fmt]}.")
        folder = target.parent
        if folder.exists() and not folder.is_dir():
            raise ExportError(f"Cannot save '{target.name}': '{folder}' is a file, not a folder.")
        if not folder.is_dir():
            raise ExportError(f"Cannot save '{target.name}': the folder '{folder}' does not exist.")

    audio = None
    if settings.audio_path is not None:
        audio_path = Path(settings.audio_path)
        if fmt not in AUDIO_FORMATS:
            notes.append(f"A {FORMAT_NAMES[fmt]} has no sound; the audio track was left out.")
        elif not audio_path.is_file():
            raise ExportError(f"The audio file '{audio_path}' does not exist; export without sound or choose "
                              "another file.")
        else:
            audio = audio_path
    return _Plan(fmt, times, (width, height), target, audio, notes)


# ------------------------------------------------------------------ ffmpeg
def ffmpeg_exe() -> str:
    """Path of the ffmpeg binary (imageio-ffmpeg's). Raises :class:`ExportError` when there is none."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise ExportError("Video export needs the imageio-ffmpeg package, which is not installed. "
                          "Install it (pip install imageio-ffmpeg) or export a PNG sequence.") from None
    try:
        exe = imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as exc:
        raise ExportError(f"The video encoder (ffmpeg) was not found: {exc}. Reinstall imageio-ffmpeg, "
                          "or export a PNG sequence.") from None
    return exe


def _tail(path: Path, lines: int = 8) -> str:
    try:
        text = Path(path).read_text(errors="replace")
    except OSError:
        return ""
    kept = [line.strip() for line in text.splitlines() if line.strip()]
    return "\n".join(kept[-lines:])


def _ffmpeg_failure(what: str, log: Path, returncode: int | None = None, audio: Path | None = None) -> ExportError:
    tail = _tail(log)
    hint = ""
    if audio is not None and str(audio) in tail:
        hint = f" The sound file '{audio.name}' could not be read: export without sound or choose another file."
    elif "No space left" in tail:
        hint = " The disk is full: free some space or choose another folder."
    elif "Permission denied" in tail:
        hint = " Mimica is not allowed to write there: choose another folder."
    code = f" (exit status {returncode})" if returncode not in (None, 0) else ""
    detail = f"\nffmpeg said:\n{tail}" if tail else ""
    return ExportError(f"Could not {what}: the encoder ffmpeg failed{code}.{hint}{detail}")


def _wait(proc: subprocess.Popen, cancelled: Callable[[], bool]) -> int:
    """Wait for ``proc``, polling ``cancelled`` (then kill it and raise :class:`ExportCancelled`)."""
    while True:
        try:
            return proc.wait(timeout=0.05)
        except subprocess.TimeoutExpired:
            if cancelled():
                proc.kill()
                proc.wait()
                raise ExportCancelled() from None


class _Sink(abc.ABC):
    """Takes (h, w, 3) uint8 frames for one output; ``finish`` completes it, ``abort`` drops it."""

    @abc.abstractmethod
    def write(self, image: np.ndarray) -> None:
        """Add one frame."""

    def finish(self, cancelled: Callable[[], bool]) -> None:
        pass

    def abort(self) -> None:
        pass


class _FfmpegSink(_Sink):
    """Raw RGB frames piped into one ffmpeg process writing ``out_args``."""

    def __init__(self, exe: str, size: tuple[int, int], fps: float, out_args: list[str], log: Path,
                 *, audio_args: list[str] = (), what: str = "write the video", audio: Path | None = None):
        width, height = size
        self.log = log
        self.what = what
        self.audio = audio
        cmd = [exe, "-hide_banner", "-nostats", "-loglevel", "error", "-y",
               "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}", "-framerate", f"{fps:g}",
               "-i", "pipe:0", *audio_args, *out_args]
        self._log_file = open(log, "wb")
        try:
            self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                         stderr=self._log_file)
        except OSError as exc:
            self._log_file.close()
            raise ExportError(f"Could not start the video encoder ffmpeg ({exe}): {exc.strerror or exc}.") from None

    def write(self, image: np.ndarray) -> None:
        try:
            self.proc.stdin.write(memoryview(np.ascontiguousarray(image, dtype=np.uint8)).cast("B"))
        except (BrokenPipeError, OSError):
            returncode = self.proc.wait()
            self._log_file.close()
            raise _ffmpeg_failure(self.what, self.log, returncode, self.audio) from None

    def finish(self, cancelled: Callable[[], bool]) -> None:
        try:
            self.proc.stdin.close()
        except (BrokenPipeError, OSError):
            pass
        try:
            returncode = _wait(self.proc, cancelled)
        finally:
            self._log_file.close()
        if returncode != 0:
            raise _ffmpeg_failure(self.what, self.log, returncode, self.audio)

    def abort(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        with contextlib.suppress(OSError, ValueError):
            self.proc.stdin.close()
        self.proc.wait()
        self._log_file.close()


class _GifSink(_FfmpegSink):
    """Frames into a lossless FFV1 file, then palettegen + paletteuse into the GIF (two ffmpeg passes)."""

    def __init__(self, exe: str, size, fps: float, staging: Path, work: Path):
        self.exe, self.staging, self.work = exe, staging, work
        self.frames_file = work / "frames.mkv"
        super().__init__(exe, size, fps, ["-c:v", "ffv1", "-f", "matroska", str(self.frames_file)],
                         work / "ffmpeg-frames.log", what="write the GIF")

    def finish(self, cancelled: Callable[[], bool]) -> None:
        super().finish(cancelled)
        palette = self.work / "palette.png"
        passes = (
            ["-i", str(self.frames_file), "-vf", "palettegen=stats_mode=full", "-update", "1", str(palette)],
            ["-i", str(self.frames_file), "-i", str(palette), "-lavfi", "paletteuse=dither=sierra2_4a",
             "-loop", "0", "-f", "gif", str(self.staging)],
        )
        for number, args in enumerate(passes, 1):
            log = self.work / f"ffmpeg-gif-{number}.log"
            with open(log, "wb") as fh:
                proc = subprocess.Popen([self.exe, "-hide_banner", "-nostats", "-loglevel", "error", "-y", *args],
                                        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=fh)
                returncode = _wait(proc, cancelled)
            if returncode != 0:
                raise _ffmpeg_failure("write the GIF", log, returncode)


class _StillSink(_Sink):
    """One PNG/JPG written with Pillow."""

    def __init__(self, staging: Path, fmt: str, quality: int):
        self.staging, self.fmt, self.quality = staging, fmt, quality

    def write(self, image: np.ndarray) -> None:
        from PIL import Image

        pil = Image.fromarray(np.ascontiguousarray(image[..., :3]))
        try:
            if self.fmt == "jpg":
                pil.save(self.staging, format="JPEG", quality=int(self.quality))
            else:
                pil.save(self.staging, format="PNG")
        except OSError as exc:
            raise ExportError(f"Could not write the image: {exc.strerror or exc}.") from None


def _make_sink(plan: _Plan, settings: ExportSettings, staging: Path, work: Path) -> _Sink:
    fmt, quality = plan.format, int(settings.quality)
    if fmt in STILL_FORMATS:
        return _StillSink(staging, fmt, quality)
    exe = ffmpeg_exe()
    fps = float(settings.fps)
    log = work / "ffmpeg.log"
    audio_args: list[str] = []
    if plan.audio is not None:
        # Cut or pad (silence) the sound to exactly the video's length with filters: "apad + -shortest"
        # is racy when the video arrives slowly through the pipe (ffmpeg ran the audio up to 1 s long).
        length = f"{plan.n_frames / fps:.6f}"
        audio_args = ["-ss", f"{float(settings.start_s):.6f}", "-i", str(plan.audio), "-map", "0:v", "-map", "1:a",
                      "-af", f"apad=whole_dur={length},atrim=end={length}"]
    if fmt == "mp4":
        crf = round(35 - 20 * (quality - 1) / 99)
        out = ["-c:v", "libx264", "-preset", "medium", "-crf", str(crf), "-pix_fmt", "yuv420p",
               "-movflags", "+faststart"]
        if plan.audio is not None:
            out += ["-c:a", "aac", "-b:a", "192k"]
        return _FfmpegSink(exe, plan.size, fps, [*out, "-f", "mp4", str(staging)], log, audio_args=audio_args,
                           audio=plan.audio)
    if fmt == "avi":
        q = round(31 - 29 * (quality - 1) / 99)
        out = ["-c:v", "mjpeg", "-q:v", str(q), "-pix_fmt", "yuvj420p"]
        if plan.audio is not None:
            out += ["-c:a", "pcm_s16le"]
        return _FfmpegSink(exe, plan.size, fps, [*out, "-f", "avi", str(staging)], log, audio_args=audio_args,
                           audio=plan.audio)
    if fmt == "gif":
        return _GifSink(exe, plan.size, fps, staging, work)
    # png-sequence: ffmpeg's image2 muxer, numbered from 0, into the hidden staging folder
    pattern = staging / plan.target.name
    return _FfmpegSink(exe, plan.size, fps, ["-c:v", "png", "-start_number", "0", "-f", "image2", str(pattern)],
                       log, what="write the PNG images")


# ------------------------------------------------------------------ staging and commit
def _make_staging(plan: _Plan) -> Path:
    """Create the temporary output (a file, or a folder for sequences) beside the target."""
    folder = plan.folder
    try:
        if plan.format == "png-sequence":
            parent = folder if folder.is_dir() else folder.parent
            return Path(tempfile.mkdtemp(prefix=".mimica-export-", suffix=".part", dir=parent))
        fd, name = tempfile.mkstemp(prefix=f".{plan.target.stem}.", suffix=f".part{plan.target.suffix}", dir=folder)
        os.close(fd)
        return Path(name)
    except PermissionError:
        raise ExportError(f"Mimica is not allowed to write in '{folder if folder.is_dir() else folder.parent}'. "
                          "Choose another folder or check its permissions.") from None
    except OSError as exc:
        raise ExportError(f"Cannot write in '{folder}': {exc.strerror or exc}.") from None


def _discard(staging: Path | None) -> None:
    if staging is None:
        return
    if staging.is_dir():
        shutil.rmtree(staging, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            staging.unlink()


def _commit(plan: _Plan, staging: Path) -> list[Path]:
    """Move the finished staging output to its final name(s); returns the files written."""
    try:
        if plan.format == "png-sequence":
            folder = plan.folder
            folder.mkdir(exist_ok=True)
            written = []
            for k in range(plan.n_frames):
                name = plan.target.name % k
                source = staging / name
                if not source.is_file():
                    raise ExportError(f"The encoder wrote no image for frame {k} ({name}); the sequence is "
                                      "incomplete.")
                os.replace(source, folder / name)
                written.append(folder / name)
            shutil.rmtree(staging, ignore_errors=True)
            return written
        target = plan.target
        mode = target.stat().st_mode & 0o777 if target.exists() else 0o644  # as core.mesh_io.write_atomic
        os.chmod(staging, mode)
        os.replace(staging, target)
        return [target]
    except PermissionError:
        raise ExportError(f"Mimica is not allowed to write '{plan.target}'. Choose another name or folder.") from None
    except OSError as exc:
        raise ExportError(f"Could not save '{plan.target}': {exc.strerror or exc}.") from None


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
    """One off-screen plotter showing ``face``; :meth:`render` draws given vertices and reads the pixels."""

    def __init__(self, face: Face, settings: ExportSettings, size: tuple[int, int]):
        import pyvista as pv

        from app import render, scene

        render._prefer_egl_without_display()
        self.size = size
        self.plotter = pv.Plotter(off_screen=True, window_size=size)
        try:
            # FXAA, not the window's multisampling: in software rendering (llvmpipe) 4x MSAA doubles the
            # CPU per frame (338 vs 156 ms at 1280x720 for the default face) for no visible gain in a
            # video. VTK's own FXAA is used directly because pyvista swaps it for SSAA (slower still)
            # whenever VTK can do EGL; it renders correctly through both the X and the EGL windows here.
            scene.setup_stage(self.plotter, anti_aliasing=None)
            self.plotter.render_window.SetMultiSamples(0)
            self.plotter.renderer.UseFXAAOn()
            self.actor = scene.add_face_actor(self.plotter, face, settings.mode)
            if settings.camera is not None:
                apply_camera(self.plotter, settings.camera)
            else:
                scene.set_camera_view(self.plotter, settings.view, face.vertices)
            self.plotter.show(auto_close=False)  # realises the window; later frames use render()
        except BaseException:
            self.plotter.close()
            raise

    def render(self, vertices: np.ndarray) -> np.ndarray:
        """(h, w, 3) uint8 RGB of the face at ``vertices`` (n, 3) mm, top row first."""
        self.actor.update_vertices(vertices)
        self.plotter.renderer.ResetCameraClippingRange()
        self.plotter.render()
        image = np.asarray(self.plotter.image)
        height, width = self.size[1], self.size[0]
        if image.shape[:2] != (height, width):
            raise ExportError(f"The renderer produced a {image.shape[1]}×{image.shape[0]} image instead of "
                              f"{width}×{height}; try a smaller size.")
        return image[..., :3]

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
        notes=list(plan.notes))


def _render_to_staging(face: Face, next_vertices: Callable[[int, float], np.ndarray], settings: ExportSettings,
                       plan: _Plan, staging: Path, *, progress, cancelled) -> dict:
    """Render every frame into the staging output; returns timing stats (seconds)."""
    start = time.perf_counter()
    render_s = encode_s = 0.0
    n_vertices = face.n_vertices
    with tempfile.TemporaryDirectory(prefix="mimica-export-work-") as work:
        sink = _make_sink(plan, settings, staging, Path(work))
        renderer = None
        try:
            renderer = _FaceRenderer(face, settings, plan.size)
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
            renderer.close()
            renderer = None
            t0 = time.perf_counter()
            sink.finish(cancelled)
            encode_s += time.perf_counter() - t0
        except BaseException:
            sink.abort()
            raise
        finally:
            if renderer is not None:
                renderer.close()
    return {"seconds": time.perf_counter() - start, "render_seconds": render_s, "encode_seconds": encode_s}


# ------------------------------------------------------------------ export in a child process
def _save_face_npz(face: Face, path: Path) -> None:
    arrays = {"vertices": np.asarray(face.vertices, np.float64), "triangles": np.asarray(face.triangles, np.int64)}
    if face.uv is not None:
        arrays["uv"] = np.asarray(face.uv, np.float64)
    if face.texture is not None:
        arrays["texture"] = np.asarray(face.texture, np.uint8)
    if face.vertex_colors is not None:
        arrays["vertex_colors"] = np.asarray(face.vertex_colors, np.uint8)
    np.savez(path, **arrays)


def _load_face_npz(path: Path) -> Face:
    with np.load(path) as data:
        return Face(data["vertices"], data["triangles"],
                    uv=data["uv"] if "uv" in data.files else None,
                    texture=data["texture"] if "texture" in data.files else None,
                    vertex_colors=data["vertex_colors"] if "vertex_colors" in data.files else None)


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
    staging = _make_staging(plan)
    proc = None
    try:
        with tempfile.TemporaryDirectory(prefix="mimica-export-") as tmp:
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
                                    cancelled=_never)
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
        sys.exit(_child_main(sys.argv[2]))
    print("usage: python -m app.export --child SPEC.json  (internal: used by export_in_subprocess)", file=sys.stderr)
    sys.exit(2)
