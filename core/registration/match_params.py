"""The matcher's parameters (thesis A ch. 3 weights, radii and thresholds) and its error."""

from __future__ import annotations

from dataclasses import dataclass


# One HK map per scan serves both the HK appearance term and the Colombo seeds, which need the
# coarser 5 mm smoothing (curvature.colombo_seed_vertices); computing both would cost ~1 s more.
HK_SMOOTHING_MM = 5.0


class MatchingError(ValueError):
    """Matching cannot run (bad parameters, no candidates)."""


@dataclass(frozen=True)
class MatchParams:
    """Parameters of the structural matcher. λ's as in thesis A (3.1, 3.2, 3.4).

    lam : λ, appearance (1) vs structure (0).
    lam_a : λ_A, texture colour (1) vs HK class colour (0).
    lam_s : λ_S, edge angle (1) vs edge length (0).
    candidates, quality, min_distance_px : Shi-Tomasi n, l, d.
    radius : candidate search radius around the predicted position, × face scale (0 = no limit).
    position_weight : weight w of the distance-to-prediction cost (0 = the thesis cost).
    propagate : unmatched G_d vertices follow the matched ones.
    seeds : match the Colombo seeds first.
    refine : patch refinement on the scan surface; refine_radius × face scale; patch_mm side.
    pixel_mm : frontal raster pixel size.
    mouth_opening : put inner-lip points on the edges of a visible mouth opening (depth steps).
    steep_prediction : points on steep sides follow the confident matches (see the module docstring).
    lid_depth : a doubtful upper-lid point goes to the foot of the lid's depth fall (module docstring).
    brows : brow tops and outer ends placed on the brow band or ridge (``brow_pass``).
    eyes : each eye found as a whole by its shape; closed eyes' points on the lid line (``eye_pass``).
    outliers : a weak point far from where the confident matches put it follows them (``outlier_pass``).
    ambiguity : a patch match that fits as well elsewhere (flat evidence) is reported low confidence
        (``ambiguity``; the reported confidence only, positions unchanged).
    """

    lam: float = 0.0     # sweep on 3 synthetic people (evaluate_landmarks): best over all tests at 0.0
    lam_a: float = 0.5
    lam_s: float = 0.5
    candidates: int = 1500
    quality: float = 0.003
    min_distance_px: float = 5.0
    radius: float = 0.3
    position_weight: float = 0.3
    propagate: bool = True
    seeds: bool = True
    refine: bool = True
    refine_radius: float = 0.1
    patch_mm: float = 14.0
    pixel_mm: float = 0.75
    pull: float = 0.15
    sigma: float = 0.2
    mouth_opening: bool = True
    steep_prediction: bool = True
    lid_depth: bool = True
    outliers: bool = True
    brows: bool = True
    eyes: bool = True
    ambiguity: bool = True

    def __post_init__(self):
        for name in ("lam", "lam_a", "lam_s", "position_weight", "pull"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise MatchingError(f"{name} must be in [0, 1], got {v}")
        for name in ("radius", "refine_radius"):
            if not 0.0 <= getattr(self, name) <= 5.0:
                raise MatchingError(f"{name} must be in [0, 5] (x face scale), got {getattr(self, name)}")
        if self.candidates < 1:
            raise MatchingError(f"candidates must be >= 1, got {self.candidates}")
        if not (0.1 <= self.pixel_mm <= 5.0 and 2.0 <= self.patch_mm <= 60.0):
            raise MatchingError("pixel_mm must be in [0.1, 5] and patch_mm in [2, 60]")
