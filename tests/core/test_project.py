"""Project files: exact round trips, face references and embedding, clear errors, autosave."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from core.formats import project as P
from core.formats.project import FaceRef, Project, ProjectError, ProjectVersionError, RigSettings, SpeechClip
from core.timeline import Timeline
from tests.core.conftest import make_grid_face


def _timeline() -> Timeline:
    tl = Timeline(12.5, 25)
    rng = np.random.default_rng(4)
    tl.add_keys({
        "fap:3": [(0.0, 0.0), (1.0 / 3.0, 512.123456789, "linear"), (2.7, 140.0, "step"), (12.5, 3.0)],
        "fap:19": [(0.1, -300.0), (5.0, 1024.0)],
        "expression:joy": [(0.0, 0.25), (4.0, 1.0)],
        "viseme:7": [(t, float(v)) for t, v in zip(np.arange(0.0, 3.0, 0.1), rng.random(30))],
        "muscle:zygomatic_major:left": [(0.0, 0.0), (2.0, 9.5)],
        "muscle:orbicularis_oris": [(1.0, 8.0)],
        "jaw": [(0.0, 0.0), (6.0, 12.0, "linear"), (7.0, 2.5)],
    })
    return tl


def _project(face_ref=None, landmarks=None) -> Project:
    return Project(
        face=face_ref or FaceRef.default_face(),
        landmarks=landmarks,
        rig=RigSettings({"fap:3": 120.5, "fap:19": -33.25, "expression:joy": 0.5, "viseme:4": 0.3, "viseme:7": 0.7,
                         "muscle:risorius:left": 42.0, "muscle:orbicularis_oris": 8.0, "jaw": 3.5}),
        timeline=_timeline(),
        speech=[SpeechClip("Olá, como vai você?", "pt-br", 1.25)],
        view={"camera": {"position": [1.0, 2.0, 300.0], "zoom": 1.5}, "mode": "textured",
              "overlays": ["landmarks"], "numpy": np.float32(0.5), "array": np.arange(3)},
    )


def test_round_trip_is_exact(tmp_path):
    path = tmp_path / "scene.mimica"
    original = _project()
    P.save_project(path, original)
    text = path.read_text(encoding="utf-8")
    assert '"format": "mimica-project"' in text and '"version": 2' in text and "Olá" in text
    loaded = P.load_project(path)
    assert loaded.face == FaceRef.default_face()
    assert loaded.rig == original.rig
    assert loaded.speech == original.speech
    assert loaded.view == {"camera": {"position": [1.0, 2.0, 300.0], "zoom": 1.5}, "mode": "textured",
                           "overlays": ["landmarks"], "numpy": 0.5, "array": [0, 1, 2]}
    assert (loaded.timeline.duration, loaded.timeline.fps) == (12.5, 25)
    assert list(loaded.timeline.tracks) == list(original.timeline.tracks)
    for t in np.concatenate([np.linspace(-1, 14, 61), [1.0 / 3.0, 2.7]]):
        assert loaded.timeline.evaluate(t) == original.timeline.evaluate(t)  # bit for bit
    P.save_project(tmp_path / "again.mimica", loaded)
    assert (tmp_path / "again.mimica").read_text(encoding="utf-8") == text


def test_embedded_face_and_its_landmarks(tmp_path, grid_face):
    face = grid_face
    path = tmp_path / "grid.mimica"
    ref = P.embed_face(face, path)
    assert ref.path == (tmp_path / "grid.face.ply").resolve() and len(ref.sha256) == 64
    proj = Project.from_state(face, ref, view={"mode": "shaded"})
    P.save_project(path, proj)
    doc = json.loads(path.read_text(encoding="utf-8"))
    assert doc["face"]["path"] == "grid.face.ply"
    # The folder moves: the relative path still works.
    moved = tmp_path / "moved"
    moved.mkdir()
    for name in ("grid.mimica", "grid.face.ply", "grid.face.png"):
        (tmp_path / name).rename(moved / name)
    loaded = P.load_project(moved / "grid.mimica")
    notes: list[str] = []
    reopened = P.open_face(loaded, notes)
    assert notes == []
    np.testing.assert_array_equal(reopened.vertices, face.vertices)
    assert reopened.landmarks == face.landmarks
    # The face file is edited (triangles reversed): detected, landmarks follow their saved positions.
    from core.face import Face
    from core.formats.mesh_io import save_face

    changed = Face(face.vertices, face.triangles[::-1], uv=face.uv, texture=face.texture)
    save_face(changed, moved / "grid.face.ply")
    notes = []
    relocated = P.open_face(loaded, notes)
    assert "changed since the project was saved" in notes[0]
    np.testing.assert_allclose(relocated.landmark_positions(face.landmark_names),
                               face.landmark_positions(face.landmark_names), atol=1e-6)
    (moved / "grid.face.ply").unlink()
    with pytest.raises(ProjectError, match="is missing"):
        P.open_face(loaded)


def test_default_face_rig_is_restored_exactly(tmp_path):
    from core.default_face import load_default_face
    from core.rig import FaceRig
    from core.timeline import apply_to_rig

    face = load_default_face()
    rig = FaceRig(face)
    tl = Timeline(4.0, 30)
    tl.add_keys({"fap:3": [(0.0, 0.0), (2.0, 600.0)], "fap:59": [(1.0, 80.0)], "viseme:1": [(0.0, 0.0), (3.0, 0.8)],
                 "expression:surprise": [(0.5, 0.4)]})
    rig.set_fap(31, 50.0)
    rig.set_expression("joy", 0.35)
    rig.set_fap1(4, 10, 20)
    proj = Project.from_state(face, FaceRef.default_face(), rig, tl, view={"camera": "front"})
    P.save_project(tmp_path / "rig.mimica", proj)
    wanted = rig.vertices().copy()
    apply_to_rig(rig, tl.evaluate(1.3))
    animated = rig.vertices().copy()

    loaded = P.load_project(tmp_path / "rig.mimica")
    face2 = P.open_face(loaded)
    np.testing.assert_array_equal(face2.vertices, face.vertices)
    assert face2.landmarks == face.landmarks
    # The FAT is a deterministic function of the face and its landmarks (checked equal above),
    # so the deformer is reused instead of rebuilding it (about 4 s).
    rig2 = FaceRig(face2, deformer=rig.deformer)
    loaded.rig.apply(rig2)
    assert rig2.expressions == ((1, 0.35),) and dict(rig2.visemes) == {4: 20 / 63, 10: 1 - 20 / 63}
    np.testing.assert_array_equal(rig2.vertices(), wanted)
    apply_to_rig(rig2, loaded.timeline.evaluate(1.3))
    np.testing.assert_array_equal(rig2.vertices(), animated)


def _write(tmp_path, doc, name="bad.mimica"):
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc), encoding="utf-8")
    return path


def test_newer_format_is_refused_with_a_clear_message(tmp_path):
    doc = P.to_document(_project(), tmp_path)
    doc["version"] = 3
    with pytest.raises(ProjectVersionError) as info:
        P.load_project(_write(tmp_path, doc))
    assert "made by a newer Mimica (format 3); this Mimica reads up to 2 — update Mimica" in str(info.value)


@pytest.mark.parametrize("mutate, words", [
    (lambda d: d.pop("timeline"), "field timeline is missing"),
    (lambda d: d["timeline"].pop("fps"), "field timeline.fps is missing"),
    (lambda d: d["timeline"]["tracks"][0]["keys"][1].__setitem__(1, "high"), r"timeline.tracks\[0\].keys\[1\]\[1\] must be a number"),
    (lambda d: d["timeline"]["tracks"][0]["keys"][1].__setitem__(2, "cubic"), "interpolation must be one of"),
    (lambda d: d["timeline"]["tracks"][1].__setitem__("key", "fap:999"), r"timeline.tracks\[1\].key is invalid"),
    (lambda d: d["timeline"].__setitem__("fps", 29), "frame rate"),
    (lambda d: d["timeline"].__setitem__("duration", 1.0), "extend the duration"),
    (lambda d: d["rig"]["values"].__setitem__("fap:3", True), r"rig.values.fap:3 must be a number, got true"),
    (lambda d: d["rig"]["values"].__setitem__("expression:joy", 2), "outside its range 0 to 1"),
    (lambda d: d["rig"]["values"].__setitem__("muscle:risorius:up", 1.0), r"rig.values.muscle:risorius:up.*left/right"),
    (lambda d: d["rig"]["values"].__setitem__("muscle:biceps:left", 1.0), "unknown muscle 'biceps'"),
    (lambda d: d.__setitem__("face", {"builtin": "someone"}), "unknown built-in face"),
    (lambda d: d.__setitem__("face", {"absolute": "/x.ply"}), "field face.path is missing"),
    (lambda d: d.__setitem__("view", []), "view must be an object"),
    (lambda d: d.__setitem__("version", "1"), "version must be a whole number"),
    (lambda d: d.__setitem__("format", "other"), "not a Mimica project"),
    (lambda d: d.__setitem__("landmarks", [{"name": "2.1", "triangle": 0, "barycentric": [0.5, 0.5]}]),
     "must hold 3 numbers"),
])
def test_bad_fields_are_named(tmp_path, mutate, words):
    doc = P.to_document(_project(), tmp_path)
    mutate(doc)
    with pytest.raises(ProjectError, match=words):
        P.load_project(_write(tmp_path, doc))


def test_format_1_projects_still_load(tmp_path):
    doc = P.to_document(_project(), tmp_path)
    doc["version"] = 1
    doc["rig"] = {"faps": {"3": 120.5, "19": -33.25}, "expressions": [{"id": 1, "name": "joy", "intensity": 0.5}],
                  "visemes": [{"id": 4, "intensity": 0.3}, {"id": 7, "intensity": 0.7}],
                  "muscles": [{"name": "risorius", "side": "left", "force": 42.0},
                              {"name": "orbicularis_oris", "side": None, "force": 8.0}], "jaw": 3.5}
    loaded = P.load_project(_write(tmp_path, doc))
    assert loaded.rig == _project().rig
    doc["rig"]["muscles"][0]["side"] = "up"
    with pytest.raises(ProjectError, match=r"rig.muscles\[0\].side"):
        P.load_project(_write(tmp_path, doc))


def test_damaged_files(tmp_path):
    with pytest.raises(ProjectError, match="line 2, column"):
        P.load_project(_write(tmp_path, '{"format": "mimica-project",\n "version": 1 "face"}'))
    with pytest.raises(ProjectError, match="NaN is not a valid number"):
        P.load_project(_write(tmp_path, '{"format": "mimica-project", "version": 1, "x": NaN}'))
    with pytest.raises(ProjectError, match="not UTF-8"):
        path = tmp_path / "bin.mimica"
        path.write_bytes(b"\x80\x04\x95 pickle")
        P.load_project(path)
    with pytest.raises(ProjectError, match="does not exist"):
        P.load_project(tmp_path / "nothing.mimica")
    proj = _project()
    proj.view = {"widget": object()}
    with pytest.raises(ProjectError, match="view.widget: values of type object cannot be saved"):
        P.save_project(tmp_path / "x.mimica", proj)
    proj.view = {"zoom": float("inf")}
    with pytest.raises(ProjectError, match="finite"):
        P.save_project(tmp_path / "x.mimica", proj)
    with pytest.raises(ProjectError, match="does not exist"):
        P.save_project(tmp_path / "no" / "dir.mimica", _project())


def test_autosave_recovery_cycle(tmp_path):
    path = tmp_path / "scene.mimica"
    P.save_project(path, _project())
    assert P.find_autosave(path) is None
    auto = P.write_autosave(_project(), path)
    assert auto == tmp_path / "scene.mimica.autosave"
    os.utime(path, ns=(1_000_000_000, 1_000_000_000))
    assert P.find_autosave(path) == auto
    recovered = P.load_project(auto)
    assert recovered.timeline.evaluate(1.0) == _project().timeline.evaluate(1.0)
    os.utime(auto, ns=(500_000_000, 500_000_000))  # older than the project: nothing to recover
    assert P.find_autosave(path) is None
    P.discard_autosave(path)
    assert not auto.exists()
    P.discard_autosave(path)  # no error when there is none

    state = tmp_path / "state"
    untitled = P.write_autosave(_project(), untitled_id="untitled-42", state_dir=state)
    assert untitled == state / "untitled-42.mimica.autosave"
    assert P.find_autosave(untitled_id="untitled-42", state_dir=state) == untitled
    assert P.untitled_autosaves(state) == [untitled]
    P.discard_autosave(untitled_id="untitled-42", state_dir=state)
    assert P.untitled_autosaves(state) == []
    # A scan derived in memory is embedded beside its autosave; discarding the autosave removes it too.
    face = make_grid_face(5)
    project = _project(face_ref=P.embed_face(face, P.autosave_path(untitled_id="untitled-43", state_dir=state)))
    P.write_autosave(project, untitled_id="untitled-43", state_dir=state)
    assert {p.name for p in state.iterdir()} == {
        "untitled-43.mimica.autosave", "untitled-43.mimica.autosave.face.ply", "untitled-43.mimica.autosave.face.png"}
    P.discard_autosave(untitled_id="untitled-43", state_dir=state)
    assert list(state.iterdir()) == []
    with pytest.raises(ProjectError, match="bad autosave name"):
        P.autosave_path(untitled_id="../escape")


def test_default_state_dir_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    assert P.default_state_dir() == tmp_path / "mimica" / "autosave"
