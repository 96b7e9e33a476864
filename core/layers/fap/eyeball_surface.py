"""An eyeball's outer surface as a map of its radius by direction, for the lid guard
(``FapDeformer._close_lids``).

The guard keeps lid skin outside the eyeball. An eyeball is not a surface of revolution about the
gaze axis: the default face's is a front cap 30 mm wide and 23 mm high, its radius from the fitted
centre 12.8 mm above and below the cornea and 16.0 mm at the sides at one angle from the axis. A
profile by that angle alone (the largest radius at each) put the skin above and below the eye up to
1.65 mm inside a ball it lies outside of; pushed onto that profile it jumped out while its
neighbours did not, and folded.

The map holds the radius over two angles instead, in the azimuthal equidistant projection about
+z: a direction at angle ``theta`` from +z and azimuth ``phi`` sits at ``(u, v) = theta (cos phi,
sin phi)`` rad, on a square grid of ``RADIUS_MAP_STEP_RAD`` cells reaching ``RADIUS_MAP_REACH_RAD``
from the axis (no singular pole, cells of nearly one size). Each node holds the largest radius of
the ball's surface over the four cells around it, so a bilinear read anywhere in a cell is at least
the surface's largest radius in that cell: interpolation never dips inside the mesh. Behind a
cap's open rim the map continues the rim's radius for ``SKIRT_RAD`` (skin tucked behind the rim is
not read as free of the ball); farther round it reads 0: no ball there.
"""

from __future__ import annotations

import numpy as np

# Grid cell (rad). At 1 degree the map stands above the default face's ball by 0.04 mm (median over
# its surface, largest 0.07 mm; generated identity 0.03 / 0.05 mm): less than the lid guard's
# smallest clearance (0.1 mm). At 2 degrees the filter's overshoot doubles.
RADIUS_MAP_STEP_RAD = float(np.radians(1.0))
# The map covers directions up to this angle from the gaze axis (rad): a ball's widest circle and a
# margin. Skin farther round is behind the ball's centre, where a push forward cannot put it outside.
RADIUS_MAP_REACH_RAD = float(np.radians(100.0))
# Surface samples per cell edge are spaced at most this far (mm); the sampled cell maxima then miss
# the surface's by at most 0.002 mm (checked with samples 0.03 mm apart on both identities).
SAMPLE_SPACING_MM = 0.05
# How far behind an open rim the map continues the rim's radius (rad), in azimuth bins of the second
# constant. The default face's ball is a front cap whose rim lies 67-72 degrees off the gaze axis; the
# socket skin under it reaches 80 degrees. Read as free of the ball there (0), its triangles that the
# cheek lift pulls over the rim crossed it: lift_l_cheek 400 87 lid crossing pairs, 31 with the skirt.
SKIRT_RAD = float(np.radians(30.0))
# The lid guard pushes skin forward (+z) up to this angle from the gaze axis and radially beyond the
# second, turning smoothly in between. The balls' rims lie 69-72 degrees off the axis (default face and
# a generated identity); skin beside a rim, tucked behind it at about the rim's radius, pushed forward
# onto it jumped 7.8 mm forward at the outer eye corner when a generated face closed its eyes (the
# radial push there is 1-2 mm), and 10 mm at its temple with the cheek lift.
PUSH_TURN_START_RAD = float(np.radians(60.0))
PUSH_TURN_END_RAD = float(np.radians(85.0))
SKIRT_AZIMUTH_STEP_RAD = float(np.radians(2.0))


def radius_map(vertices: np.ndarray, triangles: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(m, m) mm: the radius map of the surface ``triangles`` (t, 3) of ``vertices`` (n, 3) mm about
    ``centre`` (3,) mm (see the module docstring); 0 where no triangle lies in that direction."""
    m = _nodes()
    cells = np.zeros((m - 1, m - 1))
    for points in _surface_samples(np.asarray(vertices, float), np.asarray(triangles), SAMPLE_SPACING_MM):
        offsets = points - centre
        fu, fv = _grid_coordinates(offsets)
        i, j = np.floor(fu).astype(np.int64), np.floor(fv).astype(np.int64)
        inside = (i >= 0) & (j >= 0) & (i < m - 1) & (j < m - 1)
        np.maximum.at(cells, (i[inside], j[inside]), np.sqrt((offsets[inside] ** 2).sum(axis=1)))
    cells = _with_skirt(cells)
    nodes = np.zeros((m, m))
    for di in (0, 1):
        for dj in (0, 1):
            window = nodes[di:m - 1 + di, dj:m - 1 + dj]
            np.maximum(window, cells, out=window)
    return nodes


def map_radius(offsets: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(k,) mm: the radius map ``radii`` (m, m) read bilinearly in the directions of ``offsets``
    (k, 3) mm from its centre; 0 outside the map. The same sums as the compiled lid guard
    (``compiled_steps._map_radius``)."""
    m = radii.shape[0]
    fu, fv = _grid_coordinates(offsets)
    i, j = np.floor(fu), np.floor(fv)
    inside = (i >= 0) & (j >= 0) & (i < m - 1) & (j < m - 1)
    tu, tv = fu - i, fv - j
    i, j = np.where(inside, i, 0).astype(np.int64), np.where(inside, j, 0).astype(np.int64)
    value = ((radii[i, j] * (1.0 - tu) + radii[i + 1, j] * tu) * (1.0 - tv)
             + (radii[i, j + 1] * (1.0 - tu) + radii[i + 1, j + 1] * tu) * tv)
    return np.where(inside, value, 0.0)


def _with_skirt(cells: np.ndarray) -> np.ndarray:
    """(m - 1, m - 1) cell maxima with the ball continued behind an open rim: each empty cell up
    to ``SKIRT_RAD`` beyond the outermost covered cell of its azimuth takes the radius there (the
    largest over neighbouring azimuths), so skin tucked behind the rim is not read as free of the ball."""
    m = cells.shape[0] + 1
    centres = (np.arange(m - 1) + 0.5) * RADIUS_MAP_STEP_RAD - RADIUS_MAP_REACH_RAD
    u, v = np.meshgrid(centres, centres, indexing="ij")
    theta, azimuth = np.hypot(u, v), np.arctan2(v, u)
    bins = int(round(2 * np.pi / SKIRT_AZIMUTH_STEP_RAD))
    which = np.minimum(((azimuth + np.pi) / SKIRT_AZIMUTH_STEP_RAD).astype(np.int64), bins - 1)
    covered = cells > 0.0
    outermost = np.full(bins, -1.0)
    np.maximum.at(outermost, which[covered], theta[covered])
    rim = covered & (theta >= outermost[which] - RADIUS_MAP_STEP_RAD)
    rim_radius = np.zeros(bins)
    np.maximum.at(rim_radius, which[rim], cells[rim])
    rim_radius = np.max([np.roll(rim_radius, k) for k in (-1, 0, 1)], axis=0)
    # The skirt starts at the nearest rim of the neighbouring azimuths (bins the ball misses: none).
    outermost = np.min([np.where(rolled < 0, np.inf, rolled) for rolled in (np.roll(outermost, k) for k in (-1, 0, 1))],
                       axis=0)
    skirt = ~covered & (theta > outermost[which]) & (theta <= outermost[which] + SKIRT_RAD)
    out = cells.copy()
    out[skirt] = rim_radius[which[skirt]]
    return out


def push_outside(x: np.ndarray, lid: np.ndarray, centre: np.ndarray, clearance: np.ndarray,
                 radii: np.ndarray) -> None:
    """Push the vertices ``x[lid]`` ((n, 3) mm, in place; ``lid`` (k,)) that lie inside the guard
    surface (the radius map ``radii`` about ``centre`` (3,) mm plus ``clearance`` (k,) mm) onto it
    along :func:`push_direction`; the numpy twin of ``compiled_steps.close_lids_over_eyeball``.

    Two passes: pushing a vertex forward turns it toward the cornea, which is higher."""
    for _ in range(2):
        r = x[lid] - centre
        length = np.sqrt((r * r).sum(axis=1))
        need = map_radius(r, radii) + clearance
        inside = length < need
        if not inside.any():
            break
        r, need = r[inside], need[inside]
        d = push_direction(r)
        along = (r * d).sum(axis=1)
        t = -along + np.sqrt(np.maximum(along * along - (r * r).sum(axis=1) + need * need, 0.0))
        x[lid[inside]] += t[:, None] * d


def push_direction(offsets: np.ndarray) -> np.ndarray:
    """(k, 3) unit directions in which the lid guard pushes skin at ``offsets`` (k, 3) mm from the
    ball's centre: forward (+z) in front of the ball, so the lid keeps its height and closing lids
    meet where the FAT puts them; turning to the radial direction between ``PUSH_TURN_START_RAD``
    and ``PUSH_TURN_END_RAD`` from the gaze axis, where a forward push onto a surface of about the
    skin's own distance from the centre would be many times longer than the skin's depth inside it."""
    planar = np.sqrt(offsets[:, 0] ** 2 + offsets[:, 1] ** 2)
    theta = np.arctan2(planar, offsets[:, 2])
    w = np.clip((theta - PUSH_TURN_START_RAD) / (PUSH_TURN_END_RAD - PUSH_TURN_START_RAD), 0.0, 1.0)
    w = w * w * (3.0 - 2.0 * w)
    radial = offsets / np.maximum(np.sqrt((offsets ** 2).sum(axis=1)), 1e-300)[:, None]
    d = w[:, None] * radial
    d[:, 2] += 1.0 - w
    return d / np.maximum(np.sqrt((d ** 2).sum(axis=1)), 1e-300)[:, None]


def _nodes() -> int:
    """Nodes per side of the map's square grid."""
    return int(round(2 * RADIUS_MAP_REACH_RAD / RADIUS_MAP_STEP_RAD)) + 1


def _grid_coordinates(offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,), (k,): the directions of ``offsets`` (k, 3) in grid units from the map's corner."""
    rx, ry, rz = offsets[:, 0], offsets[:, 1], offsets[:, 2]
    planar = np.sqrt(rx * rx + ry * ry)
    theta = np.arctan2(planar, rz)
    scale = np.where(planar > 0.0, theta / np.where(planar > 0.0, planar, 1.0), 0.0)
    return ((rx * scale + RADIUS_MAP_REACH_RAD) / RADIUS_MAP_STEP_RAD,
            (ry * scale + RADIUS_MAP_REACH_RAD) / RADIUS_MAP_STEP_RAD)


def _surface_samples(vertices: np.ndarray, triangles: np.ndarray, spacing: float):
    """Yields (s, 3) mm arrays of points on the triangles, a barycentric grid per triangle with
    neighbours at most ``spacing`` mm apart (triangles grouped by how fine their grid must be)."""
    a, b, c = vertices[triangles[:, 0]], vertices[triangles[:, 1]], vertices[triangles[:, 2]]
    longest = np.sqrt(np.max([((a - b) ** 2).sum(1), ((b - c) ** 2).sum(1), ((c - a) ** 2).sum(1)], axis=0))
    divisions = np.maximum(np.ceil(longest / spacing), 1).astype(np.int64)
    for n in np.unique(divisions):
        group = divisions == n
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        wa, wb = (i[keep] / n)[None, :, None], (j[keep] / n)[None, :, None]
        yield (a[group][:, None] * wa + b[group][:, None] * wb + c[group][:, None] * (1.0 - wa - wb)).reshape(-1, 3)


__all__ = ["RADIUS_MAP_REACH_RAD", "RADIUS_MAP_STEP_RAD", "map_radius", "push_outside", "radius_map"]
