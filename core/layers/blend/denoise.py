"""Registration noise taken out of scanned poses: each displacement field smoothed over the face.

A pose registered from a scan carries the scan's depth noise and the registration's sideways slide
of the canonical vertices (``pose_registration``): the displacement D_k = pose − neutral wobbles by
about half a millimetre from vertex to vertex where the face did not move. Blended at 100 % that
wobble cut the lids through each other and into the eyeballs, crossed the lips and folded the
nostrils (default face's built-in library, ``benchmarks/face_quality.py --families blends``: 20/20
poses failed). An expression's own motion is smooth across the skin — the muscles pull sheets of
it — so a field smoothed over a few millimetres keeps it and drops the wobble.

The smoothing is implicit diffusion on the canonical mesh, (I + t·L) S = D per axis, L the graph
Laplacian with 1/length² edge weights (rest geometry, so ``length_mm`` means the same on any mesh
resolution), t = length_mm² / 2 (the variance of a Gaussian of that width). The mesh's own openings
keep the lips apart (the mouth is a slit in the canonical topology); the covers of the eye openings
are taken out of the graph, so an upper lid never averages with its lower lid, and then filled with
the smoothest field that meets the lids around them (a membrane). Registered onto the eyeballs, the
covers' own displacements were noise, which deformation transfer carried into another face's lid
margins (generated identity, viseme_1: texture stretch 6.7 at the lids; 1.5 with the membrane).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse

from core.layers.blend.library import ExpressionLibrary, LibraryError

__all__ = ["check_smoothing_width", "cleaned", "eye_cover_vertices", "smooth_displacements", "SMOOTHING_MM"]

#: Width (mm) of the smoothing of the built-in library's poses (``builtin.build_builtin_library``).
#: Measured against the FAP presets the default face's poses were scanned from (their FAT offsets on
#: the canonical vertices; mean over the 20 poses of the rms error): raw 0.94 mm; 4 mm 0.82, 5 mm
#: 0.82, 6 mm 0.82, 8 mm 0.85 (pose magnitude rms: presets 2.25 mm, raw 2.31, 6 mm 2.02, 8 mm 1.90).
#: Failing poses at 100 % (face_quality, default / generated face): raw 20 / 20, 4 mm 14 / 11,
#: 6 mm 12 / 9, 8 mm 10 / 7. 6 mm: as close to the scanned truth as any width, fewer failures.
SMOOTHING_MM = 6.0


def check_smoothing_width(length_mm) -> float:
    """``length_mm`` as a float; LibraryError unless it is a length in mm >= 0."""
    try:
        length_mm = float(length_mm)
    except (TypeError, ValueError):
        raise LibraryError(f"the smoothing width must be a length in mm >= 0, got {length_mm!r}") from None
    if not np.isfinite(length_mm) or length_mm < 0:
        raise LibraryError(f"the smoothing width must be a length in mm >= 0, got {length_mm}")
    return length_mm


@functools.lru_cache(maxsize=4)
def eye_cover_vertices(template: str) -> np.ndarray:
    """(N,) bool: canonical vertices of ``template`` strictly inside the triangles that cover its eye
    openings (between the lids; they lie on the eyeballs, not on skin). Read-only."""
    from core.layers.fap.template import DenseTemplate
    from core.registration.templates import get_template
    from core.subdivision import subdivide

    base = get_template(template).base
    covered = sorted(base.eye_opening_triangles)
    v = np.random.default_rng(0).random((len(base.points), 3))   # positions do not matter, only coords
    t, creases, coords = base.triangles, base.crease_edges(), np.eye(len(v))
    for scheme in base.steps:
        sub = subdivide(v, t, scheme=scheme, creases=creases, params=coords)
        v, t, coords, creases = sub.vertices, sub.triangles, sub.params, sub.creases
    dense = DenseTemplate(base, v, t, coords, np.full(len(v), -1))
    others = [i for i in range(len(base.triangles)) if i not in base.eye_opening_triangles]
    inside = dense.in_base_triangles(covered) & ~dense.in_base_triangles(others) if covered else np.zeros(len(v), bool)
    inside.setflags(write=False)
    return inside


def smooth_displacements(library: ExpressionLibrary, length_mm: float, triangles: np.ndarray,
                         filled: np.ndarray | None = None) -> ExpressionLibrary:
    """``library`` with every pose's displacement (n, 3) mm smoothed over ``length_mm`` on its rest
    mesh (``triangles`` (T, 3)). Vertices marked ``filled`` ((n,) bool, e.g. :func:`eye_cover_vertices`)
    are left out of that smoothing (the skin around them does not average across them) and then
    take the smoothest field that meets the skin around them (a membrane). The rest, names and mean
    face are kept."""
    import scipy.sparse.linalg

    length_mm = check_smoothing_width(length_mm)
    n = library.n_vertices
    triangles = np.asarray(triangles, dtype=np.int64)
    if triangles.ndim != 2 or triangles.shape[1] != 3 or (len(triangles) and triangles.max() >= n):
        raise LibraryError(f"the triangles do not fit the library's {n} vertices")
    if length_mm == 0 or not library.names:
        return library
    filled = np.zeros(n, bool) if filled is None else np.asarray(filled, bool)
    if filled.shape != (n,):
        raise LibraryError(f"the mask of filled vertices must have {n} entries, got shape {filled.shape}")
    skin = _laplacian(library.rest, triangles[~filled[triangles].any(axis=1)], n)
    solve = scipy.sparse.linalg.factorized((scipy.sparse.identity(n) + 0.5 * length_mm ** 2 * skin).tocsc())
    d = np.array(library.displacements)
    for k in range(len(d)):
        d[k] = np.column_stack([solve(np.ascontiguousarray(d[k][:, a])) for a in range(3)])
    inner = np.flatnonzero(filled)
    if len(inner):
        # A membrane over each filled patch, held by the smoothed skin around it: L_ii d_i = -L_ib d_b.
        whole = _laplacian(library.rest, triangles, n).tocsr()
        fill = scipy.sparse.linalg.factorized(whole[inner][:, inner].tocsc())
        border = whole[inner][:, np.flatnonzero(~filled)]
        for k in range(len(d)):
            rhs = -(border @ d[k][~filled])
            d[k][inner] = np.column_stack([fill(np.ascontiguousarray(rhs[:, a])) for a in range(3)])
    return library.replace(displacements=d)


def _laplacian(rest: np.ndarray, triangles: np.ndarray, n: int) -> scipy.sparse.csr_matrix:
    """(n, n) graph Laplacian of ``triangles``' edges weighted by 1 / rest length² (mm⁻²)."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    length = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    weight = scipy.sparse.coo_matrix((1.0 / np.maximum(length, 1e-6) ** 2, (edges[:, 0], edges[:, 1])),
                                     shape=(n, n)).tocsr()
    weight = weight.maximum(weight.T)          # each interior edge was seen from both of its triangles
    return (scipy.sparse.diags(np.asarray(weight.sum(axis=1)).ravel()) - weight).tocsr()


def cleaned(library: ExpressionLibrary, smoothing_mm: float = SMOOTHING_MM) -> ExpressionLibrary:
    """``library`` (registered poses on a known canonical template) with the scans' registration noise
    smoothed out of its poses over ``smoothing_mm`` (0: as registered), the eye openings' covers
    filled as a membrane; its ``base`` says by how much. LibraryError for a ``"custom"`` library
    (no canonical mesh to smooth on) or a width that is not a length >= 0."""
    from core.registration.correspondence import canonical_triangles
    from core.registration.templates import TEMPLATE_NAMES

    if check_smoothing_width(smoothing_mm) == 0 or not library.names:
        return library
    if library.template not in TEMPLATE_NAMES:
        raise LibraryError(f"a library of template {library.template!r} has no canonical mesh to smooth its poses "
                           "on: build it from scans registered with one of " + ", ".join(TEMPLATE_NAMES))
    smooth = smooth_displacements(library, smoothing_mm, canonical_triangles(library.template),
                                  eye_cover_vertices(library.template))
    return smooth.replace(base=f"{library.base}; poses smoothed over {float(smoothing_mm):g} mm")
