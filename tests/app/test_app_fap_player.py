"""The .fap player (app/fap_player.py) on a real FaceRig of the default face.

The .fap texts are written by hand here (not by core.fap_file.format_fap), so a
writer bug cannot hide a player bug. Known answers come from the texts.
"""

from __future__ import annotations

import time

import pytest

from core.fap_file import FapSequence, parse_fap, read_fap
from core.rig import FaceRig


# ------------------------------------------------------------------ fixtures and helpers
@pytest.fixture(scope="module")
def shared_rig():
    from core.default_face import generate_face, load_default_face
    from core.fap.template import TemplateError

    try:
        return FaceRig(load_default_face())
    except TemplateError:  # the committed NPZ predates the current template: build the face afresh
        return FaceRig(generate_face())


@pytest.fixture
def rig(shared_rig):
    shared_rig.reset_faps()
    shared_rig.set_expression(None, 0.0)
    shared_rig.set_viseme(None, 0.0)
    yield shared_rig
    shared_rig.reset_faps()
    shared_rig.set_expression(None, 0.0)
    shared_rig.set_viseme(None, 0.0)


@pytest.fixture
def player(qtbot, rig):
    from app.fap_player import FapPlayer

    p = FapPlayer(rig)
    yield p
    p.pause()


@pytest.fixture
def bar(qtbot, player, error_boxes):
    from app.fap_player import FapPlayerBar

    b = FapPlayerBar(player)
    qtbot.addWidget(b)
    b.show()
    qtbot.waitExposed(b)
    return b


def fap_text(frames: list[dict], fps: float = 25, name: str = "test") -> str:
    """A standard .fap text: frames are {fap: value}, FAP 1 -> 4-tuple, FAP 2 -> 6-tuple."""
    lines = ["# written by the test", f"2.1 {name} {fps:g} {len(frames)}"]
    for k, frame in enumerate(frames):
        lines.append(" ".join("1" if f in frame else "0" for f in range(1, 69)))
        tokens = [str(k)]
        for f in (1, 2):
            if f in frame:
                tokens += [str(t) for t in frame[f]]
        tokens += [f"{frame[f]:g}" for f in sorted(frame) if f > 2]
        lines.append(" ".join(tokens))
    return "\n".join(lines) + "\n"


def seq_of(frames: list[dict], fps: float = 25) -> FapSequence:
    return parse_fap(fap_text(frames, fps))


def jaw_ramp(n: int, fps: float = 25) -> FapSequence:
    """n frames, open_jaw = 50 * k."""
    return seq_of([{3: 50 * k} for k in range(n)], fps)


# ------------------------------------------------------------------ applying frames
def test_seek_applies_the_frame(player, rig):
    player.load(seq_of([{3: 100}, {3: 400}, {3: 900}]))
    assert rig.fap_value(3) == 0  # loading alone does not touch the face
    frames = []
    player.frame_changed.connect(frames.append)
    player.seek(1)
    assert player.frame == 1
    assert rig.fap_value(3) == 400
    player.seek(2)
    assert rig.fap_value(3) == 900
    player.seek(0)
    assert rig.fap_value(3) == 100
    player.seek(99)  # clamped to the last frame
    assert player.frame == 2 and rig.fap_value(3) == 900
    assert frames == [1, 2, 0, 2]


def test_masked_out_faps_hold_their_last_value(player, rig):
    rig.set_fap(31, 120)  # the user's own value, never driven by the file
    player.load(seq_of([
        {3: 300, 5: 50},
        {3: 600},
        {5: -70, 19: 500},
    ]))
    player.seek(1)
    assert rig.fap_value(5) == 50  # held from frame 0
    assert rig.fap_value(3) == 600
    assert rig.fap_value(31) == 120
    player.seek(2)
    assert rig.fap_value(3) == 600  # held from frame 1
    assert rig.fap_value(5) == -70
    assert rig.fap_value(19) == 500
    player.seek(0)  # before FAP 19's first key: back to its value before playback
    assert rig.fap_value(19) == 0
    assert (rig.fap_value(3), rig.fap_value(5), rig.fap_value(31)) == (300, 50, 120)


def test_fap2_and_fap1_frames_set_the_presets(player, rig):
    player.load(seq_of([
        {2: (3, 42, 0, 0, 0, 0), 3: 10},
        {1: (5, 2, 21, 0), 3: 20},
    ]))
    player.seek(0)
    assert rig.expression == (3, pytest.approx(42 / 63))
    assert rig.visemes == ((0, 0.0),)  # FAP 1 not given yet: untouched
    player.seek(1)
    assert rig.expression == (3, pytest.approx(42 / 63))  # FAP 2 held
    assert rig.visemes == ((5, pytest.approx(21 / 63)), (2, pytest.approx(42 / 63)))


def test_one_frame_is_one_rig_update(player, rig, monkeypatch):
    player.load(seq_of([
        {1: (4, 0, 63, 0), 2: (1, 63, 0, 0, 0, 0), 3: 200, 19: 300, 31: 100},
        {3: 300},
    ]))
    emitted = []
    rig.changed.connect(lambda: emitted.append(1))
    calls = []
    original = rig.set_faps
    monkeypatch.setattr(rig, "set_faps", lambda values: (calls.append(dict(values)), original(values)))
    player.seek(0)
    assert len(emitted) == 1
    assert calls == [{3: 200.0, 19: 300.0, 31: 100.0}]
    assert rig.expression == (1, 1.0)
    player.seek(0)  # nothing changes: no redraw
    assert len(emitted) == 1
    player.seek(1)
    assert len(emitted) == 2
    assert calls == [{3: 200.0, 19: 300.0, 31: 100.0}, {3: 300.0}]  # only what changes


# ------------------------------------------------------------------ what cannot be played as is
def test_unanimated_faps_are_skipped_and_reported(player, rig):
    assert 45 not in rig.animated_faps and 66 not in rig.animated_faps
    player.load(seq_of([
        {3: 200, 43: 10, 45: 30},
        {3: 300},
        {3: 400, 66: 50},
    ]))
    player.seek(0)
    assert rig.fap_value(3) == 200  # the animatable FAP of the frame still plays
    assert player.skipped == {43, 45}
    assert rig.fap_value(45) == 0
    assert player.report() == "Played 1 frame; ignored FAPs 43, 45 (tongue: not animated)"
    player.seek(2)
    assert player.skipped == {43, 45, 66}
    assert player.report() == (
        "Played 2 frames; ignored FAPs 43, 45 (tongue: not animated), 66 (ears: not animated)"
    )


def test_values_beyond_the_slider_range_are_recorded_then_limited(player, rig):
    player.load(seq_of([
        {3: 500},
        {3: 1800, 6: -500, 19: 900},
        {3: 1600},
    ]))
    player.seek(0)
    assert player.clipped == {} and player.report() == "Played 1 frame"
    player.seek(1)
    assert rig.fap_value(3) == 1400
    assert rig.fap_value(6) == -400
    assert rig.fap_value(19) == 900  # inside its range: as given
    assert player.clipped == {3: 1800, 6: 500}
    assert player.report() == (
        "Played 2 frames; 2 values beyond the slider range were limited: "
        "open_jaw 1800 > 1400, stretch_l_cornerlip -500 < -400"
    )
    player.seek(2)
    assert player.clipped == {3: 1800, 6: 500}  # 1600 is not the largest
    assert player.report().startswith("Played 3 frames; 3 values beyond the slider range were limited: open_jaw 1800")
    player.seek(1)  # seeing a frame again does not count its values twice
    assert "; 3 values" in player.report()


# ------------------------------------------------------------------ playback in time
def test_play_advances_and_finishes(qtbot, player, rig):
    n = 10
    player.load(jaw_ramp(n, fps=25))  # 0.4 s
    states = []
    player.state_changed.connect(states.append)
    start = time.monotonic()
    with qtbot.waitSignal(player.finished, timeout=5000):
        player.play()
        assert player.is_playing
        qtbot.waitUntil(lambda: player.frame > 0, timeout=2000)
    took = time.monotonic() - start
    assert 0.3 < took < 2.0
    assert not player.is_playing
    assert states == [True, False]
    assert player.frame == n - 1
    assert rig.fap_value(3) == 50 * (n - 1)
    assert player.frames_played == n
    assert player.report() == f"Played {n} frames"


def test_slow_rendering_drops_frames_instead_of_slowing_down(qtbot, player, rig):
    n = 25
    player.load(jaw_ramp(n, fps=25))  # 1 s
    shown = []
    player.frame_changed.connect(shown.append)

    def slow_redraw():
        time.sleep(0.1)  # 10 fps of "rendering" for a 25 fps file

    rig.changed.connect(slow_redraw)
    try:
        start = time.monotonic()
        with qtbot.waitSignal(player.finished, timeout=10000):
            player.play()
        took = time.monotonic() - start
    finally:
        rig.changed.disconnect(slow_redraw)
    assert took < 2.0  # showing every frame would take >= 2.5 s
    assert len(shown) < n - 1  # frames were dropped ...
    assert shown[-1] == n - 1 and rig.fap_value(3) == 50 * (n - 1)
    assert player.frames_played == n  # ... but counted as played


def test_loop_keeps_playing(qtbot, player):
    player.load(jaw_ramp(5, fps=50))  # 0.1 s
    player.loop = True
    shown = []
    player.frame_changed.connect(shown.append)
    finished = []
    player.finished.connect(lambda: finished.append(1))
    player.play()
    qtbot.wait(450)
    assert player.is_playing
    assert not finished
    assert any(b < a for a, b in zip(shown, shown[1:]))  # wrapped around
    player.pause()
    assert not player.is_playing


def test_stop_restores_the_face_before_playback(qtbot, player, rig):
    rig.set_faps({3: 77, 31: 100})
    rig.set_expression("joy", 0.4)
    player.load(seq_of([{3: 200, 19: 300}, {2: (6, 63, 0, 0, 0, 0), 3: 900}, {3: 1000}]))
    player.play()
    player.seek(2)
    assert rig.fap_value(3) == 1000 and rig.expression == (6, 1.0)
    emitted = []
    rig.changed.connect(lambda: emitted.append(1))
    player.stop()
    assert not player.is_playing and player.frame == 0
    assert rig.fap_value(3) == 77 and rig.fap_value(19) == 0 and rig.fap_value(31) == 100
    assert rig.expression == (1, 0.4)
    assert len(emitted) == 1
    qtbot.wait(100)
    assert rig.fap_value(3) == 77  # the timer is really stopped


def test_play_at_the_end_starts_again_from_frame_0(qtbot, player, rig):
    player.load(jaw_ramp(4, fps=25))
    player.seek(3)
    with qtbot.waitSignal(player.frame_changed, timeout=1000) as blocker:
        player.play()
    assert blocker.args == [0]
    qtbot.waitUntil(lambda: not player.is_playing, timeout=3000)
    assert player.frame == 3 and player.frames_played == 4


def test_set_rig_restores_the_old_rig(player, rig):
    player.load(jaw_ramp(3))
    player.seek(2)
    assert rig.fap_value(3) == 100
    player.set_rig(None)
    assert rig.fap_value(3) == 0
    player.play()
    player.seek(1)
    assert not player.is_playing and player.frame == 0
    player.set_rig(rig)


def test_loading_another_sequence_restores_first(player, rig):
    rig.set_fap(3, 50)
    player.load(jaw_ramp(3))
    player.seek(2)
    assert rig.fap_value(3) == 100
    player.load(seq_of([{19: 100}]))
    assert rig.fap_value(3) == 50
    assert player.n_frames == 1 and player.frame == 0


# ------------------------------------------------------------------ export
def test_export_reads_back_as_the_rig_state(bar, rig, tmp_path):
    rig.set_faps({3: 345.5, 31: -120, 19: 0})
    rig.set_expression("sadness", 0.5)
    rig.set_viseme(7, 1.0)
    path = tmp_path / "state.fap"
    assert bar.export_file(path)
    seq = read_fap(path)
    assert seq.n_frames == 1 and seq.notes == []
    assert seq.frame(0) == {3: 345.5, 31: -120.0}
    sadness = rig.expression[0]
    assert seq.expression[0].tolist() == [sadness, 32, 0, 0, 0, 0]
    assert seq.viseme[0].tolist() == [7, 0, 63, 0]
    # played back on a neutral face it gives the same state
    rig.reset_faps()
    rig.set_expression(None, 0.0)
    rig.set_viseme(None, 0.0)
    assert bar.open_file(path)
    bar.player.seek(0)
    assert rig.fap_value(3) == 345.5 and rig.fap_value(31) == -120
    assert rig.expression == (sadness, pytest.approx(32 / 63))
    assert rig.viseme == (7, 1.0)


def test_sequence_from_rig_of_a_neutral_face_is_empty(rig):
    from app.fap_player import sequence_from_rig

    seq = sequence_from_rig(rig, fps=30, name="n")
    assert seq.n_frames == 1 and seq.fps == 30 and seq.name == "n"
    assert not seq.mask.any()


def test_export_error_is_a_message_box(bar, error_boxes, tmp_path):
    assert not bar.export_file(tmp_path / "missing-folder" / "x.fap")
    assert len(error_boxes) == 1
    title, text = error_boxes[0]
    assert "export" in title.lower()
    assert "missing-folder" in text and "Traceback" not in text


# ------------------------------------------------------------------ the bar
def test_open_malformed_file_keeps_the_previous_sequence(bar, error_boxes, tmp_path):
    good = tmp_path / "good.fap"
    good.write_text(fap_text([{3: 100}, {3: 200}]))
    assert bar.open_file(good)
    previous = bar.player.sequence
    bad = tmp_path / "bad.fap"
    text = fap_text([{3: 100}, {3: 200}]).splitlines()
    text[5] = "1 abc"  # the value line of frame 1 (line 6 of the file)
    bad.write_text("\n".join(text) + "\n")
    assert not bar.open_file(bad)
    assert bar.player.sequence is previous
    assert len(error_boxes) == 1
    assert "'bad.fap', line 6" in error_boxes[0][1] and "'abc' is not a number" in error_boxes[0][1]
    assert bar.frame_label.text() == "frame 1 / 2 · 25 fps"
    empty = tmp_path / "empty.fap"
    empty.write_text("2.1 empty 25 0\n")
    assert not bar.open_file(empty)
    assert bar.player.sequence is previous and "no frames" in error_boxes[1][1]


def test_bar_scrubbing_label_and_buttons(qtbot, bar, rig, tmp_path):
    from PySide6.QtCore import Qt

    assert bar.frame_label.text() == "no .fap loaded"
    assert not bar.play_button.isEnabled()
    path = tmp_path / "ramp.fap"
    path.write_text(fap_text([{3: 100 * k} for k in range(12)], fps=30))
    messages = []
    bar.message.connect(messages.append)
    assert bar.open_file(path)
    assert messages == ["Loaded 'ramp.fap': 12 frames at 30 fps."]
    assert bar.play_button.isEnabled() and bar.slider.maximum() == 11
    bar.slider.setValue(4)  # scrubbing
    assert bar.player.frame == 4 and rig.fap_value(3) == 400
    assert bar.frame_label.text() == "frame 5 / 12 · 30 fps"
    qtbot.mouseClick(bar.loop_check, Qt.MouseButton.LeftButton)
    assert bar.player.loop
    qtbot.mouseClick(bar.play_button, Qt.MouseButton.LeftButton)
    assert bar.player.is_playing and bar.play_button.text() == "Pause"
    qtbot.waitUntil(lambda: bar.slider.value() != 4, timeout=2000)  # the slider follows playback
    qtbot.mouseClick(bar.play_button, Qt.MouseButton.LeftButton)
    assert not bar.player.is_playing and bar.play_button.text() == "Play"
    qtbot.mouseClick(bar.stop_button, Qt.MouseButton.LeftButton)
    assert bar.player.frame == 0 and bar.slider.value() == 0 and rig.fap_value(3) == 0
    assert bar.frame_label.text() == "frame 1 / 12 · 30 fps"
    assert messages[-1].startswith("Played ")
