"""service.tracing: how a stored scene version answers a query: the engine's answer under the
meshes' stable indices, only the fields asked for, at the version traced."""

from __future__ import annotations

import numpy as np
import pytest
from service_helpers import quad

from dacrt import InputError
from service import tracing, wire
from service.errors import Invalid
from service.options import FIELDS, Query, make_options
from service.store import Store

QUERIES = list(Query)


def rays(origins, directions, **extra) -> wire.Rays:
    return wire.Rays(
        np.asarray(origins, np.float32), np.asarray(directions, np.float32), None, None, **extra
    )


#: Three rays straight down on x = 0.5 + 2k: at the quads of meshes "a" (x in [0, 1]), "b" (x in
#: [2, 3]) and nothing.
DOWN = rays([[0.5, 0.5, 1], [2.5, 0.5, 1], [4.5, 0.5, 1]], [[0, 0, -1]] * 3)


@pytest.fixture
def store() -> Store:
    store = Store(2**20, 2**30)
    for name, x in (("a", 0), ("b", 2)):
        store.put_mesh("s", name, wire.mesh_arrays(*quad(x, x + 1, 0, 1, 0)))
    return store


def test_answers_name_the_meshes_by_their_stable_indices(store):
    before = tracing.trace(store.snapshot("s"), DOWN, make_options("closest"))
    assert before.arrays["mesh"].tolist() == [0, 1, -1]
    store.delete_mesh("s", "a")  # "b" is now the engine's first mesh, and keeps its index
    snapshot = store.snapshot("s")
    after = tracing.trace(snapshot, DOWN, make_options("closest"))
    assert after.arrays["mesh"].tolist() == [-1, 1, -1]
    assert after.version == snapshot.version > before.version
    assert np.array_equal(after.arrays["prim"], [-1, before.arrays["prim"][1], -1])


def test_an_answer_holds_the_fields_asked_for_and_stats_say_where(store):
    options = make_options("closest", fields="t", stats=True, strategy="sah")
    answer = tracing.trace(store.snapshot("s"), DOWN, options)
    assert list(answer.arrays) == ["t"]
    np.testing.assert_array_equal(answer.arrays["t"], [1, 1, np.inf])
    assert answer.stats["strategy"] == "sah" and answer.stats["where"] == "process"
    assert answer.stats["rays"] == 3 and answer.where == "process"


@pytest.mark.parametrize("query", QUERIES)
def test_every_query_answers_on_a_stored_scene(store, query):
    answer = tracing.trace(store.snapshot("s"), DOWN, make_options(query.value))
    assert tuple(answer.arrays) == FIELDS[query]
    hit = {"closest": "t", "occluded": "occluded", "hits": "truncated", "count": "count"}
    assert len(answer.arrays[hit[query.value]]) == 3


def test_the_masks_of_a_batch_come_from_the_body_or_the_query_string_not_both(store):
    options = make_options("occluded", mask=0x2)
    masked = rays(DOWN.origins, DOWN.directions, mask=np.array([1, 1, 1], np.uint32))
    with pytest.raises(Invalid, match="in the body and in \\?mask= too"):
        tracing.trace(store.snapshot("s"), masked, options)
    hidden = tracing.trace(store.snapshot("s"), DOWN, options)  # meshes of mask 0xFFFFFFFF
    assert hidden.arrays["occluded"].tolist() == [True, True, False]


def test_a_bad_ray_is_the_engines_input_error_in_its_words(store):
    bad = rays([[0.5, 0.5, np.nan]], [[0, 0, -1]])
    with pytest.raises(InputError, match=r"origins\[0\]"):  # the caller's key and row
        tracing.trace(store.snapshot("s"), bad, make_options("closest"))


def test_a_one_shot_trace_is_version_0_of_mesh_0():
    answer = tracing.trace_once(
        wire.mesh_arrays(*quad(0, 1, 0, 1, 0)), DOWN, make_options("closest")
    )
    assert answer.version == 0 and answer.arrays["mesh"].tolist() == [0, -1, -1]


def test_meshes_without_triangles_are_left_out_of_the_engine_scene():
    vertices, faces = quad(0, 1, 0, 1, 0)
    engine = tracing.build_engine_scene(
        [(0, vertices, faces[:0]), (4, vertices, faces), (7, vertices[:0], faces[:0])]
    )
    assert engine.scene.n_meshes == 1
    assert engine.map_mesh(np.array([0, -1])).tolist() == [4, -1]


def _frame_rays(seed: int, n: int = 400) -> wire.Rays:
    rng = np.random.default_rng(seed)
    origins = rng.uniform(-1, 3, (n, 3))
    targets = rng.uniform(0, 2, (n, 3))
    return rays(origins, targets - origins)


def _moved(angle: float, shift) -> np.ndarray:
    matrix = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    matrix[:2, :2] = [[c, -s], [s, c]]
    matrix[:3, 3] = shift
    return matrix


def test_a_new_version_changes_the_earlier_engine_scene_and_answers_as_one_built_whole():
    """Frames that move instances, deform a source and mask a mesh make each version's engine
    scene from the earlier one's (the static mesh's packed arrays shared), with the answers of
    an engine scene built whole from the same meshes, bit for bit."""
    rng = np.random.default_rng(5)
    store = Store(2**22, 2**32)
    world = rng.uniform(0, 2, (900, 3)).astype(np.float32)
    car = rng.uniform(0, 0.5, (90, 3)).astype(np.float32)
    store.apply_frame(
        "s",
        {
            "world": (world, np.arange(900, dtype=np.int32).reshape(-1, 3)),
            "car": (car, np.arange(90, dtype=np.int32).reshape(-1, 3)),
            "c1": wire.FrameChange(instance_of="car", transform=_moved(0.3, [1, 0, 0])),
            "c2": wire.FrameChange(instance_of="car", transform=_moved(1.1, [0, 1, 0.5])),
        },
    )
    frames = [
        {"c1": wire.FrameChange(transform=_moved(0.5, [1.2, 0.1, 0]))},
        {"c2": wire.FrameChange(transform=_moved(1.3, [0.2, 1, 0.5]), mask=2)},
        {"car": wire.FrameChange(vertices=car + np.float32(0.25))},
        {"world": wire.FrameChange(mask=3)},
        {},  # the same meshes: the same engine scene
    ]
    options = [make_options(q) for q in ("closest", "hits", "count")]
    first = store.snapshot("s").cached("dacrt", tracing._snapshot_engine)
    for k, frame in enumerate(frames):
        before = store.snapshot("s").cached("dacrt", tracing._snapshot_engine)
        snapshot = store.apply_frame("s", frame)
        assert snapshot.earlier("dacrt")[1] is before
        engine = snapshot.cached("dacrt", tracing._snapshot_engine)
        assert snapshot.earlier("dacrt") is None  # let go once this version has its own
        assert (engine.scene is before.scene) == (not frame)
        # the base level (world and car, as given) is packed again only when the car deforms
        assert (engine.scene._base is first.scene._base) == (k < 2)
        meshes = [
            (m.index, m.vertices, m.faces, m.mask, m.transform) for m in snapshot.meshes.values()
        ]
        whole = tracing.build_engine_scene(meshes)
        _assert_answers_as_whole(snapshot, whole, _frame_rays(k), options, k)


def _assert_answers_as_whole(snapshot, whole, batch, options, label):
    """The version's answers to ``batch`` for each of ``options``: those of ``whole``, an engine
    scene built whole from its meshes, bit for bit."""
    for query in options:
        got = tracing.trace(snapshot, batch, query).arrays
        want = tracing._run(whole, batch, query, snapshot.version, 0.0).arrays
        assert got.keys() == want.keys()
        for key in got:
            np.testing.assert_array_equal(got[key], want[key], err_msg=f"{label} {key}")


def test_a_frame_deforming_the_only_mesh_changes_the_earlier_engine_scene():
    """New vertices of the same faces keep the earlier engine scene for the new version to change
    (its storage order kept, not sorted again), even when no mesh is kept whole, with the
    answers of an engine scene built whole."""
    rng = np.random.default_rng(6)
    store = Store(2**22, 2**32)
    soup = rng.uniform(0, 2, (900, 3)).astype(np.float32)
    faces = rng.permutation(900).astype(np.int32).reshape(-1, 3)  # incoherent: sorted rows
    store.apply_frame("s", {"soup": (soup, faces)})
    before = store.snapshot("s").cached("dacrt", tracing._snapshot_engine)
    moved = (soup + rng.normal(0, 0.3, soup.shape)).astype(np.float32)
    snapshot = store.apply_frame("s", {"soup": wire.FrameChange(vertices=moved)})
    assert snapshot.earlier("dacrt")[1] is before
    engine = snapshot.cached("dacrt", tracing._snapshot_engine)
    mesh = snapshot.meshes["soup"]
    whole = tracing.build_engine_scene([(mesh.index, mesh.vertices, mesh.faces, mesh.mask, None)])
    np.testing.assert_array_equal(engine.scene._base.ids, before.scene._base.ids)
    assert not np.array_equal(engine.scene._base.ids, whole.scene._base.ids)
    options = [make_options(q) for q in ("closest", "hits", "count")]
    _assert_answers_as_whole(snapshot, whole, _frame_rays(7), options, "deformed")


def test_an_earlier_version_is_held_only_when_its_engine_scene_can_be_changed():
    """A version holds the earlier one's engine scene (until it builds its own) only when its
    meshes with triangles are the same, with the same faces: deleting, adding or replacing a
    mesh lets the earlier one go, so that it does not stay outside DACRT_MAX_SCENE_BYTES."""
    rng = np.random.default_rng(8)
    store = Store(2**22, 2**32)
    big = rng.uniform(0, 2, (900, 3)).astype(np.float32)
    small = rng.uniform(0, 1, (30, 3)).astype(np.float32)
    faces = {n: np.arange(n, dtype=np.int32).reshape(-1, 3) for n in (900, 30)}
    store.apply_frame("s", {"big": (big, faces[900]), "small": (small, faces[30])})

    def engine():
        return store.snapshot("s").cached("dacrt", tracing._snapshot_engine)

    changes = [
        (lambda: store.apply_frame("s", {"small": wire.FrameChange(vertices=small + 1)}), True),
        (lambda: store.set_mask("s", "small", 5), True),
        (lambda: store.delete_mesh("s", "big"), False),
        (lambda: store.apply_frame("s", {"big": (big, faces[900])}), False),  # added
        (lambda: store.apply_frame("s", {"small": (small, faces[30].copy())}), False),  # new faces
        (lambda: store.apply_frame("s", {"none": (big[:0], faces[900][:0])}), True),  # empty
    ]
    for k, (change, held) in enumerate(changes):
        before = engine()
        change()
        snapshot = store.snapshot("s")
        assert (snapshot.earlier("dacrt") is not None) == held, k
        if held:
            assert snapshot.earlier("dacrt")[1] is before
