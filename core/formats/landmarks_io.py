"""landmarks_io.py
----
Save and load a face's landmarks as JSON::

    {"format": "mimica-landmarks", "version": 1, "units": "mm",
     "landmarks": [{"name": "2.1", "xyz": [x, y, z], "triangle": 812,
                    "barycentric": [0.2, 0.3, 0.5]}, ...]}

``triangle`` + ``barycentric`` are the landmark (a surface point); ``xyz`` is
its position when saved, kept for people reading the file and as a fallback:
when the triangle does not exist on the face the landmarks are loaded onto
(e.g. the file was made for another mesh), the closest surface point to
``xyz`` is used instead and a note says so.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from core.face import Face, SurfacePoint
from core.formats.atomic_files import write_atomic, write_reporting_errors
from core.formats.text_files import read_file_bytes, read_json_file, reading

__all__ = ["LandmarkFileError", "save_landmarks", "load_landmarks", "read_landmark_text", "FORMAT_NAME",
           "FORMAT_VERSION"]

FORMAT_NAME = "mimica-landmarks"
FORMAT_VERSION = 1
#: Accepted "units" values and their size in mm (xyz is only used as a fallback).
UNIT_SCALE = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
#: Tolerance on the sum of barycentric weights (the same as SurfacePoint's).
BARYCENTRIC_SUM_TOLERANCE = 1e-4
#: More landmarks than this in one file are refused.
MAX_LANDMARKS = 10_000
#: Landmark names longer than this are refused.
MAX_NAME_CHARS = 200
#: A stored xyz this far (mm) from where its triangle puts it earns a note.
POSITION_MISMATCH_MM = 1.0


class LandmarkFileError(Exception):
    """A landmark file could not be read or written; ``str(error)`` is a user-facing message."""


def save_landmarks(face: Face, path) -> None:
    """Write all landmarks of ``face`` to ``path`` as mimica-landmarks JSON (atomically).

    Raises
    ------
    LandmarkFileError
        If the folder does not exist or cannot be written.
    """
    path = Path(path)
    names = face.landmark_names
    positions = face.landmark_positions(names)
    points = face.landmarks
    document = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "units": "mm",
        "landmarks": [
            {
                "name": name,
                "xyz": [float(c) for c in xyz],
                "triangle": points[name].triangle,
                "barycentric": list(points[name].barycentric),
            }
            for name, xyz in zip(names, positions)
        ],
    }
    text = (json.dumps(document, indent=2) + "\n").encode("utf-8")
    write_reporting_errors(path, lambda: write_atomic(path, text), LandmarkFileError)


def load_landmarks(path, face: Face, *, notes: list[str] | None = None) -> dict[str, SurfacePoint]:
    """Read landmarks saved by :func:`save_landmarks` and map them onto ``face``.

    Parameters
    ----------
    path : str or os.PathLike
    face : Face
        The face the landmarks are for; it is not modified (apply the result
        with ``face.set_landmark``).
    notes : list of str, optional
        Receives one user-facing sentence per landmark that was relocated
        (triangle missing from ``face``, closest surface point to ``xyz``
        used) or whose stored xyz disagrees with its triangle.

    Returns
    -------
    dict of name -> SurfacePoint, in file order.

    Raises
    ------
    LandmarkFileError
        Missing or unreadable file, invalid JSON (with line and column), not
        a mimica-landmarks file, unsupported version or units, or a landmark
        with bad data (named in the message).
    """
    path = Path(path)
    with reading(LandmarkFileError, f"'{path.name}'", "landmark"):
        return _load_landmarks(path, face, notes)


def _load_landmarks(path: Path, face: Face, notes: list[str] | None) -> dict[str, SurfacePoint]:
    document = _read_json(path)
    entries = _check_header(document, path.name)
    scale = UNIT_SCALE[document.get("units", "mm")]
    result: dict[str, SurfacePoint] = {}
    relocate: dict[str, np.ndarray] = {}
    stored_xyz: dict[str, np.ndarray] = {}
    missing: dict[str, str] = {}  # why a landmark is relocated
    for index, entry in enumerate(entries):
        name, xyz, triangle, bary = _parse_entry(entry, index, path.name)
        if name in result or name in relocate:
            raise LandmarkFileError(f"'{path.name}': landmark '{name}' appears more than once.")
        if xyz is not None:
            xyz = xyz * scale
        if triangle is not None and 0 <= triangle < face.n_triangles:
            result[name] = SurfacePoint(triangle, bary)
            if xyz is not None:
                stored_xyz[name] = xyz
        elif xyz is not None:
            relocate[name] = xyz
            missing[name] = (
                "has no triangle" if triangle is None
                else f"refers to triangle {triangle}, which this face does not have ({face.n_triangles} triangles)"
            )
            result[name] = None  # reserve the slot so the file order is kept; filled below
        else:
            raise LandmarkFileError(
                f"'{path.name}': landmark '{name}' refers to triangle {triangle}, but the face has only "
                f"{face.n_triangles} triangles, and it has no xyz position to fall back on."
            )
    messages = []
    if relocate:
        closest, triangles, barys = face.closest_surface_points(np.array(list(relocate.values())))
        for name, xyz, position, tri, bary in zip(relocate, relocate.values(), closest, triangles, barys):
            result[name] = SurfacePoint(int(tri), tuple(bary))
            messages.append(
                f"Landmark '{name}' {missing[name]}; it was placed at the surface point closest to its saved "
                f"position ({np.linalg.norm(position - xyz):.2f} mm away). The file was probably made for another mesh."
            )
    if stored_xyz:
        names = list(stored_xyz)
        tri = np.array([result[n].triangle for n in names])
        bary = np.array([result[n].barycentric for n in names])
        computed = np.einsum("kj,kjd->kd", bary, face.vertices[face.triangles[tri]])
        distance = np.linalg.norm(computed - np.array(list(stored_xyz.values())), axis=1)
        messages += [
            f"Landmark '{n}' is {d:.1f} mm from its saved position; the file may have been made for "
            "another mesh or another pose."
            for n, d in zip(names, distance)
            if d > POSITION_MISMATCH_MM
        ]
    if notes is not None:
        notes.extend(messages)
    return result


def _read_json(path: Path):
    """The JSON document of a landmark file (regular file, at most ``MAX_BYTES['landmark']``,
    no NaN, nesting or numbers a float cannot hold); LandmarkFileError otherwise."""
    return read_json_file(path, "landmark", LandmarkFileError, what="a landmark file",
                          hint="Fix that line in a text editor or save the landmarks again.")


def read_landmark_text(path) -> str:
    """The text of a landmark file (CSV or JSON): a regular UTF-8 file of at most
    ``MAX_BYTES['landmark']``; LandmarkFileError otherwise."""
    path = Path(path)
    data = read_file_bytes(path, "landmark", LandmarkFileError, what="a landmark file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise LandmarkFileError(f"'{path.name}' is not a text (UTF-8) file.") from None


def _check_header(document, name: str) -> list:
    """The ``landmarks`` list, after checking format, version and units."""
    if not isinstance(document, dict) or document.get("format") != FORMAT_NAME:
        found = document.get("format") if isinstance(document, dict) else None
        raise LandmarkFileError(
            f"'{name}' is not a Mimica landmark file (its \"format\" is {found!r}, expected '{FORMAT_NAME}')."
        )
    version = document.get("version")
    if version != FORMAT_VERSION:
        raise LandmarkFileError(
            f"'{name}' is a landmark file of version {version!r}; this Mimica reads version "
            f"{FORMAT_VERSION} only. It may come from a newer Mimica: update Mimica to read it."
        )
    units = document.get("units", "mm")
    if not isinstance(units, str) or units not in UNIT_SCALE:
        raise LandmarkFileError(f"'{name}' has units {units!r}; expected one of {', '.join(UNIT_SCALE)}.")
    entries = document.get("landmarks")
    if not isinstance(entries, list):
        raise LandmarkFileError(f"'{name}' has no \"landmarks\" list.")
    if len(entries) > MAX_LANDMARKS:
        raise LandmarkFileError(f"'{name}' holds {len(entries)} landmarks; a landmark file holds at most "
                                f"{MAX_LANDMARKS} (the densest template has 80).")
    return entries


def _parse_entry(entry, index: int, file_name: str):
    """(name, xyz (3,) or None, triangle or None, barycentric tuple or None) of one landmark entry."""
    if not isinstance(entry, dict) or not isinstance(entry.get("name"), str) or not entry["name"]:
        raise LandmarkFileError(f"'{file_name}': landmark number {index + 1} has no name.")
    name = entry["name"]
    if len(name) > MAX_NAME_CHARS:
        raise LandmarkFileError(f"'{file_name}': landmark number {index + 1} has a name of {len(name)} "
                                f"characters; names have at most {MAX_NAME_CHARS}.")

    def bad(what: str) -> LandmarkFileError:
        return LandmarkFileError(f"'{file_name}': landmark '{name}' {what}.")

    xyz = entry.get("xyz")
    if xyz is not None:
        if not _numbers(xyz, 3):
            raise bad("has an invalid \"xyz\" (expected 3 finite numbers)")
        xyz = np.array(xyz, dtype=np.float64)
    triangle, bary = entry.get("triangle"), entry.get("barycentric")
    if triangle is None and xyz is None:
        raise bad("has neither a triangle nor an xyz position")
    if triangle is not None:
        if isinstance(triangle, bool) or not isinstance(triangle, int):
            raise bad(f"has an invalid \"triangle\" ({triangle!r}; expected a whole number)")
        if not _numbers(bary, 3):
            raise bad("has an invalid \"barycentric\" (expected 3 finite numbers)")
        total = math.fsum(bary)
        if abs(total - 1.0) > BARYCENTRIC_SUM_TOLERANCE:
            raise bad(f"has barycentric weights that sum to {total:.6g} instead of 1")
        if min(bary) < -BARYCENTRIC_SUM_TOLERANCE:
            raise bad("has a negative barycentric weight (the point lies outside its triangle)")
        bary = tuple(float(b) for b in bary)
    return name, xyz, triangle, bary


def _numbers(value, count: int) -> bool:
    return (
        isinstance(value, list)
        and len(value) == count
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    )
