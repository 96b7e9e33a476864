"""Project files from the window: save -> open restores the animation exactly, bad files leave the open
project alone, the title tracks the modified state, autosave and crash recovery.

One window on the default face for the module (its FAP deformer takes seconds to build); every test
starts from an empty untitled project.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from PySide6.QtWidgets import QMessageBox

from app.timeline_dock import TimelineDock
from core.formats import project as cp


# ------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def shared(qapp, default_face, deformer, tmp_path_factory):
    from PySide6.QtCore import QSettings

    from app.main_window import MainWindow
    from core.rig import FaceRig

    folder = tmp_path_factory.mktemp("project_window")
    settings = QSettings(str(folder / "mimica-test.ini"), QSettings.Format.IniFormat)
    w = MainWindow(settings=settings, load_default=False, tools=False)
    w.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    w.show()
    controller = TimelineDock(w.document, w, check_recovery=False).controller  # autosaves beside the test settings
    yield w, controller
    w.close()
    w.deleteLater()


class Answers:
    """QMessageBox.question stand-in: answers from ``self.next`` (default Discard), records the questions."""

    def __init__(self):
        self.calls: list[tuple[str, str]] = []
        self.next = QMessageBox.StandardButton.Discard

    def __call__(self, parent, title, text, *args, **kwargs):
        self.calls.append((title, text))
        return self.next


@pytest.fixture
def answers(monkeypatch):
    a = Answers()
    monkeypatch.setattr(QMessageBox, "question", a)
    return a


@pytest.fixture
def win(qtbot, shared, error_boxes, answers):
    w, c = shared
    answers.next = QMessageBox.StandardButton.Discard
    c.project.new_project()  # modified -> asked (Discard) -> empty untitled project
    c.set_auto_key(False)
    c.dock.show_all_check.setChecked(False)
    c.dock.view.collapsed.clear()
    w.set_view_mode("textured")
    w.flush_updates()
    answers.calls.clear()
    error_boxes.clear()
    qtbot.waitExposed(w)
    assert not c.timeline.tracks and not w.rig.fap_values().any() and not c.project.is_modified
    return w


@pytest.fixture
def c(win, shared):
    return shared[1]


@pytest.fixture
def rig(win):
    return win.rig


def _animate(c, rig) -> None:
    """A little animation with FAP, expression and hand-set rig values."""
    rig.set_faps({3: 200.0, 4: -50.5})
    c.set_key(None, 0.0)
    rig.set_faps({3: 950.25, 4: 120.0, 19: 300.0})
    rig.set_expression("joy", 0.75)
    c.seek(1.5)
    c.set_key()
    c.set_selection({"fap:4": [0.0]})
    c.set_interpolation("step")
    c.seek(0.7)
    rig.set_fap(31, 77.0)  # a hand-set value on an untracked FAP


def _evaluate(c, times):
    return [c.timeline.evaluate(t) for t in times]


# ------------------------------------------------------------------ save / open
def test_save_then_open_restores_tracks_rig_and_view_exactly(qtbot, win, c, rig, tmp_path, answers, error_boxes):
    _animate(c, rig)
    c.loop = True
    c.dock.show_all_check.setChecked(True)
    win.set_view_mode("shaded")
    win.plotter.camera_position = [(30.0, 20.0, 400.0), (0.0, 10.0, 0.0), (0.0, 1.0, 0.0)]
    camera = [tuple(v) for v in win.plotter.camera_position]
    times = [0.0, 0.3, 0.7, 1.2, 1.5, 4.0]
    tracks = dict(c.timeline.tracks)
    values = _evaluate(c, times)
    fap_values = rig.fap_values()
    expressions = rig.expressions
    vertices = np.array(rig.vertices(), copy=True)
    assert c.project.is_modified and win.isWindowModified()

    path = tmp_path / "anim.mimica"
    assert c.project.save_project(path)
    assert not c.project.is_modified and not win.isWindowModified()
    assert win.windowTitle().startswith("anim[*]")
    doc = json.loads(path.read_text())
    assert doc["face"] == {"builtin": "default_face"} and doc["view"]["display_mode"] == "shaded"

    # wipe everything
    c.project.new_project()
    win.set_view_mode("textured")
    c.loop = False
    c.dock.show_all_check.setChecked(False)
    win.plotter.camera_position = [(0.0, 0.0, 500.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)]
    assert not c.timeline.tracks and not rig.fap_values().any()

    assert c.project.open_project(path)
    assert c.project.path == path and not c.project.is_modified
    assert dict(c.timeline.tracks) == tracks
    assert _evaluate(c, times) == values
    assert c.current_time == pytest.approx(0.7)
    np.testing.assert_array_equal(rig.fap_values(), fap_values)
    assert rig.expressions == expressions
    np.testing.assert_array_equal(rig.vertices(), vertices)
    assert win.view_mode == "shaded" and c.loop and c.dock.view.show_all
    np.testing.assert_allclose(np.array([tuple(v) for v in win.plotter.camera_position]), np.array(camera),
                               atol=1e-9)
    assert not error_boxes
    # opening did not put anything on the undo stack
    assert win.undo_stack.count() == 0
    # Edit after open -> modified again, '*' in the title
    c.set_key(["fap:3"], 2.0)
    assert win.isWindowModified() and "[*]" in win.windowTitle()


def test_new_and_open_ask_before_dropping_unsaved_changes(qtbot, win, c, rig, tmp_path, answers):
    rig.set_fap(3, 100.0)
    c.set_key(["fap:3"], 0.0)
    answers.next = QMessageBox.StandardButton.Cancel
    assert not c.project.new_project()
    assert "fap:3" in c.timeline.tracks and answers.calls and "Unsaved" in answers.calls[-1][0]
    answers.next = QMessageBox.StandardButton.Discard
    assert c.project.new_project()
    assert not c.timeline.tracks


def test_corrupt_or_newer_project_shows_the_message_and_keeps_the_open_project(
        qtbot, win, c, rig, tmp_path, error_boxes):
    _animate(c, rig)
    good = tmp_path / "good.mimica"
    assert c.project.save_project(good)
    tracks = dict(c.timeline.tracks)
    values = rig.fap_values()
    title = win.windowTitle()

    broken = tmp_path / "broken.mimica"
    broken.write_text('{"format": "mimica-project", "version": 1, "face": {"builtin": "default_face"}, ')
    assert not c.project.open_project(broken)
    assert len(error_boxes) == 1
    assert "broken.mimica" in error_boxes[0][0] and "damaged" in error_boxes[0][1]
    newer = tmp_path / "newer.mimica"
    newer.write_text(json.dumps({"format": "mimica-project", "version": 99}))
    assert not c.project.open_project(newer)
    assert len(error_boxes) == 2 and "newer Mimica" in error_boxes[1][1]
    bad_track = json.loads(good.read_text())
    bad_track["timeline"]["tracks"][0]["keys"][0][1] = 1e9  # beyond the FAP's range
    (tmp_path / "range.mimica").write_text(json.dumps(bad_track))
    assert not c.project.open_project(tmp_path / "range.mimica")
    assert len(error_boxes) == 3 and "timeline.tracks[0].keys" in error_boxes[2][1]

    assert c.project.path == good and dict(c.timeline.tracks) == tracks
    np.testing.assert_array_equal(rig.fap_values(), values)
    assert win.windowTitle() == title and not c.project.is_modified


def test_save_errors_are_reported(qtbot, win, c, rig, tmp_path, error_boxes):
    target = tmp_path / "no" / "such" / "dir" / "x.mimica"
    assert not c.project.save_project(target)
    assert len(error_boxes) == 1 and "x.mimica" in error_boxes[0][0]
    assert c.project.path is None


# ------------------------------------------------------------------ autosave / recovery
def _crash(c) -> None:
    """Forget the open project without the clean-up of New / close (what a crash leaves)."""
    from core.timeline import Timeline

    c.set_timeline(Timeline())
    c.project.path = None
    c.undo_stack.clear()
    c.project._mark_clean()


def test_autosave_is_offered_after_open_and_recovers(qtbot, win, c, rig, tmp_path, answers):
    path = tmp_path / "take.mimica"
    rig.set_fap(3, 100.0)
    c.set_key(["fap:3"], 0.0)
    assert c.project.save_project(path)
    assert c.project.autosave_if_needed() is None, "nothing to autosave when saved"
    rig.set_fap(3, 600.0)
    c.set_key(["fap:3"], 1.0)  # unsaved work
    autosave = c.project.autosave_if_needed()
    assert autosave == cp.autosave_path(path) and autosave.is_file()
    assert c.project.autosave_if_needed() is None, "unchanged since the last autosave"
    st = path.stat()
    recovered_track = c.timeline.track("fap:3")
    _crash(c)  # the next session starts from nothing; the autosave is newer than the project
    os.utime(autosave, ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))

    answers.next = QMessageBox.StandardButton.Yes
    c.project.open_project(path)
    assert answers.calls and "Recover" in answers.calls[-1][0] and "take.mimica" in answers.calls[-1][1]
    assert c.timeline.track("fap:3") == recovered_track
    assert c.project.path == path and c.project.is_modified and win.isWindowModified()
    # saving makes it the real file and removes the autosave
    assert c.project.save()
    assert not autosave.exists() and not c.project.is_modified

    # Discard deletes a newer autosave and keeps the file's content
    autosave.write_text(path.read_text())
    os.utime(autosave, ns=(st.st_atime_ns, path.stat().st_mtime_ns + 5_000_000_000))
    c.project.new_project()
    answers.next = QMessageBox.StandardButton.Discard
    c.project.open_project(path)
    assert not autosave.exists() and c.timeline.track("fap:3") == recovered_track


def test_startup_recovery_of_an_untitled_autosave_from_a_dead_process(qtbot, win, c, rig, answers, tmp_path):
    rig.set_fap(3, 250.0)
    c.set_key(["fap:3"], 0.5)
    own = c.project.autosave_now()
    assert own.parent == c.project.state_dir and own.name.startswith(f"untitled-{os.getpid()}-")
    assert c.project.startup_candidates() == [], "a running Mimica's autosave is not a crash"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    crashed = c.project.state_dir / f"untitled-{int(dead.stdout)}-1.mimica.autosave"
    crashed.write_bytes(own.read_bytes())
    own.unlink()
    tracks = dict(c.timeline.tracks)
    c.project.new_project()
    assert c.project.startup_candidates() == [crashed]
    answers.next = QMessageBox.StandardButton.Yes
    assert c.project.check_startup_recovery()
    assert dict(c.timeline.tracks) == tracks and c.project.path is None and c.project.is_modified
    assert not crashed.exists(), "recovered: its content lives on in this session"
    answers.next = QMessageBox.StandardButton.Discard
    assert not c.project.check_startup_recovery()


def test_closing_with_unsaved_work_autosaves_instead_of_blocking(qtbot, qapp, default_face, deformer, settings,
                                                                   tmp_path, answers, error_boxes):
    from app.main_window import MainWindow
    from core.rig import FaceRig

    w = MainWindow(settings=settings, load_default=False, tools=False)
    w.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    ctl = TimelineDock(w.document, w, state_dir=tmp_path / "state", check_recovery=False).controller
    w.rig.set_fap(3, 300.0)
    ctl.set_key(["fap:3"], 0.0)
    target = ctl.project.autosave_path()
    w.close()
    assert not answers.calls and target.is_file()
    assert cp.load_project(target).timeline.track("fap:3").values.tolist() == [300.0]
    w.deleteLater()


def test_closing_with_unsaved_changes_asks_save_discard_cancel(qtbot, settings, error_boxes, default_face, deformer,
                                                              tmp_path, monkeypatch):
    """As the window run by `mimica` does (ask_on_close): a modified project asks before closing;
    Cancel keeps the window and the work, Discard closes; an unmodified one closes without asking."""
    from PySide6.QtWidgets import QMessageBox

    from app.main_window import MainWindow
    from core.rig import FaceRig

    answers, asked = [QMessageBox.StandardButton.Cancel, QMessageBox.StandardButton.Discard], []

    def question(parent, title, text, *args, **kwargs):
        asked.append(text)
        return answers.pop(0)

    monkeypatch.setattr(QMessageBox, "question", question)
    w = MainWindow(settings=settings, load_default=False)
    qtbot.addWidget(w)
    w.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    w.show()
    project = w.document.project
    project.ask_on_close = True
    w.rig.set_values({"fap:3": 200.0})
    c = w.timeline
    c.set_key(["fap:3"])
    assert project.is_modified
    assert not w.close()                       # Cancel: still open, nothing lost
    assert w.isVisible() and "fap:3" in c.timeline.tracks and "before closing" in asked[0]
    assert w.close()                           # Discard
    assert len(asked) == 2
    clean = MainWindow(settings=settings, load_default=False)
    qtbot.addWidget(clean)
    clean.document.project.ask_on_close = True
    clean.show()
    assert clean.close() and len(asked) == 2   # nothing to save: no question


def test_link_left_right_is_saved_in_the_project(qtbot, win, c, rig, tmp_path, answers):
    dock = win.fap_dock
    dock.link_check.setChecked(True)
    path = tmp_path / "linked.mimica"
    assert c.project.save_project(path)
    import json

    assert json.loads(path.read_text(encoding="utf-8"))["view"]["link_left_right"]["faps"] is True
    dock.link_check.setChecked(False)
    assert c.project.open_project(path, ask=False)
    qtbot.waitUntil(lambda: dock.link_check.isChecked(), timeout=30_000)
    dock.link_check.setChecked(False)


def test_open_recent_lists_projects_and_opens_them(qtbot, win, c, rig, tmp_path, answers):
    path = tmp_path / "recent.mimica"
    rig.set_values({"fap:3": 120.0})
    c.set_key(["fap:3"])
    assert c.project.save_project(path)
    assert win.recent_files()[0] == str(path)
    c.project.new_project()
    assert "fap:3" not in c.timeline.tracks
    win.open_recent(str(path))
    qtbot.waitUntil(lambda: "fap:3" in c.timeline.tracks, timeout=30_000)
    assert c.project.path == path


def test_a_project_with_another_face_opens_it_in_the_background(qtbot, settings, tmp_path, answers, error_boxes,
                                                                 monkeypatch):
    """The project's face is not the one shown: it loads (and its rig is built) as a background job of
    app.jobs; a newer open supersedes an older one, and a face that cannot be read is a message."""
    from app_helpers import make_synthetic_face

    from app.main_window import MainWindow

    w = MainWindow(make_synthetic_face(name="first"), settings=settings, load_default=False, tools=False)
    qtbot.addWidget(w)
    ctl = TimelineDock(w.document, w, state_dir=tmp_path / "state", check_recovery=False).controller
    path = tmp_path / "first.mimica"
    assert ctl.project.save_project(path)   # the face exists only in memory: written beside the project
    assert (tmp_path / "first.face.ply").is_file()
    w.set_face(make_synthetic_face(30, 40, name="other"))
    with qtbot.waitSignal(ctl.project.project_opened, timeout=20000):
        assert not ctl.project.open_project(path, ask=False)   # False: still loading
    assert w.face.n_vertices == 48 * 64 and ctl.project.path == path and w.document.project_path == path
    assert not error_boxes

    # A newer open wins over one still loading.
    slow_then_fast = []
    real_open_face = cp.open_face

    def open_face(project, notes=None):
        slow_then_fast.append(project.face.path)
        if len(slow_then_fast) == 1:
            import time
            time.sleep(0.5)
        return real_open_face(project, notes)

    monkeypatch.setattr(cp, "open_face", open_face)
    w.set_face(make_synthetic_face(30, 40, name="other"))
    opened = []
    ctl.project.project_opened.connect(opened.append)
    second = tmp_path / "second.mimica"
    w2 = make_synthetic_face(20, 30, name="second")
    cp.save_project(second, cp.Project.from_state(w2, cp.embed_face(w2, second), None, ctl.timeline))
    ctl.project.open_project(path, ask=False)
    ctl.project.open_project(second, ask=False)
    qtbot.waitUntil(lambda: opened == [second], timeout=20000)
    qtbot.wait(800)
    assert opened == [second] and w.face.n_vertices == 20 * 30

    # The face file went away: the message names the project, the face shown stays.
    (tmp_path / "first.face.ply").unlink()
    ctl.project.open_project(path, ask=False)
    qtbot.waitUntil(lambda: bool(error_boxes), timeout=20000)
    assert "first.mimica" in error_boxes[-1][0] and w.face.n_vertices == 20 * 30
    w.close()


def test_a_face_outside_the_projects_folder_is_opened_only_when_the_user_agrees(qtbot, win, c, tmp_path, answers,
                                                                                 error_boxes, monkeypatch):
    """A project whose face file lies outside its folder: the window names the path and asks; No leaves
    the open project as it was, Yes opens it without a note repeating the path."""
    from core.formats.mesh_io import save_face
    from tests.core.conftest import make_grid_face

    faces, projects = tmp_path / "faces", tmp_path / "projects"
    faces.mkdir(), projects.mkdir()
    save_face(make_grid_face(), faces / "anna.ply")
    doc = {"format": cp.FORMAT_NAME, "version": cp.FORMAT_VERSION, "face": {"path": "../faces/anna.ply"},
           "landmarks": None, "rig": {"values": {}}, "timeline": {"duration": 10.0, "fps": 30, "tracks": []},
           "speech": [], "view": {}}
    (projects / "p.mimica").write_text(json.dumps(doc), encoding="utf-8")
    face_before = win.document.face
    infos = []
    monkeypatch.setattr(QMessageBox, "information", lambda *a, **k: infos.append(a[2]))
    answers.next = QMessageBox.StandardButton.No
    assert c.project.open_project(projects / "p.mimica", ask=False) is False
    assert len(answers.calls) == 1 and str((faces / "anna.ply").resolve()) in answers.calls[0][1]
    assert win.document.face is face_before and c.project.path is None
    answers.next = QMessageBox.StandardButton.Yes
    c.project.open_project(projects / "p.mimica", ask=False)
    qtbot.waitUntil(lambda: c.project.path == projects / "p.mimica", timeout=60_000)
    assert win.document.face is not face_before
    assert not any("outside the project's folder" in text for text in infos)
