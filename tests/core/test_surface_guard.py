"""The surface guard (``core.layers.fap.surface_guard``): skin that would fold or smear is smoothed
there, continuously, and nowhere else.

Known answers on a flat grid: a vertex pushed past its neighbours folds the grid and the guard
unfolds it; a gentle pose is left bit for bit; held vertices never move; sweeping a pose through the
point where the guard starts acting moves the result continuously (no pop); the compiled check is
the numpy one. On the default face, stretch_cornerlip at 400 no longer folds the mouth corner."""

from __future__ import annotations

import numpy as np
import pytest

from core.layers.fap.surface_guard import SurfaceGuard
from core.mesh_quality import FaceQualityProbe, _local_frames, _normals, principal_stretches
from tests.core.test_blend_quality import _flat_grid


def _grid(nx: int = 25, ny: int = 25):
    """A flat 1 mm grid (test_blend_quality's)."""
    return _flat_grid(nx, ny, 1.0)


def _bump(v: np.ndarray, amplitude_mm: float, width_mm: float = 1.2) -> np.ndarray:
    """A pose: the grid's middle pushed along +x by a narrow Gaussian (steep enough to fold)."""
    centre = v.mean(axis=0)
    g = np.exp(-np.sum((v - centre) ** 2, axis=1) / (2 * width_mm ** 2))
    return v + amplitude_mm * g[:, None] * np.array([1.0, 0.0, 0.0])


def _breaks(rest, tris, x) -> tuple[int, float, float]:
    turned = int((np.einsum("ij,ij->i", _normals(x[tris]), _normals(rest[tris])) < 0).sum())
    big, small = principal_stretches(_local_frames(rest[tris]), x[tris])
    return turned, float(big.max()), float(small.min())


def test_a_folding_pose_is_unfolded_and_a_gentle_one_left_alone():
    v, tris = _grid()
    guard = SurfaceGuard(v, tris, np.zeros(len(v), bool))
    folded = _bump(v, 3.0)
    assert _breaks(v, tris, folded)[0] > 0                      # the pose folds the grid
    x = folded.copy()
    assert guard.apply(x)
    turned, big, small = _breaks(v, tris, x)
    assert turned == 0 and big <= 2.0 and small >= 0.25, (turned, big, small)
    assert 0.3 < np.abs(x - v).max() < 3.0                       # still pushed, much less at its narrow peak
    gentle = _bump(v, 0.3)
    x = gentle.copy()
    assert not guard.apply(x)
    np.testing.assert_array_equal(x, gentle)


def test_held_vertices_never_move_and_the_guard_fades_in_beside_them():
    v, tris = _grid()
    centre = np.argmin(np.linalg.norm(v - v.mean(axis=0), axis=1))
    held = np.zeros(len(v), bool)
    held[centre] = True
    guard = SurfaceGuard(v, tris, held)
    x = _bump(v, 3.0)
    before = x.copy()
    guard.apply(x)
    np.testing.assert_array_equal(x[centre], before[centre])
    beside = np.flatnonzero(np.abs(np.linalg.norm(v - v[centre], axis=1) - 1.0) < 1e-9)   # its 4 grid neighbours
    far = np.linalg.norm(v - v[centre], axis=1) > 2.5
    moved = np.linalg.norm(x - before, axis=1)
    assert moved[beside].max() < moved[far].max()


def _split(v: np.ndarray, tris: np.ndarray, column_x: float):
    """The grid cut along the column x = ``column_x``: the triangles right of it use copies of the
    column's vertices (appended), as the default face's head shell meets its face. (vertices, triangles,
    (k, 2) (copy, original) pairs)."""
    column = np.flatnonzero(np.abs(v[:, 0] - column_x) < 1e-9)
    copies = len(v) + np.arange(len(column))
    index = np.arange(len(v))
    index[column] = copies
    right = v[tris].mean(axis=1)[:, 0] > column_x
    split = tris.copy()
    split[right] = index[tris[right]]
    return np.concatenate([v, v[column]]), split, np.stack([copies, column], axis=1)


def test_a_seam_that_moves_as_one_is_smoothed_as_one_surface():
    """Cut through the fold, the two sides were smoothed each on its own: ``joined`` seam copies make
    the result the uncut grid's, the copies following their originals."""
    v, tris = _grid()
    x_whole = _bump(v, 3.0)
    SurfaceGuard(v, tris, np.zeros(len(v), bool)).apply(x_whole)
    centre_x = float(v[np.argmin(np.linalg.norm(v - v.mean(axis=0), axis=1)), 0])
    cut_v, cut_tris, pairs = _split(v, tris, centre_x)
    x_joined = _bump(cut_v, 3.0)
    assert SurfaceGuard(cut_v, cut_tris, np.zeros(len(cut_v), bool), pairs).apply(x_joined)
    np.testing.assert_allclose(x_joined[:len(v)], x_whole, atol=1e-12)
    np.testing.assert_array_equal(x_joined[pairs[:, 0]], x_joined[pairs[:, 1]])
    x_apart = _bump(cut_v, 3.0)
    SurfaceGuard(cut_v, cut_tris, np.zeros(len(cut_v), bool)).apply(x_apart)
    assert np.abs(x_apart[:len(v)] - x_whole).max() > 0.05       # each side alone: another surface


def test_skin_on_an_eyeball_slides_on_it_when_smoothed():
    """A cap of skin lying on a 24 mm ball, folded along the ball's surface: smoothed freely its
    vertices cut inside the ball; as ``balls`` skin they keep their distance from its centre, and the
    fold is still undone."""
    v, tris = _grid()
    v = v - v.mean(axis=0)
    radius = 24.0
    v[:, 2] = np.sqrt(radius ** 2 - v[:, 0] ** 2 - v[:, 1] ** 2)
    ball_vertex = np.array([[0.0, 0.0, 0.0]])           # the ball's own vertex: its motion is the ball's
    rest = np.concatenate([v, ball_vertex])
    centre, anchors = np.zeros(3), np.array([len(v)])

    def on_sphere(x):
        return x * (radius / np.linalg.norm(x, axis=1))[:, None]

    folded = rest.copy()
    bump = 3.0 * np.exp(-(v[:, 0] ** 2 + v[:, 1] ** 2) / (2 * 1.2 ** 2))      # _bump's, about the cap's top
    folded[:len(v)] = on_sphere(v + bump[:, None] * np.array([1.0, 0.0, 0.0]))
    assert _breaks(v, tris, folded[:len(v)])[0] > 0
    skin = np.arange(len(v))
    free = folded.copy()
    SurfaceGuard(rest, tris, np.zeros(len(rest), bool)).apply(free)
    assert np.linalg.norm(free[:len(v)], axis=1).min() < radius - 0.01      # chords cut into the ball
    sliding = folded.copy()
    assert SurfaceGuard(rest, tris, np.zeros(len(rest), bool), balls=((skin, centre, anchors),)).apply(sliding)
    np.testing.assert_allclose(np.linalg.norm(sliding[:len(v)], axis=1), radius, atol=1e-9)
    assert _breaks(v, tris, sliding[:len(v)])[0] == 0


def test_pinned_vertices_stay_exactly_where_their_layer_put_them():
    """A dragged control point is pinned for the pose: the guard smooths around it, not it."""
    v, tris = _grid()
    guard = SurfaceGuard(v, tris, np.zeros(len(v), bool))
    peak = int(np.argmin(np.linalg.norm(v - v.mean(axis=0), axis=1)))
    folded = _bump(v, 3.0)
    for compiled in (True, False):
        x = folded.copy()
        if not compiled:
            x = np.asfortranarray(x)                       # not C-contiguous: the numpy path
        assert guard.apply(x, np.array([peak]))
        np.testing.assert_array_equal(x[peak], folded[peak])
        assert np.abs(x - folded).max() > 0.1              # the rest was smoothed


def test_the_guard_acts_continuously_as_a_pose_grows():
    """Sweeping the bump's amplitude in fine steps through where the guard starts acting, up to
    twice where it folds: no vertex of the guarded pose moves more than 2.5 times what the bump's
    peak moves per step (a threshold would jump by millimetres), and the end does not fold."""
    v, tris = _grid(31, 31)
    guard = SurfaceGuard(v, tris, np.zeros(len(v), bool))
    amplitudes = np.linspace(0.2, 4.4, 211)
    previous, acted = None, []
    worst = 0.0
    for a in amplitudes:
        x = _bump(v, a, width_mm=2.0)
        acted.append(guard.apply(x))
        if previous is not None:
            worst = max(worst, np.abs(x - previous).max())
        previous = x
    per_step = amplitudes[1] - amplitudes[0]
    assert not acted[0] and acted[-1]                            # the sweep crosses the onset
    assert _breaks(v, tris, _bump(v, amplitudes[-1], width_mm=2.0))[0] > 0 and _breaks(v, tris, previous)[0] == 0
    assert worst < 2.5 * per_step, (worst, per_step)


def test_the_compiled_guard_is_the_numpy_one(monkeypatch):
    """The severity check and the smoothing as numba kernels give the numpy path's numbers (a held
    strip across the bump, so the taper and the held rows are compared too)."""
    from core.layers.fap import kernels

    built = kernels.get()
    if built is None:
        pytest.skip("numba is not installed: only the numpy path exists")
    v, tris = _grid()
    held = np.abs(v[:, 1] - 14.0) < 0.5
    guard = SurfaceGuard(v, tris, held)
    rng = np.random.default_rng(4)
    x = _bump(v, 3.0) + rng.normal(0.0, 0.05, v.shape) * (rng.random(len(v)) < 0.5)[:, None]
    compiled, compiled_pose = guard.severity(x), x.copy()
    assert guard.apply(compiled_pose)
    monkeypatch.setattr(kernels, "get", lambda: None)
    reference, reference_pose = guard.severity(x), x.copy()
    assert guard.apply(reference_pose)
    assert (reference > 0).sum() > 10 and (reference == 0).sum() > 10
    np.testing.assert_allclose(compiled, reference, atol=1e-9)
    np.testing.assert_allclose(compiled_pose, reference_pose, atol=1e-9)
    assert np.abs(reference_pose - x).max() > 0.1
    # The compiled check measures again only around what changed since its last pose: a second bump
    # elsewhere, then the first one gone, give what a fresh guard measures.
    monkeypatch.setattr(kernels, "get", lambda: built)
    for pose in (x + _bump(v - [8.0, 8.0, 0.0], 2.5) - v, v + 0.0):
        remembered = guard.severity(pose)
        np.testing.assert_array_equal(remembered, SurfaceGuard(v, tris, held).severity(pose))
    assert not remembered.any()


def test_a_region_smooths_only_its_own_strain():
    """With a region, only strain on its triangles is smoothed: of two folding bumps, the one outside
    the region stays as it was, bit for bit, and the region's own is unfolded as by a whole pass;
    each region keeps its own last check (after region passes, a whole pass gives a fresh guard's)."""
    v, tris = _grid(41, 25)
    guard = SurfaceGuard(v, tris, np.zeros(len(v), bool))

    def bump(centre_x):        # _bump's push, centred at x = centre_x on the grid's middle row
        g = np.exp(-np.sum((v - [centre_x, v[:, 1].mean(), 0.0]) ** 2, axis=1) / (2 * 1.2 ** 2))
        return 3.0 * g[:, None] * np.array([1.0, 0.0, 0.0])

    left, right = bump(10.0), bump(30.0)
    both = v + left + right
    region = guard.region("left", np.flatnonzero(v[:, 0] < v[:, 0].mean()))
    x = both.copy()
    assert guard.apply(x, region=region)
    far_right = v[:, 0] > v[:, 0].mean() + 2.0
    np.testing.assert_array_equal(x[far_right], both[far_right])
    assert _breaks(v, tris, x)[0] > 0                           # the right bump still folds
    alone = v + left
    assert guard.apply(alone)
    far_left = v[:, 0] < v[:, 0].mean() - 2.0
    np.testing.assert_allclose(x[far_left], alone[far_left], atol=1e-12)
    assert _breaks(v, tris[far_left[tris].all(axis=1)], x)[0] == 0
    expected = both.copy()
    SurfaceGuard(v, tris, np.zeros(len(v), bool)).apply(expected)
    whole = both.copy()
    assert guard.apply(whole)
    np.testing.assert_array_equal(whole, expected)
    assert _breaks(v, tris, whole)[0] == 0


def test_the_teeth_pushes_are_smoothed_at_the_mouth(generated_rig):
    """On the generated identity, joy + viseme FF pushed one upper-lip vertex 1.1 mm out of the teeth
    beside neighbours pushed 0.14 mm: its triangles stretched 2.39 x. The mouth is smoothed again
    after the teeth guard: within bounds, nothing in the teeth, and the lips not crossing."""
    rig = generated_rig
    probe = FaceQualityProbe(rig.face)
    rig.reset()
    rig.set_expression("joy", 1.0)
    rig.set_viseme("FF", 1.0)
    x = rig.vertices()
    rig.reset()
    quality = probe.measure(x)
    assert quality.max_stretch <= 2.0 and quality.min_stretch >= 0.25 and quality.folded_triangles == 0, quality
    assert quality.teeth_intersections == 0 and quality.lip_intersections == 0


def test_the_mouth_corner_no_longer_folds_at_a_corner_stretch(default_rig):
    """stretch_cornerlip 400 turned three triangles at the default face's mouth corner (the corner
    moved 7.9 mm, the skin 0.9 mm beyond it 7.2 mm); guarded, none turns and the corner still moves."""
    rig = default_rig
    probe = FaceQualityProbe(rig.face)
    rig.reset()
    rig.set_fap(6, 400)
    x = rig.vertices()
    rig.reset()
    quality = probe.measure(x)
    assert quality.folded_triangles == 0 and quality.max_stretch <= 2.0 and quality.min_stretch >= 0.25
    corner = rig.face.landmark_position("8.3")
    moved = np.linalg.norm(x - rig.face.vertices, axis=1)
    near = np.linalg.norm(rig.face.vertices - corner, axis=1) < 2.0
    assert 5.0 < moved[near].max() < 9.0
