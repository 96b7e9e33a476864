"""Finding the face in a bust in unknown units (core.registration.alignment): known answers."""

import numpy as np
import pytest
import trimesh

from core.face import Face
from core.registration.alignment import FaceNotFoundError, locate_face, skin_fit
from core.registration.icp import apply_transform, rigid_transform, rotation_about_axis
from core.registration.pipeline import default_model, detect_landmarks
from core.registration.templates import template_positions

UNITS = 4.5                       # the bust is stored in 4.5-mm units
PITCH = rotation_about_axis((1.0, 0.0, 0.0), 12.0)   # looking down a little
SHIFT = np.array([3.0, 40.0, -7.0])


@pytest.fixture(scope="module")
def model():
    return default_model()


@pytest.fixture(scope="module")
def face_scan(model):
    """The model re-meshed by the virtual scanner (no shared vertices), in mm."""
    from core.registration.virtual_scanner import scan_face

    return scan_face(model, n_target=30_000, rng=np.random.default_rng(5)).face


def to_bust_units(points, units=UNITS):
    """mm in the model's frame -> the bust file's frame and units."""
    return (apply_transform(points, rigid_transform(PITCH, SHIFT))) / units


def make_bust(face_scan, units=UNITS) -> Face:
    """The face scan on top of shoulders (a box as wide as a torso under the chin), tilted, moved and
    stored in ``units``-mm units: the scan's centroid is far below the face."""
    torso = trimesh.creation.box(extents=(330.0, 170.0, 160.0))
    torso.apply_translation((0.0, -200.0, -70.0))
    offset = face_scan.n_vertices
    vertices = np.concatenate([face_scan.vertices, torso.vertices])
    triangles = np.concatenate([face_scan.triangles, torso.faces + offset])
    uv = np.concatenate([face_scan.uv, np.zeros((len(torso.vertices), 2))])
    return Face(to_bust_units(vertices, units), triangles, uv=uv, texture=face_scan.texture)


@pytest.fixture(scope="module")
def bust(face_scan):
    """The bust stored in 4.5-mm units: its size is 'wrong' too."""
    return make_bust(face_scan)


def test_locate_face_recovers_units_and_placement(model, bust):
    found = locate_face(bust, model)
    assert found.scale == pytest.approx(UNITS, rel=0.04)
    # The model's nose tip and eye corners land where the bust has them.
    names = ["9.3", "3.7", "3.12", "8.3", "8.4"]
    truth = to_bust_units(model.landmark_positions(names))
    placed = apply_transform(model.landmark_positions(names), np.linalg.inv(found.scale_transform))
    err_mm = np.linalg.norm(placed - truth, axis=1) * UNITS
    assert err_mm.max() < 4.0, dict(zip(names, err_mm.round(1)))
    assert found.model_paired > 0.7   # at most 0.8: ICP trims the worst 20 % of the pairs


def test_skin_fit_tells_a_face_scan_from_a_bust(model, face_scan, bust):
    median, covered = skin_fit(face_scan, model, np.eye(4))
    assert median < 0.5 and covered > 0.95
    # The bust at the model's place, as a centroid start would leave it: far off.
    centred = rigid_transform(translation=model.vertices.mean(axis=0) - bust.vertices.mean(axis=0))
    assert skin_fit(bust, model, centred)[1] < 0.6


def test_detection_on_the_bust_finds_the_landmarks_and_suggests_the_scale(model, face_scan, bust):
    det = detect_landmarks(bust, template="a48")
    assert det.scale_hint == pytest.approx(UNITS, rel=0.04)
    assert any("not millimetres" in line and "Scale face" in line for line in det.report)
    truth = template_positions(face_scan, "a48")
    names = list(truth)
    expected = to_bust_units(np.array([truth[n] for n in names]))
    err_mm = np.linalg.norm(np.array([det.positions[n] for n in names]) - expected, axis=1) * UNITS
    eye_distance = np.linalg.norm(truth["3.7"] - truth["3.12"])
    assert np.mean(err_mm < 0.1 * eye_distance) > 0.9, dict(zip(names, err_mm.round(1)))
    # Surface points sit on the bust at the reported positions (bust units).
    for n, p in det.landmarks.items():
        on_surface = np.array(p.barycentric) @ bust.vertices[bust.triangles[p.triangle]]
        assert np.allclose(on_surface, det.positions[n], atol=1e-6)


def test_a_scan_in_millimetres_gets_no_scale_hint(face_scan):
    assert detect_landmarks(face_scan, template="a48").scale_hint is None


def test_a_bust_in_millimetres_is_matched_at_its_own_size(face_scan):
    bust_mm = make_bust(face_scan, units=1.0)
    det = detect_landmarks(bust_mm, template="a48")
    assert det.scale_hint is None
    truth = template_positions(face_scan, "a48")
    names = list(truth)
    err = np.linalg.norm(np.array([det.positions[n] for n in names])
                         - to_bust_units(np.array([truth[n] for n in names]), 1.0), axis=1)
    assert np.median(err) < 1.5 and np.mean(err < 9.0) > 0.95


def test_something_that_is_no_face_is_reported(model):
    ball = trimesh.creation.icosphere(subdivisions=4, radius=90.0)
    with pytest.raises(FaceNotFoundError, match="upright"):
        locate_face(Face(ball.vertices, ball.faces), model)


@pytest.mark.parametrize("axis, degrees, label", [((1, 0, 0), -90, "z-up, facing -y"), ((0, 1, 0), 90, "facing +x"),
                                                  ((0, 0, 1), 180, "upside down")])
def test_a_scan_facing_another_way_is_turned_and_landmarked_as_it_lies(model, face_scan, axis, degrees, label):
    from core.registration.alignment import find_orientation

    upright = detect_landmarks(face_scan)
    R = rotation_about_axis(axis, degrees)
    turned_scan = face_scan.with_vertices(face_scan.vertices @ R.T)
    orientation = find_orientation(turned_scan, model)
    assert orientation.turned and abs(orientation.angle_deg - abs(degrees)) < 15, label
    assert np.degrees(np.arccos(np.clip((np.trace(orientation.rotation @ R) - 1) / 2, -1, 1))) < 15, \
        "the turn undoes the rotation"
    found = detect_landmarks(turned_scan)
    assert "did not face forward" in found.report[0]
    # The same landmarks, on the scan as it lies: positions rotated with it, surface points identical.
    errors = [np.linalg.norm(found.positions[n] - R @ upright.positions[n]) for n in upright.positions]
    assert np.median(errors) < 1.0 and np.max(errors) < 5.0
    for n in list(upright.landmarks)[:5]:
        point = found.landmarks[n]
        corners = turned_scan.vertices[turned_scan.triangles[point.triangle]]
        np.testing.assert_allclose(np.asarray(point.barycentric) @ corners, found.positions[n], atol=1e-6)


def test_an_upright_scan_is_not_turned(model, face_scan):
    from core.registration.alignment import find_orientation

    orientation = find_orientation(face_scan, model)
    assert not orientation.turned and orientation.median_mm < 2.0
    assert not any("did not face forward" in line for line in detect_landmarks(face_scan).report)
