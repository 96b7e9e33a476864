"""The ``mimica`` command: one module per subcommand, one shared helper module (:mod:`app.cli.common`).

    mimica                       open the window on the default face
    mimica gui [FACE]            open the window on FACE (or the default face)
    mimica render [FACE] --out PNG [--view ...] [--size WxH] [--mode ...] [--landmarks]
                 [--fap ...] [--expression ...] [--viseme ...] [--muscles ...] [--jaw DEG]
    mimica landmarks | register | evaluate-landmarks     scans, one file or a folder
    mimica export | lipsync | demo                       projects and animation

Each subcommand module has ``add_parser(subparsers)`` and ``run(args)``; none imports another.
Heavy imports (Qt, VTK, mesh loaders) happen inside ``run`` so ``mimica --help`` is instant and
``mimica render`` never loads Qt. User errors print one line on stderr and exit non-zero, without
a traceback.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from app.cli import demo, evaluate, export, gui, landmarks, lipsync, prepare, register, render
from app.cli.common import (PROG, CliError, load_face_or_default, parse_muscle_forces, parse_size,
                            unexpected_error_message)

_parse_size = parse_size  # the name tests and scripts used

SUBCOMMANDS = (gui, render, landmarks, register, evaluate, export, lipsync, demo, prepare)


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
    for command in SUBCOMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``mimica`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)  # argparse prints usage + one error line, exits 2
    func = getattr(args, "func", gui.run)
    if func is not gui.run:   # the window sweeps when it offers recovery
        from app.export_sinks import sweep_at_start

        sweep_at_start()   # what killed exports left (their temporary and target folders)
    try:
        return int(func(args) or 0)
    except CliError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return exc.status
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - last resort: one line, no traceback
        print(f"{PROG}: error: {unexpected_error_message(exc, getattr(args, 'command', None))}", file=sys.stderr)
        return 1


__all__ = ["main", "build_parser", "CliError", "load_face_or_default", "parse_muscle_forces", "PROG"]
