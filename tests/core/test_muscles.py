"""Biomechanical muscle model (thesis C): known answers on the default face's 1160-vertex tissue."""

import json
import re

import numpy as np
import pytest

from core.default_face import load_default_face
from core.layers.muscles import (ForceFileError, ForceSet, MuscleLayer, SolverDiverged, control_keys, load_force_set,
                          muscle_specs, preset, preset_names, save_force_set)
from core.layers.muscles.kernels import HAVE_NUMBA, SpringKernels
from core.layers.muscles import muscles as muscles_module
from core.layers.muscles.model import load_definitions
from core.layers.muscles.specs import spec_by_name
from core.mesh_quality import _local_frames, principal_stretches
from core.layers.muscles.solver import State

MIRROR_PAIRS = [("8.3", "8.4"), ("8.5", "8.6"), ("8.7", "8.8"), ("2.4", "2.5"), ("2.6", "2.7"), ("2.8", "2.9")]


@pytest.fixture(scope="module")
def face():
    return load_default_face()


@pytest.fixture(scope="module")
def layer(face):
    return MuscleLayer(face, level=2)


@pytest.fixture
def fresh(layer):
    layer.reset()
    layer.integrator = "stable"
    layer.explicit_step = 0.01
    yield layer
    layer.reset()
    layer.integrator = "stable"


def skin_disp(layer, name):
    """(3,) mm displacement of the template vertex at feature point ``name``."""
    i = layer.model.template.index(name)
    return layer.tissue_skin()[i] - layer.model.skin_mm[i]


def free_disp(layer):
    return layer._state.x - layer.model.rest[:layer.model.n_free]


# ------------------------------------------------------------------ data
def test_specs_keys_and_presets():
    specs = muscle_specs()
    assert len(specs) == 10 and sum(s.paired for s in specs) == 9
    assert specs[-1].name == "orbicularis_oris" and not specs[-1].paired
    keys = control_keys()
    assert len(keys) == 19 and keys[-1] == ("orbicularis_oris", None)
    assert ("zygomatic_major", "left") in keys and ("mentalis", "right") in keys
    assert preset_names() == ("discreet_smile", "half_smile", "sadness", "disgust", "kiss")
    from core.layers.muscles import preset_id

    # By id or by the name the window shows, in any case and spacing.
    assert preset_id("kiss") == preset_id("Kiss") == preset_id(" KISS ") == "kiss"
    assert preset_id("Half smile, mouth open") == preset_id("half-smile") == "half_smile"
    assert preset_id("grin") is None and preset_id("") is None
    smile = preset("discreet_smile").full()
    assert smile[("risorius", "left")] == smile[("risorius", "right")] == 42
    disgust = preset("disgust").forces
    assert disgust[("zygomatic_minor", "left")] == 14 and ("zygomatic_minor", "right") not in disgust
    assert disgust[("mentalis", "left")] == 2 and disgust[("mentalis", "right")] == 1
    assert preset("kiss").forces == {("orbicularis_oris", None): 8.0}
    assert preset("half_smile").jaw_deg > 0


def test_mirror_map_matches_the_default_face(face):
    for left, right in load_definitions()["mirror"].items():
        a, b = face.landmark_position(left), face.landmark_position(right)
        assert np.allclose(a * [-1, 1, 1], b, atol=0.5), (left, right)
        assert left == right or a[0] > 0  # definitions are for the face's own left (+x, FP 8.3)


# ------------------------------------------------------------------ force files
def test_force_file_round_trip(tmp_path):
    fs = preset("disgust")
    fs.jaw_deg = 4.5
    path = tmp_path / "disgust.json"
    save_force_set(path, fs)
    text = path.read_text()
    assert '"zygomatic_minor"' in text and "\n  " in text  # human-readable
    back = load_force_set(path)
    assert back.full() == fs.full() and back.jaw_deg == 4.5 and back.name == fs.name


@pytest.mark.parametrize("content, expected", [
    ("{not json", "is not valid JSON: Expecting property name enclosed in double quotes at line 1"),
    ({"format": "mimica-muscle-forces", "version": 1, "forces": {"buccinator": 3}}, "unknown muscle 'buccinator'"),
    ({"format": "mimica-muscle-forces", "version": 1, "forces": {"risorius": {"middle": 3}}}, "bad side 'middle'"),
    ({"format": "mimica-muscle-forces", "version": 1, "forces": {"risorius": {"left": "strong"}}}, "must be a number"),
    ({"format": "mimica-muscle-forces", "version": 1, "forces": {"risorius": {"left": 900}}}, "outside its range"),
    ({"format": "mimica-muscle-forces", "version": 1, "forces": {"risorius": 5}}, "left/right pair"),
    ({"format": "mimica-muscle-forces", "version": 7, "forces": {}}, "newer Mimica"),
    ({"format": "mimica-muscle-forces", "version": 1, "jaw_deg": 90, "forces": {}}, "jaw opening 90"),
    ({"format": "something-else", "version": 1}, "not a Mimica muscle force file"),
    ([1, 2], "expected a JSON object"),
])
def test_malformed_force_files_give_clear_messages(tmp_path, content, expected):
    path = tmp_path / "bad.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(ForceFileError, match=re.escape(expected)) as info:
        load_force_set(path)
    assert "bad.json" in str(info.value)
    assert isinstance(info.value, ValueError)


def test_missing_file_and_bad_save(tmp_path):
    with pytest.raises(ForceFileError, match="does not exist"):
        load_force_set(tmp_path / "nope.json")
    with pytest.raises(ForceFileError, match="outside its range"):
        save_force_set(tmp_path / "x.json", ForceSet({("risorius", "left"): -1.0}))
    assert not (tmp_path / "x.json").exists()


# ------------------------------------------------------------------ controls
def test_control_validation_is_atomic_and_never_clamps(fresh):
    fresh.set_force("risorius", "left", 10)
    for bad, msg in [(("buccinator", "left", 1), "unknown muscle"), (("risorius", None, 1), "side must be"),
                     (("orbicularis_oris", "left", 1), "side must be None"), (("risorius", "left", 61), "outside"),
                     (("risorius", "left", float("nan")), "finite"), (("risorius", "left", "3"), "number")]:
        with pytest.raises(ValueError, match=msg):
            fresh.set_force(*bad)
    with pytest.raises(ValueError):
        fresh.set_forces({("mentalis", "left"): 5, ("risorius", "right"): 1000})
    assert fresh.forces()[("mentalis", "left")] == 0 and fresh.forces()[("risorius", "left")] == 10
    with pytest.raises(ValueError, match="jaw"):
        fresh.set_jaw(-30)
    assert len(fresh.forces()) == 19


# ------------------------------------------------------------------ rest and energy
def test_zero_forces_stay_at_rest_for_10_seconds(fresh):
    assert fresh.converged and fresh.relax().iterations == 0
    fresh.start_animation()
    for _ in range(300):
        fresh.advance(1 / 30)
    assert fresh.time == pytest.approx(10.0)
    assert np.abs(free_disp(fresh)).max() < 1e-9
    assert np.abs(fresh.skin_offsets()).max() < 1e-12


def test_unforced_motion_loses_energy(fresh):
    fresh.apply(preset("discreet_smile"))
    fresh.solve()
    solver, state = fresh.solver, fresh._state.copy()
    state.act[:] = 0.0          # release all muscles at once: free, damped motion back to rest
    state.act_rate[:] = 0.0
    frame = solver.frame(0.0)
    targets = np.zeros(len(control_keys()))
    energies = [solver.energy(state.x, state.v, frame)]
    for _ in range(90):
        solver.advance_stable(state, targets, 0.0, 1 / 30, solver.frame)
        energies.append(solver.energy(state.x, state.v, frame))
    e = np.array(energies)
    assert e[0] > 0
    assert np.all(np.diff(e) <= 1e-9 * e[0])   # never gains energy
    assert e[-1] < 0.05 * e[0]


# ------------------------------------------------------------------ one linear muscle
def test_linear_muscle_pulls_P_toward_R_and_only_inside_its_cylinder(fresh):
    key = ("risorius", "left")
    mus = fresh.muscles.linear[control_keys().index(key)]
    m = fresh.model
    frame = fresh.solver.frame(0.0)
    act = np.zeros(19)
    act[control_keys().index(key)] = 30.0
    f = fresh.solver.muscle_force(frame, act)
    pushed = np.nonzero(np.linalg.norm(f, axis=1) > 0)[0]
    assert set(pushed) <= set(mus.nodes) and len(pushed) > 3
    # every pushed vertex is inside the finite cylinder around P -> R, continued behind P by the insertion
    p, r = mus.P.position(m, m.rest), mus.R.position(m, m.rest)
    u = (r - p) / np.linalg.norm(r - p)
    q = m.rest[pushed]
    t = (q - p) @ u
    across = np.linalg.norm(q - p - t[:, None] * u, axis=1)
    behind = fresh.muscles.insertion_cm
    assert behind > 0 and np.any(t < 0)
    assert np.all(t >= -behind) and np.all(t <= np.linalg.norm(r - p)) and np.all(across < mus.radius_cm)
    fresh.set_force(*key, 30.0)
    assert fresh.solve().converged
    x = fresh._state.x
    moved = mus.P.position(m, x) - p
    assert moved @ u > 0.1                        # cm: the mobile end moves > 1 mm toward R
    assert moved @ u > 0.8 * np.linalg.norm(moved)  # and mostly along the muscle
    mirror = fresh.muscles.linear[control_keys().index(("risorius", "right"))]
    assert np.linalg.norm(mirror.P.position(m, x) - mirror.P.position(m, m.rest)) < 0.1 * np.linalg.norm(moved)


def test_insertion_spreads_the_pull_behind_the_mobile_end_and_keeps_its_total(fresh, monkeypatch):
    """The thesis cylinder (no insertion) ends at P; the insertion moves part of the same total pull
    behind P, so the heaviest node pulls less and the corner's skin stretches less in a smile."""
    m, muscles = fresh.model, fresh.muscles
    area = m.area_scale
    for mus in muscles.linear:
        monkeypatch.setattr(muscles, "insertion_cm", 0.0)
        nodes, weight = muscles._cylinder(mus.P, mus.R, mus.radius_cm, spec_by_name()[mus.key[0]].lip)
        monkeypatch.undo()
        p, r = mus.P.position(m, m.rest), mus.R.position(m, m.rest)
        assert np.all((m.rest[nodes] - p) @ (r - p) >= 0)     # thesis C: nothing behind P
        assert (mus.weight * area[mus.nodes]).sum() == pytest.approx((weight * area[nodes]).sum(), rel=1e-9)
        assert mus.weight.max() < weight.max()

    def corner_stretch(layer):
        layer.apply(preset("discreet_smile"))
        assert layer.solve().converged
        T = layer.model.triangles
        rest, posed = layer.model.skin_mm[T], layer.tissue_skin()[T]
        near = np.linalg.norm(rest.mean(axis=1) - layer.face.landmark_position("8.3"), axis=1) < 6.0
        big, _ = principal_stretches(_local_frames(rest[near]), posed[near])
        return big.max()

    definitions = dict(load_definitions(), insertion={"spread": 0.0, "unit": "MW"})
    monkeypatch.setattr(muscles_module, "load_definitions", lambda: definitions)
    thesis = MuscleLayer(fresh.face, level=2)
    assert thesis.muscles.insertion_cm == 0.0
    assert corner_stretch(fresh) < corner_stretch(thesis) - 0.1


# ------------------------------------------------------------------ presets
def test_symmetric_preset_gives_mirror_symmetric_result(fresh):
    fresh.apply(preset("discreet_smile"))
    assert fresh.solve().converged
    scale = np.abs(skin_disp(fresh, "8.3")).max()
    assert scale > 3.0  # mm: the corner visibly moves
    for left, right in MIRROR_PAIRS:
        a, b = skin_disp(fresh, left), skin_disp(fresh, right)
        assert np.allclose(a * [-1, 1, 1], b, atol=0.03 * scale), (left, right, a, b)


def test_smile_raises_corners_up_and_back(fresh):
    fresh.apply(preset("discreet_smile"))
    fresh.solve()
    for corner, outward in (("8.3", 1), ("8.4", -1)):
        d = skin_disp(fresh, corner)
        assert d[1] > 1.5 and d[0] * outward > 2.0 and d[2] < 0  # up, out, back


def test_sadness_lowers_the_mouth_corners(fresh):
    fresh.apply(preset("sadness"))
    fresh.solve()
    for corner in ("8.3", "8.4"):
        assert skin_disp(fresh, corner)[1] < -2.0


def test_disgust_raises_left_upper_lip_more_than_right(fresh):
    fresh.apply(preset("disgust"))
    fresh.solve()
    left, right = skin_disp(fresh, "8.5"), skin_disp(fresh, "8.6")
    assert left[1] > right[1] + 0.5 and left[1] > 0.5


def test_kiss_moves_lips_forward_and_narrows_the_mouth(fresh):
    """Thesis C's kiss (orbicularis oris 8, Table 5.6) visibly purses the lips: forward by more than
    half a centimetre, the mouth a centimetre narrower (before the sphincter's gain was calibrated it
    was hard to see from the front)."""
    fresh.apply(preset("kiss"))
    fresh.solve()
    for p in ("8.1", "8.2", "2.2", "2.3", "8.5", "8.7"):
        assert skin_disp(fresh, p)[2] > 6.0, p
    width0 = fresh.model.skin_mm[fresh.model.template.index("8.3"), 0] * 2
    width = skin_disp(fresh, "8.3")[0] - skin_disp(fresh, "8.4")[0] + width0
    assert width < width0 - 10.0


def test_jaw_rotation_opens_the_lips(fresh, face):
    fresh.set_jaw(10.0)
    assert fresh.solve().converged
    for p in ("2.3", "8.2"):
        assert skin_disp(fresh, p)[1] < -3.0, p     # lower lip goes down
    assert skin_disp(fresh, "2.1")[1] < -2.0         # chin too
    for p in ("2.2", "8.1"):
        assert np.abs(skin_disp(fresh, p)).max() < 0.3, p  # upper lip stays
    off = fresh.skin_offsets()
    assert np.abs(off[face.parts["teeth_lower"]]).max() > 3.0
    for part in ("teeth_upper", "eyeball_l", "eyeball_r", "mouth_cavity"):
        assert not off[face.parts[part]].any(), part


# ------------------------------------------------------------------ integrators
def _equilibrium(layer, key, value):
    layer.reset()
    layer.set_force(*key, value)
    frame = layer.solver.frame(0.0)
    state = layer._state.copy()
    state.act[control_keys().index(key)] = value
    layer.solver.relax(state, frame, budget_s=10.0, tolerance=1e-4)
    return state.x


def _simulate(layer, key, value, dt, seconds, integrator="stable"):
    layer.reset()
    layer.integrator = integrator
    layer.set_force(*key, value)
    layer.start_animation()
    for _ in range(int(round(seconds / dt))):
        layer.advance(dt)
    return layer._state.x.copy()


def test_stable_integrator_same_equilibrium_for_two_step_sizes_and_matches_explicit(fresh):
    key, value = ("zygomatic_major", "left"), 25.0
    x_eq = _equilibrium(fresh, key, value)
    rest = fresh.model.rest[:fresh.model.n_free]
    scale = np.linalg.norm(x_eq - rest, axis=1).max()
    a = _simulate(fresh, key, value, 1 / 30, 16.0)
    b = _simulate(fresh, key, value, 1 / 60, 16.0)
    c = _simulate(fresh, key, value, 1 / 30, 16.0, integrator="explicit")   # thesis Euler, Δt = 0.01 s
    for x in (a, b, c):
        assert np.linalg.norm(x - x_eq, axis=1).max() < 0.01 * scale
    assert np.linalg.norm(a - c, axis=1).max() < 0.01 * scale


def test_activation_ramps_like_eq_3_16(fresh):
    fresh.set_force("risorius", "left", 40.0)
    fresh.start_animation()
    tau = fresh.model.params.tau
    fresh.advance(tau)
    a = fresh.activations()[("risorius", "left")]
    assert a == pytest.approx(40.0 * (1 - 2 * np.exp(-1)), rel=1e-9)  # critically damped: 1 - (1 + t/τ) e^(-t/τ)


def test_divergence_is_caught_and_state_restored(fresh):
    fresh.apply(preset("discreet_smile"))
    fresh.solve()
    before = fresh.skin_offsets().copy()
    snap = fresh.snapshot()
    fresh.integrator = "explicit"
    fresh.explicit_step = 0.2            # far beyond the explicit limit (about 20 ms)
    fresh.set_force("risorius", "left", 60.0)
    with pytest.raises(SolverDiverged, match="Lower the muscle forces") as info:
        fresh.advance(2.0)
    assert isinstance(info.value, ValueError)
    assert np.isfinite(fresh._state.x).all()
    assert np.array_equal(fresh.skin_offsets(), before)
    fresh.restore(snap)
    assert fresh.converged and np.array_equal(fresh.skin_offsets(), before)


def test_snapshot_restore_round_trip(fresh):
    fresh.set_force("depressor_anguli_oris", "right", 20)
    fresh.start_animation()
    fresh.advance(0.2)
    snap = fresh.snapshot()
    x = fresh._state.x.copy()
    fresh.advance(0.5)
    fresh.restore(snap)
    assert np.array_equal(fresh._state.x, x)
    assert fresh.forces()[("depressor_anguli_oris", "right")] == 20
    fresh.advance(0.5)
    fresh.restore(snap)
    with pytest.raises(ValueError):
        fresh.restore(object())


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")
def test_numpy_and_numba_kernels_agree(fresh):
    m = fresh.model
    rng = np.random.default_rng(1)
    x = m.rest + 0.02 * rng.standard_normal(m.rest.shape)
    l0 = np.linalg.norm(m.rest[m.springs_i] - m.rest[m.springs_j], axis=1)
    outs = []
    for backend in ("numba", "numpy"):
        k = SpringKernels(backend)
        f, r, v = np.zeros_like(x), np.zeros_like(x), np.zeros(m.n)
        k.forces(x, m.springs_i, m.springs_j, m.springs_k, l0, f)
        k.rhs(x, m.springs_i, m.springs_j, m.springs_k, l0, r)
        k.prism_dv(x, m.triangles, m.n, np.zeros(len(m.triangles)), v)
        outs.append((f, r, v))
    for a, b in zip(*outs):
        assert np.allclose(a, b, rtol=1e-10, atol=1e-10)


# ------------------------------------------------------------------ rig composition
def test_layer_composes_with_the_face_rig(face, layer):
    from core.rig import FaceRig

    layer.reset()
    rig = FaceRig(face)
    plain = rig.vertices().copy()
    layer.attach(rig)
    try:
        assert np.array_equal(rig.vertices(), plain)   # zero forces leave the rig unchanged
        calls = []
        rig.changed.connect(lambda: calls.append(1))
        layer.set_force("zygomatic_major", "left", 30)
        assert not calls                                 # a new force alone does not move the face yet
        layer.solve()
        assert calls                                     # the new pose touches the rig
        moved = np.linalg.norm(rig.vertices() - plain, axis=1)
        assert moved.max() > 2.0
        corner = face.landmark_position("8.3")
        near = np.linalg.norm(face.vertices - corner, axis=1) < 5
        assert moved[near].mean() > 1.0
        rig.set_fap("open_jaw", 200)                      # FAPs and muscles add
        both = rig.vertices()
        layer.reset()
        assert not np.array_equal(rig.vertices(), both)
    finally:
        rig.remove_layer("muscles")
        layer.pose_changed.disconnect(rig.touch)
        layer._rig = None
        layer.reset()


def test_segments_and_ring_for_drawing(fresh):
    fresh.set_force("mentalis", "left", 30)
    segs = fresh.muscle_segments()
    assert len(segs) == 18
    name, side, P, R, a = next(s for s in segs if s[:2] == ("mentalis", "left"))
    assert P.shape == R.shape == (3,) and a == 0.0      # not yet activated
    fresh.solve()
    a = next(s for s in fresh.muscle_segments() if s[:2] == ("mentalis", "left"))[4]
    assert a == pytest.approx(0.5)
    ring, act = fresh.muscle_ring()
    assert ring.shape == (10, 3) and act == 0.0


def test_state_api_smoke(layer):
    assert isinstance(layer._state, State)
    assert layer.node_count == 3 * 1160 and layer.spring_count > 9000


def test_muscle_package_names_resolve_lazily_without_the_solver():
    """The window's muscle dock lists the presets at start-up: ``core.layers.muscles.preset_names``
    must not import the solver (and numba) before the face is on screen; every other public name still
    resolves, and an unknown one is an AttributeError."""
    from tests.core.conftest import run_fresh_python

    code = ("import sys\n"
            "from core.layers.muscles import preset_names\n"
            "print(len(preset_names()), 'core.layers.muscles.solver' in sys.modules, 'numba' in sys.modules)\n"
            "import core.layers.muscles as m\n"
            "print(all(getattr(m, name) is not None for name in m.__all__))\n"
            "try:\n    m.no_such_name\nexcept AttributeError:\n    print('AttributeError')\n")
    out = run_fresh_python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["5", "False", "False", "True", "AttributeError"]
