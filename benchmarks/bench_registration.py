"""Registration timings on synthetic 50,000-vertex scans (thesis A ch. 3).

    python benchmarks/bench_registration.py [--scans 3]

Median seconds per scan for ICP, landmarking (detect_landmarks, everything included except the
model's one-off preparation) and dense correspondence (register_scan with mpeg4_80, with and
without reusing the detection's Embree scene), plus carry-back binding; and our ICP against
``trimesh.registration.icp`` on the same input (one run each: time and final RMS).
Prints ``landmarking_s median=<x>`` and ``correspondence_s median=<x>``. Goals: 2 s and 0.5 s.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scans", type=int, default=3)
    ap.add_argument("--template", default="mpeg4_80", choices=["mpeg4_80", "a48"])
    args = ap.parse_args(argv)

    from core.registration.icp import icp
    from core.registration.pipeline import default_model, detect_landmarks, get_model_context, register_scan
    from core.registration.matching import MatchParams
    from core.registration.synthetic import poses, synthetic_scan

    model = default_model()
    t = time.perf_counter()
    get_model_context(model, args.template, MatchParams())
    print(f"model preparation (once per model): {time.perf_counter() - t:.2f} s")
    scans = [synthetic_scan(1 + i // 3, poses()[(i * 2) % 7]) for i in range(args.scans)]
    t_icp, t_lm, t_corr, t_corr_shared, t_bind = [], [], [], [], []
    for s in scans:
        used = s.vertices[np.unique(s.triangles)]
        t = time.perf_counter()
        icp(used, model, max_iterations=50, sample=3000)
        t_icp.append(time.perf_counter() - t)
        t = time.perf_counter()
        det = detect_landmarks(s, template=args.template)
        t_lm.append(time.perf_counter() - t)
        t = time.perf_counter()
        reg = register_scan(s, det.landmarks, template=args.template)
        t_corr.append(time.perf_counter() - t)
        t = time.perf_counter()
        register_scan(s, det.landmarks, template=args.template, rays=det.rays)
        t_corr_shared.append(time.perf_counter() - t)
        t = time.perf_counter()
        reg.carry_back()
        t_bind.append(time.perf_counter() - t)
        print(f"  {s.metadata.name}: {s.n_vertices} vertices; icp {t_icp[-1]:.2f} s, landmarks {t_lm[-1]:.2f} s "
              f"({', '.join(f'{k} {v:.2f}' for k, v in det.timings.items())}), correspondence {t_corr[-1]:.2f} s "
              f"(shared scene {t_corr_shared[-1]:.2f} s), {reg.fallbacks} fallbacks, carry-back bind {t_bind[-1]:.2f} s")

    # Our ICP against trimesh's on one scan, started from the same (centroid) guess.
    import trimesh

    s = scans[0]
    used = s.vertices[np.unique(s.triangles)]
    t = time.perf_counter()
    ours = icp(used, model, max_iterations=50, sample=3000)
    t_ours = time.perf_counter() - t
    init = np.eye(4)
    init[:3, 3] = model.vertices.mean(axis=0) - used.mean(axis=0)
    sub = used[np.random.default_rng(0).choice(len(used), 3000, replace=False)]
    t = time.perf_counter()
    _T, _moved, cost = trimesh.registration.icp(sub, model.as_trimesh(), initial=init, max_iterations=50)
    t_tm = time.perf_counter() - t
    from scipy.spatial import cKDTree

    tree = cKDTree(model.vertices)

    def rms(T):
        moved = sub @ T[:3, :3].T + T[:3, 3]
        d, _ = tree.query(moved)
        d = np.sort(d)[: int(0.8 * len(d))]   # same trimming for both
        return float(np.sqrt((d ** 2).mean()))

    print(f"ICP on {s.metadata.name} (3000 source points): ours {t_ours:.2f} s, RMS {rms(ours.transform):.3f} mm; "
          f"trimesh {t_tm:.2f} s, RMS {rms(_T):.3f} mm; time ratio trimesh/ours = {t_tm / max(t_ours, 1e-9):.1f}")
    print(f"icp_s median={np.median(t_icp):.3f}")
    print(f"carry_back_bind_s median={np.median(t_bind):.3f}")
    print(f"correspondence_shared_scene_s median={np.median(t_corr_shared):.3f}")
    print(f"landmarking_s median={np.median(t_lm):.3f}")
    print(f"correspondence_s median={np.median(t_corr):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
