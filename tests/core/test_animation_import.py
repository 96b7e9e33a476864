"""Animations from .fap and DPC files as timeline tracks (known answers)."""

import numpy as np
import pytest

from core.formats.animation_import import tracks_from_dpc, tracks_from_fap
from core.formats.dpc_file import DpcSequence
from core.layers.fap import tables
from core.formats.fap_file import FapSequence, parse_fap
from core.timeline import Timeline


def test_fap_frames_become_keys_that_replay_the_file():
    values = np.full((4, tables.N_FAPS), np.nan)
    values[:, 2] = [0, 100, 300, 200]          # open_jaw every frame
    values[[0, 3], 18] = [0, 1024]             # close_t_l_eyelid in frames 0 and 3 only
    seq = FapSequence.from_values(values, 25.0)
    tracks, notes = tracks_from_fap(seq, start_s=1.0)
    assert not notes and set(tracks) == {"fap:3", "fap:19"}
    tl = Timeline(duration=2.0, fps=25, tracks=tracks.values())
    assert tl.evaluate(1.0 + 2 / 25)["fap:3"] == pytest.approx(300)   # keys are hit exactly
    assert tl.evaluate(1.0 + 1.5 / 25)["fap:3"] == pytest.approx(200)  # linear between frames
    assert tracks["fap:19"].times.tolist() == pytest.approx([1.0, 1.12])


def test_fap1_and_fap2_become_preset_intensities():
    text = ("2.1 t 25 2\n" + "1 1 " + "0 " * 66 + "\n0 1 10 21 0 3 63 0 0 0 0\n"
            + "1 1 " + "0 " * 66 + "\n1 1 10 63 0 3 0 0 0 0 0\n")
    seq = parse_fap(text)
    tracks, _ = tracks_from_fap(seq)
    assert tracks["viseme:1"].values.tolist() == pytest.approx([21 / 63, 1.0])
    assert tracks["viseme:10"].values.tolist() == pytest.approx([42 / 63, 0.0])
    name = tables.expression_names()[3]
    assert tracks[f"expression:{name}"].values.tolist() == pytest.approx([1.0, 0.0])


def test_out_of_range_fap_values_are_reported_not_clamped():
    values = np.full((2, tables.N_FAPS), np.nan)
    values[:, 2] = [100, 99999]
    tracks, notes = tracks_from_fap(FapSequence.from_values(values, 10.0))
    assert tracks["fap:3"].values.tolist() == [100] and "outside" in notes[0]


def test_dpc_displacement_along_a_fap_axis_gives_the_fap_value():
    fapu = {"MNS": 2.0, "MW": 5.0, "IRISD": 1.0, "ES": 6.0, "ENS": 4.0, "AU": 1e-5}
    d = np.zeros((3, 2, 3))
    d[:, 0, 1] = [0.0, -10.0, -20.0]     # chin (2.1) moves down 0, 10, 20 mm
    seq = DpcSequence(d, ("chin", "nowhere"), ("2.1", None), fps=None)
    tracks, notes = tracks_from_dpc(seq, fapu, fps=10)
    spec = tables.fap_spec("open_jaw")
    expected = np.array([0.0, -10.0, -20.0]) * np.asarray(spec.axis)[1] / fapu["MNS"]
    assert tracks["fap:3"].values.tolist() == pytest.approx(expected.tolist())
    assert tracks["fap:3"].times.tolist() == pytest.approx([0.0, 0.1, 0.2])
    assert any("nowhere" in n for n in notes)
    with pytest.raises(ValueError, match="frames per second"):
        tracks_from_dpc(seq, fapu)
