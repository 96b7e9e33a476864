"""params.py
----
Identity parameters of the built-in face and the 2-D layout derived from them.

Defaults are adult anthropometric norms (Farkas, "Anthropometry of the Head
and Face", 2nd ed. 1994: n-gn ~ 121 mm, zy-zy ~ 137 mm, go-go ~ 100 mm,
en-en ~ 33 mm, ex-ex ~ 91 mm, al-al ~ 35 mm, ch-ch ~ 50 mm, sn-sto : sto-gn
~ 1 : 2). Coordinates: mm, +x = the face's own left, +y up, +z toward the
viewer; the nose tip of the default face is near the origin.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True)
class FaceParameters:
    """Identity of a generated face. Lengths in mm; prominences are unitless gains (1 = average)."""

    face_width: float = 137.0          # bizygomatic breadth zy-zy, mm
    face_height: float = 121.0         # nasion to menton n-gn, mm
    jaw_width: float = 104.0           # bigonial breadth go-go, mm
    chin_prominence: float = 1.0       # forward projection of the chin boss
    cheekbone_prominence: float = 1.0  # malar fullness
    brow_ridge: float = 1.0            # supraorbital ridge and glabella
    nose_length: float = 57.0          # nasion to subnasale n-sn, mm
    nose_width: float = 35.0           # alar breadth al-al, mm
    nose_projection: float = 17.0      # nose tip in front of the subnasale, mm
    lip_thickness: float = 1.0         # vermilion height gain (1 = 7 mm upper, 9 mm lower)
    mouth_width: float = 48.0          # ch-ch, mm
    eye_spacing: float = 35.0          # intercanthal width en-en, mm
    eye_width: float = 28.0            # palpebral fissure length en-ex, mm
    skin_tone: float = 0.3             # 0 = very light ... 1 = very dark
    iris_hue: float = 0.65             # 0 = blue, 0.5 = green/hazel, 1 = dark brown
    texture_seed: int = 7              # seed of the skin noise (deterministic)

    #: (min, max) accepted for each numeric parameter; outside is an error, never clamped.
    RANGES = {
        "face_width": (110.0, 165.0), "face_height": (95.0, 145.0), "jaw_width": (80.0, 130.0),
        "chin_prominence": (0.0, 2.0), "cheekbone_prominence": (0.0, 2.0), "brow_ridge": (0.0, 2.0),
        "nose_length": (40.0, 66.0), "nose_width": (25.0, 48.0), "nose_projection": (10.0, 26.0),
        "lip_thickness": (0.4, 1.8), "mouth_width": (38.0, 64.0), "eye_spacing": (26.0, 42.0),
        "eye_width": (23.0, 33.0), "skin_tone": (0.0, 1.0), "iris_hue": (0.0, 1.0),
    }

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "texture_seed":
                continue
            lo, hi = self.RANGES[f.name]
            if not np.isfinite(value) or not lo <= value <= hi:
                raise ValueError(f"{f.name} = {value} is outside the supported range [{lo}, {hi}]")

    @classmethod
    def random(cls, rng: np.random.Generator, spread: float = 0.5) -> "FaceParameters":
        """A random identity: each parameter drawn around its default, ``spread`` of the half-range."""
        base = cls()
        values = {}
        for name, (lo, hi) in cls.RANGES.items():
            centre = getattr(base, name)
            half = spread * min(centre - lo, hi - centre)
            values[name] = float(np.clip(centre + rng.uniform(-half, half), lo, hi))
        return cls(**values, texture_seed=int(rng.integers(0, 2**31)))


@dataclass(frozen=True)
class FaceLayout:
    """Key 2-D positions (x, y in mm) and depths derived from the parameters.

    Only the face's left side (+x) is stored; the right side mirrors it.
    """

    p: FaceParameters
    nasion_y: float
    subnasale_y: float
    nose_tip_y: float
    stomion_y: float
    menton_y: float
    chin_y: float
    sulcus_y: float
    upper_lip_height: float   # vermilion height at the midline, mm
    lower_lip_height: float
    mouth_half_width: float
    eye_inner_x: float
    eye_outer_x: float
    eye_line_y: float         # height of the pupil centres
    pupil_x: float
    iris_radius: float
    eyeball_radius: float
    eyeball_apex_z: float
    alar_half_width: float
    hairline_y: float

    @classmethod
    def from_parameters(cls, p: FaceParameters) -> "FaceLayout":
        nasion_y = 41.5
        subnasale_y = nasion_y - p.nose_length
        menton_y = nasion_y - p.face_height
        lower = subnasale_y - menton_y
        stomion_y = subnasale_y - 0.30 * lower
        eye_inner_x = p.eye_spacing / 2
        eye_outer_x = eye_inner_x + p.eye_width
        return cls(
            p=p,
            nasion_y=nasion_y,
            subnasale_y=subnasale_y,
            nose_tip_y=subnasale_y + 0.26 * p.nose_length,
            stomion_y=stomion_y,
            menton_y=menton_y,
            chin_y=menton_y + 0.20 * lower,
            sulcus_y=stomion_y - 0.30 * (stomion_y - menton_y),
            upper_lip_height=7.0 * p.lip_thickness,
            lower_lip_height=9.0 * p.lip_thickness,
            mouth_half_width=p.mouth_width / 2,
            eye_inner_x=eye_inner_x,
            eye_outer_x=eye_outer_x,
            eye_line_y=33.0,
            pupil_x=(eye_inner_x + eye_outer_x) / 2,
            iris_radius=5.6,
            eyeball_radius=12.0,
            eyeball_apex_z=-28.5,
            alar_half_width=p.nose_width / 2,
            hairline_y=nasion_y + 0.36 * p.face_height,
        )

    # ---- eye fissure (palpebral opening), left eye; mirror x for the right
    def lid_margins(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Upper and lower lid margin heights y at x (mm), for |x| between the eye corners.

        The corners lie on a line tilted up laterally (canthal tilt ~ 4 deg); the
        upper margin peaks a little medial of centre, the lower a little lateral,
        and both are tangent to the iris at the pupil (MPEG-4 neutral face).
        """
        s = np.clip((np.abs(x) - self.eye_inner_x) / (self.eye_outer_x - self.eye_inner_x), 0.0, 1.0)
        inner_y, outer_y = self.eye_line_y - 1.2, self.eye_line_y + 0.8
        line = inner_y + (outer_y - inner_y) * s
        s_pupil = 0.5
        # Skewed arches: sin(pi * s**a) peaks at s = 0.5**(1/a).
        a_up, a_lo = np.log(0.5) / np.log(0.46), np.log(0.5) / np.log(0.56)
        up_shape = np.sin(np.pi * s ** a_up) ** 0.8
        lo_shape = np.sin(np.pi * s ** a_lo) ** 0.9
        line_pupil = inner_y + (outer_y - inner_y) * s_pupil
        up_gain = (self.eye_line_y + self.iris_radius - line_pupil) / np.sin(np.pi * s_pupil ** a_up) ** 0.8
        lo_gain = (line_pupil - (self.eye_line_y - self.iris_radius)) / np.sin(np.pi * s_pupil ** a_lo) ** 0.9
        return line + up_gain * up_shape, line - lo_gain * lo_shape

    def inside_fissure(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Boolean mask of points inside either palpebral opening."""
        ax = np.abs(x)
        upper, lower = self.lid_margins(ax)
        within = (ax > self.eye_inner_x) & (ax < self.eye_outer_x)
        return within & (y < upper) & (y > lower)

    def fissure_outline(self, n: int = 200) -> np.ndarray:
        """(2n, 2) closed outline of the left fissure, counter-clockwise."""
        xs = np.linspace(self.eye_inner_x, self.eye_outer_x, n)
        upper, lower = self.lid_margins(xs)
        return np.concatenate([np.stack([xs, lower], 1), np.stack([xs[::-1], upper[::-1]], 1)])

    # ---- lips
    def mouth_line(self, x: np.ndarray) -> np.ndarray:
        """y of the line where the lips meet (stomion line), defined for all x."""
        x = np.asarray(x, dtype=float)
        return self.stomion_y + 0.0011 * x**2 - 0.5 * np.exp(-((x / 5.0) ** 2))

    def _lip_taper(self, x: np.ndarray) -> np.ndarray:
        t = np.clip(np.abs(x) / self.mouth_half_width, 0.0, 1.0)
        return np.sqrt(1.0 - t**2.2)

    def upper_lip_border(self, x: np.ndarray) -> np.ndarray:
        """y of the upper vermilion border (with Cupid's bow)."""
        x = np.asarray(x, dtype=float)
        bow = 0.9 * np.exp(-(((np.abs(x) - 5.5) / 3.2) ** 2)) - 0.5 * np.exp(-((x / 2.0) ** 2))
        height = self.upper_lip_height * (0.25 + 0.75 * self._lip_taper(x)) + bow
        return self.mouth_line(x) + height * (np.abs(x) < self.mouth_half_width + 1e-9)

    def lower_lip_border(self, x: np.ndarray) -> np.ndarray:
        """y of the lower vermilion border."""
        x = np.asarray(x, dtype=float)
        height = self.lower_lip_height * (0.2 + 0.8 * self._lip_taper(x) ** 0.8)
        return self.mouth_line(x) - height * (np.abs(x) < self.mouth_half_width + 1e-9)

    # ---- brows
    def brow_curve(self, x: np.ndarray) -> np.ndarray:
        """y of the eyebrow's centre line for |x| from the inner to the outer end."""
        ax = np.abs(np.asarray(x, dtype=float))
        xi, xt, xo = self.brow_x
        yi, yt, yo = self.brow_y
        return np.interp(ax, [xi, xt, xo], [yi, yt, yo]) + 1.5 * np.sin(
            np.pi * np.clip((ax - xi) / (xo - xi), 0, 1)
        ) * (ax < xt)

    @property
    def brow_x(self) -> tuple[float, float, float]:
        """x of the inner end, top and outer end of the left brow."""
        return (self.eye_inner_x - 4.5, self.pupil_x + 4.0, self.eye_outer_x + 10.0)

    @property
    def brow_y(self) -> tuple[float, float, float]:
        e = self.eye_line_y
        return (e + 17.5, e + 22.5, e + 13.5)
