"""Regenerate the README's contact sheets of the built-in face (off screen; no display needed):

    .venv/bin/python scripts/readme_figures.py [head] [fap] [muscles] [blend]     (all four by default)

docs/default_head.png: the built-in head at rest from the front, the side, in three-quarter view and
from the back, framed whole;
docs/fap_expressions.png: the six expression presets, a jaw opening and a blink, each from the
front and in three-quarter view; docs/muscle_presets.png: thesis C's muscle presets the same way;
docs/blend_library.png: poses of the built-in expression library and caricatures, each tile
labelled with the ``mimica render`` option that makes it.
Every image is rendered by the same code as ``mimica render`` (app.render, app.cli.render).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

TILE = 360   # pixels per view


def sheet(rows: list[tuple[str, list[np.ndarray]]], columns: int = 3, tile: int = TILE) -> Image.Image:
    """Labelled tiles (each a row of views side by side, ``tile`` pixels each), ``columns`` poses per line."""
    views = len(rows[0][1])
    width = tile * views
    columns = min(columns, len(rows))
    lines = (len(rows) + columns - 1) // columns
    band = max(24, tile // 9)
    out = Image.new("RGB", (width * columns, (tile + band) * lines), (255, 255, 255))
    draw = ImageDraw.Draw(out)
    font = ImageFont.load_default(size=int(band * 0.65))
    for k, (label, images) in enumerate(rows):
        x, y = (k % columns) * width, (k // columns) * (tile + band)
        draw.text((x + 8, y + band * 0.15), label, fill=(190, 20, 20) if label.startswith("FAIL") else (20, 20, 20),
                  font=font)
        for j, image in enumerate(images):
            out.paste(Image.fromarray(image).resize((tile, tile)), (x + j * tile, y + band))
    return out


def poses_of(rig, settings) -> list[tuple[str, list[np.ndarray]]]:
    from app.render import render_face_image

    rows = []
    for label, apply in settings:
        rig.reset()
        apply(rig)
        face = rig.face.with_vertices(rig.vertices())
        rows.append((label, [render_face_image(face, view=v, size=(TILE * 2, TILE * 2))
                             for v in ("front", "three-quarter")]))
    return rows


#: docs/blend_library.png: (label, view, {parameter key: value}) per tile, four tiles a line.
BLEND_TILES = (
    ("neutral", "front", {}), ("--blend joy:80", "front", {"blend:joy": 80.0}),
    ("--blend surprise", "front", {"blend:surprise": 100.0}),
    ("--blend viseme_10 (a)", "front", {"blend:viseme_10": 100.0}),
    ("neutral", "three-quarter", {}), ("--blend joy:80", "three-quarter", {"blend:joy": 80.0}),
    ("--blend surprise", "three-quarter", {"blend:surprise": 100.0}),
    ("--caricature 100", "three-quarter", {"caricature": 100.0}),
    ("--caricature -100 (mean face)", "front", {"caricature": -100.0}),
    ("--caricature 0", "front", {"caricature": 0.0}), ("--caricature 100", "front", {"caricature": 100.0}),
)


def blend_sheet(face) -> Image.Image:
    """docs/blend_library.png: :data:`BLEND_TILES` on dark tiles with yellow labels (posed as
    ``mimica render`` poses them: rig layers on demand, then the values; one rig for all tiles)."""
    from app.render import render_face_image
    from core.rig import FaceRig

    rig = FaceRig(face)

    tile, columns = 300, 4
    lines = (len(BLEND_TILES) + columns - 1) // columns
    out = Image.new("RGB", (tile * columns, tile * lines), (40, 42, 48))
    draw = ImageDraw.Draw(out)
    font = ImageFont.load_default(size=16)
    for k, (label, view, values) in enumerate(BLEND_TILES):
        rig.reset()
        rig.ensure_layers(values)
        rig.set_values(values)
        posed = face.with_vertices(rig.vertices())
        image = Image.fromarray(render_face_image(posed, view=view, size=(2 * tile, 2 * tile))).resize((tile, tile))
        x, y = (k % columns) * tile, (k // columns) * tile
        out.paste(image, (x, y))
        draw.text((x + 6, y + 6), label, fill=(255, 255, 0), font=font)
    return out


def head_sheet(face, tile: int = 420) -> Image.Image:
    """docs/default_head.png: ``face`` at rest from every camera preset, side by side, framed whole
    (the neck and the shoulders' start too, which the portrait framing of exports leaves out)."""
    from app.render import render_face_image
    from app.scene import VIEWS

    images = [render_face_image(face, view=view, size=(2 * tile, 2 * tile), frame_points=face.vertices)
              for view in VIEWS]
    return sheet([(" · ".join(VIEWS), images)], columns=1, tile=tile)


def main(argv=None) -> None:
    from core.default_face import load_default_face
    from core.layers.muscles import preset, preset_names
    from core.rig import FaceRig

    sheets = ("head", "fap", "muscles", "blend")
    which = set(sys.argv[1:] if argv is None else argv) or set(sheets)
    unknown = which - set(sheets)
    if unknown:
        raise SystemExit(f"unknown sheet(s) {', '.join(sorted(unknown))}; choose from {', '.join(sheets)}")
    face = load_default_face()
    if "head" in which:
        out = ROOT / "docs" / "default_head.png"
        head_sheet(face).save(out)
        print(f"wrote {out}")
    if "blend" in which:
        out = ROOT / "docs" / "blend_library.png"
        blend_sheet(face).save(out)
        print(f"wrote {out}")
    if not which & {"fap", "muscles"}:
        return
    rig = FaceRig(face)
    expressions = [("neutral", lambda r: None)] + [
        (name, lambda r, n=name: r.set_expression(n, 1.0))
        for name in ("joy", "surprise", "anger", "sadness", "fear", "disgust")]
    expressions += [("open jaw (FAP 3 = 600)", lambda r: r.set_fap(3, 600)),
                    ("blink (FAPs 19/20 = 1024)", lambda r: r.set_faps({19: 1024, 20: 1024}))]
    if "fap" in which:
        out = ROOT / "docs" / "fap_expressions.png"
        sheet(poses_of(rig, expressions)).save(out)
        print(f"wrote {out}")
    if "muscles" not in which:
        return

    rig.ensure_layers(["muscle:risorius:left"])
    layer = rig.layer("muscles")
    muscles = []
    for name in preset_names():
        def apply(r, p=preset(name)):
            layer.apply(p)
            layer.solve()
            r.touch()
        muscles.append((preset(name).name, apply))
    out = ROOT / "docs" / "muscle_presets.png"
    sheet(poses_of(rig, muscles)).save(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
