"""Closed eyes on a face (a scan taken with the eyes shut): where each lid line runs, and which lid a
vertex belongs to.

A face with open eyes has a real opening between its lids; a closed eye is one sheet of skin across
the eye, and to open it (the lid FAPs 19-22 on a registered scan) the skin must be cut along the lid
line and each side must follow its own lid. Both the scan's cut (``core.registration.scan_mouth``)
and the FAP deformer's binding of the cut skin (``fat.FapDeformer``) ask :func:`closed_eye_side`.

Geometry only, from the face's landmarks: an eye is closed when its lid centres (3.1 and 3.3 on the
left, 3.2 and 3.4 on the right) are closer than ``CLOSED_EYE_GAP`` x the eye's width; its lid line
runs from corner to corner through the middle of the two lid centres, in the eye's own frame (u
along the corners, v up towards the brow, w out of the face), so a tilted or turned head works too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.face import Face

#: A lid gap under this share of its eye's width (corner to corner) is a closed eye. Open eyes measure
#: about 0.3-0.4 (eye aperture ~10 mm over ~28-30 mm), the default face with its lids at 1024 IRISD 0.05.
CLOSED_EYE_GAP = 0.15
#: Vertices within this share of the eye's width above or below a closed eye's lid line are upper or
#: lower lid (about 11 mm on an adult: the lids, not the brow or the cheek).
LID_BAND = 0.4
#: ... and within this share of the width in front of or behind the corners' chord (not the far side
#: of the head, nor the nose's side wall).
LID_DEPTH = 0.6
#: Per eye: upper-lid centre, lower-lid centre, outer corner, inner corner, the brow points above it.
EYES = {"l": ("3.1", "3.3", "3.7", "3.11", ("4.1", "4.3", "4.5")),
        "r": ("3.2", "3.4", "3.12", "3.8", ("4.2", "4.4", "4.6"))}
#: The lid feature points of each side (used to keep a lid's landmarks on its own side of a cut).
UPPER_LID_POINTS = frozenset({"3.1", "3.2", "3.13", "3.14"})
LOWER_LID_POINTS = frozenset({"3.3", "3.4", "3.9", "3.10"})


@dataclass(frozen=True)
class LidLine:
    """A closed eye's lid line: from corner ``start`` (3,) mm along unit ``u`` (to the other corner,
    ``width`` mm away), with unit ``v`` up (towards the brow) and ``w`` out of the face; the line is
    the parabola through both corners and height ``t_mid`` mm at ``s_mid`` mm along u (the lid
    centres' middle)."""

    eye: str
    start: np.ndarray
    u: np.ndarray
    v: np.ndarray
    w: np.ndarray
    width: float
    s_mid: float
    t_mid: float
    #: The skin's own lid crease where it was found (``core.registration.lid_crease``): samples at
    #: ``crease_s`` mm along u of the crease's height above the parabola (``crease_t``, mm) and its
    #: depth along w (``crease_depth``, mm); empty: the parabola alone.
    crease_s: tuple = ()
    crease_t: tuple = ()
    crease_depth: tuple = ()

    def parabola(self, s: np.ndarray) -> np.ndarray:
        """(k,) mm: the parabola's height at ``s`` (k,) mm along u."""
        return self.t_mid * s * (self.width - s) / max(self.s_mid * (self.width - self.s_mid), 1e-9)

    def height(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(height above the line (k,) mm, inside the lid band (k,) bool) of points (k, 3)."""
        rel = np.asarray(points, float) - self.start
        s, t, depth = rel @ self.u, rel @ self.v, rel @ self.w
        # The parabola through both corners and the lid centres' middle: a lid line curves smoothly;
        # on a scan, moved onto the skin's own crease where one was found.
        line = self.parabola(s)
        if len(self.crease_s):
            line = line + np.interp(s, self.crease_s, self.crease_t)
        above = t - line
        inside = ((s > 0.0) & (s < self.width) & (np.abs(above) < LID_BAND * self.width)
                  & (np.abs(depth) < LID_DEPTH * self.width))
        return above, inside

    def off_crease(self, points: np.ndarray) -> np.ndarray:
        """(k,) mm: how far points (k, 3) lie in front of (+) or behind (-) the crease's depth at
        their place along u (their depth from the corners' chord without a crease)."""
        rel = np.asarray(points, float) - self.start
        depth = rel @ self.w
        if not len(self.crease_s):
            return depth
        return depth - np.interp(rel @ self.u, self.crease_s, self.crease_depth)


def closed_lid_lines(face: Face) -> list[LidLine]:
    """The lid lines of ``face``'s closed eyes (none for open eyes, or without the eye landmarks)."""
    return _lid_lines(face, closed=True)


def open_eye_lines(face: Face) -> list[LidLine]:
    """The same frame for ``face``'s open eyes (their "lid line" runs between the open lids): the
    eye's corners, width, up (v) and outward (w) directions, for placing an eyeball behind it."""
    return _lid_lines(face, closed=False)


def _lid_lines(face: Face, closed: bool) -> list[LidLine]:
    names = set(face.landmark_names)
    lines = []
    for eye, (top, bottom, outer, inner, brows) in EYES.items():
        brows = [b for b in brows if b in names]
        if not brows or not {top, bottom, outer, inner} <= names:
            continue
        p_top, p_bottom, p_outer, p_inner = face.landmark_positions([top, bottom, outer, inner])
        width = float(np.linalg.norm(p_inner - p_outer))
        if width <= 0 or (np.linalg.norm(p_top - p_bottom) < CLOSED_EYE_GAP * width) != closed:
            continue
        u = (p_inner - p_outer) / width
        centre = (p_outer + p_inner) / 2
        v = face.landmark_positions(brows).mean(axis=0) - centre
        v -= (v @ u) * u
        if np.linalg.norm(v) < 1e-9:
            continue
        v /= np.linalg.norm(v)
        w = np.cross(u, v)
        middle = (p_top + p_bottom) / 2
        if (middle - centre) @ w < 0:   # the lids bulge out of the face, over the eyeball
            w = -w
        rel = middle - p_outer
        lines.append(LidLine(eye, p_outer, u, v, w, width, float(rel @ u), float(rel @ v)))
    return lines


def closed_eye_side(face: Face, ids: np.ndarray | None = None, lines: list[LidLine] | None = None,
                    cut_only: bool = False) -> np.ndarray:
    """(len(ids),) +1 upper lid, -1 lower lid, 0 elsewhere, for vertices ``ids`` (default all) of
    ``face`` around its closed eyes (``lines``, default :func:`closed_lid_lines`).

    Vertices on a cut along the lid line (a seam of duplicated boundary vertices at the same places)
    take the side their own triangles lie on, as ``template.mouth_side`` does for the lips.
    ``cut_only``: only those get a side (the geometric line is a polyline through three points; a
    vertex of an uncut lid within a millimetre of it may be on either side).
    """
    from core.subdivision import boundary_edges

    ids = np.arange(face.n_vertices) if ids is None else np.asarray(ids, np.int64)
    side = np.zeros(len(ids), np.int64)
    lines = closed_lid_lines(face) if lines is None else lines
    if not lines or not len(ids):
        return side
    rim = np.zeros(face.n_vertices, bool)
    rim[boundary_edges(face.triangles).ravel()] = True
    adjacency = face.adjacency
    for line in lines:
        above, inside = line.height(face.vertices[ids])
        on_cut = inside & rim[ids] & (np.abs(above) < 0.05 * line.width)
        if not cut_only:
            side = np.where(inside, np.where(above > 0, 1, -1), side)
        if on_cut.any():
            neighbours = adjacency[ids[on_cut]]
            counts = np.maximum(np.asarray(neighbours.sum(axis=1)).ravel(), 1)
            mean_above = (neighbours @ line.height(face.vertices)[0]) / counts
            side[on_cut] = np.where(mean_above > above[on_cut], 1, -1)
    return side


def lid_point_sides(face: Face, lines: list[LidLine] | None = None) -> dict[str, int]:
    """{lid feature point: +1 upper / -1 lower} for the lid points of ``face``'s closed eyes."""
    lines = closed_lid_lines(face) if lines is None else lines
    closed = {line.eye for line in lines}
    sides = {}
    for eye in closed:
        ids = ("3.1", "3.13", "3.3", "3.9") if eye == "l" else ("3.2", "3.14", "3.4", "3.10")
        for name in ids:
            sides[name] = 1 if name in UPPER_LID_POINTS else -1
    return sides
