"""Coarticulated viseme intensity curves and blinks, as timeline keys.

Coarticulation (thesis A §4.2.2: "the viseme shown is affected by the previous one"; the mouth
never jumps) follows the dominance model of Cohen & Massaro (1993): every viseme segment (silence
included) has a dominance curve, and each viseme's intensity is its dominance divided by the sum
of all dominances at that time, so the intensities always sum to 1 (the FAP presets they weight
add up linearly in the rig, so a larger sum would exaggerate the mouth). A dominance curve is a
trapezoid: 0 -> 1 over the transition window at the segment's start, 1 over the segment, 1 -> 0
over the window at its end. Each boundary's window lasts ``transition_s`` and is centred on the
boundary (the next viseme is anticipated by half a window and the previous one lingers half a
window), except next to a must-reach viseme (lip contact: p b m, f v,
``resources/lipsync/visemes.csv``): there the whole window lies in the other phoneme, and no
window reaches into a must-reach phoneme, so the lips are fully closed for the whole contact
phoneme — unless the phonemes between two contacts are shorter than a window ("papa" at speed):
then the transition also uses the outer 40 % of the contact phonemes, which stay closed over
their middle 20 % at least. A phoneme shorter than a window overlaps its neighbours' windows and shares
the time with them (undershoot, as in fast speech). Speech that starts or ends on a sound fades
in from / out to silence over one window outside the audio (the lips move before the sound).

Keys: the breakpoints of the dominance curves, plus samples every ``SAMPLE_S`` where more than two
segments overlap (the normalised curve is not linear there); ``smooth`` interpolation (monotone
cubic, zero slope at plateaus), so values stay in [0, 1] and the largest frame-to-frame change
is about 1.5 · frame / transition (0.5 at 30 fps with 0.1 s).

Blinks (thesis A: the eyes-closed pose is used for blinking; thesis B: never perfectly symmetric):
one every 2.5–5 s (people blink about 15–20 times a minute while talking), first one 0.5–2 s in;
the lids close in 0.08 s, stay shut 0.04 s and reopen in 0.16 s (opening is slower than closing);
one eye starts 15–40 ms after the other, which eye leads is random per blink. Closed = upper lid
830 + lower lid 194 = 1024 IRISD, the sum at which ``lid_contact`` makes the lids meet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.timeline import Track
from core.lipsync.visemes import VisemeSegment, must_reach

SAMPLE_S = 0.02  # s between keys inside a transition
MUST_REACH_MARGIN = 0.4  # fraction of a contact phoneme a crowded transition may use at each end
BLINK_INTERVAL_S = (2.5, 5.0)
BLINK_FIRST_S = (0.5, 2.0)
BLINK_CLOSE_S, BLINK_HOLD_S, BLINK_OPEN_S = 0.08, 0.04, 0.16
BLINK_EYE_OFFSET_S = (0.015, 0.040)
BLINK_UPPER, BLINK_LOWER = 830.0, 194.0  # IRISD; sum 1024 = closed
BLINK_FAPS = {"left": (19, 21), "right": (20, 22)}  # (close_t, close_b) per eye


def _windows(segments, transition_s: float) -> list[tuple[float, float]]:
    """Transition window (start, end) between segment i and i + 1."""
    hard = must_reach()
    n = len(segments)
    out = []
    for i, (a, b) in enumerate(zip(segments[:-1], segments[1:])):
        boundary, w = b.start_s, transition_s
        if a.viseme in hard and b.viseme in hard:
            out.append(_fit(boundary - w / 2, w, a.start_s, b.end_s))
            continue
        # Never reach into a must-reach phoneme (other than the side that anticipates it) ...
        k_lo = next((k for k in range(i, -1, -1) if segments[k].viseme in hard), None)
        k_hi = next((k for k in range(i + 1, n) if segments[k].viseme in hard), None)
        lo = segments[k_lo].end_s if k_lo is not None else segments[0].start_s
        hi = segments[k_hi].start_s if k_hi is not None else segments[-1].end_s
        if hi - lo < w:
            # ... unless the phonemes between are shorter than a window: then the outer
            # MUST_REACH_MARGIN of the contact phonemes is used too (their middle stays closed).
            if k_lo is not None:
                lo -= MUST_REACH_MARGIN * segments[k_lo].duration_s
            if k_hi is not None:
                hi += MUST_REACH_MARGIN * segments[k_hi].duration_s
            out.append(_fit((lo + hi) / 2 - w / 2, w, lo, hi))
        elif b.viseme in hard:
            out.append(_fit(boundary - w, w, lo, hi))
        elif a.viseme in hard:
            out.append(_fit(boundary, w, lo, hi))
        else:
            out.append(_fit(boundary - w / 2, w, lo, hi))
    return out


def _fit(w0: float, w: float, lo: float, hi: float) -> tuple[float, float]:
    """The window [w0, w0 + w] moved inside [lo, hi] (shortened to it if longer)."""
    if hi - lo <= w:
        return lo, hi
    w0 = min(max(w0, lo), hi - w)
    return w0, w0 + w


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class _Dominance:
    """One segment's dominance: min(rise, fall), smoothstep ramps over the two windows (None = none)."""

    rise: tuple[float, float] | None
    fall: tuple[float, float] | None
    start: float
    end: float

    def breakpoints(self) -> list[float]:
        pts = [self.start, self.end]
        for w in (self.rise, self.fall):
            if w is not None:
                n = max(1, int(math.ceil((w[1] - w[0]) / SAMPLE_S)))
                pts += np.linspace(w[0], w[1], n + 1).tolist()
        if self.rise is not None and self.fall is not None and self.rise[1] > self.fall[0]:
            # Overlapping windows: the peak is where the two ramps cross (as for straight lines,
            # since 1 - smoothstep(x) = smoothstep(1 - x)).
            (r0, r1), (f0, f1) = self.rise, self.fall
            pts.append((r0 * (f1 - f0) + f1 * (r1 - r0)) / ((f1 - f0) + (r1 - r0)))
        return pts

    def __call__(self, t: np.ndarray) -> np.ndarray:
        v = np.ones_like(t)
        if self.rise is not None:
            v = np.minimum(v, _smoothstep((t - self.rise[0]) / (self.rise[1] - self.rise[0])))
        if self.fall is not None:
            v = np.minimum(v, 1.0 - _smoothstep((t - self.fall[0]) / (self.fall[1] - self.fall[0])))
        return v


def _accumulate(grid: np.ndarray, shapes: list[_Dominance], n_rows: int, rows) -> np.ndarray:
    """(n_rows, len(grid)) sums of the dominance curves, each added into its row."""
    out = np.zeros((n_rows, len(grid)))
    for row, d in zip(rows, shapes):
        lo = d.rise[0] if d.rise is not None else d.start
        hi = d.fall[1] if d.fall is not None else d.end
        a, b = np.searchsorted(grid, lo, "left"), np.searchsorted(grid, hi, "right")
        out[row, a:b] += d(grid[a:b])
    return out


def viseme_curves(segments: tuple[VisemeSegment, ...] | list[VisemeSegment], *, transition_s: float = 0.1,
                  ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per viseme id (1..14) the keys (times s, intensities 0..1) of its coarticulated curve."""
    if not (transition_s > 0 and math.isfinite(transition_s)):
        raise ValueError(f"transition time must be a positive number of seconds, got {transition_s!r}")
    segments = list(segments)
    if not segments:
        return {}
    t0, t1 = segments[0].start_s, segments[-1].end_s
    if segments[0].viseme != 0:
        segments.insert(0, VisemeSegment(0, t0 - transition_s, t0, "_"))
    if segments[-1].viseme != 0:
        segments.append(VisemeSegment(0, t1, t1 + transition_s, "_"))
    windows = _windows(segments, transition_s)
    shapes = [_Dominance(windows[i - 1] if i else None, windows[i] if i < len(windows) else None,
                         seg.start_s, seg.end_s) for i, seg in enumerate(segments)]
    visemes = np.array([seg.viseme for seg in segments])
    grid = np.unique(np.round(np.concatenate([d.breakpoints() for d in shapes]), 9))
    total = _accumulate(grid, shapes, 1, [0] * len(shapes))[0]
    dominance = _accumulate(grid, shapes, 15, visemes)
    intensity = dominance / np.maximum(total, 1e-12)
    out = {}
    for v in sorted(set(visemes.tolist()) - {0}):
        values = np.clip(intensity[v], 0.0, 1.0)
        values = np.where(values > 1e-9, values, 0.0)
        nz = np.nonzero(values)[0]
        a, b = max(nz[0] - 1, 0), min(nz[-1] + 2, len(grid))
        out[v] = _drop_flat(grid[a:b], values[a:b])
    return out


def _drop_flat(times: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop interior points of flat runs (keep the ends of plateaus and of zero stretches)."""
    keep = np.ones(len(v), bool)
    keep[1:-1] = ~((v[1:-1] == v[:-2]) & (v[1:-1] == v[2:]))
    return times[keep], v[keep]


def viseme_tracks(segments, *, transition_s: float = 0.1, offset_s: float = 0.0) -> dict[str, Track]:
    """``viseme:<id>`` tracks (smooth keys) for the segments, times shifted by ``offset_s``.

    Keys that would fall before time 0 (a fade-in before speech that starts at 0) are cut at 0.
    """
    out = {}
    for v, (times, values) in viseme_curves(segments, transition_s=transition_s).items():
        times = times + offset_s
        if times[0] < 0:
            at_zero = float(np.interp(0.0, times, values))
            keep = times > 0
            times, values = _drop_flat(np.concatenate([[0.0], times[keep]]), np.concatenate([[at_zero], values[keep]]))
        out[f"viseme:{v}"] = Track.from_arrays(f"viseme:{v}", times, values, np.full(len(times), 2, np.int8))
    return out


#: A blink of a short clip keeps this far (s) from its start and end.
BLINK_MARGIN_S = 0.1


def blink_tracks(start_s: float, end_s: float, rng: np.random.Generator) -> dict[str, Track]:
    """FAP 19–22 tracks with blinks between ``start_s`` and ``end_s`` (only whole blinks)."""
    length = BLINK_CLOSE_S + BLINK_HOLD_S + BLINK_OPEN_S + BLINK_EYE_OFFSET_S[1]
    keys = {n: [] for pair in BLINK_FAPS.values() for n in pair}
    t = start_s + rng.uniform(*BLINK_FIRST_S)
    if t + length > end_s and end_s - start_s >= length + 2 * BLINK_MARGIN_S:
        # A short clip would otherwise get no blink at all although one was asked for: one whole
        # blink, somewhere inside it.
        t = start_s + rng.uniform(BLINK_MARGIN_S, end_s - start_s - length - BLINK_MARGIN_S)
    while t + length <= end_s:
        offset = rng.uniform(*BLINK_EYE_OFFSET_S)
        lead = "left" if rng.random() < 0.5 else "right"
        for side, (upper, lower) in BLINK_FAPS.items():
            tb = t if side == lead else t + offset
            for fap, closed in ((upper, BLINK_UPPER), (lower, BLINK_LOWER)):
                keys[fap] += [(tb, 0.0), (tb + BLINK_CLOSE_S, closed), (tb + BLINK_CLOSE_S + BLINK_HOLD_S, closed),
                              (tb + BLINK_CLOSE_S + BLINK_HOLD_S + BLINK_OPEN_S, 0.0)]
        t += rng.uniform(*BLINK_INTERVAL_S)
    return {f"fap:{n}": Track(f"fap:{n}", [(kt, kv, "smooth") for kt, kv in k]) for n, k in keys.items() if k}
