"""Structural landmark matching (thesis A §3.2): known answers and bad inputs."""

import numpy as np
import pytest

from core.face import Face, SurfacePoint
from core.registration.matching import MatchingError, MatchParams, Side, greedy_match, match_order
from core.registration.pipeline import ScanInputError, detect_landmarks
from core.registration.templates import get_template, template_positions


@pytest.fixture(scope="module")
def model():
    from core.registration.pipeline import default_model

    return default_model()


@pytest.fixture(scope="module")
def scan(model):
    """The model itself, re-meshed by the virtual scanner (different vertices and triangles)."""
    from core.registration.virtual_scanner import scan_face

    return scan_face(model, n_target=30_000, rng=np.random.default_rng(3)).face


@pytest.fixture(scope="module")
def detection(scan):
    return detect_landmarks(scan, template="a48")


def scale_of(face):
    return float(np.linalg.norm(face.landmark_position("3.7") - face.landmark_position("3.12")))


def test_remeshed_model_gives_the_exact_landmarks(scan, detection):
    gt = template_positions(scan, "a48")
    err = np.array([np.linalg.norm(detection.positions[n] - gt[n]) for n in gt])
    assert len(err) == 48
    assert err.max() < 0.05 * scale_of(scan), dict(zip(gt, err.round(1)))   # < ~4.5 mm everywhere
    assert err.mean() < 1.5
    # Landmarks are surface points of the scan at the reported positions.
    for n, p in detection.landmarks.items():
        on_surface = np.array(p.barycentric) @ scan.vertices[scan.triangles[p.triangle]]
        assert np.allclose(on_surface, detection.positions[n], atol=1e-6)
    assert all(0.0 <= c <= 1.0 for c in detection.confidence.values())
    assert np.median(list(detection.confidence.values())) > 0.5


def test_fixed_landmarks_are_kept(scan, detection):
    name = "8.3"
    moved = scan.surface_point(detection.positions[name] + np.array([0.0, 4.0, 0.0]))
    d = detect_landmarks(scan, template="a48", fixed={name: moved})
    assert d.landmarks[name] == moved
    assert d.sources[name] == "fixed" and d.confidence[name] == 1.0


def test_fixed_mouth_corners_steer_the_inner_corners_beside_them(scan, detection):
    """A user who corrects the outer mouth corners (8.3 / 8.4, here 8 mm lower on the scan) and detects
    again gets the closed mouth's inner corners (2.4 / 2.5) beside them, as the model has them: the
    lip order pass reads the fixed points too (it once saw no pixel for them and left the inner
    corners where the patches found them, 8 mm away)."""
    scale = scale_of(scan)
    fixed = {n: scan.surface_point(detection.positions[n] + np.array([0.0, -8.0, 0.0])) for n in ("8.3", "8.4")}
    d = detect_landmarks(scan, template="a48", fixed=fixed)
    for inner, outer in (("2.4", "8.3"), ("2.5", "8.4")):
        given = np.array(fixed[outer].barycentric) @ scan.vertices[scan.triangles[fixed[outer].triangle]]
        expected = given + (detection.positions[inner] - detection.positions[outer])
        assert np.linalg.norm(d.positions[inner] - expected) < 0.05 * scale, inner
        assert np.linalg.norm(d.positions[inner] - detection.positions[inner]) > 5.0, inner


def test_no_texture_falls_back_to_geometry(scan):
    bare = Face(scan.vertices, scan.triangles, landmarks=scan.landmarks)
    d = detect_landmarks(bare, template="a48")
    assert any("no texture" in line for line in d.report)
    assert len(d.landmarks) == 48
    gt = template_positions(scan, "a48")
    err = np.array([np.linalg.norm(d.positions[n] - gt[n]) for n in gt])
    assert np.median(err) < 0.1 * scale_of(scan)   # geometry alone still finds most points


def test_tiny_mesh_is_refused():
    v = np.random.default_rng(0).random((30, 3)) * 100
    with pytest.raises(ScanInputError, match="vertices"):
        detect_landmarks(Face(v, [[0, 1, 2], [2, 3, 4]]))


def test_metres_are_detected(scan):
    metres = Face(scan.vertices / 1000.0, scan.triangles)
    with pytest.raises(ScanInputError, match="metres.*1000"):
        detect_landmarks(metres)


def test_bad_params_are_refused():
    with pytest.raises(MatchingError, match="lam"):
        MatchParams(lam=1.5)


def test_greedy_recovers_a_permutation():
    """Candidates = the model's points shuffled and jittered: Algorithm 1 finds each point."""
    tpl = get_template("a48")
    from core.registration.pipeline import default_model

    pts = np.array(list(template_positions(default_model(), "a48").values()))
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(pts))
    colour = rng.random((len(pts), 3))
    model = Side(pts, colour, colour)
    cand = Side(pts[perm] + rng.normal(0, 0.3, pts.shape), colour[perm], colour[perm])
    order = match_order(tpl, pts, [tpl.index("9.3")])
    assert sorted(order) == list(range(48)) and order[0] == tpl.index("9.3")
    for propagate in (False, True):
        g = greedy_match(tpl, model, cand, MatchParams(lam=0.5, propagate=propagate), 91.0, order=order)
        assert np.array_equal(perm[g.candidate], np.arange(48))
        assert (g.margin > 0).all()


def pixel_context_for(tpl, raster, model_px, *, search=None, scale=90.0):
    """A PixelContext for testing one mouth pass (greedy pixels and graph distances unused)."""
    from core.registration.match_context import PixelContext

    P = len(tpl.detected)
    return PixelContext(tpl, raster, model_px, model_px, scale, MatchParams(), np.zeros(P, bool), search,
                        np.zeros((P, P)))


def test_inner_lips_go_to_the_edges_of_a_mouth_opening():
    """A depth raster with a rectangular opening (rows 35-50, cols 25-55, 20 mm deep): the upper
    inner-lip points land on row 34, the lower ones on row 51, spread between the opening's ends;
    a closed mouth (no opening) leaves them alone."""
    from core.registration.matching import FrontalRaster
    from core.registration.mouth_passes import mouth_opening_pass
    from core.registration.pass_results import PixelEstimates

    tpl = get_template("a48")
    names = tpl.detected
    P = len(names)
    model_px = np.full((P, 2), 40.0)
    loop = list(tpl.base.mouth)                   # corner, upper chain, corner, lower chain
    half = len(loop) // 2
    for j, n in enumerate(loop):
        t = j / half if j <= half else (len(loop) - j) / half
        model_px[names.index(n)] = (20 + 40 * t, 30.0)
    for o, i in (("8.3", "2.4"), ("8.4", "2.5")):   # each outer corner 2 px beyond its inner one
        inner = names.index(i)
        model_px[names.index(o)] = model_px[inner] + (2.0 if model_px[inner, 0] > 40 else -2.0, 0.0)
    model_px[names.index("9.15")] = (40, 10)
    for n in ("2.10", "2.1", "2.11", "2.12"):
        model_px[names.index(n)] = (40, 70)
    depth = np.zeros((90, 80))
    est = PixelEstimates(model_px.copy(), np.zeros(P))
    raster = FrontalRaster(0.0, 0.0, 0.75, np.zeros((90, 80), int), np.zeros((90, 80, 3)), np.zeros((90, 80, 1)), depth)
    assert len(mouth_opening_pass(pixel_context_for(tpl, raster, model_px), est)) == 0   # closed: nothing moves
    depth[35:51, 25:56] = -20.0
    moves = mouth_opening_pass(pixel_context_for(tpl, raster, model_px), est)
    out = est.apply(moves).pixel
    np.testing.assert_array_equal(est.pixel, model_px)      # the pass returns moves, changes nothing
    upper = [names.index(n) for n in loop[1:half]]
    lower = [names.index(n) for n in loop[half + 1:]]
    corners = [names.index(loop[0]), names.index(loop[half])]
    assert np.all(out[upper, 1] == 34) and np.all(out[lower, 1] == 51)
    assert np.all((out[upper + lower, 0] > 24) & (out[upper + lower, 0] < 56))
    # The corners (cols 20 and 60) are already beyond the opening's ends (24.5, 55.5), 4 rows above
    # its top (row 34, within 0.05 x scale): lips that touch there; they stay.
    np.testing.assert_array_equal(out[corners], model_px[corners])
    assert set(moves.index) == set(upper + lower) and np.all(moves.peak == 0.5)
    # Corners as far out but 20 rows (15 mm) above the opening are on the cheek: they go to its tips,
    # the outer corners beside them.
    high = model_px.copy()
    high[corners, 1] = high[[names.index("8.3"), names.index("8.4")], 1] = 10.0
    est = PixelEstimates(high, np.zeros(P))
    out = est.apply(mouth_opening_pass(pixel_context_for(tpl, raster, high), est)).pixel
    np.testing.assert_array_equal(np.sort(out[corners, 0]), [24.5, 55.5])
    assert np.all(out[corners, 1] == 42.5)
    for o, i in (("8.3", "2.4"), ("8.4", "2.5")):
        np.testing.assert_array_equal(out[names.index(o)] - out[names.index(i)],
                                      high[names.index(o)] - high[names.index(i)])


def _model_mouth_at_row_45():
    """(template, detected names, P, model pixels (P, 2), inner-lip loop, half its length): every point
    at (40, 40) but the inner-lip loop, a closed mouth on row 45 from column 25 to 55."""
    tpl = get_template("mpeg4_80")
    names = tpl.detected
    P = len(names)
    model_px = np.full((P, 2), 40.0)
    loop = list(tpl.base.mouth)
    half = len(loop) // 2
    for j, n in enumerate(loop):
        t = j / half if j <= half else (len(loop) - j) / half
        model_px[names.index(n)] = (25 + 30 * t, 45.0)
    return tpl, names, P, model_px, loop, half


def test_a_smile_whose_ends_rise_and_thin_to_a_slit_is_followed_to_its_tips():
    """An unscanned opening (a hole, as a virtual scan of a mesh with an open mouth shows it) whose
    ends rise above the philtrum row the middle is searched from and thin to a one-row slit, far
    thinner than a hole counted in the middle (HOLE_MM): the corners go to where the slit ends."""
    from core.registration.matching import FrontalRaster
    from core.registration.mouth_passes import mouth_opening_pass
    from core.registration.pass_results import PixelEstimates

    tpl, names, P, model_px, loop, half = _model_mouth_at_row_45()
    model_px[names.index("9.15")] = (40, 15)         # philtrum row: 15 + (45 - 15) / 2 = 30
    for n in ("2.10", "2.1", "2.11", "2.12"):
        model_px[names.index(n)] = (40, 80)
    depth = np.zeros((95, 80))
    for col in range(18, 63):
        centre = 40.0 - 0.04 * (col - 40) ** 2           # the ends rise to row 20.6 / 21.0 (above 30)
        h = 0 if abs(col - 40) > 12 else int(round(6 * (1 - abs(col - 40) / 13)))   # one row beyond
        depth[int(round(centre)) - h:int(round(centre)) + h + 1, col] = np.nan
    covered = np.isfinite(depth)
    raster = FrontalRaster(0.0, 0.0, 0.75, np.where(covered, 0, -1), np.zeros(depth.shape + (3,)),
                           np.zeros(depth.shape + (1,)), depth)
    est = PixelEstimates(model_px.copy(), np.zeros(P))
    out = est.apply(mouth_opening_pass(pixel_context_for(tpl, raster, model_px), est)).pixel
    c0, c1 = names.index(loop[0]), names.index(loop[half])
    left, right = (c0, c1) if model_px[c0, 0] < model_px[c1, 0] else (c1, c0)
    assert out[left, 0] == 17.5 and out[right, 0] == 62.5
    assert abs(out[left, 1] - (40.0 - 0.04 * 22 ** 2)) <= 1 and abs(out[right, 1] - (40.0 - 0.04 * 22 ** 2)) <= 1


def test_corners_of_a_smiling_open_mouth_go_to_the_opening_tips():
    """An opening shaped like a smile (its ends curve up and narrow to a point at cols 22 and 58):
    the inner-lip corners go to the tips, up and out from the model's level closed corners, and the
    outer-lip corners keep the model's offset from them. An opening much wider than the model's
    mouth (a raster border, not lips) moves no corner."""
    from core.registration.matching import FrontalRaster
    from core.registration.mouth_passes import mouth_opening_pass
    from core.registration.pass_results import PixelEstimates

    tpl, names, P, model_px, loop, half = _model_mouth_at_row_45()
    c0, c1 = names.index(loop[0]), names.index(loop[half])
    outer = {names.index("8.3"), names.index("8.4")}
    for o, i in (("8.3", "2.4"), ("8.4", "2.5")):   # each outer corner 2 px beyond its inner one
        inner = names.index(i)
        model_px[names.index(o)] = model_px[inner] + (2.0 if model_px[inner, 0] > 40 else -2.0, 0.0)
    model_px[names.index("9.15")] = (40, 15)
    for n in ("2.10", "2.1", "2.11", "2.12"):
        model_px[names.index(n)] = (40, 80)
    depth = np.zeros((95, 80))
    for col in range(22, 59):
        centre = 46.0 - 0.03 * (col - 40) ** 2           # the ends curve up
        h = 6.0 * (1.0 - ((col - 40) / 18.5) ** 2)       # and close to a point
        if h >= 0.5:
            depth[int(round(centre - h)):int(round(centre + h)) + 1, col] = -15.0
    raster = FrontalRaster(0.0, 0.0, 0.75, np.zeros(depth.shape, int), np.zeros(depth.shape + (3,)),
                           np.zeros(depth.shape + (1,)), depth)
    est = PixelEstimates(model_px.copy(), np.zeros(P))
    out = est.apply(mouth_opening_pass(pixel_context_for(tpl, raster, model_px), est)).pixel
    open_cols = np.nonzero((depth < -1).any(axis=0))[0]
    left, right = (c0, c1) if model_px[c0, 0] < model_px[c1, 0] else (c1, c0)
    assert out[left, 0] == open_cols[0] - 0.5 and out[right, 0] == open_cols[-1] + 0.5
    assert out[left, 1] < 40 and out[right, 1] < 40                  # raised, from row 45
    for k in outer:
        inner = left if out[k, 0] < 40 else right
        np.testing.assert_allclose(out[k] - out[inner], model_px[k] - model_px[inner])
    depth[44:48, 0:80] = -15.0                             # an opening across the whole raster
    est = PixelEstimates(model_px.copy(), np.zeros(P))
    out = est.apply(mouth_opening_pass(pixel_context_for(tpl, raster, model_px), est)).pixel
    np.testing.assert_array_equal(out[[c0, c1] + sorted(outer)], model_px[[c0, c1] + sorted(outer)])


def test_steep_points_are_the_lateral_sides(model):
    from core.registration.matching import steep_points
    from core.registration.pipeline import get_model_context

    ctx = get_model_context(model, "a48", MatchParams())
    steep = {n for n, s in zip(ctx.template.detected, steep_points(ctx)) if s}
    assert {"10.7", "10.8", "2.13", "2.14", "4.5", "4.6"} <= steep
    assert not steep & {"11.1", "9.3", "3.11", "3.8", "8.3", "8.4", "2.2", "9.12"}


def test_lower_inner_lip_collapsed_on_the_outer_lip_goes_back_to_the_seam(model):
    from core.registration.mouth_passes import lip_order_pass
    from core.registration.pass_results import PixelEstimates

    tpl = get_template("a48")
    pos = template_positions(model, "a48")
    model_px = np.array([[pos[n][0], -pos[n][1]] for n in tpl.detected]) / 0.75   # (col, row), rows grow down
    out = model_px.copy()
    i23, i82, i81, i29 = (tpl.index(n) for n in ("2.3", "8.2", "8.1", "2.9"))
    out[i23] = (model_px[i23, 0], model_px[i82, 1] + 1.0)     # collapsed onto (below) the lower outer lip
    peak = np.ones(len(out))

    class Search:
        def nearest_covered(self, px):
            return tuple(px)

    moves = lip_order_pass(pixel_context_for(tpl, None, model_px, search=Search()), PixelEstimates(out, peak))
    assert list(moves.index) == [i23]
    est = PixelEstimates(out, peak).apply(moves)
    out, peak = est.pixel, est.peak
    assert out[i23, 1] == pytest.approx(model_px[i23, 1])     # back at the seam, below the upper outer lip
    assert out[i23, 1] < out[i82, 1] and out[i23, 1] > out[i81, 1]
    assert peak[i23] == 0.0 and peak[i29] == 1.0               # the uncollapsed point is left alone
    np.testing.assert_array_equal(out[i29], model_px[i29])


def test_a_closed_mouths_inner_lip_points_keep_the_models_spacing_on_the_seam(model):
    """Closed mouth: a lower inner-lip point found elsewhere along the seam (2.9 slid 8 px toward the
    corner, where the patch fitted as well) goes back to the model's fraction between the inner
    corners, on the seam; an inner corner found far from its outer corner (2.5 12 px below 8.4:
    the mouth's width is ~70 px) goes back beside it at the model's offset. Points in place stay."""
    from core.registration.mouth_passes import lip_order_pass
    from core.registration.pass_results import PixelEstimates

    tpl = get_template("a48")
    pos = template_positions(model, "a48")
    model_px = np.array([[pos[n][0], -pos[n][1]] for n in tpl.detected]) / 0.75   # (col, row), rows grow down
    i29, i25, i27 = (tpl.index(n) for n in ("2.9", "2.5", "2.7"))

    class Search:
        def nearest_covered(self, px):
            return tuple(px)

    out = model_px.copy()
    out[i29] += (8.0, 0.0)
    out[i25] += (0.0, 12.0)
    moves = lip_order_pass(pixel_context_for(tpl, None, model_px, search=Search()),
                           PixelEstimates(out, np.ones(len(out))))
    assert set(moves.index) == {i29, i25}
    est = PixelEstimates(out, np.ones(len(out))).apply(moves)
    np.testing.assert_allclose(est.pixel[i25], model_px[i25], atol=1e-9)
    assert est.pixel[i29, 0] == pytest.approx(model_px[i29, 0], abs=1e-9)
    assert abs(est.pixel[i29, 1] - model_px[i29, 1]) < 1.0
    np.testing.assert_array_equal(est.pixel[i27], model_px[i27])


def test_upper_outer_lip_found_below_the_seam_goes_back_above_it(model):
    """Closed mouth, no texture: the upper lip midpoint 8.1 found on the lower lip (below the seam
    point 2.2) is searched again at the model's lip height above the seam; where no patch fits
    there it takes that height with no evidence. 8.1 above the seam is left alone."""
    from core.registration.mouth_passes import lip_order_pass
    from core.registration.pass_results import PixelEstimates

    tpl = get_template("a48")
    pos = template_positions(model, "a48")
    model_px = np.array([[pos[n][0], -pos[n][1]] for n in tpl.detected]) / 0.75   # (col, row), rows grow down
    i81, i22, i82 = (tpl.index(n) for n in ("8.1", "2.2", "8.2"))
    height = model_px[i22, 1] - model_px[i81, 1]
    assert height > 2
    calls = []

    class Search:
        def __init__(self, fits):
            self.fits = fits

        def nearest_covered(self, px):
            return tuple(px)

        def search(self, k, centre, rx, ry, pull_px=None):
            calls.append((k, tuple(centre), rx, ry))
            return ((centre[0] + 1.0, centre[1] - 1.0), 0.7) if self.fits else (None, 0.0)

    for fits, want_row, want_peak in ((True, model_px[i22, 1] - height - 1.0, 0.7),
                                      (False, model_px[i22, 1] - height, 0.0)):
        out = model_px.copy()
        out[i81] = (model_px[i81, 0], model_px[i82, 1])   # on the lower lip
        peak = np.ones(len(out))
        calls.clear()
        moves = lip_order_pass(pixel_context_for(tpl, None, model_px, search=Search(fits)), PixelEstimates(out, peak))
        est = PixelEstimates(out, peak).apply(moves)
        assert list(moves.index) == [i81]
        assert calls and calls[0][0] == i81 and calls[0][1][1] == pytest.approx(model_px[i22, 1] - height)
        assert est.pixel[i81, 1] == pytest.approx(want_row) and est.pixel[i81, 1] < est.pixel[i22, 1]
        assert est.peak[i81] == want_peak
    out = model_px.copy()                                  # in order: nothing moves
    moves = lip_order_pass(pixel_context_for(tpl, None, model_px, search=Search(True)),
                           PixelEstimates(out, np.ones(len(out))))
    assert len(moves.index) == 0


def test_moves_are_applied_to_a_copy_and_results_are_read_only():
    from core.registration.pass_results import MatchState, PixelEstimates, PixelMoves, SurfaceMoves

    state = MatchState(np.zeros((3, 3)), [-1, 5, 6], np.zeros((3, 3)), ("prediction",) * 3, np.zeros(3))
    moves = SurfaceMoves([0], [7], [[0.2, 0.3, 0.5]], [[1.0, 2.0, 3.0]], source=["refined"])
    after = state.apply(moves)
    assert list(after.triangle) == [7, 5, 6] and after.source == ("refined", "prediction", "prediction")
    np.testing.assert_array_equal(after.positions[0], (1, 2, 3))
    assert list(state.triangle) == [-1, 5, 6] and not state.positions.any()   # the state it came from is kept
    for a in (after.positions, moves.bary, state.evidence):
        with pytest.raises(ValueError):
            a[0] = 1.0
    est = PixelEstimates.empty(3).apply(PixelMoves.take(np.ones((3, 2)), np.full(3, 0.8), [2]))
    assert np.isnan(est.pixel[:2]).all() and list(est.pixel[2]) == [1.0, 1.0] and list(est.peak) == [0, 0, 0.8]



def _outlier_case(model, fixed_names=()):
    """(model context, detected names, the context the outlier pass reads): the scan is the model
    itself, each point's closest scan point is the point itself; ``fixed_names`` are fixed."""
    from types import SimpleNamespace

    from core.registration.greedy import graph_distances
    from core.registration.pipeline import get_model_context

    m = get_model_context(model, "mpeg4_80", MatchParams())
    names = list(m.template.detected)
    fixed = np.array([n in fixed_names for n in names])
    ctx = SimpleNamespace(model=m, params=MatchParams(), gdist=graph_distances(m.template, m.side.points),
                          fixed=fixed, scan_raster=None,
                          closest=lambda p: (np.zeros(len(p), int), np.tile([1.0, 0.0, 0.0], (len(p), 1)), p))
    return m, names, ctx


def test_a_weak_point_far_from_the_confident_ones_follows_them(model):
    """The scan is the model itself; 3.7 was matched 15 mm away with confidence 0.2: it goes back to
    its place (the anchors did not move, so their prediction is the model's point), as a
    "prediction" with evidence 0. A point as far but with confidence 0.45 (some evidence), a weak
    one only 3 mm off, a fixed one and a weak far one on the mouth opening's edge (source "opening")
    stay where they are."""
    from core.registration.outlier_pass import outlier_pass
    from core.registration.pass_results import MatchState

    m, names, ctx = _outlier_case(model, fixed_names=("9.15",))
    P = len(names)
    truth = m.side.points.copy()
    positions = truth.copy()
    confidence = np.full(P, 0.9)
    far_weak, far_doubtful, near_weak, fixed_far, on_opening = (names.index(n) for n in
                                                                ("3.7", "3.12", "4.4", "9.15", "8.3"))
    positions[[far_weak, far_doubtful, fixed_far, on_opening]] += (0.0, 15.0, 0.0)
    positions[near_weak] += (0.0, 3.0, 0.0)
    confidence[[far_weak, near_weak, fixed_far, on_opening]] = 0.2
    confidence[far_doubtful] = 0.45
    sources = ["refined"] * P
    sources[on_opening] = "opening"      # put on the mouth opening's edge by the scan's shape
    state = MatchState(positions, np.zeros(P, int), np.tile([1.0, 0.0, 0.0], (P, 1)), sources, np.ones(P))
    moves = outlier_pass(ctx, state, confidence)
    assert list(moves.index) == [far_weak]
    after = state.apply(moves)
    # (to 0.01 mm: the opening point 15 mm off anchors the prediction too, with a vanishing weight there)
    np.testing.assert_allclose(after.positions[far_weak], truth[far_weak], atol=0.01)
    assert after.source[far_weak] == "prediction" and after.evidence[far_weak] == 0.0




def test_a_point_that_lost_its_place_follows_the_confident_ones_even_on_the_outline(model):
    """The chin 2.1 (an outline point) 40 mm up on the face with confidence 0.42, the nose wing 9.5
    as far with 0.39: more than three tolerances (0.3 x the face's scale) from where the confident
    matches put them, they go back there although their evidence is not weak (< 0.3); the brow 4.4
    as far but with confidence 0.6 (evidence the picker would not list) stays."""
    from core.registration.outlier_pass import GROSS_DISTANCE, outlier_pass
    from core.registration.pass_results import MatchState

    m, names, ctx = _outlier_case(model)
    P = len(names)
    truth = m.side.points.copy()
    positions = truth.copy()
    confidence = np.full(P, 0.9)
    chin, wing, brow = (names.index(n) for n in ("2.1", "9.5", "4.4"))
    assert 40.0 > GROSS_DISTANCE * m.scale
    positions[[chin, wing, brow]] += (0.0, 40.0, 0.0)
    confidence[[chin, wing, brow]] = (0.42, 0.39, 0.6)
    state = MatchState(positions, np.zeros(P, int), np.tile([1.0, 0.0, 0.0], (P, 1)), ("refined",) * P, np.ones(P))
    moves = outlier_pass(ctx, state, confidence)
    assert sorted(moves.index) == sorted([chin, wing])
    after = state.apply(moves)
    np.testing.assert_allclose(after.positions[[chin, wing]], truth[[chin, wing]], atol=0.5)


def test_points_on_the_mouth_opening_anchor_the_outlier_prediction(model):
    """An open mouth: the jaw, chin and lower lip 15 mm down; the lower inner lip on the opening's
    edge (source "opening") with confidence 0.2, the lower outer lip 8.2 weak (0.2) and its
    neighbours 8.7 / 8.8 doubtful (0.5, no anchors). The opening's points anchor the prediction,
    so 8.2 (where the lower lip went) is not pulled back up to the closed model's lip."""
    from core.registration.outlier_pass import outlier_pass
    from core.registration.pass_results import MatchState

    m, names, ctx = _outlier_case(model)
    P = len(names)
    positions = m.side.points.copy()
    confidence = np.full(P, 0.9)
    lower = [names.index(n) for n in m.template.base.lower_lip_points if n in names]
    positions[lower + [names.index(n) for n in ("2.10", "2.1", "2.11", "2.12")]] += (0.0, -15.0, 0.0)
    opening = [names.index(n) for n in ("2.7", "2.3", "2.9")]
    confidence[opening + [names.index("8.2")]] = 0.2
    confidence[[names.index("8.7"), names.index("8.8")]] = 0.5
    sources = ["opening" if i in opening else "refined" for i in range(P)]
    state = MatchState(positions, np.zeros(P, int), np.tile([1.0, 0.0, 0.0], (P, 1)), sources, np.ones(P))
    assert len(outlier_pass(ctx, state, confidence)) == 0
    # The same lip placed by the patch search alone (no "opening" source): 8.2 follows the closed model.
    state = state.replace(source=("refined",) * P)
    assert names.index("8.2") in outlier_pass(ctx, state, confidence).index


def _brow_case(model, *, textured, band_from=None, band_to=52.0, model_band=True):
    """The model's own points as the match, with the left brow top 4.3 slid 8 mm outwards along the
    brow and its outer end 4.5 3 mm out, on a synthetic frontal raster in the model frame (0.75 mm
    pixels; pixel (row, col) is triangle row * W + col) whose grey channel has, when textured, a
    dark band 4 mm thick centred 1 mm below the model's brow line (through 4.1, 4.3, 4.5) from
    x = ``band_from`` (default the model's 4.1) to ``band_to`` mm (the model's 4.5 is at 55.5);
    the right brow has no band. The model's raster is the same with its band (when ``model_band``)
    from its 4.1 to x = 52 mm."""
    from types import SimpleNamespace

    from core.registration.matching import FrontalRaster
    from core.registration.pass_results import MatchState
    from core.registration.pipeline import get_model_context

    m = get_model_context(model, "mpeg4_80", MatchParams())
    names = list(m.template.detected)
    P = len(names)
    pts = m.side.points
    x0, y0, px, H, W = -90.0, 100.0, 0.75, 120, 241
    cols, rows = np.meshgrid(np.arange(W), np.arange(H))
    x, y = x0 + cols * px, y0 - rows * px
    xs, ys = pts[[names.index(n) for n in ("4.1", "4.3", "4.5")], :2].T
    band_from = xs[0] if band_from is None else band_from
    line = np.interp(x, xs, ys)

    def raster_with_band(start, stop):
        channels = np.zeros((H, W, 5), np.float32)
        if start is not None:
            band = (np.abs(y - (line - 1.0)) <= 2.0) & (x >= start) & (x <= stop)
            channels[..., 3] = np.where(band, -3.0, 0.0)
        return FrontalRaster(x0, y0, px, rows * W + cols, np.tile([1.0, 0.0, 0.0], (H, W, 1)), channels,
                             np.zeros((H, W)))

    raster = raster_with_band(band_from if textured else None, band_to)
    m = SimpleNamespace(template=m.template, side=m.side, scale=m.scale,
                        raster=raster_with_band(xs[0] if model_band else None, 52.0))
    positions = pts.copy()
    positions[names.index("4.3")] += (8.0, 0.0, 0.0)
    positions[names.index("4.5")] += (3.0, 0.0, 0.0)
    ctx = SimpleNamespace(model=m, fixed=np.zeros(P, bool), textured=textured, scan_raster=raster)
    state = MatchState(positions, np.zeros(P, int), np.tile([1.0, 0.0, 0.0], (P, 1)), ["refined"] * P, np.ones(P))
    col_of = lambda x: (x - raster.x0) / raster.pixel          # noqa: E731
    row_of = lambda y: (raster.y0 - np.interp(y, xs, ys) + 1.0) / raster.pixel   # noqa: E731  band middle at x
    return ctx, state, names, xs, col_of, row_of, W


def _landed(moves, names, name, W):
    """(row, col) of the raster pixel the move of ``name`` chose."""
    k = list(moves.index).index(names.index(name))
    return divmod(int(moves.triangle[k]), W)


@pytest.mark.parametrize("band_from, band_to, model_band", [(None, 52.0, True), (20.0, 60.0, True),
                                                            (20.0, 60.0, False)])
def test_brow_top_and_end_go_to_the_texture_band(model, band_from, band_to, model_band):
    """The left brow top slid 8 mm along the brow goes to the band's middle row at the fraction of
    the band's length (inner to outer end) where the model's 4.3 lies on the model's own band
    (4.1 .. 52 mm), or, when the model has no band, at its template points' fraction 4.1 -> 4.5;
    the outer end goes to where the band ends, on its middle row. Also for a brow that starts
    7 mm farther out and ends 4.5 mm beyond the model's 4.5. The right brow has no band: nothing
    moves there."""
    from core.registration.brow_pass import BAND_EVIDENCE, brow_pass

    ctx, state, names, xs, col_of, row_of, W = _brow_case(model, textured=True, band_from=band_from,
                                                          band_to=band_to, model_band=model_band)
    moves = brow_pass(ctx, state, np.full(len(names), 0.5))
    assert {names[i] for i in moves.index} == {"4.3", "4.5"}
    start = xs[0] if band_from is None else band_from
    frac = (xs[1] - xs[0]) / ((52.0 if model_band else xs[2]) - xs[0])
    x_top = start + frac * (band_to - start)
    r, c = _landed(moves, names, "4.3", W)
    assert abs(c - col_of(x_top)) <= 1 and abs(r - row_of(x_top)) <= 1
    r, c = _landed(moves, names, "4.5", W)
    assert abs(c - col_of(band_to)) <= 1 and abs(r - row_of(band_to)) <= 1
    assert set(moves.source) == {"refined"} and np.all(moves.evidence == BAND_EVIDENCE)
    np.testing.assert_array_equal(state.positions[names.index("4.3")], model.landmark_position("4.3") + (
        8.0, 0, 0))                                                # the pass returns moves, changes nothing


def test_brow_pass_leaves_untextured_scans_fixed_points_and_bad_eyes(model):
    """No texture: nothing moves. A fixed brow top stays (its outer end still moves); a band that
    does not end within END_WALK x scale outwards (it runs off the face) moves nothing; with the
    left eye's corners collapsed onto each other the left brow is left alone."""
    from core.registration.brow_pass import brow_pass

    ctx, state, names, *_ = _brow_case(model, textured=False)
    assert len(brow_pass(ctx, state, np.full(len(names), 0.5))) == 0
    ctx, state, names, *_ = _brow_case(model, textured=True, band_to=200.0)
    assert len(brow_pass(ctx, state, np.full(len(names), 0.5))) == 0
    ctx, state, names, *_ = _brow_case(model, textured=True)
    ctx.fixed[names.index("4.3")] = True
    assert {names[i] for i in brow_pass(ctx, state, np.full(len(names), 0.5)).index} == {"4.5"}
    ctx.fixed[:] = False
    positions = state.positions.copy()
    positions[names.index("3.7")] = positions[names.index("3.11")]
    assert len(brow_pass(ctx, state.replace(positions=positions), np.full(len(names), 0.5))) == 0


def _search_on(scan_channel: np.ndarray, model_channel: np.ndarray, point_px):
    """A PatchSearch of one landmark at pixel ``point_px`` (col, row) of ``model_channel`` (H, W)
    over ``scan_channel`` (H, W); both rasters 0.75 mm pixels, fully covered."""
    from core.registration.matching import FrontalRaster
    from core.registration.patches import PatchSearch

    def raster(channel):
        H, W = channel.shape
        return FrontalRaster(0.0, 0.0, 0.75, np.arange(H * W).reshape(H, W), np.tile([1.0, 0.0, 0.0], (H, W, 1)),
                             channel[..., None].astype(np.float32))

    point = np.array([[point_px[0] * 0.75, -point_px[1] * 0.75, 0.0]])
    return PatchSearch(point, raster(model_channel), raster(scan_channel), MatchParams(), ["full"], [False])


@pytest.mark.parametrize("shape, distinct", [("bump", 1.0), ("ridge", 0.0)])
def test_evidence_along_a_ridge_is_flat_and_a_bump_is_distinct(shape, distinct):
    """A bump's patch fits only at the bump (distinctness 1); a straight ridge's patch fits as well
    anywhere along the ridge, so where along it the point lies is not evidenced (0)."""
    from core.registration.ambiguity import distinctness

    rows, cols = np.mgrid[0:200, 0:200]
    if shape == "bump":
        channel = np.exp(-((rows - 100.0) ** 2 + (cols - 100.0) ** 2) / (2 * 6.0 ** 2))
    else:
        channel = np.exp(-((rows - 100.0) ** 2) / (2 * 6.0 ** 2))
    search = _search_on(channel, channel, (100, 100))
    scale_px = 91.0 / 0.75
    got = distinctness(search, np.array([[100.0, 100.0]]), np.array([True]), scale_px)
    # (to 1e-4: the NCC is summed in float32, and its last bits depend on the CPU's vector width:
    # 4.8e-6 on one machine, 0 on another)
    assert got[0] == pytest.approx(distinct, abs=1e-4)
    # Not placed by the patch search: nothing measured.
    assert distinctness(search, np.array([[100.0, 100.0]]), np.array([False]), scale_px)[0] == 1.0


def test_ambiguity_changes_only_the_reported_confidence(scan):
    """The flat-evidence check lowers confidences (never raises them) and moves no point."""
    bare = Face(scan.vertices, scan.triangles, landmarks=scan.landmarks)
    with_check = detect_landmarks(bare, template="mpeg4_80")
    without = detect_landmarks(bare, template="mpeg4_80", params=MatchParams(ambiguity=False))
    for n in with_check.positions:
        assert np.allclose(with_check.positions[n], without.positions[n])
        assert with_check.confidence[n] <= without.confidence[n] + 1e-12
    assert sum(with_check.confidence[n] < without.confidence[n] for n in with_check.confidence) > 0
