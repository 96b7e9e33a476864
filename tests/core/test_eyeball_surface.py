"""The lid guard's eyeball surface (core.layers.fap.eyeball_surface): a radius map over both angles
about the gaze axis, read bilinearly, never below the ball's mesh; and the push onto it."""

import numpy as np
import pytest

from core.layers.fap import kernels
from core.layers.fap.eyeball_surface import (PUSH_TURN_END_RAD, PUSH_TURN_START_RAD, RADIUS_MAP_REACH_RAD,
                                             RADIUS_MAP_STEP_RAD, map_radius, push_outside, radius_map)

CENTRE = np.array([31.5, 33.0, -43.0])
SEMI_AXES = np.array([15.0, 12.0, 14.0])    # mm: wider than high, as the default face's ball
CAP_DEG = 70.0                              # the cap reaches this far from the gaze axis (+z)


def ellipsoid_radius(directions: np.ndarray) -> np.ndarray:
    """(k,) mm: the ellipsoid's radius about its centre along unit ``directions`` (k, 3)."""
    return 1.0 / np.sqrt(((directions / SEMI_AXES) ** 2).sum(axis=1))


def unit(theta_deg, phi_deg) -> np.ndarray:
    t, p = np.broadcast_arrays(np.radians(theta_deg), np.radians(phi_deg))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def ellipsoid_cap(rings: int = 40, sectors: int = 96) -> tuple[np.ndarray, np.ndarray]:
    """A front cap of the ellipsoid about CENTRE: (vertices (n, 3) mm, triangles (t, 3)), open at CAP_DEG."""
    theta = np.linspace(0.0, CAP_DEG, rings + 1)[1:]
    phi = np.arange(sectors) * 360.0 / sectors
    d = unit(theta[:, None], phi[None, :]).reshape(-1, 3)
    apex = np.array([[0.0, 0.0, 1.0]])
    d = np.concatenate([apex, d])
    vertices = CENTRE + d * ellipsoid_radius(d)[:, None]
    tris = [[0, 1 + j, 1 + (j + 1) % sectors] for j in range(sectors)]
    for i in range(rings - 1):
        for j in range(sectors):
            a, b = 1 + i * sectors + j, 1 + i * sectors + (j + 1) % sectors
            tris += [[a, a + sectors, b], [b, a + sectors, b + sectors]]
    return vertices, np.array(tris)


@pytest.fixture(scope="module")
def cap():
    vertices, triangles = ellipsoid_cap()
    return vertices, triangles, radius_map(vertices, triangles, CENTRE)


def test_the_radius_map_of_an_ellipsoid_cap_stands_just_above_its_surface(cap):
    vertices, triangles, radii = cap
    rng = np.random.default_rng(3)
    # Points on the cap's own (flat-faceted) surface: barycentric samples of random triangles.
    t = triangles[rng.integers(0, len(triangles), 4000)]
    w = rng.dirichlet(np.ones(3), len(t))
    points = (vertices[t] * w[:, :, None]).sum(axis=1) - CENTRE
    over = map_radius(points, radii) - np.linalg.norm(points, axis=1)
    assert over.min() >= -0.002           # never inside the mesh (up to the sampling's 0.002 mm)
    assert over.max() <= 0.15             # a 1-degree filter over a ball 12-15 mm across
    assert np.median(over) < 0.06
    # Known answer: the analytic ellipsoid, within the facets' sag (about 0.05 mm here).
    d = unit(rng.uniform(0, CAP_DEG - 2, 500), rng.uniform(0, 360, 500))
    assert np.abs(map_radius(d, radii) - ellipsoid_radius(d)).max() < 0.2


def test_behind_the_rim_the_map_continues_the_ball_then_ends(cap):
    _vertices, _triangles, radii = cap
    # Just behind an open rim: the rim's radius at that azimuth (socket skin tucked behind it is
    # not read as free of the ball); the high (y) and the wide (x) sides differ as the ellipsoid does.
    for phi, axis in ((0.0, 0), (90.0, 1)):
        rim = ellipsoid_radius(unit(np.array([CAP_DEG]), np.array([phi])))[0]
        behind = map_radius(unit(np.array([CAP_DEG + 10.0]), np.array([phi])), radii)[0]
        assert rim - 0.05 <= behind <= rim + 0.3, (phi, rim, behind)
    assert SEMI_AXES[0] - SEMI_AXES[1] > 2.0       # so the two sides above are told apart
    # Far round the side and behind the centre there is no ball.
    assert map_radius(unit(np.array([CAP_DEG + 35.0, 150.0]), np.array([45.0, 0.0])), radii).tolist() == [0.0, 0.0]
    assert RADIUS_MAP_STEP_RAD < RADIUS_MAP_REACH_RAD


def test_skin_inside_the_ball_is_pushed_forward_onto_it_at_its_clearance_compiled_and_numpy(cap):
    _vertices, _triangles, radii = cap
    rng = np.random.default_rng(5)
    d = unit(rng.uniform(5, 55, 200), rng.uniform(0, 360, 200))
    depth = rng.uniform(-1.5, 1.5, 200)               # inside (< 0) or outside the ball
    start = CENTRE + d * (ellipsoid_radius(d) + depth)[:, None]
    lid = np.arange(200, dtype=np.int64)
    clearance = np.full(200, 0.4)
    pushed = start.copy()
    push_outside(pushed, lid, CENTRE, clearance, radii)
    moved = np.abs(pushed - start).max(axis=1) > 0
    # Only what was inside the guard surface moves, only forward, keeping its height (x, y).
    assert np.array_equal(moved, np.linalg.norm(start - CENTRE, axis=1) < map_radius(start - CENTRE, radii) + clearance)
    assert moved.sum() > 50 and (~moved).sum() > 50
    assert np.array_equal(pushed[:, :2], start[:, :2]) and (pushed[:, 2] >= start[:, 2]).all()
    # Known answer: it ends 0.4 mm outside the ellipsoid along its new direction (the map's filter
    # adds up to 0.15 mm; two passes settle a push that turned the vertex toward the cornea).
    out = pushed[moved] - CENTRE
    gap = np.linalg.norm(out, axis=1) - ellipsoid_radius(out / np.linalg.norm(out, axis=1)[:, None])
    assert gap.min() > 0.4 - 0.05 and gap.max() < 0.4 + 0.2
    built = kernels.get()
    if built is None:
        pytest.skip("numba is not installed: only the numpy path exists")
    compiled = start.copy()
    # At full clearance (ramp 1) and not slid (rest = start): the same clearance as above.
    built.close_lids_over_eyeball(compiled, lid, start.copy(), np.zeros(3), CENTRE, clearance, clearance, 1.0, 2.0, 0.0,
                                  radii, float(radii.max()), RADIUS_MAP_STEP_RAD, RADIUS_MAP_REACH_RAD,
                                  PUSH_TURN_START_RAD, PUSH_TURN_END_RAD)
    assert np.abs(compiled - pushed).max() <= 1e-12


def test_skin_beside_the_ball_is_pushed_out_radially_not_far_forward(cap):
    """Skin tucked behind the rim, beside the ball (85-95 degrees off the gaze axis, in the map's skirt),
    1-2 mm inside: pushed straight out by its depth. Forward, onto a surface of about its own distance
    from the centre, it would have moved ~6 mm (a generated face's outer eye corner jumped 7.8 mm
    forward as the lids closed)."""
    _vertices, _triangles, radii = cap
    rng = np.random.default_rng(8)
    n = 100
    d = unit(rng.uniform(86, 95, n), rng.uniform(-60, 60, n))      # beside the ball, toward the temple
    offsets = d * (map_radius(d, radii) - rng.uniform(1.0, 2.0, n))[:, None]
    start = CENTRE + offsets
    lid = np.arange(n, dtype=np.int64)
    clearance = np.full(n, 0.1)
    pushed = start.copy()
    push_outside(pushed, lid, CENTRE, clearance, radii)
    step = pushed - start
    depth = map_radius(offsets, radii) + clearance - np.linalg.norm(offsets, axis=1)
    np.testing.assert_allclose(np.linalg.norm(step, axis=1), depth, rtol=1e-9)
    np.testing.assert_allclose(np.cross(step, offsets), 0.0, atol=1e-9)             # along the radius
    forward = np.sqrt((map_radius(offsets, radii) + clearance) ** 2 - (offsets[:, :2] ** 2).sum(axis=1)) - offsets[:, 2]
    assert (forward > 2.5 * depth).all()
    built = kernels.get()
    if built is not None:
        compiled = start.copy()
        built.close_lids_over_eyeball(compiled, lid, start.copy(), np.zeros(3), CENTRE, clearance, clearance, 1.0, 2.0,
                                      0.0, radii, float(radii.max()), RADIUS_MAP_STEP_RAD, RADIUS_MAP_REACH_RAD,
                                      PUSH_TURN_START_RAD, PUSH_TURN_END_RAD)
        assert np.abs(compiled - pushed).max() <= 1e-12
