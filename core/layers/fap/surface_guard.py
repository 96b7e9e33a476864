"""Skin that would fold or smear is smoothed where it would: the FAP layer's last shaping step.

Every layer's offsets add up (FAPs, the expression library's poses) and the finish steps shape the
lids, lips and teeth; where the result still turns a skin triangle over or stretches its texture
past ``core.mesh_quality``'s bounds, nothing upstream could see it coming: a FAP's field is steep
at its feature point (stretch_cornerlip 400 turned three triangles at the default face's mouth
corner: the corner moved 7.9 mm, the skin 0.9 mm beyond it 7.2 mm), two fields meet, a preset asks
more than the face's slider limits allow. This step smooths the displacement there, blended in by
how close each triangle is to breaking:

    s_t = max(ramp(largest stretch, STRETCH_RAMP), ramp(smallest stretch, SQUEEZE_RAMP),
              ramp(cos(normal, rest normal), TURN_RAMP))                       triangle t, 0..1
    a_v = max over t within RINGS rings of v of s_t · (1 − ring / (RINGS + 1)),  × the hold taper
    x_v += a_v · ((Pᵏ u)_v − u_v)        u = x − rest,  P the 1/length-weighted neighbour average,
                                         k = SMOOTHING_STEPS

Each term is continuous in the pose (no threshold, no iteration), so the face never jumps as a slider
passes the point where the guard begins to act, and a pose that holds up everywhere (every s_t = 0,
the common case) is left as it was, bit for bit. The ramps reach 1 just inside the bounds, so a pose
that would break gets the whole smoothing.

Held (never moved, and the guard fades out over ``HOLD_TAPER_RINGS`` rings around them): the lid
margins, which the lid steps place (smoothed, a closed lid opened 58 %). The skin the lid guard keeps
outside an eyeball (``balls``: the lids, the socket, the cheek under the eye) slides on it: smoothed
like the rest, then put back at its distance from the ball's centre, so what the smoothing would have
drawn into the ball stays outside it. (Held instead, the cheek lift bunched the skin under the eye
to 0.06 x its height, and joy failed with it; smoothed freely, joy's skin crossed the eyeball 352 times.)
Held for one pose: the vertices other layers place exactly (``pinned``: dragged control points; a
14 mm drag of the mouth corner ended 1.7 mm short of the pointer).
Seam copies (one position at rest) that coincide in the pose end at one position. Those the caller
says always move as one (``joined``: the face/head-shell seam, where the FAT gives both copies one row)
are one vertex of the smoothing: smoothed apart, each copy saw its own side's neighbours only, and a
thin triangle beside the default face's jaw angle, unstrained by surprise + viseme aa, came out
stretched 2.15 x (every failing expression + viseme mix but joy's).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse

from core.layers.fap import kernels
from core.mesh_quality import _EPS, MAX_STRETCH, MIN_STRETCH, _local_frames, _normals, principal_stretches, \
    welded_vertices

__all__ = ["GuardRegion", "SurfaceGuard"]

# (where the guard starts, where it is at full strength): full just inside core.mesh_quality's bounds,
# starting far enough before them that the face's motion stays monotone as a pose grows (starting at
# 0.85 x the stretch bound, 1.3 x the squeeze bound and a 72.5° turn, the default face's mouth corner
# at stretch_cornerlip 120 -> 140 -> 160 went 5.62 -> 5.34 -> 6.11 mm: the guard caught up with it).
STRETCH_RAMP = (0.75 * MAX_STRETCH, 0.975 * MAX_STRETCH)
SQUEEZE_RAMP = (1.8 * MIN_STRETCH, 1.05 * MIN_STRETCH)
TURN_RAMP = (0.6, 0.05)            # cosine of a triangle's turn from its rest normal (53° .. 87°)
RINGS = 4                          # how far around a breaking triangle the smoothing reaches
SMOOTHING_STEPS = 8                # 12 took twice the time (3.2 vs 1.6 ms on joy) for no pose more held
HOLD_TAPER_RINGS = 3


def _ramp(value: np.ndarray, ramp: tuple[float, float]) -> np.ndarray:
    """0 at ramp[0], 1 at ramp[1] (either direction), clipped, C0."""
    start, full = ramp
    return np.clip((value - start) / (full - start), 0.0, 1.0)


class GuardRegion(NamedTuple):
    """Some of a guard's triangles, whose strain alone :meth:`SurfaceGuard.apply` smooths, with their
    rows gathered once (:meth:`SurfaceGuard.region`).

    name : the region's own slot of the guard's incremental check; triangles : (t,) int indices;
    corners, inverses, normals, checked : those triangles' rows of the guard's arrays.
    """

    name: str
    triangles: np.ndarray
    corners: np.ndarray
    inverses: np.ndarray
    normals: np.ndarray
    checked: np.ndarray


class SurfaceGuard:
    """The guard of one face (see the module docstring).

    rest : (n, 3) mm; skin_triangles : (T, 3) the triangles measured and smoothed over (no parts);
    held : (n,) bool vertices other steps own; joined : (k, 2) int (copy, original) seam pairs at one
    rest position that always move as one (smoothed as one vertex; the copy follows the original);
    balls : per eyeball (the skin vertices that slide on it (k,) int, its centre at rest (3,) mm, a
    few of its own vertices (m,) int whose mean motion is the ball's shift).
    """

    def __init__(self, rest: np.ndarray, skin_triangles: np.ndarray, held: np.ndarray,
                 joined: np.ndarray | None = None,
                 balls: tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...] = ()):
        rest = np.array(rest, dtype=float)
        rest.setflags(write=False)         # as the compiled kernel was warmed with (a type of its own)
        tris = np.ascontiguousarray(skin_triangles, dtype=np.int64)
        n = len(rest)
        self.rest = rest
        self.triangles = tris
        frames = _local_frames(rest[tris])
        self._rest_frames = frames
        det = frames[:, 0, 0] * frames[:, 1, 1]
        area = 0.5 * np.abs(det)
        # Checked: not slivers, which have no direction (as core.mesh_quality counts them), and (below)
        # within reach of a vertex the guard may move.
        self._checked = area > 1e-6 * max(float(np.median(area)) if len(area) else 0.0, _EPS)
        safe = np.abs(det) > _EPS
        # The rest frames' inverses (upper triangular: a, b; 0, d), for the compiled strain kernel.
        self._inv = np.zeros((len(tris), 3))
        self._inv[safe, 0] = 1.0 / frames[safe, 0, 0]
        self._inv[safe, 1] = -frames[safe, 0, 1] / det[safe]
        self._inv[safe, 2] = 1.0 / frames[safe, 1, 1]
        self._rest_normals = np.ascontiguousarray(_normals(rest[tris]))
        joined = np.zeros((0, 2), np.int64) if joined is None else np.asarray(joined, np.int64).reshape(-1, 2)
        # The smoothing's vertex of each vertex: a joined copy's original (the copy has no neighbours of
        # its own, is held, and takes its original's position after the smoothing).
        self._joined = joined
        self._smoothed_as = np.arange(n)
        self._smoothed_as[joined[:, 0]] = joined[:, 1]
        graph_tris = self._smoothed_as[tris]
        edges = np.concatenate([graph_tris[:, [0, 1]], graph_tris[:, [1, 2]], graph_tris[:, [2, 0]]])
        edges = edges[edges[:, 0] != edges[:, 1]]
        length = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
        weight = scipy.sparse.coo_matrix((1.0 / np.maximum(length, 1e-6), (edges[:, 0], edges[:, 1])),
                                         shape=(n, n)).tocsr()
        weight = weight.maximum(weight.T).tocsr()
        weight.sort_indices()
        degree = np.asarray(weight.sum(axis=1)).ravel()
        held = np.asarray(held, bool) | (degree == 0)
        self._held = held
        self._weights = np.ascontiguousarray(weight.data, dtype=float)
        # P: each free vertex takes its neighbours' weighted mean; held ones keep their own value.
        average = scipy.sparse.diags(np.where(held, 0.0, 1.0 / np.maximum(degree, _EPS))) @ weight
        self._average = (average + scipy.sparse.diags(held.astype(float))).tocsr()
        self._indptr, self._indices = weight.indptr.astype(np.int64), weight.indices.astype(np.int64)
        # 0 on held vertices, rising by 1 / (HOLD_TAPER_RINGS + 1) a ring to 1.
        self._taper = np.where(held, 0.0, 1.0)
        for k, ring in enumerate(self._rings(np.flatnonzero(held), HOLD_TAPER_RINGS), start=1):
            self._taper[ring] = k / (HOLD_TAPER_RINGS + 1)
        # Triangles farther than RINGS rings inside the held vertices cannot reach a vertex the guard
        # moves: not checked (few on a face, whose held vertices are the lid margins: a test grid's held
        # patch, or a caller that holds a whole region, skips its inside).
        reach = np.zeros(n, bool)
        reach[self._ring(np.flatnonzero(self._taper > 0), RINGS)] = True
        self._checked &= reach[graph_tris].any(axis=1)
        self._balls = tuple((np.asarray(skin, np.int64), np.asarray(centre, float), np.asarray(anchors, np.int64))
                            for skin, centre, anchors in balls)
        welded = welded_vertices(rest)
        copies = np.flatnonzero(welded != np.arange(n))
        self._copies, self._originals = copies, welded[copies]
        # The last pose and result of each check, by region name (None: every triangle): the finish
        # step checks the whole skin, then the mouth again after the teeth.
        self._last: dict = {}

    @staticmethod
    def _forgotten() -> tuple[np.ndarray, np.ndarray]:
        """No last pose: the compiled check measures every triangle (its last result read-only, as
        every later one: one compiled signature)."""
        out = np.zeros(0)
        out.setflags(write=False)
        return np.zeros((0, 3)), out

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_last": {}}     # a cached guard starts afresh

    def _rows(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(neighbours of the vertices ``idx``, concatenated; where each one's list starts in it)."""
        starts, ends = self._indptr[idx], self._indptr[idx + 1]
        lengths = ends - starts
        offsets = np.cumsum(lengths) - lengths
        flat = np.repeat(starts - offsets, lengths) + np.arange(int(lengths.sum()))
        return self._indices[flat], offsets

    def _rings(self, idx: np.ndarray, rings: int):
        """Yield the vertices 1, 2, ... ``rings`` rings from ``idx`` (n,) int, ring by ring (breadth first)."""
        inside = np.zeros(len(self.rest), bool)
        inside[idx] = True
        frontier = idx
        for _ in range(rings):
            neighbours = self._rows(frontier)[0]
            frontier = np.unique(neighbours[~inside[neighbours]])
            inside[frontier] = True
            yield frontier

    def _ring(self, idx: np.ndarray, rings: int) -> np.ndarray:
        """Sorted vertex indices within ``rings`` rings of ``idx``."""
        return np.unique(np.concatenate([np.asarray(idx, np.int64), *self._rings(idx, rings)]))

    # ------------------------------------------------------------------ per tick
    def severity(self, x: np.ndarray, region: GuardRegion | None = None) -> np.ndarray:
        """(T,) 0..1 (read-only) how close each skin triangle of the pose ``x`` (n, 3) is to breaking
        (0 where none of its corners moved, and outside ``region`` when given). Compiled, only the
        triangles around vertices that changed since the last call for that region are measured again
        (a slider moves one region: joy with a brow slider, ~4 ms -> ~1 ms); the last pose and its
        result are one tuple, replaced at once, so two threads that share the guard (the window and
        an export) never mix them."""
        if region is None:
            return self._measure(x, None)
        out = np.zeros(len(self.triangles))
        out[region.triangles] = self._measure(x, region)
        return out

    def _measure(self, x: np.ndarray, region: GuardRegion | None) -> np.ndarray:
        """The severity of ``region``'s triangles (t,) (every triangle's (T,) when None)."""
        if region is None:
            tris, inverses, normals, checked = self.triangles, self._inv, self._rest_normals, self._checked
        else:
            tris, inverses, normals, checked = region.corners, region.inverses, region.normals, region.checked
        compiled = kernels.get()
        if compiled is not None and x.dtype == np.float64 and x.flags.c_contiguous:
            slot = None if region is None else region.name
            last_x, last_out = self._last.get(slot) or self._forgotten()
            out = np.empty(len(tris))
            compiled.strain_severity(x, self.rest, tris, inverses, normals, checked,
                                     STRETCH_RAMP[0], STRETCH_RAMP[1], SQUEEZE_RAMP[0], SQUEEZE_RAMP[1],
                                     TURN_RAMP[0], TURN_RAMP[1], last_x, last_out, out)
            out.setflags(write=False)          # kept as the next call's last result: no copy a tick
            self._last[slot] = (np.array(x), out)
            return out
        out = np.zeros(len(tris))
        moved = (x != self.rest).any(axis=1)
        some = np.flatnonzero(moved[tris].any(axis=1) & checked)
        if not len(some):
            return out
        frames = self._rest_frames[some if region is None else region.triangles[some]]
        corners = x[tris[some]]
        big, small = principal_stretches(frames, corners)
        turn = np.einsum("ij,ij->i", _normals(corners), normals[some])
        out[some] = np.maximum.reduce([_ramp(big, STRETCH_RAMP), _ramp(small, SQUEEZE_RAMP), _ramp(turn, TURN_RAMP)])
        return out

    def region(self, name: str, vertices: np.ndarray) -> GuardRegion:
        """The region ``name`` of :meth:`apply`: the skin triangles with a corner among ``vertices``
        (k,) int."""
        mask = np.zeros(len(self.rest), bool)
        mask[np.asarray(vertices, np.int64)] = True
        tris = np.flatnonzero(mask[self.triangles].any(axis=1))
        return GuardRegion(name, tris, *(np.ascontiguousarray(a[tris]) for a in (
            self.triangles, self._inv, self._rest_normals, self._checked)))

    def footprint(self, region: GuardRegion) -> tuple[np.ndarray, np.ndarray]:
        """(reads, writes): sorted vertex indices :meth:`apply` with ``region`` may read and move (for
        a ``StepMemo``): the smoothing moves vertices within ``RINGS`` rings of the region's corners
        (with their seam partners) and reads ``SMOOTHING_STEPS`` rings past those, and the eyeballs'
        anchors."""
        corners = self._smoothed_as[np.unique(region.corners)]
        moved = self._with_partners(self._ring(corners, RINGS))
        anchors = [anchors for _skin, _centre, anchors in self._balls]
        reads = np.unique(np.concatenate([self._ring(self._smoothed_as[moved], SMOOTHING_STEPS), moved, *anchors]))
        return self._with_partners(reads), moved

    def _with_partners(self, idx: np.ndarray) -> np.ndarray:
        """Sorted ``idx`` with every vertex at one rest position with one of them (seam copies, the
        joined ones among them: :meth:`apply` puts them together)."""
        inside = np.zeros(len(self.rest), bool)
        inside[idx] = True
        inside[self._originals[inside[self._copies]]] = True
        inside[self._copies[inside[self._originals]]] = True
        return np.flatnonzero(inside)

    def apply(self, x: np.ndarray, pinned: np.ndarray | None = None, region: GuardRegion | None = None) -> bool:
        """Smooth the pose ``x`` (n, 3) in place where it would break; False (and ``x`` untouched)
        where every triangle holds. ``pinned`` ((k,) int): vertices another layer places exactly (a
        dragged control point), held for this pose (the smoothing around them takes their motion in).
        ``region`` (:meth:`region`): only its triangles' strain is smoothed (the smoothing still reaches
        ``RINGS`` rings past them)."""
        severity = self._measure(x, region)
        some = np.flatnonzero(severity > 0)
        if not len(some):
            return False
        severity = severity[some]
        breaking = some if region is None else region.triangles[some]
        strength = np.zeros(len(x))
        np.maximum.at(strength, self._smoothed_as[self.triangles[breaking].ravel()], np.repeat(severity, 3))
        held, taper = self._held, self._taper
        if pinned is not None and len(pinned):
            pinned = self._smoothed_as[np.asarray(pinned, np.int64)]
            held, taper = held.copy(), taper.copy()
            held[pinned], taper[pinned] = True, 0.0
        before = x[self._copies] == x[self._originals]
        copy, original = self._joined.T
        follows = (x[copy] == x[original]).all(axis=1)
        on_ball = [(skin, x[skin]) for skin, _centre, _anchors in self._balls]
        compiled = kernels.get()
        if compiled is not None and x.dtype == np.float64 and x.flags.c_contiguous:
            if not compiled.guard_smooth(x, self.rest, self._indptr, self._indices, self._weights, held,
                                         taper, strength, RINGS, SMOOTHING_STEPS):
                return False
        elif not self._smooth(x, strength, held, taper):
            return False
        for (skin, centre, anchors), (_skin, was) in zip(self._balls, on_ball):
            self._back_on_ball(x, skin, was, centre + (x[anchors] - self.rest[anchors]).mean(axis=0))
        x[copy[follows]] = x[original[follows]]
        together = before.all(axis=1)
        if together.any():
            a, b = self._copies[together], self._originals[together]
            mean = 0.5 * (x[a] + x[b])
            x[a], x[b] = mean, mean
        return True

    @staticmethod
    def _back_on_ball(x: np.ndarray, skin: np.ndarray, was: np.ndarray, centre: np.ndarray) -> None:
        """Put the vertices ``skin`` of ``x`` that the smoothing moved back at the distance from
        ``centre`` (3,) they had before it (``was`` (k, 3)), in their new direction from it."""
        moved = np.flatnonzero((x[skin] != was).any(axis=1))
        if not len(moved):
            return
        idx = skin[moved]
        direction = x[idx] - centre
        length = np.linalg.norm(direction, axis=1)
        radius = np.linalg.norm(was[moved] - centre, axis=1)
        x[idx] = centre + direction * (radius / np.maximum(length, _EPS))[:, None]

    def _smooth(self, x: np.ndarray, strength: np.ndarray, held: np.ndarray, taper: np.ndarray) -> bool:
        """The numpy path of the smoothing (``compiled_steps.guard_smooth``): ``strength`` (n,) the
        per-vertex severity, ``held`` and ``taper`` (n,) this pose's; False where nothing moved."""
        # Spread over RINGS rings, falling off linearly: a_v = max(a_v, max of its neighbours - step).
        idx = self._ring(np.flatnonzero(strength), RINGS)
        neighbours, starts = self._rows(idx)      # every skin vertex has neighbours: no empty row
        step = 1.0 / (RINGS + 1)
        for _ in range(RINGS):
            strength[idx] = np.maximum(strength[idx], np.maximum.reduceat(strength[neighbours], starts) - step)
        strength *= taper
        idx = idx[strength[idx] > 0]
        if not len(idx):
            return False
        # (P^k u) at idx needs u up to k rings out: iterate on that support, from u (exact at idx).
        support = self._ring(idx, SMOOTHING_STEPS)
        u = x - self.rest
        smooth = u.copy()
        average = self._average[support]
        pinned = np.flatnonzero(held & ~self._held)
        for _ in range(SMOOTHING_STEPS):
            smooth[support] = average @ smooth
            smooth[pinned] = u[pinned]             # held for this pose: keep their own motion
        x[idx] += strength[idx, None] * (smooth[idx] - u[idx])
        return True
