"""Framing a face: the head down to just below the chin, in the face's own orientation."""

import numpy as np

from core.default_face import load_default_face
from core.face import Face
from core.framing import BELOW_CHIN_SHARE, portrait_points


def test_the_portrait_keeps_the_head_and_drops_the_neck():
    face = load_default_face()
    chin = face.landmark_position("2.1")
    up = (face.landmark_position("3.5") + face.landmark_position("3.6")) / 2 - chin
    span = np.linalg.norm(up)
    height = (face.vertices - chin) @ (up / span)
    kept = portrait_points(face)
    assert len(kept) == int((height >= -BELOW_CHIN_SHARE * span).sum())
    assert np.isclose(kept[:, 1].max(), face.vertices[:, 1].max())              # the crown stays
    head = face.vertices[face.vertices[:, 1] > chin[1]]
    assert np.isclose(np.ptp(kept[:, 0]), np.ptp(head[:, 0]))                     # ear to ear stays
    assert np.ptp(kept[:, 0]) < np.ptp(face.vertices[:, 0])                       # the shoulders' start goes
    assert kept[:, 1].min() > chin[1] - 0.25 * span                              # a little below the chin
    assert face.vertices[:, 1].min() < chin[1] - 50.0                            # the neck is dropped


def test_the_cut_follows_the_face_not_the_world_axes():
    face = load_default_face()
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])      # lying on its side
    lying = face.with_vertices(face.vertices @ turn.T)
    assert len(portrait_points(lying)) == len(portrait_points(face))


def test_eye_corners_stand_in_for_the_pupils():
    """A detected face has the eye corners but not the pupils: the cut is nearly the same."""
    face = load_default_face()
    corners_only = Face(face.vertices, face.triangles, parts=face.parts,
                        landmarks={n: p for n, p in face.landmarks.items() if n not in ("3.5", "3.6")})
    with_pupils, without = len(portrait_points(face)), len(portrait_points(corners_only))
    assert without < face.n_vertices and abs(without - with_pupils) < 0.02 * face.n_vertices


def test_a_face_without_feature_points_is_framed_whole():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    face = Face(v, np.array([[0, 1, 2]]))
    assert np.array_equal(portrait_points(face), v)
