"""mesh_io.py
----
Load and save :class:`~core.face.Face` meshes: OBJ (+MTL +texture), PLY,
STL, glTF/GLB.

Loading always returns a clean face in millimetres or raises
:class:`MeshLoadError` with a message meant for the user (the GUI shows it
verbatim); a partially built face is never returned. Problems that can be
repaired (polygons, duplicate or degenerate faces, unused vertices, missing
texture, unit conversion...) are repaired and described, one sentence each,
in ``face.metadata.notes``.

Vertex order
    OBJ is parsed by :mod:`core.formats.mesh_formats` (not by trimesh) so that vertex order is kept exactly.
    A vertex that the file uses with several texture coordinates (a uv seam)
    is duplicated: the first (vertex, uv) pair met in the file keeps the
    original index, the others are appended after the last vertex. Files
    written by :func:`save_face` have one uv per vertex, so they reload with
    the same vertices in the same order.
    PLY, STL and glTF are parsed by trimesh with ``process=False`` (no merging,
    no reordering). STL has no shared vertices, so coincident corners are
    welded, keeping first-appearance order. A PLY with per-corner texture
    coordinates (MeshLab's ``texcoord`` face list) is split at seams by
    trimesh, which may reorder vertices.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import scipy.sparse

from core.face import Face, FaceMetadata
from core.formats.atomic_files import write_atomic, write_reporting_errors, write_set_atomic  # noqa: F401
from core.formats.mesh_formats import (PLY_MIMICA_COMMENT, PLY_NAME_COMMENT, PlyLengthError, PLY_PART_COMMENT, PLY_PART_PROPERTY,
                                      READERS, RawMesh, _image_to_rgb, plural, ply_face_name, reason, weld)
from core.formats.text_files import check_file

__all__ = ["MeshLoadError", "MeshSaveError", "load_face", "load_texture_image", "save_face", "LOAD_FORMATS",
           "SAVE_FORMATS"]

#: Extensions :func:`load_face` understands, with a human name for messages.
LOAD_FORMATS = {".obj": "OBJ", ".ply": "PLY", ".stl": "STL", ".gltf": "glTF", ".glb": "GLB"}
#: Extensions :func:`save_face` writes.
SAVE_FORMATS = {".obj": "OBJ", ".ply": "PLY", ".glb": "GLB"}

# Unit detection from the bounding-box diagonal of the loaded mesh. A human
# face or head scan is roughly 150-400 mm across, i.e. 0.15-0.4 in metres and
# 15-40 in centimetres. The thresholds sit far from all three ranges: nothing
# face-sized in mm or cm has a diagonal under 1.5, and nothing in metres or mm
# lands between 1.5 and 60.
METRES_MAX_DIAGONAL = 1.5
CENTIMETRES_MAX_DIAGONAL = 60.0

# A triangle is degenerate when twice its area is below this fraction of the
# squared bounding-box diagonal: far above floating-point noise for collinear
# corners, far below any real triangle (1e-12 * (300 mm)^2 ~ a 0.0003 mm side).
DEGENERATE_AREA_RATIO = 1e-12

DECIMATE_HINT = (
    "decimate it first, e.g. in MeshLab: Filters > Remeshing > Quadric Edge Collapse Decimation, "
    "or Blender's Decimate modifier"
)

_A_FORMAT = {"OBJ": "an OBJ", "PLY": "a PLY", "STL": "an STL", "glTF": "a glTF", "GLB": "a GLB"}

ProgressCallback = Callable[[float, str], None]


class MeshLoadError(Exception):
    """A mesh file could not be loaded; ``str(error)`` is a user-facing message."""


class MeshSaveError(Exception):
    """A face could not be saved; ``str(error)`` is a user-facing message."""


# =====================================================================  load
def load_texture_image(path) -> np.ndarray:
    """(H, W, 3) uint8 of the image at ``path`` (any mode: alpha dropped, grey expanded, 16-bit
    scaled), for a texture that comes as a separate file. MeshLoadError with a user-facing message."""
    import PIL.Image

    path = Path(path)
    check_file(path, "image", MeshLoadError, what="an image")  # never open a pipe or a device: it would block
    try:
        with PIL.Image.open(path) as image:
            return _image_to_rgb(image)
    except Exception as exc:  # noqa: BLE001 - PIL raises many kinds; the user needs one sentence
        raise MeshLoadError(f"'{path.name}' is not an image Mimica can read ({reason(exc)})") from None


def load_face(path, *, progress: ProgressCallback | None = None, max_triangles: int = 5_000_000,
              keep_topology: Callable[[int, np.ndarray], str | None] | None = None) -> Face:
    """Load a face mesh, repair what can be repaired and convert it to millimetres.

    Parameters
    ----------
    path : str or os.PathLike
        ``.obj`` (with its ``.mtl`` and ``map_Kd`` texture, resolved relative
        to the MTL file), ``.ply`` (vertex colours, ``texture_u/v`` or
        ``s/t`` uv, ``comment TextureFile``), ``.stl``, ``.gltf`` or ``.glb``
        (embedded textures, vertex colours; all meshes of the scene with their
        node transforms, concatenated).
    progress : callable(fraction: float, message: str), optional
        Called at each stage with a fraction in [0, 1]; exceptions it raises
        propagate unchanged (the GUI may use that to cancel).
    max_triangles : int
        Larger meshes are refused with a hint on how to decimate them.
    keep_topology : callable(n_vertices, triangles) -> name or None, optional
        Says whether the mesh is a known topology whose triangles must stay as they are (a canonical
        face: ``core.registration.correspondence.canonical_template_of``); its zero-area triangles
        are then kept, with a note, instead of removed.

    Returns
    -------
    Face
        Vertices in mm, ``metadata.units == "mm"``, ``metadata.source`` the
        path, ``metadata.name`` the file stem (or the name a PLY Mimica wrote keeps), ``metadata.notes`` one sentence
        per conversion or repair.

    Raises
    ------
    MeshLoadError
        Missing, unreadable, unknown or unparsable file, no faces, non-finite
        coordinates, or more than ``max_triangles`` triangles.
    """
    report = progress if progress is not None else (lambda fraction, message: None)
    path = Path(path)
    fmt = _check_readable(path)
    report(0.0, f"Reading {path.name}")
    try:
        mesh = READERS[fmt](path)
    except MeshLoadError:
        raise
    except PlyLengthError as exc:
        raise MeshLoadError(str(exc)) from None
    except Exception as exc:  # the parsers raise anything from KeyError to struct.error
        raise MeshLoadError(
            f"Could not read '{path.name}' as {_A_FORMAT[fmt]} file: {reason(exc)}. The file may be damaged or "
            f"not really {fmt}; try exporting it again from the program that made it."
        ) from exc
    report(0.7, "Checking and repairing the mesh")
    mesh = _repair(mesh, path.name, max_triangles, keep_topology)
    report(0.9, "Converting units")
    vertices, units_note = _to_millimetres(mesh.vertices)
    if units_note:
        mesh.notes.append(units_note)
    face = Face(
        vertices,
        mesh.triangles,
        uv=mesh.uv,
        texture=mesh.texture,
        vertex_colors=mesh.vertex_colors,
        metadata=FaceMetadata(source=str(path), units="mm", notes=mesh.notes,
                              name=(ply_face_name(path) if fmt == "PLY" else None) or path.stem),
        parts=mesh.parts,
    )
    report(1.0, f"Loaded {path.name}")
    return face


def _check_readable(path: Path) -> str:
    """Raise MeshLoadError unless ``path`` is an existing readable file of a known format."""
    if not path.exists():
        raise MeshLoadError(
            f"The file '{path}' does not exist. Check that the path is right and that the file "
            "has not been moved or deleted."
        )
    if path.is_dir():
        raise MeshLoadError(f"'{path}' is a folder, not a mesh file. Choose a mesh file inside it.")
    check_file(path, "mesh", MeshLoadError, what="a mesh file")  # regular file, size cap: before open()
    fmt = LOAD_FORMATS.get(path.suffix.lower())
    if fmt is None:
        supported = ", ".join(LOAD_FORMATS)
        raise MeshLoadError(
            f"'{path.name}' has an unsupported file type ('{path.suffix or 'no extension'}'). "
            f"Mimica can load {supported}; convert the mesh to one of these, e.g. with MeshLab or Blender."
        )
    try:
        with open(path, "rb") as fh:
            empty = not fh.read(1)
    except PermissionError:
        raise MeshLoadError(
            f"Mimica is not allowed to read '{path}'. Check the file's permissions, "
            "or copy it to a folder you own."
        ) from None
    except OSError as exc:
        raise MeshLoadError(f"'{path}' could not be opened: {exc.strerror or exc}.") from None
    if empty:
        raise MeshLoadError(f"'{path.name}' is empty (0 bytes). The export that made it probably failed; export it again.")
    return fmt


# ------------------------------------------------------------- repairs
def _repair(mesh: RawMesh, name: str, max_triangles: int,
            keep_topology: Callable[[int, np.ndarray], str | None] | None = None) -> RawMesh:
    """Validate and clean raw arrays; raise MeshLoadError or append one note per repair."""
    v, tri = mesh.vertices, mesh.triangles
    if len(tri) == 0 and len(v) == 0:
        raise MeshLoadError(
            f"'{name}' holds no vertices or faces Mimica can read: it is probably not a mesh of the kind its "
            "extension says (another kind of file renamed, or an export that failed). Open the file the mesh "
            "was exported as, or export it again."
        )
    if len(tri) == 0:
        raise MeshLoadError(
            f"'{name}' contains no faces ({len(v)} points only): it is a point cloud, not a surface. "
            "Mimica needs a triangle mesh; reconstruct a surface first, e.g. in MeshLab: "
            "Filters > Remeshing > Screened Poisson Surface Reconstruction."
        )
    if len(tri) > max_triangles:
        raise MeshLoadError(
            f"'{name}' has {len(tri):,} triangles, more than the {max_triangles:,} Mimica accepts. "
            f"Please {DECIMATE_HINT}."
        )
    if tri.min() < 0 or tri.max() >= len(v):
        bad = int(tri.min()) if tri.min() < 0 else int(tri.max())
        raise MeshLoadError(
            f"'{name}' is damaged: a face refers to vertex {bad} but there are only {len(v)} vertices. "
            "Export it again."
        )
    used = np.zeros(len(v), dtype=bool)
    used[tri] = True
    n_bad = int((~np.isfinite(v).all(axis=1) & used).sum())
    if n_bad:
        raise MeshLoadError(
            f"'{name}' has {plural(n_bad, 'vertex', 'vertices')} with invalid coordinates (NaN or infinity). "
            "Repair the mesh (e.g. MeshLab: Filters > Cleaning and Repairing) or export it again."
        )
    notes = mesh.notes
    if mesh.exact:   # Mimica's own copy of a face it held: landmarks and rigs index it as it is
        return mesh
    canonical = keep_topology(len(v), tri) if keep_topology is not None else None
    repeated = (tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2]) | (tri[:, 2] == tri[:, 0])
    corners = v[tri]
    twice_area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    diagonal = np.linalg.norm(np.ptp(v[used], axis=0))
    flat = ~repeated & (twice_area <= DEGENERATE_AREA_RATIO * diagonal**2)
    counts = ((mesh.n_short, "with fewer than 3 corners"), (int(repeated.sum()), "with a repeated vertex"),
              (int(flat.sum()), "with zero area"))
    parts = [f"{n} {what}" for n, what in counts if n]
    if canonical is not None:
        # Its vertex order and triangles are what makes it animatable: never alter them.
        if parts:
            notes.append(f"Kept {', '.join(parts).replace('with ', 'triangles with ')}: this is a canonical face of "
                         f"template {canonical}, whose triangles must stay as they are (its surface folds there; "
                         "correct the landmarks nearby and register again to smooth it).")
        repeated = flat = np.zeros(len(tri), dtype=bool)
        parts = []
    if parts:
        notes.append(f"Removed degenerate faces: {', '.join(parts)}.")
    keep = ~(repeated | flat)
    _, first = np.unique(np.sort(tri, axis=1), axis=0, return_index=True)
    unique = np.zeros(len(tri), dtype=bool)
    unique[first] = True
    n_duplicates = int((keep & ~unique).sum())
    if n_duplicates:
        notes.append(f"Removed {plural(n_duplicates, 'duplicate face')} (the same three vertices listed again).")
    tri = tri[keep & unique]
    if len(tri) == 0 and len(v) == 0:
        raise MeshLoadError(
            f"'{name}' holds no vertices or faces Mimica can read: it is probably not a mesh of the kind its "
            "extension says (another kind of file renamed, or an export that failed). Open the file the mesh "
            "was exported as, or export it again."
        )
    if len(tri) == 0:
        raise MeshLoadError(
            f"'{name}' has no usable faces: all {len(keep)} are degenerate (zero area or a repeated vertex). "
            "Export it again."
        )
    used = np.zeros(len(v), dtype=bool)
    used[tri] = True
    n_unused = int((~used).sum())
    if n_unused:
        notes.append(f"Removed {plural(n_unused, 'vertex', 'vertices')} that no face uses.")
        new_index = np.cumsum(used) - 1
        tri = new_index[tri]
        v = v[used]
        mesh.uv = None if mesh.uv is None else mesh.uv[used]
        mesh.vertex_colors = None if mesh.vertex_colors is None else mesh.vertex_colors[used]
        mesh.parts = {name: new_index[idx[used[idx]]] for name, idx in mesh.parts.items() if used[idx].any()}
    if mesh.uv is not None and not np.isfinite(mesh.uv).all():
        notes.append("The texture coordinates contain invalid numbers, so the texture was not used.")
        mesh.uv = mesh.texture = None
    if mesh.texture is not None and mesh.uv is None:
        notes.append("The texture was ignored because the mesh has no texture coordinates.")
        mesh.texture = None
    _, welded = weld(v)  # count parts by position, so that uv seams do not split them
    n_parts = _count_components(welded[tri], int(welded.max()) + 1)
    if n_parts > 1 and not mesh.parts:   # named parts (eyeballs, teeth) are separate by design
        notes.append(
            f"The mesh has {n_parts} separate parts (connected components); all were kept. Loose parts can be "
            "removed in MeshLab: Filters > Cleaning and Repairing > Remove Isolated pieces."
        )
    mesh.vertices, mesh.triangles = v, tri
    return mesh


def _count_components(triangles: np.ndarray, n_vertices: int) -> int:
    """Connected components of the vertices used by ``triangles`` (m, 3)."""
    rows = triangles[:, [0, 1, 2]].ravel()
    cols = triangles[:, [1, 2, 0]].ravel()
    graph = scipy.sparse.coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    from scipy.sparse.csgraph import connected_components   # here: the window imports this module at start-up

    _, labels = connected_components(graph, directed=False)
    return len(np.unique(labels[triangles.ravel()]))


def _to_millimetres(vertices: np.ndarray) -> tuple[np.ndarray, str | None]:
    """Vertices (n, 3) scaled to mm from the unit guessed by the bounding-box diagonal, and a note."""
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    if diagonal < METRES_MAX_DIAGONAL:
        return vertices * 1000.0, f"Scaled from metres to millimetres (bounding box {diagonal:.3g} m)."
    if diagonal < CENTIMETRES_MAX_DIAGONAL:
        return vertices * 10.0, f"Scaled from centimetres to millimetres (bounding box {diagonal:.3g} cm)."
    return vertices, None


# =====================================================================  save
def save_face(face: Face, path) -> None:
    """Write ``face`` to ``path``, the format chosen by the extension.

    ``.obj``
        OBJ with ``vt`` lines when the face has uv, vertex colours as
        ``v x y z r g b`` when it has them, and, when it has a texture and uv,
        ``<stem>.mtl`` and ``<stem>.png`` next to it (overwritten).
    ``.ply``
        Binary little-endian PLY, coordinates as doubles in mm, uv as
        ``texture_u/texture_v``. Vertex colours are written when present; a
        face with a texture but no vertex colours gets colours *baked* by
        sampling the texture at each vertex's uv (bilinear), so that viewers
        without texture support still show it. With a texture, ``<stem>.png``
        is written too and named by ``comment TextureFile``, so that Mimica
        and MeshLab reload the texture.
    ``.glb``
        Binary glTF with the texture embedded as PNG (else vertex colours).
        Coordinates are written in metres, as the glTF specification requires;
        :func:`load_face` scales them back to mm.

    Every file is written to a temporary file first and moved into place, so
    an existing file is never left half-written. Vertex order, triangles, uv
    and texture pixels survive a round trip through :func:`load_face`.

    Raises
    ------
    MeshSaveError
        Unknown extension, missing or unwritable folder, disk errors.
    """
    path = Path(path)
    fmt = SAVE_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise MeshSaveError(
            f"Cannot save as '{path.suffix or path.name}': Mimica saves faces as {', '.join(SAVE_FORMATS)}. "
            "Choose one of these extensions."
        )
    write_reporting_errors(path, lambda: _WRITERS[fmt](face, path), MeshSaveError)


def _rows(fmt: str, array: np.ndarray) -> str:
    """Format every row of a 2-D array with ``fmt`` (which ends in a newline) in one C-level call."""
    return (fmt * len(array)) % tuple(array.ravel().tolist())


def _png_bytes(texture: np.ndarray) -> bytes:
    import PIL.Image

    buffer = io.BytesIO()
    PIL.Image.fromarray(np.ascontiguousarray(texture)).save(buffer, format="PNG")
    return buffer.getvalue()


def _write_obj(face: Face, path: Path) -> None:
    textured = face.texture is not None and face.uv is not None
    header = "# Written by Mimica; units: millimetres\n"
    companions: dict[Path, bytes] = {}
    if textured:
        mtl = f"# Written by Mimica\nnewmtl face\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {path.stem}.png\n"
        companions = {path.with_suffix(".png"): _png_bytes(face.texture), path.with_suffix(".mtl"): mtl.encode()}
        header += f"mtllib {path.stem}.mtl\nusemtl face\n"
    if face.vertex_colors is not None:
        rows = np.hstack([face.vertices, face.vertex_colors / 255.0])
        body = [_rows("v %.10g %.10g %.10g %.6g %.6g %.6g\n", rows)]
    else:
        body = [_rows("v %.10g %.10g %.10g\n", face.vertices)]
    corners = face.triangles + 1
    if face.uv is not None:
        body.append(_rows("vt %.10g %.10g\n", face.uv))
        body.append(_rows("f %d/%d %d/%d %d/%d\n", np.repeat(corners, 2, axis=1)))
    else:
        body.append(_rows("f %d %d %d\n", corners))
    write_set_atomic({path: (header + "".join(body)).encode(), **companions})


def _write_ply(face: Face, path: Path) -> None:
    colors = face.vertex_colors
    if colors is None and face.texture is not None and face.uv is not None:
        colors = _sample_texture(face.texture, face.uv)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if face.uv is not None:
        fields += [("texture_u", "<f8"), ("texture_v", "<f8")]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    part_names = sorted(face.parts)[:65535]
    if part_names:
        fields += [(PLY_PART_PROPERTY, "<u2")]
    vertex = np.empty(face.n_vertices, dtype=fields)
    for axis, name in enumerate("xyz"):
        vertex[name] = face.vertices[:, axis]
    if face.uv is not None:
        vertex["texture_u"], vertex["texture_v"] = face.uv[:, 0], face.uv[:, 1]
    if colors is not None:
        vertex["red"], vertex["green"], vertex["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    if part_names:
        vertex[PLY_PART_PROPERTY] = 0       # skin; a vertex in several parts keeps the last one named
        for k, name in enumerate(part_names, start=1):
            vertex[PLY_PART_PROPERTY][np.asarray(face.parts[name], np.int64)] = k
    tri = np.empty(face.n_triangles, dtype=[("n", "u1"), ("i", "<i4", (3,))])
    tri["n"], tri["i"] = 3, face.triangles
    ply_type = {"<f8": "double", "u1": "uchar", "<u2": "ushort"}
    header = ["ply", "format binary_little_endian 1.0", f"{PLY_MIMICA_COMMENT}; units: millimetres"]
    header += [f"comment {PLY_PART_COMMENT} {k} {name}" for k, name in enumerate(part_names, start=1)]
    if face.metadata.name:
        header.append(f"comment {PLY_NAME_COMMENT} {json.dumps(face.metadata.name)}")
    companions: dict[Path, bytes] = {}
    if face.texture is not None and face.uv is not None:
        companions[path.with_suffix(".png")] = _png_bytes(face.texture)
        header.append(f"comment TextureFile {path.stem}.png")
    header.append(f"element vertex {face.n_vertices}")
    header += [f"property {ply_type[t]} {n}" for n, t in fields]
    header += [f"element face {face.n_triangles}", "property list uchar int vertex_indices", "end_header"]
    write_set_atomic({path: ("\n".join(header) + "\n").encode("ascii") + vertex.tobytes() + tri.tobytes(),
                      **companions})


def _sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(n, 3) uint8 bilinear samples of ``texture`` (H, W, 3) at ``uv`` (n, 2), v = 0 at the bottom."""
    height, width = texture.shape[:2]
    x = np.clip(uv[:, 0], 0.0, 1.0) * (width - 1)
    y = (1.0 - np.clip(uv[:, 1], 0.0, 1.0)) * (height - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, width - 1), np.minimum(y0 + 1, height - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    img = texture.astype(np.float64)
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return np.clip(np.rint(top * (1 - fy) + bottom * fy), 0, 255).astype(np.uint8)


def _write_glb(face: Face, path: Path) -> None:
    import PIL.Image
    import trimesh

    if face.texture is not None and face.uv is not None:
        visual = trimesh.visual.TextureVisuals(uv=face.uv, image=PIL.Image.fromarray(np.ascontiguousarray(face.texture)))
    elif face.vertex_colors is not None:
        visual = trimesh.visual.ColorVisuals(vertex_colors=face.vertex_colors)
    else:
        visual = None
    mesh = trimesh.Trimesh(face.vertices / 1000.0, face.triangles, visual=visual, process=False, validate=False)
    write_atomic(path, mesh.export(file_type="glb"))


_WRITERS = {"OBJ": _write_obj, "PLY": _write_ply, "GLB": _write_glb}
