"""``mimica demo [--out demo.mp4]``: the built-in showcase, played in the window or exported."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from app.cli.common import CliError, export_video, parse_size


def run(args: argparse.Namespace) -> int:
    """The built-in showcase: export it (--out) or play it in the window."""
    from app.demo import demo_project

    if args.out is None:
        from app.main_window import run_gui

        return run_gui(None, demo=True)
    out = Path(args.out)
    if out.suffix.lower() not in (".mp4", ".gif", ".avi"):
        raise CliError(f"--out must end in .mp4, .gif or .avi, got {args.out!r}")
    if not out.parent.exists():
        raise CliError(f"output folder does not exist: {out.parent}")
    from core.animation import ProjectAnimation, speech_wav

    face, project = demo_project()
    animation = ProjectAnimation.for_face(face, project.timeline, project.rig.values,
                                          log=lambda text: print(text, file=sys.stderr))
    with tempfile.TemporaryDirectory(prefix="mimica-demo-") as tmp:
        audio = speech_wav(project.speech, Path(tmp)) if out.suffix.lower() != ".gif" else None
        export_video(face, animation.vertices, out, size=args.size, fps=float(args.fps),
                     duration=project.timeline.duration, audio=audio)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help="play (or export) the built-in showcase",
                       description="The six expressions, a spoken sentence, and muscle-driven kiss and "
                                   "smile. Without --out it plays in the window.")
    p.add_argument("--out", "-o", metavar="demo.mp4")
    p.add_argument("--size", type=parse_size, default=(1280, 720), metavar="WxH")
    p.add_argument("--fps", type=int, choices=(24, 25, 30, 60), default=30)
    p.set_defaults(func=run)
