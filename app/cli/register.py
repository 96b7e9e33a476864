"""``mimica register SCAN|FOLDER --landmarks L --out FACE``: the canonical face of scans (dense correspondence)."""

from __future__ import annotations

import argparse
from pathlib import Path

from app.cli.common import (TEMPLATES, CliError, add_texture_options, load_face_or_default, output_for,
                            positive_factor, run_batch, scan_files, with_texture)


def run(args: argparse.Namespace) -> int:
    """Build the canonical face of each scan from its landmarks (dense correspondence)."""
    from core.formats.landmarks_io import LandmarkFileError, load_landmarks
    from core.formats.mesh_io import MeshSaveError, save_face
    from core.registration.pipeline import register_scan

    files = scan_files(args.scan)
    batch = len(files) > 1 or Path(args.scan).is_dir()
    landmark_source = Path(args.landmarks)
    if batch and not landmark_source.is_dir():
        raise CliError("with a folder of scans, --landmarks must be the folder written by 'mimica landmarks'")
    out = Path(args.out)
    if not batch and out.suffix.lower() not in (".obj", ".ply", ".glb"):
        raise CliError(f"--out must end in .obj, .ply or .glb, got {args.out!r}")

    def work(path: Path) -> str:
        scan = with_texture(load_face_or_default(str(path)), args)
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
        target = output_for(path, out, batch, ".canonical.obj")
        try:
            save_face(registration.face, target)
        except MeshSaveError as exc:
            raise CliError(str(exc)) from None
        face = registration.face
        return (f"{face.n_vertices} vertices / {face.n_triangles} triangles -> {target}; "
                f"{registration.fallbacks} vertices took the closest point (normal ray missed)")

    return run_batch(files, work, "registered")


def add_parser(sub) -> None:
    p = sub.add_parser("register", help="build the canonical face of a scan from its landmarks",
                       description="Dense correspondence: subdivide the placed template, projecting onto "
                                   "the scan, so every scan gets the same vertex count and meaning.")
    p.add_argument("scan", metavar="SCAN|FOLDER")
    p.add_argument("--landmarks", "-l", required=True, metavar="L.json|FOLDER")
    p.add_argument("--template", choices=TEMPLATES, default="mpeg4_80")
    p.add_argument("--scale", type=positive_factor, metavar="FACTOR",
                   help="multiply the scan's coordinates by FACTOR first (a scan in other units; "
                        "'mimica landmarks' prints the factor it suggests)")
    p.add_argument("--out", "-o", required=True, metavar="FACE.obj|FOLDER")
    add_texture_options(p)
    p.set_defaults(func=run)
