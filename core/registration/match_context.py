"""What the matcher's passes read; none of it changes while a match runs.

* ``ModelContext``: the model's side (template points, their appearance, the model's frontal
  raster), built once per model and template.

Frames: the model frame is the model's own, in mm; the scan is aligned to it by ``to_model``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.face import Face, SurfacePoint
from core.registration.templates import LandmarkTemplate
from core.registration.rasters import (FrontalRaster, Grid, Side, frontal_raster, grid_for, sample_texture,
                                       sample_vertex_values)
from core.registration.greedy import face_scale
from core.registration.match_params import HK_SMOOTHING_MM, MatchParams


@dataclass
class ModelContext:
    """Everything about the model that does not change between inputs (build once per model)."""

    face: Face
    template: LandmarkTemplate
    side: Side
    scale: float
    grid: Grid
    raster: FrontalRaster
    surface: list            # per detected point: SurfacePoint on the model
    normals: np.ndarray | None = None   # (P, 3) unit model surface normals at the points


def model_context(model: Face, template: LandmarkTemplate, params: MatchParams) -> ModelContext:
    """Template points on ``model`` (its landmarks, derived points computed), their appearance, the
    model's frontal raster."""
    from core.registration.correspondence import SurfaceRays
    from core.registration.curvature import hk_maps
    from core.registration.templates import template_positions

    pos = template_positions(model, template.name)
    pts = np.array([pos[p] for p in template.detected])
    _, tri, bary = model.closest_surface_points(pts)
    hk = hk_maps(model, smoothing_mm=HK_SMOOTHING_MM)
    side = Side(pts, sample_texture(model, tri, bary), sample_vertex_values(model, hk.colours / 255.0, tri, bary))
    scale = face_scale(pos, pts)
    grid = grid_for(pts, params.pixel_mm, margin=0.25 * scale)
    rays = SurfaceRays(model.vertices, model.triangles)
    raster = frontal_raster(model, rays, np.eye(4), grid)
    surface = [SurfacePoint(int(t), tuple(b)) for t, b in zip(tri, bary)]
    nrm = (bary[:, :, None] * model.vertex_normals[model.triangles[tri]]).sum(axis=1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    return ModelContext(model, template, side, scale, grid, raster, surface, nrm)
