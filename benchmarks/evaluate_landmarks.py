"""Landmark-matching accuracy on the synthetic database (thesis A §3.3 protocol).

    python benchmarks/evaluate_landmarks.py [--people 3] [--template a48] [--pairs 1] [--out out/landmarks]
                                                [--untextured]

Prints per-expression and per-landmark accuracy for λ = 0..1 (step 0.1), mean errors and time per
scan, writes charts, and ends with ``min_expression_accuracy=<x> neutral_across_people_accuracy=<y>``.
The synthetic scans are generated on first use (~5 s per scan) and cached.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from core.registration.evaluation import LAMBDAS, evaluate  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--people", type=int, default=3, help="people 0..n-1 (30 = the full protocol; slow)")
    ap.add_argument("--template", default="a48", choices=["a48", "mpeg4_80"])
    ap.add_argument("--pairs", type=int, default=1, help="across-people partners per person (n-1 = all pairs)")
    ap.add_argument("--poses", nargs="*", default=None)
    ap.add_argument("--lambdas", type=float, nargs="*", default=list(LAMBDAS))
    ap.add_argument("--out", default="out/landmarks", help="directory for the PNG charts")
    ap.add_argument("--quiet", action="store_true", help="no per-case lines")
    ap.add_argument("--untextured", action="store_true",
                    help="input scans without texture (the geometry-only path); models keep theirs")
    args = ap.parse_args(argv)
    res = evaluate(args.people, template=args.template, poses=args.poses, lambdas=args.lambdas, pairs=args.pairs,
                   out_dir=args.out, textured=not args.untextured, log=None if args.quiet else print)
    if args.quiet:
        print("\n".join(res.lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
