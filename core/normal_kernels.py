"""Area-weighted vertex normals in one compiled pass (numba), for :class:`core.face.VertexNormals`.

Per slider tick the viewport needs the normals of the posed face: with numpy that is nine gathers,
a cross product and a sparse product, ~5-10 ms for the 105k-triangle default face; this loop does
the same sums in ~1 ms. Numba compiles on first use (``cache=True`` keeps the machine code under
``__pycache__``); without numba, or with ``MIMICA_NO_NUMBA=1``, :func:`vertex_normals_into` is None
and the numpy path is used.
"""

from __future__ import annotations

import os

import numpy as np

vertex_normals_into = None

if not os.environ.get("MIMICA_NO_NUMBA"):
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is a dependency; the numpy path still works
        numba = None
    if numba is not None:
        @numba.njit(cache=True, nogil=True)
        def _vertex_normals_into(v, tri, out):  # pragma: no cover - compiled
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

        vertex_normals_into = _vertex_normals_into



def warm_up() -> None:
    """Compile (or load the cached machine code of) the kernel now, e.g. on a loader thread, so the
    first slider tick does not pay for it."""
    if vertex_normals_into is not None:
        v = np.eye(3)
        vertex_normals_into(v, np.array([[0, 1, 2]], dtype=np.int64), np.empty_like(v))


__all__ = ["vertex_normals_into", "warm_up"]
