"""Range images -> Face, and scan clean-up (thesis A §2): known answers on small synthetic grids."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.face import SurfacePoint
from core.registration.cleanup import CleanupError, clean_scan
from core.registration.icp import boundary_vertex_mask
from core.registration.range_image import RangeImageError, face_from_xyz_grid, load_range_image

R = 60.0  # sphere radius, mm


def sphere_cap_grid(n=40, h=0.7):
    """(n, n, 3) grid of a sphere cap of radius R (apex at z = 0) and a colour image."""
    x, y = np.meshgrid((np.arange(n) - n / 2) * h, -(np.arange(n) - n / 2) * h)
    z = np.sqrt(R * R - x * x - y * y) - R
    colour = (np.random.default_rng(0).random((n, n, 3)) * 255).astype(np.uint8)
    return np.stack([x, y, z], axis=-1), colour


def test_xyz_grid_round_trip_counts_positions_uv():
    xyz, colour = sphere_cap_grid(n=20)
    xyz[3, 4] = np.nan  # one missing sample
    face = face_from_xyz_grid(xyz, colour)
    assert face.n_vertices == 20 * 20 - 1
    # 19x19 cells, 2 triangles each; the 4 cells around the hole keep 1 triangle each.
    assert face.n_triangles == 2 * 19 * 19 - 4
    valid = np.isfinite(xyz).all(axis=2)
    np.testing.assert_allclose(face.vertices, xyz[valid])
    rows, cols = np.nonzero(valid)
    np.testing.assert_allclose(face.uv[:, 0], (cols + 0.5) / 20)
    np.testing.assert_allclose(face.uv[:, 1], 1 - (rows + 0.5) / 20)
    assert face.texture.shape == (20, 20, 3) and np.array_equal(face.texture, colour)
    # Texel under each vertex's uv is the pixel it came from.
    px = np.rint(face.uv * [20, -20] + [-0.5, 19.5]).astype(int)
    np.testing.assert_array_equal(px[:, 0], cols)
    np.testing.assert_array_equal(px[:, 1], rows)
    # Normals face the viewer (+z) at the apex.
    assert face.vertex_normals[np.argmax(face.vertices[:, 2]), 2] > 0.99


def test_long_edges_are_dropped_at_depth_jumps():
    xyz, _ = sphere_cap_grid(n=10)
    xyz[:, 5:, 2] -= 50.0  # a 50 mm step between columns 4 and 5
    face = face_from_xyz_grid(xyz)
    assert face.n_triangles == 2 * 9 * 9 - 2 * 9
    assert face.n_components == 2


def test_depth_png_with_intrinsics(tmp_path):
    fx = fy = 500.0
    cx, cy = 15.5, 11.5
    depth_mm = np.full((24, 32), 600.0)
    depth_mm[0, 0] = 0  # no sample
    cv2.imwrite(str(tmp_path / "d.png"), (depth_mm * 10).astype(np.uint16))  # 0.1 mm units
    colour = np.zeros((48, 64, 3), np.uint8)
    colour[..., 0] = 200  # red in RGB
    cv2.imwrite(str(tmp_path / "c.png"), colour[:, :, ::-1])
    face = load_range_image(tmp_path / "d.png", tmp_path / "c.png", intrinsics=(fx, fy, cx, cy),
                            depth_scale_mm=0.1)
    assert face.n_vertices == 24 * 32 - 1
    np.testing.assert_allclose(face.vertices[:, 2], -600.0)
    # Pixel (col 31, row 23) -> x = (31 - 15.5) * 600 / 500, y = -(23 - 11.5) * 600 / 500
    np.testing.assert_allclose(face.vertices[-1], [18.6, -13.8, -600.0])
    assert face.texture.shape == (48, 64, 3) and face.texture[0, 0, 0] == 200


def test_range_image_errors(tmp_path):
    cv2.imwrite(str(tmp_path / "d8.png"), np.full((8, 8), 100, np.uint8))
    with pytest.raises(RangeImageError, match="8-bit"):
        load_range_image(tmp_path / "d8.png", intrinsics=(500, 500, 4, 4))
    np.save(tmp_path / "d.npy", np.full((8, 8), 600.0))
    with pytest.raises(RangeImageError, match="intrinsics"):
        load_range_image(tmp_path / "d.npy")
    with pytest.raises(RangeImageError, match="not found"):
        load_range_image(tmp_path / "missing.png", intrinsics=(500, 500, 4, 4))
    np.save(tmp_path / "zero.npy", np.zeros((8, 8)))
    with pytest.raises(RangeImageError, match="valid samples"):
        load_range_image(tmp_path / "zero.npy", intrinsics=(500, 500, 4, 4))
    xyz, _ = sphere_cap_grid(n=8)
    with pytest.raises(RangeImageError, match="same field of view"):
        face_from_xyz_grid(xyz, np.zeros((8, 16, 3), np.uint8))
    with pytest.raises(RangeImageError, match="floating point"):
        face_from_xyz_grid(xyz.astype(np.int32))
    with pytest.raises(RangeImageError, match=r"\(H, W, 3\)"):
        face_from_xyz_grid(xyz[..., :2])


# ---------------------------------------------------------------- clean-up
@pytest.fixture(scope="module")
def dirty():
    """Sphere cap with a 2.2 mm hole, a 3 mm spike and a small floating patch."""
    xyz, colour = sphere_cap_grid(n=60)
    x, y = xyz[..., 0], xyz[..., 1]
    xyz[(x - 5) ** 2 + (y - 3) ** 2 < 2.2 ** 2] = np.nan
    xyz[40, 20, 2] += 3.0
    xyz[2:6, 50:56, 2] += 30.0  # floats 30 mm in front: separate component (long edges dropped)
    face = face_from_xyz_grid(xyz, colour, max_edge_mm=5.0)
    face.set_landmark("apex", face.surface_point([0.0, 0.0, 0.0]))
    face.set_landmark("floater", face.surface_point(xyz[3, 52]))
    return face, xyz


def test_cleanup_drops_fills_smooths_and_reports(dirty):
    face, xyz = dirty
    assert face.n_components == 2
    loops_before = boundary_vertex_mask(face.triangles, face.n_vertices).sum()
    res = clean_scan(face, min_component=100, max_hole_edges=40, spike_threshold_mm=1.0)
    out = res.face
    assert res.counts["components_removed"] == 1 and res.counts["vertices_removed"] == 24
    assert any("Removed 1 small component" in line for line in res.report)
    # Two holes: the 2.2 mm disc and the gap the floating patch leaves in the cap.
    assert res.counts["holes_filled"] == 2 and res.counts["vertices_added"] > 0
    assert out.n_components == 1
    # Only the outer rim stays open.
    assert boundary_vertex_mask(out.triangles, out.n_vertices).sum() < loops_before
    outer = 4 * 59
    assert boundary_vertex_mask(out.triangles, out.n_vertices).sum() == outer
    # The filled surface and the smoothed spike lie close to the sphere.
    v = out.vertices
    dev = np.abs(v[:, 2] - (np.sqrt(R * R - v[:, 0] ** 2 - v[:, 1] ** 2) - R))
    assert dev.max() < 0.3
    assert res.counts["spike_vertices"] == 1 and res.counts["smoothed_vertices"] > 1
    # uv and texture carried over; the landmark on the kept surface is unchanged.
    assert out.uv.shape == (out.n_vertices, 2) and np.array_equal(out.texture, face.texture)
    np.testing.assert_allclose(out.landmark_position("apex"), face.landmark_position("apex"), atol=1e-9)
    assert "floater" in out.landmark_names and res.counts["landmarks_rebound"] == 1
    assert out.n_triangles > 0 and out.metadata.notes[-len(res.report):] == res.report


def test_cleanup_steps_are_optional(dirty):
    face, _ = dirty
    res = clean_scan(face, fill_holes=False, min_component=0, smooth_spikes=False)
    assert res.face.n_vertices == face.n_vertices and res.face.n_triangles == face.n_triangles
    np.testing.assert_array_equal(res.face.vertices, face.vertices)
    with pytest.raises(CleanupError, match="max_hole_edges"):
        clean_scan(face, max_hole_edges=2)
    with pytest.raises(CleanupError, match="spike_threshold_mm"):
        clean_scan(face, spike_threshold_mm=0)


def test_hole_fill_is_consistently_oriented(dirty):
    face, _ = dirty
    out = clean_scan(face, min_component=100, smooth_spikes=False).face
    # Every interior edge is used once in each direction.
    t = out.triangles
    he = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    key = he[:, 0] * out.n_vertices + he[:, 1]
    assert len(np.unique(key)) == len(key)
    assert np.all(out.face_normals[:, 2] > 0)
