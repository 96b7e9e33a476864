"""The a48 and mpeg4_80 landmark templates: data, topology and subdivision counts (thesis A
Table 3.2 and Table 5.1), checked on a scan, not only the default face."""

import numpy as np
import pytest

from core.registration.correspondence import dense_correspondence
from core.registration.templates import (TEMPLATE_NAMES, UnknownTemplateError, expected_counts, get_template,
                                         template_positions, with_template_landmarks)
from core.subdivision import boundary_edges, unique_edges

A48_COUNTS = [(48, 74), (170, 296), (636, 1184), (2456, 4736), (9648, 18944)]
M80_COUNTS = [(80, 140), (300, 560), (1160, 2240), (4560, 8960)]


@pytest.fixture(scope="module")
def face():
    from core.default_face import load_default_face

    return load_default_face(full_head=False)   # the registration protocol's generic model


@pytest.fixture(scope="module")
def scan(face):
    """A re-meshed, partial copy of the default face (no parts, different triangles): a virtual scan."""
    from core.registration.virtual_scanner import scan_face

    return scan_face(face, n_target=20_000, rng=np.random.default_rng(1)).face


def test_a48_topology_is_the_thesis_annulus():
    t = get_template("a48")
    assert len(t.base.points) == 48 and len(set(t.base.points)) == 48
    assert len(t.base.triangles) == 74
    edges, _ = unique_edges(t.base.triangles)
    assert len(edges) == 122
    assert 48 - 122 + 74 == 0                      # Euler characteristic 0: outline + one opening
    b = boundary_edges(t.base.triangles)
    assert len(b) == 22                            # 14 outline + 8 mouth
    mouth = {t.base.index(n) for n in t.base.mouth}
    assert sum(set(e) <= mouth for e in map(tuple, b)) == 8


def test_expected_counts_match_the_thesis_tables():
    assert expected_counts(get_template("a48").base) == A48_COUNTS
    assert expected_counts(get_template("mpeg4_80").base) == M80_COUNTS
    assert list(get_template("a48").counts) == [tuple(c) for c in A48_COUNTS]


def test_a48_points_are_feature_points_or_derived():
    from core.layers.fap.template import load_template

    t = get_template("a48")
    m80 = load_template("mpeg4_80")
    for p in t.detected:
        assert p in m80.feature_points or p in t.derived
    for name, d in t.derived.items():
        ids = {m80.index(c) for c in d["corners"]}
        assert any(ids == set(t.tolist()) for t in m80.triangles)   # a triangle of mpeg4_80
        assert abs(sum(d["barycentric"]) - 1) < 1e-9


def test_unknown_template_is_a_clear_error():
    with pytest.raises(UnknownTemplateError, match="a48"):
        get_template("nope")


def test_ground_truth_on_default_face(face):
    pos = template_positions(face, "a48")
    assert set(pos) == set(get_template("a48").detected)
    # The temple points lie on the skin, between the hairline corner and the ear contact.
    tl = pos["a48.temple_l"]
    assert tl[0] > 40 and 38 < tl[1] < 78
    d = np.linalg.norm(face.closest_surface_points(tl[None])[0][0] - tl)
    assert d < 1e-6


@pytest.mark.parametrize("name, counts", [("a48", A48_COUNTS), ("mpeg4_80", M80_COUNTS)])
def test_subdivision_counts_on_a_scan(scan, name, counts):
    pos = template_positions(with_template_landmarks(scan, name), name)
    reg = dense_correspondence(scan, pos, template=name)
    assert reg.projection.dense.counts == counts
    assert reg.face.n_vertices == counts[-1][0] and reg.face.n_triangles == counts[-1][1]
    assert name in TEMPLATE_NAMES
