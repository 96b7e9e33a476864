"""Mimica project files (``.mimica``): the face, its landmarks, rig settings, timeline, speech and view.

A project is human-readable JSON::

    {"format": "mimica-project", "version": 2, "generator": "Mimica 0.1.0",
     "face": {"builtin": "default_face"}                       # the built-in face: nothing else stored
          or {"path": "anna.face.ply", "absolute": "/home/u/anim/anna.face.ply", "sha256": "…"},
     "landmarks": [{"name": "2.1", "triangle": 812, "barycentric": [0.2, 0.3, 0.5], "xyz": [x, y, z]}, …],
     "rig": {"values": {"fap:3": 120.0, "expression:joy": 0.5, "muscle:risorius:left": 4.0}},
                                                               # parameters away from their defaults
     "timeline": {"duration": 10.0, "fps": 30, "tracks": [{"key": "fap:3", "keys": [[0.0, 0.0, "smooth"], …]}]},
     "speech": [{"text": "Olá", "lang": "pt-br", "start_s": 1.0, "rate_wpm": 175}],
     "view": {…}}                                              # opaque to core: camera, display mode, overlays

Choices:

- **The face is referenced, never copied into the JSON.** The built-in default face is stored as
  ``{"builtin": "default_face"}``; any other face is a file next to (or below) the project, stored
  by a path relative to the project (kept working when the folder moves), the absolute path as a
  fallback (when only the project file moved) and its SHA-256, so a changed file is detected and
  reported on opening. A face that exists only in memory (generated, edited) is written next to the
  project as ``<project>.face.ply`` by :func:`embed_face` (binary PLY keeps vertex order, doubles,
  uv, and the texture as ``<project>.face.png``), then referenced like any file.
- Landmarks are stored as surface points (triangle + barycentric) plus their position; when the
  face file changed since saving (hash differs) or a triangle no longer exists, landmarks are
  placed at the surface point closest to their saved position and a note says so.
- Floats are written with Python's shortest round-trip repr, so reopening restores every FAP value,
  key time and value bit for bit. NaN/Infinity are refused on save and on load.
- Reading never executes anything (plain JSON; no pickle). Every problem raises
  :class:`ProjectError` (a ValueError) naming the file and the field, e.g.
  ``timeline.tracks[2].keys[5][1]``; a file from a newer Mimica raises :class:`ProjectVersionError`.
- Saving is atomic (temporary file + rename). Autosave writes ``<project>.mimica.autosave`` next to a
  saved project (so relative face paths stay valid) or ``<state dir>/<id>.mimica.autosave`` for an
  untitled one (``$XDG_STATE_HOME/mimica/autosave``, default ``~/.local/state/mimica/autosave``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from core.face import Face, SurfacePoint
from core.formats.atomic_files import write_atomic, write_reporting_errors
from core.formats.mesh_io import save_face
from core.formats.text_files import MAX_BYTES, parse_json, read_file_bytes, reading
from core.parameters import ParameterError, check_value, key_of, sort_key
from core.timeline import Key, Timeline, TimelineError, Track, canonical_key

FORMAT_NAME = "mimica-project"
FORMAT_VERSION = 2  # 2: the rig's values by parameter key; 1 (still read): FAPs, presets and muscles apart
SUFFIX = ".mimica"
AUTOSAVE_SUFFIX = ".autosave"
BUILTIN_FACES = ("default_face",)
MAX_FILE_BYTES = MAX_BYTES["project"]
GENERATOR = "Mimica 0.1.0"


class ProjectError(ValueError):
    """A project file cannot be read or written; ``str(error)`` is a message for the user."""


class ProjectVersionError(ProjectError):
    """The file was written by a newer Mimica (a newer format version)."""


# ====================================================================== data
@dataclass(frozen=True)
class FaceRef:
    """Where the project's face comes from: a built-in face, or a file (absolute path in memory)."""

    builtin: str | None = None
    path: Path | None = None
    sha256: str | None = None

    @classmethod
    def default_face(cls) -> "FaceRef":
        return cls(builtin="default_face")

    @classmethod
    def for_file(cls, path: str | os.PathLike) -> "FaceRef":
        """Reference a face file (hashed now, to detect later changes)."""
        path = Path(path).resolve()
        return cls(path=path, sha256=file_sha256(path))


@dataclass
class RigSettings:
    """The rig's own parameter values (what the sliders show), not the animation: {canonical key:
    value} for every parameter away from its default (``core.parameters``), any layer's included."""

    values: dict[str, float] = field(default_factory=dict)

    @classmethod
    def from_rig(cls, rig) -> "RigSettings":
        """Capture a ``FaceRig``'s values (every layer it has)."""
        return cls(rig.values(nondefault=True))

    def apply(self, rig, *, slow_layers: bool = True) -> dict[str, float]:
        """Put these values on a ``FaceRig`` (everything else back to its default).

        Layers the rig lacks are built first (``rig.ensure_layers``); with ``slow_layers=False`` the
        slow ones (the muscle model, seconds) are not, and their values are returned, not applied.
        """
        rig.ensure_layers(self.values, slow=slow_layers)
        owned = set(rig.parameters())
        pending = {k: v for k, v in self.values.items() if k not in owned}
        with rig.batch():
            rig.reset()
            rig.set_values({k: v for k, v in self.values.items() if k in owned})
        return pending


@dataclass(frozen=True)
class SpeechClip:
    """A lip-sync clip: the text spoken from ``start_s`` (its audio is regenerated from this)."""

    text: str
    lang: str
    start_s: float
    rate_wpm: int = 175


@dataclass
class Project:
    """Everything a .mimica file holds. ``landmarks`` None = keep the face's own landmarks."""

    face: FaceRef = field(default_factory=FaceRef.default_face)
    landmarks: dict[str, SurfacePoint] | None = None
    landmark_positions: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    #: name -> (status "auto" | "edited" | "confirmed", confidence or None): the landmark editor's
    #: state, so a scan session's checked landmarks come back as checked.
    landmark_status: dict[str, tuple[str, float | None]] = field(default_factory=dict)
    rig: RigSettings = field(default_factory=RigSettings)
    timeline: Timeline = field(default_factory=Timeline)
    speech: list[SpeechClip] = field(default_factory=list)
    view: dict = field(default_factory=dict)
    #: What reading the file found worth telling the user (e.g. a face outside the project's folder);
    #: :func:`open_face` passes them on with its own.
    notes: list[str] = field(default_factory=list, compare=False)

    @classmethod
    def from_state(cls, face: Face, face_ref: FaceRef, rig=None, timeline: Timeline | None = None, *,
                   speech: list[SpeechClip] | None = None, view: dict | None = None,
                   landmark_status: dict | None = None) -> "Project":
        """A project from the app's live objects (the face's landmarks and their positions included;
        ``landmark_status``: name -> (status, confidence) from the landmark editor)."""
        names = face.landmark_names
        positions = face.landmark_positions(names) if names else np.zeros((0, 3))
        return cls(
            face=face_ref,
            landmarks=dict(face.landmarks),
            landmark_positions={n: tuple(float(c) for c in p) for n, p in zip(names, positions)},
            landmark_status={n: (str(s), None if c is None else float(c))
                             for n, (s, c) in (landmark_status or {}).items() if n in face.landmarks},
            rig=RigSettings.from_rig(rig) if rig is not None else RigSettings(),
            timeline=timeline if timeline is not None else Timeline(),
            speech=list(speech or []),
            view=dict(view or {}),
        )


# ====================================================================== writing
def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


EMBEDDED_FACE_SUFFIX = ".face.ply"


def is_embedded_face(path: str | os.PathLike) -> bool:
    """True for a project's (or an autosave's) own copy of its face: its file name is the project's,
    not the face's (show ``face.metadata.name``, which the PLY keeps)."""
    return Path(path).name.lower().endswith(EMBEDDED_FACE_SUFFIX)


def embed_face(face: Face, project_path: str | os.PathLike) -> FaceRef:
    """Write ``face`` next to the project as ``<project>.face.ply`` and return its reference."""
    project_path = Path(project_path)
    target = project_path.with_name(project_path.name.removesuffix(SUFFIX) + EMBEDDED_FACE_SUFFIX)
    save_face(face, target)
    return FaceRef.for_file(target)


def to_document(project: Project, base_dir: str | os.PathLike | None = None) -> dict:
    """The JSON document of ``project``; face paths relative to ``base_dir`` (absolute if None)."""
    doc: dict[str, Any] = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "generator": GENERATOR}
    ref = project.face
    if ref.builtin is not None:
        if ref.builtin not in BUILTIN_FACES:
            raise ProjectError(f"unknown built-in face {ref.builtin!r}; built-in faces are {', '.join(BUILTIN_FACES)}")
        doc["face"] = {"builtin": ref.builtin}
    elif ref.path is not None:
        absolute = Path(ref.path).resolve()
        entry = {"path": _relative(absolute, base_dir), "absolute": str(absolute)}
        if ref.sha256:
            entry["sha256"] = ref.sha256
        doc["face"] = entry
    else:
        raise ProjectError("the project's face has neither a built-in name nor a file; save the face first "
                           "(core.formats.project.embed_face)")
    if project.landmarks is None:
        doc["landmarks"] = None
    else:
        doc["landmarks"] = [
            {"name": name, "triangle": int(p.triangle), "barycentric": [float(b) for b in p.barycentric],
             **({"xyz": [float(c) for c in project.landmark_positions[name]]}
                if name in project.landmark_positions else {}),
             **({"status": project.landmark_status[name][0], "confidence": project.landmark_status[name][1]}
                if name in project.landmark_status else {})}
            for name, p in project.landmarks.items()
        ]
    doc["rig"] = {"values": {k: float(v) for k, v in sorted(project.rig.values.items(), key=lambda e: sort_key(e[0]))}}
    tl = project.timeline
    doc["timeline"] = {
        "duration": tl.duration, "fps": tl.fps,
        "tracks": [{"key": key, "keys": [[k.time, k.value, k.interpolation] for k in track.keys]}
                   for key, track in tl.tracks.items()],
    }
    doc["speech"] = [{"text": c.text, "lang": c.lang, "start_s": float(c.start_s), "rate_wpm": int(c.rate_wpm)}
                     for c in project.speech]
    doc["view"] = _plain(project.view, "view")
    return doc


def _relative(path: Path, base_dir) -> str:
    if base_dir is None:
        return path.as_posix()
    try:
        return Path(os.path.relpath(path, Path(base_dir).resolve())).as_posix()
    except ValueError:  # another drive (Windows)
        return path.as_posix()


def _plain(value, where: str):
    """``value`` as plain JSON types (numpy scalars/arrays converted); ProjectError names what is not."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise ProjectError(f"{where}: keys must be strings, got {k!r}")
            out[k] = _plain(v, f"{where}.{k}")
        return out
    if isinstance(value, (list, tuple)):
        return [_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist(), where)
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        raise ProjectError(f"{where}: {value} cannot be saved (numbers must be finite)")
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    raise ProjectError(f"{where}: values of type {type(value).__name__} cannot be saved in a project (use numbers, text, "
                       "lists and dicts)")


def save_project(path: str | os.PathLike, project: Project) -> Path:
    """Write ``project`` to ``path`` (atomically); ProjectError with a user message on failure."""
    path = Path(path)
    text = json.dumps(to_document(project, path.parent), indent=1, ensure_ascii=False, allow_nan=False)
    data = (text + "\n").encode("utf-8")
    write_reporting_errors(path, lambda: write_atomic(path, data), ProjectError)
    return path


# ====================================================================== reading
class _Field:
    """A value in the document with its path, for messages like ``timeline.tracks[2].keys[0]``."""

    def __init__(self, value, path: str, file: str):
        self.value, self.path, self.file = value, path, file

    def fail(self, what: str) -> ProjectError:
        return ProjectError(f"'{self.file}': {self.path} {what}")

    def __getitem__(self, key) -> "_Field":
        if isinstance(key, int):
            items = self.list()
            if not -len(items) <= key < len(items):
                raise self.fail(f"has {len(items)} items, item {key} is missing")
            return _Field(items[key], f"{self.path}[{key}]", self.file)
        if key not in self.dict():
            raise ProjectError(f"'{self.file}': field {self.path + '.' if self.path else ''}{key} is missing")
        return _Field(self.value[key], f"{self.path}.{key}" if self.path else key, self.file)

    def get(self, key, default=None) -> "_Field":
        if key not in self.dict():
            return _Field(default, f"{self.path}.{key}" if self.path else key, self.file)
        return self[key]

    def of(self, kind, what: str):
        if not isinstance(self.value, kind) or (kind in (int, (int, float)) and isinstance(self.value, bool)):
            raise self.fail(f"must be {what}, got {_describe(self.value)}")
        return self.value

    def dict(self) -> dict:
        return self.of(dict, "an object {…}")

    def list(self) -> list:
        return self.of(list, "a list […]")

    def str(self) -> str:
        return self.of(str, "text")

    def number(self) -> float:
        v = float(self.of((int, float), "a number"))
        if not math.isfinite(v):
            raise self.fail(f"must be a finite number, got {v}")
        return v

    def int(self) -> int:
        return self.of(int, "a whole number")

    def items(self):
        return [(k, _Field(v, f"{self.path}.{k}", self.file)) for k, v in self.dict().items()]

    def elements(self):
        return [_Field(v, f"{self.path}[{i}]", self.file) for i, v in enumerate(self.list())]


def _describe(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"{str(value).lower()}"
    if isinstance(value, (int, float)):
        return f"the number {value!r}"
    if isinstance(value, str):
        return f"the text {value[:40]!r}"
    return "a list" if isinstance(value, list) else "an object"


def read_document(path: str | os.PathLike) -> dict:
    """The parsed JSON of a project file, with the header checked (format and version).

    The file must be a regular file (never a pipe or device) of at most ``MAX_FILE_BYTES``; JSON
    nested deeper than ``text_files.MAX_JSON_DEPTH``, NaN/Infinity and numbers too large for a float
    are refused (ProjectError naming the file)."""
    path = Path(path)
    data = read_file_bytes(path, "project", ProjectError, max_bytes=MAX_FILE_BYTES, what="a Mimica project")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise ProjectError(f"'{path.name}' is not a Mimica project (it is not UTF-8 text)") from None
    document = parse_json(text, f"'{path.name}'", ProjectError, "project",
                          hint="The file is damaged; open its autosave or a backup.")
    if not isinstance(document, dict) or document.get("format") != FORMAT_NAME:
        raise ProjectError(f"'{path.name}' is not a Mimica project (no \"format\": \"{FORMAT_NAME}\")")
    version = document.get("version")
    if isinstance(version, bool) or not isinstance(version, int):
        raise ProjectError(f"'{path.name}': field version must be a whole number, got {_describe(version)}")
    if version > FORMAT_VERSION:
        raise ProjectVersionError(f"'{path.name}' was made by a newer Mimica (format {version}); this Mimica reads "
                                  f"up to {FORMAT_VERSION} — update Mimica")
    if version < 1:
        raise ProjectError(f"'{path.name}': unknown project format version {version}")
    return document


#: More landmarks than this in a project are refused (the densest template has 80).
MAX_LANDMARKS = 10_000
#: More speech clips than this are refused.
MAX_SPEECH_CLIPS = 1_000


def load_project(path: str | os.PathLike) -> Project:
    """Read a .mimica file (relative face paths resolve against its folder). Raises ProjectError.

    Every field is type- and range-checked here (parameters through ``core.parameters``, the
    timeline through ``core.timeline``, speech clips through ``core.lipsync.check_clip_field``);
    any other failure of a damaged file is a ProjectError too, never another exception."""
    path = Path(path)
    with reading(ProjectError, f"'{path.name}'", "project"):
        doc = _Field(read_document(path), "", path.name)
        base = path.resolve().parent
        notes: list[str] = []
        face = _read_face(doc["face"], base, notes)
        landmarks, positions, status = _read_landmarks(doc.get("landmarks"))
        rig = _read_rig(doc["rig"], doc["version"].int())
        timeline = _read_timeline(doc["timeline"])
        clips = doc.get("speech", [])
        if len(clips.list()) > MAX_SPEECH_CLIPS:
            raise clips.fail(f"holds {len(clips.value)} clips; a project holds at most {MAX_SPEECH_CLIPS}")
        speech = [_read_clip(c, timeline.duration) for c in clips.elements()]
        view = doc.get("view", {}).dict()
        return Project(face=face, landmarks=landmarks, landmark_positions=positions, landmark_status=status, rig=rig,
                       timeline=timeline, speech=speech, view=view, notes=notes)


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.resolve().relative_to(folder.resolve())
    except (ValueError, OSError, RuntimeError):
        return False
    return True


def face_outside_folder(project: "Project", project_path: Path) -> Path | None:
    """The project's face file when it lies outside the folder of ``project_path`` (the window asks
    before opening such a project: a file written by someone else may point anywhere); else None."""
    path = project.face.path
    if path is None or _inside(Path(path), Path(project_path).parent):
        return None
    return Path(path)


def _read_face(f: _Field, base: Path, notes: list[str] | None = None) -> FaceRef:
    """The face reference; a face file outside the project's folder is used as written, with a note
    naming where it is (the project file, not the user, chose that place)."""
    entry = f.dict()
    if "builtin" in entry:
        name = f["builtin"].str()
        if name not in BUILTIN_FACES:
            raise f["builtin"].fail(f"names an unknown built-in face {name!r} (known: {', '.join(BUILTIN_FACES)})")
        return FaceRef(builtin=name)
    rel = f["path"].str()
    if not rel.strip() or "\0" in rel:
        raise f["path"].fail("must name the face file (a path relative to the project)")
    candidates = [base / rel]
    if "absolute" in entry:
        absolute = f["absolute"].str()
        if "\0" in absolute:
            raise f["absolute"].fail("is not a valid path")
        candidates.append(Path(absolute))
    sha = f["sha256"].str() if "sha256" in entry else None
    chosen = next((c for c in candidates if c.is_file()), candidates[0])
    resolved = chosen.resolve() if chosen.exists() else chosen
    if notes is not None and not _inside(resolved, base):
        notes.append(f"The project's face file is outside the project's folder: '{resolved}'. Check that it is "
                     "the face you expect; save the project next to its face to keep them together.")
    return FaceRef(path=resolved, sha256=sha)


LANDMARK_STATUSES = ("auto", "edited", "confirmed")


def _read_landmarks(f: _Field):
    if f.value is None:
        return None, {}, {}
    landmarks, positions, status = {}, {}, {}
    if len(f.list()) > MAX_LANDMARKS:
        raise f.fail(f"holds {len(f.value)} landmarks; a project holds at most {MAX_LANDMARKS}")
    for e in f.elements():
        name = e["name"].str()
        if name in landmarks:
            raise e["name"].fail(f"repeats the landmark {name!r}")
        tri = e["triangle"].int()
        bary = e["barycentric"]
        values = [b.number() for b in bary.elements()]
        if len(values) != 3:
            raise bary.fail(f"must hold 3 numbers, got {len(values)}")
        try:
            landmarks[name] = SurfacePoint(tri, tuple(values))
        except ValueError as exc:
            raise bary.fail(str(exc)) from None
        if "xyz" in e.value:
            xyz = [c.number() for c in e["xyz"].elements()]
            if len(xyz) != 3:
                raise e["xyz"].fail(f"must hold 3 numbers, got {len(xyz)}")
            positions[name] = tuple(xyz)
        if "status" in e.value:
            state = e["status"].str()
            if state not in LANDMARK_STATUSES:
                raise e["status"].fail(f"must be one of {', '.join(LANDMARK_STATUSES)}, got {state!r}")
            confidence = e.get("confidence")
            status[name] = (state, None if confidence.value is None else confidence.number())
    return landmarks, positions, status


_RIG_FIELDS = {1: ("faps", "expressions", "visemes", "muscles", "jaw"), 2: ("values",)}


def _read_rig(f: _Field, version: int) -> RigSettings:
    allowed = _RIG_FIELDS[min(version, 2)]
    for name in f.dict():
        if name not in allowed:
            raise f.fail(f"has a field {name!r} that format {version} does not have (allowed: "
                         f"{', '.join(allowed)}; format 2 keeps every parameter in rig.values, e.g. "
                         "\"muscle:risorius:left\": 4.0)")
    if version == 1:
        return RigSettings(_read_rig_v1(f))
    values = {}
    for k, v in f.get("values", {}).items():
        try:
            key = key_of(k)
            values[key] = check_value(key, v.number())
        except ParameterError as exc:
            raise v.fail(str(exc)) from None
    return RigSettings(values)


def _read_rig_v1(f: _Field) -> dict[str, float]:
    """Format 1's rig: FAPs by number, preset lists, muscles as (name, side, force), the jaw."""
    values: dict[str, float] = {}

    def put(field_: _Field, spelling, value) -> None:
        try:
            key = key_of(spelling)
            # repeated entries add up; the total must be allowed too
            values[key] = check_value(key, values.get(key, 0.0) + check_value(key, value))
        except ParameterError as exc:
            raise field_.fail(str(exc)) from None

    for k, v in f.get("faps", {}).items():
        if not k.isdigit():
            raise v.fail("must be keyed by FAP number")
        put(v, int(k), v.number())
    for kind in ("expression", "viseme"):
        for e in f.get(kind + "s", []).elements():
            ident = e["id"].int()
            if ident:
                put(e["id"], f"{kind}:{ident}", _intensity(e["intensity"]))
    for e in f.get("muscles", []).elements():
        side = e.get("side").value
        if side not in (None, "left", "right"):
            raise e["side"].fail(f"must be \"left\", \"right\" or null, got {_describe(side)}")
        put(e, (e["name"].str(), side), e["force"].number())
    jaw = f.get("jaw", 0.0).number()
    if jaw:
        put(f.get("jaw"), "jaw", jaw)
    return values


def _intensity(f: _Field) -> float:
    v = f.number()
    if not 0.0 <= v <= 1.0:
        raise f.fail(f"must be between 0 and 1, got {v:g}")
    return v


def _read_timeline(f: _Field) -> Timeline:
    duration, fps = f["duration"].number(), f["fps"].int()
    try:
        timeline = Timeline(duration, fps)
    except TimelineError as exc:
        raise f.fail(f"is invalid: {exc}") from None
    tracks = {}
    for t in f["tracks"].elements():
        key = t["key"].str()
        try:
            ck = canonical_key(key)
        except TimelineError as exc:
            raise t["key"].fail(f"is invalid: {exc}") from None
        if ck in tracks:
            raise t["key"].fail(f"repeats the track {ck}")
        keys = []
        for k in t["keys"].elements():
            row = k.list()
            if len(row) != 3:
                raise k.fail(f"must be [time, value, interpolation], got {len(row)} items")
            keys.append(Key(k[0].number(), k[1].number(), k[2].str()))
        try:
            tracks[ck] = Track(ck, keys)
        except TimelineError as exc:
            raise t["keys"].fail(f"are invalid: {exc}") from None
    try:
        return Timeline(duration, fps, tracks)
    except TimelineError as exc:
        raise f["tracks"].fail(f"do not fit the timeline: {exc}") from None


def _read_clip(f: _Field, duration_s: float) -> SpeechClip:
    from core.lipsync import check_clip_field

    values = {}
    for name, default in (("text", None), ("lang", None), ("start_s", None), ("rate_wpm", 175)):
        field_ = f[name] if default is None else f.get(name, default)
        try:
            values[name] = check_clip_field(name, field_.value, duration_s=duration_s)
        except ValueError as exc:
            raise field_.fail(str(exc)) from None
    return SpeechClip(values["text"], values["lang"], float(values["start_s"]), int(values["rate_wpm"]))


# ====================================================================== the face
def open_face(project: Project, notes: list[str] | None = None) -> Face:
    """Load the project's face and put the project's landmarks on it.

    notes : receives a sentence for each thing the user should know (face file changed, landmark
    relocated). Raises ProjectError when the face file is missing or unreadable.
    """
    from core.formats.mesh_io import MeshLoadError, load_face

    notes = notes if notes is not None else []
    notes.extend(n for n in project.notes if n not in notes)
    ref = project.face
    changed = False
    if ref.builtin is not None:
        from core.default_face import load_default_face

        face = load_default_face()
    else:
        path = Path(ref.path)
        if not path.is_file():
            raise ProjectError(f"the project's face file '{path}' is missing; put it back next to the project "
                               "or open the face and save the project again")
        if ref.sha256 and file_sha256(path) != ref.sha256:
            changed = True
            notes.append(f"The face file '{path.name}' changed since the project was saved; landmarks were placed "
                         "at the surface points closest to their saved positions.")
        from core.registration.correspondence import canonical_template_of

        try:
            face = load_face(path, keep_topology=canonical_template_of)   # a canonical face stays whole
        except MeshLoadError as exc:
            raise ProjectError(str(exc)) from None
    if project.landmarks is not None:
        with reading(ProjectError, "the project's landmarks", "landmark"):
            _place_landmarks(project, face, changed, notes)
    return face


def _place_landmarks(project: Project, face: Face, changed: bool, notes: list[str]) -> None:
    """Put the project's landmarks on ``face`` (relocated by their saved positions when needed)."""
    for name in list(face.landmark_names):
        face.remove_landmark(name)
    relocate = {}
    for name, point in project.landmarks.items():
        ok = 0 <= point.triangle < face.n_triangles
        if (changed or not ok) and name in project.landmark_positions:
            relocate[name] = project.landmark_positions[name]
        elif ok:
            face.set_landmark(name, point)
        else:
            notes.append(f"Landmark '{name}' was dropped: its triangle {point.triangle} does not exist on "
                         "this face and the project holds no position for it.")
    if relocate:
        _, tris, barys = face.closest_surface_points(np.array(list(relocate.values()), float))
        for name, tri, bary in zip(relocate, tris, barys):
            face.set_landmark(name, SurfacePoint(int(tri), tuple(float(b) for b in bary)))
        if not changed:
            notes.append(f"{len(relocate)} landmark(s) referred to triangles this face does not have and were "
                         "placed at the surface points closest to their saved positions.")


# ====================================================================== autosave
def default_state_dir() -> Path:
    base = os.environ.get("XDG_STATE_HOME") or os.path.join(os.path.expanduser("~"), ".local", "state")
    return Path(base) / "mimica" / "autosave"


def autosave_path(project_path: str | os.PathLike | None = None, *, untitled_id: str = "untitled",
                  state_dir: str | os.PathLike | None = None) -> Path:
    """``<project>.autosave`` beside a saved project, or ``<state dir>/<untitled_id>.mimica.autosave``."""
    if project_path is not None:
        p = Path(project_path)
        return p.with_name(p.name + AUTOSAVE_SUFFIX)
    if not untitled_id or any(c in untitled_id for c in "/\\\0") or untitled_id.startswith("."):
        raise ProjectError(f"bad autosave name {untitled_id!r}")
    return Path(state_dir or default_state_dir()) / f"{untitled_id}{SUFFIX}{AUTOSAVE_SUFFIX}"


def write_autosave(project: Project, project_path: str | os.PathLike | None = None, *,
                   untitled_id: str = "untitled", state_dir: str | os.PathLike | None = None) -> Path:
    """Write the autosave copy of ``project`` (atomically); returns its path."""
    target = autosave_path(project_path, untitled_id=untitled_id, state_dir=state_dir)
    target.parent.mkdir(parents=True, exist_ok=True)
    return save_project(target, project)


def find_autosave(project_path: str | os.PathLike | None = None, *, untitled_id: str = "untitled",
                  state_dir: str | os.PathLike | None = None) -> Path | None:
    """The autosave worth offering to recover: it exists and is newer than the project file (if any)."""
    target = autosave_path(project_path, untitled_id=untitled_id, state_dir=state_dir)
    if not target.is_file():
        return None
    if project_path is not None and Path(project_path).is_file():
        if target.stat().st_mtime_ns <= Path(project_path).stat().st_mtime_ns:
            return None
    return target


def untitled_autosaves(state_dir: str | os.PathLike | None = None) -> list[Path]:
    """Autosaves of untitled projects (newest first), e.g. to offer recovery at start-up."""
    folder = Path(state_dir or default_state_dir())
    if not folder.is_dir():
        return []
    found = list(folder.glob(f"*{SUFFIX}{AUTOSAVE_SUFFIX}"))
    return sorted(found, key=lambda p: p.stat().st_mtime_ns, reverse=True)


def discard_autosave(project_path: str | os.PathLike | None = None, *, untitled_id: str = "untitled",
                     state_dir: str | os.PathLike | None = None) -> None:
    """Delete the autosave after a clean save or close, with the face it embedded (a scan as derived
    in memory: ``<autosave>.face.ply`` and its texture); no error if there is none."""
    target = autosave_path(project_path, untitled_id=untitled_id, state_dir=state_dir)
    face = target.with_name(target.name + EMBEDDED_FACE_SUFFIX)
    for path in (target, face, face.with_suffix(".png")):
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


__all__ = [
    "FORMAT_NAME", "FORMAT_VERSION", "SUFFIX", "ProjectError", "ProjectVersionError", "FaceRef", "RigSettings",
    "SpeechClip", "Project", "embed_face", "is_embedded_face", "EMBEDDED_FACE_SUFFIX", "to_document", "save_project",
    "read_document", "load_project",
    "open_face", "face_outside_folder", "file_sha256", "autosave_path", "write_autosave", "find_autosave", "untitled_autosaves",
    "discard_autosave", "default_state_dir",
]
