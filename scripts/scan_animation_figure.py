"""A scan made by others animated at its own full resolution (off screen):

    .venv/bin/python scripts/scan_animation_figure.py [--data ../shared/data/leeperrysmith]

Reads LeePerrySmith (``LeePerrySmith.glb`` + ``color.jpg``, CC BY 3.0, Infinite Realities /
triplegangers.com) at run time and writes only the rendered sheet ``docs/scan_animation_lps.png``.
The scan goes through the project's own pipeline (automatic landmarks -> the unit scale they
suggest -> registration, as ``mimica landmarks`` / ``mimica register --scale`` do); the FAP rig
drives the canonical face and ``core.registration.scan_mouth.animated_scan`` carries it back to every
vertex of the scan (lips cut, the default face's mouth cavity and teeth behind them; the closed eyes cut
along their lid lines, eyeballs behind them). Rows: neutral, jaw open (FAP 3 open_jaw), joy, eyelids
opened; columns front and three-quarter.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from blend_transfer_figure import registration  # noqa: E402 - the same LeePerrySmith pipeline

TILE = (420, 420)
POSES = (("neutral", {}, None), ("jaw open (FAP 3 = 500)", {"fap:3": 500.0}, None), ("joy 80 %", {}, "joy"),
         ("eyelids opened (FAPs 19, 20 = -1024)", {"fap:19": -1024.0, "fap:20": -1024.0}, None))
VIEWS = ("front", "three-quarter")


def sheet(data: Path, out: Path, report=print) -> Path:
    from app.render import render_face_image
    from core.registration.scan_mouth import animated_scan
    from core.rig import FaceRig

    reg = registration(data, report)
    animated = animated_scan(reg)
    report(f"scan: {animated.n_scan} vertices, {animated.n_copies} along the lip and lid cuts, "
           f"{animated.face.n_vertices - animated.n_scan - animated.n_copies} vertices of added parts "
           f"({', '.join(sorted(animated.face.parts))})")
    rig = FaceRig(reg.face)
    frame = reg.face.vertices                          # the camera frames the face, not the shoulders
    rows = []
    for label, values, expression in POSES:
        rig.set_values({"fap:3": 0.0, "fap:19": 0.0, "fap:20": 0.0, **values})
        rig.set_expression(expression, 0.8 if expression else 1.0)
        posed = animated.face.with_vertices(animated.vertices(rig.vertices()))
        tiles = [render_face_image(posed, view=view, size=TILE, frame_points=frame) for view in VIEWS]
        row = Image.fromarray(np.concatenate(tiles, axis=1))
        ImageDraw.Draw(row).text((10, 10), label, fill=(235, 235, 235))
        rows.append(np.asarray(row))
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(rows, axis=0)).save(out)
    report(f"wrote {out}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "leeperrysmith")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "scan_animation_lps.png")
    args = ap.parse_args()
    if not (args.data / "LeePerrySmith.glb").is_file():
        sys.exit(f"no LeePerrySmith.glb in {args.data}; pass --data FOLDER (it holds LeePerrySmith.glb and color.jpg)")
    sheet(args.data, args.out)


if __name__ == "__main__":
    main()
