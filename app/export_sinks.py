"""Where exported frames go: ffmpeg encoders (MP4, AVI, GIF with a palette pass) and image writers
(PNG/JPG stills and sequences), staged in a temporary folder and committed atomically.

Leftovers of crashed exports
    Every temporary thing an export makes carries the id of the process that owns it and the name
    of its machine: the staging file beside the target (``.clip.mimica-<pid>-<host>-XXXX.part.mp4``),
    a sequence's hidden staging folder (``.mimica-export-<pid>-<host>-XXXX.part``) and the work
    folders in the system's temporary folder (``mimica-export-<pid>-<host>-XXXX``: the face, the
    speech, the GIF's frames, logs). An export that ends in any ordinary way (done, failed,
    cancelled, SIGINT/SIGTERM/SIGHUP) removes its own; one killed outright (SIGKILL, a power cut)
    cannot, so every export first removes those of this machine whose owner is no longer running
    (:func:`sweep_stale`), and so does every start of Mimica (:func:`sweep_at_start`: the temporary
    folder, and the target folders each export noted in the state folder before staging there).
    A live owner's files are never touched, nor another machine's (a shared network folder), whose
    processes cannot be seen from here.
"""

from __future__ import annotations

import abc
import contextlib
import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

from app.export_plan import (
    STILL_FORMATS, ExportError, ExportCancelled, ExportSettings, _Plan)
from core.processes import process_alive


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


def x264_preset(quality: int) -> str:
    """The x264 preset for ``quality`` (1..100; the quality sets the CRF, :func:`x264_crf`).

    "veryfast" up to 89: measured on 90 frames of the default face at 1280x720, "veryfast" at CRF 17
    gave the face (a 320x560 crop) 45.97 dB PSNR and SSIM 0.9885 against the rendered frames for a
    289 kB file, "fast" at CRF 19 (what quality 80 used before) 46.16 dB, 0.9889 and 286 kB, for
    10.4 instead of 19.2 ms of ffmpeg's CPU a frame, which the renderer uses instead. (At the same
    CRF "veryfast" loses 1.3 dB, hence :func:`x264_crf`'s two steps.) From 90 on, where the user
    asks for the best, "medium"."""
    return "medium" if int(quality) >= 90 else "veryfast"


def x264_crf(quality: int) -> int:
    """x264's CRF for ``quality`` (1..100): 35..15, two steps lower with the "veryfast" preset
    (:func:`x264_preset`) so that the picture is as good as with "fast" at the plain CRF."""
    crf = round(35 - 20 * (int(quality) - 1) / 99)
    return crf if x264_preset(quality) == "medium" else crf - 2


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
        out = ["-c:v", "libx264", "-preset", x264_preset(quality), "-crf", str(x264_crf(quality)),
               "-pix_fmt", "yuv420p", "-movflags", "+faststart"]
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


# ------------------------------------------------------------------ temporary names and the sweep
_TEMP_DIR = re.compile(r"^mimica-export-(\d+)-([a-z0-9]+)-")
_STAGING_FILE = re.compile(r"^\..*\.mimica-(\d+)-([a-z0-9]+)-[^.-]+\.part(\.[^.]*)?$")
_STAGING_DIR = re.compile(r"^\.mimica-export-(\d+)-([a-z0-9]+)-[^.-]+\.part$")


def _host() -> str:
    """This machine's name as it appears in temporary names (lower-case letters and digits)."""
    import socket

    return re.sub(r"[^a-z0-9]", "", socket.gethostname().lower())[:24] or "host"


def owner_tag(pid: int | None = None) -> str:
    """``<pid>-<host>``: who owns a temporary export file (this process by default)."""
    return f"{os.getpid() if pid is None else int(pid)}-{_host()}"


def temp_prefix(pid: int | None = None) -> str:
    """Prefix of this process's temporary export folders (``mimica-export-<pid>-<host>-``)."""
    return f"mimica-export-{owner_tag(pid)}-"


def temp_dir() -> tempfile.TemporaryDirectory:
    """A temporary folder owned by this process (removed on exit from its ``with``; swept if it is killed)."""
    return tempfile.TemporaryDirectory(prefix=temp_prefix())


def _stale(name: str, pattern: re.Pattern) -> bool:
    match = pattern.match(name)
    return match is not None and match.group(2) == _host() and not process_alive(int(match.group(1)))


def sweep_stale(folders=()) -> list[Path]:
    """Remove what crashed exports left: staging files and folders in ``folders`` (the target's
    folder) and work folders in the system's temporary folder, each only when it names this
    machine and a process that is gone. Returns what was removed; errors are ignored (it is
    housekeeping)."""
    removed: list[Path] = []
    places = [(Path(tempfile.gettempdir()), ((_TEMP_DIR, True),))]
    places += [(Path(f), ((_STAGING_FILE, False), (_STAGING_DIR, True))) for f in folders]
    seen = set()
    for folder, patterns in places:
        if folder in seen:
            continue
        seen.add(folder)
        try:
            entries = list(os.scandir(folder))
        except OSError:
            continue
        for entry in entries:
            for pattern, is_dir in patterns:
                if not _stale(entry.name, pattern):
                    continue
                try:
                    if is_dir and entry.is_dir(follow_symlinks=False):
                        shutil.rmtree(entry.path)
                    elif not is_dir and entry.is_file(follow_symlinks=False):
                        os.unlink(entry.path)
                    else:
                        continue
                except OSError:
                    continue
                removed.append(Path(entry.path))
    return removed


def _journal_dir() -> Path:
    """Where exports note the folders they stage in (``<state>/mimica/exports``)."""
    from core.formats.project import default_state_dir

    return default_state_dir().parent / "exports"


_JOURNAL = re.compile(r"^(\d+)-([a-z0-9]+)\.folders$")


def note_staging_folder(folder: Path) -> None:
    """Note ``folder`` in this process's journal (``<pid>-<host>.folders``) before staging there, so a
    start after a SIGKILL knows where the staging file was left (housekeeping: errors are ignored)."""
    with contextlib.suppress(OSError):
        journal = _journal_dir()
        journal.mkdir(parents=True, exist_ok=True)
        with open(journal / f"{owner_tag()}.folders", "a", encoding="utf-8") as fh:
            fh.write(str(Path(folder).resolve()) + "\n")


def sweep_at_start() -> list[Path]:
    """What crashed exports left, removed when Mimica starts: work folders in the temporary folder and
    staging files in the folders the dead exports noted (:func:`note_staging_folder`); a dead
    export's journal goes once its folders are swept. Returns what was removed."""
    folders: list[str] = []
    journals = []
    with contextlib.suppress(OSError):
        for entry in os.scandir(_journal_dir()):
            if _stale(entry.name, _JOURNAL):
                with contextlib.suppress(OSError, UnicodeError):
                    folders += Path(entry.path).read_text(encoding="utf-8").splitlines()[:1000]
                journals.append(Path(entry.path))
    removed = sweep_stale(dict.fromkeys(f for f in folders if f))
    for journal in journals:
        with contextlib.suppress(OSError):
            journal.unlink()
    return removed


def sweep_for(plan: _Plan) -> list[Path]:
    """:func:`sweep_stale` for the places an export of ``plan`` writes to."""
    folder = plan.folder
    return sweep_stale([folder if folder.is_dir() else folder.parent] if plan.format == "png-sequence"
                       else [folder])


# ------------------------------------------------------------------ staging and commit
def _make_staging(plan: _Plan) -> Path:
    """Create the temporary output (a file, or a folder for sequences) beside the target, named
    with this process's id (see :func:`sweep_stale`)."""
    folder = plan.folder
    owner = owner_tag()
    note_staging_folder(folder if folder.is_dir() or plan.format != "png-sequence" else folder.parent)
    try:
        if plan.format == "png-sequence":
            parent = folder if folder.is_dir() else folder.parent
            return Path(tempfile.mkdtemp(prefix=f".mimica-export-{owner}-", suffix=".part", dir=parent))
        fd, name = tempfile.mkstemp(prefix=f".{plan.target.stem}.mimica-{owner}-", suffix=f".part{plan.target.suffix}",
                                    dir=folder)
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
        mode = target.stat().st_mode & 0o777 if target.exists() else 0o644  # as core.formats.mesh_io.write_atomic
        os.chmod(staging, mode)
        os.replace(staging, target)
        return [target]
    except PermissionError:
        raise ExportError(f"Mimica is not allowed to write '{plan.target}'. Choose another name or folder.") from None
    except OSError as exc:
        raise ExportError(f"Could not save '{plan.target}': {exc.strerror or exc}.") from None
