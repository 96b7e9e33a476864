"""Keep the mouth's skin outside the teeth, whatever moves it.

The teeth move rigidly (the upper row with the skull, the lower row with the jaw: FAPs 3/14/15 or
the muscle layer's mandible) while the skin around the mouth follows only a fraction of that
motion, and some lip FAPs (stretch_cornerlip at -400, push_t_lip at -600) drive the skin straight
into the dental arch. :class:`TeethGuard` pushes any guarded skin vertex that ends inside a row's
outer hull back out onto it (plus a small clearance), as the lid guard keeps lids over the eyeballs.

Each row's hull is a table of its outer radius in cylindrical coordinates about a vertical axis
behind the arch: r_max(angle in the horizontal plane, height y). Radial pushes leave the skin's
height alone and point forward at the incisors and sideways at the molars, along the arch's normal.
The lower row's current place comes from its vertices (a rigid fit of a few anchors), so the guard
follows whatever layer moved the jaw.

A tick looks up the table (its arctan2 is the dearest step) only for skin that can have entered a
row: each guarded vertex keeps its rest slack (its distance from the region the guard pushes out of,
in the row's frame), and a vertex that moved less than that relative to the row cannot be inside it.
The result is exactly the unfiltered guard's (``apply(x, slack_filter=False)``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse

from core.layers.fap import kernels

# Skin stays this far outside the teeth (mm) once pushed: more than the chord sag of a 2 mm skin
# triangle over a 20 mm-radius arch (0.03 mm), less than the default face's own 2 mm rest gap.
TEETH_CLEARANCE_MM = 0.5
ANGLE_STEP_DEG = 2.0
HEIGHT_STEP_MM = 0.5
HULL_MARGIN_MM = 1.0
# Skin farther than this from a row's teeth at rest (mm) is never guarded (cheeks, nose, chin).
GUARD_REACH_MM = 12.0
# Rings of neighbour averaging that spread a push over the skin around it (a bulge, not a step:
# a vertex pushed millimetres out next to one left in place folds their triangles).
SPREAD_RINGS = 3
N_ANCHORS = 12
# Taken off each rest slack (mm): covers rounding in the per-tick cell lookup, so the filter only
# ever lets through more vertices than strictly needed, never fewer.
SLACK_MARGIN_MM = 1e-4


class TeethRowHull:
    """One row of teeth as a table of outer radii r_max(angle, y) about a vertical axis.

    centre : (3,) mm, a point on the axis (behind the arch, level with the row).
    radii : (a, h) mm, outer radius per angle bin (from +z toward +x) and height bin; -inf where
        the row has no tooth (there the skin is free).
    """

    def __init__(self, points: np.ndarray):
        lo, hi = points.min(axis=0), points.max(axis=0)
        # On the arch's symmetry line, at its back: every tooth lies within +-90 degrees of +z.
        self.centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
        # A margin of bins above and below the row (filled by the widening below): a skin triangle
        # whose corners sit just past a tooth's edge still spans that edge.
        self.y0 = lo[1] - HULL_MARGIN_MM
        self.n_heights = int(np.ceil((hi[1] - lo[1] + 2 * HULL_MARGIN_MM) / HEIGHT_STEP_MM)) + 1
        self.n_angles = int(round(360.0 / ANGLE_STEP_DEG))
        self.height = self.n_heights * HEIGHT_STEP_MM
        dx, dz, height = points[:, 0] - self.centre[0], points[:, 2] - self.centre[2], points[:, 1] - self.y0
        inside = (height >= 0) & (height < self.height)
        table = np.full(self.n_angles * self.n_heights, -np.inf)
        np.maximum.at(table, self.cells(dx[inside], dz[inside], height[inside]),
                      np.hypot(dx[inside], dz[inside]))
        table = table.reshape(self.n_angles, self.n_heights)
        # Widen by one angle bin and the margin's height bins each way: a nearest-bin lookup then
        # never sees a radius below the surface between samples, and the hull covers each tooth's edge.
        reach = int(np.ceil(HULL_MARGIN_MM / HEIGHT_STEP_MM))
        wide = table.copy()
        for shift_a in (-1, 0, 1):
            for shift_h in range(-reach, reach + 1):
                # The table's margins are -inf, so rolling never wraps a tooth around.
                wide = np.maximum(wide, np.roll(np.roll(table, shift_a, axis=0), shift_h, axis=1))
        self.radii = wide
        self._flat = wide.ravel()
        # Beyond this distance from the axis no point can be inside the hull (clearance included).
        self.reach_squared = (float(wide[np.isfinite(wide)].max()) + TEETH_CLEARANCE_MM) ** 2

    def cells(self, dx: np.ndarray, dz: np.ndarray, height: np.ndarray) -> np.ndarray:
        """Flat table index of points at (dx, dz) from the axis and ``height`` (>= 0, < self.height)
        above the table's bottom (mm). Written for few numpy calls: it runs every tick."""
        a = ((np.arctan2(dx, dz) + np.pi) * (1.0 / np.radians(ANGLE_STEP_DEG))).astype(np.int64) % self.n_angles
        return a * self.n_heights + (height * (1.0 / HEIGHT_STEP_MM)).astype(np.int64)

    def outer_radius(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(radius now, hull radius (-inf off the row), dx, dz) of points (k, 3) in the row's frame."""
        dx, dz, height = points[:, 0] - self.centre[0], points[:, 2] - self.centre[2], points[:, 1] - self.y0
        inside = (height >= 0) & (height < self.height)
        hull = np.full(len(points), -np.inf)
        hull[inside] = self._flat[self.cells(dx[inside], dz[inside], height[inside])]
        return np.hypot(dx, dz), hull, dx, dz


    def distance_to_pushed_region(self, points: np.ndarray, clearance: np.ndarray) -> np.ndarray:
        """(k,) mm: a lower bound (exact up to rounding) on the distance of points (k, 3), given in the
        row's frame, from the region the guard pushes them out of: every table cell's wedge (its angle
        bin, its height bin, radius below the cell's radius + the point's ``clearance`` (k,) mm).

        A wedge is a 2-degree circular sector (convex) times a height interval: its squared distance
        is the squared distance to the sector in the horizontal plane (radial in the point's own
        angle bin, else to one of its two edge segments) plus that to the interval."""
        # Equal radii stacked in one angle bin are one wedge: fewer cells, the same region.
        finite = np.isfinite(self.radii)
        same_as_below = np.zeros_like(finite)
        same_as_below[:, 1:] = finite[:, :-1] & (self.radii[:, 1:] == self.radii[:, :-1])
        cell_a, first = np.nonzero(finite & ~same_as_below)
        if not len(cell_a):
            return np.full(len(points), np.inf)
        last = first.copy()
        for _ in range(self.n_heights):         # extend each wedge up its run of equal radii
            longer = (last + 1 < self.n_heights) & same_as_below[cell_a, np.minimum(last + 1, self.n_heights - 1)]
            if not longer.any():
                break
            last[longer] += 1
        wedge_radius = self.radii[cell_a, first]
        bottom, top = first * HEIGHT_STEP_MM, (last + 1) * HEIGHT_STEP_MM
        # Bin a holds angles atan2(dx, dz) in [a * step - pi, (a + 1) * step - pi) (see cells()):
        # its edges are edge a and edge a + 1.
        edge = np.arange(self.n_angles + 1) * np.radians(ANGLE_STEP_DEG) - np.pi
        edge_dx, edge_dz = np.sin(edge), np.cos(edge)
        out = np.empty(len(points))
        chunk = max(1, 2_000_000 // len(cell_a))
        for start in range(0, len(points), chunk):      # chunks of points bound the memory only
            p = points[start:start + chunk]
            dx, dz, height = p[:, 0] - self.centre[0], p[:, 2] - self.centre[2], p[:, 1] - self.y0
            own_bin = self.cells(dx, dz, np.zeros(len(p))) // self.n_heights
            along = dx[:, None] * edge_dx + dz[:, None] * edge_dz          # (m, edges) projections
            reach = np.maximum(wedge_radius + clearance[start:start + chunk, None], 0.0)      # (m, c)
            length_squared = (dx * dx + dz * dz)[:, None]
            horizontal = None
            for side in (cell_a, cell_a + 1):
                proj = along[:, side]
                t = np.clip(proj, 0.0, reach)          # nearest point of the edge segment
                squared = length_squared + t * (t - 2.0 * proj)
                horizontal = squared if horizontal is None else np.minimum(horizontal, squared)
            radial = np.maximum(np.sqrt(length_squared) - reach, 0.0)
            horizontal = np.where(cell_a == own_bin[:, None], radial * radial, horizontal)
            vertical = np.maximum(np.maximum(bottom - height[:, None], height[:, None] - top), 0.0)
            out[start:start + chunk] = np.sqrt(np.maximum(horizontal + vertical * vertical, 0.0).min(axis=1))
        return out


class GuardedRow(NamedTuple):
    """One row of teeth and the skin it guards.

    name : the face part ("teeth_upper" / "teeth_lower"); hull : its TeethRowHull (rest frame).
    skin : (k,) int guarded vertices; clearance : (k,) mm each keeps outside the hull.
    anchors : (N_ANCHORS,) int row vertices for the rigid fit; rest_anchors : (N_ANCHORS, 3) mm.
    rest : (k, 3) mm the guarded vertices at rest (the row's frame is the rest frame).
    slack_squared : (k,) mm^2 squared rest slack: a vertex that moved less than its slack relative to
        the row cannot be in the pushed region.
    slots : (k,) int each guarded vertex's place in ``TeethGuard.watched``.
    """

    name: str
    hull: "TeethRowHull"
    skin: np.ndarray
    clearance: np.ndarray
    anchors: np.ndarray
    rest_anchors: np.ndarray
    rest: np.ndarray
    slack_squared: np.ndarray
    slots: np.ndarray


def _sample_triangles(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Vertices plus points inside and on the edges of each triangle: the hull table sees the whole
    surface, not only its corners."""
    c = vertices[triangles]
    weights = np.array([[1, 1, 1], [2, 1, 1], [1, 2, 1], [1, 1, 2], [1, 1, 0], [0, 1, 1], [1, 0, 1]], float)
    weights /= weights.sum(axis=1, keepdims=True)
    inner = np.einsum("sj,tjk->tsk", weights, c).reshape(-1, 3)
    return np.concatenate([vertices[np.unique(triangles)], inner])


class TeethGuard:
    """Pushes guarded skin vertices out of the teeth (see the module docstring).

    Parameters
    ----------
    face : core.face.Face
        The rest face with parts ``teeth_upper`` and/or ``teeth_lower``.
    skin : (k,) int
        Candidate skin vertices (those an animation layer can move).
    """

    def __init__(self, face, skin: np.ndarray):
        self.rows: list[GuardedRow] = []
        from scipy.spatial import cKDTree   # here, not at module level: ~0.3 s of the window's start-up

        rest = face.vertices
        for name in ("teeth_upper", "teeth_lower"):
            idx = face.parts.get(name)
            if idx is None or len(idx) < 4:
                continue
            idx = np.asarray(idx)
            tris = face.triangles[np.isin(face.triangles, idx).all(axis=1)]
            hull = TeethRowHull(_sample_triangles(rest, tris) if len(tris) else rest[idx])
            radius, outer, _dx, _dz = hull.outer_radius(rest[skin])
            # Guard skin in front of the hull at rest, or beside/above/below it (it may move over
            # it), near enough to reach it; skin behind the hull at rest (inside the mouth) is not.
            gap = radius - outer
            near = cKDTree(rest[idx]).query(rest[skin], distance_upper_bound=GUARD_REACH_MM)[0] < np.inf
            guarded = near & (gap > 0)
            clearance = np.clip(np.where(np.isfinite(gap), gap, TEETH_CLEARANCE_MM), 0.0, TEETH_CLEARANCE_MM)
            # Anchors for the row's rigid fit: spread over the row (extreme points and evenly spaced).
            anchors = idx[np.linspace(0, len(idx) - 1, N_ANCHORS).astype(np.int64)]
            slack = np.maximum(hull.distance_to_pushed_region(rest[skin[guarded]], clearance[guarded])
                               - SLACK_MARGIN_MM, 0.0)
            self.rows.append(GuardedRow(name, hull, skin[guarded], clearance[guarded], anchors, rest[anchors],
                                        rest[skin[guarded]], slack * slack, np.zeros(0, np.int64)))
        # Every guarded vertex, and how a push at one spreads to the others: SPREAD_RINGS steps of
        # neighbour averaging (rows sum to 1), kept by column so a tick reads only the pushed ones.
        self.watched = np.unique(np.concatenate([row.skin for row in self.rows] or [np.zeros(0, np.int64)])
                                 ).astype(np.int64)
        self.rows = [row._replace(skin=row.skin.astype(np.int64),
                                  slots=np.searchsorted(self.watched, row.skin).astype(np.int64))
                     for row in self.rows]
        ring = face.adjacency[self.watched][:, self.watched].tocsr()
        ring.data[:] = 1.0
        ring = ring + scipy.sparse.identity(len(self.watched), format="csr")
        step = (scipy.sparse.diags(1.0 / np.asarray(ring.sum(axis=1)).ravel()) @ ring).tocsr()
        spread = scipy.sparse.identity(len(self.watched), format="csr")
        for _ in range(SPREAD_RINGS):
            spread = spread @ step
        spread = spread.tocsc()
        # int64 throughout: the compiled kernels have one signature.
        self._spread_indptr = spread.indptr.astype(np.int64)
        self._spread_indices = spread.indices.astype(np.int64)
        self._spread_data = spread.data

    def apply(self, x: np.ndarray, slack_filter: bool = True) -> np.ndarray:
        """``x`` (n, 3) mm with the guarded skin pushed out of each row of teeth where it is (in place);
        each push spreads to the skin around it, fading over ``SPREAD_RINGS`` rings.

        ``slack_filter=False`` tests every guarded vertex (the same result, slower: for tests).
        Compiled (``kernels``) where numba is available, else numpy."""
        compiled = kernels.get()
        if compiled is not None and x.dtype == np.float64:
            return self._apply_compiled(compiled, x, slack_filter)
        pushes = []
        for row in self.rows:
            hull, skin, clearance = row.hull, row.skin, row.clearance
            rotation, shift = _rigid_fit(row.rest_anchors, x[row.anchors])
            if rotation is None:
                # Still or shifted (the FAP jaw): the height band alone rules out most skin before
                # anything else is gathered.
                height = x[skin, 1] - (shift[1] + hull.y0)
                band = np.flatnonzero(np.abs(height - hull.height / 2) < hull.height / 2)
                local = np.take(x, skin[band], axis=0) - shift   # np.take: 4x a fancy index's speed
            else:   # turned (the muscle mandible): into the row's rest frame first
                local = (x[skin] - shift) @ rotation
                height = local[:, 1] - hull.y0
                band = np.flatnonzero(np.abs(height - hull.height / 2) < hull.height / 2)
                local = local[band]
            dx, dz = local[:, 0] - hull.centre[0], local[:, 2] - hull.centre[2]
            squared = dx * dx + dz * dz
            maybe_inside = squared < hull.reach_squared
            if slack_filter:
                # Only skin that moved, relative to the row, at least its rest slack can be inside
                # it: the rest skip the table lookup (its arctan2 is the guard's dearest step).
                offset = local - np.take(row.rest, band, axis=0)
                offset *= offset
                maybe_inside &= offset[:, 0] + offset[:, 1] + offset[:, 2] >= np.take(row.slack_squared, band)
            near = np.flatnonzero(maybe_inside)
            if not len(near):
                continue
            dx, dz = dx[near], dz[near]
            need = hull._flat[hull.cells(dx, dz, local[near, 1] - hull.y0)] + clearance[band[near]]
            radius = np.sqrt(squared[near])
            inside = radius < need
            if not inside.any():
                continue
            sel = near[inside]
            scale = need[inside] / np.maximum(radius[inside], 1e-9)
            moved = local[sel]
            moved[:, 0] = hull.centre[0] + dx[inside] * scale
            moved[:, 2] = hull.centre[2] + dz[inside] * scale
            moved = moved + shift if rotation is None else moved @ rotation.T + shift
            vertices = skin[band[sel]]
            pushes.append((vertices, moved - np.take(x, vertices, axis=0)))
            x[vertices] = moved
        if pushes:
            self._spread(x, pushes)
        return x

    def _apply_compiled(self, compiled, x: np.ndarray, slack_filter: bool) -> np.ndarray:
        """:meth:`apply` by the ``compiled`` kernels ``push_out_of_row`` and ``spread_pushes``."""
        slots, offsets = [], []
        for row in self.rows:
            hull = row.hull
            rotation, shift = _rigid_fit(row.rest_anchors, x[row.anchors])
            pushed = np.empty(len(row.skin), np.int64)
            pushes = np.empty((len(row.skin), 3))
            count = compiled.push_out_of_row(
                x, row.skin, row.rest, row.slack_squared, row.clearance,
                np.eye(3) if rotation is None else np.ascontiguousarray(rotation), np.asarray(shift, float),
                rotation is not None, hull.centre, float(hull.y0), float(hull.height), hull.n_angles,
                hull.n_heights, 1.0 / np.radians(ANGLE_STEP_DEG), 1.0 / HEIGHT_STEP_MM, hull._flat,
                float(hull.reach_squared), bool(slack_filter), pushed, pushes)
            if count:
                slots.append(row.slots[pushed[:count]])
                offsets.append(pushes[:count])
        if slots:
            compiled.spread_pushes(x, self.watched, np.concatenate(slots), np.concatenate(offsets),
                                  self._spread_indptr, self._spread_indices, self._spread_data)
        return x

    def _spread(self, x: np.ndarray, pushes) -> None:
        """Let the skin around pushed vertices follow their pushes part way, fading over
        ``SPREAD_RINGS`` rings (in place). A pushed vertex takes the others' spread on top of its own
        push (not its own push again): as its push falls to 0 it moves as an unpushed one. (Kept at its
        own push alone, a vertex just touching the hull lost its neighbours' spread: 0.024 mm jumps.)"""
        n = len(self.watched)
        total = np.zeros((n, 3))
        pushed = np.zeros(n, dtype=bool)
        for vertices, offsets in pushes:    # a row pushes a vertex once; one both rows pushed has both pushes
            slots = np.searchsorted(self.watched, vertices)
            total[slots] += offsets
            pushed[slots] = True
        slot = np.flatnonzero(pushed)
        total = total[slot]
        # The pushed columns of the spread matrix, read straight from its CSC arrays (scipy's column
        # slicing costs more than the whole guard).
        starts, lengths = self._spread_indptr[slot], self._spread_indptr[slot + 1] - self._spread_indptr[slot]
        entries = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())
        rows = self._spread_indices[entries]
        weights = self._spread_data[entries]
        column = np.repeat(np.arange(len(slot)), lengths)
        others = rows != slot[column]           # a pushed vertex's own column entry: its push again
        rows, weights, column = rows[others], weights[others], column[others]
        reached = np.zeros(n, dtype=bool)
        reached[rows] = True
        moved = np.flatnonzero(reached)
        around = np.stack([np.bincount(rows, weights * np.take(total[:, k], column), minlength=n)[moved]
                           for k in range(3)], axis=1)
        targets = self.watched[moved]
        x[targets] = np.take(x, targets, axis=0) + around


def _rigid_fit(rest: np.ndarray, now: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """(R (3, 3), t (3,)) with now ~= rest @ R.T + t (Kabsch); R is None when the points only
    shifted (or stayed)."""
    moved = now - rest
    if np.abs(moved - moved[0]).max() < 1e-9:
        return None, moved[0]
    mr, mn = rest.mean(axis=0), now.mean(axis=0)
    u, _s, vt = np.linalg.svd((rest - mr).T @ (now - mn))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return rotation, mn - mr @ rotation.T
