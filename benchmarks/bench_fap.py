"""What one FAP slider tick costs to compute, on a registered face and on the default face.

A tick is what the window does when a FAP slider moves: ``rig.set_fap`` (validation, events) and
``rig.vertices()`` (the FAT product, lid contact, eyeball and head rigid motions); "+ normals" adds
the vertex normals the viewport needs. Printed for the 4560-vertex canonical face (the default face
registered onto the template, as ``mimica register`` makes it) and the 53,772-vertex default face:

    fap_tick_ms median=<x> vertices=<n>
    fap_tick_normals_ms median=<x> vertices=<n>

then the window's whole per-tick compute on the default face, stage by stage (``stage_ms``: rig,
normals, the face actor's arrays including its draft copy, the heat-map overlay), and its total
``window_tick_ms``. Goals: 0.5 ms at 4560, 2 ms at 54k, + normals 5 ms; window tick 10 ms.
Each line also gives the ratio to its goal (< 1 meets it).

Usage: python benchmarks/bench_fap.py [--repeats 200]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from core.cache import DiskCache  # noqa: E402
from core.default_face import load_default_face  # noqa: E402
from core.face import VertexNormals  # noqa: E402
from core.rig import FaceRig  # noqa: E402

GOALS_MS = {"fap_tick_ms": {4560: 0.5, None: 2.0}, "fap_tick_normals_ms": {None: 5.0}, "window_tick_ms": {None: 10.0}}


def goal(name: str, n: int) -> float:
    table = GOALS_MS[name]
    return table.get(n, table[None])


def ticks(rig: FaceRig, repeats: int, rng, normals: VertexNormals | None = None) -> np.ndarray:
    """Seconds per tick: one animated FAP set to a new value, then the pose (and its normals)."""
    faps = [f for f in rig.animated_faps if f not in (48, 49, 50)]
    out = np.empty(repeats)
    for i in range(repeats):
        number = int(rng.choice(faps))
        p = rig.describe(f"fap:{number}")
        lo, hi = p.minimum, p.maximum
        value = float(rng.uniform(lo, hi) * 0.5)
        start = time.perf_counter()
        rig.set_fap(number, value)
        v = rig.vertices()
        if normals is not None:
            normals(v)
        out[i] = time.perf_counter() - start
    return out


def report(name: str, seconds: np.ndarray, n: int) -> None:
    ms = float(np.median(seconds) * 1e3)
    print(f"{name} median={ms:.3f} vertices={n}  (goal {goal(name, n)} ms, ratio {ms / goal(name, n):.2f})")


def window_stages(face, rig: FaceRig, repeats: int, rng) -> None:
    """The window's per-tick compute (app.face_view._update_face + FaceActor.update_vertices)."""
    import pyvista as pv

    from app import scene
    from app.preview import cached_preview

    plotter = pv.Plotter(off_screen=True, window_size=(400, 300))
    actor = scene.add_face_actor(plotter, face, "textured")
    actor.set_preview(cached_preview(face))
    stages = {"rig": [], "normals": [], "actor_arrays": [], "heat_overlay": []}
    faps = [f for f in rig.animated_faps if f not in (48, 49, 50)]
    for _ in range(repeats):
        number = int(rng.choice(faps))
        p = rig.describe(f"fap:{number}")
        lo, hi = p.minimum, p.maximum
        t0 = time.perf_counter()
        rig.set_fap(number, float(rng.uniform(lo, hi) * 0.5))
        v = rig.vertices()
        t1 = time.perf_counter()
        n = actor.compute_normals(v)
        t2 = time.perf_counter()
        actor.update_vertices(v, n)
        t3 = time.perf_counter()
        rig.displacement_magnitude()
        t4 = time.perf_counter()
        for key, dt in zip(stages, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
            stages[key].append(dt)
    plotter.close()
    medians = {k: float(np.median(v) * 1e3) for k, v in stages.items()}
    print("stage_ms " + " ".join(f"{k}={v:.2f}" for k, v in medians.items()) + f" vertices={face.n_vertices}")
    total = medians["rig"] + medians["normals"] + medians["actor_arrays"]
    print(f"window_tick_ms median={total:.2f} vertices={face.n_vertices}  (rig + normals + actor arrays; "
          f"+ heat overlay when shown: {total + medians['heat_overlay']:.2f}; goal 10 ms, ratio {total / 10:.2f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}")
    cache = DiskCache()
    face = load_default_face()
    rig = FaceRig(face, cache=cache)

    from core.registration.pipeline import register_scan

    canonical = register_scan(face, face.landmarks).face
    small = FaceRig(canonical, cache=cache)
    for r, f in ((small, canonical), (rig, face)):
        ticks(r, 10, rng)  # warm-up
        report("fap_tick_ms", ticks(r, args.repeats, rng), f.n_vertices)
    for r, f in ((small, canonical), (rig, face)):
        report("fap_tick_normals_ms", ticks(r, args.repeats, rng, VertexNormals(f.triangles, f.n_vertices)),
               f.n_vertices)
    window_stages(face, rig, max(args.repeats // 4, 20), rng)


if __name__ == "__main__":
    main()
