"""MPEG-4 FAP tables, FAP units measured on a face, expression and viseme presets.

All tables are data in ``resources/mpeg4/`` (sources in their header comments); this module only
parses them. FAP numbers are 1-based as in the standard; arrays indexed by FAP use ``n - 1``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

import resources

from core.layers.fap.closed_eyes import CLOSED_EYE_GAP

N_FAPS = 68
ANGLE_UNIT = 1e-5  # rad per AU
DOCK_GROUPS = ("jaw & chin", "inner lips", "lip corners", "outer lips", "eyelids", "eyebrows", "cheeks", "nose",
               "gaze", "head")


@dataclass(frozen=True)
class FapSpec:
    """One FAP of the standard table.

    axis : (3,) unit vector of the positive direction (translations) or the rotation axis
    (unit ``AU``), in face coordinates (+x the face's own left, +y up, +z forward).
    minimum, maximum : Mimica's slider range in FAP units (NaN for FAPs Mimica does not animate).
    """

    number: int
    name: str
    fp: str
    unit: str
    direction: str
    axis: tuple[float, float, float] | None
    bidirectional: bool
    group: int
    dock: str
    thesis: bool
    animated: bool
    pair: int | None
    minimum: float
    maximum: float

    @property
    def is_rotation(self) -> bool:
        return self.unit == "AU"


@functools.cache
def fap_specs() -> tuple[FapSpec, ...]:
    """All 68 FAPs, index ``n - 1`` is FAP n."""
    specs = []
    for row in resources.get_table("mpeg4/faps.csv"):
        axis = tuple(float(a) for a in row["axis"].split()) if row["axis"] else None
        specs.append(FapSpec(
            number=int(row["fap"]), name=row["name"], fp=row["fp"], unit=row["unit"], direction=row["direction"],
            axis=axis, bidirectional=row["bidirectional"] == "true", group=int(row["group"]), dock=row["dock"],
            thesis=row["thesis"] == "1", animated=row["animated"] == "1",
            pair=int(row["pair"]) if row["pair"] else None,
            minimum=float(row["min"]) if row["min"] else float("nan"),
            maximum=float(row["max"]) if row["max"] else float("nan"),
        ))
    assert [s.number for s in specs] == list(range(1, N_FAPS + 1)), "faps.csv must list FAPs 1..68 in order"
    return tuple(specs)


def fap_spec(number_or_name: int | str) -> FapSpec:
    """The spec of a FAP by number (1..68) or name (``open_jaw``); ValueError names what is valid."""
    specs = fap_specs()
    if isinstance(number_or_name, str) and not number_or_name.isdigit():
        for s in specs:
            if s.name == number_or_name:
                return s
        raise ValueError(f"unknown FAP name {number_or_name!r}; names are like 'open_jaw' or 'close_t_l_eyelid'")
    n = int(number_or_name)
    if not 1 <= n <= N_FAPS:
        raise ValueError(f"FAP numbers run from 1 to {N_FAPS}, got {n}")
    return specs[n - 1]


def thesis_faps() -> tuple[int, ...]:
    """The 46 low-level FAPs of thesis A: 3-22, 31-42, 51-64."""
    return tuple(s.number for s in fap_specs() if s.thesis)


@functools.cache
def feature_point_descriptions() -> dict[str, str]:
    """{feature point "2.1": its MPEG-4 description} (resources/mpeg4/feature_points.csv)."""
    return {r["fp"]: r["description"] for r in resources.get_table("mpeg4/feature_points.csv")}


@functools.cache
def expression_names() -> tuple[str, ...]:
    """FAP 2 expression_select names by id (0 = neutral, 1 joy ... 6 surprise)."""
    return tuple(r["name"] for r in resources.get_table("mpeg4/expressions.csv"))


@functools.cache
def viseme_names() -> tuple[str, ...]:
    """FAP 1 viseme_select names by id (0 = none ... 14)."""
    return tuple(r["name"] for r in resources.get_table("mpeg4/visemes.csv"))


@functools.cache
def viseme_phonemes() -> tuple[str, ...]:
    return tuple(r["phonemes_sampa"] for r in resources.get_table("mpeg4/visemes.csv"))


def _preset_table(name: str, key: str, ids: dict[str, int]) -> np.ndarray:
    """(len(ids), 68) FAP values of each preset at 100 %, rows by preset id."""
    table = np.zeros((len(ids), N_FAPS))
    for row in resources.get_table(name):
        table[ids[row[key]], int(row["fap"]) - 1] = float(row["value"])
    table.setflags(write=False)
    return table


@functools.cache
def thesis_expression_table() -> np.ndarray:
    """(7, 68) FAP values of each expression at 100 % as printed in thesis A Table B.1 (row 0 = zeros)."""
    return _preset_table("mpeg4/expression_presets.csv", "expression",
                         {n: i for i, n in enumerate(expression_names())})


@functools.cache
def action_unit_table() -> dict[int, np.ndarray]:
    """{FACS action unit: (68,) FAP values at full intensity} (resources/facs/action_units.csv)."""
    units: dict[int, np.ndarray] = {}
    for row in resources.get_table("facs/action_units.csv"):
        units.setdefault(int(row["au"]), np.zeros(N_FAPS))[int(row["fap"]) - 1] += float(row["value"])
    return units


@functools.cache
def expression_action_units() -> dict[str, dict[int, float]]:
    """{expression: {action unit: intensity}} of thesis B Table 3.3 (resources/facs/emotions.csv)."""
    out: dict[str, dict[int, float]] = {}
    for row in resources.get_table("facs/emotions.csv"):
        out.setdefault(row["expression"], {})[int(row["au"])] = float(row["intensity"])
    return out


@functools.cache
def expression_table() -> np.ndarray:
    """(7, 68) FAP values of each expression preset at 100 % (row 0 neutral = zeros).

    Thesis A's Table B.1 with thesis B's FACS description on top: for an emotion of thesis B's
    Table 3.3, the FAPs that FACS action units move (brows, lids, cheeks, nose, lips, jaw) take the
    sum of the emotion's own units (zero where none of them acts: joy has no jaw drop in FACS, so
    its Table B.1 mouth opening goes); the FAPs no action unit moves keep Table B.1's values.
    Disgust, absent from Table 3.3, keeps Table B.1.
    """
    table = thesis_expression_table().copy()
    units = action_unit_table()
    facs_faps = np.any([values != 0 for values in units.values()], axis=0)
    names = expression_names()
    for name, mix in expression_action_units().items():
        facs = sum((units[au] * weight for au, weight in mix.items()), np.zeros(N_FAPS))
        table[names.index(name), facs_faps] = facs[facs_faps]
    table.setflags(write=False)
    return table


@functools.cache
def viseme_table() -> np.ndarray:
    """(15, 68) FAP values of each viseme at 100 % (row 0 = none = zeros)."""
    return _preset_table("mpeg4/viseme_presets.csv", "viseme", {str(i): i for i in range(len(viseme_names()))})


def expression_id(name_or_id: str | int) -> int:
    names = expression_names()
    if isinstance(name_or_id, str) and not name_or_id.isdigit():
        key = name_or_id.strip().lower()
        if key not in names:
            raise ValueError(f"unknown expression {name_or_id!r}; choose one of {', '.join(names[1:])}")
        return names.index(key)
    i = int(name_or_id)
    if not 0 <= i < len(names):
        raise ValueError(f"expression ids run from 0 to {len(names) - 1}, got {i}")
    return i


def viseme_id(name_or_id: str | int) -> int:
    names = viseme_names()
    if isinstance(name_or_id, str) and not name_or_id.isdigit():
        lowered = [n.lower() for n in names]
        key = name_or_id.strip().lower()
        if key not in lowered:
            raise ValueError(f"unknown viseme {name_or_id!r}; use an id 0-14 or one of {', '.join(names)}")
        return lowered.index(key)
    i = int(name_or_id)
    if not 0 <= i < len(names):
        raise ValueError(f"viseme ids run from 0 to {len(names) - 1}, got {i}")
    return i


# ------------------------------------------------------------------ FAP units
#: Height of an open eye's lid opening over its width (corner to corner): adult palpebral fissure
#: ~10.5 mm high and ~30 mm long (Farkas, Anthropometry of the Head and Face, 2nd ed., 1994: ps-pi and
#: ex-en). Stands in for IRISD0 on an eye that is closed on the face.
OPEN_EYE_HEIGHT_PER_WIDTH = 0.35
#: A closed eye's lid centres may cross by up to this share of its width (detection noise); further,
#: its upper and lower lid points are swapped.
SWAPPED_LID_GAP = 0.05


class FapuError(ValueError):
    """The face lacks the feature points a FAP unit is measured on."""


def measure_fapu(positions: dict[str, np.ndarray], frame: np.ndarray | None = None) -> dict[str, float]:
    """FAP units (mm per unit; AU in rad) from neutral feature point positions.

    positions : name -> (3,) mm. frame : (3, 3) rows = the face's x, y, z axes (identity if None).
    IRISD is the mean of both eyes; without pupils (3.5/3.6), the eye centre is taken as the
    midpoint of the eye corners (the notes of thesis A's 64 points drop the pupils).
    """
    frame = np.eye(3) if frame is None else np.asarray(frame, float)
    p = {k: frame @ np.asarray(v, float) for k, v in positions.items()}

    def need(*names):
        missing = [n for n in names if n not in p]
        if missing:
            raise FapuError(f"cannot measure FAP units: feature point(s) {', '.join(missing)} are not marked")

    def eye(side):
        pupil, corners = ("3.5", ("3.7", "3.11")) if side == "l" else ("3.6", ("3.12", "3.8"))
        if pupil in p:
            return p[pupil]
        need(*corners)
        return (p[corners[0]] + p[corners[1]]) / 2

    def lid_gap(top, bottom, corners):
        """IRISD0 of one eye: its lid gap, or for a closed eye (a scan taken with the eyes shut: the gap
        under CLOSED_EYE_GAP x the eye's width) the gap an open eye of that width has, so the lid FAPs
        open it by the usual amount instead of by a share of a closed slit."""
        gap = p[top][1] - p[bottom][1]
        if all(c in p for c in corners):
            width = float(np.linalg.norm(p[corners[0]] - p[corners[1]]))
            # (A lid gap well below zero is upper and lower lid swapped: measured, and refused below.)
            if -SWAPPED_LID_GAP * width < gap < CLOSED_EYE_GAP * width:
                return OPEN_EYE_HEIGHT_PER_WIDTH * width
        return gap

    need("3.1", "3.3", "3.2", "3.4", "9.15", "2.2", "8.3", "8.4")
    left, right = eye("l"), eye("r")
    units = {
        "IRISD": (lid_gap("3.1", "3.3", ("3.7", "3.11")) + lid_gap("3.2", "3.4", ("3.12", "3.8"))) / 2,
        "ES": left[0] - right[0],
        "ENS": (left[1] + right[1]) / 2 - p["9.15"][1],
        "MNS": p["9.15"][1] - p["2.2"][1],
        "MW": p["8.3"][0] - p["8.4"][0],
    }
    for name, value in units.items():
        if not value > 0:
            raise FapuError(
                f"cannot measure FAP units: {name}0 = {value:.2f} mm is not positive; check that the left/right "
                "and upper/lower feature points are not swapped"
            )
    out = {k: v / 1024.0 for k, v in units.items()}
    out["AU"] = ANGLE_UNIT
    return out
