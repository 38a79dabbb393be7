"""Every strategy and thread count gives bitwise the same answers as the default.

The contract promises the same answers for every strategy and thread count, ties included (the
lowest global triangle index wins), so these tests compare whole result arrays bit for bit.
"""

from __future__ import annotations

import assertions as check
import numpy as np
import procedural as pg
import pytest
import sample_scenes

import dacrt


def _grid_vertex_rays():
    """A flat grid and rays exactly through its vertices and edge midpoints: t ties across faces."""
    v, f = pg.grid(16, 1.0, alternate=True)
    o1, d1, _ = pg.grid_rays(v, f, 16, "vertices", "exact_oblique")
    o2, d2, _ = pg.grid_rays(v, f, 16, "midpoints", "normal")
    return [(v, f)], np.concatenate([o1, o2]), np.concatenate([d1, d2]), None, None


def _inside_sphere():
    ((v, f),) = sample_scenes.sphere(40)
    o, d = pg.rays_from_inside(
        (0, 0, 0), 0.9 * pg.inner_radius(v, f), 3000, np.random.default_rng(40)
    )
    return [(v, f)], o, d, None, None


def _soup_with_ranges():
    meshes = sample_scenes.soup(41)
    o, d = sample_scenes.mixed_rays(meshes, 41, n=3000)
    rng = np.random.default_rng(41)
    tmin = rng.uniform(0.0, 0.5, len(o)).astype(np.float32)
    return meshes, o, d, tmin, (tmin + rng.uniform(0.0, 1.5, len(o))).astype(np.float32)


def _multi():
    meshes = sample_scenes.multi(42)
    return meshes, *sample_scenes.mixed_rays(meshes, 42, n=3000), None, None


def _duplicates():
    """A soup with every triangle twice (in both meshes too): every hit is a tie."""
    ((v, f),) = sample_scenes.soup(43)
    meshes = [(v, np.concatenate([f, f[::-1]])), (v, f)]
    return meshes, *sample_scenes.mixed_rays(meshes, 43, n=2000), None, None


def _stacked(n_copies=64, n_rays=3000):
    """Two stacks of identical triangles, one above the other, and rays through both from above
    and from below. Inside a stack every centroid is the same, so splits fall back to the median
    index; every hit is an n-way tie."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float32)
    f = np.array([[0, 1, 2]] * n_copies + [[3, 4, 5]] * n_copies, np.int32)
    rng = np.random.default_rng(46)
    xy = rng.uniform(0.05, 0.45, (n_rays, 2)).astype(np.float32)
    down = rng.random(n_rays) < 0.5
    o = np.column_stack([xy, np.where(down, 2.0, -1.0)]).astype(np.float32)
    d = np.column_stack([np.zeros((n_rays, 2)), np.where(down, -1.0, 1.0)]).astype(np.float32)
    return [(v, f)], o, d, None, None


def _many_rays():
    """40,000 rays from inside a sphere: enough for the engine to split the batch across threads."""
    ((v, f),) = sample_scenes.sphere(44)
    o, d = pg.rays_from_inside(
        (0, 0, 0), 0.9 * pg.inner_radius(v, f), 40_000, np.random.default_rng(44)
    )
    return [(v, f)], o, d, None, None


def _pinwheel():
    meshes = sample_scenes.pinwheel(45)
    return meshes, *sample_scenes.mixed_rays(meshes, 45, n=2000), None, None


def _camera_in_soup():
    """A pinhole camera's rays, all from one point (the partitions then leave the origin rows
    in place), into a soup of triangles: enough rays to split the batch and sample nodes."""
    meshes = sample_scenes.soup(48)
    o, d = pg.camera_rays(pg.bounds(*meshes[0]), 200, 150)
    return meshes, o, d, None, None


def _parallel_in_soup():
    """Parallel rays (one direction, origins on a plane) into a soup of triangles."""
    meshes = sample_scenes.soup(49)
    rng = np.random.default_rng(49)
    o = np.column_stack([rng.uniform(-0.2, 1.2, (30_000, 2)), np.full(30_000, -1.0)])
    d = np.tile([0.3, 0.2, 1.0], (30_000, 1))
    return meshes, o.astype(np.float32), d.astype(np.float32), None, None


def _teapot_camera():
    v, f = sample_scenes.load_shared("teapot")
    o, d = pg.camera_rays(pg.bounds(v, f), 64, 48)
    return [(v, f)], o, d, None, None


CASES = {
    "grid_vertex_rays": _grid_vertex_rays,
    "inside_sphere": _inside_sphere,
    "soup_with_ranges": _soup_with_ranges,
    "multi": _multi,
    "duplicates": _duplicates,
    "stacked": _stacked,
    "many_rays": _many_rays,
    "pinwheel": _pinwheel,
    "camera_in_soup": _camera_in_soup,
    "parallel_in_soup": _parallel_in_soup,
    "teapot_camera": _teapot_camera,
}


@pytest.fixture(scope="module")
def default_answers():
    """Per case: (scene, rays, default closest, default occluded), computed once."""
    cache = {}

    def get(name):
        if name not in cache:
            meshes, o, d, tmin, tmax = CASES[name]()
            scene = dacrt.Scene(meshes)
            cache[name] = (
                scene,
                (o, d, tmin, tmax),
                scene.closest(o, d, tmin, tmax),
                scene.occluded(o, d, tmin, tmax).occluded,
            )
        return cache[name]

    return get


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("case", list(CASES))
def test_strategy_and_threads_match_default(case, strategy, threads, default_answers):
    scene, (o, d, tmin, tmax), closest, occluded = default_answers(case)
    assert np.any(closest.prim >= 0), "vacuous: no hits"
    hits = scene.closest(o, d, tmin, tmax, strategy=strategy, threads=threads)
    check.assert_bitwise_equal(hits, closest, f"{strategy}, threads={threads} vs default")
    occ = scene.occluded(o, d, tmin, tmax, strategy=strategy, threads=threads).occluded
    np.testing.assert_array_equal(occ, occluded, err_msg=f"occluded: {strategy}, threads={threads}")
    np.testing.assert_array_equal(
        occ, np.isfinite(closest.t), err_msg="occluded != isfinite(closest.t)"
    )


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_stats_do_not_change_answers(strategy, default_answers):
    scene, (o, d, tmin, tmax), closest, occluded = default_answers("multi")
    hits = scene.closest(o, d, tmin, tmax, strategy=strategy, stats=True)
    check.assert_bitwise_equal(hits, closest, f"{strategy} with stats")
    answer = scene.occluded(o, d, tmin, tmax, strategy=strategy, stats=True)
    occ, _ = answer.occluded, answer.stats
    np.testing.assert_array_equal(occ, occluded)


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_batch_split_does_not_change_answers(strategy, default_answers):
    """Tracing rays in two halves, or in reverse order, gives each ray the same answer."""
    scene, (o, d, tmin, tmax), closest, _ = default_answers("soup_with_ranges")
    half = len(o) // 2
    first = scene.closest(o[:half], d[:half], tmin[:half], tmax[:half], strategy=strategy)
    second = scene.closest(o[half:], d[half:], tmin[half:], tmax[half:], strategy=strategy)
    joined = type(closest)(
        **{
            k: np.concatenate([getattr(first, k), getattr(second, k)])
            for k in ("t", "mesh", "prim", "u", "v", "normal")
        }
    )
    check.assert_bitwise_equal(joined, closest, f"{strategy}, two halves")
    rev = scene.closest(o[::-1], d[::-1], tmin[::-1], tmax[::-1], strategy=strategy)
    reversed_back = type(closest)(
        **{k: getattr(rev, k)[::-1] for k in ("t", "mesh", "prim", "u", "v", "normal")}
    )
    check.assert_bitwise_equal(reversed_back, closest, f"{strategy}, reversed order")


def test_uniform_origin_is_true_only_when_every_record_shares_origin_and_tmin():
    from dacrt.rays import new_records, pack_rays, uniform_origin

    n = 1000  # several of the check's blocks
    origins = np.tile(np.float32([0.0, 1.5, -2.0]), (n, 1))
    directions = np.tile(np.float32([0.0, 0.0, 1.0]), (n, 1))
    tmin = np.zeros(n, np.float32)
    tmax = np.full(n, np.inf, np.float32)
    ids = np.arange(n, dtype=np.int32)

    def fixed(o, d, t0=tmin):
        rays = new_records(n)
        assert pack_rays(o, d, t0, tmax, ids, rays)
        return uniform_origin(rays, n)

    assert fixed(origins, directions)
    turned = directions.copy()
    turned[n // 3] = [0.0, 0.6, 0.8]
    assert fixed(origins, turned)  # directions may differ
    moved = origins.copy()
    moved[n - 1, 2] = np.nextafter(np.float32(-2.0), np.float32(0.0))
    assert not fixed(moved, directions)
    negative_zero = origins.copy()
    negative_zero[n // 2, 0] = -0.0  # equal to 0.0, but not the same bits
    assert not fixed(negative_zero, directions)
    later_start = tmin.copy()
    later_start[7] = 1e-3
    assert not fixed(origins, directions, later_start)


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("case", ["camera_in_soup", "parallel_in_soup"])
def test_shared_rows_answer_as_when_rows_differ(case, strategy, default_answers):
    """A camera's origin and tmin, which every record shares, are not moved by partitions; one
    more ray that differs in origin, direction and tmin makes them move. Every other ray's
    answers must be the same, bit for bit."""
    scene, (o, d, tmin, tmax), closest, occluded = default_answers(case)
    assert tmin is None and tmax is None
    o_mixed = np.vstack([o, o[:1] + np.float32(0.25)])
    d_mixed = np.vstack([d, -d[:1]])
    tmin_mixed = np.zeros(len(o_mixed), np.float32)
    tmin_mixed[-1] = 0.125
    for threads in (1, 2):
        mixed = scene.closest(o_mixed, d_mixed, tmin_mixed, strategy=strategy, threads=threads)
        head = type(closest)(
            **{k: getattr(mixed, k)[: len(o)] for k in ("t", "mesh", "prim", "u", "v", "normal")}
        )
        check.assert_bitwise_equal(head, closest, f"{strategy}, threads={threads}")
        occ = scene.occluded(
            o_mixed, d_mixed, tmin_mixed, strategy=strategy, threads=threads
        ).occluded
        np.testing.assert_array_equal(occ[: len(o)], occluded)


@pytest.mark.parametrize("threads", [1, 2])
def test_stats_count_every_ray_across_threads(threads, default_answers):
    scene, (o, d, tmin, tmax), closest, _ = default_answers("many_rays")
    hits = scene.closest(o, d, tmin, tmax, threads=threads, stats=True)
    assert hits.stats["rays"] == len(o)
    assert hits.stats["ray_triangle_tests"] >= len(o)  # every ray hits
    check.assert_bitwise_equal(hits, closest, f"threads={threads} with stats")


def test_chunks_cover_every_ray_once_as_slabs_or_in_input_order():
    """Incoherent batches go to threads as slabs of origins unless their input order is already
    coherent; either way every ray is in exactly one chunk, and chunks are balanced."""
    from dacrt.chunks import chunk_ids, plan_chunks
    from dacrt.scene import Scene

    def chunks_of(origins, keep_order):
        plan = plan_chunks(origins, 3, keep_order, scene._box, lambda: scene._centre_counts)
        return [chunk_ids(plan, len(origins), 3, k) for k in range(3)]

    n = 50_000
    scattered = np.random.default_rng(46).uniform(-1, 1, (n, 3)).astype(np.float32)
    scattered[:, 1] *= 3  # y is the widest axis
    ordered = np.sort(scattered, axis=0)  # neighbours in input order start near each other
    # One triangle away from every origin: all rays weigh the same (see the next test).
    scene = Scene([(np.array([[9, 9, 9], [10, 9, 9], [9, 10, 9]], np.float32), [[0, 1, 2]])])
    for origins, expect_slabs in ((scattered, True), (ordered, False)):
        chunks = chunks_of(origins, keep_order=False)
        assert np.array_equal(np.sort(np.concatenate(chunks)), np.arange(n))
        assert all((np.diff(chunk) > 0).all() for chunk in chunks)
        assert max(map(len, chunks)) < 1.1 * n / 3
        in_order = all(np.array_equal(c, np.arange(c[0], c[0] + len(c))) for c in chunks)
        assert in_order != expect_slabs
    slabs = chunks_of(scattered, keep_order=False)
    for lower, upper in zip(slabs, slabs[1:]):
        assert scattered[lower, 1].max() <= scattered[upper, 1].min()
    assert np.array_equal(np.concatenate(chunks_of(scattered, keep_order=True)), np.arange(n))


def test_slabs_hold_fewer_rays_where_the_triangles_are_dense():
    """Slab cuts weigh each ray by the triangles around its origin: with 20,000 small triangles
    in x < 0 and 40 in x > 0, the slab of x < 0 holds fewer rays; every ray is still in exactly
    one slab, and the slabs are ordered along x."""
    from dacrt.chunks import chunk_ids, plan_chunks
    from dacrt.scene import Scene

    rng = np.random.default_rng(47)
    n = 60_000
    origins = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    origins[:, 0] *= 3  # x is the widest axis
    centres = np.concatenate(
        [
            rng.uniform([-3, -1, -1], [0, 1, 1], (20_000, 3)),
            rng.uniform([0, -1, -1], [3, 1, 1], (40, 3)),
        ]
    )
    corners = np.repeat(centres, 3, axis=0) + rng.uniform(-0.01, 0.01, (3 * len(centres), 3))
    scene = Scene([(corners.astype(np.float32), np.arange(3 * len(centres)).reshape(-1, 3))])
    plan = plan_chunks(origins, 2, False, scene._box, lambda: scene._centre_counts)
    dense, sparse = (chunk_ids(plan, n, 2, k) for k in range(2))
    assert np.array_equal(np.sort(np.concatenate([dense, sparse])), np.arange(n))
    assert origins[dense, 0].max() <= origins[sparse, 0].min()
    assert len(dense) < 0.35 * n and origins[dense, 0].max() < 0


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_stacked_triangles_tie_to_the_lowest_index(strategy, threads):
    """Rays from above hit the upper stack first (its lowest index is n_copies), rays from below
    the lower one (index 0), whatever the splits did with the stacks."""
    (meshes, o, d, _, _), n_copies = _stacked(), 64
    hits = dacrt.Scene(meshes).closest(o, d, strategy=strategy, threads=threads)
    from_above = d[:, 2] < 0
    np.testing.assert_array_equal(hits.prim, np.where(from_above, n_copies, 0))
    np.testing.assert_array_equal(hits.t, np.ones(len(o), np.float32))


def test_warmup_compiles_what_an_incoherent_two_thread_query_needs():
    """After dacrt.warmup(), slab cutting compiles nothing more, for plain arrays and for the
    read-only column views a server decodes from a body."""
    from dacrt import chunks

    dacrt.warmup()
    kernels = (chunks.centre_counts, chunks.origin_weights, chunks.slab_ids)
    before = [len(kernel.signatures) for kernel in kernels]
    rays = np.random.default_rng(48).uniform(-1, 1, (40_000, 6)).astype(np.float32)
    rays.flags.writeable = False
    scene = dacrt.Scene([(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), [[0, 1, 2]])])
    scene.closest(rays[:, :3], rays[:, 3:], threads=2)
    scene.closest(np.ascontiguousarray(rays[:, :3]), np.ascontiguousarray(rays[:, 3:]), threads=2)
    assert [len(kernel.signatures) for kernel in kernels] == before


def _halves_scene(mirror):
    """A dense soup of 120,000 triangles under a 4 x 4 grid whose middle column of vertices lies
    exactly on the plane that halves the scene's box, and rays exactly through the grid's
    vertices (ties between triangles on either side of that plane) among random rays: few
    enough rays a triangle that two threads split the triangles, not the rays. The grid's lower
    rows are on the low side of the plane, or with ``mirror`` on the high side, so a tie goes to
    one half or the other."""
    rng = np.random.default_rng(48)
    soup = pg.triangle_soup(120_000, rng)
    v, f = pg.grid(16, 4.0, alternate=True)
    if mirror:
        v[:, 0] = 4.0 - v[:, 0]
    v = v + np.array([-1.5, -1.5, 2.0], np.float32)  # x in [-1.5, 2.5]: halved at x = 0.5
    o1, d1, _ = pg.grid_rays(v, f, 16, "vertices", "exact_oblique")
    o2, d2, _ = pg.grid_rays(v, f, 16, "midpoints", "normal")
    n_random = 2 * dacrt.chunks.MIN_RAYS_PER_THREAD
    o3 = rng.uniform(-0.5, 1.5, (n_random, 3)).astype(np.float32)
    d3 = rng.normal(size=(n_random, 3)).astype(np.float32)
    return [soup, (v, f)], np.concatenate([o1, o2, o3]), np.concatenate([d1, d2, d3])


@pytest.mark.parametrize("mirror", [False, True])
@pytest.mark.parametrize("cull", ["none", "back"])
def test_triangle_halves_on_two_threads_answer_as_one_thread(cull, mirror):
    """A batch of few rays a triangle goes to two threads as halves of the triangles; each ray
    then takes the better of two answers, and that is bit for bit one thread's answer: closest
    hits (ties across the halves included) and occlusion, with culling and mixed ray masks."""
    meshes, o, d = _halves_scene(mirror)
    scene = dacrt.Scene(meshes, masks=[1, 2])
    assert dacrt.chunks.splits_triangles(len(o), scene.n_triangles, 2)
    ray_masks = np.random.default_rng(49).integers(1, 4, len(o)).astype(np.uint32)
    for mask in (None, ray_masks):
        one = scene.closest(o, d, cull=cull, mask=mask, threads=1)
        two = scene.closest(o, d, cull=cull, mask=mask, threads=2)
        check.assert_bitwise_equal(two, one, f"closest, cull={cull}, masks={mask is not None}")
        assert np.isfinite(one.t).sum() > len(o) // 4  # the rays do hit
        blocked = scene.occluded(o, d, cull=cull, mask=mask, threads=1).occluded
        assert np.array_equal(
            scene.occluded(o, d, cull=cull, mask=mask, threads=2).occluded, blocked
        )
        assert np.array_equal(blocked, np.isfinite(one.t))


def test_middle_splits_in_space_where_rays_are_many_a_triangle():
    """At many rays a triangle ``middle`` splits the triangles at the box's middle, as ``sah``
    splits them by cost, whatever the rows' storage order: the halves of an incoherent file
    order (a shuffled soup) box nearly the whole scene at every depth, and walking them would
    test each ray against every node's box."""
    rng = np.random.default_rng(7)
    centres = rng.uniform(-10, 10, (20_000, 1, 3))
    vertices = (centres + rng.uniform(-0.2, 0.2, (20_000, 3, 3))).reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    scene = dacrt.Scene([(vertices, faces)], order="file")
    origins = rng.uniform(-12, 12, (200_000, 3)).astype(np.float32)
    directions = rng.normal(size=(200_000, 3)).astype(np.float32)
    tests = {
        strategy: scene.closest(origins, directions, strategy=strategy, threads=1, stats=True)
        for strategy in ("middle", "sah")
    }
    np.testing.assert_array_equal(tests["middle"].t, tests["sah"].t)
    box_tests = {s: hits.stats["ray_box_tests"] for s, hits in tests.items()}
    assert box_tests["middle"] < 3 * box_tests["sah"], box_tests
