"""mesh_formats.py
----
Format-specific readers behind :mod:`core.formats.mesh_io` (use that
module; nothing here is public API).

Readers return a :class:`RawMesh` (arrays exactly as the file has them, plus
notes about what was converted on the way) and raise any exception on a
malformed file; :func:`core.formats.mesh_io.load_face` turns those into
``MeshLoadError`` and does the format-independent repairs. (Writers are in
:mod:`core.formats.mesh_io`.)
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np


class RawMesh:
    """Arrays as read from a file, before repairs.

    Attributes
    ----------
    vertices : (n, 3) float, file units
    triangles : (m, 3) int, may contain degenerate or duplicate triangles
    uv : (n, 2) float or None, v = 0 at the image bottom
    texture : (H, W, 3) uint8 or None, row 0 at the top
    vertex_colors : (n, 3) uint8 or None
    notes : list of str, conversions already made by the reader
    n_short : int, faces with fewer than 3 corners (already dropped)
    parts : {name: (k,) vertex indices} named parts (eyeballs, teeth, a mouth cavity) a Mimica PLY keeps
    exact : bool, the file is Mimica's own copy of a face it held (its PLY): kept exactly as written
    """

    def __init__(self, vertices, triangles, uv=None, texture=None, vertex_colors=None, notes=(), n_short=0,
                 parts=None, exact=False):
        self.vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        self.uv = uv
        self.texture = texture
        self.vertex_colors = vertex_colors
        self.notes = list(notes)
        self.n_short = n_short
        self.parts = dict(parts or {})
        self.exact = exact


def reason(exc: BaseException) -> str:
    """An exception as a short phrase for messages (the type is added when the text says little)."""
    text = str(exc).strip().rstrip(".")
    return f"{type(exc).__name__} {text}" if len(text) < 12 else text


def plural(n: int, word: str, words: str | None = None) -> str:
    """``"1 vertex"``, ``"2 vertices"``: a count with the right form of the noun."""
    return f"{n} {word if n == 1 else (words or word + 's')}"


def polygons_note(n_polygons: int) -> str:
    verb = "was" if n_polygons == 1 else "were"
    return f"{plural(n_polygons, 'polygon')} with more than 3 corners (quads or n-gons) {verb} split into triangles."


# ---------------------------------------------------------------------- OBJ
# Text is normalised so that every line starts right after a "\n" with its keyword
# (no indentation); patterns with a literal prefix are searched fast by ``re``.
_OBJ_PATTERNS = {key: re.compile(rf"\n{key}[ \t]+([^#\n]*)") for key in ("v", "vt", "f", "mtllib", "usemtl")}
_OBJ_KINDS = re.compile(r"\n(v|vt|f)[ \t]")
_CORNER_LAYOUTS = {  # (slashes, double slashes) per corner -> (numbers per corner, vt column or None)
    (0, 0): (1, None),  # v
    (1, 0): (2, 1),  # v/vt
    (2, 1): (2, None),  # v//vn
    (2, 0): (3, 1),  # v/vt/vn
}
_WHITESPACE = np.zeros(256, dtype=bool)
_WHITESPACE[[9, 10, 11, 12, 13, 32]] = True


def read_obj(path: Path) -> RawMesh:
    """Wavefront OBJ: ``v`` (optionally with r g b), ``vt``, ``f`` (any corner layout, negative
    indices, polygons fan-triangulated), texture from the first used ``map_Kd`` of the ``mtllib``."""
    text = path.read_bytes().decode("utf-8", errors="replace")
    text = "\n" + text.replace("\r\n", "\n").replace("\r", "\n").replace("\\\n", " ")
    text = re.sub(r"\n[ \t]+", "\n", text)
    v = _float_rows(_OBJ_PATTERNS["v"].findall(text), 3, "vertex ('v')")
    vt = _float_rows(_OBJ_PATTERNS["vt"].findall(text), 2, "texture coordinate ('vt')")[:, :2]
    faces = _OBJ_PATTERNS["f"].findall(text)
    joined = "\n".join(faces)
    counts = _tokens_per_row(joined, faces)
    v_idx, vt_idx = _parse_corners(joined, int(counts.sum()))
    if len(counts) and ((v_idx < 0).any() or (vt_idx is not None and (vt_idx < 0).any())):
        v_idx, vt_idx = _resolve_relative(text, counts, v_idx, vt_idx)
    else:
        v_idx = v_idx - 1
        vt_idx = None if vt_idx is None else vt_idx - 1  # a missing vt (0) becomes -1
    if len(v_idx) and (v_idx.min() < 0 or v_idx.max() >= len(v)):
        bad = int(v_idx.min() if v_idx.min() < 0 else v_idx.max()) + 1
        raise ValueError(f"a face refers to vertex {bad}, but the file defines only {len(v)} vertices")
    fan, n_polygons = _fan_triangulate(counts)
    notes = []
    if n_polygons:
        notes.append(polygons_note(n_polygons))
    triangles = v_idx[fan]
    colors = _colors_from_float(v[:, 3:6]) if v.shape[1] >= 6 else None
    vertices = v[:, :3]
    texture = _obj_texture(text, path, notes)
    uv = None
    if len(vt) and vt_idx is not None and len(triangles):
        tri_vt = vt_idx[fan]
        if tri_vt.min() < 0 or tri_vt.max() >= len(vt):
            notes.append("Some faces have no valid texture coordinates, so the texture was not used.")
            texture = None
        else:
            triangles, source, uv_source = _split_seams(len(vertices), triangles, tri_vt)
            if len(source) > len(vertices):
                notes.append(
                    f"{plural(len(source) - len(vertices), 'vertex', 'vertices')} on texture seams "
                    f"{'was' if len(source) == len(vertices) + 1 else 'were'} duplicated so that each vertex has "
                    "a single texture coordinate."
                )
            vertices = vertices[source]
            colors = None if colors is None else colors[source]
            uv = np.where((uv_source >= 0)[:, None], vt[np.maximum(uv_source, 0)], 0.0)
    return RawMesh(vertices, triangles, uv, texture, colors, notes, n_short=int((counts < 3).sum()))


def _token_starts(joined: str) -> np.ndarray | None:
    """Byte offsets where whitespace-separated tokens start in ASCII ``joined`` (None if not ASCII)."""
    if not joined.isascii():
        return None
    raw = np.frombuffer(joined.encode("ascii"), dtype=np.uint8)
    white = _WHITESPACE[raw]
    start = ~white
    start[1:] &= white[:-1]
    return np.flatnonzero(start)


def _tokens_per_row(joined: str, rows: list[str]) -> np.ndarray:
    """(k,) number of whitespace-separated tokens in each of ``rows``; ``joined`` is them joined by newlines."""
    starts = _token_starts(joined)
    if starts is None:  # non-ASCII text: exact but slower
        return np.fromiter((len(r.split()) for r in rows), dtype=np.int64, count=len(rows))
    newlines = np.flatnonzero(np.frombuffer(joined.encode("ascii"), dtype=np.uint8) == 10)
    return np.bincount(np.searchsorted(newlines, starts), minlength=len(rows)).astype(np.int64)


def _numbers(text: str, dtype) -> np.ndarray:
    """All whitespace-separated numbers of ``text``; a bad token raises ValueError naming it."""
    try:
        return np.fromstring(text, dtype=dtype, sep=" ")
    except ValueError:
        return np.array(text.split(), dtype=dtype)  # slower, but its error names the bad token


def _float_rows(rows: list[str], min_columns: int, what: str) -> np.ndarray:
    """(k, c) floats from whitespace-separated ``rows``; c = the shortest row's length, extra values dropped."""
    if not rows:
        return np.zeros((0, min_columns))
    joined = "\n".join(rows)
    counts = _tokens_per_row(joined, rows)
    columns = int(counts.min())
    if columns < min_columns:
        bad = int(np.argmax(counts < min_columns))
        raise ValueError(f"{what} number {bad + 1} has {counts[bad]} values, expected at least {min_columns}")
    if (counts != columns).any():
        joined = "\n".join(" ".join(r.split()[:columns]) for r in rows)
    values = _numbers(joined, np.float64)
    if values.size != len(rows) * columns:
        raise ValueError(f"could not read the {what} values")
    return values.reshape(-1, columns)


def _parse_corners(joined: str, n_corners: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Vertex and texture indices (1-based as written, 0 = absent) of face corners like ``7/3/7``.

    ``joined`` holds all corners separated by whitespace. When every corner
    has the same layout (checked exactly, per corner) the numbers are parsed
    in one call; mixed layouts take a slower per-corner path.
    """
    if n_corners == 0:
        return np.zeros(0, np.int64), None
    starts = _token_starts(joined)
    if starts is not None:
        slash = np.flatnonzero(np.frombuffer(joined.encode("ascii"), dtype=np.uint8) == 47)
        owner = np.searchsorted(starts, slash, side="right") - 1
        slashes = np.bincount(owner, minlength=n_corners)
        doubles = np.bincount(owner[1:][np.diff(slash) == 1], minlength=n_corners)
        layout = _CORNER_LAYOUTS.get((int(slashes[0]), int(doubles[0])))
        if layout and (slashes == slashes[0]).all() and (doubles == doubles[0]).all():
            columns, vt_column = layout
            numbers = _numbers(joined.replace("//", " ").replace("/", " "), np.int64)
            if numbers.size == n_corners * columns:
                numbers = numbers.reshape(-1, columns)
                return numbers[:, 0], None if vt_column is None else numbers[:, vt_column]
    parts = [t.split("/") for t in joined.split()]  # mixed layouts: slow path
    v_idx = np.array([p[0] for p in parts], dtype=np.int64)
    vt_idx = np.array([p[1] if len(p) > 1 and p[1] else "0" for p in parts], dtype=np.int64)
    return v_idx, vt_idx if vt_idx.any() else None


def _resolve_relative(text, counts, v_idx, vt_idx):
    """0-based indices, resolving OBJ negative indices against the elements defined so far."""
    kinds = np.array(_OBJ_KINDS.findall(text))
    is_face = kinds == "f"
    results = []
    for idx, kind in ((v_idx, "v"), (vt_idx, "vt")):
        if idx is None:
            results.append(None)
            continue
        defined_before = np.repeat(np.cumsum(kinds == kind)[is_face], counts)
        results.append(np.where(idx > 0, idx - 1, np.where(idx < 0, idx + defined_before, -1)))
    return results[0], results[1]


def _fan_triangulate(counts: np.ndarray) -> tuple[np.ndarray, int]:
    """Triangle-fan corner indices (t, 3) for faces of ``counts`` corners stored one after another.

    Faces with fewer than 3 corners give no triangle. Returns the fan and the
    number of faces that had more than 3 corners.
    """
    starts = np.cumsum(counts) - counts
    n_tri = np.maximum(counts - 2, 0)
    owner = np.repeat(np.arange(len(counts)), n_tri)
    j = np.arange(int(n_tri.sum())) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)
    first = starts[owner]
    return np.stack([first, first + j + 1, first + j + 2], axis=1), int((counts > 3).sum())


def _split_seams(n_vertices: int, triangles: np.ndarray, tri_vt: np.ndarray):
    """Give each vertex one uv: duplicate vertices used with several ``vt``.

    Returns new triangles (t, 3), the source vertex of each new vertex (n',)
    and its ``vt`` index (n',), -1 for vertices no face uses. The first pair
    met keeps the vertex's index; duplicates are appended in order of appearance.
    """
    n_vt = int(tri_vt.max()) + 1
    keys, first_seen, inverse = np.unique(
        triangles.ravel() * n_vt + tri_vt.ravel(), return_index=True, return_inverse=True
    )
    pair_v, pair_t = keys // n_vt, keys % n_vt
    order = np.argsort(first_seen, kind="stable")  # pairs in order of appearance
    _, first_of_vertex = np.unique(pair_v[order], return_index=True)
    primary = np.zeros(len(keys), dtype=bool)
    primary[order[first_of_vertex]] = True
    extras = order[~primary[order]]
    new_index = np.empty(len(keys), dtype=np.int64)
    new_index[primary] = pair_v[primary]
    new_index[extras] = n_vertices + np.arange(len(extras))
    uv_source = np.full(n_vertices, -1, dtype=np.int64)
    uv_source[pair_v[primary]] = pair_t[primary]
    source = np.concatenate([np.arange(n_vertices), pair_v[extras]])
    return new_index[inverse.ravel()].reshape(-1, 3), source, np.concatenate([uv_source, pair_t[extras]])


def _obj_texture(text: str, obj_path: Path, notes: list[str]) -> np.ndarray | None:
    """Texture of the first used material with a ``map_Kd`` (relative to its MTL file)."""
    maps: dict[str, tuple[Path, Path]] = {}  # material name -> (texture path, folder of its MTL)
    folder = obj_path.parent
    for lib in _OBJ_PATTERNS["mtllib"].findall(text)[:16]:
        lib = lib.strip().replace("\\", "/")
        mtl_path = folder / lib
        if not inside_folder(mtl_path, folder):
            notes.append(f"The OBJ names the material file '{lib}', which is outside the mesh's folder; Mimica "
                         "does not follow it (copy the material file next to the OBJ to use it).")
            continue
        if not mtl_path.is_file():
            notes.append(f"The material file '{lib}' "
                         + ("is not a regular file (a pipe, device or folder)" if mtl_path.exists() else
                            "was not found next to the OBJ") + ", so the face is shown without texture.")
            continue
        from core.formats.text_files import MAX_BYTES

        if mtl_path.stat().st_size > MAX_BYTES["material"]:
            notes.append(f"The material file '{lib}' is larger than a material file can be; it was ignored.")
            continue
        material = None
        for line in mtl_path.read_text(encoding="utf-8", errors="replace").splitlines():
            key, _, value = line.strip().partition(" ")
            if key == "newmtl":
                material = value.strip()
            elif key.lower() == "map_kd" and material is not None and material not in maps:
                value = value.strip().replace("\\", "/")
                if value.startswith("-"):  # options such as "-s 1 1 1 file.png": file name comes last
                    value = value.split()[-1]
                maps[material] = (mtl_path.parent / value, mtl_path.parent)
    used = list(dict.fromkeys(name.strip() for name in _OBJ_PATTERNS["usemtl"].findall(text)))
    textured = [maps[m] for m in (used or maps) if m in maps]
    if not textured:
        return None
    if len(set(textured)) > 1:
        notes.append(
            f"The mesh uses {len(set(textured))} texture images; Mimica shows one per face, so only "
            f"'{textured[0][0].name}' is used and other parts may look wrongly coloured."
        )
    texture_path, mtl_folder = textured[0]
    if not inside_folder(texture_path, folder):
        if (mtl_folder / texture_path.name).is_file() and inside_folder(mtl_folder / texture_path.name, folder):
            texture_path = mtl_folder / texture_path.name  # e.g. an absolute path from another computer
        else:
            notes.append(f"The material names the texture '{texture_path}', which is outside the mesh's folder; "
                         "Mimica does not follow it, so the face is shown without texture (copy the image next "
                         "to the OBJ, or use Tools ▸ Load texture image…).")
            return None
    return _read_texture(texture_path, notes, folder=mtl_folder)


def inside_folder(path: Path, folder: Path) -> bool:
    """True when ``path`` (symbolic links and '..' resolved) lies in ``folder`` or below it."""
    try:
        Path(path).resolve().relative_to(Path(folder).resolve())
    except (ValueError, OSError, RuntimeError):
        return False
    return True


def _read_texture(path: Path, notes: list[str], folder: Path | None = None) -> np.ndarray | None:
    """(H, W, 3) uint8 RGB image, or None with a note saying why the face is shown without it.

    When ``path`` does not exist but a file of the same name is in ``folder``
    (e.g. an absolute path from another computer), that file is used.
    """
    import PIL.Image

    if not path.is_file() and folder is not None and (folder / path.name).is_file():
        path = folder / path.name
    if not path.is_file():
        why = ("is not a regular file (a pipe, device or folder)" if path.exists() else
               f"was not found (looked in '{path.parent}')")
        notes.append(f"The texture image '{path.name}' {why}; the face is shown with plain shading, without texture.")
        return None
    from core.formats.text_files import check_file

    try:
        check_file(path, "image", ValueError, what="a texture image")
        with PIL.Image.open(path) as image:
            return _image_to_rgb(image)
    except Exception as exc:
        notes.append(
            f"The texture image '{path.name}' could not be read ({reason(exc)}); "
            "the face is shown with plain shading, without texture."
        )
        return None


def _image_to_rgb(image) -> np.ndarray:
    """(H, W, 3) uint8 from a PIL image of any mode: alpha dropped, grey expanded, 16-bit scaled."""
    if image.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
        grey = np.asarray(image, dtype=np.float64)
        top = 65535.0 if image.mode.startswith("I;16") or grey.max() > 255 else 255.0
        grey = np.clip(np.rint(grey * (255.0 / top)), 0, 255).astype(np.uint8)
        return np.repeat(grey[:, :, None], 3, axis=2)
    return np.array(image.convert("RGB"), dtype=np.uint8)


def _colors_from_float(colors: np.ndarray) -> np.ndarray:
    """(n, 3) uint8 from colours stored as 0-1 floats (or 0-255 if any exceeds 1)."""
    colors = np.asarray(colors, dtype=np.float64)
    if colors.size and np.nanmax(colors) <= 1.0:
        colors = colors * 255.0
    return np.clip(np.rint(np.nan_to_num(colors)), 0, 255).astype(np.uint8)


# -------------------------------------------------------- PLY, STL, glTF
_PLY_UV_NAMES = [("texture_u", "texture_v"), ("u", "v"), ("s", "t"), ("texture_s", "texture_t")]
_PLY_COLOR_NAMES = [("red", "green", "blue"), ("r", "g", "b"), ("diffuse_red", "diffuse_green", "diffuse_blue")]


def read_ply(path: Path) -> RawMesh:
    """PLY (ASCII or binary) via trimesh; vertex colours, uv and polygon counts from its raw elements."""
    import trimesh

    header = _ply_header(path)
    try:
        loaded = trimesh.load(str(path), file_type="ply", process=False, fix_texture=False, skip_materials=True)
    except Exception as exc:
        if "unexpected length" in str(exc):   # trimesh's word for a binary body shorter or longer than its header says
            raise PlyLengthError(_ply_length_message(path, header)) from None
        raise
    if not isinstance(loaded, trimesh.Trimesh):
        loaded_vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))))
        _check_ply_counts(path, header, len(loaded_vertices), 0)
        return RawMesh(loaded_vertices, np.zeros((0, 3)))
    _check_ply_counts(path, header, len(loaded.vertices), len(loaded.faces))
    raw = loaded.metadata.get("_ply_raw", {})
    vdata = raw.get("vertex", {}).get("data", {})
    names = set(vdata.dtype.names or ()) if isinstance(vdata, np.ndarray) else set(vdata)
    notes, counts = [], _ply_face_sizes(raw.get("face", {}).get("data"))
    if counts is not None and (counts > 3).any():
        notes.append(polygons_note(int((counts > 3).sum())))
    colors = next((np.column_stack([vdata[c] for c in rgb]) for rgb in _PLY_COLOR_NAMES if set(rgb) <= names), None)
    if colors is not None and colors.dtype.kind in "ui":  # 8-bit, or 16-bit scaled down
        colors = (colors if colors.max(initial=0) <= 255 else colors // 257).astype(np.uint8)
    elif colors is not None:
        colors = _colors_from_float(colors)
    uv = next((np.column_stack([vdata[c] for c in st]).astype(np.float64) for st in _PLY_UV_NAMES if set(st) <= names), None)
    vertices, triangles = np.asarray(loaded.vertices), np.asarray(loaded.faces)
    parts = _ply_parts(path, vdata[PLY_PART_PROPERTY]) if PLY_PART_PROPERTY in names else {}
    if uv is None and getattr(loaded.visual, "uv", None) is not None:  # per-corner texcoord: let trimesh split seams
        loaded = trimesh.load(str(path), file_type="ply", process=False, fix_texture=True, skip_materials=True)
        vertices, triangles, uv, colors, parts = loaded.vertices, loaded.faces, loaded.visual.uv, None, {}
    texture = None
    texture_name = _ply_texture_name(path)
    if texture_name:
        texture_path = path.parent / texture_name.replace("\\", "/")
        if inside_folder(texture_path, path.parent) or (path.parent / texture_path.name).is_file():
            texture = _read_texture(texture_path if inside_folder(texture_path, path.parent)
                                    else path.parent / texture_path.name, notes, folder=path.parent)
        else:
            notes.append(f"The PLY names the texture '{texture_name}', which is outside the mesh's folder; Mimica "
                         "does not follow it, so the face is shown without texture (copy the image next to the "
                         "PLY, or use Tools ▸ Load texture image…).")
    n_short = 0 if counts is None else int((counts < 3).sum())
    exact = PLY_MIMICA_COMMENT in _ply_header(path) and n_short == 0
    return RawMesh(vertices, triangles, uv, texture, colors, notes, n_short=n_short, parts=parts, exact=exact)


#: The first comment of every PLY Mimica writes: such a file is a face Mimica held (a project's embedded
#: face, a saved canonical face or scan) and is read back exactly, degenerate triangles and all.
PLY_MIMICA_COMMENT = "comment Written by Mimica"
#: The vertex property and header comments in which Mimica's PLY keeps a face's named parts:
#: ``property ushort mimica_part`` (0 = skin, k = the part of ``comment MimicaPart k NAME``).
PLY_PART_PROPERTY = "mimica_part"
PLY_PART_COMMENT = "MimicaPart"
#: The header comment holding the face's name (JSON, so any name fits the ASCII header).
PLY_NAME_COMMENT = "MimicaName"


def _ply_parts(path: Path, labels) -> dict[str, np.ndarray]:
    """{name: vertex indices} from the ``mimica_part`` labels and the header's part names; labels
    without a name are skin."""
    header = _ply_header(path)
    names = {int(k): name for k, name in re.findall(rf"^comment\s+{PLY_PART_COMMENT}\s+(\d+)\s+(\S+)\s*$",
                                                     header, re.MULTILINE)}
    labels = np.asarray(labels, dtype=np.int64)
    return {name: np.nonzero(labels == k)[0] for k, name in sorted(names.items()) if (labels == k).any()}


def _ply_face_sizes(face_data) -> np.ndarray | None:
    """Corner count of every PLY face, from trimesh's raw element data (None if unknown)."""
    if face_data is None:
        return None
    if isinstance(face_data, np.ndarray) and face_data.dtype.names:
        face_data = {name: face_data[name] for name in face_data.dtype.names}
    if not isinstance(face_data, dict):
        return None
    lists = next((face_data[k] for k in ("vertex_indices", "vertex_index") if k in face_data), None)
    if isinstance(lists, np.ndarray) and lists.dtype.names and "f1" in lists.dtype.names:
        lists = lists["f1"]
    if isinstance(lists, np.ndarray) and lists.dtype != object and lists.ndim == 2:
        return np.full(len(lists), lists.shape[1], dtype=np.int64)
    return None if lists is None else np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))


class PlyLengthError(ValueError):
    """A PLY whose body does not hold what its header announces (cut short, or not a PLY body)."""


def _ply_element_counts(header: str) -> dict[str, int]:
    """{element name: count} as the header announces them (``element vertex 1234``)."""
    return {name: int(n) for name, n in re.findall(r"^element\s+(\S+)\s+(\d+)\s*$", header, re.MULTILINE)}


def _ply_length_message(path: Path, header: str) -> str:
    counts = _ply_element_counts(header)
    announced = ", ".join(plural(n, name, "vertices" if name == "vertex" else None)
                          for name, n in counts.items()) or "its elements"
    return (f"'{path.name}' does not hold what its header announces ({announced}): the file was probably cut "
            "short by an interrupted copy, download or export. Copy or export it again.")


def _check_ply_counts(path: Path, header: str, n_vertices: int, n_faces: int) -> None:
    """Raise PlyLengthError when fewer vertices or faces were read than the header announces (an ASCII
    PLY cut short reads as a smaller mesh, or a point cloud, without this)."""
    counts = _ply_element_counts(header)
    if n_vertices < counts.get("vertex", 0) or n_faces < counts.get("face", 0):
        raise PlyLengthError(
            f"'{path.name}' ends early: its header announces {plural(counts.get('vertex', 0), 'vertex', 'vertices')} "
            f"and {plural(counts.get('face', 0), 'face')}, the file holds {plural(n_vertices, 'vertex', 'vertices')} "
            f"and {plural(n_faces, 'face')}. It was probably cut short by an interrupted copy, download or "
            "export; copy or export it again.")


def _ply_header(path: Path) -> str:
    """The PLY's header text (up to ``end_header``, at most 64 KiB)."""
    with open(path, "rb") as fh:
        return fh.read(1 << 16).split(b"end_header", 1)[0].decode("latin-1")


def ply_face_name(path: Path) -> str | None:
    """The face's name as Mimica wrote it (``comment MimicaName "<JSON string>"``: a project's embedded
    face is named by its project file, the face it holds is not), None when the file has none."""
    match = re.search(rf"^comment\s+{PLY_NAME_COMMENT}\s+(.+?)\s*$", _ply_header(path), re.MULTILINE)
    try:
        name = json.loads(match.group(1)) if match else None
    except ValueError:
        return None
    return name if isinstance(name, str) and name.strip() else None


def _ply_texture_name(path: Path) -> str | None:
    """File named by a ``comment TextureFile`` header line, if any."""
    header = _ply_header(path)
    match = re.search(r"^comment\s+TextureFile\s+(.+?)\s*$", header, re.MULTILINE)
    return match.group(1) if match else None


def read_stl(path: Path) -> RawMesh:
    """STL (ASCII or binary) via trimesh, coincident corners welded."""
    import trimesh

    loaded = trimesh.load(str(path), file_type="stl", process=False)
    vertices, inverse = weld(np.asarray(loaded.vertices))
    return RawMesh(vertices, inverse[np.asarray(loaded.faces)])


def read_gltf(path: Path) -> RawMesh:
    """glTF / GLB via trimesh: every mesh of the scene, node transforms applied, concatenated."""
    import trimesh

    loaded = trimesh.load(str(path), file_type=path.suffix.lower().lstrip("."), process=False)
    parts = loaded.dump(concatenate=False) if isinstance(loaded, trimesh.Scene) else [loaded]
    meshes = [p for p in parts if isinstance(p, trimesh.Trimesh) and len(p.faces)]
    if not meshes:
        n_points = sum(len(getattr(p, "vertices", ())) for p in parts)
        return RawMesh(np.zeros((n_points, 3)), np.zeros((0, 3)))
    notes = []
    if len(meshes) > 1:
        notes.append(f"The file contains {len(meshes)} separate meshes; they were combined into one face.")
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    vertices = np.concatenate([m.vertices for m in meshes])
    triangles = np.concatenate([m.faces + o for m, o in zip(meshes, offsets)])
    uvs, textures, colors = [], [], []
    for m in meshes:
        visual = m.visual
        uv = getattr(visual, "uv", None) if visual.kind == "texture" else None
        uvs.append(None if uv is None else np.asarray(uv, dtype=np.float64))
        material = getattr(visual, "material", None) if visual.kind == "texture" else None
        image = getattr(material, "baseColorTexture", None)
        image = getattr(material, "image", None) if image is None else image
        textures.append(None if image is None else _image_to_rgb(image))
        colors.append(np.asarray(visual.vertex_colors)[:, :3] if visual.kind == "vertex" else None)
    uv = texture = vertex_colors = None
    if any(u is not None for u in uvs):
        uv = np.concatenate([np.zeros((len(m.vertices), 2)) if u is None else u for m, u in zip(meshes, uvs)])
    found = [(len(m.faces), t) for m, t in zip(meshes, textures) if t is not None]
    if found:
        texture = max(found, key=lambda item: item[0])[1]
        distinct = {(t.shape, t.tobytes()) for _, t in found}
        if len(distinct) > 1:
            notes.append(
                f"The meshes use {len(distinct)} different textures; Mimica shows one per face, so only the "
                "texture of the largest mesh is used and other parts may look wrongly coloured."
            )
    if any(c is not None for c in colors):
        vertex_colors = np.concatenate(
            [np.full((len(m.vertices), 3), 200, np.uint8) if c is None else c for m, c in zip(meshes, colors)]
        )
    return RawMesh(vertices, triangles, uv, texture, vertex_colors, notes)


# ------------------------------------------------------------- helpers
def weld(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge exactly coincident vertices, keeping first-appearance order.

    Returns the unique vertices (k, 3) and, for each input vertex, its index
    among them (n,).
    """
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return vertices[np.sort(first)], rank[inverse.ravel()]



READERS = {"OBJ": read_obj, "PLY": read_ply, "STL": read_stl, "glTF": read_gltf, "GLB": read_gltf}
