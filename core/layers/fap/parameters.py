"""The FAP layer's parameter kinds: ``fap:<n>``, ``expression:<name>``, ``viseme:<id>`` (see ``core.parameters``).

Ranges are the slider ranges of ``resources/mpeg4/faps.csv``; preset intensities run 0..1.
FAP 1 and 2 are not keyed themselves: each viseme and expression is its own parameter.
"""

from __future__ import annotations

import math

from core.parameters import Parameter, ParameterError, ParameterKind, ParamKey, register_kind, split_words
from core.layers.fap import tables

# How much further (IRISD units) the upper-lid FAP of an eye closed at rest (a scan taken with the
# eyes shut) may open it than the table lets an open eye's: an open eye's lids meet when their two
# values add up to 1024 (core.layers.fap.fat.lid_contact) and the upper lid makes most of that
# travel, so -1024 opens a closed eye about as wide as an open one, and the table's -300 then widens
# it as it would an open eye. The FAP layer gives such a face that range (FapLayer.describe).
CLOSED_LID_OPENING = 1024.0
UPPER_LIDS = (19, 20)

_WORDS = {"t": "top", "b": "bottom", "i": "inner", "m": "middle", "o": "outer", "lm": "left-mid", "rm": "right-mid",
          "l": "left", "r": "right", "cornerlip": "lip corner", "midlip": "mid-lip", "eyebrow": "brow"}


def readable_name(spec: tables.FapSpec) -> str:
    """``open_jaw`` -> "open jaw", ``close_t_l_eyelid`` -> "close top left eyelid" (the outer-lip
    FAPs' trailing ``_o`` is dropped: their group says "outer lips")."""
    tokens = spec.name.split("_")
    if len(tokens) > 1 and tokens[-1] == "o":
        tokens = tokens[:-1]
    return " ".join(_WORDS.get(t, t) for t in tokens)


def fap_label(spec: tables.FapSpec) -> str:
    """"3 open jaw": the number and the readable name."""
    return f"{spec.number} {readable_name(spec)}"


def _fap_key(args: list[str]) -> ParamKey:
    (word,) = split_words(args, 1, "FAP keys are 'fap:<number>' (3..68) or 'fap:<name>', e.g. 'fap:3' or 'fap:open_jaw'")
    try:
        spec = tables.fap_spec(int(word) if word.isdigit() else word)
    except ValueError as exc:
        raise ParameterError(f"fap:{word}: {exc}") from None
    if spec.number == 1:
        raise ParameterError("FAP 1 (visemes) is set per viseme: use 'viseme:<id>' keys (intensity 0..1)")
    if spec.number == 2:
        raise ParameterError("FAP 2 (expressions) is set per expression: use 'expression:<name>' keys (0..1)")
    if not (math.isfinite(spec.minimum) and math.isfinite(spec.maximum)):
        raise ParameterError(f"FAP {spec.number} ({spec.name}) is not animated by Mimica")
    return ParamKey("fap", str(spec.number))


def _fap_describe(key: ParamKey) -> Parameter:
    spec = tables.fap_spec(int(key.id))
    verb = "rotates about" if spec.is_rotation else "moves"
    description = (f"FAP {spec.number} {spec.name} {verb} feature point {spec.fp.strip(';').replace(';', ', ')};"
                   f" positive is {spec.direction}.")
    outer = (spec.minimum - CLOSED_LID_OPENING, spec.maximum) if spec.number in UPPER_LIDS else None
    return Parameter(str(key), fap_label(spec), spec.unit, float(spec.minimum), float(spec.maximum), 0.0,
                     spec.dock, description=description,
                     mirror=f"fap:{spec.pair}" if spec.pair is not None else None, outer=outer)


def _preset_key(kind: str, to_id, usage: str, neutral: str, name_of):
    """The key parser of a preset kind: one word, a known preset, not the neutral one."""
    def parse(args: list[str]) -> ParamKey:
        (word,) = split_words(args, 1, usage)
        try:
            ident = to_id(word)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        if ident == 0:
            raise ParameterError(neutral)
        return ParamKey(kind, name_of(ident))
    return parse


_expression_key = _preset_key(
    "expression", tables.expression_id, "expression keys are 'expression:<name>', e.g. 'expression:joy'",
    "'expression:neutral' is the absence of expression; set the other expressions to 0",
    lambda i: tables.expression_names()[i])
_viseme_key = _preset_key(
    "viseme", tables.viseme_id, "viseme keys are 'viseme:<id>' with id 1..14, e.g. 'viseme:1' (p, b, m)",
    "viseme 0 is silence (the neutral mouth): set the other visemes to 0 instead", str)


def _expression_describe(key: ParamKey) -> Parameter:
    return Parameter(str(key), key.id, "", 0.0, 1.0, 0.0, "expressions")


def _viseme_describe(key: ParamKey) -> Parameter:
    vid = int(key.id)
    phonemes = " ".join(p.strip() for p in tables.viseme_phonemes()[vid].split(","))
    return Parameter(str(key), f"{vid} {phonemes}".strip(), "", 0.0, 1.0, 0.0, "visemes")


register_kind(ParameterKind("fap", "fap:<number>", _fap_key, _fap_describe, order=0))
register_kind(ParameterKind("expression", "expression:<name>", _expression_key, _expression_describe, order=1))
register_kind(ParameterKind("viseme", "viseme:<id>", _viseme_key, _viseme_describe, order=2))

__all__ = ["readable_name", "fap_label"]
