"""head.py
----
The rest of the head behind the front-of-face surface: skull, back of the
head, the jaw's sides, the neck down to the start of the shoulders, and two
ears, all generated from the identity parameters.

The head shell is a star-shaped surface around a centre C inside the skull,
point = C + R(d) d for unit directions d, then flared below the neck: R is the
distance to the zero set of a smooth union of a cranial ellipsoid, a jaw mass
and a neck column narrower than the jaw (sterno-cleido-mastoid ridges, larynx,
rounded off at a flat bottom cap), plus a correction that makes the shell meet
the face's outer boundary exactly and fades out with distance from it. Seen
from C the top of the shoulders would face the centre, so they cannot be
star-shaped: below the neck base an affine map of each horizontal slice (x and
the depth scaled, a bijection of space) flares the column into the trapezius
slope and the upper chest and back (``HeadModel.warp``); the shell stays
closed and embedded.

The shell's directions are triangulated in the stereographic plane
q = (d_x, d_y) / (1 - d_z) (projection from the front pole, which the face
covers): there the face's outer boundary is a closed curve around the origin
(the back of the head) and the shell is the disc inside it; a Delaunay
triangulation of the plane is a spherical Delaunay triangulation of the
directions (stereographic projection keeps circles). The directions are a
uniform spiral on the skull and rings spaced evenly in mm on the neck and the
flare (seen from C the throat is grazed and the flare stretches), and the
triangulation's edges are then flipped to a Delaunay one in 3-D.

The shell's seam vertices are copies of the face's outer boundary vertices
(same positions, so the surface is closed; own texture coordinates, so the
shell has its own patch of the texture, the "head atlas"). The ears are two
closed, rigid components set into the sides of the head.
All lengths in mm; triangles counter-clockwise seen from outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from core.default_face.params import FaceLayout
from core.default_face.shape import _smooth_max, _smoothstep, plane_signed_area2, polar_cap_triangles

SHELL_SPACING = 5.6        # mm, target edge length of the shell away from the face
SEAM_RINGS = ((1.3, 2), (3.2, 4), (6.0, 8))   # (offset from the seam in mm, every k-th seam vertex) of graded rings
CORRECTION_FADE = 26.0     # mm, the seam correction fades out over this distance from the face
CORRECTION_SIGMA = 0.07    # rad, angular smoothing of the seam correction along the seam
EAR_RINGS, EAR_SEGMENTS = 10, 40
FAIR_BAND_MM = 24.0        # shell vertices this close to the seam are faired into the face's slope
# Neck and shoulders' start (mm, default face; heights scale with the face's height, widths with its width).
NECK_HALF_WIDTH_OF_JAW = 0.41   # the neck column's half-width as a share of the bigonial breadth
NECK_HALF_DEPTH = 50.0
NECK_BASE_BELOW_MENTON = 32.0   # the side of the neck starts curving out this far below the chin
SHOULDER_DROP = 48.0            # ... and reaches the shoulders' start this much lower
SHOULDER_HALF_WIDTH = 125.0     # half-width there
SHOULDER_RISE = 1.7             # the outline's curve: (share of the drop) ** SHOULDER_RISE
CHEST_FORWARD, UPPER_BACK = 18.0, 40.0   # there the chest is this much in front of the neck, the back behind
CAP_BELOW_SHOULDER = 8.0        # the flat bottom cap this far below
SCM_RIDGE, LARYNX = 4.0, 3.0     # how far the sterno-cleido-mastoid ridges and the larynx stand out
FLARE_SPACING = 6.0             # mm, target edge length where the flare stretches the shell


def _softmin(a, b, k):
    return -_smooth_max(-np.asarray(a, float), -np.asarray(b, float), k)


# ---------------------------------------------------------------- a smooth join
def fair_radially(points: np.ndarray, triangles: np.ndarray, free: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(n, 3) ``points`` with the ``free`` (n,) bool ones moved along their direction from ``centre``
    so that their distance from it is biharmonic over the mesh (L^2 s = 0, L the graph Laplacian
    weighted by 1 / edge length), the other points fixed.

    Where the head shell meets the front of the face, the shell matches the face's boundary but not
    its slope: the join shows as a crease (a step at the temples, a ridge along the jaw). With two
    rings of the face fixed beside the seam, a biharmonic fill continues the face's slope into the
    shell. Moving only along the radius keeps every shell vertex's direction, hence its texture
    coordinates and triangle shapes."""
    import scipy.sparse
    import scipy.sparse.linalg

    n = len(points)
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]),
                              axis=1), axis=0)
    weight = 1.0 / np.maximum(np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1), 1e-9)
    W = scipy.sparse.coo_matrix((np.concatenate([weight, weight]), (np.concatenate([edges[:, 0], edges[:, 1]]),
                                 np.concatenate([edges[:, 1], edges[:, 0]]))), shape=(n, n)).tocsr()
    degree = np.asarray(W.sum(axis=1)).ravel()
    L = scipy.sparse.diags(1.0 / np.maximum(degree, 1e-12)) @ W - scipy.sparse.identity(n)
    M = (L @ L).tocsr()
    r = points - centre
    s = np.linalg.norm(r, axis=1)
    fixed = ~free
    rows = M[free]
    solved = scipy.sparse.linalg.spsolve(rows[:, free].tocsc(), -rows[:, fixed] @ s[fixed])
    out = points.copy()
    out[free] = centre + r[free] / s[free, None] * np.asarray(solved)[:, None]
    return out


# ---------------------------------------------------------------- outer boundary
def outer_boundary_loop(triangles: np.ndarray) -> np.ndarray:
    """Vertex indices of the longest boundary loop of a triangle mesh, in order (counter-clockwise
    seen from outside the mesh's front)."""
    tri = np.asarray(triangles)
    directed = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    n = int(tri.max()) + 1
    key = directed[:, 0] * n + directed[:, 1]
    reverse = directed[:, 1] * n + directed[:, 0]
    boundary = directed[~np.isin(key, reverse)]
    nxt = dict(zip(boundary[:, 0].tolist(), boundary[:, 1].tolist()))
    seen, best = set(), []
    for start in nxt:
        if start in seen:
            continue
        loop, v = [], start
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        if len(loop) > len(best):
            best = loop
    return np.array(best, dtype=np.int64)


def smoothed_rim(points: np.ndarray, sigma: float = 2.5, pinned: np.ndarray | None = None) -> np.ndarray:
    """(k, d) the closed rim polyline ``points`` (k, d) with the grid's staircase smoothed away
    (a circular Gaussian along the loop, ``sigma`` in vertices). Smoothed in 3-D, not re-evaluated on
    the height field: under the chin, where the outline's half-width tends to 0, a 0.3 mm step in y
    would move the height field's z by tens of mm. ``pinned`` (k,) bool: loop vertices that keep
    their place (corners of a feature point's triangle); the smoothing fades in over 4 vertices
    around them."""
    from scipy.ndimage import gaussian_filter1d, minimum_filter1d

    points = np.asarray(points, float)
    smooth = gaussian_filter1d(points, sigma, axis=0, mode="wrap")
    if pinned is None or not np.any(pinned):
        return smooth
    free = minimum_filter1d((~np.asarray(pinned)).astype(float), 3, mode="wrap")
    weight = gaussian_filter1d(free, 1.5, mode="wrap") * (~np.asarray(pinned))
    return points + (smooth - points) * weight[:, None]


# ---------------------------------------------------------------- head model
@dataclass(frozen=True)
class HeadModel:
    """Implicit head (skull, jaw mass, neck) for one layout; ``radius`` gives the shell's distance from
    ``centre`` along unit directions."""

    layout: FaceLayout

    @property
    def scale(self) -> tuple[float, float]:
        p = self.layout.p
        return p.face_width / 137.0, p.face_height / 121.0

    @property
    def centre(self) -> np.ndarray:
        L = self.layout
        return np.array([0.0, L.subnasale_y + 5.0, -100.0])

    @property
    def neck_axis_z(self) -> float:
        """z (mm) of the neck's vertical axis; the shoulders' flare scales depth about it."""
        return -110.0

    @property
    def neck_base_y(self) -> float:
        """Height (mm) where the side of the neck starts to curve out into the trapezius slope."""
        return self.layout.menton_y - NECK_BASE_BELOW_MENTON * self.scale[1]

    @property
    def neck_bottom_y(self) -> float:
        """Height (mm) of the flat cut under the shoulders' start (the bottom cap)."""
        return self.neck_base_y - (SHOULDER_DROP + CAP_BELOW_SHOULDER) * self.scale[1]

    def field(self, p: np.ndarray) -> np.ndarray:
        """(k,) approximate signed distance (mm, < 0 inside) of points (k, 3) of the head before the
        shoulders' flare (``flare``): below the neck base the neck is a plain column, star-shaped
        around ``centre``."""
        L = self.layout
        sw, sh = self.scale
        x, y, z = p[:, 0], p[:, 1], p[:, 2]

        def ellipsoid(c, axes):
            q = np.sqrt(((x - c[0]) / axes[0]) ** 2 + ((y - c[1]) / axes[1]) ** 2 + ((z - c[2]) / axes[2]) ** 2)
            return (q - 1.0) * min(axes)

        cranium = ellipsoid((0.0, L.nasion_y + 16.0 * sh, -118.0), (79.0 * sw, 88.0 * sh, 98.0))
        jaw = ellipsoid((0.0, L.stomion_y - 8.0 * sh, -82.0), (0.58 * L.p.jaw_width, 48.0 * sh, 58.0))
        # Neck: an elliptic column narrower than the jaw (its outline steps in under the jaw's angle),
        # rounded off at the bottom cap.
        nx, nz = NECK_HALF_WIDTH_OF_JAW * L.p.jaw_width, NECK_HALF_DEPTH
        neck = (np.sqrt((x / nx) ** 2 + ((z - self.neck_axis_z) / nz) ** 2) - 1.0) * min(nx, nz)
        # Sterno-cleido-mastoid: a ridge on each side from behind the ear down to the sternal notch
        # (the V of the front of the neck), and the larynx on the midline.
        mastoid = np.array([0.0, L.subnasale_y - 12.0 * sh, self.neck_axis_z - 20.0])
        sternal = np.array([0.0, self.neck_base_y - 36.0 * sh, self.neck_axis_z + nz - 6.0])
        for side in (1.0, -1.0):
            mastoid[0], sternal[0] = side * 0.92 * nx, side * 11.0 * sw
            neck = neck - SCM_RIDGE * np.exp(-((_segment_distance(p, mastoid, sternal) / 9.0) ** 2))
        larynx = np.exp(-((x / 9.0) ** 2) - ((y - (L.menton_y - 24.0 * sh)) / 12.0) ** 2)
        neck = neck - LARYNX * larynx * (z > self.neck_axis_z)
        neck = _smooth_max(neck, self.neck_bottom_y - y, 6.0)
        neck = _smooth_max(neck, y - (L.stomion_y + 10.0), 10.0)
        return _softmin(_softmin(cranium, jaw, 14.0), neck, 9.0)

    def flare(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(k,) each: the factors by which the shoulders' flare scales x and the depth about the neck
        axis at heights y (k,) mm (1 above the neck base), and the shift (mm) of the depth.

        The neck's outline leaves the column tangentially and curves out to the shoulders' start
        ``SHOULDER_HALF_WIDTH`` mm from the midline ``SHOULDER_DROP`` mm lower (a trapezius slope of
        about 20 degrees there), then keeps that slope down to the cap. In depth the upper back
        flares more than the chest (a neck on a bell would flare both alike)."""
        L = self.layout
        sw, sh = self.scale
        t = np.clip((self.neck_base_y - np.asarray(y, float)) / (SHOULDER_DROP * sh), 0.0, None)
        k = SHOULDER_RISE
        rise = np.where(t < 1.0, t ** k, 1.0 + k * (t - 1.0))
        nx = NECK_HALF_WIDTH_OF_JAW * L.p.jaw_width
        gx = 1.0 + (SHOULDER_HALF_WIDTH * sw / nx - 1.0) * rise
        gz = 1.0 + (CHEST_FORWARD + UPPER_BACK) / (2.0 * NECK_HALF_DEPTH) * rise
        return gx, gz, 0.5 * (CHEST_FORWARD - UPPER_BACK) * rise

    def unwarp(self, p: np.ndarray) -> np.ndarray:
        """(k, 3) the star-shaped head's points that ``warp`` moves to points (k, 3)."""
        gx, gz, shift = self.flare(p[:, 1])
        zc = self.neck_axis_z
        return np.column_stack([p[:, 0] / gx, p[:, 1], zc + (p[:, 2] - zc - shift) / gz])

    def warp(self, p: np.ndarray) -> np.ndarray:
        """(k, 3) points (k, 3) of the star-shaped head moved by the shoulders' flare: at each height
        an affine map of (x, z) (scales ``flare`` > 0, a shift in z), so a bijection of space: the
        closed, embedded shell stays closed and embedded. The identity above the neck base."""
        gx, gz, shift = self.flare(p[:, 1])
        zc = self.neck_axis_z
        return np.column_stack([p[:, 0] * gx, p[:, 1], zc + (p[:, 2] - zc) * gz + shift])

    def radius(self, d: np.ndarray, r_max: float = 400.0, steps: int = 36) -> np.ndarray:
        """(k,) distance from the centre to the head model along unit directions (k, 3), by bisection."""
        lo = np.zeros(len(d))
        hi = np.full(len(d), r_max)
        c = self.centre
        for _ in range(steps):
            mid = 0.5 * (lo + hi)
            inside = self.field(c + d * mid[:, None]) < 0
            lo = np.where(inside, mid, lo)
            hi = np.where(inside, hi, mid)
        return 0.5 * (lo + hi)


def stereo(d: np.ndarray) -> np.ndarray:
    """(k, 2) stereographic coordinates of unit directions (k, 3), projected from +z."""
    return d[:, :2] / np.maximum(1.0 - d[:, 2:3], 1e-12)


def unstereo(q: np.ndarray) -> np.ndarray:
    """(k, 3) unit directions of stereographic coordinates (k, 2)."""
    s = (q ** 2).sum(axis=1)
    return np.column_stack([2 * q[:, 0], 2 * q[:, 1], s - 1.0]) / (s + 1.0)[:, None]


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k,) distance (mm) of points (k, 3) from the segment a-b."""
    ab = b - a
    t = np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def flip_to_delaunay(points: np.ndarray, plane: np.ndarray, triangles: np.ndarray, max_passes: int = 50) -> np.ndarray:
    """(m, 3) ``triangles`` with interior edges flipped until the mesh on ``points`` (k, 3) is
    Delaunay in 3-D (for each edge the two opposite angles sum to at most pi), each flip kept only
    where both new triangles keep their orientation in the ``plane`` (k, 2) the triangulation was
    made in (so the map from the plane stays one-to-one). Returns triangles counter-clockwise in the
    plane.

    A Delaunay triangulation of the plane is one in 3-D only where the map to the surface is
    isotropic; where the shell is grazed from the centre or stretched by the flare, its triangles
    came out as slivers across rows of vertices."""
    tri = np.array(triangles, dtype=np.int64)

    flip = plane_signed_area2(plane, tri) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]

    def angle(at, u, v):
        e1, e2 = points[u] - points[at], points[v] - points[at]
        cos = (e1 * e2).sum(axis=1) / np.maximum(np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-12)
        return np.arccos(np.clip(cos, -1.0, 1.0))

    n = len(points)
    for _ in range(max_passes):
        # Directed edges (a, b) of triangle k with the opposite corner c; an interior edge appears as
        # (a, b) in one triangle and (b, a) in the other.
        a = tri.ravel()
        b = tri[:, [1, 2, 0]].ravel()
        c = tri[:, [2, 0, 1]].ravel()
        owner = np.repeat(np.arange(len(tri)), 3)
        key = a * n + b
        order = np.argsort(key)
        pos = np.searchsorted(key[order], b * n + a)
        pos = np.minimum(pos, len(key) - 1)
        twin = order[pos]
        interior = (key[twin] == b * n + a) & (a < b)
        e = np.nonzero(interior)[0]
        t = twin[e]
        d = c[t]
        excess = angle(c[e], a[e], b[e]) + angle(d, a[e], b[e]) - np.pi
        new1 = np.column_stack([a[e], d, c[e]])
        new2 = np.column_stack([d, b[e], c[e]])
        ok = (excess > 1e-6) & (plane_signed_area2(plane, new1) > 0) & (plane_signed_area2(plane, new2) > 0)
        e, t, d, excess, new1, new2 = e[ok], t[ok], d[ok], excess[ok], new1[ok], new2[ok]
        if not len(e):
            break
        existing = set((np.minimum(a, b) * n + np.maximum(a, b)).tolist())
        used = np.zeros(len(tri), bool)
        for i in np.argsort(-excess):
            k1, k2 = owner[e[i]], owner[t[i]]
            cd = min(c[e[i]], d[i]) * n + max(c[e[i]], d[i])
            if used[k1] or used[k2] or cd in existing:
                continue
            used[k1] = used[k2] = True
            existing.add(cd)
            tri[k1], tri[k2] = new1[i], new2[i]
    return tri


def _inside_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(k,) bool: even-odd test of points (k, 2) against the closed polygon (m, 2)."""
    x, y = points[:, 0][:, None], points[:, 1][:, None]
    x0, y0 = poly[:, 0][None], poly[:, 1][None]
    x1, y1 = np.roll(poly[:, 0], -1)[None], np.roll(poly[:, 1], -1)[None]
    crosses = ((y0 > y) != (y1 > y)) & (x < (x1 - x0) * (y - y0) / np.where(y1 != y0, y1 - y0, 1e-30) + x0)
    return crosses.sum(axis=1) % 2 == 1


@dataclass
class HeadShell:
    """The shell: vertices (k, 3); triangles (m, 3) indexing ``face vertices + own vertices`` where the
    first ``n_seam`` own vertices are copies of the face's ``seam`` vertices; ``q`` (k, 2) its plane
    coordinates (the texture parametrisation)."""

    vertices: np.ndarray
    triangles: np.ndarray
    q: np.ndarray
    seam: np.ndarray


class HeadBuilder:
    """Builds the shell and the ears of one layout around a front-of-face skin."""

    def __init__(self, layout: FaceLayout):
        self.layout = layout
        self.model = HeadModel(layout)
        self._seam_dirs = None
        self._seam_delta = None

    # ------------------------------------------------------------ correction at the seam
    def set_seam(self, seam_points: np.ndarray) -> None:
        """Fix the correction at the seam: each seam point's radial offset from the model."""
        c = self.model.centre
        r = seam_points - c
        length = np.linalg.norm(r, axis=1)
        d = r / length[:, None]
        self._seam_dirs = d
        self._seam_delta = length - self.model.radius(d)
        self._seam_tree = cKDTree(d)

    def shell_radius(self, d: np.ndarray) -> np.ndarray:
        """(k,) shell radius: the model plus the seam's offset, faded with the distance from the seam."""
        base = self.model.radius(d)
        # The seam's offsets averaged over the seam directions nearest each direction, weighted by
        # how much farther than the nearest they are (defined and smooth at any distance).
        ang, idx = self._seam_tree.query(d, k=min(64, len(self._seam_dirs)))
        dist = ang[:, 0]
        w = np.exp(-(((ang - dist[:, None]) / CORRECTION_SIGMA) ** 2))
        offset = (w * self._seam_delta[idx]).sum(axis=1) / w.sum(axis=1)
        dist_mm = dist * base
        fade = np.exp(-((dist_mm / CORRECTION_FADE) ** 2))
        return base + offset * fade

    # ------------------------------------------------------------ shell
    def shell(self, face_vertices: np.ndarray, seam: np.ndarray, guide: np.ndarray | None = None) -> HeadShell:
        """The shell stitched to the face boundary ``seam`` (ordered vertex indices into face_vertices).

        ``guide`` (k, 3): a smooth copy of the seam's positions from which the triangulation is
        planned (a seam vertex pinned in place leaves a small kink that a Delaunay triangulation
        may cut across); the seam vertices themselves keep their positions."""
        c = self.model.centre
        seam_p = face_vertices[seam]
        self.set_seam(seam_p)
        if guide is not None:
            r = np.asarray(guide, float) - c
            seam_d = r / np.linalg.norm(r, axis=1, keepdims=True)
        else:
            seam_d = self._seam_dirs
        seam_q = stereo(seam_d)
        r_seam = np.linalg.norm(seam_p - c, axis=1)
        if not _inside_polygon(np.zeros((1, 2)), seam_q)[0]:
            raise ValueError("the face's outer boundary does not surround the back of the head")
        # Graded rings just inside the seam (in the plane: toward the back of the head).
        tangent = np.roll(seam_q, -1, axis=0) - np.roll(seam_q, 1, axis=0)
        normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        probe = seam_q + 1e-3 * normal
        if _inside_polygon(probe, seam_q).mean() < 0.5:
            normal = -normal
        mm_per_q = r_seam * 2.0 / (1.0 + (seam_q ** 2).sum(axis=1))
        rings = []
        for offset, every in SEAM_RINGS:
            sel = np.arange(0, len(seam), every)
            rings.append(seam_q[sel] + normal[sel] * (offset / mm_per_q[sel])[:, None])
        rings = np.concatenate(rings)
        rings = rings[_inside_polygon(rings, seam_q)]
        # Interior: a Fibonacci sphere of directions, the part inside the seam and clear of the rings.
        mean_r = float(np.median(r_seam))
        n_sphere = int(4 * np.pi * mean_r ** 2 / (0.866 * SHELL_SPACING ** 2))
        i = np.arange(n_sphere) + 0.5
        phi = np.arccos(1 - 2 * i / n_sphere)
        theta = np.pi * (1 + 5 ** 0.5) * i
        dirs = np.column_stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)])
        dirs = dirs[dirs[:, 2] < 0.999]
        q = stereo(dirs)
        keep = _inside_polygon(q, seam_q)
        q, dirs = q[keep], dirs[keep]
        clear = SEAM_RINGS[-1][0] + 0.6 * SHELL_SPACING
        dist, _ = cKDTree(seam_d).query(dirs)
        clear_of_seam = dist * mean_r > clear
        q, dirs = q[clear_of_seam], dirs[clear_of_seam]
        # Uniform directions on the skull, rings on the neck and the shoulders' start.
        neck, alpha_top = self._neck_rings()
        neck = neck[_inside_polygon(stereo(neck), seam_q)]
        # Clear of the seam in mm on the surface (seen from the centre the throat is grazed: an
        # angular clearance there left a gap of long triangles under the chin).
        at = self.model.warp(c + neck * self.model.radius(neck)[:, None])
        neck = neck[cKDTree(seam_p).query(at)[0] > clear]
        alpha = np.arccos(np.clip(-dirs[:, 1], -1.0, 1.0))
        q = np.concatenate([q[alpha > alpha_top], stereo(neck)])
        plane = np.concatenate([seam_q, rings, q])
        tri = Delaunay(plane).simplices
        centroid = plane[tri].mean(axis=1)
        tri = tri[_inside_polygon(centroid, seam_q)]
        n_seam = len(seam)
        edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        have = set(map(tuple, edges[(edges < n_seam).all(axis=1)].tolist()))
        missing = [i for i in range(n_seam) if tuple(sorted((i, (i + 1) % n_seam))) not in have]
        if missing:
            raise ValueError(f"the head shell misses {len(missing)} edges of the face's outer boundary; "
                             "these identity parameters give a boundary the shell cannot follow")
        d = unstereo(plane)
        radius = self.shell_radius(d)
        verts = self.model.warp(c + d * radius[:, None])
        verts[:n_seam] = seam_p
        tri = flip_to_delaunay(verts, plane, tri)
        # Counter-clockwise seen from outside: the normal points away from the centre.
        e1, e2 = verts[tri[:, 1]] - verts[tri[:, 0]], verts[tri[:, 2]] - verts[tri[:, 0]]
        outward = (np.cross(e1, e2) * (verts[tri].mean(axis=1) - c)).sum(axis=1)
        if np.median(outward) < 0:
            tri = tri[:, [0, 2, 1]]
        return HeadShell(verts, tri, plane, seam)

    def _neck_rings(self) -> tuple[np.ndarray, float]:
        """(k, 3) unit directions of the shell's vertices on the neck and below, and the angle (rad)
        from straight down beyond which the shell's uniform directions take over.

        Uniform directions suit the skull, which faces the centre; seen from the centre the throat is
        grazed (the triangles came out long and thin) and the shoulders' flare stretches the shell
        (three times too long, a ragged rim on the cap). Here the vertices lie on rings around the
        straight-down direction (about horizontal on the neck, concentric on the cap), spaced
        ``FLARE_SPACING`` mm apart once flared, along each ring and, about, along the profile."""
        c = self.model.centre
        L = self.layout
        alpha = np.linspace(0.0, np.radians(100.0), 401)
        theta = np.linspace(0.0, 2 * np.pi, 97)[:-1]
        A, T = np.meshgrid(alpha, theta, indexing="ij")
        d = np.stack([np.sin(A) * np.cos(T), -np.cos(A), np.sin(A) * np.sin(T)], -1).reshape(-1, 3)
        points = self.model.warp(c + d * self.model.radius(d)[:, None]).reshape(len(alpha), len(theta), 3)
        # Up to just above the chin at the sides (theta = 0 and pi): the jaw's angle and the skull above
        # face the centre.
        sides = points[:, [0, len(theta) // 2], 1].min(axis=1)
        top = int(np.argmax(sides > L.menton_y + 10.0 * self.model.scale[1]))
        alpha, points = alpha[:top + 1], points[:top + 1]
        profile = np.concatenate([np.zeros((1, len(theta))),
                                  np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=2), axis=0)])
        n_rings = max(2, int(round(profile[-1].max() / FLARE_SPACING)))
        share = np.linspace(0.0, 1.0, n_rings + 1)[1:]
        # Per meridian, the rings at equal shares of its length: ring_alpha (rings, theta), ring_points.
        ring_alpha = np.column_stack([np.interp(share * profile[-1, j], profile[:, j], alpha)
                                      for j in range(len(theta))])
        ring_points = np.stack([np.column_stack([np.interp(ring_alpha[:, j], alpha, points[:, j, i])
                                                 for i in range(3)]) for j in range(len(theta))], axis=1)
        out = [np.array([[0.0, -1.0, 0.0]])]
        period = np.concatenate([theta, [2 * np.pi]])
        for k in range(n_rings):
            closed = np.concatenate([ring_points[k], ring_points[k, :1]])
            along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
            count = max(6, int(round(along[-1] / FLARE_SPACING)))
            t = np.interp((np.arange(count) + 0.5 * (k % 2)) * along[-1] / count, along, period)
            a = np.interp(t, period, np.concatenate([ring_alpha[k], ring_alpha[k, :1]]))
            out.append(np.column_stack([np.sin(a) * np.cos(t), -np.cos(a), np.sin(a) * np.sin(t)]))
        # Uniform directions keep clear of the top ring by about half a spacing.
        top_radius = float(np.linalg.norm(self.model.centre - points[-1], axis=1).min())
        return np.concatenate(out), float(alpha[-1]) + 0.5 * FLARE_SPACING / top_radius

    # ------------------------------------------------------------ ears
    def ears(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Both ears: vertices (2k, 3), triangles (2m, 3) local to them, and local texture
        coordinates (2k, 2) in [0, 1] (both ears use the same patch)."""
        L = self.layout
        _, sh = self.scale_factors()
        height, width = 62.0 * sh, 33.0 * sh
        s = np.linspace(0.0, 1.0, EAR_RINGS + 1)[1:]
        t = np.linspace(0.0, 2 * np.pi, EAR_SEGMENTS, endpoint=False)
        S, T = np.meshgrid(s, t, indexing="ij")
        # Outline: an egg, wider at the top (helix) than at the lobe.
        a = np.cos(T) * (0.5 * width) * (1.0 + 0.12 * np.sin(T))
        b = np.sin(T) * 0.5 * height
        u, v = S * a, S * b
        # Thickness: the helix rim rolls outward, the concha is a bowl in front of the middle.
        rim = np.exp(-(((S - 0.86) / 0.09) ** 2))
        concha = np.exp(-(((u + 0.1 * width) / (0.22 * width)) ** 2) - (((v + 0.02 * height) / (0.2 * height)) ** 2))
        lobe = _smoothstep(-0.15 * height, -0.45 * height, v)
        out = 4.0 + 5.0 * rim - 4.5 * concha * (1 - lobe) + 1.0 * lobe
        out = out * np.sqrt(np.clip(1.0 - S ** 8, 0, None)) + 0.6
        back = -2.0 * np.sqrt(np.clip(1.0 - S ** 4, 0, None)) - 0.3
        pts = []
        for side in (out, back):
            grid = np.stack([u, v, side], -1).reshape(-1, 3)
            pts.append(np.concatenate([[[0.0, 0.0, side[0, 0]]], grid]))   # the centre, then the rings
        n_side = len(pts[0])
        # Close the outline: the two sides share their last ring.
        pts[1][-EAR_SEGMENTS:] = pts[0][-EAR_SEGMENTS:]
        local = np.concatenate(pts)
        cap = polar_cap_triangles(EAR_RINGS, EAR_SEGMENTS)
        tris = np.concatenate([cap, cap[:, [0, 2, 1]] + n_side])
        # Weld the shared outline ring of the back side onto the front side's.
        last = np.arange(n_side - EAR_SEGMENTS, n_side)
        lut = np.arange(2 * n_side)
        lut[last + n_side] = last
        tris = lut[tris]
        used = np.unique(tris)
        remap = np.full(2 * n_side, -1)
        remap[used] = np.arange(len(used))
        local, tris = local[used], remap[tris]
        tex = np.column_stack([local[:, 0] / width + 0.5, local[:, 1] / height + 0.5])
        # Place (left ear; the right one mirrors it). Local u runs forward, v up, n outward. The long
        # axis leans back, the back edge stands off the head about the front edge (the tragus).
        lean, flare = np.radians(15.0), np.radians(22.0)
        uu, vv, nn = local[:, 0], local[:, 1], local[:, 2]
        u1 = uu * np.cos(lean) - vv * np.sin(lean)
        v1 = uu * np.sin(lean) + vv * np.cos(lean)
        behind = 0.5 * width - u1
        lateral = nn * np.cos(flare) + behind * np.sin(flare)
        backward = behind * np.cos(flare) - nn * np.sin(flare)
        ear_y = (L.eye_line_y + L.subnasale_y) / 2.0 + 6.0 * sh
        front_z = -92.0
        root_x = self._head_side_x(ear_y, front_z - 0.5 * width) - 3.0
        left = np.column_stack([root_x + lateral, ear_y + v1, front_z - backward])
        right = left * [-1, 1, 1]
        n = len(local)
        verts = np.concatenate([left, right])
        # Outward (counter-clockwise from outside) on the left ear; mirroring turns the right one over.
        tris_all = np.concatenate([tris[:, [0, 2, 1]], tris + n])
        return verts, tris_all, np.concatenate([tex, tex])

    def scale_factors(self) -> tuple[float, float]:
        """(width, height) of this identity's face relative to the default's."""
        return self.model.scale

    def _head_side_x(self, y: float, z: float) -> float:
        """x of the head model's side surface at height y, depth z (left side)."""
        xs = np.linspace(0.0, 150.0, 601)
        p = np.column_stack([xs, np.full_like(xs, y), np.full_like(xs, z)])
        inside = self.model.field(p) < 0
        return float(xs[np.nonzero(inside)[0][-1]]) if inside.any() else 70.0


# ---------------------------------------------------------------- texture (the head atlas)
ATLAS_WIDTH = 480          # pixels added to the right of the face's 640x480 texture
EAR_PATCH = (4, 404, 116, 72)      # (x, y from the top, width, height) pixels inside the atlas block
SHELL_PATCH = (4, 4, 472, 392)

# Hairline around the head: height y (mm) against the azimuth from the front (rad, 0 = front,
# pi = back): above the temples it meets the face's painted hairline at the seam, dips above the
# ears and reaches the nape behind them.
_HAIR_AZIMUTH = (0.0, 0.75, 1.15, 1.45, 1.75, 2.2, 2.6, np.pi)
_HAIR_HEIGHT = (85.0, 70.0, 62.0, 55.0, 42.0, -8.0, -27.0, -30.0)
HAIR_AXIS_Z = -110.0


def hair_mask(layout: FaceLayout, points: np.ndarray, soft_mm: float = 2.5, jitter: np.ndarray | None = None) -> np.ndarray:
    """(k,) in [0, 1]: how much of the hair covers each head point (k, 3), fading over ``soft_mm``
    at the hairline; ``jitter`` (k,) mm moves the hairline up or down point by point (wisps)."""
    sh = layout.p.face_height / 121.0
    azimuth = np.arctan2(np.abs(points[:, 0]), points[:, 2] - HAIR_AXIS_Z)
    height = layout.hairline_y + (np.interp(azimuth, _HAIR_AZIMUTH, _HAIR_HEIGHT) - 85.0) * sh
    if jitter is not None:
        height = height - jitter
    return 1.0 / (1.0 + np.exp(np.clip((height - points[:, 1]) / (0.25 * soft_mm), -50, 50)))


def shell_atlas_map(q: np.ndarray, q_box: tuple[float, float, float, float]) -> np.ndarray:
    """(k, 2) pixel positions (x from the atlas block's left, y from the top) of plane coordinates q."""
    x0, y0, w, h = SHELL_PATCH
    qx0, qy0, qw, qh = q_box
    s = min(w / qw, h / qh)
    return np.column_stack([x0 + (q[:, 0] - qx0) * s, y0 + (qy0 + qh - q[:, 1]) * s])


SEAM_BLEND_PX = 9.0   # atlas pixels over which the seam's colour fades into the shell's own


def paint_head_atlas(layout: FaceLayout, builder: HeadBuilder, q_box, base_rgb: np.ndarray,
                     hair_rgb: np.ndarray, seed: int, seam=None) -> np.ndarray:
    """(480, ATLAS_WIDTH, 3) uint8: the shell's skin and hair (by the texel's point on the head
    model) and the ears' patch (skin, the bowl darker). ``seam`` = (pixel positions (k, 2) of the
    seam vertices, their colours (k, 3) on the face): texels near the seam fade to those colours."""
    from scipy import ndimage

    H, W = 480, ATLAS_WIDTH
    rng = np.random.default_rng(seed + 101)
    py, px = np.mgrid[0:H, 0:W] + 0.5
    x0, y0, w, h = SHELL_PATCH
    qx0, qy0, qw, qh = q_box
    s = min(w / qw, h / qh)
    q = np.column_stack([qx0 + (px.ravel() - x0) / s, qy0 + qh - (py.ravel() - y0) / s])
    d = unstereo(q)
    points = builder.model.centre + d * builder.model.radius(d, steps=22)[:, None]
    def noise(sigma):
        a = ndimage.gaussian_filter(rng.standard_normal((H, W)), sigma)
        return (a - a.mean()) / (a.std() + 1e-12)

    # The hairline thins out in wisps like the face's (texture.HAIRLINE_*); own generator, so the
    # skin's noise below is unchanged.
    from core.default_face.texture import HAIRLINE_SOFT_MM, HAIRLINE_WISPS_MM

    wisps = ndimage.gaussian_filter(np.random.default_rng(seed + 211).standard_normal((H, W)), (1.5, 0.5))
    wisps = (wisps - wisps.mean()) / (wisps.std() + 1e-12)
    hair = hair_mask(layout, points, soft_mm=HAIRLINE_SOFT_MM, jitter=HAIRLINE_WISPS_MM * wisps.ravel()).reshape(H, W)

    img = np.broadcast_to(base_rgb, (H, W, 3)) * (1.0 + 0.04 * noise(6.0) + 0.02 * noise(1.5))[..., None]
    strands = 0.75 + 0.25 * np.clip(noise(0.7), -2, 2) / 2
    img = img * (1 - 0.97 * hair[..., None]) + (hair_rgb * strands[..., None]) * (0.97 * hair[..., None])
    if seam is not None:
        seam_px, seam_rgb = seam
        dist, nearest = cKDTree(seam_px).query(np.column_stack([px.ravel(), py.ravel()]))
        w = np.exp(-((dist / SEAM_BLEND_PX) ** 2)).reshape(H, W, 1)
        img = img * (1 - w) + seam_rgb[nearest].reshape(H, W, 3) * w
    # Ear patch: skin, a little redder, darker toward the middle (the concha and the canal).
    ex, ey, ew, eh = EAR_PATCH
    patch = (px >= ex) & (px < ex + ew) & (py >= ey) & (py < ey + eh)
    u = (px[patch] - ex) / ew - 0.5
    v = (py[patch] - ey) / eh - 0.5
    rho = np.sqrt((u / 0.5) ** 2 + (v / 0.5) ** 2)
    # The ears take the skin colour the face has at its rim (the painted face is not the plain base tone:
    # base-coloured ears stood out, salmon against the face).
    skin = np.median(seam[1], axis=0) if seam is not None else base_rgb
    ear = skin * np.array([1.02, 0.96, 0.95])
    shade = 1.0 - 0.15 * np.exp(-((rho / 0.3) ** 2))
    img[patch] = ear[None] * shade[:, None]
    return np.clip(img, 0, 255).astype(np.uint8)
