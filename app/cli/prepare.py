"""``mimica prepare [FACE]``: build the disk caches a face needs for a quick start.

The FAP table of a face (seconds for the 54k-vertex default face) and the draft level of detail
the viewport draws while things move (about a second) are stored in Mimica's cache folder
(:mod:`core.cache`); the window then reads them in milliseconds. ``scripts/run.sh`` runs this for
the built-in face right after installing, so the very first start is quick too.
"""

from __future__ import annotations

import argparse
import time

from app.cli.common import CliError, load_face_or_default


def run(args: argparse.Namespace) -> int:
    from app.document import build_rig, warm_up_kernels
    from app.preview import cached_preview
    from core.cache import DiskCache, cache_dir

    start = time.perf_counter()
    face = load_face_or_default(getattr(args, "face", None))
    cache = DiskCache()
    rig, message = build_rig(face, cache)
    if rig is None:
        raise CliError(message.splitlines()[0])
    cached_preview(face, cache)
    warm_up_kernels()   # numba's machine code to its disk cache: the window loads it in a moment
    for note in cache.notes:
        print(note)
    print(f"{face.metadata.name}: ready to animate ({time.perf_counter() - start:.1f} s; cache in {cache_dir()})")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("prepare", help="build the caches a face needs for a quick start",
                       description="Build the FAP table and the viewport's draft of FACE (default: the "
                                   "built-in face) into Mimica's cache folder, so the window starts quickly.")
    p.add_argument("face", nargs="?", metavar="FACE", help="mesh file (default: the built-in face)")
    p.set_defaults(func=run)
