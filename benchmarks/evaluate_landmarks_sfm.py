"""Landmark detection on faces none of the team made: virtual scans of the Surrey Face Model.

    python benchmarks/evaluate_landmarks_sfm.py [--people 4] [--seed 0] [--templates mpeg4_80 a48]
                                                [--textured | --untextured] [--head-pose-deg 5] [--quick]
                                                [--sfm DIR] [--dump FILE]

A second protocol next to ``evaluate_landmarks.py`` (issue 14, item 2). The database:

- **Model.** The Surrey Face Model (Huber et al., VISAPP 2016; Apache-2.0), read from
  ``../shared/data/sfm`` (``--sfm DIR``), never copied into the project: mean ``sfm_mean.npy``,
  orthonormal PCA basis ``sfm_basis.npy`` and variances ``sfm_ev.npy`` (identity = mean +
  basis @ (alpha * sqrt(ev)), alpha ~ N(0, 1) per mode from ``default_rng([seed, person])``), the
  six expression blend shapes ``bs_<name>.npy`` added at weight 1, triangles ``sfm_tri.npy``, uv.
  Its frame is checked from its own landmarks (left outer eye corner on +x, eyes above the chin,
  nose tip in front) and its units from the outer-eye-corner distance, and converted to Mimica's
  (mm, +x the face's left, +y up, +z toward the viewer) if they differ.
- **Surface.** The 3448-vertex mesh is refined by two Loop subdivision steps (``core.subdivision``;
  ~54k vertices) so that the scanned surface is smooth rather than 5 mm facets; original vertex k
  stays vertex k (at its Loop position).
- **Poses.** neutral + the six blend shapes under the synthetic protocol's names
  (``core.registration.synthetic.poses()``; SFM's "happiness" is "joy").
- **Scan.** ``core.registration.virtual_scanner.scan_face`` with the synthetic protocol's
  ``SCAN_SETTINGS`` (~50k vertices, 0.1 mm depth noise, no holes), once frontal (no pose jitter) and
  once with a small random head pose (``--head-pose-deg``, rotation ~ N(0, deg) per axis, translation
  ~ N(0, 3 mm)); random stream ``default_rng([seed, person, pose index, head-pose index])``.
- **Texture.** "textured": a synthetic 1024x1024 texture painted in the model's uv from its own ibug
  landmarks (skin of a random tone between a dark and a light
  one, with smooth blotches, dark brown brows along ibug 18-27, eye openings
  37-42 white with a dark iris and a lash line, red lips between the outer 49-60 and inner 61-68
  contours, dark nostrils near 32-36), seen by the scanner's colour image. "untextured": the same scan
  without its texture (the detector's geometry path). Both variants use the same scan.
- **Ground truth.** ibug 68 -> SFM vertex (``ibug_to_sfm.txt``) -> MPEG-4 feature point through the
  ibug <-> MPEG-4 correspondence of ``default_face_proportions.IBUG_TO_FP`` (21 points: chin, brows,
  nose tip, alar base, subnasale, eye corners, outer lip corners and midpoints, inner lip midpoints).
  The scanner binds each to the closest scan point; a point more than ``synthetic.VISIBLE_MM`` from
  its posed truth (unseen by the scanner) is not scored, as in the synthetic protocol. A template
  scores the points it has (a48 lacks 9.4/9.5: 19 points).

Detection: ``core.registration.pipeline.detect_landmarks(scan, template=...)``, the entry point of
``mimica landmarks``, for each template, with no tuning. Correct: within
``evaluation.TOLERANCE`` (0.1) x the scan's outer-eye-corner distance (3.7-3.12), as in the synthetic
protocol. Time per scan: wall and CPU seconds of ``detect_landmarks`` (the model's one-off
preparation done before timing).

Prints, per template, accuracy per pose (per variant and pooled), mm error (median, mean, p90), time
per scan, the worst points, a per-point table (each ibug point, textured and untextured apart:
accuracy, median mm, mean signed offset detected - truth and its spread in x/y/z; bias vs scatter)
and the scans that failed (accuracy < 0.5, with what the detector said
about them); the last line is
``sfm_min_expression_accuracy=<x> sfm_neutral_accuracy=<y> sfm_median_mm=<z>`` for the first template
of ``--templates`` (default ``mpeg4_80``, the ``mimica landmarks`` default), pooled over the variants run.
``--quick``: 1 person, neutral/joy/surprise. ``--dump FILE``: pickle the per-scan results.
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.default_face_proportions import IBUG_TO_FP  # noqa: E402  (the ibug <-> MPEG-4 table)

FP_TO_IBUG = {fp: k for k, fp in IBUG_TO_FP.items()}

DEFAULT_SFM = ROOT.parent / "shared" / "data" / "sfm"
SFM_POSE = {"joy": "happiness"}          # Mimica pose name -> SFM blend shape name (others are equal)
SUBDIVISIONS = 2
TEXTURE_PX = 1024
POSE_MM = 3.0                            # head-pose translation std (the synthetic protocol's)
FAIL_ACCURACY = 0.5                      # a scan below this accuracy counts as a failure


class SfmMissingError(RuntimeError):
    pass


# ----------------------------------------------------------------------------------------- the model
@dataclass
class SfmModel:
    mean: np.ndarray            # (n, 3) mm, Mimica frame
    basis: np.ndarray           # (3n, k) Mimica frame
    sdev: np.ndarray            # (k,) mm
    triangles: np.ndarray       # (m, 3)
    uv: np.ndarray              # (n, 2) Mimica convention (v up: image row = (1 - v) * H)
    blendshapes: dict           # SFM expression name -> (n, 3) mm offsets, Mimica frame
    ibug: dict                  # ibug number -> SFM vertex index
    frame_note: str


def _need(sfm_dir: Path, name: str) -> Path:
    path = sfm_dir / name
    if not path.exists():
        raise SfmMissingError(
            f"the Surrey Face Model file {path} is missing: this benchmark reads the model from "
            f"../shared/data/sfm (the project does not ship it); pass --sfm DIR")
    return path


def read_ibug_to_sfm(sfm_dir: Path) -> dict[int, int]:
    """ibug 68 landmark number -> SFM vertex index (``ibug_to_sfm.txt`` is TOML)."""
    table = tomllib.loads(_need(sfm_dir, "ibug_to_sfm.txt").read_text())["landmark_mappings"]
    return {int(k): int(v) for k, v in table.items()}


def _frame(mean: np.ndarray, ibug: dict[int, int]) -> tuple[np.ndarray, float, str]:
    """(3x3 signed axis permutation, scale to mm, note) taking SFM coordinates to Mimica's."""
    eye_l, eye_r = mean[ibug[46]], mean[ibug[37]]       # the face's own left / right outer eye corners
    chin, nose = mean[ibug[9]], mean[ibug[31]]
    eyes = (eye_l + eye_r) / 2
    wanted = [eye_l - eye_r, eyes - chin, nose - eyes]   # +x face-left, +y up, +z toward the viewer
    R = np.zeros((3, 3))
    for row, d in enumerate(wanted):
        axis = int(np.argmax(np.abs(d)))
        R[row, axis] = np.sign(d[axis])
    if abs(np.linalg.det(R)) != 1.0:
        raise SfmMissingError("cannot tell the Surrey Face Model's axes from its landmarks")
    width = float(np.linalg.norm(eye_l - eye_r))
    scale = 1.0
    for factor in (1.0, 10.0, 1000.0, 25.4):             # mm, cm, m, inches -> an adult's ~90 mm
        if 60.0 <= width * factor <= 130.0:
            scale = factor
            break
    same = np.allclose(R, np.eye(3))
    note = (f"SFM frame: {'already Mimica' if same else 'converted to Mimica'}'s axes "
            f"(+x face-left, +y up, +z viewer){'' if same else ' by ' + str(R.astype(int).tolist())}; "
            f"units {'mm' if scale == 1.0 else f'x{scale:g} to mm'} (outer eye corners {width * scale:.1f} mm apart)")
    return R * scale, scale, note


def load_sfm(sfm_dir: Path) -> SfmModel:
    sfm_dir = Path(sfm_dir)
    if not sfm_dir.is_dir():
        raise SfmMissingError(f"no Surrey Face Model folder at {sfm_dir}: pass --sfm DIR (see ../shared/data/README.md)")
    ibug = read_ibug_to_sfm(sfm_dir)
    mean = np.load(_need(sfm_dir, "sfm_mean.npy")).astype(np.float64)
    M, _scale, note = _frame(mean, ibug)
    n = len(mean)
    basis = np.load(_need(sfm_dir, "sfm_basis.npy")).astype(np.float64)
    k = basis.shape[1]
    basis = np.einsum("ij,njk->nik", M, basis.reshape(n, 3, k)).reshape(3 * n, k)
    sdev = np.sqrt(np.load(_need(sfm_dir, "sfm_ev.npy")).astype(np.float64).ravel())
    uv = np.load(_need(sfm_dir, "sfm_uv.npy")).astype(np.float64)
    uv = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])     # SFM's v grows downwards (chin below the eyes)
    shapes = {}
    for pose in ("anger", "disgust", "fear", "happiness", "sadness", "surprise"):
        shapes[pose] = np.load(_need(sfm_dir, f"bs_{pose}.npy")).astype(np.float64) @ M.T
    tris = np.load(_need(sfm_dir, "sfm_tri.npy")).astype(np.int64)
    _need(sfm_dir, "LICENSE.eos-Apache-2.0")
    return SfmModel(mean @ M.T, basis, sdev, tris, uv, shapes, ibug, note)


def identity(model: SfmModel, person: int, seed: int) -> np.ndarray:
    """(n, 3) mm: a random person from the PCA modes (alpha ~ N(0, 1), seeded)."""
    alpha = np.random.default_rng([seed, person]).standard_normal(len(model.sdev))
    return model.mean + (model.basis @ (alpha * model.sdev)).reshape(-1, 3)


# ------------------------------------------------------------------------------------- the surface
@dataclass
class Surface:
    """The Loop-refined topology shared by every SFM face (vertex k < n is SFM vertex k)."""

    triangles: np.ndarray
    uv: np.ndarray
    steps: list                   # Subdivided results, to replay the vertex positions
    landmarks: dict               # fp name -> SurfacePoint on the refined mesh (at SFM vertex ibug[k])


def refine_topology(model: SfmModel, steps: int = SUBDIVISIONS) -> Surface:
    from core.face import SurfacePoint
    from core.subdivision import subdivide

    v, t, uv, done, creases = model.mean, model.triangles, model.uv, [], None
    for _ in range(steps):
        s = subdivide(v, t, scheme="loop", params=uv, creases=creases)
        done.append(s)
        v, t, uv, creases = s.vertices, s.triangles, s.params, None
    landmarks = {}
    for k, fp in IBUG_TO_FP.items():
        vid = model.ibug[k]
        tri = int(np.nonzero((t == vid).any(axis=1))[0][0])
        bary = tuple(float(x) for x in (t[tri] == vid))
        landmarks[fp] = SurfacePoint(tri, bary)
    return Surface(t, uv, done, landmarks)


def refine_vertices(model: SfmModel, surface: Surface, vertices: np.ndarray) -> np.ndarray:
    from core.subdivision import subdivide

    v, t = vertices, model.triangles
    for s in surface.steps:
        v = subdivide(v, t, scheme="loop").vertices
        t = s.triangles
    return v


# ------------------------------------------------------------------------------------- the texture
def paint_texture(model: SfmModel, person: int, seed: int, size: int = TEXTURE_PX) -> np.ndarray:
    """(size, size, 3) uint8: skin, brows, eyes, lips and nostrils painted at the ibug landmarks' uv."""
    import cv2

    rng = np.random.default_rng([seed, person, 99])
    ib = model.ibug

    def px(*numbers) -> np.ndarray:
        uv = model.uv[[ib[k] for k in numbers]]
        return np.column_stack([uv[:, 0] * size, (1.0 - uv[:, 1]) * size])

    # mm -> texels from the outer eye corners (uv of the mean face)
    mm = size * float(np.linalg.norm(model.uv[ib[46]] - model.uv[ib[37]])) / float(
        np.linalg.norm(model.mean[ib[46]] - model.mean[ib[37]]))
    # a skin tone between a dark and a light anchor (R > G > B throughout), brows dark brown to black
    skin = np.array([95.0, 60.0, 45.0]) + rng.uniform(0.0, 1.0) * np.array([140.0, 135.0, 125.0])
    blotch = cv2.GaussianBlur(rng.normal(0, 1, (size, size)).astype(np.float32), (0, 0), 12 * mm)
    blotch /= max(float(np.abs(blotch).max()), 1e-6)
    img = skin[None, None, :] * (1.0 + 0.08 * blotch[..., None])
    img = np.clip(img, 0, 255).astype(np.uint8)
    I = lambda a: np.rint(a).astype(np.int32)  # noqa: E731
    brow = tuple(int(c) for c in rng.uniform(30, 90) * np.array([1.0, 0.75, 0.55]))
    iris_colour = tuple(int(c) for c in rng.uniform(40, 110) * np.array([1.0, 0.8, 0.6]))
    for side in ((18, 19, 20, 21, 22), (23, 24, 25, 26, 27)):
        cv2.polylines(img, [I(px(*side))], False, brow, thickness=max(1, int(round(5 * mm))), lineType=cv2.LINE_AA)
    for eye in ((37, 38, 39, 40, 41, 42), (43, 44, 45, 46, 47, 48)):
        poly = px(*eye)
        mask = np.zeros((size, size), np.uint8)
        cv2.fillPoly(mask, [I(poly)], 255, lineType=cv2.LINE_AA)
        iris = np.zeros_like(mask)
        cv2.circle(iris, tuple(I(poly.mean(axis=0))), int(round(5.5 * mm)), 255, -1, lineType=cv2.LINE_AA)
        img[mask > 0] = (235, 232, 228)
        img[(mask > 0) & (iris > 0)] = iris_colour
        cv2.polylines(img, [I(poly[:4])], False, (30, 25, 25), thickness=max(1, int(round(1.2 * mm))),
                      lineType=cv2.LINE_AA)
    lip = tuple(int(c) for c in np.clip(skin * [0.95, 0.55, 0.6] + [20, 0, 5], 0, 255))
    cv2.fillPoly(img, [I(px(*range(49, 61)))], lip, lineType=cv2.LINE_AA)
    inner = px(49, 62, 63, 64, 55, 66, 67, 68)           # 61 and 65 (inner corners) are not in the SFM map
    cv2.fillPoly(img, [I(inner)], (60, 25, 30), lineType=cv2.LINE_AA)
    for a, b in ((32, 33), (36, 35)):
        centre = (px(a)[0] * 0.6 + px(b)[0] * 0.4) - [0, 1.0 * mm]
        cv2.ellipse(img, tuple(I(centre)), (int(round(3 * mm)), int(round(1.6 * mm))), 0, 0, 360, (70, 40, 35), -1,
                    lineType=cv2.LINE_AA)
    return img


# ------------------------------------------------------------------------------------------- scans
@dataclass
class Scan:
    person: int
    pose: str
    head_pose_deg: float
    face: object                  # the scan Face (textured), ground truth as its landmarks
    visible: frozenset
    transform: np.ndarray         # (4, 4) head pose: SFM face frame -> scan


def make_scans(model: SfmModel, surface: Surface, person: int, seed: int, head_poses, poses, textured: bool):
    """Yield the Scans of one person: each pose, each head pose."""
    from core.face import Face, FaceMetadata
    from core.registration.synthetic import SCAN_SETTINGS, VISIBLE_MM, poses as all_poses
    from core.registration.virtual_scanner import scan_face

    neutral = identity(model, person, seed)
    texture = paint_texture(model, person, seed) if textured else None
    settings = {k: v for k, v in SCAN_SETTINGS.items() if not k.startswith("pose_jitter")}
    for pose in poses:
        shape = neutral if pose == "neutral" else neutral + model.blendshapes[SFM_POSE.get(pose, pose)]
        source = Face(refine_vertices(model, surface, shape), surface.triangles, uv=surface.uv, texture=texture,
                      landmarks=surface.landmarks,
                      metadata=FaceMetadata(source="Surrey Face Model", name=f"SFM person {person} {pose}"))
        for h, deg in enumerate(head_poses):
            rng = np.random.default_rng([seed, person, all_poses().index(pose), h])
            res = scan_face(source, rng=rng, pose_jitter_deg=float(deg), pose_jitter_mm=POSE_MM if deg else 0.0,
                            **settings)
            visible = frozenset(n for n, e in res.landmark_error_mm.items() if e <= VISIBLE_MM)
            yield Scan(person, pose, float(deg), res.face, visible, res.transform)


# ---------------------------------------------------------------------------------------- detection
@dataclass
class Result:
    template: str
    person: int
    pose: str
    textured: bool
    head_pose_deg: float
    names: tuple
    errors: np.ndarray            # (P,) mm, NaN where not scored
    offsets: np.ndarray           # (P, 3) mm, detected - truth in the face's frame (x left, y up, z out)
    confidence: np.ndarray        # (P,) the detector's confidence of each scored point
    tolerance_mm: float
    wall_s: float
    cpu_s: float
    n_vertices: int
    low_confidence: list = field(default_factory=list)
    scale_hint: float | None = None
    notes: list = field(default_factory=list)

    @property
    def variant(self) -> str:
        return f"{'tex' if self.textured else 'geo'}{'+pose' if self.head_pose_deg else ''}"

    @property
    def accuracy(self) -> float:
        have = np.isfinite(self.errors)
        return float((self.errors[have] <= self.tolerance_mm).mean()) if have.any() else float("nan")


def detect(scan: Scan, template: str, textured: bool) -> Result:
    from core.registration.evaluation import tolerance_for
    from core.registration.pipeline import detect_landmarks
    from core.registration.templates import get_template

    face = scan.face if textured else scan.face.without_texture()
    names = tuple(n for n in IBUG_TO_FP.values() if n in get_template(template).detected)
    w0, c0 = time.perf_counter(), time.process_time()
    det = detect_landmarks(face, template=template)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    offsets = np.full((len(names), 3), np.nan)
    for i, n in enumerate(names):
        if n in scan.visible:
            offsets[i] = scan.transform[:3, :3].T @ (det.positions[n] - scan.face.landmark_position(n))
    errors = np.linalg.norm(offsets, axis=1)
    confidence = np.array([det.confidence.get(n, np.nan) for n in names])
    return Result(template, scan.person, scan.pose, textured, scan.head_pose_deg, names, errors, offsets, confidence,
                  tolerance_for(scan.face), wall, cpu, scan.face.n_vertices, det.low_confidence(), det.scale_hint,
                  list(det.report))


# ------------------------------------------------------------------------------------------ report
def _pool(results) -> np.ndarray:
    return np.concatenate([r.errors[np.isfinite(r.errors)] for r in results]) if results else np.zeros(0)


def accuracy(results) -> float:
    ok = sum(int((r.errors[np.isfinite(r.errors)] <= r.tolerance_mm).sum()) for r in results)
    n = sum(int(np.isfinite(r.errors).sum()) for r in results)
    return ok / n if n else float("nan")


def mm_stats(results) -> tuple[float, float, float]:
    e = _pool(results)
    return (float(np.median(e)), float(e.mean()), float(np.percentile(e, 90))) if len(e) else (np.nan,) * 3


def summary(results) -> tuple[float, float, float]:
    """(worst expression accuracy, neutral accuracy, median mm) over ``results``."""
    poses = list(dict.fromkeys(r.pose for r in results))
    ex = [accuracy([r for r in results if r.pose == p]) for p in poses if p != "neutral"]
    return (min(ex) if ex else float("nan"), accuracy([r for r in results if r.pose == "neutral"]),
            mm_stats(results)[0])


def point_table(rs) -> list[str]:
    """Per ibug point and texture variant: accuracy, median mm, mean signed offset detected - truth
    (x face-left, y up, z out; mm) and its spread; where the error is bias and where scatter."""
    lines = [f"per point (all poses): {'point':>5} ibug | variant  acc   med mm   mean offset x/y/z mm   std x/y/z mm   n"]
    groups = [("tex", [r for r in rs if r.textured]), ("geo", [r for r in rs if not r.textured])]
    for i, n in enumerate(rs[0].names):
        ibug = FP_TO_IBUG[n]
        for label, sel in groups:
            if not sel:
                continue
            e = np.array([r.errors[i] for r in sel])
            t = np.array([r.tolerance_mm for r in sel])
            o = np.array([r.offsets[i] for r in sel])
            have = np.isfinite(e)
            if not have.any():
                continue
            m, sd = o[have].mean(axis=0), o[have].std(axis=0)
            lines.append(f"  {n:>5} {ibug:4d} | {label:<6} {(e[have] <= t[have]).mean():5.3f} {np.median(e[have]):6.2f}   "
                         f"{m[0]:+5.1f} {m[1]:+5.1f} {m[2]:+5.1f}        {sd[0]:4.1f} {sd[1]:4.1f} {sd[2]:4.1f}   "
                         f"{int(have.sum())}")
    return lines


def report(results, template: str, worst: int = 8) -> list[str]:
    rs = [r for r in results if r.template == template]
    if not rs:
        return []
    poses = list(dict.fromkeys(r.pose for r in rs))
    variants = list(dict.fromkeys(r.variant for r in rs))
    tol = [r.tolerance_mm for r in rs]
    lines = [f"template {template}: {len(rs[0].names)} scored points with an ibug counterpart; "
             f"{len({r.person for r in rs})} people x {len(poses)} poses x {len(variants)} variants = {len(rs)} scans "
             f"(~{np.mean([r.n_vertices for r in rs]) / 1000:.0f}k vertices); tolerance {np.mean(tol):.2f} mm "
             f"on average ({np.min(tol):.2f}-{np.max(tol):.2f})",
             "variants: tex = synthetic texture, geo = untextured (geometry only), +pose = random head pose",
             "",
             f"{'pose':<9}" + "".join(f"{v:>10}" for v in variants)
             + f" | {'all':>6} {'med mm':>7} {'mean mm':>7} {'p90 mm':>7} {'n':>5} {'s/scan':>7}"]
    for p in poses + ["all"]:
        sel = rs if p == "all" else [r for r in rs if r.pose == p]
        med, mean, p90 = mm_stats(sel)
        lines.append(f"{p:<9}" + "".join(f"{accuracy([r for r in sel if r.variant == v]):>10.3f}" for v in variants)
                     + f" | {accuracy(sel):6.3f} {med:7.2f} {mean:7.2f} {p90:7.2f} {len(_pool(sel)):5d} "
                     f"{np.median([r.wall_s for r in sel]):7.2f}")
    lines.append("")
    for v in variants:
        sel = [r for r in rs if r.variant == v]
        mn, neu, med = summary(sel)
        lines.append(f"  {v:<9} worst expression {mn:.3f}, neutral {neu:.3f}, median {med:.2f} mm; time per scan "
                     f"median {np.median([r.wall_s for r in sel]):.2f} s wall, {np.median([r.cpu_s for r in sel]):.2f} s CPU "
                     f"(max {max(r.wall_s for r in sel):.2f} s)")
    lines.append("")
    lines.append(f"worst points ({template}, all scans): accuracy, median / mean / p90 mm, n, "
                 "mean offset detected - truth (x face-left, y up, z out) mm")
    rows = []
    for i, n in enumerate(rs[0].names):
        e = np.array([r.errors[i] for r in rs])
        t = np.array([r.tolerance_mm for r in rs])
        have = np.isfinite(e)
        if have.any():
            ibug = FP_TO_IBUG[n]
            off = np.array([r.offsets[i] for r in rs])[have].mean(axis=0)
            rows.append((float((e[have] <= t[have]).mean()), n, ibug, np.median(e[have]), e[have].mean(),
                         np.percentile(e[have], 90), int(have.sum()), off))
    rows.sort(key=lambda x: (x[0], -x[3]))
    for acc, n, ibug, med, mean, p90, cnt, off in rows[:worst]:
        lines.append(f"  {n:>5} (ibug {ibug:2d})  {acc:6.3f}  {med:6.2f} / {mean:6.2f} / {p90:6.2f} mm  n={cnt:<4d} "
                     f"offset ({off[0]:+5.1f}, {off[1]:+5.1f}, {off[2]:+5.1f})")
    lines.append("")
    lines.extend(point_table(rs))
    e = np.concatenate([r.errors for r in rs])
    c = np.concatenate([r.confidence for r in rs])
    wrong = np.concatenate([r.errors > r.tolerance_mm for r in rs])
    have = np.isfinite(e) & np.isfinite(c)
    low = have & (c < 0.5)
    lines.append("")
    lines.append(f"confidence (< 0.5 = low, as the detector reports it) on the scored points: "
                 f"{low.sum()} of {have.sum()} low; {int((wrong & low).sum())} of {int((wrong & have).sum())} "
                 f"wrong points flagged; {(wrong & low).sum() / max(low.sum(), 1):.2f} of the flagged ones wrong, "
                 f"{(wrong & have & ~low).sum() / max((have & ~low).sum(), 1):.2f} of the unflagged ones wrong")
    fails = [r for r in rs if r.accuracy < FAIL_ACCURACY]
    lines.append("")
    lines.append(f"failures (accuracy < {FAIL_ACCURACY}): {len(fails)} of {len(rs)} scans")
    for r in fails:
        said = (f"{len(r.low_confidence)} low-confidence points"
                + (f", scale hint {r.scale_hint:.3g}" if r.scale_hint else "")
                + (f"; notes: {' | '.join(r.notes)[:300]}" if r.notes else ""))
        lines.append(f"  person {r.person} {r.pose} {r.variant}: accuracy {r.accuracy:.3f}, median "
                     f"{np.nanmedian(r.errors):.1f} mm; detector said: {said}")
    return lines


# -------------------------------------------------------------------------------------------- main
def main(argv=None) -> int:
    from core.registration.synthetic import poses as all_poses

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sfm", type=Path, default=DEFAULT_SFM, help="Surrey Face Model folder (default %(default)s)")
    ap.add_argument("--people", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--templates", nargs="+", default=["mpeg4_80", "a48"], choices=["mpeg4_80", "a48"],
                    help="the first one gives the last line")
    tex = ap.add_mutually_exclusive_group()
    tex.add_argument("--textured", action="store_true", help="only the textured scans")
    tex.add_argument("--untextured", action="store_true", help="only the untextured scans")
    ap.add_argument("--head-pose-deg", type=float, default=5.0,
                    help="std of the head-pose rotation per axis for the posed scans; 0 = frontal scans only")
    ap.add_argument("--poses", nargs="+", default=None, choices=list(all_poses()))
    ap.add_argument("--quick", action="store_true", help="1 person, neutral/joy/surprise")
    ap.add_argument("--quiet", action="store_true", help="no per-scan lines")
    ap.add_argument("--dump", type=Path, default=None, help="pickle the per-scan Results here (for analysis)")
    args = ap.parse_args(argv)

    try:
        model = load_sfm(args.sfm)
    except SfmMissingError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    people = 1 if args.quick else args.people
    poses = args.poses or (["neutral", "joy", "surprise"] if args.quick else list(all_poses()))
    textures = [True] if args.textured else [False] if args.untextured else [False, True]
    head_poses = [0.0] + ([args.head_pose_deg] if args.head_pose_deg > 0 else [])
    print(model.frame_note)
    print(f"Surrey Face Model (Huber et al., VISAPP 2016; Apache-2.0) from {args.sfm}: {len(model.mean)} vertices, "
          f"{len(model.sdev)} identity modes; {SUBDIVISIONS} Loop steps before scanning")

    from core.registration.matching import MatchParams
    from core.registration.pipeline import default_model, get_model_context

    t0 = time.perf_counter()
    for template in args.templates:
        get_model_context(default_model(), template, MatchParams())
    print(f"model preparation (once, not timed per scan): {time.perf_counter() - t0:.1f} s")
    surface = refine_topology(model)
    results: list[Result] = []
    t_start = time.perf_counter()
    for person in range(people):
        for scan in make_scans(model, surface, person, args.seed, head_poses, poses, textured=True in textures):
            for textured in textures:
                for template in args.templates:
                    r = detect(scan, template, textured)
                    results.append(r)
                    if not args.quiet:
                        print(f"  person {person} {scan.pose:<8} {r.variant:<9} {template:<8} accuracy {r.accuracy:.3f} "
                              f"median {np.nanmedian(r.errors):5.1f} mm  {r.wall_s:5.2f} s  "
                              f"{len(r.low_confidence)} low-confidence", flush=True)
    print(f"\n{len(results)} detections in {time.perf_counter() - t_start:.0f} s\n")
    if args.dump is not None:
        import pickle
        args.dump.write_bytes(pickle.dumps(results))
    for template in args.templates:
        print("\n".join(report(results, template)))
        print()
    for template in args.templates[1:]:
        mn, neu, med = summary([r for r in results if r.template == template])
        print(f"({template}: min expression {mn:.4f}, neutral {neu:.4f}, median {med:.2f} mm)")
    mn, neu, med = summary([r for r in results if r.template == args.templates[0]])
    print(f"sfm_min_expression_accuracy={mn:.4f} sfm_neutral_accuracy={neu:.4f} sfm_median_mm={med:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
