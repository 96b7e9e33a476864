"""Thesis C's muscle presets on a face rig hold up as surfaces (issue 18 item 2): the muscle layer's
offsets reach what they should (the mouth cavity's lining follows the lips) and nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from core.default_face import load_default_face
from core.layers.muscles import preset
from core.mesh_quality import FaceQualityProbe
from core.rig import FaceRig


@pytest.fixture(scope="module")
def rig():
    rig = FaceRig(load_default_face())
    rig.ensure_layers(["muscle:orbicularis_oris"])
    return rig


@pytest.fixture(scope="module")
def probe(rig):
    return FaceQualityProbe(rig.face)


@pytest.fixture
def muscles(rig):
    layer = rig.layer("muscles")
    layer.reset()
    yield layer
    layer.reset()


def _pose(rig, layer, name):
    layer.apply(preset(name))
    layer.solve()
    return rig.vertices()


def test_cavity_lining_follows_the_lips_the_muscles_move(rig, muscles):
    """The lining's offsets are the FAP deformer's cavity rows applied to the skin's offsets: in full
    right behind the lips, none at the back of the mouth (as for the FAPs)."""
    _pose(rig, muscles, "kiss")
    offsets = muscles.skin_offsets()
    cavity = rig.face.parts["mouth_cavity"]
    skin = np.ones(rig.face.n_vertices, bool)
    for idx in rig.face.parts.values():
        skin[idx] = False
    follow = rig.deformer.cavity_follow()
    expected = follow @ np.where(skin[:, None], offsets, 0.0)
    assert np.allclose(offsets[cavity], expected[cavity], atol=1e-9)
    weight = np.asarray(follow.sum(axis=1)).ravel()[cavity]
    moved = np.linalg.norm(offsets[cavity], axis=1)
    # The lining within CAVITY_FOLLOW_NEAR_MM of the pursed lips goes with them (3.7 mm at most on
    # the default face); the back of the mouth stays with the skull.
    assert moved[weight > 0.999].max() > 2.0
    assert moved[weight == 0].max() == 0.0


def test_kiss_lips_stay_in_front_of_the_cavity(rig, muscles, probe):
    """Held still, the lining let the pursed lips pass through it: 265 crossing pairs on the default face."""
    q = probe.measure(_pose(rig, muscles, "kiss"))
    assert q.cavity_intersections == 0
