"""What a camera frames on a face: the head, not the neck or the shoulders under it.

A full head (the default face) or a bust scan carries a neck and maybe shoulders below the chin;
framed whole, the face fills half the picture. :func:`portrait_points` keeps the vertices from a
little below the chin upward, "up" and "below" measured along the face's own axis from the chin
(feature point 2.1) to the middle of the eyes (the pupils 3.5/3.6, or the four eye corners a
detection gives), so a scan lying in any orientation is cut the same way. Faces without those
points are framed whole.
"""

from __future__ import annotations

import numpy as np

# How far below the chin the frame reaches, as a share of the chin-to-eyes distance (~110 mm on an
# adult: ~15 mm, the chin's underside and the start of the neck).
BELOW_CHIN_SHARE = 0.15
_CHIN = "2.1"
_EYES = (("3.5", "3.6"), ("3.7", "3.11", "3.8", "3.12"))   # pupils, else the eye corners


def portrait_points(face, vertices: np.ndarray | None = None) -> np.ndarray:
    """(k, 3) mm: the vertices of ``face`` (or its posed ``vertices`` (n, 3)) from
    ``BELOW_CHIN_SHARE`` of the chin-to-eyes distance below the chin upward; all of them when the
    face lacks the chin or eye points or the cut would keep almost nothing."""
    x = np.asarray(face.vertices if vertices is None else vertices, dtype=float)
    names = set(face.landmark_names)
    eye_points = next((points for points in _EYES if names.issuperset(points)), None)
    if _CHIN not in names or eye_points is None:
        return x
    chin = face.landmark_position(_CHIN, x)
    eyes = face.landmark_positions(eye_points, x).mean(axis=0)
    up = eyes - chin
    span = float(np.linalg.norm(up))
    if span <= 0:
        return x
    height = (x - chin) @ (up / span)
    kept = x[height >= -BELOW_CHIN_SHARE * span]
    return kept if len(kept) >= 0.1 * len(x) else x


__all__ = ["portrait_points", "BELOW_CHIN_SHARE"]
