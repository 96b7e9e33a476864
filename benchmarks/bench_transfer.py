"""How well expression transfer, caricature and FAP correctives reproduce known faces.

Transfer (one line per method and data set; RMS in mm over vertices and poses):

    transfer_rms_mm method=<bbox|deformation|fap_units|local_affine|copy> data=<synthetic|sfm> value=<x>

(``copy``: A's displacements unchanged, only rotated into B's frame — a reference: SFM's expression
offsets do not depend on identity, so on SFM copying is exact up to the alignment, the two
registrations' correspondence and the smoothing, and every adapting method, the thesis's included,
can only lose against it.)

* ``synthetic``: the synthetic protocol database (``core.registration.synthetic``). Persons A and B
  are scanned in each pose and registered (template mpeg4_80, landmarks from the scans: the real
  pipeline; the neutral by ``register_scan``, each pose from it by ``register_pose``). A's library (neutral + 6 expressions, each pose aligned to the neutral) is transferred
  onto B's registered neutral and compared with **B's true pose**: the generator's own displacement
  of B's face (its rig at that expression), carried to B's canonical vertices through the neutral
  scan's known pose (``Person.true_library``). B's *registered* pose is not the reference, because
  its projection slides along the skin (``registration_sliding_rms_mm``, ≈ 0.8 mm, partly shared with
  A's: no method can predict it); that comparison is printed too, as ``transfer_vs_registered_rms_mm``.
  Pairs (A, B) = (1, 2), (2, 1), (1, 3), (3, 2).
* ``sfm``: the Surrey Face Model in ``../shared/data/sfm`` (benchmark data only, never copied into
  Mimica): random identities (shape coefficients ~ N(0, 1)), each scanned untextured, landmarked
  and registered onto mpeg4_80 like a user's scan (:class:`SfmPerson`); its poses are the model's
  six expression offsets carried exactly to the canonical vertices (SFM expressions do not depend
  on identity: B's truth is B + the same offsets). 5 pairs (persons 2k, 2k + 1) × 6 expressions.

A's library is transferred as Mimica holds it after an import: its poses smoothed over
``denoise.SMOOTHING_MM`` (``denoise.cleaned``, as ``library_from_scans`` and the built-in library do);
the truths are not smoothed.

Goal: a better method (``deformation``, ``fap_units`` or ``local_affine``) beats the thesis's
``bbox`` on synthetic and is no worse on SFM; the last lines say which goals are met, and on how many
of the (pair, pose) cases the method is closer to the truth than ``bbox`` (``wins=<k>/<n>``).

Caricature (``caricature_rms_mm e=<%> data=<d> value=<x>``): at −100 % the caricature must be the
mean face (RMS to the mean), at 0 % the face (RMS to the face); ``e=100`` gives how far the face
is from the mean (what +100 % adds). On SFM, ``e=-100`` is also measured against the model's true
mean (the mean face of 40 random identities estimates it: ``vs=model_mean``).

Corrective (``corrective_rms_mm fit=<fap_only|fap_corrective> at=<100|50> value=<x>``): B's rig
on its registered neutral, FAP values fitted to each registered expression scan at 100 %; the
residual becomes a corrective driven by those FAPs. ``at=100``: against the scan it was fitted to
(the corrective restores it by construction); ``at=50``: the FAPs at half the fitted values, with
the corrective at half weight, against B's true pose at 50 % intensity (held out).

Usage: python benchmarks/bench_transfer.py [--sfm PATH] [--quick]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from core.layers.blend.caricature import caricature, mean_face  # noqa: E402
from core.layers.blend.denoise import cleaned  # noqa: E402
from core.layers.blend.library import build_library, rigid_align  # noqa: E402
from core.layers.blend.transfer import (DeformationTransfer, LocalAffineTransfer, region_weights_of,  # noqa: E402
                                        transfer_bbox, transfer_fap_units)

METHODS = ("bbox", "deformation", "fap_units", "local_affine", "copy")   # copy: D_k unchanged (a reference)
PAIRS = ((1, 2), (2, 1), (1, 3), (3, 2))
SFM_DEFAULT = ROOT.parent / "shared" / "data" / "sfm"
SFM_SEED = 16
SFM_POSES = ("anger", "disgust", "fear", "joy", "sadness", "surprise")   # evaluate_landmarks_sfm's names


def rms(a, b) -> float:
    """RMS (mm) of the per-vertex distance between (..., n, 3) arrays."""
    return float(np.sqrt(np.mean(np.sum((np.asarray(a) - np.asarray(b)) ** 2, axis=-1))))


def rms_per_pose(a, b) -> np.ndarray:
    """(k,) RMS (mm) per pose of (k, n, 3) arrays."""
    return np.sqrt(np.mean(np.sum((np.asarray(a) - np.asarray(b)) ** 2, axis=-1), axis=-1))


def transfer(method: str, base_rest, disp, model_rest, triangles) -> np.ndarray:
    if method == "bbox":
        return transfer_bbox(base_rest, disp, model_rest)
    if method == "copy":
        return np.asarray(disp) @ rigid_align(model_rest, base_rest, robust=False)[1]
    if method == "deformation":
        return DeformationTransfer(base_rest, model_rest, triangles).transfer(disp)
    if method == "fap_units":
        return transfer_fap_units(base_rest, disp, model_rest, region_weights_of(model_rest, "mpeg4_80"))
    return LocalAffineTransfer(base_rest, model_rest).transfer(disp)


# ------------------------------------------------------------------ synthetic database
class Person:
    """A synthetic person: registered neutral and poses (canonical mpeg4_80), and the truth."""

    def __init__(self, person: int, poses, cache_dir=None):
        from core.layers.blend.pose_registration import register_pose
        from core.registration.pipeline import register_scan
        from core.registration.synthetic import synthetic_case

        self.person = person
        self.faces = {}
        for pose in ("neutral",) + tuple(poses):
            case = synthetic_case(person, pose, cache_dir=cache_dir)
            scan = case.face
            if pose == "neutral":
                self.faces[pose] = register_scan(scan, scan.landmarks, template="mpeg4_80").face
                self.scan_transform = case.transform
            else:   # as a library is built from a person's scans (core.layers.blend.scans)
                self.faces[pose] = register_pose(scan, scan.landmarks, self.faces["neutral"])
        self.neutral = self.faces["neutral"]
        self.library = cleaned(build_library(self.neutral, {p: self.faces[p] for p in poses}, template="mpeg4_80",
                                             base=f"synthetic person {person}"))
        self.truth = self.true_library(poses)

    def true_library(self, poses):
        """The person's library as the generator made it: each registered neutral vertex is bound to
        the closest point of the rig's neutral surface (undoing the scan's pose jitter), moved as the
        rig moves that point in each pose, and taken back into the scan's frame. Aligned like
        ``library`` (:func:`build_library`), so only the registration's sliding along the skin differs."""
        from core.registration import synthetic
        from core.registration.icp import apply_transform
        from core.surface_query import TriangleSet

        rig = synthetic._rig(self.person, 0)
        rig.reset_faps()
        rest = np.array(rig.vertices())
        T = np.asarray(self.scan_transform, float)
        in_rig = apply_transform(self.neutral.vertices, np.linalg.inv(T))
        _, tri, bary = TriangleSet(rest, rig.face.triangles).closest(in_rig)
        corners = rig.face.triangles[tri]                                        # (n, 3)
        posed = {}
        for pose in poses:
            rig.set_expression(pose, 1.0)
            moved = np.array(rig.vertices()) - rest
            disp = np.einsum("nc,ncd->nd", bary, moved[corners])                # rig frame
            posed[pose] = self.neutral.vertices + disp @ T[:3, :3].T             # scan frame
        rig.set_expression(None, 0.0)
        return build_library(self.neutral, posed, template="mpeg4_80", base=f"synthetic person {self.person} (truth)")

    def registered_pose(self, pose: str, intensity: float) -> np.ndarray:
        """(N, 3) mm: a new scan of the person at ``pose`` × ``intensity`` (FAP 2 preset), registered
        like the others and aligned onto the neutral (held-out data for the corrective)."""
        from core.layers.blend.pose_registration import register_pose
        from core.registration import synthetic
        from core.registration.virtual_scanner import scan_face

        rig = synthetic._rig(self.person, 0)
        rig.reset_faps()
        rig.set_expression(pose, intensity)
        v = np.array(rig.vertices())
        rig.set_expression(None, 0.0)
        rng = np.random.default_rng([0, self.person, synthetic.poses().index(pose), 50])
        scan = scan_face(rig.face, vertices=v, rng=rng, **synthetic.SCAN_SETTINGS).face
        face = register_pose(scan, scan.landmarks, self.neutral)
        return rigid_align(face.vertices, self.neutral.vertices)[0]


def synthetic_transfer(people, poses) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Per method, the RMS (mm) of A's transferred library against B's true library per (pair, pose),
    and the mean against B's registered one."""
    vs_truth = {m: [] for m in METHODS}
    vs_registered = {m: [] for m in METHODS}
    for a, b in PAIRS:
        A, B = people[a], people[b]
        tri = B.neutral.triangles
        for m in METHODS:
            d = transfer(m, A.library.rest, A.library.displacements, B.library.rest, tri)
            vs_truth[m].extend(rms_per_pose(d, B.truth.displacements))
            vs_registered[m].append(rms(d, B.library.displacements))
    return {m: np.array(v) for m, v in vs_truth.items()}, {m: float(np.mean(v)) for m, v in vs_registered.items()}


# ------------------------------------------------------------------ SFM
def load_sfm(folder: Path):
    mean = np.load(folder / "sfm_mean.npy").astype(float)
    basis = np.load(folder / "sfm_basis.npy").astype(float)
    ev = np.load(folder / "sfm_ev.npy").astype(float).reshape(-1)
    tri = np.load(folder / "sfm_tri.npy").astype(np.int64)
    names = ("anger", "disgust", "fear", "happiness", "sadness", "surprise")
    offsets = np.array([np.load(folder / f"bs_{n}.npy").astype(float) for n in names])
    return mean, basis, ev, tri, names, offsets


def sfm_identity(mean, basis, ev, rng) -> np.ndarray:
    alpha = rng.standard_normal(len(ev))
    return mean + (basis @ (alpha * np.sqrt(ev))).reshape(-1, 3)


class SfmPerson:
    """A Surrey Face Model identity registered like a scan, with its expressions carried exactly.

    Its neutral is scanned (untextured, frontal), landmarked (steered by the model's 21 ibug points,
    as face_quality's SFM identity) and registered onto mpeg4_80. Each canonical vertex is bound to
    the closest point of the model's neutral surface, and follows that point into each of SFM's six
    expressions (the model's blend shape added to this identity): the poses have no registration
    sliding, so the comparison measures the transfer alone."""

    def __init__(self, model, surface, person: int):
        import evaluate_landmarks_sfm as sfm
        from core.registration.icp import apply_transform
        from core.registration.pipeline import detect_landmarks, register_scan
        from core.surface_query import TriangleSet

        case = next(iter(sfm.make_scans(model, surface, person, SFM_SEED, [0.0], ["neutral"], textured=False)))
        landmarks = detect_landmarks(case.face, fixed=dict(case.face.landmarks)).landmarks
        self.neutral = register_scan(case.face, landmarks, template="mpeg4_80").face
        shape = sfm.identity(model, person, SFM_SEED)
        source = sfm.refine_vertices(model, surface, shape)
        in_source = apply_transform(self.neutral.vertices, np.linalg.inv(case.transform))
        _, tri, bary = TriangleSet(source, surface.triangles).closest(in_source)
        corners = surface.triangles[tri]
        poses = {}
        for pose in SFM_POSES:
            moved = sfm.refine_vertices(model, surface, shape + model.blendshapes[sfm.SFM_POSE.get(pose, pose)]) - source
            poses[pose] = self.neutral.vertices + np.einsum("nc,ncd->nd", bary, moved[corners]) @ case.transform[:3, :3].T
        self.truth = build_library(self.neutral, poses, template="mpeg4_80", base=f"SFM person {person}")
        self.library = cleaned(self.truth)


def sfm_transfer(folder: Path, pairs: int = 5) -> dict[str, np.ndarray]:
    """Per method, the RMS (mm) per (pair, pose) of A's transferred library against B's true one
    (SFM's expression offsets do not depend on identity: B's poses are B + the same offsets)."""
    import evaluate_landmarks_sfm as sfm

    model = sfm.load_sfm(folder)
    surface = sfm.refine_topology(model)
    out = {m: [] for m in METHODS}
    for k in range(pairs):
        A, B = SfmPerson(model, surface, 2 * k), SfmPerson(model, surface, 2 * k + 1)
        for m in METHODS:
            d = transfer(m, A.library.rest, A.library.displacements, B.library.rest, B.neutral.triangles)
            out[m].extend(rms_per_pose(d, B.truth.displacements))
    return {m: np.array(v) for m, v in out.items()}


def sfm_caricature(folder: Path, n: int = 40) -> list[str]:
    mean, basis, ev, *_ = load_sfm(folder)
    rng = np.random.default_rng(4)
    faces = [sfm_identity(mean, basis, ev, rng) for _ in range(n)]
    m = mean_face(faces)
    f = faces[0]
    lines = [f"caricature_rms_mm e=-100 data=sfm vs=mean_face value={rms(caricature(f, m, -1.0), rigid_align(m, f, robust=False)[0]):.2e}",
             f"caricature_rms_mm e=0 data=sfm vs=face value={rms(caricature(f, m, 0.0), f):.2e}",
             f"caricature_rms_mm e=100 data=sfm vs=face value={rms(caricature(f, m, 1.0), f):.3f}",
             f"caricature_rms_mm e=-100 data=sfm vs=model_mean n_faces={n} "
             f"value={rms(caricature(f, m, -1.0), rigid_align(mean, f, robust=False)[0]):.3f}"]
    return lines


# ------------------------------------------------------------------ corrective
def corrective_lines(B: Person, poses) -> list[str]:
    from core.layers.blend.corrective import Corrective, fit_faps
    from core.layers.fap.fat import FapDeformer

    deformer = FapDeformer(B.neutral)
    full_fap, full_corr, half_fap, half_corr = [], [], [], []
    for p in poses:
        fit = fit_faps(deformer, B.faces[p])
        full_fap.append(fit.rms_fap_only_mm)
        full_corr.append(fit.rms_with_corrective_mm)
        corr = Corrective.from_fit(p, fit)
        held_out = B.registered_pose(p, 0.5) - B.neutral.vertices
        half = 0.5 * fit.fap_only
        half_fap.append(rms(half, held_out))
        half_corr.append(rms(half + corr.weight(0.5 * fit.values) * corr.shape, held_out))
    return [f"corrective_rms_mm fit=fap_only at=100 data=synthetic value={np.mean(full_fap):.3f}",
            f"corrective_rms_mm fit=fap_corrective at=100 data=synthetic value={np.mean(full_corr):.2e}",
            f"corrective_rms_mm fit=fap_only at=50 data=synthetic value={np.mean(half_fap):.3f}",
            f"corrective_rms_mm fit=fap_corrective at=50 data=synthetic value={np.mean(half_corr):.3f}"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sfm", type=Path, default=SFM_DEFAULT, help="folder of the Surrey Face Model .npy files")
    parser.add_argument("--quick", action="store_true", help="one synthetic pair, two poses")
    parser.add_argument("--cache-dir", default=None, help="reuse synthetic scans from this folder (default: fresh ones)")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores, load {os.getloadavg()[0]:.2f}")
    from core.registration.synthetic import poses as all_poses

    poses = all_poses()[1:]
    global PAIRS
    if args.quick:
        PAIRS = ((1, 2),)
        poses = poses[:2]
    t0 = time.perf_counter()
    # Fresh scans in a private cache: the database's shared cache is keyed by its VERSION only, so
    # scans made before a change of the expression presets would otherwise be mixed with new ones.
    cache = tempfile.TemporaryDirectory(prefix="mimica_bench_transfer_") if args.cache_dir is None else None
    cache_dir = args.cache_dir or cache.name
    people = {p: Person(p, poses, cache_dir) for p in sorted({x for pair in PAIRS for x in pair})}
    print(f"scanned and registered {len(people)} synthetic people x {len(poses) + 1} poses in {time.perf_counter() - t0:.1f} s")
    syn_cases, syn_registered = synthetic_transfer(people, poses)
    syn = {m: float(v.mean()) for m, v in syn_cases.items()}
    for m, v in syn.items():
        print(f"transfer_rms_mm method={m} data=synthetic value={v:.3f}")
    for m, v in syn_registered.items():
        print(f"transfer_vs_registered_rms_mm method={m} data=synthetic value={v:.3f}")
    sliding = np.mean([rms(people[b].library.displacements, people[b].truth.displacements) for _, b in PAIRS])
    print(f"registration_sliding_rms_mm data=synthetic value={sliding:.3f} (B's registered, smoothed library vs its truth)")
    sfm = sfm_cases = None
    if (args.sfm / "sfm_mean.npy").exists():
        sfm_cases = sfm_transfer(args.sfm)
        sfm = {m: float(v.mean()) for m, v in sfm_cases.items()}
        for m, v in sfm.items():
            print(f"transfer_rms_mm method={m} data=sfm value={v:.3f}")
    else:
        print(f"sfm: no data in {args.sfm}; skipped")
    neutrals = [people[p].neutral.vertices for p in sorted(people)]
    m = mean_face(neutrals)
    f = neutrals[0]
    print(f"caricature_rms_mm e=-100 data=synthetic vs=mean_face value="
          f"{rms(caricature(f, m, -1.0), rigid_align(m, f, robust=False)[0]):.2e}")
    print(f"caricature_rms_mm e=0 data=synthetic vs=face value={rms(caricature(f, m, 0.0), f):.2e}")
    print(f"caricature_rms_mm e=100 data=synthetic vs=face value={rms(caricature(f, m, 1.0), f):.3f}")
    if sfm is not None:
        for line in sfm_caricature(args.sfm):
            print(line)
    for line in corrective_lines(people[PAIRS[0][1]], poses):
        print(line)
    for better in ("deformation", "fap_units", "local_affine"):
        ok_syn = syn[better] < syn["bbox"]
        ok_sfm = sfm is None or sfm[better] <= sfm["bbox"]
        wins = lambda cases: f"wins={int((cases[better] < cases['bbox']).sum())}/{cases['bbox'].size}"   # noqa: E731
        print(f"goal method={better}: beats bbox on synthetic {'met' if ok_syn else 'NOT met'} "
              f"({syn[better]:.3f} vs {syn['bbox']:.3f} mm, {100 * (syn[better] / syn['bbox'] - 1):+.1f} %, {wins(syn_cases)}); "
              "no worse on sfm " + ("skipped" if sfm is None else f"{'met' if ok_sfm else 'NOT met'} "
                                    f"({sfm[better]:.3f} vs {sfm['bbox']:.3f} mm, {wins(sfm_cases)})"))
    print(f"total {time.perf_counter() - t0:.1f} s")
    if cache is not None:
        cache.cleanup()


if __name__ == "__main__":
    main()
