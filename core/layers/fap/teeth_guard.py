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
"""

from __future__ import annotations

import numpy as np
import scipy.sparse
from scipy.spatial import cKDTree

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
        self.rows: list[tuple[str, TeethRowHull, np.ndarray, np.ndarray, np.ndarray]] = []
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
            self.rows.append((name, hull, skin[guarded], clearance[guarded], anchors))
        self._rest_anchors = {name: rest[anchors] for name, _h, _s, _c, anchors in self.rows}
        # Every guarded vertex, and how a push at one spreads to the others: SPREAD_RINGS steps of
        # neighbour averaging (rows sum to 1), kept by column so a tick reads only the pushed ones.
        self.watched = np.unique(np.concatenate([s for _n, _h, s, _c, _a in self.rows] or [np.zeros(0, np.int64)]))
        ring = face.adjacency[self.watched][:, self.watched].tocsr()
        ring.data[:] = 1.0
        ring = ring + scipy.sparse.identity(len(self.watched), format="csr")
        step = (scipy.sparse.diags(1.0 / np.asarray(ring.sum(axis=1)).ravel()) @ ring).tocsr()
        spread = scipy.sparse.identity(len(self.watched), format="csr")
        for _ in range(SPREAD_RINGS):
            spread = spread @ step
        spread = spread.tocsc()
        self._spread_indptr, self._spread_indices, self._spread_data = spread.indptr, spread.indices, spread.data

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``x`` (n, 3) mm with the guarded skin pushed out of each row of teeth where it is (in place);
        each push spreads to the skin around it, fading over ``SPREAD_RINGS`` rings."""
        pushes = []
        for name, hull, skin, clearance, anchors in self.rows:
            rotation, shift = _rigid_fit(self._rest_anchors[name], x[anchors])
            if rotation is None:
                # Still or shifted (the FAP jaw): the height band alone rules out most skin before
                # anything else is gathered.
                height = x[skin, 1] - (shift[1] + hull.y0)
                band = np.flatnonzero(np.abs(height - hull.height / 2) < hull.height / 2)
                local = x[skin[band]] - shift
            else:   # turned (the muscle mandible): into the row's rest frame first
                local = (x[skin] - shift) @ rotation
                height = local[:, 1] - hull.y0
                band = np.flatnonzero(np.abs(height - hull.height / 2) < hull.height / 2)
                local = local[band]
            dx, dz = local[:, 0] - hull.centre[0], local[:, 2] - hull.centre[2]
            squared = dx * dx + dz * dz
            near = np.flatnonzero(squared < hull.reach_squared)
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
            pushes.append((vertices, moved - x[vertices]))
            x[vertices] = moved
        if pushes:
            self._spread(x, pushes)
        return x

    def _spread(self, x: np.ndarray, pushes) -> None:
        """Let the skin around pushed vertices follow their pushes part way, fading over
        ``SPREAD_RINGS`` rings (in place; pushed vertices keep their own push)."""
        vertices = np.concatenate([v for v, _o in pushes])
        offsets = np.concatenate([o for _v, o in pushes])
        slot, which = np.unique(np.searchsorted(self.watched, vertices), return_inverse=True)
        total = np.zeros((len(slot), 3))
        np.add.at(total, which, offsets)     # a vertex both rows pushed has both pushes
        # The pushed columns of the spread matrix, read straight from its CSC arrays (scipy's column
        # slicing costs more than the whole guard).
        starts, lengths = self._spread_indptr[slot], np.diff(self._spread_indptr)[slot]
        entries = np.repeat(starts - np.cumsum(lengths) + lengths, lengths) + np.arange(lengths.sum())
        rows = self._spread_indices[entries]
        weights = self._spread_data[entries]
        column = np.repeat(np.arange(len(slot)), lengths)
        n = len(self.watched)
        around = np.stack([np.bincount(rows, weights * total[column, k], minlength=n) for k in range(3)], axis=1)
        around[slot] = 0.0          # already where they must be
        moved = np.unique(rows)
        x[self.watched[moved]] += around[moved]


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
