"""Thesis B's files and the RBF layer: PPC positions of a layer, DPC export of a timeline's control-point
tracks, and DPC/EPC import as timeline keys.

A DPC frame k holds every control point's displacement (dx, dy, dz mm) at time k / fps; its keys are
``cp:<fp>:<x|y|z>``. Export samples the tracks at the timeline's frame rate (points without a track are 0);
import keys every frame linearly, so export → import → export gives the same file.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from core.formats.dpc_file import DpcSequence
from core.formats.ppc_file import ControlPointPositions
from core.parameters import ParameterError

__all__ = ["ppc_of", "dpc_from_timeline", "keys_from_dpc"]

AXES = ("x", "y", "z")


def ppc_of(layer) -> ControlPointPositions:
    """The layer's control points and their rest positions, ready for ``write_ppc``."""
    pos = layer.positions()
    return ControlPointPositions(layer.points.names, layer.points.feature_points,
                                 np.array([pos[n] for n in layer.points.names]).reshape(-1, 3))


def dpc_from_timeline(timeline, layer, *, start_s: float = 0.0, end_s: float | None = None) -> DpcSequence:
    """(n_frames, c, 3) displacements of ``layer``'s control points sampled from ``timeline`` at its frame
    rate from ``start_s`` to ``end_s`` (default: its duration), as a DpcSequence with names and fps."""
    fps = timeline.fps
    end = timeline.duration if end_s is None else float(end_s)
    if not 0 <= start_s <= end:
        raise ParameterError(f"the DPC export range must have 0 ≤ start ≤ end, got {start_s:g} to {end:g} s")
    times = np.arange(int(round(start_s * fps)), int(np.floor(end * fps + 1e-9)) + 1) / fps
    names, fps_ = layer.points.names, layer.points.feature_points
    keys = [f"cp:{fp}:{a}" for fp in fps_ for a in AXES]
    have = [k for k in keys if k in timeline.tracks and len(timeline.track(k))]
    out = np.zeros((len(times), len(keys)))
    if have:
        cols = [keys.index(k) for k in have]
        for i, t in enumerate(times):
            _, values = timeline.evaluate_array(float(t), have)
            out[i, cols] = values
    return DpcSequence(out.reshape(len(times), len(names), 3), names, fps_, float(fps))


def keys_from_dpc(sequence, fps: float | None = None, *, start_s: float = 0.0,
                  interpolation: str = "linear") -> dict[str, list[tuple[float, float, str]]]:
    """{cp key: [(time, value, interpolation)]}: one key per frame and axis, for ``Timeline.add_keys``.
    Works for a DpcSequence or an EpcEmotion (its frames); control points need a feature point."""
    frames = sequence.displacements if isinstance(sequence, DpcSequence) else sequence.frames
    rate = fps if fps is not None else getattr(sequence, "fps", None)
    if rate is None or not rate > 0:
        raise ParameterError("this file has no frame rate (thesis B's files carry none): give fps, e.g. 25")
    missing = [n for n, f in zip(sequence.names, sequence.feature_points) if f is None]
    if missing:
        raise ParameterError(f"the control points {', '.join(missing)} have no MPEG-4 feature point, so they have "
                             "no cp: parameter; name them as Mimica's control points")
    times = start_s + np.arange(len(frames)) / float(rate)
    out: dict[str, list] = {}
    for i, fp in enumerate(sequence.feature_points):
        for a, axis in enumerate(AXES):
            out[f"cp:{fp}:{axis}"] = [(float(t), float(v), interpolation) for t, v in zip(times, frames[:, i, a])]
    return out


def apply_frame(layer, sequence, frame: int = -1, intensity: float = 1.0) -> None:
    """Pose ``layer`` at one frame of a DPC/EPC sequence (points the layer lacks are ignored)."""
    frames = sequence.displacements if isinstance(sequence, DpcSequence) else sequence.frames
    moves: Mapping[str, np.ndarray] = {n: frames[frame, i] * intensity for i, n in enumerate(sequence.names)}
    d = np.zeros((len(layer.points), 3))
    for i, n in enumerate(layer.points.names):
        if n in moves:
            d[i] = moves[n]
    layer.set_displacements(d)
