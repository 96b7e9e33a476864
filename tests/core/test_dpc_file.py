"""core.formats.dpc_file: thesis B control-point dynamics files (round trip, tolerated quirks, line-numbered errors)."""

from __future__ import annotations

import numpy as np
import pytest

from core.formats.dpc_file import DpcFileError, DpcSequence, control_points, format_dpc, parse_dpc, read_dpc, write_dpc

# The example printed in thesis B §5.2 (3 control points shown per frame), with its annotations.
THESIS_EXAMPLE = """\
2                # Total de quadros

1.0  2.0  0.0    #
1.1  0.0  0.5    # Primeiro Quadro
0.0 -3.0  3.0    #

2.0  2.0  0.0    #
0.0 -1.0  3.0    # Segundo Quadro
0.0 -3.0  3.0    #
"""


def test_thesis_example_reads_as_two_frames_of_three_points():
    seq = parse_dpc(THESIS_EXAMPLE)
    assert (seq.n_frames, seq.n_points) == (2, 3)
    np.testing.assert_array_equal(seq.displacements[0], [[1.0, 2.0, 0.0], [1.1, 0.0, 0.5], [0.0, -3.0, 3.0]])
    np.testing.assert_array_equal(seq.displacements[1, 1], [0.0, -1.0, 3.0])
    assert seq.names == ("cp1", "cp2", "cp3") and seq.feature_points == (None, None, None)
    assert seq.fps is None and "cp1..cp3" in seq.notes[0]
    with pytest.raises(ValueError, match="no frame rate"):
        seq.times()
    np.testing.assert_allclose(seq.times(10), [0.0, 0.1])


def test_default_table_names_a_29_point_file_and_maps_feature_points():
    table = control_points()
    assert len(table) == 29 and [p.index for p in table] == list(range(1, 30))
    rng = np.random.default_rng(3)
    values = np.round(rng.normal(0, 2, (4, 29, 3)), 3)
    text = "4\n" + "".join("\n" + "\n".join(" ".join(map(str, p)) for p in frame) + "\n" for frame in values)
    seq = parse_dpc(text)
    assert seq.names == tuple(p.name for p in table) and not seq.notes
    assert seq.feature_points[seq.names.index("mouth_corner_l")] == "8.3"
    np.testing.assert_array_equal(seq.points["mouth_corner_l"], values[:, 21])
    np.testing.assert_array_equal(seq.by_feature_point()["4.1"], values[:, 0])


def test_table_points_are_feature_points_of_the_default_face():
    import resources
    from core.default_face import load_default_face

    known = {row["fp"] for row in resources.get_table("mpeg4/feature_points.csv")}
    table = control_points()
    assert {p.fp for p in table} <= known
    assert len({p.fp for p in table}) == len({p.name for p in table}) == len(table)
    assert {p.fp for p in table} <= set(load_default_face().landmark_names)


def test_eight_point_file_is_the_mouth_set():
    text = "1\n" + "0 0 0\n" * 8
    seq = parse_dpc(text)
    assert seq.names == tuple(p.name for p in control_points("mouth"))
    assert seq.feature_points == ("8.1", "8.2", "8.3", "8.4", "8.5", "8.6", "8.7", "8.8")
    assert "mouth" in seq.notes[0]


def test_round_trip_with_metadata_and_bare(tmp_path):
    rng = np.random.default_rng(0)
    disp = rng.normal(0, 3, (5, 4, 3))
    disp[0, 0] = [1.0, -0.0, 2.5]
    seq = DpcSequence(disp, ("a", "b", "mouth_corner_l", "8.4"), (None, "9.3", "8.3", "8.4"), fps=25)
    path = tmp_path / "take.dpc"
    write_dpc(path, seq)
    back = read_dpc(path)
    np.testing.assert_allclose(back.displacements, disp, atol=5e-7)
    assert back.names == seq.names and back.feature_points == seq.feature_points and back.fps == 25.0
    assert back.notes == []
    text = path.read_text()
    assert "\n5\n\n1 0 2.5\n" in text  # count line, blank line, integers without a point, no '-0'
    bare = format_dpc(seq, metadata=False)
    assert "#" not in bare and bare.startswith("5\n\n")
    again = parse_dpc(bare, names=seq.names, fps=25)
    np.testing.assert_allclose(again.displacements, disp, atol=5e-7)
    # a name that is an MPEG-4 point maps to itself, table names to their point
    assert again.feature_points == (None, None, "8.3", "8.4")


def test_positions_from_rest():
    seq = DpcSequence(np.ones((2, 2, 3)), ("p", "q"))
    rest = {"p": (0.0, 0.0, 0.0), "q": (10.0, 0.0, 0.0)}
    np.testing.assert_array_equal(seq.positions(rest)[1], [[1, 1, 1], [11, 1, 1]])
    with pytest.raises(ValueError, match="no rest position"):
        seq.positions({"p": (0, 0, 0)})


def test_tolerated_quirks_are_noted():
    # no count line; frames separated by blank lines; CRLF, tabs
    seq = parse_dpc("1 2 3\r\n4\t5 6\r\n\r\n7 8 9\r\n1 1 1\r\n")
    assert (seq.n_frames, seq.n_points) == (2, 2) and "no frame-count line" in seq.notes[0]
    # the count disagrees with the data: everything is read
    seq = parse_dpc("3\n\n1 2 3\n\n4 5 6\n")
    assert seq.n_frames == 2 and "says 3 frames" in seq.notes[0]
    # decimal commas (a Portuguese locale) and comma-separated numbers
    seq = parse_dpc("1\n1,5 0,0 -2,25\n")
    np.testing.assert_array_equal(seq.displacements[0, 0], [1.5, 0.0, -2.25])
    assert any("decimal commas" in n for n in seq.notes)
    seq = parse_dpc("1\n1.5,0,2\n0.5;1;2\n")
    np.testing.assert_array_equal(seq.displacements[0], [[1.5, 0, 2], [0.5, 1, 2]])
    # 2-D tracking output: dz = 0
    seq = parse_dpc("2\n1 2\n3 4\n")
    np.testing.assert_array_equal(seq.displacements[:, 0], [[1, 2, 0], [3, 4, 0]])
    assert any("2-D" in n for n in seq.notes)
    # frame count from n_points when the file has no blank lines
    seq = parse_dpc("2\n" + "1 2 3\n" * 6, n_points=3)
    assert (seq.n_frames, seq.n_points) == (2, 3)
    # without blank lines, the count alone splits the frames
    assert parse_dpc("2\n" + "1 2 3\n" * 6).n_points == 3


def test_utf16_and_bom_files(tmp_path):
    path = tmp_path / "u16.dpc"
    path.write_bytes("1\n1 2 3\n".encode("utf-16"))
    seq = read_dpc(path)
    assert seq.displacements.shape == (1, 1, 3) and "UTF-16" in seq.notes[0]
    path.write_bytes(b"\xef\xbb\xbf1\n1 2 3\n")
    assert read_dpc(path).n_frames == 1


@pytest.mark.parametrize("text, message", [
    ("", "no data"),
    ("# only a comment\n", "no data"),
    ("two\n1 2 3\n", "line 1: the first line must be the number of frames"),
    ("-1\n1 2 3\n", "line 1: the first line must be the number of frames"),
    ("2\n", "line 1: the file says 2 frames but has no control-point lines"),
    ("1\n1 2 x\n", "line 2: 'x' is not a number"),
    ("1\n1 2 nan\n", "line 2: 'nan' is not a number"),
    ("1\n1 2 3 4\n", "line 2: expected 3 numbers"),
    ("1\n1 2 3\n4 5\n", "line 3: expected 3 numbers .* found 2"),
    ("2\n\n1 2 3\n1 2 3\n\n1 2 3\n", "line 6: the last frame has 1 of 2"),
    ("3\n\n1 2 3\n1 2 3\n\n1 2 3\n\n1 2 3\n1 2 3\n", "line 6: frame 2 .* has 1 control-point lines"),
    ("2\n1 2 3\n1 2 3\n1 2 3\n", "says 2 frames but has 3 control-point lines"),
    ("1 2 3\n4 5 6\n", "cannot tell how many control points"),
    ("# points a b\n1\n1 2 3\n", "line 3: the last frame has 1 of 2"),  # the names fix the count
    ("# feature_points 99.9\n1\n1 2 3\n", "line 1: '99.9' is not an MPEG-4 feature point"),
    ("# fps fast\n1\n1 2 3\n", "line 1: the frame rate"),
])
def test_errors_name_the_line(text, message):
    with pytest.raises(DpcFileError, match=message):
        parse_dpc(text, source="take.dpc" if "points" in text else "<text>")


def test_errors_name_the_file(tmp_path):
    path = tmp_path / "smile.dpc"
    path.write_text("1\n1 2\n1 2 3\n")
    with pytest.raises(DpcFileError, match=r"'smile.dpc', line 2: expected 3 numbers"):
        read_dpc(path)
    with pytest.raises(DpcFileError, match="does not exist"):
        read_dpc(tmp_path / "missing.dpc")
    with pytest.raises(DpcFileError, match="is a folder"):
        read_dpc(tmp_path)
    path.write_bytes(b"\x00\x01\x02binary")
    with pytest.raises(DpcFileError, match="not a text file"):
        read_dpc(path)


def test_names_must_match_the_file():
    with pytest.raises(DpcFileError, match="line 1: the '# points' comment names 2"):
        parse_dpc("# points a b\n1\n1 2 3\n", n_points=1)
    with pytest.raises(DpcFileError, match="last frame has 1 of 2"):
        parse_dpc("1\n1 2 3\n1 2 3\n1 2 3\n", names=["a", "b"])
    with pytest.raises(DpcFileError, match="single words"):
        parse_dpc("1\n1 2 3\n", names=["left corner"])
    with pytest.raises(DpcFileError, match="named twice"):
        parse_dpc("1\n1 2 3\n1 2 3\n", names=["a", "a"])


def test_writer_refuses_bad_values_and_folders(tmp_path):
    seq = DpcSequence(np.zeros((2, 1, 3)), ("a",))
    seq.displacements[1, 0, 2] = np.inf
    with pytest.raises(DpcFileError, match="frame 2: control point 'a' has dz = inf"):
        format_dpc(seq)
    with pytest.raises(DpcFileError, match="does not exist"):
        write_dpc(tmp_path / "nope" / "x.dpc", DpcSequence(np.zeros((1, 1, 3)), ("a",)))
    with pytest.raises(ValueError, match="shape"):
        DpcSequence(np.zeros((2, 3)), ("a",))
