"""FACS emotion presets for the RBF control points (thesis B §3.2, Tables 3.2-3.3).

``resources/facs/control_point_action_units.csv``: each action unit as control-point displacements (mm);
``resources/facs/emotions.csv``: each emotion's action units with their intensities (B Table 3.3; the
FAP expression presets use the same table). An emotion is the intensity-weighted sum of its
action units, shipped as an EPC file ``resources/rbf/emotions/<emotion>.epc`` (what the layer applies, so a
user can edit or replace it like any EPC). ``python -m core.layers.rbf.emotions`` rewrites those files from
the two tables; a test checks they agree.
"""

from __future__ import annotations

import functools

import numpy as np

from core.formats.epc_file import EpcEmotion, read_epc, write_epc
from core.layers.fap.tables import expression_action_units
from core.parameters import ParameterError

__all__ = ["EMOTIONS", "action_units", "emotion_aus", "build_emotion", "preset", "emotion_displacements"]

EMOTIONS = ("joy", "surprise", "fear", "anger", "sadness")


@functools.cache
def action_units() -> dict[int, dict[str, np.ndarray]]:
    """{AU: {control-point name: (3,) mm}} (B Table 3.2's units)."""
    import resources

    out: dict[int, dict[str, np.ndarray]] = {}
    for r in resources.get_table("facs/control_point_action_units.csv"):
        d = out.setdefault(int(r["au"]), {})
        d[r["point"]] = d.get(r["point"], np.zeros(3)) + np.array([float(r[k]) for k in ("dx", "dy", "dz")])
    return out


def emotion_aus() -> dict[str, tuple[int, ...]]:
    """{emotion: its action units} (B Table 3.3)."""
    return {name: tuple(mix) for name, mix in expression_action_units().items()}


def build_emotion(name: str) -> EpcEmotion:
    """The emotion as the sum of its action units, on Mimica's default control points (one frame)."""
    from core.layers.rbf.regions import control_point_specs

    if name not in emotion_aus():
        raise ParameterError(f"unknown emotion {name!r}; the presets are {', '.join(emotion_aus())}")
    specs = control_point_specs()
    index = {s.name: i for i, s in enumerate(specs)}
    d = np.zeros((len(specs), 3))
    for au, intensity in expression_action_units()[name].items():
        for point, move in action_units()[au].items():
            d[index[point]] += intensity * move
    return EpcEmotion(name, d[None], tuple(s.name for s in specs), tuple(s.fp for s in specs), emotion_aus()[name])


@functools.cache
def preset(name: str) -> EpcEmotion:
    """The shipped EPC preset ``name`` (resources/rbf/emotions/<name>.epc)."""
    import resources

    if name not in EMOTIONS:
        raise ParameterError(f"unknown emotion {name!r}; the presets are {', '.join(EMOTIONS)}")
    return read_epc(resources.path(f"rbf/emotions/{name}.epc"))


def emotion_displacements(emotion) -> dict[str, np.ndarray]:
    """{control-point name: (3,) mm} of a preset name or an EpcEmotion."""
    if isinstance(emotion, str):
        emotion = preset(emotion)
    if not isinstance(emotion, EpcEmotion):
        raise ParameterError(f"an emotion is a preset name ({', '.join(EMOTIONS)}) or an EPC emotion, got "
                             f"{emotion!r}")
    return emotion.as_dict()


def write_presets(folder=None) -> None:
    """Write every emotion of the tables as an EPC file into ``folder`` (default: the resources folder)."""
    import resources
    from pathlib import Path

    folder = Path(folder) if folder is not None else resources.path("rbf/emotions")
    for name in emotion_aus():
        write_epc(folder / f"{name}.epc", build_emotion(name))


if __name__ == "__main__":
    write_presets()
