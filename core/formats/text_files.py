"""Reading small text formats (.fap, DPC) with clear errors: missing file, folder, permissions,
binary data, UTF-16 (read, with a note) and latin-1 fallback; and the tokens' numbers."""

from __future__ import annotations

import math
import re
from pathlib import Path

_BINARY = re.compile(rb"[\x00-\x08\x0e-\x1f]")


def read_text_file(path, kind: str, error: type[Exception], binary_hint: str) -> tuple[str, list[str]]:
    """(text, notes) of ``path``; ``error(message)`` for anything unreadable.

    kind : what the file should be, for messages ("FAP", "DPC").
    binary_hint : one sentence saying what a text file of this kind looks like.
    """
    path = Path(path)
    if not path.exists():
        raise error(f"The {kind} file '{path}' does not exist. Check the name and folder.")
    if path.is_dir():
        raise error(f"'{path}' is a folder, not a {kind} file. Choose a file inside it.")
    try:
        data = path.read_bytes()
    except PermissionError:
        raise error(f"Mimica is not allowed to read '{path}'. Check the file's permissions.") from None
    except OSError as exc:
        raise error(f"'{path.name}' could not be read: {exc.strerror or exc}.") from None
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            text = data.decode("utf-16")
        except UnicodeDecodeError:
            raise error(f"'{path.name}' starts like UTF-16 text but is not valid UTF-16. "
                        "Save it again as UTF-8 text in a text editor.") from None
        return text, ["The file is UTF-16 text; it was read, but other programs may need UTF-8 or ASCII."]
    if _BINARY.search(data):
        raise error(f"'{path.name}' is not a text file (it contains binary data). {binary_hint}")
    try:
        return data.decode("utf-8-sig"), []
    except UnicodeDecodeError:
        return data.decode("latin-1"), []


def number(token: str) -> float | None:
    """The finite float ``token`` spells, else None."""
    try:
        value = float(token)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def integer(token: str) -> int | None:
    """The whole number ``token`` spells ('3' or '3.0'), else None."""
    try:
        return int(token)
    except ValueError:
        value = number(token)
        return int(value) if value is not None and value.is_integer() else None
