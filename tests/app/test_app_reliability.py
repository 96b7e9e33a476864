"""Issue 19 in the window: recovery never deletes work (the autosave goes only once the recovered
project is on screen and written again), autosave serialises off the GUI thread, imports keep the
24 h limit and a hostile animation file is a message."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest
from PySide6.QtWidgets import QMessageBox

from app.timeline_dock import TimelineDock
from core.formats import project as cp
from core.timeline import Timeline, Track


@pytest.fixture
def answers(monkeypatch):
    calls = []

    def question(parent, title, text, *args, **kwargs):
        calls.append((title, text))
        return QMessageBox.StandardButton.Yes

    monkeypatch.setattr(QMessageBox, "question", question)
    return calls


def _window(qtbot, settings, tmp_path):
    from app_helpers import make_synthetic_face

    from app.main_window import MainWindow

    w = MainWindow(make_synthetic_face(name="first"), settings=settings, load_default=False, tools=False)
    qtbot.addWidget(w)
    ctl = TimelineDock(w.document, w, state_dir=tmp_path / "state", check_recovery=False).controller
    return w, ctl


def _crashed_autosave(state_dir, face_name="second"):
    """An untitled autosave left by a Mimica process that is gone, for a face that is not shown."""
    from app_helpers import make_synthetic_face

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    state_dir.mkdir(parents=True, exist_ok=True)
    crashed = state_dir / f"untitled-{int(dead.stdout)}-1.mimica.autosave"
    face = make_synthetic_face(20, 30, name=face_name)
    tl = Timeline(30.0, 25)
    tl.replace_tracks({"fap:3": Track("fap:3", [(float(k) / 10, float(k % 500)) for k in range(300)])})
    cp.save_project(crashed, cp.Project.from_state(face, cp.embed_face(face, crashed), None, tl))
    return crashed, tl.tracks["fap:3"]


def test_recovery_keeps_the_autosave_until_the_recovered_project_is_saved_again(qtbot, settings, tmp_path,
                                                                              answers, error_boxes):
    """A kill -9 at any moment of a recovery loses nothing: at every event-loop pass, the crashed
    autosave exists or this session's autosave holds the recovered keys."""
    w, ctl = _window(qtbot, settings, tmp_path)
    crashed, track = _crashed_autosave(ctl.project.state_dir)
    own = ctl.project.autosave_path()
    opened = []
    ctl.project.project_opened.connect(opened.append)
    assert ctl.project.check_startup_recovery()
    states = []
    deadline = time.monotonic() + 30
    while not opened and time.monotonic() < deadline:
        has_own = own.is_file() and cp.load_project(own).timeline.tracks.get("fap:3") == track
        states.append((crashed.is_file(), has_own))
        qtbot.wait(5)
    assert opened, "the recovered project did not open"
    assert states and states[0][0], "the autosave was deleted before its face was even loaded"
    assert all(c or o for c, o in states), states
    assert w.face.n_vertices == 20 * 30 and ctl.timeline.track("fap:3") == track
    assert own.is_file() and cp.load_project(own).timeline.track("fap:3") == track
    assert not crashed.exists(), "recovered and autosaved again: the old autosave is gone"
    assert not error_boxes


def test_a_recovery_whose_face_fails_keeps_its_autosave(qtbot, settings, tmp_path, answers, error_boxes):
    w, ctl = _window(qtbot, settings, tmp_path)
    crashed, _track = _crashed_autosave(ctl.project.state_dir)
    cp.load_project(crashed).face.path.write_bytes(b"ply\nformat ascii 1.0\nbroken")
    assert ctl.project.check_startup_recovery()
    qtbot.waitUntil(lambda: bool(error_boxes), timeout=20000)
    assert crashed.is_file(), "a recovery that failed must keep the work"
    assert w.face.metadata.name == "first"


def test_autosave_serialises_off_the_gui_thread(qtbot, settings, tmp_path, monkeypatch):
    w, ctl = _window(qtbot, settings, tmp_path)
    ctl.push(lambda: ctl.timeline.replace_tracks({"fap:3": Track("fap:3", [(0.0, 0.0), (1.0, 500.0)])}))
    threads = []
    real = cp.write_autosave

    def slow_write(*args, **kwargs):
        threads.append(threading.current_thread())
        time.sleep(0.5)
        return real(*args, **kwargs)

    monkeypatch.setattr(cp, "write_autosave", slow_write)
    start = time.perf_counter()
    assert ctl.project.autosave_in_background()
    assert time.perf_counter() - start < 0.3, "the GUI thread waited for the autosave"
    assert not ctl.project.autosave_in_background(), "nothing changed since: no second write"
    # an edit while the worker writes does not reach the file being written (a copy was captured)
    ctl.push(lambda: ctl.timeline.replace_tracks({"fap:4": Track("fap:4", [(0.0, 10.0)])}))
    ctl.project.wait_for_autosave()
    assert threads and threads[0] is not threading.main_thread()
    saved = cp.load_project(ctl.project.autosave_path())
    assert list(saved.timeline.tracks) == ["fap:3"]
    assert ctl.project.autosave_in_background()  # the later edit is autosaved by the next tick
    ctl.project.wait_for_autosave()
    assert set(cp.load_project(ctl.project.autosave_path()).timeline.tracks) == {"fap:3", "fap:4"}


def test_import_keeps_the_24_hour_limit(qtbot, settings, tmp_path):
    from core.timeline import MAX_DURATION_S

    w, ctl = _window(qtbot, settings, tmp_path)
    ctl.push(lambda: ctl.timeline.set_settings(duration=MAX_DURATION_S))
    path = tmp_path / "long.fap"
    mask = " ".join("1" if f == 3 else "0" for f in range(1, 69))
    path.write_text("2.1 x 25 500\n" + "".join(f"{mask}\n{k} {k}\n" for k in range(500)))
    messages = []
    ctl.message.connect(messages.append)
    ctl.seek(MAX_DURATION_S - 5.0)
    assert ctl.import_animation(path) is None
    assert ctl.timeline.duration <= MAX_DURATION_S and "fap:3" not in ctl.timeline.tracks
    assert messages and "24 h" in messages[-1]
    hostile = tmp_path / "hostile.fap"
    hostile.write_text(f"2.1 x 1e-7 1\n{mask}\n0 1\n")
    assert ctl.import_animation(hostile) is None and "hostile.fap" in messages[-1]


def test_a_derived_face_is_autosaved_as_shown_not_as_its_raw_file(qtbot, settings, tmp_path, answers, error_boxes):
    """A scan scaled (or retextured) in Mimica keeps its file's path; its autosave must hold the scaled
    face, or recovering reopens the raw mesh with every landmark relocated into one clump."""
    import numpy as np
    from app_helpers import make_synthetic_face

    from core.formats.mesh_io import load_face, save_face

    w, ctl = _window(qtbot, settings, tmp_path)
    scan = tmp_path / "scan.ply"
    save_face(make_synthetic_face(20, 30, name="scan"), scan)
    raw = load_face(scan)
    w.set_face(raw, path=str(scan))
    assert cp.load_project(ctl.project.autosave_now()).face.path == scan.resolve(), "as read: referenced"
    scaled = raw.scaled(10.0)
    w.set_face(scaled, path=str(scan))            # what Tools ▸ scale does: same path, new content
    ctl.push(lambda: ctl.timeline.replace_tracks({"fap:3": Track("fap:3", [(0.0, 0.0), (1.0, 500.0)])}))
    autosave = ctl.project.autosave_now()
    project = cp.load_project(autosave)
    assert project.face.path != scan.resolve()
    face = cp.open_face(project)
    assert np.allclose(face.vertices, scaled.vertices)
    # saving the project writes its own copy of the face beside it, not a reference into the state folder
    assert ctl.project.save_project(tmp_path / "take.mimica")
    saved = cp.load_project(tmp_path / "take.mimica")
    assert saved.face.path == (tmp_path / "take.face.ply").resolve() and not saved.notes
    assert np.allclose(cp.open_face(saved).vertices, scaled.vertices)
    # the built-in face stays a name
    from core.default_face import load_default_face

    w.set_face(load_default_face())
    assert cp.load_project(ctl.project.autosave_now()).face.builtin == "default_face"


def test_landmark_statuses_come_back_with_the_project(qtbot, settings, tmp_path, answers, error_boxes):
    """A scan session's checked landmarks: confirmed / edited statuses and confidences are saved in the
    project (and its autosave) and restored on opening."""
    from core.landmark_editing import LandmarkStatus

    w, ctl = _window(qtbot, settings, tmp_path)
    model = w.document.landmarks
    names = model.names[:3]
    assert len(names) == 3
    model.confirm(names[0])
    model.move(names[1], model.point(names[2]))
    path = tmp_path / "scan.mimica"
    assert ctl.project.save_project(path)
    saved = cp.load_project(path)
    assert saved.landmark_status[names[0]][0] == "confirmed" and saved.landmark_status[names[1]][0] == "edited"
    model.update_states({n: type(model.state(n))(model.point(n), LandmarkStatus.AUTO, None) for n in names})
    with qtbot.waitSignal(ctl.project.project_opened, timeout=20000):
        ctl.project.open_project(path, ask=False)
    model = w.document.landmarks
    assert model.status(names[0]) is LandmarkStatus.CONFIRMED and model.status(names[1]) is LandmarkStatus.EDITED
    assert model.status(names[2]) is LandmarkStatus.AUTO


def test_a_refused_import_is_shown_in_a_message_box(qtbot, settings, tmp_path, error_boxes):
    w, ctl = _window(qtbot, settings, tmp_path)
    bad = tmp_path / "deep.fap"
    bad.write_text("2.1 x 1e300 1\n")
    assert ctl.dock.import_file(bad) is None
    assert error_boxes and "deep.fap" in error_boxes[-1][0] and "frame rate" in error_boxes[-1][1]


def test_a_recovered_derived_face_shows_its_own_name_not_the_autosaves(qtbot, settings, tmp_path, answers,
                                                                     error_boxes):
    """A scan built in Mimica is autosaved as the project's own copy (<autosave>.face.ply); reopened
    from it, the face keeps its name (the PLY holds it) and the status bar shows that name."""
    from app_helpers import make_synthetic_face

    from core.formats.mesh_io import load_face, save_face

    w, _ctl = _window(qtbot, settings, tmp_path)
    face = make_synthetic_face(20, 30, name="LeePerrySmith")
    copy = tmp_path / "untitled-7-1.mimica.autosave.face.ply"
    save_face(face, copy)
    w.set_face(load_face(copy), path=str(copy))
    assert w.face.metadata.name == "LeePerrySmith"
    assert w.file_label.text() == "LeePerrySmith" and w.file_label.toolTip() == str(copy)
    plain = tmp_path / "anna.ply"
    save_face(face, plain)
    w.set_face(load_face(plain), path=str(plain))
    assert w.file_label.text() == "anna.ply"
