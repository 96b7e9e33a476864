"""``mimica register SCAN|FOLDER --landmarks L --out FACE``: the canonical face of scans (dense
correspondence; a folder runs as a batch, see :mod:`app.cli.batch`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from types import SimpleNamespace

from app.cli.batch import ScanResult, add_batch_options, run_batch
from app.cli.common import (TEMPLATES, CliError, add_texture_options, load_face_or_default, output_for,
                            positive_factor, scan_files, with_texture)


def register_one(path: Path, options) -> ScanResult:
    """Register one scan with its landmark file and save its canonical face (a batch worker's job)."""
    from core.formats.landmarks_io import LandmarkFileError, load_landmarks
    from core.formats.mesh_io import MeshSaveError, save_face
    from core.registration.pipeline import register_scan

    scan = with_texture(load_face_or_default(str(path)), options)
    source = Path(options.landmarks)
    lm_path = source / f"{path.stem}.landmarks.json" if options.batch else source
    if not lm_path.is_file():
        raise CliError(f"no landmark file {lm_path}; run 'mimica landmarks' first")
    try:
        landmarks = load_landmarks(lm_path, scan)
        if options.scale is not None:  # surface points survive scaling
            scan = scan.scaled(options.scale)
        registration = register_scan(scan, landmarks, template=options.template)
    except (LandmarkFileError, ValueError) as exc:
        raise CliError(str(exc)) from None
    target = output_for(path, Path(options.out), options.batch, ".canonical.obj")
    try:
        save_face(registration.face, target)
    except MeshSaveError as exc:
        raise CliError(str(exc)) from None
    notes = "".join(f"\n  note: {line}" for line in registration.report[1:])   # [0] repeats the summary
    return ScanResult(f"{registration.summary()} -> {target}{notes}")


def run(args: argparse.Namespace) -> int:
    """Build the canonical face of each scan from its landmarks (dense correspondence)."""
    files = scan_files(args.scan)
    batch = len(files) > 1 or Path(args.scan).is_dir()
    if batch and not Path(args.landmarks).is_dir():
        raise CliError("with a folder of scans, --landmarks must be the folder written by 'mimica landmarks'")
    out = Path(args.out)
    if not batch and out.suffix.lower() not in (".obj", ".ply", ".glb"):
        raise CliError(f"--out must end in .obj, .ply or .glb, got {args.out!r}")
    if batch:
        out.mkdir(parents=True, exist_ok=True)
    options = SimpleNamespace(template=args.template, out=str(out), batch=batch, landmarks=args.landmarks,
                              scale=args.scale, texture=args.texture, flip_texture=args.flip_texture,
                              workers=args.workers, scheduler=args.scheduler, resume=args.resume)
    return run_batch(files, register_one, options, "registered",
                     output=lambda path: output_for(path, out, batch, ".canonical.obj"),
                     summary_dir=out if batch else None)


def add_parser(sub) -> None:
    p = sub.add_parser("register", help="build the canonical face of a scan from its landmarks",
                       description="Dense correspondence: subdivide the placed template, projecting onto "
                                   "the scan, so every scan gets the same vertex count and meaning. For a "
                                   "folder, a summary.csv in the output folder lists each scan's result.")
    p.add_argument("scan", metavar="SCAN|FOLDER")
    p.add_argument("--landmarks", "-l", required=True, metavar="L.json|FOLDER")
    p.add_argument("--template", choices=TEMPLATES, default="mpeg4_80")
    p.add_argument("--scale", type=positive_factor, metavar="FACTOR",
                   help="multiply the scan's coordinates by FACTOR first (a scan in other units; "
                        "'mimica landmarks' prints the factor it suggests)")
    p.add_argument("--out", "-o", required=True, metavar="FACE.obj|FOLDER")
    add_texture_options(p)
    add_batch_options(p)
    p.set_defaults(func=run)
