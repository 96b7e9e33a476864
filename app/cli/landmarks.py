"""``mimica landmarks SCAN|FOLDER --out L.json|FOLDER``: detect the template's landmarks on scans
(a folder: in parallel with ``--workers N`` or on a Dask cluster with ``--scheduler``; see
:mod:`app.cli.batch`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

from app.cli.batch import ScanResult, add_batch_options, run_batch
from app.cli.common import (TEMPLATES, CliError, add_texture_options, load_face_or_default, output_for, scan_files,
                            with_texture)


def landmark_scan(path: Path, options) -> ScanResult:
    """Detect and save the landmarks of one scan (runs in a batch worker: module level, plain options)."""
    from core.formats.landmarks_io import LandmarkFileError, save_landmarks
    from core.registration.pipeline import detect_landmarks

    scan = with_texture(load_face_or_default(str(path)), options)
    try:
        detection = detect_landmarks(scan, template=options.template)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    target = output_for(path, Path(options.out), options.batch, ".landmarks.json")
    try:
        save_landmarks(detection.face_with_landmarks(scan), target)
    except LandmarkFileError as exc:
        raise CliError(str(exc)) from None
    for line in detection.report:
        print(f"  note: {line}", file=sys.stderr)
    low = detection.low_confidence()
    summary = (f"{len(detection.landmarks)} landmarks -> {target}"
               + (f"; check {len(low)} with low confidence" if low else "")
               + (f"; not in mm: register with --scale {detection.scale_hint:.3g}" if detection.scale_hint else ""))
    return ScanResult(summary, detection.scan_confidence, len(low))


def run(args: argparse.Namespace) -> int:
    """Detect the template's landmarks on each scan and save them as landmark JSON."""
    files = scan_files(args.scan)
    batch = len(files) > 1 or Path(args.scan).is_dir()
    out = Path(args.out)
    if batch:
        out.mkdir(parents=True, exist_ok=True)
    options = SimpleNamespace(template=args.template, out=str(out), batch=batch, texture=args.texture,
                              flip_texture=args.flip_texture, workers=args.workers, scheduler=args.scheduler,
                              resume=args.resume)
    return run_batch(files, landmark_scan, options, "landmarked",
                     output=lambda path: output_for(path, out, batch, ".landmarks.json"),
                     summary_dir=out if batch else None)


def add_parser(sub) -> None:
    p = sub.add_parser("landmarks", help="detect landmarks on a scan or a folder of scans",
                       description="Find the template's landmarks on SCAN (or every scan in a folder) by "
                                   "ICP and structural matching, and save them as landmark JSON. For a folder, "
                                   "a summary.csv in the output folder lists each scan's time, confidence "
                                   "and failures.")
    p.add_argument("scan", metavar="SCAN|FOLDER")
    p.add_argument("--template", choices=TEMPLATES, default="mpeg4_80",
                   help="landmark set: the 80-point MPEG-4 template (default) or the thesis's 48 points")
    p.add_argument("--out", "-o", required=True, metavar="L.json|FOLDER")
    add_texture_options(p)
    add_batch_options(p)
    p.set_defaults(func=run)
