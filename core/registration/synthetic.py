"""Synthetic protocol database (thesis A §3.2 test protocol): 30 people x 7 poses of virtual scans.

The thesis's database (30 people x neutral + Ekman's six expressions, Vivid 910 scans with 48
hand-marked landmarks) is not public; this module makes an equivalent one with ground truth:

- **People.** Person 0 is the built-in default face; person p > 0 is
  ``generate_face(FaceParameters.random(default_rng([seed, p])), full_head=False)``.
- **Poses.** ``POSES`` = "neutral" + the six expressions of ``core.layers.fap.tables.expression_names()``
  (MPEG-4 FAP 2 presets), applied at full intensity with ``FaceRig.set_expression(name, 1.0)``.
- **Scan.** ``scan_face`` with ``SCAN_SETTINGS`` (0.1 mm depth noise, 2 deg / 3 mm pose jitter, no
  holes -- the thesis's meshes were already hole-filled), random stream
  ``default_rng([seed, person, pose index, 1])``. Deterministic per (person, pose, seed).
- **Ground truth.** The scan carries *every* source landmark, each bound to the scan point closest
  to the posed source landmark (the scanner's projection of it). A landmark is **visible** when
  that point is within ``VISIBLE_MM`` (2 mm: noise + resampling) of the truth; hidden ones (inner
  lip points inside a closed mouth, teeth behind the lips) sit on the nearest surface the scanner
  saw, up to a few mm away. :func:`synthetic_case` returns the visibility flags; the evaluation
  scores only visible landmarks of an input, while a *model* scan uses all of them (a user marking
  the model would put a hidden inner-lip point on the lip seam, which is what the projection is).
- **Cache.** One compressed NPZ per scan (no pickle; ``np.load(allow_pickle=False)``) under
  ``cache_dir`` or ``~/.cache/mimica/synthetic/<VERSION>/``. Vertices are stored as float32
  (1e-5 mm steps); a freshly generated scan goes through the same rounding, so cached and fresh
  results are identical. ``VERSION`` changes whenever the recipe does; the file name also carries a
  hash of the pose's FAP values, so a change of the expression presets makes new scans, and one of
  the person's face (the committed default face, or the generator's source), so does a changed face.
- **Cost.** Building a person's rig (generate_face ~2 s + FAP deformer ~1-2 s) dominates; the rig
  of the last two people is kept in memory so the 7 poses of a person share it. A scan is ~1.2 s;
  loading a cached scan ~50 ms.
"""

from __future__ import annotations

import functools
import io
import json
import os
from pathlib import Path
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from core.face import Face, FaceMetadata, SurfacePoint

VERSION = "v2"   # v2: all landmarks stored, with a visibility flag
SCAN_SETTINGS = dict(n_target=50_000, noise_mm=0.1, holes=0, pose_jitter_deg=2.0, pose_jitter_mm=3.0)
VISIBLE_MM = 2.0


class SyntheticError(ValueError):
    """Bad person/pose/cache arguments."""


def poses() -> tuple[str, ...]:
    """("neutral", "joy", "sadness", "anger", "fear", "disgust", "surprise") from the FAP tables."""
    from core.layers.fap import tables

    return tuple(tables.expression_names())




def default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "mimica" / "synthetic" / VERSION


def identity_face(person: int, seed: int = 0) -> Face:
    """The neutral face of ``person`` (0 = the default face)."""
    if person < 0:
        raise SyntheticError(f"person must be >= 0, got {person}")
    if person == 0:
        from core.default_face import load_default_face

        return load_default_face(full_head=False)   # a single-view scan sees the front only
    from core.default_face import FaceParameters, generate_face

    return generate_face(FaceParameters.random(np.random.default_rng([seed, person])), full_head=False)


@functools.lru_cache(maxsize=2)
def _rig(person: int, seed: int):
    from core.rig import FaceRig

    return FaceRig(identity_face(person, seed))


@functools.cache
def _pose_recipe(pose: str) -> str:
    """A short hash of the FAP values that make ``pose`` and of the code that turns them into a face
    (the expression presets change with the FACS tables, the FAP table with its code: a scan cached
    with older ones must not be read as this pose)."""
    import hashlib

    from core.layers.fap import tables
    from core.layers.fap.fat import deformer_code_version

    row = tables.expression_table()[tables.expression_id(pose)] if pose != "neutral" else np.zeros(1)
    recipe = np.ascontiguousarray(row, dtype=np.float64).tobytes()
    if pose != "neutral":
        recipe += deformer_code_version().encode()
    return hashlib.sha1(recipe).hexdigest()[:8]


@functools.cache
def _identity_recipe(person: int) -> str:
    """A short hash of what makes ``person``'s face: the committed default face's file (person 0)
    or the generator's source (core/default_face/*.py), so a scan cached from an older face (its
    eyeballs, say) is not read as this person's."""
    import hashlib

    import core.default_face as package

    face_file = package.default_face_path() if person == 0 else None
    if face_file is not None and face_file.exists():
        data = face_file.read_bytes()
    else:
        sources = sorted(Path(package.__file__).parent.glob("*.py"))
        data = (b"generated" if person == 0 else b"") + b"".join(s.name.encode() + s.read_bytes() for s in sources)
    return hashlib.sha1(data).hexdigest()[:8]


def _cache_path(cache_dir, person: int, pose: str, seed: int) -> Path:
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return root / f"p{person:03d}_{pose}_s{seed}_{_pose_recipe(pose)}_{_identity_recipe(person)}.npz"


@dataclass(frozen=True)
class SyntheticScan:
    """A synthetic scan and its ground truth.

    face : Face carrying every source landmark (projected onto the scan).
    visible : frozenset of landmark names the scanner saw (projection within ``VISIBLE_MM``).
    error_mm : name -> distance (mm) of the projected landmark from the posed source landmark.
    transform : (4, 4) rigid transform from the person's rig frame to the scan's (the pose jitter).
    """

    face: Face
    visible: frozenset
    error_mm: dict
    transform: np.ndarray

    @property
    def hidden(self) -> tuple[str, ...]:
        return tuple(n for n in self.face.landmark_names if n not in self.visible)


def synthetic_scan(person: int, pose: str, *, cache_dir=None, seed: int = 0) -> Face:
    """The Face of :func:`synthetic_case` (all landmarks, visible or not)."""
    return synthetic_case(person, pose, cache_dir=cache_dir, seed=seed).face


def synthetic_case(person: int, pose: str, *, cache_dir=None, seed: int = 0) -> SyntheticScan:
    """The virtual scan of ``person`` in ``pose`` (generated once, then read from the cache).

    Parameters
    ----------
    person : int >= 0 (0 = the default face)
    pose : str, one of :func:`poses`
    cache_dir : path, optional (default ``~/.cache/mimica/synthetic/<VERSION>/``)
    seed : int, database seed (identities and scan randomness)

    Returns
    -------
    SyntheticScan: the Face (uv, 640x480 texture, all ground-truth landmarks) and visibility.
    """
    names = poses()
    if pose not in names:
        raise SyntheticError(f"unknown pose {pose!r}; choose one of {', '.join(names)}")
    if int(person) != person or person < 0:
        raise SyntheticError(f"person must be an integer >= 0, got {person!r}")
    person = int(person)
    path = _cache_path(cache_dir, person, pose, seed)
    if path.exists():
        try:
            return _load(path)
        except (OSError, ValueError, KeyError):
            pass  # a damaged cache file is regenerated below
    payload = _generate(person, pose, seed)
    from core.formats.atomic_files import write_atomic

    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    np.savez_compressed(buf, **payload)
    write_atomic(path, buf.getvalue())
    return _from_payload(payload, str(path))


def protocol_database(n_people: int = 30, poses: Sequence[str] | None = None, cache_dir=None, *,
                      seed: int = 0) -> Iterator[tuple[int, str, Face]]:
    """Yield (person, pose, scan) for persons 0..n_people-1 and each pose (person-major order)."""
    chosen = tuple(_all_poses() if poses is None else poses)
    for pose in chosen:
        if pose not in _all_poses():
            raise SyntheticError(f"unknown pose {pose!r}; choose from {', '.join(_all_poses())}")
    for person in range(int(n_people)):
        for pose in chosen:
            yield person, pose, synthetic_scan(person, pose, cache_dir=cache_dir, seed=seed)


def _all_poses() -> tuple[str, ...]:
    return poses()


def _generate(person: int, pose: str, seed: int) -> dict[str, np.ndarray]:
    from core.registration.virtual_scanner import scan_face

    rig = _rig(person, seed)
    rig.reset_faps()
    rig.set_expression(None if pose == "neutral" else pose, 1.0)
    verts = np.array(rig.vertices())
    rig.set_expression(None, 0.0)
    index = _all_poses().index(pose)
    result = scan_face(rig.face, vertices=verts, rng=np.random.default_rng([seed, person, index, 1]),
                       **SCAN_SETTINGS)
    scan = result.face
    names = list(scan.landmark_names)
    visible = [result.landmark_error_mm[n] <= VISIBLE_MM for n in names]
    lms = scan.landmarks
    meta = dict(person=person, pose=pose, seed=seed, version=VERSION, settings=SCAN_SETTINGS,
                hidden=[n for n, ok in zip(names, visible) if not ok])
    return dict(
        vertices=scan.vertices.astype(np.float32),
        triangles=scan.triangles.astype(np.int32),
        uv=scan.uv.astype(np.float32),
        texture=np.asarray(scan.texture),
        landmark_names=np.array(names, dtype="U16"),
        landmark_triangles=np.array([lms[n].triangle for n in names], dtype=np.int64),
        landmark_bary=np.array([lms[n].barycentric for n in names], dtype=np.float64).reshape(-1, 3),
        landmark_error_mm=np.array([result.landmark_error_mm[n] for n in names], dtype=np.float64),
        landmark_visible=np.array(visible, dtype=bool),
        transform=result.transform,
        meta=np.array(json.dumps(meta)),
    )


def _load(path: Path) -> SyntheticScan:
    with np.load(path, allow_pickle=False) as data:
        payload = {k: data[k] for k in data.files}
    meta = json.loads(str(payload["meta"]))
    if meta.get("version") != VERSION:
        raise ValueError("stale cache version")
    return _from_payload(payload, str(path))


def _from_payload(payload: dict, source: str) -> SyntheticScan:
    meta = json.loads(str(payload["meta"]))
    landmarks = {}
    for name, t, b in zip(payload["landmark_names"], payload["landmark_triangles"], payload["landmark_bary"]):
        b = np.asarray(b, np.float64)
        landmarks[str(name)] = SurfacePoint(int(t), tuple(b / b.sum()))
    notes = [f"Synthetic protocol scan: person {meta['person']}, pose {meta['pose']}, seed {meta['seed']}."]
    if meta.get("hidden"):
        notes.append(f"Landmarks not visible to the scanner (projected onto the nearest scanned surface): "
                     f"{', '.join(meta['hidden'])}")
    face = Face(
        payload["vertices"].astype(np.float64), payload["triangles"].astype(np.int64),
        uv=payload["uv"].astype(np.float64), texture=payload["texture"], landmarks=landmarks,
        metadata=FaceMetadata(source=source, units="mm", notes=notes,
                              name=f"person {meta['person']} {meta['pose']}"),
    )
    names = [str(n) for n in payload["landmark_names"]]
    visible = frozenset(n for n, ok in zip(names, payload["landmark_visible"]) if ok)
    return SyntheticScan(face, visible, dict(zip(names, map(float, payload["landmark_error_mm"]))),
                         np.asarray(payload["transform"], float).reshape(4, 4))
