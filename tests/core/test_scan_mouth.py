"""The registered scan itself animated: lips cut along the lip line, a mouth cavity and teeth behind them."""

import numpy as np
import pytest
import scipy.sparse

from core.registration.correspondence import canonical_triangles
from core.registration.pipeline import register_scan
from core.registration.scan_mouth import (BEHIND_SKIN_MM, ScanMouthError, _depth_below, animated_scan,
                                          inner_lip_halves, lip_labels)
from core.registration.templates import get_template


@pytest.fixture(scope="module")
def registration():
    from core.default_face import load_default_face
    from core.registration.virtual_scanner import scan_face

    scan = scan_face(load_default_face(full_head=False), n_target=30_000, rng=np.random.default_rng(5)).face
    return register_scan(scan, scan.landmarks, template="mpeg4_80")


@pytest.fixture(scope="module")
def animated(registration):
    return animated_scan(registration)


@pytest.fixture(scope="module")
def jaw_open(registration):
    from core.rig import FaceRig

    rig = FaceRig(registration.face)
    rig.set_fap(3, 400)                     # open_jaw
    return rig.vertices()


def _edge_growth(rest, moved, triangles):
    """(T,) mm: how much each triangle's longest-growing edge lengthened."""
    def lengths(v):
        return np.linalg.norm(v[triangles] - v[np.roll(triangles, 1, axis=1)], axis=2)
    return (lengths(moved) - lengths(rest)).max(axis=1)


def test_lip_halves_split_the_mouth_loop_at_the_inner_corners():
    triangles = canonical_triangles("mpeg4_80")
    base = get_template("mpeg4_80").base
    upper, lower = inner_lip_halves(triangles, "mpeg4_80")
    assert base.index("2.2") in upper and base.index("2.3") in lower
    assert not {base.index("2.4"), base.index("2.5")} & (set(upper) | set(lower))
    labels = lip_labels(triangles, "mpeg4_80")
    assert (labels[upper] == 1).all() and (labels[lower] == -1).all()
    assert labels[base.index("11.1")] == 0            # the forehead is neither lip


def test_rest_pose_is_the_scan_and_the_cut_is_closed(registration, animated):
    scan = registration.scan
    n_skin = animated.n_scan + animated.n_copies
    assert animated.n_copies > 0
    rest = animated.vertices(registration.face.vertices)
    assert np.array_equal(rest[:scan.n_vertices], scan.vertices)
    assert np.allclose(rest[:n_skin], animated.face.vertices[:n_skin], atol=1e-9)


def test_the_jaw_opens_the_scans_mouth_instead_of_stretching_its_lips(registration, animated, jaw_open):
    scan = registration.scan
    # Carried back whole, the triangles across the lip line stretch into a web as the jaw opens.
    webbed = _edge_growth(scan.vertices, registration.carry_back().apply(jaw_open), scan.triangles)
    assert webbed.max() > 5.0
    face = animated.face
    skin = face.triangles[(face.triangles < animated.n_scan + animated.n_copies).all(axis=1)]
    grown = _edge_growth(face.vertices, animated.vertices(jaw_open), skin)
    assert grown.max() < 1.5
    assert (_edge_growth(face.vertices, animated.vertices(registration.face.vertices), skin) == 0).all()


def _pair_distances(points):
    """(k,) distances between every 23rd point and the next sample (a fixed subset of pairs)."""
    sample = points[::23]
    return np.linalg.norm(sample[1:] - sample[:-1], axis=1)


def test_teeth_and_cavity_sit_behind_the_lips_and_the_lower_teeth_follow_the_jaw(registration, animated, jaw_open):
    face = animated.face
    # Placed by the landmarks alone, 19 % of the upper teeth's vertices were less than half a
    # millimetre behind the canonical face (or in front of it); a few stay where the lips part (the
    # depth under the opening's edge has no clear sign).
    # (With the fold-free fit the rim of the canonical mouth sits a little differently: 1-2 % of the
    # teeth's vertices end 1 mm from the rim's edge, where that depth's sign says little.) What
    # counts: at rest, seen from the front, no vertex of the mouth parts shows in front of the skin.
    from core.registration.correspondence import SurfaceRays

    rays = SurfaceRays(face.vertices, face.triangles)
    canonical = SurfaceRays(registration.face.vertices, registration.face.triangles)
    skin_triangle = (face.triangles < animated.n_scan + animated.n_copies).all(axis=1)
    for name in ("mouth_cavity", "teeth_upper", "teeth_lower"):
        points = face.vertices[face.parts[name]]
        depth, _, _ = _depth_below(registration.face, points)
        if name != "mouth_cavity" and canonical.engine == "embree":
            # A tooth's depth along the face's forward direction: behind closed lips the skin closest
            # to it is often the lips' inner surface, facing down or up, and the depth below that has
            # no clear sign (4 % of the upper teeth "in front" of it, though behind the lips).
            hit_at, _, hit = canonical.first_hits(points, np.tile([0.0, 0.0, 1.0], (len(points), 1)))
            depth = np.where(hit, hit_at[:, 2] - points[:, 2], -np.inf)
        assert (depth < BEHIND_SKIN_MM / 2).mean() < 0.02, name
        if rays.engine == "embree":
            _, tri, hit = rays.first_hits(points + [0.0, 0.0, 50.0], np.tile([0.0, 0.0, -1.0], (len(points), 1)))
            assert not (hit & ~skin_triangle[np.maximum(tri, 0)]).any(), f"{name} shows through the closed lips"
    # Each row of teeth keeps the donor's shape (one similarity, then moved back as one): pushed point
    # by point below the skin closest to them, which behind closed lips is often the lips' inner
    # surface, LeePerrySmith's arches tore into shards between parted lips.
    from core.default_face import load_default_face

    donor = load_default_face(full_head=False)           # animated_scan's donor when none is given
    for name in ("teeth_upper", "teeth_lower"):
        ratio = _pair_distances(face.vertices[face.parts[name]]) / _pair_distances(donor.vertices[donor.parts[name]])
        assert ratio.std() < 1e-9 * ratio.mean(), name
    moved = animated.vertices(jaw_open) - face.vertices
    assert np.abs(moved[face.parts["teeth_upper"]]).max() == 0
    assert np.abs(moved[face.parts["mouth_cavity"]]).max() == 0
    lower = moved[face.parts["teeth_lower"]]
    assert lower[:, 1].mean() < -2.0                  # down with the jaw (the chin moves 7.7 mm)
    # rigidly: distances between lower-teeth vertices are kept
    a, b = face.vertices[face.parts["teeth_lower"]][[0, -1]]
    a2, b2 = (face.vertices + moved)[face.parts["teeth_lower"]][[0, -1]]
    assert np.isclose(np.linalg.norm(a - b), np.linalg.norm(a2 - b2))


def test_the_scan_keeps_its_texture_and_the_parts_get_the_default_faces(registration, animated):
    scan, face = registration.scan, animated.face

    def colour(image, uv):
        h, w = image.shape[:2]
        col = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
        row = np.clip(((1 - uv[:, 1]) * h).astype(int), 0, h - 1)
        return image[row, col].astype(int)

    before = colour(scan.texture, scan.uv)
    after = colour(face.texture, face.uv[:scan.n_vertices])
    assert np.median(np.abs(before - after)) <= 2
    teeth = colour(face.texture, face.uv[face.parts["teeth_upper"]])
    assert teeth.mean() > 150                          # light teeth, not skin or background


def test_a_canonical_face_without_a_mouth_opening_is_refused_with_a_reason():
    triangles = canonical_triangles("mpeg4_80")
    closed = np.concatenate([triangles, triangles[:, ::-1]])     # every edge paired: no opening anywhere
    with pytest.raises(ScanMouthError, match="no mouth opening"):
        inner_lip_halves(closed, "mpeg4_80")


def test_the_animated_scan_carries_the_registrations_landmarks_each_inner_lip_point_on_its_own_lip(
        registration, animated):
    canonical, face = registration.face, animated.face
    names = canonical.landmark_names
    assert set(face.landmark_names) == set(names)
    gap = dict(zip(names, np.linalg.norm(face.landmark_positions(names) - canonical.landmark_positions(names), axis=1)))
    base = get_template("mpeg4_80").base
    lips = base.upper_lip_points | base.lower_lip_points
    # (on the scan: the fold-free fit may leave a landmark vertex a few micrometres off it)
    assert max(g for n, g in gap.items() if n not in lips) < 1e-2, "where the registration put them"
    # an inner-lip point on a cut triangle kept by the other lip moves to the nearest of its own
    assert max(g for n, g in gap.items() if n in lips) < 1.0
    labels = lip_labels(canonical.triangles, "mpeg4_80")
    n_skin = animated.n_scan + animated.n_copies
    score = animated.matrix @ labels.astype(float)
    side = np.where(score > 0.5, 1, np.where(score < -0.5, -1, 0))    # +1 upper lip, -1 lower lip (skin)
    for name in ("2.2", "2.3", "2.6", "2.9"):
        corners = face.triangles[face.landmarks[name].triangle]
        assert (corners < n_skin).all()
        own = 1 if name in base.upper_lip_points else -1
        assert not (side[corners] == -own).any(), f"{name} sits on a triangle of the other lip"


def test_a_rig_on_the_animated_scan_uses_the_registration_fit_and_opens_the_jaw(registration, animated):
    from core.layers.fap.fat import FapDeformer
    from core.rig import FaceRig

    assert animated.dense is not None
    assert np.array_equal(animated.dense.vertices, registration.face.vertices)
    deformer = FapDeformer(animated.face, dense=animated.dense)
    assert deformer.dense is animated.dense
    rig = FaceRig(animated.face, deformer)
    rig.set_fap(3, 400)
    face = animated.face
    moved = face.landmark_positions(["2.2", "2.3"], rig.vertices()) - face.landmark_positions(["2.2", "2.3"])
    assert moved[1, 1] < -2.0 and abs(moved[0, 1]) < 0.5 * abs(moved[1, 1])


def test_closing_the_slits_adds_no_sliver(animated):
    """The slits' closing triangles span them: none joins collinear vertices of one scanner row (the
    synthetic scan's two slits gave 4 triangles 0.007 mm high, whose "stretch" capped the jaw's
    slider at 44 MNS)."""
    from core.mesh_quality import height_ratios

    assert (height_ratios(animated.face.vertices[animated.face.triangles]) < 0.01).sum() == 0


def test_a_slit_left_between_closed_lips_is_closed_and_still_opens_with_the_jaw(registration, jaw_open):
    """A scanner leaves slits where it cannot see into the closed lips' fold (a Surrey Face Model scan:
    5 mm slits along the whole lip line, through which the added teeth showed white at rest): closed
    by triangles between the slit's own vertices, which the lip cut then parts with the jaw."""
    from core.face import Face
    from core.registration.correspondence import SurfaceRays
    from core.registration.scan_mouth import _scan_lip_labels

    scan = registration.scan
    side = _scan_lip_labels(registration.carry_back().binding.matrix, lip_labels(registration.face.triangles, "mpeg4_80"))
    corner = side[scan.triangles]
    middle = scan.landmark_position("2.2")
    centroid = scan.vertices[scan.triangles].mean(axis=1)
    across = (corner == 1).any(axis=1) & (corner == -1).any(axis=1)
    slit = across & (np.abs(centroid[:, 0] - middle[0]) < 3.0)
    assert 3 <= slit.sum() < 40
    holed = Face(scan.vertices, scan.triangles[~slit], uv=scan.uv, texture=scan.texture)
    names = scan.landmark_names
    again = register_scan(holed, dict(zip(names, scan.landmark_positions(names))), template="mpeg4_80")
    animated = animated_scan(again)
    face = animated.face
    # At rest a ray from in front of the slit meets the skin, not the teeth or the cavity behind it.
    target = centroid[slit].mean(axis=0)
    rays = SurfaceRays(face.vertices, face.triangles)
    if rays.engine != "embree":
        pytest.skip("ray casting needs embreex")
    _, tri, hit = rays.first_hits(target[None] + [0.0, 0.0, 30.0], np.array([[0.0, 0.0, -1.0]]))
    in_part = np.zeros(face.n_vertices, bool)
    in_part[np.concatenate(list(face.parts.values()))] = True
    assert hit[0] and not in_part[face.triangles[tri[0]]].any()
    # The jaw still opens it: no skin web across the opening.
    skin = face.triangles[(face.triangles < animated.n_scan + animated.n_copies).all(axis=1)]
    assert _edge_growth(face.vertices, animated.vertices(jaw_open), skin).max() < 1.5


def _slit_sheet(upper_row: int):
    """A flat 20 x 4 grid (1 mm, z = 0; its outer border wider than a slit) with a 4 x 1 mm slit
    between rows 1 and 2 (x 1..5); rows from ``upper_row`` up are the upper lip (+1), the others the
    lower lip (-1); each vertex bound to its own canonical vertex."""
    from core.face import Face

    width = 20
    xs, ys = np.meshgrid(np.arange(float(width)), np.arange(4.0))
    vertices = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(4 * width)])
    triangles = []
    for row in range(3):
        for x in range(width - 1):
            if row == 1 and 1 <= x < 5:
                continue                                   # the slit
            a, b = row * width + x, row * width + x + 1
            triangles += [(a, b, b + width), (a, b + width, a + width)]
    side = np.where(vertices[:, 1] >= upper_row, 1, -1)
    return Face(vertices, np.array(triangles)), side, scipy.sparse.identity(4 * width, format="csr")


def _area(vertices, triangles):
    corners = vertices[triangles]
    return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1).sum()


def test_a_slit_between_the_lips_is_closed_by_two_halves_meeting_in_its_middle():
    """A slit whose sides are on different lips is where they part: each lip closes its half, up to
    a middle line whose vertices move with their own side (kept whole and cut, a closing triangle
    reached across to the other lip's rim, and pressed lips passed through it at once)."""
    from core.registration.scan_mouth import _with_lip_slits_closed

    sheet, side, matrix = _slit_sheet(upper_row=2)
    closed, labels, rows = _with_lip_slits_closed(sheet, side, matrix)
    fill = closed.triangles[len(sheet.triangles):]
    assert _area(closed.vertices, fill) == pytest.approx(4.0)          # the whole slit, nothing more
    middle = np.arange(sheet.n_vertices, closed.n_vertices)
    assert len(middle) >= 2 * 3 and np.allclose(closed.vertices[middle, 1], 1.5)
    # Each middle vertex twice (once per lip), moving exactly like the slit vertex of its own lip.
    for lip in (1, -1):
        own = middle[labels[middle] == lip]
        assert len(own) == len(middle) // 2
        source = rows[own].toarray().argmax(axis=1)
        assert np.allclose(rows[own].toarray().max(axis=1), 1.0) and (labels[source] == lip).all()
        assert np.allclose(np.abs(closed.vertices[source, 1] - 1.5), 0.5)
    # Every closing triangle on the middle line is on one lip: its other corners are that lip's or one
    # of the slit's two ends (which the lip cut then copies).
    strangers = set()
    for triangle in fill[(fill >= sheet.n_vertices).any(axis=1)]:
        lip = labels[triangle[triangle >= sheet.n_vertices][0]]
        strangers |= {int(v) for v in triangle if labels[v] != lip}
    assert len(strangers) <= 2


def test_a_slit_inside_one_lip_is_closed_as_that_lips_skin():
    """Both sides of the slit on the upper lip (one lower-lip vertex at its end): closed by the
    strip between its own vertices, with no middle line."""
    from core.registration.scan_mouth import _with_lip_slits_closed

    sheet, side, matrix = _slit_sheet(upper_row=1)
    side[20 + 1] = -1                                      # the slit's lower left corner
    closed, labels, rows = _with_lip_slits_closed(sheet, side, matrix)
    assert closed.n_vertices == sheet.n_vertices and np.array_equal(labels, side)
    assert _area(closed.vertices, closed.triangles[len(sheet.triangles):]) == pytest.approx(4.0)
    assert (rows != matrix).nnz == 0


def test_pressed_lips_of_a_scan_with_slits_do_not_pass_through_each_other(animated):
    """The synthetic scan's two slits: zipped greedily from an end that lay in one lip's scanner row,
    they fanned 1-3 % high slivers along that row, which lower_t_lip_lm crossed from 2 MNS on (5 pairs
    at 60, a viseme's value). Closed by the best-shaped strip, none."""
    from core.layers.fap.fat import FapDeformer
    from core.layers.fap.limits import new_crossings
    from core.mesh_quality import FaceQualityProbe

    face = animated.face
    deformer = FapDeformer(face, dense=animated.dense, binding=animated.binding())
    probe = FaceQualityProbe(face)
    crosses = new_crossings(face.vertices, probe.lip_tris, probe.welded, 0.0)
    values = np.zeros(68)
    for number in (8, 9, 4):
        values[:] = 0.0
        values[number - 1] = 60.0
        assert not crosses(deformer.deform(values)), f"FAP {number} at 60 crosses the lips"


def test_a_slit_vertex_labelled_with_the_other_lip_takes_its_sides_lip_and_moves_with_it():
    """One vertex of the slit's upper side bound to the lower lip (most of its side on the upper): it
    takes the upper lip, and is bound as its upper-lip neighbours, so it no longer moves with the jaw."""
    from core.registration.scan_mouth import _with_lip_slits_closed

    sheet, side, matrix = _slit_sheet(upper_row=2)
    stray = 2 * 20 + 3                                     # row 2 (the slit's upper side), x = 3
    side[stray] = -1
    closed, labels, rows = _with_lip_slits_closed(sheet, side, matrix)
    assert labels[stray] == 1
    neighbours = np.unique(sheet.triangles[(sheet.triangles == stray).any(axis=1)])
    upper = neighbours[(neighbours != stray) & (side[neighbours] == 1)]
    expected = np.zeros(sheet.n_vertices)
    expected[upper] = 1.0 / len(upper)
    np.testing.assert_allclose(rows[stray].toarray().ravel(), expected)
    others = np.setdiff1d(np.arange(sheet.n_vertices), stray)
    assert (rows[others] != matrix[others]).nnz == 0                 # every other vertex as it was
