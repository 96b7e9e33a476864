"""The ``mimica`` command line: help, render without a display, clean errors."""

from __future__ import annotations

import os
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
    face = load_face(canonical)
    assert face.n_vertices == 4560
    # The OBJ has no landmarks, but Mimica recognises a canonical face and can animate it.
    joy = tmp_path / "joy.png"
    assert cli.main(["render", str(canonical), "--expression", "joy:80", "-o", str(joy), "--size", "200x150"]) == 0
    assert image_variance(np.asarray(Image.open(joy))) > 0
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
