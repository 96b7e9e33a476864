"""Build resources/templates/a48.json: the 48-point landmark graph of thesis A §3.2 (Fig. 3.4).

Run once by a developer (``python tools/build_a48_template.py``); the JSON is the data the program
uses. The thesis shows its 48 points only as a figure, so Mimica defines its own set:

* 46 MPEG-4 feature points (every synthetic face and the default face carry them, so ground truth
  exists everywhere), and
* 2 temple points on the face outline (``a48.temple_l`` / ``a48.temple_r``), defined as fixed
  barycentric positions on mpeg4_80 template triangles (the midpoint of the outline edge
  11.3-10.9, resp. 11.2-10.10), snapped to the skin like the mpeg4_80 extras.

Topology. The thesis's counts 48/74 -> 170/296 -> 636/1184 -> 2456/4736 -> 9648/18944 give
E = 170 - 48 = 122 edges, so V - E + F = 48 - 122 + 74 = 0 (an annulus: the face outline plus
exactly one opening), and 3F = 2E - B gives B = 22 boundary edges (each step doubles B: 44, 88,
176). Mimica's split: 14 outline edges (12 outline FPs + 2 temples) and 8 mouth edges (the inner
lip contour 2.2-2.9: "the mouth interior is not covered"); the eyes are covered (2 triangles per
eye inside the lid margin 3.7-3.1-3.11-3.3, tagged ``eye_opening``), as in the mpeg4_80 template.
26 interior points: brows 4.1-4.6, eyelids/corners 3.1 3.3 3.7 3.11 and mirror, nose 9.12 9.3
9.15 9.1 9.2, outer lip 8.1-8.4, cheeks 5.1 5.2, chin boss 2.10.

The triangulation is a Delaunay triangulation of the frontal (x, y) layout on the default face
(closed mouth spread open a little), cut to the outline and the mouth opening.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from matplotlib.path import Path as PolyPath
from scipy.spatial import Delaunay

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from core.default_face.store import load_default_face  # noqa: E402
from core.layers.fap.template import base_positions, load_template  # noqa: E402

OUTLINE = ["11.1", "11.3", "a48.temple_l", "10.9", "10.7", "2.13", "2.11", "2.1", "2.12", "2.14", "10.8",
           "10.10", "a48.temple_r", "11.2"]
MOUTH = ["2.4", "2.6", "2.2", "2.7", "2.5", "2.9", "2.3", "2.8"]
EYES = {"l": ["3.7", "3.1", "3.11", "3.3"], "r": ["3.12", "3.2", "3.8", "3.4"]}
INTERIOR = ["4.1", "4.3", "4.5", "4.2", "4.4", "4.6", *EYES["l"], *EYES["r"], "9.12", "9.3", "9.15", "9.1", "9.2",
            "8.1", "8.2", "8.3", "8.4", "5.1", "5.2", "2.10"]
NAMES = OUTLINE + MOUTH + INTERIOR
# Non-FP points: (mpeg4_80 point names of the triangle corners, barycentric) -> resolved to a triangle index.
DERIVED = {"a48.temple_l": (("11.3", "10.9"), (0.5, 0.5)), "a48.temple_r": (("11.2", "10.10"), (0.5, 0.5))}
MIRROR = {"a48.temple_l": "a48.temple_r"}


def derived_table() -> dict:
    tpl = load_template("mpeg4_80")
    out = {}
    for name, (corners, weights) in DERIVED.items():
        ids = [tpl.index(c) for c in corners]
        tri = [i for i, t in enumerate(tpl.triangles) if set(ids) <= set(t.tolist())]
        assert tri, f"no mpeg4_80 triangle holds {corners}"
        t = int(tri[0])
        bary = [0.0, 0.0, 0.0]
        for c, w in zip(corners, weights):
            bary[tpl.triangles[t].tolist().index(tpl.index(c))] = w
        out[name] = {"template": "mpeg4_80", "triangle": t,
                     "corners": [tpl.points[i] for i in tpl.triangles[t]], "barycentric": bary}
    return out


def layout() -> dict[str, np.ndarray]:
    face = load_default_face()
    tpl = load_template("mpeg4_80")
    base = base_positions(tpl, face)
    pos = {n: face.landmark_position(n)[:2] for n in NAMES if n in face.landmark_names}
    for name, d in derived_table().items():
        pos[name] = (np.array(d["barycentric"])[:, None] * base[tpl.triangles[d["triangle"]]]).sum(axis=0)[:2]
    for n in ("2.2", "2.6", "2.7"):  # spread the closed mouth for triangulating
        pos[n] = pos[n] + [0, 1.5]
    for n in ("2.3", "2.8", "2.9"):
        pos[n] = pos[n] - [0, 1.5]
    return pos


def triangulate(pos: dict[str, np.ndarray]) -> np.ndarray:
    xy = np.array([pos[n] for n in NAMES])
    tri = Delaunay(xy).simplices
    centroids = xy[tri].mean(axis=1)
    index = {n: i for i, n in enumerate(NAMES)}
    outer = PolyPath(xy[[index[n] for n in OUTLINE]])
    mouth = PolyPath(xy[[index[n] for n in MOUTH]])
    keep = outer.contains_points(centroids) & ~mouth.contains_points(centroids)
    tri = tri[keep]
    a, b, c = xy[tri[:, 0]], xy[tri[:, 1]], xy[tri[:, 2]]
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    tri[cross < 0] = tri[cross < 0][:, [0, 2, 1]]  # counter-clockwise seen from the front (+z)
    return tri


def edges_of(tri):
    e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0, return_counts=True)


def check(tri: np.ndarray) -> None:
    index = {n: i for i, n in enumerate(NAMES)}
    uniq, count = edges_of(tri)
    boundary = {tuple(e) for e in uniq[count == 1]}
    all_edges = {tuple(e) for e in uniq}
    for loop in (OUTLINE, MOUTH):
        for a, b in zip(loop, loop[1:] + loop[:1]):
            assert tuple(sorted((index[a], index[b]))) in boundary, f"boundary edge {a}-{b} missing"
    for loop in EYES.values():
        for a, b in zip(loop, loop[1:] + loop[:1]):
            assert tuple(sorted((index[a], index[b]))) in all_edges, f"eye margin edge {a}-{b} missing"
    assert len(boundary) == 22, f"{len(boundary)} boundary edges"
    assert len(NAMES) == 48 and len(set(NAMES)) == 48 and len(tri) == 74, (len(NAMES), len(tri))
    assert len(uniq) == 122


def eye_opening_triangles(tri):
    index = {n: i for i, n in enumerate(NAMES)}
    return {s: [int(t) for t in np.nonzero([set(r) <= {index[n] for n in loop} for r in tri])[0]]
            for s, loop in EYES.items()}


def plot(pos, tri, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xy = np.array([pos[n] for n in NAMES])
    fig, ax = plt.subplots(figsize=(9, 11))
    ax.triplot(-xy[:, 0], xy[:, 1], tri, lw=0.7)  # viewer's view: the face's left on the right
    for n, p in zip(NAMES, xy):
        ax.text(-p[0], p[1], n, fontsize=7, color="darkred" if n.startswith("a48") else "k")
    ax.set_aspect("equal")
    ax.set_title("a48: 48 points, 74 triangles")
    fig.savefig(path, dpi=100)


def write_json(tri) -> Path:
    mirror = {**MIRROR, **{v: k for k, v in MIRROR.items()}}
    data = {
        "name": "a48",
        "description": (
            "Mimica's 48-landmark graph for structural matching and dense correspondence (thesis A "
            "Fig. 3.4 and Table 3.2): 46 MPEG-4 feature points and 2 temple points on the outline "
            "(barycentric on mpeg4_80 triangles, see 'derived'); 74 triangles; an annulus (V-E+F = 0) "
            "with 22 boundary edges: 14 on the outline, 8 around the mouth opening (inner lip contour). "
            "The eye openings are covered by 2 triangles each ('eye_opening_triangles'). "
            "Subdivided linear, linear, Loop, Loop: 48/74 -> 170/296 -> 636/1184 -> 2456/4736 -> 9648/18944. "
            "Built by tools/build_a48_template.py."
        ),
        "points": NAMES,
        "extras": {},
        "derived": derived_table(),
        "mirror": mirror,
        "triangles": tri.tolist(),
        "outline": OUTLINE,
        "mouth": MOUTH,
        "eye_margins": EYES,
        "eye_opening_triangles": eye_opening_triangles(tri),
        "upper_lip_points": ["2.2", "2.6", "2.7", "8.1"],
        "lower_lip_points": ["2.3", "2.8", "2.9", "8.2"],
        "subdivision": ["linear", "linear", "loop", "loop"],
        "counts": [[48, 74], [170, 296], [636, 1184], [2456, 4736], [9648, 18944]],
        "regions": [],
    }
    path = ROOT / "resources" / "templates" / "a48.json"
    path.write_text(json.dumps(data, indent=1))
    return path


if __name__ == "__main__":
    pos = layout()
    tri = triangulate(pos)
    print(len(NAMES), "points", len(tri), "triangles")
    (ROOT / "out").mkdir(exist_ok=True)
    plot(pos, tri, ROOT / "out" / "a48_layout.png")
    check(tri)
    print("wrote", write_json(tri))
