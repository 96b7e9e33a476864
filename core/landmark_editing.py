"""landmark_editing.py
----
A Qt-free model of the landmark set being corrected by hand (thesis A §3.3,
Fig. 3.28: the detected landmarks are shown in 3-D and the user re-marks the
wrong ones by clicking).

Every landmark has

* a position: a :class:`~core.face.SurfacePoint` (triangle + barycentric) on
  the face's *neutral* mesh. Picks made on a deformed (animated) display give
  the same triangle + barycentric, so they are stored unchanged;
* a status: ``auto`` (placed by a detector or loaded, not checked by a
  person), ``edited`` (moved by the user) or ``confirmed`` (checked by the
  user);
* a confidence: the detector's score (float) or ``None`` when unknown.

Choices the thesis leaves open, written down here:

* Status transitions: any move makes a landmark ``edited`` and clears its
  confidence (the detector's score no longer describes where it is now);
  ``confirm`` makes it ``confirmed`` and keeps the confidence. Re-running the
  detector (:meth:`LandmarkEditModel.apply_detection`) only replaces ``auto``
  landmarks: ``edited`` and ``confirmed`` ones are the user's and stay fixed
  (:meth:`LandmarkEditModel.fixed_points`).
* Files without a status (older JSON files, CSV rows with an empty status)
  load as ``auto``: nobody has confirmed them in this session.
* Mirror partners are the MPEG-4 left/right feature-point pairs of
  ``resources/mpeg4/landmark_pairs.csv``. The mid-sagittal plane is fitted
  to the pairs present (normal = main direction of left - right, through
  the mean of the pair midpoints), leaving out the pair being mirrored so
  the user's new, possibly asymmetric, point does not tilt its own mirror.
  Without any pair the plane x = centre of the face's bounding box is used
  (+x is the face's left in Mimica's convention). The reflected point is
  projected onto the closest point of the neutral surface.
* The model writes every change straight into the face
  (``face.set_landmark``), so anything that reads ``face.landmarks`` sees the
  corrected set at once.

Files: JSON uses the mimica-landmarks format of :mod:`core.formats.landmarks_io`
with two extra per-landmark keys, ``status`` and ``confidence`` (ignored by
readers that do not know them). CSV has the header
``name,x,y,z,status,confidence`` (x/y/z in mm on the neutral face); its
points are placed at the closest surface point on loading.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass, replace
from enum import Enum
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np
from psygnal import Signal

from core.face import Face, SurfacePoint
from core.formats.landmarks_io import (FORMAT_NAME, FORMAT_VERSION, MAX_LANDMARKS, MAX_NAME_CHARS, POSITION_MISMATCH_MM,
                                      LandmarkFileError, load_landmarks, read_landmark_text)
from core.formats.text_files import NotUtf8, parse_json, reading, text_lines
from core.formats.atomic_files import write_atomic, write_reporting_errors

__all__ = [
    "LandmarkStatus", "LandmarkState", "LandmarkEditModel", "LandmarkEditError", "LandmarkFileError",
    "mirror_pairs", "fp_sort_key", "CSV_COLUMNS",
]

CSV_COLUMNS = ("name", "x", "y", "z", "status", "confidence")
LOW_CONFIDENCE = 0.5   # detector scores below this are worth checking (lists, counts and reports)
_FP_NAME = re.compile(r"^(\d+)\.(\d+)$")


class LandmarkStatus(str, Enum):
    """Who vouches for a landmark's position."""

    AUTO = "auto"
    EDITED = "edited"
    CONFIRMED = "confirmed"


@dataclass(frozen=True)
class LandmarkState:
    """Everything the editor knows about one landmark (immutable: undo keeps these)."""

    point: SurfacePoint
    status: LandmarkStatus = LandmarkStatus.AUTO
    confidence: float | None = None


class LandmarkEditError(ValueError):
    """A request the landmark model cannot honour (unknown name, bad value); the message says why."""


def mirror_pairs() -> dict[str, str]:
    """name -> mirror partner for every MPEG-4 left/right pair (both directions)."""
    import resources

    pairs: dict[str, str] = {}
    for row in resources.get_table("mpeg4/landmark_pairs.csv"):
        pairs[row["left"]] = row["right"]
        pairs[row["right"]] = row["left"]
    return pairs


def _left_names() -> frozenset[str]:
    import resources

    return frozenset(row["left"] for row in resources.get_table("mpeg4/landmark_pairs.csv"))


def fp_sort_key(name: str, index: int = 0) -> tuple:
    """Sort key: MPEG-4 names "g.i" by (group, index) numerically, other names after, in given order."""
    m = _FP_NAME.match(name)
    return (0, int(m.group(1)), int(m.group(2)), 0) if m else (1, 0, 0, index)


def _status(value, where: str) -> LandmarkStatus:
    if isinstance(value, LandmarkStatus):
        return value
    try:
        return LandmarkStatus(str(value).strip().lower())
    except ValueError:
        allowed = ", ".join(s.value for s in LandmarkStatus)
        raise LandmarkEditError(f"{where}: status must be one of {allowed}, got {value!r}") from None


def _confidence(value, where: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool):
        raise LandmarkEditError(f"{where}: confidence must be a number or empty, got {value!r}")
    try:
        c = float(value)
    except (TypeError, ValueError):
        raise LandmarkEditError(f"{where}: confidence must be a number or empty, got {value!r}") from None
    if not math.isfinite(c):
        raise LandmarkEditError(f"{where}: confidence must be a finite number, got {value!r}")
    return c


class LandmarkEditModel:
    """The landmarks of one face while they are being corrected.

    Parameters
    ----------
    face : Face
        The neutral face; its landmarks are the initial set and every change is written back
        with ``face.set_landmark``.
    status : mapping name -> LandmarkStatus or str, optional
        Initial statuses (default ``auto``).
    confidence : mapping name -> float or None, optional

    Signals
    -------
    changed(str)
        A landmark's position, status or confidence changed (its name), or ``""`` when several
        changed at once or names were added/removed (re-read everything).
    selection_changed(object)
        The selected name (or None).
    """

    changed = Signal(str)
    selection_changed = Signal(object)

    def __init__(self, face: Face, *, status: Mapping | None = None, confidence: Mapping | None = None):
        self._face = face
        self._pairs = mirror_pairs()
        self._states: dict[str, LandmarkState] = {}
        # Statuses the face inherited (e.g. a canonical face built from corrected points), then the given ones.
        status = {**getattr(face.metadata, "landmark_status", {}), **dict(status or {})}
        confidence = {**getattr(face.metadata, "landmark_confidence", {}), **dict(confidence or {})}
        for name, point in face.landmarks.items():
            self._states[name] = LandmarkState(
                point, _status(status.get(name, LandmarkStatus.AUTO), f"landmark {name!r}"),
                _confidence(confidence.get(name), f"landmark {name!r}"))
        self._names = self._sorted(self._states)
        self._selected: str | None = None

    # ------------------------------------------------------------ queries
    @property
    def face(self) -> Face:
        return self._face

    @property
    def names(self) -> list[str]:
        """Landmark names in display order (MPEG-4 group then number; others after)."""
        return list(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name) -> bool:
        return name in self._states

    def index(self, name: str) -> int:
        self._check(name)
        return self._names.index(name)

    def state(self, name: str) -> LandmarkState:
        self._check(name)
        return self._states[name]

    def snapshot(self) -> dict[str, LandmarkState]:
        """A copy of every landmark's state (what undo stores)."""
        return dict(self._states)

    def point(self, name: str) -> SurfacePoint:
        return self.state(name).point

    def status(self, name: str) -> LandmarkStatus:
        return self.state(name).status

    def confidence(self, name: str) -> float | None:
        return self.state(name).confidence

    def position(self, name: str, vertices: np.ndarray | None = None) -> np.ndarray:
        """(3,) mm on the neutral face (or on ``vertices`` (n, 3), e.g. the displayed pose)."""
        self._check(name)
        return self._face.landmark_position(name, vertices)

    def positions(self, vertices: np.ndarray | None = None) -> np.ndarray:
        """(k, 3) mm of all landmarks in :attr:`names` order."""
        return self._face.landmark_positions(self._names, vertices)

    def triangles_and_barycentrics(self) -> tuple[np.ndarray, np.ndarray]:
        """((k,) int triangles, (k, 3) barycentric weights) in :attr:`names` order."""
        points = [self._states[n].point for n in self._names]
        tri = np.array([p.triangle for p in points], dtype=np.int64)
        bary = np.array([p.barycentric for p in points], dtype=np.float64).reshape(-1, 3)
        return tri, bary

    def statuses(self) -> list[LandmarkStatus]:
        return [self._states[n].status for n in self._names]

    def counts(self) -> dict[LandmarkStatus, int]:
        out = {s: 0 for s in LandmarkStatus}
        for st in self._states.values():
            out[st.status] += 1
        return out

    def fixed_points(self) -> dict[str, SurfacePoint]:
        """The user's landmarks (edited or confirmed): what a re-run of the detector must keep."""
        return {n: s.point for n, s in self._states.items() if s.status is not LandmarkStatus.AUTO}

    # ------------------------------------------------------------ selection
    @property
    def selected(self) -> str | None:
        return self._selected

    def select(self, name: str | None) -> None:
        if name is not None:
            self._check(name)
        if name != self._selected:
            self._selected = name
            self.selection_changed.emit(name)

    def neighbour(self, name: str | None, step: int = 1, *, wrap: bool = True) -> str | None:
        """The name ``step`` places after ``name`` in display order (the first/last when None)."""
        if not self._names:
            return None
        if name is None or name not in self._states:
            return self._names[0] if step >= 0 else self._names[-1]
        i = self._names.index(name) + step
        if wrap:
            return self._names[i % len(self._names)]
        return self._names[min(max(i, 0), len(self._names) - 1)]

    def select_next(self, step: int = 1) -> str | None:
        """Select the next (``step`` > 0) or previous landmark, wrapping around; returns it."""
        name = self.neighbour(self._selected, step)
        self.select(name)
        return name

    # ------------------------------------------------------------ edits
    def move(self, name: str, point: SurfacePoint) -> None:
        """Put ``name`` at ``point`` (on the neutral face); it becomes ``edited`` with no confidence."""
        self._check(name)
        self._check_point(name, point)
        self.set_state(name, LandmarkState(point, LandmarkStatus.EDITED, None))

    def confirm(self, name: str) -> None:
        """Mark ``name`` as checked by the user (position and confidence unchanged)."""
        self.set_state(name, replace(self.state(name), status=LandmarkStatus.CONFIRMED))

    def confirm_all(self) -> list[str]:
        """Confirm every landmark; returns the names whose status changed."""
        new = {n: replace(s, status=LandmarkStatus.CONFIRMED) for n, s in self._states.items()
               if s.status is not LandmarkStatus.CONFIRMED}
        self.update_states(new)
        return list(new)

    def set_state(self, name: str, state: LandmarkState) -> None:
        """Set one landmark's full state (adds the name when new)."""
        self.update_states({name: state})

    def update_states(self, states: Mapping[str, LandmarkState]) -> None:
        """Set several landmarks' states at once (new names are added); one signal per name, or ``""``."""
        for name, state in states.items():
            if not isinstance(state, LandmarkState):
                raise LandmarkEditError(f"landmark {name!r}: expected a LandmarkState, got {type(state).__name__}")
            self._check_point(name, state.point)
        changed = [n for n, s in states.items() if self._states.get(n) != s]
        if not changed:
            return
        added = [n for n in changed if n not in self._states]
        for name in changed:
            self._states[name] = states[name]
            self._face.set_landmark(name, states[name].point)
        if added:
            self._names = self._sorted(self._states)
        if added or len(changed) > 1:
            self.changed.emit("")
        else:
            self.changed.emit(changed[0])

    def restore(self, snapshot: Mapping[str, LandmarkState]) -> None:
        """Make the set exactly ``snapshot`` (names missing from it are removed; undo of a load)."""
        removed = [n for n in self._states if n not in snapshot]
        if not removed:
            self.update_states(snapshot)
            return
        with self.changed.blocked():
            for name in removed:
                del self._states[name]
                self._face.remove_landmark(name)
            self._names = self._sorted(self._states)
            self.update_states(snapshot)
        if self._selected in removed:
            self.select(None)
        self.changed.emit("")

    def apply_detection(self, points: Mapping[str, SurfacePoint],
                        confidence: Mapping[str, float | None] | None = None) -> list[str]:
        """A detector's result: replaces the ``auto`` landmarks (and adds new names) as ``auto``.

        Edited and confirmed landmarks are kept as they are. Returns the names that changed.
        """
        confidence = dict(confidence or {})
        new = {}
        for name, point in points.items():
            current = self._states.get(name)
            if current is not None and current.status is not LandmarkStatus.AUTO:
                continue
            new[name] = LandmarkState(point, LandmarkStatus.AUTO,
                                      _confidence(confidence.get(name), f"landmark {name!r}"))
        changed = [n for n, s in new.items() if self._states.get(n) != s]
        self.update_states(new)
        return changed

    # ------------------------------------------------------------ symmetry
    def mirror_partner(self, name: str) -> str | None:
        """The MPEG-4 left/right partner of ``name`` (None on the midline or for other names)."""
        return self._pairs.get(name)

    def mid_sagittal_plane(self, *, exclude: Iterable[str] = ()) -> tuple[np.ndarray, np.ndarray]:
        """(origin (3,), unit normal (3,)) of the face's symmetry plane, mm, neutral face.

        The normal points to the face's left (+x side). See the module docstring for the fit;
        ``exclude`` names (and their partners) are left out unless that leaves no pair.
        """
        excluded = set(exclude)
        excluded |= {self._pairs[n] for n in excluded if n in self._pairs}
        lefts = sorted(n for n in _left_names() if n in self._states and self._pairs[n] in self._states)
        use = [n for n in lefts if n not in excluded] or lefts
        if not use:
            lo, hi = self._face.bounds
            return (lo + hi) / 2.0, np.array([1.0, 0.0, 0.0])
        left = self._face.landmark_positions(use)
        right = self._face.landmark_positions([self._pairs[n] for n in use])
        diff = left - right
        # Main direction of the left - right vectors (sign-free, longer pairs weigh more).
        _, vecs = np.linalg.eigh(diff.T @ diff)
        normal = vecs[:, -1]
        if normal @ diff.sum(axis=0) < 0:
            normal = -normal
        return ((left + right) / 2.0).mean(axis=0), normal

    def mirror_position(self, xyz, *, exclude: Iterable[str] = ()) -> np.ndarray:
        """(3,) reflection of ``xyz`` (3,) mm across :meth:`mid_sagittal_plane`."""
        origin, normal = self.mid_sagittal_plane(exclude=exclude)
        p = np.asarray(xyz, dtype=np.float64).reshape(3)
        return p - 2.0 * ((p - origin) @ normal) * normal

    def suggest_mirror(self, name: str) -> SurfacePoint:
        """Where the mirror image of landmark ``name`` lies on the surface.

        This is the suggestion for ``mirror_partner(name)`` after ``name`` was moved: the position
        of ``name`` reflected across the mid-sagittal plane (fitted without this pair) and
        projected onto the closest point of the neutral surface.
        """
        reflected = self.mirror_position(self.position(name), exclude=[name])
        _, tri, bary = self._face.closest_surface_points(reflected[None])
        return SurfacePoint(int(tri[0]), tuple(bary[0]))

    # ------------------------------------------------------------ files
    def save_json(self, path) -> None:
        """Write the set as mimica-landmarks JSON with status and confidence (atomically)."""
        path = Path(path)
        positions = self.positions()
        entries = []
        for name, xyz in zip(self._names, positions):
            s = self._states[name]
            entries.append({
                "name": name, "xyz": [float(c) for c in xyz], "triangle": s.point.triangle,
                "barycentric": list(s.point.barycentric), "status": s.status.value, "confidence": s.confidence,
            })
        document = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "units": "mm", "landmarks": entries}
        text = (json.dumps(document, indent=2) + "\n").encode("utf-8")
        write_reporting_errors(path, lambda: write_atomic(path, text), LandmarkFileError)

    def read_json(self, path, *, notes: list[str] | None = None) -> dict[str, LandmarkState]:
        """The states stored in a landmark JSON file for this face (the model is not changed).

        Raises :class:`LandmarkFileError` with a user-facing message.
        """
        path = Path(path)
        points = load_landmarks(path, self._face, notes=notes)
        # load_landmarks validated the file; read the editing keys it does not know.
        extra = {}
        with reading(LandmarkFileError, f"'{path.name}'", "landmark"):
            document = parse_json(read_landmark_text(path), f"'{path.name}'", LandmarkFileError, "landmark")
            for entry in document["landmarks"]:
                extra[entry["name"]] = entry
        out = {}
        for name, point in points.items():
            entry = extra.get(name, {})
            where = f"'{path.name}': landmark '{name}'"
            try:
                status = _status(entry.get("status") or LandmarkStatus.AUTO.value, where)
                conf = _confidence(entry.get("confidence"), where)
            except LandmarkEditError as exc:
                raise LandmarkFileError(str(exc) + ".") from None
            out[name] = LandmarkState(point, status, conf)
        return out

    def load_json(self, path, *, notes: list[str] | None = None) -> list[str]:
        """Read a JSON file and apply it (names in the file replace or are added). Returns the names."""
        states = self.read_json(path, notes=notes)
        self.update_states(states)
        return list(states)

    def save_csv(self, path) -> None:
        """Write ``name,x,y,z,status,confidence`` rows (x/y/z in mm on the neutral face, atomically)."""
        path = Path(path)
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(CSV_COLUMNS)
        for name, xyz in zip(self._names, self.positions()):
            s = self._states[name]
            conf = "" if s.confidence is None else repr(float(s.confidence))
            writer.writerow([name, *(f"{c:.6f}" for c in xyz), s.status.value, conf])
        data = buffer.getvalue().encode("utf-8")
        write_reporting_errors(path, lambda: write_atomic(path, data), LandmarkFileError)

    def read_csv(self, path, *, notes: list[str] | None = None) -> dict[str, LandmarkState]:
        """The states in a landmark CSV file, placed on this face (the model is not changed).

        Raises :class:`LandmarkFileError`; problems in a row name its line number.
        """
        path = Path(path)
        with reading(LandmarkFileError, f"'{path.name}'", "landmark CSV"):
            return self._read_csv(path, notes)

    def _read_csv(self, path: Path, notes: list[str] | None) -> dict[str, LandmarkState]:
        lines = text_lines(path, "landmark", LandmarkFileError,
                           f"A landmark CSV file is text with the header '{','.join(CSV_COLUMNS)}'.")
        try:
            names, xyz, statuses, confs = self._csv_rows(path.name, lines)
        except NotUtf8:
            raise LandmarkFileError(f"'{path.name}' is not a text (UTF-8) file.") from None
        target = np.array(xyz, dtype=np.float64)
        closest, tri, bary = self._face.closest_surface_points(target)
        distance = np.linalg.norm(closest - target, axis=1)
        if notes is not None:
            notes.extend(
                f"Landmark '{n}' was {d:.1f} mm off the surface; it was placed at the closest surface point."
                for n, d in zip(names, distance) if d > POSITION_MISMATCH_MM)
        return {n: LandmarkState(SurfacePoint(int(t), tuple(b)), s, c)
                for n, t, b, s, c in zip(names, tri, bary, statuses, confs)}

    @staticmethod
    def _csv_rows(file_name: str, lines) -> tuple[list[str], list[list[float]], list, list]:
        """(names, xyz, statuses, confidences) of a landmark CSV file's rows, read and checked one line
        at a time (a problem names its line; at most MAX_LANDMARKS rows are held)."""
        header_line = None
        names, xyz, statuses, confs, first_line = [], [], [], [], {}
        for lineno, line in enumerate(lines, start=1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            try:
                fields = next(csv.reader([line]))
            except csv.Error as exc:
                raise LandmarkFileError(f"'{file_name}' line {lineno}: {exc}.") from None
            if header_line is None:
                header = [f.strip().lower() for f in fields]
                if tuple(header) != CSV_COLUMNS:
                    raise LandmarkFileError(
                        f"'{file_name}' line {lineno}: expected the header '{','.join(CSV_COLUMNS)}', "
                        f"found '{line.strip()}'. Is this a Mimica landmark CSV file?")
                header_line = lineno
                continue
            if len(names) >= MAX_LANDMARKS:
                raise LandmarkFileError(f"'{file_name}' line {lineno}: more than {MAX_LANDMARKS} landmarks; a "
                                        f"landmark file holds at most {MAX_LANDMARKS} (the densest template has 80).")
            where = f"'{file_name}' line {lineno}"
            if len(fields) != len(CSV_COLUMNS):
                raise LandmarkFileError(
                    f"{where}: expected {len(CSV_COLUMNS)} values ({','.join(CSV_COLUMNS)}), found {len(fields)}.")
            name = fields[0].strip()
            if not name:
                raise LandmarkFileError(f"{where}: the landmark has no name.")
            if len(name) > MAX_NAME_CHARS:
                raise LandmarkFileError(f"{where}: the name has {len(name)} characters; names have at most "
                                        f"{MAX_NAME_CHARS}.")
            if name in first_line:
                raise LandmarkFileError(
                    f"{where}: landmark '{name}' appears twice (first on line {first_line[name]}).")
            first_line[name] = lineno
            coords = []
            for axis, value in zip("xyz", fields[1:4]):
                try:
                    c = float(value)
                except ValueError:
                    raise LandmarkFileError(f"{where}: {axis} is not a number ({value.strip()!r}).") from None
                if not math.isfinite(c):
                    raise LandmarkFileError(f"{where}: {axis} must be a finite number, got {value.strip()!r}.")
                coords.append(c)
            try:
                status = _status(fields[4].strip() or LandmarkStatus.AUTO.value, where)
                conf = _confidence(fields[5].strip() or None, where)
            except LandmarkEditError as exc:
                raise LandmarkFileError(str(exc) + ".") from None
            names.append(name)
            xyz.append(coords)
            statuses.append(status)
            confs.append(conf)
        if header_line is None:
            raise LandmarkFileError(f"'{file_name}' is empty: expected the header '{','.join(CSV_COLUMNS)}'.")
        if not names:
            raise LandmarkFileError(f"'{file_name}' has a header but no landmarks.")
        return names, xyz, statuses, confs

    def load_csv(self, path, *, notes: list[str] | None = None) -> list[str]:
        """Read a CSV file and apply it (names in the file replace or are added). Returns the names."""
        states = self.read_csv(path, notes=notes)
        self.update_states(states)
        return list(states)

    def read_file(self, path, *, notes: list[str] | None = None) -> dict[str, LandmarkState]:
        """:meth:`read_csv` for ``.csv`` files, :meth:`read_json` otherwise."""
        if Path(path).suffix.lower() == ".csv":
            return self.read_csv(path, notes=notes)
        return self.read_json(path, notes=notes)

    def save_file(self, path) -> None:
        """:meth:`save_csv` for ``.csv`` files, :meth:`save_json` otherwise."""
        if Path(path).suffix.lower() == ".csv":
            self.save_csv(path)
        else:
            self.save_json(path)

    # ------------------------------------------------------------ helpers
    def _check(self, name) -> None:
        if name not in self._states:
            raise LandmarkEditError(f"there is no landmark named {name!r} on this face")

    def _check_point(self, name: str, point) -> None:
        if not isinstance(point, SurfacePoint):
            raise LandmarkEditError(f"landmark {name!r} must be a SurfacePoint, got {type(point).__name__}")
        if not 0 <= point.triangle < self._face.n_triangles:
            raise LandmarkEditError(
                f"landmark {name!r}: triangle {point.triangle} does not exist "
                f"(the face has {self._face.n_triangles} triangles)")

    @staticmethod
    def _sorted(states: Mapping[str, LandmarkState]) -> list[str]:
        order = list(states)
        return sorted(order, key=lambda n: fp_sort_key(n, order.index(n)))
