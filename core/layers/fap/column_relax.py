"""Spread the steep ramps of each FAP's displacement field on the face, so no slider end smears the skin.

The FAT's weights are relaxed on the dense template (``fat._relax``), but the face binds to that
template region by region (the lips only to their own lip, the skin beside them to the cheek or
chin), so a ramp can still be steep on the face: the lip-corner stretch (FAP 6 at 400) moved the
skin 1.9 mm at the lower lip's border and 0.1 mm 1.3 mm below it, a shear that stretched the texture
2.2x. Here each column (a FAP's field, mm per FAP unit) is posed at the values the presets take it to
(whatever the surface does, the soft limits let those through); where a skin triangle stretches past
``TARGET_STRETCH``, shrinks under ``TARGET_SQUEEZE`` or turns over, the field around it is relaxed by
Jacobi steps of Laplacian smoothing over the face (neighbours weighted by 1 / edge length), holding
fixed what must not change: the FAP's core (where it moves the skin by at least ``CORE_SHARE`` of its
largest displacement, so its feature point moves as the table says) with a margin, and every vertex on
a border of the skin (lid margins and lip rims must still meet; the copies of a seam must move
together). A column is replaced only by a relaxed one with fewer offending triangles, none more turned
over and a worst stretch no worse.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from core.layers.fap.limits import PRESET_MARGIN, _normals, _rest_measures
from core.mesh_quality import principal_stretches
from core.subdivision import boundary_edges, unique_edges

# Below core.mesh_quality's MAX_STRETCH (2.0) / MIN_STRETCH (0.25): presets add several FAPs' fields.
TARGET_STRETCH = 1.8
TARGET_SQUEEZE = 0.35
CORE_SHARE = 0.9        # the core: vertices moved by at least this share of the column's largest motion
CORE_MARGIN_RINGS = 4   # ... and this many edges around it (~2.6 mm on the default face) are held
RINGS = 6               # the relaxed neighbourhood: this many edges around each offending triangle (~4 mm)
STEPS = 40              # Jacobi steps per round
ROUNDS = 3              # rounds, each on a neighbourhood RINGS wider


class ColumnRelaxer:
    """Relaxes FAP fields (n, 3) on one face's skin; see the module docstring.

    vertices (n, 3) mm; skin_triangles (m, 3) the skin's triangles (parts excluded)."""

    def __init__(self, vertices: np.ndarray, skin_triangles: np.ndarray):
        n = len(vertices)
        self.rest = vertices
        self.triangles = skin_triangles
        # Rest normals, frames and which triangles are no slivers, as the limits measure them.
        self.normals, self.frames, self.measurable = _rest_measures(vertices, skin_triangles)
        e = unique_edges(skin_triangles)[0]
        inv = 1.0 / np.maximum(np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1), 1e-6)
        w = scipy.sparse.coo_matrix((np.concatenate([inv, inv]), (np.concatenate([e[:, 0], e[:, 1]]),
                                                                   np.concatenate([e[:, 1], e[:, 0]]))),
                                    shape=(n, n)).tocsr()
        self.weights = w
        self.degree = np.asarray(w.sum(axis=1)).ravel()
        self.ring = (w > 0).astype(np.float32).tocsr()
        self.fixed = self.degree == 0
        self.fixed[boundary_edges(skin_triangles).ravel()] = True

    def worst(self, field: np.ndarray, ends, tris: np.ndarray) -> tuple[np.ndarray, tuple[int, float]]:
        """(offending (k,) triangle ids among ``tris``, score): triangles that stretch past the targets
        or turn over at any of ``ends`` (FAP values scaling ``field`` (n, 3) mm); score (triangles
        turned over, the largest of max stretch and 1 / min stretch), 1 when none moves."""
        bad = np.zeros(len(tris), bool)
        score, folds = 1.0, 0
        for end in ends:
            corners = self.rest[self.triangles[tris]] + end * field[self.triangles[tris]]
            big, small = principal_stretches(self.frames[tris], corners)
            turned = np.einsum("ij,ij->i", _normals(corners), self.normals[tris]) < 0
            ok = self.measurable[tris]
            bad |= ok & ((big > TARGET_STRETCH) | (small < TARGET_SQUEEZE) | turned)
            folds += int((turned & ok).sum())
            if ok.any():
                score = max(score, float(big[ok].max()), float(1.0 / max(small[ok].min(), 1e-6)))
        return tris[bad], (folds, score)

    def _grow(self, mask: np.ndarray, rings: int) -> np.ndarray:
        for _ in range(rings):
            mask = mask | ((self.ring @ mask.astype(np.float32)) > 0)
        return mask

    def relax(self, field: np.ndarray, ends) -> np.ndarray | None:
        """``field`` (n, 3) mm per FAP unit relaxed where it is too steep at ``ends`` (FAP values x
        FAPU), or None when it need not (or could not) be: the best of ``ROUNDS`` ever wider
        neighbourhoods, kept only if it has fewer offending triangles, none more turned over and its
        worst stretch no worse (that may sit on held vertices the relaxation cannot move)."""
        moving = np.linalg.norm(field, axis=1)
        if not moving.any():
            return None

        def measure(f):
            return self.worst(f, ends, np.flatnonzero((np.abs(f[self.triangles]).sum(axis=(1, 2)) > 0)))

        bad, score = measure(field)
        if not len(bad):
            return None
        # The core and a margin around it stay: a Laplacian fill against a small held core steepens
        # the ramp next to it (a cone), where the core's own triangles already stretch most.
        hold = self.fixed | self._grow(moving >= CORE_SHARE * moving.max(), CORE_MARGIN_RINGS)
        best, best_key = None, (score[0], len(bad), score[1])
        out = field.copy()
        region = np.zeros(len(field), bool)
        region[self.triangles[bad].ravel()] = True
        for _ in range(ROUNDS):
            region = self._grow(region, RINGS)
            free = np.flatnonzero(region & ~hold)
            if not len(free):
                break
            take = scipy.sparse.diags(1.0 / self.degree[free]) @ self.weights[free]
            for _ in range(STEPS):
                out[free] = take @ out
            bad, new = measure(out)
            key = (new[0], len(bad), new[1])
            if key[0] <= score[0] and key[2] <= score[1] + 1e-9 and key < best_key:
                best, best_key = out.copy(), key
            if not len(bad):
                break
            region[self.triangles[bad].ravel()] = True
        return best


def relax_columns(matrix: scipy.sparse.csr_matrix, vertices: np.ndarray, skin_triangles: np.ndarray,
                  fapu_vector: np.ndarray, specs, numbers, reach: np.ndarray) -> scipy.sparse.csr_matrix:
    """(3n, 68) ``matrix`` (mm per FAP unit before ``fapu_vector``, rows x, y, z per vertex) with the
    columns of FAPs ``numbers`` (translations) relaxed by :class:`ColumnRelaxer` for the values the
    presets take them to, ``reach`` (68, 2) (``limits.preset_reach``), and ``PRESET_MARGIN`` past:
    what the sliders' soft limits let through whatever the surface does (``limits.keeping``). Beyond
    that the soft limits stop a slider where its skin breaks."""
    n = len(vertices)
    relaxer = ColumnRelaxer(vertices, skin_triangles)
    columns = matrix.tocsc()
    replaced = {}
    for number in numbers:
        spec = specs[number - 1]
        ends = [v * (1 + PRESET_MARGIN) * fapu_vector[number - 1] for v in reach[number - 1] if v != 0]
        if spec.is_rotation or not ends:
            continue
        field = columns[:, number - 1].toarray().reshape(n, 3)
        relaxed = relaxer.relax(field, ends)
        if relaxed is not None:
            replaced[number - 1] = scipy.sparse.csc_matrix(relaxed.reshape(-1, 1))
    if not replaced:
        return matrix
    parts = [replaced.get(c, columns[:, c]) for c in range(columns.shape[1])]
    out = scipy.sparse.hstack(parts, format="csr")
    out.eliminate_zeros()
    return out
