"""cli_scan.py
----
Batch commands for scans (thesis A ch. 2-3), usable on one file or a folder of scans:

    mimica landmarks SCAN|FOLDER [--template mpeg4_80|a48] --out L.json|FOLDER
    mimica register  SCAN|FOLDER --landmarks L.json|FOLDER --out FACE.obj|FOLDER [--template ...]
    mimica evaluate-landmarks [--people N] [--template a48|mpeg4_80] [--charts DIR]

A folder is processed file by file with a progress line per scan; a scan that fails is reported
and skipped, and the exit status is 1 if any failed. The handlers import the solvers lazily.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from app.cli import CliError, load_face_or_default

SCAN_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
TEMPLATES = ("mpeg4_80", "a48")


def _scan_files(path: str) -> list[Path]:
    p = Path(path)
    if not p.exists():
        raise CliError(f"no such file or folder: {path}")
    if p.is_dir():
        files = sorted(f for f in p.iterdir() if f.suffix.lower() in SCAN_SUFFIXES)
        if not files:
            raise CliError(f"{path} holds no scans ({', '.join(SCAN_SUFFIXES)})")
        return files
    return [p]


def _output_for(scan: Path, out: Path, batch: bool, suffix: str) -> Path:
    """Output path of one scan: ``out`` itself, or ``out/<scan name><suffix>`` for a folder."""
    if not batch:
        if not out.parent.exists():
            raise CliError(f"output folder does not exist: {out.parent}")
        return out
    out.mkdir(parents=True, exist_ok=True)
    return out / (scan.stem + suffix)


def _run_batch(files: list[Path], work, what: str) -> int:
    """Run ``work(path) -> summary`` for each file, print progress; 1 if any failed."""
    failed = 0
    for k, path in enumerate(files, 1):
        start = time.perf_counter()
        prefix = f"[{k}/{len(files)}] {path.name}" if len(files) > 1 else path.name
        try:
            summary = work(path)
        except CliError as exc:
            failed += 1
            print(f"{prefix}: failed: {exc}", file=sys.stderr)
            continue
        print(f"{prefix}: {summary} ({time.perf_counter() - start:.1f} s)", flush=True)
    if failed:
        print(f"{failed} of {len(files)} scan(s) could not be {what}", file=sys.stderr)
    return 1 if failed else 0


def _with_texture(scan, args: argparse.Namespace):
    """``scan`` with the image of ``--texture`` (flipped with ``--flip-texture``), if given."""
    from core.mesh_io import MeshLoadError, load_texture_image

    try:
        if args.texture:
            scan = scan.with_texture(load_texture_image(args.texture))
        return scan.with_flipped_texture() if args.flip_texture and scan.texture is not None else scan
    except (MeshLoadError, ValueError) as exc:
        raise CliError(f"--texture {args.texture}: {exc}") from None


def _add_texture_options(p) -> None:
    p.add_argument("--texture", metavar="IMAGE",
                   help="map IMAGE onto the scan through its texture coordinates (a scan whose texture is a "
                        "separate file)")
    p.add_argument("--flip-texture", action="store_true",
                   help="turn the texture upside down (texture coordinates that count rows from the other end)")


def cmd_landmarks(args: argparse.Namespace) -> int:
    """Detect the template's landmarks on each scan and save them as landmark JSON."""
    from core.landmarks_io import LandmarkFileError, save_landmarks
    from core.registration.pipeline import detect_landmarks

    files = _scan_files(args.scan)
    batch = len(files) > 1 or Path(args.scan).is_dir()
    out = Path(args.out)

    def work(path: Path) -> str:
        scan = _with_texture(load_face_or_default(str(path)), args)
        try:
            detection = detect_landmarks(scan, template=args.template)
        except ValueError as exc:
            raise CliError(str(exc)) from None
        target = _output_for(path, out, batch, ".landmarks.json")
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

    return _run_batch(files, work, "landmarked")


def cmd_register(args: argparse.Namespace) -> int:
    """Build the canonical face of each scan from its landmarks (dense correspondence)."""
    from core.landmarks_io import LandmarkFileError, load_landmarks
    from core.mesh_io import MeshSaveError, save_face
    from core.registration.pipeline import register_scan

    files = _scan_files(args.scan)
    batch = len(files) > 1 or Path(args.scan).is_dir()
    landmark_source = Path(args.landmarks)
    if batch and not landmark_source.is_dir():
        raise CliError("with a folder of scans, --landmarks must be the folder written by 'mimica landmarks'")
    out = Path(args.out)
    if not batch and out.suffix.lower() not in (".obj", ".ply", ".glb"):
        raise CliError(f"--out must end in .obj, .ply or .glb, got {args.out!r}")

    def work(path: Path) -> str:
        scan = _with_texture(load_face_or_default(str(path)), args)
        lm_path = landmark_source / f"{path.stem}.landmarks.json" if batch else landmark_source
        if not lm_path.is_file():
            raise CliError(f"no landmark file {lm_path}; run 'mimica landmarks' first")
        try:
            landmarks = load_landmarks(lm_path, scan)
            if args.scale is not None:  # surface points survive scaling
                scan = scan.scaled(args.scale)
            registration = register_scan(scan, landmarks, template=args.template)
        except (LandmarkFileError, ValueError) as exc:
            raise CliError(str(exc)) from None
        target = _output_for(path, out, batch, ".canonical.obj")
        try:
            save_face(registration.face, target)
        except MeshSaveError as exc:
            raise CliError(str(exc)) from None
        face = registration.face
        return (f"{face.n_vertices} vertices / {face.n_triangles} triangles -> {target}; "
                f"{registration.fallbacks} vertices took the closest point (normal ray missed)")

    return _run_batch(files, work, "registered")


def cmd_evaluate_landmarks(args: argparse.Namespace) -> int:
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


# ------------------------------------------------------------------ parsers
def add_landmarks(sub) -> None:
    p = sub.add_parser("landmarks", help="detect landmarks on a scan or a folder of scans",
                       description="Find the template's landmarks on SCAN (or every scan in a folder) by "
                                   "ICP and structural matching, and save them as landmark JSON.")
    p.add_argument("scan", metavar="SCAN|FOLDER")
    p.add_argument("--template", choices=TEMPLATES, default="mpeg4_80",
                   help="landmark set: the 80-point MPEG-4 template (default) or the thesis's 48 points")
    p.add_argument("--out", "-o", required=True, metavar="L.json|FOLDER")
    _add_texture_options(p)
    p.set_defaults(func=cmd_landmarks)


def add_register(sub) -> None:
    p = sub.add_parser("register", help="build the canonical face of a scan from its landmarks",
                       description="Dense correspondence: subdivide the placed template, projecting onto "
                                   "the scan, so every scan gets the same vertex count and meaning.")
    p.add_argument("scan", metavar="SCAN|FOLDER")
    p.add_argument("--landmarks", "-l", required=True, metavar="L.json|FOLDER")
    p.add_argument("--template", choices=TEMPLATES, default="mpeg4_80")
    p.add_argument("--scale", type=_positive_factor, metavar="FACTOR",
                   help="multiply the scan's coordinates by FACTOR first (a scan in other units; "
                        "'mimica landmarks' prints the factor it suggests)")
    p.add_argument("--out", "-o", required=True, metavar="FACE.obj|FOLDER")
    _add_texture_options(p)
    p.set_defaults(func=cmd_register)


def _positive_factor(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number such as 10 or 0.001, got {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"the scale factor must be a positive number, got {text!r}")
    return value


def add_evaluate(sub) -> None:
    p = sub.add_parser("evaluate-landmarks", help="landmarking accuracy on the synthetic database",
                       description="Thesis A's protocol on synthetic scans: neutral -> each expression of "
                                   "a person, and one expression across people; lambda swept 0..1.")
    p.add_argument("--people", type=int, default=5, help="people in the database (the thesis used 30; default 5)")
    p.add_argument("--template", choices=TEMPLATES, default="a48")
    p.add_argument("--charts", metavar="DIR", help="write accuracy charts (PNG) to DIR")
    p.set_defaults(func=cmd_evaluate_landmarks)
