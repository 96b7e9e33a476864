"""Known answers of the face-quality measures (core.mesh_quality)."""

import numpy as np
import pytest

from core.face import Face
from core.mesh_quality import (FaceQualityProbe, count_intersections, principal_stretches, welded_vertices,
                               triangles_intersect, _local_frames)


def _pair(offset_z: float) -> np.ndarray:
    """Two triangles: one in z = 0, one vertical crossing it when offset_z straddles 0."""
    flat = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0]], float)
    upright = np.array([[1, 1, -1 + offset_z], [1, 1, 1 + offset_z], [2, 1.5, offset_z]], float)
    return flat, upright


def test_crossing_triangles_are_found_and_apart_or_touching_ones_are_not():
    flat, upright = _pair(0.0)
    assert triangles_intersect(flat[None], upright[None])[0]
    flat, upright = _pair(5.0)
    assert not triangles_intersect(flat[None], upright[None])[0]
    # Touching along a shared position (lips closed on each other) is not a crossing.
    touching = np.array([[1, 1, 0], [1, 1, 2], [2, 1.5, 1]], float)
    assert not triangles_intersect(flat[None], touching[None])[0]


def test_count_intersections_within_and_between_sets_skips_neighbours():
    flat, upright = _pair(0.0)
    vertices = np.vstack([flat, upright, [[4, 4, 0]]])
    tris = np.array([[0, 1, 2], [3, 4, 5], [1, 6, 2]])   # triangle 2 shares an edge with triangle 0
    assert count_intersections(vertices, tris) == 1
    assert count_intersections(vertices, tris[:1], tris[1:2]) == 1
    moved = vertices.copy()
    moved[3:6, 2] += 5.0
    assert count_intersections(moved, tris) == 0


def test_a_seams_copies_of_a_vertex_count_as_one_vertex():
    flat, upright = _pair(0.0)
    vertices = np.vstack([flat, upright, flat[:1]])      # vertex 6: a seam's copy of vertex 0
    welded = welded_vertices(vertices)
    assert welded.tolist() == [0, 1, 2, 3, 4, 5, 0]
    crossing = np.array([[6, 1, 2]]), np.array([[3, 4, 5]])
    assert count_intersections(vertices, *crossing, welded) == 1          # no shared vertex: counted
    touching = np.array([[0, 1, 2]]), np.array([[6, 4, 5]])                # meet at the copied vertex
    assert count_intersections(vertices, *touching, welded) == 0


def test_principal_stretches_of_known_maps():
    rest = np.array([[[0, 0, 0], [2, 0, 0], [0, 1, 0]]], float)
    frames = _local_frames(rest)
    # Uniform scale by 3 -> both stretches 3; a rigid rotation -> 1; stretch along x only -> (2, 1).
    big, small = principal_stretches(frames, rest * 3)
    assert big[0] == pytest.approx(3) and small[0] == pytest.approx(3)
    c, s = np.cos(0.7), np.sin(0.7)
    rotation = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    big, small = principal_stretches(frames, rest @ rotation.T + 5)
    assert big[0] == pytest.approx(1) and small[0] == pytest.approx(1)
    big, small = principal_stretches(frames, rest * np.array([2.0, 1.0, 1.0]))
    assert big[0] == pytest.approx(2) and small[0] == pytest.approx(1)


def _grid(n=12):
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.vstack([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return vertices, tris


def test_probe_counts_a_fold_and_stretch_but_not_a_rigid_move():
    vertices, tris = _grid()
    probe = FaceQualityProbe(Face(vertices, tris))
    quality = probe.measure(vertices + [3.0, -2.0, 1.0])
    assert quality.folded_triangles == 0 and quality.failures() == []
    assert quality.lip_intersections is None            # no feature points, no lip region
    folded = vertices.copy()
    folded[5 * 12 + 5, 0] += 2.5                          # drag one vertex past its neighbour
    quality = probe.measure(folded)
    assert quality.folded_triangles > 0
    assert quality.max_stretch > 2.0
    assert any("folded" in why for why in quality.failures())


def _eye_face(vertices, skin_tris, ball):
    """A face of a skin plate and an eyeball part, with the left eye's corners at x = -3 and 3."""
    from core.face import SurfacePoint

    n_skin = len(vertices)
    ball_idx = np.arange(n_skin, n_skin + len(ball))
    ball_tris = np.column_stack([ball_idx[:-2], ball_idx[1:-1], ball_idx[2:]])
    face = Face(np.vstack([vertices, ball]), np.vstack([skin_tris, ball_tris]), parts={"eyeball_l": ball_idx})
    for name, x in {"3.7": -3.0, "3.11": 3.0, "3.8": -3.0, "3.12": 3.0}.items():
        vertex = int(np.argmin(np.linalg.norm(vertices - [x, 0, 0], axis=1)))
        t = int(np.nonzero((skin_tris == vertex).any(axis=1))[0][0])
        face.set_landmark(name, SurfacePoint(t, tuple((skin_tris[t] == vertex).astype(float))))
    return face


def test_eye_openness_sees_a_lid_closing_over_an_eyeball():
    # An eyeball (a small sphere) behind a skin plate with a hole; closing the hole hides it.
    vertices, tris = _grid(21)
    vertices[:, :2] -= 10.0
    in_hole = np.linalg.norm(vertices[tris].mean(axis=1)[:, :2], axis=1) < 3.0
    u, v = np.meshgrid(np.linspace(0.1, np.pi - 0.1, 10), np.linspace(0, 2 * np.pi, 16, endpoint=False))
    ball = np.column_stack([np.sin(u.ravel()) * np.cos(v.ravel()), np.sin(u.ravel()) * np.sin(v.ravel()),
                            np.cos(u.ravel())]) * 2.0 - [0, 0, 2.5]
    open_face = _eye_face(vertices, tris[~in_hole], ball)
    assert FaceQualityProbe(open_face).eye_openness(open_face.vertices)["left"] > 0.5
    closed = _eye_face(vertices, tris, ball)
    assert FaceQualityProbe(closed).eye_openness(closed.vertices)["left"] == 0.0


def test_skin_pulled_into_the_mouth_cavity_is_counted():
    """The probe counts mouth skin crossing the mouth cavity's lining (a region pulled in through the
    lips): none at rest; the chin's skin pushed 20 mm back into the head crosses it."""
    from core.default_face import load_default_face

    face = load_default_face()
    probe = FaceQualityProbe(face)
    assert probe.measure(face.vertices).cavity_intersections == 0
    chin = face.landmark_position("2.1")
    in_part = np.zeros(face.n_vertices, bool)
    for idx in face.parts.values():
        in_part[idx] = True
    near_chin = (np.linalg.norm(face.vertices - chin, axis=1) < 25.0) & ~in_part
    pushed = face.vertices.copy()
    pushed[near_chin] += [0.0, 12.0, -20.0]      # up behind the lower lip and back into the mouth
    quality = probe.measure(pushed)
    assert quality.cavity_intersections > 0
    assert any("mouth cavity" in why for why in quality.failures())


def test_crossings_the_rest_face_already_has_fail_only_the_rest_pose():
    """A registered scan can cross itself at rest (its closed lips, the creases by its nose wings):
    those pairs are the face's, reported with each pose (``at_rest``), failing the rest pose when
    asked (``count_rest``); a pose fails on the pairs it makes cross."""
    from core.face import SurfacePoint

    plate, plate_tris = _grid()
    upright = np.array([[5.3, 5.3, -1.0], [5.3, 5.3, 1.0], [6.3, 5.8, 0.0]])
    vertices = np.vstack([plate, upright])
    tris = np.vstack([plate_tris, [[144, 145, 146]]])
    face = Face(vertices, tris)
    for name, x in {"8.3": 2.0, "8.4": 9.0}.items():
        vertex = 5 * 12 + int(x)
        t = int(np.nonzero((plate_tris == vertex).any(axis=1))[0][0])
        face.set_landmark(name, SurfacePoint(t, tuple((plate_tris[t] == vertex).astype(float))))
    probe = FaceQualityProbe(face)
    rest = probe.measure(vertices)
    assert rest.lip_intersections >= 1 and rest.at_rest == {"lip": rest.lip_intersections}
    assert rest.failures() == []
    assert rest.failures(count_rest=True) == [f"{rest.lip_intersections} lip intersections "
                                              f"({rest.lip_intersections} already at rest)"]
    moved = vertices.copy()
    moved[144:] += [-3.0, 0.0, 0.0]           # the same triangle through other plate triangles
    pose = probe.measure(moved)
    assert pose.lip_intersections >= 1 and pose.at_rest == {}
    assert pose.failures() == [f"{pose.lip_intersections} lip intersections"]
    apart = vertices.copy()
    apart[144:, 2] += 5.0
    assert probe.measure(apart).lip_intersections == 0 and probe.measure(apart).failures() == []
