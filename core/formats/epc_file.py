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

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from core.formats.dpc_file import DpcFileError, DpcSequence, format_dpc, parse_dpc
from core.formats.atomic_files import write_atomic, write_reporting_errors
from core.formats.text_files import read_text_file

__all__ = ["EpcFileError", "EpcEmotion", "parse_epc", "read_epc", "format_epc", "write_epc"]


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
    """Parse EPC text (see the module docstring); EpcFileError naming the line for anything malformed."""
    try:
        seq = parse_dpc(text, source=source, names=names)
    except DpcFileError as exc:
        raise EpcFileError(str(exc).replace("DPC", "EPC")) from None
    meta_name, aus = None, ()
    for number, line in enumerate(text.removeprefix("\ufeff").splitlines(), 1):
        words = line.partition("#")[2].split()
        if len(words) >= 2 and words[0].lower() == "emotion":
            meta_name = words[1]
        elif words and words[0].lower() == "aus":
            try:
                aus = tuple(int(w) for w in words[1:])
            except ValueError:
                where = "" if source == "<text>" else f"'{source}', "
                raise EpcFileError(f"{where}line {number}: '# aus' lists FACS action units as whole numbers, "
                                   f"found {' '.join(words[1:])!r}.") from None
    return EpcEmotion(name or meta_name or "emotion", seq.displacements, seq.names, seq.feature_points, aus,
                      seq.notes)


def read_epc(path, *, names=None) -> EpcEmotion:
    """Read an EPC file (size-capped text; the emotion is named by its '# emotion' comment or the file's stem)."""
    path = Path(path)
    text, notes = read_text_file(path, "EPC", EpcFileError,
                                 "An EPC file is text: a frame count, then one line 'dx dy dz' per control point.")
    emotion = parse_epc(text, source=path.name, names=names)
    if emotion.name == "emotion" and "# emotion" not in text:
        emotion.name = path.stem
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
