"""The built-in default face: deterministic, complete, human-shaped, open at mouth and eyes."""

import numpy as np
import pytest

import resources
from core.default_face import FaceLayout, FaceParameters, generate_face, load_default_face
from core.default_face.mouth import MouthInterior
from core.default_face.shape import OUTLINE_T, FaceShape
from core.face import Face

JAW_DROP = 25.0  # mm, the FAP engine opens the jaw by up to this much at the chin
PARTS = ("eyeball_l", "eyeball_r", "mouth_cavity", "teeth_upper", "teeth_lower")


@pytest.fixture(scope="module")
def face():
    """The front of the face (the scan-like surface; the full head is tested in test_default_head.py)."""
    return generate_face(full_head=False)


@pytest.fixture(scope="module")
def layout():
    return FaceLayout.from_parameters(FaceParameters())


@pytest.fixture(scope="module")
def shape(layout):
    return FaceShape(layout)


def part_face(face: Face, names) -> Face:
    """A face of only the triangles whose vertices all belong to the named parts (same vertex array)."""
    mask = np.zeros(face.n_vertices, bool)
    for name in names:
        mask |= face.part_mask(name)
    return Face(face.vertices, face.triangles[mask[face.triangles].all(axis=1)])


def skin_mask(face: Face) -> np.ndarray:
    return ~np.any([face.part_mask(name) for name in face.parts], axis=0)


def dense_surface_samples(face: Face, names) -> np.ndarray:
    """Vertices, edge midpoints and centroids of the named parts' triangles (k, 3)."""
    sub = part_face(face, names)
    corners = sub.vertices[sub.triangles]
    mids = (corners + np.roll(corners, 1, axis=1)) / 2
    return np.concatenate([corners.reshape(-1, 3), mids.reshape(-1, 3), corners.mean(axis=1)])


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
    assert np.array_equal(a.uv, b.uv)
    assert a.landmarks == b.landmarks
    assert a.parts.keys() == b.parts.keys()
    assert all(np.array_equal(a.parts[k], b.parts[k]) for k in a.parts)


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


def test_eyeball_rims_are_tucked_behind_the_skin_at_the_outer_corners(face, layout, shape):
    """Known answers: inside the palpebral opening (and up to the tuck's start) each ball is exactly
    its ellipsoid; its open rim lies at least RIM_CLEARANCE_MM behind the skin's height field along
    the ball's normal (untucked, the default face's outer-corner rim was 0.01 mm behind the skin's
    triangles); only the outer side moves."""
    from core.default_face.build import EYE_SEGMENTS, RIM_CLEARANCE_MM, _skin_along

    radii = shape.eyeball_radii()
    corner = np.degrees(np.arcsin((layout.eye_outer_x - layout.eye_inner_x) / 2 / radii[0]))
    for k, name in enumerate(("eyeball_l", "eyeball_r")):
        centre = shape.eyeball_centres()[k]
        ball = face.vertices[face.parts[name]]
        u = (ball - centre) / radii
        q = np.linalg.norm(u, axis=1)
        theta = np.degrees(np.arccos(np.clip(u[:, 2] / q, -1.0, 1.0)))
        assert np.abs(q[theta < corner + 5.0] - 1.0).max() < 1e-9      # the visible ball is untouched
        tucked = q < 1.0 - 1e-9
        assert tucked.any() and (q > 0.9).all()
        lateral = np.sign(ball[:, 0] - centre[0]) == np.sign(centre[0])
        assert lateral[tucked].all()                                   # the outer side only
        rim = face.parts[name][-EYE_SEGMENTS:]
        normal = u[-EYE_SEGMENTS:] / radii
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        depth = _skin_along(shape, face.vertices[rim], normal)
        assert depth.min() > RIM_CLEARANCE_MM - 0.02


def test_parameters_out_of_range_are_refused():
    with pytest.raises(ValueError, match="nose_length = 90"):
        FaceParameters(nose_length=90)


@pytest.mark.parametrize("full_head", [False, True])
def test_committed_copy_matches_the_generator(face, full_head):
    stored = load_default_face(full_head=full_head)
    face = generate_face(full_head=True) if full_head else face
    assert stored.n_vertices == face.n_vertices
    assert np.array_equal(stored.triangles, face.triangles)
    assert np.allclose(stored.vertices, face.vertices, atol=1e-4)
    assert np.array_equal(stored.texture, face.texture)
    assert np.allclose(stored.uv, face.uv, atol=1e-6)
    assert stored.landmark_positions() == pytest.approx(face.landmark_positions(), abs=1e-3)
    assert stored.parts.keys() == face.parts.keys()
    assert all(np.array_equal(stored.parts[k], face.parts[k]) for k in face.parts)


def test_committed_copy_is_small():
    from core.default_face import default_face_path

    assert default_face_path().stat().st_size < 4_000_000


# ---------------------------------------------------------------- parts
def test_parts_are_present_disjoint_and_whole_components(face):
    assert set(face.parts) == set(PARTS)
    labels = face.component_labels
    seen = np.zeros(face.n_vertices, int)
    for name in PARTS:
        idx = face.parts[name]
        assert len(idx) > 100
        seen[idx] += 1
        # Each part is exactly one connected component.
        component = np.unique(labels[idx])
        assert len(component) == 1
        assert np.array_equal(np.nonzero(labels == component[0])[0], idx)
    assert seen.max() == 1                                    # disjoint
    skin = skin_mask(face)
    assert len(np.unique(face.component_labels[skin])) == 1   # the rest is one skin
    assert skin.sum() > 45_000


def test_eyeball_parts_are_the_eyeball_components(face):
    labels = face.component_labels
    for name, fp, side in (("eyeball_l", "3.5", 1), ("eyeball_r", "3.6", -1)):
        point = face.landmarks[fp]
        pupil = face.triangles[point.triangle][np.argmax(point.barycentric)]
        assert np.array_equal(np.nonzero(labels == labels[pupil])[0], face.parts[name])
        assert np.all(np.sign(face.vertices[face.parts[name], 0]) == side)   # +x is the face's left


# ---------------------------------------------------------------- mouth interior
def test_mouth_cavity_lies_behind_the_skin(face, shape):
    pts = dense_surface_samples(face, ["mouth_cavity"])
    clearance = shape.skin_depth(pts[:, 0], pts[:, 1]) - pts[:, 2]
    assert clearance.min() >= 2.0
    # ... also behind the lower face moved down with the jaw (by up to JAW_DROP).
    layout = shape.L
    for s in np.linspace(0, JAW_DROP, 11)[1:]:
        from_below = pts[:, 1] + s < layout.mouth_line(pts[:, 0])
        moved = shape.skin_depth(pts[from_below, 0], pts[from_below, 1] + s)
        assert (moved - pts[from_below, 2]).min() >= 2.0
    # Never behind the scan's side edge at that height (the profile view cannot see it).
    edge = shape.skin_depth(OUTLINE_T * shape.half_width(pts[:, 1]), pts[:, 1])
    assert (pts[:, 2] - edge).min() > 3.0


def test_mouth_cavity_extent(face, layout):
    cavity = face.vertices[face.parts["mouth_cavity"]]
    hw = layout.mouth_half_width
    near_line = np.abs(cavity[:, 1] - layout.stomion_y) < 3
    assert cavity[near_line, 0].max() >= hw + 8 and cavity[near_line, 0].min() <= -(hw + 8)
    assert cavity[:, 1].max() >= layout.subnasale_y - 2          # up to about the nose base
    assert cavity[:, 1].min() <= layout.chin_y                   # down past the chin boss


def test_mouth_interior_faces_the_opening(face):
    normals = face.face_normals
    cavity = face.part_mask("mouth_cavity")[face.triangles].all(axis=1)
    assert normals[cavity, 2].min() > 0                           # concave bowl facing +z
    for name in ("teeth_upper", "teeth_lower"):
        sub = part_face(face, [name])
        v = sub.vertices[sub.triangles]
        volume = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6
        assert volume > 500                                       # closed, outward normals
        # The incisors' labial face looks at the viewer.
        front = sub.triangles[np.abs(v[:, :, 0]).max(axis=1) < 2]
        fn = triangle_normals_of(face, front)
        assert fn[:, 2].max() > 0.9


def triangle_normals_of(face, triangles):
    from core.face import triangle_normals

    return triangle_normals(face.vertices, triangles)


def test_teeth_hide_behind_the_lips_at_rest(face, shape, layout):
    pts = dense_surface_samples(face, ["teeth_upper", "teeth_lower"])
    assert (shape.skin_depth(pts[:, 0], pts[:, 1]) - pts[:, 2]).min() >= 2.0
    # The incisors' front is 3-4 mm behind the inner lip contour at the midline.
    upper = face.vertices[face.parts["teeth_upper"]]
    mid = upper[np.abs(upper[:, 0]) < 1e-6]
    setback = face.landmark_position("2.2")[2] - mid[:, 2].max()
    assert 3.0 <= setback <= 4.0
    # And the teeth lie in front of the cavity.
    mouth = MouthInterior(layout, shape)
    assert (pts[:, 2] - mouth.cavity_depth(pts[:, 0], pts[:, 1])).min() > 3.0


def test_open_mouth_shows_cavity_or_teeth(face, layout):
    """Rays from the viewer through the lip opening with the lower lip 25 mm down end inside the mouth."""
    interior = part_face(face, ["mouth_cavity", "teeth_upper", "teeth_lower"])
    hw = layout.mouth_half_width
    xs = np.linspace(-hw + 0.5, hw - 0.5, 47)
    fractions = np.linspace(0.02, 0.98, 25)
    X = np.repeat(xs, len(fractions))
    line = layout.mouth_line(X)
    Y = line - 25.0 * np.tile(fractions, len(xs))
    origins = np.column_stack([X, Y, np.full(len(X), 100.0)])
    _loc, ray, _tri = interior.ray_hits(origins, np.tile([0.0, 0.0, -1.0], (len(X), 1)))
    assert len(np.unique(ray)) == len(X)
    # The cavity alone already covers it (the teeth move with the jaw).
    cavity = part_face(face, ["mouth_cavity"])
    _loc, ray, _tri = cavity.ray_hits(origins, np.tile([0.0, 0.0, -1.0], (len(X), 1)))
    assert len(np.unique(ray)) == len(X)


def test_dropped_lower_teeth_stay_in_front_of_the_cavity(face, layout, shape):
    mouth = MouthInterior(layout, shape)
    lower = face.vertices[face.parts["teeth_lower"]].copy()
    crown = lower[:, 1] > face.landmark_position("9.11")[1] - 4.0     # the incisal 4 mm
    lower[:, 1] -= JAW_DROP
    inside = mouth.cavity_inside(lower[:, 0], lower[:, 1]) & crown
    assert inside.sum() > 100
    assert (lower[inside, 2] - mouth.cavity_depth(lower[inside, 0], lower[inside, 1])).min() > 0.5


def test_mouth_interior_texture_patches(face):
    """The mouth parts have their own texels (no skin or eye texels), painted dark / off-white."""
    H, W = face.texture.shape[:2]

    def texel_box(mask):
        tri = face.triangles[mask[face.triangles].all(axis=1)]
        uv = face.uv[np.unique(tri)]
        return (uv[:, 0].min() * W - 2, uv[:, 0].max() * W + 2, uv[:, 1].min() * H - 2, uv[:, 1].max() * H + 2)

    boxes = {name: texel_box(face.part_mask(name)) for name in PARTS}
    boxes["skin"] = texel_box(skin_mask(face))
    names = list(boxes)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if {a, b} == {"eyeball_l", "eyeball_r"}:
                continue                                      # both eyes share the eye atlas
            A, B = boxes[a], boxes[b]
            overlap = A[0] < B[1] and B[0] < A[1] and A[2] < B[3] and B[2] < A[3]
            assert not overlap, (a, b)

    def colour(idx):
        u, v = face.uv[idx, 0], face.uv[idx, 1]
        return face.texture[np.clip(((1 - v) * H).astype(int), 0, H - 1), np.clip((u * W).astype(int), 0, W - 1)]

    cavity = face.vertices[face.parts["mouth_cavity"]]
    deep = face.parts["mouth_cavity"][np.abs(cavity[:, 0]) < 15]
    assert colour(deep).mean() < 60
    for fp, part in (("9.10", "teeth_upper"), ("9.11", "teeth_lower")):   # central incisors: off-white
        idx = face.parts[part]
        v = face.vertices[idx]
        crown = idx[(np.abs(np.abs(v[:, 0]) - 3.0) < 1.0) & (np.abs(v[:, 1] - face.landmark_position(fp)[1]) < 2.0)]
        rgb = np.median(colour(crown), axis=0)
        assert len(crown) > 4 and rgb.min() > 180 and rgb.max() - rgb.min() < 45, rgb


def test_teeth_feature_points(face, layout):
    pos = {fp: face.landmark_position(fp) for fp in ("9.8", "9.10", "9.11", "9.9")}
    for fp, part in (("9.8", "teeth_upper"), ("9.10", "teeth_upper"), ("9.11", "teeth_lower"), ("9.9", "teeth_lower")):
        tri = face.triangles[face.landmarks[fp].triangle]
        assert face.part_mask(part)[tri].all(), fp
        assert pos[fp][0] == pytest.approx(0.0, abs=1e-9)      # midline
    # Top of upper > bottom of upper > top of lower > bottom of lower.
    assert pos["9.8"][1] > pos["9.10"][1] > pos["9.11"][1] > pos["9.9"][1]
    # The upper incisal edge at about the mouth line, the lower teeth just below it.
    assert pos["9.10"][1] == pytest.approx(layout.mouth_line(0.0), abs=2.5)
    assert 0 < pos["9.10"][1] - pos["9.11"][1] < 2.0
    assert pos["9.8"][1] - pos["9.10"][1] > 6.0 and pos["9.11"][1] - pos["9.9"][1] > 5.0


# ---------------------------------------------------------------- ears
def test_ear_contact_points_on_the_side_edge(face, shape, layout):
    pos = dict(zip(face.landmark_names, face.landmark_positions()))
    for left, right in (("10.7", "10.8"), ("10.9", "10.10")):
        assert pos[left][0] > 0 > pos[right][0]
        assert pos[left] == pytest.approx(pos[right] * [-1, 1, 1], abs=1e-6)
        for fp in (left, right):
            t = float(shape.outline_t(pos[fp][0], pos[fp][1]))
            assert 0.85 < t < OUTLINE_T - 0.02, fp                 # near, but safely inside, the scan edge
            assert pos[fp][2] == pytest.approx(float(shape.skin_depth(pos[fp][0], pos[fp][1])), abs=0.2)
    # Ordered down the left outline: hairline, upper ear contact, lower ear contact, jaw corner.
    assert pos["11.3"][1] > pos["10.9"][1] > pos["10.7"][1] > pos["2.13"][1]
    # Upper contact between the eye corners and the brow; lower at about the nose base.
    assert pos["3.7"][1] <= pos["10.9"][1] <= pos["4.5"][1]
    assert pos["10.7"][1] == pytest.approx(pos["9.15"][1], abs=5.0)
