"""Expression library files: a JSON header plus a compact array file beside it.

``<name>.json`` (the file a user opens and picks)::

    {"format": "mimica-expression-library", "version": 1,
     "template": "mpeg4_80",            # canonical template of the faces ("custom": other topology)
     "vertex_count": 4560, "poses": ["joy", "sadness", ...], "units": "mm",
     "arrays": "<name>.npz",            # beside the JSON file
     "base": "person 1", "transfer": "", "has_mean": false}

``<name>.npz`` (NumPy, no pickle): ``rest`` (n, 3) float32 mm, ``displacements`` (k, n, 3) float32
mm, and ``mean`` (n, 3) float32 when ``has_mean``. float32 keeps 1e-5 mm steps at face size.

Reading checks everything before anything is used: the JSON and the array file through
``core.formats.text_files`` (regular file, size cap, depth, finite numbers), every header field,
the array members' declared sizes before they are decompressed, shapes against the header, NaN,
and, when asked, the template and vertex count a face needs. Any problem is a
:class:`LibraryFileError` naming the file and the field; nothing is returned half-read, so a
caller that replaces its library only after :func:`read_library` returns changes nothing.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np

from core.formats.text_files import parse_json, read_file_bytes, reading
from core.layers.blend.library import ExpressionLibrary, LibraryError, POSE_NAME

__all__ = ["LibraryFileError", "FORMAT", "VERSION", "read_library", "write_library", "arrays_path"]

FORMAT = "mimica-expression-library"
VERSION = 1
MAX_JSON_BYTES = 1 * 2**20
MAX_ARRAY_BYTES = 512 * 2**20
MAX_POSES = 256
MAX_VERTICES = 2_000_000


class LibraryFileError(LibraryError):
    """An expression library file cannot be read or does not fit; the message names file and field."""


def arrays_path(path) -> Path:
    """The array file that goes with the JSON header ``path`` (same stem, ``.npz``)."""
    return Path(path).with_suffix(".npz")


def write_library(library: ExpressionLibrary, path) -> Path:
    """Write ``library`` to ``path`` (.json) and its arrays beside it (.npz); returns the JSON path.
    Each file is written atomically (temporary file, then rename)."""
    from core.formats.atomic_files import write_atomic

    path = Path(path)
    if path.suffix.lower() != ".json":
        raise LibraryFileError(f"'{path.name}': expression libraries are saved as .json (plus a .npz beside it)")
    npz = arrays_path(path)
    arrays = {"rest": library.rest.astype(np.float32),
              "displacements": library.displacements.astype(np.float32)}
    if library.mean is not None:
        arrays["mean"] = library.mean.astype(np.float32)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    header = {"format": FORMAT, "version": VERSION, "template": library.template,
              "vertex_count": library.n_vertices, "poses": list(library.names), "units": library.units,
              "arrays": npz.name, "base": library.base, "transfer": library.transfer,
              "has_mean": library.mean is not None}
    write_atomic(npz, buf.getvalue())
    write_atomic(path, (json.dumps(header, indent=1) + "\n").encode("utf-8"))
    return path


def _field_error(path: Path, field: str, message: str) -> LibraryFileError:
    return LibraryFileError(f"'{path.name}' is not a usable expression library: field '{field}' {message}.")


def _check_header(path: Path, head) -> dict:
    if not isinstance(head, dict):
        raise LibraryFileError(f"'{path.name}' is not an expression library: it is JSON but not an object")
    if head.get("format") != FORMAT:
        raise _field_error(path, "format", f"must be {FORMAT!r}, got {head.get('format')!r}")
    version = head.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise _field_error(path, "version", f"must be a whole number ≥ 1, got {version!r}")
    if version > VERSION:
        raise _field_error(path, "version", f"is {version}, newer than this Mimica reads ({VERSION}): update Mimica")
    template = head.get("template")
    if not isinstance(template, str) or not template:
        raise _field_error(path, "template", f"must name the canonical template, got {template!r}")
    n = head.get("vertex_count")
    if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= MAX_VERTICES:
        raise _field_error(path, "vertex_count", f"must be a whole number 1…{MAX_VERTICES}, got {n!r}")
    if template != "custom":
        from core.registration.templates import TEMPLATE_NAMES

        if template not in TEMPLATE_NAMES:
            raise _field_error(path, "template", f"names an unknown template {template!r} "
                                                 f"(known: {', '.join(TEMPLATE_NAMES)}, or 'custom')")
        from core.registration.correspondence import canonical_triangles

        expected = int(canonical_triangles(template).max()) + 1
        if n != expected:
            raise _field_error(path, "vertex_count", f"is {n}, but faces of template {template!r} have {expected} vertices")
    poses = head.get("poses")
    if not isinstance(poses, list) or len(poses) > MAX_POSES:
        raise _field_error(path, "poses", f"must be a list of at most {MAX_POSES} pose names")
    for p in poses:
        if not isinstance(p, str) or not POSE_NAME.match(p) or p == "neutral":
            raise _field_error(path, "poses", f"holds {p!r}, not a pose name (lower-case letters, digits, '_')")
    if len(set(poses)) != len(poses):
        raise _field_error(path, "poses", "names a pose twice")
    if head.get("units", "mm") != "mm":
        raise _field_error(path, "units", f"must be 'mm', got {head.get('units')!r}")
    arrays = head.get("arrays", arrays_path(path).name)
    if not isinstance(arrays, str) or Path(arrays).name != arrays or not arrays.endswith(".npz"):
        raise _field_error(path, "arrays", f"must be the name of a .npz file beside it, got {arrays!r}")
    for key in ("base", "transfer"):
        if not isinstance(head.get(key, ""), str):
            raise _field_error(path, key, "must be text")
    if not isinstance(head.get("has_mean", False), bool):
        raise _field_error(path, "has_mean", "must be true or false")
    return head


def read_library(path, *, template: str | None = None, n_vertices: int | None = None) -> ExpressionLibrary:
    """The library in ``path`` (.json header; arrays in the .npz it names, beside it).

    template, n_vertices : what the caller's face needs (None: anything); a library of another
    template or vertex count is refused with a message saying what to do.
    Raises LibraryFileError (a ValueError) for anything wrong; returns a complete library or nothing.
    """
    path = Path(path)
    data = read_file_bytes(path, "expression library", LibraryFileError, max_bytes=MAX_JSON_BYTES,
                           what="an expression library (.json)")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise LibraryFileError(f"'{path.name}' is not an expression library (it is not UTF-8 text)") from None
    head = _check_header(path, parse_json(text, f"'{path.name}'", LibraryFileError, "expression library"))
    n, poses = head["vertex_count"], head["poses"]
    if template is not None and head["template"] != template:
        raise _field_error(path, "template", f"is {head['template']!r}, but this face is registered to template "
                                             f"{template!r}: transfer the library onto this face, or register the "
                                             f"face with {head['template']!r}")
    if n_vertices is not None and n != n_vertices:
        raise _field_error(path, "vertex_count", f"is {n}, but this face has {n_vertices} vertices: register the face "
                                                 f"to the library's template {head['template']!r} first")
    npz_path = path.parent / head["arrays"]
    raw = read_file_bytes(npz_path, "expression library", LibraryFileError, max_bytes=MAX_ARRAY_BYTES,
                          what="an expression library's array file (.npz)")
    shapes = {"rest": (n, 3), "displacements": (len(poses), n, 3)}
    if head.get("has_mean", False):
        shapes["mean"] = (n, 3)
    try:
        arrays = _read_arrays(npz_path, raw, shapes)
    # zipfile raises NotImplementedError for a compression method it cannot read (a foreign archive)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, NotImplementedError) as exc:
        raise LibraryFileError(f"'{npz_path.name}' is not an expression library's array file: it is not a readable "
                               f"NumPy .npz archive ({exc}). Save the library again, or open a backup.") from None
    try:
        return ExpressionLibrary(arrays["rest"], tuple(poses), arrays["displacements"], template=head["template"],
                                 mean=arrays.get("mean"), base=head.get("base", ""),
                                 transfer=head.get("transfer", ""))
    except LibraryError as exc:
        raise LibraryFileError(f"'{path.name}' is not a usable expression library: {exc}") from None


def _read_arrays(npz_path: Path, raw: bytes, shapes: dict) -> dict[str, np.ndarray]:
    """The arrays of ``shapes`` from the .npz bytes, each member's size checked before it is inflated."""
    arrays = {}
    with reading(LibraryFileError, f"'{npz_path.name}'", "expression library array"):
        with zipfile.ZipFile(io.BytesIO(raw)) as zf:
            sizes = {i.filename: i.file_size for i in zf.infolist()}
        for key, shape in shapes.items():
            member = f"{key}.npy"
            if member not in sizes:
                raise _field_error(npz_path, key, "is missing from the array file")
            limit = 8 * int(np.prod(shape)) + 4096     # float64 at most, plus the .npy header
            if sizes[member] > limit:
                raise _field_error(npz_path, key, f"is larger than {shape} numbers; the file does not match its header")
        with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
            for key, shape in shapes.items():
                a = npz[key]
                if a.dtype.kind != "f":
                    raise _field_error(npz_path, key, f"must hold floating-point numbers, got {a.dtype}")
                if a.shape != shape:
                    raise _field_error(npz_path, key, f"has shape {a.shape}, the header says {shape}")
                if not np.all(np.isfinite(a)):
                    raise _field_error(npz_path, key, "holds NaN or infinite values")
                arrays[key] = a.astype(float)
    return arrays
