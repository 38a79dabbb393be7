"""The scene store in-process: versions, stable indices, immutable snapshots, atomic frames,
limits, and that a rejected change leaves nothing behind."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from service_helpers import grid, quad

from dacrt import InputError
from service import tracing
from service.errors import Conflict, Invalid, NotFound, TooLarge
from service.footprint import POINT_TRIANGLE_BYTES, TRIANGLE_BYTES
from service.store import Snapshot, Store, check_name, referenced_bounds
from service.wire import FrameChange, MeshArrays

#: What a stored scene counts per placed triangle: the engine's scene and its point queries'.
PLACED_BYTES = TRIANGLE_BYTES + POINT_TRIANGLE_BYTES


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


def test_a_scene_that_gave_out_every_int32_index_takes_no_new_mesh(store):
    """Hit results give a mesh's index as int32: past 2**31 - 1 a new mesh is 413 (indices are
    never reused), while the scene's meshes still change."""
    store.put_mesh("s", "a", mesh())
    old = store.snapshot("s")
    store.restore([Snapshot("s", old.version, old.meshes, 2**31 - 1)], {"s": old.version})
    assert store.put_mesh("s", "b", mesh())[0].index == 2**31 - 1
    with pytest.raises(TooLarge, match="scene 's' has given out every mesh index"):
        store.apply_frame("s", {"a": (quad(0, 2, 0, 2, 0)[0], None), "c": quad(0, 1, 0, 1, 1)})
    assert store.snapshot("s").version == 2  # the refused frame changed nothing
    assert store.set_mask("s", "b", 1).version == 3
    store.delete_scene("s")
    assert store.put_mesh("s", "c", mesh())[0].index == 0  # a new scene starts again


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


def test_the_meshes_of_a_scene_are_bounded_and_a_refusal_changes_nothing():
    store = Store(max_triangles_per_scene=1000, max_scene_bytes=100_000, max_meshes_per_scene=3)
    store.put_mesh("s", "a", mesh())
    store.put_instance("s", "b", "a")
    store.apply_frame("s", {"c": FrameChange(instance_of="a")})
    before, nbytes = store.snapshot("s"), store.nbytes
    over = "scene 's' would hold 4 meshes, over the limit of 3 .*DACRT_MAX_MESHES_PER_SCENE"
    with pytest.raises(TooLarge, match=over):
        store.put_mesh("s", "d", mesh())
    with pytest.raises(TooLarge, match=over):
        store.put_instance("s", "d", "a")
    with pytest.raises(TooLarge, match=over):
        store.apply_frame("s", {"d": FrameChange(instance_of="a")})
    with pytest.raises(TooLarge, match="would hold 5 meshes"):  # refused before it is built
        store.apply_frame("t", {name: quad(0, 1, 0, 1, 0) for name in "abcde"})
    assert store.snapshot("s") is before and store.nbytes == nbytes
    assert [s.scene for s in store.snapshots()] == ["s"]
    store.put_mesh("s", "a", mesh())  # replacing a mesh adds none
    store.delete_mesh("s", "c")
    store.put_instance("s", "d", "a")


def test_vertex_count_change_is_409_with_advice(store):
    store.put_mesh("s", "a", mesh())
    with pytest.raises(Conflict, match="has 4 vertices but the update has 9.*PUT the whole mesh"):
        store.update_vertices("s", "a", grid(2)[0])


def test_limits_name_their_setting(store):
    with pytest.raises(
        TooLarge, match="1800 triangles, over the limit of 1000 .*DACRT_MAX_TRIANGLES_PER_SCENE"
    ):
        store.put_mesh("s", "big", MeshArrays(*grid(30)))
    small = MeshArrays(*grid(10))  # 200 triangles, 121 vertices: 3852 bytes of arrays
    for i in range(2):  # and 200 x 168 bytes of engine scene: 37452 bytes each
        store.put_mesh(f"s{i}", "m", small)
    with pytest.raises(TooLarge, match="over the limit of 100000 bytes .*DACRT_MAX_SCENE_BYTES"):
        store.put_mesh("s2", "m", small)
    assert store.nbytes == 2 * (3852 + 200 * PLACED_BYTES)
    with pytest.raises(NotFound):
        store.snapshot("s2")


def test_the_scene_limit_counts_the_engines_placed_triangles():
    """Instances share their source's arrays but the engine places each one's triangles: the
    limit counts them (7 instances of a mesh whose arrays alone fit)."""
    store = Store(max_triangles_per_scene=100_000, max_scene_bytes=700_000)
    store.put_mesh("s", "car", MeshArrays(*grid(20)))  # 14892 bytes, 800 triangles
    for i in range(4):
        store.put_instance("s", f"car{i}", "car", np.eye(4))
    assert store.nbytes == 14892 + 5 * 800 * PLACED_BYTES
    with pytest.raises(TooLarge, match="engine's 168 bytes a placed triangle.*DACRT_MAX_SCENE_"):
        store.put_instance("s", "car4", "car", np.eye(4))
    assert store.snapshot("s").array_bytes == 14892


def test_held_bytes_count_the_engine_scene_once_built(store):
    """What /metrics shows: the arrays, then the engine's scene once a query built it, within
    the estimate the limit counts."""
    store.put_mesh("s", "a", MeshArrays(*grid(10)))
    store.put_instance("s", "b", "a", np.eye(4))
    snapshot = store.snapshot("s")
    assert store.held_bytes() == snapshot.array_bytes == 3852
    engine = snapshot.cached("dacrt", tracing._snapshot_engine)
    assert engine.scene.nbytes >= 400 * 64  # corners, box and row of each placed triangle
    assert store.held_bytes() == 3852 + engine.scene.nbytes <= store.nbytes


def test_held_bytes_count_the_earlier_engine_scene_kept_for_reuse(store):
    """After a vertices update, the new version holds the earlier one (its vertices and engine
    scene) until its own engine scene is built from it; /metrics counts them, the shared faces
    once, and lets them go once the new version's is built."""
    vertices, faces = grid(10)
    store.put_mesh("s", "a", MeshArrays(vertices, faces))
    before = store.snapshot("s")
    engine = before.cached("dacrt", tracing._snapshot_engine)
    store.update_vertices("s", "a", vertices + 1)
    after = store.snapshot("s")
    assert after.earlier("dacrt") == (before, engine)
    assert after.meshes["a"].faces is before.meshes["a"].faces
    vertex_bytes = after.meshes["a"].vertices.nbytes
    assert store.held_bytes() == after.array_bytes + vertex_bytes + engine.scene.nbytes
    built = after.cached("dacrt", tracing._snapshot_engine)
    assert store.held_bytes() == after.array_bytes + built.scene.nbytes


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


# ---- masks, transforms and instances


def turn(degrees: float = 90.0, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) float64: a turn about +z, then a shift."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    matrix = np.eye(4)
    matrix[:2, :2] = [[c, -s], [s, c]]
    matrix[:3, 3] = shift
    return matrix


def test_every_placement_change_makes_one_version(store):
    store.put_mesh("s", "a", mesh(), mask=5)
    assert store.set_transform("s", "a", turn()).version == 2
    assert store.set_mask("s", "a", 6).version == 3
    assert store.put_instance("s", "b", "a", turn(45))[0].version == 4
    frame = {"a": FrameChange(transform=turn(10), mask=1), "b": FrameChange(transform=turn(20))}
    assert store.apply_frame("s", frame).version == 5
    assert store.set_transform("s", "b", None).transform is None  # the identity
    assert store.snapshot("s").version == 6


def test_mask_and_transform_are_kept_until_set(store):
    store.put_mesh("s", "a", mesh(), mask=5)
    store.set_transform("s", "a", turn())
    kept = [
        store.update_vertices("s", "a", quad(0, 2, 0, 2, 0)[0]),
        store.put_mesh("s", "a", mesh(0, 3, 0, 3, 0))[0],
        store.apply_frame("s", {"a": (quad(0, 4, 0, 4, 0)[0], None)}).meshes["a"],
        store.apply_frame("s", {"a": quad(0, 1, 0, 1, 0)}).meshes["a"],
    ]
    for m in kept:
        assert m.mask == 5 and np.array_equal(m.transform, turn())
    assert store.put_mesh("s", "a", mesh(), mask=7)[0].mask == 7


def test_bounds_are_of_the_placed_referenced_vertices(store):
    vertices = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0], [1e30, 1e30, 1e30]], np.float32)
    faces = np.array([[0, 1, 2]], np.int32)
    store.put_mesh("s", "a", MeshArrays(vertices, faces))
    placed = store.set_transform("s", "a", turn(90, shift=(10, 0, 5)))
    expected = (vertices[:3].astype(np.float64) @ turn(90)[:3, :3].T + [10, 0, 5]).astype(
        np.float32
    )
    np.testing.assert_array_equal(placed.bounds, [expected.min(axis=0), expected.max(axis=0)])
    np.testing.assert_allclose(placed.bounds, [[9, 0, 5], [10, 2, 5]], atol=1e-6)
    np.testing.assert_array_equal(store.snapshot("s").bounds, placed.bounds)


def test_a_frame_places_many_instances_at_once_as_each_alone():
    """A frame that moves 30 instances of one mesh (and ends the move of some) makes each one's
    bounds as placed alone: those of its referenced vertices placed in float64, then float32,
    the box of both placements for a moving one. One that places a vertex beyond float32 is 422
    naming it, and the scene keeps its version."""
    store = Store(max_triangles_per_scene=10_000, max_scene_bytes=10**7)
    vertices, faces = grid(6)
    vertices = np.vstack([vertices, np.float32([[1e30, 1e30, 1e30]])])  # one unreferenced
    store.put_mesh("s", "car", MeshArrays(vertices, faces))
    for k in range(1, 30):
        store.put_instance("s", f"car{k}", "car")
    names = ["car"] + [f"car{k}" for k in range(1, 30)]
    rng = np.random.default_rng(2)
    starts = [turn(rng.uniform(0, 360), rng.normal(size=3) * 50) for _ in names]
    ends = {name: turn(rng.uniform(0, 360), rng.normal(size=3) * 50) for name in names[::4]}
    frame = {
        name: FrameChange(transform=start, transform_end=ends.get(name))
        for name, start in zip(names, starts)
    }
    snapshot = store.apply_frame("s", frame)
    referenced = vertices[:-1].astype(np.float64)
    for name, start in zip(names, starts):
        boxes = []
        for matrix in (start, ends.get(name)):
            if matrix is not None:
                placed = (referenced @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
                boxes.append([placed.min(axis=0), placed.max(axis=0)])
        expected = [np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)]
        np.testing.assert_array_equal(snapshot.meshes[name].bounds, expected, name)
    frame["car17"] = FrameChange(transform=np.diag([1e9, 1.0, 1.0, 1.0]))
    beyond = f"transform of mesh 'car17' places vertex {len(vertices) - 1} beyond"
    with pytest.raises(InputError, match=beyond):
        store.apply_frame("s", frame)
    assert store.snapshot("s").version == snapshot.version


def test_a_transform_that_leaves_the_float32_range_is_422(store):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1e30, 0, 0]], np.float32)
    store.put_mesh("s", "a", MeshArrays(vertices, np.array([[0, 1, 2]], np.int32)))
    with pytest.raises(InputError, match="transform of mesh 'a' places vertex 3 beyond the float"):
        store.set_transform("s", "a", np.diag([1e9, 1.0, 1.0, 1.0]))  # vertex 3 is unreferenced
    assert store.snapshot("s").version == 1
    assert store.set_transform("s", "a", np.diag([1e8, 1.0, 1.0, 1.0])).version == 2


def test_instances_share_their_sources_arrays_counted_once():
    store = Store(max_triangles_per_scene=10_000, max_scene_bytes=900_000)
    source, _ = store.put_mesh("s", "car", MeshArrays(*grid(20)))  # 14892 bytes
    for i in range(5):
        store.put_instance("s", f"car{i}", "car", turn(10 * i, shift=(i, 0, 0)), mask=i + 1)
    snapshot = store.snapshot("s")
    for i in range(5):
        made = snapshot.meshes[f"car{i}"]
        assert made.vertices is source.vertices and made.faces is source.faces
        assert (made.instance_of, made.mask, made.index) == ("car", i + 1, i + 1)
    assert snapshot.array_bytes == 14892 and snapshot.n_triangles == 6 * 800
    assert store.nbytes == snapshot.nbytes == 14892 + 6 * 800 * PLACED_BYTES
    store.delete_mesh("s", "car0")
    assert store.nbytes == 14892 + 5 * 800 * PLACED_BYTES


def test_instances_follow_their_sources_arrays(store):
    store.put_mesh("s", "car", mesh())
    store.put_instance("s", "twin", "car", turn(0, shift=(5, 0, 0)))
    before = store.snapshot("s")
    moved = store.update_vertices("s", "car", quad(0, 1, 0, 1, 3)[0])
    twin = store.snapshot("s").meshes["twin"]
    assert twin.vertices is moved.vertices and twin.version == 3
    assert twin.bounds.tolist() == [[5, 0, 3], [6, 1, 3]]
    assert before.meshes["twin"].bounds.tolist() == [[5, 0, 0], [6, 1, 0]]  # unchanged
    store.put_mesh("s", "car", MeshArrays(*grid(2)))
    twin = store.snapshot("s").meshes["twin"]
    assert twin.n_triangles == 8 and twin.vertices is store.snapshot("s").meshes["car"].vertices
    assert store.snapshot("s").array_bytes == store.snapshot("s").meshes["car"].nbytes


def test_an_instance_of_an_instance_shares_the_first_source(store):
    store.put_mesh("s", "car", mesh())
    store.put_instance("s", "a", "car")
    assert store.put_instance("s", "b", "a")[0].instance_of == "car"
    frame = {"c": FrameChange(instance_of="d"), "d": FrameChange(instance_of="b")}
    assert {m.instance_of for m in store.apply_frame("s", frame).meshes.values()} == {None, "car"}


def test_a_chain_of_instances_listed_from_its_far_end_links_each_to_the_first_source():
    store = Store(max_triangles_per_scene=10_000, max_scene_bytes=1_000_000)
    store.put_mesh("s", "car", mesh())
    links = 1000
    frame = {f"d{i}": FrameChange(instance_of=f"d{i - 1}" if i else "car") for i in range(links)}
    snapshot = store.apply_frame("s", dict(reversed(frame.items())))
    assert {m.instance_of for name, m in snapshot.meshes.items() if name != "car"} == {"car"}
    car = snapshot.meshes["car"]
    assert all(snapshot.meshes[f"d{i}"].vertices is car.vertices for i in range(links))


def test_a_frame_makes_instances_of_a_mesh_it_adds(store):
    v, f = quad(0, 1, 0, 1, 2)
    frame = {"i": FrameChange(instance_of="car", transform=turn(90)), "car": FrameChange(v, f)}
    snapshot = store.apply_frame("s", frame)
    assert snapshot.meshes["i"].vertices is snapshot.meshes["car"].vertices
    assert [m.name for m in snapshot.meshes.values()] == ["i", "car"]


@pytest.mark.parametrize(
    "change, error, message",
    [
        (lambda s: s.delete_mesh("s", "car"), Conflict, r"instances \['i'\], so it cannot be del"),
        (lambda s: s.put_instance("s", "car", "b"), Conflict, "cannot become an instance of 'b'"),
        (lambda s: s.put_instance("s", "x", "zz"), NotFound, "no mesh 'zz' for 'x'"),
        (lambda s: s.put_instance("s", "x", "x"), Invalid, "cannot be an instance of itself"),
        (lambda s: s.put_instance("s", "x", "a b"), Invalid, "mesh name 'a b'"),
        (lambda s: s.put_instance("t", "x", "car"), NotFound, "no scene 't'"),
        (lambda s: s.update_vertices("s", "i", quad(0, 1, 0, 1, 0)[0]), Conflict, "an instance"),
        (
            lambda s: s.apply_frame("s", {"b": (quad(0, 1, 0, 1, 7)[0], None), "i": ([], None)}),
            Conflict,
            "'i' of scene 's' is an instance of 'car'",
        ),
        (
            lambda s: s.apply_frame("s", {"p": FrameChange(instance_of="q"), "q": (None, None)}),
            NotFound,
            "no mesh 'q'",
        ),
        (
            lambda s: s.apply_frame("s", {f"k{i}": FrameChange(instance_of="b") for i in range(9)}),
            TooLarge,
            "DACRT_MAX_TRIANGLES_PER_SCENE",
        ),
    ],
)
def test_a_rejected_instance_change_changes_nothing(change, error, message):
    store = Store(max_triangles_per_scene=20, max_scene_bytes=100_000)
    store.put_mesh("s", "car", mesh())
    store.put_mesh("s", "b", mesh())
    store.put_instance("s", "i", "car")
    before, nbytes = store.snapshot("s"), store.nbytes
    with pytest.raises(error, match=message):
        change(store)
    assert store.snapshot("s") is before and store.nbytes == nbytes


def test_info_shows_mask_transform_and_source(store):
    store.put_mesh("s", "car", mesh(), mask=0xF0)
    info = store.put_instance("s", "i", "car", turn(0, shift=(1, 2, 3)))[0].info("s")
    assert info["mask"] == 0xFFFFFFFF and info["instance_of"] == "car"
    assert info["transform"] == turn(0, shift=(1, 2, 3)).tolist()
    assert store.snapshot("s").meshes["car"].info("s")["transform"] == np.eye(4).tolist()
    assert store.snapshot("s").meshes["car"].info("s")["mask"] == 0xF0


def test_the_triangle_limit_is_exact():
    store = Store(max_triangles_per_scene=201, max_scene_bytes=10**9)
    store.put_mesh("s", "grid", MeshArrays(*grid(10)))  # 200 triangles
    with pytest.raises(TooLarge, match="202 triangles, over the limit of 201"):
        store.put_mesh("s", "quad", mesh())  # 2 more
    assert store.snapshot("s").n_triangles == 200
    exact = Store(max_triangles_per_scene=202, max_scene_bytes=10**9)
    exact.put_mesh("s", "grid", MeshArrays(*grid(10)))
    assert exact.put_mesh("s", "quad", mesh())[1] and exact.snapshot("s").n_triangles == 202


def test_the_byte_limit_is_exact():
    nbytes = 3852 + 200 * PLACED_BYTES  # grid(10): its arrays and its engine scene
    Store(1000, max_scene_bytes=nbytes).put_mesh("s", "m", MeshArrays(*grid(10)))
    with pytest.raises(TooLarge, match=f"{nbytes} bytes .* limit of {nbytes - 1} bytes"):
        Store(1000, max_scene_bytes=nbytes - 1).put_mesh("s", "m", MeshArrays(*grid(10)))


def test_a_replaced_mesh_no_longer_deforms(store):
    vertices, faces = quad(0, 1, 0, 1, 0)
    store.apply_frame(
        "s", {"a": FrameChange(vertices=vertices, faces=faces, vertices_end=vertices + 1)}
    )
    assert store.snapshot("s").meshes["a"].vertices_end is not None
    replaced, created = store.put_mesh("s", "a", mesh(0, 2, 0, 2, 0))
    assert not created and replaced.vertices_end is None
    assert replaced.info("s")["vertices_end"] is None


def shift(x: float) -> np.ndarray:
    matrix = np.eye(4)
    matrix[0, 3] = x
    return matrix


def test_setting_a_transform_makes_a_moving_mesh_static(store):
    vertices, faces = quad(0, 1, 0, 1, 0)
    change = FrameChange(vertices=vertices, faces=faces, transform=shift(1), transform_end=shift(2))
    assert store.apply_frame("s", {"a": change}).meshes["a"].transform_end is not None
    placed = store.set_transform("s", "a", shift(3))
    assert np.array_equal(placed.transform, shift(3)) and placed.transform_end is None
    assert store.snapshot("s").meshes["a"].info("s")["transform_end"] is None


def test_new_start_vertices_make_a_moving_mesh_static(store):
    """Every change that gives a mesh new start vertices and no end (a frame's vertices, with
    faces or not, PUT .../vertices, PUT of the whole mesh) drops its transform_end."""
    vertices, faces = quad(0, 1, 0, 1, 0)
    moving = FrameChange(vertices=vertices, faces=faces, transform_end=shift(2))
    changes = [
        lambda: store.apply_frame("s", {"a": FrameChange(vertices=vertices)}),
        lambda: store.apply_frame("s", {"a": FrameChange(vertices=vertices, faces=faces)}),
        lambda: store.update_vertices("s", "a", vertices),
        lambda: store.put_mesh("s", "a", MeshArrays(vertices, faces)),
    ]
    for change in changes:
        assert store.apply_frame("s", {"a": moving}).meshes["a"].transform_end is not None
        change()
        assert store.snapshot("s").meshes["a"].transform_end is None
        assert store.snapshot("s").meshes["a"].info("s")["transform_end"] is None
    # so the moving mesh may deform instead: start and end vertices in one frame
    store.apply_frame("s", {"a": moving})
    deforming = FrameChange(vertices=vertices, vertices_end=vertices + 1)
    mesh = store.apply_frame("s", {"a": deforming}).meshes["a"]
    assert mesh.transform_end is None and mesh.vertices_end is not None
    # an end alone keeps the other end
    mesh = store.apply_frame("s", {"a": FrameChange(mask=3)}).meshes["a"]
    assert mesh.vertices_end is not None


def test_a_new_transform_makes_a_deforming_mesh_static(store):
    """A frame's transform without an end drops a mesh's vertices_end, as PUT .../transform
    does, the identity too."""
    vertices, faces = quad(0, 1, 0, 1, 0)
    deforming = FrameChange(
        vertices=vertices, faces=faces, transform=np.eye(4), vertices_end=vertices + 1
    )
    for transform in (shift(1), np.eye(4)):
        assert store.apply_frame("s", {"a": deforming}).meshes["a"].vertices_end is not None
        mesh = store.apply_frame("s", {"a": FrameChange(transform=transform)}).meshes["a"]
        assert mesh.vertices_end is None and mesh.transform_end is None
        np.testing.assert_array_equal(
            mesh.transform if mesh.transform is not None else np.eye(4), transform
        )
    store.apply_frame("s", {"a": deforming})
    assert store.set_transform("s", "a", shift(1)).vertices_end is None
    # a transform with its end: now moving by the transform
    store.apply_frame("s", {"a": deforming})
    change = FrameChange(transform=shift(1), transform_end=shift(2))
    mesh = store.apply_frame("s", {"a": change}).meshes["a"]
    assert mesh.vertices_end is None and np.array_equal(mesh.transform_end, shift(2))
