"""Scanned detail on parametric animation (thesis A's future work): FAP fit plus a corrective shape.

The FAP layer's displacement is linear in the FAP values (``FapDeformer.displacement``, before lid
contact and the rigid eyeball/head steps):

    d(v) = F · (v ⊙ fapu)          F (3n, 68) the Facial Animation Table, v (68,) in FAP units

so fitting a scanned expression S (same vertices as the rig's face, aligned rigidly onto the
neutral) is a linear least-squares problem over the FAT's columns of the chosen FAPs:

    v* = argmin_v ‖F_I (v_I ⊙ fapu_I) − (S − rest)‖²         I: the FAPs fitted (default: the
                                                               thesis's 46 low-level FAPs)

The residual C = (S − rest) − d(v*) (wrinkles, bulges the FAT cannot make) becomes a *corrective
shape* driven by the FAP values: at FAP values v the corrective adds c(v)·C with

    c(v) = (v_I · v*_I) / (v*_I · v*_I)     (1 at the fitted values, 0 at neutral, linear between)

so FAP animation toward the scanned expression gains the scan's detail.
:class:`CorrectiveLayer` is that rig layer; it has no parameters of its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from psygnal import Signal

from core.layers.blend.library import LibraryError, _points, rigid_align
from core.layers.fap import tables

__all__ = ["FapFit", "fit_faps", "Corrective", "CorrectiveLayer", "thesis_faps"]


def thesis_faps() -> tuple[int, ...]:
    """The 46 low-level FAP numbers of thesis A (no gaze, head or presets)."""
    return tuple(s.number for s in tables.fap_specs() if s.thesis)


@dataclass(frozen=True)
class FapFit:
    """values (68,) FAP units (zero outside the fitted FAPs); fitted: the FAP numbers fitted;
    target (n, 3) mm the scan's displacement from rest; fap_only (n, 3) mm d(values);
    residual (n, 3) mm target − fap_only (the corrective shape); RMS values in mm over vertices."""

    values: np.ndarray
    fitted: tuple[int, ...]
    target: np.ndarray
    fap_only: np.ndarray
    residual: np.ndarray

    @property
    def rms_fap_only_mm(self) -> float:
        return float(np.sqrt(np.mean(np.sum(self.residual ** 2, axis=1))))

    @property
    def rms_with_corrective_mm(self) -> float:
        return float(np.sqrt(np.mean(np.sum((self.target - self.fap_only - self.residual) ** 2, axis=1))))


def fit_faps(deformer, scan, *, faps=None, align: bool = True, ridge: float = 1e-9) -> FapFit:
    """Least-squares FAP values for a scanned expression (see the module docstring).

    deformer : core.layers.fap.fat.FapDeformer of the neutral face (n vertices);
    scan : (n, 3) mm or a Face with the same vertices' meaning (a registered scan);
    faps : FAP numbers to fit (default :func:`thesis_faps`); align : rigidly align the scan onto
    the neutral first (robust Procrustes); ridge : Tikhonov weight relative to the mean column norm².
    """
    rest = np.asarray(deformer.face.vertices, float)
    s = _points(getattr(scan, "vertices", scan), "scan", len(rest))
    if align:
        s = rigid_align(s, rest)[0]
    target = s - rest
    fitted = tuple(thesis_faps() if faps is None else (int(f) for f in faps))
    idx = np.array([f - 1 for f in fitted], int)
    if not len(idx) or idx.min() < 0 or idx.max() >= tables.N_FAPS:
        raise LibraryError(f"FAP numbers to fit must be 1..{tables.N_FAPS}, got {list(fitted)}")
    A = deformer.matrix[:, idx].multiply(deformer.fapu_vector[idx][None, :]).tocsc()   # (3n, |I|) mm per FAP unit
    AtA = (A.T @ A).toarray()
    scale = float(np.mean(np.diag(AtA))) or 1.0
    AtA += ridge * scale * np.eye(len(idx))
    coef = np.linalg.solve(AtA, A.T @ target.reshape(-1))
    values = np.zeros(tables.N_FAPS)
    values[idx] = coef
    fap_only = (A @ coef).reshape(-1, 3)
    return FapFit(values, fitted, target, fap_only, target - fap_only)


@dataclass(frozen=True)
class Corrective:
    """A corrective shape (n, 3) mm driven by FAP values (68,) (see the module docstring)."""

    name: str
    driver: np.ndarray
    shape: np.ndarray

    @classmethod
    def from_fit(cls, name: str, fit: FapFit) -> "Corrective":
        return cls(name, fit.values.copy(), fit.residual.copy())

    def weight(self, fap_values) -> float:
        """c(v) = (v · v*) / (v* · v*) over the fitted FAPs (0 when the driver is all zero)."""
        d = self.driver
        norm = float(d @ d)
        return 0.0 if norm == 0 else float(np.asarray(fap_values, float) @ d) / norm


class CorrectiveLayer:
    """Corrective shapes on a rig, driven by its FAP layer's effective values. No parameters.

    faps : the rig's FapLayer (``rig.faps``); correctives : Corrective shapes on the rig's face."""

    name = "correctives"
    parameters_changed = Signal(object)
    pose_changed = Signal()

    def __init__(self, faps, correctives=()):
        self.faps = faps
        self.correctives = tuple(correctives)
        n = faps.deformer.face.n_vertices
        for c in self.correctives:
            if c.shape.shape != (n, 3) or c.driver.shape != (tables.N_FAPS,):
                raise LibraryError(f"corrective {c.name!r} must have a ({n}, 3) shape and a ({tables.N_FAPS},) driver")
        self._shapes = np.array([c.shape.reshape(-1) for c in self.correctives]).reshape(len(self.correctives), -1)
        drivers = np.array([c.driver for c in self.correctives]).reshape(len(self.correctives), -1)
        norms = np.einsum("kf,kf->k", drivers, drivers)
        self._drivers = drivers / np.where(norms > 0, norms, np.inf)[:, None]

    def joined(self, rig) -> None:
        """Called by ``FaceRig.add_layer``: follow that rig's FAP layer (a copied rig's, on export)."""
        if rig.faps.deformer.face.n_vertices != self.faps.deformer.face.n_vertices:
            raise LibraryError("the correctives were fitted on a face with another vertex count")
        self.faps = rig.faps

    def parameters(self) -> tuple[str, ...]:
        return ()

    def value(self, key):
        from core.parameters import ParameterError

        raise ParameterError(f"{key} is not a parameter of the correctives layer (it follows the FAP values)")

    def set_values(self, values) -> None:
        if values:
            self.value(next(iter(values)))

    def weights(self) -> np.ndarray:
        """(k,) each corrective's current weight c(v) from the effective FAP values."""
        return self._drivers @ self.faps.effective_values()

    def offset(self, x: np.ndarray) -> np.ndarray | None:
        if not self.correctives:
            return None
        w = self.weights()
        if not w.any():
            return None
        return (w @ self._shapes).reshape(-1, 3)

    def snapshot(self):
        return ()

    def restore(self, snapshot) -> None:
        pass

    def copy(self) -> "CorrectiveLayer":
        return CorrectiveLayer(self.faps, self.correctives)
