"""Export settings, their checks and the frame plan: formats, sizes, frame times, where the files go.

Used by :mod:`app.export` (rendering and encoding) and the export dialog."""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np


MIN_SIZE, MAX_SIZE = 16, 8192        # pixels per side
MIN_FPS, MAX_FPS = 1.0, 120.0        # frames per second
#: Most render processes one export may use (each holds a renderer of its own: 550 MB resident at
#: 1280x720 with the default face, measured here, part of it shared libraries).
MAX_WORKERS = 32
#: The default never starts more render processes than this, however many cores there are...
DEFAULT_MAX_WORKERS = 8
#: ...nor more than the memory available holds at this much each.
WORKER_MEMORY_BYTES = 600 * 2**20
#: With the default number of workers, each gets at least this many frames: a render process takes
#: 1-3 s to start (imports, the face, the first draw), a dozen frames' time or more.
MIN_FRAMES_PER_WORKER = 24
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


_PATTERN = re.compile(r"%0?(\d*)d")
_SUFFIXES = {".mp4": "mp4", ".m4v": "mp4", ".gif": "gif", ".avi": "avi", ".png": "png", ".jpg": "jpg", ".jpeg": "jpg"}


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
        1..100: x264 CRF 35..15 (preset "veryfast" two CRF steps lower, "medium" from 90 on;
        :func:`app.export_sinks.x264_crf`), MJPEG q 31..2, JPEG quality.
    format : str, optional
        One of :data:`FORMATS`; default: from ``path``.
    workers : int, optional
        Render processes working in parallel (1..:data:`MAX_WORKERS`); default (None): one per
        core (:func:`default_workers`), fewer for short exports (:func:`planned_workers`).
        1 renders in the exporting process itself.
    full_detail : bool
        Draw the full face in every frame. Default (False): where the face's triangles are a few
        pixels on screen, a decimated face that gives the same picture (:mod:`app.export_lod`).
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
    workers: int | None = None
    full_detail: bool = False

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
    workers: int = 1

    @property
    def frames_per_second(self) -> float:
        """Frames exported per second of wall time (start-up included)."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def speed(self) -> str:
        """``"300 frames in 41.2 s (7.3 fps, 2 workers)"``."""
        workers = f"{self.workers} worker{'s' if self.workers != 1 else ''}"
        return (f"{self.frames} frame{'s' if self.frames != 1 else ''} in {self.seconds:.1f} s "
                f"({self.frames_per_second:.1f} fps, {workers})")

    def describe(self) -> str:
        """One line for a status bar."""
        if self.format == "png-sequence":
            first, last = (self.files[0].name, self.files[-1].name) if self.files else ("", "")
            return f"Exported {self.frames} PNG frames to {self.path.parent} ({first} … {last})"
        if self.format in STILL_FORMATS:
            return f"Exported {self.path}"
        return (f"Exported {FORMAT_NAMES[self.format]} {self.path} ({self.frames} frames, "
                f"{self.duration_s:.2f} s{', with sound' if self.has_audio else ''})")


def _available_memory() -> int | None:
    """Bytes of memory available to new processes (Linux's MemAvailable), or None when unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def default_workers() -> int:
    """Render processes used by default: one per core this process may run on, at most
    :data:`DEFAULT_MAX_WORKERS` and no more than the available memory holds
    (:data:`WORKER_MEMORY_BYTES` each)."""
    import os

    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    workers = min(cores, DEFAULT_MAX_WORKERS)
    memory = _available_memory()
    if memory is not None:
        workers = min(workers, memory // WORKER_MEMORY_BYTES)
    return max(1, int(workers))


def planned_workers(settings: ExportSettings, n_frames: int) -> int:
    """Render processes an export of ``n_frames`` frames uses: ``settings.workers`` (at most one per
    frame), or by default :func:`default_workers` with at least :data:`MIN_FRAMES_PER_WORKER`
    frames each (a short export renders in one process, as starting more would cost more than
    they save). A still always uses one."""
    if n_frames <= 1:
        return 1
    if settings.workers is not None:
        return max(1, min(int(settings.workers), n_frames))
    return max(1, min(default_workers(), n_frames // MIN_FRAMES_PER_WORKER))


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
    workers: int = 1   # render processes (planned_workers)

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
    workers = settings.workers
    if workers is not None and not (isinstance(workers, (int, np.integer)) and not isinstance(workers, bool)
                                    and 1 <= workers <= MAX_WORKERS):
        raise ExportError(f"The number of render workers must be a whole number from 1 to {MAX_WORKERS}, "
                          f"got {workers!r}.")

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
    return _Plan(fmt, times, (width, height), target, audio, notes, planned_workers(settings, len(times)))
