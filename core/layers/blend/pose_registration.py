"""Register an expression scan of a person *relative to that person's registered neutral*.

``register_scan`` places every canonical vertex afresh on each scan (template from the landmarks,
subdivision, projection along normals). That is right for one face, but between a neutral and an
open-mouth pose of the same person it does not land vertex i on the same skin: the lower lip's
band between the inner and outer lip contours curls when the jaw drops, and the projection of the
subdivided base triangles spreads its vertices differently over the curled lip (on the default
face's surprise, lower-lip vertices land up to 5.7 mm, rms 1.5 mm, away from their neutral skin
point). D = pose − neutral then carries that slide as motion: the lower lip sags and gets lumpy.

Here the neutral's canonical face itself is moved onto the pose scan, so the pose keeps the
neutral's placement of the vertices on the skin:

1. a rigid motion of the neutral's landmarks onto the scan's (robust Procrustes);
2. the landmarks' remaining displacements spread over the canonical mesh as a biharmonic field
   (smooth, exact at the landmarks; the mouth is an opening of the mesh, so the lips part);
3. every vertex moves to the closest point of the scan (eye-opening vertices onto the whole scan,
   the rest onto its skin), the landmarks stay where they were given. Vertices on the template's
   creases (eye margins, inner lip contour) keep the spread's position: there the scan has a depth
   step (lid over eyeball, an open mouth's inner lip curling out of view), and its closest point
   lies on whatever is behind (surprise: lower-lip error max 4.7 mm projected, 3.0 mm kept).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from core.face import Face

__all__ = ["register_pose"]


@functools.lru_cache(maxsize=4)
def _canonical_masks(template_name: str) -> tuple[np.ndarray, np.ndarray]:
    """((N,) bool, (N,) bool): canonical vertices inside the template's eye-opening triangles (not on
    a margin), and vertices on its creases (the eye margins and the inner lip contour)."""
    from core.layers.fap.template import DenseTemplate, _edge_vertices
    from core.registration.templates import get_template
    from core.subdivision import subdivide

    template = get_template(template_name).base
    eye = sorted(template.eye_opening_triangles)
    v = np.random.default_rng(0).random((len(template.points), 3))
    t, creases, coords = template.triangles, template.crease_edges(), np.eye(len(v))
    for scheme in template.steps:
        sub = subdivide(v, t, scheme=scheme, creases=creases, params=coords)
        v, t, coords, creases = sub.vertices, sub.triangles, sub.params, sub.creases
    crease = np.zeros(len(v), bool)
    crease[np.asarray(creases, np.int64).ravel()] = True
    if not eye:
        return np.zeros(len(v), bool), crease
    staged = DenseTemplate(template, v, t, coords, np.full(len(v), -1))
    return staged.in_base_triangles(eye) & ~_edge_vertices(t, creases, len(v)), crease


def _bilaplacian(triangles: np.ndarray, n: int) -> scipy.sparse.csr_matrix:
    """(n, n) LᵀL of the mesh's random-walk Laplacian (I − D⁻¹A): its null space is the constants."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    a = scipy.sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    a = ((a + a.T) > 0).astype(float)
    deg = np.maximum(np.asarray(a.sum(axis=1)).ravel(), 1.0)
    lap = scipy.sparse.identity(n, format="csr") - scipy.sparse.diags(1.0 / deg) @ a
    return (lap.T @ lap).tocsr()


def register_pose(scan: Face, landmarks, neutral: Face, *, template: str = "mpeg4_80") -> Face:
    """The canonical face of ``scan`` (a pose of the person whose registered canonical face is
    ``neutral``) with the neutral's vertex placement (see the module docstring).

    landmarks : {name: SurfacePoint or (3,) mm} on the scan (detected or corrected), as for
        ``register_scan``. Returns ``neutral`` with the new vertices (in the scan's frame)."""
    from core.layers.blend.library import LibraryError, rigid_align
    from core.layers.fap.template import skin_triangles
    from core.registration.correspondence import landmark_positions_on
    from core.registration.templates import get_template
    from core.surface_query import TriangleSet

    names = get_template(template).base.points
    positions = landmark_positions_on(scan, dict(landmarks))
    idx = np.array([i for i, n in enumerate(names) if n in positions], np.int64)
    if len(idx) < 4:
        raise LibraryError(f"the pose scan has {len(idx)} of the template's points; at least 4 are needed")
    dst = np.array([positions[names[i]] for i in idx], float)
    v0 = np.asarray(neutral.vertices, float)
    n = len(v0)
    _, R, t = rigid_align(v0[idx], dst)
    v = v0 @ R.T + t
    # Biharmonic spread of the landmark displacements: solve B_ff x_f = −B_fl x_l.
    bi = _bilaplacian(np.asarray(neutral.triangles), n)
    free = np.setdiff1d(np.arange(n), idx)
    shift = np.zeros((n, 3))
    shift[idx] = dst - v[idx]
    shift[free] = scipy.sparse.linalg.splu(bi[free][:, free].tocsc()).solve(-(bi[free][:, idx] @ shift[idx]))
    v = v + shift
    eye, crease = _canonical_masks(template)
    if len(eye) != n:
        eye, crease = np.zeros(n, bool), np.zeros(n, bool)
    skin_ids = skin_triangles(scan) if scan.parts else np.arange(scan.n_triangles)
    out = v.copy()
    for sel, tri_ids in ((~eye & ~crease, skin_ids), (eye & ~crease, np.arange(scan.n_triangles))):
        if sel.any():
            out[sel] = TriangleSet(scan.vertices, scan.triangles[tri_ids]).closest(v[sel])[0]
    out[idx] = dst
    return neutral.with_vertices(out)
