"""A rig layer written the way a new animation method would be: one module, one registration line.

``offset:z`` (mm, -10..10) pushes the whole face forward. Nothing in the timeline, undo, project
or export code knows about it; the tests in tests/core/test_rig_layers.py and
tests/app/test_app_new_layer.py prove they handle it anyway.
"""

from __future__ import annotations

import numpy as np

from core.layer import ValueLayer, register_layer
from core.parameters import Parameter, ParameterError, ParameterKind, ParamKey, register_kind


class ForwardOffsetLayer(ValueLayer):
    name = "offset"

    def __init__(self, face):
        super().__init__(["offset:z"])

    def offset(self, x: np.ndarray) -> np.ndarray:
        return np.broadcast_to(np.array([0.0, 0.0, self.value("offset:z")]), x.shape)


def _key(args: list[str]) -> ParamKey:
    if args != ["z"]:
        raise ParameterError("the offset layer has one parameter: 'offset:z'")
    return ParamKey("offset", "z")


register_kind(ParameterKind("offset", "offset:z", _key,
                            lambda key: Parameter("offset:z", "push forward", "mm", -10.0, 10.0, 0.0, "offset")))
register_layer("offset", ("offset",), lambda rig: ForwardOffsetLayer(rig.face))
