"""Thesis C's muscle presets on a face rig hold up as surfaces (issue 18 item 2): the muscle layer's
offsets reach what they should (the mouth cavity's lining follows the lips) and nothing else."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse

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


def _edge_slopes(model, weights, near_mm):
    """Largest |w_i - w_j| / |p_i - p_j| (1/mm) over the tissue's skin edges within ``near_mm`` of a mouth corner."""
    from core.subdivision import unique_edges

    edges = unique_edges(model.triangles)[0]
    p = model.skin_mm
    corners = p[[model.template.index(c) for c in ("8.3", "8.4")]]
    mid = (p[edges[:, 0]] + p[edges[:, 1]]) / 2
    near = np.linalg.norm(mid[:, None] - corners[None], axis=2).min(axis=1) < near_mm
    length = np.linalg.norm(p[edges[:, 0]] - p[edges[:, 1]], axis=1)
    keep = near & (length > 1e-6)      # the template's welded seam copies have no length
    return (np.abs(weights[edges[keep, 0]] - weights[edges[keep, 1]]) / length[keep]).max()


def test_jaw_weights_blend_into_the_mouth_corners():
    """The model's own jaw weights: the lower lip's 1 and the upper lip's 0 met the corner's 0.4 in a
    step across sub-millimetre edges (2.3 per mm); blended over a quarter mouth width they change by
    at most ~1.5 x 0.6 / 12 mm per mm, and the corners keep 0.4."""
    from core.layers.muscles.model import TissueModel, dense_template

    face = load_default_face()
    model = TissueModel(face, dense_template(face, 2))
    corners = [model.template.index(c) for c in ("8.3", "8.4")]
    assert np.allclose(model.jaw_weight[corners], 0.4)
    assert model.jaw_weight[model.template.index("8.2")] == pytest.approx(1.0, abs=0.02)
    assert _edge_slopes(model, model.jaw_weight, 5.0) < 0.2


def test_attached_muscle_jaw_moves_the_skin_as_fap_3_does(rig, muscles, probe):
    """On a rig the muscle jaw takes FAP 3's weights; opened 8 degrees alone it leaves the mouth
    corners whole (its own weights: texture stretch 10.5 at a corner, 10 folded triangles)."""
    from core.layers.muscles import ForceSet

    w3 = rig.deformer.template_weights[3]
    assert np.allclose(muscles.model.jaw_weight, w3 / w3.max())
    muscles.apply(ForceSet({}, 8.0, "jaw"))
    muscles.solve()
    x = rig.vertices()
    from core.mesh_quality import principal_stretches

    big, _small = principal_stretches(probe._rest_frames, x[probe.skin_tris])
    centroids = rig.face.vertices[probe.skin_tris].mean(axis=1)
    corners = np.array([rig.face.landmark_position(c) for c in ("8.3", "8.4")])
    near = np.linalg.norm(centroids[:, None] - corners[None], axis=2).min(axis=1) < 6.0
    assert big[near & probe._measurable].max() < 2.0


def test_skin_filter_keeps_smooth_fields_and_removes_element_scale_ones():
    """On a regular 0.5 mm grid a Gaussian of width s passes a wave of wavelength L by
    exp(-2 pi^2 s^2 / L^2): 0.95 for 40 mm at s = 2 mm, next to nothing of a 1 mm checkerboard; constants pass
    exactly; the other lip's points never enter a row; width 0 is the identity."""
    from core.layers.muscles.model import smoothing_matrix

    g = np.arange(-20.0, 20.01, 0.5)
    X, Y = np.meshgrid(g, g)
    points = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    area = np.full(len(points), 0.25)
    lip = np.zeros(len(points), np.int8)
    S = smoothing_matrix(points, area, lip, 2.0)
    assert np.allclose(np.asarray(S.sum(axis=1)).ravel(), 1.0)
    inner = (np.abs(points[:, :2]) <= 10.0).all(axis=1)
    wave = np.cos(2 * np.pi * points[:, 0] / 40.0)
    assert np.allclose((S @ wave)[inner], np.exp(-2 * np.pi ** 2 * 4.0 / 40.0 ** 2) * wave[inner], atol=1e-2)   # cut at 2.5 widths: 0.958, not 0.952
    checker = (-1.0) ** (np.rint(2 * points[:, 0]) + np.rint(2 * points[:, 1]))
    assert np.abs((S @ checker)[inner]).max() < 0.01   # what the cut lets through
    lip[points[:, 1] > 0] = 1
    lip[points[:, 1] < 0] = -1
    S = smoothing_matrix(points, area, lip, 2.0).tocoo()
    assert (lip[S.row].astype(int) * lip[S.col] >= 0).all()
    assert (smoothing_matrix(points, area, lip, 0.0) != scipy.sparse.identity(len(points), format="csr")).nnz == 0


def test_kiss_purses_the_lips_without_folding_them(rig, muscles, probe):
    """Thesis C's kiss on the default face: the sphincter buckled the lattice's lips into millimetre
    wrinkles the face showed (94 folded triangles, 35 lip crossing pairs); seen through the skin
    filter none are left, and the lips still purse: forward by 8-10 mm, the mouth about 8 mm narrower."""
    rest = rig.face.vertices
    x = _pose(rig, muscles, "kiss")
    q = probe.measure(x)
    assert q.folded_triangles == 0 and q.lip_intersections == 0 and q.teeth_intersections == 0
    near = {n: int(np.argmin(np.linalg.norm(rest - rig.face.landmark_position(n), axis=1))) for n in ("8.1", "8.2", "8.3", "8.4")}
    assert (x - rest)[near["8.1"], 2] > 7.0 and (x - rest)[near["8.2"], 2] > 7.0
    width = lambda v: v[near["8.3"], 0] - v[near["8.4"], 0]
    assert width(rest) - width(x) > 6.0


def test_skin_filter_keeps_the_lips_apart_but_blends_them_at_the_corners(rig, muscles):
    """Relaxed along the mesh (no edge crosses the mouth), the lip labels stay +-1 at the inner lips'
    midpoints and are 0 at the corners: the filter row of an inner lip point takes nothing of the
    other lip, a corner's row takes both lips (hard labels left a step there: stretch 2.7 -> 2.4 in the
    discreet smile)."""
    m = muscles.model
    side = m._lip_side()
    index = {n: m.template.index(n) for n in ("2.2", "2.3", "8.3", "8.4")}
    assert side[index["2.2"]] == pytest.approx(1.0, abs=1e-6) and side[index["2.3"]] == pytest.approx(-1.0, abs=1e-6)
    assert abs(side[index["8.3"]]) < 0.05 and abs(side[index["8.4"]]) < 0.05
    rows, F = m.skin_filter(np.ones(m.n, bool))
    for name, other in (("2.2", -1), ("2.3", 1)):
        row = F[index[name]]
        assert row.data[m.lip[row.indices] == other].sum() == 0.0
    corner = F[index["8.3"]]     # most of its weight is on the unlabelled corner nodes (8 % on each lip)
    assert corner.data[m.lip[corner.indices] > 0].sum() > 0.05 and corner.data[m.lip[corner.indices] < 0].sum() > 0.05
