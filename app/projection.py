"""World to screen: where a 3-D point lands on the render window (no Qt, usable off screen)."""

from __future__ import annotations

import numpy as np

__all__ = ["world_to_display"]


def world_to_display(renderer, points) -> np.ndarray:
    """(k, 3): display x, y (VTK device pixels, origin bottom-left) and depth in [0, 1] of world points (k, 3)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    camera = renderer.GetActiveCamera()
    aspect = renderer.GetTiledAspectRatio()
    m = camera.GetCompositeProjectionTransformMatrix(aspect, -1.0, 1.0)
    mat = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
    homo = np.c_[pts, np.ones(len(pts))] @ mat.T
    ndc = homo[:, :3] / homo[:, 3:4]
    width, height = renderer.GetSize()
    ox, oy = renderer.GetOrigin()
    x = (ndc[:, 0] + 1.0) * 0.5 * width + ox
    y = (ndc[:, 1] + 1.0) * 0.5 * height + oy
    return np.c_[x, y, (ndc[:, 2] + 1.0) * 0.5]
