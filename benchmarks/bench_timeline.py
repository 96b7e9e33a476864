"""How long does posing the face at a new time take?

A 30-second timeline (30 fps) with keys on all 46 FAPs of thesis A (one key every ~0.5 s, mixed
interpolation). For random times t (a scrub):

1. ``rig_eval_ms``: timeline evaluation at t + the FAT product on the 4560-vertex dense template
   (``FapDeformer.template_matrix``, 3·4560 × 68) — the size the issue's 2 ms goal is set for;
2. ``rig_eval_full_ms``: timeline evaluation + ``apply_to_rig`` + ``rig.vertices()`` on the default face
   (53,772 vertices; includes the rig's FAP validation and the eyeball/head rigid motions).

Also printed: the timeline evaluation alone. Medians over ``--repeats`` times.

With ``--export``, also the wall seconds to export 10 s of 1280x720 video at 30 fps of this timeline
(``export_s``, through the window's path: a child process hands the frames to the default number of
render processes (one per core) and encodes with ffmpeg), with the per-frame render / encoder-wait
split. Rendering here is software (Mesa llvmpipe). ``benchmarks/bench_export.py`` compares worker
counts.

Usage: python benchmarks/bench_timeline.py [--repeats 300] [--export]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from core.default_face import load_default_face  # noqa: E402
from core.layers.fap import tables  # noqa: E402
from core.layers.fap.fat import lid_contact  # noqa: E402
from core.rig import FaceRig  # noqa: E402
from core.timeline import INTERPOLATIONS, Timeline, apply_to_rig  # noqa: E402


def build_timeline(rng: np.random.Generator, duration: float = 30.0) -> Timeline:
    tl = Timeline(duration, 30)
    keys = {}
    for n in tables.thesis_faps():
        spec = tables.fap_spec(n)
        times = np.unique(np.round(np.concatenate([[0.0], np.cumsum(rng.uniform(0.3, 0.7, 80))]), 3))
        times = times[times <= duration]
        values = rng.uniform(0.4 * spec.minimum, 0.4 * spec.maximum, len(times))
        keys[f"fap:{n}"] = [(t, v, INTERPOLATIONS[rng.integers(0, 3)]) for t, v in zip(times, values)]
    tl.add_keys(keys)
    return tl


def median_ms(fn, times) -> float:
    samples = []
    for t in times:
        start = time.perf_counter()
        fn(t)
        samples.append(time.perf_counter() - start)
    return 1e3 * float(np.median(samples))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=300)
    parser.add_argument("--export", action="store_true", help="also time a 10 s 1280x720 MP4 export")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    tl = build_timeline(rng)
    n_keys = sum(len(t) for t in tl.tracks.values())
    times = rng.uniform(0.0, tl.duration, args.repeats)

    t0 = time.perf_counter()
    face = load_default_face()
    rig = FaceRig(face)
    build_s = time.perf_counter() - t0
    deformer = rig.deformer
    F = deformer.template_matrix.tocsr()
    base = deformer.dense.vertices.ravel().copy()
    scale = deformer.fapu_vector
    keys = tuple(tl.tracks)
    index = np.array([int(k.split(":")[1]) - 1 for k in keys])

    def dense_pose(t):
        _, values = tl.evaluate_array(t, keys)
        v = np.zeros(tables.N_FAPS)
        v[index] = values
        return (base + F @ (lid_contact(v) * scale)).reshape(-1, 3)

    def full_pose(t):
        apply_to_rig(rig, tl.evaluate(t))
        return rig.vertices()

    for fn in (dense_pose, full_pose):  # warm up
        fn(0.5)
    eval_ms = median_ms(lambda t: tl.evaluate(t), times)
    dense_ms = median_ms(dense_pose, times)
    full_ms = median_ms(full_pose, times)
    print(f"timeline: {len(tl.tracks)} FAP tracks, {n_keys} keys over {tl.duration:g} s; rig built in {build_s:.1f} s")
    print(f"timeline_eval_ms median={eval_ms:.3f}")
    print(f"rig_eval_ms median={dense_ms:.3f} (evaluate + FAT product, {len(base) // 3} template vertices)")
    print(f"rig_eval_full_ms median={full_ms:.3f} (evaluate + apply_to_rig + rig.vertices(), "
          f"{face.n_vertices} vertices)")
    if args.export:
        export_video(face, full_pose)


def export_video(face, pose) -> None:
    import tempfile

    from app.export import ExportSettings, export_in_subprocess

    with tempfile.TemporaryDirectory() as tmp:
        settings = ExportSettings(path=Path(tmp) / "bench.mp4", end_s=10.0, size=(1280, 720), fps=30)
        t0 = time.perf_counter()
        result = export_in_subprocess(face, lambda t: np.array(pose(t)), settings)
        wall = time.perf_counter() - t0
    per = 1000.0 / max(result.frames, 1)
    print(f"export_s={wall:.1f} ({result.frames} frames 1280x720, {getattr(result, 'workers', 1)} render "
          f"process(es); render {result.render_seconds * per:.0f} ms/frame, "
          f"waiting for the encoder {result.encode_seconds * per:.0f} ms/frame)")


if __name__ == "__main__":
    main()
