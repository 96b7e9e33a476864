"""Tests for core.formats.fap_file (textual MPEG-4 .fap files), on texts written in the tests."""

from __future__ import annotations

import re

import numpy as np
import pytest

from core.formats.fap_file import N_FAPS, FapFileError, FapSequence, format_fap, parse_fap, read_fap, write_fap

# The made-up example of the format note (3 frames at 25 fps), verbatim.
EXAMPLE = """\
# made-up example for documentation: 3 frames at 25 fps
2.1 demo_example 25 3
1 0 1 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
0 1 7 40 0 120
0 1 1 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 1 1 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
1 1 45 0 0 0 0 200 300 300
0 0 1 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 1 0 0 0 0 1 1 0 0 0 0 0 0 0 0 0 0 0 0 0 0
2 80 -8727 150 150
"""


def mask_line(*faps: int, entries: int = N_FAPS, sep: str = " ") -> str:
    """A mask line with 1 at the given FAP numbers (1-based) and ``entries`` entries in all."""
    bits = ["0"] * entries
    for fap in faps:
        bits[fap - 1] = "1"
    return sep.join(bits)


def replace_line(text: str, number: int, new: str) -> str:
    """``text`` with its 1-based line ``number`` replaced by ``new``."""
    lines = text.split("\n")
    lines[number - 1] = new
    return "\n".join(lines)


def assert_same_sequence(a: FapSequence, b: FapSequence):
    assert a.fps == b.fps
    np.testing.assert_array_equal(a.mask, b.mask)
    np.testing.assert_array_equal(a.values, b.values)  # NaN == NaN here
    np.testing.assert_array_equal(a.viseme, b.viseme)
    np.testing.assert_array_equal(a.expression, b.expression)


# ------------------------------------------------------------ reading
def test_made_up_example_is_read_with_known_values():
    seq = parse_fap(EXAMPLE)
    assert (seq.version, seq.name, seq.fps, seq.n_frames) == ("2.1", "demo_example", 25.0, 3)
    assert seq.duration == pytest.approx(0.12)
    assert seq.notes == []  # a comment line is normal, not a quirk
    assert seq.values.shape == seq.mask.shape == (3, N_FAPS)
    assert seq.values.dtype == np.float64 and seq.mask.dtype == bool
    np.testing.assert_array_equal(seq.mask[:, :2], [[True, False], [False, True], [False, False]])
    np.testing.assert_array_equal(seq.viseme, [[1, 7, 40, 0], [-1] * 4, [-1] * 4])
    np.testing.assert_array_equal(seq.expression, [[-1] * 6, [1, 45, 0, 0, 0, 0], [-1] * 6])
    assert seq.frame(0) == {3: 120.0}
    assert seq.frame(1) == {3: 200.0, 19: 300.0, 20: 300.0}
    assert seq.frame(2) == {3: 80.0, 48: -8727.0, 53: 150.0, 54: 150.0}
    assert np.isnan(seq.values[:, :2]).all()
    assert np.isnan(seq.values).sum() == 3 * N_FAPS - 8  # exactly the 8 low-level values are set
    np.testing.assert_array_equal(seq.mask[:, 2:], ~np.isnan(seq.values[:, 2:]))


def test_greta_style_file_69_entry_masks_one_token_fap1_fap2_name_with_spaces():
    text = (
        "2.1 Greta Welcome_1.fap 25 3\n"
        f"{mask_line(1, 3, entries=69)} \n"
        "0 4 120 \n"
        f"{mask_line(2, 3, 19, entries=69)} \n"
        "1 3 200 300 \n"
        f"{mask_line(3, entries=69)} \n"
        "2 -40 \n"
    )
    seq = parse_fap(text)
    assert seq.name == "Greta Welcome_1.fap"
    assert seq.n_frames == 3
    np.testing.assert_array_equal(seq.viseme[0], [4, 0, 63, 0])  # select1 at full blend
    np.testing.assert_array_equal(seq.expression[1], [3, 63, 0, 0, 0, 0])  # select1 at full intensity
    assert not seq.mask[0, 1] and not seq.mask[1, 0] and not seq.mask[2, :2].any()
    assert [seq.frame(k) for k in range(3)] == [{3: 120.0}, {3: 200.0, 19: 300.0}, {3: -40.0}]
    # one note per kind, not per line
    assert len(seq.notes) == 4
    assert sum("69" in note for note in seq.notes) == 1
    assert sum("FAP 1 (viseme) is written as one number" in note for note in seq.notes) == 1
    assert sum("FAP 2 (expression) is written as one number" in note for note in seq.notes) == 1
    assert sum("spaces" in note for note in seq.notes) == 1
    assert format_fap(seq).startswith("2.1 Greta_Welcome_1.fap 25 3\n")


def test_values_of_mask_entries_after_the_68th_are_dropped():
    text = f"2.1 g 25 1\n{mask_line(3, 69, entries=69)}\n0 120 7\n"
    seq = parse_fap(text)
    assert seq.frame(0) == {3: 120.0}
    assert any("after the 68th" in note and "line 3" in note for note in seq.notes)


def test_tab_separated_version_2_0_file_with_comments_is_read_without_vreng_division():
    text = (
        "# VREng-style file\n"
        "2.0\tjag\t5\t2\n"
        f"{mask_line(3, 48, sep=chr(9))}\t\n"
        "0\t100\t-2000\n"
        "   # a comment between frames\n"
        "\n"
        f"{mask_line(3, sep=chr(9))}\n"
        "1\t12.5\n"
    )
    seq = parse_fap(text)
    assert (seq.version, seq.name, seq.fps, seq.n_frames) == ("2.0", "jag", 5.0, 2)
    assert seq.frame(0) == {3: 100.0, 48: -2000.0}  # not divided by 20
    assert seq.frame(1) == {3: 12.5}
    assert seq.notes == []


def test_crlf_line_ends_and_trailing_spaces_read_like_lf():
    crlf = "\r\n".join(line + "  " for line in EXAMPLE.split("\n"))
    assert "\r\n" in crlf
    seq = parse_fap(crlf)
    assert_same_sequence(seq, parse_fap(EXAMPLE))
    assert seq.name == "demo_example" and seq.notes == []


def test_text_starting_with_a_byte_order_mark_is_read():
    seq = parse_fap("\ufeff2.1 bom 25 0\n")
    assert (seq.version, seq.name, seq.n_frames) == ("2.1", "bom", 0)


def test_float_fps_and_float_values():
    seq = parse_fap(f"2.1 x 29.97 1\n{mask_line(3, 4)}\n0 1.5 -2e2\n")
    assert seq.fps == 29.97
    assert seq.frame(0) == {3: 1.5, 4: -200.0}


def test_fewer_frames_than_the_header_says_are_kept_with_a_note():
    seq = parse_fap(EXAMPLE.replace("demo_example 25 3", "demo_example 25 5"))
    assert seq.n_frames == 3
    assert seq.frame(2) == {3: 80.0, 48: -8727.0, 53: 150.0, 54: 150.0}
    assert seq.notes == ["The header says 5 frames, file has 3."]


def test_more_frames_than_the_header_says_are_all_read_with_a_note():
    seq = parse_fap(EXAMPLE.replace("demo_example 25 3", "demo_example 25 2"))
    assert seq.n_frames == 3
    assert len(seq.notes) == 1 and "header says 2 frames, file has 3" in seq.notes[0]


def test_frame_numbers_from_1_are_kept_in_file_order_with_a_note():
    text = f"2.1 x 25 3\n{mask_line(3)}\n1 10\n{mask_line(3)}\n2 20\n{mask_line(3)}\n3 30\n"
    seq = parse_fap(text)
    np.testing.assert_array_equal(seq.values[:, 2], [10, 20, 30])
    assert len(seq.notes) == 1 and "start at 1 instead of 0" in seq.notes[0]


def test_skipped_frame_numbers_are_kept_in_file_order_with_a_note():
    text = f"2.1 x 25 3\n{mask_line(3)}\n0 10\n{mask_line(3)}\n2 20\n{mask_line(3)}\n5 30\n"
    seq = parse_fap(text)
    np.testing.assert_array_equal(seq.values[:, 2], [10, 20, 30])
    assert len(seq.notes) == 1 and "line 5 has frame number 2 where 1 was expected" in seq.notes[0]


def test_header_only_file_has_no_frames():
    seq = parse_fap("2.1 empty 25 0\n")
    assert seq.n_frames == 0 and seq.values.shape == (0, N_FAPS) and seq.viseme.shape == (0, 4)
    assert seq.notes == [] and seq.duration == 0.0


# ------------------------------------------------------------ reader errors
@pytest.mark.parametrize(
    "line, new, message",
    [
        (5, mask_line(2, 3, entries=12), "line 5: expected 68 mask values (0 or 1), found 12"),
        (5, mask_line(2, 3, 19, 20).replace("0", "2", 1), "line 5: mask entry 1 (FAP 1) is '2'; expected 0 or 1"),
        (6, "1 1 45 0 0 0 0 200 abc 300", "line 6: 'abc' is not a number (the value of FAP 19)"),
        (6, "1 1 45 0 0 0 0 200 nan 300", "line 6: 'nan' is not a number (the value of FAP 19)"),
        (6, "1 x 45 0 0 0 0 200 300 300", "line 6: 'x' is not a number (expression_select1 of FAP 2)"),
        (4, "0 15 7 40 0 120", "line 4: viseme_select1 (FAP 1) is 15; expected a whole number from 0 to 14"),
        (4, "0 1 7 64 0 120", "line 4: viseme_blend (FAP 1) is 64; expected a whole number from 0 to 63"),
        (4, "0 1 7 40.5 0 120", "line 4: viseme_blend (FAP 1) is 40.5; expected a whole number from 0 to 63"),
        (6, "1 7 45 0 0 0 0 200 300 300",
         "line 6: expression_select1 (FAP 2) is 7; expected a whole number from 0 to 6"),
        (6, "1 1 45 0 -1 0 0 200 300 300",
         "line 6: expression_intensity2 (FAP 2) is -1; expected a whole number from 0 to 63"),
        (8, "2 80 -8727 150", "line 8: expected 5 numbers (the frame number, then 4 values for the FAPs set in "
                              "the mask on line 7), found 4"),
        (4, "0 1 7 40 120", "line 4: expected 6 numbers (the frame number, 4 for FAP 1 (viseme), then 1 value for "
                            "the low-level FAPs set in the mask on line 3) or 3 (with FAP 1 as one number, as Greta "
                            "and VREng write it), found 5"),
        (8, "2.5 80 -8727 150 150", "line 8: the frame number '2.5' (first item) is not a whole number"),
        (2, "2.1 demo_example 25", "line 2: expected the header line '<version> <name> <fps> <num_frames>' "
                                   "(4 items), found 3"),
        (2, "2.1 demo_example 0 3", "line 2: the frame rate in the header is 0; it must be from 0.1 to 1000 frames per second"),
        (2, "2.1 demo_example -25 3", "line 2: the frame rate in the header is -25; it must be from 0.1 to 1000 frames per second"),
        (2, "2.1 demo_example fast 3", "line 2: the frame rate 'fast' in the header is not a number"),
        (2, "v2 demo_example 25 3", "line 2: the version 'v2' in the header is not a number"),
        (2, "2.1 demo_example 25 -3", "line 2: the number of frames in the header must be a whole number >= 0"),
        (2, mask_line(1, 3), "line 2: expected the header line '<version> <name> <fps> <num_frames>', found a "
                             "mask line (68 zeros and ones); the header is missing"),
    ],
)
def test_reader_errors_name_the_line_and_what_was_expected(line, new, message):
    with pytest.raises(FapFileError, match="^" + re.escape(message)):
        parse_fap(replace_line(EXAMPLE, line, new))


def test_missing_value_line_in_the_middle_is_reported_as_a_mask_line():
    text = replace_line(EXAMPLE, 6, "# value line deleted")
    with pytest.raises(FapFileError, match=r"^line 7: expected 10 numbers .* or 5 .* found 68; this looks like a mask"):
        parse_fap(text)


def test_truncated_pair_at_the_end_is_an_error_naming_the_mask_line():
    text = "\n".join(EXAMPLE.split("\n")[:7]) + "\n"
    with pytest.raises(FapFileError, match=r"^line 7: the mask line of frame 2 has no value line after it"):
        parse_fap(text)


def test_empty_text_and_source_in_messages():
    with pytest.raises(FapFileError, match=r"^'joy\.fap': the file is empty"):
        parse_fap("# only a comment\n\n", source="joy.fap")
    with pytest.raises(FapFileError, match=r"^'joy\.fap', line 5: expected 68 mask values"):
        parse_fap(replace_line(EXAMPLE, 5, "0 1"), source="joy.fap")


# ------------------------------------------------------------ writing
def test_format_of_the_example_is_the_example_without_its_comment():
    assert format_fap(parse_fap(EXAMPLE)) == EXAMPLE.split("\n", 1)[1]


def test_values_are_written_as_integers_when_integral_else_up_to_4_decimals():
    values = np.full((1, N_FAPS), np.nan)
    values[0, 2:8] = [0.5, 1.23456, 2.0, -0.00001, -7.25, 1e6]
    seq = FapSequence.from_values(values, 12.5, name="my  face ")
    assert format_fap(seq) == (
        f"2.1 my_face 12.5 1\n{mask_line(3, 4, 5, 6, 7, 8)}\n0 0.5 1.2346 2 0 -7.25 1000000\n"
    )


def test_round_trip_of_random_integer_data_with_fap1_and_fap2_is_exact(tmp_path):
    rng = np.random.default_rng(20240611)
    n = 40
    values = rng.integers(-20000, 20000, size=(n, N_FAPS)).astype(float)
    values[rng.random((n, N_FAPS)) < 0.7] = np.nan
    viseme = np.column_stack([rng.integers(0, 15, n), rng.integers(0, 15, n),
                              rng.integers(0, 64, n), rng.integers(0, 2, n)])
    expression = np.column_stack([rng.integers(0, 7, n), rng.integers(0, 64, n), rng.integers(0, 7, n),
                                  rng.integers(0, 64, n), rng.integers(0, 2, n), rng.integers(0, 2, n)])
    viseme[rng.random(n) < 0.5] = -1
    expression[rng.random(n) < 0.5] = -1
    seq = FapSequence.from_values(values, 25, name="random", viseme=viseme, expression=expression)
    assert 0 < seq.mask[:, 0].sum() < n and 0 < seq.mask[:, 1].sum() < n
    assert (seq.mask[:, 0] & seq.mask[:, 1]).any()

    text = format_fap(seq)
    back = parse_fap(text)
    assert_same_sequence(back, seq)
    assert (back.name, back.version, back.notes) == ("random", "2.1", [])
    assert format_fap(back) == text

    write_fap(tmp_path / "random.fap", seq)
    from_file = read_fap(tmp_path / "random.fap")
    assert_same_sequence(from_file, seq)
    assert [p.name for p in tmp_path.iterdir()] == ["random.fap"]  # no temporary file left


def test_writer_refuses_nan_in_a_masked_value_and_bad_fps_and_out_of_range_viseme():
    seq = parse_fap(EXAMPLE)
    seq.values[1, 18] = np.nan
    with pytest.raises(FapFileError, match=r"frame 1: FAP 19 is masked in but its value is nan"):
        format_fap(seq)
    for fps in (0.0, -25.0, float("nan")):
        seq = parse_fap(EXAMPLE)
        seq.fps = fps
        with pytest.raises(FapFileError, match=r"frame rate"):
            format_fap(seq)
    seq = parse_fap(EXAMPLE)
    seq.viseme[0, 0] = 20
    with pytest.raises(FapFileError, match=r"frame 0: viseme_select1 \(FAP 1\) is 20"):
        format_fap(seq)
    seq = parse_fap(EXAMPLE)
    seq.mask[0, 1] = True  # expression row of frame 0 is -1 (not set)
    with pytest.raises(FapFileError, match=r"frame 0: expression_select1 \(FAP 2\) is -1"):
        format_fap(seq)


def test_write_into_a_missing_folder_raises_fap_file_error(tmp_path):
    target = tmp_path / "missing" / "anim.fap"
    with pytest.raises(FapFileError, match=r"does not exist"):
        write_fap(target, parse_fap(EXAMPLE))
    assert not target.parent.exists()


def test_write_refusal_leaves_an_existing_file_untouched(tmp_path):
    target = tmp_path / "anim.fap"
    target.write_text("old")
    seq = parse_fap(EXAMPLE)
    seq.fps = 0
    with pytest.raises(FapFileError):
        write_fap(target, seq)
    assert target.read_text() == "old"


# ------------------------------------------------------------ files
def test_read_fap_file_errors(tmp_path):
    with pytest.raises(FapFileError, match=r"does not exist"):
        read_fap(tmp_path / "nothing.fap")
    with pytest.raises(FapFileError, match=r"is a folder"):
        read_fap(tmp_path)
    binary = tmp_path / "stream.fap"
    binary.write_bytes(b"\x00\x01\x02FBA\x00" * 10)
    with pytest.raises(FapFileError, match=r"'stream\.fap' is not a text file \(it contains binary data\)"):
        read_fap(binary)
    bad = tmp_path / "bad.fap"
    bad.write_text(replace_line(EXAMPLE, 3, "1 0 1"))
    with pytest.raises(FapFileError, match=r"^'bad\.fap', line 3: expected 68 mask values \(0 or 1\), found 3"):
        read_fap(bad)


def test_read_fap_accepts_latin1_utf8_bom_and_utf16(tmp_path):
    body = EXAMPLE.split("\n", 2)[2]
    latin = tmp_path / "latin.fap"
    latin.write_bytes(("2.1 café 25 3\n" + body).encode("latin-1"))
    assert read_fap(latin).name == "café"
    bom = tmp_path / "bom.fap"
    bom.write_bytes(EXAMPLE.encode("utf-8-sig"))
    assert_same_sequence(read_fap(bom), parse_fap(EXAMPLE))
    wide = tmp_path / "wide.fap"
    wide.write_bytes(EXAMPLE.encode("utf-16"))
    seq = read_fap(wide)
    assert_same_sequence(seq, parse_fap(EXAMPLE))
    assert len(seq.notes) == 1 and "UTF-16" in seq.notes[0]


# ------------------------------------------------------------ from_values / frame
def test_from_values_builds_the_mask_from_nan():
    values = np.full((3, N_FAPS), np.nan)
    values[:, 0:2] = 5.0  # FAPs 1 and 2 have no low-level value: ignored
    values[0, 2] = 120
    values[1, [18, 19]] = [300, -300]
    viseme = np.array([[1, 7, 40, 0], [-1, -1, -1, -1], [-1, -1, -1, -1]])
    seq = FapSequence.from_values(values, 25, viseme=viseme)
    expected = np.zeros((3, N_FAPS), bool)
    expected[0, [0, 2]] = True
    expected[1, [18, 19]] = True
    np.testing.assert_array_equal(seq.mask, expected)
    assert np.isnan(seq.values[:, :2]).all()
    np.testing.assert_array_equal(seq.expression, np.full((3, 6), -1))
    assert [seq.frame(k) for k in range(3)] == [{3: 120.0}, {19: 300.0, 20: -300.0}, {}]
    assert (seq.name, seq.version, seq.fps, seq.n_frames) == ("mimica", "2.1", 25.0, 3)
    assert seq.duration == pytest.approx(0.12)
    assert values[0, 0] == 5.0  # the caller's array is not modified


def test_from_values_rejects_bad_shapes_and_out_of_range_rows():
    with pytest.raises(ValueError, match=r"shape \(n_frames, 68\)"):
        FapSequence.from_values(np.zeros((3, 67)), 25)
    with pytest.raises(ValueError, match=r"viseme must have shape \(2, 4\)"):
        FapSequence.from_values(np.zeros((2, N_FAPS)), 25, viseme=np.zeros((3, 4)))
    with pytest.raises(FapFileError, match=r"frame 1: expression_intensity1 \(FAP 2\) is 70"):
        FapSequence.from_values(np.zeros((2, N_FAPS)), 25,
                                expression=[[-1, -1, -1, -1, -1, -1], [1, 70, 0, 0, 0, 0]])


def test_read_fap_streams_lines_old_mac_line_ends_and_a_late_binary_line(tmp_path):
    cr = tmp_path / "mac.fap"
    cr.write_bytes(EXAMPLE.replace("\n", "\r").encode())
    assert np.array_equal(read_fap(cr).values, parse_fap(EXAMPLE).values, equal_nan=True)
    late = tmp_path / "late.fap"
    late.write_bytes(EXAMPLE.encode() + b"\n\x00\x01 binary tail\n")
    with pytest.raises(FapFileError, match="not a text file"):
        read_fap(late)


def test_a_file_growing_past_its_cap_while_read_is_refused():
    import io

    from core.formats.text_files import _CappedRaw

    raw = _CappedRaw(io.BytesIO(b"x" * 100), 40, FapFileError("too big"))
    with pytest.raises(FapFileError, match="too big"):
        io.BufferedReader(raw).read()
    assert io.BufferedReader(_CappedRaw(io.BytesIO(b"x" * 40), 40, FapFileError("no"))).read() == b"x" * 40


def test_reading_a_long_fap_file_holds_about_its_frames_not_its_text(tmp_path):
    """Streaming: the peak of what the reader allocates stays within ~2.5 times the frames it returns
    (reading the whole text first, then a Python object per frame, took 3.3 times)."""
    import tracemalloc

    rng = np.random.default_rng(1)
    n = 6000
    mask = " ".join(["0", "0"] + ["1"] * 66)
    body = "".join(f"{mask}\n{k} " + " ".join(map(str, rng.integers(-300, 300, 66))) + "\n" for k in range(n))
    path = tmp_path / "long.fap"
    path.write_text(f"2.1 long 25 {n}\n" + body)
    tracemalloc.start()
    try:
        seq = read_fap(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    result = seq.values.nbytes + seq.mask.nbytes + seq.viseme.nbytes + seq.expression.nbytes
    assert len(seq.values) == n
    assert peak < 2.5 * result, (peak, result)
