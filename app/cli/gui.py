"""``mimica gui [FACE]``: open the desktop window (the default when no command is given)."""

from __future__ import annotations

import argparse
from pathlib import Path

from app.cli.common import CliError


def run(args: argparse.Namespace) -> int:
    """Start the desktop window."""
    face = getattr(args, "face", None)
    if face is not None and not Path(face).is_file():
        raise CliError(f"no such file: {face}")
    from app.main_window import run_gui

    return run_gui(face)


def add_parser(sub) -> None:
    p = sub.add_parser("gui", help="open the desktop window (the default when no command is given)",
                       description="Open the Mimica window on FACE, or on the built-in default face.")
    p.add_argument("face", nargs="?", metavar="FACE", help="mesh file to open (obj, ply, stl, glb, gltf)")
    p.set_defaults(func=run)
