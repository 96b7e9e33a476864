"""The fold-free fit of the canonical mesh (core/registration/fold_free.py, issue 15)."""

import numpy as np
import pytest

from core.registration.fold_free import MARGIN, along_reference, blocked_step, fold_free_fit
from core.registration.folds import folded_triangles, triangle_normals
from core.surface_query import TriangleSet

from tests.core.test_folds import grid


def unit_normals(v, t):
    n = triangle_normals(v, t)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_a_blocked_step_goes_all_the_way_unless_a_triangle_would_turn_over():
    v, t = grid()
    unit = unit_normals(v, t)
    floor = MARGIN * np.linalg.norm(triangle_normals(v, t), axis=1)
    shifted = v + [1.0, 0.5, 0.0]                   # a move that folds nothing: taken whole
    out, reach, braked = blocked_step(v, shifted, t, unit, floor)
    np.testing.assert_allclose(out, shifted)
    assert reach.min() == 1.0 and not braked.any()
    across = v.copy()
    across[220, :2] += [5.0, 3.0]                   # the middle vertex 2.5 grid steps over its neighbours
    out, reach, braked = blocked_step(v, across, t, unit, floor)
    assert not folded_triangles(out, t, triangle_normals(v, t)).any()
    assert (along_reference(out, t, unit) >= floor - 1e-12).all()
    assert 0.0 < np.linalg.norm(out[220] - v[220]) < np.linalg.norm(across[220] - v[220])
    assert braked.any() and np.all(np.any(np.isin(t[braked], [220]), axis=1))


def test_the_fit_reaches_a_surface_of_another_shape_without_folding():
    """Known answer: the reference is a flat grid, the surface the domed grid; with the corners as
    landmarks the fit lies on the dome (every vertex), no triangle folds, the landmarks are reached."""
    v, t = grid()
    flat = v.copy()
    flat[:, 2] = 0.0
    corners = [0, 20, 420, 440]
    fit = fold_free_fit(flat, t, {i: v[i] for i in corners}, flat, TriangleSet(v, t), unit_normals(v, t))
    assert not folded_triangles(fit.vertices, t, triangle_normals(flat, t)).any()
    closest, _, _ = TriangleSet(v, t).closest(fit.vertices)
    assert np.abs(closest - fit.vertices).max() < 1e-6
    assert fit.landmark_shift.max() < 1e-6


def test_a_landmark_across_its_neighbours_moves_back_a_little_instead_of_folding():
    """The fit's targets ask one vertex to lie across its neighbours (what a landmark that turns
    a template triangle over asks): nothing folds, and that vertex stops short."""
    v, t = grid()
    targets = {i: v[i] for i in (0, 20, 420, 440)}
    crossed = v[220] + [5.0, 3.0, 0.0]
    targets[220] = crossed
    fit = fold_free_fit(v, t, targets, v, TriangleSet(v, t), unit_normals(v, t))
    assert not folded_triangles(fit.vertices, t, triangle_normals(v, t)).any()
    assert fit.landmark_shift[:4].max() < 1e-6


@pytest.fixture(scope="module")
def scan():
    from core.default_face import load_default_face
    from core.registration.virtual_scanner import scan_face

    return scan_face(load_default_face(full_head=False), n_target=30_000, rng=np.random.default_rng(5)).face


def test_a_landmark_turning_a_template_triangle_over_registers_without_folds(scan):
    """The inner lip corner 2.4 lies 0.8 mm inside the line from the lip corner 8.3 to the upper
    lip 8.5 on the default face; moved 1.2 mm across that line (on the scan), its template
    triangle 2.4-8.3-8.5 is turned over, so with the landmarks held the canonical mesh had to fold
    there. The fit leaves no fold and keeps every landmark within 1 mm of where it was given."""
    from core.registration.correspondence import landmark_positions_on
    from core.registration.pipeline import register_scan
    from core.registration.templates import get_template
    from core.surface_query import TriangleSet as Surface

    positions = landmark_positions_on(scan, dict(scan.landmarks))
    a, b, c = (positions[n] for n in ("8.3", "8.5", "2.4"))
    edge = (b - a) / np.linalg.norm(b - a)
    inward = (c - a) - np.dot(c - a, edge) * edge
    height = np.linalg.norm(inward)
    moved = c - (height + 1.2) * inward / height
    positions["2.4"] = Surface(scan.vertices, scan.triangles).closest(moved[None])[0][0]
    base = get_template("mpeg4_80").base
    turned = np.cross(b - a, c - a) @ np.cross(b - a, positions["2.4"] - a)
    assert turned < 0, "the template triangle 8.3-8.5-2.4 is turned over"
    registration = register_scan(scan, positions)
    assert registration.folded().sum() == 0
    names = [n for n in base.points if n in positions and n not in base.extras]
    given = np.array([positions[n] for n in names])
    canonical = registration.face.vertices[[base.index(n) for n in names]]
    assert np.linalg.norm(canonical - given, axis=1).max() < 1.0
    d = registration.distances_to_scan()
    assert d.mean() < 0.5 and np.percentile(d, 95) < 2.0
