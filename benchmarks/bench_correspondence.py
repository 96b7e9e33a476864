"""Register -> save -> reload -> animate, over scans of two origins (issue 15).

For each scan: register it with landmarks taken as given (the synthetic database's ground truth;
for the Surrey Face Model, whose truth has 21 points, detection steered by those 21), save the
canonical face as OBJ, reload it as `mimica` does, build its rig and pose joy at 80 %. Prints per scan

    <data> <scan>: folds=<n> forced=<k> dist_mean_mm=<x> dist_p95_mm=<y> landmark_shift_max_mm=<z> (<j> > 1 mm)
        released=<names|-> animatable=<yes|no> (register <s> s, <s> s)

where folds counts the canonical triangles ``Registration.folded()`` reports: collapsed (area < 1e-3
of the median) or facing against the same triangle of the registration's reference (the template
registered on the default face, brought onto the scan's landmarks by a similarity; until
helper/folds it was the FAP rig's densified default face, unaligned); forced of them lie inside a
template triangle the landmarks themselves turn over (``Registration.forced()``). The distance is
from the canonical triangles' centroids to the scan surface (how far the canonical surface leaves
the scan between its vertices); the landmark shift is how far the fit moved the canonical
landmark vertices from the given landmarks (where they would fold the mesh), released names the landmarks
that contradicted their template neighbours and were placed by the fit (``core.registration.consistency``;
their shift is counted too); then per data set and overall

    animatable=<k>/<n> folds=<total> mean_mm=<x> p95_mm=<y>

Usage: python benchmarks/bench_correspondence.py [--people 2] [--sfm-people 4] [--sfm DIR]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def measure(scan, landmarks, folder: Path, label: str):
    """(folds, forced folds, centroid distances (T,), landmark shifts (n_base,) mm, released landmarks,
    animatable, registration seconds, seconds) of one scan."""
    from core.formats.mesh_io import save_face
    from core.registration.correspondence import load_face_or_canonical
    from core.registration.pipeline import register_scan
    from core.rig import FaceRig

    t0 = time.perf_counter()
    registration = register_scan(scan, landmarks)
    register_s = time.perf_counter() - t0
    face = registration.face
    folded = registration.folded()
    folds, forced = int(folded.sum()), int((folded & registration.forced()).sum())
    distance = registration.distances_to_scan()
    path = folder / f"{label}.obj"
    save_face(face, path)
    try:
        rig = FaceRig(load_face_or_canonical(path))
        rig.set_expression("joy", 0.8)
        animatable = bool(np.abs(rig.vertices() - rig.face.vertices).max() > 1.0)
    except ValueError:
        animatable = False
    return (folds, forced, distance, registration.landmark_shift, registration.released, animatable, register_s,
            time.perf_counter() - t0)


def synthetic_cases(people: int):
    from core.registration.synthetic import poses, synthetic_scan

    for person in range(1, people + 1):
        for pose in poses():
            scan = synthetic_scan(person, pose)
            yield f"p{person}_{pose}", scan, dict(scan.landmarks)


def sfm_cases(people: int, sfm_dir: Path):
    import evaluate_landmarks_sfm as sfm

    from core.registration.pipeline import detect_landmarks
    from core.registration.synthetic import poses

    model = sfm.load_sfm(sfm_dir)
    surface = sfm.refine_topology(model)
    for person in range(1, people + 1):
        for case in sfm.make_scans(model, surface, person, 0, [0.0], list(poses()), textured=False):
            truth = dict(case.face.landmarks)
            yield f"p{person}_{case.pose}", case.face, detect_landmarks(case.face, fixed=truth).landmarks


def report(data: str, cases, folder: Path) -> tuple[int, int, int, list[np.ndarray]]:
    ok = n = folds = 0
    distances = []
    for label, scan, landmarks in cases:
        try:
            f, forced, d, shift, released, animatable, register_s, seconds = measure(scan, landmarks, folder,
                                                                                    f"{data}_{label}")
        except ValueError as exc:
            print(f"{data} {label}: registration failed: {exc}", flush=True)
            n += 1
            continue
        n += 1
        ok += animatable
        folds += f
        distances.append(d)
        print(f"{data} {label}: folds={f} forced={forced} dist_mean_mm={d.mean():.3f} "
              f"dist_p95_mm={np.percentile(d, 95):.3f} landmark_shift_max_mm={shift.max(initial=0.0):.2f} "
              f"({int((shift > 1.0).sum())} > 1 mm) released={','.join(released) or '-'} "
              f"animatable={'yes' if animatable else 'no'} (register {register_s:.1f} s, {seconds:.1f} s)", flush=True)
    return ok, n, folds, distances


def summary(ok, n, folds, distances, prefix: str = "") -> None:
    d = np.concatenate(distances) if distances else np.zeros(1)
    print(f"{prefix}animatable={ok}/{n} folds={folds} mean_mm={d.mean():.3f} p95_mm={np.percentile(d, 95):.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--people", type=int, default=2, help="synthetic people (7 poses each)")
    ap.add_argument("--sfm-people", type=int, default=4, help="Surrey Face Model identities (7 poses each)")
    ap.add_argument("--sfm", type=Path, default=ROOT.parent / "shared" / "data" / "sfm")
    args = ap.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="mimica-bench-correspondence-"))
    totals = [0, 0, 0, []]
    results = [("synthetic", report("synthetic", synthetic_cases(args.people), folder))]
    if args.sfm_people and args.sfm.is_dir():
        results.append(("sfm", report("sfm", sfm_cases(args.sfm_people, args.sfm), folder)))
    elif args.sfm_people:
        print(f"(no Surrey Face Model at {args.sfm}: SFM scans skipped)")
    for data, (ok, n, folds, distances) in results:
        summary(ok, n, folds, distances, prefix=f"{data}: ")
        totals = [totals[0] + ok, totals[1] + n, totals[2] + folds, totals[3] + distances]
    summary(*totals)


if __name__ == "__main__":
    main()
