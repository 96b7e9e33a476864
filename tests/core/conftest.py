"""Small synthetic faces built in code for the core tests (no files from outside the repo)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from core.face import Face, FaceMetadata, SurfacePoint


def make_grid_face(nx: int = 6, ny: int = 5, size_mm: float = 200.0, seed: int = 0) -> Face:
    """A bumpy height-field patch about ``size_mm`` across, with uv, texture and vertex colours.

    Vertices (nx * ny, 3) in mm on a regular x/y grid; uv = normalised x/y so
    that every vertex has exactly one uv; texture (7, 9, 3) random pixels;
    three landmarks.
    """
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0.0, 1.0, nx), np.linspace(0.0, 1.0, ny))
    uv = np.column_stack([x.ravel(), y.ravel()])
    z = 0.1 * np.sin(3 * uv[:, 0]) * np.cos(2 * uv[:, 1]) + 0.01 * rng.random(len(uv))
    vertices = np.column_stack([uv - 0.5, z]) * size_mm
    index = np.arange(nx * ny).reshape(ny, nx)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, 1:].ravel(), index[1:, :-1].ravel()
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    texture = rng.integers(0, 256, size=(7, 9, 3), dtype=np.uint8)
    colors = rng.integers(0, 256, size=(len(vertices), 3), dtype=np.uint8)
    landmarks = {
        "2.1": SurfacePoint(0, (0.2, 0.3, 0.5)),
        "8.3": SurfacePoint(len(triangles) - 1, (1.0, 0.0, 0.0)),
        "9.3": SurfacePoint(7, (1 / 3, 1 / 3, 1 / 3)),
    }
    return Face(vertices, triangles, uv=uv, texture=texture, vertex_colors=colors,
                landmarks=landmarks, metadata=FaceMetadata(name="grid"))


@pytest.fixture
def grid_face() -> Face:
    return make_grid_face()


@pytest.fixture(scope="session")
def default_rig():
    """A FaceRig on the built-in face (about 5 s to build; shared: reset what you change)."""
    from core.default_face import load_default_face
    from core.rig import FaceRig

    return FaceRig(load_default_face())


def without_surface_guard(monkeypatch, rig) -> None:
    """Leave the FAP layer's surface guard out of ``rig`` for one test (its smoothing is not
    additive: for checks of how offsets sum, or of what a limit does alone)."""
    monkeypatch.setattr(rig.deformer._surface_guard, "apply", lambda x, pinned=None, region=None: False)


@pytest.fixture(scope="session")
def generated_rig():
    """A FaceRig on the generated identity of ``benchmarks/face_quality.py`` (Mimica's generator,
    seed 7: other proportions than the built-in face; about 35 s to build; reset what you change)."""
    from core.default_face import generate_face
    from core.default_face.params import FaceParameters
    from core.rig import FaceRig

    return FaceRig(generate_face(FaceParameters.random(np.random.default_rng(7), spread=0.8)))


def run_fresh_python(code: str, env: dict | None = None, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter from the repository root (what this process imported or
    loaded, e.g. numba, does not leak into it); ``env`` replaces the environment."""
    root = Path(__file__).resolve().parents[2]
    return subprocess.run([sys.executable, "-c", code], cwd=root, env=env if env is not None else dict(os.environ),
                          capture_output=True, text=True, timeout=timeout)

