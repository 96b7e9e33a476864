"""World to screen: where a 3-D point lands on the render window (no Qt, usable off screen)."""

from __future__ import annotations

import numpy as np

__all__ = ["world_to_display", "display_to_world", "display_ray", "closest_on_line"]


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


def _composite(renderer) -> np.ndarray:
    camera = renderer.GetActiveCamera()
    m = camera.GetCompositeProjectionTransformMatrix(renderer.GetTiledAspectRatio(), -1.0, 1.0)
    return np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])


def display_to_world(renderer, x: float, y: float, depth: float) -> np.ndarray:
    """(3,) world point at display x, y (device pixels, origin bottom-left) and depth in [0, 1]: the inverse
    of :func:`world_to_display`. A fixed depth is a plane parallel to the view plane (also in perspective)."""
    width, height = renderer.GetSize()
    ox, oy = renderer.GetOrigin()
    ndc = np.array([2.0 * (x - ox) / width - 1.0, 2.0 * (y - oy) / height - 1.0, 2.0 * depth - 1.0, 1.0])
    homo = np.linalg.solve(_composite(renderer), ndc)
    return homo[:3] / homo[3]


def display_ray(renderer, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """(origin, unit direction) of the ray under display pixel (x, y), from the near plane into the scene."""
    near, far = display_to_world(renderer, x, y, 0.0), display_to_world(renderer, x, y, 1.0)
    d = far - near
    return near, d / np.linalg.norm(d)


def closest_on_line(origin, direction, ray_origin, ray_direction, *, min_sine: float = 0.05) -> float | None:
    """t such that ``origin + t * direction`` (unit direction) is the line's point nearest the ray; None when
    the line runs almost along the ray (sine of their angle below ``min_sine``: the point would fly off)."""
    a, b = np.asarray(direction, float), np.asarray(ray_direction, float)
    w = np.asarray(origin, float) - np.asarray(ray_origin, float)
    ab = float(a @ b)
    denom = 1.0 - ab * ab
    if denom < min_sine ** 2:
        return None
    return float((ab * (b @ w) - a @ w) / denom)
