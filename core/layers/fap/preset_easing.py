"""Presets eased jointly until their pose holds up on one face (issue 18 item 2).

A preset (an expression or viseme at 100 %) moves many FAPs at once. Each may stay inside its own
clean limit (``limits``) while together they fold the skin, smear its texture or push the lips or
lids through each other: joy's raised and stretched lip corners cross the lips at the corners and its
cheek lift pushes the lower lids into the upper ones. :func:`ease_preset` therefore measures the
preset's whole pose (``FapDeformer.deform``: the FAT, lid contact, lip contact and the teeth guard)
with ``core.mesh_quality.FaceQualityProbe`` and, while anything is broken, scales down the FAPs
that strain the broken skin most by ``STEP`` (those that strain it at least ``BLAME_SHARE`` as much
as the FAP that strains it most), until the pose holds up, ``MAX_ROUNDS`` have passed or easing
stops helping (``STALL_ROUNDS``). FAPs that
do not strain the broken skin (a joy's brows, cheek raise and lid narrowing, when the lip corners
cross) keep their full value, so the preset keeps its character. Values only ever shrink toward 0.

The result, :class:`PresetEasing`, says what was eased (for the preset's tooltip); the deformer
computes it once per preset and face and caches it (``FapDeformer.preset_easing``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

from core.layers.fap import tables

# Each round keeps this share of every blamed FAP: small steps, so a FAP is not eased further than
# needed (a round costs one pose check, about half a second at 58k vertices).
STEP = 0.85
# A FAP is blamed when it strains the skin around the broken vertices at least this share as much
# as the FAP straining it most (both FAPs of a left/right pair are blamed together).
BLAME_SHARE = 0.5
# 0.85 ** 25 = 1.7 %: a preset that still breaks after this is left at its last (eased) values.
MAX_ROUNDS = 25
# Easing stops when this many rounds in a row broke no fewer vertices than the best round so far:
# what is left does not shrink with the values (a seam that crosses at any value) and easing
# further would only mute the preset. The least-eased values of the best round are kept.
STALL_ROUNDS = 4
# What is already broken at this share of the preset is a seam that breaks at any value, not the
# preset's size: it is not blamed on the FAPs (easing cannot mend it), nor is what lies within
# SEAM_REACH_MM of it (mm, at rest; the same seam spreads a little with the values).
SEAM_SHARE = 0.05
SEAM_REACH_MM = 2.0
# Vertices that move less than this (mm) are "not moved" for the intersection tests.
MOVED_MM = 1e-3


@dataclass(frozen=True)
class PresetEasing:
    """A preset's FAP values as authored and as eased on one face.

    authored, eased: (68,) FAP values (FAP units); holds: whether the eased pose holds up (False
    when a seam breaks at any value, or easing stopped helping); rounds: pose checks run."""

    authored: np.ndarray
    eased: np.ndarray
    holds: bool
    rounds: int

    def eased_faps(self) -> list[tuple[int, float, float]]:
        """[(FAP number, authored value, eased value)] of the FAPs the easing lowered."""
        changed = np.flatnonzero(~np.isclose(self.eased, self.authored))
        return [(int(i) + 1, float(self.authored[i]), float(self.eased[i])) for i in changed]

    def note(self) -> str | None:
        """"Eased so the skin holds up on this face: open_jaw 430 -> 250 (58 %), ..." or None when
        the preset holds up as authored (mirror FAPs with the same change are named once)."""
        parts: dict[tuple[float, float], list[str]] = {}
        for number, authored, eased in self.eased_faps():
            parts.setdefault((authored, eased), []).append(tables.fap_spec(number).name)
        if not parts:
            return None
        items = [f"{'/'.join(names)} {authored:g} -> {eased:.0f} ({100 * eased / authored:.0f} %)"
                 for (authored, eased), names in parts.items()]
        head = "Eased so the skin holds up on this face" if self.holds else \
            "Eased where that helps (the skin still breaks on this face at any intensity)"
        return f"{head}: " + ", ".join(items)


def ease_preset(values: np.ndarray, pose: Callable[[np.ndarray], np.ndarray], rest: np.ndarray,
                triangles: np.ndarray, fields: Callable[[int], np.ndarray],
                broken: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> PresetEasing:
    """The preset ``values`` (68,) eased until its pose holds up (see the module docstring).

    pose(values) -> (n, 3) mm the posed face; rest (n, 3) mm and triangles (m, 3) the rest face;
    fields(i) -> (n, 3) mm per FAP unit of FAP index i (number - 1); broken(vertices, moved) -> (n,)
    bool the broken vertices of a pose (``FaceQualityProbe.broken_vertices``).

    A FAP's blame is how much it strains the skin around the broken vertices: the mean change of
    length it gives the edges there, relative to their rest length (a FAP that carries the broken
    skin along without deforming it, e.g. the jaw under a crease of the lip, is not blamed)."""
    authored = np.asarray(values, dtype=float).copy()
    eased = authored.copy()
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]),
                      axis=1), axis=0)
    length = np.maximum(np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1), 1e-9)
    field = {int(i): fields(int(i)) for i in np.flatnonzero(authored)}

    def broken_in(values: np.ndarray) -> np.ndarray:
        vertices = pose(values)
        return broken(vertices, np.linalg.norm(vertices - rest, axis=1) > MOVED_MM)

    seam = broken_in(authored * SEAM_SHARE)
    if seam.any():
        near_seam = np.zeros(len(rest), dtype=bool)
        near_seam[np.concatenate(cKDTree(rest).query_ball_point(rest[seam], SEAM_REACH_MM))] = True
        seam = near_seam
    best, best_count, stalled = eased.copy(), np.inf, 0
    for rounds in range(1, MAX_ROUNDS + 1):
        broken_now = broken_in(eased)
        bad = broken_now & ~seam
        if not bad.any():
            return PresetEasing(authored, eased, not broken_now.any(), rounds)
        count = int(bad.sum())
        if count < best_count:
            best, best_count, stalled = eased.copy(), count, 0
        else:
            stalled += 1
            if stalled >= STALL_ROUNDS:
                return PresetEasing(authored, best, False, rounds)
        near = bad[edges].any(axis=1)
        a, b, rest_length = edges[near, 0], edges[near, 1], length[near]
        blame = {i: float((np.linalg.norm(f[a] - f[b], axis=1) / rest_length).mean()) * abs(eased[i])
                 for i, f in field.items()}
        worst = max(blame.values(), default=0.0)
        if worst <= 0.0:   # broken by something no preset FAP strains: nothing to ease
            return PresetEasing(authored, best, False, rounds)
        for i, strain in blame.items():
            if strain >= BLAME_SHARE * worst:
                eased[i] *= STEP
    return PresetEasing(authored, best, False, MAX_ROUNDS)


__all__ = ["PresetEasing", "ease_preset", "STEP", "BLAME_SHARE", "MAX_ROUNDS", "STALL_ROUNDS"]
