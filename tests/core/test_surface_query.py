"""Closest points on a triangle set: the compiled loop and the numpy path agree, and both are exact."""

from __future__ import annotations

import numpy as np
import pytest

from core import surface_query, surface_query_kernels
from core.surface_query import TriangleSet


def _wavy_sheet(n: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """A (n x n)-vertex height field (mm) and its triangles: a bumpy surface with edges and corners."""
    u, v = np.meshgrid(np.linspace(0, 60, n), np.linspace(0, 60, n))
    vertices = np.column_stack([u.ravel(), v.ravel(), (5 * np.sin(u / 7) * np.cos(v / 9)).ravel()])
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()
    triangles = np.concatenate([np.column_stack([a, a + 1, a + n]), np.column_stack([a + 1, a + n + 1, a + n])])
    return vertices, triangles


def _numpy_closest(ts: TriangleSet, points, monkeypatch, **kwargs):
    monkeypatch.setattr(surface_query_kernels, "kernel", lambda **_: None)
    try:
        return ts.closest(points, **kwargs)
    finally:
        monkeypatch.undo()


def test_known_answers_interior_edge_and_corner(monkeypatch):
    ts = TriangleSet(np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0]]), np.array([[0, 1, 2]]))
    points = np.array([[2.0, 3, 5], [5, -4, 1], [-3, -2, 0], [8, 8, 0]])
    expected = np.array([[2.0, 3, 0], [5, 0, 0], [0, 0, 0], [5, 5, 0]])
    for pos, tri, bary in (ts.closest(points), _numpy_closest(ts, points, monkeypatch)):
        np.testing.assert_allclose(pos, expected, atol=1e-12)
        assert (tri == 0).all()
        np.testing.assert_allclose(bary @ ts.corners[0], expected, atol=1e-12)


def test_compiled_loop_gives_the_numpy_answer_bit_for_bit(monkeypatch):
    if surface_query_kernels.kernel(load=True) is None:
        pytest.skip("numba is disabled or missing: only the numpy path exists")
    vertices, triangles = _wavy_sheet()
    ts = TriangleSet(vertices, triangles)
    rng = np.random.default_rng(3)
    points = rng.uniform([-10, -10, -15], [70, 70, 15], (3000, 3))   # off the sheet's edges too
    compiled = ts.closest(points)
    reference = _numpy_closest(ts, points, monkeypatch)
    for got, want in zip(compiled, reference):
        assert np.array_equal(got, want)
    # Exact: no triangle of the whole set is closer than the answer (brute force over all of them).
    brute = np.linalg.norm(surface_query._closest_on_triangles(
        points[:, None], *(ts.corners[None, :, i] for i in range(3)))[0] - points[:, None], axis=2).min(axis=1)
    np.testing.assert_allclose(np.linalg.norm(compiled[0] - points, axis=1), brute, atol=1e-9)
