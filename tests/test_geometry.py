"""dacrt.geometry against plain numpy: the slab test, the watertight triangle test, the cull
distance and the geometric normal. Seeded and parametrised; kernels are called directly."""

from __future__ import annotations

import numpy as np
import procedural as pg
import pytest

from dacrt.geometry import cull_distance, intersect_triangle, triangle_normal, watertight_setup
from dacrt.partition import mark_rays_hitting_box
from dacrt.rays import new_records, pack_rays

SEEDS = (0, 1, 2)


def slab_interval(origins, directions, tmin, tmax, box):
    """Exact (float64) [near, far] of each ray's segment inside the closed ``box`` (6,); a NaN
    bound (0 * inf: a ray lying in the plane of a face) does not restrict the interval."""
    o = origins.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions.astype(np.float64)
        t0 = (np.asarray(box[:3], np.float64) - o) * inv
        t1 = (np.asarray(box[3:], np.float64) - o) * inv
    near_planes = np.where(inv >= 0, t0, t1)
    far_planes = np.where(inv >= 0, t1, t0)
    near = np.fmax(np.nanmax(near_planes, axis=1, initial=-np.inf), tmin)
    far = np.fmin(np.nanmin(far_planes, axis=1, initial=np.inf), tmax)
    return near, far


def box_mask(origins, directions, tmin, tmax, box):
    """The kernel's verdict (``mark_rays_hitting_box`` over packed records) for every ray."""
    n = len(origins)
    rays = new_records(n)
    assert pack_rays(origins, directions, tmin, tmax, np.arange(n, dtype=np.int32), rays)
    mask = np.zeros(n, np.bool_)
    mark_rays_hitting_box(rays, 0, n, np.asarray(box, np.float32), mask, False)
    return mask


def box_rays(rng, n, box, kind):
    """Rays around ``box``: generic, with zero direction components, or starting on its faces."""
    lo, hi = np.asarray(box[:3]), np.asarray(box[3:])
    origins = rng.uniform(lo - 1.0, hi + 1.0, (n, 3))
    directions = rng.normal(size=(n, 3))
    if kind in ("axis_parallel", "on_faces"):
        directions[rng.random((n, 3)) < 0.4] = 0.0
        directions[~directions.any(axis=1), 0] = 1.0
    if kind == "on_faces":
        axis = rng.integers(0, 3, n)
        side = rng.integers(0, 2, n)
        origins[np.arange(n), axis] = np.where(side == 0, lo[axis], hi[axis])
    tmin = rng.uniform(0.0, 0.5, n)
    tmax = tmin + rng.exponential(2.0, n)
    tmax[rng.random(n) < 0.3] = np.inf
    return (
        origins.astype(np.float32),
        directions.astype(np.float32),
        tmin.astype(np.float32),
        tmax.astype(np.float32),
    )


@pytest.mark.parametrize("kind", ["generic", "axis_parallel", "on_faces"])
@pytest.mark.parametrize("seed", SEEDS)
def test_box_test_is_the_slab_test_and_never_misses_a_hit(seed, kind):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-1, 0, 3)
    box = np.concatenate([lo, lo + rng.uniform(0.5, 1.5, 3)]).astype(np.float32)
    origins, directions, tmin, tmax = box_rays(rng, 4000, box, kind)
    near, far = slab_interval(origins, directions, tmin, tmax, box)
    hit = box_mask(origins, directions, tmin, tmax, box)
    size = np.abs(far) + np.abs(near)
    clear_hit = near < far - 1e-5 * np.where(np.isfinite(size), size, 1.0)
    assert 0.02 < clear_hit.mean() < 0.98, "vacuous: (almost) every or no ray hits"
    missed = np.flatnonzero(clear_hit & ~hit)
    assert not len(missed), f"the box test misses rays that hit: {missed[:5]}"
    clear_miss = near > far + 1e-4 * np.where(np.isfinite(size), size + 1.0, 1.0)
    false_hits = np.flatnonzero(clear_miss & hit)
    assert not len(false_hits), f"the box test hits rays that miss: {false_hits[:5]}"


@pytest.mark.parametrize("seed", SEEDS)
def test_a_direction_component_whose_inverse_overflows_misses_no_hit(seed):
    """|d| < 1/FLT_MAX: float32's 1/d is +-inf, which would put the plane x = 0 at an infinite
    distance from an origin 1e-45 before it; the ray reaches it at a finite one (1e-45 / d)."""
    rng = np.random.default_rng(seed)
    n = 4000
    box = np.float32([0, 0, 0, 1, 1, 1])
    origins, directions, tmin, tmax = box_rays(rng, n, box, "generic")
    tiny = np.float32([1.4e-45, 1e-42, 1e-40, 2.9e-39])
    origins[:, 0] = rng.choice([-1e-40, -1.4e-45, 0.0, 1.4e-45, 0.5], n) * np.float32(1)
    directions[:, 0] = rng.choice(tiny, n) * rng.choice([-1, 1], n).astype(np.float32)
    assert (np.abs(directions[:, 0]) < 1 / np.finfo(np.float32).max).all()  # 1/d overflows
    near, far = slab_interval(origins, directions, tmin, tmax, box)
    size = np.abs(far) + np.abs(near)
    clear_hit = near < far - 1e-5 * np.where(np.isfinite(size), size, 1.0)
    assert clear_hit.mean() > 0.05, "vacuous"
    hit = box_mask(origins, directions, tmin, tmax, box)
    missed = np.flatnonzero(clear_hit & ~hit)
    assert not len(missed), f"the box test misses rays that hit: {missed[:5]}"


@pytest.mark.parametrize("seed", SEEDS)
def test_a_ray_grazing_a_corner_of_the_box_hits_it(seed):
    """Conservative in rounding: a ray that enters the slabs of some axes and leaves those of the
    others at one corner touches the box at that point only; the slab test computes entry and
    exit from rounded reciprocals, and the grown exit keeps it a hit. The values are multiples
    of 1/64, so each ray passes exactly through its corner, at t = its step."""
    rng = np.random.default_rng(seed)
    n = 4000
    lo = rng.integers(-64, 0, 3) / 64
    box = np.concatenate([lo, lo + rng.integers(16, 64, 3) / 64]).astype(np.float32)
    corners = box.reshape(2, 3)[rng.integers(0, 2, (n, 3)), np.arange(3)]
    outward = np.sign(corners - 0.5 * (box[:3] + box[3:]))
    leaving = rng.random((n, 3)) < 0.5
    leaving[:, 0] = True  # at least one axis left and one entered at the corner
    leaving[:, 1] = False
    directions = np.where(leaving, outward, -outward) * rng.integers(1, 64, (n, 3)) / 64
    steps = rng.integers(1, 8, (n, 1))
    origins = corners - steps * directions
    near, far = slab_interval(origins, directions, 0.0, np.inf, box)
    assert np.allclose(near, steps[:, 0], rtol=1e-12) and np.allclose(far, near, rtol=1e-12)
    tmin = np.zeros(n, np.float32)
    tmax = np.full(n, np.inf, np.float32)
    hit = box_mask(origins.astype(np.float32), directions.astype(np.float32), tmin, tmax, box)
    assert hit.all(), f"rays grazing a corner miss the box: {np.flatnonzero(~hit)[:5]}"


@pytest.mark.parametrize("best_t", [0.0, -0.0, 1e-30, 1.0, 3.5e3, 1e30, np.inf, -np.inf])
def test_cull_distance_is_a_little_beyond_best_t(best_t):
    best = np.float32(best_t)
    culled = cull_distance(best)
    assert culled >= best
    if np.isfinite(best):
        assert culled - best <= 2e-5 * abs(best)
    else:
        assert culled == best


def moller_trumbore(p0, p1, p2, origins, directions):
    """(t, u, v, det) of matching rows, float64."""
    e1, e2 = p1 - p0, p2 - p0
    pvec = np.cross(directions, e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    svec = origins - p0
    qvec = np.cross(svec, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.einsum("ij,ij->i", svec, pvec) / det
        v = np.einsum("ij,ij->i", directions, qvec) / det
        t = np.einsum("ij,ij->i", e2, qvec) / det
    return t, u, v, det


def kernel_hits(tri_verts, origins, directions):
    """intersect_triangle of ray i against triangle i: (hit, t, u, v), each (n,)."""
    out = np.zeros((len(origins), 4))
    for i, (o, d) in enumerate(zip(origins, directions)):
        kx, ky, kz, sx, sy, sz = watertight_setup(d[0], d[1], d[2])
        ok = [np.float64(o[k]) for k in (kx, ky, kz)]
        out[i] = intersect_triangle(tri_verts, i, *ok, kx, ky, kz, sx, sy, sz)
    return out[:, 0].astype(bool), out[:, 1], out[:, 2], out[:, 3]


@pytest.mark.parametrize("seed", SEEDS)
def test_triangle_test_matches_moller_trumbore(seed):
    rng = np.random.default_rng(seed)
    n = 1500
    corners = rng.uniform(-1, 1, (n, 3, 3)).astype(np.float32)
    targets = (corners * rng.dirichlet([1, 1, 1], n)[:, :, None]).sum(axis=1)
    targets += rng.normal(scale=0.3, size=(n, 3))  # some land outside their triangle
    origins = rng.uniform(-3, 3, (n, 3)).astype(np.float32)
    directions = (targets - origins).astype(np.float32)
    tri_verts = corners.reshape(n, 9)
    hit, t, u, v = kernel_hits(tri_verts, origins, directions)
    p0, p1, p2 = (corners[:, k].astype(np.float64) for k in range(3))
    t_ref, u_ref, v_ref, det = moller_trumbore(
        p0, p1, p2, origins.astype(np.float64), directions.astype(np.float64)
    )
    w = 1.0 - u_ref - v_ref
    margin = 1e-6
    inside = (u_ref > margin) & (v_ref > margin) & (w > margin) & (np.abs(det) > 1e-6)
    outside = (u_ref < -margin) | (v_ref < -margin) | (w < -margin)
    assert 0.2 < inside.mean() < 0.8, "vacuous: (almost) every or no ray lands inside"
    assert hit[inside].all(), f"misses inside: {np.flatnonzero(inside & ~hit)[:5]}"
    assert not hit[outside].any(), f"hits outside: {np.flatnonzero(outside & hit)[:5]}"
    np.testing.assert_allclose(t[inside], t_ref[inside], rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(u[inside], u_ref[inside], atol=1e-7)
    np.testing.assert_allclose(v[inside], v_ref[inside], atol=1e-7)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_ray_through_a_shared_edge_hits_one_of_its_triangles(seed):
    """Watertightness: two triangles sharing an edge, a ray aimed at a point of that edge."""
    rng = np.random.default_rng(seed)
    n = 1000
    a, b, c, d = (rng.uniform(-1, 1, (n, 3)).astype(np.float32) for _ in range(4))
    first = np.stack([a, b, c], axis=1).reshape(n, 9)
    second = np.stack([b, a, d], axis=1).reshape(n, 9)  # the same edge, the other way round
    s = rng.uniform(0, 1, (n, 1))
    on_edge = a + s * (b.astype(np.float64) - a)
    origins = rng.uniform(-3, 3, (n, 3)).astype(np.float32)
    directions = (on_edge - origins).astype(np.float32)
    hit_first = kernel_hits(first, origins, directions)[0]
    hit_second = kernel_hits(second, origins, directions)[0]
    # c and d on the same side of the plane through the ray and the edge: the ray may pass beside
    # both; only when they lie on opposite sides does it have to cross the union.
    normal = np.cross(directions.astype(np.float64), b.astype(np.float64) - a)
    opposite = np.einsum("ij,ij->i", normal, c - on_edge) * np.einsum(
        "ij,ij->i", normal, d - on_edge
    )
    crossing = opposite < 0
    assert crossing.sum() > n // 4
    gaps = np.flatnonzero(crossing & ~hit_first & ~hit_second)
    assert not len(gaps), f"rays slip through the shared edge: {gaps[:5]}"


@pytest.mark.parametrize("seed", SEEDS)
def test_triangle_normal_is_the_cross_product(seed):
    rng = np.random.default_rng(seed)
    v, f = pg.triangle_soup(200, rng)
    tri_verts = np.ascontiguousarray(v[f].reshape(-1, 9), dtype=np.float32)
    p = tri_verts.reshape(-1, 3, 3).astype(np.float64)
    expected = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    got = np.array([triangle_normal(tri_verts, row) for row in range(len(tri_verts))])
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-15)
