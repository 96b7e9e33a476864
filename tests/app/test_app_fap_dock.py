"""The FAP dock driving a real FaceRig on the default face, and the viewport following it.

The FAP deformer of the default face is built once per module (a second or two); every test gets
a fresh FaceRig on it, shown in a MainWindow through ``set_face(face, rig=...)``.
"""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtCore import QEvent, QPoint, QPointF, Qt
from PySide6.QtGui import QEnterEvent, QWheelEvent
from PySide6.QtWidgets import QApplication

from app.fap_dock import NO_RIG_MESSAGE, FapDock, readable_name
from core.layers.fap import tables
from core.layers.fap.limits import FOLD_REASON, SMEAR_REASON

TICK_TIMEOUT_MS = 5000


# ------------------------------------------------------------------ fixtures
@pytest.fixture
def rig(default_face, deformer):
    from core.rig import FaceRig

    return FaceRig(default_face, deformer=deformer)


@pytest.fixture
def win(qtbot, settings, error_boxes, default_face, rig):
    from app.main_window import MainWindow

    w = MainWindow(settings=settings, load_default=False)
    qtbot.addWidget(w)
    w.set_face(default_face, rig=rig)
    w.show()
    qtbot.waitExposed(w)
    qtbot.wait(30)
    yield w
    w.close()


@pytest.fixture
def dock(win) -> FapDock:
    return win.fap_dock


def _near(face, landmark: str, radius_mm: float) -> np.ndarray:
    """Indices of the face's vertices within ``radius_mm`` of a landmark."""
    p = face.landmark_position(landmark)
    idx = np.nonzero(np.linalg.norm(face.vertices - p, axis=1) < radius_mm)[0]
    assert len(idx) > 5, f"no vertices near {landmark}"
    return idx


def _wait_tick(qtbot, win):
    qtbot.waitUntil(lambda: not win._tick_timer.isActive(), timeout=TICK_TIMEOUT_MS)


# ------------------------------------------------------------------ layout
def test_rows_groups_labels_units_and_tooltips(dock, rig):
    animated = set(rig.animated_faps)
    assert set(dock.rows) == {f"fap:{s.number}" for s in tables.fap_specs() if s.number in animated and s.dock}
    expected_groups = [g for g in tables.DOCK_GROUPS
                       if any(tables.fap_spec(n).dock == g for n in animated)]
    assert list(dock.groups) == expected_groups
    assert ("gaze" in dock.groups) == (23 in animated) and ("head" in dock.groups) == (48 in animated)
    for name, group in dock.groups.items():  # rows sit in their own group, in FAP order
        assert group.numbers == sorted(n for n in animated if tables.fap_spec(n).dock == name)

    jaw = dock.row(3)
    assert jaw.label.text() == "3 open jaw"
    assert readable_name(tables.fap_spec(19)) == "close top left eyelid"
    assert readable_name(tables.fap_spec(35)) == "raise left outer brow"
    assert readable_name(tables.fap_spec(57)) == "raise bottom lip left-mid"  # outer lips: group says "outer"
    assert (jaw.slider.minimum(), jaw.slider.maximum()) == (0, 1400)  # unidirectional: starts at 0
    assert (jaw.spin.minimum(), jaw.spin.maximum()) == (0, 1400) and jaw.spin.suffix() == " MNS"
    lips = dock.row(4)  # bidirectional: centred at 0
    assert lips.slider.minimum() == -lips.slider.maximum() < 0 and lips.slider.value() == 0
    assert dock.row(6).spin.suffix() == " MW" and dock.row(19).spin.suffix() == " IRISD"
    tip = jaw.slider.toolTip()
    mm = rig.fapu["MNS"]
    for needle in ("open_jaw", "2.1", "Bottom of the chin", "down", f"1 MNS unit = {mm:.3f} mm on this face"):
        assert needle in tip, needle
    assert "FAP 7" in dock.row(6).toolTip()  # the mirror FAP is named
    # A slider end that would fold this face's skin or smear its texture is eased, and the tooltip
    # says from where and why: the jaw opens cleanly past what the presets ask of it (viseme aa, 600
    # MNS) ...
    limit, reason = rig.deformer.clean_limits[3 - 1, 1], rig.deformer.limit_reasons[3 - 1, 1]
    assert 600 < limit < 1400 and reason in (FOLD_REASON, SMEAR_REASON)
    assert f"beyond {limit:.0f} {reason}: eased" in dock.row(3).toolTip()
    assert "presets go to" not in dock.row(3).toolTip()
    # ... and where a preset goes past the surface's limit (this face's lip corners: joy stretches
    # them 160 MW), the preset passes as authored and the tooltip says so; the slider alone eases.
    reach = rig.deformer.preset_reach[:, 1]
    upper = rig.deformer.clean_limits[:, 1]
    past = [n for n in sorted(animated) if f"fap:{n}" in dock.rows and np.isfinite(upper[n - 1])
            and reach[n - 1] > upper[n - 1]]
    assert past
    n = past[0]
    assert (f"beyond {upper[n - 1]:.0f} {rig.deformer.limit_reasons[n - 1, 1]}: eased; the presets go to "
            f"{reach[n - 1]:.0f} as authored") in dock.row(n).toolTip()
    (low, high), (low_why, high_why) = rig.deformer.clean_limits[15 - 1], rig.deformer.limit_reasons[15 - 1]
    assert {low_why, high_why} <= {FOLD_REASON, SMEAR_REASON}
    expected = ([f"beyond {low:.0f} and {high:.0f} {low_why}"] if low_why == high_why else   # one reason: one phrase
                [f"beyond {low:.0f} {low_why}", f"beyond {high:.0f} {high_why}"])
    assert all(phrase in dock.row(15).toolTip() for phrase in expected)
    # The lids close all the way (their closing end is never eased); an upper lid's opening end would
    # stop where it folds through its crease, but with the lid's skin sliding on the eyeball (the
    # surface guard) the default face's opens to the table's -300 without crossing it.
    crease = rig.deformer.clean_limits[19 - 1, 0]
    assert crease == -np.inf and "eased" not in dock.row(19).toolTip()
    assert "beyond 1024" not in dock.row(19).toolTip() and "eased" not in dock.row(21).toolTip()
    # Labels are never cut: every label is as wide as its text needs.
    for row in dock.rows.values():
        assert row.label.width() >= row.label.fontMetrics().horizontalAdvance(row.label.text())


def test_rotation_faps_show_degrees(dock, rig):
    rotations = [n for n in rig.animated_faps if tables.fap_spec(n).is_rotation and tables.fap_spec(n).dock]
    if not rotations:
        pytest.skip("this face animates no gaze/head rotation")
    row = dock.row(rotations[0])
    assert row.spin.suffix() == "°"
    assert row.spin.maximum() == pytest.approx(np.degrees(tables.fap_spec(rotations[0]).maximum * 1e-5), abs=0.1)
    row.spin.setValue(10.0)
    assert rig.fap_value(rotations[0]) == pytest.approx(np.radians(10.0) / 1e-5, rel=1e-6)


# ------------------------------------------------------------------ sliders -> rig -> face
def test_open_jaw_slider_moves_chin_not_forehead(qtbot, dock, rig, default_face):
    slider = dock.row("open_jaw").slider
    qtbot.keyClick(slider, Qt.Key.Key_PageUp)  # a real key press on the slider
    qtbot.keyClick(slider, Qt.Key.Key_PageUp)
    assert slider.value() > 0
    assert rig.fap_value(3) == slider.value() == dock.row(3).spin.value()
    slider.setValue(600)  # what a drag does: valueChanged with tracking on
    assert rig.fap_value(3) == 600
    moved = rig.vertices() - default_face.vertices
    chin = _near(default_face, "2.1", 6.0)
    forehead = _near(default_face, "11.1", 12.0)
    assert moved[chin, 1].mean() < -3.0, "the chin should move down by several mm"
    assert np.abs(moved[forehead]).max() < 0.05, "the forehead must not move"


def test_rig_change_from_code_updates_widgets_without_echo(qtbot, dock, rig):
    row = dock.row(3)
    changes = []
    rig.changed.connect(lambda: changes.append(rig.fap_value(3)))
    with qtbot.assertNotEmitted(row.edited), qtbot.assertNotEmitted(dock.expression_combo.currentIndexChanged):
        rig.set_fap(3, 700)
        rig.set_expression("surprise", 0.5)
    assert changes == [700, 700], "one change each, and nothing written back"
    assert row.slider.value() == 700 and row.spin.value() == 700
    assert dock.expression_combo.currentIndex() == tables.expression_id("surprise")
    assert dock.expression_slider.value() == 50 and dock.expression_spin.value() == 50
    rig.reset_faps()
    assert row.slider.value() == 0 and row.spin.value() == 0


def test_link_left_right_moves_the_pair_in_one_call(qtbot, dock, rig):
    left, right = dock.row("stretch_l_cornerlip"), dock.row("stretch_r_cornerlip")
    assert left.mirror == right.key == "fap:7" and right.mirror == left.key  # from the parameter registry
    changes = []
    rig.changed.connect(lambda: changes.append(1))
    qtbot.mouseClick(dock.link_check, Qt.MouseButton.LeftButton)
    assert dock.link_check.isChecked()
    left.slider.setValue(200)
    assert rig.value(left.key) == rig.value(right.key) == 200
    assert right.slider.value() == 200 and len(changes) == 1, "the pair moves with one rig change"
    qtbot.mouseClick(dock.link_check, Qt.MouseButton.LeftButton)
    assert not dock.link_check.isChecked()
    left.slider.setValue(-100)
    assert rig.value(left.key) == -100 and rig.value(right.key) == 200


def test_reset_row_group_and_all(qtbot, dock, rig):
    rig.set_faps({3: 500, 14: 300, 4: 200, 31: 100})
    rig.set_expression("joy", 0.8)
    rig.set_viseme(1, 0.5)
    qtbot.mouseClick(dock.row(3).reset_button, Qt.MouseButton.LeftButton)
    assert rig.fap_value(3) == 0 and rig.fap_value(14) == 300 and dock.row(3).slider.value() == 0
    qtbot.mouseClick(dock.groups["jaw & chin"].reset_button, Qt.MouseButton.LeftButton)
    assert rig.fap_value(14) == 0 and rig.fap_value(4) == 200
    label = dock.row(4).label
    qtbot.mouseDClick(dock.row(4), Qt.MouseButton.LeftButton, pos=label.geometry().center())
    assert rig.fap_value(4) == 0 and rig.fap_value(31) == 100
    qtbot.mouseClick(dock.reset_all_button, Qt.MouseButton.LeftButton)
    assert not rig.fap_values().any() and rig.expression[0] == 0 and rig.viseme[0] == 0
    assert not rig.effective_fap_values().any()
    assert dock.row(31).slider.value() == 0 and dock.expression_combo.currentIndex() == 0


def test_group_collapses(qtbot, dock):
    group = dock.groups["inner lips"]
    assert group.body.isVisible()
    qtbot.mouseClick(group.toggle, Qt.MouseButton.LeftButton)
    assert not group.expanded and not group.body.isVisible()
    qtbot.mouseClick(group.toggle, Qt.MouseButton.LeftButton)
    assert group.body.isVisible()


def test_expression_and_viseme_presets(qtbot, dock, rig):
    combo = dock.expression_combo
    assert [combo.itemText(i).lower() for i in range(combo.count())] == list(tables.expression_names())
    combo.setCurrentIndex(tables.expression_id("joy"))
    assert rig.expression == (1, 1.0)
    assert np.any(rig.preset_values() != 0)
    dock.expression_spin.setValue(40)
    assert rig.expression == (1, pytest.approx(0.4))
    dock.expression_slider.setValue(75)
    assert rig.expression == (1, pytest.approx(0.75)) and dock.expression_spin.value() == 75
    np.testing.assert_allclose(rig.preset_values(), tables.expression_table()[1] * 0.75)

    vcombo = dock.viseme_combo
    assert vcombo.count() == len(tables.viseme_names())
    assert vcombo.itemText(1).split() == ["1", "PP", "p", "b", "m"]
    vcombo.setCurrentIndex(1)
    assert rig.viseme == (1, 1.0)
    dock.viseme_slider.setValue(30)
    assert rig.viseme == (1, pytest.approx(0.3))
    combo.setCurrentIndex(0)
    assert rig.expression[0] == 0 and not dock.expression_slider.isEnabled()


def test_out_of_range_entry_cannot_reach_the_rig(qtbot, dock, rig):
    row = dock.row(3)
    spin = row.spin
    spin.setFocus()
    spin.selectAll()
    qtbot.keyClicks(spin, "5000")
    assert spin.valueFromText(spin.lineEdit().text()) <= 1400, "the box must refuse the keystroke"
    qtbot.keyClick(spin, Qt.Key.Key_Return)
    assert 0 <= rig.fap_value(3) <= 1400
    assert rig.fap_value(3) == spin.value() == row.slider.value()
    assert not dock.message_label.isVisible(), "the box itself must stop it, before the rig has to refuse"
    spin.selectAll()
    qtbot.keyClicks(spin, "-300")
    qtbot.keyClick(spin, Qt.Key.Key_Return)
    assert rig.fap_value(3) >= 0, "open_jaw is one-way: the box must not accept negatives"
    row.slider.setValue(99_999)
    assert rig.fap_value(3) == 1400
    with pytest.raises(ValueError):  # the rig itself refuses it too
        rig.check_fap(3, 5000)


def test_a_faces_own_range_reaches_the_row(qtbot, dock, rig, monkeypatch):
    """A face whose rig describes a FAP with its own range (a scan's closed eye: the upper lid opens
    to -1324 instead of the table's -300) gets it on the slider, the box and the tooltip."""
    import dataclasses

    from core import parameters as P

    own = dataclasses.replace(P.describe("fap:19"), minimum=-1324.0, note="this eye is closed at rest")
    table = rig.faps.describe
    monkeypatch.setattr(rig.faps, "describe", lambda key: own if P.key_of(key) == "fap:19" else table(key))
    dock.set_rig(rig)
    row, other = dock.row(19), dock.row(20)
    assert row.minimum == -1324.0 and other.minimum == -300.0
    assert row.spin.minimum() == pytest.approx(-1324.0 * row.display_scale)
    assert row.slider.minimum() == round(-1324.0 * row.slider_scale)
    assert "On this face: this eye is closed at rest" in row.slider.toolTip()
    assert "Range -1324 to 1024 IRISD" in row.slider.toolTip()
    row.slider.setValue(round(-1200 * row.slider_scale))
    assert rig.fap_value(19) == -1200.0
    other.slider.setValue(other.slider.minimum() - 1000)      # the other lid keeps the table's end
    assert rig.fap_value(20) == -300.0


def test_refused_edit_shows_a_message_and_snaps_back(qtbot, dock, rig, monkeypatch):
    def refuse(values):
        raise ValueError("open_jaw refused for this test")

    monkeypatch.setattr(rig, "set_values", refuse)
    dock.row(3).slider.setValue(800)
    assert rig.fap_value(3) == 0
    assert dock.row(3).slider.value() == 0 and dock.row(3).spin.value() == 0
    assert dock.message_label.isVisible() and "refused for this test" in dock.message_label.text()
    monkeypatch.undo()
    dock.row(3).slider.setValue(100)
    assert rig.fap_value(3) == 100 and not dock.message_label.isVisible()


def test_wheel_scrolls_the_dock_not_an_unfocused_slider(qtbot, dock, rig):
    slider = dock.row(4).slider
    assert not slider.hasFocus()
    pos = QPointF(slider.rect().center())
    wheel = QWheelEvent(pos, QPointF(slider.mapToGlobal(pos.toPoint())), QPoint(0, 0), QPoint(0, -120),
                        Qt.MouseButton.NoButton, Qt.KeyboardModifier.NoModifier, Qt.ScrollPhase.NoScrollPhase, False)
    QApplication.sendEvent(slider, wheel)
    assert slider.value() == 0 and rig.fap_value(4) == 0


# ------------------------------------------------------------------ viewport
def test_viewport_follows_the_rig_once_per_burst(qtbot, win, dock, rig, monkeypatch):
    # The muscle layer joining the rig when its background build ends also moves the mesh: let it land first.
    qtbot.waitUntil(lambda: not win.muscle_dock.simulation.building, timeout=120000)
    _wait_tick(qtbot, win)
    actor = win.face_actor
    mesh = actor.mesh
    before = np.array(mesh.points)
    calls = []
    original = actor.update_vertices
    monkeypatch.setattr(actor, "update_vertices", lambda v, n=None: (calls.append(1), original(v, n)))
    for value in range(100, 1100, 100):  # ten slider events before the event loop runs
        dock.row(3).slider.setValue(value)
    assert not calls, "the viewport must not redraw per slider event"
    _wait_tick(qtbot, win)
    assert len(calls) == 1
    assert win.face_actor.mesh is mesh
    np.testing.assert_allclose(mesh.points, rig.vertices(), atol=1e-4)
    assert np.abs(np.asarray(mesh.points) - before).max() > 3.0
    compute_ms, draw_ms = win.last_tick_ms
    assert compute_ms > 0 and draw_ms > 0
    assert "compute" in win.tick_label.text() and "draw" in win.tick_label.text()


def test_heat_map_toggle_puts_scalars_on_the_mesh(qtbot, win, dock, rig):
    actor = win.face_actor
    dock.row(3).slider.setValue(300)
    qtbot.mouseClick(dock.heat_check, Qt.MouseButton.LeftButton)
    _wait_tick(qtbot, win)
    assert actor.scalars_visible and actor.actor.texture is None
    np.testing.assert_allclose(actor.scalars, rig.displacement_magnitude(), atol=1e-3)
    assert actor.scalar_bar_title == "Displacement (mm)"
    assert actor.scalar_range[1] >= float(rig.displacement_magnitude().max())
    first_max = float(actor.scalars.max())
    dock.row(3).slider.setValue(600)  # live while sliders move (600: viseme aa's, so not eased)
    _wait_tick(qtbot, win)
    assert float(actor.scalars.max()) > first_max + 1.0
    np.testing.assert_allclose(actor.scalars, rig.displacement_magnitude(), atol=1e-3)
    qtbot.mouseClick(dock.heat_check, Qt.MouseButton.LeftButton)
    _wait_tick(qtbot, win)
    assert not actor.scalars_visible and actor.actor.texture is not None
    assert actor.scalar_bar_title is None


def _enter(widget):
    pos = QPointF(5, 5)
    QApplication.sendEvent(widget, QEnterEvent(pos, pos, QPointF(widget.mapToGlobal(QPoint(5, 5)))))


def _leave(widget):
    QApplication.sendEvent(widget, QEvent(QEvent.Type.Leave))


def test_influence_of_hovered_fap(qtbot, win, dock, rig):
    actor = win.face_actor
    dock.influence_check.setChecked(True)
    _wait_tick(qtbot, win)
    assert not actor.scalars_visible, "nothing hovered yet"
    _enter(dock.row(31))
    _wait_tick(qtbot, win)
    assert dock.overlay() == ("influence", 31)
    assert actor.scalars_visible
    np.testing.assert_allclose(actor.scalars, rig.fap_influence(31), atol=1e-5)
    _leave(dock.row(31))
    _enter(dock.row(3))
    _wait_tick(qtbot, win)
    np.testing.assert_allclose(actor.scalars, rig.fap_influence(3), atol=1e-5)
    _leave(dock.row(3))
    _wait_tick(qtbot, win)
    assert not actor.scalars_visible and actor.actor.texture is not None


def test_feature_points_toggle_uses_the_window_landmarks(qtbot, win, dock):
    assert not win.face_actor.landmarks_visible
    qtbot.mouseClick(dock.feature_points_check, Qt.MouseButton.LeftButton)
    assert win.face_actor.landmarks_visible and win.landmarks_action.isChecked()
    win.landmarks_action.trigger()  # View menu / L key
    assert not win.face_actor.landmarks_visible and not dock.feature_points_check.isChecked()


def test_view_menu_toggles_the_dock(win, dock):
    assert dock.isVisible() and win.fap_dock_action in win.view_menu.actions()
    assert win.dockWidgetArea(dock) == Qt.DockWidgetArea.RightDockWidgetArea
    assert dock.width() < win.width() / 2, "the dock must leave most of the window to the viewport"
    win.fap_dock_action.trigger()
    assert not dock.isVisible()
    win.fap_dock_action.trigger()
    assert dock.isVisible()


# ------------------------------------------------------------------ faces without a rig
def test_face_without_feature_points_keeps_the_window_usable(window):
    """The conftest window shows a synthetic face with 6 landmarks: no rig, a clear message."""
    dock = window.fap_dock
    assert window.rig is None
    assert NO_RIG_MESSAGE in dock.message_label.text() and dock.message_label.isVisible()
    assert not dock.rows and not dock.reset_all_button.isEnabled() and not dock.heat_check.isEnabled()
    assert "Traceback" not in dock.message_label.text()
    window.set_view_mode("shaded")
    window.set_landmarks_visible(True)
    assert window.face_actor.landmarks_visible and dock.feature_points_check.isChecked()


def test_new_face_replaces_the_rig(qtbot, win, dock, rig, synthetic_face, default_face, deformer):
    from core.rig import FaceRig

    win.set_face(synthetic_face)
    assert win.rig is None and not dock.rows
    _wait_tick(qtbot, win)
    rig.set_fap(3, 500)  # the old rig no longer drives anything
    assert not win._tick_timer.isActive() and dock.rig is None
    fresh = FaceRig(default_face, deformer=deformer)
    win.set_face(default_face, rig=fresh)
    assert win.rig is fresh and dock.rig is fresh and dock.row(3).slider.value() == 0
    assert not dock.message_label.isVisible()
    dock.row(3).slider.setValue(300)
    assert fresh.fap_value(3) == 300 and rig.fap_value(3) == 500


def test_background_load_builds_the_rig(qtbot, settings, error_boxes):
    """The default face comes through the loader thread with its rig already built."""
    from app.main_window import MainWindow

    w = MainWindow(settings=settings)
    qtbot.addWidget(w)
    with qtbot.waitSignal(w.load_finished, timeout=120_000):
        pass
    assert not error_boxes and w.rig is not None, w.rig_message
    assert w.fap_dock.rows and w.fap_dock.rig is w.rig
    w.close()


# ------------------------------------------------------------------ .fap files through the timeline
def test_window_imports_and_exports_fap_files_through_the_timeline(qtbot, win, rig, default_face, tmp_path):
    """File ▸ Import animation puts a .fap file on the timeline, which drives the window's rig;
    File ▸ Export .fap writes the timeline back (the .fap player dock is retired)."""
    path = tmp_path / "jaw.fap"
    lines = ["2.1 jaw 30 3"]   # the timeline's frame rate, so frames land on its grid
    for k in range(3):
        lines += [" ".join("1" if f == 3 else "0" for f in range(1, 69)), f"{k} {200 * k}"]
    path.write_text("\n".join(lines) + "\n")
    c = win.timeline
    c.seek(0.0)
    assert c.import_animation(path) is not None
    assert "fap:3" in c.timeline.tracks
    c.seek(2 / 30)
    assert rig.fap_value(3) == pytest.approx(400)
    _wait_tick(qtbot, win)
    shown = win.face_actor.mesh.points
    chin = default_face.landmark_position("2.1")
    i = int(np.argmin(np.linalg.norm(default_face.vertices - chin, axis=1)))
    assert shown[i, 1] < default_face.vertices[i, 1] - 1.0   # the viewport shows the jaw open
    out = tmp_path / "back.fap"
    assert c.export_fap(out)
    from core.formats.fap_file import read_fap

    seq = read_fap(out)
    assert seq.values[2][2] == pytest.approx(400)
    assert rig.fap_value(3) == pytest.approx(400)   # exporting did not move the face on screen
    win.undo_stack.undo()
    rig.reset_faps()


def test_window_without_rig_exports_no_fap_file(qtbot, settings, error_boxes, tmp_path):
    from app_helpers import make_synthetic_face

    from app.main_window import MainWindow

    w = MainWindow(make_synthetic_face(), settings=settings, load_default=False)
    qtbot.addWidget(w)
    try:
        assert w.rig is None
        out = tmp_path / "x.fap"
        messages = []
        w.timeline.message.connect(messages.append)
        assert not w.timeline.export_fap(out) and not out.exists()
        assert "no rig" in messages[-1]
    finally:
        w.close()


def test_the_dock_follows_change_events_row_by_row(dock, rig, monkeypatch):
    """A FAP change moves only its own row; a pose-only change (a muscle layer settling) moves none."""
    from core.layer import ParameterChange

    shown = []
    for key, row in dock.rows.items():
        monkeypatch.setattr(row, "show_value", lambda v, k=key: shown.append(k))
    rig.set_values({"fap:3": 250.0})
    assert shown == ["fap:3"]
    shown.clear()
    rig.changed.emit(ParameterChange())          # what a settling muscle step sends
    rig.parameters_changed.emit(ParameterChange())
    assert shown == []
    rig.set_values({"fap:3": 0.0})


def test_view_keys_follow_the_mouse_into_the_viewport(qtbot, win, dock):
    """A number box keeps digits typed into it; once the mouse enters the 3-D view, 1/2/3 change
    the view instead of typing into the box (its value committed, nothing else changed)."""
    from PySide6.QtCore import QEvent, QPointF
    from PySide6.QtGui import QEnterEvent
    from PySide6.QtWidgets import QApplication

    spin = dock.row(3).spin
    win.activateWindow()
    qtbot.waitUntil(win.isActiveWindow)
    spin.setFocus()
    qtbot.waitUntil(lambda: QApplication.focusWidget() in (spin, spin.lineEdit()))
    spin.selectAll()
    qtbot.keyClicks(spin.lineEdit(), "2")                 # typing in the box types in the box
    qtbot.keyClick(spin.lineEdit(), Qt.Key.Key_Return)
    assert win.rig.fap_value(3) == 2.0
    win.set_camera_view("front")
    QApplication.sendEvent(win.plotter, QEnterEvent(QPointF(5, 5), QPointF(5, 5), QPointF(5, 5)))
    assert win.plotter.hasFocus()
    qtbot.keyClick(win.plotter, Qt.Key.Key_2)            # now the key is the side view's
    assert win._view == "side" and win.rig.fap_value(3) == 2.0
    win.rig.set_values({"fap:3": 0.0})


def test_typing_a_number_out_of_range_is_refused_visibly(qtbot, win, dock):
    """Typing 500 into the ±400 box of FAP 31 does not give 50: the box says 500 is outside its
    range and keeps its value; an in-range number typed the same way is taken."""
    row = dock.row(31)
    spin = row.spin
    notes = []
    spin.refused.connect(notes.append)
    win.activateWindow()
    qtbot.waitUntil(win.isActiveWindow)
    spin.setFocus()
    spin.selectAll()
    qtbot.keyClicks(spin.lineEdit(), "500")
    assert spin.lineEdit().text().startswith("500")       # every digit typed is there
    qtbot.keyClick(spin.lineEdit(), Qt.Key.Key_Return)
    assert win.rig.fap_value(31) == 0.0 and notes and "500 is outside -400 to 400 ENS" in notes[-1]
    spin.selectAll()
    qtbot.keyClicks(spin.lineEdit(), "250")
    qtbot.keyClick(spin.lineEdit(), Qt.Key.Key_Return)
    assert win.rig.fap_value(31) == 250.0
    win.rig.set_values({"fap:31": 0.0})


def test_preset_values_show_as_marks_on_the_sliders(win, dock, rig):
    """Joy at 100 %: every FAP Joy moves gets a mark where Joy puts it; the others none."""
    from core.layers.fap import tables

    rig.set_expression("joy", 1.0)
    joy = tables.expression_table()[tables.expression_id("joy")]
    try:
        marked = {n for n in rig.animated_faps if f"fap:{n}" in dock.rows and dock.row(n).mark is not None}
        assert marked == {n for n in rig.animated_faps if f"fap:{n}" in dock.rows and joy[n - 1] != 0} and marked
        n = next(iter(marked))
        assert dock.row(n).slider.ghost == round(joy[n - 1]) and dock.row(n).mark == round(joy[n - 1])
        assert "active preset" in dock.row(n).slider.toolTip()
    finally:
        rig.set_expression(None)
    assert all(row.slider.ghost is None for row in dock.rows.values())
