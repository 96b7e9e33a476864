"""``mimica lipsync "TEXT" --out PROJECT.mimica``: a talking-face project from text (eSpeak NG)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from app.cli.common import CliError


def run(args: argparse.Namespace) -> int:
    """Text -> visemes (+ blinks) on a new project for the default face."""
    from core.default_face import load_default_face
    from core.lipsync import lipsync_tracks
    from core.formats.project import FaceRef, Project, ProjectError, SpeechClip, save_project
    from core.timeline import Timeline

    out = Path(args.out)
    if out.suffix.lower() != ".mimica":
        raise CliError(f"--out must end in .mimica, got {args.out!r}")
    if not out.parent.exists():
        raise CliError(f"output folder does not exist: {out.parent}")
    if not args.text.strip():
        raise CliError("give some text to speak")
    try:
        result = lipsync_tracks(args.text, args.lang, blinks=not args.no_blinks)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    duration = float(np.ceil((result.end_s + 0.5) * 10) / 10)
    timeline = Timeline(duration=duration, fps=args.fps, tracks=result.tracks.values())
    project = Project.from_state(load_default_face(), FaceRef.default_face(), timeline=timeline,
                                 speech=[SpeechClip(args.text, args.lang, 0.0)])
    try:
        save_project(out, project)
    except (ProjectError, OSError) as exc:
        raise CliError(f"cannot write {out}: {exc}") from None
    n_keys = sum(len(t) for t in result.tracks.values())
    print(f"wrote {out}: {len(result.phonemes)} phonemes, {len(result.tracks)} tracks, {n_keys} keys, "
          f"{duration:.1f} s")
    if result.unmapped:
        print(f"note: phonemes without a viseme (their time went to the neighbours): "
              f"{', '.join(sorted(set(result.unmapped)))}", file=sys.stderr)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("lipsync", help="make a talking-face project from text",
                       description="Speak TEXT with espeak-ng, map its phonemes to MPEG-4 visemes with "
                                   "coarticulation (and blinks) and save a project with the speech attached.")
    p.add_argument("text", metavar="TEXT")
    p.add_argument("--lang", choices=("en", "en-gb", "pt-br"), default="en")
    p.add_argument("--out", "-o", required=True, metavar="PROJECT.mimica")
    p.add_argument("--fps", type=int, choices=(24, 25, 30, 60), default=30)
    p.add_argument("--no-blinks", action="store_true", help="do not add eye blinks")
    p.set_defaults(func=run)
