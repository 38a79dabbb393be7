"""The scene store in-process: versions, stable indices, immutable snapshots, atomic frames,
limits, and that a rejected change leaves nothing behind."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from service_helpers import grid, quad

from service.errors import Conflict, Invalid, NotFound, TooLarge
from service.store import Store, check_name, referenced_bounds
from service.wire import MeshArrays


def mesh(*args) -> MeshArrays:
    return MeshArrays(*quad(*args)) if args else MeshArrays(*quad(0, 1, 0, 1, 0))


@pytest.fixture
def store() -> Store:
    return Store(max_triangles_per_scene=1000, max_scene_bytes=100_000)


def test_each_change_increments_the_version(store):
    info, created = store.put_mesh("s", "a", mesh())
    assert created and info.version == 1 and store.snapshot("s").version == 1
    assert store.put_mesh("s", "a", mesh(0, 2, 0, 2, 1))[1] is False
    store.update_vertices("s", "a", quad(0, 3, 0, 3, 0)[0])
    store.apply_frame("s", {"a": (quad(0, 4, 0, 4, 0)[0], None)})
    store.delete_mesh("s", "a")
    assert store.snapshot("s").version == 5


def test_indices_are_stable_and_never_reused(store):
    for name in "abc":
        store.put_mesh("s", name, mesh())
    store.delete_mesh("s", "b")
    store.put_mesh("s", "a", mesh(0, 5, 0, 5, 0))  # a replacement keeps its index
    store.put_mesh("s", "d", mesh())
    assert {m.name: m.index for m in store.snapshot("s").meshes.values()} == {
        "a": 0,
        "c": 2,
        "d": 3,
    }


def test_versions_go_on_after_a_scene_is_deleted(store):
    store.put_mesh("s", "a", mesh())
    store.put_mesh("s", "a", mesh())
    store.delete_scene("s")
    with pytest.raises(NotFound, match="no scene 's'"):
        store.snapshot("s")
    assert store.put_mesh("s", "a", mesh())[0].version == 3


def test_a_snapshot_never_changes(store):
    store.put_mesh("s", "a", mesh())
    before = store.snapshot("s")
    vertices = before.meshes["a"].vertices.copy()
    store.update_vertices("s", "a", vertices + 1)
    store.put_mesh("s", "b", mesh())
    assert before.version == 1 and list(before.meshes) == ["a"]
    assert np.array_equal(before.meshes["a"].vertices, vertices)
    with pytest.raises(ValueError):
        before.meshes["a"].vertices[0, 0] = 7  # read-only
    with pytest.raises(TypeError):
        before.meshes["x"] = before.meshes["a"]  # type: ignore[index]


def test_store_owns_its_arrays(store):
    v, f = quad(0, 1, 0, 1, 0)
    store.put_mesh("s", "a", MeshArrays(v, f))
    v[0] = 99  # the caller's buffer changes later: the scene must not
    assert store.snapshot("s").meshes["a"].vertices[0, 0] == 0


def test_frame_changes_several_meshes_in_one_version(store):
    store.put_mesh("s", "a", mesh())
    snapshot = store.apply_frame(
        "s", {"a": (quad(0, 1, 0, 1, 5)[0], None), "b": quad(0, 1, 0, 1, 6)}
    )
    assert snapshot.version == 2 and snapshot.meshes["b"].index == 1
    assert [m.version for m in snapshot.meshes.values()] == [2, 2]
    assert snapshot.bounds[:, 2].tolist() == [5, 6]


@pytest.mark.parametrize(
    "changes, error",
    [
        ({"a": (quad(0, 1, 0, 1, 5)[0], None), "b": (grid(2)[0], None)}, NotFound),  # b unknown
        ({"a": (quad(0, 1, 0, 1, 5)[0], None), "c": (grid(2)[0], None)}, NotFound),
        ({"a": (quad(0, 1, 0, 1, 5)[0], None), "b": grid(30)}, TooLarge),  # 1800 triangles
        ({"a": (grid(2)[0], None)}, Conflict),  # 9 vertices, not 4
        ({"a": (quad(0, 1, 0, 1, 5)[0], None), "b c": quad(0, 1, 0, 1, 0)}, Invalid),  # bad name
    ],
)
def test_a_rejected_frame_changes_nothing(store, changes, error):
    store.put_mesh("s", "a", mesh())
    before = store.snapshot("s")
    nbytes = store.nbytes
    with pytest.raises(error):
        store.apply_frame("s", changes)
    assert store.snapshot("s") is before and store.nbytes == nbytes


def test_vertex_count_change_is_409_with_advice(store):
    store.put_mesh("s", "a", mesh())
    with pytest.raises(Conflict, match="has 4 vertices but the update has 9.*PUT the whole mesh"):
        store.update_vertices("s", "a", grid(2)[0])


def test_limits_name_their_setting(store):
    with pytest.raises(
        TooLarge, match="1800 triangles, over the limit of 1000 .*DACRT_MAX_TRIANGLES_PER_SCENE"
    ):
        store.put_mesh("s", "big", MeshArrays(*grid(30)))
    small = MeshArrays(*grid(20))  # 800 triangles, 441 vertices: 14892 bytes
    for i in range(6):
        store.put_mesh(f"s{i}", "m", small)
    with pytest.raises(TooLarge, match="over the limit of 100000 bytes .*DACRT_MAX_SCENE_BYTES"):
        store.put_mesh("s6", "m", small)
    assert store.nbytes == 6 * 14892
    with pytest.raises(NotFound):
        store.snapshot("s6")


def test_memory_accounting_returns_to_zero(store):
    store.put_mesh("s", "a", MeshArrays(*grid(3)))
    store.put_mesh("s", "b", mesh())
    store.put_mesh("t", "a", mesh())
    store.delete_mesh("s", "a")
    store.delete_scene("t")
    store.delete_mesh("s", "b")
    assert store.nbytes == 0 and store.snapshot("s").n_triangles == 0


@pytest.mark.parametrize("name", ["", "a b", "a/b", "x" * 65, "é", ".", ".."])
def test_bad_names_are_422(name):
    with pytest.raises(Invalid, match="1-64 characters"):
        check_name("scene", name)


@pytest.mark.parametrize("name", ["a", "A-z_0.9", "x" * 64, "..."])
def test_good_names(name):
    assert check_name("mesh", name) == name


def test_bounds_cover_referenced_vertices_only():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [100, 100, 100]], np.float32)
    assert referenced_bounds(v, np.array([[0, 1, 2]], np.int32)).tolist() == [[0, 0, 0], [1, 1, 0]]
    assert referenced_bounds(v, np.zeros((0, 3), np.int32)).tolist() == [[0, 0, 0], [0, 0, 0]]


@pytest.mark.parametrize("unreferenced", [0, 1, 500])
def test_bounds_match_a_plain_reduction(unreferenced):
    rng = np.random.default_rng(unreferenced)
    v = (rng.normal(size=(2000, 3)) * [1, 10, 100]).astype(np.float32)
    faces = rng.permutation(2000)[: 2000 - unreferenced]  # each referenced vertex once at least
    faces = (
        np.concatenate([faces, rng.choice(faces, 3 - len(faces) % 3)])
        .reshape(-1, 3)
        .astype(np.int32)
    )
    used = v[np.unique(faces)]
    expected = [[min(used[:, a]) for a in range(3)], [max(used[:, a]) for a in range(3)]]
    assert referenced_bounds(v, faces).tolist() == expected


def test_cached_builds_once_per_snapshot_under_concurrency(store):
    store.put_mesh("s", "a", mesh())
    snapshot, calls = store.snapshot("s"), []

    def build(s):
        calls.append(s.version)
        return object()

    results = []
    threads = [
        threading.Thread(target=lambda: results.append(snapshot.cached("k", build)))
        for _ in range(8)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert calls == [1] and len({id(r) for r in results}) == 1


def test_unknown_mesh_lists_the_meshes(store):
    store.put_mesh("s", "a", mesh())
    with pytest.raises(NotFound, match=r"no mesh 'zz'; it has \['a'\]"):
        store.delete_mesh("s", "zz")
