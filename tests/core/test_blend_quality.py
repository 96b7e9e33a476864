"""Expression-library poses that hold up (issues 16 and 18): the scans' noise smoothed out of the
poses (``core.layers.blend.denoise``), and the FAP layer's finish steps acting on the lids and the
mouth cavity whatever layer moved the skin.

Known answers: fields the smoothing must keep (constants, linear fields over a filled patch), a
filled strip nothing crosses, a lid pushed through the eyeball by a blend pose and pushed back out,
a uniform blend offset the mouth cavity's lining follows in full near the lips."""

from __future__ import annotations

import numpy as np
import pytest

from core.layers.blend.denoise import cleaned, eye_cover_vertices, smooth_displacements
from core.layers.blend.layer import BlendLayer
from core.layers.blend.library import ExpressionLibrary, LibraryError
from core.mesh_quality import FaceQualityProbe, count_intersections


def _flat_grid(nx: int = 30, ny: int = 20, step_mm: float = 2.0):
    """(vertices (nx*ny, 3) mm on the plane z = 0, triangles): a regular grid, every cell cut along
    the same diagonal (its graph Laplacian with 1/length² weights is zero on linear fields inside)."""
    x, y = np.meshgrid(np.arange(nx) * step_mm, np.arange(ny) * step_mm)
    v = np.column_stack([x.ravel(), y.ravel(), np.zeros(nx * ny)])
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
    a = (j * nx + i).ravel()
    tris = np.concatenate([np.column_stack([a, a + 1, a + nx + 1]), np.column_stack([a, a + nx + 1, a + nx])])
    return v, tris


def _library(rest, displacements) -> ExpressionLibrary:
    d = np.asarray(displacements, float).reshape(-1, len(rest), 3)
    return ExpressionLibrary(rest, tuple(f"pose_{k}" for k in range(len(d))), d)


# ------------------------------------------------------------------ smoothing the poses
def test_smoothing_keeps_a_uniform_pose_and_takes_out_noise():
    v, tris = _flat_grid()
    rng = np.random.default_rng(5)
    noise = rng.normal(0.0, 0.5, (len(v), 3))
    lib = _library(v, [np.broadcast_to([1.0, -2.0, 0.5], v.shape), noise])
    out = smooth_displacements(lib, 6.0, tris)
    np.testing.assert_allclose(out.displacements[0], lib.displacements[0], atol=1e-9)   # a rigid shift stays
    assert np.std(out.displacements[1]) < np.std(noise) / 4                               # the wobble goes
    np.testing.assert_array_equal(out.rest, lib.rest)
    assert out.names == lib.names
    assert smooth_displacements(lib, 0.0, tris) is lib
    with pytest.raises(LibraryError, match="width"):
        smooth_displacements(lib, -1.0, tris)
    with pytest.raises(LibraryError, match="triangles"):
        smooth_displacements(lib, 6.0, tris + len(v))


def test_a_filled_patch_takes_the_membrane_and_keeps_its_two_sides_apart():
    nx, ny = 30, 20
    v, tris = _flat_grid(nx, ny)
    column = np.arange(len(v)) % nx
    strip = (column >= 13) & (column <= 16)              # a band across the whole patch, like an eye cover
    left, right = column < 13, column > 16
    rng = np.random.default_rng(2)
    # one side lifted by 3 mm, the other by 1 mm, and noise in the band (a cover registered on an eyeball)
    pose = np.where(left[:, None], [0.0, 3.0, 0.0], [0.0, 1.0, 0.0]) + np.where(strip[:, None], rng.normal(0, 2.0, (len(v), 3)), 0.0)
    out = smooth_displacements(_library(v, [pose]), 8.0, tris, filled=strip).displacements[0]
    # smoothing never crosses the band: each side keeps its own uniform lift exactly
    np.testing.assert_allclose(out[left], np.broadcast_to([0.0, 3.0, 0.0], (left.sum(), 3)), atol=1e-9)
    np.testing.assert_allclose(out[right], np.broadcast_to([0.0, 1.0, 0.0], (right.sum(), 3)), atol=1e-9)
    # the band is a membrane between them: no noise left, falling from 3 to 1 mm across it
    band = out[strip].reshape(ny, 4, 3)
    assert np.abs(band[:, :, [0, 2]]).max() < 1e-9
    assert (1.0 < band[:, :, 1]).all() and (band[:, :, 1] < 3.0).all() and (np.diff(band[:, :, 1], axis=1) < 0).all()
    with pytest.raises(LibraryError, match="entries"):
        smooth_displacements(_library(v, [pose]), 8.0, tris, filled=strip[:-1])


def test_cleaned_smooths_a_template_librarys_poses_and_refuses_what_it_cannot():
    """A canonical mpeg4_80 library: a uniform pose stays exactly (away from the eye covers, whose
    membrane meets it too), noise goes, the base says so; a custom library or a bad width is refused."""
    from core.layers.blend.builtin import builtin_library

    rest = builtin_library().rest                    # the default face on the canonical mpeg4_80 mesh
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 0.5, rest.shape)
    lib = ExpressionLibrary(rest, ("lift", "wobble"), np.stack([np.broadcast_to([0.0, 2.0, 0.0], rest.shape), noise]),
                            template="mpeg4_80", base="someone")
    out = cleaned(lib, 6.0)
    np.testing.assert_allclose(out.displacements[0], lib.displacements[0], atol=1e-9)
    assert np.std(out.displacements[1]) < np.std(noise) / 4
    assert out.base == "someone; poses smoothed over 6 mm" and out.names == lib.names
    assert cleaned(lib, 0) is lib
    for width in (-1.0, float("nan"), "wide"):
        with pytest.raises(LibraryError, match="smoothing width"):
            cleaned(lib, width)
    with pytest.raises(LibraryError, match="template 'custom'"):
        cleaned(lib.replace(template="custom"), 6.0)


def test_eye_covers_are_the_rigs_eye_openings(default_rig):
    covers = eye_cover_vertices("mpeg4_80")
    np.testing.assert_array_equal(covers, default_rig.deformer._eye_opening_interior())
    assert 100 < covers.sum() < 0.2 * len(covers)


# ------------------------------------------------------------------ finish steps act on any layer
def _eye_ball_crossings(x, probe) -> int:
    return sum(count_intersections(x, probe.lid_tris[side], probe.eyeball_tris[side]) for side in ("left", "right"))


@pytest.fixture(scope="module")
def probe(default_rig):
    return FaceQualityProbe(default_rig.face)


def test_a_blend_pose_pushing_the_upper_lid_into_the_eyeball_is_pushed_back_out(default_rig, probe):
    rig = default_rig
    rig.reset()
    face = rig.face
    rest = face.vertices
    # the left upper lid's skin pushed 4 mm back (no FAP set): it would pass through the eyeball
    lid = face.landmark_position("3.1")
    weight = np.exp(-np.sum((rest - lid) ** 2, axis=1) / (2 * 3.0 ** 2))
    skin = np.ones(len(rest), bool)
    for idx in face.parts.values():
        skin[idx] = False
    push = np.where(skin[:, None], weight[:, None] * [0.0, 0.0, -4.0], 0.0)
    assert _eye_ball_crossings(rest + push, probe) > 0                  # the raw offset crosses
    try:
        rig.add_layer(BlendLayer(face, _library(rest, [push])))
        rig.set_values({"blend:pose_0": 100.0})
        posed = np.array(rig.vertices())
        assert _eye_ball_crossings(posed, probe) == 0
        free = ~rig.deformer.finish_zone()
        np.testing.assert_allclose(posed[free], (rest + push)[free], atol=1e-9)   # elsewhere the pose as given
        rig.set_values({"blend:pose_0": 0.0})
        np.testing.assert_array_equal(rig.vertices(), rest)                    # zero weight: rest exactly
    finally:
        rig.remove_layer("blend")
        rig.reset()


def test_the_mouth_cavity_follows_a_blend_pose_near_the_lips(default_rig):
    from core.layers.blend.builtin import rig_correspondence

    rig = default_rig
    rig.reset()
    deformer = rig.deformer
    canonical = np.array(deformer.dense.vertices)
    shift = np.array([0.0, -1.5, -2.0])
    lib = ExpressionLibrary(canonical, ("shift",), np.broadcast_to(shift, canonical.shape)[None], template="mpeg4_80")
    m = rig_correspondence(deformer, len(canonical))
    offset = BlendLayer(rig.face, lib, correspondence=m)
    offset.set_values({"blend:shift": 100.0})
    moved = offset.offset(rig.face.vertices)
    cavity = rig.face.parts["mouth_cavity"]
    follow = deformer.cavity_follow()
    share = np.asarray(follow[cavity].sum(axis=1)).ravel()
    # lining within CAVITY_FOLLOW_NEAR_MM of skin that is bound in full moves with it in full
    bound = np.asarray(deformer.binding.sum(axis=1)).ravel()
    near = cavity[np.abs(share - 1.0) < 1e-12]
    whole = near[np.array([np.abs(bound[follow[i].indices] - 1.0).max() < 1e-12 for i in near])]
    assert len(whole) > 50
    np.testing.assert_allclose(moved[whole], np.broadcast_to(shift, (len(whole), 3)), atol=1e-9)
    still = cavity[share == 0]
    assert len(still) and np.abs(moved[still]).max() == 0.0                    # the back of the mouth stays


# ------------------------------------------------------------------ the built-in library at 100 %
@pytest.mark.parametrize("pose", ["sadness", "viseme_1", "viseme_8"])
def test_built_in_poses_hold_up_on_the_default_face(default_rig, probe, pose):
    rig = default_rig
    rig.reset()
    try:
        rig.ensure_layers([f"blend:{pose}"])
        rig.set_values({f"blend:{pose}": 100.0})
        q = probe.measure(np.array(rig.vertices()))
        assert (q.lip_intersections, q.lid_intersections, q.cavity_intersections, q.teeth_intersections) == (0, 0, 0, 0)
        assert q.folded_triangles == 0 and q.max_stretch < 2.0, q.failures()
        rig.set_values({f"blend:{pose}": 0.0})
        np.testing.assert_array_equal(rig.vertices(), rig.face.vertices)
    finally:
        rig.remove_layer("blend")
        rig.reset()


def test_built_in_expressions_follow_the_presets_they_were_scanned_from(default_rig):
    """The built-in library is the default face's FAP presets scanned, landmarked (detected points
    more than builtin.LANDMARK_TOLERANCE_MM off corrected, as in the picker), registered and smoothed:
    each expression's displacement of the canonical vertices stays close to the preset's own there
    (rms outside the inner lips, whose scanned contour the scanner does not see). With detected points
    kept up to 3 mm off, the six expressions averaged 1.0 mm, joy's mouth corners moved 4.2 of 7.1 mm."""
    from core.face import Face
    from core.layers.blend.builtin import builtin_library
    from core.registration.correspondence import bind_scan, canonical_triangles
    from core.registration.scan_mouth import lip_labels

    lib = builtin_library()
    triangles = canonical_triangles(lib.template)
    rig = default_rig
    face = rig.face
    on_face = bind_scan(Face(lib.rest, triangles), face).matrix
    outside_lips = lip_labels(triangles, lib.template, 3) == 0
    errors = []
    try:
        for name in ("joy", "sadness", "anger", "fear", "disgust", "surprise"):
            rig.reset()
            rig.set_expression(name, 1.0)
            preset = on_face @ (np.array(rig.vertices()) - face.vertices)
            difference = (lib.displacements[lib.names.index(name)] - preset)[outside_lips]
            errors.append(float(np.sqrt((difference ** 2).sum(axis=1).mean())))
    finally:
        rig.reset()
    assert np.mean(errors) < 0.85, dict(zip(("joy", "sadness", "anger", "fear", "disgust", "surprise"), errors))
