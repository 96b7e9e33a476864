"""Waters vector muscles (thesis B eqs. 4.16-4.19): known answers of one muscle's field, the 18-muscle layer
on the default face, the combine rules, composition with the other layers, and the inverse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core import parameters as P
from core.layers.waters.inverse import reach, solve_strengths
from core.layers.waters.layer import WatersLayer
from core.layers.waters.model import WatersModel, WatersMuscle, muscle_field


@pytest.fixture(scope="module")
def face():
    from core.default_face import load_default_face

    return load_default_face()


@pytest.fixture(scope="module")
def model(face):
    return WatersModel(face)


@pytest.fixture
def layer(face, model):
    return WatersLayer(face, model=model)


def _muscle(**kw) -> WatersMuscle:
    base = dict(name="m", side="left", label="m", attachment=np.zeros(3), insertion=np.array([10.0, 0, 0]),
                alpha_deg=30.0, start=0.5, end=1.5, contraction=0.2, group="g")
    base.update(kw)
    return WatersMuscle(**base)


def test_one_muscle_known_answers():
    m = _muscle()
    beta = math.radians(20)
    pts = np.array([[10.0, 0, 0],                                   # the insertion
                    [3.0, 0, 0],                                    # inside S: δ = δA = 1
                    [8 * math.cos(beta), 8 * math.sin(beta), 0],    # β = 20°, beyond S
                    [10 * math.cos(math.radians(40)), 10 * math.sin(math.radians(40)), 0],   # β > α: outside
                    [16.0, 0, 0],                                   # beyond E·|AI| = 15: outside
                    [-5.0, 0, 0]])                                  # behind the attachment
    idx, disp = muscle_field(pts, m)
    assert idx.tolist() == [0, 1, 2]
    # insertion: δ = δA·δR = 1 · cos((10 − 5)/(15 − 5) · π/2); δV = −C·δ·AV, toward A
    np.testing.assert_allclose(disp[0], [-0.2 * math.cos(math.pi / 4) * 10, 0, 0], atol=1e-12)
    np.testing.assert_allclose(disp[1], [-0.2 * 3, 0, 0], atol=1e-12)
    da = (math.cos(beta) - math.cos(math.radians(30))) / (1 - math.cos(math.radians(30)))
    dr = math.cos((8 - 5) / 10 * math.pi / 2)
    np.testing.assert_allclose(disp[2], -0.2 * da * dr * pts[2], atol=1e-12)


def test_zero_strength_is_the_identity(layer, model, face):
    assert layer.offset(None) is None
    assert not model.displacement(np.zeros(len(model.keys))).any()
    assert len(model.keys) == 18 and len({k.rsplit(":", 1)[0] for k in model.keys}) == 9


def test_a_muscle_pulls_its_insertion_toward_its_attachment_and_nothing_outside_its_zone(layer, model, face):
    j = model.keys.index("waters:zygomatic_major:left")
    m = model.muscles[j]
    layer.set_values({m.key: 1.0})
    u = layer.offset(None)
    from core.layers.rbf.regions import skin_vertices

    skin = skin_vertices(face)
    v = skin[np.argmin(np.linalg.norm(face.vertices[skin] - m.insertion, axis=1))]
    toward = m.attachment - face.vertices[v]
    assert np.dot(u[v], toward) / (np.linalg.norm(u[v]) * np.linalg.norm(toward)) > 0.999
    assert np.linalg.norm(u[v]) > 2.0
    # outside the zone (angle or distance) nothing moves; the right half of the face stays put
    av = face.vertices - m.attachment
    ai = m.insertion - m.attachment
    cos_b = av @ ai / (np.linalg.norm(av, axis=1) * np.linalg.norm(ai))
    outside = (cos_b < math.cos(math.radians(m.alpha_deg))) | (np.linalg.norm(av, axis=1) > m.end * np.linalg.norm(ai))
    assert np.abs(u[outside]).max() == 0.0 and outside.sum() > 40_000
    assert np.abs(u[face.vertices[:, 0] < -15]).max() == 0.0   # (its cone reaches just past the midline)
    # linear in the strength
    layer.set_combine("sum")
    layer.set_values({m.key: 0.5})
    np.testing.assert_allclose(layer.offset(None), u / 2, atol=1e-12)


def test_strongest_of_group_keeps_only_the_strongest(layer, model):
    layer.set_combine("strongest")
    layer.set_values({"waters:frontalis_inner:left": 0.3, "waters:frontalis_major:left": 0.7,
                      "waters:zygomatic_major:left": 0.2})
    strongest = layer.offset(None)
    alone = np.zeros(len(model.keys))
    alone[model.keys.index("waters:frontalis_major:left")] = 0.7
    alone[model.keys.index("waters:zygomatic_major:left")] = 0.2     # another group: kept
    np.testing.assert_allclose(strongest, model.displacement(alone, "sum"), atol=1e-12)
    layer.set_combine("sum")
    assert np.abs(layer.offset(None) - strongest).max() > 0.1


def test_the_limit_caps_each_vertex_and_leaves_smaller_ones(layer, model):
    layer.set_values({k: 1.0 for k in model.keys})
    layer.set_combine("sum")
    free = layer.offset(None)
    layer.set_combine("limit", 2.0)
    capped = layer.offset(None)
    n_free, n_cap = np.linalg.norm(free, axis=1), np.linalg.norm(capped, axis=1)
    assert n_free.max() > 4 and n_cap.max() <= 2.0 + 1e-9
    small = n_free <= 2.0
    np.testing.assert_array_equal(capped[small], free[small])
    big = n_free > 2.0
    np.testing.assert_allclose(n_cap[big], 2.0)
    cos = np.einsum("ij,ij->i", capped[big], free[big]) / (n_cap[big] * n_free[big])
    assert cos.min() > 1 - 1e-12     # shortened along its own direction
    with pytest.raises(P.ParameterError, match="combine by"):
        layer.set_combine("max")
    with pytest.raises(P.ParameterError, match="mm > 0"):
        layer.set_combine("limit", -1.0)
    with pytest.raises(P.ParameterError, match="outside its range"):
        layer.set_values({"waters:zygomatic_major:left": 1.5})


def test_bad_muscles_are_refused_with_a_reason():
    with pytest.raises(P.ParameterError, match="zone angle"):
        _muscle(alpha_deg=0)
    with pytest.raises(P.ParameterError, match="S < E"):
        _muscle(start=1.2, end=1.0)
    with pytest.raises(P.ParameterError, match="coincide"):
        _muscle(insertion=np.zeros(3))
    with pytest.raises(P.ParameterError, match="unknown Waters muscle"):
        P.key_of("waters:risorius:left")


def test_the_inverse_reaches_a_target_made_by_known_strengths(face, model):
    known = np.zeros(len(model.keys))
    for key, s in (("waters:zygomatic_major:left", 0.45), ("waters:inner_labii_nasi:left", 0.3),
                   ("waters:angular_depressor:left", 0.2)):
        known[model.keys.index(key)] = s
    u = model.displacement(known, "sum")
    m = model.muscles[model.keys.index("waters:zygomatic_major:left")]
    v = int(np.argmin(np.linalg.norm(face.vertices - m.insertion, axis=1) + 1e9 * (np.abs(u).sum(1) == 0)))
    s = solve_strengths(model.vertex_response([v]), u[v], np.zeros(len(model.keys)))
    reached = model.displacement(s, "sum")[v]
    assert np.linalg.norm(reached - u[v]) < 0.1
    assert s.min() >= 0 and s.max() <= 1
    # several points at once: three vertices moved by the same known strengths
    vs = np.nonzero(np.linalg.norm(u, axis=1) > 1.0)[0][::400][:3]
    s = solve_strengths(model.vertex_response(vs), u[vs].ravel(), np.zeros(len(model.keys)))
    assert np.linalg.norm(model.displacement(s, "sum")[vs] - u[vs], axis=1).max() < 0.1


def test_the_inverse_on_a_rig_with_other_layers(default_rig, model):
    rig = default_rig
    try:
        rig.add_layer(WatersLayer(rig.face, model=model, combine="sum"))
        rig.set_values({"fap:3": 200.0})
        layer = rig.layer("waters")
        known = {"waters:zygomatic_major:right": 0.5, "waters:labii_nasi:right": 0.4}
        rig.set_values(known)
        target_pose = rig.vertices().copy()
        m = model.muscles[model.keys.index("waters:zygomatic_major:right")]
        moved = np.linalg.norm(layer.offset(None), axis=1)
        v = int(np.argmin(np.linalg.norm(rig.face.vertices - m.insertion, axis=1) + 1e9 * (moved == 0)))
        rig.set_values({k: 0.0 for k in known})
        reach(rig, layer, [v], target_pose[[v]])
        assert np.linalg.norm(rig.vertices()[v] - target_pose[v]) < 0.1
    finally:
        rig.remove_layer("waters")
        rig.reset()
