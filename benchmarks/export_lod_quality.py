"""Does the export's level of detail give the same frames as the full face? PSNR and SSIM, measured.

Renders frames of the export benchmark's animation (``bench_export.py``: the default face, the
46-FAP timeline of ``bench_timeline.py``, 1280x720, front view, textured) through the export's own
renderer (:class:`app.export._FaceRenderer`), once with the full face and once per decimation budget
(``--targets``), and compares each decimated frame with the full one over the face's region (the
bounding box of the pixels either frame draws differently from the empty background, plus 8 px:
the untouched background would only inflate both measures):

- PSNR (dB) of the RGB pixels, peak 255;
- SSIM of the luminance (Rec. 601), Wang et al. 2004: Gaussian window sigma 1.5, K1 0.01, K2 0.03.

Prints per budget::

    lod_triangles=<t> psnr_db median=<x> min=<x> ssim median=<x> min=<x> render_ms full=<x> lod=<x>

then, for the budget :data:`app.export_lod.EXPORT_LOD_TRIANGLES` (the export's default)::

    export_lod_psnr_db median=<x> min=<x>
    export_lod_ssim median=<x> min=<x>

and whether it passes the threshold (SSIM >= 0.98 and PSNR >= 38 dB, both at the worst frame).

Usage: python benchmarks/export_lod_quality.py [--frames 24] [--targets 24000 36000 48000] [--size 1280x720]
       [--ignore-pixel-rule]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_timeline import build_timeline  # noqa: E402

from core.default_face import load_default_face  # noqa: E402
from core.rig import FaceRig  # noqa: E402
from core.timeline import apply_to_rig  # noqa: E402

MIN_SSIM, MIN_PSNR_DB = 0.98, 38.0


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio (dB, peak 255) of two uint8 images; inf when identical."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0 ** 2 / mse)


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM of the luminance of two (h, w, 3) uint8 images (Gaussian window, sigma 1.5)."""
    weights = np.array([0.299, 0.587, 0.114])
    x, y = a.astype(np.float64) @ weights, b.astype(np.float64) @ weights
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(image: np.ndarray) -> np.ndarray:
        return gaussian_filter(image, 1.5, truncate=3.5)

    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return float(s.mean())


def face_region(background: np.ndarray, *frames: np.ndarray, margin: int = 8) -> tuple[slice, slice]:
    """Rows and columns of the pixels any of ``frames`` draws differently from ``background``."""
    drawn = np.zeros(background.shape[:2], bool)
    for frame in frames:
        drawn |= (frame != background).any(axis=2)
    rows, cols = np.flatnonzero(drawn.any(axis=1)), np.flatnonzero(drawn.any(axis=0))
    if not len(rows):
        return slice(None), slice(None)
    h, w = drawn.shape
    return (slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h)),
            slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, w)))


def main() -> None:
    from app.export import ExportSettings, _FaceRenderer
    from app.export_lod import EXPORT_LOD_TRIANGLES, LOD_MAX_PIXELS_PER_TRIANGLE

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24, help="frames compared, spread over the 10 s animation")
    parser.add_argument("--targets", type=int, nargs="+", default=[24_000, 36_000, 48_000, 60_000])
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--ignore-pixel-rule", action="store_true",
                        help="use the level of detail whatever the triangles' size on screen (to see where it fails)")
    args = parser.parse_args()
    if args.ignore_pixel_rule:
        import app.export_lod

        app.export_lod.LOD_MAX_PIXELS_PER_TRIANGLE = float("inf")
    size = tuple(int(v) for v in args.size.lower().split("x"))
    targets = sorted(set(args.targets) | {EXPORT_LOD_TRIANGLES})
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}")

    face = load_default_face()
    rig = FaceRig(face)
    timeline = build_timeline(np.random.default_rng(0))
    poses = []
    for t in np.linspace(0.0, 10.0, args.frames, endpoint=False):
        apply_to_rig(rig, timeline.evaluate(float(t)))
        poses.append(np.array(rig.vertices()))

    with tempfile.TemporaryDirectory() as tmp:
        settings = ExportSettings(path=Path(tmp) / "x.mp4", end_s=10.0, size=size)
        full = _FaceRenderer(face, dataclasses.replace(settings, full_detail=True), size)
        background = full._background if full._background is not None else None
        full_frames, full_ms = [], []
        for v in poses:
            t0 = time.perf_counter()
            full_frames.append(full.render(v))
            full_ms.append((time.perf_counter() - t0) * 1e3)
        if background is None:          # no strip: the empty frame drawn once, for the face's region
            full.actor.actor.SetVisibility(False)
            full.plotter.render()
            background = full._read(size[0])
        print(f"full face: {face.triangles.shape[0]} triangles, median {full.pixels_per_triangle(face):.2f} px "
              f"each on screen (the export uses its level of detail up to {LOD_MAX_PIXELS_PER_TRIANGLE} px), "
              f"{size[0]}x{size[1]}, {len(poses)} frames")
        full.close()
        results = {}
        for target in targets:
            renderer = _FaceRenderer(face, settings, size, lod_triangles=target)
            if not renderer.lod_triangles:
                print(f"lod_triangles={target}: not used (the face's triangles are too large on screen here)")
                renderer.close()
                continue
            psnrs, ssims, ms = [], [], []
            for v, reference in zip(poses, full_frames):
                t0 = time.perf_counter()
                frame = renderer.render(v)
                ms.append((time.perf_counter() - t0) * 1e3)
                rows, cols = face_region(background, reference, frame)
                psnrs.append(psnr_db(frame[rows, cols], reference[rows, cols]))
                ssims.append(ssim(frame[rows, cols], reference[rows, cols]))
            renderer.close()
            results[target] = (np.array(psnrs), np.array(ssims))
            print(f"lod_triangles={renderer.lod_triangles} (budget {target}) psnr_db median={np.median(psnrs):.2f} "
                  f"min={np.min(psnrs):.2f} ssim median={np.median(ssims):.4f} min={np.min(ssims):.4f} "
                  f"render_ms full={np.median(full_ms):.0f} lod={np.median(ms):.0f}", flush=True)
    if EXPORT_LOD_TRIANGLES in results:
        psnrs, ssims = results[EXPORT_LOD_TRIANGLES]
        print(f"export_lod_psnr_db median={np.median(psnrs):.2f} min={np.min(psnrs):.2f}")
        print(f"export_lod_ssim median={np.median(ssims):.4f} min={np.min(ssims):.4f}")
        passes = psnrs.min() >= MIN_PSNR_DB and ssims.min() >= MIN_SSIM
        print(f"export default ({EXPORT_LOD_TRIANGLES} triangle budget): "
              f"{'passes' if passes else 'FAILS'} SSIM >= {MIN_SSIM} and PSNR >= {MIN_PSNR_DB} dB at the worst frame")
    print(f"load after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
