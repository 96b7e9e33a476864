"""A new rig layer in the window with no change to the timeline, undo, project or export code: the
offset layer of tests/offset_layer.py (one module, one registration line) is keyed on the timeline,
undone from the one undo stack, saved in a project and reopened, and rendered by export."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import offset_layer  # noqa: E402,F401 - registers the offset:z kind and its layer


@pytest.fixture
def win(default_face_window):
    return default_face_window


def test_a_new_layer_keys_undoes_saves_reopens_and_exports(qtbot, win, tmp_path):
    from app.export import ExportSettings, export
    from app.undo import gestures

    rig, c, stack = win.rig, win.timeline, win.undo_stack
    assert rig.ensure_layers(["offset:z"]) == ["offset"]
    neutral = rig.vertices().copy()
    # Undo: a change of its parameter is one step on the one stack, and undo reverts it.
    gestures().new()
    rig.set_values({"offset:z": 4.0})
    assert stack.undoText() == "push forward"
    np.testing.assert_allclose(rig.vertices()[:, 2] - neutral[:, 2], 4.0)
    stack.undo()
    assert rig.value("offset:z") == 0.0
    # Timeline: Set key keys it like any parameter, and playing poses it.
    c.seek(0.0)
    c.set_key(["offset:z"])
    c.seek(1.0)
    rig.set_values({"offset:z": -6.0})
    c.set_key(["offset:z"])
    assert c.timeline.track("offset:z").values.tolist() == [0.0, -6.0]
    c.seek(0.5)
    assert rig.value("offset:z") == pytest.approx(c.timeline.track("offset:z").evaluate(0.5))
    # Project: saved by key and reopened onto a fresh rig of the same face.
    path = tmp_path / "offset.mimica"
    assert c.project.save_project(path)
    assert '"offset:z"' in path.read_text(encoding="utf-8")
    c.seek(1.0)
    rig.remove_layer("offset")
    assert c.project.open_project(path, ask=False)
    qtbot.waitUntil(lambda: win.rig is not None and win.rig.layer("offset") is not None, timeout=60_000)
    assert "offset:z" in win.timeline.timeline.tracks
    # Export: the rendered frame shows the offset (the face is pushed towards the camera).
    frames = {}
    for t in (0.0, 1.0):
        out = tmp_path / f"frame{t:g}.png"
        export(win.face, win.timeline.frame_vertices, ExportSettings(path=out, start_s=t, end_s=t, size=(160, 120),
                                                                    format="png", view="side"))
        from PIL import Image

        frames[t] = np.asarray(Image.open(out).convert("L"), dtype=float)
    assert np.abs(frames[0.0] - frames[1.0]).mean() > 0.5
