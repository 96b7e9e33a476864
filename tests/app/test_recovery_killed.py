"""Issue 19, "the kill -9 recovery test passes at every moment of a recovery": the real window is
started in a child process on a state folder holding a crashed session's autosave, answers "Recover",
and is killed with SIGKILL at chosen and at random moments of the recovery — after the autosave is
parsed, after this session's autosave is written (before the old one is removed), and anywhere in
between. After every kill, the state folder still holds an autosave that loads with every key and
its face, and the next start recovers it."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np

from core.formats import project as cp
from core.formats.mesh_io import load_face, save_face
from core.timeline import Timeline, Track

ROOT = Path(__file__).resolve().parents[2]
KEYS = 20_000

# The window as `mimica` starts it, with "Recover unsaved work?" answered Yes. It says "parsed" when
# it has read an autosave and "written" when it has written one, then waits there PAUSE seconds when
# told to (argv[2]), so a kill lands exactly between those steps and the next.
CHILD = textwrap.dedent("""
    import sys, time
    from PySide6.QtWidgets import QMessageBox
    QMessageBox.question = staticmethod(lambda *args, **kwargs: QMessageBox.StandardButton.Yes)
    from core.formats import project as cp
    pause_at = sys.argv[2]
    real_load, real_write = cp.load_project, cp.write_autosave
    def load_project(path, *args, **kwargs):
        project = real_load(path, *args, **kwargs)
        if str(path).endswith(".autosave"):
            print("parsed", flush=True)
            if pause_at == "parsed":
                time.sleep(5)
        return project
    def write_autosave(*args, **kwargs):
        written = real_write(*args, **kwargs)
        print("written", flush=True)
        if pause_at == "written":
            time.sleep(5)
        return written
    cp.load_project, cp.write_autosave = load_project, write_autosave
    from app.main_window import run_gui
    run_gui(sys.argv[1])
""")


def _dead_pid() -> int:
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                           check=True)
    return int(child.stdout)


def _crashed_session(tmp_path):
    """(state folder, the crashed autosave's track, its face's vertex count, the face the window opens)."""
    from app_helpers import make_synthetic_face

    state = tmp_path / "config" / "Mimica" / "autosave"   # the window's: beside its settings file
    state.mkdir(parents=True)
    crashed = state / f"untitled-{_dead_pid()}-1.mimica.autosave"
    face = make_synthetic_face(30, 40, name="recovered")
    times = np.arange(KEYS) / 60.0
    track = Track.from_arrays("fap:3", times, (np.arange(KEYS) % 400).astype(float), np.zeros(KEYS, int))
    timeline = Timeline(float(times[-1]) + 1.0, 60)
    timeline.replace_tracks({"fap:3": track})
    cp.save_project(crashed, cp.Project.from_state(face, cp.embed_face(face, crashed), None, timeline))
    shown = tmp_path / "shown.ply"
    save_face(make_synthetic_face(12, 16, name="shown"), shown)
    return state, track, face.n_vertices, shown


def _start(tmp_path, shown: Path, pause_at: str) -> subprocess.Popen:
    env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"), XDG_CONFIG_HOME=str(tmp_path / "config"),
               PYTHONPATH=str(ROOT))
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(shown), pause_at], cwd=ROOT, env=env,
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    child.said = queue.Queue()
    threading.Thread(target=lambda: [child.said.put(line.strip()) for line in child.stdout], daemon=True).start()
    return child


def _wait_for(child: subprocess.Popen, word: str, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if child.said.get(timeout=0.5) == word:
                return
        except queue.Empty:
            if child.poll() is not None:
                break
    raise AssertionError(f"the window never said {word!r}")


def _kill(child: subprocess.Popen) -> None:
    os.kill(child.pid, signal.SIGKILL)
    child.wait(20)


def _work_is_on_disk(state: Path, track: Track, n_vertices: int) -> list[str]:
    """The autosaves that hold the work (they load with every key and their face); AssertionError if none."""
    found, holding = [], []
    for autosave in sorted(state.glob("*.mimica.autosave")):
        project = cp.load_project(autosave)
        found.append(autosave.name)
        if project.timeline.tracks.get("fap:3") == track and load_face(project.face.path).n_vertices == n_vertices:
            holding.append(autosave.name)
    assert holding, f"the recovered work is lost: the state folder holds {found}"
    return holding


def test_a_recovery_killed_at_any_moment_loses_nothing(tmp_path):
    state, track, n_vertices, shown = _crashed_session(tmp_path)
    crashed = _work_is_on_disk(state, track, n_vertices)

    # Killed once the autosave is parsed, before it is applied (the old code had deleted it by then).
    child = _start(tmp_path, shown, "parsed")
    _wait_for(child, "parsed")
    time.sleep(0.5)
    _kill(child)
    assert _work_is_on_disk(state, track, n_vertices) == crashed

    # Killed after this session's autosave is written, before the old one is removed: both hold it.
    child = _start(tmp_path, shown, "written")
    _wait_for(child, "written")
    time.sleep(0.5)
    _kill(child)
    assert len(_work_is_on_disk(state, track, n_vertices)) == 2

    # A whole recovery, timed from the start to this session's autosave on disk, then killed anywhere in it.
    child = _start(tmp_path, shown, "")
    started = time.monotonic()
    _wait_for(child, "written")
    whole = time.monotonic() - started
    _kill(child)
    _work_is_on_disk(state, track, n_vertices)
    for delay in np.random.default_rng(19).uniform(0.3 * whole, 1.1 * whole, 2):
        child = _start(tmp_path, shown, "")
        time.sleep(float(delay))
        _kill(child)
        _work_is_on_disk(state, track, n_vertices)


# The window with one timeline edit made once its face is shown (unsaved work); says "ready" then.
EDITED = textwrap.dedent("""
    import sys
    from app import main_window as mw
    real_show = mw.MainWindow.show
    def show(self):
        real_show(self)
        def ready(ok):
            controller = self.document.timeline
            controller.push(lambda: controller.timeline.add_keys({"fap:3": [(0.5, 123.0)]}), "key")
            print("ready", flush=True)
        self.load_finished.connect(ready)
    mw.MainWindow.show = show
    sys.exit(mw.run_gui(sys.argv[1]))
""")


def test_sigterm_and_sighup_close_the_window_and_keep_unsaved_work(tmp_path):
    """SIGTERM/SIGHUP (logout, kill, a closed terminal) close the window like its close button, without
    a question: the process exits 0 and the unsaved edit is in an autosave offered at the next start
    (before, the process died at once and the edit was lost)."""
    from app_helpers import make_synthetic_face

    shown = tmp_path / "shown.ply"
    save_face(make_synthetic_face(12, 16, name="shown"), shown)
    state = tmp_path / "config" / "Mimica" / "autosave"
    for name in ("SIGTERM", "SIGHUP"):
        env = dict(os.environ, XDG_STATE_HOME=str(tmp_path / "state"), XDG_CONFIG_HOME=str(tmp_path / "config"),
                   PYTHONPATH=str(ROOT))
        child = subprocess.Popen([sys.executable, "-c", EDITED, str(shown)], cwd=ROOT, env=env,
                                 stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        child.said = queue.Queue()
        threading.Thread(target=lambda: [child.said.put(line.strip()) for line in child.stdout], daemon=True).start()
        try:
            _wait_for(child, "ready")
            child.send_signal(getattr(signal, name))
            assert child.wait(30) == 0, f"{name}: the window did not close cleanly"
        finally:
            if child.poll() is None:
                child.kill()
        autosaves = list(state.glob("untitled-*.mimica.autosave"))
        assert len(autosaves) == 1, autosaves
        assert cp.load_project(autosaves[0]).timeline.tracks["fap:3"].values.tolist() == [123.0]
        autosaves[0].unlink()
