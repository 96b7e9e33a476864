"""The built-in default face: deterministic, complete, human-shaped, open at mouth and eyes."""

import numpy as np
import pytest

import resources
from core.default_face import FaceLayout, FaceParameters, generate_face, load_default_face


@pytest.fixture(scope="module")
def face():
    return generate_face()


def frontal_feature_points():
    return [r["fp"] for r in resources.get_table("mpeg4/feature_points.csv") if r["frontal"] == "1"]


def test_scan_like_size_and_texture(face):
    assert 45_000 <= face.n_vertices <= 55_000
    assert face.texture.shape == (480, 640, 3)
    assert face.uv.shape == (face.n_vertices, 2)
    assert face.uv.min() >= 0 and face.uv.max() <= 1
    assert np.isfinite(face.vertices).all()
    # Skin, two eyeballs, mouth cavity, upper and lower teeth.
    assert face.n_components == 6


def test_deterministic():
    a, b = generate_face(), generate_face()
    assert np.array_equal(a.vertices, b.vertices)
    assert np.array_equal(a.triangles, b.triangles)
    assert np.array_equal(a.texture, b.texture)
    assert a.landmarks == b.landmarks


def test_different_parameters_give_different_faces(face):
    wide = generate_face(FaceParameters(mouth_width=58.0, nose_width=42.0, skin_tone=0.8))
    w = wide.landmark_position("8.3")[0] - wide.landmark_position("8.4")[0]
    assert w == pytest.approx(58.0, abs=0.1)
    assert not np.array_equal(wide.texture, face.texture)
    assert wide.texture.mean() < face.texture.mean()  # darker skin tone


def test_every_frontal_feature_point_is_a_landmark(face):
    expected = frontal_feature_points()
    assert len(expected) == 70  # 62 on the skin and eyes, 4 ear contacts, 4 teeth
    assert sorted(face.landmark_names) == sorted(expected)


def test_landmarks_match_the_layout_by_construction(face):
    layout = FaceLayout.from_parameters(FaceParameters())
    pos = dict(zip(face.landmark_names, face.landmark_positions()))
    # MPEG-4 axes: +x is the face's own left.
    assert pos["3.7"][0] > 0 > pos["3.12"][0]
    assert pos["8.3"][0] == pytest.approx(layout.mouth_half_width, abs=1e-6)
    assert pos["3.5"][:2] == pytest.approx([layout.pupil_x, layout.eye_line_y], abs=1e-6)
    # Nose tip is the most forward landmark; eyes lie behind it.
    assert max(pos, key=lambda k: pos[k][2]) == "9.3"
    # FAPU distances (MPEG-4): eye separation, iris diameter, mouth width, in adult ranges.
    assert pos["3.5"][0] - pos["3.6"][0] == pytest.approx(63.0, abs=1.0)
    assert pos["3.1"][1] - pos["3.3"][1] == pytest.approx(2 * layout.iris_radius, abs=0.05)
    assert 15 < pos["9.15"][1] - pos["2.2"][1] < 25       # MNS0
    # Left/right symmetry of the generated identity.
    for left, right in [("3.7", "3.12"), ("4.5", "4.6"), ("8.3", "8.4"), ("5.3", "5.4")]:
        assert pos[left] == pytest.approx(pos[right] * [-1, 1, 1], abs=1e-6)


def test_mouth_is_a_seam_that_can_open(face):
    """Inner lip midpoints coincide at rest but sit on different vertices: pulling the
    lower lip's vertices down parts the lips without moving the upper lip."""
    upper, lower = face.landmarks["2.2"], face.landmarks["2.3"]
    assert face.landmark_position("2.2") == pytest.approx(face.landmark_position("2.3"), abs=1e-9)
    up_verts = set(face.triangles[upper.triangle])
    low_verts = set(face.triangles[lower.triangle])
    assert not (up_verts & low_verts)
    moved = face.vertices.copy()
    moved[list(low_verts), 1] -= 5.0
    opened = face.with_vertices(moved)
    assert opened.landmark_position("2.2")[1] - opened.landmark_position("2.3")[1] == pytest.approx(5.0, abs=1e-6)


def test_eye_openings_are_holes_with_eyeballs_behind(face):
    # Boundary edges exist around each eye (skin rim) and the pupils are on the eyeballs.
    e = np.sort(np.concatenate([face.triangles[:, [0, 1]], face.triangles[:, [1, 2]], face.triangles[:, [2, 0]]]), 1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    rim = np.unique(uniq[count == 1])
    layout = FaceLayout.from_parameters(FaceParameters())
    near_eye = np.abs(np.abs(face.vertices[rim, 0]) - layout.pupil_x) < 16
    near_eye &= np.abs(face.vertices[rim, 1] - layout.eye_line_y) < 7
    assert near_eye.sum() > 60
    pupil_vertex = face.triangles[face.landmarks["3.5"].triangle][np.argmax(face.landmarks["3.5"].barycentric)]
    assert face.component_labels[pupil_vertex] != face.component_labels[face.triangles[0, 0]]
    # The upper lid margin is in front of the eyeball (lids cover, never cut into, the eye).
    assert face.landmark_position("3.1")[2] > face.landmark_position("3.5")[2] - 3.0


def test_parameters_out_of_range_are_refused():
    with pytest.raises(ValueError, match="nose_length = 90"):
        FaceParameters(nose_length=90)


def test_committed_copy_matches_the_generator(face):
    stored = load_default_face()
    assert stored.n_vertices == face.n_vertices
    assert np.array_equal(stored.triangles, face.triangles)
    assert np.allclose(stored.vertices, face.vertices, atol=1e-4)
    assert np.array_equal(stored.texture, face.texture)
    assert stored.landmark_positions() == pytest.approx(face.landmark_positions(), abs=1e-3)
