"""app_helpers.py
----
Helpers for the GUI/render tests (a uniquely named module so it cannot clash
with other test folders' helpers):

* :func:`make_synthetic_face`: a small, fast, textured stand-in for a face:
  the front half of an ellipsoid with a nose bump, planar uv, a texture whose
  top is visibly different from its bottom, vertex colours and a few MPEG-4
  style landmarks;
* :func:`write_obj`: a plain OBJ writer independent of ``core.formats.mesh_io``;
* image statistics for "is this render blank / did it change".
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.face import Face, FaceMetadata


def _grid(n_u: int, n_v: int):
    """Vertices and triangles of a (n_v x n_u) lat-long grid over the front half-ellipsoid."""
    theta = np.linspace(-0.5 * np.pi * 0.95, 0.5 * np.pi * 0.95, n_u)  # left-right
    phi = np.linspace(-0.5 * np.pi * 0.9, 0.5 * np.pi * 0.9, n_v)  # bottom-top
    th, ph = np.meshgrid(theta, phi)
    a, b, c = 75.0, 105.0, 60.0  # mm half-axes: width, height, depth
    x = a * np.sin(th) * np.cos(ph)
    y = b * np.sin(ph)
    z = c * np.cos(th) * np.cos(ph)
    # Nose: a smooth bump in the middle of the face.
    z = z + 22.0 * np.exp(-((x / 12.0) ** 2 + ((y + 5.0) / 25.0) ** 2))
    verts = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    idx = np.arange(n_u * n_v).reshape(n_v, n_u)
    a0, a1 = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    b0, b1 = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    # Counter-clockwise seen from +z (outside).
    tris = np.concatenate([np.stack([a0, a1, b1], 1), np.stack([a0, b1, b0], 1)])
    return verts, tris


def make_texture(height: int = 128, width: int = 128) -> np.ndarray:
    """Skin-coloured checker; the top half is tinted red and the bottom half blue."""
    yy, xx = np.mgrid[0:height, 0:width]
    checker = ((yy // 16 + xx // 16) % 2).astype(np.float64)
    tex = np.empty((height, width, 3))
    tex[...] = np.array([224, 180, 150]) * (0.8 + 0.2 * checker[..., None])
    top = yy < height // 2
    tex[top] = tex[top] * np.array([1.0, 0.55, 0.55])
    tex[~top] = tex[~top] * np.array([0.55, 0.65, 1.0])
    return tex.astype(np.uint8)


def make_synthetic_face(n_u: int = 48, n_v: int = 64, *, texture: bool = True,
                        vertex_colors: bool = True, name: str = "synthetic") -> Face:
    """The synthetic face; ~3k vertices by default."""
    verts, tris = _grid(n_u, n_v)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    uv = (verts[:, :2] - lo[:2]) / (hi[:2] - lo[:2])  # planar projection, v=0 at the chin
    colors = None
    if vertex_colors:
        # Green on the face's left (+x), magenta on its right.
        t = uv[:, :1]
        colors = (np.array([60, 200, 80]) * t + np.array([200, 60, 200]) * (1 - t)).astype(np.uint8)
    face = Face(
        verts, tris,
        uv=uv if texture else None,
        texture=make_texture() if texture else None,
        vertex_colors=colors,
        metadata=FaceMetadata(source=None, units="mm", notes=[], name=name),
    )
    # Landmarks by nearest surface point to rough anatomical spots.
    spots = {
        "9.3": (0.0, -5.0, 90.0),  # nose tip
        "2.1": (0.0, -100.0, 20.0),  # chin
        "3.5": (28.0, 25.0, 50.0),  # left eye centre
        "3.6": (-28.0, 25.0, 50.0),  # right eye centre
        "8.3": (30.0, -55.0, 45.0),  # left mouth corner
        "8.4": (-30.0, -55.0, 45.0),  # right mouth corner
    }
    for label, xyz in spots.items():
        face.set_landmark(label, face.surface_point(xyz))
    return face


def landmark_names() -> list[str]:
    return ["9.3", "2.1", "3.5", "3.6", "8.3", "8.4"]


def write_obj(face, path: Path) -> Path:
    """A plain OBJ (v, vt, f v/vt) of ``face``, written without core.formats.mesh_io."""
    lines = ["# test face"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in face.vertices]
    has_uv = face.uv is not None
    if has_uv:
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in face.uv]
    t = np.asarray(face.triangles) + 1
    if has_uv:
        lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in t]
    else:
        lines += [f"f {a} {b} {c}" for a, b, c in t]
    path.write_text("\n".join(lines) + "\n")
    return path


def image_variance(image) -> float:
    """Pixel variance of an RGB image (near zero for a blank/flat render)."""
    return float(np.asarray(image, dtype=np.float64)[..., :3].var())


def image_difference(a, b) -> float:
    """Mean absolute per-pixel difference of two same-size RGB images (0..255)."""
    a = np.asarray(a, dtype=np.float64)[..., :3]
    b = np.asarray(b, dtype=np.float64)[..., :3]
    assert a.shape == b.shape, (a.shape, b.shape)
    return float(np.abs(a - b).mean())
