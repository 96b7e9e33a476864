"""Lip-sync from text: eSpeak NG phoneme timings, phoneme -> viseme tables, coarticulation, blinks, audio."""

from __future__ import annotations

import wave

import numpy as np
import pytest

from core import lipsync
from core.layers.fap import tables
from core.lipsync import coarticulation, visemes
from core.lipsync.espeak import Phoneme
from core.timeline import Timeline

SENTENCES = {
    "en": ["The quick brown fox jumps over the lazy dog", "She sells sea shells by the sea shore",
           "How are you? I'm fine, thanks: a joyful voice, the measure of a pure choir at the zoo."],
    "en-gb": ["The quick brown fox jumps over the lazy dog", "Where are you going, dear? Near the square tower."],
    "pt-br": ["Olá, como vai você?", "O rato roeu a roupa do rei de Roma",
              "Minha mãe não põe pão no chão; o filho da lhama é muito bom em futebol."],
}
FPS = 30

try:
    lipsync.phonemes("a", "en")
except lipsync.SpeechError as exc:  # the eSpeak NG library is a system dependency
    pytest.skip(f"eSpeak NG is not available: {exc}", allow_module_level=True)


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))


def _viseme_matrix(result, fps=FPS):
    ts = np.arange(0.0, result.end_s + 0.2, 1.0 / fps)
    keys = sorted(k for k in result.tracks if k.startswith("viseme:"))
    return ts, keys, np.array([result.tracks[k].evaluate(ts) for k in keys])


@pytest.mark.parametrize("lang", sorted(SENTENCES))
def test_tables_cover_every_phoneme_espeak_emits(lang):
    for text in SENTENCES[lang]:
        found = lipsync.phonemes(text, lang)
        assert found, text
        for ph in found:
            if ph.symbol != "_":
                visemes.lookup(ph.symbol, lang)  # KeyError if unmapped
        assert lipsync.lipsync_tracks(text, lang, write_audio=False).unmapped == []


def test_tables_are_well_formed():
    n = len(tables.viseme_names())
    for name in ("en", "pt-br"):
        table = visemes.phoneme_table(name)
        used = {v for ids in table.values() if ids for v in ids}
        assert used <= set(range(n))
        assert table["_"] == (0,)
    assert visemes.phoneme_table("en")["p"] == (1,) and visemes.phoneme_table("en")["θ"] == (3,)
    # Thesis A note 3: θ and ð do not exist in Portuguese, so its table never uses viseme 3.
    assert 3 not in {v for ids in visemes.phoneme_table("pt-br").values() if ids for v in ids}
    assert visemes.must_reach() == {1, 2}


@pytest.mark.parametrize("lang", ["en", "pt-br"])
def test_phoneme_timings_tile_the_audio(lang):
    found = lipsync.phonemes("papa mama", lang)
    assert found[0].start_s == 0.0
    for a, b in zip(found, found[1:]):
        assert b.start_s == pytest.approx(a.end_s, abs=1e-9)
        assert a.duration_s > 0
    symbols = [p.symbol for p in found]
    assert symbols.count("p") == 2 and symbols.count("m") == 2 and symbols[-1] == "_"
    path, rate = lipsync.speech_audio("papa mama", lang)
    with wave.open(str(path), "rb") as w:
        assert w.getframerate() == rate and w.getnchannels() == 1 and w.getsampwidth() == 2
        audio_s = w.getnframes() / rate
    assert found[-1].end_s == pytest.approx(audio_s, abs=1e-9)
    assert path.parent.parent.name == "mimica"  # in the (temporary) speech cache


@pytest.mark.parametrize("lang", ["en", "pt-br"])
def test_bilabials_close_the_lips_fully(lang):
    result = lipsync.lipsync_tracks("papa mama", lang, start_s=0.5, write_audio=False)
    lips = result.tracks["viseme:1"]
    bilabials = [p for p in result.phonemes if p.symbol in ("p", "b", "m")]
    assert len(bilabials) == 4
    for p in bilabials:
        assert lips.evaluate(p.start_s + p.duration_s / 2) == pytest.approx(1.0)
        for key, track in result.tracks.items():
            if key != "viseme:1" and key.startswith("viseme:"):
                assert track.evaluate(p.start_s + p.duration_s / 2) == pytest.approx(0.0, abs=1e-9)
    assert lips.evaluate(0.49) == 0.0 and lips.evaluate(result.end_s + 0.2) == 0.0


@pytest.mark.parametrize("lang", sorted(SENTENCES))
def test_visemes_crossfade_without_popping(lang):
    for text in SENTENCES[lang]:
        result = lipsync.lipsync_tracks(text, lang, write_audio=False)
        ts, keys, M = _viseme_matrix(result)
        assert M.min() >= 0.0 and M.max() <= 1.0
        # 1.5 x frame / transition (0.5) for a full transition; crowded contacts ("papa") a little more.
        assert np.abs(np.diff(M, axis=1)).max() < 0.6, text
        assert M.sum(axis=0).max() < 1.01  # intensities are a partition of unity (no exaggeration)
        # A viseme segment longer than 1.5 transitions (one whole window may lie inside it, next
        # to a lip contact, plus half a centred one) shows its own viseme fully at its middle.
        for seg in result.segments:
            if seg.viseme and seg.duration_s >= 0.16:
                mid = seg.start_s + seg.duration_s / 2
                assert result.tracks[f"viseme:{seg.viseme}"].evaluate(mid) > 0.9, (text, seg)


def test_neighbouring_visemes_overlap():
    result = lipsync.lipsync_tracks("She sells sea shells", "en", blinks=False, write_audio=False)
    sh, i = result.tracks["viseme:6"], result.tracks["viseme:12"]
    first_i = next(p for p in result.phonemes if p.symbol == "iː")
    # The vowel is anticipated before its phoneme starts while ʃ still shows.
    t = first_i.start_s - 0.02
    assert 0 < i.evaluate(t) < 1 and 0 < sh.evaluate(t) < 1


def test_unmapped_phonemes_are_reported_and_give_their_time_to_neighbours():
    ph = [Phoneme("_", 0.0, 0.1), Phoneme("p", 0.1, 0.1), Phoneme("ʘ", 0.2, 0.1), Phoneme("a", 0.3, 0.2),
          Phoneme("ʘ", 0.5, 0.05), Phoneme("_", 0.55, 0.3)]
    segments, unmapped = visemes.map_phonemes(ph, "pt-br")
    assert unmapped == ["ʘ"]
    assert [s.viseme for s in segments] == [0, 1, 10, 0]
    assert segments[1].end_s == pytest.approx(0.25) and segments[2].start_s == pytest.approx(0.25)
    # Diphthongs split their time; English words inside Portuguese fall back to the English table.
    segments, unmapped = visemes.map_phonemes([Phoneme("aʊ", 0.0, 0.2), Phoneme("θ", 0.2, 0.1)], "pt-br")
    assert [s.viseme for s in segments] == [10, 14, 3]
    np.testing.assert_allclose([(s.start_s, s.end_s) for s in segments], [(0, 0.1), (0.1, 0.2), (0.2, 0.3)])
    assert unmapped == []
    assert visemes.lookup("ẽː", "pt-br") == (11,)  # diacritics/length stripped as a last resort


def test_blinks_are_periodic_and_asymmetric():
    result = lipsync.lipsync_tracks("O rato roeu a roupa do rei de Roma. " * 4, "pt-br", seed=7, write_audio=False)
    assert {"fap:19", "fap:20", "fap:21", "fap:22"} <= set(result.tracks)
    left, right = result.tracks["fap:19"], result.tracks["fap:20"]
    starts_l, starts_r = left.times[::4], right.times[::4]
    assert len(starts_l) == len(starts_r) >= 2
    offsets = np.abs(starts_l - starts_r)
    assert np.all((offsets >= 0.015 - 1e-9) & (offsets <= 0.040 + 1e-9))
    assert np.all(np.diff(starts_l) >= 2.5 - 0.05)
    closed = left.times[1] + 0.02
    assert left.evaluate(closed) + result.tracks["fap:21"].evaluate(closed) == pytest.approx(1024.0)
    again = lipsync.lipsync_tracks("O rato roeu a roupa do rei de Roma. " * 4, "pt-br", seed=7, write_audio=False)
    np.testing.assert_array_equal(again.tracks["fap:19"].times, left.times)
    none = lipsync.lipsync_tracks("O rato roeu", "pt-br", blinks=False, write_audio=False)
    assert not any(k.startswith("fap:") for k in none.tracks)


def test_result_goes_on_a_timeline():
    result = lipsync.lipsync_tracks("Olá, como vai você?", "pt-br", start_s=1.0, seed=1,
                                    audio_path=None, write_audio=True)
    assert result.audio_path is not None and result.audio_path.is_file()
    assert result.phonemes[0].start_s == 1.0 and result.start_s == 1.0
    tl = Timeline(result.end_s + 1.0, 30)
    edit = tl.replace_tracks(result.tracks)
    values = tl.evaluate(result.segments[2].start_s + result.segments[2].duration_s / 2)
    assert set(values) == set(result.tracks)
    tl.apply_edit(edit.inverse())
    assert not tl.tracks


def test_speech_starting_on_a_sound_fades_in():
    curves = coarticulation.viseme_curves([visemes.VisemeSegment(13, 0.0, 0.2, "o"),
                                           visemes.VisemeSegment(0, 0.2, 0.5, "_")], transition_s=0.1)
    times, values = curves[13]
    assert times[0] == pytest.approx(-0.05) and values[0] == 0.0  # the lips move before the sound
    tracks = coarticulation.viseme_tracks([visemes.VisemeSegment(13, 0.0, 0.2, "o"),
                                           visemes.VisemeSegment(0, 0.2, 0.5, "_")])
    assert tracks["viseme:13"].times[0] == 0.0 and tracks["viseme:13"].values[0] == pytest.approx(0.5)


def test_bad_input():
    with pytest.raises(lipsync.LanguageError, match="unsupported language"):
        lipsync.phonemes("hello", "klingon")
    with pytest.raises(ValueError, match="no text"):
        lipsync.phonemes("   ", "en")
    with pytest.raises(ValueError, match=">= 0"):
        lipsync.lipsync_tracks("hello", "en", start_s=-1)
    with pytest.raises(ValueError, match="positive"):
        coarticulation.viseme_curves([visemes.VisemeSegment(1, 0, 1, "p")], transition_s=0)


def test_a_short_clip_still_gets_a_blink_when_asked():
    """A 1.6 s clip used to get none (the first blink was placed 0.5-2 s in, whole blinks only)."""
    import numpy as np

    from core.lipsync.coarticulation import blink_tracks

    for seed in range(20):
        tracks = blink_tracks(0.0, 1.6, np.random.default_rng(seed))
        assert set(tracks) == {"fap:19", "fap:20", "fap:21", "fap:22"}
        times = np.concatenate([t.times for t in tracks.values()])
        assert times.min() >= 0.0 and times.max() <= 1.6
    assert blink_tracks(0.0, 0.2, np.random.default_rng(0)) == {}   # no room for a whole blink
