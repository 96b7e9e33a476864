"""Issue 19, bounded resources: the line readers (DPC, EPC, PPC, landmark CSV) parse one line at a
time, so what a read allocates at its peak is bounded by what it returns, not by the file's text.
Reading the whole text first and then a token list per line took 31 times the DPC displacements
returned (measured on the 3,000-frame file below)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from core.formats.dpc_file import DpcFileError, read_dpc
from core.formats.epc_file import EpcFileError, read_epc
from core.formats.ppc_file import read_ppc
from core.formats.text_files import MAX_BYTES
from core.landmark_editing import LandmarkEditModel, LandmarkFileError

from tests.core.conftest import make_grid_face


def _peak_bytes(read):
    """(result of ``read()``, the peak bytes Python allocated while it ran)."""
    tracemalloc.start()
    try:
        result = read()
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _displacement_rows(n_rows: int) -> str:
    values = np.round(np.random.default_rng(1).uniform(-20, 20, (n_rows, 3)), 3)
    return "\n".join(" ".join(map(str, row)) for row in values.tolist()) + "\n"


# A comment line that repeats: it pads a file's text without adding anything the reader returns.
PADDING = "# " + "padding " * 120 + "\n"


def test_a_long_dpc_file_costs_about_its_displacements_not_its_text(tmp_path):
    frames, points = 3000, 29
    path = tmp_path / "long.dpc"
    path.write_text(f"{frames}\n" + _displacement_rows(frames * points))
    seq, peak = _peak_bytes(lambda: read_dpc(path))
    assert seq.displacements.shape == (frames, points, 3)
    assert peak < 2.5 * seq.displacements.nbytes, (peak, seq.displacements.nbytes)


def test_a_long_epc_file_costs_about_its_frames_not_its_text(tmp_path):
    frames, points = 3000, 29
    path = tmp_path / "long.epc"
    path.write_text(f"# emotion joy\n# aus 6 12\n{frames}\n" + _displacement_rows(frames * points))
    emotion, peak = _peak_bytes(lambda: read_epc(path))
    assert emotion.frames.shape == (frames, points, 3) and emotion.name == "joy" and emotion.aus == (6, 12)
    assert peak < 2.5 * emotion.frames.nbytes, (peak, emotion.frames.nbytes)


def test_a_ppc_file_padded_with_comments_is_not_held_whole(tmp_path):
    lines = [f"cp{i} - {i}.5 {-i} 2" for i in range(29)]
    padding = PADDING * ((MAX_BYTES["PPC"] - 4096) // len(PADDING))
    path = tmp_path / "padded.ppc"
    path.write_text(padding + "\n".join(lines) + "\n")
    ppc, peak = _peak_bytes(lambda: read_ppc(path))
    assert ppc.names == tuple(f"cp{i}" for i in range(29)) and ppc.positions[3].tolist() == [3.5, -3, 2]
    assert peak < path.stat().st_size / 5, (peak, path.stat().st_size)


def test_a_landmark_csv_padded_with_comments_is_not_held_whole(tmp_path):
    model = LandmarkEditModel(make_grid_face())
    small = tmp_path / "small.csv"
    small.write_text("name,x,y,z,status,confidence\n2.1,1.0,2.0,0.0,confirmed,\n")
    model.read_csv(small)   # the first read builds the face's closest-point search (~11 MB), cached after
    path = tmp_path / "padded.csv"
    padding = PADDING * ((MAX_BYTES["landmark"] - 4096) // len(PADDING))
    path.write_text("name,x,y,z,status,confidence\n" + padding + "2.1,1.0,2.0,0.0,confirmed,\n")
    states, peak = _peak_bytes(lambda: model.read_csv(path))
    assert list(states) == ["2.1"]
    assert peak < path.stat().st_size / 20, (peak, path.stat().st_size)


@pytest.mark.parametrize("read, suffix, error", [(read_dpc, "dpc", DpcFileError), (read_epc, "epc", EpcFileError)])
def test_streamed_dpc_and_epc_still_name_the_line_and_read_other_encodings(tmp_path, read, suffix, error):
    bad = tmp_path / f"bad.{suffix}"
    bad.write_text("2\n1 2 3\n1 2 3\n\n1 x 3\n1 2 3\n")
    with pytest.raises(error, match=rf"'bad\.{suffix}', line 5: 'x' is not a number"):
        read(bad)
    utf16 = tmp_path / f"utf16.{suffix}"
    utf16.write_text("1\n1 2 3\n4 5 6\n", encoding="utf-16")
    latin1 = tmp_path / f"latin1.{suffix}"
    latin1.write_bytes("# cr\xe9\xe9\n1\n1 2 3\n4 5 6\n".encode("latin-1"))
    for path in (utf16, latin1):
        result = read(path, n_points=2) if read is read_dpc else read(path, names=["a", "b"])
        frames = result.displacements if read is read_dpc else result.frames
        assert frames.reshape(-1, 3).tolist() == [[1, 2, 3], [4, 5, 6]]
    assert "UTF-16" in read(utf16, **({"n_points": 2} if read is read_dpc else {"names": ["a", "b"]})).notes[0]


def test_landmark_csv_that_is_not_utf8_is_refused_with_a_message(tmp_path):
    model = LandmarkEditModel(make_grid_face())
    path = tmp_path / "latin1.csv"
    path.write_bytes("name,x,y,z,status,confidence\nm\xe9,1,2,0,auto,\n".encode("latin-1"))
    with pytest.raises(LandmarkFileError, match=r"'latin1\.csv' is not a text \(UTF-8\) file"):
        model.read_csv(path)
