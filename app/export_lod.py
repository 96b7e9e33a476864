"""export_lod.py
----
The export's level of detail: a decimated face drawn where the full one's triangles are a few pixels.

On software OpenGL (Mesa llvmpipe) a 1280x720 frame of the 105k-triangle default face costs about
70 ms of vertex work and 110 ms of rasterising triangles of 2-3 pixels each (per-triangle set-up,
not shading, dominates). Where the face covers so few pixels per triangle, a face with fewer
triangles gives the same picture: :func:`export_lod` is a vertex-subset decimation of the face
(:func:`app.preview.decimate`, the window's draft level of detail, with a larger triangle budget),
driven by the rig's output through one index and shaded with the full face's normals.

It is used only where it was checked: ``benchmarks/export_lod_quality.py`` renders the export
benchmark's frames both ways and measures PSNR and SSIM over the face's region. At 1280x720, front
view (the full face's triangles 2.1 px each), 24 frames: 24k triangles fail (PSNR min 35.1 dB), 30k
pass narrowly (min 39.3 dB, SSIM min 0.989), 36k pass with margin (PSNR median 42.5 min 41.6 dB,
SSIM median 0.993 min 0.992); at 1920x1080 (4.75 px) 36k give PSNR min 41.4 dB, SSIM min 0.993.
A frame whose full face has larger triangles on screen than :data:`LOD_MAX_PIXELS_PER_TRIANGLE` (a
bigger size, a closer camera) is drawn in full, and the export option "full detail"
(``ExportSettings.full_detail``, ``mimica export --full-detail``, the export dialog's check box)
turns it off.
"""

from __future__ import annotations

import numpy as np

from app.preview import PREVIEW_VERSION, PreviewMesh, decimate, part_triangles
from core.cache import DiskCache, fingerprint

#: Triangles of the export's decimated face (12k of them the eyes, teeth and mouth, kept whole): the
#: smallest budget tried that passes SSIM >= 0.98 and PSNR >= 38 dB at the worst frame with 3 dB to spare.
EXPORT_LOD_TRIANGLES = 36_000
#: The full face's median triangle area on screen (pixels) up to which the level of detail is used:
#: checked at 2.1 px (1280x720) and 4.75 px (1920x1080), front view of the default face.
LOD_MAX_PIXELS_PER_TRIANGLE = 5.0


def pixels_per_triangle(vertices: np.ndarray, triangles: np.ndarray, projection: np.ndarray,
                        size: tuple[int, int]) -> float:
    """Median screen area (pixels) of the triangles (t, 3) of ``vertices`` (n, 3) mm in front of the
    camera, through ``projection`` (4, 4), the camera's composite projection for ``size`` (w, h)
    pixels; inf when no triangle is in front."""
    clip = vertices @ projection[:, :3].T + projection[:, 3]
    w = clip[:, 3]
    front = (w[triangles] > 1e-9).all(axis=1)
    if not front.any():
        return float("inf")
    pixel = clip[:, :2] / np.where(w > 1e-9, w, 1.0)[:, None] * (np.array(size, float) / 2.0)
    a, b, c = (pixel[triangles[front, k]] for k in range(3))
    area = 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    return float(np.median(area))


def export_lod(face, target: int = EXPORT_LOD_TRIANGLES, cache: DiskCache | None = None) -> PreviewMesh | None:
    """The export's decimated copy of ``face`` (about ``target`` triangles; its parts: eyes, teeth and
    mouth kept whole), from the disk cache when this face was seen before; None for small faces."""
    cache = cache if cache is not None else DiskCache()
    keep = part_triangles(face)
    # The parts are part of the key: the render processes get the face from a file and must find
    # (or build) the same decimation as the exporting process.
    key = fingerprint("export-lod", PREVIEW_VERSION, target, face.vertices, face.triangles, keep)
    found = cache.get("export-lod", key)
    if isinstance(found, PreviewMesh) or found is False:
        return found or None
    lod = decimate(face.vertices, face.triangles, target, keep)
    cache.put("export-lod", key, lod if lod is not None else False)
    return lod


__all__ = ["EXPORT_LOD_TRIANGLES", "LOD_MAX_PIXELS_PER_TRIANGLE", "export_lod", "pixels_per_triangle"]
