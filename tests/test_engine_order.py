"""Storage order: a mesh's rows may be packed along a Morton curve (``Scene(order=)``), and that
changes no answer. Ties in t (and in distance) compare (mesh, prim), never rows, so a
scene packed in Morton order answers bit for bit as one packed in its faces' order, for every
query, strategy and thread count; and a mesh given in another face order answers the same up
to the permutation (but for ties, which go to the lowest prim of the order given).
"""

from __future__ import annotations

import numpy as np
import procedural as pg
import pytest
import sample_scenes

import dacrt

FIELDS = {
    "closest": ("t", "mesh", "prim", "u", "v", "normal"),
    "occluded": ("occluded",),
    "hits": ("offsets", "t", "mesh", "prim", "u", "v", "normal", "truncated"),
    "count": ("count",),
    "nearest": ("distance", "point", "mesh", "prim", "u", "v"),
}


def _coplanar(n=40, n_rays=2000):
    """Coplanar triangles at z = 0 that all cover the unit square, each shifted at random (so
    their Morton order is not their face order), and a second mesh of the same faces in reverse
    order; rays straight down and up through the square, points above it. Every hit is a 2n-way
    tie at t = 1 (mesh 0, prim 0 wins), and every nearest triangle ties with its copy in mesh 1."""
    rng = np.random.default_rng(50)
    shift = rng.uniform(-2.0, -1.0, (n, 2))
    corners = np.stack([shift, shift + [10.0, 0.0], shift + [0.0, 10.0]], axis=1)  # (n, 3, 2)
    v = np.concatenate([corners.reshape(-1, 2), np.zeros((3 * n, 1))], axis=1).astype(np.float32)
    f = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    xy = rng.uniform(0.05, 0.95, (n_rays, 2)).astype(np.float32)
    down = rng.random(n_rays) < 0.5
    o = np.column_stack([xy, np.where(down, 1.0, -1.0)]).astype(np.float32)
    d = np.column_stack([np.zeros((n_rays, 2)), np.where(down, -1.0, 1.0)]).astype(np.float32)
    return [(v, f), (v, f[::-1].copy())], o, d


def _multi():
    meshes = sample_scenes.multi(42)
    return meshes, *sample_scenes.mixed_rays(meshes, 42, n=3000)


def _shared(name):
    v, f = sample_scenes.load_shared(name)
    meshes = [(np.array(v), np.array(f))]
    return meshes, *sample_scenes.mixed_rays(meshes, 7, n=20000)


CASES = {
    "coplanar": _coplanar,
    "multi": _multi,
    "teapot": lambda: _shared("teapot"),
    "bunny": lambda: _shared("bunny"),
}


def _answers(scene, o, d, strategy, threads):
    """Every query's answer arrays on the rays (o, d) and on their origins as points."""
    options = {"strategy": strategy, "threads": threads}
    found = {
        "closest": scene.closest(o, d, **options),
        "occluded": scene.occluded(o, d, **options),
        "hits": scene.hits(o, d, **options),
        "count": scene.count(o, d, **options),
        "nearest": scene.nearest(o, threads=threads),
    }
    answers = {(kind, name): getattr(found[kind], name) for kind in FIELDS for name in FIELDS[kind]}
    answers[("contains", "inside")] = scene.contains(o, threads=threads)
    return answers


def _file_order_scene(meshes):
    """The Scene of ``meshes`` packed in their faces' order."""
    return dacrt.Scene(meshes, order="file")


def _assert_same(got, expected, what):
    for key, want in expected.items():
        have = got[key]
        assert have.dtype == want.dtype and have.shape == want.shape, (what, key)
        differ = np.flatnonzero(have.view(np.uint8) != want.view(np.uint8))
        assert not len(differ), f"{what}: {key} differs bitwise (byte {differ[:3]})"


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("case", list(CASES))
def test_morton_order_answers_as_file_order(case, strategy, threads):
    """Bit for bit: closest, occluded, hits, count, nearest and contains."""
    meshes, o, d = CASES[case]()
    morton = dacrt.Scene(meshes, order="morton")
    in_file_order = _file_order_scene(meshes)
    # The rows really are in another order.
    assert not np.array_equal(morton._base.ids, in_file_order._base.ids)
    expected = _answers(in_file_order, o, d, strategy, threads)
    _assert_same(_answers(morton, o, d, strategy, threads), expected, f"{case} {strategy}")


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_exact_ties_go_to_the_lowest_mesh_and_prim_in_any_storage_order(strategy, threads):
    """The coplanar faces tie everywhere: the lowest (mesh, prim) wins, although Morton order
    stores another face first, and hit lists sort their ties by (mesh, prim)."""
    meshes, o, d = _coplanar()
    scene = dacrt.Scene(meshes, order="morton")
    assert scene._base.ids[0] != 0  # another face is stored first
    hits = scene.closest(o, d, strategy=strategy, threads=threads)
    np.testing.assert_array_equal(hits.t, np.ones(len(o), np.float32))
    np.testing.assert_array_equal(hits.mesh, np.zeros(len(o)))
    np.testing.assert_array_equal(hits.prim, np.zeros(len(o)))
    every = scene.hits(o, d, max_hits=8, strategy=strategy, threads=threads)
    np.testing.assert_array_equal(every.prim.reshape(len(o), 8), np.tile(np.arange(8), (len(o), 1)))
    np.testing.assert_array_equal(every.mesh, np.zeros(len(every.mesh)))
    # Mesh 1 repeats mesh 0's faces: every nearest triangle ties with its copy, and mesh 0 wins.
    nearest = scene.nearest(o + np.float32([0, 0, -0.5]) * np.sign(o[:, 2:]), threads=threads)
    np.testing.assert_array_equal(nearest.mesh, np.zeros(len(o)))


def test_with_changes_and_instances_keep_the_tie_rule():
    """A deformed mesh is packed again in Morton order, and a placed one (an instance) is traced
    from its own Morton-ordered rows: both answer as a Scene packed in file order."""
    (first, second), o, d = _coplanar()
    lifted = first[0] + np.float32([0, 0, 0.25])
    moved = np.eye(4)
    moved[2, 3] = -0.25
    scene = dacrt.Scene([first, second], transforms=[None, moved], order="morton")
    scene = scene.with_changes(vertices={0: lifted})
    expected = _file_order_scene([(lifted, first[1]), second])
    expected = expected.with_changes(transforms={1: moved})
    for threads in (1, 2):
        _assert_same(
            _answers(scene, o, d, "sampling", threads),
            _answers(expected, o, d, "sampling", threads),
            f"with_changes, {threads} threads",
        )


def _shuffled(meshes, seed):
    """``meshes`` with each one's faces in a random order, and each permutation (shuffled
    face row -> file face row)."""
    rng = np.random.default_rng(seed)
    perms = [rng.permutation(len(f)) for _, f in meshes]
    return [(v, f[p]) for (v, f), p in zip(meshes, perms)], perms


@pytest.mark.parametrize("case", ["multi", "teapot", "bunny"])
def test_shuffled_faces_answer_as_file_order(case):
    """Faces given in a random order: the same t, meshes, counts, occlusion and distances bit
    for bit, and the same triangles through the permutation, but where a ray hits two faces at
    one t (an edge they share), which goes to the lowest prim of the order given."""
    meshes, o, d = CASES[case]()
    shuffled, perms = _shuffled(meshes, 51)
    scene, other = dacrt.Scene(meshes), dacrt.Scene(shuffled)
    a, b = scene.closest(o, d), other.closest(o, d)
    np.testing.assert_array_equal(b.t.view(np.uint32), a.t.view(np.uint32))
    np.testing.assert_array_equal(b.mesh, a.mesh)
    hit = b.mesh >= 0
    mapped = b.prim.copy()
    for m, perm in enumerate(perms):
        at = hit & (b.mesh == m)
        mapped[at] = perm[b.prim[at]]
    same = mapped == a.prim
    assert same.mean() > 0.99 and hit.sum() > len(o) // 4
    for name in ("u", "v", "normal"):
        np.testing.assert_array_equal(getattr(b, name)[same], getattr(a, name)[same])
    # A ray that answers another face hits it at the same t (a tie).
    every = scene.hits(o[~same], d[~same], max_hits=64)
    for i, ray in enumerate(np.flatnonzero(~same)):
        rows = slice(every.offsets[i], every.offsets[i + 1])
        tied = (every.t[rows] == a.t[ray]) & (every.mesh[rows] == b.mesh[ray])
        assert mapped[ray] in every.prim[rows][tied]
    np.testing.assert_array_equal(other.occluded(o, d).occluded, scene.occluded(o, d).occluded)
    np.testing.assert_array_equal(other.count(o, d).count, scene.count(o, d).count)
    a_near, b_near = scene.nearest(o), other.nearest(o)
    np.testing.assert_array_equal(b_near.distance.view(np.uint32), a_near.distance.view(np.uint32))
    # Every hit through the permutation, in (t, mesh, prim) order per ray.
    a_all, b_all = scene.hits(o, d, max_hits=64), other.hits(o, d, max_hits=64)
    np.testing.assert_array_equal(b_all.offsets, a_all.offsets)
    assert not a_all.truncated.any()
    b_prim = b_all.prim.copy()
    for m, perm in enumerate(perms):
        b_prim[b_all.mesh == m] = perm[b_all.prim[b_all.mesh == m]]
    ray_of = np.repeat(np.arange(len(o)), np.diff(a_all.offsets))
    a_order = np.lexsort((a_all.prim, a_all.mesh, a_all.t, ray_of))
    b_order = np.lexsort((b_prim, b_all.mesh, b_all.t, ray_of))
    np.testing.assert_array_equal(a_order, np.arange(len(a_order)))  # already in that order
    np.testing.assert_array_equal(b_all.t[b_order], a_all.t)
    np.testing.assert_array_equal(b_prim[b_order], a_all.prim)


def test_morton_order_sorts_rows_by_their_box_centres():
    """A mesh's rows follow the Morton codes of their box centres, and ids keep the face rows."""
    v, f = pg.triangle_soup(3000, np.random.default_rng(52))
    packed = dacrt.packed.pack_mesh(v, f, "morton")
    codes = dacrt.points.triangle_codes(
        packed.bounds, np.arange(len(packed), dtype=np.int32), packed.box
    )
    assert np.all(np.diff(codes) >= 0)
    np.testing.assert_array_equal(packed.verts, v[f[packed.ids]].reshape(-1, 9))


def test_auto_order_sorts_faces_that_come_incoherent_and_keeps_coherent_ones():
    """The "auto" order keeps a grid's faces, which come row by row, in their order, and sorts
    the same faces shuffled; "file" keeps even shuffled faces; a bad order is the caller's
    error."""
    v, f = pg.grid(40, 2.0)
    shuffled = f[np.random.default_rng(53).permutation(len(f))]
    rows = np.arange(len(f))
    assert np.array_equal(dacrt.Scene([(v, f)])._base.ids, rows)
    assert not np.array_equal(dacrt.Scene([(v, f)], order="morton")._base.ids, rows)
    assert np.array_equal(dacrt.Scene([(v, shuffled)], order="file")._base.ids, rows)
    auto = dacrt.Scene([(v, shuffled)])._base
    codes = dacrt.points.triangle_codes(auto.bounds, rows.astype(np.int32), auto.box)
    assert np.all(np.diff(codes) >= 0)
    with pytest.raises(dacrt.InputError, match="order must be one of auto, morton, file"):
        dacrt.Scene([(v, f)], order="sorted")
