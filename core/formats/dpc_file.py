"""dpc_file.py
----
Read and write thesis B's control-point dynamics files ("Dinâmicas dos Pontos
de Controle", DPC; Körting 2007, §5.2): per frame, the displacement of every
control point from its rest position, as text::

    2                # number of frames ("Total de quadros")
                     #
    1.0  2.0  0.0    # frame 1: one line per control point, dx dy dz
    1.1  0.0  0.5    #   (relative to the control point's initial position)
    ...
    0.0 -3.0  3.0
                     # (a blank line between frames, as in the thesis)
    2.0  2.0  0.0    # frame 2
    ...

What the thesis leaves open, and what Mimica decides (a compatible, tolerant
reading of the one example the thesis prints):

* **Points per frame** are not in the file (they are the points of the PPC
  file the dynamics drive). The reader takes the count from ``names=`` or
  ``n_points=`` when given, else from a Mimica ``# points`` comment, else from
  the blank-line-separated blocks when they all have one size, else from
  (data lines / frame count) when that divides exactly; otherwise it asks for
  ``n_points`` in a :class:`DpcFileError`.
* **Names**: points are identified by order. When the file does not name
  them, Mimica's control-point table (``resources/dpc/control_points.csv``:
  29 points on MPEG-4 feature points, as B's Fig. 4.3 places them) names a
  29-point file, its 8 ``mouth`` rows name an 8-point file (B's Fig. 5.4 mouth
  example), and any other count gets ``cp1`` .. ``cpN`` with no feature point
  (a note says so).
* **Timing**: the file has none (B's webcam frame rate varied). ``fps`` is
  None unless given to the reader or written by Mimica (``# fps``);
  :meth:`DpcSequence.times` needs one.
* **Units**: the mesh's (millimetres in Mimica).
* ``#`` starts a comment, as the thesis annotates its example. Mimica's
  metadata lives in comments so a written file keeps the thesis layout::

      # mimica-dpc 1
      # fps 25
      # points brow_inner_l brow_inner_r ...
      # feature_points 4.1 4.2 ...      ('-' for a point without one)

  ``write_dpc(..., metadata=False)`` writes the bare thesis layout.

EPC files (emotions as control-point displacements, B §5.1: "in the same
pattern as the DPCs") have the same layout and are read by the same functions.

Tolerated and reported in :attr:`DpcSequence.notes` (one sentence per kind):
a missing frame-count line, a count that disagrees with the data, decimal
commas (``1,5 0,0 -2,25``), comma- or semicolon-separated numbers, files of
2-D displacements (every line ``dx dy``; dz is set to 0), UTF-16 files. Blank
lines, TABs, CRLF line ends and a UTF-8 BOM are accepted silently. Errors name
the line (``'smile.dpc', line 7: ...``).
"""

from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from core.formats.atomic_files import write_atomic, write_reporting_errors

from core.formats.text_files import integer as _integer
from core.formats.text_files import number as _number
from core.formats.text_files import RowBlocks, parse_text_lines

__all__ = [
    "DpcFileError", "DpcSequence", "ControlPoint", "control_points", "parse_dpc", "parse_dpc_lines", "read_dpc", "format_dpc",
    "write_dpc",
]

_TABLE = "dpc/control_points.csv"
_MAGIC = "mimica-dpc"
_NAME = re.compile(r"^[^\s#]+$")


class DpcFileError(ValueError):
    """A DPC file or text could not be read or written; ``str(error)`` is a user-facing message."""


@dataclass(frozen=True)
class ControlPoint:
    """One row of Mimica's control-point table: 1-based ``index`` (file order), ``name``, MPEG-4 ``fp``."""

    index: int
    name: str
    fp: str
    region: str
    description: str


def control_points(region: str | None = None) -> tuple[ControlPoint, ...]:
    """Mimica's default control points in DPC file order (only ``region``'s when given)."""
    import resources

    rows = tuple(ControlPoint(int(r["index"]), r["name"], r["fp"], r["region"], r["description"])
                 for r in resources.get_table(_TABLE))
    return rows if region is None else tuple(r for r in rows if r.region == region)


def _known_feature_points() -> frozenset[str]:
    import resources

    return frozenset(r["fp"] for r in resources.get_table("mpeg4/feature_points.csv"))


@dataclass(eq=False)
class DpcSequence:
    """Control-point dynamics: ``displacements[k, i]`` is point ``i``'s offset (dx, dy, dz) at frame ``k``.

    Attributes
    ----------
    displacements : (n_frames, n_points, 3) float64
        From each control point's rest position, in the mesh's units (mm).
    names : tuple of str
        Control-point names, file order (single tokens, no spaces).
    feature_points : tuple of (str or None)
        The MPEG-4 feature point each control point sits on (None when unknown).
    fps : float or None
        Frames per second when known (the thesis format has no timing).
    notes : list of str
        What the reader tolerated, one sentence per kind.
    """

    displacements: np.ndarray
    names: tuple[str, ...]
    feature_points: tuple[str | None, ...] = ()
    fps: float | None = None
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.displacements = np.asarray(self.displacements, dtype=np.float64)
        if self.displacements.ndim != 3 or self.displacements.shape[2] != 3:
            raise ValueError(f"DpcSequence.displacements must have shape (n_frames, n_points, 3), "
                             f"got {self.displacements.shape}")
        n = self.displacements.shape[1]
        self.names = tuple(str(s) for s in self.names)
        if len(self.names) != n:
            raise ValueError(f"DpcSequence has {n} control points but {len(self.names)} names")
        if len(set(self.names)) != n:
            raise ValueError("DpcSequence control-point names must be unique")
        if not self.feature_points:
            self.feature_points = (None,) * n
        self.feature_points = tuple(None if f in (None, "", "-") else str(f) for f in self.feature_points)
        if len(self.feature_points) != n:
            raise ValueError(f"DpcSequence has {n} control points but {len(self.feature_points)} feature points")
        if self.fps is not None:
            self.fps = float(self.fps)
            if not (math.isfinite(self.fps) and self.fps > 0):
                raise ValueError(f"DpcSequence.fps must be > 0, got {self.fps}")

    @property
    def n_frames(self) -> int:
        return self.displacements.shape[0]

    @property
    def n_points(self) -> int:
        return self.displacements.shape[1]

    @property
    def points(self) -> dict[str, np.ndarray]:
        """{name: (n_frames, 3) displacement track} (views into :attr:`displacements`)."""
        return {name: self.displacements[:, i] for i, name in enumerate(self.names)}

    def by_feature_point(self) -> dict[str, np.ndarray]:
        """{MPEG-4 feature point: (n_frames, 3) displacement track} of the points that have one."""
        return {fp: self.displacements[:, i] for i, fp in enumerate(self.feature_points) if fp is not None}

    def times(self, fps: float | None = None) -> np.ndarray:
        """(n_frames,) seconds ``k / fps`` (``fps`` defaults to the sequence's; one is needed)."""
        rate = self.fps if fps is None else float(fps)
        if rate is None or not (math.isfinite(rate) and rate > 0):
            raise ValueError("this DPC sequence has no frame rate (thesis B's files carry none); "
                             "pass fps, e.g. seq.times(25)")
        return np.arange(self.n_frames) / rate

    def positions(self, rest) -> np.ndarray:
        """(n_frames, n_points, 3) absolute positions from rest positions.

        ``rest`` is (n_points, 3) in file order, or a mapping name -> (3,) (e.g. from a PPC file or
        ``{name: face.landmark_position(fp)}``) that must cover every control point.
        """
        if isinstance(rest, dict):
            missing = [n for n in self.names if n not in rest]
            if missing:
                raise ValueError(f"no rest position for control point(s) {', '.join(missing)}")
            rest = np.array([rest[n] for n in self.names], dtype=np.float64)
        rest = np.asarray(rest, dtype=np.float64)
        if rest.shape != (self.n_points, 3):
            raise ValueError(f"rest positions must have shape ({self.n_points}, 3), got {rest.shape}")
        return rest[None] + self.displacements


# ------------------------------------------------------------------ reading
def parse_dpc(text: str, *, source: str = "<text>", names=None, n_points: int | None = None,
              fps: float | None = None, on_comment: Callable[[int, list[str]], None] | None = None) -> DpcSequence:
    """Parse the text of a DPC file (see :func:`parse_dpc_lines`)."""
    return parse_dpc_lines(io.StringIO(text.removeprefix("\ufeff"), newline=None), source=source, names=names,
                           n_points=n_points, fps=fps, on_comment=on_comment)


def parse_dpc_lines(lines: Iterable[str], *, source: str = "<text>", names=None, n_points: int | None = None,
                    fps: float | None = None, on_comment: Callable[[int, list[str]], None] | None = None
                    ) -> DpcSequence:
    """Parse a DPC file from its lines (an iterable of strings, line ends optional; see the module
    docstring for the format and the choices), one at a time: what is held is the displacements read
    so far (24 bytes a control-point line), never the whole text.

    Parameters
    ----------
    source : str
        Names the file in messages ("'smile.dpc', line 5: ...").
    names : sequence of str, optional
        The control points in file order (e.g. from a PPC file); fixes the points per frame.
    n_points : int, optional
        Points per frame when no names are given.
    fps : float, optional
        Frame rate (overrides a ``# fps`` comment).
    on_comment : callable (line number, words), optional
        Called with the words of every '#' comment (for formats built on DPC, such as EPC).

    Raises
    ------
    DpcFileError
        Empty file, a frame count that is not a whole number, a line that is not 3 (or, for a whole
        2-D file, 2) numbers, a last frame with missing points, blocks that cannot be frames, a
        names list that does not match the file; the message names the line.
    """
    p = _Parser(source)
    meta, count, count_line, data, row_lines, blocks = p.scan(lines, on_comment)
    if not len(data):
        if count is not None:
            raise p.error(count_line, f"the file says {count} frames but has no control-point lines after it")
        raise DpcFileError(f"{p.prefix()}the file has no data; expected a frame count, then one line "
                           "'dx dy dz' per control point and frame.")
    if names is not None:
        names = [str(n) for n in names]
        if n_points is not None and n_points != len(names):
            raise ValueError(f"n_points={n_points} disagrees with {len(names)} names")
        n_points = len(names)
    if n_points is None and meta.get("points"):
        n_points = len(meta["points"])
    n = p.points_per_frame(n_points, count, row_lines, blocks)
    total = len(data)
    if total % n:
        have = total % n
        raise p.error(int(row_lines[-have]), f"the last frame has {have} of {n} control-point lines "
                                             f"(it starts here); the file is probably truncated")
    frames = total // n
    if count is None:
        p.note("count", f"The file has no frame-count line; {frames} frame{'s' * (frames != 1)} "
                        f"of {n} control points were read.")
    elif count != frames:
        p.note("count", f"The file says {count} frames (line {count_line}) but has {frames}; "
                        f"all {frames} were read.")
    seq_names, feature_points = p.naming(n, names, meta)
    rate = fps if fps is not None else meta.get("fps")
    return DpcSequence(data.reshape(frames, n, 3), tuple(seq_names), tuple(feature_points), rate, p.notes)


def read_dpc(path, *, names=None, n_points: int | None = None, fps: float | None = None) -> DpcSequence:
    """Read a DPC file (UTF-8, latin-1 or UTF-16 text) line by line; see :func:`parse_dpc_lines`.

    Raises
    ------
    DpcFileError
        Missing, unreadable or binary file, or any error of :func:`parse_dpc_lines`.
    """
    path = Path(path)
    seq, notes = parse_text_lines(
        path, "DPC", DpcFileError,
        "A DPC file is text: a frame count, then one line 'dx dy dz' per control point and frame.",
        lambda lines: parse_dpc_lines(lines, source=path.name, names=names, n_points=n_points, fps=fps))
    seq.notes[:0] = notes
    return seq


def _guarded(parse):
    """``parse`` with any exception a hostile text provokes turned into DpcFileError."""
    import functools

    from core.formats.text_files import reading

    @functools.wraps(parse)
    def wrapper(text, *, source: str = "<text>", **kwargs):
        with reading(DpcFileError, f"'{source}'" if source != "<text>" else "the DPC text", "DPC"):
            return parse(text, source=source, **kwargs)
    return wrapper


parse_dpc = _guarded(parse_dpc)
parse_dpc_lines = _guarded(parse_dpc_lines)


class _Parser:
    """Line-level work of :func:`parse_dpc`, with the source name and the notes collected so far."""

    def __init__(self, source: str):
        self.source = source
        self.notes: list[str] = []
        self._noted: set[str] = set()

    def prefix(self, line: int | None = None) -> str:
        where = "" if self.source == "<text>" else f"'{self.source}'"
        if line is not None:
            where = f"{where}, line {line}" if where else f"line {line}"
        return f"{where}: " if where else ""

    def error(self, line: int | None, message: str) -> DpcFileError:
        end = "" if message.endswith(("?", ".")) else "."
        return DpcFileError(f"{self.prefix(line)}{message}{end}")

    def note(self, kind: str, text: str) -> None:
        if kind not in self._noted:
            self._noted.add(kind)
            self.notes.append(text)

    def scan(self, lines: Iterable[str], on_comment=None):
        """(metadata, frame count or None, its line, (n_rows, 3) displacements, (n_rows,) line of each
        row, (n_blocks, 2) [first row, rows] of each blank-line-separated block), one line at a time.

        Each data line is checked as it is read; 2-D files get dz = 0 when every line has 2 numbers."""
        meta: dict = {}
        count = count_line = None
        # line numbers as int32 (a DPC file is at most 8 MB): they cost a third of the displacements, not two
        data, row_lines, blocks = RowBlocks(3, np.float64), RowBlocks(1, np.int32), RowBlocks(2, np.int64)
        block_start = block_rows = 0
        first = True
        first_2d_line = None   # the first line with 2 numbers, and whether any line has 3
        any_3d = False
        for number, line in enumerate(lines, 1):
            body, _, comment = line.partition("#")
            if comment:
                words = comment.split()
                self._metadata(number, words, meta)
                if on_comment is not None and words:
                    on_comment(number, words)
            tokens = body.replace(";", " ").split()
            if not tokens:
                if not line.strip() and block_rows:
                    blocks.append((block_start, block_rows))  # a truly blank line ends a block; comments do not
                    block_rows = 0
                continue
            if first:
                first = False
                if len(tokens) == 1 and "," not in tokens[0]:
                    value = _integer(tokens[0])
                    if value is None or value < 0:
                        raise self.error(number, f"the first line must be the number of frames (a whole number "
                                                 f"≥ 0), found {tokens[0]!r}")
                    count, count_line = value, number
                    continue
            values = self._numbers(number, tokens)
            if len(values) == 2:
                first_2d_line = number if first_2d_line is None else first_2d_line
                values.append(0.0)
            else:
                any_3d = True
            if not block_rows:
                block_start = len(data)
            block_rows += 1
            data.append(values)
            row_lines.append(number)
        if block_rows:
            blocks.append((block_start, block_rows))
        if first_2d_line is not None:
            if any_3d:
                raise self.error(first_2d_line, "expected 3 numbers (dx dy dz of one control point), found 2; "
                                                "other lines have 3")
            self.note("2d", "Every line has 2 numbers (a 2-D file, e.g. from webcam tracking); they were read "
                            "as dx dy with dz = 0.")
        return meta, count, count_line, data.array(), row_lines.array()[:, 0], blocks.array()

    def _metadata(self, line: int, words: list[str], meta: dict) -> None:
        if not words:
            return
        key, values = words[0].lower(), words[1:]
        if key == "fps" and len(values) == 1:
            rate = _number(values[0])
            if rate is None or not 0.1 <= rate <= 1000:
                raise self.error(line, f"the frame rate in '# fps {values[0]}' must be a number from 0.1 to 1000")
            meta["fps"] = rate
        elif key == "points" and values:
            meta["points"] = values
            meta["points_line"] = line
        elif key == "feature_points" and values:
            meta["feature_points"] = values
            meta["feature_points_line"] = line

    def _numbers(self, line: int, tokens: list[str]) -> list[float]:
        """The 2 or 3 numbers of one data line."""
        tokens = self._split(line, tokens)
        values = [_number(t) for t in tokens]
        for token, value in zip(tokens, values):
            if value is None:
                raise self.error(line, f"{token!r} is not a number; each line holds one control point's "
                                       "displacement 'dx dy dz'")
        if len(values) not in (2, 3):
            raise self.error(line, f"expected 3 numbers (dx dy dz of one control point), found {len(values)}: "
                                   f"{' '.join(tokens)!r}")
        return values

    def _split(self, line: int, tokens: list[str]) -> list[str]:
        """Undo decimal commas ('1,5') and comma-separated numbers ('1.5,0,2')."""
        if not any("," in t for t in tokens):
            return tokens
        if len(tokens) in (2, 3) and all(t.count(",") <= 1 and "." not in t for t in tokens):
            self.note("decimal comma", f"Numbers are written with decimal commas (line {line}: "
                                       f"{' '.join(tokens)!r}); they were read as decimal points.")
            return [t.replace(",", ".") for t in tokens]
        split = [part for t in tokens for part in t.split(",") if part]
        self.note("comma", f"Numbers are separated by commas (line {line}); they were read as separate numbers.")
        return split

    def points_per_frame(self, n_points: int | None, count: int | None, row_lines: np.ndarray,
                         blocks: np.ndarray) -> int:
        """Control points per frame; ``row_lines`` (n_rows,) line of each data row, ``blocks``
        (n_blocks, 2) first row and row count of each blank-line-separated block."""
        total = len(row_lines)
        if n_points is not None:
            if n_points < 1:
                raise ValueError(f"n_points must be ≥ 1, got {n_points}")
            return int(n_points)
        sizes = blocks[:, 1]
        if len(blocks) > 1:
            if (sizes == sizes[0]).all():
                return int(sizes[0])
            # A last block shorter than the others is a truncated frame; report it where it starts.
            if (sizes[:-1] == sizes[0]).all() and sizes[-1] < sizes[0] and (count is None or count == len(blocks)):
                return int(sizes[0])
            if count and total % count == 0:
                self.note("blocks", "Blank lines in the file do not split it into frames of equal size; "
                                    f"frames were taken as {total // count} lines each from the frame count.")
                return total // count
            k = int(np.flatnonzero(sizes != sizes[0])[0])
            raise self.error(int(row_lines[blocks[k, 0]]), f"frame {k + 1} (starting here) has {sizes[k]} "
                                                           f"control-point lines but frame 1 has {sizes[0]}; every "
                                                           "frame needs one line per control point")
        if count:
            if total % count:
                raise self.error(None, f"the file says {count} frames but has {total} control-point lines, which "
                                       f"do not split into {count} equal frames; pass the number of control "
                                       "points (n_points) or fix the frame count")
            return total // count
        if count == 0:
            raise self.error(None, f"the file says 0 frames but has {total} control-point lines")
        raise self.error(None, "cannot tell how many control points each frame has (no frame count and no "
                               "blank lines between frames); pass the number of control points (n_points)")

    def naming(self, n: int, names, meta) -> tuple[list[str], list[str | None]]:
        """(names, feature points) of the n control points."""
        known = _known_feature_points()
        table = {p.name: p.fp for p in control_points()}
        if names is not None:
            chosen = list(names)
        elif meta.get("points"):
            chosen = list(meta["points"])
            if len(chosen) != n:
                raise self.error(meta["points_line"], f"the '# points' comment names {len(chosen)} control points "
                                                      f"but every frame has {n} lines")
        else:
            full, mouth = control_points(), control_points("mouth")
            if n == len(full):
                chosen = [p.name for p in full]
            elif n == len(mouth):
                chosen = [p.name for p in mouth]
                self.note("names", f"The file has {n} control points per frame; they were read as Mimica's "
                                   f"{n} mouth points ({', '.join(chosen)}), as in thesis B's mouth example.")
            else:
                chosen = [f"cp{i + 1}" for i in range(n)]
                self.note("names", f"The file has {n} control points per frame, which matches no known control-"
                                   f"point set ({len(full)} or {len(mouth)}); they were named cp1..cp{n} and "
                                   "have no MPEG-4 feature point.")
        bad = [name for name in chosen if not _NAME.match(name)]
        if bad:
            raise DpcFileError(f"Control-point names must be single words without '#': {bad[0]!r}.")
        if len(set(chosen)) != len(chosen):
            duplicate = next(name for name in chosen if chosen.count(name) > 1)
            raise DpcFileError(f"The control point {duplicate!r} is named twice.")
        if meta.get("feature_points"):
            fps = [None if f == "-" else f for f in meta["feature_points"]]
            if len(fps) != n:
                raise self.error(meta["feature_points_line"], f"the '# feature_points' comment lists {len(fps)} "
                                                              f"points but every frame has {n} lines")
            unknown = [f for f in fps if f is not None and f not in known]
            if unknown:
                raise self.error(meta["feature_points_line"], f"{unknown[0]!r} is not an MPEG-4 feature point")
        else:
            fps = [table.get(name, name if name in known else None) for name in chosen]
        return chosen, fps


# ------------------------------------------------------------------ writing
def format_dpc(seq: DpcSequence, *, metadata: bool = True) -> str:
    """The DPC text of ``seq``: the frame count, then per frame a blank line and one 'dx dy dz' line per
    control point (up to 6 decimals, integers without a point). With ``metadata`` the control-point
    names, feature points and frame rate go first as '#' comments; without, the bare thesis layout.

    Raises
    ------
    DpcFileError
        A NaN or infinite displacement (the message names the frame and the point).
    """
    values = seq.displacements
    bad = ~np.isfinite(values)
    if bad.any():
        k, i, axis = np.argwhere(bad)[0]
        raise DpcFileError(f"Cannot write frame {k + 1}: control point {seq.names[i]!r} has "
                           f"d{'xyz'[axis]} = {values[k, i, axis]}.")
    lines = []
    if metadata:
        lines.append(f"# {_MAGIC} 1: thesis B control-point dynamics, dx dy dz per control point and frame (mm)")
        if seq.fps is not None:
            fps = float(seq.fps)
            lines.append(f"# fps {int(fps) if fps.is_integer() else repr(fps)}")
        lines.append("# points " + " ".join(seq.names))
        if any(f is not None for f in seq.feature_points):
            lines.append("# feature_points " + " ".join(f or "-" for f in seq.feature_points))
    lines.append(str(seq.n_frames))
    text = _format_numbers(values.reshape(-1))
    rows = [" ".join(text[j:j + 3]) for j in range(0, len(text), 3)]
    n = seq.n_points
    for k in range(seq.n_frames):
        lines.append("")
        lines.extend(rows[k * n:(k + 1) * n])
    return "\n".join(lines) + "\n"


def write_dpc(path, seq: DpcSequence, *, metadata: bool = True) -> None:
    """Write ``seq`` to ``path`` in the format of :func:`format_dpc` (UTF-8), atomically.

    Raises
    ------
    DpcFileError
        Anything :func:`format_dpc` refuses, a missing or unwritable folder, disk errors.
    """
    path = Path(path)
    data = format_dpc(seq, metadata=metadata).encode("utf-8")
    write_reporting_errors(path, lambda: write_atomic(path, data), DpcFileError)


def _format_numbers(values: np.ndarray) -> list[str]:
    """Each value as an integer when it rounds to one at 6 decimals, else with up to 6 decimals."""
    rounded = np.round(values, 6) + 0.0  # + 0.0 turns -0.0 into 0.0
    integral = rounded == np.trunc(rounded)
    text = np.empty(len(values), dtype=object)
    text[integral] = [str(int(v)) for v in rounded[integral].tolist()]
    text[~integral] = [f"{v:.6f}".rstrip("0") for v in rounded[~integral].tolist()]
    return text.tolist()
