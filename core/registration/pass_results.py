"""What the matcher's passes return, and the state of the match their results change.

A pass reads the match (``match_context``) and returns which landmarks it moves, to where and with
what evidence; it changes nothing. Only the orchestrator (``matching.match``) applies the moves,
so each pass can be read and tested on its own. The arrays of the moves and states are read-only.

Two levels, as the matcher works: in the scan's frontal raster (``PixelMoves`` onto
``PixelEstimates``: the patch search and the mouth passes) and on the scan surface
(``SurfaceMoves`` onto ``MatchState``: pixels lifted to the surface, the closest-point snap, the
lid and steep passes). P is the number of template points (``template.detected``), indices are
into that order.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np


def _freeze(obj, **fields) -> None:
    """Replace each named array field of the frozen dataclass ``obj`` (None stays None) by a
    read-only copy of it, of the given (dtype, shape): sequences are accepted, and the caller's
    arrays can be neither changed through ``obj`` nor change it."""
    for name, (dtype, shape) in fields.items():
        value = getattr(obj, name)
        if value is not None:
            out = np.array(value, dtype=dtype).reshape(shape)
            out.setflags(write=False)
            object.__setattr__(obj, name, out)


# ------------------------------------------------------------------ greedy
@dataclass(frozen=True)
class GreedyMatch:
    """The greedy structural match (thesis A Algorithm 1, ``greedy.greedy_match``).

    positions : (P, 3) float, model frame, mm: the deformation graph G_d after the loop.
    candidate : (P,) int, the candidate matched to each vertex, −1 where none (preset or predicted).
    margin : (P,) float, cost of the best candidate elsewhere (> 0.1 × scale away) minus the chosen
        one's (1 when there is none; 0 for unmatched vertices).
    prediction : (P, 3) float, model frame, mm: each vertex's structural prediction when it was matched.
    """

    positions: np.ndarray
    candidate: np.ndarray
    margin: np.ndarray
    prediction: np.ndarray


# ------------------------------------------------------------------ frontal-raster level
@dataclass(frozen=True)
class PixelMoves:
    """Landmarks one pixel pass moves in the scan's frontal raster.

    index : (k,) int, ascending, each landmark at most once.
    pixel : (k, 2) float (col, row) in the scan raster; NaN when the pass found no usable pixel.
    peak : (k,) float, the point's NCC evidence afterwards (0 = placed without a patch match).
    """

    index: np.ndarray
    pixel: np.ndarray
    peak: np.ndarray

    def __post_init__(self):
        _freeze(self, index=(np.int64, (-1,)), pixel=(float, (-1, 2)), peak=(float, (-1,)))

    @classmethod
    def take(cls, pixel: np.ndarray, peak: np.ndarray, moved: Iterable[int]) -> PixelMoves:
        """The rows ``moved`` of a pass's working arrays pixel (P, 2) / peak (P,)."""
        idx = np.array(sorted(set(int(i) for i in moved)), dtype=np.int64)
        return cls(idx, pixel[idx], peak[idx])

    def __len__(self) -> int:
        return len(self.index)


@dataclass(frozen=True)
class PixelEstimates:
    """Every landmark's current estimate in the scan raster: pixel (P, 2) float (col, row), NaN
    where none yet; peak (P,) float NCC evidence (0 where none)."""

    pixel: np.ndarray
    peak: np.ndarray

    def __post_init__(self):
        _freeze(self, pixel=(float, (-1, 2)), peak=(float, (-1,)))

    @classmethod
    def empty(cls, n: int) -> PixelEstimates:
        return cls(np.full((n, 2), np.nan), np.zeros(n))

    def working(self) -> tuple[np.ndarray, np.ndarray]:
        """Writable copies (pixel, peak) for a pass to work on (its moves are read back from them)."""
        return self.pixel.copy(), self.peak.copy()

    def apply(self, moves: PixelMoves) -> PixelEstimates:
        pixel, peak = self.working()
        pixel[moves.index] = moves.pixel
        peak[moves.index] = moves.peak
        return PixelEstimates(pixel, peak)


# ------------------------------------------------------------------ surface level
@dataclass(frozen=True)
class SurfaceMoves:
    """Landmarks one surface pass moves on the scan (sequences are converted to read-only arrays).

    index : (k,) int, each landmark at most once.
    triangle : (k,) int scan triangle; bary : (k, 3) barycentric coordinates in it.
    position : (k, 3) float, model frame, mm; None when the pass gives surface points only (the
        orchestrator then derives the positions from them).
    source : k str ("refined", "prediction", ...), or None: sources unchanged.
    evidence : (k,) float appearance evidence, or None: unchanged.
    """

    index: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    position: np.ndarray | None = None
    source: tuple[str, ...] | None = None
    evidence: np.ndarray | None = None

    def __post_init__(self):
        _freeze(self, index=(np.int64, (-1,)), triangle=(np.int64, (-1,)), bary=(float, (-1, 3)),
                position=(float, (-1, 3)), evidence=(float, (-1,)))
        if self.source is not None:
            object.__setattr__(self, "source", tuple(self.source))

    @classmethod
    def none(cls) -> SurfaceMoves:
        return cls([], [], [])

    def __len__(self) -> int:
        return len(self.index)


@dataclass(frozen=True)
class MatchState:
    """The match so far, one row a template point.

    positions : (P, 3) float, model frame, mm.
    triangle : (P,) int scan triangle, −1 while a point has no surface point; bary : (P, 3).
    source : P str: "seed", "candidate", "refined", "opening" (on the mouth opening's edge), "fixed", "prediction".
    evidence : (P,) float appearance evidence (the NCC peak; 0 when none).
    """

    positions: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    source: tuple[str, ...]
    evidence: np.ndarray

    def __post_init__(self):
        _freeze(self, positions=(float, (-1, 3)), triangle=(np.int64, (-1,)), bary=(float, (-1, 3)),
                evidence=(float, (-1,)))
        object.__setattr__(self, "source", tuple(self.source))

    def apply(self, moves: SurfaceMoves) -> MatchState:
        """The state with ``moves`` applied (positions kept where the moves give none)."""
        i = moves.index
        tri, bary, pos, ev = (a.copy() for a in (self.triangle, self.bary, self.positions, self.evidence))
        tri[i], bary[i] = moves.triangle, moves.bary
        if moves.position is not None:
            pos[i] = moves.position
        if moves.evidence is not None:
            ev[i] = moves.evidence
        source = list(self.source)
        for k, s in zip(i, moves.source or ()):
            source[k] = s
        return MatchState(pos, tri, bary, tuple(source), ev)

    def replace(self, **changes) -> MatchState:
        return dataclasses.replace(self, **changes)


# ------------------------------------------------------------------ the match
@dataclass
class MatchResult:
    """positions (P, 3) model frame; triangle (P,) / bary (P, 3) on the input face; confidence (P,);
    source (P,) str: "seed", "candidate", "refined", "opening", "fixed", "prediction"; timings."""

    names: tuple[str, ...]
    positions: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    confidence: np.ndarray
    source: list[str]
    greedy_positions: np.ndarray
    timings: dict = field(default_factory=dict)
