"""The disk cache of derived face data (core.cache) and the FAP table read back from it."""

from __future__ import annotations

import numpy as np
import pytest

from core.cache import DiskCache, fingerprint, source_version
from core.layers.fap.fat import FapDeformer, deformer_key


def test_fingerprint_sees_values_dtypes_shapes_and_order():
    a = np.arange(6.0)
    assert fingerprint(a, "x", {"b": 1, "a": 2}) == fingerprint(a.copy(), "x", {"a": 2, "b": 1})
    others = [fingerprint(a + 1e-12, "x", {"a": 2, "b": 1}), fingerprint(a.astype(np.float32), "x", {"a": 2, "b": 1}),
              fingerprint(a.reshape(2, 3), "x", {"a": 2, "b": 1}), fingerprint("x", a, {"a": 2, "b": 1})]
    assert len({fingerprint(a, "x", {"a": 2, "b": 1}), *others}) == 5
    with pytest.raises(TypeError):
        fingerprint(object())


def test_source_version_follows_the_code():
    import core.cache as module

    assert source_version(module) == source_version(module)
    assert source_version(module) != source_version(np)


def test_round_trip_and_atomic_files(tmp_path):
    cache = DiskCache(tmp_path)
    assert cache.get("kind", "k1") is None
    assert cache.put("kind", "k1", {"x": np.arange(3)})
    np.testing.assert_array_equal(cache.get("kind", "k1")["x"], np.arange(3))
    assert [p.name for p in (tmp_path / "kind").iterdir()] == ["k1.pkl"], "no temporary files left"
    calls = []
    assert cache.get_or_build("kind", "k2", lambda: calls.append(1) or 7) == 7
    assert cache.get_or_build("kind", "k2", lambda: calls.append(1) or 8) == 7
    assert calls == [1] and cache.notes == []


def test_a_damaged_entry_is_deleted_and_rebuilt_with_a_note(tmp_path):
    cache = DiskCache(tmp_path)
    cache.put("kind", "k", [1, 2, 3])
    cache.path("kind", "k").write_bytes(b"\x80\x05garbage")
    assert cache.get_or_build("kind", "k", lambda: "rebuilt") == "rebuilt"
    assert len(cache.notes) == 1 and "rebuilt" in cache.notes[0] and "kind" in cache.notes[0]
    assert "cache" in cache.notes[0]            # the window puts notes naming the cache in its status bar
    assert cache.get("kind", "k") == "rebuilt"


def test_an_unwritable_folder_only_costs_the_speed_up(tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder should be")
    cache = DiskCache(blocker)
    assert cache.get_or_build("kind", "k", lambda: 5) == 5
    assert len(cache.notes) == 1 and "MIMICA_CACHE_DIR" in cache.notes[0]


def test_disabled_cache_always_builds(tmp_path):
    cache = DiskCache(tmp_path, enabled=False)
    assert not cache.put("kind", "k", 1) and cache.get("kind", "k") is None
    assert not any(tmp_path.iterdir())


@pytest.fixture(scope="module")
def small_face():
    from core.default_face import generate_face

    return generate_face(grid_spacing=3.0)


def test_the_fap_table_read_back_deforms_exactly_like_the_built_one(small_face, tmp_path):
    cache = DiskCache(tmp_path)
    built = FapDeformer.for_face(small_face, cache)
    assert cache.path("fap", deformer_key(small_face)).exists()
    read = FapDeformer.for_face(small_face, cache)
    assert read is not built and read.face is small_face and cache.notes == []
    values = np.zeros(68)
    values[[2, 11, 18, 47]] = (400.0, 150.0, 600.0, 20000.0)  # jaw, lip corner, upper lid, head pitch
    np.testing.assert_array_equal(read.deform(values), built.deform(values))
    np.testing.assert_array_equal(read.influence(3), built.influence(3))


def test_a_moved_feature_point_is_a_new_cache_entry(small_face):
    from core.face import SurfacePoint

    key = deformer_key(small_face)
    moved = small_face.with_vertices(small_face.vertices)
    assert deformer_key(moved) == key, "same arrays and points: same entry"
    point = small_face.landmarks["2.1"]
    moved.set_landmark("2.1", SurfacePoint(point.triangle, (0.2, 0.3, 0.5)))
    assert deformer_key(moved) != key
    assert deformer_key(small_face.with_vertices(small_face.vertices + 0.01)) != key


def test_a_damaged_fap_table_is_rebuilt_with_a_note(small_face, tmp_path):
    cache = DiskCache(tmp_path)
    built = FapDeformer.for_face(small_face, cache)
    entry = cache.path("fap", deformer_key(small_face))
    entry.write_bytes(entry.read_bytes()[: entry.stat().st_size // 2])   # a file cut short (disk full, crash)
    again = FapDeformer.for_face(small_face, cache)
    assert len(cache.notes) == 1 and "rebuilt" in cache.notes[0]
    values = np.zeros(68)
    values[2] = 300.0
    np.testing.assert_array_equal(again.deform(values), built.deform(values))
    assert FapDeformer.for_face(small_face, DiskCache(tmp_path)) is not None and entry.stat().st_size > 0



def test_a_fap_table_bound_otherwise_is_not_read_back(small_face, tmp_path):
    """The key hashes the face, not a scan's own binding (``AnimatedScan.binding``): a deformer asked
    for with another binding is built afresh, not read back with the old one."""
    cache = DiskCache(tmp_path)
    built = FapDeformer.for_face(small_face, cache)
    same = FapDeformer.for_face(small_face, cache, dense=built.dense, binding=built.binding)
    assert same is not built and (same.binding != built.binding).nnz == 0
    other = built.binding.tolil()
    moved = 10
    other[moved] = 0.0
    other[moved, 0] = 1.0                           # one vertex bound to another dense vertex
    rebound = FapDeformer.for_face(small_face, cache, dense=built.dense, binding=other.tocsr())
    assert (rebound.binding != other.tocsr()).nnz == 0
