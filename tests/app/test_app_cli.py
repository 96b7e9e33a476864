"""The ``mimica`` command line: help, render without a display, clean errors."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from app_helpers import image_variance, write_obj
from PIL import Image

from app import cli

ROOT = Path(__file__).resolve().parents[2]


def _mimica_cmd() -> list[str]:
    """The installed console script if present, else ``python -m app.cli``."""
    script = Path(sys.executable).parent / "mimica"
    return [str(script)] if script.exists() else [sys.executable, "-m", "app.cli"]


def run_mimica(*args: str, headless: bool = False, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    if headless:
        # Prove no display is needed: no X, no Wayland, Qt told to stay off screen.
        for var in ("DISPLAY", "WAYLAND_DISPLAY", "XAUTHORITY"):
            env.pop(var, None)
        env["QT_QPA_PLATFORM"] = "offscreen"
    return subprocess.run([*_mimica_cmd(), *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)


def _assert_clean_error(proc: subprocess.CompletedProcess, fragment: str) -> None:
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert any(fragment in ln for ln in lines), proc.stderr
    assert lines[-1].startswith("mimica: error:") or "error:" in lines[-1], proc.stderr


def test_help_lists_subcommands():
    proc = run_mimica("--help")
    assert proc.returncode == 0, proc.stderr
    assert "render" in proc.stdout and "gui" in proc.stdout
    proc = run_mimica("render", "--help")
    assert proc.returncode == 0
    for option in ("--out", "--view", "--size", "--mode", "--landmarks", "three-quarter", "wireframe"):
        assert option in proc.stdout


def test_render_default_face_without_display(tmp_path):
    out = tmp_path / "default.png"
    proc = run_mimica("render", "--out", str(out), "--size", "400x300", "--view", "three-quarter",
                      "--landmarks", headless=True)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    img = np.asarray(Image.open(out))
    assert img.shape[:2] == (300, 400)
    assert image_variance(img) > 100


def test_render_obj_file_without_display(tmp_path, synthetic_face):
    obj = write_obj(synthetic_face, tmp_path / "synthetic.obj")
    out = tmp_path / "wire.jpg"
    proc = run_mimica("render", str(obj), "-o", str(out), "--size", "320x240", "--mode", "wireframe",
                      "--view", "side", headless=True)
    assert proc.returncode == 0, proc.stderr
    assert image_variance(np.asarray(Image.open(out))) > 50


def test_render_bad_arguments_fail_cleanly(tmp_path):
    out = str(tmp_path / "x.png")
    _assert_clean_error(run_mimica("render", "--out", out, "--size", "big"), "size")
    _assert_clean_error(run_mimica("render", "--out", out, "--view", "top"), "invalid choice")
    _assert_clean_error(run_mimica("render", str(tmp_path / "missing.obj"), "--out", out), "no such file")
    _assert_clean_error(run_mimica("render", "--out", str(tmp_path / "x.gif")), ".png or .jpg")
    _assert_clean_error(run_mimica("render", "--out", str(tmp_path / "nodir" / "x.png")), "does not exist")
    _assert_clean_error(run_mimica("render"), "--out")
    _assert_clean_error(run_mimica("frobnicate"), "invalid choice")
    # out-of-range parameter options name the option and the range
    _assert_clean_error(run_mimica("render", "--out", out, "--jaw", "nan"), "--jaw")
    _assert_clean_error(run_mimica("render", "--out", out, "--caricature", "999"), "--caricature")


def test_render_unreadable_face_fails_cleanly(tmp_path):
    bad = tmp_path / "broken.obj"
    bad.write_text("this is not an obj file\nf 1 2 99\n")
    proc = run_mimica("render", str(bad), "--out", str(tmp_path / "x.png"), headless=True)
    _assert_clean_error(proc, "broken.obj")


def test_no_subcommand_starts_gui_on_default_face(monkeypatch):
    import app.main_window as mw

    calls = []
    monkeypatch.setattr(mw, "run_gui", lambda face=None: calls.append(face) or 0)
    assert cli.main([]) == 0
    assert calls == [None]


def test_gui_subcommand_opens_given_file(monkeypatch, tmp_path):
    import app.main_window as mw

    face_file = tmp_path / "f.obj"
    face_file.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    calls = []
    monkeypatch.setattr(mw, "run_gui", lambda face=None: calls.append(face) or 0)
    assert cli.main(["gui", str(face_file)]) == 0
    assert calls == [str(face_file)]


def test_gui_subcommand_missing_file(capsys):
    assert cli.main(["gui", "/nonexistent/face.obj"]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines() == ["mimica: error: no such file: /nonexistent/face.obj"]


@pytest.mark.parametrize("text,expected", [("1200x900", (1200, 900)), ("64X48", (64, 48))])
def test_parse_size(text, expected):
    assert cli._parse_size(text) == expected


def test_landmarks_then_register_a_scan_in_other_units(tmp_path, capsys):
    """A face stored in 2-mm units: 'landmarks' finds the points and names the factor, 'register
    --scale' builds the canonical face at human size."""
    from core.formats.mesh_io import load_face, save_face
    from core.registration.pipeline import default_model
    from core.registration.virtual_scanner import scan_face

    scan = scan_face(default_model(), n_target=20_000, rng=np.random.default_rng(1)).face
    scan_path = tmp_path / "half.ply"
    save_face(scan.scaled(0.5), scan_path)
    landmarks = tmp_path / "half.json"
    assert cli.main(["landmarks", str(scan_path), "--out", str(landmarks)]) == 0
    out = capsys.readouterr()
    assert "not millimetres" in out.err and "--scale 2" in out.out, out
    canonical = tmp_path / "half.obj"
    assert cli.main(["register", str(scan_path), "-l", str(landmarks), "--scale", "2", "-o", str(canonical)]) == 0
    printed = capsys.readouterr().out
    mean_mm = float(printed.split("distance to the scan mean ")[1].split(" mm")[0])
    assert 0.0 <= mean_mm < 0.5, printed          # the fit's closeness to the scan, per scan
    face = load_face(canonical)
    assert face.n_vertices == 4560
    # The scan itself animated (lips cut, mouth behind them): the jaw opens the scan's own mouth.
    scan_open, scan_rest = tmp_path / "scan_open.png", tmp_path / "scan_rest.png"
    for out, extra in ((scan_rest, []), (scan_open, ["--fap", "open_jaw=500"])):
        assert cli.main(["render", str(scan_path), "--register", str(landmarks), "--scale", "2", *extra,
                         "-o", str(out), "--size", "240x240"]) == 0
    assert "Animated at full resolution" in capsys.readouterr().err
    assert image_variance(np.asarray(Image.open(scan_open))) > 0
    from types import SimpleNamespace

    from app.cli.render import posed_vertices, registered_scan

    shown = registered_scan(load_face(scan_path), SimpleNamespace(face=str(scan_path), register=str(landmarks), scale=2.0))
    assert np.array_equal(shown.vertices[:scan.n_vertices], load_face(scan_path).scaled(2.0).vertices)
    moved = np.linalg.norm(posed_vertices(shown, {"fap:3": 500.0}) - shown.vertices, axis=1)
    lips = shown.landmark_positions(["2.2", "2.3"])
    above_nose = shown.vertices[:, 1] > shown.landmark_position("9.15")[1] + 5.0
    assert moved[above_nose].max() < 0.01 and moved[shown.parts["teeth_lower"]].min() > 1.0
    # (The lower lip's feature point: the vertex nearest to it may be the upper lip's side of the cut.)
    lower_lip = shown.landmark_positions(["2.3"], posed_vertices(shown, {"fap:3": 500.0})) - lips[1]
    assert np.linalg.norm(lower_lip) > 3.0, "the lower lip goes down with the jaw"
    assert cli.main(["render", "--register", str(landmarks), "-o", str(scan_open)]) == 1
    assert "--register needs a FACE" in capsys.readouterr().err
    assert cli.main(["render", str(scan_path), "--register", str(tmp_path / "none.json"), "-o", str(scan_open)]) == 1
    assert "--register" in capsys.readouterr().err
    # The OBJ has no landmarks, but Mimica recognises a canonical face and can animate it.
    joy = tmp_path / "joy.png"
    assert cli.main(["render", str(canonical), "--expression", "joy:80", "-o", str(joy), "--size", "200x150"]) == 0
    assert image_variance(np.asarray(Image.open(joy))) > 0
    # The built-in expression library moves onto a registered face; bad poses and percents say why.
    blend = tmp_path / "blend.png"
    assert cli.main(["render", str(canonical), "--blend", "joy:80", "-o", str(blend), "--size", "200x150"]) == 0
    assert image_variance(np.asarray(Image.open(blend))) > 0
    capsys.readouterr()
    assert cli.main(["render", str(canonical), "--blend", "grin:80", "-o", str(blend)]) == 1
    assert "no pose 'grin'; its poses are joy, sadness" in capsys.readouterr().err
    assert cli.main(["render", str(canonical), "--blend", "joy:lots", "-o", str(blend)]) == 1
    assert "the percent 'lots' is not a number" in capsys.readouterr().err
    width = np.ptp(face.vertices[:, 0])
    assert abs(width - np.ptp(scan.vertices[:, 0])) < 0.1 * width   # back at the face's size in mm
    with pytest.raises(SystemExit):
        cli.main(["register", str(scan_path), "-l", str(landmarks), "--scale", "-3", "-o", str(canonical)])
    assert "positive number" in capsys.readouterr().err
    # A separate texture image (here also flipped): the canonical face carries it through the scan's uv.
    image = tmp_path / "tex.png"
    Image.new("RGB", (8, 4), (0, 0, 255)).save(image)
    assert cli.main(["register", str(scan_path), "-l", str(landmarks), "--scale", "2", "--texture", str(image),
                     "--flip-texture", "-o", str(canonical)]) == 0
    colours = load_face(canonical).texture.reshape(-1, 3)
    assert (colours[:, 2] > 200).mean() > 0.9 and (colours[:, 0] < 50).mean() > 0.9
    (tmp_path / "bad.png").write_text("no image")
    assert cli.main(["landmarks", str(scan_path), "--texture", str(tmp_path / "bad.png"), "-o", str(landmarks)]) == 1
    assert "not an image" in capsys.readouterr().err


def test_prepare_fills_the_cache_the_window_reads(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("MIMICA_CACHE_DIR", str(cache))
    first = run_mimica("prepare", headless=True)
    assert first.returncode == 0, first.stderr
    assert "ready to animate" in first.stdout
    assert len(list((cache / "fap").iterdir())) == 1 and len(list((cache / "preview").iterdir())) == 1
    from app.document import build_rig
    from core.cache import DiskCache
    from core.default_face import load_default_face

    reader = DiskCache(cache)
    rig, message = build_rig(load_default_face(), reader)
    assert rig is not None and message == "" and reader.notes == []
    missing = run_mimica("prepare", str(tmp_path / "nope.obj"), headless=True)
    _assert_clean_error(missing, "no such file")


def test_a_texture_image_is_turned_upright_from_the_scan_itself(tmp_path, capsys):
    import argparse

    from app.cli.common import with_texture
    from app_helpers import make_synthetic_face
    from core.face import Face

    face = make_synthetic_face()
    down = Face(face.vertices, face.triangles, uv=face.uv * [1, -1] + [0, 1])
    image = np.zeros((8, 4, 3), np.uint8)
    image[:4] = (255, 0, 0)   # red top half, as drawn
    Image.fromarray(image).save(tmp_path / "tex.png")
    args = argparse.Namespace(texture=str(tmp_path / "tex.png"), flip_texture=False)
    upright = with_texture(down, args)
    assert (upright.texture[4:, :, 0] == 255).all() and "turned upside down" in capsys.readouterr().err
    assert (with_texture(face, args).texture[:4, :, 0] == 255).all(), "uv counted from the bottom: as drawn"
    args.flip_texture = True
    assert (with_texture(down, args).texture[:4, :, 0] == 255).all(), "--flip-texture overrides"


# ---------------------------------------------------------------- export: workers, speed, signals, leftovers
def _worktree_mimica(*args: str, tmpdir: Path) -> subprocess.Popen:
    """``python -m app.cli ARGS`` of this checkout, headless, with its own temporary folder."""
    env = dict(os.environ)
    for var in ("DISPLAY", "WAYLAND_DISPLAY", "XAUTHORITY"):
        env.pop(var, None)
    env.update(QT_QPA_PLATFORM="offscreen", TMPDIR=str(tmpdir), PYTHONUNBUFFERED="1",
               PYTHONPATH=str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else ""))
    return subprocess.Popen([sys.executable, "-m", "app.cli", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _jaw_project(path: Path, seconds: float) -> Path:
    """A project on the default face: the jaw opens over ``seconds``."""
    from core.formats.project import Project, save_project
    from core.timeline import Timeline

    timeline = Timeline(seconds, 30)
    timeline.add_keys({"fap:3": [(0.0, 0.0, "linear"), (seconds, 400.0, "linear")]})
    return save_project(path, Project(timeline=timeline))


def _export_leftovers(out_dir: Path, tmpdir: Path, pid: int) -> list[str]:
    names = [p.name for p in out_dir.iterdir() if f"mimica-{pid}-" in p.name or f"mimica-export-{pid}-" in p.name]
    return sorted(names + [p.name for p in tmpdir.iterdir() if p.name.startswith(f"mimica-export-{pid}-")])


def _processes_mentioning(*fragments: str) -> list[int]:
    """Live processes whose command line mentions any of ``fragments`` (render workers, ffmpeg)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state not in ("Z", "X") and any(f in cmdline for f in fragments):
            found.append(int(entry.name))
    return found


def _wait_until(condition, timeout: float, what: str) -> None:
    import time

    end = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.1)


def _start_export_and_wait_for_frames(tmp_path: Path, seconds: float = 60.0) -> tuple[subprocess.Popen, Path, Path]:
    """A ``mimica export --workers 2`` under way: its staging file exists and frames are coming."""
    import threading

    out_dir, tmpdir = tmp_path / "out", tmp_path / "tmp"
    out_dir.mkdir()
    tmpdir.mkdir()
    project = _jaw_project(tmp_path / "jaw.mimica", seconds)
    proc = _worktree_mimica("export", str(project), "--out", str(out_dir / "jaw.mp4"), "--size", "160x120",
                            "--workers", "2", tmpdir=tmpdir)
    err: list[str] = []
    threading.Thread(target=lambda: err.extend(iter(lambda: proc.stderr.read(1), "")), daemon=True).start()
    try:
        _wait_until(lambda: "rendering frame" in "".join(err) or proc.poll() is not None, 240, "the first frames")
    except AssertionError:
        proc.kill()
        raise
    assert proc.poll() is None, "".join(err)
    proc.captured_stderr = err
    return proc, out_dir, tmpdir


def test_export_with_workers_prints_its_speed(tmp_path):
    project = _jaw_project(tmp_path / "jaw.mimica", 2.0)
    out = tmp_path / "jaw.mp4"
    proc = _worktree_mimica("export", str(project), "--out", str(out), "--size", "160x120", "--workers", "2",
                            tmpdir=tmp_path)
    stdout, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    last = stdout.strip().splitlines()[-1]
    assert re.fullmatch(r"exported 60 frames in \d+\.\d s \(\d+\.\d fps, 2 workers\)", last), stdout
    assert out.is_file() and sorted(p.name for p in tmp_path.iterdir()) == ["jaw.mimica", "jaw.mp4"]
    bad = _worktree_mimica("export", str(project), "--out", str(out), "--workers", "0", tmpdir=tmp_path)
    _, stderr = bad.communicate(timeout=60)
    assert bad.returncode == 2 and "--workers must be between 1 and" in stderr and "Traceback" not in stderr


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_export_stopped_by_a_signal_leaves_nothing(tmp_path, signame):
    """SIGTERM/SIGHUP are handled like Ctrl-C: the staging file, the speech/work folders and the render
    processes are gone when the command returns."""
    import signal

    proc, out_dir, tmpdir = _start_export_and_wait_for_frames(tmp_path)
    proc.send_signal(getattr(signal, signame))
    proc.wait(timeout=30)
    stderr = "".join(proc.captured_stderr)
    assert proc.returncode == 130, stderr
    assert "mimica: interrupted" in stderr and "Traceback" not in stderr
    assert sorted(p.name for p in out_dir.iterdir()) == [] and list(tmpdir.iterdir()) == []
    _wait_until(lambda: not _processes_mentioning(str(tmpdir), str(out_dir)), 10, "the render processes to end")


def test_next_export_sweeps_what_a_killed_one_left(tmp_path, monkeypatch):
    """SIGKILL leaves the staging file and the work folders (named with the dead process's id); the next
    export removes them, and only them."""
    import tempfile

    from app_helpers import make_synthetic_face

    from app.export import ExportSettings, export

    proc, out_dir, tmpdir = _start_export_and_wait_for_frames(tmp_path)
    proc.kill()
    proc.wait(timeout=30)
    # its render processes and encoder see their input end and stop by themselves
    _wait_until(lambda: not _processes_mentioning(str(tmpdir), str(out_dir)), 30, "the orphans to end")
    left = _export_leftovers(out_dir, tmpdir, proc.pid)
    assert any(name.startswith(".jaw.mimica-") and name.endswith(".part.mp4") for name in left), left
    assert sum(name.startswith(f"mimica-export-{proc.pid}-") for name in left) >= 2, left  # speech + work
    from app.export_sinks import owner_tag

    other = out_dir / f".other.mimica-{owner_tag()}-abcd1234.part.mp4"   # a live export's: kept
    other.write_bytes(b"x")

    monkeypatch.setattr(tempfile, "tempdir", str(tmpdir))
    face = make_synthetic_face(32, 40)
    result = export(face, lambda t: face.vertices, ExportSettings(out_dir / "next.gif", end_s=0.2, size=(64, 48),
                                                                  fps=10))
    assert result.path.is_file()
    assert _export_leftovers(out_dir, tmpdir, proc.pid) == []
    assert sorted(p.name for p in out_dir.iterdir()) == [other.name, "next.gif"]
    assert list(tmpdir.iterdir()) == []


def test_the_next_start_sweeps_what_a_killed_export_left(tmp_path, monkeypatch):
    """kill -9 of an export and of its render processes and encoder: the next start of ``mimica`` (any
    command, here one that fails at once) removes the staging file beside the target and the work
    folders in the temporary folder, without exporting again."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    proc, out_dir, tmpdir = _start_export_and_wait_for_frames(tmp_path)
    children = _processes_mentioning(str(tmpdir), str(out_dir))
    for pid in [proc.pid, *children]:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    proc.wait(timeout=30)
    _wait_until(lambda: not _processes_mentioning(str(tmpdir), str(out_dir)), 30, "the killed processes to end")
    left = _export_leftovers(out_dir, tmpdir, proc.pid)
    assert any(name.endswith(".part.mp4") for name in left) and any(n.startswith("mimica-export-") for n in left)

    other = _worktree_mimica("export", str(tmp_path / "missing.mimica"), "--out", str(tmp_path / "x.fap"),
                             tmpdir=tmpdir)
    _, stderr = other.communicate(timeout=120)
    assert other.returncode != 0 and "Traceback" not in stderr
    assert _export_leftovers(out_dir, tmpdir, proc.pid) == []
    assert list(out_dir.iterdir()) == [] and list(tmpdir.iterdir()) == []
    assert list((tmp_path / "state" / "mimica" / "exports").iterdir()) == [], "the dead export's note goes too"


@pytest.mark.parametrize("fps", ["0", "-5", "nan", "inf"])
@pytest.mark.parametrize("command", [["export", "p.mimica", "--out", "o.fap"], ["export", "p.mimica", "--out", "o.mp4"],
                                     ["lipsync", "hello", "--out", "l.mimica"], ["demo", "--out", "d.mp4"]])
def test_every_fps_option_refuses_nonsense_with_a_message(tmp_path, capsys, monkeypatch, command, fps):
    """``--fps 0`` is not "not given", and -5, nan and inf never reach a writer (issue 19), on every
    command that takes --fps: a one-line message naming the option, no traceback."""
    monkeypatch.chdir(tmp_path)
    try:
        status = cli.main([*command, "--fps", fps])
    except SystemExit as exc:   # argparse: usage and one error line
        status = exc.code
    err = capsys.readouterr().err
    assert status in (1, 2) and "--fps" in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []
