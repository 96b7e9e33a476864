"""Data files shipped with Mimica, loaded through one helper.

Tables are CSV (read as lists of dicts, strings unparsed), structured data is
JSON, arrays are NPZ. Results are cached per process; callers must not mutate
what they get back (tables are returned as tuples of read-only mappings).
"""

from __future__ import annotations

import csv
import functools
import json
from importlib import resources as _ilr
from pathlib import Path
from types import MappingProxyType

_ROOT = Path(str(_ilr.files(__name__)))


def path(name: str) -> Path:
    """Absolute path of a resource file, e.g. ``path("default_face/face.npz")``."""
    p = _ROOT / name
    if not p.exists():
        raise FileNotFoundError(f"Mimica resource {name!r} is missing from {_ROOT}; reinstall Mimica")
    return p


@functools.cache
def get_table(name: str) -> tuple:
    """Rows of a CSV resource as read-only dicts (column -> str). Lines starting with '#' are comments."""
    with open(path(name), newline="", encoding="utf-8") as fh:
        lines = [line for line in fh if not line.lstrip().startswith("#")]
    return tuple(MappingProxyType(dict(row)) for row in csv.DictReader(lines))


@functools.cache
def _json_text(name: str) -> str:
    return path(name).read_text(encoding="utf-8")


def get_json(name: str):
    """Parsed JSON resource (a fresh object each call, so callers may modify it)."""
    return json.loads(_json_text(name))
