"""The built-in expression library of the default face, and its builder.

Made through the real pipeline, not copied from the FAP presets' displacements:

1. the default face is posed by each preset (the six expressions of FAP 2 and the 14 visemes of
   FAP 1, at full intensity) and *scanned* by the virtual scanner with the synthetic database's
   settings (``core.registration.synthetic.SCAN_SETTINGS``: depth noise, pose jitter, resampling);
2. each scan is landmarked automatically (``detect_landmarks``, template mpeg4_80); when the
   detection reports trouble or lands far from the scanner's known truth, the scan's ground-truth
   landmarks stand in for the user's correction in the picker, and the summary says which;
3. each scan is registered by moving the registered default face onto it
   (``pose_registration.register_pose``: landmarks, a biharmonic spread, closest points), aligned
   rigidly onto the registered default face, and D_k = pose − neutral (``build_library``);
4. the mean face (for the ``caricature`` slider) is the mean of the registered neutral default face
   and synthetic identities 1..8 of the protocol database (``core.registration.synthetic``).

Open-mouth poses used to look crooked (lower lip sagging and lumpy, teeth over it in three-quarter
view). Measured against the FAP preset each pose is scanned from: each pose was registered afresh
(``register_scan``), which spreads the canonical vertices differently over a lower lip that curls
when the jaw drops; the middle of the lower lip's band landed on skin up to 5.7 mm lower than in
the neutral, and D_k took that slide for motion (surprise: lower-lip error rms 2.09 mm, the band's
middle 2.3 mm too low and 1.3 mm too far in). Registering each pose from the neutral keeps the
vertices on their skin (lower-lip rms 1.61 mm, max 3.95 mm; the band's middle 0.9 mm low). What is
left sits on the inner lip contour, which the scanner does not see when the mouth is open (its
landmark lands about 2.4 mm off on the visible lip), and on landmarks the detector puts 1-3 mm off.
Not fixed: joy tears the outer eye corners of the default face (eye-region error rms 1.9 mm; it
was 1.6 mm, with torn lower lids, before).

5. the poses are smoothed over ``SMOOTHING_MM`` (``core.layers.blend.denoise.cleaned``, as a user's imported
   scans are):
   as registered, their half-millimetre wobble crossed lids and lips and folded the nostrils at
   100 % (every pose failed ``benchmarks/face_quality.py``), and the covers of the eye openings,
   registered on the eyeballs, fed noise through deformation transfer into another face's lid margins.
   With the FAP layer's lid guard acting on blend poses too, joy's eye corners no longer tear.
   Rebuilt after the FAP presets were corrected, the rim of the eyeball's cap (0.01 mm behind the
   skin at the outer corners) cut the skin there (joy 7, anger 9, sadness 4, disgust 14 crossing
   pairs); with the rim tucked behind the skin (``core.default_face.build.RIM_CLEARANCE_MM``) no
   lid/eyeball pair but disgust's (12 after the FAT binding's smoothing, on the left eye; joy keeps
   3 pairs of lower-lid skin): the skin's steep triangles (4.5-4.9 mm long over a 0.65 mm grid
   cell) where the lid's drape falls off the ball beside the outer corner come down onto the ball's
   last bands, 70-78 degrees off its axis.

The neutral is the default face itself registered with its own landmarks, so the library's rest
(4560 vertices, template mpeg4_80) is in the default face's frame. The default face (53k vertices)
uses it through :func:`builtin_library_for`, which binds its vertices to that canonical face.

Build: ``python -m core.layers.blend.builtin`` writes ``resources/blend/default_face.json`` + ``.npz``.
"""

from __future__ import annotations

import functools
import sys
import time

import numpy as np

from core.layers.blend.denoise import SMOOTHING_MM, cleaned
from core.layers.blend.library import ExpressionLibrary, build_library

__all__ = ["RESOURCE", "builtin_library", "builtin_library_for", "build_builtin_library", "main"]

RESOURCE = "blend/default_face.json"
TEMPLATE = "mpeg4_80"
# A detected landmark further than this from the truth counts as "needed correction" (the picker's
# work a careful user does). At 3 mm the mouth corners of joy stayed 1.9 mm off: the poses' feature
# points moved 20-30 % less than the presets scanned (joy's corners 5.4 of 7.1 mm before smoothing,
# surprise's outer brows 6.5 of 9.2), rms error against the presets 0.69 mm over the 20 poses
# smoothed (1.0 mm: 0.49 mm; failing library poses in face_quality unchanged, 1 per identity).
LANDMARK_TOLERANCE_MM = 1.0


@functools.lru_cache(maxsize=1)
def builtin_library() -> ExpressionLibrary | None:
    """The built-in library (None when the resource is not installed)."""
    import resources
    from core.formats.blend_library import read_library

    try:
        p = resources.path(RESOURCE)
    except FileNotFoundError:
        return None
    return read_library(p, template=TEMPLATE)


#: Parts that do not follow the skin: eyeballs and upper teeth stay with the skull, the mouth cavity
#: stays (the lips open over it); the lower teeth follow the chin (see :func:`bind_face`).
STILL_PARTS = ("eyeball_l", "eyeball_r", "teeth_upper", "mouth_cavity")
CHIN_POINT, CHIN_RADIUS_MM = "2.10", 12.0


def _lower_teeth_rows(m, parts, canonical_vertices, template: str):
    """Rows of ``m`` (lil) for the lower teeth: the mean of the canonical vertices near the chin."""
    from core.registration.templates import get_template

    lower = parts.get("teeth_lower", ())
    if len(lower):
        chin = canonical_vertices[get_template(template).base.index(CHIN_POINT)]
        jaw = np.flatnonzero(np.linalg.norm(canonical_vertices - chin, axis=1) < CHIN_RADIUS_MM)
        for i in lower:
            m.rows[i], m.data[i] = list(jaw), [1.0 / len(jaw)] * len(jaw)
    return m


def rig_correspondence(deformer, n_library: int, template: str = TEMPLATE):
    """(n_face, N) sparse map from canonical vertices to the face's, from the face's FAP deformer:
    its dense template *is* the face's canonical face (same template, same subdivision), and its
    binding already keeps upper and lower lips apart and leaves the eyeballs, teeth and mouth cavity
    alone; the lower teeth are added to follow the chin. None when the deformer's dense template is
    not of ``template`` with ``n_library`` vertices."""
    import scipy.sparse

    from core.registration.correspondence import canonical_triangles

    dense = getattr(deformer, "dense", None)
    binding = getattr(deformer, "binding", None)
    if dense is None or binding is None or len(dense.vertices) != n_library:
        return None
    if not np.array_equal(dense.triangles, canonical_triangles(template)):
        return None
    m = scipy.sparse.csr_matrix(binding)
    follow = getattr(deformer, "cavity_follow", None)
    if follow is not None and deformer.face is not None:
        # The mouth cavity's lining follows the skin the pose moves, as it follows the FAPs' (held
        # still, skin moved inward by a pose passed through it: default face 618 crossing pairs).
        m = m + follow() @ m
    m = _lower_teeth_rows(m.tolil(), getattr(deformer.face, "parts", {}) or {}, dense.vertices, template)
    return scipy.sparse.csr_matrix(m)


def bind_face(face, canonical_vertices, template: str = TEMPLATE):
    """(n_face, N) sparse map from a registered canonical face's vertices (N, 3) mm to ``face``'s
    when no FAP deformer is at hand: skin vertices move with their closest canonical surface point
    (``bind_scan``; lips that touch may catch each other's motion), the parts in
    :data:`STILL_PARTS` do not move, the lower teeth follow the chin."""
    import scipy.sparse

    from core.face import Face
    from core.registration.correspondence import bind_scan, canonical_triangles

    canonical = Face(np.asarray(canonical_vertices, float), canonical_triangles(template))
    m = bind_scan(face, canonical).matrix.tolil()
    parts = getattr(face, "parts", {}) or {}
    for name in STILL_PARTS:
        for i in parts.get(name, ()):
            m.rows[i], m.data[i] = [], []
    return scipy.sparse.csr_matrix(_lower_teeth_rows(m, parts, canonical.vertices, template))


@functools.lru_cache(maxsize=2)
def _binding_for_default(key: str):
    from core.default_face import load_default_face

    return bind_face(load_default_face(), builtin_library().rest)


def builtin_library_for(face, deformer=None, method: str = "deformation"):
    """(library, correspondence or None) of the built-in library for ``face``, or None when it does
    not fit: the default face (through its FAP ``deformer``'s binding when given, else bound to the
    library's canonical face), that canonical face itself, or any face whose FAP ``deformer`` has an
    mpeg4_80 dense template: the library is transferred onto it by ``method`` (its ``transfer``
    field says which)."""
    lib = builtin_library()
    if lib is None:
        return None
    v = np.asarray(face.vertices)
    if v.shape == lib.rest.shape and np.allclose(v, lib.rest, atol=1e-3):
        return lib, None
    from core.default_face import load_default_face

    default = load_default_face()
    if v.shape == default.vertices.shape and np.array_equal(v, default.vertices):
        m = rig_correspondence(deformer, lib.n_vertices) if deformer is not None else None
        return lib, (m if m is not None else _binding_for_default("default"))
    m = rig_correspondence(deformer, lib.n_vertices) if deformer is not None else None
    if m is None:
        return None
    # Another face with a FAP rig: its dense template is its canonical face; move the library onto it.
    return transferred_to(lib, deformer.dense.vertices, method, region_weights=deformer.template_weights), m


def transferred_to(library: ExpressionLibrary, canonical_vertices, method: str = "deformation", *,
                   region_weights: dict | None = None) -> ExpressionLibrary:
    """``library`` transferred (``core.layers.blend.transfer``) onto a canonical face (N, 3) mm of its
    template; the library itself when that face is its rest already. ``region_weights``: the face's
    FAP region weights on that canonical face (its rig's ``deformer.template_weights``), for
    "fap_units" (measured when not given)."""
    from core.layers.blend.transfer import transfer_library
    from core.registration.correspondence import canonical_triangles

    v = np.asarray(canonical_vertices, float)
    if method == "deformation" and v.shape == library.rest.shape and np.allclose(v, library.rest, atol=1e-3):
        return library
    return transfer_library(library, v, canonical_triangles(library.template if library.template != "custom"
                                                            else TEMPLATE), method=method, region_weights=region_weights)


def _scan_and_register(rig, preset: str, name, index: int, report, neutral, *, detect: bool = True):
    from core.layers.blend.pose_registration import register_pose
    from core.registration.pipeline import detect_landmarks
    from core.registration.synthetic import SCAN_SETTINGS
    from core.registration.virtual_scanner import scan_face

    rig.reset_faps()
    if preset == "expression":
        rig.set_expression(name, 1.0)
    else:
        rig.set_viseme(name, 1.0)
    verts = np.array(rig.vertices())
    rig.reset_faps()
    rig.set_expression(None, 0.0)
    rig.set_viseme(None, 0.0)
    result = scan_face(rig.face, vertices=verts, rng=np.random.default_rng([16, index]), **SCAN_SETTINGS)
    scan = result.face
    truth = {n: scan.landmark_position(n) for n in scan.landmark_names}
    landmarks = truth
    note = "ground-truth landmarks"
    if detect:
        try:
            det = detect_landmarks(scan, template=TEMPLATE)
            found = {n: np.asarray(p, float) for n, p in _positions(scan, det.landmarks).items()}
            far = [n for n in found if n in truth and np.linalg.norm(found[n] - truth[n]) > LANDMARK_TOLERANCE_MM]
            from core.registration.templates import get_template

            missing = [n for n in get_template(TEMPLATE).base.feature_points if n not in found and n in truth]
            if far or missing:
                landmarks = {**found, **{n: truth[n] for n in far + missing}}
                note = f"automatic; {len(far) + len(missing)} landmark(s) corrected ({', '.join((far + missing)[:6])})"
            else:
                landmarks = found
                note = "automatic, no correction"
        except Exception as exc:  # noqa: BLE001 - a failed detection is corrected by hand (the truth)
            note = f"automatic detection failed ({exc}); all landmarks corrected"
    report(f"{preset} {name}: {note}")
    return register_pose(scan, landmarks, neutral, template=TEMPLATE)


def _positions(scan, landmarks) -> dict:
    from core.registration.correspondence import landmark_positions_on

    return landmark_positions_on(scan, dict(landmarks))


def build_builtin_library(*, detect: bool = True, mean_people: int = 8, smoothing_mm: float = SMOOTHING_MM,
                          report=print) -> ExpressionLibrary:
    """Scan, landmark, register the default face's 6 expressions and 14 visemes; the library, with
    the mean face of the default face and ``mean_people`` synthetic identities (caricatures), its
    poses smoothed over ``smoothing_mm`` (:func:`cleaned`; 0 keeps them as registered)."""
    from core.default_face import load_default_face
    from core.layers.fap import tables
    from core.registration.pipeline import register_scan
    from core.rig import FaceRig

    face = load_default_face(full_head=False)   # scanned like the synthetic database: the front only
    neutral = register_scan(face, face.landmarks, template=TEMPLATE).face
    rig = FaceRig(face)
    poses = {}
    index = 0
    for name in tables.expression_names()[1:]:
        index += 1
        poses[name] = _scan_and_register(rig, "expression", name, index, report, neutral, detect=detect)
    for vid in range(1, len(tables.viseme_phonemes())):
        index += 1
        poses[f"viseme_{vid}"] = _scan_and_register(rig, "viseme", vid, index, report, neutral, detect=detect)
    mean = None
    if mean_people > 0:
        from core.layers.blend.caricature import mean_face
        from core.registration.synthetic import synthetic_scan

        faces = [neutral.vertices]
        for person in range(1, int(mean_people) + 1):
            scan = synthetic_scan(person, "neutral")
            faces.append(register_scan(scan, scan.landmarks, template=TEMPLATE).face.vertices)
        mean = mean_face(faces)          # in the first face's (the default face's) frame
        report(f"mean face: the default face and synthetic people 1..{mean_people} (registered neutrals)")
    library = build_library(neutral, poses, template=TEMPLATE, mean=mean,
                            base="default face (virtual scans, registered with mpeg4_80)")
    return cleaned(library, smoothing_mm)


def main(argv=None) -> int:
    import argparse

    import resources
    from core.formats.blend_library import write_library

    parser = argparse.ArgumentParser(description="Build the default face's built-in expression library.")
    parser.add_argument("--no-detect", action="store_true", help="use the scans' ground-truth landmarks")
    parser.add_argument("--mean-people", type=int, default=8, help="synthetic identities in the mean face (default 8)")
    parser.add_argument("--smoothing-mm", type=float, default=SMOOTHING_MM,
                        help=f"width of the poses' smoothing (default {SMOOTHING_MM:g}; 0: as registered)")
    parser.add_argument("--out", default=None, help="output .json (default: resources/blend/default_face.json)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    lib = build_builtin_library(detect=not args.no_detect, mean_people=args.mean_people, smoothing_mm=args.smoothing_mm)
    from pathlib import Path

    out = Path(args.out) if args.out is not None else Path(str(resources._ROOT)) / RESOURCE
    out.parent.mkdir(parents=True, exist_ok=True)
    path = write_library(lib, out)
    print(f"wrote {path} ({len(lib.names)} poses, {lib.n_vertices} vertices) in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
