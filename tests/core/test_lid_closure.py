"""Each lid closed alone at its slider's end: the eye shuts, the surface holds.

Known answers: the lid columns fitted to a made-up eye opening reach the other rim exactly; the
lower lid's handover keeps the closing sum and is the identity below its start; on the default face
and the generated identity every lid FAP at 1024 IRISD closes its eye with no fold, crossing or smear
(before: stretch 2.9-3.2x and 4-7 folds per lid).
"""

import numpy as np
import pytest
import scipy.sparse

from core.layers.fap import fat
from core.layers.fap.fat import (LID_FIT_OVERLAP_MM, LOWER_LID_HANDOVER, LOWER_LID_REACH, N_FAPS, fit_lids_to_rims,
                                 lower_lid_handover)
from core.mesh_quality import MAX_STRETCH, MIN_STRETCH, FaceQualityProbe


def _eye_opening(n=41, width=28.0, height=11.0):
    """(vertices (2n, 3), upper rim (n,), lower rim (n,)): an almond-shaped opening, rims ordered by x."""
    x = np.linspace(0.0, width, n)
    arch = np.sin(np.pi * x / width)
    upper = np.stack([x, 0.55 * height * arch, np.zeros(n)], axis=1)
    lower = np.stack([x, -0.45 * height * arch ** 1.3, np.zeros(n)], axis=1)
    return np.concatenate([upper, lower]), np.arange(n), np.arange(n, 2 * n)


def test_lid_columns_are_fitted_to_reach_the_other_rim_all_along_the_eye():
    vertices, upper, lower = _eye_opening()
    n = len(vertices)
    fapu = np.zeros(N_FAPS)
    fapu[18] = fapu[20] = 11.0 / 1024            # IRISD: the opening at its centre
    # Template-like columns that overshoot toward the corners (as the default face's did by 10-20 %).
    x = vertices[:, 0]
    wrong = 1.0 + 0.2 * ((x - 14.0) / 14.0) ** 2
    opening = vertices[upper, 1] - vertices[lower, 1]
    column = np.zeros((3 * n, N_FAPS))
    column[3 * upper + 1, 18] = -opening * wrong[upper] / 11.0           # close_t: down
    column[3 * lower + 1, 20] = opening * wrong[lower] / 11.0            # close_b: up
    fitted = fit_lids_to_rims(scipy.sparse.csr_matrix(column), vertices, [(upper, lower)], fapu).toarray()
    for number, own, other in ((19, upper, lower), (21, lower, upper)):
        travel = fitted[3 * own + 1, number - 1] * fapu[number - 1] * 1024
        wanted = vertices[other, 1] - vertices[own, 1]
        inner = np.abs(wanted) > 2.0                  # the fit reads the rim where the lids travel > 1 mm
        assert np.abs(travel - wanted - np.sign(wanted) * LID_FIT_OVERLAP_MM)[inner].max() < 0.05
        before = column[3 * own + 1, number - 1] * fapu[number - 1] * 1024
        assert np.abs(before - wanted)[inner].max() > 0.4                # the check can fail
    # An eye closed at rest (skip) keeps its columns; other FAPs are untouched.
    kept = fit_lids_to_rims(scipy.sparse.csr_matrix(column), vertices, [(upper, lower)], fapu,
                            skip=frozenset({19, 21})).toarray()
    assert np.array_equal(kept, column)


def test_the_lower_lid_hands_what_it_cannot_reach_to_the_upper_lid():
    values = np.zeros(N_FAPS)
    values[20], values[21] = 200.0, 1024.0           # left lower lid within reach, right at its end
    out = lower_lid_handover(values.copy())
    assert out[20] == 200.0 and out[18] == 0.0       # below the handover: as authored
    assert LOWER_LID_HANDOVER < out[21] <= LOWER_LID_REACH
    assert out[19] + out[21] == pytest.approx(1024.0)   # the eye still closes: the sum is kept
    # Continuous and smooth through the start of the handover (C1).
    step = 1e-3
    eased = [lower_lid_handover(np.eye(N_FAPS)[21] * (LOWER_LID_HANDOVER + d))[21] for d in (-step, 0.0, step)]
    assert (eased[2] - eased[0]) / (2 * step) == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("rig_name", ["default_rig", "generated_rig"])
def test_each_lid_closed_alone_shuts_its_eye_and_the_surface_holds(rig_name, request):
    rig = request.getfixturevalue(rig_name)
    probe = FaceQualityProbe(rig.face)
    try:
        for number, side in ((19, "left"), (20, "right"), (21, "left"), (22, "right")):
            rig.reset()
            rig.set_fap(number, 1024)
            q = probe.measure(rig.vertices(), eyes=True)
            assert q.eye_openness[side] == 0.0, (number, q)
            assert q.folded_triangles == 0 and q.lid_intersections == 0, (number, q)
            assert q.max_stretch <= MAX_STRETCH and q.min_stretch >= MIN_STRETCH, (number, q)
        # Both lids of both eyes: the lids meet (lid contact), nothing crosses.
        rig.reset()
        rig.set_faps({19: 1024, 20: 1024, 21: 1024, 22: 1024})
        q = probe.measure(rig.vertices(), eyes=True)
        assert q.eye_openness == {"left": 0.0, "right": 0.0} and q.lid_intersections == 0 and q.folded_triangles == 0
        rig.reset()
        assert min(probe.eye_openness(rig.vertices()).values()) > 0.5      # open at rest: the check can fail
    finally:
        rig.reset()


def test_the_lower_lids_tooltip_says_where_the_upper_lid_takes_over(default_rig):
    note = default_rig.deformer.limit_note(21)
    assert f"at most {LOWER_LID_REACH:.0f}" in note and "upper lid" in note
    assert "upper lid comes down" not in (default_rig.deformer.limit_note(19) or "")


def test_a_closed_lid_rests_in_front_of_the_other_at_its_rim(default_rig):
    """Where the rims touch, the upper rim is brought in front of the lower one, typically by
    LID_TUCK_MM (touching at one depth, the two rims' rows crossed where their vertices interleave)."""
    rig = default_rig
    try:
        rig.reset()
        rig.set_fap(21, 1024)                         # the lower lid closed: the lids meet mid-way
        v = rig.vertices()
        upper, lower = rig.deformer._eye_rims[0]
        order = np.argsort(v[lower, 0])
        y_lower = np.interp(v[upper, 0], v[lower, 0][order], v[lower, 1][order])
        z_lower = np.interp(v[upper, 0], v[lower, 0][order], v[lower, 2][order])
        touching = np.abs(v[upper, 1] - y_lower) < 0.05
        assert touching.sum() > 10
        in_front = (v[upper, 2] - z_lower)[touching]
        assert in_front.min() >= 0.0 and np.median(in_front) >= 0.9 * fat.LID_TUCK_MM
    finally:
        rig.reset()
