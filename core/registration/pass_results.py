"""What the matcher's passes return, and the state of the match their results change.

A pass reads the match (``match_context``) and returns which landmarks it moves, to where and with
what evidence; it changes nothing. Only the orchestrator (``matching.match``) applies the moves,
so each pass can be read and tested on its own. The arrays of the moves are read-only.

In the scan's frontal raster: ``PixelMoves`` onto ``PixelEstimates`` (the patch search and the
mouth passes). P is the number of template points (``template.detected``), indices are into that
order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np


def _frozen(a, dtype=None, shape=None) -> np.ndarray:
    """A read-only copy of ``a`` (reshaped to ``shape`` when given)."""
    out = np.array(a, dtype=dtype)
    if shape is not None:
        out = out.reshape(shape)
    out.setflags(write=False)
    return out


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

    @classmethod
    def take(cls, pixel: np.ndarray, peak: np.ndarray, moved: Iterable[int]) -> PixelMoves:
        """The rows ``moved`` of a pass's working arrays pixel (P, 2) / peak (P,)."""
        idx = np.array(sorted(set(int(i) for i in moved)), dtype=np.int64)
        return cls(_frozen(idx), _frozen(pixel[idx], float, (-1, 2)), _frozen(peak[idx], float))

    def __len__(self) -> int:
        return len(self.index)


@dataclass(frozen=True)
class PixelEstimates:
    """Every landmark's current estimate in the scan raster: pixel (P, 2) float (col, row), NaN
    where none yet; peak (P,) float NCC evidence (0 where none)."""

    pixel: np.ndarray
    peak: np.ndarray

    @classmethod
    def empty(cls, n: int) -> PixelEstimates:
        return cls(_frozen(np.full((n, 2), np.nan)), _frozen(np.zeros(n)))

    def working(self) -> tuple[np.ndarray, np.ndarray]:
        """Writable copies (pixel, peak) for a pass to work on (its moves are read back from them)."""
        return self.pixel.copy(), self.peak.copy()

    def apply(self, moves: PixelMoves) -> PixelEstimates:
        pixel, peak = self.working()
        pixel[moves.index] = moves.pixel
        peak[moves.index] = moves.peak
        return PixelEstimates(_frozen(pixel), _frozen(peak))


# ------------------------------------------------------------------ the match
@dataclass
class MatchResult:
    """positions (P, 3) model frame; triangle (P,) / bary (P, 3) on the input face; confidence (P,);
    source (P,) str: "seed", "candidate", "refined", "fixed", "prediction"; timings."""

    names: tuple[str, ...]
    positions: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    confidence: np.ndarray
    source: list[str]
    greedy_positions: np.ndarray
    timings: dict = field(default_factory=dict)
