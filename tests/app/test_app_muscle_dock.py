"""The muscle dock driving a real MuscleLayer on the default face, and the viewport following it.

One window for the whole module (the FAP deformer and the muscle model of the default face take
seconds to build); every test starts from the layer at rest with the dock's toggles off.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QApplication

from app.muscle_dock import BUILDING_MESSAGE, JAW, NO_FACE_MESSAGE, MuscleDock
from core.layers.muscles import SolverDiverged, control_keys, preset, preset_names
from core.parameters import key_of

TIMEOUT_MS = 20000


def _process_until(predicate, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    app = QApplication.instance()
    while time.monotonic() < end:
        app.processEvents()
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


# ------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def built(qapp, default_face, deformer, tmp_path_factory):
    """(window, what the dock showed right after attach) with the muscle layer built."""
    from app.main_window import MainWindow
    from core.rig import FaceRig

    settings = QSettings(str(tmp_path_factory.mktemp("muscles") / "m.ini"), QSettings.Format.IniFormat)
    win = MainWindow(settings=settings, load_default=False, tools=False)
    win.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    # Software OpenGL under Xvfb: fewer pixels and no 8x MSAA make redraws several times faster.
    win.resize(900, 600)
    win.plotter.disable_anti_aliasing()
    win.show()
    dock = win.muscle_dock = MuscleDock(win.document, win)   # the window's tool docks, as _create_tool_docks does
    dock.simulation.animation_s = 0.4  # keep the playback tests short
    first = {"message": dock.message_label.text(), "building": dock.is_building,
             "enabled": dock.apply_button.isEnabled()}
    assert _process_until(lambda: dock.layer is not None or not dock.is_building, 180), "muscle build timed out"
    assert dock.layer is not None, dock.message_label.text()
    yield win, first
    win.close()


@pytest.fixture
def win(built):
    return built[0]


@pytest.fixture
def dock(win, qtbot, error_boxes) -> MuscleDock:
    d = win.muscle_dock
    d.simulation.stop(relax=False)
    d.link_check.setChecked(False)
    d.set_muscles_visible(False)
    d.layer.reset()
    win.undo_stack.clear()
    qtbot.waitUntil(lambda: not d.simulation.settling and not win._tick_timer.isActive(), timeout=TIMEOUT_MS)
    return d


def _settle(qtbot, win, dock):
    qtbot.waitUntil(lambda: not dock.simulation.settling and not dock.simulation.animating and dock.layer.converged
                    and not win._tick_timer.isActive(), timeout=TIMEOUT_MS)


# ------------------------------------------------------------------ layout and building
def test_built_off_thread_tabified_with_the_fap_dock_and_in_the_view_menu(built, dock):
    win, first = built
    assert first["building"] and first["message"] == BUILDING_MESSAGE and not first["enabled"]
    assert dock in win.tabifiedDockWidgets(win.fap_dock)
    assert win.muscle_dock.toggle_action in win.view_menu.actions()
    assert dock.layer is not None and dock.preset_combo.isEnabled() and not dock.message_label.isVisible()
    assert "muscles" in dock.rig._layers and dock.rig is win.rig  # attached to the window's rig
    # 9 pairs x 2 + orbicularis + jaw
    assert set(dock.rows) == {key_of(k) for k in control_keys()} | {JAW} and JAW == "jaw"
    assert dock.row(("risorius", "left")).spin.suffix() == " u"
    assert dock.row(JAW).spin.suffix() == "°"
    assert dock.row(("risorius", "right")).label.text() == "right" and dock.row(JAW).label.text() == ""
    assert dock.status == "at rest"


def test_no_face_and_no_rig_disable_the_dock_with_the_reason(window, qtbot):
    from app.main_window import MainWindow

    empty = MainWindow(settings=window.settings, load_default=False, tools=False)
    qtbot.addWidget(empty)
    d = MuscleDock(empty.document, empty)
    assert d.layer is None and d.message_label.text() == NO_FACE_MESSAGE and not d.apply_button.isEnabled()
    empty.close()

    # The synthetic face has too few feature points for a rig.
    d2 = window.muscle_dock   # the full window attaches its own muscle dock
    assert window.rig is None
    assert d2.layer is None and not d2.apply_button.isEnabled() and not d2.is_building
    assert "not available" in d2.message_label.text() and window.rig_message.splitlines()[0] in d2.message_label.text()


# ------------------------------------------------------------------ dock <-> layer
def test_slider_sets_the_layer_force(dock):
    row = dock.row(("zygomatic_major", "left"))
    row.slider.setValue(123)
    forces = dock.layer.forces()
    assert forces[("zygomatic_major", "left")] == pytest.approx(12.3)
    assert forces[("zygomatic_major", "right")] == 0.0
    assert row.spin.value() == pytest.approx(12.3)
    row.spin.setValue(4.5)
    assert dock.layer.forces()[("zygomatic_major", "left")] == pytest.approx(4.5)
    assert row.slider.value() == 45
    dock.row(JAW).spin.setValue(6.0)
    assert dock.layer.jaw_deg == pytest.approx(6.0)


def test_layer_change_from_code_shows_without_echo(dock, win):
    edits = []
    for row in dock.rows.values():
        row.edited.connect(lambda key, value: edits.append((key, value)))
    steps = win.undo_stack.count()
    dock.layer.set_force("risorius", "right", 7.5)
    dock.layer.set_jaw(3.0)
    row = dock.row(("risorius", "right"))
    assert row.slider.value() == 75 and row.spin.value() == pytest.approx(7.5)
    assert dock.row(JAW).spin.value() == pytest.approx(3.0)
    assert edits == []  # nothing written back
    assert dock.layer.forces()[("risorius", "right")] == 7.5
    # Recorded like any rig change (the FAP sliders' rule): undo takes a script's change back too.
    assert win.undo_stack.count() == steps + 2
    win.undo_stack.undo()
    win.undo_stack.undo()
    assert dock.layer.jaw_deg == 0.0 and dock.layer.forces()[("risorius", "right")] == 0.0
    assert row.slider.value() == 0


def test_link_left_right_moves_the_partner(dock):
    dock.link_check.setChecked(True)
    dock.row(("depressor_anguli_oris", "right")).slider.setValue(200)
    forces = dock.layer.forces()
    assert forces[("depressor_anguli_oris", "left")] == pytest.approx(20.0)
    assert forces[("depressor_anguli_oris", "right")] == pytest.approx(20.0)
    assert dock.row(("depressor_anguli_oris", "left")).slider.value() == 200
    dock.link_check.setChecked(False)
    dock.row(("depressor_anguli_oris", "right")).slider.setValue(50)
    assert dock.layer.forces()[("depressor_anguli_oris", "left")] == pytest.approx(20.0)


def test_reset_row_and_reset_all(dock):
    dock.layer.apply(preset("discreet_smile"))
    dock.row(("risorius", "left")).reset_button.click()
    forces = dock.layer.forces()
    assert forces[("risorius", "left")] == 0.0 and forces[("risorius", "right")] == 42.0
    dock.row(JAW).slider.setValue(50)
    dock.reset_all_button.click()
    assert not any(dock.layer.forces().values()) and dock.layer.jaw_deg == 0.0
    assert all(row.value == 0.0 for row in dock.rows.values())
    assert dock.status == "at rest"


def test_one_undo_step_per_drag(dock, win):
    from app.undo import gestures

    gestures().new()
    slider = dock.row(("mentalis", "left")).slider
    for v in (10, 40, 80, 120):  # one drag: many values, one gesture
        slider.setValue(v)
    assert win.undo_stack.count() == 1
    gestures().new()
    dock.apply_preset("kiss")
    assert win.undo_stack.count() == 2
    win.undo_stack.undo()
    assert dock.layer.forces()[("orbicularis_oris", None)] == 0.0
    assert dock.layer.forces()[("mentalis", "left")] == pytest.approx(12.0)
    win.undo_stack.undo()
    assert dock.layer.forces()[("mentalis", "left")] == 0.0
    assert dock.row(("mentalis", "left")).slider.value() == 0
    win.undo_stack.redo()
    assert dock.layer.forces()[("mentalis", "left")] == pytest.approx(12.0)


# ------------------------------------------------------------------ presets and files
@pytest.mark.parametrize("name", ["discreet_smile", "disgust"])
def test_preset_apply_sets_the_thesis_forces(dock, qtbot, name):
    assert name in preset_names()
    dock.preset_combo.setCurrentIndex(dock.preset_combo.findData(name))
    dock.apply_button.click()
    expected = preset(name)
    assert dock.layer.forces() == pytest.approx(expected.full())
    assert dock.layer.jaw_deg == pytest.approx(expected.jaw_deg)
    for key, value in expected.full().items():
        assert dock.row(key).spin.value() == pytest.approx(value)
    if name == "discreet_smile":  # thesis C §5.2
        assert dock.layer.forces()[("risorius", "left")] == 42 and dock.layer.forces()[("zygomatic_major", "right")] == 9


def test_save_open_round_trip(dock, tmp_path):
    dock.apply_preset("disgust")  # asymmetric
    dock.set_control(JAW, 4.5)
    saved = dock.layer.forces()
    path = tmp_path / "mine.json"
    assert dock.save_force_file(path)
    assert json.loads(path.read_text())["jaw_deg"] == pytest.approx(4.5)
    dock.simulation.reset_all()
    assert not any(dock.layer.forces().values())
    assert dock.open_force_file(path)
    assert dock.layer.forces() == pytest.approx(saved)
    assert dock.layer.jaw_deg == pytest.approx(4.5)
    assert dock.row(("zygomatic_minor", "left")).spin.value() == pytest.approx(14.0)


@pytest.mark.parametrize("text", ["{not json", json.dumps({"format": "mimica-muscle-forces", "version": 1,
                                                            "forces": {"risorius": {"left": 999}}})])
def test_malformed_force_file_shows_the_message_and_keeps_the_forces(dock, tmp_path, error_boxes, text):
    from core.layers.muscles import ForceFileError, load_force_set

    dock.apply_preset("sadness")
    before = dock.layer.forces()
    bad = tmp_path / "bad.json"
    bad.write_text(text)
    with pytest.raises(ForceFileError) as info:
        load_force_set(bad)
    assert not dock.open_force_file(bad)
    assert len(error_boxes) == 1
    title, message = error_boxes[0]
    assert "bad.json" in title and message == str(info.value)
    assert dock.layer.forces() == before


# ------------------------------------------------------------------ live solve and viewport
def test_viewport_follows_a_muscle_slider_once_settled(dock, win, qtbot):
    before = np.array(win.face_actor.mesh.points)
    dock.row(("zygomatic_major", "left")).slider.setValue(400)
    assert dock.simulation.settling  # the relax timer drives the solve
    _settle(qtbot, win, dock)
    assert dock.status == "equilibrium"
    after = np.array(win.face_actor.mesh.points)
    moved = np.linalg.norm(after - before, axis=1)
    assert moved.max() > 1.0  # mm
    # Known answer: the zygomatic major pulls the mouth corner up toward the cheekbone.
    (_n, _s, P, R, _a), = [s for s in dock.layer.muscle_segments() if s[:2] == ("zygomatic_major", "left")]
    near = np.linalg.norm(before - P, axis=1) < 8.0
    assert (after - before)[near, 1].mean() > 0.2
    assert np.dot((after - before)[near].mean(axis=0), R - P) > 0
    assert dock.simulation.last_relax is not None and dock.simulation.last_settle_s is not None


def test_muscles_toggle_adds_and_removes_the_actor(dock, win, qtbot):
    renderer = win.plotter.renderer
    assert "muscles" not in renderer.actors
    dock.show_check.click()
    assert dock.show_check.isChecked() and "muscles" in renderer.actors
    view = dock.view
    assert view.n_segments == 18 + len(dock.layer.muscle_ring()[0])
    actor = view.actor
    points0 = np.array(view.mesh.points)
    assert np.all(view.activations == 0)
    dock.row(("risorius", "right")).slider.setValue(500)
    _settle(qtbot, win, dock)
    i = view.keys.index(("risorius", "right"))
    assert view.activations[i] > 0.5 and view.activations[view.keys.index(("risorius", "left"))] == 0
    assert view.actor is actor  # updated in place
    assert not np.allclose(np.array(view.mesh.points), points0)
    dock.show_check.click()
    assert "muscles" not in renderer.actors


def test_animate_plays_in_wall_clock_time_then_settles(dock, win, qtbot):
    dock.apply_preset("discreet_smile")
    _settle(qtbot, win, dock)
    dock.animate_button.click()
    assert dock.simulation.animating and dock.stop_button.isEnabled()
    assert dock.layer.mode == "dynamic"
    qtbot.waitUntil(lambda: not dock.simulation.animating, timeout=TIMEOUT_MS)
    assert dock.layer.time > 0.3  # simulated seconds played
    _settle(qtbot, win, dock)
    assert dock.status == "equilibrium"
    assert dock.layer.forces() == pytest.approx(preset("discreet_smile").full())


def test_stop_and_rest(dock, win, qtbot):
    dock.apply_preset("sadness")
    dock.simulation.animate()
    qtbot.wait(100)
    dock.stop_button.click()
    assert not dock.simulation.animating
    dock.rest_button.click()  # animated back to neutral
    assert dock.simulation.animating and not any(dock.layer.forces().values())
    qtbot.waitUntil(lambda: not dock.simulation.animating, timeout=TIMEOUT_MS)
    _settle(qtbot, win, dock)
    assert dock.status == "at rest"


def test_solver_diverged_stops_and_reports(dock, win, qtbot, monkeypatch):
    def boom(budget_s=0.02):
        raise SolverDiverged("the tissue simulation blew up; lower the forces")

    monkeypatch.setattr(dock.layer, "relax", boom)
    dock.row(("mentalis", "right")).slider.setValue(100)
    qtbot.waitUntil(lambda: not dock.simulation.settling, timeout=TIMEOUT_MS)
    assert "blew up" in dock.status
    assert "blew up" in win.statusBar().currentMessage()
    assert dock.row(("mentalis", "right")).slider.value() == 100  # the layer's controls are shown
    monkeypatch.undo()


def test_same_face_new_rig_reuses_the_layer(dock, win, qtbot, default_face, deformer):
    from core.rig import FaceRig

    layer = dock.layer
    dock.set_control(("risorius", "left"), 10.0)
    old_rig = win.rig
    win.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    assert dock.layer is layer and dock.rig is win.rig
    assert "muscles" in win.rig._layers and "muscles" not in old_rig._layers
    assert not any(layer.forces().values())  # a new rig starts neutral


def test_corrected_landmarks_on_the_same_face_mean_a_new_build(synthetic_face):
    """Tools > Rebuild animation hands back the same Face object with moved landmarks."""
    from app.muscle_simulation import face_signature as _face_signature

    before = _face_signature(synthetic_face)
    assert _face_signature(synthetic_face) == before
    name = synthetic_face.landmark_names[0]
    other = synthetic_face.landmarks[synthetic_face.landmark_names[1]]
    synthetic_face.set_landmark(name, other)
    assert _face_signature(synthetic_face) != before


def test_choosing_a_preset_applies_it_like_the_fap_presets(dock, win, qtbot):
    index = dock.preset_combo.findData("kiss")
    steps = win.undo_stack.count()
    dock.preset_combo.activated.emit(index)         # what a user's choice in the list sends
    assert dock.layer.forces()[("orbicularis_oris", None)] == preset("kiss").full()[("orbicularis_oris", None)]
    assert win.undo_stack.count() == steps + 1


def test_preset_box_follows_the_forces_from_anywhere(dock, win):
    """The box shows the preset the forces match, whoever set them (a choice in the list, an edit,
    undo, redo, a script or a timeline frame): "Custom" when they match none, "None" at rest."""
    from app.undo import gestures

    combo = dock.preset_combo
    assert combo.currentData() is None and combo.currentText() == "None"
    gestures().new()
    combo.activated.emit(combo.findData("sadness"))
    assert combo.currentData() == "sadness"
    gestures().new()
    dock.set_control(("mentalis", "left"), 10.0)
    assert combo.currentData() is None and combo.currentText() == "Custom"
    win.undo_stack.undo()
    assert combo.currentData() == "sadness"
    win.undo_stack.undo()
    assert combo.currentData() is None and combo.currentText() == "None"
    win.undo_stack.redo()
    assert combo.currentData() == "sadness"
    kiss = preset("kiss")
    win.rig.set_values({**{key_of(k): v for k, v in kiss.full().items()}, "jaw": kiss.jaw_deg})  # not via the dock
    assert combo.currentData() == "kiss" and combo.currentText() == "Kiss"
    dock.simulation.reset_all()
    assert combo.currentData() is None and combo.currentText() == "None"
    # The placeholder is not a choice: only presets can be picked.
    assert not combo.model().item(0).isEnabled()


def test_apply_again_marks_the_preset_on_the_sliders(dock):
    """After edits the sliders mark where the preset "Apply again" applies puts them (set_mark, as
    the FAP dock marks its active presets); none while the forces are the preset's."""
    dock.apply_preset("discreet_smile")
    assert all(row.mark is None for row in dock.rows.values())
    assert dock.apply_button.isEnabled()
    dock.set_control(("risorius", "left"), 10.0)
    row = dock.row(("risorius", "left"))
    assert dock.preset_combo.currentText() == "Custom"
    assert row.mark == pytest.approx(42.0) and "Discreet smile puts it at 42" in row.slider.toolTip()
    assert dock.row(("orbicularis_oris", None)).mark is None  # the preset leaves it at 0: no mark
    dock.apply_button.click()                                # applies the marked preset again
    assert dock.layer.forces()[("risorius", "left")] == 42.0
    assert dock.preset_combo.currentData() == "discreet_smile"
    assert all(row.mark is None for row in dock.rows.values()) and "puts it" not in row.slider.toolTip()


def test_a_cancelled_close_leaves_the_muscles_working(qtbot, built, settings, error_boxes, default_face, deformer,
                                                      monkeypatch):
    """Closing with unsaved changes asks Save / Discard / Cancel. After Cancel the muscle dock still
    follows the rig and settles; only a close that happens stops its simulation. (Here the dock is
    attached after the project's question, so a dock that stopped on any Close event would be dead.)"""
    from PySide6.QtWidgets import QMessageBox

    import core.layers.muscles as muscles
    from app.main_window import MainWindow
    from app.timeline_dock import TimelineDock
    from core.rig import FaceRig

    twin = built[0].muscle_dock.layer.copy()   # the same model: no second build of seconds
    monkeypatch.setattr(muscles, "MuscleLayer", lambda face, level=3, template_dense=None: twin)
    answers = [QMessageBox.StandardButton.Cancel, QMessageBox.StandardButton.Discard]
    monkeypatch.setattr(QMessageBox, "question", lambda *args, **kwargs: answers.pop(0))
    w = MainWindow(settings=settings, load_default=False, tools=False)
    qtbot.addWidget(w)
    w.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    w.show()
    TimelineDock(w.document, w, check_recovery=False)
    d = MuscleDock(w.document, w)
    qtbot.waitUntil(lambda: d.layer is twin, timeout=TIMEOUT_MS)
    w.document.project.ask_on_close = True
    w.rig.set_values({"fap:3": 200.0})
    w.timeline.set_key(["fap:3"])
    assert w.document.project.is_modified

    assert not w.close() and answers == [QMessageBox.StandardButton.Discard]   # Cancel
    assert not d.simulation.closed
    w.rig.set_values({"muscle:risorius:left": 10.0})       # from anywhere (undo, the timeline)
    assert d.row(("risorius", "left")).value == 10.0 and d.simulation.settling
    qtbot.waitUntil(lambda: d.status == "equilibrium", timeout=TIMEOUT_MS)
    d.set_control(("risorius", "right"), 5.0)              # and from the dock
    assert twin.forces()[("risorius", "right")] == 5.0 and d.simulation.settling

    assert w.close() and not answers                       # Discard: the window closes
    assert d.simulation.closed and not d.simulation.settling and d.view is None
    twin.set_force("risorius", "left", 20.0)
    assert not d.simulation.settling and d.row(("risorius", "left")).value == 10.0
