"""The control-point dock in the window: it adds the RBF and Waters layers, an emotion button is one undo
step, a kernel the system refuses is a message and changes nothing, a Waters row moves its muscle and its
mirror, a PPC file places the points and a bad one changes nothing."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtCore import Qt


@pytest.fixture
def win(default_face_window):
    return default_face_window


def test_the_dock_drives_control_points_and_waters_muscles(qtbot, win, tmp_path):
    from app.undo import gestures
    from core.layers.rbf.kernels import Kernel

    dock = win.control_point_dock
    assert dock.ensure_layers()
    rig, stack = win.rig, win.undo_stack
    assert rig.layer("control_points") is not None and rig.layer("waters") is not None
    neutral = rig.vertices().copy()

    # An emotion button: the FACS preset on the control points, one undo step.
    gestures().new()
    dock.emotion_buttons["joy"].click()
    assert rig.value("cp:8.3:y") == pytest.approx(5.0)
    corner = rig.layer("control_points").points.vertices[rig.layer("control_points").points.names.index("mouth_corner_l")]
    assert rig.vertices()[corner, 1] - neutral[corner, 1] == pytest.approx(5.0)
    stack.undo()
    assert rig.value("cp:8.3:y") == 0.0

    # The kernel box switches the kernel; a main parameter the system cannot take is a message.
    gestures().new()
    dock.kernel_combo.setCurrentIndex(dock.kernel_combo.findData("gaussian"))
    assert rig.layer("control_points").kernel.name == "gaussian"
    before = rig.layer("control_points").kernel
    dock.main_spin.setValue(900000.0)
    assert rig.layer("control_points").kernel == before and "singular" in dock.message_label.text()
    gestures().new()
    dock.kernel_combo.setCurrentIndex(dock.kernel_combo.findData("multiquadric"))
    assert rig.layer("control_points").kernel == Kernel()
    stack.undo()                                                    # kernel changes are undo steps too
    assert rig.layer("control_points").kernel.name == "gaussian"
    assert dock.kernel_combo.currentData() == "gaussian"
    stack.redo()
    assert rig.layer("control_points").kernel == Kernel()

    # A point's row moves it; Waters rows move the muscle and, linked, its mirror.
    dock.point_combo.setCurrentIndex(dock.point_combo.findData("8.1"))
    dock.rows["cp:8.1:y"].edited.emit("cp:8.1:y", 3.0)
    assert rig.value("cp:8.1:y") == 3.0
    gestures().new()
    dock.rows["waters:zygomatic_major:left"].edited.emit("waters:zygomatic_major:left", 0.6)
    assert rig.value("waters:zygomatic_major:right") == 0.6
    assert dock.rows["waters:zygomatic_major:right"].value == pytest.approx(0.6)
    stack.undo()
    assert rig.value("waters:zygomatic_major:left") == 0.0

    # PPC: save, a bad file changes nothing, a good one places the points.
    assert dock.save_ppc(str(tmp_path / "face.ppc"))
    (tmp_path / "bad.ppc").write_text("chin 2.10 0 zero 1\n")
    layer_before = rig.layer("control_points").deformer
    assert not dock.open_ppc(str(tmp_path / "bad.ppc"))
    assert "line 1" in dock.message_label.text() and rig.layer("control_points").deformer is layer_before
    assert dock.open_ppc(str(tmp_path / "face.ppc"))
    np.testing.assert_array_equal(rig.layer("control_points").points.vertices, layer_before.points.vertices)
    assert rig.layer("control_points").deformer is not layer_before
    stack.undo()
    assert rig.layer("control_points").deformer is layer_before


def test_dpc_files_go_to_and_from_the_timeline(qtbot, win, tmp_path):
    dock, c = win.control_point_dock, win.timeline
    assert dock.ensure_layers()
    c.push(lambda: c.timeline.add_keys({"cp:8.3:y": [(0.0, 0.0, "linear"), (1.0, 6.0, "linear")]}))
    assert dock.export_dpc(str(tmp_path / "a.dpc"))
    win.undo_stack.undo()
    assert "cp:8.3:y" not in c.timeline.tracks or not len(c.timeline.track("cp:8.3:y"))
    assert dock.import_dpc(str(tmp_path / "a.dpc"))
    track = c.timeline.track("cp:8.3:y")
    assert len(track) == c.timeline.n_frames and track.evaluate(0.5) == pytest.approx(3.0)
    c.seek(0.5)
    assert win.rig.value("cp:8.3:y") == pytest.approx(3.0)
    (tmp_path / "bad.dpc").write_text("2\n0 0 0\n0 x 0\n")
    assert not dock.import_dpc(str(tmp_path / "bad.dpc"))
    assert "line 3" in dock.message_label.text()


def test_control_points_show_on_the_face_and_follow_the_pose(qtbot, win):
    dock = win.control_point_dock
    assert dock.ensure_layers()
    dock.show_check.setChecked(True)
    layer = win.rig.layer("control_points")
    assert dock.points_actor is not None and dock._points_mesh.n_points == len(layer.points)
    before = np.array(dock._points_mesh.points)
    win.rig.set_values({"cp:8.3:y": 4.0})
    win.flush_updates()                                  # the markers move with the drawn frame
    corner = layer.points.names.index("mouth_corner_l")
    assert np.array(dock._points_mesh.points)[corner, 1] - before[corner, 1] == pytest.approx(4.0, abs=1e-4)
    dock.show_check.setChecked(False)
    assert dock.points_actor is None


def test_clicks_move_a_control_point_and_drive_the_inverse(qtbot, win):
    from app.picking import world_to_display

    dock, rig = win.control_point_dock, win.rig
    assert dock.ensure_layers()
    renderer = win.plotter.renderer
    layer = rig.layer("control_points")
    dock.point_combo.setCurrentIndex(dock.point_combo.findData("8.3"))
    dock.click_combo.setCurrentIndex(dock.click_combo.findData("move"))
    corner = layer.points.vertices[layer.points.names.index("mouth_corner_l")]
    # a surface point 4 mm above the corner (the vertex of the face nearest there)
    goal = rig.face.vertices[corner] + [0.0, 4.0, 0.0]
    near = int(np.argmin(np.linalg.norm(rig.face.vertices - goal, axis=1)))
    x, y, _ = world_to_display(renderer, rig.face.vertices[near])[0]
    dock.on_click(x, y)
    assert np.linalg.norm(rig.vertices()[corner] - rig.face.vertices[near]) < 0.5
    assert rig.value("cp:8.3:y") > 3.0
    win.undo_stack.undo()
    assert rig.value("cp:8.3:y") == 0.0
    # inverse: pick a skin point on the left cheek near the zygomatic insertion, then a target up and out
    dock.click_combo.setCurrentIndex(dock.click_combo.findData("inverse"))
    waters = rig.layer("waters")
    m = waters.model.muscles[waters.model.keys.index("waters:zygomatic_major:left")]
    response = np.abs(waters.model.response[:, waters.model.keys.index("waters:zygomatic_major:left")].toarray())
    moved = response.reshape(-1, 3).max(axis=1)
    skin = int(np.argmin(np.linalg.norm(rig.face.vertices - m.insertion, axis=1) + 1e9 * (moved < 1.0)))
    x, y, _ = world_to_display(renderer, rig.face.vertices[skin])[0]
    dock.on_click(x, y)
    assert dock.inverse_vertex is not None
    target = rig.vertices()[dock.inverse_vertex] + 0.5 * (m.attachment - rig.face.vertices[dock.inverse_vertex]) * 0.1
    tx, ty, _ = world_to_display(renderer, target)[0]
    dock.on_click(tx, ty)
    assert dock.inverse_vertex is None and "reach within" in dock.message_label.text()
    assert rig.value("waters:zygomatic_major:left") > 0.0


def test_the_chart_selects_a_point_and_a_click_places_it(qtbot, win):
    from PySide6.QtCore import QPoint

    from app.picking import world_to_display

    dock, rig = win.control_point_dock, win.rig
    assert dock.ensure_layers()
    chart = dock.chart
    u, v = chart.points["8.3"]
    p = chart._to_widget(u, v)
    qtbot.mouseClick(chart, Qt.MouseButton.LeftButton, pos=QPoint(int(p.x()), int(p.y())))
    assert dock.point_combo.currentData() == "8.3" and chart.selected == "8.3"
    layer = rig.layer("control_points")
    old_vertex = layer.points.vertices[layer.points.names.index("mouth_corner_l")]
    dock.click_combo.setCurrentIndex(dock.click_combo.findData("place"))
    spot = rig.face.vertices[old_vertex] + [3.0, 2.0, 0.0]
    near = int(np.argmin(np.linalg.norm(rig.face.vertices - spot, axis=1)))
    x, y, _ = world_to_display(win.plotter.renderer, rig.face.vertices[near])[0]
    dock.on_click(x, y)
    new_vertex = layer.points.vertices[layer.points.names.index("mouth_corner_l")]
    assert new_vertex != old_vertex
    assert np.linalg.norm(rig.face.vertices[new_vertex] - rig.face.vertices[near]) < 1.5
    win.undo_stack.undo()
    assert layer.points.vertices[layer.points.names.index("mouth_corner_l")] == old_vertex


def test_link_left_right_mirrors_control_points_and_muscles():
    from app.control_point_dock import mirrored

    every = ("cp:8.3:x", "cp:8.4:x", "cp:8.4:y", "waters:zygomatic_major:right")
    assert mirrored("cp:8.3:x", 2.0, every) == {"cp:8.4:x": -2.0}
    assert mirrored("cp:8.3:y", 2.0, every) == {"cp:8.4:y": 2.0}
    assert mirrored("cp:8.1:y", 2.0, every) == {}                       # on the midline: no partner
    assert mirrored("waters:zygomatic_major:left", 0.5, every) == {"waters:zygomatic_major:right": 0.5}
    assert mirrored("cp:8.3:z", 1.0, every) == {}                       # partner not animated here


def test_the_layers_are_built_when_the_tab_is_shown_not_at_start_up(qtbot, win):
    """Building the control-point layer takes about a second: not while the dock is a tab behind the
    FAP dock (start-up stays fast), but as soon as the user brings the tab forward."""
    from core.rig import FaceRig

    dock = win.control_point_dock
    win.fap_dock.raise_()
    qtbot.wait(50)
    rig = FaceRig(win.face, deformer=win.rig.deformer)
    win.document.set_rig(rig)          # the rig arrives after the window is shown, as at start-up
    assert dock.rig is rig and rig.layer("control_points") is None
    dock.raise_()
    qtbot.waitUntil(lambda: win.rig.layer("control_points") is not None, timeout=20000)
    assert dock.rows
