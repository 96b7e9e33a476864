"""Timeline: parameter keys, interpolation, vectorised evaluation, reversible edits, rig application,
and the simulated-layer cache (against a 1-D damped system integrated exactly)."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pytest

from core import timeline as T
from core.layers.fap import tables
from core.timeline import Key, MuscleSimulationCache, Timeline, TimelineError, Track, apply_to_rig


# ---------------------------------------------------------------- keys
@pytest.mark.parametrize("key, canonical", [
    ("fap:3", "fap:3"), ("fap:open_jaw", "fap:3"), (" FAP:19 ", "fap:19"), ("expression:Joy", "expression:joy"),
    ("expression:1", "expression:joy"), ("viseme:1", "viseme:1"), ("viseme:PP", "viseme:1"),
    ("muscle:zygomatic_major:left", "muscle:zygomatic_major:left"), ("muscle:orbicularis_oris", "muscle:orbicularis_oris"),
    ("jaw", "jaw"),
])
def test_canonical_keys(key, canonical):
    assert T.canonical_key(key) == canonical


@pytest.mark.parametrize("key, words", [
    ("eyebrow:3", "unknown parameter"), ("fap:1", "viseme:<id>"), ("fap:2", "expression:<name>"),
    ("fap:99", "1 to 68"), ("fap:1.5", "unknown FAP name"), ("viseme:0", "silence"), ("viseme:15", "0 to 14"),
    ("expression:neutral", "absence"), ("expression:bored", "unknown expression"),
    ("muscle:zygomatic_major:up", "left/right pair"), ("muscle:Bad-Name", "unknown muscle"), ("jaw:2", "just 'jaw'"),
    ("fap:", "FAP keys"),
])
def test_bad_keys_raise_clear_errors(key, words):
    with pytest.raises(ValueError, match=words):
        T.canonical_key(key)


def test_gaze_fap_not_animated_by_mimica_is_refused():
    spec = next(s for s in tables.fap_specs() if s.number > 2 and not math.isfinite(s.minimum))
    with pytest.raises(TimelineError, match="not animated"):
        T.canonical_key(f"fap:{spec.number}")


def test_muscle_keys_are_checked_against_the_muscle_table():
    with pytest.raises(TimelineError, match="outside its range 0 to 60"):
        Track("muscle:risorius:left", [(0.0, 61.0)])
    with pytest.raises(TimelineError, match="jaw angle"):
        Track("jaw", [(0.0, 30.0)])
    assert T.canonical_key("muscle:risorius:right") == "muscle:risorius:right"
    with pytest.raises(TimelineError, match="unknown muscle"):
        T.canonical_key("muscle:biceps:left")
    with pytest.raises(TimelineError, match="left/right pair"):
        T.canonical_key("muscle:risorius")
    with pytest.raises(TimelineError, match="single muscle"):
        T.canonical_key("muscle:orbicularis_oris:left")


@pytest.mark.parametrize("key, value, words", [
    ("fap:3", 5000, "outside its range"), ("viseme:3", 1.2, "outside its range 0 to 1"), ("expression:joy", -0.1, "0 to 1"),
    ("muscle:risorius:left", -1, "outside its range 0 to"), ("jaw", float("nan"), "finite"), ("fap:3", "x", "numbers"),
])
def test_values_are_checked_not_clamped(key, value, words):
    with pytest.raises(TimelineError, match=words):
        Track(key, [(0.0, value)])


def test_keys_must_fit_the_timeline_and_be_distinct():
    tl = Timeline(2.0, 30)
    with pytest.raises(TimelineError, match="extend the duration"):
        tl.set_key("fap:3", 2.5, 10)
    with pytest.raises(TimelineError, match="same time"):
        Track.from_arrays("fap:3", [0.0, 0.0], [1, 2], [2, 2])
    with pytest.raises(TimelineError, match="frame rate"):
        Timeline(1.0, 29)
    with pytest.raises(TimelineError, match="duration"):
        Timeline(0.0, 30)
    with pytest.raises(TimelineError, match="interpolation"):
        tl.set_key("fap:3", 1.0, 10, "cubic")


# ---------------------------------------------------------------- interpolation
def _random_track(rng, n=12, key="fap:3", codes=None) -> Track:
    times = np.cumsum(rng.uniform(0.05, 0.5, n))
    values = rng.uniform(-150, 1300, n) if key == "fap:3" else rng.uniform(0, 1, n)
    values = np.clip(values, 0, 1400) if key == "fap:3" else values
    codes = rng.integers(0, 3, n) if codes is None else np.full(n, codes)
    return Track.from_arrays(key, times, values, codes)


@pytest.mark.parametrize("code", [0, 1, 2])
def test_keys_are_hit_exactly_and_ends_hold(code):
    tr = _random_track(np.random.default_rng(code), codes=code)
    np.testing.assert_array_equal(tr.evaluate(tr.times), tr.values)
    assert tr.evaluate(tr.times[0] - 5) == tr.values[0]
    assert tr.evaluate(tr.times[-1] + 5) == tr.values[-1]


def test_step_and_linear():
    tr = Track("fap:3", [(0.0, 100, "step"), (1.0, 300, "linear"), (2.0, 500, "smooth")])
    assert tr.evaluate(0.999) == 100
    assert tr.evaluate(1.5) == pytest.approx(400)
    assert tr.evaluate(1.25) == pytest.approx(350)


def test_smooth_stays_within_neighbouring_keys_and_eases_at_ends():
    rng = np.random.default_rng(5)
    for _ in range(20):
        tr = _random_track(rng, codes=2)
        for i in range(len(tr) - 1):
            ts = np.linspace(tr.times[i], tr.times[i + 1], 50)
            v = tr.evaluate(ts)
            lo, hi = sorted((tr.values[i], tr.values[i + 1]))
            assert v.min() >= lo - 1e-9 and v.max() <= hi + 1e-9
            assert np.all(np.diff(v) * np.sign(tr.values[i + 1] - tr.values[i]) >= -1e-9)  # monotone segment
    tr = Track("expression:joy", [(0.0, 0.0), (1.0, 1.0)])
    eps = 1e-4
    assert (tr.evaluate(eps) - tr.evaluate(0.0)) / eps < 1e-2  # zero slope at the first key
    assert tr.evaluate(0.5) == pytest.approx(0.5)


def test_smooth_is_c1_at_interior_keys():
    tr = Track("fap:3", [(0.0, 0.0), (1.0, 400.0), (1.5, 900.0), (3.0, 1000.0)])
    h = 1e-6
    left = (tr.evaluate(1.0) - tr.evaluate(1.0 - h)) / h
    right = (tr.evaluate(1.0 + h) - tr.evaluate(1.0)) / h
    assert left == pytest.approx(right, rel=1e-3) and left > 0


def test_vectorised_timeline_evaluation_matches_each_track():
    rng = np.random.default_rng(1)
    tl = Timeline(60.0, 30)
    keys = {}
    for n in tables.thesis_faps()[:20]:
        spec = tables.fap_spec(n)
        k = int(rng.integers(1, 9))
        times = np.sort(rng.choice(np.arange(0, 40, 0.1), k, replace=False))
        keys[f"fap:{n}"] = [(t, rng.uniform(spec.minimum, spec.maximum), T.INTERPOLATIONS[rng.integers(0, 3)])
                            for t in times]
    keys["viseme:4"] = [(3.0, 0.5)]
    tl.add_keys(keys)
    for t in np.concatenate([rng.uniform(-1, 61, 50), [0.0, 40.0, 3.0]]):
        values = tl.evaluate(t)
        assert set(values) == set(tl.tracks)
        for key, v in values.items():
            assert v == pytest.approx(tl.tracks[key].evaluate(t), abs=1e-9)
    names, arr = tl.evaluate_array(3.0, ["viseme:4", "fap:3"])
    assert names == ("viseme:4", "fap:3") and arr[0] == 0.5


# ---------------------------------------------------------------- edits and undo
def _state(tl: Timeline):
    return {k: (tr.times.tolist(), tr.values.tolist(), tr.codes.tolist()) for k, tr in tl.tracks.items()}, \
        (tl.duration, tl.fps)


def test_every_edit_is_undone_by_its_inverse_and_redone():
    tl = Timeline(10.0, 25)
    received = []
    tl.changed.connect(received.append)
    history = []
    history.append((_state(tl), tl.add_keys({"fap:3": [(0, 0), (1, 500), (2, 100)], "viseme:1": [(0.5, 1.0)]})))
    history.append((_state(tl), tl.set_key("fap:3", 1.0, 700)))  # replace, keeps the interpolation
    history.append((_state(tl), tl.move_keys({"fap:3": [1.0, 2.0]}, dt=0.5, dvalue=-50)))
    history.append((_state(tl), tl.set_interpolation({"fap:3": [0.0]}, "step")))
    clip = tl.copy_keys({"fap:3": [1.5, 2.5], "viseme:1": [0.5]})
    assert clip.keys["viseme:1"][0].time == 0.0 and clip.keys["fap:3"][0].time == 1.0
    history.append((_state(tl), tl.paste_keys(clip, 6.0)))
    history.append((_state(tl), tl.delete_keys({"viseme:1": [0.5, 6.0]})))
    history.append((_state(tl), tl.set_settings(duration=20.0, fps=60)))
    history.append((_state(tl), tl.remove_track("fap:3")))
    assert [e.label for e in received] == [e.label for _, e in history]
    assert "fap:3" not in tl and tl.fps == 60
    final = _state(tl)
    for before, edit in reversed(history):
        tl.apply_edit(edit.inverse())
        assert _state(tl) == before
    assert tl.tracks == {} and (tl.duration, tl.fps) == (10.0, 25)
    for _, edit in history:
        tl.apply_edit(edit)
    assert _state(tl) == final


def test_edit_results():
    tl = Timeline(10.0, 30)
    tl.add_keys({"fap:3": [(0, 0, "linear"), (1, 500, "step"), (2, 100)]})
    tl.move_keys({"fap:3": [1.0]}, dt=1.0)  # lands on the key at 2 s and replaces it
    assert tl.track("fap:3").keys == (Key(0.0, 0.0, "linear"), Key(2.0, 500.0, "step"))
    tl.paste_keys(tl.copy_keys({"fap:3": [0.0, 2.0]}), 5.0)
    np.testing.assert_allclose(tl.track("fap:3").times, [0, 2, 5, 7])
    with pytest.raises(TimelineError, match="no key at"):
        tl.delete_keys({"fap:3": [1.0]})
    with pytest.raises(TimelineError, match="outside"):
        tl.move_keys({"fap:3": [7.0]}, dt=5.0)
    with pytest.raises(TimelineError, match="outside its range"):
        tl.move_keys({"fap:3": [2.0]}, dvalue=5000)
    with pytest.raises(TimelineError, match="cannot shorten"):
        tl.set_settings(duration=6.0)
    tl.delete_keys({"fap:3": [0.0, 2.0, 5.0, 7.0]})
    assert "fap:3" not in tl


def test_stale_edit_is_refused():
    tl = Timeline(5.0, 30)
    edit = tl.set_key("fap:3", 1.0, 100)
    tl.set_key("fap:3", 2.0, 200)
    with pytest.raises(TimelineError, match="changed since"):
        tl.apply_edit(edit.inverse())


def test_earliest_change_bounds_where_values_differ():
    rng = np.random.default_rng(3)
    for trial in range(30):
        tl = Timeline(10.0, 30)
        tl.add_keys({"jaw": [(t, rng.uniform(0, 25)) for t in np.sort(rng.choice(np.arange(0, 10, 0.25), 8, False))]})
        before = tl.track("jaw")
        i = int(rng.integers(0, len(before)))
        edit = tl.set_key("jaw", float(before.times[i]), rng.uniform(0, 25), T.INTERPOLATIONS[trial % 3])
        start = edit.earliest_change()
        ts = np.linspace(0, 10, 401)
        ts = ts[ts < start]
        np.testing.assert_array_equal(before.evaluate(ts), tl.track("jaw").evaluate(ts))


# ---------------------------------------------------------------- applying to a rig
class FakeRig:
    """Records what the timeline sets, through the rig's one generic entry point."""

    def __init__(self):
        self.calls = []

    def set_values(self, values):
        self.calls.append(("values", dict(values)))

    @contextlib.contextmanager
    def batch(self):
        self.calls.append(("batch",))
        yield
        self.calls.append(("end",))


def test_apply_to_rig_sets_every_non_simulated_parameter_by_key():
    rig = FakeRig()
    values = {"fap:3": 120.0, "fap:19": 40.0, "expression:joy": 0.3, "expression:anger": 0.6, "viseme:4": 0.25,
              "viseme:1": 0.75, "muscle:risorius:left": 4.0, "muscle:orbicularis_oris": 2.0, "jaw": 7.5}
    apply_to_rig(rig, values)
    assert rig.calls == [("values", {"fap:3": 120.0, "fap:19": 40.0, "expression:joy": 0.3, "expression:anger": 0.6,
                                     "viseme:4": 0.25, "viseme:1": 0.75})]


def test_apply_to_a_real_rig_blends_keyed_presets(default_rig):
    rig = default_rig
    rig.reset()
    try:
        apply_to_rig(rig, {"expression:joy": 0.3, "expression:anger": 0.6, "viseme:4": 0.25, "fap:3": 100.0})
        assert rig.expressions == ((tables.expression_id("anger"), 0.6), (tables.expression_id("joy"), 0.3))
        assert rig.value("viseme:4") == 0.25 and rig.fap_value(3) == 100.0
        apply_to_rig(rig, {"expression:anger": 0.0})
        assert rig.expressions == ((tables.expression_id("joy"), 0.3),)
    finally:
        rig.reset()


# ---------------------------------------------------------------- simulated layer cache
class DampedLayer:
    """x' = -K (x - target), target = sum of forces + jaw / 10; advance integrates exactly."""

    K = 3.0

    def __init__(self):
        self.x, self.forces, self.jaw = 0.0, {}, 0.0
        self.starts = self.relaxes = 0

    def target(self):
        return sum(self.forces.values()) + self.jaw / 10

    def set_values(self, values):
        for key, value in values.items():
            if key == "jaw":
                self.jaw = value
            else:
                self.forces[key] = value

    def start_animation(self):
        self.starts += 1

    def advance(self, dt):
        f = self.target()
        self.x = f + (self.x - f) * math.exp(-self.K * dt)

    def snapshot(self):
        return self.x

    def restore(self, snap):
        self.x = snap

    def relax(self, budget_s):
        self.relaxes += 1
        self.x = self.target()


def _reference(tl: Timeline, frame: int) -> float:
    """Play forward from frame 0, independently of the cache."""
    fps = tl.fps
    force = tl.track("muscle:risorius:left")
    jaw = tl.track("jaw")

    def target(t):
        return force.evaluate(t) + jaw.evaluate(t) / 10

    x = target(0.0)
    for j in range(frame):
        f = target(j / fps)
        x = f + (x - f) * math.exp(-DampedLayer.K / fps)
    return x


def _sim_timeline() -> Timeline:
    tl = Timeline(4.0, 30)
    tl.add_keys({"muscle:risorius:left": [(0.0, 0.0), (0.5, 10.0, "linear"), (1.5, 2.0, "step"), (2.5, 6.0)],
                 "jaw": [(0.0, 0.0), (3.0, 20.0)], "fap:3": [(0.0, 0.0), (2.0, 300.0)]})
    return tl


def test_simulation_cache_matches_playing_forward_and_scrubs_back_cheaply():
    tl, layer = _sim_timeline(), DampedLayer()
    cache = MuscleSimulationCache(tl, layer, snapshot_interval_s=0.25)
    assert cache.interval_frames == 8
    cache.seek(3.0)
    assert layer.x == pytest.approx(_reference(tl, 90), abs=1e-12)
    assert cache.steps == 90 and layer.relaxes == 1 and layer.starts == 1
    for t in (0.5, 2.2, 1.0, 0.0, 3.9, 1.7):
        before = cache.steps
        frame = cache.seek(t)
        assert frame == round(t * 30)
        assert layer.x == pytest.approx(_reference(tl, frame), abs=1e-12)
        assert cache.steps - before < cache.interval_frames or t == 3.9  # never re-simulated from 0
    before = cache.steps
    cache.seek(1.7)
    assert cache.steps == before  # already there


def test_simulation_cache_invalidates_after_muscle_edits_only():
    tl, layer = _sim_timeline(), DampedLayer()
    cache = MuscleSimulationCache(tl, layer)
    cache.seek(4.0)
    cached = cache.cached_frames
    tl.set_key("fap:3", 1.0, 100.0)  # not simulated: nothing forgotten
    assert cache.cached_frames == cached
    edit = tl.set_key("muscle:risorius:left", 2.5, 1.0)
    start = edit.earliest_change()
    assert start == pytest.approx(0.5)  # a change at key 3 reaches back to key 1 (smooth tangents)
    assert all(k < start * 30 for k in cache.cached_frames) and 8 in cache.cached_frames
    for t in (3.5, 0.2, 2.0):
        frame = cache.seek(t)
        assert layer.x == pytest.approx(_reference(tl, frame), abs=1e-12)
    tl.apply_edit(edit.inverse())
    assert cache.seek(3.5) == 105 and layer.x == pytest.approx(_reference(tl, 105), abs=1e-12)
    tl.set_settings(fps=60)
    assert cache.cached_frames == ()
    assert cache.seek(1.0) == 60 and layer.x == pytest.approx(_reference(tl, 60), abs=1e-12)
    tl.remove_track("jaw")  # a deleted track's parameter returns to rest
    cache.seek(2.0)
    assert layer.jaw == 0.0
    tl.add_keys({"jaw": [(0.0, 0.0)]})
    assert cache.seek(3.0) == 180 and layer.x == pytest.approx(_reference(tl, 180), abs=1e-12)
    cache.close()
    tl.set_key("muscle:risorius:left", 0.0, 3.0)
    assert cache.cached_frames  # disconnected: no longer listening


def test_apply_at_poses_rig_and_layer():
    tl, layer, rig = _sim_timeline(), DampedLayer(), FakeRig()
    cache = MuscleSimulationCache(tl, layer)
    values = T.apply_at(tl, 2.0, rig, cache)
    assert values["fap:3"] == 300.0 and rig.calls[0] == ("batch",) and rig.calls[-1] == ("end",)
    assert ("values", {"fap:3": 300.0}) in rig.calls
    assert layer.x == pytest.approx(_reference(tl, 60), abs=1e-12)
