"""Remove the sliver triangles that snapping a grid's rim onto a curve leaves behind.

The front of the default face is a regular grid; the rims of the eye openings are snapped onto the
lid margins (``build._cut_eye_openings``). Where a margin runs along the grid, three neighbouring rim
vertices land on it almost in a line, and the triangle they span is a sliver: on the default face 34
of the eye rims' triangles have a height under a tenth of their longest edge, 20 of them folded over
at rest. Such a triangle has no texture to show, but the smallest move of its corners turns or
stretches it without bound (a lower lid's outer corner measured "stretched 6.5x" by a 2.8 mm lid drop
that moved the skin around it evenly), and it shades as a crease. (The outer rim's slivers, left by
``build._smooth_outer_rim``, are not touched: the head's seam places those vertices again in 3-D.)

:func:`remove_rim_slivers` takes each such triangle out in the plane of the grid, where the snapped
positions are final: its middle vertex (opposite the longest edge) is merged into the nearer end of
that edge, unless a merge would turn another triangle over; a vertex only the sliver used goes with it.
"""

from __future__ import annotations

import numpy as np

from core.default_face.shape import plane_signed_area2

# A triangle whose height is below this share of its longest edge is a sliver. The regular grid's
# triangles have 0.71 (half-squares); the snapped rims' slivers 0.000-0.06; the snapped but sound
# triangles beside them 0.2 and up.
SLIVER_HEIGHT_RATIO = 0.1


def sliver_triangles(xy: np.ndarray, tris: np.ndarray, candidates: np.ndarray | None = None) -> np.ndarray:
    """Indices of the triangles of ``tris`` (m, 3) whose height over their longest edge in the plane
    ``xy`` (n, 2) is below SLIVER_HEIGHT_RATIO, or that are folded over (negative area); only those
    with all three corners in ``candidates`` ((n,) bool) when given."""
    corners = xy[tris]
    longest = np.linalg.norm(corners[:, [1, 2, 0]] - corners, axis=2).max(axis=1)
    area2 = plane_signed_area2(xy, tris)
    thin = area2 < SLIVER_HEIGHT_RATIO * np.maximum(longest, 1e-12) ** 2
    if candidates is not None:
        thin &= candidates[tris].all(axis=1)
    return np.flatnonzero(thin)


def remove_rim_slivers(xy: np.ndarray, tris: np.ndarray, rim: np.ndarray, pinned: np.ndarray) -> np.ndarray:
    """(m', 3) ``tris`` without the slivers whose three corners are all ``rim`` vertices (see the
    module docstring). ``xy`` (n, 2) grid positions; ``rim`` (n,) bool the snapped vertices;
    ``pinned`` (n,) bool vertices that must keep every triangle they have (exact eye corners, the
    mouth seam). Vertices no triangle uses any more are left for the caller to drop. Build time only:
    a loop over the few slivers, not over the mesh."""
    tris = np.array(tris, copy=True)
    alive = np.ones(len(tris), bool)
    for _ in range(len(tris)):       # each pass removes at least one sliver or stops
        changed = False
        for t in np.flatnonzero(alive)[sliver_triangles(xy, tris[alive], rim)]:
            if not alive[t]:
                continue
            corners = tris[t]
            edges = np.linalg.norm(xy[corners[[1, 2, 0]]] - xy[corners], axis=1)
            k = int(np.argmax(edges))                       # the longest edge: corners k, k+1
            a, b, apex = corners[k], corners[(k + 1) % 3], corners[(k + 2) % 3]
            if pinned[apex]:
                continue
            users = np.flatnonzero(alive & (tris == apex).any(axis=1))
            if len(users) == 1:             # a lone ear on the rim: the triangle and its apex go
                alive[t] = False
                changed = True
                continue
            for target in sorted((a, b), key=lambda v: np.linalg.norm(xy[v] - xy[apex])):
                merged = tris[users].copy()
                merged[merged == apex] = target
                degenerate = (merged == target).sum(axis=1) > 1
                kept = merged[~degenerate]
                if not (plane_signed_area2(xy, kept) > 0).all() or len(sliver_triangles(xy, kept)):
                    continue                # the merge would turn a triangle over or make another sliver
                tris[users] = merged
                alive[users[degenerate]] = False
                changed = True
                break
        if not changed:
            break
    return tris[alive]


__all__ = ["SLIVER_HEIGHT_RATIO", "remove_rim_slivers", "sliver_triangles"]
