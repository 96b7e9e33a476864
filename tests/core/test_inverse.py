"""The inverse on SABiom's simulated muscles (``core.inverse``): a linear response measured on a copy of the
layer, bounded least squares, and secant refinement rounds that reach a target the real simulation made
from known forces within 0.1 mm."""

from __future__ import annotations

import numpy as np
import pytest

from core import parameters as P
from core.inverse import LinearResponse, reach, solve_activations


@pytest.fixture(scope="module")
def muscles():
    from core.default_face import load_default_face
    from core.layers.muscles.layer import MuscleLayer

    face = load_default_face()
    layer = MuscleLayer(face)
    return face, layer, LinearResponse.measured(layer)


class _Rig:
    """The two calls ``reach`` makes of a rig, on the muscle layer alone."""

    def __init__(self, face, layer):
        self.face, self.layer = face, layer

    def vertices(self):
        off = self.layer.offset(None)
        return self.face.vertices + (0.0 if off is None else off)

    def set_values(self, values):
        self.layer.set_values(values)


def test_measuring_the_response_leaves_the_layer_alone(muscles):
    face, layer, response = muscles
    assert response.keys == layer.parameters() and response.matrix.shape == (3 * face.n_vertices, 20)
    assert all(layer.value(k) == 0.0 for k in layer.parameters())
    assert response.lower.min() == 0.0
    j = response.keys.index("muscle:zygomatic_major:left")
    col = response.matrix[:, j].reshape(-1, 3)
    assert np.abs(col[face.vertices[:, 0] < -20]).max() < 0.02 * np.abs(col).max()   # a left muscle: left side


def test_the_inverse_reaches_a_target_the_simulation_made(muscles):
    face, layer, response = muscles
    rig = _Rig(face, layer)
    known = {"muscle:zygomatic_major:left": 20.0, "muscle:levator_labii_superioris:left": 15.0}
    layer.set_values(known)
    layer.solve()
    target = rig.vertices().copy()
    v = int(np.argmax(np.linalg.norm(layer.offset(None), axis=1)))
    assert np.linalg.norm(target[v] - face.vertices[v]) > 4.0
    try:
        layer.set_values({k: 0.0 for k in layer.parameters()})
        layer.solve()
        values = reach(rig, layer, response, [v], target[[v]], refine=2, settle=lambda lay: lay.solve())
        layer.solve()
        assert np.linalg.norm(rig.vertices()[v] - target[v]) < 0.1
        assert min(values.values()) >= 0.0
        assert all(values[k] <= P.describe(k).maximum for k in values)
    finally:
        layer.set_values({k: 0.0 for k in layer.parameters()})
        layer.solve()


def test_bounds_and_bad_input():
    a = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    s = solve_activations(a, [-1.0, 5.0, 0.0], np.zeros(2), np.zeros(2), np.array([1.0, 2.0]), 0.0)
    np.testing.assert_allclose(s, [0.0, 2.0], atol=1e-12)          # muscles only pull, and only so far
    with pytest.raises(P.ParameterError, match="regulariser"):
        solve_activations(a, [0, 0, 0], np.zeros(2), np.zeros(2), np.ones(2), -1.0)
    with pytest.raises(P.ParameterError, match="response"):
        solve_activations(a, [0, 0], np.zeros(2), np.zeros(2), np.ones(2))


def test_rounding_outside_a_bound_is_clipped(monkeypatch):
    """BVLS may end at -1e-17 for a muscle at rest; the rig's registry refuses anything below 0."""
    import types

    import core.inverse

    rounded = types.SimpleNamespace(x=np.array([-1e-17, 2 + 1e-15]))
    monkeypatch.setattr(core.inverse, "lsq_linear", lambda *a, **k: rounded)
    s = solve_activations(np.eye(2), [0.0, 2.0], np.zeros(2), np.zeros(2), np.array([1.0, 2.0]))
    assert s[0] == 0.0 and s[1] == 2.0
