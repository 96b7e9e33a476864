"""Slivers left by snapping grid rims onto a curve: found, removed, and none around the eyes."""

import numpy as np

from core.default_face import generate_face
from core.default_face.rim_slivers import SLIVER_HEIGHT_RATIO, remove_rim_slivers, sliver_triangles


def _fan():
    """A strip of two good triangles with a sliver ear (2, 3, 4) on its top edge, whose apex 3 sits
    0.01 above the middle of 2-4: (0,0) (2,0) / (0,1) (1,1.01) (2,1)."""
    xy = np.array([[0, 0], [2, 0], [0, 1], [1, 1.01], [2, 1]], float)
    tris = np.array([[0, 1, 4], [0, 4, 2], [2, 4, 3]])
    return xy, tris


def test_a_lone_ear_on_the_rim_goes_with_its_apex():
    xy, tris = _fan()
    rim = np.array([False, False, True, True, True])
    assert list(sliver_triangles(xy, tris, rim)) == [2]
    out = remove_rim_slivers(xy, tris, rim, pinned=np.zeros(5, bool))
    assert sorted(map(tuple, out)) == [(0, 1, 4), (0, 4, 2)]


def test_a_shared_apex_merges_into_the_nearer_end_without_turning_anything_over():
    # The rim runs 2 -> 3 -> 4 with 3 a hair below the line 2-4; 3 also has two sound triangles below.
    xy = np.array([[0, 0], [2, 0], [0, 1], [0.7, 0.99], [2, 1]], float)
    tris = np.array([[2, 3, 4], [0, 1, 3], [1, 4, 3], [0, 3, 2]])

    def area2(t):
        a, b, c = xy[t[:, 0]], xy[t[:, 1]], xy[t[:, 2]]
        return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])

    assert (area2(tris) > 0).all()
    rim = np.array([False, False, True, True, True])
    out = remove_rim_slivers(xy, tris, rim, pinned=np.zeros(5, bool))
    assert sorted(map(tuple, out)) == [(0, 1, 2), (1, 4, 2)]      # 3 merged into 2, the nearer end
    assert (area2(out) > 0).all() and not len(sliver_triangles(xy, out))
    # Pinned (an exact eye corner), it stays.
    pinned = np.array([False, False, False, True, False])
    assert len(remove_rim_slivers(xy, tris, rim, pinned)) == 4


def test_generated_faces_have_no_slivers_on_their_eye_rims():
    for face in (generate_face(full_head=False),):
        skin = ~np.any([face.part_mask(n) for n in face.parts], axis=0)
        tris = face.triangles[skin[face.triangles].all(axis=1)]
        e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
        uniq, count = np.unique(e, axis=0, return_counts=True)
        boundary = np.zeros(face.n_vertices, bool)
        boundary[uniq[count == 1]] = True
        v = face.vertices
        # Eye rims: boundary vertices above the nose tip and inside the outline.
        eye_rim = boundary & (v[:, 1] > face.landmark_position("9.3")[1] - 25) & (np.abs(v[:, 0]) < 50)
        near = eye_rim[tris].sum(axis=1) >= 2
        corners = v[tris[near]]
        longest = np.linalg.norm(corners[:, [1, 2, 0]] - corners, axis=2).max(axis=1)
        height = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1) / longest
        assert near.sum() > 100
        assert (height >= 0.5 * SLIVER_HEIGHT_RATIO * longest).all(), np.sort(height / longest)[:5]
