"""core.landmark_editing: status transitions, selection, mirror suggestion, JSON/CSV files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.face import Face, SurfacePoint
from core.landmark_editing import (
    LandmarkEditError,
    LandmarkEditModel,
    LandmarkFileError,
    LandmarkState,
    LandmarkStatus,
    fp_sort_key,
    mirror_pairs,
)


def symmetric_face(rotation=None, shift=(0.0, 0.0, 0.0)) -> Face:
    """Front of an ellipsoid, exactly mirror-symmetric about x = 0 (vertex i <-> its mirror),
    optionally rotated and shifted as a whole."""
    n_u, n_v = 31, 25  # odd: a column of vertices on x = 0
    th, ph = np.meshgrid(np.linspace(-1.3, 1.3, n_u), np.linspace(-1.2, 1.2, n_v))
    v = np.stack([70 * np.sin(th) * np.cos(ph), 100 * np.sin(ph), 60 * np.cos(th) * np.cos(ph)], -1).reshape(-1, 3)
    idx = np.arange(n_u * n_v).reshape(n_v, n_u)
    a0, a1, b0, b1 = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.concatenate([np.stack([a0, a1, b1], 1), np.stack([a0, b1, b0], 1)])
    if rotation is not None:
        v = v @ np.asarray(rotation).T
    v = v + np.asarray(shift)
    face = Face(v, tris)
    # Mirror pairs and a midline point, all exactly on vertices.
    spots = {"8.3": (5, 15 + 6), "8.4": (5, 15 - 6), "3.7": (17, 15 + 9), "3.12": (17, 15 - 9),
             "4.1": (20, 15 + 3), "4.2": (20, 15 - 3), "9.3": (12, 15), "2.1": (1, 15)}
    for name, (row, col) in spots.items():
        face.set_landmark(name, vertex_point(face, idx[row, col]))
    return face


def vertex_point(face: Face, vertex: int) -> SurfacePoint:
    """The SurfacePoint exactly at ``vertex``."""
    tri = int(np.nonzero((face.triangles == vertex).any(axis=1))[0][0])
    bary = [0.0, 0.0, 0.0]
    bary[list(face.triangles[tri]).index(vertex)] = 1.0
    return SurfacePoint(tri, tuple(bary))


def grid_index(row: int, col: int) -> int:
    return row * 31 + col


@pytest.fixture
def model() -> LandmarkEditModel:
    return LandmarkEditModel(symmetric_face())


# ---------------------------------------------------------------- statuses and selection
def test_initial_state_order_and_writes_back(model):
    assert model.names == ["2.1", "3.7", "3.12", "4.1", "4.2", "8.3", "8.4", "9.3"]
    assert all(s is LandmarkStatus.AUTO for s in model.statuses())
    assert model.confidence("8.3") is None
    assert fp_sort_key("2.10") > fp_sort_key("2.9")


def test_move_confirm_status_transitions(model):
    events = []
    model.changed.connect(events.append)
    target = vertex_point(model.face, grid_index(6, 22))
    model.set_state("8.3", LandmarkState(model.point("8.3"), LandmarkStatus.AUTO, 0.8))
    model.move("8.3", target)
    assert model.status("8.3") is LandmarkStatus.EDITED
    assert model.confidence("8.3") is None  # the detector's score no longer applies
    assert model.face.landmarks["8.3"] == target  # written back into the face
    np.testing.assert_allclose(model.position("8.3"), model.face.vertices[grid_index(6, 22)])
    model.confirm("8.3")
    assert model.status("8.3") is LandmarkStatus.CONFIRMED
    assert model.point("8.3") == target
    model.move("8.3", vertex_point(model.face, grid_index(6, 21)))
    assert model.status("8.3") is LandmarkStatus.EDITED  # confirmed -> edited on a move
    model.confirm("9.3")
    assert events == ["8.3", "8.3", "8.3", "8.3", "9.3"]
    assert model.fixed_points().keys() == {"8.3", "9.3"}
    counts = model.counts()
    assert (counts[LandmarkStatus.AUTO], counts[LandmarkStatus.EDITED], counts[LandmarkStatus.CONFIRMED]) == (6, 1, 1)
    changed = model.confirm_all()
    assert sorted(changed) == sorted(set(model.names) - {"9.3"})
    assert events[-1] == ""
    assert model.counts()[LandmarkStatus.CONFIRMED] == 8


def test_bad_requests_raise(model):
    with pytest.raises(LandmarkEditError, match="no landmark named 'x'"):
        model.move("x", SurfacePoint(0, (1, 0, 0)))
    with pytest.raises(LandmarkEditError, match="triangle 99999 does not exist"):
        model.move("8.3", SurfacePoint(99999, (1, 0, 0)))
    with pytest.raises(LandmarkEditError, match="no landmark"):
        model.select("nope")


def test_selection_next_previous_wraps(model):
    seen = []
    model.selection_changed.connect(seen.append)
    assert model.select_next() == "2.1"
    assert model.select_next() == "3.7"
    assert model.select_next(-1) == "2.1"
    assert model.select_next(-1) == "9.3"  # wraps
    model.select(None)
    assert seen == ["2.1", "3.7", "2.1", "9.3", None]


def test_restore_snapshot_exactly_and_removes_added_names(model):
    before = model.snapshot()
    model.move("8.3", vertex_point(model.face, grid_index(7, 20)))
    model.set_state("11.1", LandmarkState(vertex_point(model.face, grid_index(22, 15))))
    assert "11.1" in model.names and "11.1" in model.face.landmarks
    events = []
    model.changed.connect(events.append)
    model.restore(before)
    assert model.snapshot() == before
    assert "11.1" not in model.face.landmarks
    assert events == [""]


def test_apply_detection_keeps_user_landmarks(model):
    mine = vertex_point(model.face, grid_index(6, 20))
    model.move("8.3", mine)
    model.confirm("9.3")
    detected = {n: vertex_point(model.face, grid_index(3, 3)) for n in ("8.3", "8.4", "9.3", "5.1")}
    changed = model.apply_detection(detected, {"8.4": 0.25, "5.1": 0.5})
    assert sorted(changed) == ["5.1", "8.4"]
    assert model.point("8.3") == mine and model.status("8.3") is LandmarkStatus.EDITED
    assert model.status("9.3") is LandmarkStatus.CONFIRMED
    assert model.point("8.4") == detected["8.4"] and model.confidence("8.4") == 0.25
    assert model.status("5.1") is LandmarkStatus.AUTO and "5.1" in model.names


# ---------------------------------------------------------------- mirror
def test_mirror_pairs_table():
    pairs = mirror_pairs()
    assert pairs["8.3"] == "8.4" and pairs["8.4"] == "8.3"
    assert pairs["3.7"] == "3.12" and pairs["3.11"] == "3.8"  # outer/inner eye corners
    assert pairs["8.10"] == "8.9"
    assert "9.3" not in pairs and "2.1" not in pairs


def test_mid_sagittal_plane_of_symmetric_face(model):
    origin, normal = model.mid_sagittal_plane()
    np.testing.assert_allclose(normal, [1.0, 0.0, 0.0], atol=1e-12)
    assert abs(origin[0]) < 1e-9
    assert model.mirror_partner("8.3") == "8.4" and model.mirror_partner("9.3") is None


@pytest.mark.parametrize("tilted", [False, True])
def test_suggest_mirror_reflects_a_known_point(tilted):
    if tilted:  # the whole face turned 20 degrees about y and 10 about z, and moved
        a, b = np.radians(20.0), np.radians(10.0)
        ry = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        rz = np.array([[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]])
        face = symmetric_face(rz @ ry, shift=(12.0, -30.0, 5.0))
    else:
        face = symmetric_face()
    model = LandmarkEditModel(face)
    # The user moves 8.3 somewhere else; its mirror vertex is known by construction.
    model.move("8.3", vertex_point(face, grid_index(8, 15 + 11)))
    expected = face.vertices[grid_index(8, 15 - 11)]
    suggestion = model.suggest_mirror("8.3")
    suggested = np.einsum("j,jd->d", suggestion.barycentric, face.vertices[face.triangles[suggestion.triangle]])
    np.testing.assert_allclose(suggested, expected, atol=1e-6)
    assert np.linalg.norm(expected - model.position("8.4")) > 10.0  # not just the old partner


def test_plane_falls_back_without_pairs():
    face = symmetric_face()
    for name in list(face.landmark_names):
        if name not in ("9.3", "2.1"):
            face.remove_landmark(name)
    origin, normal = LandmarkEditModel(face).mid_sagittal_plane()
    np.testing.assert_allclose(normal, [1, 0, 0])
    assert abs(origin[0]) < 1e-9


# ---------------------------------------------------------------- files
def test_json_round_trip_with_status_and_confidence(model, tmp_path):
    model.move("8.3", vertex_point(model.face, grid_index(6, 22)))
    model.confirm("9.3")
    model.set_state("2.1", LandmarkState(model.point("2.1"), LandmarkStatus.AUTO, 0.75))
    path = tmp_path / "marks.json"
    model.save_json(path)
    document = json.loads(path.read_text())
    assert document["format"] == "mimica-landmarks"
    fresh = LandmarkEditModel(symmetric_face())
    notes = []
    names = fresh.load_json(path, notes=notes)
    assert notes == [] and sorted(names) == sorted(model.names)
    assert fresh.snapshot() == model.snapshot()


def test_csv_round_trip(model, tmp_path):
    model.move("8.3", vertex_point(model.face, grid_index(6, 22)))
    model.set_state("4.1", LandmarkState(model.point("4.1"), LandmarkStatus.CONFIRMED, 0.5))
    path = tmp_path / "marks.csv"
    model.save_csv(path)
    lines = path.read_text().splitlines()
    assert lines[0] == "name,x,y,z,status,confidence"
    assert len(lines) == 1 + len(model)
    fresh = LandmarkEditModel(symmetric_face())
    fresh.load_csv(path)
    for name in model.names:
        np.testing.assert_allclose(fresh.position(name), model.position(name), atol=1e-5)
        assert fresh.status(name) is model.status(name)
        assert fresh.confidence(name) == model.confidence(name)


@pytest.mark.parametrize("body, message", [
    ("", "is empty"),
    ("name,x,y\n", "expected the header"),
    ("name,x,y,z,status,confidence\n", "has a header but no landmarks"),
    ("name,x,y,z,status,confidence\n8.3,1,2,3,auto,\n8.4,1,2\n", "line 3: expected 6 values"),
    ("name,x,y,z,status,confidence\n# comment\n8.3,1,abc,3,auto,\n", "line 3: y is not a number \\('abc'\\)"),
    ("name,x,y,z,status,confidence\n8.3,1,2,nan,auto,\n", "line 2: z must be a finite number"),
    ("name,x,y,z,status,confidence\n8.3,1,2,3,maybe,\n", "line 2: status must be one of auto, edited, confirmed"),
    ("name,x,y,z,status,confidence\n8.3,1,2,3,auto,high\n", "line 2: confidence must be a number"),
    ("name,x,y,z,status,confidence\n8.3,1,2,3,auto,\n\n8.3,1,2,3,auto,\n", "line 4: landmark '8.3' appears twice"
     " \\(first on line 2\\)"),
    ("name,x,y,z,status,confidence\n,1,2,3,auto,\n", "line 2: the landmark has no name"),
])
def test_malformed_csv_errors_name_the_line(model, tmp_path, body, message):
    path = tmp_path / "bad.csv"
    path.write_text(body)
    before = model.snapshot()
    with pytest.raises(LandmarkFileError, match=message):
        model.load_csv(path)
    assert model.snapshot() == before  # nothing applied


def test_csv_notes_points_off_the_surface_and_missing_file(model, tmp_path):
    path = tmp_path / "far.csv"
    x, y, z = model.face.vertices[grid_index(12, 15)]
    path.write_text(f"name,x,y,z,status,confidence\n9.3,{x},{y},{z + 10.0},edited,\n")
    notes = []
    states = model.read_csv(path, notes=notes)
    assert len(notes) == 1 and "9.3" in notes[0] and "10.0 mm off the surface" in notes[0]
    assert states["9.3"].status is LandmarkStatus.EDITED
    with pytest.raises(LandmarkFileError, match="does not exist"):
        model.read_csv(tmp_path / "missing.csv")


def test_json_bad_status_is_reported(model, tmp_path):
    path = tmp_path / "m.json"
    model.save_json(path)
    doc = json.loads(path.read_text())
    doc["landmarks"][0]["status"] = "perfect"
    path.write_text(json.dumps(doc))
    with pytest.raises(LandmarkFileError, match="landmark '2.1': status must be one of"):
        model.read_json(path)
