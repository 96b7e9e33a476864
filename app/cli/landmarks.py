"""``mimica landmarks SCAN|FOLDER --out L.json|FOLDER``: detect the template's landmarks on scans."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.cli.common import (TEMPLATES, CliError, add_texture_options, load_face_or_default, output_for, run_batch,
                            scan_files, with_texture)


def run(args: argparse.Namespace) -> int:
    """Detect the template's landmarks on each scan and save them as landmark JSON."""
    from core.formats.landmarks_io import LandmarkFileError, save_landmarks
    from core.registration.pipeline import detect_landmarks

    files = scan_files(args.scan)
    batch = len(files) > 1 or Path(args.scan).is_dir()
    out = Path(args.out)

    def work(path: Path) -> str:
        scan = with_texture(load_face_or_default(str(path)), args)
        try:
            detection = detect_landmarks(scan, template=args.template)
        except ValueError as exc:
            raise CliError(str(exc)) from None
        target = output_for(path, out, batch, ".landmarks.json")
        try:
            save_landmarks(detection.face_with_landmarks(scan), target)
        except LandmarkFileError as exc:
            raise CliError(str(exc)) from None
        for line in detection.report:
            print(f"  note: {line}", file=sys.stderr)
        low = detection.low_confidence()
        return (f"{len(detection.landmarks)} landmarks -> {target}"
                + (f"; check {len(low)} with low confidence" if low else "")
                + (f"; not in mm: register with --scale {detection.scale_hint:.3g}" if detection.scale_hint else ""))

    return run_batch(files, work, "landmarked")


def add_parser(sub) -> None:
    p = sub.add_parser("landmarks", help="detect landmarks on a scan or a folder of scans",
                       description="Find the template's landmarks on SCAN (or every scan in a folder) by "
                                   "ICP and structural matching, and save them as landmark JSON.")
    p.add_argument("scan", metavar="SCAN|FOLDER")
    p.add_argument("--template", choices=TEMPLATES, default="mpeg4_80",
                   help="landmark set: the 80-point MPEG-4 template (default) or the thesis's 48 points")
    p.add_argument("--out", "-o", required=True, metavar="L.json|FOLDER")
    add_texture_options(p)
    p.set_defaults(func=run)
