"""store.py
----
The committed copy of the default face: one compressed NPZ under
``resources/default_face/``. The front of the face, exactly as the
single-view-scan-like generator makes it (``generate_face(full_head=False)``):
vertices, triangles, uv, texture, landmarks, and each named part as
``part_<name>``. The full head (``generate_face()``), whose front stops short of the steep rim a
scanner cannot see (so it has fewer vertices and triangles), as ``head_vertices``,
``head_triangles``, ``head_uv``, ``head_texture`` (wider: the head's atlas to the right),
``head_landmarks`` and ``head_part_<name>``.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from core.face import Face, FaceMetadata, SurfacePoint

_RESOURCE = "default_face/default_face.npz"


def default_face_path() -> Path:
    import resources

    return Path(resources.__file__).parent / _RESOURCE


def save_default_face(face: Face, path: Path | None = None, head: Face | None = None) -> Path:
    """Write the front-of-face ``face`` (and its full ``head``) as the NPZ the app loads."""
    path = Path(path) if path is not None else default_face_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays = _arrays(face)
    if head is not None:
        arrays.update({f"head_{key}": value for key, value in _arrays(head).items()})
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    path.write_bytes(buf.getvalue())
    return path


def _arrays(face: Face) -> dict[str, np.ndarray]:
    landmarks = {n: {"triangle": p.triangle, "barycentric": list(p.barycentric)} for n, p in face.landmarks.items()}
    return {
        "vertices": face.vertices.astype(np.float32),
        "triangles": face.triangles.astype(np.int32),
        "uv": face.uv.astype(np.float32),
        "texture": face.texture,
        "landmarks": np.array(json.dumps({"order": list(face.landmarks), "points": landmarks})),
        **{f"part_{name}": idx.astype(np.int32) for name, idx in face.parts.items()},
    }


def load_default_face(full_head: bool = True) -> Face:
    """The built-in face (from the committed NPZ; generated if that file is missing).

    ``full_head=False``: only the front of the face, like a single-view range scan (what the
    synthetic scan database and the registration protocol use).
    """
    path = default_face_path()
    if not path.exists():
        from core.default_face.build import generate_face

        return generate_face(full_head=full_head)
    with np.load(path) as data:
        prefix = "head_" if full_head and "head_vertices" in data.files else ""
        meta = json.loads(str(data[prefix + "landmarks"]))
        landmarks = {n: SurfacePoint(meta["points"][n]["triangle"], tuple(meta["points"][n]["barycentric"]))
                     for n in meta["order"]}
        part = prefix + "part_"
        return Face(
            data[prefix + "vertices"].astype(np.float64), data[prefix + "triangles"],
            uv=data[prefix + "uv"].astype(np.float64), texture=data[prefix + "texture"], landmarks=landmarks,
            parts={key[len(part):]: data[key] for key in data.files if key.startswith(part)},
            metadata=FaceMetadata(source="built-in", units="mm", name="Mimica default face"),
        )
