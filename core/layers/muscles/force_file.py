"""Muscle force configurations: ``ForceSet``, the thesis presets and the force file format.

Thesis C's Save/Open buttons stored the force of each muscle per side and the jaw rotation. Here
a force file is human-readable JSON::

    {
      "format": "mimica-muscle-forces",
      "version": 1,
      "name": "discreet smile",
      "jaw_deg": 0.0,
      "forces": {
        "risorius": {"left": 42, "right": 42},
        "zygomatic_major": {"both": 9},
        "orbicularis_oris": 8.0
      }
    }

Paired muscles take {"left": f, "right": f} (or "both"); the orbicularis oris a plain number.
Muscles not listed have force 0. Forces are in thesis units (``resources/muscles/tissue.json``
defines one unit in dyn). Presets (``resources/muscles/presets.json``) use the same format.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import resources

from core.layers.muscles.specs import check_control, control_keys, jaw_range, spec_by_name

FORMAT = "mimica-muscle-forces"
VERSION = 1


class ForceFileError(ValueError):
    """A force file cannot be read or written; the message says what is wrong and where."""


@dataclass
class ForceSet:
    """Forces per control (name, "left"|"right"|None) in thesis units, jaw opening in degrees."""

    forces: dict[tuple[str, str | None], float] = field(default_factory=dict)
    jaw_deg: float = 0.0
    name: str = ""

    def full(self) -> dict[tuple[str, str | None], float]:
        """All 19 controls (missing ones 0)."""
        return {k: float(self.forces.get(k, 0.0)) for k in control_keys()}


# ------------------------------------------------------------------ JSON <-> ForceSet
def force_set_to_json(force_set: ForceSet) -> dict:
    """The JSON object of a force set (validated; ValueError if a value is bad)."""
    jaw = _check_jaw(force_set.jaw_deg, ValueError)
    out: dict = {}
    for key, value in force_set.forces.items():
        if not (isinstance(key, tuple) and len(key) == 2):
            raise ValueError(f"force keys must be (muscle, side) pairs, got {key!r}")
        (name, side), value = check_control(key[0], key[1], value)
        if side is None:
            out[name] = value
        else:
            out.setdefault(name, {})[side] = value
    ordered = {}
    for spec in spec_by_name().values():  # data order, readable diffs
        if spec.name in out:
            ordered[spec.name] = out[spec.name]
    return {"format": FORMAT, "version": VERSION, "name": str(force_set.name), "jaw_deg": jaw, "forces": ordered}


def force_set_from_json(data, where: str = "force file", error=ForceFileError) -> ForceSet:
    """Parse a force-set JSON object; ``error`` (ForceFileError) names what is wrong in ``where``."""
    if not isinstance(data, dict):
        raise error(f"{where}: expected a JSON object with 'format', 'version' and 'forces', got {type(data).__name__}")
    fmt = data.get("format")
    if fmt != FORMAT:
        raise error(f"{where}: not a Mimica muscle force file (format is {fmt!r}, expected {FORMAT!r})")
    version = data.get("version")
    if isinstance(version, bool) or not isinstance(version, int):
        raise error(f"{where}: 'version' must be an integer, got {version!r}")
    if version > VERSION:
        raise error(f"{where} was written by a newer Mimica (format version {version}); this version reads "
                    f"version {VERSION}. Update Mimica to open it.")
    if version < 1:
        raise error(f"{where}: unknown format version {version}")
    name = data.get("name", "")
    if not isinstance(name, str):
        raise error(f"{where}: 'name' must be a string, got {name!r}")
    jaw = _check_jaw(data.get("jaw_deg", 0.0), error, where)
    raw = data.get("forces", {})
    if not isinstance(raw, dict):
        raise error(f"{where}: 'forces' must be an object mapping muscle names to forces")
    specs = spec_by_name()
    forces: dict[tuple[str, str | None], float] = {}
    for muscle, value in raw.items():
        if muscle not in specs:
            raise error(f"{where}: unknown muscle {muscle!r}; known muscles are {', '.join(specs)}")
        spec = specs[muscle]
        if spec.paired:
            if not isinstance(value, dict):
                raise error(f"{where}: {muscle} is a left/right pair: give {{\"left\": f, \"right\": f}} "
                            f"(or {{\"both\": f}}), got {value!r}")
            for side, v in value.items():
                sides = ("left", "right") if side == "both" else (side,)
                if side not in ("left", "right", "both"):
                    raise error(f"{where}: {muscle}: bad side {side!r}; use 'left', 'right' or 'both' "
                                "(the face's own sides)")
                for s in sides:
                    forces[(muscle, s)] = _check_value(muscle, s, v, error, where)
        else:
            if isinstance(value, dict):
                raise error(f"{where}: {muscle} is a single muscle around the mouth: give one number, got {value!r}")
            forces[(muscle, None)] = _check_value(muscle, None, value, error, where)
    return ForceSet(forces, jaw, name)


def _check_value(muscle, side, value, error, where) -> float:
    label = f"{muscle} ({side})" if side else muscle
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise error(f"{where}: force of {label} must be a number, got {value!r}")
    try:
        return check_control(muscle, side, value)[1]
    except ValueError as exc:
        raise error(f"{where}: {exc}") from None


def _check_jaw(value, error, where: str = "force set") -> float:
    lo, hi = jaw_range()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise error(f"{where}: 'jaw_deg' must be a finite number of degrees, got {value!r}")
    if not lo <= value <= hi:
        raise error(f"{where}: jaw opening {value:g} degrees is outside its range {lo:g} to {hi:g}")
    return float(value)


# ------------------------------------------------------------------ files
def save_force_set(path, force_set: ForceSet) -> None:
    """Write ``force_set`` as JSON to ``path`` atomically (ForceFileError with a message on failure)."""
    from core.formats.atomic_files import write_atomic, write_reporting_errors

    path = Path(path)
    try:
        data = force_set_to_json(force_set)
    except ValueError as exc:
        raise ForceFileError(f"cannot save '{path.name}': {exc}") from None
    text = json.dumps(data, indent=2) + "\n"
    write_reporting_errors(path, lambda: write_atomic(path, text.encode("utf-8")), ForceFileError)


def load_force_set(path) -> ForceSet:
    """Read a force file (ForceFileError naming what is wrong: bad JSON, unknown muscle, bad side,
    non-number, out of range, newer version, unreadable file)."""
    from core.formats.text_files import read_json_file, reading

    path = Path(path)
    where = f"'{path.name}'"
    with reading(ForceFileError, where, "muscle force"):
        data = read_json_file(path, "force", ForceFileError, what="a muscle force file")
        return force_set_from_json(data, where)



# ------------------------------------------------------------------ presets (thesis C §5.1)
@functools.cache
def _presets() -> dict[str, dict]:
    data = resources.get_json("muscles/presets.json")
    return {p["id"]: p for p in data["presets"]}


def preset_names() -> tuple[str, ...]:
    """Ids of the thesis test expressions: discreet_smile, half_smile, sadness, disgust, kiss."""
    return tuple(_presets())


def preset_id(text: str) -> str | None:
    """The id of the preset ``text`` names, by its id or its display name as the window shows it, in
    any case and spacing (``"Kiss"``, ``"Half smile, mouth open"``); None when none does."""
    def key(s: str) -> str:
        return "_".join("".join(c if c.isalnum() else " " for c in str(s).lower()).split())

    wanted = key(text)
    for pid, data in _presets().items():
        if wanted in (key(pid), key(data.get("name", ""))):
            return pid
    return None


def preset(name: str) -> ForceSet:
    """The force set of a preset (a fresh object)."""
    presets = _presets()
    if name not in presets:
        raise ValueError(f"unknown muscle preset {name!r}; presets are {', '.join(presets)}")
    return force_set_from_json(presets[name], f"preset {name!r}", error=ValueError)
