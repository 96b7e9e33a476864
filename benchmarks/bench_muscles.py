"""Muscle model (thesis C) timings on the default face: slider ticks, settling, playback.

For each tissue level (2: 1160 skin vertices, about thesis C's head; 3: 4560, the full canonical
face) prints the node and spring counts, build times, the stability numbers, then

    pose_tick_ms median=<x>            one warm-started relax(0.02) + skin offsets after a slider change
    pose_converge_s median=<x>         rest -> within 1 % of the smile's equilibrium (true error, budgeted calls)
    dynamic_realtime_factor=<x>        stable integrator, 1/30 s frames: simulated s / wall s
    explicit_realtime_factor=<x>       thesis explicit Euler, Δt = 0.01 s

Goals: tick <= 33 ms, converge <= 1 s, dynamic >= 10x real time. The last block (level 3, the
layer's default) is the one to quote.

Usage: python benchmarks/bench_muscles.py [--levels 2,3] [--repeats 7]
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
from core.layers.muscles import MuscleLayer, preset  # noqa: E402
from core.layers.muscles import kernels  # noqa: E402
from core.layers.muscles.solver import State  # noqa: E402


def true_error(layer, x_ref, rest) -> float:
    scale = np.linalg.norm(x_ref - rest, axis=1).max()
    return float(np.linalg.norm(layer._state.x - x_ref, axis=1).max() / scale)


def bench_level(face, level: int, repeats: int) -> dict:
    t0 = time.perf_counter()
    layer = MuscleLayer(face, level=level)
    build = time.perf_counter() - t0
    m, s = layer.model, layer.solver
    print(f"\n== level {level}: {m.summary()}")
    print(f"nodes={m.n_nodes} free={m.n_free} springs={m.n_springs}")
    print(f"build_s={build:.2f} (factorisation {s.factor_seconds * 1e3:.0f} ms, "
          f"numba first call {kernels.compile_seconds if kernels.compile_seconds is not None else float('nan'):.2f} s)")
    rep = s.stability_report(0.01)
    print(f"lambda_max={rep['lambda_max_per_s2']:.0f} 1/s^2  explicit dt limit={rep['explicit_dt_limit_s'] * 1e3:.1f} ms "
          f"(margin at 0.01 s: {rep['explicit_margin']:.2f})  stable dt limit={rep['stable_dt_limit_s'] * 1e3:.1f} ms "
          f"-> {s.substeps(1 / 30)} substep(s) per 1/30 s frame")
    t0 = time.perf_counter()
    layer.skin_offsets()
    print(f"binding to the full face (first skin_offsets) {time.perf_counter() - t0:.2f} s")
    rest = m.rest[:m.n_free]
    smile = preset("discreet_smile")

    # Reference equilibrium (tight).
    layer.apply(smile)
    frame = s.frame(0.0)
    ref_state = layer._state.copy()
    ref_state.act[:] = layer._controls
    s.relax(ref_state, frame, budget_s=60.0, tolerance=1e-5)
    x_ref = ref_state.x.copy()

    # Converge from rest, budgeted calls as the GUI timer would make them.
    conv, flagged_err = [], []
    for _ in range(repeats):
        layer.reset()
        layer.apply(smile)
        t0 = time.perf_counter()
        reached = None
        while True:
            r = layer.relax(0.02)
            layer.skin_offsets()
            if reached is None and true_error(layer, x_ref, rest) <= 0.01:
                reached = time.perf_counter() - t0
            if r.converged:
                break
        conv.append(reached if reached is not None else time.perf_counter() - t0)
        flagged_err.append(true_error(layer, x_ref, rest))

    # Tick: one relax(0.02) + offsets after a slider change from a converged pose.
    ticks, iters = [], []
    for k in range(repeats * 2):
        value = 9.0 + (1.0 if k % 2 == 0 else 0.0)
        layer.set_force("zygomatic_major", "left", value)
        t0 = time.perf_counter()
        r = layer.relax(0.02)
        layer.skin_offsets()
        ticks.append(time.perf_counter() - t0)
        iters.append(r.iterations)
        layer.solve()

    # Dynamics: play the smile from rest, 1/30 s frames.
    def realtime(integrator: str, seconds: float) -> float:
        layer.reset()
        layer.integrator = integrator
        layer.apply(smile)
        layer.start_animation()
        t0 = time.perf_counter()
        for _ in range(int(round(seconds * 30))):
            layer.advance(1 / 30)
            layer.skin_offsets()
        wall = time.perf_counter() - t0
        layer.integrator = "stable"
        return seconds / wall

    dyn = [realtime("stable", 2.0) for _ in range(3)]
    try:
        exp = [realtime("explicit", 1.0) for _ in range(3)]
    except ValueError as exc:  # SolverDiverged: Δt = 0.01 s beyond the limit at this level
        print(f"explicit Euler at 0.01 s diverged: {exc}")
        exp = [float("nan")]
    print(f"smile equilibrium: max skin displacement {np.linalg.norm(x_ref - rest, axis=1).max() * 10:.2f} mm; "
          f"true error when the layer says converged: median {np.median(flagged_err) * 100:.2f} %, "
          f"max {np.max(flagged_err) * 100:.2f} %; iterations per tick median {np.median(iters):.0f}")
    out = {
        "pose_tick_ms": float(np.median(ticks) * 1e3),
        "pose_converge_s": float(np.median(conv)),
        "dynamic_realtime_factor": float(np.median(dyn)),
        "explicit_realtime_factor": float(np.median(exp)),
    }
    print(f"pose_tick_ms median={out['pose_tick_ms']:.1f}")
    print(f"pose_converge_s median={out['pose_converge_s']:.3f}")
    print(f"dynamic_realtime_factor={out['dynamic_realtime_factor']:.1f}")
    print(f"explicit_realtime_factor={out['explicit_realtime_factor']:.1f}")
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--levels", default="2,3")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    face = load_default_face()
    print(f"spring kernel backend: {'numba' if kernels.HAVE_NUMBA else 'numpy'}")
    for level in (int(v) for v in args.levels.split(",")):
        bench_level(face, level, args.repeats)


if __name__ == "__main__":
    main()
