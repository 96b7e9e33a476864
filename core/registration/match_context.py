"""What the matcher's passes read; none of it changes while a match runs.

* ``ModelContext``: the model's side (template points, their appearance, the model's frontal
  raster), built once per model and template;
* ``MatchContext``: one match (the scan, its rigid alignment and rasters, the parameters in force),
  read by the surface passes;
* ``PixelContext``: what the passes in the scan's frontal raster read (patch search, model pixels).

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
    can_close_eyes: bool = False        # the model's FAP rig can close its lids (``eye_pass``): the built-in face


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


@dataclass(frozen=True)
class MatchContext:
    """One match's inputs, as the surface passes read them.

    model : the ModelContext. scan : the input Face in its own frame (mm).
    to_model / from_model : (4, 4) scan -> model frame and its inverse.
    rays : ``correspondence.SurfaceRays`` over the scan (its own frame).
    params : the parameters in force (λ_A = 0 for a scan without texture).
    textured : the scan has a texture (appearance uses colour as well as shape).
    fixed : (P,) bool, the user's fixed points (kept as given, never searched).
    gdist : (P, P) float, mm: shortest-path distances along G_m on the model (``greedy.graph_distances``).
    scan_raster : the scan's FrontalRaster on the model's grid; None without refinement.
    """

    model: ModelContext
    scan: Face
    to_model: np.ndarray
    from_model: np.ndarray
    rays: object
    params: MatchParams
    textured: bool
    fixed: np.ndarray
    gdist: np.ndarray
    scan_raster: FrontalRaster | None

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.template.detected

    def surface_position(self, triangle: int, bary: np.ndarray) -> np.ndarray:
        """(3,) model-frame position of one scan surface point."""
        from core.registration.icp import apply_transform

        return apply_transform((bary @ self.scan.vertices[self.scan.triangles[triangle]])[None], self.to_model)[0]

    def surface_positions(self, triangle: np.ndarray, bary: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """(P, 3) model-frame positions of the scan surface points (triangle (P,), bary (P, 3)),
        computed together; ``positions`` where triangle < 0."""
        from core.registration.icp import apply_transform

        out = positions.copy()
        ok = triangle >= 0
        p = np.einsum("pk,pkd->pd", bary[ok], self.scan.vertices[self.scan.triangles[triangle[ok]]])
        out[ok] = apply_transform(p, self.to_model)
        return out

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The scan surface points closest to model-frame points (k, 3): (triangle (k,), bary (k, 3),
        model-frame positions (k, 3))."""
        from core.registration.icp import apply_transform

        pos, tri, bary = self.rays.closest(apply_transform(points, self.from_model))
        return tri, bary, apply_transform(pos, self.to_model)


def match_context(model: ModelContext, scan: Face, to_model: np.ndarray, rays, params: MatchParams, *,
                  textured: bool, fixed: np.ndarray, gdist: np.ndarray,
                  scan_raster: FrontalRaster | None) -> MatchContext:
    return MatchContext(model, scan, to_model, np.linalg.inv(to_model), rays, params, textured, fixed, gdist,
                        scan_raster)


@dataclass(frozen=True)
class PixelContext:
    """What the passes in the scan's frontal raster read (pixels are (col, row), rows grow downwards).

    template : the landmark template. raster : the scan's FrontalRaster (depth in mm).
    model_px : (P, 2) float, the model points' pixels on the same grid.
    greedy_px : (P, 2) float, the greedy matches' pixels (where round 1 searches).
    scale : face scale, mm. params : the parameters in force. skip : (P,) bool, points not searched
    (fixed). search : the ``patches.PatchSearch`` (None only in tests of a pass that can do without).
    gdist : (P, P) float, mm, graph distances on the model (round 2's weights).
    """

    template: LandmarkTemplate
    raster: FrontalRaster
    model_px: np.ndarray
    greedy_px: np.ndarray
    scale: float
    params: MatchParams
    skip: np.ndarray
    search: object
    gdist: np.ndarray

    @property
    def radius_px(self) -> int:
        """Round 1's search radius (``refine_radius`` × scale), pixels, at least 1."""
        return max(1, int(round(self.params.refine_radius * self.scale / self.params.pixel_mm)))

    @property
    def scale_px(self) -> float:
        """The face scale in pixels."""
        return self.scale / self.params.pixel_mm


def pixel_context(ctx: MatchContext, greedy_positions: np.ndarray) -> PixelContext:
    """The pixel passes' context of a match with refinement (``ctx.scan_raster`` set)."""
    from core.registration.patches import PatchSearch, patch_halves
    from core.registration.rasters import shape_only

    m = ctx.model
    tpl = m.template
    # Without texture the model's colour channels would compare with nothing: shape only.
    model_raster = m.raster if ctx.textured else shape_only(m.raster)
    search = PatchSearch(m.side.points, model_raster, ctx.scan_raster, ctx.params, patch_halves(tpl),
                         [n in tpl.base.outline for n in tpl.detected])
    return PixelContext(tpl, ctx.scan_raster, model_raster.to_pixel(m.side.points),
                        ctx.scan_raster.to_pixel(greedy_positions), m.scale, ctx.params, ctx.fixed, search,
                        ctx.gdist)
