"""``WatersLayer``: Waters' 18 vector muscles as a rig layer (parameters ``waters:<muscle>:<left|right>``,
strength 0..1). Settings (part of the snapshot, not animatable): ``combine`` ('limit', 'strongest' or
'sum', see ``model``) and ``limit_mm``. The offset is computed on the rest face (Waters' fields do not
follow the other layers), so it composes additively with the FAPs and the SABiom muscles."""

from __future__ import annotations

import numpy as np

from core import parameters as P
from core.face import Face
from core.layer import ValueLayer
from core.layers.waters import parameters as _kinds  # noqa: F401 - registers the waters kind
from core.layers.waters.model import COMBINE, WatersModel

__all__ = ["WatersLayer"]


class WatersLayer(ValueLayer):
    name = "waters"

    def __init__(self, face: Face, *, model: WatersModel | None = None, combine: str = "limit",
                 limit_mm: float = 10.0):
        self.face = face
        self.model = model if model is not None else WatersModel(face)
        super().__init__(self.model.keys)
        self._combine, self._limit = "sum", 10.0
        self.set_combine(combine, limit_mm)

    @property
    def combine(self) -> str:
        return self._combine

    @property
    def limit_mm(self) -> float:
        return self._limit

    def set_combine(self, combine: str, limit_mm: float | None = None) -> None:
        """How muscles add up: 'limit' (each vertex at most ``limit_mm`` mm), 'strongest' (one per group) or
        'sum'. ParameterError for anything else."""
        if combine not in COMBINE:
            raise P.ParameterError(f"Waters muscles combine by {', '.join(COMBINE)}, got {combine!r}")
        limit = self._limit if limit_mm is None else limit_mm
        if isinstance(limit, bool) or not isinstance(limit, (int, float)) or not 0 < limit < 1e6:
            raise P.ParameterError(f"the Waters displacement limit is a number of mm > 0, got {limit!r}")
        if (combine, float(limit)) != (self._combine, self._limit):
            self._combine, self._limit = combine, float(limit)
            self.pose_changed.emit()

    def strengths(self) -> np.ndarray:
        """(m,) strengths in the model's muscle order."""
        return np.array([self._values[k] for k in self.model.keys])

    def offset(self, x: np.ndarray) -> np.ndarray | None:
        s = self.strengths()
        if not s.any():
            return None
        return self.model.displacement(s, self._combine, self._limit)

    def snapshot(self):
        return (super().snapshot(), self._combine, self._limit)

    def restore(self, snapshot) -> None:
        values, combine, limit = snapshot
        self.set_combine(combine, limit)
        self.set_values(dict(values))
