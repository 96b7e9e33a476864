"""Pick latency of the landmark editor on a ~1.3M-triangle mesh.

Compares, for rays through random pixels of an off-screen view of an icosphere
(trimesh.creation.icosphere(subdivisions=8): 655,362 vertices, 1,310,720 triangles):

* vtkCellPicker with a cached vtkStaticCellLocator (app.picking.SurfacePicker, what the editor uses);
* vtkCellPicker without a locator;
* the camera ray cast in core through Face.ray_hits (trimesh + embreex when installed).

Prints build times and median / p90 per pick in milliseconds.

    .venv/bin/python benchmarks/landmark_pick.py [subdivisions]
"""

from __future__ import annotations

import sys
import time

import numpy as np


def _stats(times: list[float]) -> str:
    t = np.array(times) * 1e3
    return f"median {np.median(t):7.2f} ms   p90 {np.percentile(t, 90):7.2f} ms   (n={len(t)})"


def main(subdivisions: int = 8, n_picks: int = 60) -> None:
    import pyvista as pv
    import trimesh
    import vtk

    from app.picking import SurfacePicker, world_to_display
    from core.face import Face

    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=100.0)
    face = Face(sphere.vertices, sphere.faces)
    print(f"mesh: {face.n_vertices:,} vertices, {face.n_triangles:,} triangles")
    tris = np.asarray(face.triangles)
    cells = np.hstack([np.full((len(tris), 1), 3), tris]).ravel()
    mesh = pv.PolyData(np.array(face.vertices), faces=cells)

    plotter = pv.Plotter(off_screen=True, window_size=(1000, 800))
    actor = plotter.add_mesh(mesh, color="tan")
    plotter.view_xy()
    plotter.render()
    renderer = plotter.renderer

    rng = np.random.default_rng(0)
    centre = world_to_display(renderer, np.zeros((1, 3)))[0]
    rim = world_to_display(renderer, np.array([[70.0, 0.0, 0.0]]))[0]
    radius = abs(rim[0] - centre[0])
    angles = rng.uniform(0, 2 * np.pi, n_picks)
    radii = radius * np.sqrt(rng.uniform(0, 1, n_picks))
    pixels = np.c_[centre[0] + radii * np.cos(angles), centre[1] + radii * np.sin(angles)]

    t0 = time.perf_counter()
    picker = SurfacePicker(actor, mesh, tris)
    print(f"vtkStaticCellLocator build: {(time.perf_counter() - t0) * 1e3:.0f} ms (once per mesh state)")
    times, hits = [], []
    for x, y in pixels:
        t = time.perf_counter()
        hit = picker.pick(renderer, x, y)
        times.append(time.perf_counter() - t)
        hits.append(hit)
    print("vtkCellPicker + cached static locator:", _stats(times))

    plain = vtk.vtkCellPicker()
    plain.PickFromListOn()
    plain.AddPickList(actor)
    plain.SetTolerance(1e-6)
    times = []
    for x, y in pixels[: max(5, n_picks // 6)]:
        t = time.perf_counter()
        plain.Pick(float(x), float(y), 0.0, renderer)
        times.append(time.perf_counter() - t)
    print("vtkCellPicker without locator:       ", _stats(times))

    # Core ray cast: camera ray through the pixel.
    def ray(x, y):
        renderer.SetDisplayPoint(x, y, 0.0)
        renderer.DisplayToWorld()
        near = np.array(renderer.GetWorldPoint()[:3]) / renderer.GetWorldPoint()[3]
        renderer.SetDisplayPoint(x, y, 1.0)
        renderer.DisplayToWorld()
        far = np.array(renderer.GetWorldPoint()[:3]) / renderer.GetWorldPoint()[3]
        d = far - near
        return near, d / np.linalg.norm(d)

    import trimesh.ray

    print(f"trimesh ray backend: {'embree (embreex)' if trimesh.ray.has_embree else 'rtree/python'}")
    o, d = ray(*pixels[0])
    t0 = time.perf_counter()
    face.ray_hits(o[None], d[None])
    print(f"core Face.ray_hits first call (builds the BVH): {(time.perf_counter() - t0) * 1e3:.0f} ms")
    times = []
    agree = []
    for (x, y), hit in zip(pixels, hits):
        o, d = ray(x, y)
        t = time.perf_counter()
        loc, _idx, tri = face.ray_hits(o[None], d[None])
        times.append(time.perf_counter() - t)
        if hit is not None and len(loc):
            agree.append(np.linalg.norm(loc[0] - np.array(hit.position)))
    print("core Face.ray_hits (embree) per pick: ", _stats(times))
    if agree:
        print(f"VTK vs core hit points: max distance {max(agree):.2e} mm over {len(agree)} picks")
    plotter.close()


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 8)
