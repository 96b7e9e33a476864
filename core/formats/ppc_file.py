"""ppc_file.py
----
Thesis B's control-point positions ("Posições dos Pontos de Controle", PPC; Körting 2007 §5.1): where each
RBF control point sits on one face, so a user places them once and reuses the mesh. B prints no PPC
example; Mimica writes, one control point per line, ``name fp x y z`` (mm, the mesh's units)::

    # mimica-ppc 1: thesis B control-point positions (mm)
    29                                   # number of control points (optional)
    brow_inner_l 4.1 13.0 50.5 -19.3
    ...

Read tolerantly: ``name x y z`` lines (feature point from Mimica's table, resources/dpc/control_points.csv)
and bare ``x y z`` lines in that table's order (29 points; 8 are its mouth points, as the DPC reader does);
decimal commas and comma/semicolon separators (a note says so); blank lines, ``#`` comments, CRLF, a BOM,
UTF-16 (a note). Errors name the file and line and nothing is returned, so nothing changes.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from core.formats.dpc_file import control_points
from core.formats.atomic_files import write_atomic, write_reporting_errors
from core.formats.text_files import RowBlocks, integer, number, parse_text_lines, reading

__all__ = ["PpcFileError", "ControlPointPositions", "parse_ppc", "parse_ppc_lines", "read_ppc", "format_ppc", "write_ppc"]

_MAGIC = "mimica-ppc"
_NAME = re.compile(r"^[A-Za-z_][\w.\-]*$")


class PpcFileError(ValueError):
    """A PPC file could not be read or written; ``str(error)`` is a user-facing message."""


@dataclass(eq=False)
class ControlPointPositions:
    """names : (c,) str; feature_points : (c,) MPEG-4 feature point or None; positions : (c, 3) mm;
    notes : what the reader tolerated."""

    names: tuple[str, ...]
    feature_points: tuple[str | None, ...]
    positions: np.ndarray
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.positions = np.asarray(self.positions, dtype=float).reshape(-1, 3)
        if len(self.names) != len(self.positions) or len(self.feature_points) != len(self.positions):
            raise ValueError("ControlPointPositions: names, feature points and positions differ in length")

    def as_dict(self) -> dict[str, np.ndarray]:
        return {n: self.positions[i] for i, n in enumerate(self.names)}


def _known_fps() -> frozenset[str]:
    import resources

    return frozenset(r["fp"] for r in resources.get_table("mpeg4/feature_points.csv"))


def parse_ppc(text: str, *, source: str = "<text>") -> ControlPointPositions:
    """Parse PPC text (see :func:`parse_ppc_lines`)."""
    return parse_ppc_lines(io.StringIO(text.removeprefix("\ufeff"), newline=None), source=source)


def parse_ppc_lines(lines: Iterable[str], *, source: str = "<text>") -> ControlPointPositions:
    """Parse a PPC file from its lines (see the module docstring), one at a time: what is held is the
    control points read so far, never the whole text. PpcFileError naming the line for anything
    malformed."""
    with reading(PpcFileError, f"'{source}'" if source != "<text>" else "the PPC text", "PPC"):
        return _parse(lines, source)


def _parse(lines: Iterable[str], source: str) -> ControlPointPositions:
    where = "" if source == "<text>" else f"'{source}', "

    def error(line: int | None, message: str) -> PpcFileError:
        at = f"{where}line {line}: " if line is not None else (f"'{source}': " if where else "")
        return PpcFileError(f"{at}{message}.")

    notes: list[str] = []
    table = {p.name: p.fp for p in control_points()}
    known = _known_fps()
    count = count_line = None
    names, fps, positions = [], [], RowBlocks(3, np.float64)   # name / fp None when the line has none
    first_line = {}                   # name -> line it is first on
    mixed_line = duplicate = None     # the first line that names (or not) unlike the first; the first repeat
    for number_, raw in enumerate(lines, 1):
        body = raw.partition("#")[0].replace(";", " ")
        tokens = body.split()
        if not tokens:
            continue
        if count is None and not names and len(tokens) == 1 and integer(tokens[0]) is not None:
            count, count_line = integer(tokens[0]), number_
            if count < 0:
                raise error(number_, f"the number of control points must be ≥ 0, found {tokens[0]!r}")
            continue
        if any("," in t for t in tokens):
            if all(t.count(",") <= 1 and "." not in t for t in tokens[-3:]) and len(tokens) >= 3:
                tokens = tokens[:-3] + [t.replace(",", ".") for t in tokens[-3:]]
                if "decimal" not in " ".join(notes):
                    notes.append(f"Numbers are written with decimal commas (line {number_}); they were read as "
                                 "decimal points.")
            else:
                tokens = [p for t in tokens for p in t.split(",") if p]
        values = [number(t) for t in tokens[-3:]]
        if len(tokens) < 3 or any(v is None for v in values):
            bad = next((t for t, v in zip(tokens[-3:], values) if v is None), None)
            what = f"{bad!r} is not a number; " if bad is not None and len(tokens) >= 3 else ""
            raise error(number_, f"{what}expected 'name fp x y z', 'name x y z' or 'x y z' (one control point "
                                 f"in mm), found {body.strip()!r}")
        head = tokens[:-3]
        if len(head) > 2:
            raise error(number_, f"expected 'name fp x y z', found {len(tokens)} words: {body.strip()!r}")
        name = head[0] if head else None
        fp = head[1] if len(head) == 2 else None
        if name is not None and not _NAME.match(name):
            raise error(number_, f"{name!r} is not a control-point name (a word starting with a letter)")
        if fp is not None and fp != "-" and fp not in known:
            raise error(number_, f"{fp!r} is not an MPEG-4 feature point")
        if names and (name is None) != (names[0] is None) and mixed_line is None:
            mixed_line = number_
        if name is not None:
            if name in first_line and duplicate is None:
                duplicate = (number_, name, first_line[name])
            first_line.setdefault(name, number_)
        names.append(name)
        fps.append(None if fp == "-" else fp)
        positions.append(values)
    if not names:
        raise error(count_line, "the file has no control points; expected one line 'name fp x y z' per point")
    if mixed_line is not None:
        raise error(mixed_line, "some lines name their control point and others do not; name every point or none")
    if count is not None and count != len(names):
        notes.append(f"The file says {count} control points (line {count_line}) but has {len(names)}; all "
                     f"{len(names)} were read.")
    if names[0] is not None:
        if duplicate is not None:
            line, name, first = duplicate
            raise error(line, f"the control point {name!r} is already on line {first}")
        fps = [fp if fp is not None else table.get(name, name if name in known else None)
               for name, fp in zip(names, fps)]
    else:
        full, mouth = control_points(), control_points("mouth")
        order = full if len(names) == len(full) else mouth if len(names) == len(mouth) else None
        if order is None:
            raise error(None, f"the file has {len(names)} unnamed control points, which matches no known set "
                              f"({len(full)} or {len(mouth)}); write 'name x y z' on every line")
        names = [p.name for p in order]
        fps = [p.fp for p in order]
        notes.append(f"The control points are unnamed; they were read in Mimica's order of {len(names)} points.")
    return ControlPointPositions(tuple(names), tuple(fps), positions.array(), notes)


def read_ppc(path) -> ControlPointPositions:
    """Read a PPC file line by line (size-capped text; see :func:`parse_ppc_lines`)."""
    path = Path(path)
    out, notes = parse_text_lines(path, "PPC", PpcFileError,
                                  "A PPC file is text: one line 'name fp x y z' per control point.",
                                  lambda lines: parse_ppc_lines(lines, source=path.name))
    out.notes[:0] = notes
    return out


def format_ppc(ppc: ControlPointPositions) -> str:
    """The PPC text of ``ppc`` (positions with up to 6 decimals). PpcFileError for a non-finite position."""
    bad = ~np.isfinite(ppc.positions)
    if bad.any():
        i = int(np.argwhere(bad)[0][0])
        raise PpcFileError(f"Cannot write control point {ppc.names[i]!r}: its position is not finite.")
    lines = [f"# {_MAGIC} 1: thesis B control-point positions, name fp x y z (mm)", str(len(ppc.names))]
    for name, fp, xyz in zip(ppc.names, ppc.feature_points, ppc.positions):
        lines.append(" ".join([name, fp or "-"] + [_fmt(v) for v in xyz]))
    return "\n".join(lines) + "\n"


def write_ppc(path, ppc: ControlPointPositions) -> None:
    """Write ``ppc`` atomically (UTF-8); PpcFileError for anything that fails."""
    path = Path(path)
    data = format_ppc(ppc).encode("utf-8")
    write_reporting_errors(path, lambda: write_atomic(path, data), PpcFileError)


def _fmt(v: float) -> str:
    r = round(float(v), 6) + 0.0
    return str(int(r)) if r == int(r) else f"{r:.6f}".rstrip("0")
