"""Clean limits of the FAPs and the soft limit that eases into them (issue 18 item 2)."""

from __future__ import annotations

import numpy as np
import pytest

from core.layers.fap import tables
from core.layers.fap.limits import EASE_START, keeping, soft_limit
from core.layers.fap.template import load_template
from core.mesh_quality import FaceQualityProbe
from tests.core.conftest import without_surface_guard


def test_soft_limit_is_the_identity_inside_and_eases_smoothly_toward_the_limit():
    limits = np.array([[-np.inf, np.inf]] * 68)
    limits[2] = [-50.0, 100.0]
    values = np.linspace(-150, 250, 4001)
    out = np.array([soft_limit(np.r_[np.zeros(2), v, np.zeros(65)], limits)[2] for v in values])
    inside = (values >= -50 * EASE_START) & (values <= 100 * EASE_START)
    assert np.array_equal(out[inside], values[inside])             # untouched well inside
    assert out.max() < 100.0 and out.min() > -50.0                 # never at or past the limit
    far = soft_limit(np.full(68, 1e4), limits)[2], soft_limit(np.full(68, -1e4), limits)[2]
    assert far[0] <= 100.0 and far[1] >= -50.0                     # not even far beyond it
    assert np.all(np.diff(out) > 0)                                # still a slider: strictly increasing
    slope = np.diff(out) / np.diff(values)
    assert slope.max() <= 1.0 + 1e-9 and slope[np.argmin(np.abs(values[:-1] - 70.0))] == pytest.approx(1.0, abs=0.01)
    assert out[-1] > 99.0                                          # 2.5x the limit nearly reaches it
    other = np.full(68, 1e6)
    assert soft_limit(other, limits)[5] == 1e6                     # no limit: nothing changes


def test_keeping_lets_every_preset_pass_and_eases_just_past_it():
    """A preset past the surface's limit passes unchanged and the slider's end eases toward
    PRESET_MARGIN of the overshoot past it (not EASE_START's 43 % more); a preset inside the limit but
    past the ease's start moves the start to the preset and still eases toward the limit itself."""
    from core.layers.fap.limits import PRESET_MARGIN

    limits = np.array([[-np.inf, np.inf]] * 68)
    limits[2] = [-10.0, 174.0]
    limits[5] = [-100.0, 100.0]
    presets = np.zeros((3, 68))
    presets[0, 2], presets[1, 2], presets[2, 5] = 600.0, -30.0, 90.0
    wide, start = keeping(limits, presets)
    assert wide[2, 1] == pytest.approx(600.0 + PRESET_MARGIN * (600 - 174))
    assert wide[2, 0] == pytest.approx(-30.0 - PRESET_MARGIN * (30 - 10))
    assert wide[5, 1] == 100.0 and start[5, 1] == pytest.approx(0.9) and wide[5, 0] == -100.0
    assert start[5, 0] == EASE_START and np.isinf(wide[0]).all()          # untouched elsewhere
    for row in presets:
        assert np.array_equal(soft_limit(row, wide, start), row)
    far = np.zeros(68)
    far[2], far[5] = 5000.0, 5000.0
    eased = soft_limit(far, wide, start)
    assert 600.0 < eased[2] <= 630.0 and 90.0 < eased[5] <= 100.0


@pytest.fixture(scope="module")
def rig():
    from core.default_face import load_default_face
    from core.rig import FaceRig

    return FaceRig(load_default_face())


@pytest.mark.parametrize("number,value", [(15, 400), (15, -400), (4, -800), (35, -400), (61, -200), (39, 300),
                                          (51, -800)])
def test_slider_ends_that_folded_the_skin_no_longer_do(rig, number, value, monkeypatch):
    """On the default face these ends folded 24-460 skin triangles; eased into the FAP's clean limit
    they fold none (the raw value still does without the surface guard: the check can fail). Ends
    whose limit a preset widened (stretch_cornerlip, lift_cheek, open_jaw) are the surface guard's
    (test_surface_guard)."""
    from core.mesh_quality import FaceQualityProbe

    probe = FaceQualityProbe(rig.face)
    rig.reset()
    rig.set_fap(number, value)
    assert abs(rig.faps.limited_values()[number - 1]) < abs(value)      # eased
    assert rig.fap_value(number) == value                               # the slider keeps what was asked
    assert probe.surface(rig.vertices())[0] == 0
    without_surface_guard(monkeypatch, rig)
    raw = rig.deformer.deform(rig.effective_fap_values())
    assert probe.surface(raw)[0] > 0
    rig.reset()


@pytest.mark.parametrize("number,value", [(63, -300), (61, 200), (39, 300), (52, -800)])
def test_slider_ends_that_smeared_the_texture_no_longer_do(rig, number, value, monkeypatch):
    """On the default face these ends stretched a skin triangle's texture 2.7-5.1 times (face_quality);
    eased into the FAP's clean limit every principal stretch stays within [MIN_STRETCH, MAX_STRETCH],
    and the tooltip names the smear as the reason. (Ends a preset widened, e.g. the brows, keep the
    preset's own smear: that is the preset's to fix.)"""
    from core.mesh_quality import MAX_STRETCH, MIN_STRETCH, FaceQualityProbe

    probe = FaceQualityProbe(rig.face)
    rig.reset()
    rig.set_fap(number, value)
    folded, big, small = probe.surface(rig.vertices())
    assert folded == 0 and big <= MAX_STRETCH and small >= MIN_STRETCH
    without_surface_guard(monkeypatch, rig)      # the limit alone
    raw = rig.deformer.deform(rig.effective_fap_values())
    assert probe.surface(raw)[1] > MAX_STRETCH or probe.surface(raw)[2] < MIN_STRETCH   # the check can fail
    assert "texture would smear" in rig.deformer.limit_note(number)
    rig.reset()


def test_presets_and_the_lids_are_never_eased(rig):
    """Every expression and viseme at 100 % drives the deformation exactly as authored, and the
    lids still close all the way (1024 IRISD)."""
    for row in np.concatenate([tables.expression_table(), tables.viseme_table()]):
        assert np.array_equal(rig.deformer.limited(row), row)
        assert np.array_equal(rig.deformer.limited(row, row), row)       # as the FAP layer asks
    lids = np.zeros(68)
    lids[18:22] = 1024
    assert np.array_equal(rig.deformer.limited(lids), lids)
    assert "1024" not in (rig.deformer.limit_note(19) or "")       # only the opening end is limited
    assert rig.deformer.limit_note(15).startswith("beyond -")


def test_a_slider_alone_stops_at_its_own_limit_though_a_preset_goes_past_it(rig):
    """Where a preset goes past a FAP's limit, the preset in use passes as authored, and the slider
    alone eases into the limit, which is where the finished pose breaks the skin (the default face's
    cheek lift: 0.24x squeeze at joy's 220 IRISD, toward which the slider alone used to ease).
    Expression and viseme mixed pass too."""
    reach, clean = rig.deformer.preset_reach[:, 1], rig.deformer.clean_limits[:, 1]
    past = [n for n in rig.animated_faps if np.isfinite(clean[n - 1]) and reach[n - 1] > clean[n - 1]]
    assert 41 in past and 42 in past
    for n in past:
        rig.reset()
        rig.set_fap(n, tables.fap_spec(n).maximum)                       # the slider's end
        alone = rig.faps.limited_values()[n - 1]
        assert alone < clean[n - 1] < reach[n - 1]                      # the old ease went past reach
    rig.reset()
    rig.set_fap(41, 400)
    assert FaceQualityProbe(rig.face).surface_holds(np.array(rig.vertices()))
    table = np.concatenate([tables.expression_table(), tables.viseme_table()])
    n = past[0]
    row = table[np.argmax(table[:, n - 1])]
    rig.reset()
    assert np.array_equal(rig.deformer.limited(row, row), row)
    for expression in tables.expression_names()[1:]:
        for viseme in tables.viseme_names()[1:]:
            rig.reset()
            rig.set_expression(expression, 1.0)
            rig.set_viseme(viseme, 1.0)
            asked = rig.faps.effective_values()
            low, high = rig.deformer.preset_reach.T
            if ((asked >= low) & (asked <= high)).all():     # a mix past every preset's reach eases
                assert np.array_equal(rig.faps.limited_values(), asked), (expression, viseme)
    rig.reset()


def test_a_preset_just_inside_a_limit_does_not_widen_it():
    """keeping's margin applies only past a limit the preset passes itself: a preset at 100 of a
    101 limit leaves the limit at 101 (it went to 105, past where the surface breaks), and the end
    moves continuously as a preset's value crosses the limit."""
    limits = np.array([[-np.inf, np.inf]] * 68)
    limits[3] = (-200.0, 101.0)
    presets = np.zeros((1, 68))
    presets[0, 3] = 100.0
    wide, start = keeping(limits, presets)
    assert wide[3, 1] == 101.0 and start[3, 1] == pytest.approx(100 / 101)
    far = np.zeros(68)
    far[3] = 800
    assert 100 < soft_limit(far, wide, start)[3] <= 101
    ends = []
    for value in (100.999, 101.0, 101.001):
        presets[0, 3] = value
        wide, start = keeping(limits, presets)
        ends.append(soft_limit(far, wide, start)[3])
    assert np.ptp(ends) < 0.01


def test_an_upper_lid_opened_to_its_slider_end_no_longer_folds_through_its_crease(rig, monkeypatch):
    """close_t -300 raised the default face's upper lid under its crease and through it (14 crossing
    pairs per eye) while the surface guard held the lids' zone, and the crease check (a bisection on
    the finished pose) eased that end to where the crossings began. With the lid's skin sliding on the
    eyeball, and the lid's region reaching up to the brow, the lid opens to -300 without crossing: no
    limit, the slider's end as authored. With the region ending at the crease as it did and the lids'
    zone held again, the check finds the old limit (it can fail)."""
    import dataclasses

    from core.layers.fap.fat import FapDeformer
    from core.layers.fap.surface_guard import SurfaceGuard
    from core.mesh_quality import FaceQualityProbe

    probe = FaceQualityProbe(rig.face)
    d = rig.deformer
    for number in (19, 20):
        assert d.clean_limits[number - 1, 0] == -np.inf and "eased" not in (d.limit_note(number) or "")
        values = np.zeros(68)
        values[number - 1] = -300
        assert probe.measure(d.deform(values)).lid_intersections == 0
        rig.reset()
        rig.set_fap(number, -300)
        assert rig.fap_value(number) == -300
    rig.reset()
    template = load_template()
    up_to_the_crease = {19: [28, 57, 63, 64, 65, 87], 20: [37, 51, 78, 79, 134, 135]}
    narrow = dataclasses.replace(template, regions=tuple(
        {**r, "triangles": up_to_the_crease[r["fap"]]} if r["fap"] in up_to_the_crease else r
        for r in template.regions))
    old = FapDeformer(rig.face, template=narrow)
    guard = old._surface_guard
    monkeypatch.setattr(old, "_surface_guard", SurfaceGuard(rig.face.vertices, guard.triangles, old.lid_zone(),
                                                            guard._joined))
    for number, side in ((19, "left"), (20, "right")):
        assert -300 < old._lid_crease_limit(probe, number, side) < -200


def test_a_slider_end_can_start_its_ease_later():
    """soft_limit and keeping take the ease's start per slider end (the upper lids' opening ends
    start at 0.85 of the limit): identity up to there, then eased, the limit never reached."""
    limits = np.array([[-np.inf, np.inf]] * 68)
    limits[18] = (-250.0, np.inf)
    start = np.full((68, 2), EASE_START)
    start[18, 0] = 0.85
    v = np.zeros(68)
    v[18] = -0.85 * 250
    assert np.array_equal(soft_limit(v, limits, start), v)
    assert soft_limit(v, limits)[18] > v[18]                       # the global start eases it already
    v[18] = -400
    assert -250 < soft_limit(v, limits, start)[18] < -249
    presets = np.zeros((1, 68))
    presets[0, 18] = -220
    wide, later = keeping(limits, presets, start)
    assert wide[18, 0] == -250.0 and later[18, 0] == pytest.approx(220 / 250)  # the preset passes, toward -250


def test_linear_path_measures_like_posing_the_triangles():
    """The closed-form probe of ``clean_limits`` (quadratic in the value) gives the same folds and
    smears as posing the triangles and measuring them (``core.mesh_quality.principal_stretches``)."""
    from core.layers.fap.limits import _LinearPath, _normals
    from core.mesh_quality import MAX_STRETCH, MIN_STRETCH, _local_frames, principal_stretches

    rng = np.random.default_rng(5)
    base = rng.normal(0, 5, (400, 3, 3))
    step = rng.normal(0, 0.02, (400, 3, 3))
    path = _LinearPath(base, step, _normals(base), _local_frames(base))
    values = np.array([-300.0, -120.0, -10.0, 0.0, 40.0, 150.0, 400.0])
    folds, smears = path.folds(values), path.smears(values)
    for row, value in enumerate(values):
        posed = base + value * step
        big, small = principal_stretches(_local_frames(base), posed)
        assert np.array_equal(folds[row], np.einsum("ij,ij->i", _normals(posed), _normals(base)) < 0)
        assert np.array_equal(smears[row], (big > MAX_STRETCH) | (small < MIN_STRETCH))
    assert not folds[3].any() and not smears[3].any()                   # rest: nothing breaks
    assert folds[-1].any() and smears[-1].any() and not folds[2].all()  # the check can fail both ways
    # A known map: the whole triangle scaled by 3 at value 1 (step = 2 x base) smears, never folds.
    scaled = _LinearPath(base[:1], 2 * base[:1], _normals(base[:1]), _local_frames(base[:1]))
    assert scaled.smears([1.0])[0, 0] and not scaled.smears([0.4])[0, 0] and not scaled.folds([1.0])[0, 0]


def test_finished_limits_catch_what_a_finish_step_breaks_beyond_the_linear_field():
    """A FAP whose linear field holds to its slider's end, but whose finished pose (here a stand-in
    finish step that flips one vertex through its neighbours from 300 on) folds the skin: its end is
    limited just below 300, with the fold as reason; an end a preset takes further is left alone."""
    from core.layers.fap.limits import FOLD_REASON, finished_limits, preset_reach

    u, v = np.meshgrid(np.arange(4.0), np.arange(4.0))
    rest = np.column_stack([u.ravel(), v.ravel(), np.zeros(16)])
    quads = [(r * 4 + c, r * 4 + c + 1, r * 4 + c + 4, r * 4 + c + 5) for r in range(3) for c in range(3)]
    triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (b, d, c))])
    specs = tables.fap_specs()

    def deform(values):
        x = rest.copy()
        x[:, 2] += values[2] * 1e-3                 # open_jaw: a rigid lift, never folds
        if values[2] >= 300:
            x[5, :2] += (3.0, 3.0)                  # the "finish step": vertex 5 jumps across the grid
        return x

    limits = np.array([[-np.inf, np.inf]] * 68)
    reasons = np.full((68, 2), "", dtype=object)
    finished_limits(deform, rest, triangles, limits, reasons, specs, [3], preset_reach(np.zeros((1, 68))))
    step = 1400 / 2 ** 7
    assert 300 - step <= limits[2, 1] < 300 and reasons[2, 1] == FOLD_REASON
    assert np.isneginf(limits[2, 0]) and reasons[2, 0] == ""
    presets = np.zeros((1, 68))
    presets[0, 2] = 1400.0                          # a preset goes to the end: the preset's to fix
    untouched = np.array([[-np.inf, np.inf]] * 68)
    finished_limits(deform, rest, triangles, untouched, reasons, specs, [3], preset_reach(presets))
    assert np.isposinf(untouched[2, 1])


def test_finished_limits_stop_where_the_crossing_check_says_the_surfaces_cross():
    """Two sheets, one tilted above the other; the FAP lowers the upper sheet rigidly (never a fold
    nor a smear), and its lowest corner reaches the lower sheet at 500: with the lips' crossing
    check the slider's end stops there with the crossing as reason (the nostrils' own, for the nose
    FAPs); without it, it is not limited."""
    from core.layers.fap.limits import CROSSING_REASON, NOSTRIL_REASON, finished_limits, preset_reach
    from core.mesh_quality import count_intersections

    u, v = np.meshgrid(np.arange(4.0), np.arange(4.0))
    lower = np.column_stack([u.ravel(), v.ravel(), np.zeros(16)])
    upper = np.column_stack([u.ravel() + 0.01, v.ravel() + 0.01, 1.0 + u.ravel()])
    rest = np.vstack([lower, upper])
    quads = [(r * 4 + c, r * 4 + c + 1, r * 4 + c + 4, r * 4 + c + 5) for r in range(3) for c in range(3)]
    sheet = np.array([t for a, b, c, d in quads for t in ((a, b, c), (b, d, c))])
    triangles = np.vstack([sheet, sheet + 16])
    specs = tables.fap_specs()

    def deform(values):
        x = rest.copy()
        x[16:, 2] -= values[2] / 500.0              # open_jaw lowers the upper sheet: 1 mm per 500
        return x

    def crossing(x):
        return count_intersections(x, triangles) > 0

    no_presets = preset_reach(np.zeros((1, 68)))
    limits = np.array([[-np.inf, np.inf]] * 68)
    reasons = np.full((68, 2), "", dtype=object)
    finished_limits(deform, rest, triangles, limits, reasons, specs, [3], no_presets, crossing=crossing)
    step = 1400 / 2 ** 7
    assert 500 - step <= limits[2, 1] <= 500 and reasons[2, 1] == CROSSING_REASON
    fap3 = np.eye(68)[2]
    assert crossing(deform(fap3 * (limits[2, 1] + step))) and not crossing(deform(fap3 * limits[2, 1]))
    nose = np.array([[-np.inf, np.inf]] * 68)
    finished_limits(deform, rest, triangles, nose, reasons, specs, [3], no_presets, crossing=crossing,
                    crossing_reason=NOSTRIL_REASON)
    assert nose[2, 1] == limits[2, 1] and reasons[2, 1] == NOSTRIL_REASON
    unchecked = np.array([[-np.inf, np.inf]] * 68)
    finished_limits(deform, rest, triangles, unchecked, reasons, specs, [3], no_presets)
    assert np.isposinf(unchecked[2, 1])


def test_a_crossing_already_there_at_rest_does_not_stop_a_slider():
    """A sheet crossing another at rest (a registered scan's zigzagging closed lips) is the scan's own:
    only a pair the pose newly crosses counts. A third sheet lowered onto both crosses them only when it
    reaches them."""
    from core.layers.fap.limits import new_crossings
    from core.mesh_quality import count_intersections, welded_vertices

    u, v = np.meshgrid(np.arange(4.0), np.arange(4.0))
    flat = np.column_stack([u.ravel(), v.ravel(), np.zeros(16)])
    tilted = np.column_stack([u.ravel() + 0.01, v.ravel() + 0.01, -0.7 + 0.5 * u.ravel()])   # through `flat`
    above = np.column_stack([u.ravel() + 0.02, v.ravel() + 0.02, 5.0 + 0.1 * u.ravel()])
    rest = np.vstack([flat, tilted, above])
    quads = [(r * 4 + c, r * 4 + c + 1, r * 4 + c + 4, r * 4 + c + 5) for r in range(3) for c in range(3)]
    sheet = np.array([t for a, b, c, d in quads for t in ((a, b, c), (b, d, c))])
    triangles = np.vstack([sheet, sheet + 16, sheet + 32])
    assert count_intersections(rest, triangles) > 0

    crosses = new_crossings(rest, triangles, welded_vertices(rest), 0.05)

    def lowered(mm):
        x = rest.copy()
        x[32:, 2] -= mm
        return x

    assert not crosses(rest) and not crosses(lowered(3.0))
    assert crosses(lowered(5.15))                       # 5.15 lower it cuts the flat sheet at u = 1.5
