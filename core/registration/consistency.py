"""Landmarks that contradict their neighbours in the template's shape (issue 15).

A landmark template is a triangle mesh over the landmarks. Placed on a scan, its triangles should
face the way they face on a face (the template registered on the default face, brought onto the
landmarks by a similarity: the reference). A triangle that faces the other way cannot be part of
a fold-free canonical mesh holding its three landmarks. Often that is a difference of shape the
fit bends around (a smile's inner lip corner a few millimetres beyond the outer lip's line); but
on open mouths the detector found the lower-lip points 8.7 / 8.8 on the upper lip next to the
corners, 20-30 mm from where their neighbours put them, and the canonical lower lip, held there,
spanned the mouth opening 5-12 mm off the scan.

:func:`inconsistent_landmarks` finds those: each given landmark of a turned triangle is predicted
from its template neighbours (the reference's ring around it brought onto the ring's positions by
a similarity, refitted without the neighbours that disagree with it: several neighbours may be
wrong together); the one farthest from its prediction, in units of its ring's edges, whose move to
the prediction turns triangles back is released (it takes the predicted position), and the next is
looked for with that position, until none is farther than ``RELEASE_EDGES`` edge lengths or turns
a triangle back. Triangles on the template's outline are left out: the outline is bent round the
landmark inside it (``correspondence.rounded_outline``), ground truth turns them on some faces.
"""

from __future__ import annotations

import numpy as np

from core.registration.folds import similarity, triangle_normals

#: A triangle is turned over when its area along the reference normal is below minus this fraction
#: of its reference area (flat is not turned).
TURNED_RATIO = 1e-6
#: A landmark is released only when its prediction is farther than this many of its ring's mean
#: edge lengths. Ground truth lies up to 2/3 of an edge from its prediction (the synthetic faces'
#: and the Surrey Face Model's shapes and expressions against the default face's: 0.66 at most, on
#: the SFM's lip corners and nostrils); the lower-lip points found on the upper lip of open mouths,
#: 0.9-1.4 edges.
RELEASE_EDGES = 0.8
#: The prediction's similarity is refitted without neighbours farther than this many times the
#: median misfit (twice at most).
TRIM = 2.0


def turned_over(points: np.ndarray, reference: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(T,) bool: triangles of ``points`` (n, 3) facing against the same triangle of ``reference`` (n, 3)."""
    ref_normals = triangle_normals(reference, triangles)
    ref_area2 = np.einsum("kd,kd->k", ref_normals, ref_normals)
    along = np.einsum("kd,kd->k", triangle_normals(points, triangles), ref_normals)
    return along < -TURNED_RATIO * ref_area2


def ring_prediction(points: np.ndarray, reference: np.ndarray, ring: np.ndarray, vertex: int) -> np.ndarray:
    """(3,) where ``vertex`` lies if its neighbours ``ring`` are right: the reference's ring and
    vertex moved by the similarity of the ring onto ``points``, refitted without neighbours that
    misfit by more than ``TRIM`` times the median (at least 4 kept)."""
    keep = ring
    for _ in range(3):
        scale, rotation, shift = similarity(reference[keep], points[keep])
        misfit = np.linalg.norm(scale * reference[keep] @ rotation.T + shift - points[keep], axis=1)
        kept = keep[misfit <= TRIM * np.median(misfit) + 1e-9]
        if len(kept) < 4 or len(kept) == len(keep):
            break
        keep = kept
    return scale * rotation @ reference[vertex] + shift


def inconsistent_landmarks(points: np.ndarray, reference: np.ndarray, triangles: np.ndarray,
                           given: np.ndarray, outline: np.ndarray) -> tuple[list[int], np.ndarray]:
    """(released landmarks in the order found, positions (n, 3) with the released at their prediction).

    points : (n, 3) the template's points placed on the scan (mm); reference : (n, 3) the same
    points on a face of the template, aligned onto ``points``; triangles : (T, 3) the template's;
    given : (n,) bool the landmarks that were given (not computed from others); outline : (n,) bool
    the template's outline points.
    """
    x = np.array(points, float)
    inner = given[triangles].all(axis=1) & (outline[triangles].sum(axis=1) < 2)
    triangles = triangles[inner]
    released: list[int] = []
    turned = turned_over(x, reference, triangles)
    while turned.any():
        best, best_edges, best_at = -1, RELEASE_EDGES, None
        for vertex in np.unique(triangles[turned]).tolist():
            if vertex in released:
                continue
            incident = (triangles == vertex).any(axis=1)
            ring = np.unique(triangles[incident])
            ring = ring[ring != vertex]
            predicted = ring_prediction(x, reference, ring, vertex)
            edges = float(np.linalg.norm(reference[ring] - reference[vertex], axis=1).mean())
            away = float(np.linalg.norm(predicted - x[vertex])) / max(edges, 1e-12)
            trial = x.copy()
            trial[vertex] = predicted
            untangles = turned_over(trial, reference, triangles[incident]).sum() < turned[incident].sum()
            if untangles and away > best_edges:
                best, best_edges, best_at = vertex, away, predicted
        if best < 0:
            break
        x[best] = best_at
        released.append(best)
        turned = turned_over(x, reference, triangles)
    return released, x
