"""Presets eased jointly until their pose holds up (core.layers.fap.preset_easing, issue 18)."""

from __future__ import annotations

import numpy as np
import pytest

from core.layers.fap import tables
from core.layers.fap.preset_easing import STEP, PresetEasing, ease_preset

# A strip of 4 triangles along x: vertices 0..5, (0,1,2) (1,3,2) (2,3,4) (3,5,4).
REST = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0], [1, 2, 0]], float)
TRIS = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4]])


def fields_of(table: dict[int, np.ndarray]):
    return lambda i: table.get(i, np.zeros_like(REST))


def folded(vertices, moved):
    """Vertices of triangles whose normal turned over (the strip's normal is +z)."""
    c = vertices[TRIS]
    turned = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])[:, 2] < 0
    out = np.zeros(len(vertices), bool)
    out[TRIS[turned]] = True
    return out


def test_only_the_fap_that_folds_the_skin_is_eased_until_the_fold_is_gone():
    # FAP index 3 pushes vertex 4 down by 1 per unit: triangle (2,3,4) turns over past 1.0 unit.
    # FAP index 7 moves the whole strip sideways: no strain, never blamed.
    fold = np.zeros_like(REST)
    fold[4, 1] = -1.0
    fields = fields_of({3: fold, 7: np.tile([1.0, 0, 0], (6, 1))})
    values = np.zeros(68)
    values[3], values[7] = 1.6, 5.0

    def pose(v):
        return REST + fields(3) * v[3] + fields(7) * v[7]

    easing = ease_preset(values, pose, REST, TRIS, fields, folded)
    assert easing.holds
    # Eased in steps of STEP just below the fold at 1.0 unit: 1.6 * 0.85^3 = 0.98.
    assert easing.eased[3] == pytest.approx(1.6 * STEP ** 3)
    assert easing.eased[7] == 5.0
    assert [n for n, _, _ in easing.eased_faps()] == [4]
    assert easing.note() == "Eased so the skin holds up on this face: lower_t_midlip 1.6 -> 1 (61 %)"
    assert not folded(pose(easing.eased), None).any()


def test_a_preset_that_holds_up_is_not_eased_and_has_no_note():
    fields = fields_of({3: np.tile([0, 0, 1.0], (6, 1))})
    values = np.zeros(68)
    values[3] = 2.0
    easing = ease_preset(values, lambda v: REST + fields(3) * v[3], REST, TRIS, fields, folded)
    assert easing.holds and easing.rounds == 1
    np.testing.assert_array_equal(easing.eased, values)
    assert easing.note() is None


def test_a_seam_broken_at_any_value_is_reported_but_does_not_mute_the_preset():
    fields = fields_of({3: np.tile([0, 0, 1.0], (6, 1))})
    values = np.zeros(68)
    values[3] = 2.0

    def always_broken(vertices, moved):
        out = np.zeros(len(vertices), bool)
        out[5] = True
        return out

    easing = ease_preset(values, lambda v: REST + fields(3) * v[3], REST, TRIS, fields, always_broken)
    assert not easing.holds
    np.testing.assert_array_equal(easing.eased, values)


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


@pytest.mark.parametrize("viseme", ["CH", "ih"])
def test_visemes_that_folded_the_default_face_hold_up_eased_and_say_so(default_rig, viseme):
    """Viseme CH folded 61 skin triangles at 100 % and ih 30 (stretch 3.6) before easing."""
    from core.mesh_quality import FaceQualityProbe

    rig = default_rig
    rig.reset()
    rig.set_viseme(viseme, 1.0)
    quality = FaceQualityProbe(rig.face).measure(rig.vertices())
    assert quality.failures() == []
    easing = rig.deformer.preset_easing("viseme", tables.viseme_id(viseme))
    assert easing.holds and easing.note().startswith("Eased so the skin holds up on this face: ")
    assert easing.note() in rig.faps.preset_notes().values()
    # Eased, not muted: the mouth still opens at least half of what the table asks.
    assert easing.eased[2] >= 0.5 * easing.authored[2] > 0
    # What the user asked for is kept as asked (the presets' values, the project's state).
    np.testing.assert_allclose(rig.preset_values(), easing.authored)
    rig.reset()


def test_preset_easing_is_computed_once_and_cached_on_disk(default_rig, tmp_path):
    import copy

    from core.cache import DiskCache

    def fresh(deformer):
        twin = copy.copy(deformer)    # pickled state: without the face, given back as for_face does
        twin.face, twin._rest = deformer.face, deformer._rest
        twin._easings = {}
        return twin

    deformer = fresh(default_rig.deformer)
    deformer._easing_store = (DiskCache(tmp_path), "a-face-key")
    ss = tables.viseme_id("SS")
    first = deformer.preset_easing("viseme", ss)
    assert deformer.preset_easing("viseme", ss) is first          # kept in memory
    assert list((tmp_path / "fap-preset").glob("*.pkl"))
    # Another process with the same face: read back from the disk, never recomputed.
    again = fresh(deformer)
    again._easing_store = deformer._easing_store
    again._ease = None
    np.testing.assert_array_equal(again.preset_easing("viseme", ss).eased, first.eased)
