"""Thesis B's PPC (control-point positions) and EPC (emotions) files, and DPC export of control-point tracks:
round trips, tolerant reading, line-numbered errors that change nothing."""

from __future__ import annotations

import numpy as np
import pytest

from core.formats.dpc_file import read_dpc, write_dpc
from core.formats.epc_file import EpcEmotion, EpcFileError, parse_epc, read_epc, write_epc
from core.formats.ppc_file import ControlPointPositions, PpcFileError, parse_ppc, read_ppc, write_ppc
from core.layers.rbf.files import apply_frame, dpc_from_timeline, keys_from_dpc, ppc_of
from core.layers.rbf.layer import ControlPointLayer
from core.parameters import ParameterError
from core.timeline import Timeline


@pytest.fixture(scope="module")
def face():
    from core.default_face import load_default_face

    return load_default_face()


@pytest.fixture
def layer(face):
    return ControlPointLayer(face)


def test_ppc_round_trips_a_layers_points(layer, tmp_path):
    ppc = ppc_of(layer)
    write_ppc(tmp_path / "face.ppc", ppc)
    back = read_ppc(tmp_path / "face.ppc")
    assert back.names == layer.points.names and back.feature_points == layer.points.feature_points
    np.testing.assert_allclose(back.positions, ppc.positions, atol=1e-6)
    assert back.notes == []


def test_ppc_reads_the_tolerated_spellings():
    bare = "\n".join(f"{i},5 0 -{i}" for i in range(29))
    ppc = parse_ppc(bare)
    assert ppc.names[0] == "brow_inner_l" and ppc.feature_points[-1] == "2.1"
    assert ppc.positions[3].tolist() == [3.5, 0.0, -3.0]
    assert any("decimal commas" in n for n in ppc.notes) and any("unnamed" in n for n in ppc.notes)
    named = parse_ppc("\ufeff# a comment\r\n3\r\nmouth_corner_l 24 -34 -33\r\nchin; 0; -66; -22\r\n")
    assert named.names == ("mouth_corner_l", "chin") and named.feature_points == ("8.3", "2.10")
    assert any("says 3 control points" in n for n in named.notes)


@pytest.mark.parametrize("text, message", [
    ("2\nchin 2.10 0 1 2\nlip_upper_mid 8.1 0 x 2\n", "line 3: 'x' is not a number"),
    ("chin 2.10 0 1 2\nchin 2.1 0 1 3\n", "line 2: the control point 'chin' is already on line 1"),
    ("chin 77.7 0 1 2\n", "line 1: '77.7' is not an MPEG-4 feature point"),
    ("chin 0 1 2\n1 2 3\n", "line 2: some lines name their control point"),
    ("chin 0 1\n", "line 1: 'chin' is not a number; expected 'name fp x y z'"),
    ("a b chin 0 1 2\n", "line 1: expected 'name fp x y z', found 6 words"),
    ("# only a comment\n", "no control points"),
    ("1 2 3\n4 5 6\n", "2 unnamed control points"),
])
def test_malformed_ppc_says_where(text, message):
    with pytest.raises(PpcFileError, match=message.replace("(", r"\(")):
        parse_ppc(text, source="bad.ppc")


def test_a_ppc_moves_the_points_and_a_bad_one_changes_nothing(layer, tmp_path):
    layer.set_values({"cp:8.3:y": 2.0})
    before = (layer.deformer, layer.parameters(), layer.value("cp:8.3:y"))
    (tmp_path / "bad.ppc").write_text("mouth_corner_l 24 -34 -33\nnot_a_point 1 2 3\n")
    with pytest.raises(ParameterError, match="unknown control points not_a_point"):
        layer.place_points(read_ppc(tmp_path / "bad.ppc").as_dict())
    (tmp_path / "broken.ppc").write_text("mouth_corner_l 24 -34\n")
    with pytest.raises(PpcFileError, match="line 1"):
        read_ppc(tmp_path / "broken.ppc")
    assert (layer.deformer, layer.parameters(), layer.value("cp:8.3:y")) == before
    # Only the 8 mouth points, the left corner 3 mm further out: the layer has their 24 keys now.
    mouth = ["lip_upper_mid", "lip_lower_mid", "mouth_corner_l", "mouth_corner_r", "lip_upper_l", "lip_upper_r",
             "lip_lower_l", "lip_lower_r"]
    pos = {n: p for n, p in layer.positions().items() if n in mouth}
    pos["mouth_corner_l"] = pos["mouth_corner_l"] + [3.0, 0, 0]
    old_corner = layer.points.vertices[layer.points.names.index("mouth_corner_l")]
    layer.place_points(pos)
    assert len(layer.parameters()) == 24 and layer.value("cp:8.3:y") == 2.0
    corner = layer.points.vertices[layer.points.names.index("mouth_corner_l")]
    assert corner != old_corner and np.linalg.norm(layer.face.vertices[corner] - pos["mouth_corner_l"]) < 2.0
    np.testing.assert_allclose(layer.offset(None)[corner], [0, 2.0, 0], atol=1e-9)


def test_epc_round_trips_and_names_itself(tmp_path):
    rng = np.random.default_rng(0)
    emo = EpcEmotion("smirk", rng.normal(0, 2, (2, 3, 3)).round(3), ("chin", "mouth_corner_l", "nose_tip"),
                     ("2.10", "8.3", "9.3"), (12, 14))
    write_epc(tmp_path / "x.epc", emo)
    back = read_epc(tmp_path / "x.epc")
    assert (back.name, back.names, back.feature_points, back.aus) == ("smirk", emo.names, emo.feature_points, (12, 14))
    np.testing.assert_array_equal(back.frames, emo.frames)
    (tmp_path / "grin.epc").write_text("1\n0 1 0\n0 2 0\n" + "0 0 0\n" * 27)
    assert read_epc(tmp_path / "grin.epc").name == "grin"


@pytest.mark.parametrize("text, message", [
    ("1\n0 1 0\n0 1\n0 0 0\n", "line 3"),
    ("# aus 1 six\n1\n" + "0 0 0\n" * 29, "line 1: '# aus' lists FACS action units"),
    ("1\n0 1 zero\n", "line 2: 'zero' is not a number"),
])
def test_malformed_epc_says_where(text, message):
    with pytest.raises(EpcFileError, match=message):
        parse_epc(text, source="bad.epc")


def test_dpc_export_of_control_point_tracks_round_trips(layer, tmp_path):
    tl = Timeline(duration=0.4, fps=25)
    tl.add_keys({"cp:8.3:y": [(0.0, 0.0, "linear"), (0.4, 5.0, "linear")],
                 "cp:4.1:x": [(0.0, 1.0, "linear"), (0.2, -1.0, "linear")]})
    seq = dpc_from_timeline(tl, layer)
    assert seq.displacements.shape == (11, 29, 3) and seq.fps == 25
    corner = layer.points.names.index("mouth_corner_l")
    np.testing.assert_allclose(seq.displacements[:, corner, 1], np.linspace(0, 5, 11))
    write_dpc(tmp_path / "anim.dpc", seq)
    back = read_dpc(tmp_path / "anim.dpc")
    np.testing.assert_allclose(back.displacements, seq.displacements, atol=1e-6)
    tl2 = Timeline(duration=0.4, fps=25)
    tl2.add_keys(keys_from_dpc(back))
    np.testing.assert_allclose(dpc_from_timeline(tl2, layer).displacements, seq.displacements, atol=1e-6)
    apply_frame(layer, back, 5)
    assert layer.value("cp:8.3:y") == pytest.approx(2.5) and layer.value("cp:4.1:x") == pytest.approx(-1.0)
    with pytest.raises(ParameterError, match="frame rate"):
        keys_from_dpc(type(back)(back.displacements, back.names, back.feature_points, None))


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_TOKENS = st.sampled_from(["chin", "2.10", "8.3", "mouth_corner_l", "1", "-2.5", "1,5", "nan", "inf", "1e400", "x",
                           "#", "# aus 1 x", "# emotion joy", "# points chin", ";", ",", "-", "\t", "\ufeff", "0"])
_TEXTS = st.lists(st.lists(_TOKENS, max_size=6).map(" ".join), max_size=12).map("\n".join)


@settings(max_examples=150, deadline=None, derandomize=True, database=None)
@given(_TEXTS)
def test_ppc_and_epc_readers_raise_only_their_own_errors(text):
    try:
        ppc = parse_ppc(text, source="f.ppc")
        assert np.isfinite(ppc.positions).all() and len(ppc.names) == len(ppc.positions)
    except PpcFileError as exc:
        assert str(exc)
    try:
        emo = parse_epc(text, source="f.epc")
        assert np.isfinite(emo.frames).all() and emo.frames.shape[1] == len(emo.names)
    except EpcFileError as exc:
        assert str(exc)
