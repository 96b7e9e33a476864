"""The landmark-correction picker (app.landmark_dock, app.picking) and the undo stack (app.undo).

Run under Xvfb: xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python -m pytest tests/app/test_app_landmarks.py -q
"""

from __future__ import annotations

import numpy as np
import pytest
from psygnal import Signal
from PySide6.QtCore import QPoint, Qt

from core.landmark_editing import LandmarkStatus


# ------------------------------------------------------------------ fixtures
# One window for the whole module (building one costs seconds); each test gets a fresh face,
# which also gives it a fresh landmark model and an empty undo stack.
@pytest.fixture(scope="module")
def shared_window(qapp, tmp_path_factory):
    from PySide6.QtCore import QSettings
    from PySide6.QtTest import QTest

    from app.landmark_dock import LandmarkDock
    from app.main_window import MainWindow
    from app_helpers import make_synthetic_face

    settings = QSettings(str(tmp_path_factory.mktemp("landmarks") / "s.ini"), QSettings.Format.IniFormat)
    win = MainWindow(make_synthetic_face(), settings=settings, load_default=False, tools=False)
    win.show()
    QTest.qWaitForWindowExposed(win)
    dock = LandmarkDock(win.document, win)   # as the window builds it (tools=True)
    win.landmark_dock, win.landmark_editor = dock, dock.editor
    QTest.qWait(30)
    yield win
    win.close()


@pytest.fixture
def window(shared_window, error_boxes):
    """The module's window (overrides conftest's per-test window)."""
    return shared_window


@pytest.fixture
def editor(window, qtbot):
    from app_helpers import make_synthetic_face

    window.set_face(make_synthetic_face())
    dock = window.landmark_dock
    dock.pick_button.setChecked(False)
    dock.mirror_check.setChecked(False)
    dock.set_registration_available(__import__("app.landmark_dock").landmark_dock.registration_available())
    dock.raise_()
    window.activateWindow()
    qtbot.waitActive(window)  # window shortcuts (N, P, C, M, Ctrl+Z) need the active window
    ed = window.landmark_editor
    qtbot.waitUntil(lambda: ed.active, timeout=3000)
    window.plotter.render()
    return ed


def to_widget(plotter, display_xy) -> QPoint:
    """Qt widget position of a VTK display point (rounded to whole logical pixels)."""
    from app.picking import display_to_qt

    qx, qy = display_to_qt(plotter, *display_xy)
    return QPoint(int(round(qx)), int(round(qy)))


def sent_display(plotter, pos: QPoint) -> tuple[float, float]:
    """The VTK display point pyvistaqt makes of widget position ``pos``."""
    from app.picking import qt_to_display

    return qt_to_display(plotter, pos.x(), pos.y())


def project(editor, points) -> np.ndarray:
    from app.picking import world_to_display

    return world_to_display(editor.plotter.renderer, points)


def marker_pixel(editor, name: str) -> QPoint:
    """Where landmark ``name``'s marker is drawn."""
    from app.picking import MARKER_OFFSET_MM

    positions, normals = editor._landmark_geometry()
    i = editor.model.index(name)
    return to_widget(editor.plotter, project(editor, positions[i] + MARKER_OFFSET_MM * normals[i])[0, :2])


def camera_ray_hit(editor, display_xy) -> np.ndarray:
    """The face point under a display pixel, by an independent ray cast in core (trimesh/embree)."""
    return camera_ray_hit_on(editor, display_xy, editor.face)


def camera_ray_hit_on(editor, display_xy, face) -> np.ndarray:
    renderer = editor.plotter.renderer
    ends = []
    for depth in (0.0, 1.0):
        renderer.SetDisplayPoint(display_xy[0], display_xy[1], depth)
        renderer.DisplayToWorld()
        w = np.array(renderer.GetWorldPoint())
        ends.append(w[:3] / w[3])
    direction = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    locations, _, _ = face.ray_hits(ends[0][None], direction[None])
    assert len(locations) == 1
    return locations[0]


def surface_pixel(editor, xyz) -> QPoint:
    """The widget pixel over the face vertex closest to ``xyz``."""
    v = editor.face.vertices[editor.face.kdtree.query(xyz)[1]]
    return to_widget(editor.plotter, project(editor, v)[0, :2])


# ------------------------------------------------------------------ projection
def test_world_to_display_matches_vtk(editor):
    renderer = editor.plotter.renderer
    points = editor.face.vertices[::500]
    ours = project(editor, points)
    for p, (x, y, z) in zip(points, ours):
        renderer.SetWorldPoint(*p, 1.0)
        renderer.WorldToDisplay()
        np.testing.assert_allclose(renderer.GetDisplayPoint(), (x, y, z), atol=1e-6)


# ------------------------------------------------------------------ view <-> list
def test_click_marker_selects_it_in_the_list(editor, window, qtbot):
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton, pos=marker_pixel(editor, "9.3"))
    assert editor.model.selected == "9.3"
    table = window.landmark_dock.table
    assert editor.dock.name_at(table.currentIndex()) == "9.3"
    assert editor.markers.selected_index == editor.model.index("9.3")


def test_click_row_selects_and_highlights_in_view(editor, window, qtbot):
    from app.picking import SELECTED_OFFSET_MM

    table = window.landmark_dock.table
    rect = table.visualRect(editor.dock.view_index("8.3"))
    qtbot.mouseClick(table.viewport(), Qt.MouseButton.LeftButton, pos=rect.center())
    assert editor.model.selected == "8.3"
    positions, normals = editor._landmark_geometry()
    i = editor.model.index("8.3")
    shown = np.asarray(editor.markers.selected_mesh.points[0])
    np.testing.assert_allclose(shown, positions[i] + SELECTED_OFFSET_MM * normals[i], atol=1e-9)
    assert editor.markers._selected_actor.GetVisibility()


# ------------------------------------------------------------------ moving
def test_click_moves_selected_landmark_to_the_surface_point_under_the_cursor(editor, window, qtbot):
    face, model = editor.face, editor.model
    before = model.snapshot()
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton, pos=marker_pixel(editor, "9.3"))
    assert model.selected == "9.3"
    window.landmark_dock.pick_button.setChecked(True)

    target = surface_pixel(editor, (22.0, 35.0, 100.0))
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton, pos=target)
    expected = camera_ray_hit(editor, sent_display(window.plotter, target))
    moved = model.position("9.3")
    np.testing.assert_allclose(moved, expected, atol=1e-3)  # the exact hit point, not a vertex
    assert np.linalg.norm(moved - face.landmark_position("9.3")) < 1e-9  # written into the face
    old_point = before["9.3"].point
    assert np.linalg.norm(moved - np.asarray(old_point.barycentric) @ face.vertices[face.triangles[old_point.triangle]]) > 10.0
    assert model.status("9.3") is LandmarkStatus.EDITED
    assert "move landmark 9.3" in window.undo_action.text()
    # the list shows it
    row = editor.dock.table_model.row_of("9.3")
    x_text = editor.dock.table_model.index(row, 3).data()
    assert x_text == f"{moved[0]:.1f}"
    after = model.snapshot()

    window.undo_action.trigger()
    assert model.snapshot() == before  # exactly the old SurfacePoint and status
    assert face.landmarks["9.3"] == before["9.3"].point
    window.redo_action.trigger()
    assert model.snapshot() == after


def test_drag_rotates_but_never_moves(editor, window, qtbot):
    model = editor.model
    model.select("9.3")
    window.landmark_dock.pick_button.setChecked(True)
    before = model.snapshot()
    count = window.undo_stack.count()
    start = surface_pixel(editor, (20.0, 30.0, 100.0))
    end = start + QPoint(30, 0)
    qtbot.mousePress(window.plotter, Qt.MouseButton.LeftButton, pos=start)
    qtbot.mouseMove(window.plotter, start + QPoint(10, 0))
    qtbot.mouseMove(window.plotter, end)
    qtbot.mouseRelease(window.plotter, Qt.MouseButton.LeftButton, pos=end)
    assert model.snapshot() == before
    assert window.undo_stack.count() == count


def test_plain_click_without_pick_mode_does_not_move_but_shift_click_does(editor, window, qtbot):
    model = editor.model
    model.select("2.1")
    assert not window.landmark_dock.pick_button.isChecked()
    before = model.snapshot()
    target = surface_pixel(editor, (-25.0, -30.0, 100.0))
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton, pos=target)
    assert model.snapshot() == before
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.ShiftModifier, pos=target)
    expected = camera_ray_hit(editor, sent_display(window.plotter, target))
    np.testing.assert_allclose(model.position("2.1"), expected, atol=1e-3)


def test_mirror_edit_moves_the_partner_in_one_undo_step(editor, window):
    model = editor.model
    window.landmark_dock.mirror_check.setChecked(True)
    before = model.snapshot()
    face = editor.face
    target = face.surface_point((36.0, -60.0, 45.0))
    editor.move("8.3", target)
    assert model.point("8.3") == target
    assert model.point("8.4") == model.suggest_mirror("8.3")
    assert model.status("8.4") is LandmarkStatus.EDITED
    left, right = model.position("8.3"), model.position("8.4")
    assert right[0] < 0 < left[0] and abs(left[0] + right[0]) < 1.0 and abs(left[1] - right[1]) < 1.0
    assert "8.3 and 8.4" in window.undo_action.text()
    window.undo_action.trigger()
    assert model.snapshot() == before


def test_typed_coordinate_goes_to_closest_surface_point(editor):
    table_model = editor.dock.table_model
    row = table_model.row_of("3.5")
    old = editor.model.position("3.5")
    assert table_model.setData(table_model.index(row, 4), old[1] + 6.0)
    new = editor.model.position("3.5")
    assert abs(new[1] - (old[1] + 6.0)) < 0.5 and editor.model.status("3.5") is LandmarkStatus.EDITED


def test_picks_on_the_displayed_pose_store_the_neutral_surface_point(editor, window, qtbot):
    """The view shows a deformed face (e.g. an expression); markers follow it, and a pick stores
    the triangle + barycentric of the displayed hit, which is a point of the neutral face."""
    from app.picking import MARKER_OFFSET_MM

    face, model = editor.face, editor.model
    displayed = face.vertices * np.array([1.15, 1.0, 1.0]) + np.array([0.0, 4.0, 6.0])
    window.update_vertices(displayed)  # in place + render, as the animation tick does
    qtbot.wait(10)
    positions, normals = editor._landmark_geometry()
    np.testing.assert_allclose(positions, face.landmark_positions(model.names, displayed), atol=1e-9)
    np.testing.assert_allclose(np.asarray(editor.markers.mesh.points), positions + MARKER_OFFSET_MM * normals,
                               atol=1e-6)
    model.select("3.5")
    window.landmark_dock.pick_button.setChecked(True)
    target = to_widget(editor.plotter, project(editor, displayed[face.kdtree.query((-20.0, 40.0, 90.0))[1]])[0, :2])
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton, pos=target)
    hit = camera_ray_hit_on(editor, sent_display(window.plotter, target), face.with_vertices(displayed))
    np.testing.assert_allclose(face.landmark_position("3.5", displayed), hit, atol=1e-3)
    # stored on the neutral face: the same surface point evaluated on the neutral vertices
    point = model.point("3.5")
    neutral = np.asarray(point.barycentric) @ face.vertices[face.triangles[point.triangle]]
    np.testing.assert_allclose(model.position("3.5"), neutral, atol=1e-12)
    assert abs(model.position("3.5")[2] - hit[2]) > 3.0  # it is not the displayed position


# ------------------------------------------------------------------ keyboard
def test_keyboard_next_previous_confirm_and_undo(editor, window, qtbot):
    model = editor.model
    table = window.landmark_dock.table
    table.setFocus()
    model.select(model.names[0])
    qtbot.keyClick(table, Qt.Key.Key_N)
    assert model.selected == model.names[1]
    qtbot.keyClick(table, Qt.Key.Key_P)
    assert model.selected == model.names[0]
    first = model.names[0]
    qtbot.keyClick(table, Qt.Key.Key_C)
    assert model.status(first) is LandmarkStatus.CONFIRMED
    assert model.selected == model.names[1]
    second = model.names[1]
    qtbot.keyClick(table, Qt.Key.Key_Return)
    assert model.status(second) is LandmarkStatus.CONFIRMED and model.selected == model.names[2]
    qtbot.keyClick(window.plotter, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier)
    assert model.status(second) is LandmarkStatus.AUTO
    assert model.status(first) is LandmarkStatus.CONFIRMED
    editor.confirm_all()
    assert all(s is LandmarkStatus.CONFIRMED for s in model.statuses())
    assert "Confirmed" not in editor.dock.summary_label.text() and "6 confirmed" in editor.dock.summary_label.text()
    window.undo_action.trigger()
    assert model.status(second) is LandmarkStatus.AUTO


def test_edit_menu_and_pick_shortcut(editor, window, qtbot):
    titles = [a.text().replace("&", "") for a in window.menuBar().actions()]
    assert titles.index("Edit") == titles.index("File") + 1
    assert window.undo_action.shortcut().matches(Qt.Modifier.CTRL | Qt.Key.Key_Z) is not None
    qtbot.keyClick(window.plotter, Qt.Key.Key_M)
    assert window.landmark_dock.pick_button.isChecked()
    qtbot.keyClick(window.plotter, Qt.Key.Key_Escape)
    assert not window.landmark_dock.pick_button.isChecked()


def test_hidden_dock_disables_picking(editor, window, qtbot):
    window.fap_dock.raise_()
    qtbot.waitUntil(lambda: not editor.active, timeout=3000)
    editor.model.select("9.3")
    window.landmark_dock.pick_button.setChecked(True)
    before = editor.model.snapshot()
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton, pos=surface_pixel(editor, (20.0, 30.0, 100.0)))
    assert editor.model.snapshot() == before


# ------------------------------------------------------------------ files and matching buttons
def test_save_load_csv_and_json_with_errors(editor, window, tmp_path, error_boxes):
    model = editor.model
    editor.move("9.3", editor.face.surface_point((5.0, 0.0, 90.0)))
    csv_path, json_path = tmp_path / "m.csv", tmp_path / "m.json"
    assert editor.save_file(csv_path) and editor.save_file(json_path)
    saved = model.snapshot()
    window.undo_action.trigger()
    assert model.status("9.3") is LandmarkStatus.AUTO
    assert editor.load_file(json_path)
    assert model.snapshot() == saved
    window.undo_action.trigger()
    assert model.status("9.3") is LandmarkStatus.AUTO
    assert editor.load_file(csv_path)
    np.testing.assert_allclose(model.position("9.3"), saved_position := editor.face.landmark_position("9.3"))
    assert model.status("9.3") is LandmarkStatus.EDITED and saved_position is not None

    bad = tmp_path / "bad.csv"
    bad.write_text("name,x,y,z,status,confidence\n9.3,1,2,3,auto,\n8.3,1,two,3,auto,\n")
    before = model.snapshot()
    assert not editor.load_file(bad)
    assert model.snapshot() == before
    title, text = error_boxes[-1]
    assert "bad.csv" in title and "line 3: y is not a number ('two')" in text


def test_matching_buttons_follow_registration_availability(editor, window, qtbot):
    from app.landmark_dock import NEEDS_REGISTRATION, registration_available

    dock = window.landmark_dock
    available = registration_available()
    assert dock.detect_button.isEnabled() == available
    assert dock.build_button.isEnabled() == available
    if not available:
        assert dock.detect_button.toolTip() == NEEDS_REGISTRATION
    dock.set_registration_available(True)
    assert dock.detect_button.isEnabled() and not dock.rerun_button.isEnabled()  # nothing fixed yet
    editor.model.select("9.3")
    editor.confirm_selected()
    assert dock.rerun_button.isEnabled()
    with qtbot.waitSignal(dock.detect_requested) as blocker:
        dock.rerun_button.click()
    assert list(blocker.args[0]) == ["9.3"]
    with qtbot.waitSignal(dock.detect_requested) as blocker:
        dock.detect_button.click()
    assert blocker.args[0] == {}
    with qtbot.waitSignal(dock.build_requested):
        dock.build_button.click()
    # A detector's result replaces only the auto landmarks, as one undo step.
    point = editor.face.surface_point((0.0, 0.0, 90.0))
    changed = editor.apply_detection({"9.3": point, "2.1": point}, {"2.1": 0.4})
    assert changed == ["2.1"] and editor.model.confidence("2.1") == 0.4
    row = editor.dock.table_model.row_of("2.1")
    assert editor.dock.table_model.index(row, 2).data() == "0.40"
    window.undo_action.trigger()
    assert editor.model.confidence("2.1") is None


def test_new_face_retargets_editor_and_clears_history(editor, window, qtbot):
    from app_helpers import make_synthetic_face

    editor.move("9.3", editor.face.surface_point((5.0, 0.0, 90.0)))
    assert window.undo_stack.count() == 1
    face = make_synthetic_face(40, 50, name="other")
    window.set_face(face)
    assert editor.face is face and editor.model.face is face
    assert window.undo_stack.count() == 0
    assert editor.picker.mesh is window.face_actor.mesh


def test_the_landmark_model_lives_in_the_document(editor, window):
    """The editor is a controller over ``document.landmarks``: edits reach the document's signals,
    the scan tools' detections go in through the document (one undo step) and show in the dock, and a
    new face brings a new model."""
    from app_helpers import make_synthetic_face

    doc = window.document
    assert editor.model is doc.landmarks and doc.landmarks.face is doc.face
    changed, selected = [], []
    doc.landmarks_changed.connect(changed.append)
    doc.landmark_selected.connect(selected.append)
    try:
        editor.select("9.3")
        editor.move("9.3", doc.face.surface_point((5.0, 0.0, 90.0)))
        assert selected == ["9.3"] and changed == ["9.3"]
        assert doc.landmarks.status("9.3") is LandmarkStatus.EDITED
        assert editor.dock.table_model.index(editor.dock.table_model.row_of("9.3"), 1).data() == "edited"
        assert doc.apply_landmark_detection({"2.1": doc.face.surface_point((0.0, -60.0, 60.0))}, {"2.1": 0.3}) \
            == ["2.1"]
        assert editor.dock.table_model.index(editor.dock.table_model.row_of("2.1"), 2).data() == "0.30"
        assert window.undo_stack.undoText() == "detect landmarks"
        window.undo_action.trigger()
        assert doc.landmarks.confidence("2.1") is None
        old = doc.landmarks
        window.set_face(make_synthetic_face(40, 50, name="other"))
        assert doc.landmarks is not old and editor.model is doc.landmarks and window.undo_stack.count() == 0
    finally:
        doc.landmarks_changed.disconnect(changed.append)
        doc.landmark_selected.disconnect(selected.append)


# ------------------------------------------------------------------ undo machinery
class FakeRig:
    """The part of core.rig.FaceRig that UndoableRigEdits uses: keys, set_values, parameters_changed."""

    parameters_changed = Signal(object)

    def __init__(self):
        self._values = {"fap:3": 0.0, "fap:4": 0.0, "fap:5": 0.0, "fap:6": 0.0, "expression:fear": 0.0}

    def parameters(self):
        return tuple(self._values)

    def value(self, key):
        return self._values[key]

    def set_values(self, values):
        from core.layer import ParameterChange

        previous = {k: self._values[k] for k, v in values.items() if self._values[k] != v}
        self._values.update(values)
        if previous:
            self.parameters_changed.emit(ParameterChange({k: values[k] for k in previous}, previous, "faps"))


def test_rig_edits_merge_per_gesture_and_undo(qtbot):
    from PySide6.QtWidgets import QLabel

    from app.undo import UndoableRigEdits, gestures, make_undo_stack

    stack = make_undo_stack()
    rig = FakeRig()
    edits = UndoableRigEdits(stack, rig)
    target = QLabel("slider stand-in")
    qtbot.addWidget(target)
    # A drag: one press, many values, one release -> one step.
    qtbot.mousePress(target, Qt.MouseButton.LeftButton)
    for v in (50.0, 120.0, 300.0):
        rig.set_values({"fap:3": v})
    qtbot.mouseRelease(target, Qt.MouseButton.LeftButton)
    assert stack.count() == 1 and stack.undoText() == "3 open jaw"
    # Another gesture on the same slider is a new step.
    qtbot.mousePress(target, Qt.MouseButton.LeftButton)
    rig.set_values({"fap:3": 400.0})
    assert stack.count() == 2
    # A preset in a new gesture.
    gestures().new()
    rig.set_values({"expression:fear": 0.5})
    assert stack.count() == 3 and stack.undoText() == "fear"
    stack.undo()
    assert rig.value("expression:fear") == 0.0
    stack.undo()
    assert rig.value("fap:3") == 300.0
    stack.undo()
    assert rig.value("fap:3") == 0.0
    stack.redo()
    assert rig.value("fap:3") == 300.0
    # Playback is not recorded.
    with edits.suspended():
        rig.set_values({"fap:5": 10.0})
    assert stack.count() == 3 and stack.index() == 1
    # A drag that comes back to where it started leaves no step (the redo history goes, as always).
    gestures().new()
    rig.set_values({"fap:4": 20.0})
    rig.set_values({"fap:4": 0.0})
    assert stack.count() == 1 and stack.index() == 1
    stack.undo()
    assert [rig.value(k) for k in ("fap:3", "fap:4", "fap:5")] == [0.0, 0.0, 10.0]
    # Several keys changed together are one step that names how many.
    gestures().new()
    rig.set_values({"fap:3": 10.0, "fap:6": 5.0})
    assert stack.undoText() == "2 parameters"
    stack.undo()
    assert rig.value("fap:3") == 0.0 and rig.value("fap:6") == 0.0
    edits.set_rig(None)
    # The stack has no Qt parent: emptied here, not by the garbage collector at exit, where
    # ~QUndoStack -> clear() deleting Python commands inside a collected cycle segfaulted.
    stack.clear()


def test_set_value_command_merges_only_within_a_gesture():
    from app.undo import SetValueCommand, make_undo_stack

    stack = make_undo_stack()
    seen = []
    stack.push(SetValueCommand("opacity", seen.append, 0.0, 0.2, merge_id="opacity", gesture=1))
    stack.push(SetValueCommand("opacity", seen.append, 0.2, 0.5, merge_id="opacity", gesture=1))
    stack.push(SetValueCommand("opacity", seen.append, 0.5, 0.7, merge_id="opacity", gesture=2))
    assert stack.count() == 2 and seen == [0.2, 0.5, 0.7]
    stack.undo()
    stack.undo()
    assert seen[-1] == 0.0


def test_the_list_sorts_by_confidence_and_shows_the_doubtful_only(editor, window, qtbot):
    from app.landmark_table import LOW_BACKGROUND
    from core.landmark_editing import LOW_CONFIDENCE

    dock = window.landmark_dock
    names = list(editor.model.names)
    scores = {name: (i % 5) / 5 for i, name in enumerate(names)}   # 0.0 .. 0.8
    import dataclasses

    for name, score in scores.items():
        editor.model.set_state(name, dataclasses.replace(editor.model.state(name), confidence=score))
    dock.table_model.refresh()
    low = sorted(n for n, c in scores.items() if c < LOW_CONFIDENCE)
    # a click on the Conf. header sorts the doubtful first
    header = dock.table.horizontalHeader()
    qtbot.mouseClick(header.viewport(), Qt.MouseButton.LeftButton,
                     pos=QPoint(header.sectionViewportPosition(2) + 5, header.height() // 2))
    shown = [dock.name_at(dock.table_filter.index(r, 0)) for r in range(dock.table_filter.rowCount())]
    assert [scores[n] for n in shown] == sorted(scores.values())
    assert dock.table_filter.index(0, 2).data(Qt.ItemDataRole.BackgroundRole).color() == LOW_BACKGROUND
    qtbot.mouseClick(dock.low_only_check, Qt.MouseButton.LeftButton)
    listed = sorted(dock.name_at(dock.table_filter.index(r, 0)) for r in range(dock.table_filter.rowCount()))
    assert listed == low and 0 < len(low) < len(names)
    editor._update_counts()
    assert f"{len(low)} low confidence" in dock.summary_label.text()
    # selecting through the filtered list still selects the landmark; confirming one removes it
    qtbot.mouseClick(dock.table.viewport(), Qt.MouseButton.LeftButton,
                     pos=dock.table.visualRect(dock.table_filter.index(0, 0)).center())
    first = editor.model.selected
    assert first in low
    editor.model.confirm(first)
    assert dock.table_filter.rowCount() == len(low) - 1
