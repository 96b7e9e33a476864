"""Reading the files Mimica opens, safely: one place that says what a file may be before anything
is parsed (an existing, regular file — never a named pipe or a device, which would block — no larger
than its format's cap, stated in the refusal), reads its bytes and turns any failure of a parser
into the format's own error class (:func:`reading`), so a damaged or hostile file is a message,
never a traceback, a hang or a memory blow-up.

Also: line formats (.fap, DPC, EPC, PPC, landmark CSV) read one line at a time with clear errors
(binary data, UTF-16 read with a note, latin-1 fallback), JSON documents with depth and number checks, and the tokens' numbers."""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import re
import stat
from pathlib import Path

import numpy as np

_BINARY = re.compile(rb"[\x00-\x08\x0e-\x1f]")
_BINARY_TEXT = re.compile("[\x00-\x08\x0e-\x1f]")

#: Size caps (bytes) of the files Mimica reads, by format; a larger file is refused with the cap
#: in the message. They bound the time and memory a file can cost (measured at the cap: a .fap
#: ~5 s and ~400 MB, a DPC file ~3 s and ~400 MB) and stay far above real files (a 45,000-key
#: project is ~3 MB, a landmark file ~20 KB, thesis B's DPC files a few KB).
MAX_BYTES = {
    "project": 128 * 2**20,
    "landmark": 16 * 2**20,
    "force": 1 * 2**20,
    "FAP": 64 * 2**20,
    "DPC": 8 * 2**20,
    "PPC": 1 * 2**20,
    "EPC": 8 * 2**20,
    "mesh": 2 * 2**30,
    "image": 512 * 2**20,
    "material": 16 * 2**20,
}
#: JSON nesting deeper than this is refused (every Mimica document is at most ~6 deep).
MAX_JSON_DEPTH = 64
#: The note a UTF-16 file earns (it was read, but other programs may not read it).
UTF16_NOTE = "The file is UTF-16 text; it was read, but other programs may need UTF-8 or ASCII."



def _a(kind: str) -> str:
    """The article for a format's name as read aloud: "an EPC", "an .fap"... "a DPC", "a project"."""
    word = kind.split()[0] if kind.split() else ""
    spoken = word[:1].upper()
    acronym = word.isupper()   # read letter by letter: "an EPC", "an MTL"; words: "a Mimica project"
    return "an" if spoken and (spoken in "AEIOU" or (acronym and spoken in "FHLMNRSX")) else "a"

def size_text(n: int) -> str:
    """``n`` bytes for a message: '512 MB', '16 MB', '900 KB'."""
    if n >= 2**30 and n % 2**30 == 0:
        return f"{n // 2**30} GB"
    if n >= 2**20:
        return f"{n / 2**20:.0f} MB"
    return f"{max(1, round(n / 2**10))} KB"


def check_file(path, kind: str, error: type[Exception], *, max_bytes: int | None = None,
               what: str | None = None) -> int:
    """The size of ``path`` after checking, without opening it, that it is a regular file no larger than
    ``max_bytes`` (default ``MAX_BYTES[kind]``); ``error(message)`` otherwise.

    kind : the format ("FAP", "project") for messages and the default cap; what : "a FAP file".
    """
    path = Path(path)
    what = what or f"a {kind} file"
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"The {kind} file '{path}' does not exist. Check the name and folder.") from None
    except PermissionError:
        raise error(f"Mimica is not allowed to read '{path}'. Check the permissions of the file and its folder.") from None
    except (OSError, ValueError) as exc:
        raise error(f"'{path}' cannot be opened: {getattr(exc, 'strerror', None) or exc}.") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"'{path}' is a folder, not {what}. Choose a file inside it.")
    if not stat.S_ISREG(st.st_mode):
        kind_of = ("a named pipe (FIFO)" if stat.S_ISFIFO(st.st_mode) else "a device" if
                   stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode)
                   else "not a regular file")
        raise error(f"'{path}' is {kind_of}, not {what}; Mimica reads only regular files. "
                    "Save the data to a file first and open that.")
    cap = MAX_BYTES.get(kind) if max_bytes is None else max_bytes
    if cap is not None and st.st_size > cap:
        raise error(f"'{path.name}' is {size_text(st.st_size)}, more than the {size_text(cap)} Mimica accepts for "
                    f"{what}; it is probably not {what}, or split it into smaller files.")
    return st.st_size


def read_file_bytes(path, kind: str, error: type[Exception], *, max_bytes: int | None = None,
                    what: str | None = None) -> bytes:
    """The bytes of ``path`` after :func:`check_file` (never more than the cap, even if it grows)."""
    path = Path(path)
    cap = MAX_BYTES.get(kind) if max_bytes is None else max_bytes
    check_file(path, kind, error, max_bytes=max_bytes, what=what)
    try:
        with open(path, "rb") as fh:
            data = fh.read() if cap is None else fh.read(cap + 1)
    except PermissionError:
        raise error(f"Mimica is not allowed to read '{path}'. Check the file's permissions.") from None
    except MemoryError:
        raise error(f"'{path.name}' is too large to read into memory.") from None
    except OSError as exc:
        raise error(f"'{path.name}' could not be read: {exc.strerror or exc}.") from None
    if cap is not None and len(data) > cap:
        raise error(f"'{path.name}' is more than the {size_text(cap)} Mimica accepts for {what or f'a {kind} file'}.")
    return data


@contextlib.contextmanager
def reading(error: type[Exception], source: str, kind: str):
    """Turn anything a parser raises into ``error`` naming ``source`` (its own errors pass unchanged):
    a damaged or hostile file gives a message, never a traceback."""
    try:
        yield
    except (error, NotUtf8):   # NotUtf8: the caller reads the file again as latin-1
        raise
    except RecursionError:
        raise error(f"{source}: the {kind} data is nested too deeply to be a {kind} file.") from None
    except MemoryError:
        raise error(f"{source}: the {kind} data needs more memory than this computer has; it is probably "
                    "damaged.") from None
    except (OverflowError, TypeError, ValueError, UnicodeError, KeyError, IndexError, AttributeError) as exc:
        detail = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else "it cannot be read"
        raise error(f"{source}: the {kind} data is damaged or not {_a(kind)} file ({detail}). Save it again from "
                    "the program that made it, or open a backup.") from None


def _json_depth_ok(text: str, limit: int) -> bool:
    """False when brackets (outside strings) nest deeper than ``limit`` — checked before parsing,
    so a deeply nested document never reaches the recursive parser."""
    if text.count("[") + text.count("{") <= limit:
        return True
    stripped = re.sub(r'"(?:[^"\\]|\\.)*"', '""', text)
    depth = 0
    for match in re.finditer(r"[\[\]{}]", stripped):
        if match.group() in "[{":
            depth += 1
            if depth > limit:
                return False
        else:
            depth -= 1
    return True


def _reject_constant(name: str):
    raise ValueError(f"{name} is not a valid number (numbers must be finite)")


def _parse_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"the number {text[:40]} is too large (numbers must be finite)")
    return value


def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > 30:  # far beyond any count or index in a Mimica file
        raise ValueError(f"the whole number {text[:40]}… has {len(text)} digits, too many")
    return int(text)


def parse_json(text: str, source: str, error: type[Exception], kind: str, *, hint: str = ""):
    """The JSON document in ``text``: no NaN/Infinity, numbers that fit a float, at most
    ``MAX_JSON_DEPTH`` levels; ``error`` naming ``source`` and the line otherwise."""
    if not _json_depth_ok(text, MAX_JSON_DEPTH):
        raise error(f"{source} is not {_a(kind)} file: its JSON nests more than {MAX_JSON_DEPTH} levels deep.")
    try:
        return json.loads(text, parse_constant=_reject_constant, parse_float=_parse_float, parse_int=_parse_int)
    except json.JSONDecodeError as exc:
        raise error(f"{source} is not valid JSON: {exc.msg} at line {exc.lineno}, column {exc.colno}."
                    + (f" {hint}" if hint else "")) from None
    except RecursionError:
        raise error(f"{source} is not {_a(kind)} file: its JSON nests too deeply.") from None
    except (ValueError, OverflowError) as exc:
        raise error(f"{source} is not a valid {kind} file: {exc}.") from None


def read_json_file(path, kind: str, error: type[Exception], *, what: str | None = None, hint: str = ""):
    """The JSON document of the file at ``path`` (UTF-8, size-capped, regular file); ``error`` otherwise."""
    path = Path(path)
    data = read_file_bytes(path, kind, error, what=what)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise error(f"'{path.name}' is not {what or f'a {kind} file'} (it is not UTF-8 text).") from None
    return parse_json(text, f"'{path.name}'", error, kind, hint=hint)


class NotUtf8(Exception):
    """Raised by :func:`text_lines` when UTF-8 decoding fails: read the file again as latin-1."""


class _CappedRaw(io.RawIOBase):
    """A file's bytes, refusing (``error``) to go past ``cap`` even if the file grows while read."""

    def __init__(self, fh, cap: int | None, error: Exception):
        self._fh, self._left, self._error = fh, (cap + 1 if cap is not None else None), error

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        n = self._fh.readinto(buffer)
        if self._left is not None and n:
            self._left -= n
            if self._left <= 0:
                raise self._error
        return n


def text_lines(path, kind: str, error: type[Exception], binary_hint: str, *, latin1: bool = False):
    """Yield the lines of a text file one at a time (without their line ends; any of \\n, \\r\\n,
    \\r), so a parser holds only what it keeps, never the whole text, after the checks of
    :func:`check_file` (a binary line is refused when it is reached; UTF-16 with a BOM is read,
    and :func:`parse_text_lines` adds the note it earns).

    Raises :class:`NotUtf8` when the bytes are not UTF-8: call again with ``latin1=True``.
    """
    path = Path(path)
    check_file(path, kind, error)
    cap = MAX_BYTES.get(kind)
    too_big = error(f"'{path.name}' is more than the {size_text(cap)} Mimica accepts for a {kind} file."
                    if cap is not None else f"'{path.name}' is too large.")
    try:
        fh = open(path, "rb")
    except PermissionError:
        raise error(f"Mimica is not allowed to read '{path}'. Check the file's permissions.") from None
    except OSError as exc:
        raise error(f"'{path.name}' could not be read: {exc.strerror or exc}.") from None
    with fh:
        start = fh.read(2)
        fh.seek(0)
        utf16 = start in (b"\xff\xfe", b"\xfe\xff")
        encoding = "utf-16" if utf16 else "latin-1" if latin1 else "utf-8-sig"
        text = io.TextIOWrapper(io.BufferedReader(_CappedRaw(fh, cap, too_big)), encoding=encoding, newline=None)
        try:
            for line in text:
                line = line.rstrip("\n")
                if not utf16 and _BINARY_TEXT.search(line):
                    raise error(f"'{path.name}' is not a text file (it contains binary data). {binary_hint}")
                yield line
        except UnicodeDecodeError:
            if utf16:
                raise error(f"'{path.name}' starts like UTF-16 text but is not valid UTF-16. "
                            "Save it again as UTF-8 text in a text editor.") from None
            raise NotUtf8(str(path)) from None
        except OSError as exc:
            raise error(f"'{path.name}' could not be read: {exc.strerror or exc}.") from None


class RowBlocks:
    """Rows of a fixed width appended one at a time into arrays of 4096 rows (a frame costs its bytes, not
    a Python object per frame; joining them costs one more copy of the largest column)."""

    BLOCK = 4096

    def __init__(self, width: int, dtype):
        self._width, self._dtype = width, dtype
        self._blocks: list[np.ndarray] = []
        self._pending: list = []   # the rows of the block being filled (converted in one call when full)

    def __len__(self) -> int:
        return len(self._blocks) * self.BLOCK + len(self._pending)

    def append(self, row) -> None:
        self._pending.append(row)
        if len(self._pending) == self.BLOCK:
            self._blocks.append(self._block(self._pending))
            self._pending = []

    def _block(self, rows) -> np.ndarray:
        return np.array(rows, self._dtype).reshape(len(rows), self._width)

    def array(self) -> np.ndarray:
        """(n, width) array of the rows; the blocks are released (call once, at the end)."""
        out = np.empty((len(self), self._width), self._dtype)
        for k, block in enumerate(self._blocks):
            out[k * self.BLOCK:(k + 1) * self.BLOCK] = block
        out[len(self._blocks) * self.BLOCK:] = self._block(self._pending)
        self._blocks, self._pending = [], []
        return out


def parse_text_lines(path, kind: str, error: type[Exception], binary_hint: str, parse):
    """(``parse(lines)``, notes) for the text file at ``path``, read line by line through
    :func:`text_lines` (UTF-8, else latin-1; UTF-16 with a BOM earns a note), for parsers that take
    an iterable of lines."""
    for latin1 in (False, True):
        try:
            result = parse(text_lines(path, kind, error, binary_hint, latin1=latin1))
        except NotUtf8:
            continue   # not UTF-8: read it again as latin-1 (every byte is a latin-1 character)
        break
    return result, [UTF16_NOTE] if is_utf16(path) else []


def is_utf16(path) -> bool:
    """Whether ``path`` starts with a UTF-16 byte-order mark."""
    with open(path, "rb") as fh:
        return fh.read(2) in (b"\xff\xfe", b"\xfe\xff")


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
