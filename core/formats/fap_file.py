"""fap_file.py
----
Read and write the textual MPEG-4 ``.fap`` format (FAP animation files of the
MPEG-4 reference tools, Xface, Greta, visage|SDK, VREng)::

    # optional comment lines
    2.1 <name> <fps> <num_frames>           header
    1 0 1 0 0 ... (68 entries, 0 or 1)      mask of frame 0, FAP 1 first
    0 1 7 40 0 120                          frame number, then the masked-in FAPs' values
    ...                                     one mask line + one value line per frame

FAP 1 (viseme) takes 4 numbers on a value line and FAP 2 (expression) 6; every
low-level FAP (3..68) one number, in FAPU or, for rotations, AU (1e-5 rad).

The reader tolerates what real files contain and says so in
``FapSequence.notes`` (one sentence per kind of quirk): Greta's 69-entry masks
and one-number FAP 1/2, header names with spaces (Greta writes file names),
frame numbers not counting 0, 1, 2, ..., a frame count in the header that
disagrees with the file, UTF-16 files. Comment lines ('#' first), blank lines,
TABs, trailing spaces and CRLF line ends are part of normal files and are
accepted silently. VREng's division of version-2.0 values by 20 is a VREng
quirk, not the format, and is not applied.

The writer produces the standard layout (68-entry masks, FAP 1 as 4 numbers,
FAP 2 as 6) without comment lines, because Greta's reader does not skip them.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from core.formats.atomic_files import write_atomic, write_reporting_errors
from core.formats.text_files import integer as _integer
from core.formats.text_files import number as _number
from core.formats.text_files import NotUtf8, is_utf16, reading, text_lines
from core.formats.text_files import RowBlocks as _Rows

__all__ = [
    "N_FAPS", "VISEME_FIELDS", "EXPRESSION_FIELDS", "FapFileError", "FapSequence",
    "parse_fap", "parse_fap_lines", "read_fap", "format_fap", "write_fap", "check_fap_size",
]

N_FAPS = 68
#: (name, lowest, highest) of the 4 numbers of FAP 1, in file order.
VISEME_FIELDS = (
    ("viseme_select1", 0, 14), ("viseme_select2", 0, 14), ("viseme_blend", 0, 63), ("viseme_def", 0, 1),
)
#: (name, lowest, highest) of the 6 numbers of FAP 2, in file order.
EXPRESSION_FIELDS = (
    ("expression_select1", 0, 6), ("expression_intensity1", 0, 63), ("expression_select2", 0, 6),
    ("expression_intensity2", 0, 63), ("init_face", 0, 1), ("expression_def", 0, 1),
)
_HEADER = "'<version> <name> <fps> <num_frames>'"
#: Frame rates a .fap header may give (frames per second).
FPS_RANGE = (0.1, 1000.0)
#: The longest animation a .fap file may hold (the timeline's limit, 24 h).
MAX_DURATION_S = 24 * 3600.0
#: Frame numbers beyond this (in magnitude) are refused.
MAX_FRAME_NUMBER = 10**12


class FapFileError(ValueError):
    """A .fap file or text could not be read or written; ``str(error)`` is a user-facing message."""


@dataclass(eq=False)
class FapSequence:
    """A .fap animation. Frame k's low-level values are values[k, fap-1] in FAP units (FAPU or AU),
    valid where mask[k, fap-1]; columns 0 and 1 (FAPs 1, 2) of values are unused (NaN).

    Attributes
    ----------
    fps : float
        Frames per second.
    values : (n_frames, 68) float64
        NaN where not masked in.
    mask : (n_frames, 68) bool
        Column ``fap - 1`` tells whether FAP ``fap`` is set in a frame.
    viseme : (n_frames, 4) int64
        viseme_select1, viseme_select2 (0..14), viseme_blend (0..63: 63 = all select1), viseme_def;
        meaningful where ``mask[:, 0]`` (-1 elsewhere when read or built by :meth:`from_values`).
    expression : (n_frames, 6) int64
        expression_select1, expression_intensity1, expression_select2, expression_intensity2
        (selects 0..6, intensities 0..63), init_face, expression_def; meaningful where ``mask[:, 1]``.
    name, version : str
        Header fields (the name may contain spaces; they are written as '_').
    notes : list of str
        What the reader tolerated, one sentence per kind.
    """

    fps: float
    values: np.ndarray
    mask: np.ndarray
    viseme: np.ndarray
    expression: np.ndarray
    name: str = "mimica"
    version: str = "2.1"
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.fps = float(self.fps)
        self.values = np.asarray(self.values, dtype=np.float64)
        self.mask = np.asarray(self.mask, dtype=bool)
        self.viseme = np.asarray(self.viseme, dtype=np.int64)
        self.expression = np.asarray(self.expression, dtype=np.int64)
        n = len(self.values)
        for label, array, width in (("values", self.values, N_FAPS), ("mask", self.mask, N_FAPS),
                                    ("viseme", self.viseme, 4), ("expression", self.expression, 6)):
            if array.shape != (n, width):
                raise ValueError(f"FapSequence.{label} must have shape ({n}, {width}), got {array.shape}")

    @property
    def n_frames(self) -> int:
        return len(self.values)

    @property
    def duration(self) -> float:
        """Length in seconds (n_frames / fps)."""
        return self.n_frames / self.fps

    @classmethod
    def from_values(cls, values: np.ndarray, fps: float, *, name: str = "mimica",
                    viseme: np.ndarray | None = None, expression: np.ndarray | None = None) -> FapSequence:
        """Build a sequence from low-level values (n, 68) with NaN = not driven (columns 0, 1 ignored).

        ``viseme`` (n, 4) and ``expression`` (n, 6) are optional; a row of -1 means "not set in that
        frame", any other row masks FAP 1 / FAP 2 in and must be in range (else :class:`FapFileError`).
        """
        values = np.array(values, dtype=np.float64)
        if values.ndim != 2 or values.shape[1] != N_FAPS:
            raise ValueError(f"values must have shape (n_frames, {N_FAPS}), got {values.shape}")
        n = len(values)
        values[:, :2] = np.nan
        mask = ~np.isnan(values)
        high = []
        for label, given, fields in (("viseme", viseme, VISEME_FIELDS), ("expression", expression, EXPRESSION_FIELDS)):
            width = len(fields)
            array = np.full((n, width), -1, np.int64) if given is None else np.asarray(given)
            if array.shape != (n, width):
                raise ValueError(f"{label} must have shape ({n}, {width}), got {array.shape}")
            if not np.array_equal(array, np.round(array)):
                raise FapFileError(f"The {label} numbers must be whole numbers.")
            array = array.astype(np.int64)
            is_set = (array != -1).any(axis=1)
            _check_high_level(array, is_set, fields, "Cannot use")
            high.append(array)
            mask[:, len(high) - 1] = is_set
        return cls(float(fps), values, mask, high[0], high[1], name=name)

    def frame(self, k: int) -> dict[int, float]:
        """{fap_number: value} of the low-level FAPs (3..68) masked in at frame ``k``."""
        columns = np.flatnonzero(self.mask[k, 2:]) + 2
        return {int(c) + 1: float(v) for c, v in zip(columns, self.values[k, columns])}


# ------------------------------------------------------------------ reading
def parse_fap(text: str, *, source: str = "<text>") -> FapSequence:
    """Parse the text of a .fap file (see :func:`parse_fap_lines`)."""
    return parse_fap_lines(io.StringIO(text.removeprefix("\ufeff"), newline=None), source=source)


def parse_fap_lines(lines: Iterable[str], *, source: str = "<text>") -> FapSequence:
    """Parse a .fap file from its lines (an iterable of strings, line ends optional), one at a time:
    what is held is the frames read so far, never the whole text.

    ``source`` names the file in error messages ("'joy.fap', line 5: ...").

    Raises
    ------
    FapFileError
        Missing or malformed header, a mask line with fewer than 68 entries or an entry that is not
        0/1, a value line with the wrong number of numbers or a non-number, a viseme/expression field
        out of range, a mask line without its value line; the message names the line.
    """
    parser = _Parser(source)
    lines = _content_lines(lines)
    first = next(lines, None)
    if first is None:
        raise FapFileError(f"{parser.prefix()}the file is empty; expected the header line {_HEADER}.")
    version, name, fps, declared = parser.header(*first)
    max_frames = int(MAX_DURATION_S * fps) + 1
    masks, values = _Rows(N_FAPS, bool), _Rows(N_FAPS, np.float64)
    visemes, expressions = _Rows(4, np.int64), _Rows(6, np.int64)
    frame_numbers, number_lines = _Rows(1, np.int64), _Rows(1, np.int64)
    for mask_line, mask_tokens in lines:
        if len(masks) >= max_frames:
            raise parser.error(mask_line, f"the file has more than {max_frames} frames, longer than "
                                          f"{MAX_DURATION_S / 3600:g} h at {fps:g} fps (the longest animation "
                                          "Mimica takes); split it into shorter files")
        mask, extra = parser.mask(mask_line, mask_tokens)
        value = next(lines, None)
        if value is None:
            raise parser.error(mask_line, f"the mask line of frame {len(masks)} has no value line after it "
                                          "(the file ends there); the file is probably truncated")
        frame_number, row, vis, expr = parser.values(*value, mask, mask_line, extra)
        masks.append(mask)
        values.append(row)
        visemes.append(vis)
        expressions.append(expr)
        frame_numbers.append(frame_number)
        number_lines.append(value[0])
    n = len(masks)
    if n != declared:
        parser.note("count", f"The header says {declared} frames, file has {n}"
                    + ("; all of them were read." if n > declared else "."))
    parser.check_frame_numbers(frame_numbers.array()[:, 0], number_lines.array()[:, 0])
    low = values.array()
    return FapSequence(
        fps=fps,
        values=low,
        mask=masks.array(),
        viseme=visemes.array(),
        expression=expressions.array(),
        name=name,
        version=version,
        notes=parser.notes,
    )


def read_fap(path) -> FapSequence:
    """Read a .fap file (UTF-8, latin-1 or UTF-16 with BOM text) line by line; see :func:`parse_fap_lines`.

    Raises
    ------
    FapFileError
        Missing, unreadable or binary file, or any error of :func:`parse_fap_lines`.
    """
    path = Path(path)
    hint = (f"Mimica reads the textual .fap format (a header line {_HEADER}, then a mask line and a value line "
            "per frame); a binary MPEG-4 FBA stream must be converted to a text .fap file first.")
    for latin1 in (False, True):
        with reading(FapFileError, f"'{path.name}'", "FAP"):
            try:
                seq = parse_fap_lines(text_lines(path, "FAP", FapFileError, hint, latin1=latin1), source=path.name)
            except NotUtf8:
                continue   # not UTF-8: read it again as latin-1 (every byte is a latin-1 character)
        break
    if is_utf16(path):
        seq.notes.insert(0, "The file is UTF-16 text; it was read, but other programs may need UTF-8 or ASCII.")
    return seq


def _guarded(parse):
    """``parse`` with any exception a hostile text provokes turned into FapFileError."""
    import functools

    @functools.wraps(parse)
    def wrapper(text, *, source: str = "<text>"):
        with reading(FapFileError, f"'{source}'" if source != "<text>" else "the .fap text", "FAP"):
            return parse(text, source=source)
    return wrapper


parse_fap = _guarded(parse_fap)
parse_fap_lines = _guarded(parse_fap_lines)


def _content_lines(lines: Iterable[str]):
    """Yield (1-based line number, tokens) of each line that is neither blank nor a '#' comment."""
    for number, line in enumerate(lines, 1):
        tokens = line.split()
        if tokens and not tokens[0].startswith("#"):
            yield number, tokens


def _looks_like_mask(tokens: list[str]) -> bool:
    return len(tokens) >= N_FAPS and set(tokens) <= {"0", "1"}


class _Parser:
    """Line-level checks of :func:`parse_fap`, with the source name and the notes collected so far."""

    def __init__(self, source: str):
        self.source = source
        self.notes: list[str] = []
        self._noted: set[str] = set()
        self._masks: dict[tuple, tuple[np.ndarray, int]] = {}

    def prefix(self, line: int | None = None) -> str:
        where = "" if self.source == "<text>" else f"'{self.source}'"
        if line is not None:
            where = f"{where}, line {line}" if where else f"line {line}"
        return f"{where}: " if where else ""

    def error(self, line: int, message: str) -> FapFileError:
        end = "" if message.endswith(("?", ".")) else "."
        return FapFileError(f"{self.prefix(line)}{message}{end}")

    def note(self, kind: str, text: str) -> None:
        if kind not in self._noted:
            self._noted.add(kind)
            self.notes.append(text)

    def header(self, line: int, tokens: list[str]) -> tuple[str, str, float, int]:
        """(version, name, fps, num_frames) from the header line."""
        if _looks_like_mask(tokens):
            raise self.error(line, f"expected the header line {_HEADER}, found a mask line "
                                   f"({len(tokens)} zeros and ones); the header is missing")
        fps, count = (_number(tokens[-2]), _integer(tokens[-1])) if len(tokens) >= 4 else (None, None)
        if len(tokens) < 4 or (len(tokens) > 4 and (fps is None or count is None)):
            raise self.error(line, f"expected the header line {_HEADER} (4 items), found {len(tokens)} "
                                   f"items: {' '.join(tokens)!r}")
        version = tokens[0]
        if _number(version) is None:
            raise self.error(line, f"the version {version!r} in the header is not a number; expected e.g. 2.1")
        if fps is None:
            raise self.error(line, f"the frame rate {tokens[-2]!r} in the header is not a number")
        if not FPS_RANGE[0] <= fps <= FPS_RANGE[1]:
            raise self.error(line, f"the frame rate in the header is {tokens[-2]}; it must be from {FPS_RANGE[0]:g} "
                                   f"to {FPS_RANGE[1]:g} frames per second")
        if count is None or count < 0:
            raise self.error(line, f"the number of frames in the header must be a whole number >= 0, "
                                   f"found {tokens[-1]!r}")
        name = " ".join(tokens[1:-2])
        if len(tokens) > 4:
            self.note("name", f"The name in the header contains spaces ({name!r}; Greta writes file names there); "
                              "it is written back with '_' instead of spaces.")
        return version, name, fps, count

    def mask(self, line: int, tokens: list[str]) -> tuple[np.ndarray, int]:
        """((68,) bool, number of 1s after the 68th entry) from a mask line (read-only: a mask met
        again is not parsed again — files repeat a few masks over thousands of frames)."""
        key = tuple(tokens)
        cached = self._masks.get(key)
        if cached is not None:
            return cached
        cached = self._parse_mask(line, tokens)
        cached[0].setflags(write=False)
        if len(self._masks) < 4096:
            self._masks[key] = cached
        return cached

    def _parse_mask(self, line: int, tokens: list[str]) -> tuple[np.ndarray, int]:
        if len(tokens) < N_FAPS:
            raise self.error(line, f"expected {N_FAPS} mask values (0 or 1), found {len(tokens)}")
        if len(tokens) > N_FAPS:
            self.note("long mask", f"Mask lines have more than {N_FAPS} entries ({len(tokens)} on line {line}; "
                                   f"Greta writes 69); the entries after the {N_FAPS}th were ignored.")
        entries = np.array(tokens[:N_FAPS])
        mask = entries == "1"
        for column in np.flatnonzero(~mask & (entries != "0")).tolist():  # odd spellings such as '+1' or '1.0'
            bit = _integer(tokens[column])
            if bit not in (0, 1):
                raise self.error(line, f"mask entry {column + 1} (FAP {column + 1}) is {tokens[column]!r}; "
                                       "expected 0 or 1")
            mask[column] = bit == 1
        return mask, sum(_integer(t) == 1 for t in tokens[N_FAPS:])

    def values(self, line: int, tokens: list[str], mask: np.ndarray, mask_line: int, extra: int = 0):
        """(frame number, (68,) float values, (4,) viseme, (6,) expression) from a value line.

        ``extra``: 1s in the mask after its 68th entry; their values (at the end of the line) are dropped.
        """
        n_low = int(mask[2:].sum())
        has_viseme, has_expression = bool(mask[0]), bool(mask[1])
        standard = 1 + n_low + 4 * has_viseme + 6 * has_expression
        single = 1 + n_low + has_viseme + has_expression
        if extra and len(tokens) not in (standard, single) and len(tokens) - extra in (standard, single):
            tokens = tokens[:-extra]
            self.note("extra values", f"Some value lines end with values for mask entries after the {N_FAPS}th "
                                      f"(line {line}); they were ignored.")
        if len(tokens) == standard:
            widths = (4 * has_viseme, 6 * has_expression)
        elif len(tokens) == single:
            widths = (int(has_viseme), int(has_expression))
            if has_viseme:
                self.note("viseme1", "FAP 1 (viseme) is written as one number (Greta/VREng style); it was read "
                                     "as viseme_select1 with viseme_blend 63.")
            if has_expression:
                self.note("expression1", "FAP 2 (expression) is written as one number (Greta/VREng style); it "
                                         "was read as expression_select1 with expression_intensity1 63.")
        else:
            raise self.error(line, self._count_message(len(tokens), n_low, has_viseme, has_expression, mask_line)
                             + ("; this looks like a mask line: is the value line of the frame before missing?"
                                if _looks_like_mask(tokens) else ""))
        frame_number = _integer(tokens[0])
        if frame_number is None:
            raise self.error(line, f"the frame number {tokens[0]!r} (first item) is not a whole number")
        if abs(frame_number) > MAX_FRAME_NUMBER:
            raise self.error(line, f"the frame number {tokens[0]} (first item) is out of range; frame numbers "
                                   f"count frames from 0 (at most {MAX_FRAME_NUMBER:g})")
        position = 1
        viseme = np.full(4, -1, np.int64)
        expression = np.full(6, -1, np.int64)
        for target, width, fields, default, fap in ((viseme, widths[0], VISEME_FIELDS, (0, 63, 0), 1),
                                                    (expression, widths[1], EXPRESSION_FIELDS, (63, 0, 0, 0, 0), 2)):
            if width:
                used = fields[:width]
                target[:width] = [self._field(line, t, f, fap) for t, f in zip(tokens[position:position + width], used)]
                if width == 1:
                    target[1:] = default
                position += width
        row = np.full(N_FAPS, np.nan)
        low_tokens = tokens[position:]
        try:
            low = np.array([float(t) for t in low_tokens])
        except ValueError:
            low = None
        faps = np.flatnonzero(mask[2:]) + 3
        if low is None or not np.isfinite(low).all():
            for token, fap in zip(low_tokens, faps):
                if _number(token) is None:
                    raise self.error(line, f"{token!r} is not a number (the value of FAP {fap})")
        row[faps - 1] = low
        return frame_number, row, viseme, expression

    def _field(self, line: int, token: str, spec: tuple[str, int, int], fap: int) -> int:
        name, lowest, highest = spec
        value = _integer(token)
        if value is None and _number(token) is None:
            raise self.error(line, f"{token!r} is not a number ({name} of FAP {fap})")
        if value is None or not lowest <= value <= highest:
            raise self.error(line, f"{name} (FAP {fap}) is {token}; expected a whole number from {lowest} to {highest}")
        return value

    @staticmethod
    def _count_message(found: int, n_low: int, has_viseme: bool, has_expression: bool, mask_line: int) -> str:
        standard = 1 + n_low + 4 * has_viseme + 6 * has_expression
        low = f"{n_low} value{'' if n_low == 1 else 's'} for the {'low-level ' * (has_viseme or has_expression)}" \
              f"FAPs set in the mask on line {mask_line}"
        if not (has_viseme or has_expression):
            return f"expected {standard} numbers (the frame number, then {low}), found {found}"
        high = [text for flag, text in ((has_viseme, "4 for FAP 1 (viseme)"),
                                        (has_expression, "6 for FAP 2 (expression)")) if flag]
        named = " and ".join(f"FAP {fap}" for flag, fap in ((has_viseme, 1), (has_expression, 2)) if flag)
        single = 1 + n_low + has_viseme + has_expression
        return (f"expected {standard} numbers (the frame number, {', '.join(high)}, then {low}) or {single} "
                f"(with {named} as one number{' each' if has_viseme and has_expression else ''}, as Greta and VREng "
                f"write {'them' if has_viseme and has_expression else 'it'}), found {found}")

    def check_frame_numbers(self, numbers: np.ndarray, lines: list[int]) -> None:
        """Note frame numbers that do not count 0, 1, 2, ... (frames are kept in file order anyway)."""
        expected = np.arange(len(numbers))
        if np.array_equal(numbers, expected):
            return
        if np.all(np.diff(numbers) == 1):
            self.note("numbers", f"The frame numbers start at {numbers[0]} instead of 0; "
                                 "the frames were kept in file order.")
        else:
            k = int(np.flatnonzero(numbers != numbers[0] + expected)[0])
            self.note("numbers", f"The frame numbers do not count up by 1 (line {lines[k]} has frame number "
                                 f"{numbers[k]} where {numbers[0] + k} was expected); the frames were kept in "
                                 "file order, one per mask/value pair.")


# ------------------------------------------------------------------ writing
def check_fap_size(n_frames: int, n_faps: int = 1) -> None:
    """FapFileError unless a .fap of ``n_frames`` frames driving ``n_faps`` low-level FAPs stays within
    the size Mimica reads back (``text_files.MAX_BYTES['FAP']``); call it before evaluating a long
    animation, so a 24 h export is refused in a moment instead of after minutes."""
    from core.formats.text_files import MAX_BYTES, size_text

    cap = MAX_BYTES["FAP"]
    estimate = int(n_frames) * (2 * N_FAPS + 8 + 7 * max(int(n_faps), 0))
    if estimate > cap:
        raise FapFileError(
            f"A .fap of {n_frames:,} frames × {n_faps} FAPs would be about {size_text(estimate)}, more than the "
            f"{size_text(cap)} a .fap file may have (Mimica would not read it back). Shorten the timeline or "
            f"export at a lower frame rate (at most about {cap // (2 * N_FAPS + 8 + 7 * max(int(n_faps), 1)):,} "
            "frames).")


def format_fap(seq: FapSequence) -> str:
    """The standard .fap text of ``seq``: header '<version> <name> <fps> <n>' (spaces in the name
    become '_'), 68-entry masks, FAP 1 as 4 numbers, FAP 2 as 6, frames numbered from 0; values
    as integers when integral, else with up to 4 decimals. LF line ends.

    Raises
    ------
    FapFileError
        fps not > 0, a version that is not a number, a masked-in value that is NaN or infinite, or a
        masked-in viseme/expression out of range.
    """
    fps = float(seq.fps)
    if not (math.isfinite(fps) and fps > 0):
        raise FapFileError(f"Cannot write a .fap file with a frame rate of {seq.fps} fps; "
                           "the frame rate must be greater than 0.")
    version = str(seq.version).strip()
    if _number(version) is None or len(version.split()) != 1:
        raise FapFileError(f"Cannot write a .fap file of version {seq.version!r}; the version must be a number "
                           "such as 2.1.")
    mask = seq.mask
    low_mask = mask[:, 2:]
    low = seq.values[:, 2:][low_mask]
    bad = ~np.isfinite(low)
    if bad.any():
        k, column = np.argwhere(low_mask)[np.flatnonzero(bad)[0]]
        raise FapFileError(f"Cannot write frame {k}: FAP {column + 3} is masked in but its value is "
                           f"{seq.values[k, column + 2]}.")
    _check_high_level(seq.viseme, mask[:, 0], VISEME_FIELDS, "Cannot write")
    _check_high_level(seq.expression, mask[:, 1], EXPRESSION_FIELDS, "Cannot write")
    check_fap_size(seq.n_frames, int(low_mask.any(axis=0).sum()) + 10 * bool(mask[:, :2].any()))

    name = "_".join(str(seq.name).split()) or "mimica"
    fps_text = str(int(fps)) if fps.is_integer() else repr(fps)
    lines = [f"{version} {name} {fps_text} {seq.n_frames}"]
    mask_lines = [" ".join(row) for row in np.where(mask, "1", "0").tolist()]
    low_text = _format_numbers(low)
    ends = np.cumsum(low_mask.sum(axis=1)).tolist()
    start = 0
    for k, (mask_line, end, vis, expr) in enumerate(zip(mask_lines, ends, seq.viseme.tolist(),
                                                          seq.expression.tolist())):
        tokens = [str(k)]
        if mask[k, 0]:
            tokens += map(str, vis)
        if mask[k, 1]:
            tokens += map(str, expr)
        tokens += low_text[start:end]
        start = end
        lines += [mask_line, " ".join(tokens)]
    return "\n".join(lines) + "\n"


def write_fap(path, seq: FapSequence) -> None:
    """Write ``seq`` to ``path`` in the format of :func:`format_fap` (UTF-8), atomically.

    Raises
    ------
    FapFileError
        Anything :func:`format_fap` refuses, a missing or unwritable folder, disk errors.
    """
    path = Path(path)
    data = format_fap(seq).encode("utf-8")
    write_reporting_errors(path, lambda: write_atomic(path, data), FapFileError)


def _format_numbers(values: np.ndarray) -> list[str]:
    """Each value as an integer when it rounds to one at 4 decimals, else with up to 4 decimals."""
    rounded = np.round(values, 4)
    integral = rounded == np.trunc(rounded)
    text = np.empty(len(values), dtype=object)
    text[integral] = [str(int(v)) for v in rounded[integral].tolist()]
    text[~integral] = [f"{v:.4f}".rstrip("0") for v in rounded[~integral].tolist()]
    return text.tolist()


def _check_high_level(array: np.ndarray, is_set: np.ndarray, fields, action: str) -> None:
    """Raise FapFileError naming the first set row of ``array`` (n, len(fields)) with a field out of range."""
    lowest = np.array([f[1] for f in fields])
    highest = np.array([f[2] for f in fields])
    bad = ((array < lowest) | (array > highest)) & np.asarray(is_set, bool)[:, None]
    if bad.any():
        k, column = np.argwhere(bad)[0]
        name, lo, hi = fields[column]
        fap = 1 if fields is VISEME_FIELDS else 2
        raise FapFileError(f"{action} frame {k}: {name} (FAP {fap}) is {array[k, column]}; "
                           f"expected a whole number from {lo} to {hi}.")
