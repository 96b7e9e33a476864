"""Folded canonical triangles: the count and their removal (core/registration/folds.py)."""

import numpy as np

from core.registration.folds import (aligned_reference, arap_patch, folded_triangles, forced_folds,
                                     triangle_normals, unfold, _edges)
from core.surface_query import TriangleSet


def grid(n: int = 21, size: float = 40.0):
    """(vertices (n*n, 3), triangles) of a gently domed square (mm), triangles facing +z."""
    u = np.linspace(-size / 2, size / 2, n)
    x, y = np.meshgrid(u, u)
    z = 10.0 - (x ** 2 + y ** 2) / 200.0
    v = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n, i.ravel() + n + 1
    return v, np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])


def test_folded_triangles_counts_collapsed_and_turned_ones():
    v, t = grid()
    normals = triangle_normals(v, t)
    assert not folded_triangles(v, t, normals).any()
    w = v.copy()
    w[220] = w[221]                       # two vertices on one spot: their shared triangles collapse
    collapsed = folded_triangles(w, t, normals)
    assert collapsed.sum() == 2 and np.all(np.any(t[collapsed] == 220, axis=1))
    assert folded_triangles(v, t[:, ::-1], normals).all()      # every triangle turned over


def test_unfold_removes_a_fold_and_puts_the_patch_back_on_the_surface():
    """A vertex pulled across its neighbours (a fold as projection makes them in a crease) is
    untangled; the patch returns onto the surface, every triangle the right way round."""
    v, t = grid()
    normals = triangle_normals(v, t)
    folded = v.copy()
    centre = 220                                    # the middle vertex of the 21 x 21 grid
    folded[centre, :2] += [5.0, 3.0]                # 2.5 grid steps over its neighbours
    folded[[centre + 1, centre + 21], :2] -= [2.0, 2.0]
    before = folded_triangles(folded, t, normals).sum()
    assert before > 4
    held = np.zeros(len(v), bool)
    held[[0, 20, 420, 440]] = True                  # the corners stand for the landmarks
    out, on_surface, count_before, after = unfold(folded, t, v, normals, held, TriangleSet(v, t))
    assert count_before == before and after == 0
    assert not folded_triangles(out, t, normals).any()
    closest, _, _ = TriangleSet(v, t).closest(out[on_surface])
    assert np.abs(closest - out[on_surface]).max() < 1e-9
    np.testing.assert_array_equal(out[held], folded[held])
    assert np.linalg.norm(out[centre] - v[centre]) < 1.0     # back near its place, not somewhere else


def test_arap_patch_with_a_free_interior_gives_back_the_reference():
    """Known answer: the held ring is the reference's, so the free interior takes its shape exactly
    (the start is a scrambled, folded patch)."""
    v, t = grid()
    free = np.zeros(len(v), bool)
    free[np.arange(len(v)).reshape(21, 21)[5:16, 5:16].ravel()] = True
    scrambled = v.copy()
    scrambled[free] += np.random.default_rng(0).normal(0, 3.0, (free.sum(), 3))
    assert folded_triangles(scrambled, t, triangle_normals(v, t)).any()
    out = arap_patch(scrambled, v, _edges(t), free)
    assert np.abs(out - v).max() < 1e-6


def test_a_turned_template_triangle_is_forced_and_a_turned_head_is_not():
    base = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [10.0, 10.0, 0.0]])
    base_triangles = np.array([[0, 1, 2], [1, 3, 2]])
    assert not forced_folds(base, base, base_triangles, 8).any()
    # A similarity (a turned, larger head) changes nothing.
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    turned_head = 1.3 * base @ rotation.T + 5.0
    assert not forced_folds(turned_head, aligned_reference(base, turned_head, 4), base_triangles, 8).any()
    # Corner 3 pulled across the edge 1-2: its triangle turns over; canonical triangles k and k+2
    # (k mod 2 == 1) lie inside it.
    moved = base.copy()
    moved[3] = [2.0, 2.0, 0.0]
    forced = forced_folds(moved, base, base_triangles, 8)
    np.testing.assert_array_equal(forced, np.arange(8) % 2 == 1)
