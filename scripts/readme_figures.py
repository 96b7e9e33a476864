"""Regenerate the README's contact sheets of the built-in face (off screen; no display needed):

    .venv/bin/python scripts/readme_figures.py

docs/fap_expressions.png: the six expression presets, a jaw opening and a blink, each from the
front and in three-quarter view; docs/muscle_presets.png: thesis C's muscle presets the same way.
Every image is rendered by the same code as ``mimica render`` (app.render).
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


def main() -> None:
    from core.default_face import load_default_face
    from core.layers.muscles import preset, preset_names
    from core.rig import FaceRig

    face = load_default_face()
    rig = FaceRig(face)
    expressions = [("neutral", lambda r: None)] + [
        (name, lambda r, n=name: r.set_expression(n, 1.0))
        for name in ("joy", "surprise", "anger", "sadness", "fear", "disgust")]
    expressions += [("open jaw (FAP 3 = 600)", lambda r: r.set_fap(3, 600)),
                    ("blink (FAPs 19/20 = 1024)", lambda r: r.set_faps({19: 1024, 20: 1024}))]
    out = ROOT / "docs" / "fap_expressions.png"
    sheet(poses_of(rig, expressions)).save(out)
    print(f"wrote {out}")

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
