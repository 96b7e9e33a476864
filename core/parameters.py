"""The parameter registry: one spelling, one description, one check for every animatable parameter.

A parameter is named by a canonical key string ``kind:id[:side]``:

    ``fap:<n>``                      a low-level FAP 3..68, in its FAP unit
    ``expression:<name>``            an expression preset (FAP 2) intensity 0..1, e.g. ``expression:joy``
    ``viseme:<id>``                  a viseme preset (FAP 1) intensity 0..1, id 1..14
    ``muscle:<name>:<left|right>``   a SABiom muscle force per side; ``muscle:<name>`` if unpaired
    ``jaw``                          the muscle layer's jaw angle in degrees
    ``cp:<feature point>:<x|y|z>``   an RBF control point's displacement in mm (thesis B)
    ``waters:<muscle>:<left|right>`` a Waters vector muscle's contraction 0..1 (thesis B)
    ``blend:<pose>``                 an expression-library pose weight in %, e.g. ``blend:joy``
    ``caricature``                   exaggeration from the mean face in % (-100 = the mean face)

:func:`key_of` turns every older spelling into it: a FAP number ``3``, a FAP name ``open_jaw``,
``fap:open_jaw``, a muscle pair ``("risorius", "left")`` or ``("orbicularis_oris", None)``,
a :class:`ParamKey`. The timeline's tracks, undo labels, project files, the docks and the command
line all name parameters this way.

Each family (a :class:`ParameterKind`) is registered by the module that animates it (its rig
layer) with :func:`register_kind`; :func:`describe` gives a parameter's label, unit, range,
default, description and left/right mirror (what "Link left/right" moves with it),
:func:`check_value` validates a value (never clamps). A rig may describe a parameter of its face
differently (``FaceRig.describe``: a range of its own); the docks, the timeline and the command
line ask the rig when there is one. The built-in kinds are defined in
``core.layers.fap.parameters`` and ``core.layers.muscles.parameters`` and load on first use.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from typing import Callable, Hashable, Iterable

__all__ = [
    "ParameterError", "ParamKey", "Parameter", "ParameterKind", "register_kind", "kinds", "key_of", "parse",
    "describe", "check_value", "label", "is_simulated", "sort_key",
]


class ParameterError(ValueError):
    """An unknown parameter or a value it does not allow; the message says what to do."""


@dataclass(frozen=True, order=True)
class ParamKey:
    """A parameter's typed key: ``kind`` (e.g. ``"fap"``), ``id`` (``"3"``, ``"joy"``, ``"risorius"``)
    and ``side`` (``"left"``/``"right"`` for paired muscles, else None). ``str()`` is the canonical key."""

    kind: str
    id: str = ""
    side: str | None = None

    def __str__(self) -> str:
        return ":".join(p for p in (self.kind, self.id, self.side) if p)


@dataclass(frozen=True)
class Parameter:
    """What a user needs to know about one parameter (its slider, its timeline lane, its undo label)."""

    key: str            # canonical key
    label: str          # short readable name, e.g. "3 open jaw", "joy", "risorius (L)"
    unit: str           # "MNS", "%", "force", "°", ...
    minimum: float
    maximum: float
    default: float = 0.0
    group: str = ""     # e.g. the FAP group or "muscles", for docks and timeline groups
    simulated: bool = False  # drives a dynamic layer (its value at t depends on the history)
    description: str = ""    # one sentence on what it does (tooltips)
    mirror: str | None = None  # the canonical key of its left/right partner ("Link left/right"), if any
    note: str = ""      # why a face's description differs from the registry's (e.g. its own range)
    # The widest range any face may give it (None: minimum..maximum); keys and files are checked
    # against it, a rig against its own face's (``FaceRig.describe``).
    outer: tuple[float, float] | None = None


@dataclass(frozen=True)
class ParameterKind:
    """One family of parameters.

    canonical(args) -> ParamKey from the ``:``-separated words after the kind (ParameterError if bad);
    describe(key) -> Parameter for a canonical key; order: where the family sorts in lists.
    """

    name: str
    syntax: str
    canonical: Callable[[list[str]], ParamKey]
    describe: Callable[[ParamKey], Parameter]
    simulated: bool = False
    order: int = 50


_KINDS: dict[str, ParameterKind] = {}
#: Where the built-in kinds are registered (imported on first use, so ``core.parameters`` itself
#: depends on no layer).
_BUILTIN = {"fap": "core.layers.fap.parameters", "expression": "core.layers.fap.parameters", "viseme": "core.layers.fap.parameters",
            "muscle": "core.layers.muscles.parameters", "jaw": "core.layers.muscles.parameters",
            "cp": "core.layers.rbf.parameters", "waters": "core.layers.waters.parameters",
            "blend": "core.layers.blend.parameters", "caricature": "core.layers.blend.parameters"}


def register_kind(kind: ParameterKind) -> None:
    """Make a family of parameters known (a rig layer's module calls this once at import)."""
    _KINDS[kind.name] = kind


def kinds() -> tuple[str, ...]:
    """Names of the registered kinds (the built-in ones included)."""
    for module in dict.fromkeys(_BUILTIN.values()):
        importlib.import_module(module)
    return tuple(_KINDS)


def _kind(name: str) -> ParameterKind | None:
    if name not in _KINDS and name in _BUILTIN:
        importlib.import_module(_BUILTIN[name])
    return _KINDS.get(name)


def parse(spelling: Hashable) -> ParamKey:
    """The :class:`ParamKey` of any spelling (see the module docstring); ParameterError if unknown."""
    if isinstance(spelling, ParamKey):
        words = [spelling.kind, spelling.id] + ([spelling.side] if spelling.side else [])
    elif isinstance(spelling, tuple) and len(spelling) == 2 and isinstance(spelling[0], str):
        name, side = spelling            # a muscle control as MuscleLayer takes it
        words = ["muscle", name] + ([side] if side else [])
    elif isinstance(spelling, bool) or spelling is None:
        raise ParameterError(f"parameter keys are strings like 'fap:3' or 'muscle:risorius:left', got {spelling!r}")
    elif isinstance(spelling, int) or (isinstance(spelling, float) and float(spelling).is_integer()):
        words = ["fap", str(int(spelling))]
    elif isinstance(spelling, str):
        words = [w.strip() for w in spelling.strip().split(":")]
        words[0] = words[0].lower()
        if len(words) == 1 and _kind(words[0]) is None:
            words = ["fap", words[0]]    # a bare FAP number or name: "3", "open_jaw"
    else:
        raise ParameterError(f"parameter keys are strings like 'fap:3' or 'muscle:risorius:left', got {spelling!r}")
    kind = _kind(words[0])
    if kind is None:
        known = ", ".join(repr(_kind(k).syntax) for k in kinds())
        raise ParameterError(f"unknown parameter {':'.join(words)!r}: keys look like {known}")
    return kind.canonical(words[1:])


def key_of(spelling: Hashable) -> str:
    """The canonical key string of any spelling (``"open_jaw"`` -> ``"fap:3"``)."""
    return str(parse(spelling))


def describe(spelling: Hashable) -> Parameter:
    """Label, unit, range and default of a parameter."""
    key = parse(spelling)
    return _KINDS[key.kind].describe(key)


def label(spelling: Hashable) -> str:
    """Short readable name, e.g. "3 open jaw"; the key itself when it is not a known parameter."""
    try:
        return describe(spelling).label
    except ParameterError:
        return str(spelling)


def is_simulated(spelling: Hashable) -> bool:
    """True for parameters that drive a dynamic layer (muscle forces, jaw)."""
    return _KINDS[parse(spelling).kind].simulated


def check_value(spelling: Hashable, value, parameter: Parameter | None = None) -> float:
    """``value`` as a float if the parameter allows it; ParameterError naming the parameter otherwise.

    ``parameter``: the description to check against when a face has its own (a rig's ``describe``:
    e.g. the lids of an eye closed in the scan open further than the table's range); the registry's
    otherwise, which allows the widest range any face gives it (its ``outer`` range: a timeline key or
    a file is not tied to one face)."""
    p = parameter if parameter is not None else describe(spelling)
    low, high = (p.minimum, p.maximum) if parameter is not None or p.outer is None else p.outer
    if isinstance(value, bool):
        raise ParameterError(f"{p.key} ({p.label}): values are numbers, got {value!r}")
    try:
        value = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ParameterError(f"{p.key} ({p.label}): values are numbers, got {value!r}") from None
    if not math.isfinite(value):
        raise ParameterError(f"{p.key} ({p.label}): values must be finite numbers, got {value}")
    if not low <= value <= high:
        raise ParameterError(f"{p.key} ({p.label}) = {value:g} is outside its range {low:g} to {high:g} {p.unit}".rstrip())
    return value


def sort_key(spelling: Hashable) -> tuple:
    """Sort parameters by family (FAPs, expressions, visemes, muscles, jaw, others) then number/name."""
    key = parse(spelling)
    kind = _KINDS[key.kind]
    return (kind.order, key.kind, int(key.id) if key.id.isdigit() else 0, key.id, key.side or "")


def split_words(words: Iterable[str], count: int, usage: str) -> list[str]:
    """``words`` as a list of exactly ``count`` non-empty words; ParameterError saying ``usage`` otherwise."""
    words = list(words)
    if len(words) != count or not all(words):
        raise ParameterError(usage)
    return words
