"""``Scene.hits`` and ``Scene.count`` against the exact reference, Open3D, and each other.

Random rays pass through no edge or vertex, so on them the engine's crossings must be the
reference's exactly (``prim``), with ``t``, ``u``, ``v`` and normals to float32 tolerance. Rays
aimed exactly at the vertices and edges of closed meshes test the half-open rule: the count's
parity is exact (even from outside, odd from inside), and it equals the reference's wherever
every way of moving the ray off the edge or vertex gives one count (``reference.count_range``).
Where the engine's float64 arithmetic is exact (dyadic vertices, a direction whose dominant
component is a power of two) its choice must be the contract's rule itself, which the reference
reproduces with ``perturbation="shear"``.
"""

from __future__ import annotations

import functools

import crossing_rays as cr
import hitlist_checks as hc
import numpy as np
import procedural as pg
import pytest
import reference
import sample_scenes

import dacrt

BIG = 256  # max_hits that truncates nothing here (the engine holds max_hits + 1 slots a ray)
MESH_MASKS = np.array([0b0001, 0b0010, 0b0110, 0xFFFFFFFF], np.uint32)
RAY_MASKS = np.array([0b0001, 0b0010, 0b0100, 0b1000, 0b0011, 0xFFFFFFFF], np.uint32)
GENERIC_SCENES = ("soup", "multi", "teapot", "bunny", "sibenik_slice")


# ---------------------------------------------------------------------------------------------
# Scenes, rays and the reference's answers, built once per session
# ---------------------------------------------------------------------------------------------


def _meshes(name):
    if name in sample_scenes.SCENES:
        return sample_scenes.SCENES[name](5)
    if name == "sibenik_slice":
        # The nave between x = -4 and x = 4: a quarter of the cathedral's triangles.
        v, f = sample_scenes.load_shared("sibenik")
        centre_x = v[f].mean(axis=1)[:, 0]
        return [(v, f[np.abs(centre_x) < 4.0])]
    return [sample_scenes.load_shared(name)]


@functools.cache
def generic_case(name):
    """(meshes, vertices, faces, offsets, origins, directions, tmin, tmax, full, window):
    random rays over a scene, random windows, and the reference's crossings without and with
    the windows."""
    meshes = _meshes(name)
    vertices, faces, offsets = pg.concat(meshes)
    n_rays = 600 if len(faces) < 10_000 else 300
    origins, directions = pg.mixed_rays(pg.bounds(vertices), n_rays, np.random.default_rng(21))
    rng = np.random.default_rng(22)
    scale = np.linalg.norm(np.ptp(pg.bounds(vertices), axis=0))
    tmin = rng.uniform(0.0, 0.6 * scale, n_rays).astype(np.float32)
    tmax = (tmin + rng.uniform(0.0, 0.8 * scale, n_rays)).astype(np.float32)
    full = reference.all_hits(vertices, faces, origins, directions)
    window = reference.all_hits(vertices, faces, origins, directions, tmin, tmax)
    return meshes, vertices, faces, offsets, origins, directions, tmin, tmax, full, window


def generic(name):
    """``generic_case(name)``; skips the test when ../shared is absent (a skip is not cached)."""
    return generic_case(name)


# ---------------------------------------------------------------------------------------------
# Random rays: the reference, Open3D, every strategy and thread count
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", GENERIC_SCENES)
def test_hits_and_count_match_reference(name):
    meshes, v, f, offsets, o, d, tmin, tmax, full, window = generic(name)
    scene = dacrt.Scene(meshes)
    assert full.count.sum() > len(o) // 2 and (full.count > 1).any()
    everything = scene.hits(o, d, max_hits=BIG)
    hc.check_hitlist_layout(everything, len(o))
    assert not everything.truncated.any()
    hc.check_hits_match_reference(everything, full, v, f, offsets, o, d, "hits")
    hc.check_first_hit_is_closest(everything, scene.closest(o, d))
    counts = scene.count(o, d)
    assert isinstance(counts, dacrt.Counts) and len(counts) == len(o)
    assert counts.count.dtype == np.int32 and counts.count.shape == (len(o),)
    np.testing.assert_array_equal(counts.count, full.count)
    # The default max_hits is 16.
    default = scene.hits(o, d)
    np.testing.assert_array_equal(default.truncated, full.count > 16)
    np.testing.assert_array_equal(np.diff(default.offsets), np.minimum(full.count, 16))
    # Windows [tmin, tmax].
    windowed = scene.hits(o, d, tmin, tmax, max_hits=BIG)
    hc.check_hitlist_layout(windowed, len(o))
    assert 0 < window.count.sum() < full.count.sum()
    hc.check_hits_match_reference(windowed, window, v, f, offsets, o, d, "hits in windows")
    assert np.all(windowed.t >= np.repeat(tmin, windowed.counts))
    assert np.all(windowed.t <= np.repeat(tmax, windowed.counts))
    hc.check_first_hit_is_closest(windowed, scene.closest(o, d, tmin, tmax))
    np.testing.assert_array_equal(scene.count(o, d, tmin, tmax).count, window.count)


@pytest.mark.parametrize("max_hits", [1, 3])
@pytest.mark.parametrize("name", ["soup", "teapot"])
def test_max_hits_keeps_the_nearest(name, max_hits):
    """A list cut at max_hits is the full list's first max_hits hits, bit for bit, and
    truncated says exactly where hits were dropped."""
    meshes, v, f, offsets, o, d, tmin, tmax, full, window = generic(name)
    scene = dacrt.Scene(meshes)
    everything = scene.hits(o, d, max_hits=BIG)
    cut = scene.hits(o, d, max_hits=max_hits)
    hc.check_hitlist_layout(cut, len(o))
    np.testing.assert_array_equal(cut.truncated, full.count > max_hits)
    assert cut.truncated.any() and (~cut.truncated & (full.count > 0)).any()
    rank = np.arange(len(everything.t)) - np.repeat(everything.offsets[:-1], everything.counts)
    kept = rank < max_hits
    np.testing.assert_array_equal(np.diff(cut.offsets), np.minimum(full.count, max_hits))
    for name_ in ("t", "mesh", "prim", "u", "v", "normal"):
        np.testing.assert_array_equal(getattr(cut, name_), getattr(everything, name_)[kept])
    nearest, truncated = reference.nearest(full, max_hits)
    np.testing.assert_array_equal(truncated, cut.truncated)
    hc.check_hits_match_reference(cut, nearest, v, f, offsets, o, d, f"max_hits={max_hits}")


@functools.cache
def _default_answers(name):
    meshes, *_, o, d, tmin, tmax, _, _ = generic(name)
    masks = MESH_MASKS[np.arange(len(meshes)) % len(MESH_MASKS)]
    ray_masks = np.random.default_rng(23).choice(RAY_MASKS, len(o))
    scene = dacrt.Scene(meshes, masks=masks)
    args = (o, d, tmin, tmax)
    return scene, args, ray_masks, _answers(scene, args, ray_masks, "sampling", 1)


def _answers(scene, args, ray_masks, strategy, threads):
    o, d, tmin, tmax = args
    run = {"strategy": strategy, "threads": threads}
    return {
        "hits": scene.hits(o, d, max_hits=5, **run),
        "hits windowed": scene.hits(*args, max_hits=BIG, cull="back", **run),
        "hits masked": scene.hits(o, d, mask=ray_masks, max_hits=BIG, **run),
        "count": scene.count(o, d, **run).count,
        "count windowed": scene.count(*args, cull="front", **run).count,
        "count masked": scene.count(o, d, mask=ray_masks, **run).count,
    }


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("name", GENERIC_SCENES)
def test_every_strategy_and_thread_count_gives_the_same_answers(name, strategy, threads):
    scene, args, ray_masks, default = _default_answers(name)
    got = _answers(scene, args, ray_masks, strategy, threads)
    for what, answer in default.items():
        if what.startswith("hits"):
            hc.assert_same_hitlist(got[what], answer, f"{strategy}, {threads} threads, {what}")
        else:
            np.testing.assert_array_equal(got[what], answer, f"{strategy}, {threads}, {what}")


@pytest.mark.parametrize("batch", ["scattered", "camera"])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_two_threads_split_a_large_batch_without_changing_it(strategy, batch):
    """A batch large enough to be cut into chunks on two threads (scattered origins: slabs;
    one eye: coherent chunks) gives the one-thread hit lists and counts bit for bit."""
    meshes = sample_scenes.multi(26)
    v, _, _ = pg.concat(meshes)
    n_rays = 2 * dacrt.chunks.MIN_RAYS_PER_THREAD + 101
    if batch == "scattered":
        o, d = pg.mixed_rays(pg.bounds(v), n_rays, np.random.default_rng(26))
    else:
        o, d = pg.camera_rays(pg.bounds(v), 182, 182)
        o, d = o[:n_rays], d[:n_rays]
    masks = MESH_MASKS[np.arange(len(meshes)) % len(MESH_MASKS)]
    ray_masks = np.random.default_rng(27).choice(RAY_MASKS, len(o))
    scene = dacrt.Scene(meshes, masks=masks)
    one = {"strategy": strategy, "threads": 1}
    two = {"strategy": strategy, "threads": 2}
    for options in ({"max_hits": 4}, {"max_hits": 64, "mask": ray_masks, "cull": "back"}):
        a = scene.hits(o, d, **options, **one)
        hc.assert_same_hitlist(scene.hits(o, d, **options, **two), a, f"two threads {options}")
        assert a.truncated.any() == (options["max_hits"] == 4) and a.offsets[-1] > 2000
    np.testing.assert_array_equal(scene.count(o, d, **two).count, scene.count(o, d, **one).count)


@pytest.mark.parametrize("name", ["teapot", "bunny", "sibenik_slice"])
def test_open3d_lists_the_same_hits(name):
    """Open3D's count_intersections and list_intersections (sorted) equal count and hits on the
    rays whose crossings are apart in t (Open3D drops one of two crossings at one float32 t)."""
    pytest.importorskip("open3d")
    from oracles import open3d_hits as open3d_oracle

    meshes, v, f, offsets, o, d, tmin, tmax, full, window = generic(name)
    scene = dacrt.Scene(meshes)
    hl = scene.hits(o, d, max_hits=BIG)
    ray = full.ray
    close = (ray[1:] == ray[:-1]) & (np.abs(np.diff(full.t)) <= 1e-5 * full.t[1:])
    apart = np.ones(len(o), bool)
    apart[ray[1:][close]] = False
    assert apart.mean() > 0.97
    counts = scene.count(o, d).count
    np.testing.assert_array_equal(counts[apart], open3d_oracle.count(v, f, o, d)[apart])
    listed = open3d_oracle.list_hits(v, f, o, d)
    gprim = offsets[hl.mesh] + hl.prim
    for i in np.flatnonzero(apart):
        ours = slice(hl.offsets[i], hl.offsets[i + 1])
        theirs = slice(listed.offsets[i], listed.offsets[i + 1])
        np.testing.assert_array_equal(gprim[ours], listed.prim[theirs], f"ray {i}")
        np.testing.assert_allclose(hl.t[ours], listed.t[theirs], rtol=2e-6, err_msg=f"ray {i}")


# ---------------------------------------------------------------------------------------------
# Rays exactly through vertices and edges: the half-open rule
# ---------------------------------------------------------------------------------------------


@functools.cache
def closed_case(name, side):
    """A closed mesh, rays exactly through its vertices and edge midpoints from ``side``, and
    the reference's count range for them."""
    v, f = cr.closed_mesh(name)
    targets = cr.feature_points(v, f)
    if side == "outside":
        o, d = cr.rays_through(targets, np.random.default_rng(31))
    else:
        o, d = cr.rays_from(cr.INSIDE_POINT, targets)
    return v, f, o, d, reference.count_range(v, f, o, d)


@pytest.mark.parametrize("side", ["outside", "inside"])
@pytest.mark.parametrize("name", cr.CLOSED_MESHES)
def test_count_through_vertices_and_edges_of_closed_meshes(name, side):
    v, f, o, d, (lo, hi) = closed_case(name, side)
    scene = dacrt.Scene([(v, f)])
    parity = 0 if side == "outside" else 1
    for strategy in dacrt.STRATEGIES:
        count = scene.count(o, d, strategy=strategy).count
        wrong = np.flatnonzero(count % 2 != parity)
        assert not len(wrong), (
            f"{strategy}: {len(wrong)} rays with the wrong parity, first: origin "
            f"{o[wrong[0]].tolist()}, direction {d[wrong[0]].tolist()}, got {count[wrong[0]]}"
        )
        outside = np.flatnonzero((count < lo) | (count > hi))
        assert not len(outside), (
            f"{strategy}: a count no moved ray has: origin {o[outside[0]].tolist()}, direction "
            f"{d[outside[0]].tolist()}, expected {lo[outside[0]]}..{hi[outside[0]]}, "
            f"got {count[outside[0]]}"
        )
        hl = scene.hits(o, d, max_hits=BIG, strategy=strategy)
        np.testing.assert_array_equal(hl.counts, count)
        hc.check_hitlist_layout(hl, len(o))
    # Rays that cross (lo == hi) are most; from outside some graze a silhouette too.
    assert (lo == hi).mean() > 0.35
    if side == "outside":
        assert (lo < hi).any()


def _exact_directions(n, rng):
    """Integer directions whose dominant component is +-8 and the others within +-7: the
    watertight test's shear (d[kx] / d[kz]) and every product after it are exact in float64."""
    d = rng.integers(-7, 8, size=(n, 3)).astype(np.float64)
    axis = rng.integers(0, 3, size=n)
    d[np.arange(n), axis] = rng.choice([-8.0, 8.0], size=n)
    return d


@pytest.mark.parametrize("name", [*cr.CLOSED_MESHES, "grid"])
def test_exact_arithmetic_follows_the_contract_rule(name):
    """Where the engine's arithmetic is exact, a ray exactly through an edge or vertex crosses
    the triangles the contract's rule names (zero edge function: the sign of its x-derivative in
    the sheared frame, else of its y-derivative), grazing rays included."""
    if name == "grid":
        gv, f = pg.grid(8, 1.0, alternate=True)
        v = pg.transform(gv, offset=(0.0, 0.0, 0.25))
        targets = cr.feature_points(v, f)
    else:
        v, f = cr.closed_mesh(name)
        targets = cr.feature_points(v, f)
    rng = np.random.default_rng(32)
    directions = _exact_directions(len(targets), rng)
    o, d = pg.rays_at(targets, directions, 4.0)
    cr.assert_exact(o, d, targets, 4.0)
    ref = reference.all_hits(v, f, o, d, perturbation="shear")
    lo, hi = reference.count_range(v, f, o, d)
    assert (lo < hi).any() or name == "grid"
    scene = dacrt.Scene([(v, f)])
    for strategy in dacrt.STRATEGIES:
        hl = scene.hits(o, d, max_hits=BIG, strategy=strategy)
        bad = np.flatnonzero(hl.counts != ref.count)
        assert not len(bad), (
            f"{strategy}: {len(bad)} rays, first: origin {o[bad[0]].tolist()}, direction "
            f"{d[bad[0]].tolist()}: the rule gives {ref.count[bad[0]]} crossings "
            f"{ref.prim[ref.offsets[bad[0]] : ref.offsets[bad[0] + 1]].tolist()}, got "
            f"{hl.prim[hl.offsets[bad[0]] : hl.offsets[bad[0] + 1]].tolist()}"
        )
        ray = np.repeat(np.arange(len(o)), hl.counts)
        np.testing.assert_array_equal(
            hl.prim[np.lexsort((hl.prim, ray))], ref.prim[np.lexsort((ref.prim, ref.ray))]
        )
        np.testing.assert_array_equal(scene.count(o, d, strategy=strategy).count, ref.count)


def test_parity_through_a_real_closed_mesh(load_shared):
    """The dragon is closed (every edge shared by two consistently wound faces): rays from
    outside its box through (within float32 rounding of) its vertices and edge midpoints cross
    it an even number of times, and as often as the reference says."""
    trimesh = pytest.importorskip("trimesh")
    v, f = load_shared("dragon")
    assert trimesh.Trimesh(v, f, process=False).is_watertight
    rng = np.random.default_rng(33)
    edges = cr.edges(f[rng.choice(len(f), 150, replace=False)])
    vv = v.astype(np.float64)
    targets = np.concatenate(
        [vv[rng.choice(len(v), 150)], (vv[edges[:150, 0]] + vv[edges[:150, 1]]) / 2]
    )
    box = pg.bounds(v)
    o, d = pg.rays_at(targets, pg.unit_vectors(len(targets), rng), 2 * np.ptp(box, axis=0).max())
    outside = np.any((o < box[0]) | (o > box[1]), axis=1)
    assert outside.all()
    count = dacrt.Scene([(v, f)]).count(o, d).count
    assert np.all(count % 2 == 0) and (count > 0).mean() > 0.9
    lo, hi = reference.count_range(v, f, o, d)
    assert np.all((lo <= count) & (count <= hi))


# ---------------------------------------------------------------------------------------------
# Culling, masks, and the edge cases
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cull", ["none", "back", "front"])
def test_cull_and_masks_match_reference(cull):
    """Per-mesh masks (Scene(masks=)), per-ray masks (mask=) and culling drop the same crossings
    from hits and count as from the reference."""
    meshes, v, f, offsets, o, d, *_ = generic("multi")
    masks = MESH_MASKS[: len(meshes)]
    ray_masks = np.random.default_rng(24).choice(RAY_MASKS, len(o))
    face_masks = np.repeat(masks, np.diff(offsets)).astype(np.uint32)
    scene = dacrt.Scene(meshes, masks=masks)
    for mask, ray_mask in ((None, None), (ray_masks, ray_masks), (0b0010, np.uint32(0b0010))):
        ref = reference.all_hits(v, f, o, d, cull=cull, ray_masks=ray_mask, face_masks=face_masks)
        assert ref.count.sum() > 20
        hl = scene.hits(o, d, max_hits=BIG, cull=cull, mask=mask)
        hc.check_hitlist_layout(hl, len(o))
        hc.check_hits_match_reference(hl, ref, v, f, offsets, o, d, f"cull={cull}, mask={mask}")
        count = scene.count(o, d, cull=cull, mask=mask).count
        np.testing.assert_array_equal(count, ref.count)
        if cull != "none":
            facing = np.einsum("ij,ij->i", hl.normal, np.repeat(d, hl.counts, axis=0))
            assert np.all(facing < 0) if cull == "back" else np.all(facing > 0)


def test_empty_batch_and_empty_scenes():
    v, f = pg.single_triangle()
    none = np.zeros((0, 3), np.float32)
    hl = dacrt.Scene([(v, f)]).hits(none, none)
    hc.check_hitlist_layout(hl, 0)
    np.testing.assert_array_equal(hl.offsets, [0])
    counts = dacrt.Scene([(v, f)]).count(none, none)
    assert counts.count.shape == (0,) and counts.count.dtype == np.int32
    o = np.array([[0.25, 0.25, 1.0], [0.0, 0.0, 0.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]], np.float32)
    for scene in (dacrt.Scene([]), dacrt.Scene([(v, f[:0])]), dacrt.Scene([(none, f[:0])])):
        hl = scene.hits(o, d)
        hc.check_hitlist_layout(hl, 2)
        np.testing.assert_array_equal(hl.offsets, [0, 0, 0])
        assert not hl.truncated.any()
        np.testing.assert_array_equal(scene.count(o, d).count, [0, 0])


def test_degenerate_triangles_are_never_counted():
    rng = np.random.default_rng(25)
    v, f, targets = pg.degenerate_triangles(rng, 100)
    o, d = pg.rays_at(targets, pg.unit_vectors(len(targets), rng), 0.5)
    scene = dacrt.Scene([(v, f)])
    np.testing.assert_array_equal(scene.count(o, d).count, 0)
    assert scene.hits(o, d).offsets[-1] == 0
    # Mixed in a soup, they change nothing.
    v, f, degenerate, targets = pg.with_degenerates(rng)
    o, d = pg.mixed_rays(pg.bounds(v), 300, rng)
    ref = reference.all_hits(v, f, o, d)
    hl = dacrt.Scene([(v, f)]).hits(o, d, max_hits=BIG)
    assert not degenerate[hl.prim].any()
    hc.check_hits_match_reference(hl, ref, v, f, [0, len(f)], o, d, "soup with degenerates")


def test_coplanar_duplicates_count_each_time():
    """The same triangle three times in one mesh (as given, corners rotated, reversed) and once
    more in another mesh: a ray through its inside crosses all four; through a shared edge of a
    doubled grid, two."""
    v, f = pg.single_triangle()
    f3 = np.array([[0, 1, 2], [1, 2, 0], [2, 1, 0]], np.int32)
    scene = dacrt.Scene([(v, f3), (v, f)])
    o = np.array([[0.25, 0.25, 1.0], [0.3, 0.1, -1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0], [0.1, 0.2, 1.0]], np.float32)
    np.testing.assert_array_equal(scene.count(o, d).count, [4, 4])
    hl = scene.hits(o, d)
    np.testing.assert_array_equal(hl.mesh, [0, 0, 0, 1] * 2)
    np.testing.assert_array_equal(hl.prim, [0, 1, 2, 0] * 2)
    assert np.all(hl.t[:4] == hl.t[0]) and np.all(hl.t[4:] == hl.t[4])
    np.testing.assert_array_equal(scene.count(o, d, cull="back").count, [3, 1])
    gv, gf = pg.grid(4, 1.0, alternate=True)
    rays = [
        pg.grid_rays(gv, gf, 4, kind, "exact_oblique")[:2] for kind in ("vertices", "midpoints")
    ]
    go, gd = (np.concatenate(x) for x in zip(*rays))
    doubled = dacrt.Scene([(gv, gf), (gv, gf)])
    np.testing.assert_array_equal(doubled.count(go, gd).count, 2)
    hl = doubled.hits(go, gd)
    np.testing.assert_array_equal(hl.mesh, np.tile([0, 1], len(go)))
    np.testing.assert_array_equal(hl.prim[0::2], hl.prim[1::2])


@pytest.mark.parametrize("max_hits", [0, -1, 1.5, True, "3", None, np.float32(2)])
def test_bad_max_hits_is_a_value_error(max_hits):
    v, f = pg.single_triangle()
    o = np.array([[0.25, 0.25, 1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0]], np.float32)
    with pytest.raises(dacrt.InputError, match="max_hits"):
        dacrt.Scene([(v, f)]).hits(o, d, max_hits=max_hits)


@pytest.mark.parametrize("max_hits", [2**31 - 2, 2**31 - 1, 2**31, 2**70])
@pytest.mark.parametrize("placed", [False, True])
def test_a_max_hits_beyond_int32_keeps_every_hit(max_hits, placed):
    """A ray has fewer hits than the scene has triangles: any larger max_hits keeps them all
    (2**31 and up, or 2**31 - 1 with placed meshes, raised an OverflowError)."""
    v, f = pg.single_triangle()
    o = np.array([[0.25, 0.25, 1.0], [0.25, 0.25, -1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]], np.float32)
    scene = dacrt.Scene(
        [(v, f), (v - [0, 0, 2], f)], transforms=[np.eye(4), None] if placed else None
    )
    every = scene.hits(o, d, max_hits=max_hits)
    np.testing.assert_array_equal(every.counts, [2, 1])
    assert not every.truncated.any()


def test_numpy_integer_max_hits_is_accepted():
    v, f = pg.single_triangle()
    o = np.array([[0.25, 0.25, 1.0]], np.float32)
    d = np.array([[0.0, 0.0, -1.0]], np.float32)
    hl = dacrt.Scene([(v, f)]).hits(o, d, max_hits=np.int64(1))
    np.testing.assert_array_equal(hl.offsets, [0, 1])


def test_a_direction_component_whose_inverse_overflows_keeps_its_hit():
    """d_x = 1e-40: float32's 1/d_x is inf, which put the plane x = 0 of the triangle's box at
    an infinite distance from an origin 1.4e-45 before it; the ray crosses the triangle at t = 1
    (exactly: the reference)."""
    v = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.int32([[0, 1, 2]])
    o, d = np.float32([[-1.4e-45, 0.3, 1]]), np.float32([[1e-40, 0, -1]])
    assert reference.count(v, f, o, d, perturbation="shear").tolist() == [1]
    scene = dacrt.Scene([(v, f)])
    for strategy in dacrt.STRATEGIES:
        hit = scene.closest(o, d, strategy=strategy)
        assert hit.t.tolist() == [1.0] and hit.prim.tolist() == [0], strategy
        assert scene.count(o, d, strategy=strategy).count.tolist() == [1], strategy


@pytest.mark.parametrize("seed", range(10))
def test_direction_components_whose_inverse_overflows_answer_alike_in_every_batch(seed):
    """Components under 1/FLT_MAX beside geometry on the planes through 0 and origins 1e-44
    from them: each ray answers the same in every strategy and alone as in its batch (a box
    test that dropped boxes such rays enter dropped different hits in different trees)."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    v = (rng.random((3 * n, 3)) - 0.5).astype(np.float32)
    v[rng.random(v.shape) < 0.2] = 0.0
    f = np.arange(3 * n).reshape(-1, 3)
    o = (rng.random((30, 3)) - 0.5).astype(np.float32)
    o[rng.random(o.shape) < 0.3] *= np.float32(1e-44)
    d = (rng.random((30, 3)) - 0.5).astype(np.float32)
    tiny = rng.random(d.shape) < 0.4
    signs = rng.choice([-1, 1], tiny.sum())
    d[tiny] = (signs * 10.0 ** rng.uniform(-45, -38.5, tiny.sum())).astype(np.float32)
    d[~d.any(axis=1), 2] = 1
    assert (np.abs(d[d != 0]) < 1 / np.finfo(np.float32).max).any()  # 1/d overflows
    scene = dacrt.Scene([(v, f)])
    batch = scene.count(o, d).count
    first = scene.closest(o, d)
    for strategy in dacrt.STRATEGIES:
        np.testing.assert_array_equal(scene.count(o, d, strategy=strategy).count, batch)
        np.testing.assert_array_equal(scene.closest(o, d, strategy=strategy).prim, first.prim)
    for r in range(len(o)):
        alone = slice(r, r + 1)
        assert scene.count(o[alone], d[alone]).count[0] == batch[r], r
        assert scene.closest(o[alone], d[alone]).prim[0] == first.prim[r], r
