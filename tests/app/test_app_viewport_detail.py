"""The viewport's draft level of detail (app.preview, app.viewport): drafts while things move,
the full face once input pauses, and that full frame identical to a render made from scratch."""

from __future__ import annotations

import numpy as np
import pytest

from app.preview import PreviewMesh, cached_preview, decimate, part_triangles
from app_helpers import image_difference
from core.cache import DiskCache

TIMEOUT_MS = 8000


@pytest.fixture(scope="module")
def preview(default_face):
    return decimate(default_face.vertices, default_face.triangles, keep=part_triangles(default_face))


def test_the_draft_is_a_vertex_subset_about_five_times_lighter(default_face, preview):
    assert isinstance(preview, PreviewMesh)
    assert 15_000 <= preview.n_triangles <= 25_000 < len(default_face.triangles) / 4
    assert preview.index.min() >= 0 and preview.index.max() < default_face.n_vertices
    # each draft vertex is one face vertex (not found by position: coincident vertices move apart)
    assert len(np.unique(preview.index)) == len(preview.index)
    assert preview.triangles.max() == len(preview.index) - 1
    # eyes, teeth and the mouth cavity are kept whole: a uniform decimation erased the teeth
    parts = default_face.triangles[part_triangles(default_face)]
    drawn = {tuple(sorted(t)) for t in preview.index[preview.triangles]}
    assert all(tuple(sorted(t)) in drawn for t in parts)


def test_small_faces_have_no_draft(synthetic_face, tmp_path):
    assert decimate(synthetic_face.vertices, synthetic_face.triangles) is None
    cache = DiskCache(tmp_path)
    assert cached_preview(synthetic_face, cache) is None
    assert cached_preview(synthetic_face, cache) is None and cache.notes == []


def test_the_draft_is_read_back_from_the_disk_cache(default_face, preview, tmp_path):
    cache = DiskCache(tmp_path)
    cache.put("preview", "unrelated", preview)
    first = cached_preview(default_face, cache)
    assert len(list((tmp_path / "preview").iterdir())) == 2
    again = cached_preview(default_face, cache)
    np.testing.assert_array_equal(first.index, again.index)
    np.testing.assert_array_equal(first.triangles, preview.triangles)


@pytest.fixture
def win(qtbot, settings, error_boxes, default_face, deformer, preview):
    from app.main_window import MainWindow
    from core.rig import FaceRig

    w = MainWindow(settings=settings, load_default=False)
    qtbot.addWidget(w)
    w.set_face(default_face, rig=FaceRig(default_face, deformer=deformer))
    w.show()
    qtbot.waitExposed(w)
    qtbot.waitUntil(lambda: w.face_actor.preview is not None, timeout=30000)
    yield w
    w.close()


def _settled(win) -> bool:
    return not win.viewport.timer.isActive() and not win.viewport.settle_timer.isActive()


def test_a_slider_draws_the_draft_then_the_full_face(qtbot, win):
    actor = win.face_actor
    qtbot.waitUntil(lambda: _settled(win) and not actor.showing_preview, timeout=TIMEOUT_MS)
    assert actor.actor.GetVisibility()
    win.fap_dock.row(3).slider.setValue(500)
    qtbot.waitUntil(lambda: win.viewport.last_tick_ms is not None and actor.showing_preview, timeout=TIMEOUT_MS)
    assert not actor.actor.GetVisibility() and actor.preview_actor.GetVisibility()
    posed = win.rig.vertices()
    np.testing.assert_allclose(actor.preview_mesh.points, posed[actor.preview.index], atol=1e-4)
    np.testing.assert_allclose(actor.mesh.points, posed, atol=1e-4)  # the full face is current too
    qtbot.waitUntil(lambda: _settled(win) and not actor.showing_preview, timeout=TIMEOUT_MS)
    assert actor.actor.GetVisibility() and not actor.preview_actor.GetVisibility()
    assert win.viewport.last_full_ms is not None
    # The same image, sampled without mipmaps in the draft (cheaper on software GL), with them in full.
    draft, full = actor.preview_actor.texture, actor.actor.texture
    assert not draft.mipmap and full.mipmap
    assert np.array_equal(draft.to_image().point_data.active_scalars, full.to_image().point_data.active_scalars)


def test_the_full_frame_after_a_move_equals_a_render_from_scratch(qtbot, win, default_face):
    from app import scene

    win.fap_dock.row(3).slider.setValue(600)
    win.fap_dock.row(12).slider.setValue(200)
    qtbot.waitUntil(lambda: _settled(win) and not win.face_actor.showing_preview, timeout=TIMEOUT_MS)
    after_move = win.screenshot()
    posed = default_face.with_vertices(win.rig.vertices())
    win.face_actor.remove()
    win.face_actor = scene.add_face_actor(win.plotter, posed, win.view_mode)
    from_scratch = win.screenshot()
    assert after_move.shape == from_scratch.shape
    assert image_difference(after_move, from_scratch) < 0.5


def test_overlays_and_wireframe_are_never_drafted(qtbot, win):
    actor = win.face_actor
    win.set_view_mode("wireframe")
    win.fap_dock.row(3).slider.setValue(300)
    qtbot.waitUntil(lambda: win.viewport.last_tick_ms is not None and not win.viewport.timer.isActive(),
                    timeout=TIMEOUT_MS)
    assert not actor.showing_preview and actor.actor.GetVisibility()
    win.set_view_mode("textured")
    win.fap_dock.heat_check.setChecked(True)
    win.fap_dock.row(3).slider.setValue(400)
    qtbot.waitUntil(lambda: not win.viewport.timer.isActive() and actor.scalars_visible, timeout=TIMEOUT_MS)
    assert not actor.showing_preview


def test_a_pick_during_a_draft_hits_the_full_face(qtbot, win):
    from app.picking import SurfacePicker

    actor = win.face_actor
    actor.use_preview(True)
    picker = SurfacePicker(actor.actor, actor.mesh, win.face.triangles)
    w, h = win.plotter.window_size
    hit = picker.pick(win.plotter.renderer, w / 2, h / 2)
    assert hit is not None and 0 <= hit.triangle < len(win.face.triangles)
    assert actor.showing_preview and not actor.actor.GetVisibility(), "the pick leaves the draft drawn"


def test_software_opengl_gets_no_msaa(win):
    from app.scene import anti_aliasing_for

    assert anti_aliasing_for("llvmpipe (LLVM 15.0.6, 256 bits)") is None
    assert anti_aliasing_for("NVIDIA GeForce RTX 3060/PCIe/SSE2") == "msaa"
    assert isinstance(win.renderer_name, str)


def test_a_camera_drag_is_drawn_as_a_draft_then_in_full(qtbot, win):
    from PySide6.QtCore import QEvent, QPointF, Qt
    from PySide6.QtGui import QMouseEvent
    from PySide6.QtWidgets import QApplication

    actor, plotter = win.face_actor, win.plotter
    qtbot.waitUntil(lambda: _settled(win) and not actor.showing_preview, timeout=TIMEOUT_MS)
    centre = QPointF(plotter.width() / 2, plotter.height() / 2)

    def send(kind, pos, button, buttons):
        QApplication.sendEvent(plotter, QMouseEvent(kind, pos, QPointF(plotter.mapToGlobal(pos.toPoint())),
                                                    button, buttons, Qt.KeyboardModifier.NoModifier))

    position = plotter.camera.position
    send(QEvent.Type.MouseButtonPress, centre, Qt.MouseButton.LeftButton, Qt.MouseButton.LeftButton)
    during = []
    for i in range(1, 6):
        send(QEvent.Type.MouseMove, centre + QPointF(10 * i, 4 * i), Qt.MouseButton.NoButton, Qt.MouseButton.LeftButton)
        qtbot.wait(10)
        during.append(actor.showing_preview)
    send(QEvent.Type.MouseButtonRelease, centre + QPointF(50, 20), Qt.MouseButton.LeftButton, Qt.MouseButton.NoButton)
    assert all(during) and plotter.camera.position != position, "the view turned, drawn as a draft"
    qtbot.waitUntil(lambda: not actor.showing_preview, timeout=TIMEOUT_MS)
    assert win.viewport.last_full_ms is not None
