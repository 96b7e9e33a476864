"""Range images -> textured Face (thesis A §2.1: a depth per grid point + a registered colour image).

Inputs:

- a depth image (16-bit PNG, or NPY of integers or floats) in units of ``depth_scale_mm`` with
  pinhole intrinsics (fx, fy, cx, cy in pixels); 0 or NaN (or inf) means "no sample";
- or an (H, W, 3) grid of xyz positions in mm (NaN = no sample), as many scanners export.

Coordinates: the camera looks along -z. A pixel (col, row) at depth d becomes
x = (col - cx) d / fx, y = -(row - cy) d / fy, z = -d: +x to the image's right (the scanned
person's own left, the MPEG-4 convention of Face), +y up, the camera at the origin and the face at
negative z, nearer points having larger z. No recentring is done (ICP aligns scans anyway).

Triangulation: the grid's own quads (each 2x2 block of valid samples -> 2 triangles along the
shorter diagonal; a block with 3 valid samples -> 1 triangle), then triangles with a 3-D edge
longer than ``max_edge_mm`` are dropped (default 4 x the median grid edge: depth jumps at the
nose side, chin and hair). The thesis triangulated its Vivid 910 point clouds by 2-D Delaunay of
(x, y); for samples that already lie on a grid the quad split is the same mesh up to the choice of
diagonals, costs O(n) instead of O(n log n), never creates the convex-hull slivers Delaunay makes
across concave outlines, and does not need the (x, y) projection to be one-to-one (a pinhole grid
seen at an angle can fold in x, y). Delaunay remains in ``virtual_scanner`` for scattered samples.

Texture: uv from the pixel position (u = (col + 0.5) / W, v = 1 - (row + 0.5) / H), so the
registered colour image is the texture as is. The colour image may have a different resolution
than the depth grid but must have the same aspect ratio (it covers the same field of view).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.face import Face, FaceMetadata


class RangeImageError(ValueError):
    """Bad range-image input (missing file, dtype, sizes, intrinsics, no valid samples)."""


def _read_image(path: Path, what: str) -> np.ndarray:
    import cv2

    if not path.exists():
        raise RangeImageError(f"{what} file not found: {path}")
    if path.suffix.lower() == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except ValueError as exc:
            raise RangeImageError(f"{what} file {path} is not a plain numeric .npy array: {exc}") from exc
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RangeImageError(f"cannot read {what} image {path} (unsupported format or damaged file)")
    return img


def load_range_image(depth_path, colour_path=None, *, intrinsics=None, depth_scale_mm: float = 1.0,
                     max_edge_mm: float | None = None) -> Face:
    """Read a depth image (+ registered colour image) into a textured Face.

    Parameters
    ----------
    depth_path : path to a 16-bit PNG (or TIFF) or an .npy (H, W) array; 0 / NaN = no sample
    colour_path : path to an 8-bit RGB image registered with the depth image, optional
    intrinsics : (fx, fy, cx, cy) in pixels, or a dict with those keys. Required.
    depth_scale_mm : float, millimetres per depth unit (e.g. 0.1 for a 1/10 mm PNG)
    max_edge_mm : float, optional; see :func:`face_from_xyz_grid`

    Raises
    ------
    RangeImageError
        Missing file or intrinsics, 8-bit or colour depth image, size mismatch, no valid samples.
    """
    if intrinsics is None:
        raise RangeImageError("a depth image needs pinhole intrinsics (fx, fy, cx, cy) in pixels: "
                              "pass intrinsics=(fx, fy, cx, cy), or give an xyz grid to face_from_xyz_grid")
    if isinstance(intrinsics, dict):
        try:
            intrinsics = tuple(intrinsics[k] for k in ("fx", "fy", "cx", "cy"))
        except KeyError as exc:
            raise RangeImageError(f"intrinsics dict needs keys fx, fy, cx, cy; missing {exc}") from exc
    try:
        fx, fy, cx, cy = (float(x) for x in intrinsics)
    except (TypeError, ValueError) as exc:
        raise RangeImageError(f"intrinsics must be 4 numbers (fx, fy, cx, cy), got {intrinsics!r}") from exc
    if not (fx > 0 and fy > 0) or not np.isfinite([fx, fy, cx, cy]).all():
        raise RangeImageError(f"focal lengths must be positive and all intrinsics finite, got {intrinsics!r}")
    if not depth_scale_mm > 0:
        raise RangeImageError(f"depth_scale_mm must be > 0, got {depth_scale_mm}")
    depth_path = Path(depth_path)
    depth = _read_image(depth_path, "depth")
    if depth.ndim != 2:
        raise RangeImageError(f"the depth image must have one channel, got shape {depth.shape} "
                              "(a colour image passed as depth?)")
    if depth.dtype == np.uint8 or depth.dtype == np.int8:
        raise RangeImageError("the depth image is 8-bit: depth needs 16-bit integers or floats "
                              "(an 8-bit PNG cannot hold depth at millimetre resolution)")
    if not (np.issubdtype(depth.dtype, np.integer) or np.issubdtype(depth.dtype, np.floating)):
        raise RangeImageError(f"the depth image must be integer or float, got dtype {depth.dtype}")
    d = depth.astype(np.float64) * depth_scale_mm
    d[~np.isfinite(d) | (d <= 0)] = np.nan
    H, W = d.shape
    col, row = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    xyz = np.stack([(col - cx) * d / fx, -(row - cy) * d / fy, -d], axis=-1)
    colour = None
    if colour_path is not None:
        import cv2

        img = _read_image(Path(colour_path), "colour")
        if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8:
            raise RangeImageError(f"the colour image must be 8-bit RGB, got shape {img.shape} dtype {img.dtype}")
        colour = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2RGB)
    face = face_from_xyz_grid(xyz, colour, max_edge_mm=max_edge_mm)
    face.metadata.source = str(depth_path)
    face.metadata.name = depth_path.stem
    face.metadata.notes.append(f"Range image {W}x{H}, depth scale {depth_scale_mm} mm/unit, "
                               f"intrinsics fx={fx:g} fy={fy:g} cx={cx:g} cy={cy:g}.")
    return face


def grid_triangles(index, positions) -> np.ndarray:
    """Triangles of a sampled image grid: (m, 3) int into ``positions``.

    ``index`` (H, W) int holds the sample id at each grid cell (-1 = no sample); ``positions``
    (n, 3) the samples. Each 2x2 block with 4 samples gives 2 triangles split along the shorter
    3-D diagonal, a block with 3 samples 1 triangle. Row 0 is the top of the image and columns go
    right, so the triangles are counter-clockwise seen from the viewer. For samples on a regular
    grid this is a Delaunay triangulation of their image positions (4 cocircular corners per
    block: either diagonal is Delaunay), built in O(n).
    """
    index = np.asarray(index, dtype=np.int64)
    pos = np.asarray(positions, dtype=np.float64)
    a, b = index[:-1, :-1], index[:-1, 1:]      # top-left, top-right
    c, d = index[1:, 1:], index[1:, :-1]        # bottom-right, bottom-left
    full = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
    diag_ac = np.full(a.shape, np.inf)
    diag_bd = np.full(a.shape, np.inf)
    diag_ac[full] = np.linalg.norm(pos[a[full]] - pos[c[full]], axis=1)
    diag_bd[full] = np.linalg.norm(pos[b[full]] - pos[d[full]], axis=1)
    use_bd = full & (diag_bd < diag_ac)
    use_ac = full & ~use_bd
    # Counter-clockwise seen from the viewer (rows go down the image): a, d, c and a, c, b.
    tris = [np.column_stack([a[use_ac], d[use_ac], c[use_ac]]), np.column_stack([a[use_ac], c[use_ac], b[use_ac]]),
            np.column_stack([a[use_bd], d[use_bd], b[use_bd]]), np.column_stack([b[use_bd], d[use_bd], c[use_bd]])]
    three = ~full & ((a >= 0).astype(int) + (b >= 0) + (c >= 0) + (d >= 0) == 3)
    for corners in ((a, d, c), (a, c, b), (a, d, b), (b, d, c)):
        sel = three & np.all([k >= 0 for k in corners], axis=0)
        tris.append(np.column_stack([k[sel] for k in corners]))
    return np.concatenate(tris).astype(np.int64)


def face_from_xyz_grid(xyz, colour=None, *, max_edge_mm: float | None = None) -> Face:
    """Triangulate an (H, W, 3) grid of positions (mm, NaN = no sample) into a Face.

    Parameters
    ----------
    xyz : (H, W, 3) float, mm
    colour : (h, w, 3) uint8 RGB, optional, registered with the grid (same aspect ratio)
    max_edge_mm : float, optional, longest kept 3-D edge (default 4 x the median grid edge)

    Returns
    -------
    Face with one vertex per valid sample (row-major order), uv from the pixel position and the
    colour image as texture.
    """
    xyz = np.asarray(xyz)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise RangeImageError(f"xyz must have shape (H, W, 3), got {xyz.shape}")
    if not np.issubdtype(xyz.dtype, np.floating):
        raise RangeImageError(f"xyz must be floating point with NaN for missing samples, got dtype {xyz.dtype}")
    H, W = xyz.shape[:2]
    if H < 2 or W < 2:
        raise RangeImageError(f"the grid must be at least 2x2, got {H}x{W}")
    xyz = xyz.astype(np.float64)
    valid = np.all(np.isfinite(xyz), axis=2)
    if valid.sum() < 3:
        raise RangeImageError(f"the range image has {int(valid.sum())} valid samples; need at least 3 "
                              "(is the depth scale or the invalid-value convention right?)")
    if colour is not None:
        colour = np.asarray(colour)
        if colour.ndim != 3 or colour.shape[2] != 3:
            raise RangeImageError(f"colour must be an (h, w, 3) RGB image, got shape {colour.shape}")
        if colour.dtype != np.uint8:
            raise RangeImageError(f"colour must be uint8, got dtype {colour.dtype}")
        if abs(colour.shape[1] / colour.shape[0] - W / H) > 0.01 * (W / H):
            raise RangeImageError(
                f"colour image {colour.shape[1]}x{colour.shape[0]} does not match the {W}x{H} range grid: "
                "a registered colour image must cover the same field of view (same aspect ratio)")

    index = np.full((H, W), -1, dtype=np.int64)
    index[valid] = np.arange(valid.sum())
    P = xyz
    triangles = grid_triangles(index, xyz[valid])
    vertices = xyz[valid]
    if len(triangles):
        p = vertices[triangles]
        longest = np.max(np.stack([np.linalg.norm(p[:, 1] - p[:, 0], axis=1), np.linalg.norm(p[:, 2] - p[:, 1], axis=1),
                                   np.linalg.norm(p[:, 0] - p[:, 2], axis=1)], axis=1), axis=1)
        if max_edge_mm is None:
            h_edges = np.linalg.norm(P[:, 1:] - P[:, :-1], axis=2)
            v_edges = np.linalg.norm(P[1:] - P[:-1], axis=2)
            grid_edges = np.concatenate([h_edges[np.isfinite(h_edges)], v_edges[np.isfinite(v_edges)]])
            max_edge_mm = 4.0 * float(np.median(grid_edges)) if len(grid_edges) else np.inf
        triangles = triangles[longest <= max_edge_mm]
        # Orient by the view: the normal should face the camera side (+z for this convention).
        n = np.cross(vertices[triangles[:, 1]] - vertices[triangles[:, 0]], vertices[triangles[:, 2]] - vertices[triangles[:, 0]])
        if len(n) and np.sum(n[:, 2]) < 0:
            triangles = triangles[:, [0, 2, 1]]
    rows, cols = np.nonzero(valid)
    uv = np.column_stack([(cols + 0.5) / W, 1.0 - (rows + 0.5) / H])
    notes = [f"Range grid {W}x{H}: {len(vertices)} valid samples, {len(triangles)} triangles "
             f"(quad split, edges > {max_edge_mm:.3g} mm dropped)."] if len(triangles) else [
             "Range grid has no triangle (isolated samples only)."]
    return Face(vertices, triangles, uv=uv, texture=colour,
                metadata=FaceMetadata(source="range grid", units="mm", notes=notes, name="range scan"))
