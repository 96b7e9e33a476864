"""Virtual scanner (one default-face scan per module), Colombo seeds and candidates on it,
noise/holes on a small sphere, and the synthetic database cache."""

from __future__ import annotations

import numpy as np
import pytest

from core.default_face import load_default_face
from core.face import Face
from core.registration.candidates import texture_candidates
from core.registration.curvature import colombo_seeds
from core.registration.icp import apply_transform
from core.registration.range_image import face_from_xyz_grid
from core.registration.virtual_scanner import ScanError, scan_face

HIDDEN = {"9.8", "9.9", "9.10", "9.11"}  # teeth feature points behind the closed lips
GRAZING = {"2.13", "2.14"}  # jaw corners on the steep sides: turned away, their samples are dropped


@pytest.fixture(scope="module")
def source():
    return load_default_face(full_head=False)   # scans are of the front of the face, like the database


@pytest.fixture(scope="module")
def scan(source):
    return scan_face(source, pose_jitter_deg=3.0, pose_jitter_mm=5.0, rng=7)


def test_scan_size_texture_and_pose(source, scan):
    face = scan.face
    assert 40_000 <= face.n_vertices <= 60_000
    assert face.texture.shape == (480, 640, 3)
    assert face.uv.shape == (face.n_vertices, 2) and face.uv.min() >= 0 and face.uv.max() <= 1
    R = scan.transform[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert not np.allclose(scan.transform, np.eye(4))
    # Each scan vertex lies on the posed source surface at its recorded source point.
    posed = apply_transform(source.vertices, scan.transform)
    on_source = np.einsum("kj,kjd->kd", scan.source_bary, posed[source.triangles[scan.source_triangle]])
    assert np.abs(on_source - face.vertices).max() < 1e-4
    # Triangles face the camera.
    assert np.mean(face.face_normals[:, 2] > 0) > 0.99


def test_ground_truth_landmarks(source, scan):
    face = scan.face
    assert set(face.landmark_names) == set(source.landmark_names)
    truth = apply_transform(source.landmark_positions(face.landmark_names), scan.transform)
    got = face.landmark_positions(face.landmark_names)
    err = np.linalg.norm(got - truth, axis=1)
    names = np.array(face.landmark_names)
    visible = np.array([n not in HIDDEN for n in names])
    frontal = np.array([n not in HIDDEN | GRAZING for n in names])
    assert err[frontal].max() < 1.0
    assert err[visible].max() < 2.5
    assert np.all(err[~visible] > 3.0)
    np.testing.assert_allclose([scan.landmark_error_mm[n] for n in names], err, atol=1e-9)
    assert set(scan.visible_landmarks(1.0)) >= set(names[frontal])


def test_colombo_seeds_on_scan(scan):
    face = scan.face
    seeds = colombo_seeds(face)
    for name, landmark, tol in (("nose_tip", "9.3", 3.0), ("inner_eye_corner_left", "3.11", 5.0),
                                ("inner_eye_corner_right", "3.8", 5.0)):
        assert np.linalg.norm(seeds[name] - face.landmark_position(landmark)) < tol, name


def test_texture_candidates_on_scan(scan):
    face = scan.face
    cand = texture_candidates(face, count=1500, quality=0.003, min_distance_px=5)
    assert len(cand) > 1000
    closest, _, _ = face.closest_surface_points(cand.points[:200])
    assert np.abs(closest - cand.points[:200]).max() < 1e-6


# ---------------------------------------------------------------- noise and holes (small sphere)
R = 40.0


@pytest.fixture(scope="module")
def ball():
    n = 81
    x, y = np.meshgrid(np.linspace(-30, 30, n), np.linspace(30, -30, n))
    z = np.sqrt(np.clip(R * R - x * x - y * y, 0, None))
    xyz = np.stack([x, y, z], axis=-1)
    xyz[x * x + y * y > 30 ** 2] = np.nan
    colour = np.full((n, n, 3), 180, np.uint8)
    face = face_from_xyz_grid(xyz, colour)
    face.set_landmark("top", face.surface_point([0, 0, R]))
    return face


def _radial_error(face: Face):
    return np.linalg.norm(face.vertices, axis=1) - R


def test_noise_and_holes(ball):
    clean = scan_face(ball, n_target=5000, rng=1)
    noisy = scan_face(ball, n_target=5000, noise_mm=0.3, rng=1)
    holed = scan_face(ball, n_target=5000, holes=3, hole_radius_mm=(5.0, 5.0), rng=1)
    assert 4000 <= clean.face.n_vertices <= 6000
    assert np.abs(_radial_error(clean.face)).max() < 0.05
    # Depth noise along z: radial error ~ 0.3 * cos(angle) on the cap.
    assert 0.15 < np.std(_radial_error(noisy.face)) < 0.35
    removed = clean.face.n_vertices - holed.face.n_vertices
    expected = 3 * np.pi * 25 / clean.spacing_mm ** 2  # up to overlap of the discs
    assert 0.3 * expected < removed <= 1.1 * expected
    # Same rng, different vertex indices: no correspondence between scans.
    assert holed.face.n_vertices != clean.face.n_vertices
    assert holed.landmark_error_mm["top"] < 1.0 or holed.landmark_error_mm["top"] > 1.0  # reported


def test_zbuffer_fallback_matches_embree(ball):
    a = scan_face(ball, n_target=3000, rng=3, engine="embree")
    b = scan_face(ball, n_target=3000, rng=3, engine="zbuffer")
    assert a.face.n_vertices == b.face.n_vertices
    np.testing.assert_allclose(a.face.vertices, b.face.vertices, atol=1e-6)


def test_pinhole_camera_and_bad_inputs(ball):
    pin = scan_face(ball, n_target=3000, camera="pinhole", distance_mm=500, rng=2)
    assert np.abs(_radial_error(pin.face)).max() < 0.05
    assert pin.landmark_error_mm["top"] < 0.5
    with pytest.raises(ScanError, match="shape"):
        scan_face(ball, vertices=np.zeros((3, 3)))
    with pytest.raises(ScanError, match="camera"):
        scan_face(ball, camera="fisheye")
    with pytest.raises(ScanError, match=">= 0"):
        scan_face(ball, noise_mm=-1)
    away = ball.with_vertices(ball.vertices * [1, 1, -1] - [0, 0, 10])  # now facing -z
    with pytest.raises(ScanError):
        scan_face(Face(away.vertices, away.triangles[:, [0, 2, 1]][:0]))


# ---------------------------------------------------------------- synthetic database
def test_synthetic_scan_is_cached_and_deterministic(tmp_path):
    from core.registration.synthetic import SyntheticError, synthetic_case, synthetic_scan

    first = synthetic_scan(0, "neutral", cache_dir=tmp_path)
    files = list(tmp_path.glob("*.npz"))
    assert len(files) == 1
    again = synthetic_scan(0, "neutral", cache_dir=tmp_path)
    np.testing.assert_array_equal(first.vertices, again.vertices)
    np.testing.assert_array_equal(first.triangles, again.triangles)
    assert first.landmarks == again.landmarks
    assert 40_000 <= first.n_vertices <= 60_000 and first.texture.shape == (480, 640, 3)
    # Every landmark is carried (projected onto the scan); the hidden ones are flagged as such.
    case = synthetic_case(0, "neutral", cache_dir=tmp_path)
    assert set(case.face.landmark_names) == set(first.landmark_names)
    assert "9.3" in case.visible and HIDDEN <= set(first.landmark_names) and not HIDDEN & case.visible
    assert all(case.error_mm[n] > 2.0 for n in case.hidden) and case.error_mm["9.3"] < 2.0
    with pytest.raises(SyntheticError, match="unknown pose"):
        synthetic_scan(0, "boredom", cache_dir=tmp_path)


def test_a_cached_expression_scan_is_keyed_by_the_code_that_posed_it(monkeypatch):
    """A scan of an expression cached before the FAP table's code changed is not read back as that
    expression (the pose would be the old code's); the neutral does not depend on that code."""
    import core.layers.fap.fat as fat
    from core.registration import synthetic

    synthetic._pose_recipe.cache_clear()
    before = synthetic._cache_path("/cache", 1, "joy", 0), synthetic._cache_path("/cache", 1, "neutral", 0)
    monkeypatch.setattr(fat, "deformer_code_version", lambda: "another version of the FAP code")
    synthetic._pose_recipe.cache_clear()
    after = synthetic._cache_path("/cache", 1, "joy", 0), synthetic._cache_path("/cache", 1, "neutral", 0)
    synthetic._pose_recipe.cache_clear()
    assert before[0] != after[0]
    assert before[1] == after[1]


def test_a_cached_scan_is_keyed_by_the_face_it_scanned(monkeypatch, tmp_path):
    """A scan cached before the face changed (the committed default face, or the generator that
    makes the other people) is not read back as that person's scan."""
    from core.registration import synthetic

    synthetic._identity_recipe.cache_clear()
    before = synthetic._cache_path("/cache", 0, "neutral", 0), synthetic._cache_path("/cache", 1, "neutral", 0)
    changed = tmp_path / "default_face.npz"
    changed.write_bytes(b"another default face")
    monkeypatch.setattr("core.default_face.default_face_path", lambda: changed)
    synthetic._identity_recipe.cache_clear()
    after = synthetic._cache_path("/cache", 0, "neutral", 0), synthetic._cache_path("/cache", 1, "neutral", 0)
    synthetic._identity_recipe.cache_clear()
    assert before[0] != after[0]
    assert before[1] == after[1]          # the generated people do not read the committed file
