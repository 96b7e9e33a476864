"""Build resources/templates/mpeg4_80.json: Mimica's 80-point MPEG-4 base mesh.

Run once by a developer (``python tools/build_mpeg4_template.py``); the JSON is the data the
program uses. The triangulation is a Delaunay triangulation of the points' frontal layout on the
default face, cut to the face outline and the mouth opening; the tool checks the counts and writes
a PNG of the layout to out/ for a visual check.
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

# ------------------------------------------------------------------ points
MIDLINE = ["11.1", "9.12", "9.3", "9.15", "8.1", "2.2", "2.3", "8.2", "2.10", "2.1"]
LEFT = ["11.3", "10.9", "10.7", "2.13", "2.11", "4.1", "4.3", "4.5", "3.7", "3.11", "3.1", "3.3", "3.9",
        "3.13", "5.1", "5.3", "9.7", "9.13", "9.1", "9.5", "8.3", "8.5", "8.7", "8.10", "2.4", "2.6", "2.8"]
MIRROR = {"11.3": "11.2", "10.9": "10.10", "10.7": "10.8", "2.13": "2.14", "2.11": "2.12", "4.1": "4.2",
          "4.3": "4.4", "4.5": "4.6", "3.7": "3.12", "3.11": "3.8", "3.1": "3.2", "3.3": "3.4", "3.9": "3.10",
          "3.13": "3.14", "5.1": "5.2", "5.3": "5.4", "9.7": "9.6", "9.13": "9.14", "9.1": "9.2", "9.5": "9.4",
          "8.3": "8.4", "8.5": "8.6", "8.7": "8.8", "8.10": "8.9", "2.4": "2.5", "2.6": "2.7", "2.8": "2.9"}


def extras(side: str) -> dict[str, dict[str, float]]:
    """The 8 extra points around one eye as affine combinations of feature points (and earlier extras).

    Margin points sit half-way between a corner and the lid centre, raised to where an elliptic
    lid margin passes (sqrt(0.75) = 0.866 of the centre's height above the corner line).
    """
    m = (lambda n: n) if side == "l" else (lambda n: MIRROR[n])
    outer, inner, top, bottom = m("3.7"), m("3.11"), m("3.1"), m("3.3")
    e = f"e{side}."
    return {
        e + "uo": {top: 0.866, outer: 0.317, inner: -0.183},
        e + "ui": {top: 0.866, inner: 0.317, outer: -0.183},
        e + "lo": {bottom: 0.866, outer: 0.317, inner: -0.183},
        e + "li": {bottom: 0.866, inner: 0.317, outer: -0.183},
        e + "ao": {e + "uo": 0.6, m("4.5"): 0.4},
        e + "ai": {e + "ui": 0.6, m("4.1"): 0.4},
        e + "bo": {e + "lo": 0.6, m("5.3"): 0.4},
        e + "bi": {e + "li": 0.6, m("9.13"): 0.4},
    }


FPS = MIDLINE + LEFT + [MIRROR[n] for n in LEFT]
EXTRAS = {**extras("l"), **extras("r")}
NAMES = FPS + list(EXTRAS)
OUTER = ["11.1", "11.3", "10.9", "10.7", "2.13", "2.11", "2.1", "2.12", "2.14", "10.8", "10.10", "11.2"]
MOUTH = ["2.4", "2.6", "2.2", "2.7", "2.5", "2.9", "2.3", "2.8"]
EYE = {s: [c[0], f"e{s}.uo", c[1], f"e{s}.ui", c[2], f"e{s}.li", c[3], f"e{s}.lo"]
       for s, c in (("l", ("3.7", "3.1", "3.11", "3.3")), ("r", ("3.12", "3.2", "3.8", "3.4")))}


def layout() -> dict[str, np.ndarray]:
    face = load_default_face()
    pos = {}
    for n in FPS:
        if n in face.landmark_names:
            pos[n] = face.landmark_position(n)[:2]
    # Ear contacts, if the face predates them: on the outline at eye-corner and nose-base height.
    pos.setdefault("10.9", np.array([63.0, 38.0]))
    pos.setdefault("10.7", np.array([58.0, -15.5]))
    pos.setdefault("10.10", pos["10.9"] * [-1, 1])
    pos.setdefault("10.8", pos["10.7"] * [-1, 1])
    for name, weights in EXTRAS.items():
        pos[name] = sum(w * pos[k] for k, w in weights.items())
    # Spread the closed mouth for triangulating: upper inner lip up, lower down.
    for n in ("2.2", "2.6", "2.7"):
        pos[n] = pos[n] + [0, 1.5]
    for n in ("2.3", "2.8", "2.9"):
        pos[n] = pos[n] - [0, 1.5]
    return pos


def triangulate(pos: dict[str, np.ndarray]) -> np.ndarray:
    xy = np.array([pos[n] for n in NAMES])
    tri = Delaunay(xy).simplices
    centroids = xy[tri].mean(axis=1)
    index = {n: i for i, n in enumerate(NAMES)}
    outer = PolyPath(xy[[index[n] for n in OUTER]])
    mouth = PolyPath(xy[[index[n] for n in MOUTH]])
    keep = outer.contains_points(centroids) & ~mouth.contains_points(centroids)
    tri = tri[keep]
    # Counter-clockwise seen from the front (+z).
    a, b, c = xy[tri[:, 0]], xy[tri[:, 1]], xy[tri[:, 2]]
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    tri[cross < 0] = tri[cross < 0][:, [0, 2, 1]]
    return tri


def check(tri: np.ndarray) -> None:
    index = {n: i for i, n in enumerate(NAMES)}
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    boundary = {tuple(e) for e in uniq[count == 1]}
    for loop in (OUTER, MOUTH):
        for a, b in zip(loop, loop[1:] + loop[:1]):
            e = tuple(sorted((index[a], index[b])))
            assert e in boundary, f"boundary edge {a}-{b} missing"
    for loop in EYE.values():
        for a, b in zip(loop, loop[1:] + loop[:1]):
            e = tuple(sorted((index[a], index[b])))
            assert e in {tuple(x) for x in uniq}, f"eye margin edge {a}-{b} missing"
    assert len(boundary) == len(OUTER) + len(MOUTH), f"{len(boundary)} boundary edges"
    assert len(NAMES) == 80 and len(tri) == 140, (len(NAMES), len(tri))


def eye_opening_triangles(tri: np.ndarray) -> dict[str, list[int]]:
    index = {n: i for i, n in enumerate(NAMES)}
    out = {}
    for side, loop in EYE.items():
        ids = {index[n] for n in loop}
        out[side] = [int(t) for t in np.nonzero([set(r) <= ids for r in tri])[0]]
    return out


def plot(pos, tri, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xy = np.array([pos[n] for n in NAMES])
    fig, ax = plt.subplots(figsize=(11, 13))
    ax.triplot(xy[:, 0] * -1, xy[:, 1], tri, lw=0.7)  # viewer's view: face's left on the right
    for n, p in zip(NAMES, xy):
        ax.text(-p[0], p[1], n, fontsize=7, color="darkred" if n.startswith("e") else "k")
    for i, t in enumerate(tri):
        c = xy[t].mean(axis=0)
        ax.text(-c[0], c[1], str(i), fontsize=5, color="gray", ha="center")
    ax.set_aspect("equal")
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    pos = layout()
    tri = triangulate(pos)
    print(len(NAMES), "points", len(tri), "triangles")
    plot(pos, tri, ROOT / "out" / "template_layout.png")
    check(tri)


# ------------------------------------------------------------------ regions (Facial Animation Table)
def mirror_name(n: str) -> str:
    if n.startswith("el."):
        return "er." + n[3:]
    return MIRROR.get(n, {v: k for k, v in MIRROR.items()}.get(n, n))


UPPER_LIP = ["2.2", "2.6", "2.4", "8.1", "8.5", "8.10", "8.3"]
LOWER_LIP = ["2.3", "2.8", "2.4", "8.2", "8.7", "8.3"]
JAW_CORE = ["2.1", "2.10", "2.11", "2.3", "2.8", "8.2", "8.7", "2.4", "8.3"]
# The mouth corners hang between the upper jaw and the mandible: when the jaw drops they follow it
# only part of the way (JAW_CORNER_WEIGHT), the lower lip grading from that at the corners to the full
# motion at the midline ("profile": "jaw"). The upper lip next to each corner follows the corner
# (a second jaw entry, "scale" = the corner weight), so the opening becomes an oval instead of a box
# with vertical walls at the corners. Several entries of one FAP combine by their maximum.
JAW_CORNER_WEIGHT = 0.4
JAW_EXTRA = {"symmetric": True, "profile": "jaw", "corner_weight": JAW_CORNER_WEIGHT}
BROW_REGION = ["4.1", "4.3", "4.5", "el.ai", "el.ao", "11.1", "11.3", "10.9", "9.7", "3.13", "3.7", "3.11",
               "el.ui", "3.1", "el.uo"]
BROW = {"pinned": ["3.7", "el.uo", "3.1", "el.ui", "3.11"]}
# The lip-corner raise FAPs (12/13 inner, 59/60 outer): both lips and the cheek around the corner, up
# to the cheekbone (5.3), the nose wing (9.1), back to the jaw's ear contact (10.7) and down to the
# chin (2.11). A smile moves the corner ~11 mm up; with the region ending at 5.1 and 2.13, 15 mm beside
# it, the skin between was squeezed into the corner (the lips crossing there in joy). The jaw line
# (2.11-2.13-10.7, the template's outline, which is no region border by itself) is pinned: with its
# weight left on, the skin under the jaw followed the corner up into the mouth cavity.
# The stretch FAPs keep the lips and 5.1: widened, a pucker (CH, RR, ou) pulled the cheeks into the cavity.
CORNER_REGION = UPPER_LIP + LOWER_LIP + ["5.1", "5.3", "10.7", "2.13", "9.1", "2.11"]
# ... with a round top (the weight near the core held through the relaxation, not only the two core
# points: a corner pinned alone became a cone and the skin beside it folded).
CORNER = {"round_top": True, "pinned": ["2.11", "2.13", "10.7"]}
# The mid-lip FAPs' fields are rounded at their feature point (FapDeformer's _rounded_tip): relaxed
# against a point held at 1 they were cones.
MID_LIP = {"symmetric": True, "round_tip": True}
LOWER_MARGIN = ["3.7", "el.lo", "3.3", "el.li", "3.11"]
UPPER_CORNER = (["2.4", "8.3", "2.6", "8.5", "8.10"], ["2.4", "8.3"], 4.0,
                {"symmetric": True, "scale": JAW_CORNER_WEIGHT})
# (fap, vertex set (left side; mirrored for the right FAP), core, w, extra)
# A base triangle is in the region when all three vertices are in the set; core points get the
# full value and the falloff runs from them (the FAP's own FP by default, as in thesis A).
LEFT_REGIONS = {
    3: (LOWER_LIP + ["2.11", "2.10", "2.1", "2.13", "5.1"], JAW_CORE, 6.0, JAW_EXTRA),
    4: (UPPER_LIP, ["2.2"], 8.0, MID_LIP),
    5: (LOWER_LIP, ["2.3"], 8.0, MID_LIP),
    6: (UPPER_LIP + LOWER_LIP + ["5.1"], ["2.4", "8.3"], 3.0, {}),
    8: (UPPER_LIP, ["2.6"], 2.5, {}),
    10: (LOWER_LIP, ["2.8"], 2.5, {}),
    12: (CORNER_REGION, ["2.4", "8.3"], 3.0, CORNER),
    14: (LOWER_LIP + ["2.11", "2.10", "2.1", "2.13", "5.1"], JAW_CORE, 6.0, JAW_EXTRA),
    15: (LOWER_LIP + ["2.11", "2.10", "2.1", "2.13", "5.1"], JAW_CORE, 6.0, JAW_EXTRA),
    16: (LOWER_LIP, ["2.3", "8.2"], 3.0, MID_LIP),
    17: (UPPER_LIP, ["2.2", "8.1"], 3.0, MID_LIP),
    18: (["2.10", "2.11", "2.1", "8.2", "8.7", "2.8", "2.3"], ["2.10"], 3.0, {"symmetric": True}),
    # The upper lid reaches up to the brow line (4.1-4.3-4.5) and out to the temple's 10.9, where its
    # border taper holds it: a closed lid covers the eye opening (~11 mm), and the skin between the
    # margin and the crease (el.ao-3.13-el.ai, 4 mm) alone stretched 3.1x; up to the brow 1.97x (default
    # face) and 2.00x (generated identity), with the temple 1.96x and 1.94x. (Also down the nose's side
    # to 9.7, the skin beside the inner corner squeezed to 0.22.)
    19: (["3.7", "el.uo", "3.1", "el.ui", "3.11", "el.ao", "3.13", "el.ai", "4.1", "4.3", "4.5", "10.9"],
         ["3.7", "el.uo", "3.1", "el.ui", "3.11"],
         1.5, {"chain": True, "profile": "opening", "opposite": ["3.7", "el.lo", "3.3", "el.li", "3.11"],
               "tilt": 0.12}),
    21: (["3.7", "el.lo", "3.3", "el.li", "3.11", "el.bo", "3.9", "el.bi"], ["3.7", "el.lo", "3.3", "el.li", "3.11"],
         1.5, {"chain": True, "profile": "opening", "opposite": ["3.7", "el.uo", "3.1", "el.ui", "3.11"],
               "tilt": 0.12}),
    # Brows: every brow FAP of a side shares one region, the brow and forehead down over the upper lid
    # to its margin, which stays pinned. Shared regions overlap, so raising inner, middle and outer
    # together lifts the brow as one smooth band instead of three bumps with creases between them,
    # and the skin between brow and lid stretches over the whole lid instead of creasing under the brow.
    31: (BROW_REGION, ["4.1"], 3.0, BROW),
    33: (BROW_REGION, ["4.3"], 3.0, BROW),
    35: (BROW_REGION, ["4.5"], 3.0, BROW),
    37: (BROW_REGION, ["4.1"], 3.0, BROW),
    39: (["5.1", "5.3", "8.3", "2.4", "10.7", "2.13", "9.1", "9.5", "8.5", "8.7"], ["5.1"], 3.0, {}),
    # The cheek lift reaches up to the lower lid's margin, which stays pinned: ending below the lid
    # (el.bo-3.9-el.bi, 8 mm above 5.3) it pushed the skin there into the lid (AU 6 lifts it ~10 mm).
    41: (["5.3", "5.1", "el.bo", "3.9", "el.bi", "10.9", "10.7", "9.1", "9.13", "9.5"] + LOWER_MARGIN, ["5.3"], 3.0,
         {"pinned": LOWER_MARGIN}),
    51: (["8.1", "8.10", "8.5", "2.2", "2.6", "9.15"], ["8.1"], 3.0, MID_LIP),
    52: (["8.2", "8.7", "2.3", "2.8", "2.10"], ["8.2"], 3.0, MID_LIP),
    53: (UPPER_LIP + LOWER_LIP + ["5.1"], ["2.4", "8.3"], 3.0, {}),
    55: (["8.5", "8.10", "8.1", "8.3", "2.6", "2.4", "2.2", "9.1", "9.5"], ["8.5"], 2.5, {}),
    57: (["8.7", "8.2", "8.3", "2.8", "2.4", "2.3", "2.11", "2.10"], ["8.7"], 2.5, {}),
    59: (CORNER_REGION, ["2.4", "8.3"], 3.0, CORNER),
    61: (["9.1", "9.5", "9.13", "9.3", "9.15", "8.10", "8.5"], ["9.1"], 3.0, {}),
    63: (["9.3", "9.1", "9.5", "9.15", "9.13", "9.12"], ["9.3"], 3.0, {"symmetric": True}),
    64: (["9.3", "9.1", "9.5", "9.15", "9.13", "9.12"], ["9.3"], 3.0, {"symmetric": True}),
}
PAIRS = {6: 7, 8: 9, 10: 11, 12: 13, 19: 20, 21: 22, 31: 32, 33: 34, 35: 36, 37: 38, 39: 40, 41: 42, 53: 54,
         55: 56, 57: 58, 59: 60, 61: 62}


def region_table(tri: np.ndarray) -> list[dict]:
    index = {n: i for i, n in enumerate(NAMES)}

    def triangles_within(names):
        ids = {index[n] for n in names}
        return [int(t) for t in np.nonzero([set(r) <= ids for r in tri])[0]]

    eye_opening = {t for ts in eye_opening_triangles(tri).values() for t in ts}
    out = []
    entries = list(LEFT_REGIONS.items()) + [(fap, UPPER_CORNER) for fap in (3, 14, 15)]
    for fap, (names, core, w, extra) in entries:
        variants = [(fap, names, core, extra)]
        if extra.get("symmetric"):
            variants = [(fap, names + [mirror_name(n) for n in names], sorted(set(core + [mirror_name(c) for c in core])),
                         extra)]
        elif fap in PAIRS:
            variants.append((PAIRS[fap], [mirror_name(n) for n in names], [mirror_name(c) for c in core],
                             {**extra, "opposite": [mirror_name(n) for n in extra.get("opposite", [])],
                              "pinned": [mirror_name(n) for n in extra.get("pinned", [])]}))
        for number, vnames, vcore, vextra in variants:
            triangles = triangles_within(vnames)
            if not vextra.get("chain"):
                # A skirt: every triangle around a core point joins the region, so no core sits on the
                # region's border and the weight can fade to zero on all sides (no crease).
                core_ids = {index[c] for c in vcore}
                skirt = [int(t) for t in np.nonzero([bool(set(r) & core_ids) for r in tri])[0]]
                triangles = sorted((set(triangles) | set(skirt)) - set(eye_opening))
            entry = {"fap": number, "triangles": triangles, "core": list(vcore), "w": w}
            if vextra.get("chain"):
                entry["core_is_chain"] = True
            if vextra.get("profile") == "opening":
                entry["profile"] = "opening"
                entry["opposite"] = vextra["opposite"]
            elif vextra.get("profile") == "jaw":
                entry["profile"] = "jaw"
                entry["corner_weight"] = vextra["corner_weight"]
            if vextra.get("pinned"):
                entry["pinned"] = vextra["pinned"]
            if vextra.get("round_top"):
                entry["round_top"] = True
            if vextra.get("round_tip"):
                entry["round_tip"] = True
            if vextra.get("scale"):
                entry["scale"] = vextra["scale"]
            if vextra.get("tilt"):
                entry["forward_tilt"] = vextra["tilt"]
            assert entry["triangles"], f"FAP {number} has an empty region"
            out.append(entry)
    return sorted(out, key=lambda e: (e["fap"], -len(e["triangles"])))


def write_json(tri: np.ndarray) -> Path:
    data = {
        "name": "mpeg4_80",
        "description": (
            "Mimica's MPEG-4 base mesh (thesis A section 5): the 64 feature points the thesis keeps "
            "(the 62 frontal points without the pupils 3.5/3.6, plus the ear-face contacts 10.7-10.10 on the "
            "outline) and 8 extra points around each eye; 140 triangles. The mouth is an opening (its inner "
            "lip contour is a boundary loop); the eye openings are covered by 6 triangles each, tagged "
            "'eye_opening' and in no FAP region, because 80 vertices and 140 triangles with the thesis's "
            "subdivision counts (300/560 ...) force Euler characteristic 0, i.e. exactly one opening besides "
            "the outline. The lids move over them. Built by tools/build_mpeg4_template.py."
        ),
        "points": NAMES,
        "extras": EXTRAS,
        "triangles": tri.tolist(),
        "outline": OUTER,
        "mouth": MOUTH,
        "eye_margins": EYE,
        "eye_opening_triangles": eye_opening_triangles(tri),
        "upper_lip_points": ["2.2", "2.6", "2.7", "8.1", "8.5", "8.6", "8.9", "8.10"],
        "lower_lip_points": ["2.3", "2.8", "2.9", "8.2", "8.7", "8.8"],
        "subdivision": ["linear", "linear", "loop"],
        "regions": region_table(tri),
    }
    path = ROOT / "resources" / "templates" / "mpeg4_80.json"
    path.write_text(json.dumps(data, indent=1))
    return path


if __name__ == "__main__":
    print("wrote", write_json(tri))
