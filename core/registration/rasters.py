"""Frontal rasters of a face for the matcher: the depth, normals, texture and curvature of the surface
seen from the front on a regular grid (mm), and sampling of values at surface points."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from core.face import Face


# ------------------------------------------------------------------ frontal raster
@dataclass
class FrontalRaster:
    """A frontal (−z) orthographic raster of a face in the model frame.

    x0, y0 : model-frame coordinates of the centre of pixel (0, 0) (row 0 is the *top*, largest y).
    pixel : mm. triangle (H, W) face triangle or −1; bary (H, W, 3); channels (H, W, C) float32
    normalised to zero mean / unit std over the covered pixels (0 where uncovered).
    """

    x0: float
    y0: float
    pixel: float
    triangle: np.ndarray
    bary: np.ndarray
    channels: np.ndarray
    depth: np.ndarray | None = None    # (H, W) float, model-frame z of the surface, mm (NaN uncovered)

    def to_pixel(self, xyz) -> np.ndarray:
        """(k, 2) float (col, row) of model-frame points (k, 3)."""
        p = np.atleast_2d(np.asarray(xyz, float))
        return np.column_stack([(p[:, 0] - self.x0) / self.pixel, (self.y0 - p[:, 1]) / self.pixel])


@dataclass(frozen=True)
class Grid:
    x0: float
    y0: float
    pixel: float
    width: int
    height: int


def grid_for(points: np.ndarray, pixel: float, margin: float = 15.0) -> Grid:
    lo, hi = points.min(axis=0) - margin, points.max(axis=0) + margin
    w = int(np.ceil((hi[0] - lo[0]) / pixel)) + 1
    h = int(np.ceil((hi[1] - lo[1]) / pixel)) + 1
    return Grid(float(lo[0]), float(hi[1]), pixel, w, h)


def frontal_raster(face: Face, rays, to_model: np.ndarray, grid: Grid, *, texture: bool = True) -> FrontalRaster:
    """Rasterise ``face`` seen from +z of the model frame; ``to_model`` (4, 4) maps face -> model.

    ``rays`` is a ``correspondence.SurfaceRays`` over the face's own (unmoved) vertices: the rays
    are moved into the face's frame instead of moving the face (one Embree scene per scan)."""
    from core.registration.correspondence import _barycentric

    cols, rows = np.meshgrid(np.arange(grid.width), np.arange(grid.height))
    x = grid.x0 + cols.ravel() * grid.pixel
    y = grid.y0 - rows.ravel() * grid.pixel
    R, t = to_model[:3, :3], to_model[:3, 3]
    inv_R = R.T
    top = (face.vertices @ R.T + t)[:, 2].max() + 50.0
    origins = np.column_stack([x, y, np.full_like(x, top)])
    o_face = (origins - t) @ inv_R.T
    d_face = np.broadcast_to(np.array([0.0, 0.0, -1.0]) @ inv_R.T, o_face.shape)
    if rays.engine == "embree":
        pos, local, hit = rays.first_hits(o_face, np.ascontiguousarray(d_face))
        tri = np.where(hit, rays.ids[np.maximum(local, 0)], -1)
    else:  # no Embree: nearest vertex in the frontal plane (coarse but workable)
        from scipy.spatial import cKDTree

        vm = face.vertices @ R.T + t
        d, idx = cKDTree(vm[:, :2]).query(np.column_stack([x, y]), distance_upper_bound=2 * grid.pixel)
        hit = np.isfinite(d)
        vt = np.full(face.n_vertices, -1)
        vt[face.triangles[:, 0]] = np.arange(face.n_triangles)
        tri = np.where(hit, vt[np.minimum(idx, face.n_vertices - 1)], -1)
        hit &= tri >= 0
        pos = np.where(hit[:, None], face.vertices[np.minimum(idx, face.n_vertices - 1)], 0.0)
    bary = np.zeros((len(x), 3))
    if hit.any():
        bary[hit] = _barycentric(face.vertices[face.triangles[tri[hit]]], pos[hit])
    H, W = grid.height, grid.width
    chans = []
    corners = face.triangles[np.maximum(tri, 0)]
    nrm = np.einsum("kj,kjd->kd", bary, face.vertex_normals[corners]) @ R.T
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    chans += [nrm[:, 0], nrm[:, 1], nrm[:, 2]]
    if texture and face.texture is not None and face.uv is not None:
        import cv2

        uv = np.einsum("kj,kjd->kd", bary, face.uv[corners])
        th, tw = face.texture.shape[:2]
        mx = (uv[:, 0] * tw - 0.5).astype(np.float32).reshape(H, W)
        my = ((1.0 - uv[:, 1]) * th - 0.5).astype(np.float32).reshape(H, W)
        rgb = cv2.remap(face.texture.astype(np.float32) / 255.0, mx, my, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)
        grey = rgb @ np.array([0.299, 0.587, 0.114])
        chroma = rgb[:, 0] - rgb[:, 1]
        chans += [grey, chroma]
    ch = np.column_stack(chans).astype(np.float32)
    ok = hit
    if ok.sum() > 10:
        mean = ch[ok].mean(axis=0)
        std = np.maximum(ch[ok].std(axis=0), 1e-6)
        ch = (ch - mean) / std
        # Shape weighs less than texture when both exist (3 normal channels vs 2 colour channels).
        if ch.shape[1] == 5:
            ch[:, :3] *= 0.5
    ch[~ok] = 0.0
    depth = np.full(len(x), np.nan)
    if hit.any():
        depth[hit] = pos[hit] @ R[2] + t[2]
    return FrontalRaster(grid.x0, grid.y0, grid.pixel, tri.reshape(H, W), bary.reshape(H, W, 3),
                         ch.reshape(H, W, -1), depth.reshape(H, W))


# ------------------------------------------------------------------ model / input features
@dataclass
class Side:
    """One side of the matching: points (k, 3) in the model frame, colours (k, 3) in [0, 1],
    HK colours (k, 3) in [0, 1]."""

    points: np.ndarray
    colour: np.ndarray
    hk: np.ndarray


def sample_texture(face: Face, triangle: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """(k, 3) RGB in [0, 1] of the texture (or vertex colours; 0.5 grey when none) at surface points."""
    triangle = np.asarray(triangle, np.int64)
    if face.texture is not None and face.uv is not None:
        import cv2

        uv = np.einsum("kj,kjd->kd", bary, face.uv[face.triangles[triangle]])
        th, tw = face.texture.shape[:2]
        mx = (uv[:, 0] * tw - 0.5).astype(np.float32)[None]
        my = ((1.0 - uv[:, 1]) * th - 0.5).astype(np.float32)[None]
        return cv2.remap(face.texture.astype(np.float32) / 255.0, mx, my, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)[0].astype(float)
    if face.vertex_colors is not None:
        return np.einsum("kj,kjd->kd", bary, face.vertex_colors[face.triangles[triangle]].astype(float) / 255.0)
    return np.full((len(triangle), 3), 0.5)


def sample_vertex_values(face: Face, values: np.ndarray, triangle, bary) -> np.ndarray:
    return np.einsum("kj,kjd->kd", bary, np.asarray(values, float)[face.triangles[np.asarray(triangle, np.int64)]])


def raster_hit(raster: FrontalRaster | None, p: np.ndarray):
    """(triangle, bary) of the scan surface seen at the frontal pixel of ``p`` (3,), or None."""
    if raster is None:
        return None
    c, r = np.round(raster.to_pixel(p)[0]).astype(int)
    if not (0 <= r < raster.triangle.shape[0] and 0 <= c < raster.triangle.shape[1]) or raster.triangle[r, c] < 0:
        return None
    return int(raster.triangle[r, c]), raster.bary[r, c]


def shape_only(r: FrontalRaster) -> FrontalRaster:
    """``r`` with its surface-normal channels only (no colour: for a scan without texture)."""
    return FrontalRaster(r.x0, r.y0, r.pixel, r.triangle, r.bary, np.ascontiguousarray(r.channels[..., :3]))
