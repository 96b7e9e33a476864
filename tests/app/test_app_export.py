"""app.export / app.export_dialog: video, GIF, AVI, PNG sequence and still export, cancel, errors, the dialog."""

from __future__ import annotations

import re
import subprocess
import wave
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
from app_helpers import image_difference, image_variance, make_synthetic_face
from PIL import Image

from app import export as ex
from app import export_sinks
from app.export import (
    ExportCancelled, ExportError, ExportSettings, export, export_frame_times, export_in_subprocess, frame_times)

SMALL = (160, 120)


# ------------------------------------------------------------------ helpers
@pytest.fixture(scope="module")
def face():
    return make_synthetic_face(32, 40)


def opening_mouth(face, amount_mm: float = 25.0):
    """A frame source: the lower third of the face drops by ``amount_mm`` per second."""
    rest = face.vertices.copy()
    lower = rest[:, 1] < -40.0

    def frame_vertices(t):
        v = rest.copy()
        v[lower, 1] -= amount_mm * t
        return v

    return frame_vertices


def probe(path) -> str:
    """ffmpeg's description of a media file (stream list on stderr)."""
    run = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                         capture_output=True, text=True)
    return run.stderr


def video_size(info: str) -> tuple[int, int]:
    match = re.search(r"Video: .*?(\d{2,5})x(\d{2,5})", info)
    assert match, info
    return int(match.group(1)), int(match.group(2))


def decode_frame(path, index: int, tmp_path) -> np.ndarray:
    """Frame ``index`` of a video as an RGB array (extracted with ffmpeg)."""
    out = tmp_path / f"frame{index}.png"
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-i", str(path), "-vf",
                    f"select=eq(n\\,{index})", "-frames:v", "1", str(out)], check=True)
    return np.asarray(Image.open(out).convert("RGB"))


def sine_wav(path, seconds: float, rate: int = 16000) -> Path:
    t = np.arange(int(seconds * rate)) / rate
    samples = (0.3 * 32767 * np.sin(2 * np.pi * 440 * t)).astype("<i2")
    with wave.open(str(path), "wb") as fh:
        fh.setnchannels(1)
        fh.setsampwidth(2)
        fh.setframerate(rate)
        fh.writeframes(samples.tobytes())
    return Path(path)


def leftovers(folder: Path, keep=()) -> list[str]:
    return sorted(p.name for p in Path(folder).iterdir() if p.name not in keep)


# ------------------------------------------------------------------ timing
def test_frame_times_are_exact_and_end_exclusive():
    np.testing.assert_allclose(frame_times(0.0, 1.0, 10), np.arange(10) / 10)
    times = frame_times(0.5, 2.0, 30)
    assert len(times) == 45 and times[0] == 0.5 and times[-1] == pytest.approx(2.0 - 1 / 30)
    assert len(frame_times(0.0, 10.0, 30)) == 300


# ------------------------------------------------------------------ formats
def test_mp4_frame_count_size_and_audio(tmp_path, face):
    wav = sine_wav(tmp_path / "tone.wav", 2.0)
    out = tmp_path / "clip.mp4"
    seen = []
    result = export(face, opening_mouth(face), ExportSettings(out, end_s=1.0, size=SMALL, fps=12, audio_path=wav),
                    progress=lambda done, total: seen.append((done, total)))
    assert result.path == out and result.frames == 12 and result.has_audio
    assert seen == [(k, 12) for k in range(1, 13)]
    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(out))
    assert frames == 12 and seconds == pytest.approx(1.0, abs=0.01)
    info = probe(out)
    assert "Video: h264" in info and "yuv420p" in info
    assert video_size(info) == SMALL
    assert "Audio: aac" in info
    duration = re.search(r"Duration: (\d+):(\d+):([\d.]+)", info)
    assert float(duration.group(3)) == pytest.approx(1.0, abs=0.05)  # the 2 s tone is cut to the video
    audio = re.search(r"Audio: aac.*?(\d+) kb/s", info)
    assert audio, info
    assert leftovers(tmp_path) == ["clip.mp4", "tone.wav"]  # no staging file left behind


def test_mp4_without_audio_has_no_audio_stream(tmp_path, face):
    out = tmp_path / "silent.mp4"
    export(face, opening_mouth(face), ExportSettings(out, start_s=0.5, end_s=1.0, size=SMALL, fps=10))
    assert imageio_ffmpeg.count_frames_and_secs(str(out))[0] == 5
    assert "Audio:" not in probe(out)


def test_avi_is_motion_jpeg_with_pcm_sound(tmp_path, face):
    out = tmp_path / "clip.avi"
    wav = sine_wav(tmp_path / "tone.wav", 0.3)  # shorter than the video: padded with silence
    export(face, opening_mouth(face), ExportSettings(out, end_s=0.8, size=SMALL, fps=10, audio_path=wav))
    info = probe(out)
    assert "Video: mjpeg" in info and video_size(info) == SMALL and "pcm_s16le" in info
    assert imageio_ffmpeg.count_frames_and_secs(str(out))[0] == 8


def test_gif_frame_count_and_size(tmp_path, face):
    out = tmp_path / "loop.gif"
    result = export(face, opening_mouth(face), ExportSettings(out, end_s=0.7, size=SMALL, fps=10,
                                                              audio_path=sine_wav(tmp_path / "a.wav", 1)))
    with Image.open(out) as gif:
        assert gif.n_frames == 7 and gif.size == SMALL
        assert gif.info.get("duration") == 100  # ms per frame at 10 fps
    assert not result.has_audio and "no sound" in result.notes[0]


def test_png_sequence_counts_and_moving_vertices_change_frames(tmp_path, face):
    folder = tmp_path / "frames"
    result = export(face, opening_mouth(face), ExportSettings(folder, end_s=1.0, size=SMALL, fps=5))
    names = sorted(p.name for p in folder.iterdir())
    assert names == [f"frame_{k:04d}.png" for k in range(5)]
    assert result.files == [folder / n for n in names] and result.format == "png-sequence"
    images = [np.asarray(Image.open(folder / n)) for n in names]
    assert all(img.shape == (SMALL[1], SMALL[0], 3) for img in images)
    assert image_variance(images[0]) > 100
    # the mouth opens: the lower half changes from frame to frame, the top half barely
    lower = slice(SMALL[1] // 2, None)
    assert image_difference(images[0][lower], images[-1][lower]) > 2
    assert image_difference(images[0][lower], images[-1][lower]) > 5 * image_difference(images[0][:30], images[-1][:30])
    assert leftovers(tmp_path) == ["frames"]


def test_static_source_gives_identical_frames_and_pattern_names(tmp_path, face):
    pattern = tmp_path / "shot_%03d.png"
    rest = face.vertices
    export(face, lambda t: rest, ExportSettings(pattern, end_s=0.3, size=SMALL, fps=10))
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["shot_000.png", "shot_001.png", "shot_002.png"]
    first, last = (np.asarray(Image.open(tmp_path / n)) for n in (names[0], names[-1]))
    assert image_difference(first, last) == 0.0


def test_still_png_and_jpg_render_the_requested_time(tmp_path, face):
    asked = []
    source = opening_mouth(face)

    def frame_vertices(t):
        asked.append(t)
        return source(t)

    png = export(face, frame_vertices, ExportSettings(tmp_path / "still.png", start_s=0.75, size=(200, 150)))
    assert asked == [0.75] and png.frames == 1
    img = np.asarray(Image.open(png.path))
    assert img.shape == (150, 200, 3) and image_variance(img) > 100
    # textured: the texture's red top is at the top of the picture, its blue bottom below
    centre = img[:, 60:140].astype(int)
    top, bottom = centre[20:60].reshape(-1, 3), centre[90:130].reshape(-1, 3)
    assert (top[:, 0] - top[:, 2]).mean() > 20 and (bottom[:, 2] - bottom[:, 0]).mean() > 0
    jpg = export(face, frame_vertices, ExportSettings(tmp_path / "still.jpg", start_s=0.0, size=(200, 150)))
    with Image.open(jpg.path) as im:
        assert im.format == "JPEG" and im.size == (200, 150)


def test_explicit_camera_is_used(tmp_path, face):
    far = {"position": [0, 0, 2000], "focal_point": [0, 0, 0], "view_up": [0, 1, 0], "view_angle": 30}
    near = dict(far, position=[0, 0, 500])
    a = export(face, lambda t: face.vertices, ExportSettings(tmp_path / "far.png", size=SMALL, camera=far))
    b = export(face, lambda t: face.vertices, ExportSettings(tmp_path / "near.png", size=SMALL, camera=near))
    def covered(path):  # pixels that differ from the background (a vertical gradient: column 0 of each row)
        img = np.asarray(Image.open(path)).astype(int)
        return (np.abs(img - img[:, :1]).sum(axis=2) > 40).mean()

    assert covered(b.path) > 4 * covered(a.path) > 0


# ------------------------------------------------------------------ cancel and errors
def test_cancel_removes_the_partial_file(tmp_path, face):
    out = tmp_path / "cancelled.mp4"
    done = []
    with pytest.raises(ExportCancelled):
        export(face, opening_mouth(face), ExportSettings(out, end_s=2.0, size=SMALL, fps=10),
               progress=lambda d, n: done.append(d), cancelled=lambda: len(done) >= 3)
    assert len(done) == 3
    assert leftovers(tmp_path) == []


def test_existing_file_survives_a_failed_export(tmp_path, face):
    out = tmp_path / "keep.mp4"
    out.write_bytes(b"old video")

    def broken(t):
        if t > 0.15:
            raise ExportError("no vertices here")
        return face.vertices

    with pytest.raises(ExportError, match="no vertices here"):
        export(face, broken, ExportSettings(out, end_s=1.0, size=SMALL, fps=10))
    assert out.read_bytes() == b"old video" and leftovers(tmp_path) == ["keep.mp4"]


@pytest.mark.parametrize("settings, message", [
    (dict(path="missing/x.mp4"), "does not exist"),
    (dict(path="clip.mov"), "cannot export 'clip.mov'"),
    (dict(path="x.mp4", size=(161, 120)), "even width and height"),
    (dict(path="x.mp4", size=(8, 120)), "between 16 and 8192"),
    (dict(path="x.mp4", fps=0), "frame rate"),
    (dict(path="x.mp4", fps=float("nan")), "frame rate"),
    (dict(path="x.mp4", start_s=1.0, end_s=1.0), "must be after the start"),
    (dict(path="x.mp4", end_s=0.01), "shorter than one frame"),
    (dict(path="x.gif", mode="toon"), "display mode"),
    (dict(path="x.gif", view="top"), "view"),
    (dict(path="x.gif", quality=0), "quality"),
    (dict(path="x.mp4", audio_path="nothing.wav"), "audio file"),
    (dict(path="x.txt/frames_%04d.jpg"), "must be PNG"),
])
def test_bad_settings_are_explained(tmp_path, face, settings, message):
    settings = dict(settings)
    settings["path"] = tmp_path / settings["path"]
    if "audio_path" in settings:
        settings["audio_path"] = tmp_path / settings["audio_path"]
    settings.setdefault("end_s", 1.0)
    settings.setdefault("size", SMALL)
    with pytest.raises(ExportError, match=message):
        export(face, lambda t: face.vertices, ExportSettings(**settings))


def test_unwritable_places_are_explained(tmp_path, face, monkeypatch):
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a folder")
    with pytest.raises(ExportError, match="is a file, not a folder"):
        export(face, lambda t: face.vertices, ExportSettings(blocker / "x.mp4", end_s=1, size=SMALL))
    with pytest.raises(ExportError, match="is a folder"):
        export(face, lambda t: face.vertices, ExportSettings(tmp_path, end_s=1, size=SMALL, format="mp4"))

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(ex.tempfile, "mkstemp", refuse)
    with pytest.raises(ExportError, match="not allowed to write"):
        export(face, lambda t: face.vertices, ExportSettings(tmp_path / "x.mp4", end_s=1, size=SMALL))


def test_wrong_vertices_are_explained(tmp_path, face):
    with pytest.raises(ExportError, match=r"shape \(3, 3\)"):
        export(face, lambda t: np.zeros((3, 3)), ExportSettings(tmp_path / "x.gif", end_s=1, size=SMALL))
    bad = face.vertices.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ExportError, match="non-finite"):
        export(face, lambda t: bad, ExportSettings(tmp_path / "x.png", size=SMALL))
    assert leftovers(tmp_path) == []


def test_encoder_failure_reports_its_messages(tmp_path, face, monkeypatch):
    fake = tmp_path / "fake-ffmpeg"
    fake.write_text("#!/bin/sh\ncat > /dev/null\necho 'av_interleaved_write_frame(): No space left on device' >&2\n"
                    "exit 1\n")
    fake.chmod(0o755)
    monkeypatch.setattr(export_sinks, "ffmpeg_exe", lambda: str(fake))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    with pytest.raises(ExportError, match="disk is full") as info:
        export(face, opening_mouth(face), ExportSettings(out_dir / "x.mp4", end_s=0.5, size=SMALL, fps=10))
    assert "No space left on device" in str(info.value)
    assert leftovers(out_dir) == []


def test_missing_encoder_is_explained(tmp_path, face, monkeypatch):
    def missing():
        raise RuntimeError("No ffmpeg exe could be found")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", missing)
    with pytest.raises(ExportError, match="ffmpeg.*not found"):
        export(face, opening_mouth(face), ExportSettings(tmp_path / "x.mp4", end_s=0.5, size=SMALL))
    assert leftovers(tmp_path) == []


# ------------------------------------------------------------------ child process
def test_subprocess_export_of_the_default_face(tmp_path):
    from core.default_face import load_default_face

    face = load_default_face()
    source = opening_mouth(face, 10.0)
    seen = []
    out = tmp_path / "default.mp4"
    result = export_in_subprocess(face, source, ExportSettings(out, end_s=0.4, size=(192, 144), fps=10),
                                  progress=lambda d, n: seen.append((d, n)))
    assert seen[-1] == (4, 4) and result.frames == 4 and result.render_seconds > 0
    assert imageio_ffmpeg.count_frames_and_secs(str(out))[0] == 4
    first = decode_frame(out, 0, tmp_path)
    assert first.shape == (144, 192, 3) and image_variance(first) > 100
    # the face fills the middle: the centre differs from the background corners
    corner = first[:8, :8].reshape(-1, 3).mean(axis=0)
    centre = first[54:90, 76:116].reshape(-1, 3).mean(axis=0)
    assert np.abs(centre - corner).sum() > 60


def test_subprocess_reports_the_encoders_error(tmp_path, face):
    bogus = tmp_path / "voice.wav"
    bogus.write_text("this is not a sound file")
    out = tmp_path / "voiced.mp4"
    with pytest.raises(ExportError, match="sound file 'voice.wav' could not be read") as info:
        export_in_subprocess(face, opening_mouth(face), ExportSettings(out, end_s=1.0, size=SMALL, fps=10,
                                                                        audio_path=bogus))
    assert "Invalid data" in str(info.value)  # ffmpeg's own words about the bad input
    assert leftovers(tmp_path) == ["voice.wav"]


# ------------------------------------------------------------------ parallel render processes
def render_workers() -> list[int]:
    """Pids of this process's live render workers (python -m app.export_workers)."""
    import os

    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if b"app.export_workers" in cmdline and int(stat[1]) == os.getpid() and stat[0] not in ("Z", "X"):
            pids.append(int(entry.name))
    return pids


def read_png(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def test_parallel_workers_render_the_same_frames(tmp_path, face):
    """Each frame is rendered by a free worker with the serial path's renderer: the same pixels, in order."""
    source = opening_mouth(face, 60.0)
    one = export(face, source, ExportSettings(tmp_path / "one", end_s=0.7, size=SMALL, fps=10, workers=1))
    two = export(face, source, ExportSettings(tmp_path / "two", end_s=0.7, size=SMALL, fps=10, workers=2))
    assert (one.workers, two.workers) == (1, 2) and one.frames == two.frames == 7
    assert [p.name for p in one.files] == [p.name for p in two.files]
    for a, b in zip(one.files, two.files):
        assert np.abs(read_png(a) - read_png(b)).max() <= 1, a.name
    # the frames do move (so the order is checked too), and nothing temporary is left
    assert image_difference(read_png(one.files[0]), read_png(one.files[-1])) > 2
    assert leftovers(tmp_path) == ["one", "two"] and not render_workers()
    # the window's path: the child process hands the frames to its own workers
    three = export_in_subprocess(face, source, ExportSettings(tmp_path / "three", end_s=0.7, size=SMALL, fps=10,
                                                              workers=3))
    assert three.workers == 3
    for a, b in zip(one.files, three.files):
        assert np.abs(read_png(a) - read_png(b)).max() <= 1, a.name


def test_parallel_mp4_matches_the_serial_one(tmp_path, face):
    source = opening_mouth(face)
    serial = export(face, source, ExportSettings(tmp_path / "one.mp4", end_s=1.0, size=SMALL, fps=10, workers=1))
    parallel = export(face, source, ExportSettings(tmp_path / "two.mp4", end_s=1.0, size=SMALL, fps=10,
                                                   workers=2))
    assert imageio_ffmpeg.count_frames_and_secs(str(parallel.path))[0] == 10
    for k in (0, 4, 9):
        a, b = decode_frame(serial.path, k, tmp_path), decode_frame(parallel.path, k, tmp_path)
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 2, k
    assert "2 workers" in parallel.speed() and parallel.frames_per_second > 0


def test_default_worker_count_follows_cores_and_length(monkeypatch):
    from app import export_plan

    monkeypatch.setattr(export_plan, "default_workers", lambda: 4)
    plan = export_plan.planned_workers
    assert plan(ExportSettings("x.mp4"), 300) == 4             # one per core
    assert plan(ExportSettings("x.mp4"), 50) == 2              # short: at least 24 frames each
    assert plan(ExportSettings("x.mp4"), 10) == 1
    assert plan(ExportSettings("x.png"), 1) == 1               # a still
    assert plan(ExportSettings("x.mp4", workers=3), 10) == 3   # asked for: as asked
    assert plan(ExportSettings("x.mp4", workers=8), 5) == 5    # never more than the frames
    assert 1 <= export_plan.default_workers() <= export_plan.DEFAULT_MAX_WORKERS
    monkeypatch.undo()
    monkeypatch.setattr(export_plan, "_available_memory", lambda: 2 * export_plan.WORKER_MEMORY_BYTES + 1)
    assert export_plan.default_workers() <= 2          # no more workers than the memory holds
    monkeypatch.setattr(export_plan, "_available_memory", lambda: 0)
    assert export_plan.default_workers() == 1
    with pytest.raises(ExportError, match="render workers"):
        export_frame_times(ExportSettings("x.mp4", end_s=1, workers=0))


def test_parallel_cancel_is_prompt_and_leaves_nothing(tmp_path, face):
    import time

    out = tmp_path / "cancelled.mp4"
    done, asked = [], []

    def cancelled():
        if len(done) >= 3 and not asked:
            asked.append(time.perf_counter())
        return bool(asked)

    with pytest.raises(ExportCancelled):
        export(face, opening_mouth(face), ExportSettings(out, end_s=60.0, size=SMALL, fps=10, workers=2),
               progress=lambda d, n: done.append(d), cancelled=cancelled)
    assert time.perf_counter() - asked[0] < 3.0
    assert len(done) == 3 and leftovers(tmp_path) == [] and not render_workers()


def test_parallel_errors_become_one_message(tmp_path, face, monkeypatch):
    import os
    import signal

    # the frame source fails: its message, the old file kept, nothing else left
    out = tmp_path / "keep.mp4"
    out.write_bytes(b"old video")

    def broken(t):
        if t > 0.35:
            raise ExportError("no vertices here")
        return face.vertices

    with pytest.raises(ExportError, match="no vertices here"):
        export(face, broken, ExportSettings(out, end_s=2.0, size=SMALL, fps=10, workers=2))
    assert out.read_bytes() == b"old video" and leftovers(tmp_path) == ["keep.mp4"] and not render_workers()

    # a render process dies: one sentence saying so
    def kill_a_worker(done, total):
        if done == 2:
            os.kill(render_workers()[0], signal.SIGKILL)

    with pytest.raises(ExportError, match=r"render process of the export stopped unexpectedly \(killed by signal 9\)"):
        export(face, opening_mouth(face), ExportSettings(tmp_path / "x.mp4", end_s=30.0, size=SMALL, fps=10,
                                                         workers=2), progress=kill_a_worker)
    assert leftovers(tmp_path) == ["keep.mp4"] and not render_workers()

    # a render process cannot start its renderer: what it said, once
    monkeypatch.setattr(ex, "_save_face_npz", lambda face, path: Path(path).write_bytes(b"not a face"))
    with pytest.raises(ExportError) as info:
        export(face, opening_mouth(face), ExportSettings(tmp_path / "y.mp4", end_s=1.0, size=SMALL, fps=10,
                                                         workers=2))
    message = str(info.value)
    assert message.startswith("The export renderer failed: ") and message.count("The export renderer failed") == 1
    assert "Traceback" not in message
    assert leftovers(tmp_path) == ["keep.mp4"] and not render_workers()


# ------------------------------------------------------------------ leftovers of killed exports
def dead_pid() -> int:
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def test_sweep_removes_only_what_dead_exports_left(tmp_path, monkeypatch):
    import os
    import tempfile

    from app.export_sinks import owner_tag, sweep_stale

    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    out = tmp_path / "out"
    out.mkdir()
    dead, alive = owner_tag(dead_pid()), owner_tag(os.getpid())
    elsewhere = dead.split("-")[0] + "-othermachine"   # a dead pid here may be alive on another machine
    stale = [out / f".clip.mimica-{dead}-ab12cd34.part.mp4", out / f".mimica-export-{dead}-x1y2z3.part",
             temp / f"mimica-export-{dead}-q9w8e7r6", out / f".my.clip.mimica-{dead}-a_b.part.gif"]
    kept = [out / f".clip.mimica-{alive}-ab12cd34.part.mp4", out / f".mimica-export-{alive}-x1y2z3.part",
            temp / f"mimica-export-{alive}-q9w8e7r6", out / "clip.mp4", out / ".clip.part.mp4",
            temp / "mimica-export-notapid", out / f".clip.mimica-{elsewhere}-ab12cd34.part.mp4",
            temp / f"mimica-export-{elsewhere}-q9w8e7r6"]
    for path in stale + kept:
        if path.suffix in (".mp4", ".gif"):
            path.write_bytes(b"x")
        else:
            path.mkdir()
            (path / "face.npz").write_bytes(b"x")
    removed = sweep_stale([out])
    assert sorted(removed) == sorted(stale)
    assert all(p.exists() for p in kept) and not any(p.exists() for p in stale)


# ------------------------------------------------------------------ Qt job and dialog
def test_export_job_signals_finished_and_cancelled(qtbot, tmp_path, face):
    from app.export_dialog import ExportJob

    source = opening_mouth(face)
    job = ExportJob(face, source, ExportSettings(tmp_path / "job.gif", end_s=0.5, size=SMALL, fps=10))
    progress = []
    job.progress.connect(lambda d, n: progress.append((d, n)))
    with qtbot.waitSignal(job.finished, timeout=60000) as blocker:
        job.start()
    assert blocker.args[0].frames == 5 and progress[-1] == (5, 5)
    with Image.open(tmp_path / "job.gif") as gif:
        assert gif.n_frames == 5

    assert job.generation == 1 and not job.is_running and job.total_frames == 5

    slow = ExportJob(face, source, ExportSettings(tmp_path / "slow.mp4", end_s=60.0, size=SMALL, fps=10))
    cancelling = []
    slow.progress.connect(lambda d, n: (slow.cancel(), cancelling.append(slow.is_cancelling)) if d >= 2 else None)
    slow.finished.connect(lambda _r: pytest.fail("a cancelled export finished"))
    with qtbot.waitSignal(slow.cancelled, timeout=60000):
        slow.start()
    assert cancelling[:1] == [True] and not slow.is_running and not slow.is_cancelling
    assert slow.result is None and slow.error is None
    assert leftovers(tmp_path) == ["job.gif"]

    bad = ExportJob(face, source, ExportSettings(tmp_path / "x.mp4", end_s=1.0, size=(161, 120)))
    with qtbot.waitSignal(bad.failed, timeout=5000) as failed:
        bad.start()
    assert "even width and height" in failed.args[0]


def test_export_job_outcomes_through_the_shared_job_class(qtbot, tmp_path, face, monkeypatch, capsys):
    """The job's worker is an app.jobs job: a bug becomes a sentence (its traceback in the log), a
    cancel that comes as the file is committed reports the file, not a cancel."""
    import threading

    from app import export_job
    from app.export_dialog import ExportJob

    settings = ExportSettings(tmp_path / "fake.gif", end_s=0.3, size=SMALL, fps=10)
    committing, proceed = threading.Event(), threading.Event()

    def committed_anyway(face, source, settings, *, progress, cancelled):
        progress(3, 3)
        committing.set()
        proceed.wait(5)   # cancelled meanwhile, but the file is already there
        return "result"

    monkeypatch.setattr(export_job, "export_in_subprocess", committed_anyway)
    late = ExportJob(face, lambda t: face.vertices, settings, evaluate_in="worker")
    late.cancelled.connect(lambda: pytest.fail("the file was written: not a cancel"))
    with qtbot.waitSignal(late.finished, timeout=5000) as finished:
        late.start()
        assert committing.wait(5)
        late.cancel()
        proceed.set()
    assert finished.args == ["result"] and late.result == "result"

    def bug(face, source, settings, *, progress, cancelled):
        raise KeyError("frame")

    monkeypatch.setattr(export_job, "export_in_subprocess", bug)
    broken = ExportJob(face, lambda t: face.vertices, settings, evaluate_in="worker")
    with qtbot.waitSignal(broken.failed, timeout=5000) as failed:
        broken.start()
    assert failed.args[0] == "The export failed: KeyError: 'frame'"
    assert "Traceback" in capsys.readouterr().err
    qtbot.waitUntil(lambda: not export_job._RUNNING and not export_job._ENDING, timeout=5000)


def test_dialog_validates_and_builds_settings(qtbot, tmp_path):
    from app.export_dialog import ExportDialog

    camera = {"position": [0, 0, 900], "focal_point": [0, 0, 0], "view_up": [0, 1, 0], "view_angle": 30}
    dialog = ExportDialog(None, duration_s=4.0, fps=25, default_path=tmp_path / "take.mp4", has_audio=True,
                          camera=camera)
    qtbot.addWidget(dialog)
    assert dialog.format == "mp4" and dialog.fps == 25.0 and dialog.size == (1280, 720)
    dialog.set_size(321, 240)
    assert dialog.size_combo.currentData() is None  # custom
    dialog.accept()
    assert dialog.result() != dialog.DialogCode.Accepted and "even width" in dialog.error_label.text()
    dialog.set_size(640, 480)
    dialog.part_radio.setChecked(True)
    dialog.start_spin.setValue(1.0)
    dialog.end_spin.setValue(3.0)
    settings = dialog.settings(audio_path=tmp_path / "a.wav")
    assert (settings.start_s, settings.end_s, settings.size, settings.fps) == (1.0, 3.0, (640, 480), 25.0)
    assert settings.camera == camera and settings.audio_path == tmp_path / "a.wav"
    assert "50 frames" in dialog.summary_label.text()
    dialog.set_format("gif")
    assert dialog.path_edit.text() == str(tmp_path / "take.gif") and not dialog.audio_check.isEnabled()
    dialog.set_format("png-sequence")
    assert dialog.path_edit.text() == str(tmp_path / "take")
    dialog.set_format("jpg")
    assert dialog.time_spin.isVisibleTo(dialog) and not dialog.range_widget.isVisibleTo(dialog)
    assert dialog.settings().format == "jpg"
    dialog.set_format("mp4")
    assert dialog.path_edit.text() == str(tmp_path / "take.mp4")  # remembered per format


def test_run_export_dialog_from_the_window(qtbot, window, tmp_path, monkeypatch, error_boxes):
    from app import export_dialog, export_job
    from app.export_dialog import ExportDialog, run_export_dialog

    face = window.face
    source = opening_mouth(face)
    out = tmp_path / "exports"
    out.mkdir()

    def fill_in(dialog):
        dialog.path_edit.setText(str(out / "from_window.mp4"))
        dialog.set_size(160, 120)
        dialog.part_radio.setChecked(True)
        dialog.end_spin.setValue(0.5)
        dialog.fps_combo.setCurrentIndex(dialog.fps_combo.findData(24.0))
        assert dialog.view_combo.currentData() == "current"
        dialog.accept()
        return dialog.result()

    monkeypatch.setattr(ExportDialog, "exec", fill_in)
    job = run_export_dialog(window, face, source, duration_s=2.0, fps=30)
    with qtbot.waitSignal(job.finished, timeout=60000):
        pass
    assert imageio_ffmpeg.count_frames_and_secs(str(out / "from_window.mp4"))[0] == 12
    qtbot.waitUntil(lambda: "from_window.mp4" in window.statusBar().currentMessage(), timeout=5000)
    assert re.search(r"in \d+\.\d s \(\d+\.\d fps\)", window.statusBar().currentMessage())
    assert not error_boxes and not export_job._RUNNING

    def refuse(dialog):
        dialog.path_edit.setText(str(tmp_path / "nope" / "x.mp4"))
        dialog.accept()
        return dialog.result()

    monkeypatch.setattr(ExportDialog, "exec", refuse)
    assert run_export_dialog(window, face, source, duration_s=2.0, fps=30) is None

    # a failure after the dialog: the window's error box says what went wrong
    def broken(t):
        raise RuntimeError("rig exploded")

    monkeypatch.setattr(ExportDialog, "exec", fill_in)
    job = run_export_dialog(window, face, broken, duration_s=2.0, fps=30)
    with qtbot.waitSignal(job.failed, timeout=60000):
        pass
    qtbot.waitUntil(lambda: bool(error_boxes), timeout=5000)
    assert error_boxes[-1][0] == "Export failed" and "rig exploded" in error_boxes[-1][1]
    assert leftovers(out) == ["from_window.mp4"]  # the failed export left nothing, the good one stays


def test_dialog_defaults_to_where_the_animation_ends(qtbot, tmp_path):
    """An animation whose last key is at 2.3 s on a 10 s timeline: the range 0 – 2.3 s (the last frame
    included) is preselected; the whole timeline is one click away; no content end keeps 'whole'."""
    from app.export_dialog import ExportDialog

    dialog = ExportDialog(None, duration_s=10.0, fps=30, default_path=tmp_path / "take.mp4", content_end_s=2.3)
    qtbot.addWidget(dialog)
    assert dialog.part_radio.isChecked()
    start, end = dialog.range_s()
    assert start == 0.0 and end == pytest.approx(2.3 + 1 / 30, abs=1e-3)   # the box shows ms
    dialog.whole_radio.setChecked(True)
    assert dialog.range_s() == (0.0, 10.0)
    plain = ExportDialog(None, duration_s=10.0, fps=30, default_path=tmp_path / "take.mp4", content_end_s=None)
    qtbot.addWidget(plain)
    assert plain.whole_radio.isChecked() and plain.range_s() == (0.0, 10.0)
    filled = ExportDialog(None, duration_s=10.0, fps=30, default_path=tmp_path / "take.mp4", content_end_s=10.0)
    qtbot.addWidget(filled)
    assert filled.whole_radio.isChecked()


def test_progress_text_says_the_speed_and_the_time_left():
    from app.export_dialog import FrameRate, progress_text

    now = [100.0]
    rate = FrameRate(clock=lambda: now[0])
    assert rate.add(1) is None                       # one sample: no speed yet
    now[0] += 0.25
    assert rate.add(3) is None                       # under half a second
    now[0] += 0.75
    assert rate.add(9) == pytest.approx(8.0)         # 8 frames in 1 s
    for _ in range(10):                              # only the last few seconds count
        now[0] += 1.0
        fps = rate.add(rate.samples[-1][1] + 2)
    assert fps == pytest.approx(2.0)
    assert progress_text(10, 300, None) == "Rendering frame 10 of 300…"
    assert progress_text(100, 300, 8.0) == "Rendering frame 100 of 300 — 8.0 fps, about 25 s left…"
    assert progress_text(100, 3000, 8.0).endswith("about 6 min left…")
    assert progress_text(300, 300, 8.0) == "Finishing the file…"


def test_strip_frames_match_whole_frames_and_the_workers(tmp_path, face):
    """An animation draws only a strip of the frame around the face (the rest is the background,
    drawn once): the whole frame's pixels but for rounding and the gradient's dither (one level);
    where the face does not fit the strip, the whole frame is drawn. The strip's place depends on
    the frame only, so parallel workers give the serial export's pixels."""
    source = opening_mouth(face, 60.0)
    settings = ExportSettings(tmp_path / "x.mp4", end_s=1.0, size=(480, 270))
    whole = ex._FaceRenderer(face, settings, settings.size, strip=False)
    strip = ex._FaceRenderer(face, settings, settings.size, strip=True)
    try:
        assert strip._strip_width < 480
        centre = face.vertices.mean(axis=0)
        wider = centre + 1.6 * (face.vertices - centre)   # wider than the strip
        aside = face.vertices + np.array([40.0, 0.0, 0.0])  # the strip follows the face
        for v, drawn in ((source(0.0), strip._strip_width), (source(0.6), strip._strip_width),
                         (aside, strip._strip_width), (wider, 480)):
            a, b = whole.render(v).astype(int), strip.render(v).astype(int)
            assert strip.plotter.render_window.GetSize()[0] == drawn
            diff = np.abs(a - b)
            assert diff.mean() < 0.5 and (diff.max(axis=2) > 2).mean() < 1e-3
    finally:
        whole.close()
        strip.close()
    one = export(face, source, ExportSettings(tmp_path / "one", end_s=0.5, size=(480, 270), fps=10, workers=1))
    two = export(face, source, ExportSettings(tmp_path / "two", end_s=0.5, size=(480, 270), fps=10, workers=2))
    for a, b in zip(one.files, two.files):
        assert np.array_equal(read_png(a), read_png(b)), a.name


# ------------------------------------------------------------------ level of detail
def test_pixels_per_triangle_known_answer():
    """A 10 mm right triangle through a projection of 100 mm across a 200x100 frame is 20 x 10 px,
    100 px^2; a triangle behind the camera does not count."""
    from app.export_lod import pixels_per_triangle

    # x_ndc = x / 50, y_ndc = y / 50, w = 1 - z / 100 (z = 200 is behind the camera).
    projection = np.array([[0.02, 0, 0, 0], [0, 0.02, 0, 0], [0, 0, 1, 0], [0, 0, -0.01, 1]])
    vertices = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 200], [50, 0, 200], [0, 50, 200]], float)
    triangles = np.array([[0, 1, 2], [3, 4, 5]])
    assert pixels_per_triangle(vertices, triangles, projection, (200, 100)) == pytest.approx(100.0)
    assert pixels_per_triangle(vertices, triangles[1:], projection, (200, 100)) == np.inf


def test_export_lod_gives_the_full_faces_picture_where_triangles_are_small(tmp_path):
    """The default face at 320x180: the export draws its decimated copy (its triangles are 0.13 px),
    and the frame is the full face's within PSNR 38 dB over the face's region; "full detail" draws
    the full face; a close camera (triangles of many pixels) draws the full face too. The render
    processes get the face's parts with it, so they find the same decimation."""
    import dataclasses

    from app.export_lod import LOD_MAX_PIXELS_PER_TRIANGLE, export_lod
    from core.default_face import load_default_face

    face = load_default_face()
    settings = ExportSettings(tmp_path / "x.mp4", end_s=1.0, size=(320, 180))
    full = ex._FaceRenderer(face, dataclasses.replace(settings, full_detail=True), settings.size)
    lod = ex._FaceRenderer(face, settings, settings.size)
    try:
        assert full.lod_triangles == 0 and 0 < lod.lod_triangles < len(face.triangles) / 2
        v = opening_mouth(face, 10.0)(0.5)
        a, b = full.render(v).astype(float), lod.render(v).astype(float)
        drawn = (np.abs(a - full._background).max(axis=2) > 0)
        rows, cols = np.flatnonzero(drawn.any(axis=1)), np.flatnonzero(drawn.any(axis=0))
        region = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        mse = np.mean((a[region] - b[region]) ** 2)
        assert 0 < mse and 10 * np.log10(255 ** 2 / mse) > 38.0
    finally:
        full.close()
        lod.close()
    centre = face.vertices.mean(axis=0)
    close_up = {"position": list(centre + [0, 0, 40]), "focal_point": list(centre), "view_up": [0, 1, 0],
                "view_angle": 30}
    near = ex._FaceRenderer(face, dataclasses.replace(settings, camera=close_up), settings.size, strip=False)
    try:
        assert near.pixels_per_triangle(face) > LOD_MAX_PIXELS_PER_TRIANGLE and near.lod_triangles == 0
    finally:
        near.close()
    copy = tmp_path / "face.npz"
    ex._save_face_npz(face, copy)
    loaded = ex._load_face_npz(copy)
    assert {k: list(v) for k, v in loaded.parts.items()} == {k: list(v) for k, v in face.parts.items()}
    assert np.array_equal(export_lod(loaded).triangles, export_lod(face).triangles)


def test_full_detail_from_the_dialog_and_the_command_line(qtbot, tmp_path):
    from app.cli import build_parser
    from app.export_dialog import ExportDialog

    dialog = ExportDialog(None, duration_s=4.0, fps=25, default_path=tmp_path / "take.mp4", has_audio=False)
    qtbot.addWidget(dialog)
    assert dialog.settings().full_detail is False and "decimated" in dialog.full_detail_check.toolTip()
    dialog.full_detail_check.setChecked(True)
    assert dialog.settings().full_detail is True
    assert ExportSettings.from_json(dialog.settings().to_json()).full_detail is True
    parser = build_parser()
    assert parser.parse_args(["export", "p.mimica", "-o", "x.mp4", "--full-detail"]).full_detail is True
    assert parser.parse_args(["export", "p.mimica", "-o", "x.mp4"]).full_detail is False
