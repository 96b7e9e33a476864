"""What a control-point drag, a Waters muscle tick and an inverse solve cost (issue 17).

A drag is what the window does when a control point moves: the layer's ``set_values`` (validation, event)
and its ``offset`` (the moved point's column of the cached RBF response times its displacement change,
``layer.Pose``, scattered into (n, 3)). Measured
at 80 control points on a 10,000-vertex synthetic face (no influence regions: every vertex moved by every
point), at the default face's 29 control points with their regions, and at 80 points on the default face
without regions (the worst case). The same 80 × 10,000
data against ``scipy.interpolate.RBFInterpolator`` (same kernel and settings): ratio = our drag / scipy's
construct + evaluate, and / scipy's evaluate alone (< 1: we are faster). A Waters tick is one strength set
and the 18-muscle offset at the default face ('limit' rule); the inverse is one bounded least-squares solve
for one dragged skin vertex (its response rows included), for the Waters muscles and for SABiom's (its
linear response measured once, ``core.inverse``; the settling after it is the muscle solver's).

    rbf_drag_ms median=<x> vertices=<n>          goal 5 ms
    rbf_vs_scipy ratio=<x>                       goal < 1 (two lines: construct+evaluate, evaluate)
    waters_tick_ms median=<x> vertices=<n>       goal 5 ms
    inverse_solve_ms median=<x>                  goal 30 ms

Usage: python benchmarks/bench_rbf.py [--repeats 100]
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
from core.face import Face  # noqa: E402
from core.layers.rbf.kernels import Kernel  # noqa: E402
from core.layers.rbf.layer import ControlPointDeformer, ControlPointLayer, Pose  # noqa: E402
from core.layers.rbf.regions import ControlPoints, ControlPointSpec  # noqa: E402
from core.layers.waters.inverse import solve_strengths  # noqa: E402
from core.layers.waters.layer import WatersLayer  # noqa: E402


def median_ms(seconds) -> float:
    return float(np.median(seconds) * 1e3)


def synthetic(n_side: int = 100, n_points: int = 80, seed: int = 0):
    """A 10,000-vertex curved patch (~200 mm) and 80 control points on random vertices."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(-100, 100, n_side), np.linspace(-100, 100, n_side))
    z = 30 * np.cos(x / 90) * np.cos(y / 120)
    v = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    idx = np.arange(n_side * n_side).reshape(n_side, n_side)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    face = Face(v, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]))
    chosen = rng.choice(len(v), n_points, replace=False)
    specs = tuple(ControlPointSpec(f"p{i}", "-", ()) for i in range(n_points))
    return face, ControlPoints(specs, np.sort(chosen))


def drag_times(step, n_points: int, repeats: int, rng) -> np.ndarray:
    out = np.empty(repeats)
    for i in range(repeats):
        j, value = int(rng.integers(n_points)), float(rng.uniform(-5, 5))
        start = time.perf_counter()
        step(j, value)
        out[i] = time.perf_counter() - start
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=100)
    args = parser.parse_args()
    rng = np.random.default_rng(1)
    kernel = Kernel("multiquadric", delta=400.0)

    # 80 control points x 10,000 vertices
    face, points = synthetic()
    deformer = ControlPointDeformer(face, points, regions=False)
    pose = Pose(deformer, kernel)
    d = np.zeros((len(points), 3))

    def synthetic_drag(j, value):
        d[j, 1] = value
        return pose(d)

    synth = drag_times(synthetic_drag, len(points), args.repeats, rng)
    print(f"rbf_drag_ms median={median_ms(synth):.3f} vertices={face.n_vertices}  "
          f"(80 control points, goal 5 ms)")

    # the default face, through the layer (validation, event, offset)
    default = load_default_face()
    layer = ControlPointLayer(default, kernel)
    keys = [k for k in layer.parameters() if k.endswith(":y")]

    def layer_drag(j, value):
        layer.set_values({keys[j]: value})
        return layer.offset(None)

    full = drag_times(layer_drag, len(keys), args.repeats, rng)
    print(f"rbf_drag_ms median={median_ms(full):.3f} vertices={default.n_vertices}  "
          f"({len(keys)} control points with regions, goal 5 ms)")

    # 80 control points on the default face, no regions (every vertex moved by every point: the worst case)
    from core.layers.rbf.regions import skin_vertices

    many = ControlPoints(points.specs, np.sort(rng.choice(skin_vertices(default), len(points), replace=False)))
    wide = ControlPointDeformer(default, many, regions=False)
    wide_pose = Pose(wide, kernel)
    d80 = np.zeros((len(many), 3))

    def wide_drag(j, value):
        d80[j, 1] = value
        return wide_pose(d80)

    worst = drag_times(wide_drag, len(many), args.repeats, rng)
    print(f"rbf_drag_ms median={median_ms(worst):.3f} vertices={default.n_vertices}  "
          f"(80 control points, no regions, goal 5 ms)")

    # against scipy on the 80 x 10,000 data
    import warnings

    from scipy.interpolate import RBFInterpolator

    kw = kernel.scipy_arguments()
    centres, targets = face.vertices[points.vertices], face.vertices
    values = rng.normal(0, 3, (len(points), 3))
    ref = None
    build, evaluate = [], []
    for _ in range(max(5, args.repeats // 10)):
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            interp = RBFInterpolator(centres, values, **kw)
        mid = time.perf_counter()
        ref = interp(targets)
        end = time.perf_counter()
        build.append(end - start)
        evaluate.append(end - mid)
    ours = deformer.displacement(values, kernel)
    assert np.abs(ours - ref).max() < 1e-8 * np.abs(ref).max(), "the RBF deformer disagrees with scipy"
    print(f"rbf_vs_scipy ratio={median_ms(synth) / median_ms(build):.4f}  (our drag / scipy construct+evaluate "
          f"{median_ms(build):.1f} ms, 80 x {face.n_vertices}; < 1 is faster)")
    print(f"rbf_vs_scipy ratio={median_ms(synth) / median_ms(evaluate):.4f}  (our drag / scipy evaluate alone "
          f"{median_ms(evaluate):.1f} ms; < 1 is faster)")

    # Waters at the default face
    waters = WatersLayer(default, combine="limit")
    wkeys = waters.parameters()

    def waters_tick(j, value):
        waters.set_values({wkeys[j % len(wkeys)]: abs(value) / 5})
        return waters.offset(None)

    ticks = drag_times(waters_tick, len(wkeys), args.repeats, rng)
    print(f"waters_tick_ms median={median_ms(ticks):.3f} vertices={default.n_vertices}  (18 muscles, goal 5 ms)")

    # the inverse: one dragged skin vertex
    model = waters.model
    moved = model.moved
    times = np.empty(args.repeats)
    for i in range(args.repeats):
        v = int(rng.choice(moved))
        known = rng.uniform(0, 0.6, len(model.keys))
        target = model.displacement(known, "sum")[v]
        start = time.perf_counter()
        solve_strengths(model.vertex_response([v]), target, waters.strengths())
        times[i] = time.perf_counter() - start
    print(f"inverse_solve_ms median={median_ms(times):.3f}  (18 Waters muscles, one skin vertex, goal 30 ms)")

    # the inverse on SABiom's 20 controls, from their measured linear response (one solve, no settling)
    from core.inverse import LinearResponse
    from core.layers.muscles.layer import MuscleLayer

    sabiom = MuscleLayer(default)
    response = LinearResponse.measured(sabiom)
    cols = np.abs(response.matrix).reshape(default.n_vertices, 3, -1).max(axis=(1, 2))
    skin = np.nonzero(cols > 0.01)[0]
    for i in range(args.repeats):
        v = int(rng.choice(skin))
        known = rng.uniform(0, 0.3, len(response.keys)) * response.upper
        target = response.rows([v]) @ known
        start = time.perf_counter()
        response.solve([v], target, np.zeros(len(response.keys)))
        times[i] = time.perf_counter() - start
    print(f"inverse_solve_ms median={median_ms(times):.3f}  (20 SABiom controls, linear response, one skin vertex, "
          "goal 30 ms)")


if __name__ == "__main__":
    main()
