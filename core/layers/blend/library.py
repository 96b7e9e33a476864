"""Expression sets (thesis A §4.1, eqs. 4.1–4.3): registered poses of one person as displacements.

All faces of a library share one *canonical topology* (the faces ``core.registration`` makes by
subdividing a landmark template and projecting it onto each scan: vertex i means the same facial
point on every face). A pose's displacement matrix is

    D_k = align(P_k → P_neutral) − P_neutral          (n, 3) mm

where ``align`` is a rigid motion (rotation + translation, no scale) that puts the pose on the
neutral (:func:`rigid_align`: Procrustes on the shared vertices, iteratively reweighted so the
moving mouth and brows do not drag the skull; the thesis used ICP, which on faces with known
vertex correspondence reduces to this). A face is then

    x = rest + Σ_k w_k · D_k                           weights w_k as fractions (1 = the pose)

:class:`ExpressionLibrary` holds rest, names and displacements (and optionally the mean face of a
population, for caricatures); it is immutable (arrays read-only).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

__all__ = ["ExpressionLibrary", "LibraryError", "rigid_align", "rigid_transform_between", "build_library",
           "check_pose_name", "POSE_NAME"]

#: What a pose name may look like (it becomes the parameter key ``blend:<name>``).
POSE_NAME = re.compile(r"^[a-z][a-z0-9_]{0,39}$")


class LibraryError(ValueError):
    """An expression library cannot be made or used as asked; the message says why."""


def check_pose_name(name) -> str:
    """``name`` if it is a valid pose name (lower-case letters, digits, ``_``; starts with a letter;
    at most 40 characters), else LibraryError saying so."""
    if not isinstance(name, str) or not POSE_NAME.match(name):
        raise LibraryError(f"pose names are lower-case words like 'joy' or 'viseme_1' (letters, digits, '_', "
                           f"starting with a letter, at most 40 characters), got {name!r}")
    if name == "neutral":
        raise LibraryError("'neutral' is the library's rest face, not a pose: give the pose another name")
    return name


def _points(a, name: str, n: int | None = None) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or (n is not None and a.shape[0] != n):
        want = f"({n}, 3)" if n is not None else "(n, 3)"
        raise LibraryError(f"{name} must have shape {want}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise LibraryError(f"{name} holds NaN or infinite coordinates")
    return a


def rigid_transform_between(source, target, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) minimising Σ w_i |R·source_i + t − target_i|² (weighted Kabsch, no scale).

    source, target : (n, 3) corresponding points (mm); weights : (n,) ≥ 0 or None (all 1)."""
    p = np.asarray(source, float)
    q = np.asarray(target, float)
    w = np.ones(len(p)) if weights is None else np.asarray(weights, float)
    w = w / max(w.sum(), 1e-300)
    cp, cq = w @ p, w @ q
    H = ((p - cp) * w[:, None]).T @ (q - cq)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, cq - R @ cp


def rigid_align(points, reference, *, robust: bool = True, iterations: int = 50) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``points`` moved rigidly onto ``reference`` (same topology): (aligned (n, 3), R, t).

    robust : reweight by the residual (Tukey biweight, cut at 4.685 × 1.4826 × the median residual,
        at least 1e-9 × the face's size): the moving parts of an expression get weight 0, so the
        head's still parts (forehead, nose, temples) decide the alignment; when they are exactly
        still, the rigid motion is recovered exactly. Iterates until the pose changes by < 1e-12 of
        the size, at most ``iterations`` times. False: plain Procrustes.
    """
    p = _points(points, "points")
    q = _points(reference, "reference", len(p))
    R, t = rigid_transform_between(p, q)
    if robust and len(p) >= 3:
        size = float(np.linalg.norm(q.max(0) - q.min(0))) or 1.0
        for _ in range(int(iterations)):
            r = np.linalg.norm(p @ R.T + t - q, axis=1)
            c = 4.685 * max(1.4826 * float(np.median(r)), 1e-9 * size)
            w = np.clip(1.0 - (r / c) ** 2, 0.0, None) ** 2
            if np.count_nonzero(w) < 3:
                break
            R_new, t_new = rigid_transform_between(p, q, w)
            step = np.abs(R_new - R).max() * size + np.abs(t_new - t).max()
            R, t = R_new, t_new
            if step < 1e-12 * size:
                break
    return p @ R.T + t, R, t


@dataclass(frozen=True, eq=False)   # arrays inside: identity comparison, no elementwise ==
class ExpressionLibrary:
    """Displacement sets of one person (base) on one canonical topology.

    rest : (n, 3) mm, the base person's neutral face (canonical vertices).
    names : pose names (k,), each a valid :data:`POSE_NAME`.
    displacements : (k, n, 3) mm, D_k = aligned pose − rest.
    template : the canonical template's name (``"mpeg4_80"``, ``"a48"``) or ``"custom"``.
    mean : (n, 3) mm or None, a population's mean neutral face (caricature reference).
    base : who the poses belong to (free text); units: always ``"mm"``.
    transfer : how the displacements were made: "" (scanned) or the transfer method's name.
    """

    rest: np.ndarray
    names: tuple[str, ...]
    displacements: np.ndarray
    template: str = "custom"
    mean: np.ndarray | None = None
    base: str = ""
    transfer: str = ""
    units: str = field(default="mm")

    def __post_init__(self):
        rest = _points(self.rest, "rest")
        n = len(rest)
        names = tuple(check_pose_name(s) for s in self.names)
        if len(set(names)) != len(names):
            raise LibraryError(f"pose names must be unique, got {list(names)}")
        d = np.asarray(self.displacements, float)
        if d.shape != (len(names), n, 3):
            raise LibraryError(f"displacements must have shape ({len(names)}, {n}, 3) for {len(names)} poses "
                               f"of {n} vertices, got {d.shape}")
        if not np.all(np.isfinite(d)):
            raise LibraryError("displacements hold NaN or infinite values")
        mean = None if self.mean is None else _points(self.mean, "mean", n).copy()
        if self.units != "mm":
            raise LibraryError(f"libraries are in millimetres (units 'mm'), got {self.units!r}")
        for name, value in (("rest", rest.copy()), ("displacements", d.copy()), ("mean", mean)):
            if value is not None:
                value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "names", names)
        flat = self.displacements.reshape(len(names), -1)
        flat.setflags(write=False)
        object.__setattr__(self, "_flat", flat)

    @property
    def n_vertices(self) -> int:
        return len(self.rest)

    def pose(self, name: str) -> np.ndarray:
        """(n, 3) mm: the aligned pose ``name`` (rest + its displacement)."""
        return self.rest + self.displacements[self.index(name)]

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise LibraryError(f"the library has no pose {name!r}; its poses are {', '.join(self.names) or 'none'}") from None

    def displacement(self, weights) -> np.ndarray:
        """(n, 3) mm: Σ_k w_k D_k for ``weights`` {name: fraction} or a (k,) array of fractions."""
        w = self._weights(weights)
        nz = np.flatnonzero(w)
        if not len(nz):
            return np.zeros((self.n_vertices, 3))
        return (w[nz] @ self._flat[nz]).reshape(-1, 3)

    def blend(self, weights) -> np.ndarray:
        """(n, 3) mm: rest + Σ_k w_k D_k (weights as fractions; 1 = the pose, 0 = rest exactly)."""
        return self.rest + self.displacement(weights)

    def _weights(self, weights) -> np.ndarray:
        if isinstance(weights, dict):
            w = np.zeros(len(self.names))
            for name, value in weights.items():
                w[self.index(name)] = float(value)
        else:
            w = np.asarray(weights, float).reshape(-1)
            if w.shape != (len(self.names),):
                raise LibraryError(f"weights must have {len(self.names)} entries (one per pose), got {w.shape[0]}")
        if not np.all(np.isfinite(w)):
            raise LibraryError("weights must be finite numbers")
        return w

    def replace(self, **changes) -> "ExpressionLibrary":
        """A copy with some fields changed (validated again)."""
        fields = dict(rest=self.rest, names=self.names, displacements=self.displacements, template=self.template,
                      mean=self.mean, base=self.base, transfer=self.transfer, units=self.units)
        fields.update(changes)
        return ExpressionLibrary(**fields)

    def with_pose(self, name: str, vertices) -> "ExpressionLibrary":
        """A copy with pose ``name`` added (or replaced) from its vertices (n, 3) mm, aligned first."""
        name = check_pose_name(name)
        aligned, _, _ = rigid_align(_points(vertices, f"pose {name!r}", self.n_vertices), self.rest)
        d = aligned - self.rest
        names = list(self.names)
        disp = list(self.displacements)
        if name in names:
            disp[names.index(name)] = d
        else:
            names.append(name)
            disp.append(d)
        return self.replace(names=tuple(names), displacements=np.array(disp).reshape(len(names), -1, 3))


def build_library(neutral, poses, *, template: str = "custom", base: str = "", robust: bool = True,
                  mean=None) -> ExpressionLibrary:
    """The library of one person from registered faces (same canonical topology).

    neutral : (n, 3) mm or a Face; poses : {name: (n, 3) mm or Face}; each pose is aligned rigidly
    onto the neutral (:func:`rigid_align`) before D_k = pose − neutral is taken.
    """
    rest = _points(getattr(neutral, "vertices", neutral), "neutral")
    names, disp = [], []
    for name, pose in dict(poses).items():
        names.append(check_pose_name(name))
        p = _points(getattr(pose, "vertices", pose), f"pose {name!r}", len(rest))
        aligned, _, _ = rigid_align(p, rest, robust=robust)
        disp.append(aligned - rest)
    d = np.array(disp, float).reshape(len(names), len(rest), 3)
    return ExpressionLibrary(rest, tuple(names), d, template=template, base=base, mean=mean)
