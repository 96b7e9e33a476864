"""Face -> PyVista conversion, display modes, in-place updates and camera presets (off-screen plotter)."""

from __future__ import annotations

import numpy as np
import pytest
import pyvista as pv
from app_helpers import image_difference, image_variance, make_synthetic_face

from app import scene
from core.face import Face, FaceMetadata, vertex_normals


@pytest.fixture
def plotter():
    p = pv.Plotter(off_screen=True, window_size=(320, 240))
    scene.setup_stage(p)
    yield p
    p.close()


def test_face_to_polydata_carries_everything(synthetic_face):
    mesh = scene.face_to_polydata(synthetic_face)
    assert mesh.n_points == synthetic_face.n_vertices
    assert mesh.n_cells == synthetic_face.n_triangles
    np.testing.assert_allclose(mesh.points, synthetic_face.vertices)
    np.testing.assert_array_equal(mesh.regular_faces, synthetic_face.triangles)
    np.testing.assert_allclose(mesh.point_data["Normals"], synthetic_face.vertex_normals, atol=1e-6)
    assert mesh.point_data.active_normals_name == "Normals"
    np.testing.assert_allclose(mesh.active_texture_coordinates, synthetic_face.uv, atol=1e-6)
    np.testing.assert_array_equal(mesh.point_data["rgb"], synthetic_face.vertex_colors)


def _flat_quad(texture: np.ndarray) -> Face:
    """A 100 mm square facing +z with uv (0,0) bottom-left."""
    verts = np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    return Face(verts, tris, uv=uv, texture=texture, metadata=FaceMetadata(name="quad"))


def test_texture_row_zero_is_drawn_at_the_top(plotter):
    """Face.texture row 0 is the image top and uv v=0 the bottom: red must render above blue."""
    tex = np.zeros((64, 64, 3), np.uint8)
    tex[:32] = (255, 0, 0)
    tex[32:] = (0, 0, 255)
    actor = scene.add_face_actor(plotter, _flat_quad(tex), "textured")
    scene.set_camera_view(plotter, "front", actor.mesh.points)
    img = plotter.screenshot(None, return_img=True).astype(int)
    h, w = img.shape[:2]
    top, bottom = img[h // 2 - 40, w // 2], img[h // 2 + 40, w // 2]
    assert top[0] > 2 * top[2], f"top should be red, got {top}"
    assert bottom[2] > 2 * bottom[0], f"bottom should be blue, got {bottom}"


def test_texture_left_right_not_mirrored(plotter):
    """Texture column 0 (u=0) sits at -x, which is screen left in the front view."""
    tex = np.zeros((64, 64, 3), np.uint8)
    tex[:, :32] = (0, 255, 0)
    tex[:, 32:] = (255, 255, 255)
    actor = scene.add_face_actor(plotter, _flat_quad(tex), "textured")
    scene.set_camera_view(plotter, "front", actor.mesh.points)
    img = plotter.screenshot(None, return_img=True).astype(int)
    h, w = img.shape[:2]
    left = img[h // 2, w // 2 - 40]
    assert left[1] > 1.5 * left[0], f"left half should be green, got {left}"


def test_mode_fallbacks(plotter):
    face = make_synthetic_face()
    actor = scene.add_face_actor(plotter, face, "textured")
    assert actor.actor.texture is not None and not actor.actor.mapper.scalar_visibility

    no_tex = Face(face.vertices, face.triangles, vertex_colors=face.vertex_colors)
    actor2 = scene.add_face_actor(plotter, no_tex, "textured")
    assert actor2.actor.texture is None and actor2.actor.mapper.scalar_visibility

    bare = Face(face.vertices, face.triangles)
    actor3 = scene.add_face_actor(plotter, bare, "textured")
    assert actor3.actor.texture is None and not actor3.actor.mapper.scalar_visibility
    assert actor3.actor.prop.color == pv.Color(scene.SKIN_COLOR)

    actor.set_mode("shaded")
    assert actor.actor.texture is None and actor.actor.prop.style == "Surface"
    actor.set_mode("wireframe")
    assert actor.actor.prop.style == "Wireframe"
    actor.set_mode("points")
    assert actor.actor.prop.style == "Points"
    with pytest.raises(ValueError, match="display mode"):
        actor.set_mode("cartoon")


def test_update_vertices_is_in_place(plotter, synthetic_face):
    actor = scene.add_face_actor(plotter, synthetic_face, "shaded", show_landmarks=True)
    mesh, n_actors = actor.mesh, len(plotter.renderer.actors)
    points_array = mesh.GetPoints().GetData()
    scene.set_camera_view(plotter, "front", mesh.points * 1.4)
    before = plotter.screenshot(None, return_img=True)
    assert image_variance(before) > 50
    moved = synthetic_face.vertices * np.array([1.3, 0.8, 1.0])
    actor.update_vertices(moved)
    assert actor.mesh is mesh and mesh.GetPoints().GetData() is points_array
    assert len(plotter.renderer.actors) == n_actors
    np.testing.assert_allclose(mesh.points, moved)
    np.testing.assert_allclose(mesh.point_data["Normals"], vertex_normals(moved, synthetic_face.triangles), atol=1e-6)
    expected = synthetic_face.landmark_positions(synthetic_face.landmark_names, moved)
    assert np.linalg.norm(actor.landmark_mesh.points - expected, axis=1).max() < 2.0
    plotter.render()
    after = plotter.screenshot(None, return_img=True)
    assert image_difference(before, after) > 1.0
    with pytest.raises(ValueError):
        actor.update_vertices(moved[:10])


def test_landmarks_toggle(plotter, synthetic_face):
    actor = scene.add_face_actor(plotter, synthetic_face, "shaded")
    assert not actor.landmarks_visible
    actor.set_landmarks_visible(True)
    assert actor.landmarks_visible
    assert actor.landmark_mesh.n_points == len(synthetic_face.landmark_names)
    assert list(actor.label_mesh.point_data["landmark"]) == synthetic_face.landmark_names
    actor.set_landmarks_visible(False)
    assert not any(a.GetVisibility() for a in actor._landmark_actors)
    # Hidden, they cost nothing per frame (no label layout before renders)...
    assert not actor.label_layout.active
    moved = synthetic_face.vertices * np.array([1.2, 0.9, 1.0])
    actor.update_vertices(moved)
    # ... and shown again they sit on the face where it is now.
    actor.set_landmarks_visible(True)
    assert actor.label_layout.active
    expected = synthetic_face.landmark_positions(synthetic_face.landmark_names, moved)
    assert np.linalg.norm(actor.landmark_mesh.points - expected, axis=1).max() < 2.0


def test_camera_presets(plotter, synthetic_face):
    actor = scene.add_face_actor(plotter, synthetic_face, "shaded")
    pts = actor.mesh.points
    scene.set_camera_view(plotter, "front", pts)
    cam = plotter.camera
    d = np.subtract(cam.position, cam.focal_point)
    assert d[2] > 0 and abs(d[0]) < 1e-6 and abs(d[1]) < 1e-6
    np.testing.assert_allclose(cam.up, (0, 1, 0), atol=1e-9)
    front_img = plotter.screenshot(None, return_img=True)
    assert image_variance(front_img) > 50

    scene.set_camera_view(plotter, "side", pts)
    plotter.render()
    d = np.subtract(cam.position, cam.focal_point)
    assert abs(d[0]) > 0 and abs(d[2]) < 1e-6
    side_img = plotter.screenshot(None, return_img=True)

    scene.set_camera_view(plotter, "three-quarter", pts)
    plotter.render()
    d = np.subtract(cam.position, cam.focal_point)
    yaw = np.degrees(np.arctan2(d[0], d[2]))
    elevation = np.degrees(np.arcsin(d[1] / np.linalg.norm(d)))
    assert 30 <= abs(yaw) <= 45 and 3 <= elevation <= 20
    tq_img = plotter.screenshot(None, return_img=True)

    assert image_difference(front_img, side_img) > 2
    assert image_difference(front_img, tq_img) > 2
    with pytest.raises(ValueError):
        scene.set_camera_view(plotter, "top", pts)


def test_framing_fills_the_view(plotter, synthetic_face):
    """The front view puts the whole face in frame and uses most of the height."""
    actor = scene.add_face_actor(plotter, synthetic_face, "shaded")
    scene.set_camera_view(plotter, "front", actor.mesh.points)
    img = plotter.screenshot(None, return_img=True).astype(int)
    corner = img[2, 2]
    mask = np.abs(img - img[:, :1]).sum(axis=2) > 30  # differs from the row's background
    rows = np.where(mask.any(axis=1))[0]
    cols = np.where(mask.any(axis=0))[0]
    h, w = img.shape[:2]
    assert rows.min() > 0 and rows.max() < h - 1, "face is clipped at the top/bottom"
    assert cols.min() > 0 and cols.max() < w - 1, "face is clipped at the sides"
    assert (rows.max() - rows.min()) > 0.7 * h, "face should fill most of the height"
    assert corner.sum() < 3 * 120, "background should be dark grey"


def test_scalar_overlay_in_place_and_back(plotter, synthetic_face):
    actor = scene.add_face_actor(plotter, synthetic_face, "textured")
    scene.set_camera_view(plotter, "front", actor.mesh.points)
    plotter.render()
    plain = plotter.screenshot(None, return_img=True)
    n_actors = len(plotter.renderer.actors)
    height = synthetic_face.vertices[:, 1]
    actor.show_scalars(height, cmap="viridis", clim=(-100, 100), title="height (mm)")
    assert actor.scalars_visible and actor.actor.texture is None and actor.scalar_range == (-100, 100)
    assert "height (mm)" in plotter.scalar_bars._scalar_bar_actors
    plotter.render()
    coloured = plotter.screenshot(None, return_img=True)
    assert image_difference(plain, coloured) > 5
    array = actor.mesh.point_data["overlay"]
    pointer = array.__array_interface__["data"][0]
    actor.show_scalars(-height, cmap="viridis", clim=(-100, 100), title="height (mm)")
    assert actor.mesh.point_data["overlay"].__array_interface__["data"][0] == pointer, "updated in place"
    np.testing.assert_allclose(actor.scalars, -height, atol=1e-4)
    plotter.render()
    assert image_difference(coloured, plotter.screenshot(None, return_img=True)) > 2
    actor.update_vertices(synthetic_face.vertices * 1.01)  # geometry updates keep the overlay
    assert actor.scalars_visible
    actor.set_mode("shaded")  # so do mode changes
    assert actor.actor.mapper.scalar_visibility
    actor.set_mode("textured")
    actor.clear_scalars()
    assert not actor.scalars_visible and actor.actor.texture is not None and actor.scalar_bar_title is None
    assert len(plotter.renderer.actors) == n_actors
    with pytest.raises(ValueError):
        actor.show_scalars(height[:10])



# ------------------------------------------------------------------ labels that do not pile up
def test_place_labels_shows_no_two_overlapping_boxes():
    from app.label_layout import place_labels

    centres = np.array([[0.0, 0.0], [10.0, 0.0], [100.0, 0.0], [100.0, 5.0], [50.0, 50.0]])
    sizes = np.full((5, 2), 20.0)
    # 1 overlaps 0, 3 overlaps 2: the earlier in the order wins; 4 is alone.
    assert place_labels(centres, sizes, [0, 1, 2, 3, 4]).tolist() == [True, False, True, False, True]
    assert place_labels(centres, sizes, [1, 0, 3, 2, 4]).tolist() == [False, True, False, True, True]
    # A reserved label is not shown; a blocked box (the selected landmark's own label) keeps labels off it.
    assert place_labels(centres, sizes, [0, 1, 2, 3, 4], reserved=[1]).tolist() == [True, False, True, False, True]
    assert place_labels(centres, sizes, [0, 1, 2, 3, 4], blocked=[[8.0, 0.0, 20.0, 20.0]]).tolist() == [
        False, False, True, False, True]
    # Indices not in the order (points facing away) are never shown.
    assert place_labels(centres, sizes, [4]).tolist() == [False, False, False, False, True]


def _label_boxes(actor, renderer):
    from app.projection import world_to_display

    layout = actor.label_layout
    screen = world_to_display(renderer, actor.label_mesh.points)[layout.shown, :2]
    half = layout.sizes[layout.shown] / 2
    return screen, half


def test_feature_point_labels_fit_the_view_and_follow_the_zoom(default_face):
    p = pv.Plotter(off_screen=True, window_size=(800, 600))
    scene.setup_stage(p, anti_aliasing=None)
    actor = scene.add_face_actor(p, default_face, "shaded", show_landmarks=True)
    names = actor.label_layout.names
    scene.set_camera_view(p, "front", default_face.vertices)
    p.render_window.Render()   # (pyvista's render() waits for a first show)
    shown = actor.label_layout.shown.copy()
    texts = list(actor.label_mesh.point_data["landmark"])
    assert [t for t in texts if t] == [n for n, s in zip(names, shown) if s], "hidden labels are blanked"
    assert 15 <= shown.sum() < len(names), "labels that fit are shown, the rest are not piled on them"
    centre, half = _label_boxes(actor, p.renderer)
    gap = np.abs(centre[:, None] - centre[None]) - (half[:, None] + half[None])
    overlapping = (gap[..., 0] < 0) & (gap[..., 1] < 0) & ~np.eye(len(centre), dtype=bool)
    assert not overlapping.any()
    # Zoomed in on the mouth, more of its labels fit.
    mouth = [i for i, n in enumerate(names) if n.startswith(("2.", "8."))]
    before = shown[mouth].sum()
    target = default_face.landmark_positions(["2.2"], default_face.vertices)[0]
    shift = target - np.asarray(p.camera.focal_point)
    p.camera.position = np.asarray(p.camera.position) + shift
    p.camera.focal_point = target
    p.camera.zoom(3.0)
    p.renderer.ResetCameraClippingRange()
    p.render_window.Render()
    assert actor.label_layout.shown[mouth].sum() > before
    # In profile, the points on the far side of the face have no label.
    scene.set_camera_view(p, "side", default_face.vertices)
    p.render_window.Render()
    far = np.einsum("kd,d->k", actor.label_layout.normals,
                    np.asarray(p.camera.position) - np.asarray(p.camera.focal_point)) < -0.2
    assert far.any() and not actor.label_layout.shown[far].any()
    p.close()
