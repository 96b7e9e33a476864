"""How far each FAP can go on one face before its skin breaks, and a soft limit that eases into it.

A FAP's displacement is linear in its value, so "where does it break" is a bisection along one
line per slider end: the value where the first skin triangle moved by the FAP turns its normal
more than 90 degrees (a fold; slivers with no direction are not counted, as in
``core.mesh_quality``), or stretches or squeezes its texture beyond ``core.mesh_quality``'s bounds
(a smear: a principal stretch above MAX_STRETCH or below MIN_STRETCH). Each end's reason is kept
for the slider's tooltip. The finish steps (lid guard, lip contact, teeth) move skin the FAT column
does not, so :func:`finished_limits` then poses the face at each limit and bisects again on the
finished pose where that breaks.

Never below what a preset (expression or viseme at 100 %) asks of a FAP (:func:`keeping`): the
presets are authored poses, a limit would only mute them (viseme aa opens the jaw 600 MNS where
the default face's corner texture stretches twice from 320). The teeth are kept outside by
``teeth_guard`` at any value; lips crossing is left to the combined pose (a lip FAP alone crosses a
closed mouth's lips at once, while the visemes that use it open the jaw with it, so a per-FAP
crossing limit would mute speech).

:func:`soft_limit` is the identity up to ``EASE_START`` of a limit and then eases toward it (C1,
never reaching it, never a hard clamp), applied per FAP to the effective values (user + presets).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from core.mesh_quality import _EPS, MAX_STRETCH, MIN_STRETCH, _local_frames, principal_stretches

# Where easing begins, as a share of the limit: well inside, so ordinary values pass unchanged.
EASE_START = 0.7
# How far past a preset's value a slider end may still move the face where the preset itself goes
# past the surface's limit (a share of the preset's value; see keeping).
PRESET_MARGIN = 0.05
BISECTION_STEPS = 10
# The finished pose's check (finished_limits) poses the whole face per probe: fewer steps (1/128 of
# the range, ~3 units of a 400-unit limit).
FINISHED_BISECTION_STEPS = 7
# Where along a slider's half the texture's squeeze is sampled to pick the triangles to bisect on.
SMEAR_SAMPLES = (0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0)
FOLD_REASON = "the skin would fold"
SMEAR_REASON = f"the skin's texture would smear (stretch over {MAX_STRETCH:g}x or shrink under {MIN_STRETCH:g}x)"
CROSSING_REASON = "the lips would pass through each other or the skin below them"
NOSTRIL_REASON = "the nostril's walls would pass through each other"


def _normals(corners: np.ndarray) -> np.ndarray:
    return np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])


def _rest_measures(rest: np.ndarray, skin_triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(normals (m, 3) unnormalised, in-plane frames (m, 2, 2), measurable (m,) bool) of the skin
    triangles at rest; slivers have no direction to turn (same threshold as core.mesh_quality)."""
    corners = rest[skin_triangles]
    normals = _normals(corners)
    area = np.linalg.norm(normals, axis=1)
    return normals, _local_frames(corners), area > 1e-6 * max(float(np.median(area)), 1e-12)


class _LinearPath:
    """Triangles (k,) whose corners move linearly, ``base + value * step`` (k, 3, 3), measured at
    any value in closed form: edges are linear in the value, so the turn of a normal against the
    rest one and the metric of the posed triangle in its rest frame (whose eigenvalues are the
    squared principal stretches, as ``core.mesh_quality.principal_stretches``) are quadratic in it.
    One probe is then a few multiply-adds per triangle instead of posing and re-framing them."""

    def __init__(self, base: np.ndarray, step: np.ndarray, rest_normals: np.ndarray, rest_frames: np.ndarray):
        e1, e2 = base[:, 1] - base[:, 0], base[:, 2] - base[:, 0]
        d1, d2 = step[:, 1] - step[:, 0], step[:, 2] - step[:, 0]
        dot = lambda a, b: np.einsum("ij,ij->i", a, b)
        # n(v) . n0 = fold[0] + v fold[1] + v^2 fold[2] (unnormalised normals, as _normals).
        self.fold = np.stack([dot(np.cross(e1, e2), rest_normals),
                              dot(np.cross(e1, d2) + np.cross(d1, e2), rest_normals),
                              dot(np.cross(d1, d2), rest_normals)])
        # Metric G(v) = [[e1.e1, e1.e2], [e1.e2, e2.e2]] of the posed edges, per power of v: (3, k) each.
        g00 = np.stack([dot(e1, e1), 2 * dot(e1, d1), dot(d1, d1)])
        g11 = np.stack([dot(e2, e2), 2 * dot(e2, d2), dot(d2, d2)])
        g01 = np.stack([dot(e1, e2), dot(e1, d2) + dot(d1, e2), dot(d1, d2)])
        # In the rest frame R = [[l1, along], [0, across]] (``_local_frames``): C = R^-T G R^-1 with
        # R^-1 = [[a, b], [0, c]]; degenerate rest frames (no inverse) are left out of the smear test.
        length, along, across = rest_frames[:, 0, 0], rest_frames[:, 0, 1], rest_frames[:, 1, 1]
        det = length * across
        self.safe = np.abs(det) > _EPS
        a = np.divide(1.0, length, out=np.zeros_like(det), where=self.safe)
        b = np.divide(-along, det, out=np.zeros_like(det), where=self.safe)
        c = np.divide(1.0, across, out=np.zeros_like(det), where=self.safe)
        self.c00 = a * a * g00
        self.c01 = a * (b * g00 + c * g01)
        self.c11 = b * b * g00 + 2 * b * c * g01 + c * c * g11

    @staticmethod
    def _at(coefficients: np.ndarray, values, subset) -> np.ndarray:
        """(len(values), s) quadratic ``coefficients`` (3, k) at ``values`` on triangles ``subset``."""
        v = np.asarray(values, dtype=float).reshape(-1, 1)
        c = coefficients[:, subset]
        return c[0] + v * (c[1] + v * c[2])

    def folds(self, values, subset=slice(None)) -> np.ndarray:
        """(len(values), s) whether each triangle's normal has turned past 90 degrees."""
        return self._at(self.fold, values, subset) < 0

    def smears(self, values, subset=slice(None)) -> np.ndarray:
        """(len(values), s) whether each triangle's largest principal stretch is above MAX_STRETCH
        or its smallest below MIN_STRETCH (degenerate rest frames never smear)."""
        p, r, q = (self._at(c, values, subset) for c in (self.c00, self.c11, self.c01))
        mean, spread = (p + r) / 2, np.sqrt(((p - r) / 2) ** 2 + q * q)
        out = (mean + spread > MAX_STRETCH ** 2) | (mean - spread < MIN_STRETCH ** 2)
        return out & self.safe[subset]


def clean_limits(rest: np.ndarray, skin_triangles: np.ndarray, matrix, fapu_vector: np.ndarray, specs,
                 numbers) -> tuple[np.ndarray, np.ndarray]:
    """(limits, reasons): limits (68, 2) per FAP the values (FAP units) at its slider's lower and upper
    ends up to which the FAP alone folds no skin triangle and smears no texture; ±inf where it holds
    to the slider's end or is not a translation. reasons (68, 2) str: FOLD_REASON or SMEAR_REASON
    for each finite limit ("" elsewhere).

    rest (n, 3) mm; skin_triangles (m, 3); matrix (3n, 68) mm per FAP unit before ``fapu_vector``."""
    limits = np.array([[-np.inf, np.inf]] * len(specs))
    reasons = np.full((len(specs), 2), "", dtype=object)
    rest_normals, rest_frames, measurable = _rest_measures(rest, skin_triangles)
    columns = matrix.tocsc()
    for number in numbers:
        spec = specs[number - 1]
        if spec.is_rotation or not np.isfinite(spec.minimum) or not np.isfinite(spec.maximum):
            continue
        column = columns[:, number - 1]
        moved = np.zeros(len(rest), dtype=bool)
        moved[np.unique(column.indices // 3)] = True
        tris = np.flatnonzero(moved[skin_triangles].any(axis=1) & measurable)
        if not len(tris):
            continue
        corners = skin_triangles[tris]
        field = column.toarray().reshape(-1, 3) * fapu_vector[number - 1]
        path = _LinearPath(rest[corners], field[corners], rest_normals[tris], rest_frames[tris])

        def breaks(value: float, smear: np.ndarray) -> str:
            """The reason the skin breaks at ``value`` ("" when it holds); the stretch is checked on
            the triangles ``smear`` only."""
            if path.folds(value).any():
                return FOLD_REASON
            return SMEAR_REASON if path.smears(value, smear).any() else ""

        for side, end in enumerate((spec.minimum, spec.maximum)):
            if end == 0:
                continue
            # The largest stretch of a linear map is convex along the line and 1 at rest, so only
            # triangles that smear at the slider's end can stretch too far before it. The smallest is
            # not: a triangle that folds over shrinks to nothing on the way and grows again, so the
            # candidates are those that smear at any of a few samples along the line, or fold at its
            # end. The bisection measures those alone.
            candidate = path.smears(end * np.asarray(SMEAR_SAMPLES)).any(axis=0) | path.folds(end)[0]
            smear = np.flatnonzero(candidate)
            if not breaks(end, smear):   # whole to the slider's end: no limit at all
                continue
            good, bad = bisect(lambda share: bool(breaks(end * share, smear)))
            limits[number - 1, side] = end * good
            reasons[number - 1, side] = breaks(end * bad, smear)
    return limits, reasons


def bisect(breaks, steps: int = BISECTION_STEPS) -> tuple[float, float]:
    """(good, bad) shares of a line, 0 <= good < bad <= 1, bad - good = 2^-steps, where
    ``breaks(share) -> bool`` turns true (it must hold at 0 and break at 1)."""
    good, bad = 0.0, 1.0
    for _ in range(steps):
        mid = (good + bad) / 2
        good, bad = (good, mid) if breaks(mid) else (mid, bad)
    return good, bad


def finished_limits(deform, rest: np.ndarray, skin_triangles: np.ndarray, limits: np.ndarray, reasons: np.ndarray,
                    specs, numbers, reach: np.ndarray, steps: int = FINISHED_BISECTION_STEPS,
                    sides=(0, 1), crossing: Callable[[np.ndarray], bool] | None = None,
                    crossing_reason: str = CROSSING_REASON) -> None:
    """Tighten ``limits`` / ``reasons`` (68, 2, from :func:`clean_limits`) in place where a FAP alone,
    posed by ``deform(values (68,)) -> (n, 3)`` with every finish step (lid guard, lip contact,
    teeth), folds or smears the skin before its linear limit (or its slider's end): those steps move
    skin the FAT column does not. Where a preset (``reach``, :func:`preset_reach`) goes past the linear
    limit, the finished pose is checked up to the preset's value plus PRESET_MARGIN instead (the limit
    may move out to there): the presets pass anyway (:func:`keeping`), the limit says where the slider
    alone breaks the skin.
    ``sides``: the slider ends checked (0 the lower, 1 the upper). Only triangles the pose moved
    are measured. ``crossing(x (n, 3)) -> bool``, if given, also breaks a pose (the lips' surfaces
    crossing: a fold check does not see a lip rolling under the skin next to it), for
    ``crossing_reason``."""
    rest_normals, rest_frames, measurable = _rest_measures(rest, skin_triangles)
    for number in numbers:
        spec = specs[number - 1]
        if spec.is_rotation or not np.isfinite(spec.minimum) or not np.isfinite(spec.maximum):
            continue

        last: dict[float, np.ndarray] = {}     # the latest pose: breaks(far) then crosses(far) share it

        def posed(value: float) -> np.ndarray:
            if value not in last:
                values = np.zeros(len(specs))
                values[number - 1] = value
                last.clear()
                last[value] = deform(values)
            return last[value]

        def breaks(value: float) -> str:
            x = posed(value)
            moved = (x != rest).any(axis=1)
            tris = np.flatnonzero(moved[skin_triangles].any(axis=1) & measurable)
            corners = x[skin_triangles[tris]]
            if (np.einsum("ij,ij->i", _normals(corners), rest_normals[tris]) < 0).any():
                return FOLD_REASON
            big, small = principal_stretches(rest_frames[tris], corners)
            return SMEAR_REASON if (big > MAX_STRETCH).any() or (small < MIN_STRETCH).any() else ""

        def crosses(value: float) -> bool:
            return crossing(posed(value))

        for side in sides:
            end = (spec.minimum, spec.maximum)[side]
            limit = limits[number - 1, side]
            far = limit if np.isfinite(limit) else end
            asked = reach[number - 1, side]
            if far == 0:
                continue
            if abs(asked) >= abs(far):
                if not np.isfinite(limit):
                    continue            # a preset at the slider's end: no end left to limit
                # A preset goes past the FAP's linear limit, where the finish steps (the surface guard
                # above all) may still hold the skin: the finished pose is checked up to the preset's
                # value and the margin keeping() gives it, so that the slider alone stops where the
                # finished surface breaks (the Surrey Face Model scan's raise_r_o_eyebrow: linear limit
                # 50 ENS, unbroken finished at 80; the default face's cheek lift: 215 linear, broken
                # finished before it).
                far = np.copysign(min(abs(asked) * (1 + PRESET_MARGIN), abs(end)), asked)
                limits[number - 1, side] = far
            if breaks(far):
                good, bad = bisect(lambda share: bool(breaks(far * share)), steps)
                reasons[number - 1, side] = breaks(far * bad) or FOLD_REASON
                far *= good
                limits[number - 1, side] = far
            # The crossing test is the dear one (~40 ms): once, where the surface holds, and bisected
            # only when the lips cross there.
            if crossing is None or far == 0 or abs(asked) >= abs(far) or not crosses(far):
                continue
            good, _ = bisect(lambda share: crosses(far * share), steps)
            limits[number - 1, side] = far * good
            reasons[number - 1, side] = crossing_reason


def new_crossings(rest: np.ndarray, triangles: np.ndarray, welded: np.ndarray,
                  moved_mm: float) -> Callable[[np.ndarray], bool]:
    """``crosses(x (n, 3)) -> bool`` for :func:`finished_limits`: whether the pose ``x`` makes a pair of
    ``triangles`` (k, 3) cross that did not cross at ``rest`` (n, 3) (a scan's own crossings are not
    the slider's), testing only triangles with a corner moved more than ``moved_mm`` (the FAT's tails
    move far skin by microns). ``welded``: ``core.mesh_quality.welded_vertices(rest)``."""
    from core.mesh_quality import intersecting_pairs

    k = len(triangles)

    def keys(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.minimum(a, b).astype(np.int64) * k + np.maximum(a, b)

    at_rest = keys(*intersecting_pairs(rest, triangles, None, welded))

    def crosses(x: np.ndarray) -> bool:
        moved = np.flatnonzero((np.linalg.norm(x - rest, axis=1) > moved_mm)[triangles].any(axis=1))
        ia, ib = intersecting_pairs(x, triangles[moved], triangles, welded)
        return bool(np.setdiff1d(keys(moved[ia], ib), at_rest).size)

    return crosses


def preset_reach(values: np.ndarray) -> np.ndarray:
    """(68, 2) the furthest value toward each slider end that any row of ``values`` (k, 68) asks (0
    where none goes that way)."""
    return np.stack([values.min(axis=0, initial=0.0), values.max(axis=0, initial=0.0)], axis=1)


def keeping(limits: np.ndarray, values: np.ndarray, ease_start=EASE_START,
            margin: float = PRESET_MARGIN) -> tuple[np.ndarray, np.ndarray]:
    """(limits, ease_start), both (68, 2), for :func:`soft_limit`, such that every row of ``values``
    (k, 68) passes unchanged: the presets are authored poses and must read as authored (viseme aa
    opens the jaw 600 MNS, past where the default face's mouth corners fold).

    Where a preset asks more than ``ease_start`` of a limit, the ease starts at the preset's value
    and still eases toward the limit; where the preset goes past the limit itself, toward ``margin``
    times that overshoot beyond the preset. So a slider end past every preset moves the face no further
    than the surface (or the preset that already breaks it) allows, and the limits are continuous in
    ``values``. ``ease_start``: EASE_START, or (68, 2) per end."""
    out = limits.astype(float).copy()
    start = np.array(np.broadcast_to(np.asarray(ease_start, dtype=float), limits.shape))
    reach = np.abs(preset_reach(values))
    size = np.abs(out)
    widened = reach > start * size                        # never where the limit is infinite
    # The margin grows with the overshoot: as a share of the preset's value, a preset just inside a
    # limit (the Surrey Face Model scan's lower_t_midlip: 100 of 100.7 MNS, where its lips cross) took
    # the slider's end to 105, past where the surface breaks.
    wide = np.maximum(size, reach + margin * (reach - size))
    out[widened] = np.copysign(wide, out)[widened]
    start[widened] = reach[widened] / wide[widened]
    return out, start


def soft_limit(values: np.ndarray, limits: np.ndarray, ease_start=EASE_START) -> np.ndarray:
    """(68,) ``values`` eased into ``limits`` (68, 2): unchanged within ``ease_start`` of a limit
    (EASE_START, or (68, 2) per slider end), then ``start + room * tanh((v - start) / room)``
    (slope 1 where it begins, the limit never reached)."""
    values = np.asarray(values, dtype=float)
    ease_start = np.broadcast_to(np.asarray(ease_start, dtype=float), limits.shape)
    ease = ease_start * limits
    if not ((values > ease[:, 1]).any() or (values < ease[:, 0]).any()):
        return values          # the common case, every tick: nothing near a limit
    out = values.copy()
    for side, sign in ((1, 1.0), (0, -1.0)):
        limit = sign * limits[:, side]                     # both ends as positive magnitudes
        beyond = sign * out > ease[:, side] * sign         # never true where the limit is inf
        if beyond.any():
            start = ease_start[beyond, side] * limit[beyond]
            room = np.maximum(limit[beyond] - start, 1e-12)
            out[beyond] = sign * (start + room * np.tanh((sign * out[beyond] - start) / room))
    return out
