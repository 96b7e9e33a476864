"""store.py
----
The committed copy of the default face: one compressed NPZ under
``resources/default_face/``. The front of the face, exactly as the
single-view-scan-like generator makes it (``generate_face(full_head=False)``):
vertices, triangles, uv, texture, landmarks, and each named part as
``part_<name>``. The full head (``generate_face()``) as what it adds:
``head_vertices`` / ``head_triangles`` (appended), ``head_rim`` and
``head_rim_positions`` (the front's vertices the head moves: its outer rim, smoothed where the
shell joins, and the nostrils, opened into the nose),
``head_uv`` (all vertices' uv in ``head_texture``, which is wider) and
``head_part_<name>`` (the ears).
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
    """Write the front-of-face ``face`` (and its full ``head``, which must extend it: same first
    vertices but for the outer rim, same first triangles and landmarks) as the NPZ the app loads."""
    path = Path(path) if path is not None else default_face_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    names = list(face.landmarks)
    landmarks = {n: {"triangle": p.triangle, "barycentric": list(p.barycentric)} for n, p in face.landmarks.items()}
    arrays = {}
    if head is not None:
        n, m = face.n_vertices, face.n_triangles
        if not np.array_equal(head.triangles[:m], face.triangles) or head.landmarks != face.landmarks:
            raise ValueError("the full head does not extend the front of the face (triangles or landmarks differ)")
        rim = np.nonzero((head.vertices[:n] != face.vertices).any(axis=1))[0]
        arrays = {
            "head_vertices": head.vertices[n:].astype(np.float32),
            "head_triangles": head.triangles[m:].astype(np.int32),
            "head_rim": rim.astype(np.int32),
            "head_rim_positions": head.vertices[rim].astype(np.float32),
            "head_uv": head.uv.astype(np.float32),
            "head_texture": head.texture,
            **{f"head_part_{name}": idx.astype(np.int32) for name, idx in head.parts.items()
               if name not in face.parts},
        }
    buf = io.BytesIO()
    np.savez_compressed(
        buf,
        vertices=face.vertices.astype(np.float32),
        triangles=face.triangles.astype(np.int32),
        uv=face.uv.astype(np.float32),
        texture=face.texture,
        landmarks=np.array(json.dumps({"order": names, "points": landmarks})),
        **{f"part_{name}": idx.astype(np.int32) for name, idx in face.parts.items()},
        **arrays,
    )
    path.write_bytes(buf.getvalue())
    return path


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
        meta = json.loads(str(data["landmarks"]))
        landmarks = {n: SurfacePoint(meta["points"][n]["triangle"], tuple(meta["points"][n]["barycentric"]))
                     for n in meta["order"]}
        vertices = data["vertices"].astype(np.float64)
        triangles, uv, texture = data["triangles"], data["uv"].astype(np.float64), data["texture"]
        parts = {key[len("part_"):]: data[key] for key in data.files if key.startswith("part_")}
        if full_head and "head_vertices" in data.files:
            vertices[data["head_rim"]] = data["head_rim_positions"]
            vertices = np.concatenate([vertices, data["head_vertices"].astype(np.float64)])
            triangles = np.concatenate([triangles, data["head_triangles"]])
            uv, texture = data["head_uv"].astype(np.float64), data["head_texture"]
            parts.update({key[len("head_part_"):]: data[key] for key in data.files if key.startswith("head_part_")})
        return Face(
            vertices, triangles, uv=uv, texture=texture, landmarks=landmarks, parts=parts,
            metadata=FaceMetadata(source="built-in", units="mm", name="Mimica default face"),
        )
