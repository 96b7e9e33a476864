"""Caricatures (thesis A §4.3): a face's difference from a population's mean face, scaled.

The mean face is the per-vertex mean of registered neutral faces (same canonical topology),
after generalised Procrustes alignment (each face aligned rigidly onto the running mean, three
rounds, no scale). A caricature of ``face`` with exaggeration e (a fraction: −1 … +2 for
−100 % … +200 %) is

    x = face + e · (face − mean)          (mean aligned rigidly onto face first)

so e = 0 is the face, e = −1 the mean face, e > 0 exaggerates what makes the face itself.
"""

from __future__ import annotations

import numpy as np

from core.layers.blend.library import LibraryError, _points, rigid_align

__all__ = ["mean_face", "caricature", "EXAGGERATION_RANGE"]

#: Allowed exaggeration, as a fraction (the ``caricature`` parameter is this × 100 %).
EXAGGERATION_RANGE = (-1.0, 2.0)


def mean_face(faces, *, rounds: int = 3) -> np.ndarray:
    """(n, 3) mm: the mean of registered faces (m, n, 3) (or Faces), in the first face's frame."""
    arrays = [_points(getattr(f, "vertices", f), f"face {i}") for i, f in enumerate(faces)]
    if not arrays:
        raise LibraryError("the mean face needs at least one registered face")
    n = len(arrays[0])
    for i, a in enumerate(arrays):
        if len(a) != n:
            raise LibraryError(f"face {i} has {len(a)} vertices, face 0 has {n}: register all faces with the same template")
    mean = arrays[0].copy()
    for _ in range(int(rounds)):
        aligned = [rigid_align(a, mean, robust=False)[0] for a in arrays]
        new = np.mean(aligned, axis=0)
        mean = rigid_align(new, arrays[0], robust=False)[0]   # keep the first face's frame
    return mean


def caricature(face, mean, exaggeration: float) -> np.ndarray:
    """(n, 3) mm: ``face`` (n, 3) exaggerated away from ``mean`` (n, 3) by ``exaggeration`` (a
    fraction within :data:`EXAGGERATION_RANGE`; LibraryError outside it, never clamped)."""
    f = _points(getattr(face, "vertices", face), "face")
    m = _points(mean, "mean face", len(f))
    e = float(exaggeration)
    lo, hi = EXAGGERATION_RANGE
    if not np.isfinite(e) or not lo <= e <= hi:
        raise LibraryError(f"exaggeration must be within {lo:g} … {hi:g} (−100 % … +200 %), got {exaggeration!r}")
    m_aligned = rigid_align(m, f, robust=False)[0]
    return f + e * (f - m_aligned)
