"""``mimica export PROJECT --out FILE``: render a project (MP4, GIF, AVI, PNG/JPG still) or write its .fap.

The project is evaluated by ``core.animation.ProjectAnimation`` — the same code the window's export
runs on a copy of its rig — so both make identical frames. ``--workers N`` render processes draw
the frames in parallel (default: one per core) while this process evaluates the animation and
encodes; the last line says how fast (``exported 300 frames in 41.2 s (7.3 fps, 2 workers)``).
``--full-detail`` draws the full face where the export would otherwise use its level of detail
(:mod:`app.export_lod`).
SIGTERM and SIGHUP stop it like Ctrl-C (exit status 130, nothing temporary left behind).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.cli.common import CliError, export_video, open_project, parse_size, stop_on_signals

VIDEO_SUFFIXES = (".mp4", ".gif", ".avi", ".png", ".jpg")


def run(args: argparse.Namespace) -> int:
    """Render or write a project's animation."""
    from core.animation import ProjectAnimation, speech_wav
    from core.formats.fap_file import FapFileError, write_fap

    out = Path(args.out)
    suffix = out.suffix.lower()
    if suffix not in VIDEO_SUFFIXES + (".fap",):
        raise CliError(f"--out must end in {', '.join(VIDEO_SUFFIXES + ('.fap',))}, got {args.out!r}")
    if not out.parent.exists():
        raise CliError(f"output folder does not exist: {out.parent}")
    if args.fps is not None and not 1 <= args.fps <= 120:
        raise CliError(f"--fps must be between 1 and 120 frames per second, got {args.fps:g}")
    project, face = open_project(args.project)
    timeline = project.timeline
    fps = float(args.fps if args.fps is not None else timeline.fps)
    try:
        animation = ProjectAnimation.for_face(face, timeline, project.rig.values,
                                              log=lambda text: print(text, file=sys.stderr))
    except ValueError as exc:
        raise CliError(f"cannot animate this face: {exc}") from None
    if suffix == ".fap":
        sequence = animation.fap_sequence(fps, name=out.stem)
        try:
            write_fap(out, sequence)
        except (FapFileError, ValueError, OSError) as exc:
            raise CliError(f"cannot write {out}: {exc}") from None
        driven = int(sequence.mask.any(axis=0).sum())
        print(f"wrote {out} ({sequence.n_frames} frames at {fps:g} fps, {driven} FAPs)")
        return 0
    from app.export_sinks import temp_dir

    # SIGTERM/SIGHUP like Ctrl-C: the speech file, the staging file and the work folders are removed.
    with stop_on_signals(), temp_dir() as tmp:
        audio = speech_wav(project.speech, Path(tmp)) if suffix in (".mp4", ".avi") else None
        export_video(face, animation.vertices, out, size=args.size, fps=fps, duration=timeline.duration,
                     audio=audio, workers=args.workers, full_detail=args.full_detail)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("export", help="render a project to video/stills or write its .fap",
                       description="Render PROJECT's animation off screen (MP4 H.264, GIF, AVI, PNG/JPG "
                                   "still) with its speech as sound, or write its FAP values as a .fap file.")
    p.add_argument("project", metavar="PROJECT.mimica")
    p.add_argument("--out", "-o", required=True, metavar="FILE")
    p.add_argument("--size", type=parse_size, default=(1280, 720), metavar="WxH", help="default 1280x720")
    p.add_argument("--fps", type=float, help="frames per second (default: the project's)")
    p.add_argument("--workers", type=_workers, metavar="N",
                   help="render processes working in parallel (default: one per core, fewer for short "
                        "animations; 1 renders in this process)")
    p.add_argument("--full-detail", action="store_true",
                   help="draw every triangle of the face in every frame (default: where the face's triangles "
                        "are only a few pixels on screen, a decimated face that gives the same picture, "
                        "checked by PSNR/SSIM; faster on software OpenGL)")
    p.set_defaults(func=run)


def _workers(text: str) -> int:
    from app.export_plan import MAX_WORKERS

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of workers, got {text!r}") from None
    if not 1 <= value <= MAX_WORKERS:
        raise argparse.ArgumentTypeError(f"--workers must be between 1 and {MAX_WORKERS}, got {value}")
    return value
