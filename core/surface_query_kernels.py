"""Closest points among candidate triangles in one compiled pass (numba), for
:class:`core.surface_query.TriangleSet`.

Binding a face to its FAP template asks for the closest of 16 candidate triangles for each of ~60k
points: numpy builds a dozen (p, k, 3) temporaries for it (~3 s of a cold rig build); this loop does
the same arithmetic point by point in ~0.1 s. Built lazily (:mod:`core.lazy_numba`): :func:`kernel`
gives the loop or None (numba missing, disabled or deferred: use numpy).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from core.lazy_numba import LazyKernels


def _build(numba) -> SimpleNamespace:
    @numba.njit(cache=True, nogil=True)
    def closest_among_into(points, corners, candidates, out_pos, out_tri, out_bary, out_dist):  # pragma: no cover - compiled
        """points (p, 3), corners (m, 3, 3), candidates (p, k) int64 triangle indices -> per point the
        closest position (p, 3), its triangle (p,), barycentric coordinates (p, 3) and distance (p,).
        Same regions, order and ties as ``surface_query._closest_on_triangles`` + argmin (the first
        candidate wins a tie)."""
        for i in range(points.shape[0]):
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            best = np.inf
            for j in range(candidates.shape[1]):
                t = candidates[i, j]
                ax, ay, az = corners[t, 0, 0], corners[t, 0, 1], corners[t, 0, 2]
                bx, by, bz = corners[t, 1, 0], corners[t, 1, 1], corners[t, 1, 2]
                cx, cy, cz = corners[t, 2, 0], corners[t, 2, 1], corners[t, 2, 2]
                abx, aby, abz = bx - ax, by - ay, bz - az
                acx, acy, acz = cx - ax, cy - ay, cz - az
                d1 = abx * (px - ax) + aby * (py - ay) + abz * (pz - az)
                d2 = acx * (px - ax) + acy * (py - ay) + acz * (pz - az)
                d3 = abx * (px - bx) + aby * (py - by) + abz * (pz - bz)
                d4 = acx * (px - bx) + acy * (py - by) + acz * (pz - bz)
                d5 = abx * (px - cx) + aby * (py - cy) + abz * (pz - cz)
                d6 = acx * (px - cx) + acy * (py - cy) + acz * (pz - cz)
                va = d3 * d6 - d5 * d4
                vb = d5 * d2 - d1 * d6
                vc = d1 * d4 - d3 * d2
                if d1 <= 0 and d2 <= 0:
                    u, v, w = 1.0, 0.0, 0.0
                elif d3 >= 0 and d4 <= d3:
                    u, v, w = 0.0, 1.0, 0.0
                elif d6 >= 0 and d5 <= d6:
                    u, v, w = 0.0, 0.0, 1.0
                elif vc <= 0 and d1 >= 0 and d3 <= 0:
                    den = d1 - d3
                    v = d1 / den if abs(den) > 1e-300 else 0.0
                    u, w = 1 - v, 0.0
                elif vb <= 0 and d2 >= 0 and d6 <= 0:
                    den = d2 - d6
                    w = d2 / den if abs(den) > 1e-300 else 0.0
                    u, v = 1 - w, 0.0
                elif va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
                    den = (d4 - d3) + (d5 - d6)
                    w = (d4 - d3) / den if abs(den) > 1e-300 else 0.0
                    u, v = 0.0, 1 - w
                else:
                    den = va + vb + vc
                    if abs(den) <= 1e-300:
                        den = 1e-300
                    v = vb / den
                    w = vc / den
                    u = 1 - v - w
                qx = u * ax + v * bx + w * cx
                qy = u * ay + v * by + w * cy
                qz = u * az + v * bz + w * cz
                dist = np.sqrt((qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2)
                if dist < best:
                    best = dist
                    out_pos[i, 0], out_pos[i, 1], out_pos[i, 2] = qx, qy, qz
                    out_bary[i, 0], out_bary[i, 1], out_bary[i, 2] = u, v, w
                    out_tri[i] = t
            out_dist[i] = best

    pts = np.zeros((1, 3))
    closest_among_into(pts, np.eye(3)[None], np.zeros((1, 1), np.int64), np.empty((1, 3)),
                       np.empty(1, np.int64), np.empty((1, 3)), np.empty(1))   # compile (or load) now
    return SimpleNamespace(closest_among_into=closest_among_into)


_KERNELS = LazyKernels(_build, __file__)


def kernel(*, load: bool = False):
    """The compiled ``closest_among_into`` (see :func:`_build`), or None (use numpy). ``load``: build
    it now even where kernels are deferred (a query big enough to repay loading numba)."""
    kernels = _KERNELS.load() if load else _KERNELS.get()
    return kernels.closest_among_into if kernels is not None else None


__all__ = ["kernel"]
