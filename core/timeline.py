"""Timeline: tracks of keyframes for any rig parameter, evaluation at time t, simulated-layer caching.

Parameter keys are the rig's canonical keys (``core.parameters``: ``fap:3``, ``expression:joy``,
``viseme:1``, ``muscle:risorius:left``, ``jaw``, and whatever a new layer registers); values are
checked against the parameter's range (no silent clamping).

Choices the theses leave open (thesis A §4 interpolates poses linearly; nothing about editing):

- A key's interpolation governs the segment *after* it (to the next key), as in most animation
  packages. Before the first key the first value is held, after the last key the last value.
- ``smooth`` is a monotone cubic Hermite curve: interior tangents are the Fritsch–Butland weighted
  harmonic mean of the neighbouring slopes (the PCHIP rule; zero at local extrema), the first and
  last key get a zero tangent (ease in/out, and C¹ with the held value outside the keys). These
  tangents satisfy the Fritsch–Carlson monotonicity condition, so every smooth segment stays
  between the values of its two keys: no overshoot, keys are hit exactly.
- Key times are unique per track; adding a key at an existing time (within ``TIME_TOLERANCE``)
  replaces it. Keys must lie in [0, duration]; values are checked against the parameter's range
  (no silent clamping).
- Tracks are immutable values; every edit replaces whole tracks and returns an :class:`Edit`
  holding the tracks before and after, so ``timeline.apply_edit(edit.inverse())`` undoes it.
  ``changed`` emits the applied :class:`Edit`.
- The muscle layer is a dynamic system: its state at time t depends on the whole force history.
  :class:`MuscleSimulationCache` integrates it on the frame grid (forces sampled at the start of
  each frame, held for the frame) and keeps snapshots every ``snapshot_interval_s``, so seeking to
  any frame restores the nearest earlier snapshot and integrates at most that interval forward;
  it gives the same state as playing forward from 0. Edits to muscle/jaw tracks drop the
  snapshots after the first time the edit can change.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Iterable, Mapping, Protocol, Sequence

import numpy as np
from psygnal import Signal

from core import parameters as P

INTERPOLATIONS = ("step", "linear", "smooth")
STEP, LINEAR, SMOOTH = 0, 1, 2
FPS_CHOICES = (24, 25, 30, 60)
TIME_TOLERANCE = 1e-6  # s: two key times closer than this are the same key
MAX_DURATION_S = 24 * 3600.0


class TimelineError(ValueError):
    """Bad timeline input (unknown key, value out of range, missing key...); the message says what to do."""


# ====================================================================== parameters
# Keys, their ranges and checks are the rig's parameter registry (core.parameters); the timeline
# reports their errors as TimelineError.
@contextlib.contextmanager
def _as_timeline_error():
    try:
        yield
    except P.ParameterError as exc:
        raise TimelineError(str(exc)) from None


def parameter_kinds() -> tuple[str, ...]:
    return P.kinds()


def canonical_key(key: str) -> str:
    """Validated canonical form of a parameter key (``fap:open_jaw`` -> ``fap:3``); TimelineError if unknown."""
    if not isinstance(key, str):
        raise TimelineError(f"parameter keys are strings like 'fap:3' or 'viseme:1', got {key!r}")
    with _as_timeline_error():
        return P.key_of(key)


def check_value(key: str, value: float) -> float:
    """``value`` as float if allowed for canonical ``key``; TimelineError otherwise."""
    with _as_timeline_error():
        return P.check_value(key, value)


def is_simulated(key: str) -> bool:
    """True for keys that drive a dynamic layer (muscle forces, jaw)."""
    with _as_timeline_error():
        return P.is_simulated(key)


# ====================================================================== keys and tracks
@dataclass(frozen=True)
class Key:
    """One keyframe: time (s), value (the parameter's unit), interpolation of the segment after it."""

    time: float
    value: float
    interpolation: str = "smooth"


def _number(value, what: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise TimelineError(f"{what} must be numbers, got {value!r}") from None


def interpolation_code(name: str) -> int:
    try:
        return INTERPOLATIONS.index(name)
    except ValueError:
        raise TimelineError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {name!r}") from None


class Track:
    """The keys of one parameter, as sorted arrays (an immutable value).

    times : (k,) s strictly increasing; values : (k,); codes : (k,) int8 (0 step, 1 linear, 2 smooth);
    tangents : (k,) value/s of the smooth segments (computed once).
    """

    __slots__ = ("key", "times", "values", "codes", "tangents")

    def __init__(self, key: str, keys: Iterable[Key | tuple] = ()):
        ck = canonical_key(key)
        rows = [k if isinstance(k, Key) else Key(*k) for k in keys]
        times = [_number(k.time, f"{ck}: key times") for k in rows]
        values = [check_value(ck, k.value) for k in rows]
        codes = [interpolation_code(k.interpolation) for k in rows]
        order = np.argsort(times, kind="stable")
        self._init(ck, np.array(times, float)[order], np.array(values, float)[order],
                   np.array(codes, np.int8)[order], check=True)

    @classmethod
    def from_arrays(cls, key: str, times, values, codes, *, check: bool = True) -> "Track":
        """A track from arrays (times strictly increasing; codes 0/1/2)."""
        self = object.__new__(cls)
        self._init(canonical_key(key) if check else key, np.array(times, float), np.array(values, float),
                   np.array(codes, np.int8), check=check)
        return self

    def _init(self, key, times, values, codes, *, check):
        if check:
            if not (times.ndim == values.ndim == codes.ndim == 1 and len(times) == len(values) == len(codes)):
                raise TimelineError(f"{key}: times, values and interpolations must be 1-D of equal length")
            if not np.all(np.isfinite(times)):
                raise TimelineError(f"{key}: key times must be finite")
            if len(times) > 1 and np.any(np.diff(times) <= TIME_TOLERANCE):
                i = int(np.argmin(np.diff(times)))
                raise TimelineError(f"{key}: two keys at the same time {times[i]:.6g} s; times must differ")
            if np.any((codes < 0) | (codes > 2)):
                raise TimelineError(f"{key}: interpolation codes must be 0 (step), 1 (linear) or 2 (smooth)")
            for v in values:
                check_value(key, v)
        for a in (times, values, codes):
            a.setflags(write=False)
        tangents = _pchip_tangents(times, values)
        tangents.setflags(write=False)
        self.key, self.times, self.values, self.codes, self.tangents = key, times, values, codes, tangents

    # -------------------------------------------------------- queries
    def __len__(self) -> int:
        return len(self.times)

    def __repr__(self) -> str:
        return f"Track({self.key!r}, {len(self)} keys)"

    def __eq__(self, other) -> bool:
        return (isinstance(other, Track) and self.key == other.key and np.array_equal(self.times, other.times)
                and np.array_equal(self.values, other.values) and np.array_equal(self.codes, other.codes))

    __hash__ = None

    @property
    def keys(self) -> tuple[Key, ...]:
        return tuple(Key(float(t), float(v), INTERPOLATIONS[c]) for t, v, c in zip(self.times, self.values, self.codes))

    def index_at(self, time: float) -> int | None:
        """Index of the key at ``time`` (within TIME_TOLERANCE), None if there is none."""
        if not len(self.times):
            return None
        i = int(np.searchsorted(self.times, time - TIME_TOLERANCE))
        return i if i < len(self.times) and abs(self.times[i] - time) <= TIME_TOLERANCE else None

    def evaluate(self, t):
        """Value(s) at time(s) ``t`` (float or array, s)."""
        if not len(self.times):
            raise TimelineError(f"{self.key}: the track has no keys")
        ts = np.asarray(t, float)
        out = _evaluate(self.times, self.values, self.codes, self.tangents, np.zeros(ts.size, np.int64),
                        np.full(ts.size, len(self.times)), ts.reshape(-1), offset_times=None)
        return float(out[0]) if ts.ndim == 0 else out.reshape(ts.shape)

    # -------------------------------------------------------- derived tracks
    def with_keys(self, times, values, codes) -> "Track":
        """A track of the same parameter with other keys (sorted; later duplicates win)."""
        times = np.asarray(times, float)
        order = np.argsort(times, kind="stable")
        times, values, codes = times[order], np.asarray(values, float)[order], np.asarray(codes, np.int8)[order]
        if len(times) > 1:
            # Keys closer than the tolerance are one key: keep the last one given (the newest edit wins).
            group = np.concatenate([[0], np.cumsum(np.diff(times) > TIME_TOLERANCE)])
            by_group = np.lexsort((order, group))  # within each group, by input position
            last = np.r_[group[by_group][1:] != group[by_group][:-1], True]
            keep = np.sort(by_group[last])
            times, values, codes = times[keep], values[keep], codes[keep]
        return Track.from_arrays(self.key, times, values, codes)


def _pchip_tangents(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(k,) Fritsch–Butland tangents at interior keys, zero at the first and last key."""
    k = len(times)
    m = np.zeros(k)
    if k < 3:
        return m
    h = np.diff(times)
    d = np.diff(values) / h
    h0, h1, d0, d1 = h[:-1], h[1:], d[:-1], d[1:]
    w1, w2 = 2 * h1 + h0, h1 + 2 * h0
    same = (d0 * d1) > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        mid = (w1 + w2) / (w1 / d0 + w2 / d1)
    m[1:-1] = np.where(same, mid, 0.0)
    return m


def _evaluate(times, values, codes, tangents, starts, counts, t, *, offset_times) -> np.ndarray:
    """Values of several tracks stored back to back: track i is ``[starts[i], starts[i] + counts[i])``.

    t : (q,) query time per track. ``offset_times`` : the concatenated times shifted per track so
    one searchsorted finds every track's segment (None for a single track).
    """
    if offset_times is None:
        j = np.searchsorted(times, t, side="right") - 1
    else:
        j = np.searchsorted(offset_times[0], t + offset_times[1], side="right") - 1
    last = starts + counts - 1
    before = j < starts
    after = j >= last
    jj = np.clip(j, starts, np.maximum(last - 1, starts))
    inside = ~(before | after)
    jn = np.minimum(jj + 1, last)
    t0, t1 = times[jj], times[jn]
    v0, v1 = values[jj], values[jn]
    h = np.where(inside, t1 - t0, 1.0)
    s = np.where(inside, (t - t0) / h, 0.0)
    code = codes[jj]
    s2, s3 = s * s, s * s * s
    hermite = ((2 * s3 - 3 * s2 + 1) * v0 + (s3 - 2 * s2 + s) * h * tangents[jj]
               + (-2 * s3 + 3 * s2) * v1 + (s3 - s2) * h * tangents[jn])
    linear = v0 + s * (v1 - v0)
    out = np.where(code == SMOOTH, hermite, np.where(code == LINEAR, linear, v0))
    out = np.where(before, values[starts], out)
    return np.where(after, values[last], out)


# ====================================================================== edits
@dataclass(frozen=True)
class Edit:
    """A reversible timeline change: whole tracks before and after (None = no track), and settings.

    ``timeline.apply_edit(edit.inverse())`` undoes ``edit``; ``apply_edit(edit)`` redoes it.
    """

    label: str
    before: Mapping[str, Track | None]
    after: Mapping[str, Track | None]
    settings_before: tuple[float, int] | None = None  # (duration, fps)
    settings_after: tuple[float, int] | None = None

    def inverse(self) -> "Edit":
        return Edit(f"undo {self.label}", self.after, self.before, self.settings_after, self.settings_before)

    @property
    def keys(self) -> frozenset[str]:
        """The parameter keys whose tracks change."""
        return frozenset(self.after)

    @property
    def is_empty(self) -> bool:
        return not self.after and self.settings_after == self.settings_before

    def earliest_change(self) -> float:
        """The earliest time (s) from which evaluated values may differ (inf if no track changes).

        A smooth segment depends on the keys one before and two after it (their tangents), so a
        change at key i can alter the curve from key i - 2 on (from the start if key 0 changes).
        """
        earliest = math.inf
        for key in self.after:
            a, b = self.before.get(key), self.after.get(key)
            earliest = min(earliest, _first_difference(a, b))
        return earliest


def _first_difference(a: Track | None, b: Track | None) -> float:
    """Earliest time from which track ``a``'s curve and track ``b``'s may differ."""
    if a is None and b is None:
        return math.inf
    if a is None or b is None or not len(a) or not len(b):
        return 0.0 if (a is not None and len(a)) or (b is not None and len(b)) else math.inf
    n = min(len(a), len(b))
    same = (a.times[:n] == b.times[:n]) & (a.values[:n] == b.values[:n]) & (a.codes[:n] == b.codes[:n])
    if same.all():
        if len(a) == len(b):
            return math.inf
        i = n
    else:
        i = int(np.argmin(same))
    if i == 0:
        return 0.0  # the held value before the first key changes
    return float(a.times[max(i - 2, 0)])


@dataclass(frozen=True)
class Clipboard:
    """Copied keys: per parameter key, (time relative to the earliest copied key, value, interpolation)."""

    keys: Mapping[str, tuple[Key, ...]]

    @property
    def span(self) -> float:
        return max((k[-1].time for k in self.keys.values() if k), default=0.0)


Selection = Mapping[str, Iterable[float]]


# ====================================================================== timeline
class Timeline:
    """Tracks of keys for rig parameters, with duration (s) and frame rate (fps).

    Every edit method returns the :class:`Edit` it applied (push it on the undo stack);
    ``changed`` emits that edit.
    """

    changed = Signal(object)

    def __init__(self, duration: float = 10.0, fps: int = 30, tracks: Iterable[Track] | Mapping[str, Track] = ()):
        self._duration = _check_duration(duration)
        self._fps = _check_fps(fps)
        self._tracks: dict[str, Track] = {}
        for track in (tracks.values() if isinstance(tracks, Mapping) else tracks):
            self._check_track_times(track)
            self._tracks[track.key] = track
        self._plan = None

    def copy(self) -> "Timeline":
        """An independent timeline with the same tracks (tracks are immutable, so they are shared)."""
        return Timeline(self._duration, self._fps, self._tracks)

    # -------------------------------------------------------- settings
    @property
    def duration(self) -> float:
        return self._duration

    @property
    def fps(self) -> int:
        return self._fps

    @property
    def n_frames(self) -> int:
        """Frames 0..n-1 at times k / fps, the last at or before ``duration``."""
        return int(math.floor(self._duration * self._fps + 1e-9)) + 1

    def frame_times(self) -> np.ndarray:
        return np.arange(self.n_frames) / self._fps

    def frame_of(self, t: float) -> int:
        """The nearest frame to time ``t`` (clamped to the timeline)."""
        return int(min(max(round(t * self._fps), 0), self.n_frames - 1))

    def set_settings(self, duration: float | None = None, fps: int | None = None) -> Edit:
        """Change duration and/or fps. Shortening below the last key raises (delete or move keys first)."""
        new = (self._duration if duration is None else _check_duration(duration),
               self._fps if fps is None else _check_fps(fps))
        last = max((float(t.times[-1]) for t in self._tracks.values() if len(t)), default=0.0)
        if new[0] < last - TIME_TOLERANCE:
            raise TimelineError(f"cannot shorten the timeline to {new[0]:g} s: there are keys up to {last:g} s; "
                                "move or delete them first")
        return self.apply_edit(Edit("timeline settings", {}, {}, (self._duration, self._fps), new))

    # -------------------------------------------------------- tracks
    @property
    def tracks(self) -> Mapping[str, Track]:
        """Read-only view: canonical key -> Track."""
        return MappingProxyType(self._tracks)

    def track(self, key: str) -> Track:
        ck = canonical_key(key)
        if ck not in self._tracks:
            raise TimelineError(f"the timeline has no track for {ck}")
        return self._tracks[ck]

    def __contains__(self, key: str) -> bool:
        try:
            return canonical_key(key) in self._tracks
        except TimelineError:
            return False

    # -------------------------------------------------------- evaluation
    def evaluate(self, t: float) -> dict[str, float]:
        """Every track's value at time ``t`` (s): canonical key -> value (tracks without keys omitted)."""
        keys, values = self.evaluate_array(t)
        return dict(zip(keys, values.tolist()))

    def evaluate_array(self, t: float, keys: Sequence[str] | None = None) -> tuple[tuple[str, ...], np.ndarray]:
        """(keys, (k,) values) at time ``t``; all tracks with keys, or the given canonical keys."""
        plan = self._compile()
        if keys is None:
            names, rows = plan["keys"], slice(None)
        else:
            names = tuple(keys)
            rows = np.array([plan["index"][k] for k in names], np.int64)
        starts, counts = plan["starts"][rows], plan["counts"][rows]
        if not len(starts):
            return names, np.zeros(0)
        q = np.clip(float(t), plan["lo"], plan["hi"])
        shift = plan["shift"][rows]
        values = _evaluate(plan["times"], plan["values"], plan["codes"], plan["tangents"], starts, counts,
                           np.full(len(starts), q), offset_times=(plan["offset"], shift))
        return names, values

    def _compile(self) -> dict:
        """Concatenate every non-empty track into flat arrays, shifted so one searchsorted serves all."""
        if self._plan is None:
            tracks = [tr for tr in self._tracks.values() if len(tr)]
            keys = tuple(tr.key for tr in tracks)
            counts = np.array([len(tr) for tr in tracks], np.int64)
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if len(tracks) else counts
            cat = (lambda name, dtype: np.concatenate([getattr(tr, name) for tr in tracks]).astype(dtype)
                   if tracks else np.zeros(0, dtype))
            times = cat("times", float)
            lo = float(min(times.min(), 0.0)) - 1.0 if len(times) else -1.0
            hi = float(max(times.max(), self._duration)) + 1.0 if len(times) else 1.0
            span = hi - lo + 1.0
            shift = np.arange(len(tracks)) * span  # track i's times live in [lo + i·span, hi + i·span]
            offset = times + np.repeat(shift, counts)
            self._plan = dict(keys=keys, index={k: i for i, k in enumerate(keys)}, counts=counts, starts=starts,
                              times=times, values=cat("values", float), codes=cat("codes", np.int8),
                              tangents=cat("tangents", float), offset=offset, shift=shift, lo=lo, hi=hi)
        return self._plan

    # -------------------------------------------------------- edits
    def apply_edit(self, edit: Edit) -> Edit:
        """Apply ``edit`` (an edit returned earlier, or its inverse); TimelineError if the timeline has diverged."""
        for key, track in edit.before.items():
            current = self._tracks.get(key)
            if not (current is track or (current is not None and track is not None and current == track)):
                raise TimelineError(f"cannot apply '{edit.label}': the track {key} changed since; "
                                    "undo the later edits first")
        if edit.settings_before is not None and edit.settings_before != (self._duration, self._fps):
            raise TimelineError(f"cannot apply '{edit.label}': the timeline settings changed since")
        duration, fps = self._duration, self._fps
        if edit.settings_after is not None:  # the limits hold for every edit, not only set_settings
            duration, fps = _check_duration(edit.settings_after[0]), _check_fps(edit.settings_after[1])
        for key, track in edit.after.items():
            if track is not None and len(track) and (track.times[0] < -TIME_TOLERANCE
                                                     or track.times[-1] > duration + TIME_TOLERANCE):
                raise TimelineError(f"cannot apply '{edit.label}': {key}'s keys from {track.times[0]:g} to "
                                    f"{track.times[-1]:g} s do not fit the timeline 0 to {duration:g} s "
                                    f"(at most {MAX_DURATION_S:g} s)")
        if duration < self._duration:
            for key, track in self._tracks.items():
                if key not in edit.after and len(track) and track.times[-1] > duration + TIME_TOLERANCE:
                    raise TimelineError(f"cannot apply '{edit.label}': {key} has keys up to {track.times[-1]:g} s, "
                                        f"after the new end {duration:g} s")
        if edit.settings_after is not None:
            self._duration, self._fps = duration, fps
        for key, track in edit.after.items():
            if track is None:
                self._tracks.pop(key, None)
            else:
                self._tracks[key] = track
        self._plan = None
        self.changed.emit(edit)
        return edit

    def replace_tracks(self, tracks: Mapping[str, Track | None] | Iterable[Track], label: str = "replace tracks") -> Edit:
        """Set whole tracks (None removes one), e.g. the tracks made by lip-sync."""
        if not isinstance(tracks, Mapping):
            tracks = {t.key: t for t in tracks}
        after = {}
        for key, track in tracks.items():
            ck = canonical_key(key)
            if track is not None:
                if track.key != ck:
                    raise TimelineError(f"track for {track.key} given under the key {ck}")
                self._check_track_times(track)
            after[ck] = track
        before = {k: self._tracks.get(k) for k in after}
        return self.apply_edit(Edit(label, before, after))

    def add_track(self, key: str, keys: Iterable[Key | tuple] = ()) -> Edit:
        track = Track(key, keys)
        if track.key in self._tracks:
            raise TimelineError(f"the timeline already has a track for {track.key}")
        return self.replace_tracks({track.key: track}, "add track")

    def remove_track(self, key: str) -> Edit:
        self.track(key)
        return self.replace_tracks({canonical_key(key): None}, "remove track")

    def set_key(self, key: str, time: float, value: float, interpolation: str | None = None) -> Edit:
        """Add a key (creating the track if needed) or replace the key at ``time``.

        interpolation None keeps the replaced key's interpolation (``smooth`` for a new key).
        """
        return self.add_keys({key: [(time, value, interpolation)]}, label="set key")

    def add_keys(self, keys: Mapping[str, Iterable[Key | tuple]], label: str = "add keys") -> Edit:
        """Add or replace keys on several tracks at once: key -> [(time, value[, interpolation])]."""
        after = {}
        for key, rows in keys.items():
            ck = canonical_key(key)
            old = after.get(ck) or self._tracks.get(ck) or Track.from_arrays(ck, [], [], [], check=False)
            times, values, codes = list(old.times), list(old.values), list(old.codes)
            for row in rows:
                k = row if isinstance(row, Key) else Key(*row) if len(row) == 3 else Key(row[0], row[1], None)
                t = self._check_time(ck, k.time)
                v = check_value(ck, k.value)
                i = old.index_at(t)
                if k.interpolation is None:
                    code = int(old.codes[i]) if i is not None else SMOOTH
                else:
                    code = interpolation_code(k.interpolation)
                times.append(t), values.append(v), codes.append(code)
            old = old.with_keys(times, values, codes)
            after[ck] = old
        return self.replace_tracks(after, label)

    def delete_keys(self, selection: Selection) -> Edit:
        """Delete keys by time: key -> times. A track left without keys is removed."""
        after = {}
        for ck, track, idx in self._select(selection):
            keep = np.ones(len(track), bool)
            keep[idx] = False
            after[ck] = (Track.from_arrays(ck, track.times[keep], track.values[keep], track.codes[keep], check=False)
                         if keep.any() else None)
        return self.replace_tracks(after, "delete keys")

    def move_keys(self, selection: Selection, dt: float = 0.0, dvalue: float = 0.0) -> Edit:
        """Shift the selected keys by ``dt`` seconds and ``dvalue`` (in each parameter's unit).

        Moved keys replace unselected keys they land on. Raises if a key would leave [0, duration]
        or its parameter's range.
        """
        dt, dvalue = float(dt), float(dvalue)
        after = {}
        for ck, track, idx in self._select(selection):
            moved_t = track.times[idx] + dt
            moved_v = track.values[idx] + dvalue
            for t, v in zip(moved_t, moved_v):
                self._check_time(ck, t)
                check_value(ck, v)
            keep = np.ones(len(track), bool)
            keep[idx] = False
            after[ck] = track.with_keys(np.concatenate([track.times[keep], moved_t]),
                                        np.concatenate([track.values[keep], moved_v]),
                                        np.concatenate([track.codes[keep], track.codes[idx]]))
        return self.replace_tracks(after, "move keys")

    def set_interpolation(self, selection: Selection, interpolation: str) -> Edit:
        code = interpolation_code(interpolation)
        after = {}
        for ck, track, idx in self._select(selection):
            codes = track.codes.copy()
            codes[idx] = code
            after[ck] = Track.from_arrays(ck, track.times, track.values, codes, check=False)
        return self.replace_tracks(after, f"interpolation {interpolation}")

    def copy_keys(self, selection: Selection) -> Clipboard:
        """The selected keys, times relative to the earliest selected key (of all tracks)."""
        picked = list(self._select(selection))
        t0 = min((float(track.times[idx].min()) for _, track, idx in picked if len(idx)), default=0.0)
        return Clipboard({ck: tuple(Key(float(track.times[i]) - t0, float(track.values[i]),
                                        INTERPOLATIONS[track.codes[i]]) for i in idx)
                          for ck, track, idx in picked})

    def paste_keys(self, clipboard: Clipboard, at_time: float) -> Edit:
        """Insert copied keys with the earliest at ``at_time`` (replacing keys at the same times)."""
        return self.add_keys({k: [Key(key.time + float(at_time), key.value, key.interpolation) for key in keys]
                              for k, keys in clipboard.keys.items()}, label="paste keys")

    # -------------------------------------------------------- helpers
    def _select(self, selection: Selection):
        for key, times in selection.items():
            track = self.track(key)
            idx = []
            for t in times:
                i = track.index_at(float(t))
                if i is None:
                    raise TimelineError(f"{track.key} has no key at {float(t):.6g} s")
                idx.append(i)
            yield track.key, track, np.unique(np.array(idx, np.int64))

    def _check_time(self, key: str, t: float) -> float:
        t = float(t)
        if not (math.isfinite(t) and -TIME_TOLERANCE <= t <= self._duration + TIME_TOLERANCE):
            raise TimelineError(f"{key}: key time {t:.6g} s is outside the timeline 0 to {self._duration:g} s; "
                                "extend the duration first")
        return min(max(t, 0.0), self._duration)

    def _check_track_times(self, track: Track) -> None:
        if len(track) and (track.times[0] < -TIME_TOLERANCE or track.times[-1] > self._duration + TIME_TOLERANCE):
            raise TimelineError(f"{track.key}: keys from {track.times[0]:g} to {track.times[-1]:g} s do not fit the "
                                f"timeline 0 to {self._duration:g} s; extend the duration first")


def _check_duration(duration: float) -> float:
    d = float(duration)
    if not (math.isfinite(d) and 0 < d <= MAX_DURATION_S):
        raise TimelineError(f"timeline duration must be between 0 and {MAX_DURATION_S:g} s, got {duration!r}")
    return d


def _check_fps(fps: int) -> int:
    if isinstance(fps, bool) or not isinstance(fps, (int, np.integer, float)) or fps not in FPS_CHOICES:
        raise TimelineError(f"frame rate must be one of {', '.join(map(str, FPS_CHOICES))} fps, got {fps!r}")
    return int(fps)


# ====================================================================== applying to the rig
def apply_to_rig(rig, values: Mapping[str, float]) -> None:
    """Set evaluated timeline values on a ``core.rig.FaceRig``: every parameter that is not simulated
    (untracked parameters keep their values). Simulated ones (muscle forces, jaw) depend on the
    force history: :class:`MuscleSimulationCache` (or :func:`apply_at`) integrates them over time."""
    rig.set_values({k: v for k, v in values.items() if not is_simulated(k)})


def apply_at(timeline: Timeline, t: float, rig, simulation: "MuscleSimulationCache | None" = None) -> dict[str, float]:
    """Pose the rig at time ``t``: evaluate, set the parameters, bring the simulated layer to frame(t).

    Returns the evaluated values. One ``rig.changed`` at most.
    """
    values = timeline.evaluate(t)
    with rig.batch():
        apply_to_rig(rig, values)
        if simulation is not None:
            simulation.seek(t)
    return values


# ====================================================================== simulated layers
class SimulatedLayer(Protocol):
    """The dynamic layer contract (core.layers.muscles.MuscleLayer)."""

    def set_values(self, values: Mapping[str, float]) -> None: ...

    def start_animation(self) -> None: ...

    def advance(self, dt: float) -> None: ...

    def snapshot(self) -> Any: ...

    def restore(self, snapshot: Any) -> None: ...

    def relax(self, budget_s: float) -> Any: ...


class MuscleSimulationCache:
    """The muscle layer's state at any frame, simulated forward with the timeline's forces and cached.

    Frame k (time k / fps) is reached by integrating from frame 0 with ``layer.advance(1 / fps)``;
    during the step from frame j to j + 1 the forces and jaw angle are the tracks' values at j / fps.
    Frame 0 is the equilibrium of the forces at t = 0 (``relax(relax_budget_s)``; 0 skips it) after
    which ``start_animation()`` begins the dynamic integration. Snapshots are kept every
    ``snapshot_interval_s`` (and for the last frame reached), so any seek integrates at most that
    interval. Muscles without a track keep whatever the layer has (call ``invalidate()`` when the
    user changes them); a muscle whose track is deleted returns to force 0 (jaw to 0°).
    """

    def __init__(self, timeline: Timeline, layer: SimulatedLayer, *, snapshot_interval_s: float = 0.25,
                 relax_budget_s: float = 1.0):
        if not snapshot_interval_s > 0:
            raise TimelineError(f"snapshot interval must be positive, got {snapshot_interval_s!r}")
        self.timeline = timeline
        self.layer = layer
        self.snapshot_interval_s = float(snapshot_interval_s)
        self.relax_budget_s = float(relax_budget_s)
        self._snapshots: dict[int, Any] = {}
        self._current: int | None = None  # frame the layer holds now
        self._fps = timeline.fps
        self.steps = 0  # frames integrated since creation (for tests and profiling)
        self._driven: set[str] = set()  # simulated keys whose values the cache has set on the layer
        timeline.changed.connect(self._on_edit)

    def close(self) -> None:
        self.timeline.changed.disconnect(self._on_edit)

    @property
    def interval_frames(self) -> int:
        return max(1, int(round(self.snapshot_interval_s * self.timeline.fps)))

    @property
    def cached_frames(self) -> tuple[int, ...]:
        return tuple(sorted(self._snapshots))

    def invalidate(self, from_time: float = 0.0) -> None:
        """Forget states that may depend on track values at or after ``from_time`` (s)."""
        if from_time <= 0:
            self._snapshots.clear()
            self._current = None
            return
        first_bad = int(math.floor(from_time * self.timeline.fps))  # frames >= this used forces >= from_time
        for k in [k for k in self._snapshots if k >= max(first_bad, 1)]:
            del self._snapshots[k]
        if self._current is not None and self._current >= max(first_bad, 1):
            self._current = None

    def seek(self, t: float) -> int:
        """Put the layer in its state at the frame nearest ``t``; returns that frame."""
        target = self.timeline.frame_of(t)
        if self._current == target:
            return target
        start = max((k for k in self._snapshots if k <= target), default=None)
        if self._current is not None and self._current <= target and (start is None or self._current >= start):
            start = self._current
        elif start is None:
            self._initial_state()
            start = 0
        else:
            self.layer.restore(self._snapshots[start])
        self._run(start, target)
        self._current = target
        return target

    def _initial_state(self) -> None:
        self._apply_forces(0.0)
        if self.relax_budget_s > 0:
            self.layer.relax(self.relax_budget_s)
        self.layer.start_animation()
        self._snapshots[0] = self.layer.snapshot()

    def _run(self, start: int, target: int) -> None:
        fps, every = self.timeline.fps, self.interval_frames
        dt = 1.0 / fps
        for j in range(start, target):
            self._apply_forces(j / fps)
            self.layer.advance(dt)
            self.steps += 1
            if (j + 1) % every == 0 and (j + 1) not in self._snapshots:
                self._snapshots[j + 1] = self.layer.snapshot()

    def _apply_forces(self, t: float) -> None:
        keys = [k for k in self.timeline.tracks if is_simulated(k) and len(self.timeline.tracks[k])]
        # A parameter whose track was removed returns to rest (force 0, jaw 0) rather than keeping
        # the last value the cache gave it, so the result depends only on the current tracks.
        values = {gone: P.describe(gone).default for gone in self._driven - set(keys)}
        self._driven = set(keys)
        if keys:
            names, array = self.timeline.evaluate_array(t, keys)
            values.update(zip(names, array.tolist()))
        if values:
            self.layer.set_values(values)

    def _on_edit(self, edit: Edit) -> None:
        if edit.settings_after is not None and edit.settings_after[1] != self._fps:
            self._fps = edit.settings_after[1]
            self.invalidate(0.0)
            return
        if any(is_simulated(k) for k in edit.keys):
            self.invalidate(edit.earliest_change())


__all__ = [
    "INTERPOLATIONS", "FPS_CHOICES", "TimelineError", "canonical_key", "check_value", "is_simulated", "Key",
    "Track", "Edit", "Clipboard", "Timeline", "apply_to_rig", "apply_at", "SimulatedLayer", "MuscleSimulationCache",
]
