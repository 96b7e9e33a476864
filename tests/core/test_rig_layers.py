"""The rig's layer protocol and parameter registry, proved with a layer the rest of core never saw
(tests/offset_layer.py): the timeline keys it, a project saves and reloads it, the headless
animation renders it, snapshots restore it."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import offset_layer  # noqa: E402,F401 - registers the offset:z kind and its layer

from core import parameters as P  # noqa: E402
from core.animation import ProjectAnimation  # noqa: E402
from core.formats.project import FaceRef, Project, RigSettings, load_project, save_project  # noqa: E402
from core.rig import FaceRig  # noqa: E402
from core.timeline import Timeline, TimelineError, Track  # noqa: E402


@pytest.fixture
def rig(default_rig):
    default_rig.reset()
    yield default_rig
    default_rig.remove_layer("offset")
    default_rig.reset()


def test_every_old_spelling_is_one_key():
    assert {P.key_of(s) for s in (3, "3", "open_jaw", "fap:open_jaw", "FAP:3")} == {"fap:3"}
    assert P.key_of(("risorius", "left")) == P.key_of("muscle:risorius:left") == "muscle:risorius:left"
    assert P.key_of(("orbicularis_oris", None)) == "muscle:orbicularis_oris"
    assert P.key_of("jaw") == "jaw" and P.key_of("expression:JOY") == "expression:joy"
    assert P.describe("fap:3").label == "3 open jaw" and P.describe("fap:3").unit == "MNS"
    with pytest.raises(P.ParameterError, match="unknown parameter"):
        P.key_of("eyebrow:3")
    with pytest.raises(P.ParameterError, match="outside its range"):
        P.check_value("muscle:risorius:left", 1e300)



def test_each_parameter_names_its_mirror_and_says_what_it_does():
    """"Link left/right" in both docks moves a parameter's mirror: the registry names it, both ways."""
    from core.layers.fap import tables
    from core.layers.muscles import control_keys

    keys = [f"fap:{s.number}" for s in tables.fap_specs() if s.dock] + [P.key_of(k) for k in control_keys()]
    keys.append("jaw")
    for key in keys:
        p = P.describe(key)
        assert p.description, key
        if p.mirror is not None:
            assert P.describe(p.mirror).mirror == key and P.describe(p.mirror).unit == p.unit
    assert P.describe("fap:6").mirror == "fap:7" and P.describe("fap:3").mirror is None
    assert P.describe("muscle:risorius:left").mirror == "muscle:risorius:right"
    assert P.describe("muscle:orbicularis_oris").mirror is None and P.describe("jaw").mirror is None
    assert "2.1" in P.describe("fap:3").description and "down" in P.describe("fap:3").description

def test_events_carry_keys_and_values(rig):
    seen = []
    rig.parameters_changed.connect(seen.append)
    try:
        rig.set_values({"open_jaw": 300, "expression:joy": 0.5})
        rig.set_values({"open_jaw": 300})            # no change, no event
    finally:
        rig.parameters_changed.disconnect(seen.append)
    assert len(seen) == 1
    assert dict(seen[0].values) == {"fap:3": 300.0, "expression:joy": 0.5}
    assert dict(seen[0].previous) == {"fap:3": 0.0, "expression:joy": 0.0}


def test_invalid_values_change_nothing(rig):
    before = rig.snapshot()
    with pytest.raises(P.ParameterError, match="outside its range"):
        rig.set_values({"fap:3": 100, "fap:19": 1e9})
    assert rig.snapshot() == before


def test_a_new_layer_composes_snapshots_and_copies(rig):
    plain = rig.vertices().copy()
    assert rig.ensure_layers(["offset:z"]) == ["offset"]
    rig.set_values({"offset:z": 2.5, "fap:3": 400})
    moved = rig.vertices()
    jaw_only = FaceRig(rig.face, rig.deformer)
    jaw_only.set_fap(3, 400)
    np.testing.assert_allclose(moved - jaw_only.vertices(), np.broadcast_to([0, 0, 2.5], plain.shape), atol=1e-9)
    snap = rig.snapshot()
    twin = rig.copy()
    rig.set_values({"offset:z": -1.0, "fap:3": 0})
    np.testing.assert_array_equal(twin.vertices(), moved)        # the copy is independent
    rig.restore(snap)
    np.testing.assert_array_equal(rig.vertices(), moved)


def test_timeline_keys_and_the_animation_renders_a_new_layer(rig):
    tl = Timeline(2.0, 30)
    tl.add_keys({"offset:z": [(0.0, 0.0), (1.0, 4.0, "linear")]})
    with pytest.raises(TimelineError, match="outside its range -10 to 10"):
        Track("offset:z", [(0.0, 11.0)])
    animation = ProjectAnimation(rig.copy(), tl)
    assert animation.rig.layer("offset") is not None             # built from its registration
    dz = animation.vertices(0.5)[:, 2] - rig.face.vertices[:, 2]
    np.testing.assert_allclose(dz, 2.0, atol=1e-9)
    assert rig.layer("offset") is None                          # the rig it was copied from is untouched


def test_a_project_saves_and_reloads_a_new_layer(rig, tmp_path):
    rig.ensure_layers(["offset:z"])
    rig.set_values({"offset:z": -3.25, "fap:3": 120.0})
    path = tmp_path / "offset.mimica"
    save_project(path, Project.from_state(rig.face, FaceRef.default_face(), rig))
    assert '"offset:z": -3.25' in path.read_text(encoding="utf-8")
    fresh = FaceRig(rig.face, rig.deformer)
    assert load_project(path).rig.apply(fresh) == {}
    assert fresh.value("offset:z") == -3.25 and fresh.value("fap:3") == 120.0
    np.testing.assert_array_equal(fresh.vertices(), rig.vertices())
    assert RigSettings.from_rig(fresh) == RigSettings({"fap:3": 120.0, "offset:z": -3.25})


def test_a_range_a_face_may_widen_is_kept_by_keys_and_files_and_checked_by_each_rig(rig, tmp_path):
    """fap:19's table range is -300..1024, but an eye closed at rest (a scan taken with it shut) opens
    to -1324: a key or a file may hold such a value (it is not tied to one face); each rig checks it
    against its own face's range and says so."""
    p = P.describe("fap:19")
    assert (p.minimum, p.maximum, p.outer) == (-300.0, 1024.0, (-1324.0, 1024.0))
    assert P.describe("fap:21").outer is None                      # the lower lids keep the table's
    assert P.check_value("fap:19", -900) == -900.0
    with pytest.raises(P.ParameterError, match="outside its range -1324 to 1024"):
        P.check_value("fap:19", -1400)
    timeline = Timeline(2.0, 30)
    timeline.replace_tracks({"fap:19": Track("fap:19", [(0.0, 0.0), (1.0, -900.0)])})
    path = tmp_path / "closed_eye_take.mimica"
    save_project(path, Project.from_state(rig.face, FaceRef.default_face(), rig, timeline))
    assert list(load_project(path).timeline.tracks["fap:19"].values) == [0.0, -900.0]
    with pytest.raises(P.ParameterError, match="outside its range -300 to 1024"):   # the default face's eyes are open
        rig.set_values({"fap:19": -900.0})
    assert rig.describe("fap:19") == p and rig.value("fap:19") == 0.0
