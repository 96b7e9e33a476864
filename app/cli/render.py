"""``mimica render [FACE] --out PNG``: render a face, posed by FAPs, presets or muscles, off screen."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from app.cli.common import (MODES, VIEWS, CliError, add_texture_options, checked_value, load_face_or_default,
                            parse_size, positive_factor, rig_values, with_texture)


def run(args: argparse.Namespace) -> int:
    """Render a face off screen to an image file."""
    out = Path(args.out)
    if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise CliError(f"--out must end in .png or .jpg, got {args.out!r}")
    if out.parent and not out.parent.exists():
        raise CliError(f"output folder does not exist: {out.parent}")
    values = {**rig_values(args), **blend_values(args)}    # option errors before the slow work
    face = with_texture(load_face_or_default(args.face), args)
    if args.register:
        face = registered_scan(face, args)
    for note in getattr(face.metadata, "notes", []) or []:
        print(f"note: {note}", file=sys.stderr)
    from app.render import render_face_png

    if values:
        face = face.with_vertices(posed_vertices(face, values))
    try:
        render_face_png(face, out, view=args.view, size=args.size, mode=args.mode,
                        show_landmarks=args.landmarks)
    except OSError as exc:
        raise CliError(f"cannot write {out}: {exc.strerror or exc}") from None
    print(f"wrote {out} ({args.size[0]}x{args.size[1]}, {args.view}, {args.mode})")
    return 0


def blend_values(args) -> dict[str, float]:
    """{key: %} of --blend POSE[:PERCENT] (repeatable; 100 % when no percent) and --caricature PERCENT."""
    from core import parameters as P

    values: dict[str, float] = {}
    for item in getattr(args, "blend", None) or []:
        name, _, percent = item.partition(":")
        try:
            number = float(percent) if percent.strip() else 100.0
        except ValueError:
            raise CliError(f"--blend {item!r}: the percent {percent.strip()!r} is not a number; write POSE or "
                           "POSE:PERCENT, e.g. --blend joy:80") from None
        try:
            key = P.key_of(f"blend:{name.strip()}")
            values[key] = P.check_value(key, number)
        except (P.ParameterError, ValueError) as exc:
            raise CliError(f"--blend {item!r}: {exc}; write POSE or POSE:PERCENT, e.g. --blend joy:80") from None
    if getattr(args, "caricature", None) is not None:
        values["caricature"] = checked_value("--caricature", "caricature", args.caricature)
    return values


def registered_scan(scan, args):
    """The scan itself, registered with the landmarks of ``--register`` (scaled by ``--scale``) and
    made animatable: lips cut, a mouth cavity and teeth (as the window's Build correspondence)."""
    from core.cache import DiskCache
    from core.formats.landmarks_io import LandmarkFileError, load_landmarks
    from core.registration.pipeline import register_scan
    from core.registration.scan_mouth import scan_animation

    if args.face is None:
        raise CliError("--register needs a FACE: the scan the landmark file was made for")
    try:
        landmarks = load_landmarks(Path(args.register), scan)
        if args.scale is not None:   # surface points survive scaling
            scan = scan.scaled(args.scale)
        registration = register_scan(scan, landmarks)
    except (LandmarkFileError, ValueError) as exc:
        raise CliError(f"--register {args.register}: {exc}") from None
    return scan_animation(registration, DiskCache())


def posed_vertices(face, values: dict[str, float]) -> np.ndarray:
    """(n, 3) mm: ``face`` posed by parameter ``values`` (the muscle model is built and settled when
    muscle forces or the jaw are given). The FAP table comes from the disk cache when this face was
    animated before (a registered scan's is put there by ``registered_scan``)."""
    from core.cache import DiskCache
    from core.layers.fap.template import TemplateError
    from core.layers.muscles import SolverDiverged
    from core.rig import FaceRig

    try:
        rig = FaceRig(face, cache=DiskCache())
    except (TemplateError, ValueError) as exc:
        raise CliError(f"cannot animate this face: {exc}") from None
    try:
        rig.ensure_layers(values)
        _check_blend_poses(rig, values)
        rig.set_values(values)
        muscles = rig.layer("muscles")
        start = time.perf_counter()
        while muscles is not None and not muscles.converged:
            muscles.relax(budget_s=1.0)
            if time.perf_counter() - start > 60:
                raise CliError("the muscle model did not settle within 60 s; try smaller forces")
    except SolverDiverged as exc:
        raise CliError(str(exc)) from None
    except ValueError as exc:
        raise CliError(str(exc)) from None
    return rig.vertices()


def _check_blend_poses(rig, values) -> None:
    """CliError naming the library's poses when a ``--blend`` pose is not one of them (or the face has
    no expression library at all)."""
    wanted = [k.partition(":")[2] for k in values if k.startswith("blend:")]
    if not wanted and "caricature" not in values:
        return
    layer = rig.layer("blend")
    poses = tuple(getattr(layer, "poses", ()) or ())
    has_mean = getattr(getattr(layer, "library", None), "mean", None) is not None
    if not poses and not has_mean:
        raise CliError("this face has no expression library: the built-in one fits the default face and faces "
                       "registered to the mpeg4_80 template ('mimica register'); other libraries are made in the "
                       "window (Blends dock)")
    missing = [name for name in wanted if name not in poses]
    if missing:
        raise CliError(f"--blend: the expression library has no pose {missing[0]!r}; its poses are {', '.join(poses)}")
    if "caricature" in values and not has_mean:
        raise CliError("--caricature: this face's expression library has no mean face")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "render", help="render a face to a PNG/JPG without a display",
        description="Render FACE (or the default face) off screen to an image. Needs no display.",
    )
    p.add_argument("face", nargs="?", metavar="FACE", help="mesh file (default: the built-in default face)")
    p.add_argument("--out", "-o", required=True, metavar="PNG", help="output image (.png or .jpg)")
    p.add_argument("--view", choices=VIEWS, default="front", help="camera preset (default: front)")
    p.add_argument("--size", type=parse_size, default=(1200, 900), metavar="WxH",
                   help="image size in pixels (default: 1200x900)")
    p.add_argument("--mode", choices=MODES, default="textured", help="display mode (default: textured)")
    p.add_argument("--landmarks", action="store_true", help="draw landmarks with their labels")
    add_texture_options(p)
    scan = p.add_argument_group("a scan animated at its own resolution (as the window's Build correspondence)")
    scan.add_argument("--register", metavar="L.json",
                      help="register FACE with this landmark file ('mimica landmarks' writes it) and animate the "
                           "scan itself: lips cut along the lip line, a mouth cavity and teeth behind them")
    scan.add_argument("--scale", type=positive_factor, metavar="FACTOR",
                      help="with --register: multiply the scan's coordinates by FACTOR first ('mimica landmarks' "
                           "prints the factor it suggests for a scan in other units)")
    anim = p.add_argument_group("MPEG-4 animation (the face needs the 64 feature points of the template)")
    anim.add_argument("--fap", action="append", default=[], metavar="NAME=VALUE",
                      help="low-level FAP by name or number, in FAP units, e.g. open_jaw=400 or 19=1024 "
                           "(repeatable)")
    anim.add_argument("--expression", metavar="NAME[:PERCENT]",
                      help="expression preset (joy, sadness, anger, fear, disgust, surprise), e.g. joy:60")
    anim.add_argument("--viseme", metavar="ID[:PERCENT]",
                      help="viseme preset by id 0-14 or name (PP, FF, TH, DD, kk, CH, SS, nn, RR, aa, E, ih, oh, "
                           "ou), e.g. 10:80")
    bio = p.add_argument_group("muscles (thesis C's biomechanical model; the face needs its feature points)")
    bio.add_argument("--muscles", metavar="PRESET|NAME=FORCE,...",
                     help="a preset (discreet_smile, half_smile, sadness, disgust, kiss) or forces such as "
                          "risorius=42,zygomatic_major:left=9 (no side = both sides)")
    bio.add_argument("--jaw", type=float, metavar="DEG", help="jaw rotation in degrees (opens the mouth)")
    blend = p.add_argument_group("expression blends (the face's expression library; the default face has a built-in one)")
    blend.add_argument("--blend", action="append", default=[], metavar="POSE[:PERCENT]",
                       help="add a library pose, e.g. joy:80 or viseme_10 (repeatable; 100 %% without a percent)")
    blend.add_argument("--caricature", type=float, metavar="PERCENT",
                       help="exaggerate the face's difference from the library's mean face (-100 = the mean)")
    p.set_defaults(func=run)
