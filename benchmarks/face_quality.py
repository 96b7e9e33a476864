"""Does the face hold up at every slider value? (issue 18 item 4)

Sweeps, per identity, every animated FAP to both ends of its slider range, every expression and
viseme preset at 100 %, every expression mixed with every viseme (speech with emotion) at 100 %,
thesis C's muscle presets and the poses of the face's built-in expression library (blend layer) at
100 % where it has one, and measures each pose with :class:`core.mesh_quality.FaceQualityProbe`:
lip / lid / teeth / mouth-cavity intersections, folded triangles, the largest texture stretch and smallest squeeze,
and for lid-closing FAPs at their maximum whether the eye is closed. Prints per pose

    <identity> <pose>: lip=<n> lid=<n> teeth=<n> cavity=<n> [at_rest=lip:<k>,...] folds=<n> stretch=<x> squeeze=<x> [eye=<%>] OK|FAIL <why>

(``at_rest``: how many of those crossing pairs the rest face has already — a registered scan's own
closed lips and nose creases; 0 on Mimica's faces. They fail the neutral pose; any other pose fails
on the pairs it makes cross, as the sliders' crossing limits count them: ``limits.new_crossings``.)

then per identity the totals over its poses (which failures dominate)

    <identity> totals: lip=<n> lid=<n> teeth=<n> cavity=<n> folds=<n> stretched_poses=<k> squeezed_poses=<k> open_eyes=<k>

and ``<identity>: failures=<k>/<poses> (<s> s)``, and at the end

    quality_failures=<n>

(the failing poses over all identities; goal 0). Identities: the default face; a generated identity
of other proportions (Mimica's generator, seed 7); and, when ``../shared/data/sfm`` is present, a
Surrey Face Model identity (a face made by others): a virtual scan of it, registered and animated as
the window animates a scan (``sfm``: the scan itself at full resolution, lips cut, mouth parts added,
moved through its canonical face by the registration's binding), or its canonical face alone
(``sfm-canonical``: the registration's intermediate mesh, shown only when a scan cannot be cut).

``--clean-ranges`` also prints, per FAP and identity, how much of each end of its slider range the
surface survives alone (no fold, stretch within limits; intersections not counted), by bisection on
the FAP's linear displacement field:

    <identity> clean fap <n> <name>: min=<%> max=<%>

Contact sheets (front + three-quarter, by ``app.render``) go to ``--sheets DIR`` (default
``/tmp/mimica-face-quality``), one PNG per identity and pose family; ``--no-sheets`` skips them.

``--families expressions visemes`` keeps only the poses of those families (faps, expressions,
visemes, mixes, muscles, blends; the neutral pose is in expressions).

Usage: python benchmarks/face_quality.py [--identities default generated sfm sfm-canonical] [--no-mixes]
       [--no-muscles] [--no-blends] [--families F ...] [--clean-ranges] [--sheets DIR | --no-sheets] [--tile PX]
       [--sheet-format jpg]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "scripts"))

SFM_DIR = ROOT.parent / "shared" / "data" / "sfm"
# Lid-closing FAPs and the eye each one must close at its maximum (close_t_l/r_eyelid).
CLOSING_LIDS = {19: "left", 20: "right"}
FAMILIES = ("faps", "expressions", "visemes", "mixes", "muscles", "blends")


IDENTITIES = ("default", "generated", "sfm", "sfm-canonical")
# MPEG-4 lid centres from the ibug points either side of the pupil on each lid (``ibug_to_sfm.txt``:
# 38/39 and 41/42 are the right eye's upper and lower lid, 44/45 and 47/48 the left eye's).
SFM_LID_IBUG = {"3.1": (44, 45), "3.3": (47, 48), "3.2": (38, 39), "3.4": (41, 42)}


def identity_rig(name: str):
    """The FaceRig of an identity name (see the module docstring)."""
    from core.default_face import generate_face, load_default_face
    from core.default_face.params import FaceParameters
    from core.rig import FaceRig

    if name == "default":
        return FaceRig(load_default_face())
    if name == "generated":
        return FaceRig(generate_face(FaceParameters.random(np.random.default_rng(7), spread=0.8)))
    if name in ("sfm", "sfm-canonical"):
        from core.layers.fap.fat import FapDeformer
        from core.registration.scan_mouth import animated_scan

        registration = sfm_registration()
        if name == "sfm-canonical":
            return FaceRig(registration.face)
        # What the window shows and animates for a scan (scan_mouth.scan_animation builds the same
        # deformer and leaves it in the disk cache for the window's rig).
        scan = animated_scan(registration)
        return FaceRig(scan.face, FapDeformer(scan.face, dense=scan.dense, binding=scan.binding()))
    raise SystemExit(f"unknown identity {name!r}: choose one of {', '.join(IDENTITIES)}")


def sfm_registration():
    """The registered virtual scan of a Surrey Face Model identity (person 1, seed 0, neutral)."""
    import evaluate_landmarks_sfm as sfm
    from core.registration.pipeline import detect_landmarks, register_scan
    from core.registration.synthetic import poses

    model = sfm.load_sfm(SFM_DIR)
    surface = sfm.refine_topology(model)
    case = next(iter(sfm.make_scans(model, surface, 1, 0, [0.0], [list(poses())[0]], textured=False)))
    # The model's truth has 21 points, and its lid centres: the middle of its two ibug points on each
    # lid (its eyes have no relief, so detection can only guess them: a lid 5 mm off closes the eye or
    # puts the eyeball's opening on the cheek). Detection finds the rest, steered by them (as
    # bench_correspondence).
    fixed = dict(case.face.landmarks)
    shape = sfm.refine_vertices(model, surface, sfm.identity(model, 1, 0))
    frame = case.transform[:3, :3], case.transform[:3, 3]
    for name, (a, b) in SFM_LID_IBUG.items():
        middle = (shape[model.ibug[a]] + shape[model.ibug[b]]) / 2 @ frame[0].T + frame[1]
        fixed[name] = case.face.surface_point(middle)
    landmarks = detect_landmarks(case.face, fixed=fixed).landmarks
    return register_scan(case.face, landmarks)


Pose = tuple[str, str, Callable, tuple[str, ...]]   # family, label, apply(rig), eyes that must close


def fap_poses(rig) -> Iterator[Pose]:
    from core.layers.fap import tables

    for number in rig.animated_faps:
        if number <= 2:
            continue
        spec = tables.fap_spec(number)
        lo, hi = spec.minimum, spec.maximum
        if not np.isfinite(lo) or not np.isfinite(hi):
            continue
        for value in sorted({lo, hi} - {0.0}):
            closes = (CLOSING_LIDS[number],) if number in CLOSING_LIDS and value == hi else ()
            yield ("faps", f"fap {number} {spec.name}={value:g}",
                   lambda r, n=number, x=value: r.set_fap(n, x), closes)


def preset_poses(rig, mixes: bool) -> Iterator[Pose]:
    from core.layers.fap import tables

    expressions = tables.expression_names()[1:]
    visemes = tables.viseme_names()[1:]
    for e in expressions:
        yield "expressions", e, lambda r, e=e: r.set_expression(e, 1.0), ()
    for v in visemes:
        yield "visemes", f"viseme {v}", lambda r, v=v: r.set_viseme(v, 1.0), ()
    if mixes:
        for e in expressions:
            for v in visemes:
                yield ("mixes", f"{e} + viseme {v}",
                       lambda r, e=e, v=v: (r.set_expression(e, 1.0), r.set_viseme(v, 1.0)), ())


def muscle_poses(rig) -> Iterator[Pose]:
    from core.layers.muscles import preset, preset_names

    rig.ensure_layers(["muscle:risorius:left"])
    layer = rig.layer("muscles")
    for name in preset_names():
        def apply(r, p=preset(name)):
            layer.apply(p)
            layer.solve()
            r.touch()
        yield "muscles", f"muscles {preset(name).name}", apply, ()


def blend_poses(rig) -> Iterator[Pose]:
    """The poses of the face's built-in expression library at 100 % (none when it has no library)."""
    rig.ensure_layers(["blend:joy"])
    layer = rig.layer("blend")
    for pose in (layer.poses if layer is not None else ()):
        yield "blends", f"blend {pose}", lambda r, k=f"blend:{pose}": r.set_values({k: 100.0}), ()


def clean_ranges(name: str, rig, probe) -> None:
    """Print the share of each FAP's slider ends the surface survives (see the module docstring)."""
    from core.layers.fap import tables

    deformer = rig.deformer
    rest = rig.face.vertices
    columns = deformer.matrix.tocsc()
    for number in rig.animated_faps:
        spec = tables.fap_spec(number)
        if number <= 2 or spec.is_rotation:
            continue
        field = columns[:, number - 1].toarray().reshape(-1, 3) * deformer.fapu_vector[number - 1]
        shares = []
        for end in (spec.minimum, spec.maximum):
            if end == 0:
                shares.append("-")
                continue
            lo, hi = 0.0, 1.0
            if probe.surface_holds(rest + field * end):
                lo = 1.0
            for _ in range(10 if lo < 1.0 else 0):
                mid = (lo + hi) / 2
                lo, hi = (mid, hi) if probe.surface_holds(rest + field * end * mid) else (lo, mid)
            shares.append(f"{100 * lo:.0f}%")
        print(f"{name} clean fap {number} {spec.name}: min={shares[0]} max={shares[1]}", flush=True)


def run_identity(name: str, args) -> tuple[int, int]:
    from core.mesh_quality import MAX_STRETCH, MIN_STRETCH, FaceQualityProbe

    t0 = time.perf_counter()
    rig = identity_rig(name)
    face = rig.face
    probe = FaceQualityProbe(face)
    if args.clean_ranges:
        clean_ranges(name, rig, probe)
    poses: list[Pose] = [("expressions", "neutral", lambda r: None, ())]
    poses += list(fap_poses(rig)) + list(preset_poses(rig, args.mixes))
    if args.muscles:
        poses += list(muscle_poses(rig))
    if args.blends:
        poses += list(blend_poses(rig))
    if args.families:
        poses = [p for p in poses if p[0] in args.families]
    failures = 0
    totals = dict.fromkeys(("lip", "lid", "teeth", "cavity", "folds", "stretched_poses", "squeezed_poses", "open_eyes"), 0)
    sheets: dict[str, list] = {}
    for family, label, apply, closes in poses:
        rig.reset()
        muscles = rig.layer("muscles")
        if muscles is not None:
            # Zero forces leave the tissue where the last preset pulled it until it settles again
            # (the window's timer relaxes it): back at rest, or every later pose carries it (after the
            # muscle presets, the library's poses stretched 2.0-2.2x and joy crossed its lips).
            muscles.reset()
        apply(rig)
        vertices = rig.vertices()
        q = probe.measure(vertices, eyes=bool(closes))
        # A registered scan may cross itself at rest: that fails its neutral pose, once; every other
        # pose fails on the crossings it makes.
        why = q.failures(eyes_closed=closes, count_rest=label == "neutral")
        failures += bool(why)
        for key, value in (("lip", q.lip_intersections), ("lid", q.lid_intersections),
                           ("teeth", q.teeth_intersections), ("cavity", q.cavity_intersections),
                           ("folds", q.folded_triangles),
                           ("stretched_poses", q.max_stretch > MAX_STRETCH),
                           ("squeezed_poses", q.min_stretch < MIN_STRETCH),
                           ("open_eyes", any("open, should be closed" in w for w in why))):
            totals[key] += int(value or 0)
        eye = "".join(f" eye_{s}={100 * q.eye_openness[s]:.0f}%" for s in closes if s in q.eye_openness)
        counts = " ".join(f"{k}={'-' if v is None else v}" for k, v in (
            ("lip", q.lip_intersections), ("lid", q.lid_intersections), ("teeth", q.teeth_intersections),
            ("cavity", q.cavity_intersections)))
        if q.at_rest:
            counts += " at_rest=" + ",".join(f"{k.replace(' ', '_')}:{v}" for k, v in q.at_rest.items())
        print(f"{name} {label}: {counts} folds={q.folded_triangles} stretch={q.max_stretch:.2f} "
              f"squeeze={q.min_stretch:.2f}{eye} {'FAIL ' + '; '.join(why) if why else 'OK'}", flush=True)
        if args.sheets:
            from app.render import render_face_image

            views = [render_face_image(face.with_vertices(vertices), view=v, size=(480, 480))
                     for v in ("front", "three-quarter")]
            sheets.setdefault(family, []).append((("FAIL " if why else "") + label, views))
    if args.sheets:
        from readme_figures import sheet

        args.sheets.mkdir(parents=True, exist_ok=True)
        for family, rows in sheets.items():
            path = args.sheets / f"{name}_{family}.{args.sheet_format}"
            sheet(rows, columns=4, tile=args.tile).save(path, quality=85)
        print(f"{name}: contact sheets in {args.sheets}", flush=True)
    print(f"{name} totals: " + " ".join(f"{k}={v}" for k, v in totals.items()), flush=True)
    print(f"{name}: failures={failures}/{len(poses)} ({time.perf_counter() - t0:.0f} s)", flush=True)
    return failures, len(poses)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--identities", nargs="+", choices=IDENTITIES, default=["default", "generated", "sfm"])
    parser.add_argument("--no-mixes", dest="mixes", action="store_false")
    parser.add_argument("--no-muscles", dest="muscles", action="store_false")
    parser.add_argument("--no-blends", dest="blends", action="store_false")
    parser.add_argument("--families", nargs="+", choices=FAMILIES, help="only the poses of these families")
    parser.add_argument("--clean-ranges", action="store_true")
    parser.add_argument("--sheets", type=Path, default=Path("/tmp/mimica-face-quality"))
    parser.add_argument("--no-sheets", dest="sheets", action="store_const", const=None)
    parser.add_argument("--tile", type=int, default=240, help="pixels per view in the contact sheets")
    parser.add_argument("--sheet-format", choices=("png", "jpg"), default="png")
    args = parser.parse_args()
    for name in ("sfm", "sfm-canonical"):
        if name in args.identities and not SFM_DIR.is_dir():
            print(f"{name}: skipped ({SFM_DIR} not found)")
            args.identities.remove(name)
    total = 0
    for name in args.identities:
        total += run_identity(name, args)[0]
    print(f"quality_failures={total}")


if __name__ == "__main__":
    main()
