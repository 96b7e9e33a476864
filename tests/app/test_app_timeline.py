"""The timeline dock driving a real FaceRig on the default face: keys, scrubbing, playback, undo,
auto-key, clipboard, interpolation, settings and lip-sync.

The FAP deformer of the default face is built once per module; every test gets a fresh FaceRig in a
fresh MainWindow with an :class:`app.timeline_dock.TimelineDock` built on its document.
"""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtCore import QPoint, Qt
from PySide6.QtWidgets import QMessageBox

from app.timeline_dock import TimelineDock, TrackView
from core.timeline import Track

TICK_TIMEOUT_MS = 5000


# ------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def shared(qapp, default_face, deformer, tmp_path_factory):
    """One window with the timeline for the whole module (building the default face's window takes
    seconds); every test starts from :func:`reset_timeline_window`."""
    from PySide6.QtCore import QSettings

    from app.main_window import MainWindow
    from core.rig import FaceRig

    folder = tmp_path_factory.mktemp("timeline_window")
    settings = QSettings(str(folder / "mimica-test.ini"), QSettings.Format.IniFormat)
    w = MainWindow(settings=settings, load_default=False, tools=False)
    w.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    w.show()
    controller = TimelineDock(w.document, w, state_dir=folder / "state", check_recovery=False).controller
    yield w, controller
    w.close()
    w.deleteLater()


def reset_timeline_window(w, c) -> None:
    """Back to an untitled project: empty 10 s / 30 fps timeline, neutral rig, empty undo stack."""
    from core.timeline import Timeline

    c.stop(rewind=False)
    c.set_auto_key(False)
    c.loop = False
    c.set_speed(1.0)
    dialog = c.dock.lipsync_dialog
    if dialog is not None:
        dialog.close()
    c.set_selected_tracks(set())
    c.set_selection({})
    c.clipboard = None
    c._set_speech([])
    c.dock.show_all_check.setChecked(False)
    c.dock.view.collapsed.clear()
    c.dock.view.fit()
    rig = w.rig
    rig.reset_faps()
    rig.set_expression(None)
    rig.set_viseme(None)
    c.set_timeline(Timeline())
    w.undo_stack.clear()
    c.project.path = None
    c.project._mark_clean()
    c.dock.sync()
    w.flush_updates()


@pytest.fixture
def questions(monkeypatch):
    """QMessageBox.question answers Discard (never blocks); the calls are recorded."""
    calls = []

    def fake(parent, title, text, *args, **kwargs):
        calls.append((title, text))
        return QMessageBox.StandardButton.Discard

    monkeypatch.setattr(QMessageBox, "question", fake)
    return calls


@pytest.fixture
def win(qtbot, shared, error_boxes, questions):
    w, controller = shared
    reset_timeline_window(w, controller)
    qtbot.waitExposed(w)
    return w


@pytest.fixture
def c(win, shared):
    return shared[1]


@pytest.fixture
def rig(win):
    return win.rig


@pytest.fixture
def view(c) -> TrackView:
    return c.dock.view


def _ruler_click(qtbot, view: TrackView, t: float) -> None:
    qtbot.mouseClick(view, Qt.MouseButton.LeftButton, pos=QPoint(int(round(float(view.x_of(t)))), 12))


def _key_point(view: TrackView, key: str, t: float) -> QPoint:
    i = view.row_index(key)
    assert i is not None, f"no row for {key}"
    return QPoint(int(round(float(view.x_of(t)))), int(view.row_top(i) + view.ROW_H / 2))


def _points(win) -> np.ndarray:
    return np.array(win.face_actor.mesh.points, copy=True)


# ------------------------------------------------------------------ layout
def test_dock_adds_itself_menus_and_the_fap_actions(win, c):
    assert win.timeline is c and win.document.timeline is c and c.dock.isVisible()
    assert win.dockWidgetArea(c.dock) == Qt.DockWidgetArea.BottomDockWidgetArea
    assert not hasattr(win, "fap_player_dock")   # the timeline plays .fap files; the player is retired
    assert c.actions["import_animation"].shortcut().toString() == "Ctrl+Shift+O"
    assert c.actions["export_fap"].shortcut().toString() == "Ctrl+Shift+E"
    titles = [a.text().replace("&", "") for a in win.menuBar().actions()]
    assert titles.index("File") < titles.index("Edit") < titles.index("View") < titles.index("Tools") \
        < titles.index("Help")
    assert c.actions["set_key"].shortcut().toString() == "K"
    assert c.actions["timeline"] in win.view_menu.actions()
    file_texts = [a.text() for a in win.menuBar().actions()[0].menu().actions()]
    assert file_texts[:4] == ["&New project", "&Open project…", "&Save project", "Save project &as…"]
    # no two window actions share a shortcut (an ambiguous shortcut does nothing in Qt)
    seen = {}
    for act in win.findChildren(type(c.actions["set_key"])):
        if act.shortcutContext() == Qt.ShortcutContext.WidgetShortcut:
            continue
        for seq in act.shortcuts():
            if not seq.isEmpty():
                assert seq.toString() not in seen, (seq.toString(), act.text(), seen.get(seq.toString()))
                seen[seq.toString()] = act.text()
    assert c.dock.empty_label.isVisible() and not [r for r in c.dock.view.rows if not r.is_group]


def test_every_timeline_control_stays_in_sight_in_a_narrow_dock(qtbot, win, c):
    """The toolbar wraps onto a second row instead of scrolling fps and length out of sight."""
    dock = c.dock
    widths = []
    for width in (1500, 900):
        win.resize(width, 900)
        qtbot.wait(50)
        bar = dock.findChild(type(dock.widget()), "timelineBar")
        for w in (dock.play_button, dock.key_button, dock.lipsync_button, dock.fps_combo, dock.duration_spin):
            top_left = w.mapTo(dock, w.rect().topLeft())
            assert w.isVisible() and dock.rect().contains(top_left) and \
                dock.rect().contains(top_left + w.rect().bottomRight()), (width, w.objectName())
        widths.append((dock.width(), bar.height()))
    win.resize(1400, 900)   # the module's shared window, as it was
    (wide, wide_h), (narrow, narrow_h) = widths
    assert narrow < wide and narrow_h > wide_h, "the narrow dock's bar wraps onto a second row"


# ------------------------------------------------------------------ keys, scrubbing
def test_keys_set_in_the_ui_interpolate_when_scrubbing(qtbot, win, c, view, rig):
    jaw = win.fap_dock.row(3).slider
    _ruler_click(qtbot, view, 0.0)
    assert c.current_time == 0.0
    jaw.setValue(100)
    qtbot.mouseClick(c.dock.key_button, Qt.MouseButton.LeftButton)
    _ruler_click(qtbot, view, 1.0)
    assert c.current_time == pytest.approx(1.0)
    jaw.setValue(900)
    qtbot.keyClick(view, Qt.Key.Key_K)  # the window shortcut
    track = c.timeline.track("fap:3")
    assert track.times.tolist() == [0.0, 1.0] and track.values.tolist() == [100.0, 900.0]
    assert [r.key for r in view.rows if not r.is_group] == ["fap:3"]
    assert not c.dock.empty_label.isVisible()

    win.flush_updates()
    at_one = _points(win)
    # scrub: press at 1 s, drag through the ruler to 0.5 s
    qtbot.mousePress(view, Qt.MouseButton.LeftButton, pos=QPoint(int(view.x_of(1.0)), 12))
    qtbot.mouseMove(view, QPoint(int(view.x_of(0.75)), 12))
    qtbot.mouseMove(view, QPoint(int(round(float(view.x_of(0.5)))), 12))
    qtbot.mouseRelease(view, Qt.MouseButton.LeftButton, pos=QPoint(int(round(float(view.x_of(0.5)))), 12))
    assert c.current_time == pytest.approx(0.5)
    expected = track.evaluate(0.5)
    assert 100 < expected < 900
    assert rig.fap_value(3) == expected
    assert win.fap_dock.row(3).slider.value() == round(expected)
    qtbot.waitUntil(lambda: not win._tick_timer.isActive(), timeout=TICK_TIMEOUT_MS)
    at_half = _points(win)
    assert np.abs(at_half - at_one).max() > 0.5, "the viewport follows the scrub"
    np.testing.assert_allclose(at_half, rig.vertices(), atol=1e-4)
    # scrubbing is not an undo step
    assert win.undo_stack.undoText().startswith("set key")


def test_play_advances_in_wall_clock_time_and_pause_stops(qtbot, win, c, rig):
    c.set_key(["fap:3"], 0.0)
    rig.set_fap(3, 1000)
    c.set_key(["fap:3"], 2.0)
    c.seek(0.0)
    qtbot.mouseClick(c.dock.play_button, Qt.MouseButton.LeftButton)
    assert c.playing and c.dock.play_button.isChecked()
    qtbot.waitUntil(lambda: c.current_time > 0.2 and c.frames_shown >= 3, timeout=10000)
    qtbot.mouseClick(c.dock.play_button, Qt.MouseButton.LeftButton)
    assert not c.playing
    stopped = c.current_time
    assert rig.fap_value(3) == c.timeline.track("fap:3").evaluate(stopped) > 0
    qtbot.wait(200)
    assert c.current_time == stopped, "pause stops the clock"
    assert c.frames_shown >= 2 and c.achieved_fps > 0 and "fps" in c.dock.fps_label.text()
    # playback never records undo steps
    assert "set key" in win.undo_stack.undoText()
    # at the end without loop it stops at the last frame
    c.set_speed(4.0)
    c.seek(c.timeline.duration - 0.1)
    c.play()
    qtbot.waitUntil(lambda: not c.playing, timeout=5000)
    assert c.current_time == pytest.approx(c.timeline.duration)
    qtbot.mouseClick(c.dock.stop_button, Qt.MouseButton.LeftButton)
    assert c.current_time == 0.0


def test_loop_wraps_around(qtbot, c):
    c.set_settings(duration=0.5)
    c.loop = True
    c.set_speed(2.0)
    c.seek(0.4)
    c.play()
    qtbot.waitUntil(lambda: c.current_time < 0.3, timeout=5000)
    assert c.playing
    c.pause()


def test_undo_redo_of_a_key_edit_restores_exact_values(qtbot, win, c, rig):
    stack = win.undo_stack
    rig.set_fap(3, 321.5)
    c.set_key(["fap:3"], 0.0)
    c.seek(1.0)
    rig.set_faps({3: 777.25, 4: -123.0})
    c.set_key()  # tracked fap:3 + non-neutral fap:4
    before = dict(c.timeline.tracks)
    assert set(before) == {"fap:3", "fap:4"}
    c.seek(0.5)
    value_before = rig.fap_value(3)
    c.set_key(["fap:3"], 1.0)  # replaces the key at 1 s with the current (interpolated) value
    c.seek(0.5)
    assert c.timeline.track("fap:3").values[1] == value_before != 777.25
    stack.undo()
    assert c.timeline.tracks["fap:3"] == before["fap:3"] and c.timeline.tracks["fap:4"] == before["fap:4"]
    assert rig.fap_value(3) == before["fap:3"].evaluate(0.5)
    stack.redo()
    assert c.timeline.track("fap:3").values.tolist() == [321.5, value_before]
    assert rig.fap_value(3) == c.timeline.track("fap:3").evaluate(0.5)
    while stack.canUndo():
        stack.undo()
    assert not c.timeline.tracks


def test_auto_key_records_a_slider_change(qtbot, win, c, view, rig):
    stack = win.undo_stack
    qtbot.mouseClick(c.dock.auto_key_button, Qt.MouseButton.LeftButton)
    assert c.auto_key and c.actions["auto_key"].isChecked()
    c.seek(0.5)
    count = stack.count()
    slider = win.fap_dock.row(3).slider
    qtbot.mousePress(slider, Qt.MouseButton.LeftButton)  # one gesture: the drag below
    for v in (100, 200, 300, 420):
        slider.setValue(v)
    track = c.timeline.track("fap:3")
    assert track.times.tolist() == [0.5] and track.values.tolist() == [420.0]
    assert stack.count() == count + 1, "a drag is one undo step"
    assert "auto-key" in stack.undoText()
    assert view.row_index("fap:3") is not None
    stack.undo()
    assert "fap:3" not in c.timeline.tracks and rig.fap_value(3) == 0.0 and slider.value() == 0
    stack.redo()
    assert c.timeline.track("fap:3").values.tolist() == [420.0] and rig.fap_value(3) == 420.0
    # not while playing
    c.play()
    rig.set_fap(4, 50)
    c.pause()
    assert "fap:4" not in c.timeline.tracks
    qtbot.mouseClick(c.dock.auto_key_button, Qt.MouseButton.LeftButton)
    assert not c.auto_key
    count = stack.count()
    rig.set_fap(5, 80)
    assert "fap:5" not in c.timeline.tracks
    assert stack.count() == count + 1 and "auto-key" not in stack.undoText()  # the rig recorder is back


def test_presets_are_keyed_as_intensities(qtbot, win, c, rig):
    c.set_auto_key(True)
    win.fap_dock.expression_combo.setCurrentIndex(1)  # joy at 100 %
    assert c.timeline.track("expression:joy").values.tolist() == [1.0]
    c.seek(1.0)
    win.fap_dock.expression_combo.setCurrentIndex(0)  # neutral: joy keyed to 0
    assert c.timeline.track("expression:joy").values.tolist() == [1.0, 0.0]
    c.seek(0.5)
    assert rig.expression[0] == 1 and rig.expression[1] == c.timeline.track("expression:joy").evaluate(0.5)


def test_select_delete_copy_paste_keys_with_mouse_and_keyboard(qtbot, win, c, view, rig):
    for t, v in ((0.0, 100.0), (1.0, 500.0), (2.0, 200.0)):
        rig.set_fap(3, v)
        c.set_key(["fap:3"], t)
    rig.set_fap(4, 60)
    c.set_key(["fap:4"], 1.0)
    # click selects one key, shift-click adds one
    qtbot.mouseClick(view, Qt.MouseButton.LeftButton, pos=_key_point(view, "fap:3", 1.0))
    assert c.selection() == {"fap:3": (1.0,)}
    qtbot.mouseClick(view, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.ShiftModifier,
                     _key_point(view, "fap:4", 1.0))
    assert c.selection() == {"fap:3": (1.0,), "fap:4": (1.0,)}
    # rubber band over the first two keys of fap:3 only
    a = _key_point(view, "fap:3", 0.0) + QPoint(-8, -7)
    b = _key_point(view, "fap:3", 1.0) + QPoint(8, 7)
    qtbot.mousePress(view, Qt.MouseButton.LeftButton, pos=QPoint(a.x(), a.y()))
    qtbot.mouseMove(view, QPoint((a.x() + b.x()) // 2, b.y()))
    qtbot.mouseMove(view, b)
    qtbot.mouseRelease(view, Qt.MouseButton.LeftButton, pos=b)
    assert c.selection() == {"fap:3": (0.0, 1.0)}
    # copy, paste at the cursor
    c.actions["copy_keys"].trigger()
    c.seek(3.0)
    c.actions["paste_keys"].trigger()
    track = c.timeline.track("fap:3")
    assert track.times.tolist() == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert track.values.tolist() == [100.0, 500.0, 200.0, 100.0, 500.0]
    assert c.selection() == {"fap:3": (3.0, 4.0)}, "the pasted keys are selected"
    # Delete removes the selected keys
    view.setFocus()
    qtbot.keyClick(view, Qt.Key.Key_Delete)
    assert c.timeline.track("fap:3").times.tolist() == [0.0, 1.0, 2.0] and not c.selection()
    win.undo_stack.undo()
    assert c.timeline.track("fap:3").times.tolist() == [0.0, 1.0, 2.0, 3.0, 4.0]
    win.undo_stack.undo()  # the paste
    assert c.timeline.track("fap:3").times.tolist() == [0.0, 1.0, 2.0]


def test_drag_keys_in_time_and_set_interpolation(qtbot, win, c, view, rig):
    rig.set_fap(3, 100)
    c.set_key(["fap:3"], 0.0)
    rig.set_fap(3, 700)
    c.set_key(["fap:3"], 1.0)
    p = _key_point(view, "fap:3", 1.0)
    target = QPoint(int(round(float(view.x_of(2.0)))), p.y())
    qtbot.mousePress(view, Qt.MouseButton.LeftButton, pos=p)
    qtbot.mouseMove(view, QPoint((p.x() + target.x()) // 2, p.y()))
    qtbot.mouseMove(view, target)
    qtbot.mouseRelease(view, Qt.MouseButton.LeftButton, pos=target)
    track = c.timeline.track("fap:3")
    assert track.times.tolist() == [0.0, 2.0] and track.values.tolist() == [100.0, 700.0]
    assert c.selection() == {"fap:3": (2.0,)}
    assert "move keys" in win.undo_stack.undoText()
    c.set_selection({"fap:3": [0.0]})
    c.set_interpolation("step")
    c.seek(1.0)
    assert rig.fap_value(3) == 100.0, "a step key holds its value"
    c.set_interpolation("linear")
    c.seek(1.0)
    assert rig.fap_value(3) == pytest.approx(400.0)
    win.undo_stack.undo()
    win.undo_stack.undo()
    assert c.timeline.track("fap:3").codes.tolist() == [2, 2]


def test_track_selection_decides_what_set_key_keys(qtbot, win, c, view, rig):
    qtbot.mouseClick(c.dock.show_all_check, Qt.MouseButton.LeftButton)
    assert view.row_index("fap:19") is not None and view.row_index("viseme:1") is not None
    rig.set_faps({3: 300, 19: 200})
    i = view.row_index("fap:19")
    qtbot.mouseClick(view, Qt.MouseButton.LeftButton, pos=QPoint(40, int(view.row_top(i) + 5)))
    assert c.selected_tracks == {"fap:19"}
    c.set_key()
    assert set(c.timeline.tracks) == {"fap:19"}
    c.set_selected_tracks(set())
    c.set_key()
    assert set(c.timeline.tracks) == {"fap:3", "fap:19"}
    # folding a group hides its rows
    group = next(r for r in view.rows if r.is_group and r.group == "eyelids")
    gi = view.rows.index(group)
    qtbot.mouseClick(view, Qt.MouseButton.LeftButton, pos=QPoint(40, int(view.row_top(gi) + 5)))
    assert "eyelids" in view.collapsed and view.row_index("fap:19") is None


def test_fps_and_duration_settings_are_undoable(qtbot, win, c, rig):
    combo = c.dock.fps_combo
    combo.setCurrentIndex(combo.findData(24))
    combo.activated.emit(combo.currentIndex())
    assert c.timeline.fps == 24
    win.undo_stack.undo()
    assert c.timeline.fps == 30 and combo.currentData() == 30
    rig.set_fap(3, 100)
    c.set_key(["fap:3"], 8.0)
    c.dock.duration_spin.setValue(5.0)
    assert c.timeline.duration == 10.0 and c.dock.duration_spin.value() == 10.0, "keys up to 8 s: refused"
    c.dock.duration_spin.setValue(20.0)
    assert c.timeline.duration == 20.0
    c.seek(15.0)
    win.undo_stack.undo()
    assert c.timeline.duration == 10.0 and c.current_time == 10.0


def test_lipsync_dialog_adds_viseme_tracks_as_one_undo_step(qtbot, win, c, rig):
    # No number box of an earlier test keeps the keyboard (its pending text would land as an edit).
    win.plotter.setFocus()
    qtbot.wait(20)
    win.undo_stack.clear()
    c.seek(9.0)
    dialog = c.dock.open_lipsync_dialog()
    assert dialog.start_spin.value() == 9.0
    dialog.text_edit.setPlainText("Olá, como vai você?")
    dialog.set_language("pt-br")
    qtbot.mouseClick(dialog.add_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: dialog.last_result is not None or not dialog.busy, timeout=30000)
    result = dialog.last_result
    assert result is not None, dialog.status_label.text()
    stack = win.undo_stack
    lipsync_steps = [i for i in range(stack.count()) if stack.text(i).startswith("lip-sync")]
    assert len(lipsync_steps) == 1, "the whole lip-sync is one undo step"
    visemes = [k for k in c.timeline.tracks if k.startswith("viseme:")]
    assert visemes and set(result.tracks) <= set(c.timeline.tracks)
    assert c.timeline.duration >= result.end_s and c.timeline.duration > 10.0
    assert len(c.speech) == 1 and c.speech[0].lang == "pt-br" and c.speech[0].start_s == 9.0
    assert "Added" in dialog.status_label.text()
    audio = c.audio_path()
    assert audio is not None and audio.is_file()
    # the audio is aligned with timeline time 0: 9 s of silence first
    import wave

    with wave.open(str(audio)) as w:
        rate, n = w.getframerate(), w.getnframes()
        head = np.frombuffer(w.readframes(int(8.9 * rate)), "<i2")
    assert n / rate == pytest.approx(9.0 + result.duration_s, abs=0.01) and not head.any()
    # scrubbing into the speech opens the mouth with a viseme
    mid = next(s for s in result.segments if s.viseme != 0)
    c.seek((mid.start_s + mid.end_s) / 2)
    assert rig.viseme[0] != 0 and rig.viseme[1] > 0
    # Back to before the lip-sync step. (A stray "3 open jaw" step can follow it in the full suite: a known
    # bug, see the session notes; undoing by index keeps this test about the lip-sync step.)
    stack.setIndex(lipsync_steps[0])
    assert not [k for k in c.timeline.tracks if k.startswith("viseme:")]
    assert c.timeline.duration == 10.0 and not c.speech
    dialog.close()


def test_lipsync_reports_empty_text(qtbot, c):
    dialog = c.dock.open_lipsync_dialog()
    dialog.text_edit.setPlainText("   ")
    assert not dialog.generate() and "Type some text" in dialog.status_label.text()
    with pytest.raises(ValueError, match="unknown lip-sync language"):
        dialog.set_language("xx")
    dialog.close()


def test_tracks_of_faps_the_face_cannot_animate_are_skipped(qtbot, c, rig, monkeypatch):
    # e.g. a face without eyeballs has no gaze FAPs: their tracks are ignored, the others still play
    monkeypatch.setattr(rig.deformer, "animated_faps", tuple(n for n in rig.animated_faps if n != 23))
    c.push(lambda: c.timeline.replace_tracks({
        "fap:23": Track("fap:23", [(0.0, 0.0), (1.0, 10000.0)]),
        "fap:3": Track("fap:3", [(0.0, 0.0), (1.0, 500.0)])}))
    c.seek(0.5)
    assert rig.fap_value(23) == 0.0 and rig.fap_value(3) == c.timeline.track("fap:3").evaluate(0.5) > 0


def test_muscle_tracks_drive_the_muscle_layer_through_the_simulation_cache(qtbot, win, c, view, monkeypatch):
    from app.timeline_controller import muscle_keys

    from core.layer import ValueLayer

    class FakeLayer(ValueLayer):
        """A dynamic 'muscles' layer integrating state += force · dt, so the state at a frame is a known sum."""

        name = "muscles"
        dynamic = True

        def __init__(self):
            super().__init__(muscle_keys())
            self.state = 0.0

        @property
        def forces(self):
            return {k: v for k, v in self._values.items() if k != "jaw"}

        def offset(self, x):
            return None

        def start_animation(self):
            pass

        def advance(self, dt):
            self.state += dt * sum(self.forces.values())

        def snapshot(self):
            return self.state, super().snapshot()

        def restore(self, snapshot):
            self.state = snapshot[0]
            super().restore(snapshot[1])

        def relax(self, budget_s):
            pass

    layer = FakeLayer()
    rig = win.rig
    rig.add_layer(layer)
    key = muscle_keys()[0]
    target = key
    force = Track(key, [(0.0, 0.0, "linear"), (1.0, 3.0, "linear")])
    c.push(lambda: c.timeline.replace_tracks({key: force, "jaw": Track("jaw", [(0.0, 0.0), (1.0, 8.0)])}))
    c.seek(0.5)
    fps = c.timeline.fps
    frames = np.arange(15) / fps  # frame 15 is reached with the forces of frames 0..14
    assert layer.state == pytest.approx(float(np.sum(force.evaluate(frames)) / fps))
    assert layer.forces[target] == force.evaluate(14 / fps)
    assert view.row_index(key) is not None and view.row_index("jaw") is not None
    # Set key reads the layer's values
    c.set_key([key], 2.0)
    assert c.timeline.track(key).values[-1] == layer.forces[target]
    rig.remove_layer("muscles")


def test_keyed_animation_exports_to_mp4_with_the_frames_it_plays(qtbot, win, c, rig, tmp_path):
    """Key the jaw in the window, export through the window's export job, read the frames back."""
    import imageio_ffmpeg

    from app.export import ExportSettings
    from app.export_dialog import start_export

    jaw = win.fap_dock.row(3).slider
    c.seek(0.0)
    jaw.setValue(0)
    c.set_key(["fap:3"])
    c.seek(1.0)
    jaw.setValue(900)
    c.set_key(["fap:3"])
    out = tmp_path / "jaw.mp4"
    settings = ExportSettings(path=out, end_s=1.0, size=(320, 240), fps=10)
    job = start_export(win, win.face, c.frame_vertices, settings)
    results = []
    job.finished.connect(results.append)
    qtbot.waitUntil(lambda: bool(results), timeout=120_000)
    assert results[0].frames == 10 and out.is_file()
    reader = imageio_ffmpeg.read_frames(str(out))
    meta = next(reader)
    assert tuple(meta["size"]) == (320, 240)
    frames = [np.frombuffer(f, np.uint8).reshape(240, 320, 3).astype(int) for f in reader]
    assert len(frames) == 10
    # the mouth opens over the second: the last frame differs from the first (and the first is not blank)
    assert frames[0].std() > 10 and np.abs(frames[-1] - frames[0]).mean() > 0.5


def test_import_fap_file_adds_tracks_at_the_cursor_as_one_undo_step(win, c, tmp_path):
    path = tmp_path / "jaw.fap"
    lines = ["2.1 jaw 10 3"]
    for k in range(3):
        lines += [" ".join("1" if f == 3 else "0" for f in range(1, 69)), f"{k} {300 * k}"]
    path.write_text("\n".join(lines) + "\n")
    c.seek(2.0)
    assert c.import_animation(path) is not None
    track = c.timeline.track("fap:3")
    assert track.times.tolist() == pytest.approx([2.0, 2.1, 2.2]) and track.values.tolist() == [0, 300, 600]
    win.undo_stack.undo()
    assert "fap:3" not in c.timeline.tracks
    messages = []
    c.message.connect(messages.append)
    bad = tmp_path / "bad.fap"
    bad.write_text("2.1 x 25 1\nnot a mask\n")
    assert c.import_animation(bad) is None and messages and "line" in messages[-1]


def test_window_export_and_the_command_line_make_identical_frames(qtbot, win, c, rig, tmp_path):
    """Same project, same frame, identical vertices: the window's export evaluates a copy of its rig
    with core.animation.ProjectAnimation, which is what `mimica export` runs on the saved project."""
    from core.animation import ProjectAnimation
    from core.formats.project import load_project, open_face, save_project

    c.push(lambda: c.timeline.replace_tracks({
        "fap:3": Track("fap:3", [(0.0, 0.0), (1.0, 600.0, "linear"), (2.0, 100.0)]),
        "expression:joy": Track("expression:joy", [(0.0, 0.0), (1.5, 0.8)]),
        "viseme:4": Track("viseme:4", [(0.5, 0.0), (1.0, 0.6, "step")])}))
    c.seek(0.0)
    rig.set_values({"fap:31": 60.0})            # a slider the timeline does not key
    on_screen = rig.vertices().copy()
    path = tmp_path / "same.mimica"
    save_project(path, c.project.current_project(path))
    project = load_project(path)
    headless = ProjectAnimation.for_face(open_face(project), project.timeline, project.rig.values)
    try:
        for t in (0.0, 0.5, 1.0, 4 / 3, 2.0):
            np.testing.assert_array_equal(c.frame_vertices(t), headless.vertices(t))
        assert not np.array_equal(c.frame_vertices(1.0), on_screen)
        np.testing.assert_array_equal(rig.vertices(), on_screen)   # exporting never moved the face shown
    finally:
        headless.close()
        rig.set_values({"fap:31": 0.0})
