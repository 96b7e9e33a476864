"""Lips that press on each other instead of passing through.

At rest a closed mouth's inner lip rims touch. A FAP that raises the lower lip (5 raise_b_midlip,
10/11, 52, 57/58) or lowers the upper one (4, 8/9, 51, 55/56) alone, or a mix of presets, moves a
rim past the other and the lips cut through each other. :class:`LipContact` is the lips' version of
the lids' contact: after all offsets, wherever the lower rim is above the upper rim, both lips give
way by half of the overlap each, the upper lip up and the lower lip down, fading with the distance
from the rim, so the rims meet and the lips bulge a little, as pressed lips do.

The rims are one line each; the lips' surfaces beside them can still pass through each other (an
upper lip lowered 800 MNS onto a closed mouth: rims met, but its front slid 0.1-1 mm into the lower
lip's, 176 crossing triangle pairs). So the contact then compares the lips as sheets over the (x, z)
plane: in each cell of a grid (``SHEET_CELL_EDGES`` x the lips' median edge), an upper-lip vertex
below the lower lip's highest vertex there, or a lower-lip vertex above the upper lip's lowest, has
crossed by that much (beyond what the rest face has); each lip gives way by half of it, spread to its
neighbours with a Gaussian of ``SHEET_WIDTH_MM`` (the largest share wins), for a few rounds, fading
out next to the mouth corners as the rims' contact does.

The rims are the skin's boundary vertices along the mouth opening (the side of each from its own
triangles, ``core.layers.fap.template.mouth_side``); "up" is the face's +y and the rims are
compared along x, as the FAP tables assume.
"""

from __future__ import annotations

import numpy as np

from core.face import Face
from core.layers.fap import kernels
from core.layers.fap.template import mouth_side

# How far from its rim a lip gives way (mm): a Gaussian of this width, about half a lip's height.
GIVE_WIDTH_MM = 4.0
# Beyond this from the rim (mm) nothing moves (the Gaussian is below 0.2 % there).
GIVE_REACH_MM = 10.0
# A rim needs this many vertices to be a lip line.
MIN_RIM_VERTICES = 4
# Next to a mouth corner the overlap fades to nothing over this distance along the mouth (mm).
CORNER_TAPER_MM = 3.0
# Overlaps below this (mm) are rounding, not lips passing through each other.
TOLERANCE_MM = 1e-6
# A pose that presses the rims this much (mm) past their rest overlap (a scan's lips crossing at rest)
# takes that rest overlap away too; less, the same share of it.
REST_RELEASE_MM = 0.25
# Pressed rims end this far apart (mm), not exactly touching: rims on one line leave the triangles
# either side of them cutting through each other wherever the lips' Gaussian give-way differs.
SEPARATION_MM = 0.05
# The sheet test's grid cell, in median edge lengths of the lips: a cell must hold vertices of both
# lips where they cross (default face: 1.5 edges = 1.3 mm; 0.75 mm cells left 124 of 176 crossing
# pairs of FAP 4 at 800, 1.25 mm none).
SHEET_CELL_EDGES = 1.5
# How far a sheet's give-way spreads (mm, Gaussian width; cut at twice that), and its rounds.
SHEET_WIDTH_MM = 2.5
SHEET_ROUNDS = 3
# Sheet overlaps below this (mm) are the cell test's own imprecision where the lips converge at a
# corner (0.005 mm with the jaw open 200 MNS and no triangle crossing), not lips passing through each other.
SHEET_TOLERANCE_MM = 0.02
# Next to a mouth corner the sheets' give-way fades to nothing over this distance along the mouth (mm).
SHEET_TAPER_MM = 1.5
# The sheet grid covers the lips at rest and this much around them (mm): where any FAP can take them.
SHEET_MARGIN_MM = 40.0


class LipContact:
    """The contact of the upper and lower lip of one face (no-op when the face has no mouth rims).

    face : the rest face; skin : (k,) indices of its skin vertices (not in a part).
    """

    def __init__(self, face: Face, skin: np.ndarray):
        from core.subdivision import boundary_edges

        self.active = False
        side = np.zeros(face.n_vertices, np.int64)
        side[skin] = mouth_side(face, skin)
        if not side.any():
            return
        on_rim = np.zeros(face.n_vertices, bool)
        on_rim[boundary_edges(face.triangles).ravel()] = True
        y_line = _lip_line(face)
        x, y = face.vertices[:, 0], face.vertices[:, 1]
        near_line = np.abs(y - np.interp(x, *y_line)) < 3.0
        self.upper_rim = np.flatnonzero(on_rim & near_line & (side == 1))
        self.lower_rim = np.flatnonzero(on_rim & near_line & (side == -1))
        if min(len(self.upper_rim), len(self.lower_rim)) < MIN_RIM_VERTICES:
            return
        self.upper, self.upper_weight = _zone(face.vertices, side == 1, self.upper_rim)
        self.lower, self.lower_weight = _zone(face.vertices, side == -1, self.lower_rim)
        # What overlap the rest face has (two polylines of different vertices touch only roughly):
        # only what a pose adds to it is resolved, so the rest face stays exactly as it is.
        self.rest_excess = np.maximum(self._overlap(face.vertices), 0.0)
        self.rest_overlap = self.rest_excess + TOLERANCE_MM
        lips = np.union1d(self.upper, self.lower)
        self.cell = SHEET_CELL_EDGES * _median_edge(face, lips)
        low, high = face.vertices[lips][:, [0, 2]].min(axis=0), face.vertices[lips][:, [0, 2]].max(axis=0)
        self._origin = low - SHEET_MARGIN_MM
        self._grid = tuple(int(n) for n in np.ceil((high - low + 2 * SHEET_MARGIN_MM) / self.cell) + 1)
        self.rest_sheet = tuple(np.maximum(o, 0.0) + TOLERANCE_MM for o in self._sheet_overlap(face.vertices))
        self.neighbours = (_neighbours(face.vertices[self.upper]), _neighbours(face.vertices[self.lower]))
        # Next to the mouth corners the lips converge into one column of cells, and a corner raised by
        # any layer (a control point, a muscle) rises above the other lip's cell there: the sheets'
        # give-way fades out toward the corners, as the rims' does, so a dragged corner lands where
        # it is dragged (a corner FAP keeps 3 crossing pairs at the corner itself).
        ends = np.sort(face.vertices[self.upper_rim, 0])[[0, -1]]
        self.sheet_taper = tuple(_corner_taper(face.vertices[ids, 0], ends, SHEET_TAPER_MM)
                                 for ids in (self.upper, self.lower))
        self.active = True

    def zone(self, n_vertices: int) -> np.ndarray:
        """(n_vertices,) bool: the vertices the contact may move (both lips near their rims)."""
        mask = np.zeros(n_vertices, bool)
        if self.active:
            mask[self.upper] = mask[self.lower] = True
        return mask

    def _overlap(self, x: np.ndarray) -> np.ndarray:
        """(len(lower_rim),) mm: how far each lower-rim vertex is above the upper rim at its x, tapered
        to nothing over the CORNER_TAPER_MM next to each mouth corner (there the rims meet and part
        again, and a corner raised by any layer lifts both: not lips pressed into each other);
        -inf beyond the upper rim's ends."""
        compiled = kernels.get()
        if compiled is not None and x.dtype == np.float64:
            out = np.empty(len(self.lower_rim))
            compiled.lip_overlap(x, self.upper_rim, self.lower_rim, CORNER_TAPER_MM, out)
            return out
        upper = x[self.upper_rim]
        # Stable, as the compiled path: a cut lip's copied vertices share an x, and the order of ties
        # decides which of them the interpolation reads.
        order = np.argsort(upper[:, 0], kind="stable")
        ends = upper[order[[0, -1]], 0]
        lower = x[self.lower_rim]
        above = lower[:, 1] - np.interp(lower[:, 0], upper[order, 0], upper[order, 1], left=np.inf, right=np.inf)
        taper = _corner_taper(lower[:, 0], ends, CORNER_TAPER_MM)
        inside = np.isfinite(above)
        return np.where(inside, np.where(inside, above, 0.0) * taper, -np.inf)

    def apply(self, x: np.ndarray) -> None:
        """Resolve the lips' overlap in ``x`` (n, 3) mm, in place: the rims, then the lips' sheets."""
        if not self.active:
            return
        self._press_rims(x)
        self._press_sheets(x)

    def _press_rims(self, x: np.ndarray) -> None:
        """Where the lower rim is above the upper one, both lips give way by half, in ``x`` in place."""
        overlap = self._overlap(x)
        pressed = overlap > self.rest_overlap
        if not pressed.any():
            return                      # the common case: lips apart or just touching
        lower = x[self.lower_rim]
        # Where a pose pressed the lips into each other, all of the overlap goes and the rims end
        # SEPARATION_MM apart (a rest-sized sliver left would still cut the seam's triangles through each
        # other). A scan's lips may cross at rest: their rest overlap goes by the share the pose's own
        # press is of REST_RELEASE_MM (all of it at once made them jump apart at a slider's first touch:
        # the Surrey Face Model scan, 0.35 mm at 239 vertices for raise_cornerlip 0.001; kept instead,
        # its lips crossed at lower_t_midlip's and shift_jaw's ends, 6-7 pairs; released over 1 mm,
        # 1-2 pairs; over 0.25 mm, lower_t_midlip's 1 pair).
        added = overlap - self.rest_excess
        release = np.clip(added / REST_RELEASE_MM, 0.0, 1.0)
        order = np.argsort(lower[:, 0])
        along = lower[order, 0]
        depth = np.where(pressed, added + release * self.rest_excess + SEPARATION_MM, 0.0)[order]
        half_up = 0.5 * np.interp(x[self.upper, 0], along, depth, left=0.0, right=0.0) * self.upper_weight
        half_down = 0.5 * np.interp(x[self.lower, 0], along, depth, left=0.0, right=0.0) * self.lower_weight
        x[self.upper, 1] += half_up
        x[self.lower, 1] -= half_down

    def _sheet_overlap(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((len(upper),), (len(lower),)) mm: how far each upper-lip vertex is below the lower lip's
        highest vertex in its (x, z) cell, and each lower-lip vertex above the upper lip's lowest
        (-inf where the other lip has no vertex in the cell)."""
        compiled = kernels.get()
        if compiled is not None and x.dtype == np.float64:
            below, above = np.empty(len(self.upper)), np.empty(len(self.lower))
            compiled.lip_sheet_overlap(x, self.upper, self.lower, float(self._origin[0]), float(self._origin[1]),
                                       float(self.cell), self._grid[0], self._grid[1], below, above)
            return below, above
        up, low = x[self.upper], x[self.lower]
        cell_up, cell_low = self._cells(up), self._cells(low)
        top = np.full(self._grid[0] * self._grid[1], -np.inf)
        np.maximum.at(top, cell_low, low[:, 1])
        bottom = np.full(len(top), np.inf)
        np.minimum.at(bottom, cell_up, up[:, 1])
        return top[cell_up] - up[:, 1], low[:, 1] - bottom[cell_low]

    def _cells(self, points: np.ndarray) -> np.ndarray:
        """(k,) the grid cell of each of ``points`` (k, 3) mm by x and z (a fixed grid around the lips
        at rest with SHEET_MARGIN_MM to spare; points beyond it share its edge cells)."""
        ix = ((points[:, 0] - self._origin[0]) / self.cell).astype(np.int64)
        iz = ((points[:, 2] - self._origin[1]) / self.cell).astype(np.int64)
        # In place (np.clip's call overhead was most of this; the numpy path runs when numba has not loaded).
        np.minimum(np.maximum(ix, 0, out=ix), self._grid[0] - 1, out=ix)
        np.minimum(np.maximum(iz, 0, out=iz), self._grid[1] - 1, out=iz)
        ix *= self._grid[1]
        ix += iz
        return ix

    def _press_sheets(self, x: np.ndarray) -> None:
        """Where a lip's vertex went into the other lip (:meth:`_sheet_overlap`), both give way, in place."""
        for _ in range(SHEET_ROUNDS):
            below, above = self._sheet_overlap(x)
            depth_up, depth_low = below - self.rest_sheet[0], above - self.rest_sheet[1]
            taper_up, taper_low = self.sheet_taper
            depth_up = np.where(depth_up > SHEET_TOLERANCE_MM, depth_up, 0.0) * taper_up
            depth_low = np.where(depth_low > SHEET_TOLERANCE_MM, depth_low, 0.0) * taper_low
            if not ((depth_up > 0).any() or (depth_low > 0).any()):
                return                  # the common case: no lip vertex inside the other lip
            x[self.upper, 1] += _spread(self.neighbours[0], depth_up) * taper_up
            x[self.lower, 1] -= _spread(self.neighbours[1], depth_low) * taper_low


def _neighbours(rest: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr (k+1,), indices, falloff): for each of a lip's vertices (``rest`` (k, 3) mm), the lip's
    vertices within 2 x SHEET_WIDTH_MM of it and their Gaussian falloff exp(-(d / SHEET_WIDTH_MM)^2):
    built once, so a tick that presses the lips does not build a search tree."""
    from scipy.spatial import cKDTree

    near = cKDTree(rest).query_ball_point(rest, 2.0 * SHEET_WIDTH_MM)
    counts = np.fromiter((len(n) for n in near), np.int64, len(near))
    indices = np.concatenate(near).astype(np.int64) if len(near) else np.zeros(0, np.int64)
    source = np.repeat(np.arange(len(rest)), counts)
    falloff = np.exp(-(np.linalg.norm(rest[indices] - rest[source], axis=1) / SHEET_WIDTH_MM) ** 2)
    return np.concatenate([[0], np.cumsum(counts)]), indices, falloff


def _spread(neighbours, depth: np.ndarray) -> np.ndarray:
    """(k,) mm each vertex of a lip gives way: half of each crossing vertex's ``depth`` (k,) mm (and
    SEPARATION_MM) at that vertex, falling off over its ``neighbours`` (:func:`_neighbours`) as a
    Gaussian, the largest wins (a sum would double where crossings are dense)."""
    indptr, indices, falloff = neighbours
    out = np.zeros(len(depth))
    compiled = kernels.get()
    if compiled is not None:
        compiled.lip_sheet_spread(indptr, indices, falloff, depth, SEPARATION_MM, out)
        return out
    crossing = np.flatnonzero(depth > 0)
    if not len(crossing):
        return out
    starts, counts = indptr[crossing], indptr[crossing + 1] - indptr[crossing]
    # Every neighbour entry of every crossing vertex, without a Python loop over them.
    entries = np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts) + np.arange(counts.sum())
    give = np.repeat(0.5 * depth[crossing] + SEPARATION_MM, counts) * falloff[entries]
    np.maximum.at(out, indices[entries], give)
    return out


def _corner_taper(x: np.ndarray, ends: np.ndarray, width_mm: float) -> np.ndarray:
    """(k,) in [0, 1]: 0 at or beyond the mouth's corner x ``ends`` (2,) mm, rising linearly to 1 over
    ``width_mm`` inside them, for x (k,) mm."""
    return np.clip(np.minimum(x - ends[0], ends[1] - x) / width_mm, 0.0, 1.0)


def _median_edge(face: Face, ids: np.ndarray) -> float:
    """Median length (mm) of the edges of ``face``'s triangles with all corners in ``ids``."""
    inside = np.zeros(face.n_vertices, bool)
    inside[ids] = True
    t = face.triangles[inside[face.triangles].all(axis=1)]
    if not len(t):
        return 1.0
    edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    return float(np.median(np.linalg.norm(face.vertices[edges[:, 0]] - face.vertices[edges[:, 1]], axis=1)))


def _lip_line(face: Face) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the line between the lips at rest: midway between the inner-lip points, by x."""
    up = np.array([face.landmark_position(p) for p in ("2.5", "2.7", "2.2", "2.6", "2.4")])
    lo = np.array([face.landmark_position(p) for p in ("2.5", "2.9", "2.3", "2.8", "2.4")])
    line = (up + lo) / 2
    order = np.argsort(line[:, 0])
    return line[order, 0], line[order, 1]


def _zone(vertices: np.ndarray, lip: np.ndarray, rim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ids, weights): the ``lip`` vertices within GIVE_REACH_MM of the ``rim``, and how much each
    gives way (1 on the rim, a Gaussian of the distance)."""
    from scipy.spatial import cKDTree   # here, not at module level: ~0.3 s of the window's start-up

    ids = np.flatnonzero(lip)
    distance, _ = cKDTree(vertices[rim]).query(vertices[ids], distance_upper_bound=GIVE_REACH_MM)
    near = np.isfinite(distance)
    ids, distance = ids[near], distance[near]
    return ids, np.exp(-(distance / GIVE_WIDTH_MM) ** 2)


__all__ = ["LipContact"]
