"""Property-based fuzzing of every reader (issue 19): whatever text a file holds, its reader returns a
result that keeps the format's invariants or raises the format's own error class with a message —
never another exception, a hang or a silent acceptance. Plus a bounded run of the hostile-file corpus
of ``tests/fuzz_corpus.py`` (its longer run: ``python benchmarks/fuzz_readers.py``).

Budget: deterministic (derandomized), about 20 s for the whole file."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import fuzz_corpus  # noqa: E402

from core.formats import project as P  # noqa: E402
from core.formats.dpc_file import DpcFileError, parse_dpc  # noqa: E402
from core.formats.fap_file import FapFileError, parse_fap  # noqa: E402
from core.formats.landmarks_io import LandmarkFileError, load_landmarks  # noqa: E402
from core.formats.mesh_io import MeshLoadError, load_face  # noqa: E402
from core.landmark_editing import LandmarkEditModel  # noqa: E402
from core.layers.muscles import ForceFileError, load_force_set  # noqa: E402
from core.timeline import MAX_DURATION_S, Edit, Timeline, TimelineError  # noqa: E402

FUZZ = settings(max_examples=120, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                       HealthCheck.data_too_large, HealthCheck.filter_too_much])

HOSTILE = st.sampled_from(fuzz_corpus.HOSTILE_NUMBERS)
NUMBER = st.one_of(st.integers(-2000, 2000).map(str), st.floats(allow_nan=True, allow_infinity=True).map(repr),
                   HOSTILE)
TOKEN = st.one_of(NUMBER, st.text(alphabet="01#,;.-+eE xé\t", min_size=0, max_size=6))
FACE = fuzz_corpus._grid_face()


def _json_values():
    scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**40, 10**40),
                        st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=12))
    return st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                        st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                        max_leaves=12)


def _write(tmp_path_factory, name: str, text: str) -> Path:
    path = tmp_path_factory.mktemp("fuzz") / name
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    return path


# ---------------------------------------------------------------- .fap: the grammar, then damage
@st.composite
def fap_texts(draw):
    fps = draw(st.one_of(st.sampled_from(["25", "30", "0.5"]), NUMBER))
    n = draw(st.integers(0, 4))
    lines = [f"{draw(st.sampled_from(['2.1', '2.0', 'x']))} name {fps} {draw(st.one_of(st.just(str(n)), NUMBER))}"]
    for k in range(n):
        bits = draw(st.lists(st.sampled_from(["0", "1"]), min_size=66, max_size=70))
        mask = ["0", "0"] + bits
        lines.append(" ".join(mask))
        count = sum(b == "1" for b in mask[2:68])
        values = draw(st.lists(TOKEN, min_size=max(0, count - 1), max_size=count + 2))
        lines.append(" ".join([draw(st.one_of(st.just(str(k)), NUMBER))] + values))
    text = "\n".join(lines)
    if draw(st.booleans()):
        cut = draw(st.integers(0, len(text)))
        text = text[:cut]
    return text


def _fap_ok(seq) -> None:
    assert 0.1 <= seq.fps <= 1000 and seq.duration <= MAX_DURATION_S
    assert np.isfinite(seq.values[:, 2:][seq.mask[:, 2:]]).all()


@FUZZ
@given(fap_texts())
def test_fap_reader_never_raises_anything_else(text):
    try:
        seq = parse_fap(text, source="f.fap")
    except FapFileError as exc:
        assert "'f.fap'" in str(exc) or str(exc)
        return
    _fap_ok(seq)


# ---------------------------------------------------------------- DPC
@st.composite
def dpc_texts(draw):
    lines = []
    if draw(st.booleans()):
        lines.append(draw(st.one_of(st.just("2"), NUMBER)))
    if draw(st.booleans()):
        lines.append("# fps " + draw(NUMBER))
    for _ in range(draw(st.integers(0, 12))):
        if draw(st.integers(0, 4)) == 0:
            lines.append("")
        else:
            lines.append(" ".join(draw(st.lists(TOKEN, min_size=1, max_size=4))))
    return "\n".join(lines)


@FUZZ
@given(dpc_texts(), st.one_of(st.none(), st.integers(-2, 30)))
def test_dpc_reader_never_raises_anything_else(text, n_points):
    try:
        seq = parse_dpc(text, source="d.dpc", n_points=n_points)
    except DpcFileError:
        return
    except ValueError as exc:  # a bad n_points argument is the caller's error, said as such
        assert n_points is not None and n_points < 1 and "n_points" in str(exc)
        return
    assert np.isfinite(seq.displacements).all()


# ---------------------------------------------------------------- JSON formats: valid skeletons, hostile values
def _damaged(document: dict, paths_and_values) -> dict:
    doc = json.loads(json.dumps(document))
    for path, value in paths_and_values:
        target = doc
        for key in path[:-1]:
            target = target[key] if isinstance(target, dict) and key in target else None
            if target is None:
                break
        if isinstance(target, dict):
            target[path[-1]] = value
    return doc


PROJECT_FIELDS = [("face",), ("face", "builtin"), ("landmarks",), ("rig",), ("rig", "values"), ("rig", "muscles"),
                  ("timeline",), ("timeline", "duration"), ("timeline", "fps"), ("timeline", "tracks"), ("speech",),
                  ("view",), ("version",)]
SKELETON = {"format": "mimica-project", "version": 2, "face": {"builtin": "default_face"}, "landmarks": None,
            "rig": {"values": {"fap:3": 100.0}}, "timeline": {"duration": 5.0, "fps": 25, "tracks": [
                {"key": "fap:3", "keys": [[0.0, 1.0, "linear"], [1.0, 2.0, "smooth"]]}]},
            "speech": [{"text": "hi", "lang": "en", "start_s": 0.5, "rate_wpm": 175}], "view": {}}


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(PROJECT_FIELDS), _json_values()), min_size=1, max_size=3))
def test_project_reader_never_raises_anything_else(tmp_path_factory, damage):
    path = _write(tmp_path_factory, "p.mimica", json.dumps(_damaged(SKELETON, damage)))
    try:
        project = P.load_project(path)
    except P.ProjectError as exc:
        assert "p.mimica" in str(exc)
        return
    assert fuzz_corpus._check_project(project) is None


LANDMARK_FIELDS = [("units",), ("version",), ("landmarks",), ("format",)]


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(LANDMARK_FIELDS), _json_values()), max_size=2),
       st.lists(st.dictionaries(st.sampled_from(["name", "xyz", "triangle", "barycentric", "status", "confidence"]),
                                _json_values(), max_size=6), max_size=4))
def test_landmark_json_reader_never_raises_anything_else(tmp_path_factory, damage, entries):
    doc = _damaged({"format": "mimica-landmarks", "version": 1, "units": "mm", "landmarks": entries}, damage)
    path = _write(tmp_path_factory, "l.json", json.dumps(doc))
    for read in (lambda: load_landmarks(path, FACE), lambda: LandmarkEditModel(FACE).read_file(path)):
        try:
            read()
        except LandmarkFileError as exc:
            assert "l.json" in str(exc)


@FUZZ
@given(st.lists(st.lists(TOKEN, min_size=0, max_size=7), max_size=6), st.booleans())
def test_landmark_csv_reader_never_raises_anything_else(tmp_path_factory, rows, header):
    lines = (["name,x,y,z,status,confidence"] if header else []) + [",".join(r) for r in rows]
    path = _write(tmp_path_factory, "l.csv", "\n".join(lines))
    try:
        LandmarkEditModel(FACE).read_file(path)
    except LandmarkFileError as exc:
        assert "l.csv" in str(exc)


@FUZZ
@given(st.dictionaries(st.sampled_from(["risorius", "orbicularis_oris", "zygomatic_major", "bogus", "mentalis"]),
                       _json_values(), max_size=4), _json_values(), _json_values())
def test_force_reader_never_raises_anything_else(tmp_path_factory, forces, jaw, name):
    doc = {"format": "mimica-muscle-forces", "version": 1, "name": name, "jaw_deg": jaw, "forces": forces}
    path = _write(tmp_path_factory, "f.json", json.dumps(doc))
    try:
        force_set = load_force_set(path)
    except ForceFileError as exc:
        assert "f.json" in str(exc)
        return
    assert fuzz_corpus._check_forces(force_set) is None


# ---------------------------------------------------------------- OBJ grammar
@st.composite
def obj_texts(draw):
    lines = []
    for _ in range(draw(st.integers(0, 8))):
        lines.append("v " + " ".join(draw(st.lists(NUMBER, min_size=2, max_size=6))))
    for _ in range(draw(st.integers(0, 4))):
        lines.append("vt " + " ".join(draw(st.lists(NUMBER, min_size=1, max_size=3))))
    for _ in range(draw(st.integers(0, 6))):
        corner = st.one_of(st.integers(-10, 10).map(str), st.tuples(st.integers(-10, 10), st.integers(-5, 5))
                           .map(lambda t: f"{t[0]}/{t[1]}"), st.just("1//2"), HOSTILE)
        lines.append("f " + " ".join(draw(st.lists(corner, min_size=1, max_size=5))))
    if draw(st.booleans()):
        lines.append("mtllib " + draw(st.sampled_from(["/etc/passwd", "../x.mtl", "m.mtl", ""])))
    return "\n".join(lines)


@FUZZ
@given(obj_texts())
def test_obj_reader_never_raises_anything_else(tmp_path_factory, text):
    path = _write(tmp_path_factory, "m.obj", text)
    try:
        face = load_face(path)
    except MeshLoadError as exc:
        assert str(exc)
        return
    assert np.isfinite(face.vertices).all()


# ---------------------------------------------------------------- the timeline's limits hold for every edit
@FUZZ
@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10**6)),
       st.sampled_from([24, 25, 30, 60, 0, 7, -1]))
def test_timeline_edits_keep_the_limits(duration, fps):
    tl = Timeline(10, 30)
    try:
        tl.apply_edit(Edit("x", {}, {}, (10.0, 30), (duration, fps)))
    except TimelineError:
        assert (tl.duration, tl.fps) == (10.0, 30)
        return
    assert 0 < tl.duration <= MAX_DURATION_S and math.isfinite(tl.duration)


# ---------------------------------------------------------------- command-line values
@FUZZ
@given(st.lists(st.tuples(st.sampled_from(["--fap", "--jaw", "--muscles", "--expression", "--viseme"]),
                          st.one_of(NUMBER, st.text(max_size=20),
                                    st.tuples(st.sampled_from(["open_jaw", "3", "risorius", "joy", "bogus", "10"]),
                                              st.sampled_from(["=", ":"]), NUMBER).map("".join))),
                min_size=1, max_size=3))
def test_cli_rig_values_are_refused_with_a_message(options):
    import argparse

    from app.cli.common import CliError, rig_values

    args = argparse.Namespace(fap=[], expression=None, viseme=None, muscles=None, jaw=None)
    for option, value in options:
        if option == "--fap":
            args.fap.append(value)
        elif option == "--jaw":
            try:
                args.jaw = float(value)
            except ValueError:
                continue  # argparse refuses it before rig_values
        else:
            setattr(args, option[2:], value)
    try:
        values = rig_values(args)
    except CliError as exc:
        assert str(exc)
        return
    from core import parameters as Pm

    for key, value in values.items():
        Pm.check_value(key, value)


# ---------------------------------------------------------------- the corpus, bounded
def test_hostile_corpus_bounded_run(tmp_path):
    report = fuzz_corpus.run(tmp_path, cases=400, seed=19)
    counts = report.counts()
    assert counts["cases"] >= 400 and not report.failed, report.summary()
    assert counts.get("refused", 0) > counts["cases"] // 2
