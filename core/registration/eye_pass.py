"""Eye pass: each eye found as a whole by its shape, and a closed eye's points put on its lid line.

The patch search compares small patches of the model's open eye (white, iris, lid margins): on a
scan with closed eyes nothing there looks like them, and the eye points drift up onto the brows
(LeePerrySmith's eye corners and upper lids sat 15-22 mm high). The eye as a whole is still there
in the shape: the lid bulge under the brow ridge, between the nose and the temple. So, per eye:

* **where**: the model's eye box (its eye points, a margin around) in the surface-normal channels of
  the model's frontal raster is searched in the scan's raster (NCC, ``patches._ncc``) within
  ``EYE_SEARCH`` x face scale of where the aligned model has it, at eye sizes ``EYE_SIZES`` (adult
  eye widths vary about +-15 %): the best offset and size map the model's eye points onto the scan;
* **open or closed** (textured scans, and a model that can close its lids, see
  :func:`closed_model_raster`): at that offset and size the texture (grey) of the model's eye box is
  compared with the same box with the lids closed (FAPs 19-20 at full closure); the eye is closed
  when the closed box correlates better. Without texture the shape alone does not tell a closed eye
  from an open one (measured: NCC within 0.03 either way), so the eye is taken as open;
* **moves**: an eye the patch search lost (its points' mean confidence under the detector's
  ``LOW_CONFIDENCE``) takes all its points from the fit, a closed one its upper-lid midpoint on the
  lid line (the closed model's upper lid is its lower lid); an eye that was found keeps its points,
  except that a closed eye's upper lid farther than ``EYE_MOVE`` x face scale (the protocols'
  tolerance) from the lid line goes there (the open lid's place). The fit alone is not better than
  a found eye's patches: on Surrey Face Model scans, whose eyes are smooth shells with painted
  eyes, the shape fits poorly (NCC 0.4-0.6) and the painted eyes can look closed. Surface points
  from the scan's frontal raster, source "refined", evidence the eye's shape NCC.

* **no eye in the shape** (scans without texture): where the best shape NCC of the eye box is under
  ``EYE_SHAPE_NCC`` the scan's eye region has no lid or eyeball relief (Surrey Face Model scans: a
  smooth shell). The patch search then had nothing to go by: its NCC is flat (~0.35 across +-12 mm)
  and its peaks land on the slope up to the brow ridge (inner corners ~5 mm, outer corners up to
  16 mm high), and the box fit is no better (3-4 mm low). All the eye's points are then predicted
  from the anchors (the confident non-eye points, as in ``steep_pass``; the aligned model's place
  when there are fewer than 3) and put at the closest scan point (beside the eye the surface turns
  away from the view); source "prediction", evidence 0, so they are reported low confidence.

A side is left alone when its corners are not in the template, the eye box leaves the raster, or
no eye is found (shape NCC <= 0, with texture); fixed points never move."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from core.landmark_editing import LOW_CONFIDENCE
from core.registration.pass_results import MatchState, SurfaceMoves
from core.registration.rasters import FrontalRaster

if TYPE_CHECKING:
    from core.registration.match_context import MatchContext, ModelContext

#: Per side (MPEG-4 names): outer corner, inner corner, upper lid, lower lid, lower-lid fold, upper-lid fold.
EYES = (("3.7", "3.11", "3.1", "3.3", "3.9", "3.13"), ("3.12", "3.8", "3.2", "3.4", "3.10", "3.14"))
EYE_SEARCH = 0.16          # x face scale: farthest the eye is searched from where the aligned model has it
EYE_SIZES = (0.85, 0.92, 1.0, 1.08, 1.16)   # eye sizes tried, relative to the model's
EYE_MARGIN = (0.055, 0.035)   # x face scale: the box around the eye points (x, y): lid bulge and corners
EYE_MOVE = 0.1             # x face scale: a closed eye's upper lid farther than this from its lid line moves
# Without texture, an eye box whose best shape NCC is under this shows no eye. Measured (find_eye's
# NCC, untextured scans): generated faces 0.71-0.91 (3 people x neutral/joy/anger, 30 eyes), Surrey
# Face Model scans 0.35-0.50 (4 people x neutral/sadness, 16 eyes).
EYE_SHAPE_NCC = 0.6
CLOSED_FAPS = {19: 1024.0, 20: 1024.0}   # close_t_l/r_eyelid at full closure (IRISD units: 1024 = the iris)


def closed_model_raster(model_ctx: ModelContext) -> FrontalRaster | None:
    """The model's frontal raster (its grid) with both upper lids closed by the model's FAP rig, or
    None when the model cannot close them (``model_ctx.can_close_eyes`` False: a given model such as
    a person's own neutral scan has no rig). Built once (the rig's deformer, ~15 s) and kept in the
    disk cache, keyed by the model, the grid and the source of
    this module, the rasters and the FAP tables; in memory per model context."""
    if not model_ctx.can_close_eyes:
        return None
    hit = _CLOSED.get(id(model_ctx))
    if hit is not None and hit[0] is model_ctx:
        return hit[1]
    from core.cache import DiskCache, fingerprint, source_version
    from core.layers.fap import fat, tables
    from core.registration import rasters

    face, grid = model_ctx.face, model_ctx.grid
    key = fingerprint(face.vertices, face.triangles, face.uv, face.texture, tuple(grid.__dict__.values()),
                      CLOSED_FAPS, source_version(_this_module(), rasters, fat, tables))

    def build() -> FrontalRaster:
        from core.registration.correspondence import SurfaceRays
        from core.registration.rasters import frontal_raster
        from core.rig import FaceRig

        rig = FaceRig(face, cache=DiskCache())
        rig.set_faps(CLOSED_FAPS)
        closed = face.with_vertices(np.array(rig.vertices()))
        return frontal_raster(closed, SurfaceRays(closed.vertices, closed.triangles), np.eye(4), grid)

    raster = DiskCache().get_or_build("closed_eye_raster", key, build)
    if len(_CLOSED) > 4:
        _CLOSED.clear()
    _CLOSED[id(model_ctx)] = (model_ctx, raster)
    return raster


_CLOSED: dict = {}


def _this_module():
    import sys

    return sys.modules[__name__]


def find_eye(model: np.ndarray, scan: np.ndarray, box: tuple[int, int, int, int], reach: int):
    """(ncc, size, (dcol, drow)) of the best match of ``model[box]`` in ``scan`` (both (H, W, C)
    rasters on one grid; box = (col0, row0, col1, row1) inclusive) within ``reach`` pixels of the
    box, resized by each of EYE_SIZES about its centre; (dcol, drow) moves the box centre. None when
    the search window leaves the raster."""
    import cv2

    from core.registration.patches import _ncc

    c0, r0, c1, r1 = box
    H, W = scan.shape[:2]
    patch = np.ascontiguousarray(model[r0:r1 + 1, c0:c1 + 1])
    ph, pw = patch.shape[:2]
    best = None
    for size in EYE_SIZES:
        h, w = int(round(ph * size)), int(round(pw * size))
        top, left = int(round((r0 + r1) / 2 - h / 2)) - reach, int(round((c0 + c1) / 2 - w / 2)) - reach
        if top < 0 or left < 0 or top + h + 2 * reach > H or left + w + 2 * reach > W:
            return None
        resized = cv2.resize(patch, (w, h), interpolation=cv2.INTER_LINEAR).reshape(h, w, -1)
        res = _ncc(scan[top:top + h + 2 * reach, left:left + w + 2 * reach], resized)
        iy, ix = np.unravel_index(int(np.argmax(res)), res.shape)
        if best is None or res[iy, ix] > best[0]:
            shift = (left + ix + w / 2 - (c0 + c1 + 1) / 2, top + iy + h / 2 - (r0 + r1 + 1) / 2)
            best = (float(res[iy, ix]), size, shift)
    return best


def _grey_ncc(model: np.ndarray, scan: np.ndarray, box, size: float, shift) -> float:
    """NCC of the model's grey box, resized by ``size`` and moved by ``shift`` (pixels), with the
    scan's grey at that place (best within +-2 pixels: the pose came from the shape)."""
    import cv2

    from core.registration.patches import _ncc

    c0, r0, c1, r1 = box
    patch = np.ascontiguousarray(model[r0:r1 + 1, c0:c1 + 1])
    ph, pw = patch.shape[:2]
    h, w = int(round(ph * size)), int(round(pw * size))
    top = int(round((r0 + r1 + 1) / 2 + shift[1] - h / 2)) - 2
    left = int(round((c0 + c1 + 1) / 2 + shift[0] - w / 2)) - 2
    if top < 0 or left < 0 or top + h + 4 > scan.shape[0] or left + w + 4 > scan.shape[1]:
        return -1.0
    resized = cv2.resize(patch, (w, h), interpolation=cv2.INTER_LINEAR).reshape(h, w, 1)
    return float(_ncc(scan[top:top + h + 4, left:left + w + 4, None], resized).max())


def eye_pass(ctx: MatchContext, state: MatchState, confidence: np.ndarray) -> SurfaceMoves:
    """Moves of the eye points to where the eye as a whole is (see the module docstring);
    ``confidence`` (P,) tells which eyes the patch search lost."""
    raster = ctx.scan_raster
    if raster is None:
        return SurfaceMoves.none()
    names = ctx.model.template.detected
    model_pts = ctx.model.side.points
    scale = ctx.model.scale
    px = raster.pixel
    model_shape = ctx.model.raster.channels[..., :3]
    scan_shape = raster.channels[..., :3]
    textured = ctx.textured and raster.channels.shape[-1] >= 5
    closed_raster = closed_model_raster(ctx.model) if textured else None
    reach = max(1, int(round(EYE_SEARCH * scale / px)))
    index, tri, bary, evidence, source = [], [], [], [], []
    anchored = None               # the anchors' prediction (P, 3), made when a shapeless eye needs it
    for side in EYES:
        present = [n for n in side if n in names]
        if side[0] not in present or side[1] not in present:
            continue
        idx = [names.index(n) for n in present]
        pts = model_pts[idx]
        lo = pts[:, :2].min(axis=0) - np.array(EYE_MARGIN) * scale
        hi = pts[:, :2].max(axis=0) + np.array(EYE_MARGIN) * scale
        (c0, r0), (c1, r1) = np.round(raster.to_pixel([[lo[0], hi[1], 0.0], [hi[0], lo[1], 0.0]])).astype(int)
        found = find_eye(model_shape, scan_shape, (c0, r0, c1, r1), reach)
        if found is None:
            continue
        ncc, size, shift = found
        shapeless = not ctx.textured and ncc < EYE_SHAPE_NCC
        if shapeless and anchored is None:
            anchored = _anchor_prediction(ctx, state, confidence)
        if shapeless and anchored is not None:
            # No eye in the shape: every point where the anchors put it, at the closest scan point.
            moved = [i for i in idx if not ctx.fixed[i]]
            if moved:
                t, b, _ = ctx.closest(anchored[moved])
                index += moved
                tri += [int(x) for x in t]
                bary += list(b)
                evidence += [0.0] * len(moved)
                source += ["prediction"] * len(moved)
            continue
        if shapeless:
            size, shift = 1.0, (0.0, 0.0)     # too few anchors: where the aligned model has the eye
        elif ncc <= 0:
            continue
        closed = False
        if closed_raster is not None:
            grey_open = _grey_ncc(ctx.model.raster.channels[..., 3], raster.channels[..., 3], (c0, r0, c1, r1), size, shift)
            grey_closed = _grey_ncc(closed_raster.channels[..., 3], raster.channels[..., 3], (c0, r0, c1, r1), size,
                                    shift)
            closed = grey_closed > grey_open
        # The model's eye points mapped by the found size and offset (frontal plane, mm).
        centre = (lo + hi) / 2
        target = centre + size * (pts[:, :2] - centre) + np.array([shift[0], -shift[1]]) * px
        if closed and side[2] in present and side[3] in present:
            # Closed lids: the upper lid's midpoint lies on the lower one's (the lid line).
            target[present.index(side[2])] = target[present.index(side[3])]
        # A lost eye (its points' mean confidence below the detector's "worth checking" level: the
        # open eye's patches found nothing real, e.g. a closed eye) takes all its points from the
        # fit; a found eye keeps them, except a closed eye's upper lid still at the open lid's place.
        lost = shapeless or float(np.mean(confidence[idx])) < LOW_CONFIDENCE
        for k, (i, n) in enumerate(zip(idx, present)):
            if ctx.fixed[i]:
                continue
            stuck_open = closed and n == side[2] and \
                np.linalg.norm(state.positions[i, :2] - target[k]) > EYE_MOVE * scale
            if not (lost or stuck_open):
                continue
            col, row = np.round(raster.to_pixel([[target[k, 0], target[k, 1], 0.0]])[0]).astype(int)
            if 0 <= row < raster.triangle.shape[0] and 0 <= col < raster.triangle.shape[1] \
                    and raster.triangle[row, col] >= 0:
                index.append(i)
                tri.append(int(raster.triangle[row, col]))
                bary.append(raster.bary[row, col])
                evidence.append(0.0 if shapeless else ncc)
                source.append("prediction" if shapeless else "refined")
    return SurfaceMoves(index, tri, bary, source=source, evidence=evidence)


def _anchor_prediction(ctx: MatchContext, state: MatchState, confidence: np.ndarray) -> np.ndarray | None:
    """(P, 3) model frame, mm: every point predicted from the anchors (``steep_pass.anchor_prediction``),
    steep points and the eye points left out (a shapeless eye's own points are no evidence); None
    with fewer than 3 anchors."""
    from core.registration.steep_pass import anchor_prediction, steep_points

    names = ctx.model.template.detected
    eye = np.array([any(n in side for side in EYES) for n in names])
    return anchor_prediction(ctx, state, confidence, steep_points(ctx.model) | eye)
