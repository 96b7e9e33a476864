"""RBF control points (thesis B §4.1.1): the kernels equal scipy's RBFInterpolator, the layer reproduces its
control points exactly, influence regions keep a point out of the regions it does not list, settings are
validated, and the FACS emotion presets are what their tables say."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from core import parameters as P
from core.layers.rbf.kernels import Kernel, RbfSystem
from core.layers.rbf.layer import ControlPointDeformer, ControlPointLayer
from core.layers.rbf.regions import influence


@pytest.fixture(scope="module")
def face():
    from core.default_face import load_default_face

    return load_default_face()


@pytest.fixture(scope="module")
def layer(face):
    return ControlPointLayer(face)


@pytest.fixture(autouse=True)
def _reset(request):
    yield
    if "layer" in request.fixturenames:
        lay = request.getfixturevalue("layer")
        lay.set_kernel(Kernel())
        lay.set_values({k: 0.0 for k in lay.parameters()})


def _scipy(centres, values, points, kernel: Kernel) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # scipy warns when a kernel is used without its minimum polynomial
        return RBFInterpolator(centres, values, **kernel.scipy_arguments())(points)


KERNELS = [Kernel("multiquadric", delta=400), Kernel("multiquadric", delta=100, polynomial=False),
           Kernel("inverse_multiquadric", delta=900), Kernel("inverse_multiquadric", delta=900, smoothing=1e-3),
           Kernel("gaussian", sigma=900), Kernel("gaussian", sigma=400, smoothing=1e-2, polynomial=False),
           Kernel("thin_plate_spline"), Kernel("linear"), Kernel("linear", polynomial=False)]


@pytest.mark.parametrize("kernel", KERNELS, ids=lambda k: f"{k.name}-{k.polynomial}-{k.smoothing:g}")
def test_the_system_equals_scipy_rbfinterpolator(kernel):
    rng = np.random.default_rng(1)
    centres, values = rng.uniform(-60, 60, (80, 3)), rng.normal(0, 4, (80, 3))
    points = rng.uniform(-70, 70, (2000, 3))
    system = RbfSystem(centres, kernel)
    ref = _scipy(centres, values, points, kernel)
    scale = np.abs(ref).max()
    assert np.abs(system.evaluate(points, values) - ref).max() < 1e-8 * scale
    assert np.abs(system.response(points) @ values - ref).max() < 1e-8 * scale
    if kernel.smoothing == 0:   # exact interpolation of the control points
        assert np.abs(system.evaluate(centres, values) - values).max() < 1e-9 * scale


def test_a_general_multiquadric_exponent_solves_the_thesis_system():
    """μ = 0.75 (no scipy equivalent): the coefficients satisfy B eqs. 4.5-4.6 directly."""
    rng = np.random.default_rng(2)
    centres, values = rng.uniform(-50, 50, (20, 3)), rng.normal(0, 3, (20, 3))
    kernel = Kernel("multiquadric", delta=200, mu=0.75)
    w = RbfSystem(centres, kernel).coefficients(values)
    d2 = ((centres[:, None] - centres[None]) ** 2).sum(-1)
    g = (d2 + 200) ** 0.75
    a = w[:20]
    np.testing.assert_allclose(g @ a + w[20] + ((centres - centres.mean(0)) / (np.ptp(centres, 0).max() / 2)) @ w[21:],
                               values, atol=1e-9)
    np.testing.assert_allclose(a.sum(0), 0, atol=1e-9)                    # compatibility (4.6)
    np.testing.assert_allclose(centres.T @ a, 0, atol=1e-7)


def test_without_regions_the_face_deforms_exactly_like_scipy(face):
    deformer = ControlPointDeformer(face, regions=False)
    rng = np.random.default_rng(3)
    d = rng.normal(0, 3, (len(deformer.points), 3))
    for kernel in (Kernel("multiquadric", delta=400), Kernel("gaussian", sigma=600)):
        ours = deformer.displacement(d, kernel)
        ref = _scipy(deformer.centres, d, face.vertices, kernel)
        assert np.abs(ours - ref).max() < 1e-8 * np.abs(ref).max()


@pytest.mark.parametrize("kernel", [Kernel(), Kernel("gaussian", sigma=300), Kernel("thin_plate_spline"),
                                    Kernel("inverse_multiquadric", delta=200), Kernel("linear")],
                         ids=lambda k: k.name)
def test_the_layer_moves_every_control_point_exactly(layer, kernel):
    layer.set_kernel(kernel)
    rng = np.random.default_rng(4)
    d = rng.uniform(-8, 8, (len(layer.points), 3))
    layer.set_displacements(d)
    offset = layer.offset(None)
    assert np.abs(offset[layer.points.vertices] - d).max() < 1e-9


def test_an_upper_lip_point_never_moves_the_lower_lip_even_where_it_is_closer(face, layer):
    from core.layers.fap.template import mouth_side
    from core.layers.rbf.regions import skin_vertices

    layer.set_values({"cp:8.1:y": 4.0})     # lip_upper_mid up 4 mm
    moved = np.linalg.norm(layer.offset(None), axis=1)
    skin = skin_vertices(face)
    side = mouth_side(face, skin)
    lower, upper = skin[side == -1], skin[side == 1]
    assert moved[lower].max() == 0.0 and moved[upper].max() > 1.0
    # The lower lip's middle is closer to 8.1 than upper-lip vertices that do move.
    centre = face.vertices[layer.points.vertices[layer.points.names.index("lip_upper_mid")]]
    lip_lower_mid = face.vertices[layer.points.vertices[layer.points.names.index("lip_lower_mid")]]
    far_upper = upper[(moved[upper] > 0.1) & (np.linalg.norm(face.vertices[upper] - centre, axis=1)
                                              > np.linalg.norm(lip_lower_mid - centre) + 2)]
    assert len(far_upper) > 50
    # Generally: a point moves no vertex outside its influence (Ω = 0), and a vertex fully inside moves
    # exactly as the plain RBF of all points (the others held) says.
    c = layer.points.names.index("lip_upper_mid")
    omega_full = np.zeros(face.n_vertices)
    omega_full[layer.deformer.active] = layer.deformer.omega[:, c]
    assert moved[omega_full == 0].max() == 0.0
    d = np.zeros((len(layer.points), 3))
    d[c, 1] = 4.0
    inside = np.nonzero(omega_full == 1.0)[0]
    ref = _scipy(layer.deformer.centres, d, face.vertices[inside], layer.kernel)
    np.testing.assert_allclose(layer.offset(None)[inside], ref, atol=1e-8 * 4)


def test_influence_is_one_at_each_point_and_zero_in_regions_it_does_not_list(face, layer):
    active, omega = layer.deformer.active, layer.deformer.omega
    row = {v: i for i, v in enumerate(active.tolist())}
    for c, v in enumerate(layer.points.vertices.tolist()):
        assert omega[row[v], c] == 1.0
    assert omega.min() >= 0 and omega.max() <= 1
    a2, o2 = influence(face, layer.points)
    assert np.array_equal(a2, active) and np.array_equal(o2, omega)   # deterministic
    # the eyeballs and teeth never move
    parts = np.concatenate(list(face.parts.values()))
    assert not np.isin(parts, active).any()


def test_kernels_are_cached_and_bad_settings_change_nothing(layer):
    first = layer.deformer.matrix(layer.kernel)
    layer.set_kernel(Kernel("gaussian", sigma=500))
    layer.set_kernel(Kernel())
    assert layer.deformer.matrix(layer.kernel) is first                # factorised once per kernel
    for bad, match in ((dict(name="cubic"), "unknown RBF kernel"), (dict(delta=-1.0), "δ > 0"),
                       (dict(name="gaussian", sigma=0.0), "σ > 0"), (dict(smoothing=-1.0), "λ must be ≥ 0"),
                       (dict(mu=-0.5), "μ > 0"), (dict(name="thin_plate_spline", polynomial=False), "polynomial")):
        with pytest.raises(P.ParameterError, match=match):
            Kernel(**bad)
    with pytest.raises(P.ParameterError, match="singular"):      # a Gaussian far wider than the face
        layer.set_kernel(Kernel("gaussian", sigma=1e9))
    assert layer.kernel == Kernel()


def test_snapshot_restores_values_and_kernel(layer):
    layer.set_values({"cp:8.3:y": 3.0})
    snap = layer.snapshot()
    layer.set_kernel(Kernel("gaussian", sigma=500))
    layer.set_values({"cp:8.3:y": -2.0, "cp:4.1:y": 1.0})
    layer.restore(snap)
    assert layer.kernel == Kernel() and layer.value("cp:8.3:y") == 3.0 and layer.value("cp:4.1:y") == 0.0


def test_keys_name_feature_points_and_mirror_y_and_z_only():
    assert P.key_of("cp:mouth_corner_l:Y") == "cp:8.3:y"
    assert P.describe("cp:8.3:y").mirror == "cp:8.4:y" and P.describe("cp:8.3:x").mirror is None
    assert P.describe("cp:8.3:z").unit == "mm"
    for bad in ("cp:8.3", "cp:99.1:y", "cp:8.3:w"):
        with pytest.raises(P.ParameterError):
            P.key_of(bad)


def test_emotion_presets_are_their_action_units(layer):
    from core.layers.rbf.emotions import EMOTIONS, build_emotion, preset

    for name in EMOTIONS:
        shipped, built = preset(name), build_emotion(name)
        assert shipped.aus == built.aus and shipped.names == built.names
        np.testing.assert_allclose(shipped.displacements, built.displacements, rtol=0, atol=1e-12)
    # B Table 3.3 (joy also parts the lips: AU 25)
    assert preset("joy").aus == (1, 6, 12, 14, 25) and preset("sadness").aus == (1, 4, 15, 23)
    layer.apply_emotion("joy")
    # Intensities of resources/facs/emotions.csv: AU 12 in full (corner out 4, up 5, back 1) + AU 14 at
    # 0.6 (out 1.5, back 2): the left corner moves (4.9, 5, -2.2); AU 25 in full lowers the lower lip's
    # middle 3 mm
    assert [layer.value(f"cp:8.3:{a}") for a in "xyz"] == pytest.approx([4.9, 5.0, -2.2])
    assert layer.value("cp:8.2:y") == pytest.approx(-3.0)
    # AU 15 in full (out 0.5, down 4) + AU 23 at 0.5 (in 1), the whole at 50 %: (0, -2, 0)
    layer.apply_emotion("sadness", 0.5)
    assert [layer.value(f"cp:8.3:{a}") for a in "xyz"] == pytest.approx([0.0, -2.0, 0.0])
    with pytest.raises(P.ParameterError, match="unknown emotion"):
        layer.apply_emotion("boredom")
    with pytest.raises(P.ParameterError, match="0 to 1"):
        layer.apply_emotion("joy", 2)


def test_the_rig_builds_the_layer_on_demand_and_composes_it(default_rig):
    rig = default_rig
    try:
        assert "control_points" in rig.ensure_layers(["cp:8.3:y"])
        rig.set_values({"fap:3": 300.0})
        before = rig.vertices().copy()
        rig.set_values({"cp:8.3:y": 4.0})
        layer = rig.layer("control_points")
        free = ~rig.deformer.finish_zone()        # lips pressed together, lids over the eyeballs give way
        np.testing.assert_allclose((rig.vertices() - before)[free], layer.offset(None)[free], atol=1e-9)
    finally:
        rig.remove_layer("control_points")
        rig.reset()


def test_incremental_drags_equal_the_full_product(layer):
    from core.layers.rbf.layer import Pose

    pose = Pose(layer.deformer, layer.kernel)
    rng = np.random.default_rng(5)
    d = np.zeros((len(layer.points), 3))
    for step in range(150):     # single-point drags, a few many-point changes, past the refresh count
        if step % 37 == 0:
            d = rng.uniform(-5, 5, d.shape)
        else:
            d[rng.integers(len(d)), rng.integers(3)] = rng.uniform(-5, 5)
        np.testing.assert_allclose(pose(d), layer.deformer.displacement(d, layer.kernel), atol=1e-10)
