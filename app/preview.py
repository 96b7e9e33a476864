"""preview.py
----
The face's draft level of detail: what the viewport draws while something moves.

Software OpenGL (Mesa llvmpipe: VMs, remote desktops, laptops without a GPU driver) spends its time
per triangle: the 105k-triangle default face takes 250-500 ms a frame at any window size, a 20k one
a fifth of that. While a slider, a preset, the playhead or the camera moves, the viewport shows a
decimated copy and draws the full face once input pauses (:mod:`app.viewport`).

The copy's vertices are a *subset* of the face's (VTK's vertex-deleting ``vtkDecimatePro``, which
never merges separate pieces such as the two lips), so the rig's output drives it through one
index: ``preview_vertices = vertices[preview.index]``. Building it takes about a second for the
default face; it runs in the background and is kept in the disk cache (:mod:`core.cache`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyvista as pv

from core.cache import DiskCache, fingerprint

PREVIEW_TRIANGLES = 24_000   # ~4x fewer than the default face (12k of them its eyes, teeth and mouth)
MIN_REDUCTION = 2.0          # a face under 2x the target is drawn as it is
PREVIEW_VERSION = 2          # bump when the decimation below changes


@dataclass(frozen=True)
class PreviewMesh:
    """index : (m,) int, the face vertices kept; triangles : (k, 3) int into ``index``."""

    index: np.ndarray
    triangles: np.ndarray

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)


def decimate(vertices: np.ndarray, triangles: np.ndarray, target: int = PREVIEW_TRIANGLES,
             keep: np.ndarray | None = None) -> PreviewMesh | None:
    """A vertex-subset decimation of the mesh to about ``target`` triangles, or None when the mesh
    is already within ``MIN_REDUCTION`` of it (or VTK cannot reduce it).

    ``keep`` (t,) bool marks triangles kept as they are (small rigid parts: eyeballs, teeth, the
    mouth cavity, which a uniform decimation would erase); the rest share what is left of ``target``.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.int64)
    keep = np.zeros(len(triangles), bool) if keep is None else np.asarray(keep, bool)
    if len(triangles) < MIN_REDUCTION * target or len(vertices) == 0:
        return None
    reducible = triangles[~keep]
    budget = max(target - int(keep.sum()), target // 4)
    mesh = pv.PolyData.from_regular_faces(vertices, reducible)
    mesh.point_data["vertex_id"] = np.arange(len(vertices), dtype=np.int64)
    mesh = mesh.clean(point_merging=False)   # drop the vertices of the kept parts (ids follow)
    reduced = mesh.decimate_pro(1.0 - budget / len(reducible), preserve_topology=True)
    if reduced.n_cells == 0:
        return None
    # decimate_pro only deletes vertices and carries the kept ones' point data: their ids (not
    # their positions, which coincide where the lips meet) say which face vertex each one is.
    ids = np.asarray(reduced.point_data["vertex_id"], dtype=np.int64)
    if not np.allclose(np.asarray(reduced.points), vertices[ids]):
        return None
    reduced_tris = ids[reduced.regular_faces.astype(np.int64)]
    all_tris = np.concatenate([reduced_tris, triangles[keep]])
    if len(all_tris) > len(triangles) / MIN_REDUCTION:
        return None
    index, local = np.unique(all_tris, return_inverse=True)
    return PreviewMesh(index.astype(np.int64), local.reshape(-1, 3).astype(np.int64))


def part_triangles(face) -> np.ndarray:
    """(t,) bool: triangles all of whose vertices are in one of the face's parts (eyes, teeth, mouth)."""
    in_part = np.zeros(face.n_vertices, bool)
    for idx in face.parts.values():
        in_part[idx] = True
    return in_part[np.asarray(face.triangles)].all(axis=1)


def cached_preview(face, cache: DiskCache | None = None, target: int = PREVIEW_TRIANGLES) -> PreviewMesh | None:
    """:func:`decimate` of ``face``, from the disk cache when this face was seen before."""
    cache = cache if cache is not None else DiskCache()
    key = fingerprint(PREVIEW_VERSION, target, face.vertices, face.triangles)
    found = cache.get("preview", key)
    if isinstance(found, PreviewMesh):
        return found
    if found is not None or cache.get("preview-none", key) is not None:
        return None
    preview = decimate(face.vertices, face.triangles, target, part_triangles(face))
    if preview is None:
        cache.put("preview-none", key, True)   # small faces: no need to try again
    else:
        cache.put("preview", key, preview)
    return preview


__all__ = ["PREVIEW_TRIANGLES", "PreviewMesh", "cached_preview", "decimate", "part_triangles"]
