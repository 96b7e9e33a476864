"""Are the default face's proportions human?

Aligns (similarity Procrustes: rotation, translation, uniform scale) the
default face's MPEG-4 feature points that have an ibug-68 counterpart to the
same points on the Surrey Face Model mean (../shared/data/sfm, read here only,
never copied) and prints the RMS distance in mm. Last line: ``rms_mm=<x>``.
Goal: <= 4 mm.

Usage: python benchmarks/default_face_proportions.py [--sfm DIR] [--generate]
(--generate builds the face from the default parameters instead of loading
the committed copy).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# ibug-68 landmark number -> MPEG-4 feature point (+x = the face's own left in both).
IBUG_TO_FP = {
    9: "2.1",                                   # chin bottom
    18: "4.6", 20: "4.4", 22: "4.2",            # right brow outer, top, inner
    23: "4.1", 25: "4.3", 27: "4.5",            # left brow inner, top, outer
    31: "9.3", 32: "9.4", 34: "9.15", 36: "9.5",  # nose tip, right/left alar base, subnasale
    37: "3.12", 40: "3.8", 43: "3.11", 46: "3.7",  # eye corners
    49: "8.4", 52: "8.1", 55: "8.3", 58: "8.2",   # outer lip corners and midpoints
    63: "2.2", 67: "2.3",                         # inner lip midpoints
}


def similarity_procrustes(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Source (k, 3) mapped onto target (k, 3) by the least-squares similarity transform (Umeyama 1991)."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    a, b = source - mu_s, target - mu_t
    u, sig, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    fix = np.diag([1.0, 1.0, d])
    rotation = u @ fix @ vt
    scale = np.trace(np.diag(sig) @ fix) / (a**2).sum()
    return scale * a @ rotation.T + mu_t


def read_sfm_landmarks(sfm_dir: Path) -> dict[int, np.ndarray]:
    mean = np.load(sfm_dir / "sfm_mean.npy").astype(float)
    mapping = {}
    for line in (sfm_dir / "ibug_to_sfm.txt").read_text().splitlines():
        m = re.match(r"\s*(\d+)\s*=\s*(\d+)", line)
        if m:
            mapping[int(m.group(1))] = int(m.group(2))
    return {k: mean[mapping[k]] for k in IBUG_TO_FP}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sfm", type=Path, default=ROOT.parent / "shared" / "data" / "sfm")
    parser.add_argument("--generate", action="store_true")
    args = parser.parse_args()
    if not (args.sfm / "sfm_mean.npy").exists():
        sys.exit(f"Surrey Face Model not found in {args.sfm}; pass --sfm DIR")

    from core.default_face import generate_face, load_default_face

    face = generate_face() if args.generate else load_default_face()
    sfm = read_sfm_landmarks(args.sfm)
    ibug = sorted(IBUG_TO_FP)
    ours = face.landmark_positions([IBUG_TO_FP[k] for k in ibug])
    target = np.array([sfm[k] for k in ibug])
    aligned = similarity_procrustes(ours, target)
    err = np.linalg.norm(aligned - target, axis=1)
    print(f"{'ibug':>4} {'fp':>5} {'error_mm':>8}   (after similarity alignment to the SFM mean)")
    for k, e in zip(ibug, err):
        print(f"{k:>4} {IBUG_TO_FP[k]:>5} {e:8.2f}")
    print(f"points={len(ibug)} max_mm={err.max():.2f}")
    print(f"rms_mm={np.sqrt((err**2).mean()):.2f}")


if __name__ == "__main__":
    main()
