"""cli.py
----
The ``mimica`` command.

    mimica                       open the window on the default face
    mimica gui [FACE]            open the window on FACE (or the default face)
    mimica render [FACE] --out PNG [--view ...] [--size WxH] [--mode ...] [--landmarks]
                 [--fap ...] [--expression ...] [--viseme ...] [--muscles ...] [--jaw DEG]
    mimica landmarks | register | evaluate-landmarks     (see app/cli_scan.py)
    mimica export | lipsync | demo                       (see app/cli_timeline.py)

Heavy imports (Qt, VTK, mesh loaders) happen inside the subcommand handlers
so ``mimica --help`` is instant and ``mimica render`` never loads Qt.
User errors print one line on stderr and exit non-zero, without a traceback.
Scan commands (landmarks, register, evaluate-landmarks) are in :mod:`app.cli_scan`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

PROG = "mimica"

VIEWS = ("front", "side", "three-quarter")
MODES = ("textured", "shaded", "wireframe", "points")


class CliError(Exception):
    """A user-facing error: printed as one line, exit status 1 (or ``status``)."""

    def __init__(self, message: str, status: int = 1):
        super().__init__(message)
        self.status = status


# ------------------------------------------------------------------ helpers
def _parse_size(text: str) -> tuple[int, int]:
    """``"1200x900"`` -> (1200, 900)."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        width, height = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 1200x900, got {text!r}") from None
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise argparse.ArgumentTypeError(f"size {width}x{height} out of range (16..8192 per side)")
    return width, height


def load_face_or_default(path: str | None):
    """The face at ``path`` (via ``core.mesh_io``) or the default face; raises :class:`CliError`."""
    if path is None:
        try:
            from core.default_face import load_default_face
        except ImportError as exc:
            raise CliError(f"the default face is not available ({exc}); give a face file") from None
        return load_default_face()
    p = Path(path)
    if not p.exists():
        raise CliError(f"no such file: {path}")
    if p.is_dir():
        raise CliError(f"{path} is a directory, not a face file")
    try:
        from core.mesh_io import MeshLoadError, load_face
    except ImportError as exc:
        raise CliError(f"mesh loading is not available ({exc})") from None
    try:
        face = load_face(p)
    except MeshLoadError as exc:
        raise CliError(f"cannot load {path}: {exc}") from None
    from core.registration.correspondence import with_canonical_landmarks

    return with_canonical_landmarks(face)  # a saved canonical face animates again


# ---------------------------------------------------------------- commands
def cmd_gui(args: argparse.Namespace) -> int:
    """Start the desktop window."""
    face = getattr(args, "face", None)
    if face is not None and not Path(face).is_file():
        raise CliError(f"no such file: {face}")
    from app.main_window import run_gui

    return run_gui(face)


def cmd_render(args: argparse.Namespace) -> int:
    """Render a face off screen to an image file."""
    out = Path(args.out)
    if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise CliError(f"--out must end in .png or .jpg, got {args.out!r}")
    if out.parent and not out.parent.exists():
        raise CliError(f"output folder does not exist: {out.parent}")
    face = load_face_or_default(args.face)
    for note in getattr(face.metadata, "notes", []) or []:
        print(f"note: {note}", file=sys.stderr)
    from app.render import render_face_png

    if args.fap or args.expression or args.viseme or args.muscles or args.jaw is not None:
        face = face.with_vertices(_animated_vertices(face, args))
    try:
        render_face_png(face, out, view=args.view, size=args.size, mode=args.mode,
                        show_landmarks=args.landmarks)
    except OSError as exc:
        raise CliError(f"cannot write {out}: {exc.strerror or exc}") from None
    print(f"wrote {out} ({args.size[0]}x{args.size[1]}, {args.view}, {args.mode})")
    return 0


def _named_value(text: str, what: str) -> tuple[str, str | None]:
    name, sep, value = text.partition("=" if what == "fap" else ":")
    if not name.strip() or (sep and not value.strip()):
        example = "open_jaw=400" if what == "fap" else f"{'joy:60' if what == 'expression' else '10:80'}"
        raise CliError(f"--{what} {text!r}: expected e.g. --{what} {example}")
    return name.strip(), value.strip() if sep else None


def _number(text: str, what: str) -> float:
    try:
        value = float(text.rstrip("%"))
    except ValueError:
        raise CliError(f"{what}: {text!r} is not a number") from None
    if not np.isfinite(value):
        raise CliError(f"{what}: {text!r} is not a finite number")
    return value


def _intensity(text: str | None, what: str) -> float:
    """Percent (0-100) -> fraction; absent means 100 %."""
    if text is None:
        return 1.0
    value = _number(text, what)
    if not 0 <= value <= 100:
        raise CliError(f"{what}: intensity must be 0-100 (%), got {text}")
    return value / 100.0


def _animated_vertices(face, args) -> np.ndarray:
    """The face deformed by --fap / --expression / --viseme (FAP units, percent intensities)."""
    from core.fap import tables
    from core.fap.template import TemplateError
    from core.rig import FaceRig

    try:
        rig = FaceRig(face)
    except (TemplateError, ValueError) as exc:
        raise CliError(f"cannot animate this face: {exc}") from None
    values = {}
    for item in args.fap:
        name, value = _named_value(item, "fap")
        if value is None:
            raise CliError(f"--fap {item!r}: give a value, e.g. --fap {name}=200")
        try:
            spec = tables.fap_spec(name)
        except ValueError as exc:
            raise CliError(f"--fap {item!r}: {exc}") from None
        values[spec.number] = _number(value, f"--fap {spec.name}")
    try:
        rig.set_faps(values)
        if args.expression:
            name, value = _named_value(args.expression, "expression")
            rig.set_expression(name, _intensity(value, f"--expression {name}"))
        if args.viseme:
            name, value = _named_value(args.viseme, "viseme")
            rig.set_viseme(name, _intensity(value, f"--viseme {name}"))
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if args.muscles or args.jaw is not None:
        _apply_muscles(face, rig, args)
    return rig.vertices()


def parse_muscle_forces(text: str):
    """``"kiss"`` (a preset) or ``"zygomatic_major=9,risorius:left=6,orbicularis_oris=8"`` -> ForceSet.

    A paired muscle without a side gets the force on both sides.
    """
    from core.muscles import ForceSet, control_keys, preset, preset_names

    text = text.strip()
    if text in preset_names():
        return preset(text)
    if "=" not in text:
        raise CliError(f"--muscles {text!r}: not a preset ({', '.join(preset_names())}) "
                       "and not name=force pairs, e.g. --muscles risorius=40,zygomatic_major:left=9")
    keys = control_keys()
    names = sorted({name for name, _side in keys})
    forces = {}
    for item in text.split(","):
        target, sep, value = item.partition("=")
        name, _, side = target.strip().partition(":")
        side = side.strip() or None
        if not sep or not name or not value.strip():
            raise CliError(f"--muscles {item!r}: expected name=force, e.g. risorius=40")
        if name not in names:
            raise CliError(f"--muscles: unknown muscle {name!r}; muscles are {', '.join(names)}")
        sides = [s for n, s in keys if n == name]
        if side is not None and side not in sides:
            raise CliError(f"--muscles {item!r}: side must be one of {', '.join(str(s) for s in sides)}")
        force = _number(value, f"--muscles {name}")
        for s in ([side] if side is not None else sides):
            forces[(name, s)] = force
    return ForceSet(forces=forces)


def _apply_muscles(face, rig, args) -> None:
    """Build the face's muscle model, set --muscles / --jaw and solve the pose to equilibrium."""
    import time

    from core.muscles import MuscleLayer, SolverDiverged

    force_set = parse_muscle_forces(args.muscles) if args.muscles else None
    try:
        layer = MuscleLayer(face)
        if force_set is not None:
            layer.apply(force_set)
        if args.jaw is not None:
            layer.set_jaw(args.jaw)
        layer.attach(rig)
        start = time.perf_counter()
        while not layer.converged:
            layer.relax(budget_s=1.0)
            if time.perf_counter() - start > 60:
                raise CliError("the muscle model did not settle within 60 s; try smaller forces")
    except SolverDiverged as exc:
        raise CliError(str(exc)) from None
    except ValueError as exc:
        raise CliError(f"--muscles/--jaw: {exc}") from None


# ------------------------------------------------------------------ parser
def _add_gui(sub) -> None:
    p = sub.add_parser("gui", help="open the desktop window (the default when no command is given)",
                       description="Open the Mimica window on FACE, or on the built-in default face.")
    p.add_argument("face", nargs="?", metavar="FACE", help="mesh file to open (obj, ply, stl, glb, gltf)")
    p.set_defaults(func=cmd_gui)


def _add_render(sub) -> None:
    p = sub.add_parser(
        "render", help="render a face to a PNG/JPG without a display",
        description="Render FACE (or the default face) off screen to an image. Needs no display.",
    )
    p.add_argument("face", nargs="?", metavar="FACE", help="mesh file (default: the built-in default face)")
    p.add_argument("--out", "-o", required=True, metavar="PNG", help="output image (.png or .jpg)")
    p.add_argument("--view", choices=VIEWS, default="front", help="camera preset (default: front)")
    p.add_argument("--size", type=_parse_size, default=(1200, 900), metavar="WxH",
                   help="image size in pixels (default: 1200x900)")
    p.add_argument("--mode", choices=MODES, default="textured", help="display mode (default: textured)")
    p.add_argument("--landmarks", action="store_true", help="draw landmarks with their labels")
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
    p.set_defaults(func=cmd_render)


def _subcommands() -> list[Callable]:
    """Subcommand builders, in help order (scan and timeline commands live in their own modules)."""
    from app import cli_scan, cli_timeline

    return [_add_gui, _add_render, cli_scan.add_landmarks, cli_scan.add_register, cli_scan.add_evaluate,
            cli_timeline.add_export, cli_timeline.add_lipsync, cli_timeline.add_demo]


def build_parser() -> argparse.ArgumentParser:
    from app import __version__

    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Mimica: a desktop workbench for 3-D facial animation. "
                    "Without a command, opens the window on the default face.",
        epilog="examples:\n"
               "  mimica                                   open the window on the default face\n"
               "  mimica gui head.obj                      open the window on head.obj\n"
               "  mimica render --out face.png             render the default face (no display needed)\n"
               "  mimica render head.ply -o side.png --view side --mode shaded --landmarks\n"
               "  mimica render --muscles kiss -o kiss.png  the face after a muscle preset settles\n\n"
               "Run 'mimica COMMAND --help' for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for add in _subcommands():
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mimica`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)  # argparse prints usage + one error line, exits 2
    func = getattr(args, "func", cmd_gui)
    try:
        return int(func(args) or 0)
    except CliError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return exc.status
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - last resort: one line, no traceback
        print(f"{PROG}: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
