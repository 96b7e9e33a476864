"""The Facial Animation Table (FAT): every FAP's displacement field as one sparse matrix.

Built once per face (about a second for the 50k-vertex default face):

1. the 80-point template is placed on the face and densified to 4560 vertices (``template``);
2. each FAP's influence region is the set of dense vertices inside its base triangles
   (``resources/templates/mpeg4_80.json``); d[x] is the breadth-first hop distance from the FAP's
   core inside the region graph, d_max the largest, and the weight is
   ``exp(-d² / (2·d_max·w))`` with the FAP's w (thesis A §5); d is measured along the surface in
   median edge lengths (the thesis's hops without their hexagonal iso-lines). Mimica multiplies the
   Gaussian by a smooth taper that is 1 from the core to half-way to the region's border and 0 on it,
   because the Gaussian alone stops at a nonzero weight and neighbouring regions meet in a crease;
   every region also includes the triangles around its core points (a skirt) so the taper has room;
   then the weights are relaxed (Jacobi steps of Laplacian smoothing, core and zero border fixed)
   so that no ramp between them is steeper than it must be (a steep ramp folds or tears the skin
   at a slider's end); regions the template marks ``round_top`` (the lip corners) also hold the
   Gaussian's top (weights >= ``ROUND_TOP``), as a point core held alone becomes a cone. The core
   is the FAP's feature point
   (thesis A), widened where a rigid part must follow in full (the jaw moves the lower lip and
   chin together; the lip-corner FAPs move the inner and outer corner together). For the eyelids
   the core is the whole lid margin, each margin vertex weighted by the local height of the eye
   opening relative to the centre (``profile = opening``), so a fully closed lid meets the other
   lid along the whole margin instead of bulging at the centre; lids also move slightly forward
   (``forward_tilt``) so they slide over the eyeball rather than through it;
3. the face's skin vertices are bound to the dense template (closest point, barycentric; lip
   vertices only to their own lip so the jaw never drags the upper lip), relaxed over the face mesh
   where that binding jumps (``smooth_binding``), and the lower teeth to the jaw; the mouth cavity's
   lining follows the skin it lies behind (its closest skin point's rows, in full within
   ``CAVITY_FOLLOW_NEAR_MM`` of the skin, fading to none at ``CAVITY_FOLLOW_FAR_MM``: the back of
   the mouth stays with the skull); eyeballs and upper teeth have no rows (rigid).

Then ``x = rest + F · (fap_values ∘ fapu)`` with F of shape (3n, 68), mm per FAP unit.

Several FAPs on one point add their displacements. The exception is lid contact: when an upper
and a lower lid of one eye together close more than the opening (close_t + close_b > 1024 IRISD),
both are scaled down so that they meet (``lid_contact``); the slider values are kept. Before that a
raised cheek carries its lower lid up (``carried_lower_lids``: AU 6 narrows the eye from below), and
a lower lid closed past its reach hands the rest to its upper lid (``lower_lid_handover``). The lid
columns are fitted to the face's own eye opening (``fit_lids_to_rims``). After every
layer's offset, lips moved into each other press on each other instead (``lip_contact.LipContact``:
both give way by half the overlap), and skin that ended inside a row of teeth is pushed back out
over it (``teeth_guard.TeethGuard``: the teeth move rigidly with the jaw, the skin only part way);
the mouth's skin is then smoothed once more where that left it strained (``surface_guard``).
"""

from __future__ import annotations

import math
import sys
from typing import Callable, NamedTuple, Sequence

import numpy as np
import scipy.sparse

import resources
from core.cache import DiskCache, fingerprint, source_version
from core.face import Face
from core.surface_query import TriangleSet
from core.layers.fap import kernels, tables
from core.layers.fap.eyeball_surface import (PUSH_TURN_END_RAD, PUSH_TURN_START_RAD, RADIUS_MAP_REACH_RAD,
                                             RADIUS_MAP_STEP_RAD, map_radius, push_outside,
                                             radius_map)
from core.layers.fap.column_relax import relax_columns
from core.layers.fap.closed_eyes import CLOSED_EYE_GAP, closed_eye_side, closed_lid_lines
from core.layers.fap.limits import (EASE_START, FOLD_REASON, NOSTRIL_REASON, bisect, clean_limits, finished_limits,
                                    keeping, new_crossings, preset_reach, soft_limit)
from core.layers.fap.lip_contact import LipContact
from core.layers.fap.step_memo import StepMemo
from core.layers.fap.surface_guard import SurfaceGuard
from core.layers.fap.teeth_guard import TeethGuard
from core.layers.fap.template import BaseTemplate, DenseTemplate, TemplateError, densify, load_template, mouth_side
from core.mesh_quality import welded_vertices


def dijkstra(*args, **kwargs):
    """``scipy.sparse.csgraph.dijkstra``, imported on first use: binding a face needs it, reading a
    bound rig from the cache (the window's start-up) does not, and the import costs ~0.2 s."""
    from scipy.sparse.csgraph import dijkstra as scipy_dijkstra

    return scipy_dijkstra(*args, **kwargs)


N_FAPS = tables.N_FAPS
LID_PAIRS = ((19, 21), (20, 22))  # (upper, lower) per eye
LOWER_LIDS = frozenset(lower for _upper, lower in LID_PAIRS)
OUTSIDE_FADE_MM = 20.0
# Relaxation steps of each region's weights (see _relax); measured by benchmarks/face_quality.py on
# the default face: folded triangles over all FAP extremes and presets 21,813 -> 5,367, lip
# intersections 8,708 -> 5,012, teeth 5,865 -> 3,741, lid 5,040 -> 3,826 (30 steps).
SMOOTHING_STEPS = 30
# The skin's closest-point binding jumps between dense triangles where the skin folds (the inner lower
# lip), around the nostrils and under the chin: neighbouring vertices bound to template points more than
# BINDING_JUMP x their own distance apart. Within BINDING_JUMP_RINGS rings of such an edge the binding is
# relaxed by BINDING_SMOOTHING_STEPS Jacobi steps over the face mesh (smooth_binding); elsewhere it is
# kept, so every FAP keeps its weight at its feature point. face_quality (FAP extremes, expressions,
# visemes, blends; failing poses default / generated face): none 50 / 51; everywhere 5 steps 40 / 33 but
# FAPs lost up to 23 % of their weight at their feature points (8.1: 0.93 -> 0.71) and 14 poses failed
# anew (corner stretch 2.99, visemes CH, RR 2.5); jumps > 3x, 5 rings 39 / 48; > 2x, 5 rings 37 / 48;
# > 2x, 3 rings (faded-out scalp skin not counted, the one kept) 36 / 49: 17 poses pass anew, one fails anew
# (fap 5 raise_b_midlip at -800, 24 lip crossings: its texture-smear limit moved from -255 to -598,
# and that far down the lower lip tucks into the chin skin; the lips' crossing limit now stops it at -463).
BINDING_SMOOTHING_STEPS = 5
BINDING_JUMP = 2.0
BINDING_JUMP_RINGS = 3
# Skin vertices of one lip side this close (mm) are one point (an unwelded seam: the default face's
# face/head-shell seam has ~1000 such pairs) and take one binding row: rows that differ tear the sliver
# between them (38x stretch at open_jaw on the default face).
DUPLICATE_MM = 0.02
# A round-top region's Gaussian at or above this is its top, held through the relaxation (0.9 -> 0.95 on the
# default face: expression + viseme folds 547 -> 476, lip crossings 30 -> 20).
ROUND_TOP = 0.95
# A round-tip region's relaxed field is smoothed this far from its core (hops of the dense template's
# median edge) by this many steps with the core free (see _rounded_tip).
TIP_ROUNDING_HOPS = 6.0
TIP_ROUNDING_STEPS = 10
LID_CLEARANCE_MM = 0.4      # a closing lid slides this far outside the eyeball
MIN_LID_CLEARANCE_MM = 0.1  # ... or at least this far (a 2 mm lid triangle sags 0.03 mm into a 15 mm ball)
CHEEK_GUARD_REACH_MM = 4.0  # cheek-lift and brow skin that comes no nearer the eyeball than this is not guarded
GUARD_REACH_SAMPLES = 9     # values along each cheek / brow FAP's range at which that is checked
# Skin that moved this far (mm) takes the lid guard's full clearance (face_quality on the presets: joy's
# lid/eyeball crossings 34 -> 0, folds 370 -> 394; 1 mm: 8 crossings, 4 mm: 8 and 168 folds).
GUARD_SLIDE_MM = 2.0
# The lid guard reads the eyeball's real surface (eyeball_surface: a radius map over both angles about
# the gaze axis), so skin that lies outside the ball has a true, positive rest gap. Measured together
# by core.mesh_quality on the default face (generated identity), lid crossings / folded triangles:
# skin pushed from its rest gap r > LID_CLEARANCE_MM keeps this share of r - LID_CLEARANCE_MM (0:
# lift_l_cheek 400 3 / 34 (0 / 18), joy 2 / 90 (2 / 173); 0.25 with CHEEK_BULGE 0.1: 0 / 10
# (0 / 2), 0 / 38 (0 / 137); 0.5: 8 / 12 on lift_l_cheek 400 alone) ...
REST_GAP_KEPT = 0.25
# ... and with the cheek raised (in full from CHEEK_CARRY_BLEND ENS) skin that slid past GUARD_SLIDE_MM
# stands this many mm farther off per mm slid beyond (0: lift_l_cheek 400 4 / 7, both cheeks 220
# 8 / 12, joy 8 / 36; 0.1: 0 / 10, 0 / 14, 0 / 38; 0.25: 0 / 33, 0 / 42, 0 / 66; gated by the lids
# instead of the cheek, the closed lids bulged into each other: blink 8 -> 26 crossings).
CHEEK_BULGE = 0.1
# How far the lid margins follow the cornea's vertical travel as the eye turns down (upper, lower) and
# up. Measured on the default face (core.mesh_quality, lid/eyeball crossings, folded triangles): both
# eyes 15 deg down 208 -> 0 crossings, 0 folds; 30 deg down 324 -> 27 (53 folds; 0.9/0.4 left 39 and
# 60); 30 deg up 135 -> 75 (5 folds; following 0.7/0.3 up folded 130 triangles of the raised lid).
# With the ball pitched about its own centre (_eyeball_pitch_centres) it no longer swings into the
# socket, and what crossed was the lids' own skin moved that far: both eyes 30 deg down, 0.6/0.3 54
# crossings and 106 folds, 0.4/0.2 0 and 6 (generated face 18/20 -> 0/2); 30 deg up, 0.3/0.1 28
# crossings and 10 folds, 0.2/0.1 0 and 2 (generated 24/0 -> 0/0).
UPPER_LID_FOLLOW = 0.4
LOWER_LID_FOLLOW = 0.2
LIDS_FOLLOW_UP = (0.2, 0.1)
# The mouth cavity's lining follows the skin it lies behind: in full within NEAR of it, not at all
# beyond FAR (smoothly in between). Fixed, it let skin moved inward pass through it (default face:
# shift_jaw 400 209 crossing pairs, puff_cheek -300 202, depress_chin 400 94). A lining vertex d mm
# behind the skin keeps a gap of d - (1 - follow(d)) x the skin's travel, positive for any travel
# shorter than FAR.
CAVITY_FOLLOW_NEAR_MM = 4.0
CAVITY_FOLLOW_FAR_MM = 20.0
# The brow FAPs of each eye (raise inner/middle/outer, squeeze): lowered, they push the upper lid's
# skin into the eyeball (default face, brows at -400: 88-172 crossing pairs per FAP), so the lid guard
# also holds the skin they move near the ball.
BROW_FAPS = ((31, 33, 35, 37), (32, 34, 36, 38))
# Inner- and outer-lip FAPs of one motion (4 and 51 lower the top mid-lip, ..., 12 and 59 raise the left
# corner): MPEG-4 moves each one's feature point by its value, but on a face the two contours meet at
# the corners and enclose the vermilion, where both regions reach. Summed, equal values (Table B.1's
# presets give both: joy 284 MNS to 12 and 59) moved a corner twice as far (12 + 59 at 200 MNS: 7.70 mm
# where each alone moves 3.85; stretch 6 + 53: 18.75 mm for 9.38). Where both push the same way, their
# common part (the smaller weight x the smaller value) is taken out (:meth:`FapDeformer._paired_lip_overlaps`):
# there the skin moves as the larger of the two, and a FAP alone moves as before.
PAIRED_LIP_FAPS = tuple((n, n + 47) for n in range(4, 14))
LIP_FAPS = frozenset(n for pair in PAIRED_LIP_FAPS for n in pair)
# The nose FAPs move the nostrils' pocket walls, which pass through each other as lips do (the generated
# identity's nostrils: 2-3 crossing pairs at stretch_nose's ends, +-200 ENS): their slider ends stop there too.
NOSE_FAPS = frozenset({61, 62, 63, 64})
# A lip triangle moved less than this (mm) by a FAP alone is not tested for crossing at its slider ends.
LIP_CROSSING_MOVE_MM = 0.05
_PAIR_INNER = np.array([i - 1 for i, _o in PAIRED_LIP_FAPS])
_PAIR_OUTER = np.array([o - 1 for _i, o in PAIRED_LIP_FAPS])
# The lids' and cheek lifts' FAPs (numbers).
LIDS_AND_CHEEKS = (19, 20, 21, 22, 41, 42)
# FAP indices (n - 1) the lid step reads: lids, cheek lifts, brows.
LID_GUARD_COLUMNS = np.array([n - 1 for n in LIDS_AND_CHEEKS] + list(range(30, 38)))
# FAPs whose fields column_relax leaves as bound: the upper lids and the cheek lifts. Spread toward the
# eye, a cheek's lift pushed its lower lid into the eyeball and the guard folded it (default face,
# lift_cheek at 400: 7 -> 18 folded triangles; relaxed on 2026-11-30 its squeeze went 0.21 -> 0.16). The lower
# lids are relaxed: a scan's binding steepens their field at the inner canthus (the Surrey Face Model
# scan: 0.60 mm of close_b_l_eyelid at 320 IRISD across a 0.7 mm triangle squeezed it to 0.18x in joy
# and its 14 mixes with visemes; relaxed 0.40x, and the lids' own 1024 ends fold less).
UNRELAXED_FAPS = (19, 20, 41, 42)
# Eyeball vertices whose mean motion gives the lid guard the ball's shift (see _ball_anchors).
BALL_ANCHORS = 16
GUARD_RAMP = 512.0          # closing FAP units (IRISD, ENS for the cheek) over which the lid guard takes hold
# An upper lid opened past about 250 IRISD rises under its crease and folds through it (default face
# 14 crossing pairs per eye at close_t -300, generated identity 23): that slider end is eased to the
# value where the crossings begin (FapDeformer._lid_crease_limit), from this share of it on, so
# fear's -200 still passes as authored (from 0.7 of it, the global ease, it would have to reach 286).
# Since the surface guard lets the lid's skin slide on the eyeball, neither face crosses at -300 (their
# limit is none); the check stays for faces that still would.
LID_OPENING_EASE_START = 0.85
CREASE_REASON = "the lid would fold through its crease"
# Bisection steps of that value: 300 / 2^7 = 2.3 IRISD (each step poses and checks the face: 0.12 s
# at 59k vertices, so a cold build pays about 1.7 s for both eyes).
CREASE_BISECTION_STEPS = 7
# The lid FAPs' columns are fitted to the face's own eye opening (fit_lids_to_rims): the template's
# smoothed margins overshot the real rims toward the corners by 10-20 % on the default face, and the
# closed lid's rim, lifted back alone, folded its triangles (close_t/b_eyelid 1024: 5 and 7 folds).
# The fit's scale is averaged along the eye over this width (mm, Gaussian sigma) and only read where
# both the wanted and the template's travel exceed LID_FIT_MIN_MM (the corners' are noise).
LID_FIT_SIGMA_MM = 1.0
LID_FIT_MIN_MM = 1.0
# A lid closed alone passes the other's rim by this much (mm), which the upper-stops-on-lower step
# takes back: the fit's residual (about 1 % at the lid centre) otherwise left the closed eye a slit.
LID_FIT_OVERLAP_MM = 0.1
# ... and kept within these bounds (a scan's rims that disagree with its landmarks more than this are
# better left to the template's margin and the upper-stops-on-lower step).
LID_FIT_SCALE_RANGE = (0.6, 1.6)
# A lower lid rises at most about LOWER_LID_REACH IRISD by itself; closed further, the upper lid comes
# down to meet it (lower_lid_handover), so the eye still closes at 1024. Measured alone (face_quality's
# probe; default face / generated identity): the lower lid's skin stretched 1.79 / 1.82x at 400,
# 1.95 / 1.99 at 500, 2.14 / 2.17 at 600 and 2.90 / 2.96 at 1024 with folds (a real lower lid rises
# a few millimetres; AU 6's cheek pushes it ~4). The handover starts at LOWER_LID_HANDOVER, above every
# preset's lower lid (250) and the usual cheek carry.
LOWER_LID_REACH = 450.0
LOWER_LID_HANDOVER = 300.0
HANDOVER_NOTE = (f"the lower lid rises at most {LOWER_LID_REACH:.0f} by itself (its skin would smear); "
                 f"from {LOWER_LID_HANDOVER:.0f} on the upper lid comes down to meet it, so the eye still "
                 "closes at 1024")
# Closed lids: within LID_CONTACT_MM of the lower rim the upper rim is brought up to LID_TUCK_MM in
# front of it, moving at most LID_TUCK_MAX_MM (blended in by the gap, so it does not pop; a library
# pose whose lower lid stood 0.8 mm in front of the upper near the outer corner had that rim pulled
# out, 2.5x stretched, when the whole difference was made up; the generated identity's lower lid closed
# at 1024 meets its upper lid 0.22 mm in front of it); an eye corner stays below the line across it
# by this share of its rest depth (FapDeformer._find_canthus_triangles).
LID_CONTACT_MM = 0.5
LID_TUCK_MM = 0.2
LID_TUCK_MAX_MM = 0.45
CANTHUS_KEPT = 0.5
# (cheek lift, lower lid) FAP pairs: a raised cheek carries its eye's lower lid up (see lid_values).
CHEEK_LIDS = ((41, 21), (42, 22))
# The lower lid rises at least this many IRISD per ENS of cheek lift, a smaller share than FACS's
# own cheek raiser asks (AU 6: 320 IRISD with 220 ENS, resources/facs/action_units.csv), so the
# presets keep their values. Measured by core.mesh_quality: lift_l_cheek 400 alone (eased to 310
# by its clean limit) default face 119 lid crossings -> 11, folded triangles 248 -> 152, generated
# identity 12 -> 0, 77 -> 65 (ratio 1.3 and 1.7: the same crossings, the lid margin's texture
# stretched 7.3 and 9.7 x; tilting the lift forward over the eyeball folded less but crossed more).
CHEEK_CARRIES_LID = 1.0
# Width (FAP units) over which the cheek's carry of a lower lid sets in (see carried_lower_lids).
CHEEK_CARRY_BLEND = 64.0


def lid_contact(values: np.ndarray, closed: tuple[tuple[int, int], ...] = ()) -> np.ndarray:
    """(68,) FAP values with each eye's closing values scaled so the lids meet instead of crossing.
    ``closed``: the (upper, lower) FAP pairs of eyes closed on the face at rest (a scan taken with the
    eyes shut), whose lids already meet: their closing values do nothing (opening ones still open)."""
    out = np.array(values, dtype=float)
    for upper, lower in closed:
        out[upper - 1], out[lower - 1] = min(out[upper - 1], 0.0), min(out[lower - 1], 0.0)
    for upper, lower in LID_PAIRS:
        t, b = max(out[upper - 1], 0.0), max(out[lower - 1], 0.0)
        total = (t + b) / 1024.0
        if total > 1.0:
            if out[upper - 1] > 0:
                out[upper - 1] /= total
            if out[lower - 1] > 0:
                out[lower - 1] /= total
    return out


def carried_lower_lids(values: np.ndarray) -> np.ndarray:
    """(68,) FAP values with each lower lid carried up by its raised cheek, in place: the lid's
    value plus ``ramp(CHEEK_CARRIES_LID x cheek - the lid's own closing)``, so a lid closing by
    itself at least as far as the cheek carries it keeps its value (the presets), and an opened or
    resting lid rises with the cheek. ``ramp`` is 0 below 0 and u - CHEEK_CARRY_BLEND / 2 above the
    blend width, joined by a parabola (C1): the carry is continuous in every value.

    The cheek lift (AU 6) moves the skin under the eye up by up to 8 mm at the slider's end while
    its region is held at 0 on the lower lid's margin: the few millimetres of skin between were
    squeezed to nothing and folded through themselves (default face, lift_cheek 400: 119 lid
    crossings). In a face the raised cheek pushes the lower lid up (a Duchenne smile narrows the
    eye from below), so the lid's own FAP carries its margin along."""
    for cheek, lower in CHEEK_LIDS:
        carry = CHEEK_CARRIES_LID * float(values[cheek - 1])
        if carry > 0:
            values[lower - 1] += smooth_ramp(carry - max(float(values[lower - 1]), 0.0), CHEEK_CARRY_BLEND)
    return values


def lower_lid_handover(values: np.ndarray) -> np.ndarray:
    """(68,) FAP values with each lower lid's closing eased toward LOWER_LID_REACH and what it gives
    up added to its upper lid, in place: above LOWER_LID_HANDOVER = h the lower lid rises
    h + (R - h) tanh((v - h) / (R - h)) (C1, never past R), so upper + lower closing is unchanged and
    lid contact still closes the eye at 1024."""
    span = LOWER_LID_REACH - LOWER_LID_HANDOVER
    for upper, lower in LID_PAIRS:
        value = float(values[lower - 1])
        if value > LOWER_LID_HANDOVER:
            eased = LOWER_LID_HANDOVER + span * math.tanh((value - LOWER_LID_HANDOVER) / span)
            values[lower - 1] = eased
            values[upper - 1] += value - eased
    return values


def rim_height_at(x: np.ndarray, rim: np.ndarray) -> np.ndarray:
    """(m,) mm: the height y of the polyline through ``rim`` (k, 3) points, taken in order of x, at
    ``x`` (m,) mm (held at its ends beyond them)."""
    order = np.argsort(rim[:, 0])
    return np.interp(x, rim[order, 0], rim[order, 1])


def fit_lids_to_rims(F: scipy.sparse.csr_matrix, vertices: np.ndarray, rims: Sequence[tuple[np.ndarray, np.ndarray]],
                     fapu_vector: np.ndarray, skip: frozenset[int] = frozenset()) -> scipy.sparse.csr_matrix:
    """(3n, 68) FAT ``F`` with each lid FAP's column scaled so that at 1024 IRISD its lid margin
    reaches the other lid's rim (LID_FIT_OVERLAP_MM past it) all along the eye, not only at the lid
    centre.

    ``rims``: per eye (upper rim, lower rim) vertex indices of the skin's eye opening (``vertices``
    (n, 3) mm); ``fapu_vector`` (68,) mm per FAP unit; ``skip``: FAP numbers left as they are (an
    eye closed at rest). A column's rows are scaled by a smooth function of x (the ratio of the wanted
    to the template's travel on the rim, averaged over LID_FIT_SIGMA_MM), so the skin above a rim
    vertex moves in proportion with it."""
    F = F.tocsc(copy=True)
    for pair in LID_PAIRS:
        for side, number in enumerate(pair):
            if number in skip:
                continue
            lo, hi = F.indptr[number - 1], F.indptr[number]
            rows, values = F.indices[lo:hi], F.data[lo:hi]
            column_y = np.zeros(len(vertices))
            on_y = rows % 3 == 1
            column_y[rows[on_y] // 3] = values[on_y]
            # The eye this lid belongs to: the rim its column moves most.
            eye = max(rims, key=lambda r: np.abs(column_y[r[side]]).sum(), default=None)
            if eye is None or not np.abs(column_y[eye[side]]).any():
                continue
            own, other = eye[side], eye[1 - side]
            wanted = rim_height_at(vertices[own, 0], vertices[other]) - vertices[own, 1]
            wanted += np.sign(wanted) * LID_FIT_OVERLAP_MM
            travel = column_y[own] * fapu_vector[number - 1] * 1024.0
            usable = ((np.abs(wanted) > LID_FIT_MIN_MM) & (np.abs(travel) > LID_FIT_MIN_MM)
                      & (wanted * travel > 0))
            if not usable.any():
                continue
            x, ratio = vertices[own[usable], 0], wanted[usable] / travel[usable]
            weight = np.exp(-0.5 * ((x[:, None] - x[None, :]) / LID_FIT_SIGMA_MM) ** 2)
            smooth = np.clip(weight @ ratio / weight.sum(axis=1), *LID_FIT_SCALE_RANGE)
            order = np.argsort(x)
            values *= np.interp(vertices[rows // 3, 0], x[order], smooth[order])
    return F.tocsr()


def smooth_ramp(u: float, width: float) -> float:
    """0 for u <= 0, u - width / 2 for u >= width, u² / (2 width) in between (C1)."""
    if u <= 0.0:
        return 0.0
    if u >= width:
        return u - width / 2
    return u * u / (2 * width)


class LidGuard(NamedTuple):
    """One eye's lid guard (:meth:`FapDeformer._lid_guards_over_eyeballs`)."""

    lid: np.ndarray               # (k,) the guarded skin's vertex indices
    centre: np.ndarray            # (3,) mm, the eyeball's centre at rest (a sphere fit)
    rest_clearance: np.ndarray    # (k,) mm, the clearance at rest (the rest gap where smaller)
    full_clearance: np.ndarray    # (k,) mm, the clearance of a closed eye or of skin that slid
    radii: np.ndarray             # (m, m) mm, the eyeball's radius map about ``centre`` (eyeball_surface)
    max_radius: float             # mm, the map's largest radius (skin farther out needs no lookup)
    faps: tuple[int, int, int]    # the eye's upper lid, lower lid and cheek lift FAP numbers
    rest: np.ndarray              # (k, 3) mm, the guarded vertices at rest
    gaze_radius: float            # mm, the eye's radius for the lids' gaze following (see _radius_profile)


class FapDeformer:
    """FAP deformation of one face: the FAT matrix plus the rigid eyeball and head motions.

    Raises TemplateError (a ValueError with a user message) if the face lacks feature points.
    """

    def __init__(self, face: Face, template: BaseTemplate | None = None,
                 progress: Callable[[float, str], None] | None = None, dense: DenseTemplate | None = None,
                 binding: scipy.sparse.csr_matrix | None = None):
        """``dense``: the template already fitted on ``face`` (a registration's canonical face, see
        ``core.registration.scan_mouth.AnimatedScan.dense``) instead of densifying it here;
        ``binding`` (n, N): each face vertex's weights on ``dense``'s vertices when known (the animated
        scan's own, cut lips and lids included: ``AnimatedScan.binding``) instead of closest points."""
        report = progress or (lambda _fraction, _message: None)
        self.face = face
        self.template = dense.template if dense is not None else (template or load_template())
        report(0.0, "Placing the FAP template on the face…")
        self.dense: DenseTemplate = dense if dense is not None else densify(face, self.template)
        positions = {n: face.landmark_position(n) for n in face.landmark_names}
        self.fapu = tables.measure_fapu(positions)
        self.specs = tables.fap_specs()
        report(0.45, "Weighting each FAP's influence region…")
        self.template_matrix, self.template_weights = self._template_fat()
        report(0.55, "Binding the skin to the template…")
        if binding is not None and binding.shape != (face.n_vertices, len(self.dense.vertices)):
            raise ValueError(f"binding must have shape {(face.n_vertices, len(self.dense.vertices))}, got {binding.shape}")
        self.binding = scipy.sparse.csr_matrix(binding) if binding is not None else self._bind()
        report(0.95, "Finishing the FAP table…")
        n = face.n_vertices
        B3 = scipy.sparse.kron(self.binding, scipy.sparse.identity(3, format="csr"), format="csr")
        F = (B3 @ self.template_matrix).tocsr()
        # Where binding region by region left a ramp on the face steeper than the skin takes at a
        # slider's end, spread it (column_relax); not UNRELAXED_FAPS' columns. The brows' are
        # (raise_o_eyebrow 400 on the default face: stretch 2.16 -> 1.99 beside the temple; surprise
        # 2.29 -> 2.09).
        skin = ~self._in_any_part()
        skin_triangles = face.triangles[skin[face.triangles].all(axis=1)]
        presets = np.concatenate([tables.expression_table(), tables.viseme_table()])
        F = relax_columns(F, face.vertices, skin_triangles,
                          np.array([self.fapu.get(s.unit, 0.0) for s in self.specs]), self.specs,
                          sorted(set(range(1, N_FAPS + 1)) - set(UNRELAXED_FAPS)), preset_reach(presets))
        self.fapu_vector = np.array([self.fapu.get(s.unit, 0.0) for s in self.specs])
        self._eye_rims = self._eye_rims_of_skin()
        # Eyes closed at rest (a scan taken with them shut): their lids already meet (lid_contact).
        self._closed_lid_pairs = tuple(pair for eye, pair in (("l", LID_PAIRS[0]), ("r", LID_PAIRS[1]))
                                       if eye in {line.eye for line in closed_lid_lines(face)})
        F = fit_lids_to_rims(F, face.vertices, self._eye_rims, self.fapu_vector,
                             frozenset(n for pair in self._closed_lid_pairs for n in pair))
        F = F + self._lower_teeth_rows()
        F = F + self._cavity_rows(F)
        self.matrix = F.tocsr()
        self.matrix.eliminate_zeros()
        self.pair_overlaps = self._paired_lip_overlaps()
        self._rest = face.vertices.ravel()
        # Every separate eyeball guards its lids; gaze (FAPs 23-26) turns both eyes, so it needs two (a
        # scan with one eye shut has one: the eyeball added behind that lid).
        self._eyes = self._eyeball_pivots()
        self._gaze = len(self._eyes) == 2
        self._pitch_centres = self._eyeball_pitch_centres()
        self._lid_guards = self._lid_guards_over_eyeballs()
        self._canthus_triangles = self._find_canthus_triangles()
        self._rest_lid_gaps = [face.vertices[upper, 1] - rim_height_at(face.vertices[upper, 0], face.vertices[lower])
                               for upper, lower in self._eye_rims]
        self._teeth_guard = TeethGuard(face, np.nonzero(skin)[0])
        self._lip_contact = LipContact(face, np.nonzero(skin)[0])
        self._memos = self._step_memos()
        margins = np.zeros(n, bool)
        for upper, lower in self._eye_rims:
            margins[upper] = margins[lower] = True
        balls = tuple((guard.lid, guard.centre, self._ball_anchors("eyeball_l" if 19 in guard.faps else "eyeball_r"))
                      for guard in self._lid_guards)
        self._surface_guard = SurfaceGuard(face.vertices, skin_triangles, margins,
                                           self._seam_moving_as_one(skin_triangles), balls)
        self._mouth = self._surface_guard.region("mouth", self._teeth_guard.watched)
        if len(self._teeth_guard.watched):
            reads, writes = self._surface_guard.footprint(self._mouth)
            teeth = self._memos["teeth"]
            self._memos["mouth"] = StepMemo(np.union1d(reads, teeth.reads), np.union1d(writes, teeth.writes))
        self._head_pivot = self._estimate_head_pivot()
        animated = [s.number for s in self.specs if s.thesis]
        if self._gaze:
            animated += [23, 24, 25, 26]
        animated += [48, 49, 50]
        self.animated_faps = tuple(sorted(animated))
        report(0.97, "Finding where each FAP would break the surface…")
        # The lids' closing ends are not limited: they must close completely at 1024 IRISD, and lid
        # contact and the lid guard shape them, which a linear fold check does not see.
        lids = {n for pair in LID_PAIRS for n in pair}
        limited_faps = [n for n in self.animated_faps if n not in lids]
        limits, self.limit_reasons = clean_limits(face.vertices, skin_triangles, self.matrix, self.fapu_vector,
                                                  self.specs, limited_faps)
        # The upper lids' opening ends also stop where a lid folds through its own crease (a linear
        # fold check does not see it: the lid skin rises under the crease and crosses it).
        self.ease_start = np.full((N_FAPS, 2), EASE_START)
        from core.mesh_quality import FaceQualityProbe

        probe = FaceQualityProbe(face)
        for number, side in ((19, "left"), (20, "right")):
            if number in self.closed_lid_faps:
                # An eye closed at rest has no crease to fold into: opening it stretches the closed lid
                # over the eyeball (as finished_limits below, which leaves it alone too). Checked only to
                # the table's -300 of its -1324, one lid pair touching at -300 capped a closed-eye scan's
                # left lid at -210 (2 mm of its 10 mm opening).
                continue
            crease = self._lid_crease_limit(probe, number, side)
            if crease > limits[number - 1, 0]:      # both negative: the crease comes first
                limits[number - 1, 0], self.limit_reasons[number - 1, 0] = crease, CREASE_REASON
                self.ease_start[number - 1, 0] = LID_OPENING_EASE_START
        # Then every limit on the finished pose; of the lids only the opening ends (closing must reach
        # 1024), and not those of an eye closed at rest: opening it must stretch the closed lid's skin
        # over the eyeball. (The default face's eye rims once left slivers that stopped the lower lids
        # at -61 of -300; rim_slivers removes them, and the lids open to -300 unbroken.) The lip FAPs
        # also stop where the lips cross (the lower midlip, FAP 5, rolls under the chin's skin from -463
        # MNS on the default face, before its texture smears at -598): a crossing test costs ~40 ms per
        # pose (+1.7 s of build), so the lip and nose FAPs only (the nostrils' walls are lip triangles
        # to the probe: within 0.9 mouth widths of the mouth).
        self.preset_reach = preset_reach(presets)
        lip_faps = [n for n in limited_faps if n in LIP_FAPS]
        nose_faps = [n for n in limited_faps if n in NOSE_FAPS]
        finished_limits(self.deform, face.vertices, skin_triangles, limits, self.limit_reasons, self.specs,
                        [n for n in limited_faps if n not in LIP_FAPS | NOSE_FAPS], self.preset_reach)

        # Only pairs a pose newly crosses count: a registered scan's closed lips may zigzag across each
        # other at rest (79 pairs on a Surrey Face Model neutral), which stopped every lip and nose FAP
        # of it within a few units.
        lips_cross = None if probe.lip_tris is None else new_crossings(face.vertices, probe.lip_tris, probe.welded,
                                                                        LIP_CROSSING_MOVE_MM)
        finished_limits(self.deform, face.vertices, skin_triangles, limits, self.limit_reasons, self.specs,
                        lip_faps, self.preset_reach,
                        crossing=lips_cross)
        finished_limits(self.deform, face.vertices, skin_triangles, limits, self.limit_reasons, self.specs,
                        nose_faps, self.preset_reach,
                        crossing=lips_cross, crossing_reason=NOSTRIL_REASON)
        finished_limits(self.deform, face.vertices, skin_triangles, limits, self.limit_reasons, self.specs,
                        sorted({19, 20, 21, 22} - self.closed_lid_faps), self.preset_reach, sides=(0,))
        # Where the surface breaks (each FAP alone): a slider alone eases toward it, and the presets in
        # use widen it as far as they ask (limited()); ease_limits let every preset at once pass as authored.
        self.clean_limits = limits
        self._clean_ease_start = self.ease_start.copy()
        self.ease_limits, self.ease_start = keeping(limits, presets, self.ease_start)
        assert self.matrix.shape == (3 * n, N_FAPS)

    # ------------------------------------------------------------ building
    def _template_fat(self) -> tuple[scipy.sparse.csr_matrix, dict[int, np.ndarray]]:
        d = self.dense
        N = len(d.vertices)
        edges = np.concatenate([d.triangles[:, [0, 1]], d.triangles[:, [1, 2]], d.triangles[:, [2, 0]]])
        length = np.linalg.norm(d.vertices[edges[:, 0]] - d.vertices[edges[:, 1]], axis=1)
        # Distances are measured along the surface in units of the median edge length: the thesis's
        # hop count, without the hexagonal/triangular iso-lines hops draw on a subdivided mesh.
        hop = float(np.median(length))
        adj = scipy.sparse.coo_matrix((length / hop, (edges[:, 0], edges[:, 1])), shape=(N, N)).tocsr()
        adj = adj.maximum(adj.T).tocsr()
        ignored = self._eye_opening_interior()
        weights: dict[int, np.ndarray] = {}
        tilt: dict[int, float] = {}
        for entry in self.template.regions:
            fap = entry["fap"]
            region = d.in_base_triangles(entry["triangles"])
            if entry.get("core_is_chain"):
                core = d.on_chain(entry["core"]) & region
            else:
                core = np.zeros(N, bool)
                core[[self.template.index(c) for c in entry["core"]]] = True
            ids = np.nonzero(region)[0]
            sub = adj[ids][:, ids]
            sources = np.nonzero(core[ids])[0]
            dist, _pred, nearest = dijkstra(sub, indices=sources, min_only=True, return_predecessors=True)
            reach = np.isfinite(dist)
            dmax = max(float(dist[reach].max()), 1.0)
            w = np.where(reach, np.exp(-np.where(reach, dist, 0) ** 2 / (2 * dmax * entry["w"])), 0.0)
            pinned = d.on_chain(entry["pinned"])[ids] if entry.get("pinned") else None
            w *= self._border_taper(adj, region, ignored, ids, sub, dist, core[ids], pinned)
            if entry.get("profile") == "opening":
                w *= self._opening_profile(ids, nearest, entry)
            elif entry.get("profile") == "jaw":
                w *= self._jaw_profile(ids, entry["corner_weight"])
            # The core alone held at 1 while the rest relaxes becomes a cone around a point core (the
            # weight fell 28 % in the 2 mm beside a mouth corner, and the skin there folded under a
            # smile): the Gaussian's round top (weight >= ROUND_TOP) is held with it.
            top = (w >= ROUND_TOP) if _round_top(entry) else False
            relaxed = _relax(w, sub, core[ids] | top | (w == 0), SMOOTHING_STEPS)
            w = _rounded_tip(relaxed, w > 0, sub, dist, nearest) if entry.get("round_tip") else relaxed
            w *= entry.get("scale", 1.0)
            weight = weights.setdefault(fap, np.zeros(N))
            weight[ids] = np.maximum(weight[ids], w)
            tilt[fap] = max(tilt.get(fap, 0.0), entry.get("forward_tilt", 0.0))
        rows, cols, vals = [], [], []
        for fap, weight in weights.items():
            direction = np.array(self.specs[fap - 1].axis, float)
            direction[2] += tilt[fap]
            nz = np.nonzero(weight)[0]
            for k in range(3):
                if direction[k]:
                    rows.append(3 * nz + k)
                    cols.append(np.full(len(nz), fap - 1))
                    vals.append(weight[nz] * direction[k])
        F = scipy.sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                    shape=(3 * N, N_FAPS)).tocsr()
        return F, weights

    def _paired_lip_overlaps(self) -> scipy.sparse.csr_matrix:
        """(3n, len(PAIRED_LIP_FAPS)) the part of each inner/outer lip FAP pair's FAT columns they share:
        per row, where both move it the same way, the smaller of the two (see PAIRED_LIP_FAPS)."""
        columns = self.matrix.tocsc()
        out = []
        for inner, outer in PAIRED_LIP_FAPS:
            a = columns[:, inner - 1].toarray().ravel()
            b = columns[:, outer - 1].toarray().ravel()
            out.append(scipy.sparse.csr_matrix(np.where(a * b > 0, np.sign(a) * np.minimum(np.abs(a), np.abs(b)),
                                                        0.0)[:, None]))
        return scipy.sparse.hstack(out).tocsr()

    def _eye_opening_interior(self) -> np.ndarray:
        """(N,) bool: dense vertices strictly inside the triangles covering the eye openings."""
        d, t = self.dense, self.template
        covered = sorted(t.eye_opening_triangles)
        others = [i for i in range(len(t.triangles)) if i not in t.eye_opening_triangles]
        return d.in_base_triangles(covered) & ~d.in_base_triangles(others)

    @staticmethod
    def _border_taper(adj, region, ignored, ids, sub, dist_core, core_local, pinned=None) -> np.ndarray:
        """Per region vertex: 0 on the region's inner border rising smoothly to 1 half-way to the core.

        The thesis's Gaussian keeps a nonzero weight where a region ends, so neighbouring regions
        meet in a crease. Region vertices with a neighbour outside the region (eye-opening covers and
        the template's own openings and outline do not count) form the border, plus ``pinned``
        vertices (e.g. a lid margin under a brow region).
        """
        outside = ~region & ~ignored
        touches = np.asarray(adj[ids][:, np.nonzero(outside)[0]].sum(axis=1)).ravel() > 0
        if pinned is not None:
            touches |= pinned
        border = np.nonzero(touches & ~core_local)[0]
        if not len(border):
            return np.ones(len(ids))
        dist_border = dijkstra(sub, indices=border, min_only=True)
        ratio = np.clip(2 * dist_border / np.maximum(dist_core + dist_border, 1e-9), 0.0, 1.0)
        ratio = np.where(np.isfinite(ratio), ratio, 1.0)
        taper = ratio * ratio * ratio * (ratio * (6 * ratio - 15) + 10)  # smootherstep: C2 at both ends
        return np.where(core_local, 1.0, taper)

    def _jaw_profile(self, ids, corner_weight: float) -> np.ndarray:
        """Per region vertex: how much of the jaw's motion it follows near the mouth corners.

        The corners follow ``corner_weight`` of it, the lower lip grades to the full motion at the
        midline (a cosine in the horizontal distance from the midline), and the effect fades out
        below the corners over the corner-to-chin height, where the mandible moves as a whole.
        """
        v = self.dense.vertices
        left, right = (v[self.template.index(n)] for n in ("2.4", "2.5"))
        chin = v[self.template.index("2.1")]
        mid_x, half_width = (left[0] + right[0]) / 2, abs(left[0] - right[0]) / 2
        corner_y = (left[1] + right[1]) / 2
        u = np.clip(np.abs(v[ids, 0] - mid_x) / half_width, 0.0, 1.0)
        lateral = 0.5 * (1 - np.cos(np.pi * u))
        below = np.clip((corner_y - v[ids, 1]) / max(corner_y - chin[1], 1e-6), 0.0, 1.0)
        vertical = 1 - below * below * (3 - 2 * below)
        return 1 - (1 - corner_weight) * lateral * vertical

    def _opening_profile(self, ids, nearest, entry) -> np.ndarray:
        """Per region vertex: the eye opening's height at its nearest margin vertex / the height at the FP."""
        d = self.dense
        chain = d.on_chain(entry["core"])
        opposite = d.on_chain(entry["opposite"])
        v = d.vertices
        ox, oy = v[opposite, 0], v[opposite, 1]
        order = np.argsort(ox)
        height = np.abs(v[:, 1] - np.interp(v[:, 0], ox[order], oy[order]))
        fp_height = height[self.template.index(self.specs[entry["fap"] - 1].fp)]
        profile = np.clip(height / max(fp_height, 1e-6), 0.0, 1.0)
        left, right = v[chain, 0].min(), v[chain, 0].max()
        if fp_height < CLOSED_EYE_GAP * (right - left):
            # A closed eye (a scan taken with the eyes shut): its opening is a slit of noise, so the lid
            # opens with an open eye's shape instead, an ellipse from corner to corner.
            across = (v[:, 0] - (left + right) / 2) / max((right - left) / 2, 1e-6)
            profile = np.sqrt(np.clip(1.0 - across * across, 0.0, 1.0))
        source = np.where(nearest >= 0, ids[np.maximum(nearest, 0)], ids)
        return np.where(chain[source], profile[source], 0.0)

    def _bind(self) -> scipy.sparse.csr_matrix:
        """(n, N) barycentric weights of each face skin vertex on the dense template."""
        face, d, t = self.face, self.dense, self.template
        n, N = face.n_vertices, len(d.vertices)
        in_part = np.zeros(n, bool)
        for idx in face.parts.values():
            in_part[idx] = True
        skin = np.nonzero(~in_part)[0]
        side = mouth_side(face, skin)
        # A closed eye (a scan taken with the eyes shut) cut along its lid line binds each side of the
        # cut to that lid only, as the lips: labels +2 upper lid, -2 lower lid. (An animated scan
        # brings its own binding, see __init__; this is for one rebuilt without it.)
        side = np.where(side == 0, 2 * closed_eye_side(face, skin, cut_only=True), side)
        base_tri_of = self._dense_triangle_base_points()

        def touching(names) -> np.ndarray:
            ids = {t.index(p) for p in names}
            return np.array([bool(ids & s) for s in base_tri_of])

        tri_upper, tri_lower = touching(t.upper_lip_points), touching(t.lower_lip_points)
        # Eye margins run corner, upper lid (3 points), corner, lower lid (3 points).
        tri_upper_lid = touching([p for margin in t.eye_margins.values() for p in margin[1:4]])
        tri_lower_lid = touching([p for margin in t.eye_margins.values() for p in margin[5:8]])
        # Skin never binds to the covers of the eye openings: they do not move with the lids, and a
        # lid-margin vertex bound half to them would close only part of the way (a torn margin).
        skin_tris = ~self._eye_opening_interior()[d.triangles].any(axis=1)
        # Skin beyond the template's outline follows it with a fade; the distance for that fade is
        # to the whole template (a rim vertex in an eye opening is inside it, not beyond it).
        whole = TriangleSet(d.vertices, d.triangles).closest(face.vertices[skin], k=24, widen=False)[0]
        outside_mm = np.zeros(n)
        outside_mm[skin] = np.linalg.norm(whole - face.vertices[skin], axis=1)
        rows, cols, vals = [], [], []
        for label, allowed in ((0, skin_tris), (1, skin_tris & ~tri_lower), (-1, skin_tris & ~tri_upper),
                               (2, skin_tris & ~tri_lower_lid), (-2, skin_tris & ~tri_upper_lid)):
            sel = skin[side == label]
            if not len(sel):
                continue
            tri_ids = np.nonzero(allowed)[0]
            ts = TriangleSet(d.vertices, d.triangles[tri_ids])
            _pos, tri, bary = ts.closest(face.vertices[sel], k=24, widen=False)
            fade = np.exp(-(np.maximum(outside_mm[sel] - 1.0, 0.0) / OUTSIDE_FADE_MM) ** 2)
            corners = d.triangles[tri_ids[tri]]
            rows.append(np.repeat(sel, 3))
            cols.append(corners.ravel())
            vals.append((bary * fade[:, None]).ravel())
        closest = scipy.sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                          shape=(n, N)).tocsr()
        return smooth_binding(face, closest, skin, side, BINDING_SMOOTHING_STEPS, d.vertices, BINDING_JUMP,
                              BINDING_JUMP_RINGS)

    def _dense_triangle_base_points(self) -> list[set[int]]:
        """For each dense triangle, the base points of the base triangle it lies in."""
        support = self.dense.base_coords > 1e-12
        tri_support = support[self.dense.triangles].any(axis=1)  # (M, 80)
        return [set(np.nonzero(row)[0]) for row in tri_support]

    def _lower_teeth_rows(self) -> scipy.sparse.csr_matrix:
        """The lower teeth follow the jaw FAPs (3 open_jaw, 14 thrust_jaw, 15 shift_jaw) rigidly."""
        n = self.face.n_vertices
        idx = self.face.parts.get("teeth_lower", np.zeros(0, np.int64))
        rows, cols, vals = [], [], []
        for fap in (3, 14, 15):
            axis = np.array(self.specs[fap - 1].axis)
            for k in range(3):
                if axis[k]:
                    rows.append(3 * idx + k)
                    cols.append(np.full(len(idx), fap - 1))
                    vals.append(np.full(len(idx), axis[k]))
        if not rows:
            return scipy.sparse.csr_matrix((3 * n, N_FAPS))
        return scipy.sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                       shape=(3 * n, N_FAPS)).tocsr()

    def _cavity_rows(self, F: scipy.sparse.csr_matrix) -> scipy.sparse.csr_matrix:
        """(3n, 68) rows of the mouth cavity's vertices: each follows its closest skin point's rows of
        ``F`` (see :meth:`cavity_follow`); zero for a face without a cavity."""
        W3 = scipy.sparse.kron(self.cavity_follow(), scipy.sparse.identity(3, format="csr"), format="csr")
        return (W3 @ F).tocsr()

    def cavity_follow(self) -> scipy.sparse.csr_matrix:
        """(n, n) how the mouth cavity's lining follows the skin: row i of a lining vertex holds the
        barycentric weights of its closest skin point, scaled from 1 within ``CAVITY_FOLLOW_NEAR_MM``
        of the skin to 0 at ``CAVITY_FOLLOW_FAR_MM`` (smoothstep); other rows are empty. Any layer's
        skin offset d (n, 3) moves the lining by ``cavity_follow() @ d`` (the FAT's own rows and an
        expression library's correspondence use it)."""
        face = self.face
        n = face.n_vertices
        idx = np.asarray(face.parts.get("mouth_cavity", np.zeros(0, np.int64)), dtype=np.int64)
        in_part = self._in_any_part()
        skin_tris = face.triangles[~in_part[face.triangles].any(axis=1)]
        if not len(idx) or not len(skin_tris):
            return scipy.sparse.csr_matrix((n, n))
        pos, tri, bary = TriangleSet(face.vertices, skin_tris).closest(face.vertices[idx], k=24)
        gap = np.linalg.norm(pos - face.vertices[idx], axis=1)
        t = np.clip((CAVITY_FOLLOW_FAR_MM - gap) / (CAVITY_FOLLOW_FAR_MM - CAVITY_FOLLOW_NEAR_MM), 0.0, 1.0)
        follow = t * t * (3 - 2 * t)
        return scipy.sparse.coo_matrix(((bary * follow[:, None]).ravel(), (np.repeat(idx, 3), skin_tris[tri].ravel())),
                                       shape=(n, n)).tocsr()

    def _eyeball_pivots(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """part name -> (vertex indices, centre (3,)) for eyeballs, centre by a least-squares sphere fit
        (the lid guards' centre and the eye's yaw pivot)."""
        out = {}
        for name in ("eyeball_l", "eyeball_r"):
            idx = self.face.parts.get(name)
            if idx is None or len(idx) < 10:
                continue
            p = self.face.vertices[idx]
            A = np.column_stack([2 * p, np.ones(len(p))])
            sol, *_ = np.linalg.lstsq(A, (p ** 2).sum(axis=1), rcond=None)
            out[name] = (idx, sol[:3])
        return out

    def _eyeball_pitch_centres(self) -> dict[str, np.ndarray]:
        """part name -> the eyeball's pitch pivot (3,): the centre of a least-squares axis-aligned
        ellipsoid through its vertices (the sphere's centre for a spherical ball).

        An eyeball wider than it is high (the default face's fills the palpebral opening: 15.6 x 12 x
        12 mm) is its own image under a pitch about the ellipsoid's centre; about the sphere fit's
        centre, 2.6 mm further back, looking up 30 degrees swung its wide outer side 3 mm up into the
        socket skin (61 crossing pairs per eye). Its yaw stays about the sphere fit's centre: about
        the ellipsoid's, the long axis swings its ends forward through the corners (85-92 pairs at
        35 degrees, none about the sphere's)."""
        out = {}
        for name, (idx, sphere_centre) in self._eyes.items():
            p = self.face.vertices[idx]
            mid = p.mean(axis=0)
            q = p - mid     # centred: the quadric's terms are of one scale
            coef, *_ = np.linalg.lstsq(np.column_stack([q ** 2, q]), np.ones(len(q)), rcond=None)
            # A cap too flat to fix three axes keeps the sphere's centre.
            out[name] = mid - coef[3:] / (2 * coef[:3]) if (coef[:3] > 0).all() else sphere_centre
        return out

    def _lid_guards_over_eyeballs(self) -> list[LidGuard]:
        """Guards that keep each eye's lids outside its eyeball.

        The FAT moves a lid in a straight line, but the eyeball bulges forward, and its cornea
        more: a closing lid would pass behind the cornea (the eye then shows through the closed
        lid). Lid vertices are kept at least ``LID_CLEARANCE_MM`` outside the eyeball's own surface
        in their direction from the centre (its radius map over both angles about the gaze axis,
        which covers the cornea: ``eyeball_surface``), or by their rest clearance when that is
        smaller (at least ``MIN_LID_CLEARANCE_MM``, more than a lid triangle's sag over the ball), so
        the neutral face is unchanged. Skin closer than that at rest starts from its own gap and
        reaches the clearance over the first ``GUARD_RAMP`` units of the eye's closing FAPs (no jump
        when one leaves 0; lids opening in surprise or fear leave the socket skin where it is), or as
        it slides over the ball: in full once it moved ``GUARD_SLIDE_MM`` (joy's cheek lift at the
        outer corners).
        """
        guards = []
        # The cheek lift (41/42) pushes the lower lid up over the ball as well (joy's AU 6), and the
        # lowered or squeezed brows (31-38) push the upper lid's skin down onto it (AU 4).
        for name, faps, brows in (("eyeball_l", (19, 21, 41), BROW_FAPS[0]), ("eyeball_r", (20, 22, 42), BROW_FAPS[1])):
            if name not in self._eyes:
                continue
            idx, centre = self._eyes[name]
            ball = self.face.vertices[idx]
            in_ball = np.zeros(self.face.n_vertices, bool)
            in_ball[idx] = True
            radii = radius_map(self.face.vertices, self.face.triangles[in_ball[self.face.triangles].all(axis=1)],
                               centre)
            def moved_by(numbers):
                weights = sum(self.binding @ self.template_weights[f] for f in numbers if f in self.template_weights)
                return np.asarray(weights) > 1e-6

            lids_move = moved_by(faps[:2])
            candidates = np.nonzero(lids_move | moved_by(faps[2:] + brows))[0]
            offsets = self.face.vertices[candidates] - centre
            # Beyond the map's skirt it reads 0 (no ball in that direction): a gap measured there is
            # the whole distance to the centre, and kept as clearance it pushed skin that drifted
            # back over the skirt far forward (a front-only face's temple, 2 mm lateral to the
            # ball's rim: lift_l_cheek 220 moved it 25.6 mm). There the gap is taken to the ball's
            # largest radius instead, which the skin cannot be pushed beyond.
            reference = map_radius(offsets, radii)
            reference = np.where(reference > 0.0, reference, float(radii.max()))
            rest_gap = np.sqrt((offsets ** 2).sum(axis=1)) - reference
            # The cheek lift's and brows' wide regions only where they can reach the ball (the guard
            # runs per tick): skin that one of those FAPs, anywhere along its slider's range, brings
            # within reach of the ball.
            closest = rest_gap.copy()
            for number in faps[2:] + brows:
                spec = self.specs[number - 1]
                column = self.matrix[:, number - 1].toarray().reshape(-1, 3)[candidates] * self.fapu_vector[number - 1]
                for value in np.linspace(spec.minimum, spec.maximum, GUARD_REACH_SAMPLES):
                    moved = offsets + column * value
                    closest = np.minimum(closest, np.sqrt((moved ** 2).sum(axis=1)) - map_radius(moved, radii))
            near = lids_move[candidates] | (closest < CHEEK_GUARD_REACH_MM)
            lid, rest_gap = candidates[near], rest_gap[near]
            # Skin farther out at rest stays farther out: two rows the FAT moves over one another
            # are not pressed into one shell, where they cross. Skin closer than the clearance at
            # rest (behind the rim of a ball that is a front cap) starts from its own gap: held at
            # the clearance at once it jumped forward at the first tick of a lid FAP.
            clearance = (np.clip(rest_gap, MIN_LID_CLEARANCE_MM, LID_CLEARANCE_MM)
                         + REST_GAP_KEPT * np.maximum(rest_gap - LID_CLEARANCE_MM, 0.0))
            # Skin triangles that straddle an open rim (a vertex tucked behind it, under the least
            # clearance) have the rim's sharp edge just under them: all their vertices start from
            # their own rest gaps (a scanned pose moving the default face's outer eye corner 0.2 mm
            # put the rim through them: blend sadness 2 crossing pairs, disgust 21 -> 19).
            behind = np.zeros(self.face.n_vertices, bool)
            behind[lid[rest_gap < MIN_LID_CLEARANCE_MM]] = True
            straddling = np.zeros(self.face.n_vertices, bool)
            straddling[self.face.triangles[behind[self.face.triangles].any(axis=1)]] = True
            rest_clearance = np.where(straddling[lid], rest_gap, np.minimum(rest_gap, clearance))
            guards.append(LidGuard(lid, centre, rest_clearance, clearance, radii, float(radii.max()), faps,
                                   self.face.vertices[lid], float(np.median(_radius_profile(ball - centre)))))
        return guards

    def _find_canthus_triangles(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Per eye (as ``_eye_rims``): (upper rim vertex, eye corner, skin vertex across the corner
        (k,) int, and how far the corner must stay below the line from the rim vertex to the skin
        vertex (k,) mm: CANTHUS_KEPT of its rest depth), one row per skin triangle of those three.

        Where the lower rim rises steeply into a corner (the default face's outer canthus: 0.44 mm in
        its last 0.42 mm), an upper rim vertex beside the corner that closes onto it passes below the
        corner, and the thin triangle spanning the corner turned over (close_t_eyelid 1024: one fold
        per eye). Held at the line instead, the rim vertex left that triangle and the next ones
        squeezed to 0.14 and stretched 2.3x; a real canthus moves with the closing lid."""
        face, out = self.face, []
        rest = face.vertices
        for upper, lower in self._eye_rims:
            rims = np.zeros(face.n_vertices, bool)
            rims[upper] = rims[lower] = True
            on_upper = np.zeros(face.n_vertices, bool)
            on_upper[upper] = True
            rows = []
            for corner in lower[[0, -1]]:                  # ordered by x: the two corners
                for tri in face.triangles[(face.triangles == corner).any(axis=1)]:
                    others = [v for v in tri if v != corner]
                    rim = [v for v in others if on_upper[v]]
                    beside = [v for v in others if not rims[v]]
                    if len(rim) != 1 or len(beside) != 1:
                        continue
                    c, b = rim[0], beside[0]
                    run = rest[b, 0] - rest[c, 0]
                    if (rest[corner, 0] - rest[c, 0]) * (rest[corner, 0] - rest[b, 0]) >= 0:
                        continue                           # the corner must lie between them in x
                    line = rest[c, 1] + (rest[b, 1] - rest[c, 1]) * (rest[corner, 0] - rest[c, 0]) / run
                    depth = line - rest[corner, 1]
                    if depth > 0:
                        rows.append((c, corner, b, CANTHUS_KEPT * depth))
            rows = np.array(rows, float).reshape(-1, 4)
            out.append((rows[:, 0].astype(np.int64), rows[:, 1].astype(np.int64), rows[:, 2].astype(np.int64),
                        rows[:, 3]))
        return out

    def _in_any_part(self) -> np.ndarray:
        """(n,) bool: vertices of a named part (eyeballs, teeth, mouth cavity), not skin."""
        mask = np.zeros(self.face.n_vertices, bool)
        for idx in self.face.parts.values():
            mask[idx] = True
        return mask

    def _step_memos(self) -> dict[str, StepMemo]:
        """A :class:`StepMemo` per finish step, with the vertices it reads and writes: the lids (rims
        and guards), the lip contact and the teeth guard."""
        empty = np.zeros(0, np.int64)
        lid_writes = np.concatenate([upper for upper, _lower in self._eye_rims]
                                    + [guard.lid for guard in self._lid_guards] + [empty]
                                    + [corner for _rim, corner, _beside, _depth in self._canthus_triangles])
        # The lid guards also read the eyeballs (a layer that carries a ball along carries its guard).
        balls = [self._ball_anchors(name) for name in self._eyes] if self._lid_guards else []
        lid_reads = np.concatenate([lower for _upper, lower in self._eye_rims] + balls + [lid_writes]
                                   + [beside for _rim, _corner, beside, _depth in self._canthus_triangles])
        lips = self._lip_contact
        lip_writes = np.concatenate([lips.upper, lips.lower]) if lips.active else empty
        lip_reads = np.concatenate([lips.upper_rim, lips.lower_rim, lip_writes]) if lips.active else empty
        teeth = self._teeth_guard
        teeth_reads = np.concatenate([teeth.watched] + [row.anchors for row in teeth.rows])
        # A step with nothing to read does nothing (a face without eyeballs or teeth): no memo to check.
        return {name: StepMemo(reads, writes) for name, reads, writes in (
            ("lids", lid_reads, lid_writes), ("lips", lip_reads, lip_writes), ("teeth", teeth_reads, teeth.watched))
            if len(reads)}

    def _ball_anchors(self, name: str) -> np.ndarray:
        """A few vertices spread over eyeball ``name`` (every k-th of about ``BALL_ANCHORS``): their mean
        motion is the ball's shift for the lid guard (exact for a translation; a turn about the ball's
        centre moves them little), at a tick's cost of a handful of rows rather than the whole ball."""
        idx = np.asarray(self._eyes[name][0], dtype=np.int64)
        return idx[::max(1, len(idx) // BALL_ANCHORS)]

    def _eye_rims_of_skin(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per eye: (upper rim, lower rim) vertex indices of the skin's eye opening, ordered by x.

        The lid columns are fitted to these rims (:func:`fit_lids_to_rims`), and ``_close_lids``
        still lifts any upper-rim vertex that ends below the lower rim (a lid moved by other FAPs
        too, a pose from another layer).
        """
        face = self.face
        from core.subdivision import boundary_edges

        rim = np.unique(boundary_edges(face.triangles).ravel())
        in_part = np.zeros(face.n_vertices, bool)
        for idx in face.parts.values():
            in_part[idx] = True
        rim = rim[~in_part[rim]]
        out = []
        for outer, inner in (("3.7", "3.11"), ("3.12", "3.8")):
            if not {outer, inner} <= set(face.landmark_names):
                continue
            a, b = face.landmark_position(outer), face.landmark_position(inner)
            lo, hi = sorted((a[0], b[0]))
            p = face.vertices[rim]
            line_y = np.interp(p[:, 0], [lo, hi], [a[1], b[1]] if a[0] < b[0] else [b[1], a[1]])
            near = (p[:, 0] > lo - 1.0) & (p[:, 0] < hi + 1.0) & (np.abs(p[:, 1] - line_y) < 12.0)
            upper, lower = rim[near & (p[:, 1] > line_y)], rim[near & (p[:, 1] <= line_y)]
            if len(upper) and len(lower):
                out.append((upper, lower[np.argsort(face.vertices[lower, 0])]))
        return out

    def _estimate_head_pivot(self) -> np.ndarray:
        """Top of the spine (FP 7.1) if marked, else 45 mm behind the ear contacts, level with the lower ones."""
        face = self.face
        if "7.1" in face.landmark_names:
            return face.landmark_position("7.1")
        ears = [face.landmark_position(p) for p in ("10.7", "10.8", "10.9", "10.10") if p in face.landmark_names]
        if ears:
            e = np.mean(ears, axis=0)
            return np.array([0.0, e[1] - 10.0, e[2] - 45.0])
        lo, hi = face.bounds
        return np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2 - 30.0, lo[2] - 40.0])

    # ------------------------------------------------------------ caching
    def __getstate__(self) -> dict:
        # The face is the cache key, not part of the entry: it is given back on load.
        state = dict(self.__dict__)
        del state["face"], state["_rest"]
        state.pop("_fat_columns", None)   # derived from the matrix on first use
        state.pop("_last_lid_values", None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.face = None
        self._rest = None

    @classmethod
    def for_face(cls, face: Face, cache: DiskCache | None = None,
                 progress: Callable[[float, str], None] | None = None,
                 dense: DenseTemplate | None = None, binding: scipy.sparse.csr_matrix | None = None) -> "FapDeformer":
        """The deformer of ``face``, read from ``cache`` when built before (else built and stored;
        ``progress(fraction, message)`` hears how the build goes).

        Keyed by the face's vertices, triangles, feature points and parts, the template file and
        the source of the modules that build the table: any change there builds afresh. A deformer
        built on a given ``dense`` template (a registered scan) is stored under the face's key too,
        so the rig built later for that face (the window's, a project's) finds it.
        """
        if cache is None:
            return cls(face, progress=progress, dense=dense, binding=binding)
        key = deformer_key(face)
        found = cache.get("fap", key)
        if isinstance(found, cls) and (dense is None or np.array_equal(found.dense.vertices, dense.vertices)) \
                and (binding is None or _same_sparse(found.binding, binding)):
            found.face = face
            found._rest = face.vertices.ravel()
            return found
        deformer = cls(face, progress=progress, dense=dense, binding=binding)
        cache.put("fap", key, deformer)
        return deformer

    # ------------------------------------------------------------ queries
    def why_not_animated(self, number: int) -> str:
        if number in (23, 24, 25, 26):
            return "the face has no separate eyeballs (parts eyeball_l / eyeball_r)"
        return "Mimica animates the 46 low-level FAPs of thesis A, gaze (23-26) and head rotation (48-50)"

    def influence(self, number: int) -> np.ndarray:
        """(n,) in [0, 1]: the FAP's weight at each face vertex (1 for moved rigid parts)."""
        if number in self.template_weights:
            w = self.binding @ self.template_weights[number]
        else:
            w = np.zeros(self.face.n_vertices)
        if number in (23, 25) and self._gaze:
            w[self._eyes["eyeball_l"][0]] = 1.0
        if number in (24, 26) and self._gaze:
            w[self._eyes["eyeball_r"][0]] = 1.0
        if number in (48, 49, 50):
            w[:] = 1.0
        if number in (3, 14, 15) and "teeth_lower" in self.face.parts:
            w[self.face.parts["teeth_lower"]] = 1.0
        return w

    def lip_contact_zone(self) -> np.ndarray:
        """(n,) bool: vertices lip contact may move after all offsets (there the layers' offsets do
        not simply add up: lips pressed into each other give way)."""
        return self._lip_contact.zone(self.face.n_vertices)

    def _seam_moving_as_one(self, skin_triangles: np.ndarray) -> np.ndarray:
        """(k, 2) (copy, original) skin vertex pairs at one rest position whose FAT rows are equal (the
        face/head-shell seam: 940 of the default face's 1,013 skin pairs; not the closed mouth's two
        lips, which part), for the surface guard."""
        welded = welded_vertices(self.face.vertices)
        copy = np.flatnonzero(welded != np.arange(len(welded)))
        original = welded[copy]
        on_skin = np.zeros(len(welded), bool)
        on_skin[skin_triangles.ravel()] = True
        copy, original = copy[on_skin[copy] & on_skin[original]], original[on_skin[copy] & on_skin[original]]
        F = self.matrix.tocsr()
        apart = np.zeros(len(copy), bool)
        for axis in range(3):
            difference = (F[3 * copy + axis] - F[3 * original + axis]).tocsr()
            difference.eliminate_zeros()
            apart |= np.diff(difference.indptr) > 0
        return np.stack([copy[~apart], original[~apart]], axis=1)

    def lid_zone(self) -> np.ndarray:
        """(n,) bool: vertices the lid steps may move after all offsets, whatever layer moved the lids
        (upper rims stopping on the lower ones, lid skin pushed out over the eyeballs)."""
        mask = np.zeros(self.face.n_vertices, bool)
        for upper, _lower in self._eye_rims:
            mask[upper] = True
        for guard in self._lid_guards:
            mask[guard.lid] = True
        return mask

    def finish_zone(self) -> np.ndarray:
        """(n,) bool: vertices where the layers' offsets may not simply add up (:meth:`lid_zone` and
        :meth:`lip_contact_zone`)."""
        return self.lid_zone() | self.lip_contact_zone()

    @property
    def closed_lid_faps(self) -> frozenset[int]:
        """The lid FAPs (19-22) of the eyes closed at rest on this face (a scan taken with them shut)."""
        return frozenset(n for pair in self.__dict__.get("_closed_lid_pairs", ()) for n in pair)

    def limited(self, values: np.ndarray, presets: np.ndarray | None = None) -> np.ndarray:
        """(68,) FAP values eased into this face's clean limits (``limits.soft_limit``): unchanged
        well inside them, never past them. ``presets`` (68,): the share of ``values`` the expression
        and viseme presets in use contribute; the limits widen to let those pass as authored
        (``limits.keeping``; never wider than ``ease_limits``, which every preset at 100 % passes).
        Without it, ``ease_limits``.

        Widened for every preset at once, a slider alone went past where its own surface breaks: the
        default face's cheek lift, whose finished pose squeezes the skin under the eye past 0.25x from
        about 210 IRISD, eased toward joy's 220 (0.24x there)."""
        if presets is None:
            return soft_limit(values, self.ease_limits, self.ease_start)
        asked = np.clip(presets, self.preset_reach[:, 0], self.preset_reach[:, 1])
        limits, start = keeping(self.clean_limits, asked[None], self._clean_ease_start)
        return soft_limit(values, limits, start)

    def _lid_crease_limit(self, probe, number: int, side: str) -> float:
        """The opening value (FAP units, negative) of upper-lid FAP ``number`` down to which the
        lid's skin crosses neither itself nor the eyeball on the ``side`` eye (``core.mesh_quality``
        regions of ``probe``, a FaceQualityProbe of the face), by bisection on the finished pose;
        -inf when the slider's end holds."""
        from core.mesh_quality import count_intersections

        lid_tris, ball_tris = probe.lid_tris[side], probe.eyeball_tris[side]
        end = self.specs[number - 1].minimum
        if lid_tris is None or not np.isfinite(end):
            return -np.inf

        rest = self.face.vertices

        def crosses(value: float) -> bool:
            """Does a lid triangle the pose moved cross the lid or the eyeball? (Pairs the pose left
            alone cross as they did at rest: not this FAP's doing, and ~8x the pairs to test.)"""
            values = np.zeros(N_FAPS)
            values[number - 1] = value
            x = self.deform(values)
            moved = lid_tris[(x != rest).any(axis=1)[lid_tris].any(axis=1)]
            return bool(count_intersections(x, moved, lid_tris, probe.welded)
                        or (ball_tris is not None and count_intersections(x, moved, ball_tris, probe.welded)))

        if not crosses(end):
            return -np.inf
        good, _bad = bisect(lambda share: crosses(end * share), CREASE_BISECTION_STEPS)
        return end * good

    def limit_note(self, number: int) -> str | None:
        """"beyond 240 the skin would fold: eased" for each slider end of FAP ``number`` that is
        limited on this face, with its reason (fold or texture smear; joined by "; "), and where a
        preset goes further ("beyond 174 the skin would fold: eased; the presets go to 600 as
        authored"); None when no end is limited."""
        ends: dict[str, list[str]] = {}
        for value, why, reach in zip(self.clean_limits[number - 1], self.limit_reasons[number - 1],
                                     self.preset_reach[number - 1]):
            if np.isfinite(value):
                past = f"; the presets go to {reach:.0f} as authored" if abs(reach) > abs(value) else ""
                ends.setdefault((why or FOLD_REASON, past), []).append(f"{value:.0f}")
        notes = [f"beyond {' and '.join(values)} {why}: eased{past}" for (why, past), values in ends.items()]
        if number in LOWER_LIDS and number not in self.closed_lid_faps:
            notes.append(HANDOVER_NOTE)
        return "; ".join(notes) or None

    def displacement(self, values: np.ndarray) -> np.ndarray:
        """(n, 3) mm: the FAT's offsets for (68,) effective FAP values (FAP units), lids in contact."""
        scaled = self.lid_values(values) * self.fapu_vector
        out = self.matrix @ scaled
        common = _paired_common(scaled)
        if common is not None:
            out -= self.pair_overlaps @ common
        return out.reshape(-1, 3)

    def lid_values(self, values: np.ndarray) -> np.ndarray:
        """(68,) FAP values with the lids following the eyes' vertical gaze, then in contact
        (:func:`lid_contact`). As in a real face, a lid rides on the cornea: an eye turned down by
        an angle t lowers its upper lid margin by ``UPPER_LID_FOLLOW`` x the cornea's drop (R sin t,
        R the eyeball's radius) and its lower lid by ``LOWER_LID_FOLLOW`` x it (``LIDS_FOLLOW_UP``
        when it turns up); the FAP units come from the FAT's own offset of each lid margin. Without
        it the cornea passed through the lids (324 crossings at 30 degrees down). A raised cheek then
        carries its lower lid up (:func:`carried_lower_lids`), and a lower lid closed past its reach
        hands the rest to its upper lid (:func:`lower_lid_handover`)."""
        last = self.__dict__.get("_last_lid_values")
        if last is not None and last[0] is values:
            return last[1]      # the FAP layer passes one array to the product and to finish
        out = np.array(values, dtype=float)
        # Both eyes' lid margins are needed to know which rim belongs to which eye (a face whose eye
        # corners are not marked has none): without them the lids stay put.
        if self._gaze and len(self._eye_rims) == 2 and out[24:26].any():
            for name, pitch, upper, lower in (("eyeball_l", 25, 19, 21), ("eyeball_r", 26, 20, 22)):
                if not out[pitch - 1]:
                    continue
                radius, up_gain, low_gain = self._gaze_lid_constants(name, upper, lower)
                drop = radius * math.sin(out[pitch - 1] * tables.ANGLE_UNIT)   # mm the cornea moved, + down
                if drop:
                    up_follow, low_follow = (UPPER_LID_FOLLOW, LOWER_LID_FOLLOW) if drop > 0 else LIDS_FOLLOW_UP
                    out[upper - 1] += up_follow * drop / up_gain
                    out[lower - 1] -= low_follow * drop / low_gain
        out = lid_contact(lower_lid_handover(carried_lower_lids(out)), self.__dict__.get("_closed_lid_pairs", ()))
        if isinstance(values, np.ndarray) and not values.flags.writeable:
            self._last_lid_values = (values, out)   # one tuple: safe for two threads sharing a deformer
        return out

    def _gaze_lid_constants(self, name: str, upper: int, lower: int) -> tuple[float, float, float]:
        """(the eyeball's radius mm (:attr:`LidGuard.gaze_radius`), mm down per unit of FAP
        ``upper``, mm up per unit of FAP ``lower`` at their lid margins (the FAT's mean vertical offset
        of the eye's rim vertices)); computed once."""
        constants = self.__dict__.setdefault("_gaze_lids", {})
        if name not in constants:
            radius = next((g.gaze_radius for g in self._lid_guards if (19 in g.faps) == (name == "eyeball_l")), 0.0)
            rims = self._eye_rims[0 if name == "eyeball_l" else 1]
            gains = []
            for number, rim, sign in ((upper, rims[0], -1.0), (lower, rims[1], 1.0)):
                column = self.matrix[:, number - 1].toarray().ravel()
                gains.append(max(sign * column[3 * rim + 1].mean() * self.fapu_vector[number - 1], 1e-6))
            constants[name] = (radius, *gains)
        return constants[name]

    def add_displacement(self, x: np.ndarray, values: np.ndarray) -> None:
        """``x`` (n, 3) float mm += :meth:`displacement` of (68,) values, in place: the rig's per-tick
        product (no (3n,) temporary; only the columns of non-zero FAPs are read). Equal to
        ``x + displacement(values)`` up to rounding (~1e-13 mm: the terms are added one by one)."""
        scaled = self.lid_values(values) * self.fapu_vector
        common = _paired_common(scaled)
        compiled = kernels.get()
        if compiled is not None and x.dtype == np.float64 and x.flags.c_contiguous:
            columns = self.__dict__.get("_fat_columns")
            if columns is None:     # built on first use, never pickled (see __getstate__)
                columns = self._fat_columns = (_column_arrays(self.matrix), _column_arrays(self.pair_overlaps))
            compiled.add_active_columns(x.reshape(-1), *columns[0], scaled)
            if common is not None:
                compiled.add_active_columns(x.reshape(-1), *columns[1], -common)
        else:
            x += (self.matrix @ scaled).reshape(-1, 3)
            if common is not None:
                x -= (self.pair_overlaps @ common).reshape(-1, 3)

    def _close_lids(self, x: np.ndarray, values: np.ndarray) -> None:
        """Upper lids stop on the lower ones, and lids (and the cheek lift's skin) slide over the
        eyeballs, in ``x`` (n, 3) in place, for (68,) values after :func:`lid_contact`.

        Both steps also run when another layer moved the lids' skin with no FAP value set (an
        expression library's pose: its scanned lids crossed each other and the eyeballs, default
        face's disgust 1,104 crossing pairs, because these steps waited for a lid FAP)."""
        face_rest = self._rest.reshape(-1, 3) if self._rest is not None else None
        if values[18:22].any() or _moved(x, face_rest, *(rows for rims in self._eye_rims for rows in rims)):
            for (upper, lower), rest_gap, (rim, corner, beside, depth) in zip(self._eye_rims, self._rest_lid_gaps,
                                                                               self._canthus_triangles):
                y_lower = np.interp(x[upper, 0], x[lower, 0], x[lower, 1])
                x[upper, 1] = np.maximum(x[upper, 1], y_lower)
                # A canthus comes down with a lid closed onto it: the corner stays below the line from
                # the rim vertex beside it to the skin across it (see _find_canthus_triangles).
                if len(rim):
                    run = x[beside, 0] - x[rim, 0]
                    line = x[rim, 1] + (x[beside, 1] - x[rim, 1]) * (x[corner, 0] - x[rim, 0]) / run
                    np.minimum.at(x[:, 1], corner, line - depth)
                # Closed lids: the upper margin rests just in front of the lower one (touching at one
                # depth, their rows crossed wherever the two rims' vertices interleave).
                # (Not near a corner at rest, where the rims are that close: by how much the gap closed.)
                gap = x[upper, 1] - y_lower
                contact = (np.clip(1.0 - gap / LID_CONTACT_MM, 0.0, 1.0)
                           * np.clip(1.0 - gap / np.maximum(rest_gap, 1e-9), 0.0, 1.0))
                if contact.any():
                    z_lower = np.interp(x[upper, 0], x[lower, 0], x[lower, 2])
                    x[upper, 2] += contact * np.clip(z_lower + LID_TUCK_MM - x[upper, 2], 0.0, LID_TUCK_MAX_MM)
        if (values[18:22].any() or values[40:42].any() or values[30:38].any()
                or any(not np.array_equal(x[guard.lid], guard.rest) for guard in self._lid_guards)):
            compiled = kernels.get()
            for lid, centre, rest_clearance, full_clearance, radii, max_radius, faps, rest, _ in self._lid_guards:
                # From the rest gap to the full clearance as the eye closes (opening lids leave it).
                ramp = min(max(max(values[f - 1] for f in faps), 0.0) / GUARD_RAMP, 1.0)
                # A layer that carried the eyeball along (a head moved as a whole) carries its guard:
                # only skin that moved relative to the ball slid over it. (The FAPs turn the eyeballs
                # after this step: for them the shift is zero.)
                ball = self._ball_anchors("eyeball_l" if 19 in faps else "eyeball_r")
                shift = (x[ball] - face_rest[ball]).mean(axis=0) if face_rest is not None else np.zeros(3)
                centre = centre + shift
                # Skin that slid over the ball (the cheek lift moves the socket skin millimetres) takes
                # the full clearance too: at a rest gap under it, its triangles cut the ball wherever
                # it now lies. A raised cheek bunches the skin under the eye: what slid farther stands
                # off farther (rides over the rows above it instead of through them).
                bulge = min(max(values[faps[2] - 1], 0.0) / CHEEK_CARRY_BLEND, 1.0) * CHEEK_BULGE
                if compiled is not None:
                    compiled.close_lids_over_eyeball(x, lid, rest, shift, centre, rest_clearance, full_clearance,
                                                     ramp, GUARD_SLIDE_MM, bulge, radii, max_radius,
                                                     RADIUS_MAP_STEP_RAD, RADIUS_MAP_REACH_RAD, PUSH_TURN_START_RAD,
                                                     PUSH_TURN_END_RAD)
                else:
                    clearance = _guard_clearance(x[lid] - rest - shift, rest_clearance, full_clearance, ramp, bulge)
                    push_outside(x, lid, centre, clearance, radii)

    def finish(self, x: np.ndarray, values: np.ndarray, *, in_place: bool = False,
               pinned: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) ``x`` (all offsets added) after the FAPs' non-additive steps: upper lids stop on the
        lower ones and slide over the eyeballs, lips press on each other, skin that would fold or smear
        is smoothed there (``surface_guard``), mouth skin stays outside the teeth (and the mouth is
        smoothed again where the teeth pushed it), eyeballs rotate
        (gaze 23-26), the head rotates (48-50). ``in_place``: ``x`` is a float array the caller owns
        and it is edited rather than copied (the rig's working array: one copy less per tick).
        ``pinned``: vertices another layer places exactly (dragged control points), which the surface
        guard leaves where they are."""
        values = self.lid_values(values)
        if not in_place:
            x = np.array(x, dtype=float)
        # Each step is skipped (its last result put back) when its vertices and values are as they were
        # at the last tick: a slider that moves a brow leaves the mouth's steps' inputs unchanged.
        memos = self._memos
        if "lids" in memos:
            memos["lids"].run(x, lambda y: self._close_lids(y, values), values[LID_GUARD_COLUMNS].tobytes())
        # Lips that were moved into each other press on each other instead (both give way).
        if "lips" in memos:
            memos["lips"].run(x, self._lip_contact.apply)
        # Where the skin would still fold or smear, it is smoothed (before the teeth guard, which
        # pushes back out what the smoothing drew into the teeth: push_b_lip -600 had 125 crossing
        # pairs the other way round; before the eyes and head turn, as the check compares each
        # triangle with its rest shape and normal).
        self._surface_guard.apply(x, pinned)
        # Teeth move rigidly, the skin around them only partly (and some lip FAPs drive it straight
        # at them): skin that ended inside a row of teeth goes back out over it.
        if "teeth" in memos:
            memos["teeth"].run(x, self._teeth_guard.apply)
            # The teeth's pushes, and what strain the first smoothing left at the mouth, are smoothed
            # once more over the mouth's skin, and what that draws into the teeth goes back out: a
            # push of 1.1 mm beside one of 0.14 stretched the generated identity's upper lip 2.39 x
            # in joy + viseme FF (seven of joy's viseme mixes failed on it; the muscle smiles' corners
            # went 2.47 -> 2.38). Smoothed again everywhere, the default face's joy squeezed the
            # skin under its eyes 0.27 -> 0.23.
            if "mouth" in memos:
                memos["mouth"].run(x, lambda y: self._smooth_mouth(y, pinned),
                                   b"" if pinned is None else np.asarray(pinned, np.int64).tobytes())
        if self._gaze:
            for name, (yaw, pitch) in (("eyeball_l", (23, 25)), ("eyeball_r", (24, 26))):
                a, b = values[yaw - 1] * tables.ANGLE_UNIT, values[pitch - 1] * tables.ANGLE_UNIT
                if a or b:
                    # Pitched about its pitch centre, then yawed about the sphere fit's centre (see
                    # _eyeball_pitch_centres): one turn about the pitch centre, which goes to ``target``.
                    idx, centre = self._eyes[name]
                    pitch_centre = self._pitch_centres[name]
                    R = _yaw_pitch(a, b)
                    target = _yaw_pitch(a, 0.0) @ (pitch_centre - centre) + centre
                    compiled = kernels.get()
                    if compiled is not None and x.dtype == np.float64:
                        compiled.rotate_rows(x, np.asarray(idx, dtype=np.int64), pitch_centre,
                                             np.ascontiguousarray(R, dtype=float), target)
                    else:
                        x[idx] = (x[idx] - pitch_centre) @ R.T + target
        head = values[47:50] * tables.ANGLE_UNIT
        if head.any():
            R = _rotation((0, 1, 0), head[1]) @ _rotation((1, 0, 0), head[0]) @ _rotation((0, 0, 1), head[2])
            x = (x - self._head_pivot) @ R.T + self._head_pivot
        return x

    def _smooth_mouth(self, x: np.ndarray, pinned: np.ndarray | None) -> None:
        """The surface guard again over the mouth's skin, then the teeth guard again where it acted
        (see :meth:`finish`)."""
        if self._surface_guard.apply(x, pinned, self._mouth):
            self._teeth_guard.apply(x)

    def deform(self, values: np.ndarray) -> np.ndarray:
        """(n, 3) vertices for (68,) effective FAP values alone: rest + FAT offsets, then :meth:`finish`
        (``core.rig.FaceRig`` composes other layers' offsets in between; the same sums as its rig)."""
        x = np.array(self._rest.reshape(-1, 3), dtype=float)
        self.add_displacement(x, values)
        return self.finish(x, values, in_place=True)


def deformer_key(face: Face) -> str:
    """The cache key of ``face``'s FapDeformer (see :meth:`FapDeformer.for_face`)."""
    landmarks = {n: face.landmark_position(n) for n in face.landmark_names}
    parts = {name: np.asarray(idx) for name, idx in face.parts.items()}
    data = [resources.path(name).read_bytes() for name in ("templates/mpeg4_80.json", "mpeg4/faps.csv")]
    return fingerprint(deformer_code_version(), data, face.vertices, face.triangles, landmarks, parts)


def deformer_code_version() -> str:
    """A hash of the code that decides how FAP values move a face (for caches of posed faces)."""
    import core.layers.fap.closed_eyes as closed_eyes_module
    import core.layers.fap.column_relax as column_relax_module
    import core.layers.fap.eyeball_surface as eyeball_surface_module
    import core.layers.fap.template as template_module
    import core.layers.fap.limits as limits_module
    import core.layers.fap.lip_contact as lip_contact_module
    import core.layers.fap.step_memo as step_memo_module
    import core.layers.fap.surface_guard as surface_guard_module
    import core.layers.fap.teeth_guard as teeth_guard_module
    import core.surface_query as surface_query
    import core.subdivision as subdivision

    return source_version(sys.modules[__name__], template_module, teeth_guard_module, lip_contact_module,
                          limits_module, step_memo_module, tables, surface_query, subdivision, closed_eyes_module,
                          eyeball_surface_module, column_relax_module, surface_guard_module)


def _column_arrays(matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr, indices, data) of ``matrix`` in CSC form, sorted, as the compiled column product takes them."""
    csc = matrix.tocsc()
    csc.sort_indices()
    return csc.indptr.astype(np.int64), csc.indices.astype(np.int64), np.ascontiguousarray(csc.data, dtype=np.float64)


def _paired_common(scaled: np.ndarray) -> np.ndarray | None:
    """(len(PAIRED_LIP_FAPS),) mm per pair: the value both FAPs of an inner/outer lip pair share (the
    smaller, when both have one sign; 0 otherwise), for (68,) ``scaled`` values x FAPU; None when no
    pair shares any (the common case: one slider moved)."""
    a, b = scaled[_PAIR_INNER], scaled[_PAIR_OUTER]
    same = a * b > 0
    if not same.any():
        return None
    return np.where(same, np.sign(a) * np.minimum(np.abs(a), np.abs(b)), 0.0)


def _round_top(entry: dict) -> bool:
    """Does a region keep its Gaussian's top through the relaxation (see ``_template_fat``)? The
    template marks the regions that need it (``"round_top"``: the lip corners); elsewhere a region's
    border is too close to its core for a held top (the cheek lift would push the lower lid over)."""
    return bool(entry.get("round_top"))


def _rounded_tip(relaxed: np.ndarray, support: np.ndarray, graph: scipy.sparse.csr_matrix, dist: np.ndarray,
                 nearest: np.ndarray) -> np.ndarray:
    """A region's ``relaxed`` weights (k,) without the cusp at its core points.

    Relaxed against a point held at its weight, the field is a cone there (harmonic about a point: FAP
    17 fell from 1 to 0.83 within 0.58 mm of 8.1, and the upper lip's skin stretched 2.1x at
    push_t_lip 600). The weights within TIP_ROUNDING_HOPS of the core (``dist`` (k,), hops) take
    TIP_ROUNDING_STEPS Jacobi steps with the core free; what each core point lost comes back as a
    Gaussian bump as wide as that smoothing (1 at the core, round at its top; the region's own, narrower
    Gaussian left a shoulder: push_t_lip 600 on the generated face 2.40x); no weight exceeds its
    nearest core point's (``nearest`` (k,), dijkstra's source index per vertex). ``support`` (k,) bool:
    where the weights before relaxation are nonzero (the region's zero border stays zero).

    The template marks the regions that take it (``"round_tip"``: the mid-lip FAPs). face_quality on
    the default and a generated face: 48 -> 41 failing poses; on every point-core region it was 26 ->
    29 on the default face alone (the cheek lift's wider top pushed its lower lid into the eyeball,
    the brows and the lip corners stretched), and on the jaw's chain 2.2 -> 3.9x at open_jaw.
    """
    reach = np.isfinite(dist)
    near = reach & (dist <= TIP_ROUNDING_HOPS)
    smoothed = _relax(relaxed, graph, ~near | ~support, TIP_ROUNDING_STEPS)
    source = np.where(reach, nearest, 0)
    lost = np.where(reach, relaxed[source] - smoothed[source], 0.0)
    bump = np.where(reach & support, np.exp(-np.where(reach, dist, 0.0) ** 2 / (2 * TIP_ROUNDING_HOPS ** 2)), 0.0)
    return np.minimum(smoothed + lost * bump, relaxed[source])


def _relax(w: np.ndarray, graph: scipy.sparse.csr_matrix, fixed: np.ndarray, steps: int) -> np.ndarray:
    """``w`` after ``steps`` Jacobi steps of graph-Laplacian smoothing (neighbours weighted by 1 /
    edge length), ``fixed`` entries kept: the FAP's core keeps its full weight and the region's
    zero border stays zero, while steep ramps in between spread out."""
    if steps <= 0:
        return w
    inv = graph.copy()
    inv.data = 1.0 / np.maximum(inv.data, 1e-9)
    degree = np.asarray(inv.sum(axis=1)).ravel()
    free = ~fixed & (degree > 0)
    out = w.copy()
    for _ in range(steps):
        out[free] = (inv @ out)[free] / degree[free]
    return out


def smooth_binding(face: Face, binding: scipy.sparse.csr_matrix, skin: np.ndarray, side: np.ndarray, steps: int,
                   anchors: np.ndarray | None = None, jump: float | None = None,
                   rings: int | None = None) -> scipy.sparse.csr_matrix:
    """(n, N) ``binding`` with its skin rows after ``steps`` Jacobi steps of Laplacian smoothing over the
    face's skin triangles (neighbours weighted by 1 / edge length), once at build time.

    ``skin`` (k,) vertex ids, ``side`` (k,) their lip / cut-lid side labels (0 none, +-1 upper / lower
    lip, +-2 upper / lower lid of a closed eye, as ``_bind`` uses them). Skin vertices of one side
    closer than ``DUPLICATE_MM`` are merged into one node first (an unwelded seam smooths across and
    both copies keep one row). A vertex of a side averages only neighbours of the same side (so the
    upper lip never takes a lower-lip row, and a cut lid stays on its own lid); side-0 skin averages all
    of its neighbours. Nodes on the skin's border after merging (the mouth and eye openings' rims, a
    cut, where skin meets a part) keep their rows: a lid margin must stay bound to the margin to close.
    With ``jump``, only nodes within ``rings`` (default ``steps``) edges of an edge whose ends are bound
    to points (``anchors`` (N, 3) mm, the dense vertices) over ``jump`` x the edge's length apart move.
    Other rows (parts) are returned unchanged.
    """
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = face.n_vertices
    skin = np.asarray(skin, np.int64)
    side = np.asarray(side, np.int64)
    k = len(skin)
    if steps <= 0 or k == 0:
        return binding
    local = np.full(n, -1, np.int64)
    local[skin] = np.arange(k)
    tris = local[face.triangles]
    tris = tris[(tris >= 0).all(axis=1)]
    # Near-duplicate skin vertices of one side -> one node.
    pairs = cKDTree(face.vertices[skin]).query_pairs(DUPLICATE_MM, output_type="ndarray")
    pairs = pairs[side[pairs[:, 0]] == side[pairs[:, 1]]] if len(pairs) else np.zeros((0, 2), np.int64)
    link = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(k, k))
    n_nodes, node = connected_components(link, directed=False)
    node = node.astype(np.int64)
    members = scipy.sparse.coo_matrix((np.ones(k), (node, np.arange(k))), shape=(n_nodes, k)).tocsr()
    count = np.asarray(members.sum(axis=1)).ravel()
    node_side = np.zeros(n_nodes, np.int64)
    node_side[node] = side
    # Edges between nodes; an edge of one triangle only is the skin's border.
    e = node[np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])]
    e = e[e[:, 0] != e[:, 1]]
    key = np.minimum(e[:, 0], e[:, 1]) * n_nodes + np.maximum(e[:, 0], e[:, 1])
    uniq, uses = np.unique(key, return_counts=True)
    a, b = uniq // n_nodes, uniq % n_nodes
    fixed = np.zeros(n_nodes, bool)
    fixed[a[uses == 1]] = fixed[b[uses == 1]] = True
    rep = np.zeros(n_nodes, np.int64)
    rep[node] = skin
    length = np.linalg.norm(face.vertices[rep[a]] - face.vertices[rep[b]], axis=1)
    rows = scipy.sparse.diags(1.0 / count) @ members @ binding[skin]
    if jump is not None:
        total = np.asarray(rows.sum(axis=1)).ravel()
        bound = (rows @ anchors) / np.maximum(total, 1e-12)[:, None]
        # Skin faded out beyond the template (the scalp: rows of total weight ~0) may jump unseen.
        jumps = ((np.linalg.norm(bound[a] - bound[b], axis=1) > jump * np.maximum(length, 1e-6))
                 & (np.minimum(total[a], total[b]) > 0.5))
        near = np.zeros(n_nodes, bool)
        near[a[jumps]] = near[b[jumps]] = True
        ring = scipy.sparse.coo_matrix((np.ones(len(a)), (a, b)), shape=(n_nodes, n_nodes)).tocsr()
        ring = ring + ring.T
        for _ in range(steps if rings is None else rings):
            near |= (ring @ near.astype(float)) > 0
        fixed |= ~near
    inv = 1.0 / np.maximum(length, 1e-6)
    # i takes j's row when i has no side or both have the same one.
    ij = np.concatenate([np.stack([a, b], 1), np.stack([b, a], 1)])
    wij = np.concatenate([inv, inv])
    keep = (node_side[ij[:, 0]] == 0) | (node_side[ij[:, 0]] == node_side[ij[:, 1]])
    W = scipy.sparse.coo_matrix((wij[keep], (ij[keep, 0], ij[keep, 1])), shape=(n_nodes, n_nodes)).tocsr()
    degree = np.asarray(W.sum(axis=1)).ravel()
    free = ~fixed & (degree > 0)
    take = scipy.sparse.diags(np.where(free, 1.0 / np.maximum(degree, 1e-12), 0.0)) @ W
    hold = scipy.sparse.diags((~free).astype(float))
    for _ in range(steps):
        rows = (take @ rows + hold @ rows).tocsr()
    rows.eliminate_zeros()
    # Back to vertices: every member of a node gets the node's row.
    smoothed = (members.T @ rows).tocoo()
    rest = binding.tocoo()
    outside = local[rest.row] < 0
    out = scipy.sparse.coo_matrix((np.concatenate([rest.data[outside], smoothed.data]),
                                   (np.concatenate([rest.row[outside], skin[smoothed.row]]),
                                    np.concatenate([rest.col[outside], smoothed.col]))), shape=binding.shape)
    return out.tocsr()


def _guard_clearance(slid_by: np.ndarray, rest_clearance: np.ndarray, full_clearance: np.ndarray, ramp: float,
                     bulge: float) -> np.ndarray:
    """(k,) mm: the lid guard's clearance of each vertex that moved ``slid_by`` (k, 3) mm over the
    ball, from ``rest_clearance`` to ``full_clearance`` (k,) by the larger of ``ramp`` and its slide
    in ``GUARD_SLIDE_MM``, plus ``bulge`` x its slide past that (the numpy twin of the compiled
    ``close_lids_over_eyeball``'s first lines)."""
    dx, dy, dz = slid_by[:, 0], slid_by[:, 1], slid_by[:, 2]
    slid = np.sqrt(dx * dx + dy * dy + dz * dz) / GUARD_SLIDE_MM
    clearance = rest_clearance + (full_clearance - rest_clearance) * np.minimum(np.maximum(ramp, slid), 1.0)
    if bulge != 0.0:
        clearance = clearance + bulge * np.maximum(slid - 1.0, 0.0) * GUARD_SLIDE_MM
    return clearance


def _same_sparse(a, b) -> bool:
    """Whether sparse matrices ``a`` and ``b`` hold the same values (a cached deformer's binding and the
    one asked for: the key hashes the face, not how a scan's cut skin is bound)."""
    return a.shape == b.shape and (scipy.sparse.csr_matrix(a) != scipy.sparse.csr_matrix(b)).nnz == 0


def _moved(x: np.ndarray, rest: np.ndarray | None, *rows: np.ndarray) -> bool:
    """Does any of the vertex ``rows`` of ``x`` (n, 3) differ from ``rest`` (n, 3)?"""
    return rest is not None and any(not np.array_equal(x[r], rest[r]) for r in rows)


def _radius_profile(offsets: np.ndarray, step_deg: float = 2.0) -> np.ndarray:
    """(b,) mm: an eyeball's outer radius by angle from +z in ``step_deg`` bins from its vertices'
    offsets (k, 3) from the centre; each bin holds the largest radius within one bin of it, empty
    bins the largest radius of all. Its median is the eye's radius for the lids' gaze following
    (:attr:`LidGuard.gaze_radius`; the lid guard itself reads the ball's radius map)."""
    length = np.linalg.norm(offsets, axis=1)
    angle = np.degrees(np.arccos(np.clip(offsets[:, 2] / np.maximum(length, 1e-9), -1.0, 1.0)))
    bins = np.arange(0.0, 180.0 + step_deg, step_deg)
    which = np.minimum((angle / step_deg).astype(int), len(bins) - 1)
    radii = np.full(len(bins), length.max())
    found = np.zeros(len(bins), dtype=bool)
    best = np.zeros(len(bins))
    np.maximum.at(best, which, length)
    found[which] = True
    radii[found] = best[found]
    widened = np.maximum(radii, np.maximum(np.roll(radii, 1), np.roll(radii, -1)))
    widened[0], widened[-1] = max(radii[0], radii[1]), max(radii[-1], radii[-2])
    return widened


def _yaw_pitch(yaw: float, pitch: float) -> np.ndarray:
    """3x3 rotation about y by ``yaw`` after one about x by ``pitch`` (rad): ``_rotation((0, 1, 0), yaw)
    @ _rotation((1, 0, 0), pitch)`` written out (per tick, per eye: the numpy small-matrix products
    cost more than rotating the eyeball)."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    return np.array([[cy, sy * sp, sy * cp], [0.0, cp, -sp], [-sy, cy * sp, cy * cp]])


def _rotation(axis, angle: float) -> np.ndarray:
    """3x3 right-handed rotation by ``angle`` rad about unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


__all__ = ["FapDeformer", "TemplateError", "deformer_key", "lid_contact"]
