"""How fast does a video export go, with one render process and with several?

Exports ``--seconds`` (default 10) of 1280x720 MP4 at 30 fps of the default face (53,772 vertices,
textured) animated by the 46-FAP timeline of ``bench_timeline.py``, through the window's path
(:func:`app.export.export_in_subprocess`: the rig is evaluated here, a child process encodes and
renders, or hands the frames to ``--workers`` render processes) or with ``--path cli`` through
``mimica export``'s in-process :func:`app.export.export`. Each worker count runs ``--repeats``
times, alternating, so a change in the machine's load hits both alike.

Prints per run the wall time, frames per second (start-up included, as a user waits for it) and the
render / encoder-wait split, then per worker count::

    export_fps median=<fps> workers=<n> (ratio to 1 worker: <x>)

with ``--baseline FPS`` (an earlier median, e.g. of the code before a change, measured alike) also::

    export_fps best median=<fps> workers=<n> (ratio to the baseline <fps> fps: <x>)

``--cores 1 2`` measures how the export scales with cores instead: each run is confined to the
first N cores (CPU affinity, inherited by the render processes, which then default to one per core)
and the lines are ``export_fps median=<fps> cores=<n> workers=<w> (ratio to 1 core: <x>)``.

and the load average before and after (this machine is shared; software OpenGL, Mesa llvmpipe,
draws a frame on one core, so the speed-up is bounded by the idle cores).

Usage: python benchmarks/bench_export.py [--workers 1 2 | --cores 1 2] [--repeats 3] [--seconds 10]
       [--size 1280x720] [--quality 80] [--path window|cli] [--baseline FPS]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_timeline import build_timeline  # noqa: E402

from core.default_face import load_default_face  # noqa: E402
from core.rig import FaceRig  # noqa: E402
from core.timeline import apply_to_rig  # noqa: E402


def cpu_seconds() -> float:
    """CPU time (user + system) of this process and of its finished child processes (all descendants)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    from app.export import ExportSettings, export, export_in_subprocess

    try:
        from app.export_plan import default_workers
    except ImportError:  # the code before parallel export: one worker
        def default_workers() -> int:
            return 1

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, nargs="+", default=None,
                        help=f"worker counts to compare (default: 1 and {default_workers()}, the cores)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--quality", type=int, default=80)
    parser.add_argument("--path", choices=("window", "cli"), default="window")
    parser.add_argument("--cores", type=int, nargs="+", default=None,
                        help="confine runs to this many cores each (scaling with cores; workers default to the cores)")
    parser.add_argument("--baseline", type=float, default=None,
                        help="frames per second to compare with (an earlier median, measured alike)")
    args = parser.parse_args()
    all_cores = sorted(os.sched_getaffinity(0))
    if args.cores and max(args.cores) > len(all_cores):
        parser.error(f"--cores: this process may run on {len(all_cores)} cores")
    # Each configuration is (cores, workers): cores None keeps the affinity as it is.
    configs = ([(c, None) for c in args.cores] if args.cores
               else [(None, n) for n in (args.workers or sorted({1, default_workers()}))])
    size = tuple(int(v) for v in args.size.lower().split("x"))

    face = load_default_face()
    rig = FaceRig(face)
    timeline = build_timeline(np.random.default_rng(0))

    def pose(t: float) -> np.ndarray:
        apply_to_rig(rig, timeline.evaluate(t))
        return np.array(rig.vertices())

    pose(0.0)
    print(f"export of {args.seconds:g} s at 30 fps, {size[0]}x{size[1]} MP4 (quality {args.quality}), "
          f"{face.n_vertices} vertices, path={args.path}, {os.cpu_count()} cores; load average {load()}")
    fps: dict[tuple, list[float]] = {config: [] for config in configs}
    used_workers: dict[tuple, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for config in configs:
                cores, n = config
                if cores is not None:
                    os.sched_setaffinity(0, all_cores[:cores])   # the render processes inherit it
                    n = default_workers()
                options = {"workers": n} if "workers" in ExportSettings.__dataclass_fields__ else {}  # older code
                settings = ExportSettings(path=Path(tmp) / f"bench{n}.mp4", end_s=args.seconds, size=size, fps=30,
                                          quality=args.quality, **options)
                run = export_in_subprocess if args.path == "window" else export
                cpu0 = cpu_seconds()
                t0 = time.perf_counter()
                try:
                    result = run(face, pose, settings)
                finally:
                    os.sched_setaffinity(0, all_cores)
                wall = time.perf_counter() - t0
                cpu = cpu_seconds() - cpu0
                fps[config].append(result.frames / wall)
                used_workers[config] = getattr(result, "workers", 1)
                per = 1000.0 / max(result.frames, 1)
                where = "" if cores is None else f"cores={cores} "
                print(f"  run {repeat + 1} {where}workers={getattr(result, 'workers', 1)}: {result.frames} frames in {wall:.1f} s "
                      f"({result.frames / wall:.2f} fps; waiting for frames {result.render_seconds * per:.0f} "
                      f"ms/frame, for the encoder {result.encode_seconds * per:.0f} ms/frame; CPU of all the "
                      f"export's processes {cpu * per:.0f} ms/frame = {cpu / wall:.2f} cores busy; "
                      f"{Path(result.path).stat().st_size / 1e6:.2f} MB); load {load()}", flush=True)
    base = float(np.median(fps[configs[0]]))
    first_cores, first_workers = configs[0]
    for config in configs:
        cores, n = config
        median = float(np.median(fps[config]))
        if cores is None:
            print(f"export_fps median={median:.2f} workers={n} (ratio to {first_workers} worker"
                  f"{'s' if first_workers != 1 else ''}: {median / base:.2f})")
        else:
            print(f"export_fps median={median:.2f} cores={cores} workers={used_workers[config]} (ratio to "
                  f"{first_cores} core{'s' if first_cores != 1 else ''}: {median / base:.2f})")
    if args.baseline:
        best = max(configs, key=lambda config: float(np.median(fps[config])))
        median = float(np.median(fps[best]))
        print(f"export_fps best median={median:.2f} workers={used_workers[best]} (ratio to the baseline "
              f"{args.baseline:g} fps: {median / args.baseline:.2f})")
    print(f"load average after: {load()}")


if __name__ == "__main__":
    main()
