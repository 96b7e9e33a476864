"""MPEG-4 FAP engine: tables, FAPU, template counts (thesis A Table 5.1), the FAT and the rig."""

import numpy as np
import pytest
import scipy.sparse

import resources
from core.layers.fap import tables
from core.layers.fap.fat import lid_contact
from core.layers.fap.template import TemplateError, densify, load_template
from core.rig import FaceRig
from core.subdivision import boundary_edges, subdivide
from tests.core.conftest import without_surface_guard


# ------------------------------------------------------------------ tables (no face needed)
def test_fap_table_has_68_faps_and_the_46_of_the_thesis():
    specs = tables.fap_specs()
    assert len(specs) == 68
    assert tables.thesis_faps() == tuple(range(3, 23)) + tuple(range(31, 43)) + tuple(range(51, 65))
    assert len(tables.thesis_faps()) == 46
    jaw = tables.fap_spec("open_jaw")
    assert (jaw.number, jaw.fp, jaw.unit, jaw.axis, jaw.bidirectional) == (3, "2.1", "MNS", (0.0, -1.0, 0.0), False)
    # Left is the face's own left (+x), right is -x; pairs point at each other.
    assert tables.fap_spec(6).axis == (1.0, 0.0, 0.0) and tables.fap_spec(7).axis == (-1.0, 0.0, 0.0)
    for s in specs:
        if s.pair:
            assert tables.fap_spec(s.pair).pair == s.number
        if s.animated:
            assert s.minimum < s.maximum and s.dock
            assert s.minimum == 0 or s.bidirectional  # unidirectional FAPs start at 0


def test_feature_point_table_counts():
    groups = [r["group"] for r in resources.get_table("mpeg4/feature_points.csv")]
    assert len(groups) == 84
    assert [groups.count(str(g)) for g in range(2, 12)] == [14, 14, 6, 4, 4, 1, 10, 15, 10, 6]


def test_expression_presets_reproduce_table_b1():
    t = tables.thesis_expression_table()
    joy, surprise, anger = (tables.expression_id(n) for n in ("joy", "surprise", "anger"))
    assert t[joy, 2] == 430 and t[joy, 4] == -500 and t[joy, 58] == 230 and t[joy, 59] == 230
    assert t[surprise, 5] == -280 and t[surprise, 6] == -280
    assert t[anger, 17] == 250 and t[anger, 15] == 200
    assert not t[0].any()


def test_expression_presets_follow_the_facs_action_units_of_thesis_b():
    """Thesis B Table 3.3's units on top of Table B.1: joy = AU 1, 6, 12, 14 (cheeks up, lower lids up
    narrowing the eyes, corners up and back) with the lips parted (25: MPEG-4's "mouth open", without
    B.1's jaw drop); surprise = 1, 2, 5, 15, 16, 20, 26."""
    t, b1 = tables.expression_table(), tables.thesis_expression_table()
    fap = {s.name: s.number - 1 for s in tables.fap_specs()}
    joy, surprise, disgust = (tables.expression_id(n) for n in ("joy", "surprise", "disgust"))
    assert tables.expression_action_units()["joy"].keys() == {1, 6, 12, 14, 25}
    assert tables.expression_action_units()["surprise"].keys() == {1, 2, 5, 15, 16, 20, 26}
    assert t[joy, fap["lift_l_cheek"]] > 0 and t[joy, fap["lift_r_cheek"]] > 0
    assert t[joy, fap["close_b_l_eyelid"]] > 0 > b1[joy, fap["close_b_l_eyelid"]], "Duchenne: lower lids rise"
    assert t[joy, fap["raise_l_cornerlip"]] > 0 and t[joy, fap["stretch_l_cornerlip"]] > 0
    assert t[joy, fap["open_jaw"]] == 0 < b1[joy, fap["open_jaw"]]
    assert t[joy, fap["lower_t_midlip"]] < 0 and t[joy, fap["raise_b_midlip"]] < 0, "lips part: upper up, lower down"
    # Joy's corner raise is AU 12 in full plus AU 14 at its intensity.
    units, mix = tables.action_unit_table(), tables.expression_action_units()["joy"]
    assert t[joy, fap["raise_l_cornerlip"]] == pytest.approx(
        units[12][fap["raise_l_cornerlip"]] + mix[14] * units[14][fap["raise_l_cornerlip"]])
    assert t[surprise, fap["open_jaw"]] > 0 and t[surprise, fap["close_t_l_eyelid"]] < 0
    assert t[surprise, fap["raise_l_o_eyebrow"]] > 0 and t[surprise, fap["raise_l_i_eyebrow"]] > 0
    np.testing.assert_array_equal(t[disgust], b1[disgust])   # not in Table 3.3
    # Left and right move alike in every preset.
    for left, right in (("raise_l_cornerlip", "raise_r_cornerlip"), ("close_b_l_eyelid", "close_b_r_eyelid")):
        np.testing.assert_array_equal(t[:, fap[left]], t[:, fap[right]])
    assert tables.expression_names()[1:] == ("joy", "sadness", "anger", "fear", "disgust", "surprise")
    # Every preset value lies inside the slider range of its FAP.
    for table in (t, tables.viseme_table()):
        rows, cols = np.nonzero(table)
        for r, c in zip(rows, cols):
            s = tables.fap_specs()[c]
            assert s.animated and s.minimum <= table[r, c] <= s.maximum, (r, s.name)


def test_visemes_use_only_mouth_faps_and_are_distinct():
    v = tables.viseme_table()
    assert v.shape == (15, 68) and not v[0].any()
    mouth = {s.number - 1 for s in tables.fap_specs() if s.dock in ("jaw & chin", "inner lips", "lip corners", "outer lips")}
    assert set(np.nonzero(v)[1]) <= mouth
    assert len({tuple(row) for row in v}) == 15
    assert v[tables.viseme_id("aa"), 2] > v[tables.viseme_id("PP"), 2]  # 'a' opens the jaw more than p/b/m


def test_fapu_from_known_points():
    pts = {"3.1": [30, 40, 0], "3.3": [30, 29, 0], "3.2": [-30, 40, 0], "3.4": [-30, 29, 0],
           "3.5": [31, 33, 0], "3.6": [-31, 33, 0], "9.15": [0, -15, 0], "2.2": [0, -35, 0],
           "8.3": [24, -34, 0], "8.4": [-24, -34, 0]}
    u = tables.measure_fapu({k: np.array(v, float) for k, v in pts.items()})
    assert u["IRISD"] * 1024 == pytest.approx(11)
    assert u["ES"] * 1024 == pytest.approx(62)
    assert u["ENS"] * 1024 == pytest.approx(48)
    assert u["MNS"] * 1024 == pytest.approx(20)
    assert u["MW"] * 1024 == pytest.approx(48)
    assert u["AU"] == 1e-5
    swapped = dict(pts, **{"8.3": [-24, -34, 0], "8.4": [24, -34, 0]})
    with pytest.raises(ValueError, match="MW0"):
        tables.measure_fapu({k: np.array(v, float) for k, v in swapped.items()})


# ------------------------------------------------------------------ template and subdivision
def test_template_has_80_points_140_triangles_and_a_mouth_opening():
    t = load_template()
    assert len(t.points) == 80 and len(t.triangles) == 140
    assert len(t.feature_points) == 64 and len(t.extras) == 16
    assert "3.5" not in t.points and "3.6" not in t.points  # pupils dropped, as in thesis A
    b = {tuple(e) for e in boundary_edges(t.triangles)}
    mouth = [t.index(p) for p in t.mouth]
    for a, c in zip(mouth, mouth[1:] + mouth[:1]):
        assert tuple(sorted((a, c))) in b  # the inner lip contour is open
    assert len(b) == len(t.outline) + len(t.mouth)
    assert len(t.eye_opening_triangles) == 12
    # Every FAP region refers to existing triangles, none of which covers an eye opening.
    # One region entry per thesis FAP; the jaw FAPs (3, 14, 15) add an entry for the upper-lip corners.
    assert sorted({r["fap"] for r in t.regions}) == sorted(tables.thesis_faps())
    assert len(t.regions) == 46 + 3
    for r in t.regions:
        assert set(r["triangles"]) <= set(range(140)) and not set(r["triangles"]) & t.eye_opening_triangles


def test_subdivision_counts_match_thesis_table_5_1():
    t = load_template()
    v, tri = np.random.default_rng(0).normal(size=(80, 3)), t.triangles
    counts = []
    for scheme in t.steps:
        s = subdivide(v, tri, scheme=scheme, creases=t.crease_edges())
        v, tri = s.vertices, s.triangles
        counts.append((len(v), len(tri)))
    assert t.steps == ("linear", "linear", "loop")
    assert counts == [(300, 560), (1160, 2240), (4560, 8960)]


def test_loop_subdivision_keeps_a_plane_flat_and_linear_is_exact_midpoints():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    tri = np.array([[0, 1, 2], [1, 3, 2]])
    lin = subdivide(v, tri, scheme="linear")
    assert np.allclose(lin.vertices[4:], (v[lin.edges[:, 0]] + v[lin.edges[:, 1]]) / 2)
    loop = subdivide(v, tri, scheme="loop")
    assert np.allclose(loop.vertices[:, 2], 0)


# ------------------------------------------------------------------ on the default face
@pytest.fixture(scope="module")
def rig():
    from core.default_face import load_default_face

    return FaceRig(load_default_face())


def test_dense_template_counts_on_the_default_face(rig):
    d = rig.deformer.dense
    assert d.counts == [(80, 140), (300, 560), (1160, 2240), (4560, 8960)]
    # Every dense vertex lies on the face surface (measured to the surface: on the full head's
    # nostril pockets a point of a tall wall triangle can lie over 1 mm from its corners).
    from core.surface_query import TriangleSet

    assert (d.face_triangle >= 0).all()
    _pos, _tri, _bary = TriangleSet(rig.face.vertices, rig.face.triangles).closest(d.vertices)
    dist = np.linalg.norm(_pos - d.vertices, axis=1)
    assert np.percentile(dist, 99) < 0.1
    assert np.percentile(rig.face.kdtree.query(d.vertices)[0], 95) < 1.0      # and near the mesh's vertices


def test_fapu_of_the_default_face(rig):
    assert rig.fapu["IRISD"] * 1024 == pytest.approx(11.2, abs=0.05)
    assert rig.fapu["ES"] * 1024 == pytest.approx(63.0, abs=0.05)


def test_zero_faps_leave_the_face_at_rest(rig):
    rig.reset_faps(); rig.set_expression(None); rig.set_viseme(None)
    assert np.array_equal(rig.vertices(), rig.face.vertices)


@pytest.mark.parametrize("inner, outer, unit", [(12, 59, "MNS"), (6, 53, "MW"), (4, 51, "MNS")])
def test_an_inner_and_outer_lip_fap_pair_moves_its_feature_points_once(rig, inner, outer, unit):
    """MPEG-4 moves each FAP's feature point by its value: the inner and outer lip FAPs of one motion
    given the same value (as Table B.1's presets do) move the lip by that much, not twice; each alone
    moves its own point by its value, as before; opposite signs still add."""
    d = rig.deformer
    values = lambda **v: np.array([v.get(f"f{n}", 0.0) for n in range(1, 69)])  # noqa: E731
    alone_inner = np.linalg.norm(d.displacement(values(**{f"f{inner}": 200})), axis=1)
    alone_outer = np.linalg.norm(d.displacement(values(**{f"f{outer}": 200})), axis=1)
    both = np.linalg.norm(d.displacement(values(**{f"f{inner}": 200, f"f{outer}": 200})), axis=1)
    step = 200 * rig.fapu[unit]
    assert alone_inner.max() == pytest.approx(step, rel=0.05)
    assert both.max() == pytest.approx(max(alone_inner.max(), alone_outer.max()), rel=1e-9)
    assert np.all(both <= np.maximum(alone_inner, alone_outer) + 1e-9)
    assert np.all(both >= np.maximum(alone_inner, alone_outer) - 1e-9)       # the larger of the two
    apart = d.displacement(values(**{f"f{inner}": 200, f"f{outer}": -100}))
    linear = d.displacement(values(**{f"f{inner}": 200})) + d.displacement(values(**{f"f{outer}": -100}))
    assert np.allclose(apart, linear)


def test_open_jaw_moves_chin_and_lower_lip_by_the_fapu_not_the_upper_lip(rig):
    rig.reset_faps()
    rig.set_fap(3, 512)
    f, v = rig.face, rig.vertices()
    expected = 512 * rig.fapu["MNS"]
    move = lambda p: f.landmark_position(p, v) - f.landmark_position(p)  # noqa: E731
    assert move("2.1") == pytest.approx([0, -expected, 0], abs=0.01 * expected)
    assert move("2.3")[1] == pytest.approx(-expected, rel=0.02)      # lower lip follows the jaw
    assert np.abs(move("2.2")).max() < 1e-6                          # upper lip stays
    assert np.abs(move("11.1")).max() < 1e-6 and np.abs(move("9.3")).max() < 1e-6
    # The mouth opens: the inner lips part by the jaw's travel.
    gap = f.landmark_position("2.2", v)[1] - f.landmark_position("2.3", v)[1]
    assert gap == pytest.approx(expected, rel=0.02)
    if "teeth_lower" in f.parts:
        assert np.allclose(v[f.parts["teeth_lower"]] - f.vertices[f.parts["teeth_lower"]], [0, -expected, 0])
    rig.reset_faps()


def test_a_fap_moves_only_its_region(rig):
    rig.reset_faps()
    rig.set_fap(33, 300)  # raise_l_m_eyebrow
    moved = rig.displacement_magnitude() > 1e-9
    x = rig.face.vertices[moved]
    assert moved.any() and (x[:, 0] > 0).all() and (x[:, 1] > 20).all()  # left brow area only
    assert np.allclose(rig.fap_influence(33)[moved] > 0, True)
    rig.reset_faps()


def test_lids_close_without_crossing(rig):
    f = rig.face
    rig.reset_faps()
    rig.set_faps({19: 1024, 21: 1024})  # both left lids fully closed: they must meet, not cross
    v = rig.vertices()
    top, bottom = f.landmark_position("3.1", v), f.landmark_position("3.3", v)
    assert top[1] == pytest.approx(bottom[1], abs=0.3)
    # Across the whole eye, the upper lid ends at (not below) the lower lid: the face's rim vertices
    # of the left eye opening close to a line.
    rim = _eye_rim(f, "l")
    upper, lower = rim[f.vertices[rim, 1] > f.landmark_position("3.5")[1]], rim[f.vertices[rim, 1] < f.landmark_position("3.5")[1]]
    gap = np.interp(v[upper, 0], *_sorted_xy(v[lower])) - v[upper, 1]
    assert gap.max() < 0.6  # no upper-rim point more than 0.6 mm below the lower rim
    rig.set_faps({19: 1024, 21: 0})
    v = rig.vertices()
    assert f.landmark_position("3.1", v)[1] == pytest.approx(f.landmark_position("3.3")[1], abs=0.3)
    rig.reset_faps()

def test_a_blink_hides_the_whole_eyeball_and_never_cuts_it(rig):
    """Upper lids at their maximum (1024 IRISD) close the eyes completely: no part of the eyeball is
    seen from the front, and no lid triangle passes through the eyeball or its cornea."""
    from core.mesh_quality import FaceQualityProbe, count_intersections

    probe = FaceQualityProbe(rig.face)
    rig.reset_faps()
    rig.set_faps({19: 1024, 20: 1024})
    v = rig.vertices()
    assert probe.eye_openness(v) == {"left": 0.0, "right": 0.0}
    for side in ("left", "right"):
        assert count_intersections(v, probe.lid_tris[side], probe.eyeball_tris[side]) == 0
    rig.reset_faps()
    assert min(probe.eye_openness(rig.vertices()).values()) > 0.5   # open at rest: the check can fail



@pytest.mark.parametrize("values", [{15: 400}, {15: -400}, {6: -400}, {7: -400}, {53: -400}, {54: -400},
                                    {17: -600}])
def test_the_teeth_never_pass_through_the_mouth_skin(rig, values):
    """The teeth follow the jaw rigidly, the skin around the mouth only part way (and stretch_cornerlip
    at -400 or push_t_lip at -600 drive it straight at the arch): at these extremes the teeth used to
    cut 257-489 lip triangles; the teeth guard keeps the skin outside them."""
    from core.mesh_quality import FaceQualityProbe, count_intersections

    probe = FaceQualityProbe(rig.face)
    rig.reset_faps()
    rig.set_faps(values)
    assert count_intersections(rig.vertices(), probe.lip_tris, probe.teeth_tris) == 0
    # Without the guard the same pose does cut the teeth: the check can fail.
    unguarded = rig.face.vertices + rig.deformer.displacement(rig.effective_fap_values())
    assert count_intersections(unguarded, probe.lip_tris, probe.teeth_tris) > 50
    rig.reset_faps()


def test_the_teeth_guard_leaves_the_neutral_face_and_small_motions_alone(rig, monkeypatch):
    """Skin keeps at most its own rest gap to the teeth as clearance, so nothing moves at rest, and a
    pose that stays clear of the teeth is exactly the FAT's (the surface guard, which smooths this
    pose's mouth corner a little, left out: test_surface_guard)."""
    rig.reset_faps()
    assert np.array_equal(rig.vertices(), rig.face.vertices)
    without_surface_guard(monkeypatch, rig)
    rig.set_faps({3: 300, 6: 100})
    plain = rig.face.vertices + rig.deformer.displacement(rig.effective_fap_values())
    # Equal up to the rounding of the in-place FAT product (each term added to the vertex in turn).
    np.testing.assert_allclose(rig.vertices(), plain, rtol=0, atol=1e-12)
    rig.reset_faps()


def test_the_teeth_guard_follows_the_lower_teeth_wherever_a_layer_moved_them():
    """The guard reads where the lower row is (a rigid fit of its vertices), not the jaw FAPs: a
    skin point put inside the shifted and turned row comes out on its hull plus the clearance."""
    from core.layers.fap.teeth_guard import TEETH_CLEARANCE_MM, TeethGuard, _rigid_fit
    from tests.core.conftest import make_grid_face
    from core.face import Face

    # A row of "teeth": a box 40 mm wide, 10 mm high, 6 mm deep; one skin vertex 3 mm in front of it.
    grid = make_grid_face(nx=11, ny=3, size_mm=40.0)
    box = grid.vertices * [1.0, 0.25, 0.0] + [0.0, 0.0, -6.0]
    front = grid.vertices * [1.0, 0.25, 0.0]
    teeth = np.concatenate([box, front])
    n_row = len(box)
    tris = np.concatenate([grid.triangles, grid.triangles + n_row])
    skin = np.array([[0.0, 0.0, 3.0], [1.0, 0.0, 3.0], [0.0, 1.0, 3.0]])
    vertices = np.concatenate([teeth, skin])
    face = Face(vertices, np.concatenate([tris, [[2 * n_row, 2 * n_row + 1, 2 * n_row + 2]]]),
                parts={"teeth_lower": np.arange(2 * n_row)})
    guard = TeethGuard(face, np.arange(2 * n_row, 2 * n_row + 3))
    x = face.vertices.copy()
    assert np.array_equal(guard.apply(x.copy()), x)            # 3 mm in front: left alone
    turn = np.array([[np.cos(0.1), 0, np.sin(0.1)], [0, 1, 0], [-np.sin(0.1), 0, np.cos(0.1)]])
    x[: 2 * n_row] = teeth @ turn.T + [2.0, -1.0, 1.0]        # the row moved and turned
    x[2 * n_row] = np.array([0.0, 0.0, -3.0]) @ turn.T + [2.0, -1.0, 1.0]   # a skin point inside it
    out = guard.apply(x.copy())
    rotation, shift = _rigid_fit(teeth, x[: 2 * n_row])
    assert np.allclose(rotation, turn) and np.allclose(shift, [2.0, -1.0, 1.0])
    assert _rigid_fit(teeth, teeth + [1.0, 2.0, 3.0])[0] is None   # a plain shift needs no rotation
    local = (out[2 * n_row] - shift) @ rotation
    hull = guard.rows[0][1]
    radius, outer, _dx, _dz = hull.outer_radius(local[None])
    assert radius[0] >= outer[0] + TEETH_CLEARANCE_MM - 1e-9
    assert local[2] > 0.0                                      # in front of the row's front face again


def test_the_teeth_guard_slack_filter_changes_nothing_at_extremes(rig):
    """A tick tests only skin that moved past its rest slack: on random FAP vectors at their slider
    ends (the teeth pushed into the skin in most of them) the filtered guard gives exactly the
    unfiltered one's vertices, and it does filter (each row's slack is millimetres, not 0)."""
    from core.layers.fap import tables

    deformer, guard = rig.deformer, rig.deformer._teeth_guard
    assert all(np.sqrt(row.slack_squared).min() > 1.0 for row in guard.rows)
    rng = np.random.default_rng(7)
    faps = [n for n in rig.animated_faps if n not in (48, 49, 50)]
    pushed = 0
    for _ in range(60):
        values = np.zeros(tables.N_FAPS)
        for number in rng.choice(faps, int(rng.integers(1, 8)), replace=False):
            p = rig.describe(f"fap:{number}")
            values[number - 1] = rng.choice([p.minimum, p.maximum]) * rng.uniform(0.6, 1.0)
        x = rig.face.vertices + deformer.displacement(values)
        filtered, unfiltered = guard.apply(x.copy()), guard.apply(x.copy(), slack_filter=False)
        assert np.abs(filtered - unfiltered).max() <= 1e-9
        pushed += not np.array_equal(unfiltered, x)
    assert pushed >= 10       # the comparison covers real pushes, not only untouched skin


def test_the_teeth_guard_slack_is_a_lower_bound_of_the_distance_to_the_teeth():
    """A point's rest slack is never more than its distance to any point the guard would push (inside
    a cell's radius + the clearance), and close to the nearest such point of a dense sample."""
    from scipy.spatial import cKDTree

    from core.layers.fap.teeth_guard import TeethRowHull

    rng = np.random.default_rng(3)
    # A "row": points on a half-cylinder of radius 20 mm, 8 mm high, its axis 20 mm behind z = 0.
    angle = rng.uniform(-np.pi / 2, np.pi / 2, 4000)
    row = np.stack([20 * np.sin(angle), rng.uniform(0, 8, 4000), 20 * np.cos(angle) - 20], axis=1)
    hull = TeethRowHull(row)
    points = np.stack([rng.uniform(-30, 30, 300), rng.uniform(-6, 14, 300), rng.uniform(-30, 20, 300)], axis=1)
    # A dense sample of the box around the row, and the guard's own inside test on it.
    probe = np.stack([rng.uniform(-25, 25, 400_000), rng.uniform(-3, 11, 400_000),
                      rng.uniform(-45, 5, 400_000)], axis=1)
    radius, outer, _dx, _dz = hull.outer_radius(probe)
    point_radius, point_outer, _dx, _dz = hull.outer_radius(points)
    for clearance in (0.0, 0.5):
        nearest = cKDTree(probe[radius < outer + clearance]).query(points)[0]
        slack = hull.distance_to_pushed_region(points, np.full(len(points), clearance))
        assert (slack <= nearest + 1e-9).all()
        inside = point_radius < point_outer + clearance
        assert 10 < inside.sum() < 100 and (slack[inside] == 0).all() and (slack[~inside] > 0).all()
        assert np.median(nearest - slack) < 0.3      # tight: about the sample's spacing


def test_jaw_moves_the_mouth_corners_part_way_and_the_upper_lip_stays(rig):
    f = rig.face
    rig.reset_faps()
    rig.set_fap(3, 512)
    v = rig.vertices()
    drop = 512 * rig.fapu["MNS"]
    corner = f.landmark_position("2.4", v) - f.landmark_position("2.4")
    assert -corner[1] == pytest.approx(0.4 * drop, rel=0.1)   # JAW_CORNER_WEIGHT in the template tool
    assert np.linalg.norm(f.landmark_position("2.2", v) - f.landmark_position("2.2")) < 0.01 * drop
    rig.reset_faps()


def test_region_weights_have_no_jumps(rig):
    """Neighbouring regions must not meet in a crease: along every dense edge a FAP's weight changes
    by much less than its full value (the thesis's Gaussian alone jumps from ~0.3-1 to 0 at region
    borders). The lids are the exception: their margins border the eye openings, where no skin is.
    """
    d = rig.deformer
    t = d.dense.triangles
    edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    for fap, w in d.template_weights.items():
        if fap in (19, 20, 21, 22):
            continue
        assert np.abs(w[edges[:, 0]] - w[edges[:, 1]]).max() < 0.7, fap
        assert w.max() == pytest.approx(1.0, abs=1e-9) or fap in (3, 14, 15)


def test_closed_lids_stay_in_front_of_the_eyeball(rig):
    f = rig.face
    rig.reset_faps()
    rig.set_faps({19: 1024, 21: 1024})
    v = rig.vertices()
    eye = f.parts["eyeball_l"]
    centre, radius_guard = rig.deformer._lid_guards[0][1], rig.deformer._lid_guards[0][2]
    lid = rig.deformer._lid_guards[0][0]
    dist = np.linalg.norm(v[lid] - centre, axis=1)
    assert (dist >= radius_guard - 1e-6).all()
    # The pupil is covered: a ray from the front through the pupil pole hits skin before the eyeball.
    pole = f.vertices[eye][np.argmax(f.vertices[eye, 2])]
    closed = f.with_vertices(v)
    hit, _tri, _ = closed.ray_hits(pole[None] + [0, 0, 50.0], np.array([[0, 0, -1.0]]))
    assert hit[0][2] > pole[2] + 0.2
    rig.reset_faps()


def test_the_lid_guard_reads_the_eyeballs_real_surface(rig):
    """Rest gaps are measured to the ball's own mesh along each vertex's direction from the centre
    (a ray cast, known answer): a profile by the angle from the gaze axis alone put 352 vertices per
    eye of the default face up to 1.65 mm inside a ball they lie outside of, and pushed them out."""
    import trimesh

    from core.layers.fap.eyeball_surface import map_radius

    f = rig.face
    for guard, name in zip(rig.deformer._lid_guards, ("eyeball_l", "eyeball_r")):
        in_ball = np.zeros(f.n_vertices, bool)
        in_ball[f.parts[name]] = True
        ball = trimesh.Trimesh(f.vertices, f.triangles[in_ball[f.triangles].all(axis=1)], process=False)
        offsets = guard.rest - guard.centre
        length = np.linalg.norm(offsets, axis=1)
        where, ray, _tri = ball.ray.intersects_location(np.broadcast_to(guard.centre, offsets.shape),
                                                        offsets / length[:, None], multiple_hits=False)
        true_gap = length[ray] - np.linalg.norm(where - guard.centre, axis=1)
        gap = length[ray] - map_radius(offsets[ray], guard.radii)
        assert len(ray) > 500                                   # most of the guarded skin lies over the ball
        assert (true_gap > 0).all() and (gap > 0).all()         # outside it, and read so
        assert (gap <= true_gap + 0.002).all() and (gap >= true_gap - 0.2).all()   # the 1-degree filter
    rig.reset()
    assert np.array_equal(rig.vertices(), f.vertices)           # the neutral face is untouched


def _eye_rim(face, side):
    """Boundary vertices of the skin around the eye opening of one side."""
    b = np.unique(boundary_edges(face.triangles).ravel())
    c = face.landmark_position("3.5" if side == "l" else "3.6")
    p = face.vertices[b]
    near = (np.abs(p[:, 0] - c[0]) < 16) & (np.abs(p[:, 1] - c[1]) < 9) & (p[:, 2] > c[2] - 10)
    in_part = np.zeros(face.n_vertices, bool)
    for idx in face.parts.values():
        in_part[idx] = True
    return b[near & ~in_part[b]]


def _sorted_xy(points):
    order = np.argsort(points[:, 0])
    return points[order, 0], points[order, 1]


def test_lid_contact_scales_only_when_lids_overlap():
    v = np.zeros(68)
    v[18], v[20] = 600, 300
    assert np.array_equal(lid_contact(v), v)
    v[18], v[20] = 1024, 1024
    out = lid_contact(v)
    assert out[18] + out[20] == pytest.approx(1024) and out[18] == out[20]


def test_expression_intensity_scales_the_displacement(rig, monkeypatch):
    # The surface guard smooths joy's strained mouth corners (not linear): left out (test_surface_guard).
    without_surface_guard(monkeypatch, rig)
    rig.reset_faps()
    rig.set_expression("joy", 1.0)
    full = rig.vertices() - rig.face.vertices
    rig.set_expression("joy", 0.5)
    half = rig.vertices() - rig.face.vertices
    # Closing lids slide over the eyeballs and lips pressed together give way (contacts, not
    # linear): compare everything else.
    lids = np.any([rig.fap_influence(n) > 0 for n in (19, 20, 21, 22)], axis=0)
    for guard in rig.deformer._lid_guards:     # the lids' guard over the eyeballs covers the cheek lift too
        lids[guard[0]] = True
    contact = rig.deformer._lip_contact
    lips = np.zeros(rig.face.n_vertices, bool)
    lips[contact.upper], lips[contact.lower] = True, True
    skin = ~lids & ~lips
    assert skin.sum() > 0.7 * rig.face.n_vertices   # the guard's set includes the cheek-lift region
    assert np.abs(full).max() > 5
    assert np.allclose(half[skin], full[skin] / 2, atol=1e-9)
    rig.set_fap2(1, 63, 6, 0)
    assert rig.expression == (1, 1.0)
    assert np.allclose(rig.vertices() - rig.face.vertices, full)
    rig.set_expression(None)


def test_lips_pressed_into_each_other_meet_instead_of_crossing(rig):
    """Raising the lower lip of a closed mouth (FAP 5 raise_b_midlip) would lift its rim ~6 mm
    through the upper lip: both give way by half, the rims end touching, the lips' sheets beside
    them do not cross either (224 crossing lip triangles -> 0), the upper lip is pushed up; at rest
    nothing moves."""
    from core.mesh_quality import FaceQualityProbe

    contact = rig.deformer._lip_contact
    assert contact.active
    rig.reset()
    assert np.array_equal(rig.vertices(), rig.face.vertices)
    rig.set_fap(5, 800)
    values = rig.deformer.limited(rig.effective_fap_values())
    linear = rig.face.vertices + rig.deformer.displacement(values)
    assert contact._overlap(linear).max() > 3.0                      # the FAT alone crosses the lips
    posed = rig.vertices()
    assert contact._overlap(posed).max() < 0.1                         # the rims meet (corners taper)
    probe = FaceQualityProbe(rig.face)
    crossed, left = probe.measure(linear).lip_intersections, probe.measure(posed).lip_intersections
    assert crossed > 100 and left == 0
    up = posed[contact.upper_rim, 1] - rig.face.vertices[contact.upper_rim, 1]
    assert up.max() > 1.0, "the upper lip gives way too"
    rig.reset()


def test_lips_that_cross_at_rest_do_not_jump_apart_when_a_pose_presses_them(rig):
    """A scan's closed lips may cross at rest (the Surrey Face Model scan's rims by ~0.3 mm). A pose
    that presses them a micron further gives way by about that micron and the separation, not the
    rest's whole overlap: they jumped 0.35 mm apart at a slider's first touch. A real press still
    resolves what it added and, pressing a millimetre or more, the rest's overlap too."""
    from core.layers.fap.lip_contact import SEPARATION_MM, LipContact

    face = rig.face
    skin = np.setdiff1d(np.arange(face.n_vertices), np.concatenate(list(face.parts.values())))
    lower_rim = LipContact(face, skin).lower_rim
    crossed = face.vertices.copy()
    crossed[lower_rim, 1] += 0.3                                # the lower rim 0.3 mm into the upper lip
    contact = LipContact(face.with_vertices(crossed), skin)
    rest_excess = np.maximum(contact._overlap(crossed), 0.0).max()
    assert contact.active and rest_excess > 0.25
    for lift, most in ((1e-4, 0.5 * SEPARATION_MM + 1e-3), (2.0, np.inf)):
        x = crossed.copy()
        x[contact.lower, 1] += lift * contact.lower_weight
        before = x.copy()
        contact.apply(x)
        moved = np.linalg.norm(x - before, axis=1).max()
        assert moved <= most, moved                             # the old code: ~0.17 mm each way
        assert contact._overlap(x).max() <= rest_excess + 0.05
    # The 2 mm press resolved, and the rest's overlap with it where the lip rose a millimetre or more.
    assert moved > 0.5 and contact._overlap(x).max() < rest_excess - 0.05


@pytest.mark.parametrize("number", [4, 8, 10, 57])
def test_lips_pressed_at_a_sliders_end_do_not_pass_through_each_other(rig, number, monkeypatch):
    """Every lip FAP at the end that presses a closed mouth's lips together: the rims meet, and the
    lips' surfaces beside the rims do not cross either (FAP 4 at 800 left 176 crossing triangle pairs
    at the lips' front with the rims alone); the sheets give way by fractions of a millimetre (the
    surface guard's smoothing of the strained corners, up to 1.5 mm at FAP 57, is checked apart)."""
    from core.layers.fap import tables
    from core.mesh_quality import FaceQualityProbe

    contact = rig.deformer._lip_contact
    end = tables.fap_spec(number).maximum
    rig.reset()
    rig.set_fap(number, end)
    assert FaceQualityProbe(rig.face).measure(rig.vertices()).lip_intersections == 0    # guarded too
    without_surface_guard(monkeypatch, rig)
    rig.touch()
    posed = rig.vertices()
    values = rig.deformer.limited(rig.effective_fap_values())
    rig.reset()
    rims_only = rig.face.vertices + rig.deformer.displacement(values)
    contact._press_rims(rims_only)
    probe = FaceQualityProbe(rig.face)
    assert probe.measure(posed).lip_intersections == 0
    lips = np.concatenate([contact.upper, contact.lower])
    assert np.abs(posed[lips] - rims_only[lips]).max() < 1.0


def test_a_raised_mouth_corner_leaves_the_closed_lips_touching_not_crossing(rig):
    """The closed mouth is a seam of copied vertices; a corner FAP lifts both lips' corner triangles,
    which stay meeting at those copies. The exact test counted such pairs (they touch at one point or
    along an edge); shrunk 1 % toward their centres they do not meet, and the probe no longer counts them."""
    from core.mesh_quality import FaceQualityProbe, intersecting_pairs, triangles_intersect

    probe = FaceQualityProbe(rig.face)
    rig.reset()
    rig.set_fap(12, 500)
    v = rig.vertices()
    ia, ib = intersecting_pairs(v, probe.lip_tris)                       # seam copies not welded
    assert len(ia) > 0
    a, b = v[probe.lip_tris[ia]], v[probe.lip_tris[ib]]
    shrink = lambda t: t + 0.01 * (t.mean(axis=1, keepdims=True) - t)  # noqa: E731
    assert not triangles_intersect(shrink(a), shrink(b)).any()
    assert probe.measure(v).lip_intersections == 0
    rig.reset()


def test_lip_sheet_overlap_is_the_same_compiled_and_numpy(rig, monkeypatch):
    from core.layers.fap import kernels

    built = kernels.get() or kernels._KERNELS.load()
    if built is None:
        pytest.skip("numba is not installed: only the numpy path exists")
    contact = rig.deformer._lip_contact
    rig.reset()
    rig.set_faps({4: 600.0, 12: 300.0, 3: 150.0})
    x = np.array(rig.vertices())
    rig.reset()
    monkeypatch.setattr(kernels, "get", lambda: built)
    compiled = contact._sheet_overlap(x)
    monkeypatch.setattr(kernels, "get", lambda: None)
    reference = contact._sheet_overlap(x)
    assert np.isfinite(reference[0]).sum() > 100
    for a, b in zip(compiled, reference):
        np.testing.assert_array_equal(a, b)
    # The sheets' give-way spread, both paths, on depths where some vertices crossed.
    from core.layers.fap.lip_contact import _spread

    depth = np.where(np.arange(len(contact.upper)) % 7 == 0, 0.3, -1.0)
    monkeypatch.setattr(kernels, "get", lambda: built)
    fast = _spread(contact.neighbours[0], depth)
    monkeypatch.setattr(kernels, "get", lambda: None)
    slow = _spread(contact.neighbours[0], depth)
    assert (slow > 0.15).sum() >= (depth > 0).sum()
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)


def test_fap1_blends_two_visemes(rig):
    rig.reset_faps()
    rig.set_fap1(10, 1, 63)
    assert np.allclose(rig.preset_values(), tables.viseme_table()[10])
    rig.set_fap1(10, 14, 0)
    assert np.allclose(rig.preset_values(), tables.viseme_table()[14])
    rig.set_viseme(None)


def test_gaze_rotates_the_eyeball_about_its_centre(rig):
    if 23 not in rig.animated_faps:
        pytest.skip("default face without eyeball parts")
    rig.reset_faps()
    idx = rig.face.parts["eyeball_l"]
    rig.set_fap(23, 20000)  # 0.2 rad to the left
    v = rig.vertices()
    pole = rig.face.landmark_position("3.5", v) - rig.face.landmark_position("3.5")
    assert pole[0] > 1.0  # the pupil moved toward +x, the face's left
    centre = rig.deformer._eyes["eyeball_l"][1]
    r0 = np.linalg.norm(rig.face.vertices[idx] - centre, axis=1)
    assert np.allclose(np.linalg.norm(v[idx] - centre, axis=1), r0)
    rig.reset_faps()


def test_rig_rejects_bad_values_and_keeps_state(rig):
    rig.reset_faps()
    rig.set_fap(3, 100)
    with pytest.raises(ValueError, match="outside its range"):
        rig.set_faps({4: 50, 3: 99999})
    with pytest.raises(ValueError, match="cannot be animated"):
        rig.set_fap(45, 10)
    with pytest.raises(ValueError, match="finite"):
        rig.set_fap(3, float("nan"))
    with pytest.raises(ValueError, match="0 and 1"):
        rig.set_expression("joy", 1.5)
    with pytest.raises(ValueError, match="unknown expression"):
        rig.set_expression("glee")
    assert rig.fap_value(3) == 100 and rig.fap_value(4) == 0
    rig.reset_faps()


def test_rig_signals_once_per_change(rig):
    calls = []
    rig.changed.connect(lambda: calls.append(1))
    rig.reset_faps()
    calls.clear()
    rig.set_faps({3: 100, 4: 50})
    rig.set_faps({3: 100})  # unchanged: no signal
    assert len(calls) == 1
    rig.changed.disconnect()
    rig.reset_faps()


def test_face_without_feature_points_gets_a_clear_error(grid_face):
    with pytest.raises(TemplateError, match="feature points"):
        densify(grid_face)


def test_preset_mix_adds_several_visemes_and_keeps_the_strongest_first(rig):
    rig.set_viseme_mix({1: 0.3, 10: 0.7})
    assert rig.viseme == (10, 0.7)
    expected = 0.3 * tables.viseme_table()[1] + 0.7 * tables.viseme_table()[10]
    assert np.allclose(rig.preset_values(), expected)
    with pytest.raises(ValueError):
        rig.set_viseme_mix({1: 0.5, 2: 1.5})
    assert rig.viseme == (10, 0.7)   # unchanged after a refused mix
    rig.set_viseme_mix({})
    assert rig.viseme == (0, 0.0) and not rig.preset_values().any()


def test_relaxation_keeps_fixed_weights_and_straightens_a_ramp():
    """On a path graph with both ends fixed (core 1, border 0) relaxation tends to the straight
    ramp, the gentlest one possible; a steep step in between spreads out, the ends do not move."""
    import scipy.sparse

    from core.layers.fap.fat import _relax

    n = 9
    graph = scipy.sparse.diags([np.ones(n - 1), np.ones(n - 1)], [-1, 1], format="csr")
    step = np.array([1.0, 1, 1, 1, 1, 0, 0, 0, 0])
    fixed = np.zeros(n, bool)
    fixed[[0, -1]] = True
    relaxed = _relax(step, graph, fixed, 2000)
    assert relaxed[0] == 1.0 and relaxed[-1] == 0.0
    assert np.allclose(relaxed, np.linspace(1, 0, n), atol=1e-6)
    assert np.abs(np.diff(_relax(step, graph, fixed, 30))).max() < np.abs(np.diff(step)).max()


def _seamed_grid(nx=9, ny=7, seam=4):
    """A flat grid (1 mm spacing) cut along column ``seam``: the cut's vertices are duplicated (an unwelded
    seam, as the default face's face / head-shell seam). Returns (face, left ids, right ids, seam pairs)."""
    from core.face import Face

    def patch(x0, x1, offset):
        x, y = np.meshgrid(np.arange(x0, x1 + 1.0), np.arange(ny, dtype=float))
        v = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
        idx = np.arange(x.size).reshape(ny, -1) + offset
        a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
        return v, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]), idx

    vl, tl, il = patch(0, seam, 0)
    vr, tr, ir = patch(seam, nx - 1, len(vl))
    face = Face(np.concatenate([vl, vr]), np.concatenate([tl, tr]))
    return face, il.ravel(), ir.ravel(), np.column_stack([il[:, -1], ir[:, 0]])


def test_smoothed_binding_shares_rows_across_an_unwelded_seam_and_keeps_the_skins_border():
    """Known answer on a grid bound half to dense vertex 0, half to 1: after smoothing the seam's two
    copies have one row, weight crossed the seam, rows still sum to 1 and the border keeps its rows."""
    from core.layers.fap.fat import smooth_binding

    face, left, right, pairs = _seamed_grid()
    n = face.n_vertices
    cols = np.where(np.isin(np.arange(n), right), 1, 0)
    binding = scipy.sparse.csr_matrix((np.ones(n), (np.arange(n), cols)), shape=(n, 4))
    out = smooth_binding(face, binding, np.arange(n), np.zeros(n, np.int64), 3).toarray()
    assert np.array_equal(out[pairs[:, 0]], out[pairs[:, 1]])
    assert np.allclose(out.sum(axis=1), 1.0)
    x, y = face.vertices[:, 0], face.vertices[:, 1]
    border = (x == 0) | (x == 8) | (y == 0) | (y == 6)
    assert np.array_equal(out[border & ~np.isin(np.arange(n), pairs)], binding.toarray()[border & ~np.isin(np.arange(n), pairs)])
    inner = (~border) & (x == 3)
    assert (out[inner, 1] > 0.05).all() and (out[inner, 1] < 0.5).all()   # the step spread, less than half


def test_a_binding_smoothed_only_at_its_jumps_keeps_every_row_away_from_them():
    """The grid's halves bound to dense points 100 mm apart jump at the seam: with ``jump`` only the seam
    and the rows within ``rings`` of it move (here 1: columns 2-6); columns 0, 1, 7, 8 keep their rows."""
    from core.layers.fap.fat import smooth_binding

    face, left, right, pairs = _seamed_grid()
    n = face.n_vertices
    cols = np.where(np.isin(np.arange(n), right), 1, 0)
    binding = scipy.sparse.csr_matrix((np.ones(n), (np.arange(n), cols)), shape=(n, 4))
    anchors = np.array([[0.0, 0, 0], [100.0, 0, 0], [0, 50, 0], [0, -50, 0]])
    out = smooth_binding(face, binding, np.arange(n), np.zeros(n, np.int64), 5, anchors, 2.0, 1).toarray()
    x, y = face.vertices[:, 0], face.vertices[:, 1]
    far = (x <= 1) | (x >= 7)
    assert np.array_equal(out[far], binding.toarray()[far])
    assert np.array_equal(out[pairs[:, 0]], out[pairs[:, 1]])
    assert ((out[(x == 3) & (y > 0) & (y < 6), 1] > 0.05)).all()


def test_smoothed_binding_never_mixes_the_two_lip_sides():
    """Upper-lip-side rows (+1) never take a column only lower-side rows (-1) had, and the reverse;
    side-0 skin takes both."""
    from core.layers.fap.fat import smooth_binding

    face, left, right, pairs = _seamed_grid()
    n = face.n_vertices
    y = face.vertices[:, 1]
    side = np.where(y >= 4, 1, np.where(y <= 2, -1, 0))
    cols = np.where(side == 1, 2, np.where(side == -1, 3, 0))
    binding = scipy.sparse.csr_matrix((np.ones(n), (np.arange(n), cols)), shape=(n, 4))
    out = smooth_binding(face, binding, np.arange(n), side, 5).toarray()
    assert (out[side == 1, 3] == 0).all() and (out[side == -1, 2] == 0).all()
    assert (out[side == 0][:, [2, 3]] > 0).any(axis=0).all()
    assert np.array_equal(out[pairs[:, 0]], out[pairs[:, 1]])


def test_the_default_faces_binding_is_smoothed_one_row_per_welded_point_and_per_lip(rig):
    """On the default face: skin vertices at one place on one lip side share their binding row; the
    upper lip takes no lower-lip FAP (5 raise_b_midlip) and the lower lip no upper-lip one (4); each FAP
    keeps its weight at its own feature point."""
    from scipy.spatial import cKDTree

    from core.layers.fap.template import mouth_side

    d, f = rig.deformer, rig.face
    skin = np.nonzero(~d._in_any_part())[0]
    side = mouth_side(f, skin)
    pairs = cKDTree(f.vertices[skin]).query_pairs(0.02, output_type="ndarray")
    pairs = pairs[side[pairs[:, 0]] == side[pairs[:, 1]]]
    assert len(pairs) > 500
    a, b = d.binding[skin[pairs[:, 0]]], d.binding[skin[pairs[:, 1]]]
    assert abs(a - b).max() == 0
    assert np.abs(d.influence(5)[skin[side == 1]]).max() == 0
    assert np.abs(d.influence(4)[skin[side == -1]]).max() == 0
    for number, fp in ((3, "2.1"), (4, "2.2"), (5, "2.3"), (12, "2.4"), (31, "4.1"), (51, "8.1"), (39, "5.1")):
        point = f.landmarks[fp]
        weight = np.asarray(point.barycentric) @ d.influence(number)[f.triangles[point.triangle]]
        assert weight > 0.9, (number, weight)


def test_lid_fap_first_tick_moves_the_skin_by_its_own_size_not_a_jump(default_rig):
    """Socket skin inside the eyeball's profile at rest was pushed to the guard's clearance as soon as
    any lid FAP left 0: 422 vertices jumped up to 2.5 mm at 1 IRISD (about 0.01 mm of lid travel).
    Left: the few vertices within MIN_LID_CLEARANCE_MM (0.1 mm) of the ball, held at it and turned
    toward the cornea (about 0.23 mm); the cheek lift now has the guard too."""
    rig = default_rig
    rig.reset()
    rest = rig.vertices().copy()
    for number in (19, 21, 41):
        rig.reset()
        rig.set_fap(number, 1.0)
        assert np.linalg.norm(rig.vertices() - rest, axis=1).max() < 0.3, number
    rig.reset()


def test_finish_steps_replayed_from_their_memo_give_the_same_vertices_bit_for_bit(default_rig):
    """The lid, lip, teeth and mouth-smoothing steps are skipped when their inputs are unchanged (step_memo):
    over slider ticks that move one FAP at a time (brows leave the mouth's steps alone, lips the
    lids'), each pose equals one computed with every step run afresh."""
    import copy

    from core.layers.fap.step_memo import StepMemo

    rig, deformer = default_rig, default_rig.deformer
    rng = np.random.default_rng(5)
    faps = [3, 4, 5, 12, 13, 19, 20, 31, 32, 33, 41, 42, 53, 59, 60]
    replays = 0
    rig.reset()
    for _ in range(40):
        number = int(rng.choice(faps))
        spec = rig.describe(f"fap:{number}")
        rig.set_fap(number, float(rng.uniform(spec.minimum, spec.maximum) * 0.6))
        memo_lasts = {name: memo._last for name, memo in deformer._memos.items()}
        posed = rig.vertices().copy()
        replays += sum(memo._last is memo_lasts[name] for name, memo in deformer._memos.items())
        fresh = copy.copy(deformer)
        fresh._memos = {name: StepMemo(m.reads, m.writes) for name, m in deformer._memos.items()}
        values = rig.faps.limited_values()
        again = np.array(rig.face.vertices)
        fresh.add_displacement(again, values)      # the rig's own sums
        assert np.array_equal(posed, fresh.finish(again, values, in_place=True))
    assert replays > 10, "ticks that leave a step's inputs alone replay it"
    rig.reset()


def test_compiled_finish_steps_give_the_numpy_steps_vertices(rig, monkeypatch):
    """The lid guard, teeth guard and step memos run as numba kernels (core.layers.fap.kernels) where
    numba is installed: on random FAP vectors near their slider ends (lids closing over the eyeballs,
    teeth pushed into the skin, eyes turned) they give the numpy path's vertices (exactly but for the
    gaze rotation's last bit: its sums are not BLAS's)."""
    import copy

    from core.layers.fap import kernels, tables
    from core.layers.fap.step_memo import StepMemo

    built = kernels.get()
    if built is None:
        pytest.skip("numba is not installed: only the numpy path exists")
    deformer = rig.deformer

    def finished(values, compiled: bool) -> np.ndarray:
        monkeypatch.setattr(kernels, "get", lambda: built if compiled else None)
        fresh = copy.copy(deformer)   # empty memos: every step runs
        fresh._memos = {name: StepMemo(m.reads, m.writes) for name, m in deformer._memos.items()}
        return fresh.finish(rig.face.vertices + fresh.displacement(values), values)

    rng = np.random.default_rng(11)
    faps = [n for n in rig.animated_faps if n not in (48, 49, 50)]
    lids_moved = teeth_moved = 0
    lid_vertices = np.concatenate([guard[0] for guard in deformer._lid_guards])
    teeth_vertices = deformer._teeth_guard.watched
    for _ in range(30):
        values = np.zeros(tables.N_FAPS)
        for number in rng.choice(faps, int(rng.integers(2, 10)), replace=False):
            p = rig.describe(f"fap:{number}")
            values[number - 1] = rng.choice([p.minimum, p.maximum]) * rng.uniform(0.5, 1.0)
        values[18:22] = rng.uniform(0, 1024, 4) * (rng.random() < 0.6)   # lids often closing
        compiled, reference = finished(values, True), finished(values, False)
        assert np.abs(compiled - reference).max() <= 1e-12
        plain = rig.face.vertices + deformer.displacement(values)
        lids_moved += not np.array_equal(compiled[lid_vertices], plain[lid_vertices])
        teeth_moved += not np.array_equal(compiled[teeth_vertices], plain[teeth_vertices])
    assert lids_moved >= 5 and teeth_moved >= 5     # the comparison covers real pushes


def test_lip_corner_weights_have_a_round_top_not_a_cone(rig):
    """The lip-corner raise FAPs' weight stays near 1 for the first 2 mm around the corner points: with
    only the two core points held at 1 through the relaxation it fell to 0.72 there (a cone), and a
    smile folded the skin beside the corner."""
    d = rig.deformer
    v = d.dense.vertices
    for fap, (inner, outer) in ((12, ("2.4", "8.3")), (13, ("2.5", "8.4")), (59, ("2.4", "8.3")),
                                (60, ("2.5", "8.4"))):
        w = d.template_weights[fap]
        for fp in (inner, outer):
            near = np.linalg.norm(v - v[d.template.index(fp)], axis=1) < 2.0
            assert w[near].min() > 0.9, (fap, fp, w[near].min())
        assert w.max() == pytest.approx(1.0)


def test_midlip_weights_have_a_round_tip_not_a_cusp(rig):
    """The mid-lip FAPs' weight around their feature point falls no faster than the skin takes: with
    the point held at 1 through the relaxation it fell to 0.68-0.81 within 1.5 mm (a cusp; the upper
    lip's skin stretched 2.1x at push_t_lip 600), now to 0.94 at the least. The point still moves by
    the FAP's full value and nothing around it moves more."""
    d = rig.deformer
    v = d.dense.vertices
    for fap, fp in ((5, "2.3"), (16, "8.2"), (17, "8.1"), (51, "8.1"), (52, "8.2")):
        w = d.template_weights[fap]
        core = d.template.index(fp)
        near = (np.linalg.norm(v - v[core], axis=1) < 1.5) & (w > 0)    # not the other lip's inner rim
        assert near.sum() >= 2
        assert w[core] == pytest.approx(1.0)
        assert w[near].min() > 0.9, (fap, fp, w[near].min())
        assert w.max() <= 1.0 + 1e-12


def _crossings_near(rig, points, radius):
    """Lip triangle pairs of the rig's current pose that cross, with a rest vertex within ``radius``
    mm of one of ``points`` (feature point names)."""
    from core.mesh_quality import FaceQualityProbe, intersecting_pairs

    face = rig.face
    probe = FaceQualityProbe(face)
    ia, ib = intersecting_pairs(rig.vertices(), probe.lip_tris)
    tris = np.concatenate([probe.lip_tris[ia], probe.lip_tris[ib]], axis=1)
    centres = np.array([face.landmark_position(p) for p in points])
    rest = face.vertices[tris]                                   # (k, 6, 3)
    distance = np.linalg.norm(rest[:, :, None] - centres[None, None], axis=3).min(axis=(1, 2))
    return int((distance < radius).sum())


def test_disgust_does_not_cross_the_lips_at_the_corners(rig):
    """Disgust raises the lower lip and lowers the outer corners: the lips crossed right at the
    corners, where lip contact fades out (6 pairs)."""
    rig.reset()
    rig.set_expression("disgust", 1.0)
    try:
        assert _crossings_near(rig, ("2.4", "2.5", "8.3", "8.4"), 1e3) == 0
    finally:
        rig.reset()


@pytest.mark.parametrize("expression", ["joy", "sadness"])
def test_corner_motion_keeps_the_skin_out_of_the_mouth_cavity(rig, expression):
    """Skin moved into the head shows the mouth cavity through the cheek. A
    corner raise region reaching down to the chin with the jaw line not pinned did that in joy (593
    crossing pairs)."""
    from core.mesh_quality import intersecting_pairs

    face = rig.face
    cavity = np.zeros(face.n_vertices, bool)
    cavity[face.parts["mouth_cavity"]] = True
    cavity_tris = face.triangles[cavity[face.triangles].all(axis=1)]
    in_part = np.zeros(face.n_vertices, bool)
    for idx in face.parts.values():
        in_part[idx] = True
    skin = face.triangles[~in_part[face.triangles].any(axis=1)]
    near = skin[np.linalg.norm(face.vertices[skin].mean(axis=1) - face.landmark_position("2.2"), axis=1) < 70]
    rig.reset()
    rig.set_expression(expression, 1.0)
    try:
        assert len(intersecting_pairs(rig.vertices(), near, cavity_tris)[0]) == 0
    finally:
        rig.reset()


@pytest.mark.parametrize("faps", [{15: 400}, {15: -400}, {39: -300, 40: -300}, {18: 400}, {57: 800, 58: 800}])
def test_the_mouth_cavity_lining_follows_the_skin_moved_inward(rig, faps):
    """The lining held still let skin pass through it at these slider ends (default face: shift_jaw
    400 209 crossing pairs, puff_cheek -300 202, depress_chin 400 94, raise_b_lip_lm_o 800 121): it
    now follows the skin it lies behind, and no mouth skin crosses it. The back of the mouth (the
    lining farthest behind the skin) stays where it is."""
    from core.layers.fap.fat import CAVITY_FOLLOW_FAR_MM
    from core.mesh_quality import FaceQualityProbe
    from core.surface_query import TriangleSet

    face = rig.face
    rig.reset()
    for number, value in faps.items():
        rig.set_fap(number, value)
    try:
        x = rig.vertices()
        assert FaceQualityProbe(face).measure(x).cavity_intersections == 0
        cavity = face.parts["mouth_cavity"]
        in_part = np.zeros(face.n_vertices, bool)
        for idx in face.parts.values():
            in_part[idx] = True
        skin = face.triangles[~in_part[face.triangles].any(axis=1)]
        gap = np.linalg.norm(TriangleSet(face.vertices, skin).closest(face.vertices[cavity])[0]
                             - face.vertices[cavity], axis=1)
        far = cavity[gap >= CAVITY_FOLLOW_FAR_MM]
        assert len(far) > 100 and np.abs(x[far] - face.vertices[far]).max() == 0
    finally:
        rig.reset()


def test_a_smile_keeps_the_skin_beside_the_corners_from_folding_into_them(rig):
    """Joy pulls each corner ~14 mm up and back. The corner's cone of weight squeezed the skin beside
    it into the corner: 254 crossing lip triangle pairs. With the round top the corner moves as a
    piece; what still crosses (4 pairs) is the lips' inner surfaces at the seam, beside the inner
    corners, where lip contact fades out. Less than a tenth of before is asserted."""
    rig.reset()
    rig.set_expression("joy", 1.0)
    try:
        assert _crossings_near(rig, ("2.4", "2.5"), 1e3) < 26
    finally:
        rig.reset()


def test_the_cheek_lift_reaches_the_lower_lid_margin_which_stays_pinned(rig):
    """AU 6's cheek lift (lift_l/r_cheek, ~10 mm at joy's value on the default face) spreads up to the
    lower lid's margin, held at 0 there: ending 4 mm below the margin (el.bo-3.9-el.bi) it squeezed
    the skin there into the lid (joy: 104 lid crossings)."""
    d = rig.deformer
    v = d.dense.vertices
    for fap, margin, below in ((41, ("3.7", "el.lo", "3.3", "el.li", "3.11"), "3.3"),
                               (42, ("3.12", "er.lo", "3.4", "er.li", "3.8"), "3.4")):
        w = d.template_weights[fap]
        assert np.abs(w[d.dense.on_chain(margin)]).max() == 0.0
        lid = v[d.template.index(below)]
        under = (np.abs(v[:, 0] - lid[0]) < 2.0) & (lid[1] - v[:, 1] > 1.0) & (lid[1] - v[:, 1] < 3.0)
        assert under.any() and w[under].max() > 0.05, fap


def test_a_raised_cheek_carries_the_lower_lid_up_and_the_presets_keep_their_lids():
    """lid_values' cheek carry (fat.carried_lower_lids): the lower lid rises with its cheek unless it
    closes by itself at least as far (joy's 320 IRISD with its 220 ENS cheek stays as authored),
    continuously in every value (no jump as the cheek leaves 0, whatever the lid's value)."""
    from core.layers.fap.fat import CHEEK_CARRY_BLEND, carried_lower_lids, smooth_ramp

    def lower(cheek, lid):
        v = np.zeros(68)
        v[40], v[20] = cheek, lid
        return carried_lower_lids(v)[20]

    assert lower(0.0, 0.0) == 0.0 and lower(0.0, -300.0) == -300.0
    assert lower(400.0, 0.0) == 400.0 - CHEEK_CARRY_BLEND / 2            # carried (less the blend)
    assert lower(220.0, 320.0) == 320.0                                   # joy: the lid's own value
    assert lower(400.0, -300.0) > -300.0                                  # an opened lid is pushed up too
    for lid in (-300.0, -1.0, 0.0, 5.0, 320.0):                           # continuous as the cheek rises
        steps = np.diff([lower(c, lid) for c in np.linspace(0.0, 400.0, 801)])
        assert steps.min() >= 0.0 and steps.max() <= 0.5 + 1e-9, lid
    # C1 ramp: value and slope meet at both ends of the blend.
    w = CHEEK_CARRY_BLEND
    assert smooth_ramp(w, w) == w / 2 and abs((smooth_ramp(w - 1e-6, w) - smooth_ramp(w - 2e-6, w)) / 1e-6 - 1) < 1e-4
    for row in tables.expression_table():
        assert np.array_equal(carried_lower_lids(row.copy()), row)


def test_the_cheek_lift_at_its_slider_end_no_longer_folds_the_lower_lid_through_itself(rig):
    """lift_l_cheek 400 (eased to ~310 ENS by its clean limit, ~8 mm of lift under the eye) with
    the lower lid held at its margin squeezed the skin between to nothing: 119 lid crossing pairs.
    Carried up by the cheek, the margin rises (the eye narrows from below) and 11 remain, in the
    socket under the eye's centre (the skin below the ball still rises onto it)."""
    from core.mesh_quality import FaceQualityProbe

    lower_rim = rig.deformer._eye_rims[0][1]
    rig.reset()
    rig.set_fap(41, 400)
    try:
        posed = rig.vertices()
        assert posed[lower_rim, 1].min() - rig.face.vertices[lower_rim, 1].min() > 2.0   # its lowest point
        assert FaceQualityProbe(rig.face).measure(posed).lid_intersections < 20
    finally:
        rig.reset()


def test_skin_the_cheek_lift_slides_over_the_eyeball_keeps_clear_of_it(rig):
    """Joy's cheek lift moves the socket skin at the outer eye corners 2-4 mm over the eyeball; held
    at its rest gap (inside the ball's conservative profile there) its triangles cut the ball: 20
    lid/eyeball crossings. Skin that slid takes the guard's full clearance (GUARD_SLIDE_MM)."""
    from core.mesh_quality import FaceQualityProbe, count_intersections

    probe = FaceQualityProbe(rig.face)
    rig.reset()
    rig.set_expression("joy", 1.0)
    posed = rig.vertices()
    for side in ("left", "right"):
        assert count_intersections(posed, probe.lid_tris[side], probe.eyeball_tris[side]) == 0, side
    rig.reset()


def test_lids_follow_the_eyes_vertical_gaze(rig):
    """As in a real face the lids ride on the cornea: eyes turned 15 degrees down lower the upper lid
    margins (about 0.4 x the cornea's 3.9 mm drop) and no lid crosses the eyeball (208 crossings
    when the lids stayed put); turned up, the upper lids rise. Yaw alone moves no lid."""
    from core.mesh_quality import FaceQualityProbe, count_intersections

    probe = FaceQualityProbe(rig.face)
    upper = rig.deformer._eye_rims[0][0]
    rest = rig.face.vertices[upper, 1].mean()
    rig.reset()
    rig.set_faps({25: 26180, 26: 26180})                   # 0.26 rad = 15 degrees down
    posed = rig.vertices()
    drop = rest - posed[upper, 1].mean()
    assert 1.0 < drop < 2.5
    for side in ("left", "right"):
        assert count_intersections(posed, probe.lid_tris[side], probe.eyeball_tris[side]) == 0, side
    rig.reset()
    rig.set_faps({25: -26180})
    assert rig.vertices()[upper, 1].mean() > rest + 0.5
    rig.reset()
    rig.set_faps({23: 30000})
    assert np.array_equal(rig.vertices()[upper], rig.face.vertices[upper])
    rig.reset()


@pytest.mark.parametrize("pitch", [52360, -52360])
def test_eyes_turned_30_degrees_up_or_down_cross_no_lid(rig, pitch):
    """At the gaze sliders' ends (30 degrees) no lid skin crosses itself or the eyeball. Pitched
    about the fitted sphere's centre, 2.6 mm behind the default face's ellipsoidal ball's own, the
    ball swung its wide outer side into the socket looking up (61 pairs per eye); and lids
    following 0.6 / 0.3 of the cornea's travel down (0.3 / 0.1 up) crossed their own skin (27 and
    14 pairs per eye)."""
    from core.mesh_quality import FaceQualityProbe

    rig.reset()
    rig.set_faps({25: pitch, 26: pitch})
    try:
        assert FaceQualityProbe(rig.face).measure(rig.vertices()).lid_intersections == 0
    finally:
        rig.reset()


@pytest.mark.parametrize("number", [31, 33, 35, 37])
def test_lowered_brows_push_the_upper_lid_over_the_eyeball_not_through_it(rig, number):
    """A brow lowered (or squeezed) to its slider's end pushes the upper lid's skin down onto the
    eyeball: the lid guard holds it outside (raise_l_m_eyebrow -400 crossed it 172 times)."""
    from core.mesh_quality import FaceQualityProbe

    p = rig.describe(f"fap:{number}")
    rig.reset()
    rig.set_fap(number, p.minimum if number != 37 else p.maximum)
    try:
        assert FaceQualityProbe(rig.face).measure(rig.vertices()).lid_intersections == 0
    finally:
        rig.reset()


def test_a_face_without_both_lid_margins_turns_its_eyes_without_moving_lids(rig):
    """Lid-gaze coupling needs both eyes' lid margins (found from the eye-corner feature points);
    without them a gaze change still works and leaves the lids alone instead of failing."""
    import copy

    deformer = copy.copy(rig.deformer)
    deformer._eye_rims = deformer._eye_rims[:1]
    values = np.zeros(68)
    values[24] = values[25] = 26180.0
    np.testing.assert_array_equal(deformer.lid_values(values), values)


def test_lip_overlap_reads_tied_rim_vertices_alike_compiled_and_numpy(monkeypatch):
    """A scan's cut lips have copied rim vertices at the same x (at other heights where the cut
    runs steeply): both paths sort the upper rim stably, so the interpolation reads the same copy and
    the rig's pose does not depend on whether numba had loaded yet (it did: a recovered session
    came back 0.5 mm off along the lower lip)."""
    from core.layers.fap import kernels
    from core.layers.fap.lip_contact import LipContact

    built = kernels.get() or kernels._KERNELS.load()
    if built is None:
        pytest.skip("numba is not installed: only the numpy path exists")
    rng = np.random.default_rng(4)
    xs = np.repeat(np.linspace(-25.0, 25.0, 60), 2)                   # every x twice: copies
    upper = np.column_stack([xs, rng.uniform(-1.0, 1.0, len(xs)), np.zeros(len(xs))])
    lower = np.column_stack([np.linspace(-24.0, 24.0, 97), np.full(97, -0.2), np.zeros(97)])
    lower[::4, 0] = xs[8:8 + 2 * len(lower[::4]):2]                   # some exactly at a tied x
    x = np.concatenate([upper, lower])
    contact = object.__new__(LipContact)
    contact.upper_rim = rng.permutation(len(upper))                     # the rim in no particular order
    contact.lower_rim = np.arange(len(upper), len(x))
    monkeypatch.setattr(kernels, "get", lambda: built)
    compiled = contact._overlap(x)
    monkeypatch.setattr(kernels, "get", lambda: None)
    reference = contact._overlap(x)
    assert np.isfinite(reference).sum() > 90
    np.testing.assert_array_equal(compiled, reference)


def test_skin_beside_a_front_only_faces_eyeball_does_not_jump_when_the_lids_or_cheek_move():
    """A generated front-only face (the synthetic database's person 2): skin beside the ball (a front
    cap) at about its rim's radius was pushed forward onto it — 7.8 mm at the outer eye corner as the
    upper lid closed, 7.3 mm under the lower lid at 320 IRISD — and skin beyond the radius map's skirt
    (no ball in its direction) kept its whole distance to the centre as clearance: lift_l_cheek 220
    threw a temple vertex 25.6 mm forward. Now the guard moves skin beside the ball by at most its
    depth inside (radially), and skin with no ball in its direction at rest hardly at all."""
    from core.layers.fap.eyeball_surface import map_radius
    from core.layers.fap.fat import FapDeformer
    from core.registration import synthetic

    deformer = FapDeformer(synthetic.identity_face(2))
    rest = deformer._rest.reshape(-1, 3)
    idx, centre = deformer._eyes["eyeball_l"]
    guard = next(g for g in deformer._lid_guards if 19 in g.faps)
    offsets = rest - centre
    beside = (offsets[:, 2] < 3.0) & (np.hypot(offsets[:, 0], offsets[:, 1]) < 25.0) & (offsets[:, 0] > 0)
    beside[idx] = False
    no_ball = guard.lid[map_radius(rest[guard.lid] - guard.centre, guard.radii) == 0.0]
    assert beside.sum() > 200 and len(no_ball) > 20

    def guard_push(number, value):
        values = np.zeros(68)
        values[number - 1] = value
        return np.linalg.norm(deformer.deform(values) - (rest + deformer.displacement(values)), axis=1)

    assert guard_push(19, 1024.0)[beside].max() < 1.5
    assert guard_push(21, 320.0)[beside].max() < 1.5
    assert guard_push(41, 220.0)[no_ball].max() < 0.5
