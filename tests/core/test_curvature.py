"""Curvature/HK classes on analytic surfaces, HK texture, and texture/geometry candidates."""

from __future__ import annotations

import numpy as np
import pytest

from core.face import Face
from core.registration.candidates import (CandidateError, NoTextureError, geometry_candidates,
                                          texture_candidates, uv_raster, uv_to_pixel)
from core.registration.curvature import (CLASS_COLOURS, ELLIPTIC_CONCAVE, ELLIPTIC_CONVEX, FLAT,
                                         HYPERBOLIC_CONCAVE, HYPERBOLIC_CONVEX, CurvatureError,
                                         hk_classes, hk_maps, hk_texture)
from core.registration.range_image import face_from_xyz_grid


def height_field(zfun, n=61, half=10.0) -> Face:
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(half, -half, n))
    return face_from_xyz_grid(np.stack([x, y, zfun(x, y)], axis=-1), max_edge_mm=np.inf)


R = 50.0
SPHERE = lambda x, y: np.sqrt(R * R - x * x - y * y)  # noqa: E731
CENTRE = 61 * 30 + 30


@pytest.mark.parametrize("smoothing", [0.0, 1.0])
def test_sphere_convex_and_concave(smoothing):
    hk = hk_maps(height_field(SPHERE), smoothing_mm=smoothing)
    assert hk.H[CENTRE] == pytest.approx(-1 / R, rel=2e-3)
    assert hk.K[CENTRE] == pytest.approx(1 / R ** 2, rel=4e-3)
    assert hk.classes[CENTRE] == ELLIPTIC_CONVEX
    bowl = hk_maps(height_field(lambda x, y: -SPHERE(x, y)), smoothing_mm=smoothing)
    assert bowl.H[CENTRE] == pytest.approx(1 / R, rel=2e-3)
    assert bowl.K[CENTRE] == pytest.approx(1 / R ** 2, rel=4e-3)
    assert bowl.classes[CENTRE] == ELLIPTIC_CONCAVE
    # Away from the rim the whole cap is elliptic convex.
    inner = np.linalg.norm(height_field(SPHERE).vertices[:, :2], axis=1) < 6
    assert np.all(hk.classes[inner] == ELLIPTIC_CONVEX)


def test_cylinder_and_saddle():
    cyl = hk_maps(height_field(lambda x, y: np.sqrt(R * R - x * x)), smoothing_mm=1.0)
    assert cyl.H[CENTRE] == pytest.approx(-1 / (2 * R), rel=2e-3)
    assert abs(cyl.K[CENTRE]) < 1e-7
    a = 30.0
    saddle = hk_maps(height_field(lambda x, y: (x * x - y * y) / (2 * a)), smoothing_mm=0.0)
    assert saddle.K[CENTRE] == pytest.approx(-1 / a ** 2, rel=1e-3)
    assert abs(saddle.H[CENTRE]) < 1e-8
    # Saddle with a bias: sign of H picks convex/concave hyperbolic.
    up = hk_maps(height_field(lambda x, y: (x * x - 2 * y * y) / (2 * a)), smoothing_mm=0.0)
    down = hk_maps(height_field(lambda x, y: (2 * x * x - y * y) / (2 * a)), smoothing_mm=0.0)
    assert up.classes[CENTRE] == HYPERBOLIC_CONVEX and down.classes[CENTRE] == HYPERBOLIC_CONCAVE


def test_classes_colours_and_flat():
    H = np.array([-1, -1, 1, 1, 0.0])
    K = np.array([-1, 1, -1, 1, 0.0])
    cls = hk_classes(H, K)
    np.testing.assert_array_equal(cls, [HYPERBOLIC_CONVEX, ELLIPTIC_CONVEX, HYPERBOLIC_CONCAVE, ELLIPTIC_CONCAVE, FLAT])
    c = CLASS_COLOURS.astype(int)
    # Convex classes share red, concave share blue; convexity matters more than type.
    assert c[0, 0] == c[1, 0] == 255 and c[2, 2] == c[3, 2] == 255
    within = np.linalg.norm(c[0] - c[1])
    across = np.linalg.norm(c[1] - c[3])
    assert across > within > 0
    plane = hk_maps(height_field(lambda x, y: 0.0 * x), smoothing_mm=1.0)
    assert np.all(plane.classes == FLAT)


def test_hk_texture_and_errors():
    face = height_field(SPHERE, n=21)
    with pytest.raises(NoTextureError):
        hk_texture(face, hk_maps(face, smoothing_mm=0))
    hk = hk_maps(face, smoothing_mm=0)
    img = hk_texture(face, hk, size=(40, 40))
    assert img.shape == (40, 40, 3)
    assert (img[20, 20] == CLASS_COLOURS[ELLIPTIC_CONVEX]).all()
    with pytest.raises(CurvatureError, match="smoothing_mm"):
        hk_maps(face, smoothing_mm=-1)
    with pytest.raises(CurvatureError, match="shape"):
        hk_maps(face, vertices=np.zeros((3, 3)))


# ---------------------------------------------------------------- candidates
@pytest.fixture(scope="module")
def checker_face():
    n = 60
    x, y = np.meshgrid(np.linspace(-15, 15, n), np.linspace(15, -15, n))
    xyz = np.stack([x, y, np.sqrt(R * R - x * x - y * y)], axis=-1)
    rows, cols = np.mgrid[0:240, 0:240]
    board = (((rows // 20) + (cols // 20)) % 2 * 200 + 30).astype(np.uint8)
    return face_from_xyz_grid(xyz, np.repeat(board[..., None], 3, axis=2))


def test_texture_candidates_lie_on_surface_and_map_back(checker_face):
    face = checker_face
    cand = texture_candidates(face, count=500, quality=0.01, min_distance_px=5)
    assert 50 <= len(cand) <= 500  # the 12x12 board has ~120 inner corners
    closest, _, _ = face.closest_surface_points(cand.points)
    assert np.abs(closest - cand.points).max() < 1e-9
    # The stored uv is the detected texel centre and the surface point's interpolated uv.
    px = uv_to_pixel(cand.uv, (240, 240))
    np.testing.assert_allclose(px, np.rint(px), atol=1e-9)
    uv_interp = np.einsum("kj,kjd->kd", cand.bary, face.uv[face.triangles[cand.triangle]])
    np.testing.assert_allclose(uv_interp, cand.uv, atol=1e-9)
    assert cand.colour.shape == (len(cand), 3) and 0 <= cand.colour.min() and cand.colour.max() <= 1
    # Corners of the checker board: 20-texel lattice (texel centres at 19.5 + 20 k).
    off = np.abs(((px + 0.5) / 20) - np.rint((px + 0.5) / 20)) * 20
    assert np.median(off) <= 1.0


def test_candidates_without_texture_and_geometry_fallback(checker_face):
    bare = checker_face.without_texture()
    with pytest.raises(NoTextureError):
        texture_candidates(bare)
    geo = geometry_candidates(bare, count=200)
    assert len(geo) == 200
    assert len(np.unique(geo.points, axis=0)) == 200
    corners = bare.vertices[bare.triangles[geo.triangle]]
    np.testing.assert_allclose(np.einsum("kj,kjd->kd", geo.bary, corners), geo.points)
    # Even spread: nearest-neighbour spacing far above the mesh spacing (0.5 mm).
    from scipy.spatial import cKDTree

    d, _ = cKDTree(geo.points).query(geo.points, k=2)
    assert d[:, 1].min() > 1.0
    with pytest.raises(CandidateError):
        texture_candidates(checker_face, quality=0)


def test_uv_raster_covers_the_image_once(checker_face):
    r = uv_raster(checker_face.uv, checker_face.triangles, (240, 240))
    # Vertex uvs sit at texel centres of the depth grid; the triangles tile the square between
    # the first and last vertex uv: texels inside that square are all covered.
    assert r.covered[3:-3, 3:-3].all()
    np.testing.assert_allclose(r.bary[r.covered].sum(axis=1), 1.0)


def test_blended_fit_sites_and_numpy_path_agree_on_a_sphere(monkeypatch):
    """Fitting on a voxel subsample of sites and blending, or without numba, keeps the sphere."""
    import core.registration.curvature as curvature

    face = height_field(SPHERE)
    sites = hk_maps(face, smoothing_mm=1.0, site_spacing=1.0)
    assert sites.H[CENTRE] == pytest.approx(-1 / R, rel=5e-3)
    assert sites.K[CENTRE] == pytest.approx(1 / R ** 2, rel=1e-2)
    monkeypatch.setattr(curvature, "_numba_fit", None)
    plain = hk_maps(face, smoothing_mm=1.0)
    assert plain.H[CENTRE] == pytest.approx(-1 / R, rel=2e-3)
    with pytest.raises(CurvatureError, match="site_spacing"):
        hk_maps(face, smoothing_mm=1.0, site_spacing=-1)
