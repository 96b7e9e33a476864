"""``mimica evaluate-landmarks``: the thesis's landmarking protocol on the synthetic database."""

from __future__ import annotations

import argparse
from pathlib import Path

from app.cli.common import TEMPLATES, CliError


def run(args: argparse.Namespace) -> int:
    """The thesis protocol on the synthetic database; the last line is the summary."""
    from core.registration.evaluation import evaluate, write_charts

    if args.people < 2:
        raise CliError("--people must be at least 2 (one test compares people)")
    result = evaluate(args.people, template=args.template)
    if args.charts:
        charts = Path(args.charts)
        charts.mkdir(parents=True, exist_ok=True)
        for path in write_charts(result, charts):
            print(f"wrote {path}")
    worst, neutral = result.summary()
    print(f"min_expression_accuracy={worst:.4f} neutral_across_people_accuracy={neutral:.4f}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("evaluate-landmarks", help="landmarking accuracy on the synthetic database",
                       description="Thesis A's protocol on synthetic scans: neutral -> each expression of "
                                   "a person, and one expression across people; lambda swept 0..1.")
    p.add_argument("--people", type=int, default=5, help="people in the database (the thesis used 30; default 5)")
    p.add_argument("--template", choices=TEMPLATES, default="a48")
    p.add_argument("--charts", metavar="DIR", help="write accuracy charts (PNG) to DIR")
    p.set_defaults(func=run)
