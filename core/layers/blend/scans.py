"""A person's expression scans → an expression library (issue 16 item 2, the core of the import).

Each scan (a Face in mm) is landmarked automatically (``detect_landmarks``), unless the caller
passes landmarks for it (the user's corrections from the landmark picker), registered to the
template: the neutral by ``register_scan`` (subdivision + projection), each pose by moving the
registered neutral onto it (``pose_registration.register_pose``, so vertex i stays on the same skin
point across poses), and the poses are aligned rigidly onto the neutral before their displacements
are taken (``build_library``), and the registration's noise is smoothed out of the poses over
``SMOOTHING_MM`` (``denoise.cleaned``, as in the built-in library: raw, its half-millimetre wobble
crossed lids and lips at 100 %). The summary says, per scan,
where its landmarks came from and which detected ones have low confidence (worth correcting in
the picker before trusting the pose).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

from core.layers.blend.denoise import SMOOTHING_MM, check_smoothing_width, cleaned
from core.layers.blend.library import ExpressionLibrary, LibraryError, build_library, check_pose_name

__all__ = ["ScanReport", "library_from_scans"]


@dataclass(frozen=True)
class ScanReport:
    """One scan of the import: pose name ("neutral" for the rest), landmark source ("detected" or
    "given"), low-confidence landmark names (detected only), projection fallbacks."""

    pose: str
    landmarks: str
    low_confidence: tuple[str, ...] = ()
    fallbacks: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def needs_correction(self) -> bool:
        return bool(self.low_confidence)

    def line(self) -> str:
        low = f"; check {len(self.low_confidence)} landmark(s): {', '.join(self.low_confidence[:8])}" \
            if self.low_confidence else ""
        return f"{self.pose}: landmarks {self.landmarks}{low}; {self.fallbacks} projection fallbacks"


def library_from_scans(neutral, poses: Mapping[str, object], *, template: str = "mpeg4_80",
                       landmarks: Mapping[str, Mapping] | None = None, base: str = "",
                       progress: Callable[[float, str], None] | None = None,
                       smoothing_mm: float = SMOOTHING_MM) -> tuple[ExpressionLibrary, list[ScanReport]]:
    """(library, per-scan reports) from a neutral scan and {pose name: scan} (Faces in mm).

    landmarks : {pose name or "neutral": {landmark: SurfacePoint or (3,) mm}} for scans whose
        landmarks the user gave or corrected (not detected again).
    smoothing_mm : width of the poses' smoothing (``denoise.cleaned``); 0 keeps them as registered.
    Raises LibraryError (bad pose names, smoothing width) or the registration's own ValueErrors, naming the pose.
    """
    from core.layers.blend.pose_registration import register_pose
    from core.registration.pipeline import detect_landmarks, register_scan

    check_smoothing_width(smoothing_mm)       # before minutes of registration, not after
    given = dict(landmarks or {})
    names = [check_pose_name(n) for n in poses]
    scans = [("neutral", neutral)] + list(zip(names, poses.values()))
    faces, reports = {}, []
    for i, (name, scan) in enumerate(scans):
        if progress is not None:
            progress(i / len(scans), f"registering {name}")
        try:
            if name in given:
                lms, source, low = given[name], "given", ()
            else:
                det = detect_landmarks(scan, template=template)
                lms, source, low = det.landmarks, "detected", tuple(det.low_confidence())
            if name == "neutral":
                reg = register_scan(scan, lms, template=template)
                faces[name], fallbacks = reg.face, int(reg.fallbacks)
            else:
                faces[name], fallbacks = register_pose(scan, lms, faces["neutral"], template=template), 0
        except ValueError as exc:
            raise LibraryError(f"scan of pose {name!r}: {exc}") from None
        reports.append(ScanReport(name, source, low, fallbacks))
    if progress is not None:
        progress(1.0, "building the library")
    lib = build_library(faces["neutral"], {n: faces[n] for n in names}, template=template, base=base)
    return cleaned(lib, smoothing_mm), reports
