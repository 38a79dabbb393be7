"""dacrt.leaf against brute force: a leaf's answer for each ray is the smallest (t, triangle) over
its triangles of the scalar watertight test, ties to the lower triangle, and agrees with the
numpy reference. Both loop orders (few triangles: by rays; else by triangles) are exercised."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import reference

from dacrt.contracts import STAT_NAMES
from dacrt.geometry import (
    corners_from_origin,
    crossing,
    culled,
    intersect_triangle,
    watertight_setup,
)
from dacrt.leaf import NO_HIT, intersect_leaf, leaf_scratch
from dacrt.query import ALL_HITS, ANY_HIT, COUNT, CULL_FLAGS, MASKED, QueryArrays
from dacrt.rays import BEST_T, new_records, pack_rays
from dacrt.triangles import Triangles

MODE_CLOSEST = 0
MODE_OCCLUDED = ANY_HIT


def leaf_scene(seed, n_tris, n_rays):
    """Triangles (n_tris, 9) float32 with every one also present as a later duplicate row (exact
    ties), and rays aimed at them from around, with tmin and tmax that cut some hits off."""
    rng = np.random.default_rng(seed)
    n_unique = max(1, n_tris // 2)
    corners = rng.uniform(-1, 1, (n_unique, 3, 3)).astype(np.float32)
    rows = np.concatenate([np.arange(n_unique), rng.integers(0, n_unique, n_tris - n_unique)])
    tri_verts = np.ascontiguousarray(corners[rows].reshape(n_tris, 9))
    aim = corners[rng.integers(0, n_unique, n_rays)]
    targets = (aim * rng.dirichlet([1, 1, 1], n_rays)[:, :, None]).sum(axis=1)
    targets += rng.normal(scale=0.1, size=(n_rays, 3))
    origins = rng.uniform(-3, 3, (n_rays, 3)).astype(np.float32)
    directions = (targets - origins).astype(np.float32)
    tmin = rng.uniform(0.0, 0.3, n_rays).astype(np.float32)
    tmax = np.where(rng.random(n_rays) < 0.7, np.inf, rng.uniform(0.5, 1.5, n_rays))
    return tri_verts, origins, directions, tmin, tmax.astype(np.float32), rng


def run_leaf(
    mode, tri_verts, origins, directions, tmin, tmax, tri_ids, ray_masks=None, tri_masks=None
):
    """intersect_leaf over every ray and ``tri_ids``; returns best_t, best_tri, u, v by ray, or
    (n_hits, list_t, list_tri) for COUNT and ALL_HITS. With ``ray_masks`` (n,) and ``tri_masks``
    (F,) uint32 the MASKED bit is set."""
    n = len(origins)
    # Records in another order than the rays: answers go by ray id, not by record.
    ray_ids = np.random.default_rng(n).permutation(n).astype(np.int32)
    rays = new_records(n)
    assert pack_rays(origins, directions, tmin, tmax, ray_ids, rays)
    best_tri = np.full(n, NO_HIT, np.int32)
    hit_u = np.zeros(n, np.float32)
    hit_v = np.zeros(n, np.float32)
    no_masks = np.empty(0, np.uint32)
    if ray_masks is not None:
        mode |= MASKED
    list_size = len(tri_ids) + 1 if mode & ALL_HITS else 0
    n_hits = np.zeros(n if mode & (ALL_HITS | COUNT) else 0, np.int32)
    list_t = np.empty((n if list_size else 0, list_size), np.float32)
    list_tri = np.empty((n if list_size else 0, list_size), np.int32)
    arrays = QueryArrays(
        best_tri=best_tri,
        hit_u=hit_u,
        hit_v=hit_v,
        ray_masks=no_masks if ray_masks is None else ray_masks,
        tri_masks=no_masks if tri_masks is None else tri_masks,
        tri_keys=np.arange(len(tri_verts), dtype=np.int32),
        n_hits=n_hits,
        list_t=list_t,
        list_tri=list_tri,
        hit_mask=np.empty(n, np.bool_),
        tri_bins=np.empty(len(tri_verts), np.uint8),
        stats=np.zeros(len(STAT_NAMES), np.int64),
    )
    tris = Triangles(tri_verts, np.empty((len(tri_verts), 6), np.float32), tri_ids)
    n_tests = intersect_leaf(
        mode, tris, rays, ray_ids, 0, n, 0, len(tri_ids), arrays, leaf_scratch()
    )
    # Every pair is tested, but an occlusion ray skips the blocks after its first hit.
    assert n_tests == n * len(tri_ids) if not mode & ANY_HIT else n_tests <= n * len(tri_ids)
    best_t = np.empty(n, np.float32)
    best_t[ray_ids] = rays[BEST_T >> 2, 3 : 4 * n : 4]
    if mode & (ALL_HITS | COUNT):
        return n_hits, list_t, list_tri
    return best_t, best_tri, hit_u, hit_v


def brute_force(tri_verts, origins, directions, tmin, tmax):
    """Per ray: (t, triangle, u, v) minimising (float32 t, triangle) over every triangle's scalar
    watertight test within [tmin, tmax]; (tmax, NO_HIT, 0, 0) when none."""
    n = len(origins)
    best = [(tmax[i], NO_HIT, np.float32(0), np.float32(0)) for i in range(n)]
    for i in range(n):
        kx, ky, kz, sx, sy, sz = watertight_setup(*directions[i])
        ok = [np.float64(origins[i, k]) for k in (kx, ky, kz)]
        for tri in range(len(tri_verts)):
            hit, t, u, v = intersect_triangle(tri_verts, tri, *ok, kx, ky, kz, sx, sy, sz)
            t = np.float32(t)
            if hit and tmin[i] <= t and (t, tri) < best[i][:2]:
                best[i] = (t, tri, np.float32(u), np.float32(v))
    return [np.array(column) for column in zip(*best)]


# (triangles, rays): by rays (fewer than 8 triangles, 16 rays or more), by triangles otherwise,
# and blocks of 64 with a remainder either way.
SHAPES = [(3, 40), (7, 16), (7, 15), (8, 40), (70, 5), (2, 150), (130, 20)]


@pytest.mark.parametrize("n_tris,n_rays", SHAPES)
@pytest.mark.parametrize("seed", [0, 1])
def test_closest_leaf_equals_brute_force_ties_to_the_lower_triangle(seed, n_tris, n_rays):
    tri_verts, o, d, tmin, tmax, rng = leaf_scene(seed, n_tris, n_rays)
    tri_ids = rng.permutation(n_tris).astype(np.int32)  # the order of tests changes nothing
    best_t, best_tri, u, v = run_leaf(MODE_CLOSEST, tri_verts, o, d, tmin, tmax, tri_ids)
    want_t, want_tri, want_u, want_v = brute_force(tri_verts, o, d, tmin, tmax)
    assert (want_tri != NO_HIT).sum() >= n_rays // 4, "vacuous: few rays hit"
    np.testing.assert_array_equal(best_tri, want_tri)
    np.testing.assert_array_equal(best_t, want_t)
    hit = want_tri != NO_HIT
    np.testing.assert_array_equal(u[hit], want_u[hit])
    np.testing.assert_array_equal(v[hit], want_v[hit])
    assert (u[~hit] == 0).all() and (v[~hit] == 0).all()


@pytest.mark.parametrize("n_tris,n_rays", SHAPES)
def test_closest_leaf_agrees_with_the_numpy_reference(n_tris, n_rays):
    tri_verts, o, d, tmin, tmax, rng = leaf_scene(2, n_tris, n_rays)
    tri_ids = rng.permutation(n_tris).astype(np.int32)
    best_t, best_tri, _, _ = run_leaf(MODE_CLOSEST, tri_verts, o, d, tmin, tmax, tri_ids)
    vertices, faces = tri_verts.reshape(-1, 3), np.arange(3 * n_tris).reshape(-1, 3)
    bracket = reference.closest_bracket(vertices, faces, o, d, tmin, tmax, eps=1e-4)
    hit = best_tri != NO_HIT
    assert hit[bracket.inner.hit].all(), "the leaf misses rays that hit well inside"
    assert bracket.outer.hit[hit].all(), "the leaf hits rays that miss by a margin"
    clear = bracket.inner.hit & (bracket.outer_second_t > bracket.outer.t * (1 + 1e-4))
    np.testing.assert_allclose(best_t[clear], bracket.exact.t[clear], rtol=1e-5)


@pytest.mark.parametrize("n_tris,n_rays", SHAPES)
def test_occluded_leaf_finds_a_hit_exactly_when_closest_does(n_tris, n_rays):
    tri_verts, o, d, tmin, tmax, rng = leaf_scene(3, n_tris, n_rays)
    tri_ids = rng.permutation(n_tris).astype(np.int32)
    closest_t, closest_tri, _, _ = run_leaf(MODE_CLOSEST, tri_verts, o, d, tmin, tmax, tri_ids)
    best_t, best_tri, _, _ = run_leaf(MODE_OCCLUDED, tri_verts, o, d, tmin, tmax, tri_ids)
    blocked = closest_tri != NO_HIT
    assert blocked.any()
    np.testing.assert_array_equal(best_tri != NO_HIT, blocked)
    assert (best_t[blocked] == -np.inf).all(), "an occlusion ray that hit is not done"
    np.testing.assert_array_equal(best_t[~blocked], tmax[~blocked])


def crossings_brute_force(tri_verts, origins, directions, tmin, tmax):
    """Per ray: the sorted (float32 t, triangle) of every triangle the scalar half-open test
    (``crossing``) says it crosses within [tmin, tmax]."""
    lists = []
    for i in range(len(origins)):
        kx, ky, kz, sx, sy, sz = watertight_setup(*directions[i])
        ok = [np.float64(origins[i, k]) for k in (kx, ky, kz)]
        found = []
        for tri in range(len(tri_verts)):
            corners = corners_from_origin(tri_verts, tri, *ok, kx, ky, kz)
            if crossing(*corners, sx, sy, sz)[0]:
                _, t, _, _ = intersect_triangle(tri_verts, tri, *ok, kx, ky, kz, sx, sy, sz)
                t = np.float32(t)
                if tmin[i] <= t <= tmax[i]:
                    found.append((t, tri))
        lists.append(sorted(found))
    return lists


@pytest.mark.parametrize("n_tris,n_rays", SHAPES)
def test_count_and_hits_leaves_list_every_crossing_in_order(n_tris, n_rays):
    tri_verts, o, d, tmin, tmax, rng = leaf_scene(4, n_tris, n_rays)
    tri_ids = rng.permutation(n_tris).astype(np.int32)
    want = crossings_brute_force(tri_verts, o, d, tmin, tmax)
    assert sum(map(len, want)) >= n_rays // 4, "vacuous: few crossings"
    counts, _, _ = run_leaf(COUNT, tri_verts, o, d, tmin, tmax, tri_ids)
    np.testing.assert_array_equal(counts, [len(found) for found in want])
    n_held, list_t, list_tri = run_leaf(ALL_HITS, tri_verts, o, d, tmin, tmax, tri_ids)
    np.testing.assert_array_equal(n_held, counts)
    for i, found in enumerate(want):
        got = list(zip(list_t[i, : n_held[i]], list_tri[i, : n_held[i]]))
        assert got == found, f"ray {i}"


# Every variant of the leaf: its kind (the leaf folds closest and occluded into one loop per
# order, count and hits into the same loops with the other constant), culling and masks, in both
# loop orders. Closest and occluded with culling or masks go by triangles whatever the shape.
KINDS = {"closest": 0, "occluded": ANY_HIT, "count": COUNT, "hits": ALL_HITS}
CULL_SIDES = {"none": 0.0, "back": -1.0, "front": 1.0}
# By rays: (3, 40), (2, 150) (three blocks); by triangles: (7, 15), (70, 5), (130, 20).
VARIANT_SHAPES = [(3, 40), (2, 150), (7, 15), (70, 5), (130, 20)]


def variant_scene(seed, n_tris, n_rays, masked):
    """``leaf_scene`` with a mask per ray and per triangle (None without ``masked``): masks 1, 2
    and 3, so about a third of the pairs are hidden."""
    tri_verts, o, d, tmin, tmax, rng = leaf_scene(seed, n_tris, n_rays)
    ray_masks = rng.integers(1, 4, n_rays).astype(np.uint32) if masked else None
    tri_masks = rng.integers(1, 4, n_tris).astype(np.uint32) if masked else None
    return tri_verts, o, d, tmin, tmax, ray_masks, tri_masks, rng


def seen_and_kept(tri_verts, tri, ray, frame, cull, ray_masks, tri_masks):
    """Whether ray ``ray`` may hit triangle ``tri``: its mask sees it and the query does not
    cull it. ``frame`` is (okx, oky, okz, kx, ky, kz, sx, sy, sz), as ``culled`` takes them."""
    if ray_masks is not None and (ray_masks[ray] & tri_masks[tri]) == 0:
        return False
    side = CULL_SIDES[cull]
    return side == 0.0 or not culled(tri_verts, tri, *frame, side)


def variant_brute_force(kind, cull, tri_verts, o, d, tmin, tmax, ray_masks, tri_masks):
    """The scalar tests' answer of each ray: (t, triangle, u, v) for closest (ties to the lower
    triangle; (tmax, NO_HIT, 0, 0) for none), whether it hits for occluded, and the sorted
    (t, triangle) crossings for count and hits, among the triangles it sees and keeps."""
    answers = []
    for i in range(len(o)):
        kx, ky, kz, sx, sy, sz = watertight_setup(*d[i])
        ok = [np.float64(o[i, k]) for k in (kx, ky, kz)]
        frame = (*ok, kx, ky, kz, sx, sy, sz)
        best = (tmax[i], NO_HIT, np.float32(0), np.float32(0))
        found = []
        for tri in range(len(tri_verts)):
            if not seen_and_kept(tri_verts, tri, i, frame, cull, ray_masks, tri_masks):
                continue
            hit, t, u, v = intersect_triangle(tri_verts, tri, *ok, kx, ky, kz, sx, sy, sz)
            t = np.float32(t)
            if not hit or not tmin[i] <= t <= tmax[i]:
                continue
            if (t, tri) < best[:2]:
                best = (t, tri, np.float32(u), np.float32(v))
            if crossing(*corners_from_origin(tri_verts, tri, *ok, kx, ky, kz), sx, sy, sz)[0]:
                found.append((t, tri))
        answers.append(best if kind in ("closest", "occluded") else sorted(found))
    return answers


@pytest.mark.parametrize("masked", [False, True], ids=["all-masks", "masked"])
@pytest.mark.parametrize("cull", list(CULL_SIDES))
@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("n_tris,n_rays", VARIANT_SHAPES)
def test_every_leaf_variant_equals_the_scalar_test(n_tris, n_rays, kind, cull, masked):
    """Each kind, culling and masking, by rays and by triangles, gives the scalar watertight
    test's answer bit for bit."""
    tri_verts, o, d, tmin, tmax, ray_masks, tri_masks, rng = variant_scene(
        5, n_tris, n_rays, masked
    )
    tri_ids = rng.permutation(n_tris).astype(np.int32)
    mode = KINDS[kind] | CULL_FLAGS[cull]
    got = run_leaf(mode, tri_verts, o, d, tmin, tmax, tri_ids, ray_masks, tri_masks)
    want = variant_brute_force(kind, cull, tri_verts, o, d, tmin, tmax, ray_masks, tri_masks)
    if kind in ("closest", "occluded"):
        want_t, want_tri, want_u, want_v = (np.array(column) for column in zip(*want))
        hit = want_tri != NO_HIT
        assert hit.sum() >= n_rays // 8, "vacuous: few rays hit"
        best_t, best_tri, u, v = got
        np.testing.assert_array_equal(best_tri != NO_HIT, hit)
        if kind == "occluded":
            assert (best_t[hit] == -np.inf).all()
            np.testing.assert_array_equal(best_t[~hit], tmax[~hit])
            return
        np.testing.assert_array_equal(best_tri, want_tri)
        np.testing.assert_array_equal(best_t, want_t)
        np.testing.assert_array_equal(u[hit], want_u[hit])
        np.testing.assert_array_equal(v[hit], want_v[hit])
        return
    assert sum(map(len, want)) >= n_rays // 8, "vacuous: few crossings"
    n_held, list_t, list_tri = got
    np.testing.assert_array_equal(n_held, [len(found) for found in want])
    if kind == "hits":
        for i, found in enumerate(want):
            assert list(zip(list_t[i, : n_held[i]], list_tri[i, : n_held[i]])) == found, f"ray {i}"


@pytest.mark.parametrize("masked", [False, True], ids=["all-masks", "masked"])
@pytest.mark.parametrize("cull", list(CULL_SIDES))
@pytest.mark.parametrize("n_tris,n_rays", VARIANT_SHAPES)
def test_every_leaf_variant_agrees_with_the_numpy_reference(n_tris, n_rays, cull, masked):
    """Against the independent numpy reference: culling and masks drop the same triangles from
    closest, occluded, count and hits, in both loop orders."""
    tri_verts, o, d, tmin, tmax, ray_masks, tri_masks, rng = variant_scene(
        6, n_tris, n_rays, masked
    )
    tri_ids = rng.permutation(n_tris).astype(np.int32)
    vertices, faces = tri_verts.reshape(-1, 3), np.arange(3 * n_tris).reshape(-1, 3)
    options = {"cull": cull, "ray_masks": ray_masks, "face_masks": tri_masks}
    run = functools.partial(
        run_leaf,
        tri_verts=tri_verts,
        origins=o,
        directions=d,
        tmin=tmin,
        tmax=tmax,
        tri_ids=tri_ids,
        ray_masks=ray_masks,
        tri_masks=tri_masks,
    )

    best_t, best_tri, _, _ = run(CULL_FLAGS[cull])
    bracket = reference.closest_bracket(vertices, faces, o, d, tmin, tmax, eps=1e-4, **options)
    hit = best_tri != NO_HIT
    assert bracket.inner.hit.sum() >= n_rays // 8, "vacuous: few rays hit"
    assert hit[bracket.inner.hit].all(), "the leaf misses rays that hit well inside"
    assert bracket.outer.hit[hit].all(), "the leaf hits rays that miss by a margin"
    clear = bracket.inner.hit & (bracket.outer_second_t > bracket.outer.t * (1 + 1e-4))
    np.testing.assert_allclose(best_t[clear], bracket.exact.t[clear], rtol=1e-5)

    _, occluded_tri, _, _ = run(ANY_HIT | CULL_FLAGS[cull])
    np.testing.assert_array_equal(occluded_tri != NO_HIT, hit)

    want = reference.all_hits(vertices, faces, o, d, tmin, tmax, perturbation="shear", **options)
    counts, _, _ = run(COUNT | CULL_FLAGS[cull])
    np.testing.assert_array_equal(counts, np.diff(want.offsets))
    n_held, list_t, list_tri = run(ALL_HITS | CULL_FLAGS[cull])
    np.testing.assert_array_equal(n_held, counts)
    for i in range(n_rays):
        rows = slice(want.offsets[i], want.offsets[i + 1])
        np.testing.assert_array_equal(np.sort(list_tri[i, : n_held[i]]), np.sort(want.prim[rows]))
        np.testing.assert_allclose(
            np.sort(list_t[i, : n_held[i]]), np.sort(want.t[rows]), rtol=1e-5
        )
