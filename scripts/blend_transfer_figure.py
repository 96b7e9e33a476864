"""The default face's built-in expression library transferred onto a face made by others (off screen):

    .venv/bin/python scripts/blend_transfer_figure.py [--data ../shared/data/leeperrysmith]

Reads LeePerrySmith (``LeePerrySmith.glb`` + ``color.jpg``, CC BY 3.0, Infinite Realities /
triplegangers.com) at run time and never writes it or anything derived from it, except the
rendered contact sheet ``docs/blend_transfer_lps.png``. The scan goes through the project's own
pipeline (automatic landmarks -> the unit scale they suggest -> registration, as ``mimica
landmarks`` / ``mimica register`` do), the built-in library is transferred onto the registered face
by each method (``builtin_library_for``: deformation transfer, scaling by FAP units per region and
the thesis's bounding-box scaling), and joy, surprise, sadness and anger are rendered front and three-quarter on the scan
itself at its full resolution (``scan_animation``: lips cut, a mouth cavity and teeth, as the
window shows it after Build correspondence).
``--save-face OBJ`` also writes the canonical face (to try ``mimica render OBJ --blend joy:80``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from PIL import Image, ImageDraw, ImageFont

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TILE = 300
POSES = (("neutral", 0.0), ("joy", 90.0), ("surprise", 90.0), ("sadness", 100.0), ("anger", 100.0))
METHODS = ("deformation", "fap_units", "bbox")
VIEWS = ("front", "three-quarter")


def registration(data: Path, report=print):
    """LeePerrySmith's Registration through the pipeline (landmarks, scale, registration); also used
    by scripts/scan_animation_figure.py."""
    from app.cli.common import load_face_or_default, with_texture
    from core.registration.pipeline import detect_landmarks, register_scan

    scan = with_texture(load_face_or_default(str(data / "LeePerrySmith.glb")),
                        SimpleNamespace(texture=str(data / "color.jpg"), flip_texture=False))
    det = detect_landmarks(scan)
    scale = det.scale_hint or 1.0
    report(f"landmarks: {len(det.landmarks)} found, {len(det.low_confidence())} with low confidence; "
           f"scale {scale:.3g} to millimetres")
    if scale != 1.0:
        scan = scan.scaled(scale)          # surface points survive scaling
    reg = register_scan(scan, det.landmarks)
    report(f"registered: {reg.face.n_vertices} vertices, {reg.fallbacks} took the closest point")
    return reg


def posed_images(face, method: str, cache=None, frame=None) -> list[list[np.ndarray]]:
    """[[front, three-quarter] per pose] of ``face`` with the built-in library moved on by ``method``
    (its FAP table from ``cache`` when there; the camera frames ``frame`` points, default the face)."""
    from app.render import render_face_image
    from core.layers.blend.builtin import builtin_library_for
    from core.layers.blend.layer import BlendLayer
    from core.rig import FaceRig

    rig = FaceRig(face, cache=cache)
    found = builtin_library_for(face, rig.deformer, method)
    if found is None:
        raise SystemExit("the built-in library does not fit this face (no mpeg4_80 FAP rig)")
    library, correspondence = found
    assert library.transfer == method, (library.transfer, method)
    layer = rig.add_layer(BlendLayer(face, library, correspondence=correspondence))
    out = []
    for pose, percent in POSES:
        rig.reset()
        if percent:
            rig.set_values({f"blend:{pose}": percent})
        posed = face.with_vertices(rig.vertices())
        out.append([render_face_image(posed, view=v, size=(2 * TILE, 2 * TILE), frame_points=frame) for v in VIEWS])
    rig.remove_layer(layer.name)
    return out


def contact_sheet(rows: list[tuple[str, list[np.ndarray]]], columns: list[str]) -> Image.Image:
    """Rows of tiles under column labels, each row labelled on its first tile."""
    band = 34
    sheet = Image.new("RGB", (TILE * len(columns), band + TILE * len(rows)), (40, 42, 48))
    draw = ImageDraw.Draw(sheet)
    font = ImageFont.load_default(size=20)
    for j, label in enumerate(columns):
        draw.text((j * TILE + 8, 6), label, fill=(255, 255, 120), font=font)
    for i, (label, images) in enumerate(rows):
        for j, image in enumerate(images):
            sheet.paste(Image.fromarray(image).resize((TILE, TILE)), (j * TILE, band + i * TILE))
        draw.text((8, band + i * TILE + 6), label, fill=(255, 255, 120), font=font)
    return sheet


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "leeperrysmith"),
                        help="folder with LeePerrySmith.glb and color.jpg")
    parser.add_argument("--out", default=str(ROOT / "docs" / "blend_transfer_lps.png"))
    parser.add_argument("--save-face", metavar="OBJ", help="also save the registered face (outside the repository)")
    args = parser.parse_args(argv)
    data = Path(args.data)
    if not (data / "LeePerrySmith.glb").is_file():
        print(f"no LeePerrySmith.glb in {data}", file=sys.stderr)
        return 1
    from core.cache import DiskCache
    from core.registration.scan_mouth import scan_animation

    reg = registration(data)
    if args.save_face:
        from core.formats.mesh_io import save_face

        save_face(reg.face, args.save_face)
        print(f"wrote {args.save_face}")
    cache = DiskCache()
    face = scan_animation(reg, cache)
    rows = []
    for method in METHODS:
        images = posed_images(face, method, cache, frame=reg.face.vertices)
        for k, view in enumerate(VIEWS):
            rows.append((f"{method}, {view}", [pair[k] for pair in images]))
    columns = [name if not p else f"{name} {p:.0f} %" for name, p in POSES]
    contact_sheet(rows, columns).save(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
