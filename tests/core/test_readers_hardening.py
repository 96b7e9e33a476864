"""Issue 19: every reader refuses hostile input with its own error class, naming the file and the
field; size caps; pipes refused before open(); the 24 h limit everywhere; paths that leave the
folder the user chose are not followed silently; speech buffers sized by the project."""

from __future__ import annotations

import json
import os
import threading
import wave

import numpy as np
import pytest

from core.face import Face
from core.formats import project as P
from core.formats import text_files
from core.formats.dpc_file import DpcFileError, read_dpc
from core.formats.epc_file import EpcFileError, read_epc
from core.formats.fap_file import FapFileError, parse_fap, read_fap
from core.formats.landmarks_io import LandmarkFileError, load_landmarks
from core.formats.mesh_io import MeshLoadError, load_face, load_texture_image, save_face
from core.formats.ppc_file import PpcFileError, read_ppc
from core.formats.project import ProjectError
from core.landmark_editing import LandmarkEditModel
from core.layers.muscles import ForceFileError, load_force_set
from core.timeline import MAX_DURATION_S as MAX_DURATION, Edit, Timeline, TimelineError

from tests.core.conftest import make_grid_face

DEEP = "[" * 100_000 + "]" * 100_000


def _project_doc(**changes) -> dict:
    doc = {"format": "mimica-project", "version": 2, "face": {"builtin": "default_face"}, "landmarks": None,
           "rig": {"values": {}}, "timeline": {"duration": 10.0, "fps": 30, "tracks": []}, "speech": [], "view": {}}
    doc.update(changes)
    return doc


def _write(tmp_path, name, content) -> os.PathLike:
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content if isinstance(content, str) else json.dumps(content), encoding="utf-8")
    return path


FAP_MASK = " ".join(["0", "0", "1"] + ["0"] * 65)


# ---------------------------------------------------------------- every exception -> the format's error
@pytest.mark.parametrize("text", [
    DEEP,
    '{"format": "mimica-project", "version": 2, "x": ' + DEEP + "}",
    '{"format": "mimica-project", "version": 2, "face": {"builtin": "default_face"}, "rig": {"values": {}}, '
    '"timeline": {"duration": 1' + "0" * 400 + ', "fps": 30, "tracks": []}}',
    '{"format": "mimica-project", "version": 2, "face": {"builtin": "default_face"}, "rig": {"values": {}}, '
    '"timeline": {"duration": 1e400, "fps": 30, "tracks": []}}',
])
def test_project_recursion_and_overflow_are_project_errors(tmp_path, text):
    with pytest.raises(ProjectError, match="'p.mimica'"):
        P.load_project(_write(tmp_path, "p.mimica", text))


def test_project_tracks_with_wrong_shapes_are_project_errors(tmp_path):
    for tracks in ([{"key": "fap:3", "keys": [5]}], [{"key": ["fap:3"], "keys": []}], [7], {"a": 1}):
        doc = _project_doc(timeline={"duration": 10.0, "fps": 30, "tracks": tracks})
        with pytest.raises(ProjectError, match="timeline.tracks"):
            P.load_project(_write(tmp_path, "p.mimica", doc))


@pytest.mark.parametrize("content, field", [
    ({"format": "mimica-landmarks", "version": 1, "units": ["mm"], "landmarks": []}, "units"),
    ('{"format": "mimica-landmarks", "version": 1, "landmarks": ' + DEEP + "}", "nests"),
    ('{"format": "mimica-landmarks", "version": 1, "landmarks": [{"name": "a", "xyz": [1' + "0" * 400 + ', 0, 0]}]}',
     "digits"),
    ('{"format": "mimica-landmarks", "version": 1, "landmarks": [{"name": "a", "xyz": [1e999, 0, 0]}]}', "finite"),
])
def test_landmark_json_hostile_values_are_landmark_errors(tmp_path, content, field):
    path = _write(tmp_path, "l.json", content)
    with pytest.raises(LandmarkFileError, match=field):
        load_landmarks(path, make_grid_face())
    with pytest.raises(LandmarkFileError, match=field):
        LandmarkEditModel(make_grid_face()).read_file(path)


def test_landmark_files_hold_a_bounded_number_of_names(tmp_path):
    entries = [{"name": f"n{i}", "xyz": [0, 0, 0]} for i in range(10_001)]
    path = _write(tmp_path, "many.json", {"format": "mimica-landmarks", "version": 1, "landmarks": entries})
    with pytest.raises(LandmarkFileError, match="at most 10000"):
        load_landmarks(path, make_grid_face())
    rows = "name,x,y,z,status,confidence\n" + "".join(f"n{i},0,0,0,auto,\n" for i in range(10_001))
    with pytest.raises(LandmarkFileError, match="at most 10000"):
        LandmarkEditModel(make_grid_face()).read_file(_write(tmp_path, "many.csv", rows))


@pytest.mark.parametrize("text", [DEEP, '{"format": "mimica-muscle-forces", "version": 1, "jaw_deg": 1' + "0" * 400 + "}",
                                  '{"format": "mimica-muscle-forces", "version": 1, "forces": ' + DEEP + "}"])
def test_force_file_recursion_and_overflow_are_force_errors(tmp_path, text):
    with pytest.raises(ForceFileError, match="'f.json'"):
        load_force_set(_write(tmp_path, "f.json", text))


def test_fap_huge_frame_number_names_the_line():
    with pytest.raises(FapFileError, match="line 3: the frame number 1e30"):
        parse_fap(f"2.1 x 25 1\n{FAP_MASK}\n1e30 100\n", source="a.fap")


@pytest.mark.parametrize("fps", ["1e-7", "1e300", "0.001", "5000"])
def test_fap_frame_rate_outside_its_range_is_refused(fps):
    with pytest.raises(FapFileError, match="frame rate in the header is .*from 0.1 to 1000"):
        parse_fap(f"2.1 x {fps} 1\n{FAP_MASK}\n0 100\n", source="a.fap")


def test_fap_longer_than_24_hours_is_refused():
    frames = "".join(f"{FAP_MASK}\n{k} 100\n" for k in range(8650))  # at 0.1 fps, 8641 frames pass 24 h
    with pytest.raises(FapFileError, match="longer than 24 h"):
        parse_fap("2.1 x 0.1 8650\n" + frames, source="a.fap")


def test_fap_values_outside_the_registry_and_unanimated_faps_are_left_out_with_a_note():
    from core.formats.animation_import import tracks_from_fap

    mask = " ".join(["0", "0", "1"] + ["0"] * 23 + ["1"] + ["0"] * 41)  # FAP 3 and FAP 27 (not animated)
    seq = parse_fap(f"2.1 x 25 2\n{mask}\n0 100 5\n{mask}\n1 1e300 5\n")
    tracks, notes = tracks_from_fap(seq)
    assert list(tracks) == ["fap:3"] and tracks["fap:3"].values.tolist() == [100]
    assert any("not animated" in n for n in notes) and any("outside" in n for n in notes)


# ---------------------------------------------------------------- the 24 h limit in every edit
def test_apply_edit_keeps_the_24_hour_limit():
    tl = Timeline(10, 30)
    with pytest.raises(TimelineError, match="between 0 and 86400"):
        tl.apply_edit(Edit("import", {}, {}, (10.0, 30), (99_001.0, 30)))
    with pytest.raises(TimelineError, match="frame rate"):
        tl.apply_edit(Edit("x", {}, {}, (10.0, 30), (10.0, 7)))
    assert (tl.duration, tl.fps) == (10.0, 30)
    from core.timeline import Track

    late = Track("fap:3", [(50.0, 1.0)])
    with pytest.raises(TimelineError, match="do not fit"):
        tl.apply_edit(Edit("x", {"fap:3": None}, {"fap:3": late}))
    assert "fap:3" not in tl.tracks


# ---------------------------------------------------------------- fields checked on load, named
@pytest.mark.parametrize("clip, field", [
    ({"text": "hi", "lang": "en", "start_s": 1e300}, r"speech\[0\].start_s .*after the end of the timeline"),
    ({"text": "hi", "lang": "xx", "start_s": 0}, r"speech\[0\].lang must be one of"),
    ({"text": "hi", "lang": "en", "start_s": 0, "rate_wpm": 0}, r"speech\[0\].rate_wpm .*from 80 to 450"),
    ({"text": "", "lang": "en", "start_s": 0}, r"speech\[0\].text"),
    ({"text": "hi", "lang": ["en"], "start_s": 0}, r"speech\[0\].lang"),
])
def test_speech_clips_are_checked_on_load(tmp_path, clip, field):
    with pytest.raises(ProjectError, match=field):
        P.load_project(_write(tmp_path, "p.mimica", _project_doc(speech=[clip])))


def test_unknown_rig_fields_are_refused_not_dropped(tmp_path):
    doc = _project_doc(rig={"values": {}, "muscles": [{"name": "bogus", "force": 1e300}], "jaw": 99})
    with pytest.raises(ProjectError, match="rig has a field 'muscles'"):
        P.load_project(_write(tmp_path, "p.mimica", doc))
    doc = _project_doc(timeline={"duration": 10.0, "fps": 30,
                                 "tracks": [{"key": "muscle:bogus:left", "keys": [[0, 1, "linear"]]}]})
    with pytest.raises(ProjectError, match=r"timeline.tracks\[0\].key .*unknown muscle 'bogus'"):
        P.load_project(_write(tmp_path, "p.mimica", doc))


# ---------------------------------------------------------------- size caps and non-regular files
def test_size_caps_are_stated(tmp_path, monkeypatch):
    monkeypatch.setitem(text_files.MAX_BYTES, "FAP", 1024)
    monkeypatch.setitem(text_files.MAX_BYTES, "DPC", 1024)
    monkeypatch.setitem(text_files.MAX_BYTES, "landmark", 1024)
    monkeypatch.setitem(text_files.MAX_BYTES, "force", 1024)
    big = "#" * 2048 + "\n"
    with pytest.raises(FapFileError, match="more than the 1 KB"):
        read_fap(_write(tmp_path, "a.fap", big))
    with pytest.raises(DpcFileError, match="more than the 1 KB"):
        read_dpc(_write(tmp_path, "a.dpc", big))
    with pytest.raises(LandmarkFileError, match="more than the 1 KB"):
        load_landmarks(_write(tmp_path, "a.json", " " * 2048), make_grid_face())
    with pytest.raises(LandmarkFileError, match="more than the 1 KB"):
        LandmarkEditModel(make_grid_face()).read_file(_write(tmp_path, "a.csv", big))
    with pytest.raises(ForceFileError, match="more than the 1 KB"):
        load_force_set(_write(tmp_path, "f.json", " " * 2048))
    monkeypatch.setattr(P, "MAX_FILE_BYTES", 1024)
    with pytest.raises(ProjectError, match="more than the 1 KB"):
        P.load_project(_write(tmp_path, "p.mimica", " " * 2048))


def _returns_quickly(call, seconds: float = 10.0):
    outcome = {}

    def run():
        try:
            outcome["value"] = call()
        except Exception as exc:  # noqa: BLE001
            outcome["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), "the reader blocked on a named pipe"
    return outcome


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
@pytest.mark.parametrize("name, call, error", [
    ("face.obj", load_face, MeshLoadError),
    ("skin.png", load_texture_image, MeshLoadError),
    ("p.mimica", P.load_project, ProjectError),
    ("a.fap", read_fap, FapFileError),
    ("a.dpc", read_dpc, DpcFileError),
    ("f.json", load_force_set, ForceFileError),
    ("l.json", lambda p: load_landmarks(p, make_grid_face()), LandmarkFileError),
    ("l.csv", lambda p: LandmarkEditModel(make_grid_face()).read_csv(p), LandmarkFileError),
    ("a.ppc", read_ppc, PpcFileError),
    ("a.epc", read_epc, EpcFileError),
])
def test_named_pipes_are_refused_before_open(tmp_path, name, call, error):
    fifo = tmp_path / name
    os.mkfifo(fifo)
    outcome = _returns_quickly(lambda: call(fifo))
    assert isinstance(outcome.get("error"), error)
    assert "named pipe" in str(outcome["error"])


# ---------------------------------------------------------------- paths stay where the user put them
def test_project_face_outside_its_folder_gets_a_note(tmp_path):
    faces, projects = tmp_path / "faces", tmp_path / "projects"
    faces.mkdir(), projects.mkdir()
    save_face(make_grid_face(), faces / "anna.ply")
    doc = _project_doc(face={"path": "../faces/anna.ply"})
    project = P.load_project(_write(projects, "p.mimica", doc))
    assert any("outside the project's folder" in n and "anna.ply" in n for n in project.notes)
    notes: list[str] = []
    P.open_face(project, notes)
    assert any("outside the project's folder" in n for n in notes)
    save_face(make_grid_face(), projects / "bob.ply")
    inside = P.load_project(_write(projects, "q.mimica", _project_doc(face={"path": "bob.ply"})))
    assert inside.notes == []


def _obj_with_material(folder, mtllib: str, mtl_text: str | None = None):
    face = make_grid_face()
    save_face(Face(face.vertices, face.triangles, uv=face.uv), folder / "m.obj")
    text = (folder / "m.obj").read_text()
    (folder / "m.obj").write_text(f"mtllib {mtllib}\nusemtl skin\n" + text)
    if mtl_text is not None:
        (folder / "m.mtl").write_text(mtl_text)
    return folder / "m.obj"


def test_obj_mtllib_outside_the_mesh_folder_is_not_followed(tmp_path):
    outside = tmp_path / "secret.mtl"
    outside.write_text("newmtl skin\nmap_Kd skin.png\n")
    mesh_dir = tmp_path / "mesh"
    mesh_dir.mkdir()
    face = load_face(_obj_with_material(mesh_dir, str(outside)))
    assert face.texture is None
    assert any("outside the mesh's folder" in n for n in face.metadata.notes)
    face = load_face(_obj_with_material(mesh_dir, "../secret.mtl"))
    assert any("outside the mesh's folder" in n for n in face.metadata.notes)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_obj_material_and_texture_that_are_named_pipes_do_not_block(tmp_path):
    os.mkfifo(tmp_path / "m.mtl")
    obj = _obj_with_material(tmp_path, "m.mtl")
    outcome = _returns_quickly(lambda: load_face(obj))
    notes = outcome["value"].metadata.notes
    assert outcome["value"].texture is None and any("m.mtl" in n and "not a regular file" in n for n in notes)
    os.unlink(tmp_path / "m.mtl")
    os.mkfifo(tmp_path / "skin.png")
    obj = _obj_with_material(tmp_path, "m.mtl", "newmtl skin\nmap_Kd skin.png\n")
    outcome = _returns_quickly(lambda: load_face(obj))
    notes = outcome["value"].metadata.notes
    assert outcome["value"].texture is None and any("skin.png" in n and "not a regular file" in n for n in notes)


def test_a_dpc_longer_than_24_hours_does_not_reach_the_timeline():
    from core.formats.dpc_file import parse_dpc
    from core.layers.rbf.files import keys_from_dpc

    mouth = "".join("\n" + "1 2 3\n" * 8 for _ in range(9000))   # 9,000 frames at 0.1 fps: 25 h
    seq = parse_dpc("# fps 0.1\n9000\n" + mouth)
    keys = keys_from_dpc(seq, seq.fps)
    tl = Timeline(10.0, 25)
    with pytest.raises(TimelineError, match="outside the timeline"):
        tl.add_keys(keys)
    with pytest.raises(TimelineError, match="between 0 and 86400 s"):
        tl.set_settings(duration=max(t for rows in keys.values() for t, _, _ in rows))
    assert tl.tracks == {} and tl.duration == 10.0


def test_obj_map_kd_outside_the_mesh_folder_is_not_loaded(tmp_path):
    import PIL.Image

    PIL.Image.fromarray(np.full((4, 4, 3), 200, np.uint8)).save(tmp_path / "elsewhere.png")
    mesh_dir = tmp_path / "mesh"
    mesh_dir.mkdir()
    obj = _obj_with_material(mesh_dir, "m.mtl", f"newmtl skin\nmap_Kd {tmp_path / 'elsewhere.png'}\n")
    face = load_face(obj)
    assert face.texture is None
    assert any("outside the mesh's folder" in n and "elsewhere.png" in n for n in face.metadata.notes)
    obj = _obj_with_material(mesh_dir, "m.mtl", "newmtl skin\nmap_Kd ../elsewhere.png\n")
    assert load_face(obj).texture is None
    PIL.Image.fromarray(np.full((4, 4, 3), 9, np.uint8)).save(mesh_dir / "elsewhere.png")
    assert load_face(obj).texture is not None  # a file of that name next to the mesh is used


# ---------------------------------------------------------------- speech sized by the project
def test_speech_buffers_are_sized_by_the_project(tmp_path, monkeypatch):
    from core import animation, lipsync

    def fake_audio(text, lang, rate_wpm=175):
        path = tmp_path / "clip.wav"
        with wave.open(str(path), "wb") as w:
            w.setnchannels(1), w.setsampwidth(2), w.setframerate(22050)
            w.writeframes(np.full(2205, 1000, "<i2").tobytes())
        return path, 22050

    monkeypatch.setattr(lipsync, "speech_audio", fake_audio)
    clips = [P.SpeechClip("hi", "en", 1e5), P.SpeechClip("hi", "en", 1.0)]
    samples, rate = animation.mix_speech(clips, duration_s=2.0)
    assert rate == 22050 and len(samples) == 22050 + 2205 and samples[22050] == 1000  # the late clip is left out
    monkeypatch.setattr(animation, "SPEECH_BLOCK", 4096)
    path = animation.speech_wav([P.SpeechClip("hi", "en", 3.0)], tmp_path, duration_s=10.0)
    with wave.open(str(path), "rb") as w:
        data = np.frombuffer(w.readframes(w.getnframes()), "<i2")
    assert len(data) == 3 * 22050 + 2205 and data[3 * 22050] == 1000 and not data[:3 * 22050].any()


# ---------------------------------------------------------------- the command line says what is wrong
def test_cli_names_the_file_not_the_exception_type(tmp_path, capsys):
    from app.cli import main

    deep = _write(tmp_path, "deep.mimica", '{"format": "mimica-project", "version": 2, "x": ' + DEEP + "}")
    assert main(["export", str(deep), "--out", str(tmp_path / "a.fap")]) == 1
    err = capsys.readouterr().err
    assert "deep.mimica" in err and "nests more than 64 levels" in err and "RecursionError" not in err
    bad = _write(tmp_path, "bad.mimica", _project_doc(rig={"values": {}, "muscles": [{"name": "bogus", "force": 1e300}]}))
    assert main(["export", str(bad), "--out", str(tmp_path / "b.fap")]) == 1
    assert "rig has a field 'muscles'" in capsys.readouterr().err
    assert not (tmp_path / "b.fap").exists()


def test_unexpected_errors_say_what_to_do():
    from app.cli.common import unexpected_error_message

    text = unexpected_error_message(TypeError("unhashable type: 'list'"), "export")
    assert not text.startswith("TypeError") and "'export' failed" in text and "report" in text
    assert unexpected_error_message(ProjectError("'a.mimica': timeline.fps must be …"), "export").startswith("'a.mimica'")


# ---------------------------------------------------------------- exports bounded by what reads back
def test_fap_export_is_capped_at_what_mimica_reads_back(tmp_path, monkeypatch):
    from core.formats.fap_file import FapSequence, check_fap_size, write_fap

    values = np.full((100, 68), np.nan)
    values[:, 2] = 100.0
    write_fap(tmp_path / "ok.fap", FapSequence.from_values(values, 25))
    monkeypatch.setitem(text_files.MAX_BYTES, "FAP", 4096)
    with pytest.raises(FapFileError, match="100 frames × 1 FAPs would be about .* more than the 4 KB"):
        write_fap(tmp_path / "big.fap", FapSequence.from_values(values, 25))
    assert not (tmp_path / "big.fap").exists()
    monkeypatch.setitem(text_files.MAX_BYTES, "FAP", 64 * 2**20)
    with pytest.raises(FapFileError, match="lower frame rate"):
        check_fap_size(Timeline(MAX_DURATION, 30).n_frames)  # a 24 h timeline: refused before evaluating it


def test_saving_through_a_symlink_writes_its_target(tmp_path):
    real = tmp_path / "store" / "take.mimica"
    real.parent.mkdir()
    P.save_project(real, P.Project())
    link = tmp_path / "take.mimica"
    link.symlink_to(real)
    project = P.Project(timeline=Timeline(42.0, 25))
    P.save_project(link, project)
    assert link.is_symlink() and P.load_project(real).timeline.duration == 42.0


def test_format_1_repeated_muscles_cannot_add_up_past_the_range(tmp_path):
    """Found by the fuzz corpus (seed 11): format 1's repeated rig.muscles entries were summed unchecked."""
    doc = _project_doc(version=1, rig={"muscles": [{"name": "risorius", "side": "left", "force": 50}] * 3})
    with pytest.raises(ProjectError, match=r"rig.muscles\[1\] .*risorius.* outside its range 0 to 60"):
        P.load_project(_write(tmp_path, "p.mimica", doc))
    doc = _project_doc(version=1, rig={"muscles": [{"name": "risorius", "side": "left", "force": 20}] * 2})
    assert P.load_project(_write(tmp_path, "p.mimica", doc)).rig.values == {"muscle:risorius:left": 40.0}


@pytest.mark.parametrize("suffix, companions", [(".obj", (".mtl", ".png")), (".ply", (".png",))])
def test_a_mesh_and_its_texture_are_saved_as_one_set(tmp_path, monkeypatch, suffix, companions):
    """OBJ + MTL + PNG (PLY + PNG) are committed together: a failure while moving them into place
    leaves the previous set exactly as it was and no staging or backup file behind."""
    import core.formats.mesh_io as mesh_io

    face = make_grid_face(6)
    face = Face(face.vertices, face.triangles, uv=face.vertices[:, :2] / 10.0,
                texture=np.full((8, 8, 3), 40, np.uint8))
    path = tmp_path / f"head{suffix}"
    save_face(face, path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert set(before) == {path.name, *(path.with_suffix(c).name for c in companions)}

    changed = Face(face.vertices + 1.0, face.triangles, uv=face.uv, texture=np.full((8, 8, 3), 200, np.uint8))
    real_replace = os.replace

    def fail_on_the_mesh(src, dst):
        if str(dst) == str(path) and str(src).endswith(".tmp"):
            raise OSError(28, "No space left on device")
        return real_replace(src, dst)

    monkeypatch.setattr(mesh_io.os, "replace", fail_on_the_mesh)
    with pytest.raises(mesh_io.MeshSaveError, match="No space left"):
        save_face(changed, path)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before, "the old set, nothing else"
    monkeypatch.setattr(mesh_io.os, "replace", real_replace)
    save_face(changed, path)
    assert {p.name for p in tmp_path.iterdir()} == set(before)
    reloaded = load_face(path)
    np.testing.assert_allclose(reloaded.vertices, changed.vertices, atol=1e-6)
    assert reloaded.texture is not None and int(reloaded.texture.mean()) == 200
