"""Phoneme -> MPEG-4 viseme mapping (tables in ``resources/lipsync/``).

Lookup of an eSpeak IPA symbol for a language: its own table, then the fallback tables (pt-br falls
back to English, since eSpeak speaks English words inside Portuguese text with English phonemes),
then the same with length marks and combining diacritics removed (``ẽː`` -> ``e``). A symbol found
nowhere is *unmapped*: it is reported (``map_phonemes`` returns it) and, like ``*`` entries, gives
its time to its neighbours instead of snapping the mouth to neutral.
"""

from __future__ import annotations

import functools
import unicodedata
from dataclasses import dataclass

import resources

from core.layers.fap import tables
from core.lipsync.espeak import PAUSE, Phoneme, voice_for

#: Mimica language -> phoneme tables to search, in order.
TABLES = {"en": ("en",), "en-us": ("en",), "en-gb": ("en",), "pt-br": ("pt-br", "en")}
TRANSPARENT = None  # "*" in the tables


@dataclass(frozen=True)
class VisemeSegment:
    """A stretch of time showing one viseme (0 = silence/neutral); ``phonemes`` it came from."""

    viseme: int
    start_s: float
    end_s: float
    phonemes: str

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@functools.cache
def phoneme_table(name: str) -> dict[str, tuple[int, ...] | None]:
    """IPA symbol -> viseme ids (a tuple, several for diphthongs) or None (``*``: no own shape)."""
    out: dict[str, tuple[int, ...] | None] = {}
    n_visemes = len(tables.viseme_names())
    for row in resources.get_table(f"lipsync/phonemes_{name}.csv"):
        symbol, spec = unicodedata.normalize("NFC", row["phoneme"].strip()), row["visemes"].strip()
        if symbol in out:
            raise ValueError(f"lipsync/phonemes_{name}.csv lists {symbol!r} twice")
        if spec == "*":
            out[symbol] = TRANSPARENT
            continue
        ids = tuple(int(v) for v in spec.split())
        if not ids or any(not 0 <= v < n_visemes for v in ids):
            raise ValueError(f"lipsync/phonemes_{name}.csv: {symbol!r} has bad visemes {spec!r} (ids 0-14 or *)")
        out[symbol] = ids
    return out


@functools.cache
def must_reach() -> frozenset[int]:
    """Visemes held at full intensity for their whole phoneme (lip contacts: p b m, f v)."""
    return frozenset(int(r["viseme"]) for r in resources.get_table("lipsync/visemes.csv") if r["must_reach"] == "1")


def _strip(symbol: str) -> str:
    decomposed = unicodedata.normalize("NFD", symbol)
    kept = "".join(c for c in decomposed if not unicodedata.combining(c) and c not in "ːˑˈˌ")
    return unicodedata.normalize("NFC", kept)


def lookup(symbol: str, lang: str) -> tuple[int, ...] | None:
    """Viseme ids of ``symbol`` in ``lang``; None for a shapeless phoneme; KeyError if unmapped."""
    voice_for(lang)  # validates the language
    names = TABLES[lang.strip().lower()]
    symbol = unicodedata.normalize("NFC", symbol)
    for candidate in dict.fromkeys((symbol, _strip(symbol))):
        for name in names:
            table = phoneme_table(name)
            if candidate in table:
                return table[candidate]
    raise KeyError(symbol)


def map_phonemes(phonemes: list[Phoneme] | tuple[Phoneme, ...], lang: str,
                 ) -> tuple[tuple[VisemeSegment, ...], list[str]]:
    """Viseme segments covering the phonemes' time span, and the unmapped symbols (first-seen order).

    Diphthongs split their duration equally among their visemes; shapeless phonemes (``*``) and
    unmapped ones give the first half of their time to the segment before and the rest to the
    one after; consecutive segments of the same viseme merge.
    """
    raw: list[list] = []  # [viseme | None, start, end, phoneme]
    unmapped: list[str] = []
    for ph in phonemes:
        if ph.symbol == PAUSE:
            raw.append([0, ph.start_s, ph.end_s, ph.symbol])
            continue
        try:
            ids = lookup(ph.symbol, lang)
        except KeyError:
            if ph.symbol not in unmapped:
                unmapped.append(ph.symbol)
            ids = None
        if ids is None:
            raw.append([None, ph.start_s, ph.end_s, ph.symbol])
            continue
        step = ph.duration_s / len(ids)
        for k, v in enumerate(ids):
            raw.append([v, ph.start_s + k * step, ph.start_s + (k + 1) * step, ph.symbol])
    # Shapeless runs: split between the neighbours.
    i = 0
    while i < len(raw):
        if raw[i][0] is not None:
            i += 1
            continue
        j = i
        while j < len(raw) and raw[j][0] is None:
            j += 1
        a, b = raw[i][1], raw[j - 1][2]
        names = "".join(r[3] for r in raw[i:j])
        if i > 0 and j < len(raw):
            mid = (a + b) / 2
            raw[i - 1][2], raw[j][1] = mid, mid
        elif i > 0:
            raw[i - 1][2] = b
        elif j < len(raw):
            raw[j][1] = a
        else:
            raw[i:j] = [[0, a, b, names]]
            i += 1
            continue
        del raw[i:j]
    segments: list[VisemeSegment] = []
    for v, s, e, name in raw:
        if e <= s:
            continue
        if segments and segments[-1].viseme == v:
            last = segments[-1]
            segments[-1] = VisemeSegment(v, last.start_s, e, last.phonemes + name)
        else:
            segments.append(VisemeSegment(v, s, e, name))
    return tuple(segments), unmapped
