"""Waters vector muscles (Waters 1987; thesis B §4.1.2, eqs. 4.16-4.19).

A muscle has an attachment A (bone, fixed) and an insertion I (skin), a zone angle α and a radial falloff
from S to E (fractions of |AI|, measured from A). A vertex V at angle β from AI with |AV| ≤ E·|AI| and β ≤ α
moves toward A:

    δV = −C · δ · AV                                    (4.16)   C = contraction · strength
    δ  = δA · δR  if |AV| > S·|AI|,  else δA             (4.17)
    δA = (cos β − cos α) / (1 − cos α)                   (4.18)
    δR = cos((|AV| − S·|AI|) / ((E − S)·|AI|) · π/2)     (4.19)

Evaluated at the rest face, every muscle's field is linear in its strength, so the model keeps one sparse
response B (3n, m), mm per unit strength: the sum of the muscles is B s. Combining muscles (B §4.1.2):
``sum`` (plain superposition), ``limit`` (Waters' degrees of freedom: each vertex's displacement is at most
``limit_mm`` long, longer ones are shortened along their direction) or ``strongest`` (in each group only
the strongest muscle acts, Breton et al. 2001).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse

from core.face import Face
from core.parameters import ParameterError

__all__ = ["WatersMuscle", "WatersModel", "muscle_table", "muscle_field", "COMBINE", "SIDES"]

SIDES = ("left", "right")
COMBINE = ("sum", "limit", "strongest")
_TABLE = "waters/muscles.csv"


@dataclass(frozen=True)
class WatersMuscle:
    """One placed muscle. attachment, insertion : (3,) mm; alpha_deg : zone angle; start, end : S, E as
    fractions of |AI|; contraction : C at strength 1; group : strongest-of-group group; lip : 'upper',
    'lower' or 'any'."""

    name: str
    side: str
    label: str
    attachment: np.ndarray
    insertion: np.ndarray
    alpha_deg: float
    start: float
    end: float
    contraction: float
    group: str
    lip: str = "any"

    @property
    def key(self) -> str:
        return f"waters:{self.name}:{self.side}"

    def __post_init__(self):
        if not 0 < self.alpha_deg < 180:
            raise ParameterError(f"{self.key}: the zone angle α must be between 0 and 180°, got {self.alpha_deg:g}")
        if not 0 <= self.start < self.end:
            raise ParameterError(f"{self.key}: the falloff needs 0 ≤ S < E (fractions of |AI|), got S = "
                                 f"{self.start:g}, E = {self.end:g}")
        if not self.contraction > 0:
            raise ParameterError(f"{self.key}: the contraction C must be > 0, got {self.contraction:g}")
        if np.linalg.norm(np.subtract(self.insertion, self.attachment)) < 1e-6:
            raise ParameterError(f"{self.key}: attachment and insertion coincide; move one of them")
        if self.lip not in ("upper", "lower", "any"):
            raise ParameterError(f"{self.key}: lip must be upper, lower or any, got {self.lip!r}")


@functools.cache
def muscle_table() -> tuple[dict, ...]:
    """The rows of resources/waters/muscles.csv, then their right-side mirrors, each with a 'side'."""
    import resources

    mirror = {}
    for r in resources.get_table("mpeg4/landmark_pairs.csv"):
        mirror[r["left"]], mirror[r["right"]] = r["right"], r["left"]
    rows = []
    for side in SIDES:
        for r in resources.get_table(_TABLE):
            row = dict(r, side=side)
            if side == "right":
                for end in ("attachment", "insertion"):
                    row[end] = "+".join(_mirror_term(t, mirror) for t in r[end].split("+"))
            rows.append(row)
    return tuple(rows)


def _mirror_term(term: str, mirror: dict[str, str]) -> str:
    fp, star, weight = term.strip().partition("*")
    return mirror.get(fp, fp) + star + weight


def _point(face: Face, spec: str, where: str) -> np.ndarray:
    total, weights = np.zeros(3), 0.0
    for term in spec.split("+"):
        fp, _, w = term.strip().partition("*")
        if fp not in face.landmark_names:
            raise ParameterError(f"this face lacks feature point {fp}, which the Waters muscle {where} needs; mark "
                                 "it with the landmark picker")
        weight = float(w) if w else 1.0
        total += weight * face.landmark_position(fp)
        weights += weight
    if abs(weights - 1.0) > 1e-6:
        raise ValueError(f"{_TABLE}: the weights of {spec!r} ({where}) sum to {weights:g}, not 1")
    return total


def place_muscles(face: Face) -> tuple[WatersMuscle, ...]:
    """The 18 muscles of the table on ``face`` (ParameterError naming a missing feature point)."""
    out = []
    for r in muscle_table():
        where = f"{r['name']} ({r['side']})"
        out.append(WatersMuscle(r["name"], r["side"], r["label"], _point(face, r["attachment"], where),
                                _point(face, r["insertion"], where), float(r["alpha_deg"]), float(r["start"]),
                                float(r["end"]), float(r["contraction"]), f"{r['group']}_{r['side'][0]}",
                                r["lip"]))
    return tuple(out)


def muscle_field(vertices: np.ndarray, muscle: WatersMuscle) -> tuple[np.ndarray, np.ndarray]:
    """(indices (k,), displacements (k, 3) mm): the vertices in the muscle's zone and how they move at
    strength 1 (eqs. 4.16-4.19, C = the muscle's contraction). Vectorised over the vertices."""
    a = np.asarray(muscle.attachment, dtype=float)
    ai = np.asarray(muscle.insertion, dtype=float) - a
    length = float(np.linalg.norm(ai))
    av = vertices - a
    reach = muscle.end * length
    near = np.nonzero((np.abs(av) <= reach).all(axis=1))[0]
    av = av[near]
    dist = np.linalg.norm(av, axis=1)
    cos_a = math.cos(math.radians(muscle.alpha_deg))
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_b = (av @ ai) / (dist * length)
    zone = (dist > 0) & (dist <= reach) & (cos_b >= cos_a)
    near, av, dist, cos_b = near[zone], av[zone], dist[zone], cos_b[zone]
    delta = (cos_b - cos_a) / (1.0 - cos_a)                                         # δA (4.18)
    s = muscle.start * length
    falloff = np.cos((dist - s) / ((muscle.end - muscle.start) * length) * (math.pi / 2))   # δR (4.19)
    delta = np.where(dist > s, delta * falloff, delta)                              # (4.17)
    return near, -muscle.contraction * delta[:, None] * av                          # (4.16)


class WatersModel:
    """The muscles of one face and their response B (3n, m) (immutable).

    muscles : placed muscles (default: the 18 of the table on ``face``). Only skin vertices move (not the
    eyeballs, teeth or mouth cavity); a muscle with lip='upper'/'lower' moves only that side of the mouth line.
    """

    def __init__(self, face: Face, muscles: tuple[WatersMuscle, ...] | None = None):
        from core.layers.fap.template import mouth_side
        from core.layers.rbf.regions import skin_vertices

        self.face = face
        self.muscles = place_muscles(face) if muscles is None else tuple(muscles)
        self.keys = tuple(m.key for m in self.muscles)
        if len(set(self.keys)) != len(self.keys):
            raise ParameterError("two Waters muscles have the same name and side")
        skin = skin_vertices(face)
        side = np.zeros(face.n_vertices, np.int64)
        side[skin] = mouth_side(face, skin)
        v = face.vertices[skin]
        rows, cols, vals = [], [], []
        for j, m in enumerate(self.muscles):
            idx, disp = muscle_field(v, m)
            idx = skin[idx]
            if m.lip != "any":
                keep = side[idx] != (-1 if m.lip == "upper" else 1)
                idx, disp = idx[keep], disp[keep]
            rows.append((3 * idx[:, None] + np.arange(3)).ravel())
            cols.append(np.full(3 * len(idx), j))
            vals.append(disp.ravel())
        n = face.n_vertices
        self.response = scipy.sparse.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, len(self.muscles)))
        self.moved = np.unique(np.concatenate(rows) // 3)   # vertices some muscle moves
        groups: dict[str, list[int]] = {}
        for j, m in enumerate(self.muscles):
            groups.setdefault(m.group, []).append(j)
        self.groups = {g: np.array(ix) for g, ix in groups.items()}

    def strongest(self, strengths: np.ndarray) -> np.ndarray:
        """(m,) the strengths with only the strongest muscle of each group kept (ties: the first)."""
        s = np.asarray(strengths, dtype=float)
        out = np.zeros_like(s)
        for ix in self.groups.values():
            k = ix[int(np.argmax(s[ix]))]
            out[k] = s[k]
        return out

    def displacement(self, strengths, combine: str = "sum", limit_mm: float | np.ndarray = 10.0) -> np.ndarray:
        """(n, 3) mm for strengths (m,) in muscle order (``combine``: see the module docstring; ``limit_mm``
        a scalar or (n,) per-vertex limits)."""
        s = np.asarray(strengths, dtype=float)
        if combine not in COMBINE:
            raise ParameterError(f"Waters muscles combine by {', '.join(COMBINE)}, got {combine!r}")
        if combine == "strongest":
            s = self.strongest(s)
        out = (self.response @ s).reshape(-1, 3)
        if combine == "limit":
            moved = self.moved
            d = out[moved]
            length = np.sqrt(np.einsum("ij,ij->i", d, d))
            cap = np.broadcast_to(np.asarray(limit_mm, dtype=float), (self.face.n_vertices,))[moved]
            over = length > cap
            if over.any():
                d[over] *= (cap[over] / length[over])[:, None]
                out[moved] = d
        return out

    def vertex_response(self, vertices) -> np.ndarray:
        """(3k, m) mm per unit strength of the given vertices (x, y, z rows per vertex): the linear map the
        inverse solves."""
        v = np.asarray(vertices, dtype=np.int64).ravel()
        rows = (3 * v[:, None] + np.arange(3)).ravel()
        return self.response[rows].toarray()
