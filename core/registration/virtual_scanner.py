"""Virtual range scanner: any textured Face -> a single-view scan like the thesis's Vivid 910 (A §2.1).

What a scan looks like (thesis A §2.1): a depth sample per (x, y) grid point seen from one
viewpoint, ~50,000 vertices, a registered 640x480 colour image, triangulated by a 2-D Delaunay
triangulation of the (x, y) samples; vertex indices carry no correspondence between scans.

How it is made here:

1. **Pose.** The source (``vertices`` if given, e.g. ``rig.vertices()``) is moved by a random
   rigid transform about the centre of its bounding box: a rotation vector with each component
   ~ N(0, ``pose_jitter_deg``) degrees and a translation with each component
   ~ N(0, ``pose_jitter_mm``). The 4x4 matrix is returned as ``ScanResult.transform``.
2. **Camera.** Looking along -z from in front of the face: ``camera="orthographic"`` (default;
   parallel rays, the face's own x/y frame) or ``"pinhole"`` (rays from an eye point
   ``distance_mm`` in front of the face's front plane; the Vivid 910 works at 0.6-2.5 m). The
   image window is the projected bounding box, padded by 2 % and widened to the aspect of
   ``texture_size``.
3. **Depth grid.** A coarse 160x120 ray pass measures how much of the window the face covers; the
   grid spacing is then chosen so that about ``n_target`` rays hit. Rays are cast with Embree
   (embreex through ``trimesh.ray.ray_pyembree``; ~3.6 Mrays/s); without Embree (or with
   ``engine="zbuffer"``) an orthographic camera uses a vectorised z-buffer: triangles rasterised
   onto the ray grid in far-to-near order of their centroids, the nearest written last (same
   samples as Embree on the test surfaces; a pinhole camera then raises). Hits on surfaces seen at a
   grazing angle (|cos| < ``min_cos`` = 0.1, beyond ~84 deg) are dropped, as a triangulation
   scanner loses them. What is visible is kept, including eyeballs through the lid openings and
   the mouth cavity and teeth through parted lips (a real scanner sees those too; the cavity is
   dark and the teeth light in the colour image).
4. **Noise and holes.** Gaussian noise of ``noise_mm`` along each ray (depth noise); ``holes``
   discs of missing samples (radius uniform in ``hole_radius_mm``, centres on random samples),
   like the scanner's shadow holes.
5. **Colour image.** A second ray grid of ``texture_size`` texels over the same window; each texel
   takes the source's colour at the hit (its texture through the hit's interpolated uv, bilinear;
   else its vertex colours; else light grey) times a Lambert term for a lamp at the camera
   (``shading`` = 0.35: 1 - s + s cos), like the scanner's own lamps. Missed texels are black.
   Scan uv = the vertex's position in the window, so the image is the scan's texture.
6. **Mesh.** 2-D Delaunay triangulation of the kept samples' image-plane positions. The samples
   lie on a regular ray grid, where the Delaunay triangulation is the cell split (the 4 corners
   of a cell are cocircular, either diagonal is Delaunay; the shorter 3-D diagonal is taken, and
   cells with 3 samples give 1 triangle): ``range_image.grid_triangles`` builds it in O(n) --
   Qhull needed 1.3-2.6 s for 50k degenerate grid points. Triangles with a 3-D edge longer than
   ``max_edge_factor`` x the grid spacing are dropped (depth discontinuities: nose side, lid over
   eyeball, lips); triangles are oriented counter-clockwise seen from the camera; unused samples
   are removed. Vertex order is row-major over the grid, unrelated to the source's.
7. **Ground truth.** Every source landmark, evaluated on the posed source, is bound to the closest
   point of the scan (a SurfacePoint). ``landmark_error_mm`` gives each one's distance from the
   posed source landmark: ~0 (noise aside) for visible landmarks, large for ones the scanner
   cannot see (e.g. teeth feature points behind closed lips) -- filter on it. Each scan vertex's
   source triangle and barycentric coordinates are returned too (dense ground truth).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.face import Face, FaceMetadata, SurfacePoint


class ScanError(ValueError):
    """Bad input to the virtual scanner."""


@dataclass(frozen=True)
class ScanResult:
    """A virtual scan.

    Attributes
    ----------
    face : Face
        The scan: ~n_target vertices, Delaunay triangles, uv, texture (H, W, 3) and the source's
        landmarks as SurfacePoints of the scan.
    transform : (4, 4) float
        The rigid pose applied to the source before scanning (source -> scan coordinates).
    landmark_error_mm : dict name -> float
        Distance of each transferred landmark from the posed source landmark, mm.
    source_triangle : (n,) int
        Source triangle hit by each scan vertex's ray.
    source_bary : (n, 3) float
        Barycentric coordinates of the hit in that triangle (before noise).
    spacing_mm : float
        Depth-grid spacing in the image plane, mm.
    """

    face: Face
    transform: np.ndarray
    landmark_error_mm: dict = field(default_factory=dict)
    source_triangle: np.ndarray | None = None
    source_bary: np.ndarray | None = None
    spacing_mm: float = 0.0

    def visible_landmarks(self, tolerance_mm: float = 1.0) -> list[str]:
        """Names of landmarks whose transferred position is within ``tolerance_mm`` of the truth."""
        return [n for n, e in self.landmark_error_mm.items() if e <= tolerance_mm]


def random_pose(centre, jitter_deg: float, jitter_mm: float, rng) -> np.ndarray:
    """(4, 4) rigid transform: rotation vector ~ N(0, jitter_deg) deg per axis about ``centre``,
    translation ~ N(0, jitter_mm) mm per axis."""
    from core.registration.icp import rigid_transform, rotation_about_axis

    c = np.asarray(centre, dtype=np.float64)
    w = rng.normal(0.0, jitter_deg, size=3) if jitter_deg > 0 else np.zeros(3)
    t = rng.normal(0.0, jitter_mm, size=3) if jitter_mm > 0 else np.zeros(3)
    angle = float(np.linalg.norm(w))
    R = rotation_about_axis(w, angle) if angle > 0 else np.eye(3)
    return rigid_transform(R, c + t - R @ c)


class _Camera:
    """Maps image-plane points (a, b) (mm on the plane z = ``z_plane``) to rays and back."""

    def __init__(self, kind: str, verts: np.ndarray, distance_mm: float, aspect: float):
        self.kind = kind
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        self.z_plane = float(hi[2])
        self.centre_xy = (lo[:2] + hi[:2]) / 2
        self.eye = np.array([*self.centre_xy, self.z_plane + distance_mm])
        self.distance = float(distance_mm)
        ab = self.project(verts)
        lo2, hi2 = ab.min(axis=0), ab.max(axis=0)
        size = (hi2 - lo2) * 1.04
        centre = (lo2 + hi2) / 2
        if size[0] / size[1] < aspect:
            size[0] = size[1] * aspect
        else:
            size[1] = size[0] / aspect
        self.a0, self.b0 = centre - size / 2
        self.width, self.height = size
        self.front = float(hi[2]) + 10.0  # orthographic ray origins: in front of everything

    def project(self, pts) -> np.ndarray:
        pts = np.asarray(pts, float)
        if self.kind == "orthographic":
            return pts[:, :2].copy()
        depth = self.eye[2] - pts[:, 2]
        return self.eye[:2] + (pts[:, :2] - self.eye[:2]) * (self.distance / depth)[:, None]

    def rays(self, a, b) -> tuple[np.ndarray, np.ndarray]:
        a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
        if self.kind == "orthographic":
            origins = np.column_stack([a, b, np.full(len(a), self.front)])
            dirs = np.tile([0.0, 0.0, -1.0], (len(a), 1))
        else:
            target = np.column_stack([a, b, np.full(len(a), self.z_plane)])
            origins = np.tile(self.eye, (len(a), 1))
            dirs = target - origins
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        return origins, dirs

    def grid(self, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
        """Texel-centre grid (ny, nx): a to the right, b up (row 0 at the top)."""
        a = self.a0 + (np.arange(nx) + 0.5) / nx * self.width
        b = self.b0 + self.height - (np.arange(ny) + 0.5) / ny * self.height
        return np.meshgrid(a, b)


class _Caster:
    """First-hit ray casting: Embree when available, else an orthographic z-buffer."""

    def __init__(self, verts, tris, camera: _Camera, engine: str = "auto"):
        self.verts, self.tris, self.camera = verts, tris, camera
        self.embree = None
        if engine in ("auto", "embree"):
            try:
                import trimesh
                from trimesh.ray.ray_pyembree import RayMeshIntersector

                mesh = trimesh.Trimesh(verts, tris, process=False, validate=False)
                self.embree = RayMeshIntersector(mesh, scale_to_box=False)
            except Exception as exc:  # embreex missing or broken: fall back below
                if engine == "embree":
                    raise ScanError(f"Embree ray casting is unavailable ({exc}); install embreex") from exc
        if self.embree is None and camera.kind != "orthographic":
            raise ScanError("the pinhole virtual camera needs Embree (pip install embreex); "
                            "use camera='orthographic'")

    def cast(self, a, b):
        """Returns (ray index (h,), triangle (h,), location (h, 3), direction (h, 3))."""
        origins, dirs = self.camera.rays(a, b)
        if self.embree is not None:
            tri = self.embree.intersects_first(origins, dirs)
            hit = np.nonzero(tri >= 0)[0]
            tri = tri[hit]
            # Exact hit point by ray/plane intersection with the hit triangle (Embree is float32).
            c0 = self.verts[self.tris[tri, 0]]
            n = np.cross(self.verts[self.tris[tri, 1]] - c0, self.verts[self.tris[tri, 2]] - c0)
            denom = np.einsum("ij,ij->i", n, dirs[hit])
            ok = np.abs(denom) > 1e-300
            t = np.einsum("ij,ij->i", n, c0 - origins[hit]) / np.where(ok, denom, 1.0)
            hit, tri, t = hit[ok], tri[ok], t[ok]
            return hit, tri, origins[hit] + t[:, None] * dirs[hit], dirs[hit]
        return self._zbuffer(np.asarray(a).ravel(), np.asarray(b).ravel(), origins, dirs)

    def _zbuffer(self, a, b, origins, dirs):
        # Orthographic only: the grid is regular, so rasterise triangles onto it and keep max z.
        ux = np.unique(a)
        uy = np.unique(b)
        nx, ny = len(ux), len(uy)
        dx = (ux[-1] - ux[0]) / max(nx - 1, 1) if nx > 1 else 1.0
        dy = (uy[-1] - uy[0]) / max(ny - 1, 1) if ny > 1 else 1.0
        from core.registration.candidates import uv_raster

        # Map x/y into "uv" of an (nx, ny) image whose texel centres are the ray positions.
        uv = np.column_stack([(self.verts[:, 0] - ux[0]) / (dx * nx) + 0.5 / nx,
                              (self.verts[:, 1] - uy[0]) / (dy * ny) + 0.5 / ny])
        # Painter's order: draw far triangles first so the nearest one is written last.
        order = np.argsort(self.verts[self.tris].mean(axis=1)[:, 2])
        raster = uv_raster(uv, self.tris[order], (nx, ny))
        tri_img = np.where(raster.triangle >= 0, order[np.maximum(raster.triangle, 0)], -1)[::-1]
        col = np.rint((a - ux[0]) / dx).astype(int) if nx > 1 else np.zeros(len(a), int)
        row = np.rint((b - uy[0]) / dy).astype(int) if ny > 1 else np.zeros(len(b), int)
        tri = tri_img[row, col]
        hit = np.nonzero(tri >= 0)[0]
        tri = tri[hit]
        bary = raster.bary[::-1][row[hit], col[hit]]
        # Re-order bary to the unpermuted triangle corners (same corner order, only rows moved).
        loc = np.einsum("kj,kjd->kd", bary, self.verts[self.tris[tri]])
        return hit, tri, loc, dirs[hit]


def _barycentric(p, a, b, c) -> np.ndarray:
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    den = np.where(np.abs(den) > 1e-300, den, 1.0)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    bary = np.clip(np.column_stack([1 - v - w, v, w]), 0.0, None)
    return bary / np.maximum(bary.sum(axis=1, keepdims=True), 1e-300)


def _sample_colour(face: Face, tri, bary) -> np.ndarray:
    """(h, 3) float RGB 0..255 of the source at the given surface points."""
    if face.texture is not None and face.uv is not None:
        import cv2

        uv = np.einsum("kj,kjd->kd", bary, face.uv[face.triangles[tri]])
        h, w = face.texture.shape[:2]
        k = len(uv)
        cols = 1024  # remap maps must stay below 32767 rows: lay the samples out as an image
        rows = max(1, -(-k // cols))
        mapx = np.zeros(rows * cols, np.float32)
        mapy = np.zeros(rows * cols, np.float32)
        mapx[:k] = uv[:, 0] * w - 0.5
        mapy[:k] = (1.0 - uv[:, 1]) * h - 0.5
        out = cv2.remap(np.ascontiguousarray(face.texture), mapx.reshape(rows, cols), mapy.reshape(rows, cols),
                        cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(-1, 3)[:k].astype(np.float64)
    if face.vertex_colors is not None:
        return np.einsum("kj,kjd->kd", bary, face.vertex_colors[face.triangles[tri]].astype(np.float64))
    return np.full((len(tri), 3), 200.0)


def scan_face(face: Face, *, vertices=None, n_target: int = 50_000, texture_size=(640, 480),
              noise_mm: float = 0.0, holes: int = 0, pose_jitter_deg: float = 0.0,
              pose_jitter_mm: float = 0.0, rng=None, camera: str = "orthographic",
              distance_mm: float = 800.0, hole_radius_mm=(3.0, 8.0), shading: float = 0.35,
              max_edge_factor: float = 4.0, min_cos: float = 0.1, engine: str = "auto") -> ScanResult:
    """Scan ``face`` (optionally at deformed ``vertices``) from the front. See the module docstring.

    Parameters
    ----------
    face : Face (textured or with vertex colours for a colour image)
    vertices : (n, 3) float, mm, optional deformed positions of ``face`` (e.g. ``rig.vertices()``)
    n_target : int, wanted number of scan vertices (the result is within ~10 %)
    texture_size : (width, height) of the colour image, texels
    noise_mm : float, standard deviation of the depth noise, mm
    holes : int, number of missing-sample discs
    pose_jitter_deg, pose_jitter_mm : float, standard deviations of the random pose
    rng : numpy Generator or int seed, optional
    camera : "orthographic" | "pinhole"
    distance_mm : float, pinhole eye distance in front of the face's front plane, mm
    hole_radius_mm : (min, max) radius of the holes, mm
    shading : float in [0, 1], strength of the camera-lamp Lambert term in the colour image
    max_edge_factor : float, longest kept 3-D edge in units of the grid spacing
    min_cos : float, smallest |cos| between ray and surface normal kept
    engine : "auto" | "embree" | "zbuffer", ray casting (auto = Embree if it works)

    Returns
    -------
    ScanResult
    """
    v = face.vertices if vertices is None else np.asarray(vertices, dtype=np.float64)
    if v.shape != face.vertices.shape:
        raise ScanError(f"vertices must have the face's shape {face.vertices.shape}, got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ScanError("vertices contain NaN or inf")
    if face.n_triangles == 0:
        raise ScanError("the face has no triangles to scan")
    if n_target < 100:
        raise ScanError(f"n_target must be >= 100, got {n_target}")
    tw, th = (int(s) for s in texture_size)
    if tw < 8 or th < 8:
        raise ScanError(f"texture_size must be at least 8x8 texels, got {texture_size}")
    if noise_mm < 0 or pose_jitter_deg < 0 or pose_jitter_mm < 0 or holes < 0:
        raise ScanError("noise_mm, holes, pose_jitter_deg and pose_jitter_mm must be >= 0")
    if camera not in ("orthographic", "pinhole"):
        raise ScanError(f"camera must be 'orthographic' or 'pinhole', got {camera!r}")
    if engine not in ("auto", "embree", "zbuffer"):
        raise ScanError(f"engine must be 'auto', 'embree' or 'zbuffer', got {engine!r}")
    if not 0.0 <= shading <= 1.0:
        raise ScanError(f"shading must be in [0, 1], got {shading}")
    rng = np.random.default_rng(rng)

    from core.registration.icp import apply_transform

    used = np.zeros(face.n_vertices, bool)
    used[face.triangles.ravel()] = True
    lo, hi = v[used].min(axis=0), v[used].max(axis=0)
    T = random_pose((lo + hi) / 2, pose_jitter_deg, pose_jitter_mm, rng)
    posed = apply_transform(v, T)
    cam = _Camera(camera, posed[used], distance_mm, tw / th)
    caster = _Caster(posed, face.triangles, cam, engine)
    tri_normals = _unit_normals(posed, face.triangles)

    # Coarse pass: covered area -> grid spacing for ~n_target samples.
    A, B = cam.grid(160, 120)
    hit, _, _, _ = caster.cast(A, B)
    coverage = max(len(hit), 1) / A.size
    spacing = float(np.sqrt(coverage * cam.width * cam.height / n_target))
    nx = max(2, int(round(cam.width / spacing)))
    ny = max(2, int(round(cam.height / spacing)))
    A, B = cam.grid(nx, ny)
    ray, tri, loc, dirs = caster.cast(A, B)
    cosines = np.einsum("ij,ij->i", tri_normals[tri], dirs)
    keep = np.abs(cosines) >= min_cos
    ray, tri, loc, dirs = ray[keep], tri[keep], loc[keep], dirs[keep]
    ab = np.column_stack([A.ravel()[ray], B.ravel()[ray]])
    if holes:
        r_lo, r_hi = hole_radius_mm
        centres = ab[rng.choice(len(ab), size=int(holes), replace=len(ab) < holes)]
        radii = rng.uniform(r_lo, r_hi, size=int(holes))
        inside = np.zeros(len(ab), bool)
        for c, r in zip(centres, radii):  # one vectorised test per hole (a handful)
            inside |= np.sum((ab - c) ** 2, axis=1) <= r * r
        ray, tri, loc, dirs, ab = ray[~inside], tri[~inside], loc[~inside], dirs[~inside], ab[~inside]
    if len(loc) < 3:
        raise ScanError("the scan hit fewer than 3 points: is the face in front of the camera (+z)?")
    corners = posed[face.triangles[tri]]
    bary = _barycentric(loc, corners[:, 0], corners[:, 1], corners[:, 2])
    if noise_mm > 0:
        loc = loc + dirs * rng.normal(0.0, noise_mm, size=(len(loc), 1))

    # Colour image: a ray per texel.
    A_t, B_t = cam.grid(tw, th)
    ray_t, tri_t, loc_t, dirs_t = caster.cast(A_t, B_t)
    corners_t = posed[face.triangles[tri_t]]
    bary_t = _barycentric(loc_t, corners_t[:, 0], corners_t[:, 1], corners_t[:, 2])
    colour = _sample_colour(face, tri_t, bary_t)
    lambert = np.abs(np.einsum("ij,ij->i", tri_normals[tri_t], dirs_t))
    colour *= (1.0 - shading + shading * lambert)[:, None]
    texture = np.zeros((th * tw, 3), dtype=np.uint8)
    texture[ray_t] = np.clip(np.rint(colour), 0, 255).astype(np.uint8)
    texture = texture.reshape(th, tw, 3)

    # Mesh: Delaunay in the image plane, long edges dropped.
    index = np.full(ny * nx, -1, dtype=np.int64)
    index[ray] = np.arange(len(ray))
    triangles = _triangulate(index.reshape(ny, nx), ab, loc, spacing, max_edge_factor, cam)
    referenced = np.zeros(len(loc), bool)
    referenced[triangles.ravel()] = True
    remap = np.cumsum(referenced) - 1
    triangles = remap[triangles]
    loc, ab, tri, bary = loc[referenced], ab[referenced], tri[referenced], bary[referenced]
    uv = np.column_stack([(ab[:, 0] - cam.a0) / cam.width, (ab[:, 1] - cam.b0) / cam.height])

    scan = Face(loc, triangles, uv=uv, texture=texture,
                metadata=FaceMetadata(source=f"virtual scan of {face.metadata.name}", units="mm",
                                      name=f"scan of {face.metadata.name}"))
    errors = _transfer_landmarks(face, v, T, scan)
    far = [n for n, e in errors.items() if e > 1.0]
    scan.metadata.notes.append(
        f"Virtual {camera} scan: {scan.n_vertices} vertices, grid spacing {spacing:.3f} mm, "
        f"noise {noise_mm} mm, {holes} holes, pose jitter {pose_jitter_deg} deg / {pose_jitter_mm} mm.")
    if far:
        scan.metadata.notes.append(
            f"{len(far)} landmark(s) not visible to the scanner (bound > 1 mm away): {', '.join(far)}")
    return ScanResult(face=scan, transform=T, landmark_error_mm=errors, source_triangle=tri,
                      source_bary=bary, spacing_mm=spacing)


def _unit_normals(v, t) -> np.ndarray:
    from core.face import triangle_normals

    return triangle_normals(v, t)


def _triangulate(index, ab, loc, spacing, max_edge_factor, cam: _Camera) -> np.ndarray:
    from core.registration.range_image import grid_triangles

    tris = grid_triangles(index, loc)
    p = loc[tris]
    edges = np.stack([np.linalg.norm(p[:, 1] - p[:, 0], axis=1), np.linalg.norm(p[:, 2] - p[:, 1], axis=1),
                      np.linalg.norm(p[:, 0] - p[:, 2], axis=1)], axis=1).max(axis=1)
    limit = max_edge_factor * spacing
    if cam.kind == "pinhole":
        # Samples spread with depth behind the image plane.
        depth = cam.eye[2] - p[:, :, 2].max(axis=1)
        limit = limit * np.maximum(depth / cam.distance, 1.0)
    tris = tris[edges <= limit]
    # Counter-clockwise seen from the camera (+z): positive signed area in (a, b).
    q = ab[tris]
    area = (q[:, 1, 0] - q[:, 0, 0]) * (q[:, 2, 1] - q[:, 0, 1]) - (q[:, 2, 0] - q[:, 0, 0]) * (q[:, 1, 1] - q[:, 0, 1])
    tris = tris[np.abs(area) > 1e-12 * spacing * spacing]
    flip = area[np.abs(area) > 1e-12 * spacing * spacing] < 0
    tris[flip] = tris[flip][:, [0, 2, 1]]
    return tris


def _transfer_landmarks(source: Face, v, T, scan: Face) -> dict[str, float]:
    """Bind every source landmark (posed) to the closest point of the scan; returns errors (mm)."""
    from core.surface_query import TriangleSet
    from core.registration.icp import apply_transform

    names = source.landmark_names
    if not names:
        return {}
    truth = apply_transform(source.landmark_positions(names, vertices=v), T)
    pos, tri, bary = TriangleSet(scan.vertices, scan.triangles).closest(truth)
    errors = {}
    for name, t, b, p, q in zip(names, tri, bary, pos, truth):
        scan.set_landmark(name, SurfacePoint(int(t), tuple(b)))
        errors[name] = float(np.linalg.norm(p - q))
    return errors
