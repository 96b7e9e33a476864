"""MainWindow: opening, loading through the menu path, errors, screenshots, views, settings, excepthook."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from app_helpers import image_difference, image_variance, make_synthetic_face, write_obj
from PySide6.QtCore import QPoint, QMimeData, QPointF, QSettings, Qt, QTimer, QUrl
from PySide6.QtGui import QDropEvent
from PySide6.QtWidgets import QMessageBox

from app.main_window import MAX_RECENT, MainWindow, install_excepthook
from core.face import FaceMetadata

LOAD_TIMEOUT_MS = 60_000


def _load(qtbot, window, path):
    """Run window.load_face_file(path) and wait for the outcome; returns success."""
    with qtbot.waitSignal(window.load_finished, timeout=LOAD_TIMEOUT_MS) as blocker:
        window.load_face_file(path)
    return blocker.args[0]


def _title_names(window, face_name: str) -> bool:
    """The title shows the project, the face and Mimica ("Untitled[*] — synthetic — Mimica")."""
    title = window.windowTitle()
    return f"— {face_name} —" in title and title.endswith("Mimica")


# ------------------------------------------------------------------ opening
def test_window_opens_on_given_face(window, synthetic_face):
    assert _title_names(window, "synthetic")
    assert window.face is synthetic_face
    assert window.view_mode == "textured" and window.mode_actions["textured"].isChecked()
    assert window.face_actor.actor.texture is not None
    assert "3,072 vertices" in window.counts_label.text()
    assert window.texture_label.text() == "texture: yes"
    assert window.units_label.text() == "units: mm"
    assert window.width() >= 800 and window.height() >= 600
    menus = [a.text().replace("&", "") for a in window.menuBar().actions()]
    assert menus == ["File", "Edit", "View", "Tools", "Help"]
    shortcuts = {a.text().replace("&", ""): a.shortcut().toString() for a in window.actions()}
    assert shortcuts["Open face…"] == "Ctrl+I" and shortcuts["Save face as…"] == ""
    assert shortcuts["Open project…"] == "Ctrl+O" and shortcuts["Save project"] == "Ctrl+S"
    assert shortcuts["Quit"] == "Ctrl+Q" and shortcuts["Reset camera"] == "R"
    assert [window.view_actions[v].shortcut().toString() for v in ("front", "side", "three-quarter", "back")] == [
        "1", "2", "3", "4"]
    assert window.isDockNestingEnabled()
    assert window.mode_group.isExclusive() and len(window.mode_group.actions()) == 4


def test_window_opens_on_default_face(qtbot, settings, error_boxes):
    from core.default_face import load_default_face  # noqa: F401 - must be importable

    win = MainWindow(settings=settings)
    qtbot.addWidget(win)
    win.show()
    qtbot.waitUntil(lambda: win.face is not None, timeout=LOAD_TIMEOUT_MS)
    assert not error_boxes
    assert win.face.n_vertices > 10_000 and win.face.texture is not None
    assert _title_names(win, win.face.metadata.name)
    assert win._notes_box is None, "the built-in face should not pop up a notes dialog"
    assert image_variance(win.screenshot()) > 100
    win.close()


def test_bad_start_file_falls_back_to_default_face(qtbot, settings, error_boxes, tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("nothing here\n")
    win = MainWindow(path=bad, settings=settings)
    qtbot.addWidget(win)
    win.show()
    qtbot.waitUntil(lambda: win.face is not None, timeout=LOAD_TIMEOUT_MS)
    assert len(error_boxes) == 1 and "bad.obj" in error_boxes[0][0]
    assert win.face.n_vertices > 10_000
    win.close()


def test_window_size_default(qtbot, synthetic_face, settings):
    win = MainWindow(synthetic_face, settings=settings, load_default=False)
    qtbot.addWidget(win)
    assert (win.width(), win.height()) == (1400, 900)
    win.close()


# ------------------------------------------------------------------ loading
def test_load_face_file_from_obj(qtbot, window, tmp_path, error_boxes):
    other = make_synthetic_face(n_u=30, n_v=40, texture=False, vertex_colors=False)
    path = write_obj(other, tmp_path / "other head.obj")
    assert _load(qtbot, window, path) is True
    assert not error_boxes
    assert window.face.n_vertices == other.n_vertices
    np.testing.assert_allclose(window.face.vertices, other.vertices, atol=1e-4)
    assert _title_names(window, window.face.metadata.name)
    assert window.file_label.text() == "other head.obj"
    assert window.texture_label.text() == "texture: no"
    assert window.recent_files()[0] == str(path.resolve())
    assert not window.is_loading and not window.progress_bar.isVisible()


def test_bad_file_keeps_previous_face_and_shows_error(qtbot, window, tmp_path, error_boxes):
    before = window.face
    bad = tmp_path / "broken.obj"
    bad.write_text("garbage\nf 1 2 3\n")
    with qtbot.waitSignal(window.load_failed, timeout=LOAD_TIMEOUT_MS) as failed:
        assert _load(qtbot, window, bad) is False
    assert window.face is before and window.face_actor is not None
    assert _title_names(window, "synthetic")
    assert len(error_boxes) == 1
    title, text = error_boxes[0]
    assert "broken.obj" in title
    assert text == failed.args[0] and text.strip()
    assert "Traceback" not in text
    assert window.recent_files() == []


def test_unsupported_and_missing_files_show_errors(qtbot, window, tmp_path, error_boxes):
    (tmp_path / "notes.txt").write_text("hello")
    assert _load(qtbot, window, tmp_path / "notes.txt") is False
    assert _load(qtbot, window, tmp_path / "missing.obj") is False
    assert len(error_boxes) == 2 and window.face.metadata.name == "synthetic"


def test_load_notes_are_shown(qtbot, window, tmp_path, monkeypatch):
    import core.formats.mesh_io

    noted = make_synthetic_face(n_u=20, n_v=20)
    noted.metadata = FaceMetadata(source="x.obj", units="mm", name="noted",
                                  notes=["Converted metres to millimetres.", "Removed 3 duplicate vertices."])
    monkeypatch.setattr(core.formats.mesh_io, "load_face", lambda path, progress=None, **_: noted)
    path = tmp_path / "x.obj"
    path.write_text("v 0 0 0\n")
    assert _load(qtbot, window, path) is True
    box = window._notes_box
    assert box is not None and box.isVisible() and not box.isModal()
    assert "Converted metres" in box.informativeText() and "duplicate" in box.informativeText()
    assert "Converted metres" in window.statusBar().currentMessage()


def test_progress_is_reported(qtbot, window, tmp_path, monkeypatch):
    import core.formats.mesh_io

    seen = []
    shown = window._on_load_progress
    monkeypatch.setattr(window, "_on_load_progress", lambda frac, msg: (seen.append((frac, msg)), shown(frac, msg)))

    def slow_load(path, progress=None, **_):
        for i in range(5):
            progress(i / 4, f"step {i}")
        return make_synthetic_face(n_u=12, n_v=12)

    monkeypatch.setattr(core.formats.mesh_io, "load_face", slow_load)
    (tmp_path / "p.obj").write_text("v 0 0 0\n")
    assert _load(qtbot, window, tmp_path / "p.obj") is True
    assert [f for f, _ in seen if f is not None][:5] == [0.0, 0.25, 0.5, 0.75, 1.0]
    # then the face is shown and its rig is built off the GUI thread, with its own progress
    assert seen[5] == (0.0, "Placing the FAP template on the face…")


def test_drop_file_loads_it(qtbot, window, tmp_path):
    path = write_obj(make_synthetic_face(n_u=16, n_v=16, texture=False), tmp_path / "dropped.obj")
    mime = QMimeData()
    mime.setUrls([QUrl.fromLocalFile(str(path))])
    event = QDropEvent(QPointF(50, 50), Qt.DropAction.CopyAction, mime, Qt.MouseButton.LeftButton,
                       Qt.KeyboardModifier.NoModifier)
    with qtbot.waitSignal(window.load_finished, timeout=LOAD_TIMEOUT_MS):
        window.dropEvent(event)
    assert window.file_label.text() == "dropped.obj"
    assert window.plotter.property("mimicaDrops"), "drops on the viewport go to our loader, not pv.read"

    ignored = QMimeData()
    ignored.setUrls([QUrl.fromLocalFile(str(tmp_path))])
    assert window._dropped_files(ignored) == []   # a folder is not a file


def _drop_on(widget, path):
    """A drag entering ``widget`` and a drop there, delivered as Qt delivers them (up to the first
    ancestor that takes drops)."""
    from PySide6.QtGui import QDragEnterEvent
    from PySide6.QtWidgets import QApplication

    mime = QMimeData()
    mime.setUrls([QUrl.fromLocalFile(str(path))])
    enter = QDragEnterEvent(QPoint(20, 20), Qt.DropAction.CopyAction, mime, Qt.MouseButton.LeftButton,
                            Qt.KeyboardModifier.NoModifier)
    QApplication.sendEvent(widget, enter)
    drop = QDropEvent(QPointF(20, 20), Qt.DropAction.CopyAction, mime, Qt.MouseButton.LeftButton,
                      Qt.KeyboardModifier.NoModifier)
    QApplication.sendEvent(widget, drop)
    return enter.isAccepted()


def test_drops_anywhere_open_meshes_and_textures_or_say_why_not(qtbot, window, tmp_path, error_boxes):
    from core.formats.mesh_io import save_face

    glb = tmp_path / "dropped.glb"
    save_face(make_synthetic_face(n_u=16, n_v=16), glb)   # with uv: a dropped image can be its texture
    finished = []
    window.load_finished.connect(finished.append)
    assert _drop_on(window.fap_dock, glb)               # on a dock
    qtbot.waitUntil(lambda: bool(finished), timeout=LOAD_TIMEOUT_MS)
    assert finished == [True] and window.file_label.text() == "dropped.glb", (finished, error_boxes)
    image = tmp_path / "skin.png"
    from PIL import Image

    Image.new("RGB", (32, 32), (200, 150, 120)).save(image)
    finished.clear()
    assert _drop_on(window.plotter, image)               # on the viewport: the face's texture
    qtbot.waitUntil(lambda: bool(finished), timeout=LOAD_TIMEOUT_MS)
    assert window.face.texture is not None and window.face.texture.shape[:2] == (32, 32)
    notes = tmp_path / "notes.txt"
    notes.write_text("not a face")
    assert _drop_on(window.plotter, notes)
    assert error_boxes and "Mimica opens faces" in error_boxes[-1][1]


# ------------------------------------------------------------------ recent files & settings
def test_recent_files_capped_persisted_and_missing_removed(qtbot, window, tmp_path, settings, error_boxes):
    files = []
    for i in range(MAX_RECENT + 2):
        p = tmp_path / f"f{i}.obj"
        p.write_text("v 0 0 0\n")
        files.append(p)
        window.add_recent_file(p)
    recent = window.recent_files()
    assert len(recent) == MAX_RECENT and recent[0] == str(files[-1].resolve())
    visible = [a for a in window.recent_menu.actions() if a.isVisible() and a.text().startswith("&")]
    assert len(visible) == MAX_RECENT and visible[0].data() == recent[0]
    assert QSettings(settings.fileName(), QSettings.Format.IniFormat).value("recentFiles")[0] == recent[0]

    files[-1].unlink()
    visible[0].trigger()  # File ▸ Open recent ▸ 1
    assert recent[0] not in window.recent_files()
    assert len(error_boxes) == 1 and "no longer exists" in error_boxes[0][1]
    assert len([a for a in window.recent_menu.actions() if a.isVisible() and a.text().startswith("&")]) == 7

    with qtbot.waitSignal(window.load_finished, timeout=LOAD_TIMEOUT_MS) as done:
        [a for a in window.recent_menu.actions() if a.isVisible()][0].trigger()
    assert done.args == [False]  # "v 0 0 0" is no face: an error, but the recent path was taken


def test_geometry_persisted(qtbot, synthetic_face, settings):
    win = MainWindow(synthetic_face, settings=settings, load_default=False)
    qtbot.addWidget(win)
    win.show()
    qtbot.waitExposed(win)
    win.resize(1200, 700)
    qtbot.wait(50)
    win.set_view_mode("shaded")
    win.close()
    assert settings.value("window/geometry") is not None

    again = MainWindow(synthetic_face, settings=settings, load_default=False)
    qtbot.addWidget(again)
    assert (again.width(), again.height()) == (1200, 700)
    assert again.view_mode == "shaded"
    again.close()


def test_user_settings_are_never_touched(tmp_path_factory):
    default = QSettings("Mimica", "Mimica").fileName()
    home = str(Path.home())
    assert not default.startswith(str(Path(home) / ".config")), default


# ------------------------------------------------------------------ viewport
def test_screenshot_not_blank_and_modes_differ(window, tmp_path):
    textured = window.screenshot(tmp_path / "textured.png")
    assert (tmp_path / "textured.png").stat().st_size > 1000
    assert image_variance(textured) > 100
    window.set_view_mode("wireframe")
    assert window.face_actor.actor.prop.style == "Wireframe"
    wire = window.screenshot()
    assert image_difference(textured, wire) > 3
    window.set_view_mode("points")
    window.set_view_mode("shaded")
    assert window.mode_actions["shaded"].isChecked() and not window.mode_actions["textured"].isChecked()
    window.screenshot(tmp_path / "shot.jpg")
    assert (tmp_path / "shot.jpg").read_bytes()[:2] == b"\xff\xd8"


def test_mode_actions_switch_modes(window):
    window.mode_actions["points"].trigger()
    assert window.view_mode == "points" and window.face_actor.actor.prop.style == "Points"


def _activate(qtbot, window):
    """Window shortcuts only fire in the active window."""
    window.activateWindow()
    window.plotter.setFocus()
    qtbot.waitUntil(window.isActiveWindow, timeout=5000)


def test_camera_presets_change_image(qtbot, window):
    _activate(qtbot, window)
    front = window.screenshot()
    qtbot.keyClick(window.plotter, "2")  # side view via its shortcut
    side = window.screenshot()
    window.view_actions["three-quarter"].trigger()
    three_q = window.screenshot()
    assert image_difference(front, side) > 3
    assert image_difference(front, three_q) > 3
    assert image_difference(side, three_q) > 3
    window.plotter.camera.zoom(3.0)
    window.plotter.render()
    zoomed = window.screenshot()
    qtbot.keyClick(window.plotter, "r")
    reset = window.screenshot()
    assert image_difference(zoomed, reset) > 3
    assert image_difference(three_q, reset) < 1.5


def test_vtk_single_key_bindings_disabled(qtbot, window):
    _activate(qtbot, window)
    for key in "qewsf3":
        qtbot.keyClick(window.plotter, key)
    assert window.isVisible()
    assert not getattr(window.plotter, "_closed", False)
    assert window.face_actor.actor.prop.style == "Surface"
    assert image_variance(window.screenshot()) > 100


def test_landmarks_toggle_changes_image(window):
    plain = window.screenshot()
    window.landmarks_action.trigger()
    assert window.face_actor.landmarks_visible
    marked = window.screenshot()
    changed = (np.abs(plain.astype(int) - marked.astype(int)).sum(axis=2) > 40).sum()
    assert changed > 6 * 60, f"6 markers + labels should change more than {changed} pixels"
    window.set_landmarks_visible(False)
    assert not window.face_actor.landmarks_visible


def test_update_vertices_in_place(window, synthetic_face):
    mesh = window.face_actor.mesh
    n_actors = len(window.plotter.renderer.actors)
    before = window.screenshot()
    window.update_vertices(synthetic_face.vertices * np.array([1.0, 0.85, 1.2]))
    assert window.face_actor.mesh is mesh and len(window.plotter.renderer.actors) == n_actors
    assert image_difference(before, window.screenshot()) > 1


def test_save_face_as(window, tmp_path, error_boxes):
    from core.formats.mesh_io import load_face

    out = tmp_path / "saved.ply"
    assert window.save_face_file(out) is True
    assert load_face(out).n_vertices == window.face.n_vertices
    assert window.save_face_file(tmp_path / "no" / "such" / "dir" / "x.obj") is False
    assert len(error_boxes) == 1 and "Traceback" not in error_boxes[0][1]


def test_about_lists_versions_and_credits(window, monkeypatch):
    import PySide6
    import pyvista
    import vtk

    shown = []
    monkeypatch.setattr(QMessageBox, "about", lambda parent, title, text: shown.append(text))
    window.about_action.trigger()
    text = shown[0]
    for needle in (PySide6.__version__, pyvista.__version__, vtk.vtkVersion.GetVTKVersion(),
                   sys.version.split()[0], "Default face: generated procedurally by Mimica", "ISO/IEC 14496-2"):
        assert needle in text


# ------------------------------------------------------------------ excepthook
def test_excepthook_shows_dialog(qtbot, window, capsys):
    hook = install_excepthook(window)
    try:
        try:
            raise ValueError("boom in a slot")
        except ValueError:
            sys.excepthook(*sys.exc_info())
        box = hook.last_dialog
        assert box is not None and box.isVisible()
        assert "ValueError: boom in a slot" in box.text()
        assert "Traceback" not in box.text() and "Traceback" in box.detailedText()
        assert "Traceback" in capsys.readouterr().err
        box.close()
    finally:
        hook.uninstall()


@pytest.mark.qt_no_exception_capture
def test_uncaught_exception_in_qt_callback_shows_dialog(qtbot, window):
    hook = install_excepthook(window)
    try:
        def explode():
            raise RuntimeError("kaboom from the event loop")

        QTimer.singleShot(0, explode)
        qtbot.waitUntil(lambda: hook.last_dialog is not None, timeout=5000)
        assert "kaboom" in hook.last_dialog.text()
        assert window.isVisible()
        hook.last_dialog.close()
    finally:
        hook.uninstall()


def test_exception_in_worker_thread_shows_dialog(qtbot, window):
    import threading

    hook = install_excepthook(window)
    try:
        def explode():
            raise KeyError("lost in a thread")

        t = threading.Thread(target=explode)
        t.start()
        t.join()
        qtbot.waitUntil(lambda: hook.last_dialog is not None, timeout=5000)
        assert "lost in a thread" in hook.last_dialog.text()
        hook.last_dialog.close()
    finally:
        hook.uninstall()
    assert sys.excepthook is not hook and threading.excepthook != hook.thread_hook


def test_qt_binding_keeps_none_alive():
    """PySide6 6.12.0 on CPython 3.11 lost a reference to None per void call, so a long session
    aborted ("deallocating None"); pyproject.toml excludes it. Guard against a regression."""
    import sys

    from PySide6.QtGui import QColor

    probe = QColor()
    before = sys.getrefcount(None)
    for _ in range(1000):
        probe.setAlpha(1)
    assert sys.getrefcount(None) >= before - 10


def test_scale_face_and_load_texture_replace_the_face(qtbot, window, synthetic_face, tmp_path, error_boxes):
    from PIL import Image

    width = synthetic_face.bounds[1, 0] - synthetic_face.bounds[0, 0]
    with qtbot.waitSignal(window.load_finished, timeout=30000):
        window.scale_face(2.0)
    assert window.face.bounds[1, 0] - window.face.bounds[0, 0] == pytest.approx(2 * width)
    image = tmp_path / "red.png"
    Image.new("RGB", (16, 8), (255, 0, 0)).save(image)
    with qtbot.waitSignal(window.load_finished, timeout=30000):
        window.load_texture(image)
    assert window.face.texture.shape == (8, 16, 3) and (window.face.texture[..., 0] == 255).all()
    (tmp_path / "bad.png").write_text("not an image")
    window.load_texture(tmp_path / "bad.png")
    assert error_boxes and "not an image" in error_boxes[-1][1]
    assert window.face.texture.shape == (8, 16, 3)   # nothing lost


def test_a_texture_for_top_down_coordinates_is_turned_upright_with_a_note(qtbot, window, synthetic_face, tmp_path,
                                                                         monkeypatch):
    from PIL import Image

    from core.face import Face

    down = Face(synthetic_face.vertices, synthetic_face.triangles, uv=synthetic_face.uv * [1, -1] + [0, 1],
                landmarks=synthetic_face.landmarks)
    window.set_face(down, rig=None)
    shown = []
    monkeypatch.setattr(window, "_show_notes", lambda notes, name: shown.append(notes))
    window.face_path = "head.glb"
    image = np.zeros((8, 4, 3), np.uint8)
    image[:4] = (255, 0, 0)   # red top half, as drawn
    Image.fromarray(image).save(tmp_path / "tex.png")
    with qtbot.waitSignal(window.load_finished, timeout=30000):
        window.load_texture(tmp_path / "tex.png")
    assert (window.face.texture[4:, :, 0] == 255).all() and (window.face.texture[:4, :, 0] == 0).all()
    assert shown and "tex.png was turned upside down" in shown[-1][0]
    assert not any("upside down" in n for n in down.metadata.notes), "the shown face's notes are not touched"


def test_flip_texture_turns_the_image_upside_down(qtbot, window, synthetic_face, error_boxes, monkeypatch):
    shown = []
    monkeypatch.setattr(window, "_show_notes", lambda notes, name: shown.append(notes))
    window.face.metadata.notes.append("Scaled from centimetres to millimetres.")
    window.face_path = "head.glb"  # as if opened from a file: its load notes were shown then
    before = window.face.texture.copy()
    with qtbot.waitSignal(window.load_finished, timeout=30000):
        window.flip_texture()
    assert np.array_equal(window.face.texture, before[::-1])
    assert window.face.landmarks == synthetic_face.landmarks
    with qtbot.waitSignal(window.load_finished, timeout=30000):
        window.scale_face(2.0)
    assert shown == [["Scaled by 2 in Mimica."]]   # the load notes are not shown again for each edit


def test_detection_in_other_units_scales_without_asking_and_keeps_the_landmarks(qtbot, window, synthetic_face,
                                                                              monkeypatch):
    """A detector that finds the face 2x too small: the window scales it (no question in the middle
    of detection), says so once in plain words, and the detected points (with their confidences)
    land on the scaled face."""
    from PySide6.QtWidgets import QMessageBox

    import core.registration.pipeline as pipeline
    from core.face import SurfacePoint

    points = {"9.3": SurfacePoint(3, (0.2, 0.3, 0.5)), "2.1": SurfacePoint(5, (1.0, 0.0, 0.0)),
              "3.7": synthetic_face.surface_point((25.0, 20.0, 60.0)),      # outer eye corners ~50 mm apart:
              "3.12": synthetic_face.surface_point((-25.0, 20.0, 60.0))}    # 100 mm once scaled, human
    detection = pipeline.Detection(points, {"9.3": 0.9, "2.1": 0.2, "3.7": 0.8, "3.12": 0.8},
                                   ["the scan's face is 2.00 times smaller than a human face: its units are "
                                    "probably not millimetres", "2 landmark(s) with low confidence"],
                                   {"total_s": 0.1}, "mpeg4_80", scale_hint=2.0)
    monkeypatch.setattr(pipeline, "detect_landmarks", lambda face, fixed=None: detection)
    asked = []
    monkeypatch.setattr(QMessageBox, "question", lambda *a, **k: asked.append(a[2]) or QMessageBox.StandardButton.No)
    shown = []
    monkeypatch.setattr(window, "_show_notes", lambda lines, what, heading=None: shown.append(lines))
    width = np.ptp(synthetic_face.vertices[:, 0])
    with qtbot.waitSignal(window.load_finished, timeout=30000):
        window.detect_landmarks()
    qtbot.waitUntil(lambda: window.landmark_editor.model.confidence("2.1") == pytest.approx(0.2), timeout=10000)
    assert not asked, "detection never stops to ask"
    assert np.ptp(window.face.vertices[:, 0]) == pytest.approx(2 * width)
    assert window.face.landmarks["9.3"] == points["9.3"]
    notes = shown[-1]
    assert "scaled it by 2" in notes[0] and "Scale face" in notes[0]
    assert not any("probably not millimetres" in n for n in notes[1:]), "said once"
    assert any("low confidence" in n for n in notes)

    # a face found at an absurd size (eye corners 20x apart once scaled) is not scaled behind the user's back
    detection.scale_hint = 20.0
    window.statusBar().clearMessage()
    window.detect_landmarks()
    qtbot.waitUntil(lambda: window.statusBar().currentMessage().startswith("Detected"), timeout=30000)
    assert np.ptp(window.face.vertices[:, 0]) == pytest.approx(2 * width), "not scaled again"


def test_a_loaded_face_shows_before_its_rig_is_built(qtbot, window, tmp_path, monkeypatch):
    """The face appears as soon as it is read; the rig follows from the background with progress,
    and the docks say what is happening meanwhile (not "cannot be animated")."""
    import threading

    import app.face_files
    from app.document import PREPARING_MESSAGE, build_rig

    release = threading.Event()
    built = []

    def slow_build(face, cache=None, progress=None):
        progress(0.5, "halfway")
        release.wait(30)
        built.append(face)
        return build_rig(face, cache, progress)

    monkeypatch.setattr(app.face_files, "build_rig", slow_build)
    face = make_synthetic_face(n_u=16, n_v=16)
    path = write_obj(face, tmp_path / "slow.obj")
    window.fap_dock.raise_()
    arrived = []
    window.document.rig_changed.connect(arrived.append)
    window.load_face_file(path)
    qtbot.waitUntil(lambda: window.face is not None and window.face.n_vertices == face.n_vertices,
                    timeout=LOAD_TIMEOUT_MS)
    assert window.document.rig_pending and window.is_loading and not built
    assert window.fap_dock.message_label.text() == PREPARING_MESSAGE
    assert window.muscle_dock.message_label.text().startswith("Building"), "the muscles wait for the rig"
    assert not window.landmark_editor.active, "a face whose rig is coming is not sent to the landmark tab"
    with qtbot.waitSignal(window.load_finished, timeout=LOAD_TIMEOUT_MS):
        release.set()
    assert built and arrived and not window.document.rig_pending and not window.is_loading
    # the synthetic face has too few feature points: now the docks say why, and its landmarks come first
    assert "feature points" in window.fap_dock.message_label.text()
    qtbot.waitUntil(lambda: window.landmark_editor.active, timeout=LOAD_TIMEOUT_MS)


def test_what_the_rig_build_adds_to_the_notes_reaches_the_status_bar(qtbot, window, tmp_path, monkeypatch):
    """A note the rig build adds (e.g. a damaged cache entry rebuilt) is shown when the rig arrives,
    whatever its wording; the load's own notes are not repeated as news."""
    import app.face_files
    from app.document import build_rig

    news = "The face's animation table was rebuilt; nothing of yours is lost."

    def noting_build(face, cache=None, progress=None):
        face.metadata.notes.append(news)
        return build_rig(face, cache, progress)

    monkeypatch.setattr(app.face_files, "build_rig", noting_build)
    path = write_obj(make_synthetic_face(n_u=16, n_v=16), tmp_path / "noted.obj")
    with qtbot.waitSignal(window.load_finished, timeout=LOAD_TIMEOUT_MS):
        window.load_face_file(path)
    assert window.statusBar().currentMessage() == news


def test_build_correspondence_shows_the_scan_animated_and_keeps_edited_points(qtbot, window, tmp_path, monkeypatch):
    """Issue 15: after Build correspondence the window shows the scan itself (every scan vertex where it
    was, lips cut, a mouth cavity and teeth added) animated by the rig, not the 4560-vertex canonical
    face; points the user moved or confirmed are still 'edited' / 'confirmed', the others 'auto'; the
    canonical face can be saved from Tools."""
    from core.landmark_editing import LandmarkStatus
    from core.registration.pipeline import default_model
    from core.registration.virtual_scanner import scan_face

    scan = scan_face(default_model(), n_target=12_000, rng=np.random.default_rng(4)).face
    window.set_face(scan, rig=None, rig_message="not needed here")
    model = window.document.landmarks
    nudged = scan.surface_point(scan.landmark_positions(["8.3"], scan.vertices)[0] + np.array([0.5, 0.0, 0.0]))
    model.move("8.3", nudged)
    model.confirm("9.3")
    assert model.status("8.3") == LandmarkStatus.EDITED and model.status("9.3") == LandmarkStatus.CONFIRMED
    with qtbot.waitSignal(window.load_finished, timeout=60000):
        window.build_correspondence()
    qtbot.waitUntil(lambda: window.face is not scan and window.document.landmarks is not model, timeout=60000)
    shown = window.face
    assert shown.n_vertices > scan.n_vertices
    assert np.array_equal(shown.vertices[:scan.n_vertices], scan.vertices), "the scan's own vertices, unmoved"
    assert {"mouth_cavity", "teeth_upper", "teeth_lower"} <= set(shown.parts)
    edited = window.document.landmarks
    assert edited.status("8.3") == LandmarkStatus.EDITED and edited.status("9.3") == LandmarkStatus.CONFIRMED
    others = [n for n in edited.names if n not in ("8.3", "9.3")]
    assert others and all(edited.status(n) == LandmarkStatus.AUTO for n in others)
    assert not scan.metadata.landmark_status, "the scan's own metadata is left as it was"
    assert any("canonical face" in n for n in shown.metadata.notes)
    # The rig arrives (built on the registration's fitted template) and the jaw parts the cut lips.
    qtbot.waitUntil(lambda: window.rig is not None and window.rig.face is shown, timeout=60000)
    rig = window.rig
    rig.set_values({"fap:3": 600.0})
    moved = shown.landmark_positions(["2.2", "2.3"], rig.vertices()) - shown.landmark_positions(["2.2", "2.3"])
    assert moved[1, 1] < -3.0 and abs(moved[0, 1]) < 1.0, "the lower lip drops, the upper stays"
    lower = shown.parts["teeth_lower"]
    assert np.allclose(rig.vertices()[lower] - shown.vertices[lower], rig.vertices()[lower[0]] - shown.vertices[lower[0]])
    assert np.linalg.norm(rig.vertices()[lower] - shown.vertices[lower], axis=1).min() > 1.0, "the lower teeth go with the jaw"
    # Tools ▸ Save canonical face writes the 4560-vertex face; after an edit there is none to save.
    import app.scan_tools
    from core.formats.mesh_io import load_face

    target = tmp_path / "scan.canonical.ply"
    monkeypatch.setattr(app.scan_tools.QFileDialog, "getSaveFileName", lambda *a, **k: (str(target), ""))
    window.save_canonical_action.trigger()
    assert load_face(target).n_vertices == 4560
    errors = []
    monkeypatch.setattr(window, "show_error", lambda title, text: errors.append(title))
    # Killed right after the build, the next start recovers the session from its autosave exactly: the
    # scan as cut, its parts, the landmarks with their statuses, the rig's values and pose.
    import subprocess

    project = window.document.project
    own = project.autosave_now()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    crashed = own.parent / f"untitled-{int(dead.stdout)}-1.mimica.autosave"
    crashed.write_bytes(own.read_bytes())
    own.unlink()
    posed = rig.vertices().copy()
    window.set_face(scan, rig=None, rig_message="not needed here")     # the next start, on another face
    asked = []
    monkeypatch.setattr(QMessageBox, "question", lambda *a, **k: asked.append(a[1]) or QMessageBox.StandardButton.Yes)
    assert project.check_startup_recovery() and asked == ["Recover unsaved work?"]
    qtbot.waitUntil(lambda: window.face is not scan and window.rig is not None and window.rig.face is window.face,
                    timeout=60000)
    recovered = window.face
    assert np.array_equal(recovered.vertices, shown.vertices) and np.array_equal(recovered.triangles, shown.triangles)
    assert {k: sorted(v) for k, v in recovered.parts.items()} == {k: sorted(v) for k, v in shown.parts.items()}
    assert all(np.allclose(recovered.landmark_position(n), shown.landmark_position(n), atol=1e-9)
               for n in shown.landmark_names)
    statuses = window.document.landmarks
    assert statuses.status("8.3") == LandmarkStatus.EDITED and statuses.status("9.3") == LandmarkStatus.CONFIRMED
    assert window.rig.value("fap:3") == 600.0 and np.allclose(window.rig.vertices(), posed)
    shown, rig = recovered, window.rig
    # The session survives a project round trip: the same scan, cut, mouth parts, landmarks with their
    # statuses, and the rig's values (the FAP table found again in the cache, built on the fitted template).
    saved = tmp_path / "session.mimica"
    assert project.save_project(saved)
    landmarks_before = {n: shown.landmark_position(n) for n in shown.landmark_names}
    window.set_face(scan, rig=None, rig_message="not needed here")
    # (A recovered session's face is read from the crashed autosave's folder, which recovery empties:
    # the saved project carries its own copy.)
    with qtbot.waitSignal(project.project_opened, timeout=60000):
        project.open_project(saved, ask=False)
    qtbot.waitUntil(lambda: window.rig is not None and window.rig.face is window.face, timeout=60000)
    back = window.face
    assert np.array_equal(back.vertices, shown.vertices) and np.array_equal(back.triangles, shown.triangles)
    assert {k: sorted(v) for k, v in back.parts.items()} == {k: sorted(v) for k, v in shown.parts.items()}
    assert all(np.allclose(back.landmark_position(n), p, atol=1e-9) for n, p in landmarks_before.items())
    assert window.document.landmarks.status("8.3") == LandmarkStatus.EDITED
    assert window.rig.value("fap:3") == 600.0
    assert np.allclose(window.rig.vertices(), rig.vertices()), "the same animation as before saving"
    window._canonical_of = (None, window._canonical_of[1])
    window.save_canonical_action.trigger()
    assert errors == ["No canonical face"]
