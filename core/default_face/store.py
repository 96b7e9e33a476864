"""store.py
----
The committed copy of the default face: one compressed NPZ (vertices,
triangles, uv, texture, landmarks, and each named part as ``part_<name>``)
under ``resources/default_face/``.
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


def save_default_face(face: Face, path: Path | None = None) -> Path:
    """Write ``face`` as the NPZ the app loads at start-up."""
    path = Path(path) if path is not None else default_face_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(face.landmarks)
    landmarks = {n: {"triangle": p.triangle, "barycentric": list(p.barycentric)} for n, p in face.landmarks.items()}
    buf = io.BytesIO()
    np.savez_compressed(
        buf,
        vertices=face.vertices.astype(np.float32),
        triangles=face.triangles.astype(np.int32),
        uv=face.uv.astype(np.float32),
        texture=face.texture,
        landmarks=np.array(json.dumps({"order": names, "points": landmarks})),
        **{f"part_{name}": idx.astype(np.int32) for name, idx in face.parts.items()},
    )
    path.write_bytes(buf.getvalue())
    return path


def load_default_face() -> Face:
    """The built-in face (from the committed NPZ; generated if that file is missing)."""
    path = default_face_path()
    if not path.exists():
        from core.default_face.build import generate_face

        return generate_face()
    with np.load(path) as data:
        meta = json.loads(str(data["landmarks"]))
        landmarks = {n: SurfacePoint(meta["points"][n]["triangle"], tuple(meta["points"][n]["barycentric"]))
                     for n in meta["order"]}
        return Face(
            data["vertices"].astype(np.float64), data["triangles"], uv=data["uv"].astype(np.float64),
            texture=data["texture"], landmarks=landmarks,
            parts={key[len("part_"):]: data[key] for key in data.files if key.startswith("part_")},
            metadata=FaceMetadata(source="built-in", units="mm", name="Mimica default face"),
        )
