"""Animations from files as timeline keys: MPEG-4 ``.fap`` sequences and thesis B's DPC files.

``.fap``: every FAP a frame masks in becomes a key at the frame's time (k / fps), linear between
keys, so the timeline replays the file (frames that mask a FAP out hold its value, as the MPEG-4
players do: no key there). FAP 2 (expression1·i1/63 + expression2·i2/63) becomes
``expression:<name>`` intensities and FAP 1 (viseme1·b/63 + viseme2·(1 - b/63)) ``viseme:<id>``
intensities; a preset missing from a frame that sets FAP 1/2 gets 0 there.

DPC: each control point mapped to an MPEG-4 feature point drives the FAPs of that point: the
point's displacement (mm, after ``scale_mm``) projected on the FAP's axis and divided by its FAPU
gives the FAP value (thesis B's control points move freely; MPEG-4 lets a point move only along
its FAPs' axes, so the rest of the motion is dropped and reported). Points without a feature
point, or whose feature point no FAP moves, are reported. DPC files carry no timing: ``fps`` must
be given (thesis B played them at a fixed rate).
"""

from __future__ import annotations

import numpy as np

from core.formats.dpc_file import DpcSequence
from core.layers.fap import tables
from core.formats.fap_file import FapSequence
from core import parameters as P
from core.timeline import LINEAR, Track, check_value

__all__ = ["tracks_from_fap", "tracks_from_dpc"]


def _track(key: str, times: np.ndarray, values: np.ndarray) -> Track:
    return Track.from_arrays(key, times, values, np.full(len(times), LINEAR))


def tracks_from_fap(seq: FapSequence, *, start_s: float = 0.0) -> tuple[dict[str, Track], list[str]]:
    """({key: Track}, notes) replaying ``seq`` from ``start_s``; values outside a FAP's range are
    reported and left out (never clamped)."""
    if seq.n_frames == 0:
        return {}, ["the .fap file has no frames"]
    times = start_s + np.arange(seq.n_frames) / float(seq.fps)
    tracks: dict[str, Track] = {}
    notes: list[str] = []
    specs = tables.fap_specs()
    for column in range(2, tables.N_FAPS):
        on = seq.mask[:, column]
        if not on.any():
            continue
        spec = specs[column]
        try:  # the ranges are the parameter registry's, as for every other way values reach the rig
            param = P.describe(f"fap:{spec.number}")
        except P.ParameterError as exc:
            notes.append(f"{exc}; its {int(on.sum())} value(s) were left out")
            continue
        values = seq.values[on, column]
        ok = (values >= param.minimum) & (values <= param.maximum)
        if not ok.all():
            notes.append(f"FAP {spec.number} {spec.name}: {int((~ok).sum())} value(s) outside "
                         f"{param.minimum:g}..{param.maximum:g} {param.unit} were left out")
        if ok.any():
            tracks[f"fap:{spec.number}"] = _track(f"fap:{spec.number}", times[on][ok], values[ok])
    tracks.update(_preset_tracks(seq, times))
    return tracks, notes


def _preset_tracks(seq: FapSequence, times: np.ndarray) -> dict[str, Track]:
    """expression:/viseme: intensity tracks from FAP 2 / FAP 1 frames."""
    out: dict[str, Track] = {}
    names = tables.expression_names()
    for column, kind in ((1, "expression"), (0, "viseme")):
        frames = np.nonzero(seq.mask[:, column])[0]
        if not len(frames):
            continue
        mixes = []
        for k in frames:
            if kind == "expression":
                s1, i1, s2, i2 = (int(v) for v in seq.expression[k][:4])
                mix = {s1: i1 / 63.0, s2: i2 / 63.0}
            else:
                s1, s2, blend = (int(v) for v in seq.viseme[k][:3])
                mix = {s1: blend / 63.0, s2: 1.0 - blend / 63.0}
            mixes.append({p: w for p, w in mix.items() if p != 0})
        for preset in sorted({p for mix in mixes for p in mix}):
            key = f"expression:{names[preset]}" if kind == "expression" else f"viseme:{preset}"
            values = np.array([min(max(mix.get(preset, 0.0), 0.0), 1.0) for mix in mixes])
            out[key] = _track(key, times[frames], values)
    return out


def tracks_from_dpc(seq: DpcSequence, fapu: dict[str, float], *, fps: float | None = None,
                    scale_mm: float = 1.0, start_s: float = 0.0) -> tuple[dict[str, Track], list[str]]:
    """({key: Track}, notes): FAP tracks from the control points' displacements (see the module)."""
    fps = fps or seq.fps
    if not fps or fps <= 0:
        raise ValueError("this DPC file has no timing: give the frames per second it was made for")
    times = start_s + np.arange(len(seq.displacements)) / float(fps)
    by_point: dict[str, list] = {}
    for spec in tables.fap_specs():
        if spec.thesis and spec.unit in fapu and fapu[spec.unit] > 0 and spec.fp:
            by_point.setdefault(spec.fp, []).append(spec)
    tracks: dict[str, Track] = {}
    notes: list[str] = []
    unmapped = []
    feature_points = seq.feature_points or (None,) * len(seq.names)
    for i, (name, fp) in enumerate(zip(seq.names, feature_points)):
        specs = by_point.get(fp or "")
        if not specs:
            unmapped.append(name)
            continue
        d = seq.displacements[:, i, :] * scale_mm
        used = np.zeros_like(d)
        for spec in specs:
            axis = np.asarray(spec.axis, float)
            along = d @ axis
            used += np.outer(along, axis)
            values = along / fapu[spec.unit]
            try:
                [check_value(f"fap:{spec.number}", float(v)) for v in (values.min(), values.max())]
            except ValueError:
                notes.append(f"{name} -> FAP {spec.number} {spec.name}: values reach {np.abs(values).max():.0f} "
                             f"{spec.unit}, beyond its range; check the file's units (scale)")
                continue
            tracks[f"fap:{spec.number}"] = _track(f"fap:{spec.number}", times, values)
        lost = np.linalg.norm(d - used, axis=1).max()
        if lost > 0.5:
            notes.append(f"{name} ({fp}): up to {lost:.1f} mm of its motion has no MPEG-4 FAP and was dropped")
    if unmapped:
        notes.append(f"control points without a FAP-driven feature point (ignored): {', '.join(unmapped)}")
    return tracks, notes
