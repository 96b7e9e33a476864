"""Spring kernels of the tissue solver: numba when available, numpy otherwise.

Both kernels loop over springs (i, j, stiffness k dyn/cm, rest length l0 cm) of points
``x`` (n, 3) cm and accumulate into ``out`` (n, 3):

- ``spring_forces``: g_ij of thesis C eq. 3.3 with the sign of a force, k (l - l0) (x_j - x_i) / l on i
  and the opposite on j (dyn);
- ``projection_rhs``: the local step of projective dynamics, k d on i and -k d on j with
  d = l0 (x_i - x_j) / l, the spring's current direction at its rest length (dyn).

Numba compiles on first use (``cache=True`` stores the machine code under ``__pycache__``, so
later processes load it in milliseconds); set ``MIMICA_NO_NUMBA=1`` to force the numpy path.
``compile_seconds`` reports what the first call cost in this process.
"""

from __future__ import annotations

import os
import time

import numpy as np

compile_seconds: float | None = None  # measured on the first numba call of this process


def _numpy_spring_forces(x, si, sj, k, l0, out):
    d = x[sj] - x[si]
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    scale = np.divide(k * (length - l0), length, out=np.zeros_like(length), where=length > 1e-12)
    f = d * scale[:, None]
    n = len(out)
    for c in range(3):
        out[:, c] += np.bincount(si, f[:, c], minlength=n) - np.bincount(sj, f[:, c], minlength=n)


def _numpy_projection_rhs(x, si, sj, k, l0, out):
    d = x[si] - x[sj]
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    scale = np.divide(k * l0, length, out=np.zeros_like(length), where=length > 1e-12)
    f = d * scale[:, None]
    n = len(out)
    for c in range(3):
        out[:, c] += np.bincount(si, f[:, c], minlength=n) - np.bincount(sj, f[:, c], minlength=n)


def _numpy_prism_dv(x, tri, n, V0, out):
    a, b, c = x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    h = np.linalg.norm(x[tri] - x[n + tri], axis=2).mean(axis=1)
    dv = area * h - V0
    out += np.bincount(tri.ravel(), np.repeat(dv, 3), minlength=len(out))


def _numpy_prism_shape(x, prisms, w, r0, out):
    p = x[prisms]                                            # (M, 6, 3)
    r = p - p.mean(axis=1, keepdims=True)
    f = -(w[:, None, None] * (r - r0)).reshape(-1, 3)
    idx = prisms.ravel()
    n = len(out)
    for c in range(3):
        out[:, c] += np.bincount(idx, f[:, c], minlength=n)


def _spring_energy(x, si, sj, k, l0) -> float:
    """Elastic energy of the springs (erg = dyn·cm)."""
    length = np.linalg.norm(x[si] - x[sj], axis=1)
    return float(0.5 * np.sum(k * (length - l0) ** 2))


_numba_forces = _numba_rhs = _numba_prism = _numba_csr3 = _numba_prism_shape = _numba_energy = None
if not os.environ.get("MIMICA_NO_NUMBA"):
    try:
        import numba

        @numba.njit(cache=True, fastmath=False, nogil=True)
        def _numba_forces(x, si, sj, k, l0, out):  # pragma: no cover - compiled
            for e in range(si.shape[0]):
                i = si[e]
                j = sj[e]
                dx = x[j, 0] - x[i, 0]
                dy = x[j, 1] - x[i, 1]
                dz = x[j, 2] - x[i, 2]
                length = np.sqrt(dx * dx + dy * dy + dz * dz)
                if length > 1e-12:
                    s = k[e] * (length - l0[e]) / length
                    out[i, 0] += s * dx
                    out[i, 1] += s * dy
                    out[i, 2] += s * dz
                    out[j, 0] -= s * dx
                    out[j, 1] -= s * dy
                    out[j, 2] -= s * dz

        @numba.njit(cache=True, fastmath=False, nogil=True)
        def _numba_rhs(x, si, sj, k, l0, out):  # pragma: no cover - compiled
            for e in range(si.shape[0]):
                i = si[e]
                j = sj[e]
                dx = x[i, 0] - x[j, 0]
                dy = x[i, 1] - x[j, 1]
                dz = x[i, 2] - x[j, 2]
                length = np.sqrt(dx * dx + dy * dy + dz * dz)
                if length > 1e-12:
                    s = k[e] * l0[e] / length
                    out[i, 0] += s * dx
                    out[i, 1] += s * dy
                    out[i, 2] += s * dz
                    out[j, 0] -= s * dx
                    out[j, 1] -= s * dy
                    out[j, 2] -= s * dz

        @numba.njit(cache=True, fastmath=False, nogil=True)
        def _numba_prism_shape(x, prisms, w, r0, out):  # pragma: no cover - compiled
            for t in range(prisms.shape[0]):
                c0 = 0.0
                c1 = 0.0
                c2 = 0.0
                for a in range(6):
                    q = prisms[t, a]
                    c0 += x[q, 0]
                    c1 += x[q, 1]
                    c2 += x[q, 2]
                c0 /= 6.0
                c1 /= 6.0
                c2 /= 6.0
                wt = w[t]
                for a in range(6):
                    q = prisms[t, a]
                    out[q, 0] -= wt * (x[q, 0] - c0 - r0[t, a, 0])
                    out[q, 1] -= wt * (x[q, 1] - c1 - r0[t, a, 1])
                    out[q, 2] -= wt * (x[q, 2] - c2 - r0[t, a, 2])

        @numba.njit(cache=True, fastmath=False, nogil=True)
        def _numba_energy(x, si, sj, k, l0, prisms, w, r0):  # pragma: no cover - compiled
            e = 0.0
            for s in range(si.shape[0]):
                i = si[s]
                j = sj[s]
                dx = x[j, 0] - x[i, 0]
                dy = x[j, 1] - x[i, 1]
                dz = x[j, 2] - x[i, 2]
                d = np.sqrt(dx * dx + dy * dy + dz * dz) - l0[s]
                e += 0.5 * k[s] * d * d
            for t in range(prisms.shape[0]):
                c0 = 0.0
                c1 = 0.0
                c2 = 0.0
                for a in range(6):
                    q = prisms[t, a]
                    c0 += x[q, 0]
                    c1 += x[q, 1]
                    c2 += x[q, 2]
                c0 /= 6.0
                c1 /= 6.0
                c2 /= 6.0
                acc = 0.0
                for a in range(6):
                    q = prisms[t, a]
                    u0 = x[q, 0] - c0 - r0[t, a, 0]
                    u1 = x[q, 1] - c1 - r0[t, a, 1]
                    u2 = x[q, 2] - c2 - r0[t, a, 2]
                    acc += u0 * u0 + u1 * u1 + u2 * u2
                e += 0.5 * w[t] * acc
            return e

        @numba.njit(cache=True, fastmath=False, nogil=True)
        def _numba_csr3(indptr, indices, data, x, out):  # pragma: no cover - compiled
            for i in range(out.shape[0]):
                a0 = 0.0
                a1 = 0.0
                a2 = 0.0
                for p in range(indptr[i], indptr[i + 1]):
                    j = indices[p]
                    v = data[p]
                    a0 += v * x[j, 0]
                    a1 += v * x[j, 1]
                    a2 += v * x[j, 2]
                out[i, 0] = a0
                out[i, 1] = a1
                out[i, 2] = a2

        @numba.njit(cache=True, fastmath=False, nogil=True)
        def _numba_prism(x, tri, n, V0, out):  # pragma: no cover - compiled
            for t in range(tri.shape[0]):
                a = tri[t, 0]
                b = tri[t, 1]
                c = tri[t, 2]
                ux = x[b, 0] - x[a, 0]
                uy = x[b, 1] - x[a, 1]
                uz = x[b, 2] - x[a, 2]
                vx = x[c, 0] - x[a, 0]
                vy = x[c, 1] - x[a, 1]
                vz = x[c, 2] - x[a, 2]
                cx = uy * vz - uz * vy
                cy = uz * vx - ux * vz
                cz = ux * vy - uy * vx
                area = 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)
                h = 0.0
                for q in (a, b, c):
                    dx = x[q, 0] - x[n + q, 0]
                    dy = x[q, 1] - x[n + q, 1]
                    dz = x[q, 2] - x[n + q, 2]
                    h += np.sqrt(dx * dx + dy * dy + dz * dz)
                dv = area * h / 3.0 - V0[t]
                out[a] += dv
                out[b] += dv
                out[c] += dv
    except Exception:  # numba missing or broken: numpy path
        _numba_forces = _numba_rhs = _numba_prism = _numba_csr3 = _numba_prism_shape = _numba_energy = None

HAVE_NUMBA = _numba_forces is not None


def _first_call(fn, *args):
    global compile_seconds
    t0 = time.perf_counter()
    fn(*args)
    if compile_seconds is None:
        compile_seconds = time.perf_counter() - t0


class SpringKernels:
    """The spring kernels (and the prism-volume sum) bound to one backend ("numba" or "numpy").

    ``prism_shape(x, prisms, w, r0, out)`` adds the k2 force of eq. 3.7, -w (r - r0) with
    r = p - centroid, for every prism (M, 6) node ids, weights w (M,) dyn/cm, rest vectors
    r0 (M, 6, 3) cm. ``matvec3(A, x)`` is a csr matrix times an (m, 3) array. ``prism_dv(x, tri, n, V0, out)`` adds to ``out`` (n,) the volume change (cm^3) of every
    skin-fascia prism (right prism: skin triangle area x mean skin-fascia edge) at its 3 columns.
    """

    def __init__(self, backend: str | None = None):
        if backend is None:
            backend = "numba" if HAVE_NUMBA else "numpy"
        if backend == "numba" and not HAVE_NUMBA:
            raise ValueError("numba is not available; use backend='numpy'")
        if backend not in ("numba", "numpy"):
            raise ValueError(f"unknown spring kernel backend {backend!r}; choose 'numba' or 'numpy'")
        self.backend = backend
        if backend == "numba":
            self.forces, self.rhs, self.prism_dv = _numba_forces, _numba_rhs, _numba_prism
            self._csr3 = _numba_csr3
            self.prism_shape = _numba_prism_shape
            self._energy = _numba_energy
            # Compile (or load from cache) now, on a tiny problem, so the first tick is not slow.
            x = np.zeros((2, 3))
            x[1, 0] = 1.0
            ij = np.array([0], np.int64), np.array([1], np.int64)
            kk = np.ones(1), np.ones(1)
            _first_call(self.forces, x, *ij, *kk, np.zeros((2, 3)))
            self.rhs(x, *ij, *kk, np.zeros((2, 3)))
            x6 = np.zeros((6, 3))
            x6[1, 0] = x6[2, 1] = 1.0
            self.prism_dv(x6, np.array([[0, 1, 2]], np.int64), 3, np.zeros(1), np.zeros(6))
            self._csr3(np.array([0, 1]), np.array([0]), np.ones(1), x, np.zeros((1, 3)))
            self.prism_shape(x6, np.array([[0, 1, 2, 3, 4, 5]], np.int64), np.ones(1), np.zeros((1, 6, 3)),
                             np.zeros((6, 3)))
            self._energy(x6, *ij, *kk, np.array([[0, 1, 2, 3, 4, 5]], np.int64), np.ones(1), np.zeros((1, 6, 3)))
        else:
            self._csr3 = None
            self._energy = None
            self.prism_shape = _numpy_prism_shape
            self.forces, self.rhs, self.prism_dv = _numpy_spring_forces, _numpy_projection_rhs, _numpy_prism_dv

    energy = staticmethod(_spring_energy)

    def elastic_energy(self, x, si, sj, k, l0, prisms, w, r0) -> float:
        """Springs + prism k2 energy (erg) at points ``x`` (see ``prism_shape``)."""
        if self._energy is not None:
            return float(self._energy(x, si, sj, k, l0, prisms, w, r0))
        p = x[prisms]
        r = p - p.mean(axis=1, keepdims=True) - r0
        return _spring_energy(x, si, sj, k, l0) + 0.5 * float(np.einsum("t,tak,tak->", w, r, r))

    def matvec3(self, A, x: np.ndarray) -> np.ndarray:
        """(n, 3) = A @ x for a csr matrix A (n, m) and x (m, 3) (numba: about 2x scipy's)."""
        if self._csr3 is None:
            return np.asarray(A @ x)
        out = np.empty((A.shape[0], 3))
        self._csr3(A.indptr, A.indices, A.data, np.ascontiguousarray(x), out)
        return out
