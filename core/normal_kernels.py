"""Area-weighted vertex normals in one compiled pass (numba), for :class:`core.face.VertexNormals`.

Per slider tick the viewport needs the normals of the posed face: with numpy that is nine gathers,
a cross product and a sparse product, ~5-10 ms for the 105k-triangle default face; this loop does
the same sums in ~1 ms. Built lazily (:mod:`core.lazy_numba`; ``cache=True`` keeps the machine code
under ``__pycache__``): :func:`kernel` gives the loop, or None when numba is missing, disabled
(``MIMICA_NO_NUMBA=1``) or deferred (the window's first frames use numpy).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from core.lazy_numba import LazyKernels


def _build(numba) -> SimpleNamespace:
    @numba.njit(cache=True, nogil=True)
    def vertex_normals_into(v, tri, out):  # pragma: no cover - compiled
        """v (n, 3) float64, tri (m, 3) int64 -> out (n, 3) unit normals (0 for isolated vertices)."""
        out[:] = 0.0
        for t in range(tri.shape[0]):
            a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
            e1x, e1y, e1z = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
            e2x, e2y, e2z = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
            nx = e1y * e2z - e1z * e2y   # length = 2 * area: area weighting for free
            ny = e1z * e2x - e1x * e2z
            nz = e1x * e2y - e1y * e2x
            for k in (a, b, c):
                out[k, 0] += nx
                out[k, 1] += ny
                out[k, 2] += nz
        for i in range(out.shape[0]):
            length = np.sqrt(out[i, 0] ** 2 + out[i, 1] ** 2 + out[i, 2] ** 2)
            if length > 0.0:
                out[i, 0] /= length
                out[i, 1] /= length
                out[i, 2] /= length
        return out

    v = np.eye(3)
    vertex_normals_into(v, np.array([[0, 1, 2]], dtype=np.int64), np.empty_like(v))   # compile (or load) now
    return SimpleNamespace(vertex_normals_into=vertex_normals_into)


_KERNELS = LazyKernels(_build, __file__)


def kernel():
    """The compiled ``vertex_normals_into(v (n, 3) float64, tri (m, 3) int64, out (n, 3))``, or None
    (use numpy)."""
    kernels = _KERNELS.get()
    return kernels.vertex_normals_into if kernels is not None else None


def warm_up() -> None:
    """Compile (or load the cached machine code of) the loop now, e.g. on a background thread, so the
    first slider tick does not pay for it."""
    _KERNELS.load()


__all__ = ["kernel", "warm_up"]
