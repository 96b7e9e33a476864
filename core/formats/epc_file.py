"""epc_file.py
----
Thesis B's emotions as control-point displacements ("Emoções em Pontos de Controle", EPC; Körting 2007
§5.1: "in the same pattern as the DPCs"). An EPC file is a DPC file (``core.formats.dpc_file``: a frame
count, then one ``dx dy dz`` line per control point, mm from the rest position) whose last frame is the
emotion's apex; earlier frames, if any, are its onset. Mimica adds two comments::

    # mimica-epc 1: thesis B emotion, dx dy dz per control point (mm)
    # emotion joy
    # aus 1 6 12 14                       (the FACS action units it is made of, B Table 3.3)
    # points brow_inner_l ...             (as in DPC files)
    1

    0 5.5 0
    ...

Reading is the DPC reader's (tolerant, line-numbered errors, nothing returned on failure); the emotion's
name defaults to the file's stem.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from core.formats.dpc_file import DpcFileError, DpcSequence, format_dpc, parse_dpc_lines
from core.formats.atomic_files import write_atomic, write_reporting_errors
from core.formats.text_files import parse_text_lines

__all__ = ["EpcFileError", "EpcEmotion", "parse_epc", "parse_epc_lines", "read_epc", "format_epc", "write_epc"]


class EpcFileError(DpcFileError):
    """An EPC file could not be read or written; ``str(error)`` is a user-facing message."""


@dataclass(eq=False)
class EpcEmotion:
    """name : the emotion; frames : (k, c, 3) mm, the last is the apex; names / feature_points : the control
    points; aus : FACS action units (may be empty); notes : what the reader tolerated."""

    name: str
    frames: np.ndarray
    names: tuple[str, ...]
    feature_points: tuple[str | None, ...] = ()
    aus: tuple[int, ...] = ()
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.frames = np.asarray(self.frames, dtype=float)
        if self.frames.ndim == 2:
            self.frames = self.frames[None]
        if self.frames.ndim != 3 or self.frames.shape[2] != 3 or self.frames.shape[0] < 1:
            raise ValueError(f"EpcEmotion.frames must have shape (k >= 1, c, 3), got {self.frames.shape}")
        if not self.feature_points:
            self.feature_points = (None,) * len(self.names)

    @property
    def displacements(self) -> np.ndarray:
        """(c, 3) mm: the apex."""
        return self.frames[-1]

    def as_dict(self) -> dict[str, np.ndarray]:
        """{control-point name: (3,) apex displacement mm}."""
        return {n: self.displacements[i] for i, n in enumerate(self.names)}


def parse_epc(text: str, *, source: str = "<text>", name: str | None = None, names=None) -> EpcEmotion:
    """Parse EPC text (see :func:`parse_epc_lines`)."""
    return parse_epc_lines(io.StringIO(text.removeprefix("\ufeff"), newline=None), source=source, name=name,
                           names=names)


def parse_epc_lines(lines: Iterable[str], *, source: str = "<text>", name: str | None = None,
                    names=None, default_name: str = "emotion") -> EpcEmotion:
    """Parse an EPC file from its lines, one at a time (the DPC reader's streaming parse, plus the
    '# emotion' and '# aus' comments); EpcFileError naming the line for anything malformed. The
    emotion is ``name``, else its '# emotion' comment, else ``default_name``."""
    comments = {}

    def on_comment(number: int, words: list[str]) -> None:
        if len(words) >= 2 and words[0].lower() == "emotion":
            comments["emotion"] = words[1]
        elif words[0].lower() == "aus":
            try:
                comments["aus"] = tuple(int(w) for w in words[1:])
            except ValueError:
                where = "" if source == "<text>" else f"'{source}', "
                raise EpcFileError(f"{where}line {number}: '# aus' lists FACS action units as whole numbers, "
                                   f"found {' '.join(words[1:])!r}.") from None

    try:
        seq = parse_dpc_lines(lines, source=source, names=names, on_comment=on_comment)
    except EpcFileError:
        raise
    except DpcFileError as exc:
        raise EpcFileError(str(exc).replace("DPC", "EPC")) from None
    return EpcEmotion(name or comments.get("emotion") or default_name, seq.displacements, seq.names,
                      seq.feature_points, comments.get("aus", ()), seq.notes)


def read_epc(path, *, names=None) -> EpcEmotion:
    """Read an EPC file line by line (size-capped text; the emotion is named by its '# emotion' comment or
    the file's stem)."""
    path = Path(path)
    emotion, notes = parse_text_lines(
        path, "EPC", EpcFileError, "An EPC file is text: a frame count, then one line 'dx dy dz' per control point.",
        lambda lines: parse_epc_lines(lines, source=path.name, names=names, default_name=path.stem))
    emotion.notes[:0] = notes
    return emotion


def format_epc(emotion: EpcEmotion) -> str:
    """The EPC text of ``emotion`` (the DPC layout with '# emotion' and '# aus' comments)."""
    head = [f"# mimica-epc 1: thesis B emotion, dx dy dz per control point (mm)", f"# emotion {emotion.name}"]
    if emotion.aus:
        head.append("# aus " + " ".join(str(a) for a in emotion.aus))
    try:
        body = format_dpc(DpcSequence(emotion.frames, emotion.names, emotion.feature_points))
    except DpcFileError as exc:
        raise EpcFileError(str(exc)) from None
    body = "\n".join(line for line in body.splitlines() if not line.startswith("# mimica-dpc"))
    return "\n".join(head) + "\n" + body + "\n"


def write_epc(path, emotion: EpcEmotion) -> None:
    """Write ``emotion`` atomically (UTF-8); EpcFileError for anything that fails."""
    path = Path(path)
    data = format_epc(emotion).encode("utf-8")
    write_reporting_errors(path, lambda: write_atomic(path, data), EpcFileError)
