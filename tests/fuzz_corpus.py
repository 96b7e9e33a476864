"""A corpus of hostile files for every reader Mimica has, and a runner that feeds them to the readers.

Nothing large is committed: every case is generated from a seed, starting from a valid file of its
format written by Mimica itself (a project, landmark JSON and CSV, a .fap, DPC, PPC and EPC files, a muscle
force file, OBJ/MTL, PLY, STL, glTF, a texture image) and then damaged: truncated, bytes flipped or
inserted, numbers swapped for hostile ones (1e30, nan, 10^400, 0, -5, 1e-7), JSON values replaced by
other types, nesting 100,000 deep, bloated lines, UTF-16/latin-1/binary noise, empty files, named
pipes and folders with the format's suffix. Command-line values (--fps, --size, --fap, --jaw,
--muscles, --people, --scale) are cases too.

Each case ends in one of:

* ``accepted``: the reader returned, and what it returned passes the format's invariants (timeline
  within 24 h, every parameter value inside its registry range, finite numbers, counts within the caps);
* ``refused``: the reader raised its format's error class with a message naming the file;
* ``failed``: any other exception (a traceback would reach the user), an accepted result that breaks
  an invariant (silent acceptance), a message without the file's name, or a case slower than
  ``CASE_SECONDS`` (a hang).

``python tests/fuzz_corpus.py --cases 3000 --seed 1`` runs a longer campaign and prints how many cases
ran and how many failed (``benchmarks/fuzz_readers.py`` runs it under a memory limit); the test
suite runs a few hundred cases (``tests/core/test_readers_fuzz.py``).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import random
import signal
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: Speech languages Mimica speaks (core.lipsync.espeak.VOICES).
LANGUAGES = ("en", "en-us", "en-gb", "pt-br")
#: A case slower than this (seconds) counts as a hang.
CASE_SECONDS = 10.0
#: A case that raises the process's peak memory by more than this (MB) counts as a blow-up.
CASE_MEMORY_MB = 1024.0

HOSTILE_NUMBERS = ["1e30", "-1e30", "1e300", "-1e300", "1e-7", "1e-300", "nan", "NaN", "inf", "-inf", "Infinity",
                   "0", "-0", "-5", "0.001", "1" + "0" * 400, "-" + "9" * 30, "99999999999999999999", "1e999",
                   "0x10", "1,5", "", "--1", "1e", "٣", "1_000"]
HOSTILE_JSON = [None, True, [], {}, "", "x" * 10_000, ["mm"], {"a": {"b": [1]}}, -1, 0, 1e308, -1e308, 10**30,
                1.5, "1e30", [[[[[]]]]], float("1e-300")]


@dataclass
class Case:
    kind: str
    name: str
    path: Path
    how: str


@dataclass
class Outcome:
    case: Case
    result: str          # accepted / refused / failed
    detail: str = ""
    seconds: float = 0.0


@dataclass
class Report:
    outcomes: list[Outcome] = field(default_factory=list)
    memory: tuple = (0.0, "", "")  # (MB the peak grew by, case, how) of the hungriest case

    @property
    def failed(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.result == "failed"]

    def counts(self) -> dict[str, int]:
        out = {"cases": len(self.outcomes)}
        for o in self.outcomes:
            out[o.result] = out.get(o.result, 0) + 1
        return out

    def summary(self) -> str:
        c = self.counts()
        kinds = sorted({o.case.kind for o in self.outcomes})
        per = ", ".join(f"{k} {sum(o.case.kind == k for o in self.outcomes)}" for k in kinds)
        slowest = max(self.outcomes, key=lambda o: o.seconds, default=None)
        text = (f"{c['cases']} cases ({per}): {c.get('accepted', 0)} accepted, {c.get('refused', 0)} refused "
                f"with a message, {c.get('failed', 0)} failed")
        if slowest is not None:
            text += f"; slowest {slowest.seconds:.2f} s ({slowest.case.name})"
        if self.memory[1]:
            text += f"; hungriest +{self.memory[0]:.0f} MB ({self.memory[1]}: {self.memory[2]})"
        for o in self.failed[:20]:
            text += f"\n  FAILED {o.case.name} [{o.case.how}]: {o.detail[:300]}"
        return text


# ====================================================================== valid seeds
def _grid_face():
    from core.face import Face, FaceMetadata, SurfacePoint

    rng = np.random.default_rng(0)
    nx, ny = 6, 5
    x, y = np.meshgrid(np.linspace(0.0, 1.0, nx), np.linspace(0.0, 1.0, ny))
    uv = np.column_stack([x.ravel(), y.ravel()])
    z = 0.1 * np.sin(3 * uv[:, 0]) * np.cos(2 * uv[:, 1])
    vertices = np.column_stack([uv - 0.5, z]) * 200.0
    index = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, 1:].ravel(), index[1:, :-1].ravel()
    triangles = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    texture = rng.integers(0, 256, size=(7, 9, 3), dtype=np.uint8)
    return Face(vertices, triangles, uv=uv, texture=texture,
                landmarks={"2.1": SurfacePoint(0, (0.2, 0.3, 0.5)), "9.3": SurfacePoint(7, (1 / 3, 1 / 3, 1 / 3))},
                metadata=FaceMetadata(name="grid"))


def _seeds(folder: Path) -> dict[str, list[Path]]:
    """Valid files of every format, written by Mimica into ``folder``."""
    from core.formats import project as P
    from core.formats.dpc_file import DpcSequence, write_dpc
    from core.formats.fap_file import FapSequence, write_fap
    from core.formats.landmarks_io import save_landmarks
    from core.formats.mesh_io import save_face
    from core.landmark_editing import LandmarkEditModel
    from core.layers.muscles import preset, save_force_set
    from core.timeline import Timeline

    folder.mkdir(parents=True, exist_ok=True)
    face = _grid_face()
    out: dict[str, list[Path]] = {}
    tl = Timeline(4.0, 25)
    tl.add_keys({"fap:3": [(0.0, 0.0), (1.0, 400.0, "linear")], "expression:joy": [(0.5, 0.5)],
                 "muscle:risorius:left": [(0.0, 0.0), (2.0, 30.0)], "jaw": [(1.0, 5.0)]})
    project = P.Project(rig=P.RigSettings({"fap:3": 120.0, "muscle:orbicularis_oris": 8.0, "jaw": 3.0}), timeline=tl,
                        speech=[P.SpeechClip("Hello there", "en", 0.5)], view={"mode": "textured"})
    P.save_project(folder / "seed.mimica", project)
    doc = json.loads((folder / "seed.mimica").read_text())
    doc1 = dict(doc, version=1, rig={"faps": {"3": 100}, "expressions": [{"id": 1, "intensity": 0.5}],
                                     "muscles": [{"name": "risorius", "side": "left", "force": 20}], "jaw": 2})
    (folder / "seed_v1.mimica").write_text(json.dumps(doc1))
    out["project"] = [folder / "seed.mimica", folder / "seed_v1.mimica"]
    save_landmarks(face, folder / "seed.landmarks.json")
    out["landmarks"] = [folder / "seed.landmarks.json"]
    LandmarkEditModel(face).save_csv(folder / "seed.csv")
    out["landmark_csv"] = [folder / "seed.csv"]
    values = np.full((6, 68), np.nan)
    values[:, 2] = np.linspace(0, 500, 6)
    values[:, 18] = 100.0
    viseme = np.full((6, 4), -1)
    viseme[2] = [3, 5, 40, 0]
    write_fap(folder / "seed.fap", FapSequence.from_values(values, 25, viseme=viseme))
    out["fap"] = [folder / "seed.fap"]
    from core.formats.dpc_file import control_points

    names = [p.name for p in control_points("mouth")]
    write_dpc(folder / "seed.dpc", DpcSequence(np.random.default_rng(1).normal(0, 2, (3, len(names), 3)),
                                               tuple(names), fps=25))
    (folder / "bare.dpc").write_text("2\n\n1 2 0\n1.1 0 0.5\n\n2 2 0\n0 -3 3\n")
    out["dpc"] = [folder / "seed.dpc", folder / "bare.dpc"]
    from core.formats.epc_file import EpcEmotion, write_epc
    from core.formats.ppc_file import ControlPointPositions, write_ppc

    points = control_points()
    write_ppc(folder / "seed.ppc", ControlPointPositions(tuple(p.name for p in points), tuple(p.fp for p in points),
                                                         np.random.default_rng(2).normal(0, 30, (len(points), 3))))
    (folder / "bare.ppc").write_text("".join(f"{i},5 {-i},25 2\n" for i in range(len(names))))
    out["ppc"] = [folder / "seed.ppc", folder / "bare.ppc"]
    write_epc(folder / "seed.epc", EpcEmotion("joy", np.random.default_rng(3).normal(0, 2, (2, len(names), 3)),
                                              tuple(names), aus=(6, 12)))
    out["epc"] = [folder / "seed.epc"]
    save_force_set(folder / "seed.forces.json", preset("half_smile"))
    out["force"] = [folder / "seed.forces.json"]
    save_face(face, folder / "seed.obj")
    save_face(face, folder / "seedply.ply")
    save_face(face, folder / "seed.glb")
    import trimesh

    trimesh.Trimesh(face.vertices, face.triangles, process=False).export(folder / "seed.stl")
    out["obj"], out["ply"], out["glb"], out["stl"] = [folder / "seed.obj"], [folder / "seedply.ply"], \
        [folder / "seed.glb"], [folder / "seed.stl"]
    out["mtl"] = [folder / "seed.mtl"]
    out["image"] = [folder / "seed.png"]
    return out


# ====================================================================== mutations
def _mutate_bytes(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    choice = rng.randrange(8)
    if not data:
        return b"\x00", "nul"
    i = rng.randrange(len(data))
    if choice == 0:
        return data[:i], f"truncated at {i}"
    if choice == 1:
        b = bytearray(data)
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b), "bytes flipped"
    if choice == 2:
        junk = bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
        return data[:i] + junk + data[i:], "bytes inserted"
    if choice == 3:
        j = min(len(data), i + rng.randint(1, 200))
        return data[:j] + data[i:j] * rng.randint(2, 50) + data[j:], "chunk repeated"
    if choice == 4:
        return data.decode("utf-8", "replace").encode("utf-16"), "utf-16"
    if choice == 5:
        return b"\xef\xbb\xbf" + data.replace(b"\n", b"\r\n"), "bom crlf"
    if choice == 6:
        return data[:i] + "é☃\u202e\ufeff".encode("utf-8") + b"\xff\xfe" + data[i:], "odd characters"
    return data[: len(data) // 2] + b"\x00" * 16 + data[len(data) // 2:], "nul bytes"


_NUMBER = None


def _mutate_numbers(text: str, rng: random.Random) -> tuple[str, str]:
    import re

    global _NUMBER
    _NUMBER = _NUMBER or re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
    spans = [m.span() for m in _NUMBER.finditer(text)]
    if not spans:
        return text + " 1e999", "number appended"
    picks = rng.sample(spans, min(len(spans), rng.randint(1, 3)))
    out = text
    for a, b in sorted(picks, reverse=True):
        out = out[:a] + rng.choice(HOSTILE_NUMBERS) + out[b:]
    return out, "hostile numbers"


def _mutate_lines(text: str, rng: random.Random) -> tuple[str, str]:
    lines = text.split("\n")
    choice = rng.randrange(5)
    i = rng.randrange(len(lines))
    if choice == 0:
        del lines[i]
        return "\n".join(lines), f"line {i + 1} deleted"
    if choice == 1:
        lines[i:i] = [lines[i]] * rng.randint(2, max(2, min(2000, 4_000_000 // (len(lines[i]) + 1))))
        return "\n".join(lines), f"line {i + 1} repeated"
    if choice == 2:
        lines[i] = lines[i] + " " + " ".join(rng.choice(HOSTILE_NUMBERS) or "x" for _ in range(rng.randint(1, 80)))
        return "\n".join(lines), f"line {i + 1} extended"
    if choice == 3:
        j = rng.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
        return "\n".join(lines), "lines swapped"
    tokens = lines[i].split()
    if tokens:
        tokens[rng.randrange(len(tokens))] = rng.choice(["#", "x", "1 2", "\t", "0 1", "-", "\x0b"])
    lines[i] = " ".join(tokens)
    return "\n".join(lines), f"token on line {i + 1} replaced"


def _json_paths(value, path=()):
    yield path
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _json_paths(v, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value[:20]):
            yield from _json_paths(v, path + (i,))


def _mutate_json(text: str, rng: random.Random) -> tuple[str, str]:
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError):
        return _mutate_numbers(text, rng)
    paths = list(_json_paths(doc))
    path = rng.choice(paths[1:] or paths)
    choice = rng.randrange(6)
    if choice == 0:
        new, how = rng.choice(HOSTILE_JSON), "value replaced"
    elif choice == 1:
        depth = rng.choice([100, 5000, 100_000])
        return _set_raw(doc, path, "[" * depth + "]" * depth), f"nested {depth} deep at {_p(path)}"
    elif choice == 2:
        return _set_raw(doc, path, rng.choice(["1" + "0" * 400, "1e400", "-1e400", "NaN", "Infinity", "9" * 5000])), \
            f"huge number at {_p(path)}"
    elif choice == 3:
        parent = _get(doc, path[:-1]) if path else doc
        if isinstance(parent, dict):
            parent[rng.choice(["muscles", "jaw", "extra", "values", "units", "forces", "__proto__"])] = \
                rng.choice(HOSTILE_JSON)
            return json.dumps(doc), f"key added at {_p(path[:-1])}"
        new, how = [rng.choice(HOSTILE_JSON)] * rng.randint(0, 3), "list"
    elif choice == 4:
        target = _get(doc, path)
        if isinstance(target, list) and target:
            size = len(json.dumps(target[0])) + 2  # bloat to at most ~4 MB: the corpus stays light
            target.extend([target[0]] * rng.randint(1, max(1, min(20000, 4_000_000 // size))))
            return json.dumps(doc), f"list at {_p(path)} bloated"
        new, how = rng.choice(HOSTILE_JSON), "value replaced"
    else:
        target = _get(doc, path)
        if isinstance(target, str):
            new, how = rng.choice(["../../../etc/passwd", "/dev/zero", "x" * 100_000, "\u0000", "fap:999",
                                   "muscle:bogus:left", "xx", ""]), "string replaced"
        else:
            new, how = rng.choice(HOSTILE_JSON), "value replaced"
    _put(doc, path, new)
    return json.dumps(doc, allow_nan=True), f"{how} at {_p(path)}"


def _p(path) -> str:
    return ".".join(map(str, path)) or "<root>"


def _get(doc, path):
    for p in path:
        doc = doc[p]
    return doc


def _put(doc, path, value):
    if not path:
        return
    _get(doc, path[:-1])[path[-1]] = value


def _set_raw(doc, path, raw: str) -> str:
    marker = "__FUZZ_MARKER__"
    if not path:
        return raw
    _put(doc, path, marker)
    return json.dumps(doc).replace(json.dumps(marker), raw, 1)


def _mutated(data: bytes, kind: str, rng: random.Random) -> tuple[bytes, str]:
    text_kinds = {"project", "landmarks", "force", "fap", "dpc", "ppc", "epc", "landmark_csv", "obj", "mtl"}
    json_kinds = {"project", "landmarks", "force"}
    roll = rng.random()
    if kind in json_kinds and roll < 0.55:
        text, how = _mutate_json(data.decode("utf-8", "replace"), rng)
        return text.encode("utf-8", "surrogatepass"), how
    if kind in text_kinds and roll < 0.8:
        text = data.decode("utf-8", "replace")
        text, how = (_mutate_numbers if rng.random() < 0.5 else _mutate_lines)(text, rng)
        return text.encode("utf-8", "surrogatepass"), how
    return _mutate_bytes(data, rng)


# ====================================================================== the corpus
SUFFIX = {"project": ".mimica", "landmarks": ".json", "landmark_csv": ".csv", "force": ".json", "fap": ".fap",
          "dpc": ".dpc", "ppc": ".ppc", "epc": ".epc", "obj": ".obj", "ply": ".ply", "glb": ".glb", "stl": ".stl", "mtl": ".obj", "image": ".png"}


def generate(folder: str | os.PathLike, cases: int, seed: int = 0) -> list[Case]:
    """Write ``cases`` hostile files (and the special ones: empty, pipe, folder) into ``folder``."""
    folder = Path(folder)
    seeds = _seeds(folder / "seeds")
    rng = random.Random(seed)
    out: list[Case] = []
    kinds = list(SUFFIX)
    specials = []
    for kind in kinds:
        specials.append((kind, "empty", b""))
    for k in range(cases):
        kind = kinds[k % len(kinds)]
        name = f"{k:05d}-{kind}{SUFFIX[kind]}"
        path = folder / name
        if kind == "mtl":  # the OBJ stays valid, its material file is the hostile one
            case_dir = folder / f"{k:05d}-mtl"
            case_dir.mkdir(exist_ok=True)
            obj = seeds["obj"][0].read_text()
            mtl, how = _mutate_mtl(rng, case_dir)
            (case_dir / "m.mtl").write_bytes(mtl)
            path = case_dir / "m.obj"
            path.write_text(obj.replace("mtllib seed.mtl", "mtllib m.mtl"))
            out.append(Case(kind, name, path, how))
            continue
        if kind == "image":
            data, how = _image_case(rng)
        else:
            source = rng.choice(seeds[kind])
            data = source.read_bytes()
            data, how = _mutated(data, kind, rng)
            for _ in range(rng.choice([0, 0, 1, 2])):  # several damages at once, sometimes
                data, more = _mutated(data, kind, rng)
                how += " + " + more
        path.write_bytes(data)
        out.append(Case(kind, name, path, how))
    for kind, how, data in specials:
        path = folder / f"special-{how}-{kind}{SUFFIX[kind]}"
        path.write_bytes(data)
        out.append(Case(kind, path.name, path, how))
    from core.formats.text_files import MAX_BYTES

    caps = {"project": "project", "landmarks": "landmark", "landmark_csv": "landmark", "force": "force",
            "fap": "FAP", "dpc": "DPC", "obj": "mesh", "ply": "mesh", "glb": "mesh", "stl": "mesh", "image": "image"}
    for kind, cap in caps.items():  # one byte over the cap, as a sparse file (no disk space used)
        path = folder / f"special-overcap-{kind}{SUFFIX[kind]}"
        with open(path, "wb") as fh:
            fh.truncate(MAX_BYTES[cap] + 1)
        out.append(Case(kind, path.name, path, f"{MAX_BYTES[cap] + 1} bytes"))
    for kind in kinds:
        directory = folder / f"special-folder-{kind}{SUFFIX[kind]}"
        directory.mkdir(exist_ok=True)
        out.append(Case(kind, directory.name, directory, "a folder"))
        if hasattr(os, "mkfifo"):
            fifo = folder / f"special-fifo-{kind}{SUFFIX[kind]}"
            if not fifo.exists():
                os.mkfifo(fifo)
            out.append(Case(kind, fifo.name, fifo, "a named pipe"))
        link = folder / f"special-loop-{kind}{SUFFIX[kind]}"
        if not link.is_symlink():
            os.symlink(link.name, link)
        out.append(Case(kind, link.name, link, "a symbolic link to itself"))
    return out


def _mutate_mtl(rng: random.Random, case_dir: Path) -> tuple[bytes, str]:
    choice = rng.randrange(5)
    if choice == 0:
        return b"newmtl face\nmap_Kd /etc/passwd\n", "map_Kd absolute outside"
    if choice == 1:
        return b"newmtl face\nmap_Kd ../../../../../../etc/hostname\n", "map_Kd relative outside"
    if choice == 2:
        if hasattr(os, "mkfifo"):
            os.mkfifo(case_dir / "pipe.png")
        return b"newmtl face\nmap_Kd pipe.png\n", "map_Kd a named pipe"
    if choice == 3:
        (case_dir / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(rng.randrange(256) for _ in range(200)))
        return b"newmtl face\nmap_Kd -s 1 1 1 bad.png\n", "map_Kd a damaged png"
    return bytes(rng.randrange(256) for _ in range(rng.randint(0, 500))), "binary mtl"


def _image_case(rng: random.Random) -> tuple[bytes, str]:
    import PIL.Image

    choice = rng.randrange(4)
    buf = io.BytesIO()
    if choice == 0:
        PIL.Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(buf, "PNG")
        data = buf.getvalue()
        return _mutate_bytes(data, rng)[0], "damaged png"
    if choice == 1:  # a header claiming a huge image (a decompression bomb's first bytes)
        import struct
        import zlib

        ihdr = struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0)
        chunk = b"IHDR" + ihdr
        return (b"\x89PNG\r\n\x1a\n" + struct.pack(">I", len(ihdr)) + chunk + struct.pack(">I", zlib.crc32(chunk))
                + b"\x00" * 12), "png header 60000x60000"
    if choice == 2:
        return b"GIF89a" + bytes(rng.randrange(256) for _ in range(100)), "gif noise"
    return b"P6\n99999 99999\n255\n", "ppm header claiming 10^10 pixels"


# ====================================================================== readers and invariants
def _readers():
    from core.formats import project as P
    from core.formats.dpc_file import DpcFileError, read_dpc
    from core.formats.epc_file import EpcFileError, read_epc
    from core.formats.fap_file import FapFileError, read_fap
    from core.formats.landmarks_io import LandmarkFileError, load_landmarks
    from core.formats.mesh_io import MeshLoadError, load_face, load_texture_image
    from core.formats.ppc_file import PpcFileError, read_ppc
    from core.landmark_editing import LandmarkEditModel
    from core.layers.muscles import ForceFileError, load_force_set

    face = _grid_face()
    return {
        "project": (P.load_project, P.ProjectError, _check_project),
        "landmarks": (lambda p: load_landmarks(p, face), LandmarkFileError, _check_landmarks),
        "landmark_csv": (lambda p: LandmarkEditModel(face).read_file(p), LandmarkFileError, _check_landmarks),
        "force": (load_force_set, ForceFileError, _check_forces),
        "fap": (read_fap, FapFileError, _check_fap),
        "dpc": (read_dpc, DpcFileError, _check_dpc),
        "ppc": (read_ppc, PpcFileError, _check_ppc),
        "epc": (read_epc, EpcFileError, _check_epc),
        "obj": (load_face, MeshLoadError, _check_face),
        "mtl": (load_face, MeshLoadError, _check_face),
        "ply": (load_face, MeshLoadError, _check_face),
        "glb": (load_face, MeshLoadError, _check_face),
        "stl": (load_face, MeshLoadError, _check_face),
        "image": (load_texture_image, MeshLoadError, _check_image),
    }


def _check_project(project) -> str | None:
    from core import parameters as Pm
    from core.timeline import MAX_DURATION_S

    tl = project.timeline
    if not (0 < tl.duration <= MAX_DURATION_S):
        return f"timeline of {tl.duration} s accepted"
    for key, value in project.rig.values.items():
        try:
            Pm.check_value(key, value)
        except Pm.ParameterError as exc:
            return f"rig value accepted: {exc}"
    for track in tl.tracks.values():
        if len(track) and (track.times[-1] > tl.duration + 1e-6 or track.times[0] < -1e-6):
            return f"track {track.key} outside the timeline"
    for clip in project.speech:  # an oracle of its own, not the reader's check
        if not isinstance(clip.text, str) or not clip.text.strip() or len(clip.text) > 20_000:
            return f"speech clip text {clip.text!r:.40} accepted"
        if clip.lang not in LANGUAGES:
            return f"speech clip language {clip.lang!r} accepted"
        if not 80 <= clip.rate_wpm <= 450:
            return f"speech rate {clip.rate_wpm} accepted"
        if not 0 <= clip.start_s <= tl.duration:
            return f"speech clip starting at {clip.start_s} accepted"
    if project.landmarks is not None and len(project.landmarks) > 10_000:
        return "too many landmarks accepted"
    return None


def _check_landmarks(points) -> str | None:
    if len(points) > 10_000:
        return f"{len(points)} landmarks accepted"
    return None


def _check_forces(force_set) -> str | None:
    from core import parameters as Pm

    try:
        for (name, side), value in force_set.forces.items():
            Pm.check_value((name, side), value)
        Pm.check_value("jaw", force_set.jaw_deg)
    except Pm.ParameterError as exc:
        return f"force accepted: {exc}"
    return None


def _check_fap(seq) -> str | None:
    if not (0.1 <= seq.fps <= 1000) or seq.duration > 24 * 3600:
        return f"fps {seq.fps}, {seq.duration} s accepted"
    masked = seq.values[:, 2:][seq.mask[:, 2:]]
    if not np.isfinite(masked).all():
        return "non-finite FAP value accepted"
    return None


def _check_dpc(seq) -> str | None:
    if not np.isfinite(seq.displacements).all():
        return "non-finite displacement accepted"
    return None


def _check_ppc(ppc) -> str | None:
    if not np.isfinite(ppc.positions).all():
        return "non-finite control-point position accepted"
    if len(set(ppc.names)) != len(ppc.names):
        return "a control point named twice accepted"
    return None


def _check_epc(emotion) -> str | None:
    if not np.isfinite(emotion.frames).all():
        return "non-finite displacement accepted"
    return None


def _check_face(face) -> str | None:
    if not np.isfinite(face.vertices).all():
        return "non-finite vertices accepted"
    return None


def _check_image(image) -> str | None:
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        return f"image of shape {image.shape} {image.dtype} accepted"
    return None


class _Timeout(Exception):
    pass


@contextlib.contextmanager
def _deadline(seconds: float):
    """Raise _Timeout after ``seconds`` (main thread only; elsewhere the time is only measured)."""
    import threading

    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "setitimer"):
        yield
        return

    def alarm(signum, frame):
        raise _Timeout()

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def run_case(case: Case, readers=None) -> Outcome:
    readers = readers or _readers()
    read, error, check = readers[case.kind]
    start = time.perf_counter()
    try:
        with _deadline(CASE_SECONDS), contextlib.redirect_stderr(io.StringIO()), warnings.catch_warnings(), \
                np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            value = read(case.path)
    except _Timeout:
        return Outcome(case, "failed", f"no answer within {CASE_SECONDS:g} s (a hang)", time.perf_counter() - start)
    except error as exc:
        seconds = time.perf_counter() - start
        message = str(exc)
        if not message or "Traceback" in message:
            return Outcome(case, "failed", f"unhelpful message {message!r}", seconds)
        if seconds > CASE_SECONDS:
            return Outcome(case, "failed", f"took {seconds:.1f} s", seconds)
        return Outcome(case, "refused", message, seconds)
    except BaseException as exc:  # noqa: BLE001 - exactly what the fuzzing looks for
        if isinstance(exc, KeyboardInterrupt):
            raise
        return Outcome(case, "failed", f"{type(exc).__name__}: {exc}"[:400], time.perf_counter() - start)
    seconds = time.perf_counter() - start
    problem = check(value)
    if problem:
        return Outcome(case, "failed", f"silent acceptance: {problem}", seconds)
    if seconds > CASE_SECONDS:
        return Outcome(case, "failed", f"took {seconds:.1f} s", seconds)
    return Outcome(case, "accepted", "", seconds)


# ====================================================================== command-line values
CLI_CASES = [
    (["render", "--out", "{out}/a.png", "--size", "0x0"], "size 0x0"),
    (["render", "--out", "{out}/a.png", "--size", "99999x2"], "size huge"),
    (["render", "--out", "{out}/a.png", "--size", "nanxnan"], "size nan"),
    (["render", "--out", "{out}/a.png", "--fap", "open_jaw=nan"], "fap nan"),
    (["render", "--out", "{out}/a.png", "--fap", "open_jaw=1e300"], "fap huge"),
    (["render", "--out", "{out}/a.png", "--fap", "999=1"], "fap unknown"),
    (["render", "--out", "{out}/a.png", "--jaw", "nan"], "jaw nan"),
    (["render", "--out", "{out}/a.png", "--jaw", "inf"], "jaw inf"),
    (["render", "--out", "{out}/a.png", "--jaw", "-5"], "jaw -5"),
    (["render", "--out", "{out}/a.png", "--muscles", "bogus=1e300"], "muscle unknown"),
    (["render", "--out", "{out}/a.png", "--muscles", "risorius=1e300"], "muscle huge"),
    (["render", "--out", "{out}/a.png", "--muscles", "risorius=nan"], "muscle nan"),
    (["render", "--out", "{out}/a.png", "--expression", "joy:1e300"], "expression huge"),
    (["render", "--out", "{out}/a.png", "--viseme", "99"], "viseme unknown"),
    (["export", "{project}", "--out", "{out}/a.fap", "--fps", "0"], "fps 0"),
    (["export", "{project}", "--out", "{out}/a.fap", "--fps", "-5"], "fps -5"),
    (["export", "{project}", "--out", "{out}/a.fap", "--fps", "nan"], "fps nan"),
    (["export", "{project}", "--out", "{out}/a.fap", "--fps", "inf"], "fps inf"),
    (["export", "{project}", "--out", "{out}/a.fap", "--fps", "1e-7"], "fps 1e-7"),
    (["export", "{out}/nothing.mimica", "--out", "{out}/a.fap"], "project missing"),
    (["export", "{bad_project}", "--out", "{out}/a.fap"], "project with rig.muscles"),
    (["export", "{deep_project}", "--out", "{out}/a.fap"], "project nested deep"),
    (["lipsync", "hi", "--out", "{out}/a.mimica", "--fps", "0"], "lipsync fps 0"),
    (["lipsync", "hi", "--out", "{out}/a.mimica", "--lang", "xx"], "lipsync lang"),
    (["evaluate-landmarks", "--people", "-5"], "people -5"),
    (["evaluate-landmarks", "--people", "0"], "people 0"),
    (["register", "{out}/none.obj", "--landmarks", "{out}/l.json", "--out", "{out}/x.obj", "--scale", "nan"],
     "scale nan"),
    (["register", "{out}/none.obj", "--landmarks", "{out}/l.json", "--out", "{out}/x.obj", "--scale", "-1"],
     "scale -1"),
]


def run_cli_cases(folder: Path) -> list[Outcome]:
    """Each hostile command line must end with a one-line message and a non-zero status, no traceback."""
    from app.cli import main

    folder.mkdir(parents=True, exist_ok=True)
    seeds = _seeds(folder / "seeds")
    bad = json.loads(seeds["project"][0].read_text())
    bad["rig"]["muscles"] = [{"name": "bogus", "force": 1e300}]
    (folder / "bad.mimica").write_text(json.dumps(bad))
    (folder / "deep.mimica").write_text('{"format": "mimica-project", "version": 2, "x": '
                                        + "[" * 100_000 + "]" * 100_000 + "}")
    names = {"out": folder, "project": seeds["project"][0], "bad_project": folder / "bad.mimica",
             "deep_project": folder / "deep.mimica"}
    outcomes = []
    for argv, how in CLI_CASES:
        argv = [a.format(**names) for a in argv]
        case = Case("cli", " ".join(argv[:1] + argv[-2:]), folder, how)
        err = io.StringIO()
        start = time.perf_counter()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                status = main(argv)
        except SystemExit as exc:  # argparse: usage + one error line, status 2
            status = exc.code
        except BaseException as exc:  # noqa: BLE001
            outcomes.append(Outcome(case, "failed", f"{type(exc).__name__}: {exc}", time.perf_counter() - start))
            continue
        seconds = time.perf_counter() - start
        text = err.getvalue()
        if status == 0:
            outcomes.append(Outcome(case, "failed", "silent acceptance: exit status 0", seconds))
        elif "Traceback" in text or "Error: " in text.split("error:", 1)[-1][:40] or "failed unexpectedly" in text:
            outcomes.append(Outcome(case, "failed", f"unhelpful message: {text.strip()[-300:]}", seconds))
        else:
            outcomes.append(Outcome(case, "refused", text.strip().splitlines()[-1] if text.strip() else "", seconds))
    return outcomes


def _peak_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run(folder: str | os.PathLike, cases: int, seed: int = 0, *, cli: bool = True, progress=None) -> Report:
    folder = Path(folder)
    corpus = generate(folder / "corpus", cases, seed)
    readers = _readers()
    report = Report()
    for k, case in enumerate(corpus):
        before = _peak_mb()
        outcome = run_case(case, readers)
        grew = _peak_mb() - before
        if grew > CASE_MEMORY_MB:  # the process's peak grew this much while reading one file
            outcome = Outcome(case, "failed", f"memory blow-up: the peak grew by {grew:.0f} MB", outcome.seconds)
        if grew > report.memory[0]:
            report.memory = (grew, case.name, case.how)
        report.outcomes.append(outcome)
        if progress is not None:
            progress(k + 1, len(corpus))
    if cli:
        report.outcomes.extend(run_cli_cases(folder / "cli"))
    return report


def main(argv=None) -> int:
    import tempfile

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=3000, help="generated hostile files (default 3000)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--keep", metavar="DIR", help="write the corpus to DIR and keep it")
    parser.add_argument("--no-cli", action="store_true", help="skip the command-line cases")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="mimica-fuzz-") as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)

        def progress(done, total):
            if done % 250 == 0 or done == total:
                print(f"\r{done}/{total} files", end="", file=sys.stderr, flush=True)

        report = run(folder, args.cases, args.seed, cli=not args.no_cli, progress=progress)
        print(file=sys.stderr)
    print(report.summary())
    print(f"{time.perf_counter() - start:.1f} s in all")
    return 1 if report.failed else 0


if __name__ == "__main__":
    sys.exit(main())
