"""Self-checks of the test helpers: the numpy reference against Embree, and the procedural meshes.

If these fail, the engine tests that lean on the helpers cannot be trusted.
"""

from __future__ import annotations

import numpy as np
import procedural as pg
import pytest
import reference


@pytest.mark.parametrize("seed", [0, 1])
def test_reference_matches_embree_on_soup(seed):
    pytest.importorskip("embreex")
    from oracles.embree import Embree

    rng = np.random.default_rng(seed)
    v, f = pg.triangle_soup(800, rng)
    o, d = pg.mixed_rays(pg.bounds(v), 800, rng)
    tmin = rng.uniform(0.0, 0.1, len(o))
    tmax = tmin + rng.uniform(0.5, 4.0, len(o))
    ref = reference.closest(v, f, o, d, tmin, tmax)
    emb = Embree([(v, f)]).closest(o, d, tmin, tmax)
    assert ref.hit.sum() > 80
    assert np.mean(ref.hit == emb.hit) >= 0.999
    same = ref.hit & (ref.prim == emb.prim)
    assert same.sum() >= 0.99 * ref.hit.sum()
    np.testing.assert_allclose(ref.t[same], emb.t[same], rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(ref.u[same], emb.u[same], atol=1e-3)
    np.testing.assert_allclose(ref.v[same], emb.v[same], atol=1e-3)
    np.testing.assert_array_equal(reference.occluded(v, f, o, d, tmin, tmax), ref.hit)
    assert np.mean(Embree([(v, f)]).occluded(o, d, tmin, tmax) == ref.hit) >= 0.999


def test_reference_blocks_agree_with_one_block(monkeypatch):
    """Splitting the work into ray and triangle blocks changes nothing, ties included."""
    rng = np.random.default_rng(2)
    v, f = pg.triangle_soup(300, rng)
    f = np.concatenate([f, f])  # every triangle twice: ties everywhere
    o, d = pg.mixed_rays(pg.bounds(v), 300, rng)
    whole = reference.closest_bracket(v, f, o, d)
    monkeypatch.setattr(reference, "PAIRS_PER_BLOCK", 97)
    blocked = reference.closest_bracket(v, f, o, d)
    for a, b in zip(whole, blocked):
        for x, y in zip(a if isinstance(a, tuple) else [a], b if isinstance(b, tuple) else [b]):
            np.testing.assert_array_equal(x, y)
    assert np.all(whole.exact.prim[whole.exact.hit] < 300), "a tie did not go to the lower index"
    np.testing.assert_array_equal(
        whole.outer_second_t[whole.exact.hit], whole.outer.t[whole.exact.hit]
    )


def test_reference_single_triangle_and_conventions():
    v, f = pg.single_triangle()
    o = np.array([[0.25, 0.5, 2.0], [0.25, 0.5, 2.0], [0.9, 0.9, 1.0], [0.25, 0.5, 2.0]])
    d = np.array([[0, 0, -1], [0, 0, -2], [0, 0, -1], [0, 0, -1.0]])
    hits = reference.closest(v, f, o, d, tmax=[np.inf, np.inf, np.inf, 1.0])
    np.testing.assert_array_equal(hits.prim, [0, 0, -1, -1])
    np.testing.assert_allclose(hits.t, [2.0, 1.0, np.inf, np.inf])
    np.testing.assert_allclose(hits.u, [0.25, 0.25, 0, 0])
    np.testing.assert_allclose(hits.v, [0.5, 0.5, 0, 0])
    np.testing.assert_allclose(
        reference.normals(v, f, hits.prim), [[0, 0, 1], [0, 0, 1], [0, 0, 0], [0, 0, 0]]
    )
    empty = reference.closest(v, f, np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty.t.shape == (0,) and empty.prim.dtype == np.int64


def test_reference_never_hits_degenerate_triangles():
    rng = np.random.default_rng(3)
    v, f, targets = pg.degenerate_triangles(rng, 100)
    assert reference.degenerate(v, f).all()
    o, d = pg.rays_at(targets, pg.unit_vectors(len(targets), rng), 0.5)
    assert not reference.occluded(v, f, o, d).any()


@pytest.mark.parametrize("kind", ["icosphere", "uv_sphere", "perturbed"])
def test_procedural_spheres_are_closed_and_outward(kind):
    trimesh = pytest.importorskip("trimesh")
    if kind == "uv_sphere":
        v, f = pg.uv_sphere(12, 20)
    else:
        v, f = pg.icosphere(3)
        if kind == "perturbed":
            v = pg.perturb_radially(v, np.random.default_rng(4), 0.15)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0, "faces point inwards"
    r_in = pg.inner_radius(v, f)
    assert 0.5 < r_in < 1.0


@pytest.mark.parametrize("alternate", [False, True])
def test_procedural_grid_covers_the_square_once(alternate):
    v, f = pg.grid(8, 2.0, alternate=alternate)
    n = reference.normals(v, f, np.arange(len(f)))
    np.testing.assert_array_equal(n, np.tile([0.0, 0.0, 1.0], (len(f), 1)))
    _, e1, e2 = reference.triangles(v, f)
    np.testing.assert_allclose(np.linalg.norm(np.cross(e1, e2), axis=1).sum() / 2, 4.0)
    assert len(pg.two_sided_edges(f)) == 3 * 8 * 8 - 2 * 8  # all edges but the 4 * 8 boundary ones


# ---------------------------------------------------------------------------------------------
# Every crossing (all_hits, count, count_range): the half-open rule
# ---------------------------------------------------------------------------------------------


def test_all_hits_single_triangle_conventions():
    v, f = pg.single_triangle()
    o = np.array([[0.25, 0.5, 2.0], [0.25, 0.5, -2.0], [0.9, 0.9, 1.0], [0.25, 0.5, 2.0]])
    d = np.array([[0, 0, -1], [0, 0, 1], [0, 0, -1], [1, 0, 0.0]])
    hits = reference.all_hits(v, f, o, d)
    np.testing.assert_array_equal(hits.offsets, [0, 1, 2, 2, 2])  # edge-on ray 3: no crossing
    np.testing.assert_array_equal(hits.prim, [0, 0])
    np.testing.assert_array_equal(hits.t, [2.0, 2.0])
    np.testing.assert_array_equal(hits.u, [0.25, 0.25])
    np.testing.assert_array_equal(hits.v, [0.5, 0.5])
    np.testing.assert_array_equal(hits.ray, [0, 1])
    # The normal is +z: ray 0 meets the front, ray 1 the back.
    np.testing.assert_array_equal(reference.count(v, f, o, d, cull="back"), [1, 0, 0, 0])
    np.testing.assert_array_equal(reference.count(v, f, o, d, cull="front"), [0, 1, 0, 0])
    # [tmin, tmax] is inclusive; masks select.
    np.testing.assert_array_equal(reference.count(v, f, o, d, tmax=2.0), [1, 1, 0, 0])
    np.testing.assert_array_equal(reference.count(v, f, o, d, tmin=2.0), [1, 1, 0, 0])
    np.testing.assert_array_equal(reference.count(v, f, o, d, tmax=1.999), [0, 0, 0, 0])
    masks = np.array([1, 2, 3, 4], np.uint32)
    np.testing.assert_array_equal(
        reference.count(v, f, o, d, ray_masks=masks, face_masks=np.uint32(2)), [0, 1, 0, 0]
    )
    empty = reference.all_hits(v, f, np.zeros((0, 3)), np.zeros((0, 3)))
    assert len(empty) == 0 and empty.offsets.tolist() == [0] and empty.prim.dtype == np.int64
    none = reference.all_hits(np.zeros((0, 3)), np.zeros((0, 3), int), o, d)
    np.testing.assert_array_equal(none.offsets, [0, 0, 0, 0, 0])


@pytest.mark.parametrize("seed", [0, 1])
def test_all_hits_agree_with_moller_trumbore_on_soup(seed):
    """On random rays the first crossing is the float64 Möller–Trumbore closest hit, and the
    crossings are sorted, in range and on their triangles."""
    rng = np.random.default_rng(seed)
    v, f = pg.triangle_soup(600, rng)
    o, d = pg.mixed_rays(pg.bounds(v), 600, rng)
    tmin = rng.uniform(0.0, 0.1, len(o))
    tmax = tmin + rng.uniform(0.5, 4.0, len(o))
    hits = reference.all_hits(v, f, o, d, tmin, tmax)
    closest = reference.closest(v, f, o, d, tmin, tmax)
    has = hits.count > 0
    assert has.sum() > 100 and (hits.count > 1).sum() > 20
    np.testing.assert_array_equal(has, closest.hit)
    first = hits.offsets[:-1][has]
    np.testing.assert_array_equal(hits.prim[first], closest.prim[has])
    np.testing.assert_allclose(hits.t[first], closest.t[has], rtol=1e-12)
    np.testing.assert_allclose(hits.u[first], closest.u[has], atol=1e-12)
    np.testing.assert_allclose(hits.v[first], closest.v[has], atol=1e-12)
    ray = hits.ray
    assert np.all((hits.t >= tmin[ray]) & (hits.t <= tmax[ray]))
    same_ray = ray[1:] == ray[:-1]
    assert np.all(hits.t[1:][same_ray] >= hits.t[:-1][same_ray])
    points = reference.barycentric_points(v, f, hits.prim, hits.u, hits.v)
    np.testing.assert_allclose(points, o[ray] + hits.t[:, None] * d[ray], atol=1e-9)
    np.testing.assert_array_equal(reference.count(v, f, o, d, tmin, tmax), hits.count)


@pytest.mark.parametrize("name, n_rays", [("teapot", 600), ("bunny", 300), ("sibenik", 300)])
def test_all_hits_match_open3d(name, n_rays, load_shared):
    """Counts, t and triangles of every crossing equal Open3D's on random rays over real scenes."""
    pytest.importorskip("open3d")
    from oracles import open3d_hits as open3d_oracle

    v, f = load_shared(name)
    o, d = pg.mixed_rays(pg.bounds(v), n_rays, np.random.default_rng(7))
    hits = reference.all_hits(v, f, o, d)
    assert hits.count.sum() > n_rays // 2
    # Open3D drops a crossing at the same float32 t as the one before (coplanar overlapping
    # faces, as sibenik has): leave out the rays with two crossings that close.
    ray = hits.ray
    close = (ray[1:] == ray[:-1]) & (np.abs(np.diff(hits.t)) <= 1e-5 * hits.t[1:])
    apart = np.ones(n_rays, bool)
    apart[ray[1:][close]] = False
    assert apart.mean() > 0.97
    np.testing.assert_array_equal(open3d_oracle.count(v, f, o, d)[apart], hits.count[apart])
    listed = open3d_oracle.list_hits(v, f, o, d)
    for i in np.flatnonzero(apart):
        a, b = hits.offsets[i], hits.offsets[i + 1]
        ours = slice(listed.offsets[i], listed.offsets[i + 1])
        np.testing.assert_array_equal(listed.prim[ours], hits.prim[a:b])
        np.testing.assert_allclose(listed.t[ours], hits.t[a:b], rtol=1e-5)


def _special_batch(rng):
    """A soup and a grid with rays exactly through grid vertices and edges, rays just beside them,
    and random rays."""
    sv, sf = pg.triangle_soup(60, rng)
    gv, gf = pg.grid(4, 1.0, alternate=True)
    meshes = [(sv, sf), (pg.transform(gv, offset=(0.0, 0.0, 0.5)), gf)]
    v, f, _ = pg.concat(meshes)
    targets = np.concatenate(
        [pg.grid_targets(gv, gf, 4, kind) for kind in ("vertices", "midpoints")]
    ) + (0.0, 0.0, 0.5)
    o1, d1 = pg.rays_at(targets, pg.EXACT_DOWN_DIRECTIONS[np.arange(len(targets)) % 6], 1.0)
    # The same rays one float32 step aside: within about 1e-8 of the edges and vertices.
    o2 = np.nextafter(o1, np.float32(np.inf))
    o3, d3 = pg.mixed_rays(pg.bounds(v), 120, rng)
    return v, f, np.concatenate([o1, o2, o3]), np.concatenate([d1, d1, d3])


@pytest.mark.parametrize("perturbation", [None, "shear"])
def test_float_filter_changes_nothing(monkeypatch, perturbation):
    """Deciding every pair in integers gives the same crossings as the float64 filter."""
    v, f, o, d = _special_batch(np.random.default_rng(3))
    tmax = np.where(np.arange(len(o)) % 3 == 0, 1.0, np.inf)  # the grid is at t = 1 (or nearly)
    fast = reference.all_hits(v, f, o, d, tmax=tmax, perturbation=perturbation)
    monkeypatch.setattr(reference, "_FILTER", np.inf)
    exact = reference.all_hits(v, f, o, d, tmax=tmax, perturbation=perturbation)
    np.testing.assert_array_equal(fast.offsets, exact.offsets)
    np.testing.assert_array_equal(fast.prim, exact.prim)
    np.testing.assert_allclose(fast.t, exact.t, rtol=1e-13)
    np.testing.assert_allclose(fast.u, exact.u, atol=1e-13)
    assert fast.count.sum() > 100


# The third perturbation moves the ray along y first: edges along y take q's side.
@pytest.mark.parametrize("perturbation", [None, "shear", ((0.0, 1.0, 0.5), (1.0, 0.0, 0.25))])
@pytest.mark.parametrize("direction", ["normal", "exact_oblique"])
@pytest.mark.parametrize("alternate", [False, True])
def test_rays_through_grid_vertices_and_edges_cross_once(alternate, direction, perturbation):
    """A flat grid seen from either side: every ray through a vertex, an edge or a face crosses
    exactly one triangle, whatever the perturbation."""
    v, f = pg.grid(8, 1.0, alternate=alternate)
    rays = [pg.grid_rays(v, f, 8, kind, direction)[:2] for kind in ("vertices", "midpoints")]
    o, d = (np.concatenate(x) for x in zip(*rays))
    o = np.concatenate([o, o + d])  # the same lines from below the grid
    d = np.concatenate([d, -d])
    hits = reference.all_hits(v, f, o, d, perturbation=perturbation)
    np.testing.assert_array_equal(hits.count, 1)
    np.testing.assert_allclose(hits.t, 0.5)
    lo, hi = reference.count_range(v, f, o, d)
    np.testing.assert_array_equal(lo, 1)
    np.testing.assert_array_equal(hi, 1)


def test_fold_counts_zero_or_two():
    """A ray exactly through the ridge of a fold (both faces on one side in projection) crosses
    both or neither, by the side it is moved to."""
    v = np.array([[0, 0, 0], [0, 1, 0], [1, 0.5, 1], [1, 0.5, -1]], np.float32)
    f = np.array([[0, 1, 2], [1, 0, 3]], np.int32)
    o = np.array([[0.0, 0.5, 0.0]], np.float32) - np.float32(3) * np.array([[1, 0, -4]], np.float32)
    d = np.array([[1, 0, -4]], np.float32)
    # The ray meets the ridge x = z = 0 at t = 3.
    plus = reference.count(v, f, o, d, perturbation=((1.0, 0, 0), (0, 1.0, 0)))
    minus = reference.count(v, f, o, d, perturbation=((-1.0, 0, 0), (0, 1.0, 0)))
    assert sorted([plus[0], minus[0]]) == [0, 2]
    lo, hi = reference.count_range(v, f, o, d)
    assert (lo[0], hi[0]) == (0, 2)


@pytest.mark.parametrize("name", ["cube", "icosphere", "uv_sphere"])
def test_closed_mesh_parity_through_vertices_and_edges(name):
    """Rays exactly through every vertex and edge midpoint of a closed mesh: from outside the
    count is even, from inside odd, for every perturbation; count_range brackets it."""
    import crossing_rays as cr

    v, f = cr.closed_mesh(name)
    targets = cr.feature_points(v, f)
    o, d = cr.rays_through(targets, np.random.default_rng(11))
    oi, di = cr.rays_from(cr.INSIDE_POINT, targets)
    ranges = {}
    for origins, directions, parity in ((o, d, 0), (oi, di, 1)):
        lo, hi = ranges[parity] = reference.count_range(v, f, origins, directions)
        assert np.all(lo % 2 == parity) and np.all(hi % 2 == parity)
        for perturbation in (None, "shear"):
            c = reference.count(v, f, origins, directions, perturbation=perturbation)
            assert np.all(c % 2 == parity)
            assert np.all((lo <= c) & (c <= hi))
    # Convex meshes: from inside exactly one crossing; from outside a ray through the surface
    # crosses it twice, or grazes a silhouette vertex or edge (0 or 2 as it is moved).
    np.testing.assert_array_equal(ranges[1], np.ones((2, len(oi))))
    lo, hi = ranges[0]
    np.testing.assert_array_equal(hi, 2)
    assert (lo == 2).any() and (lo == 0).any()


def test_coplanar_duplicates_count_twice_degenerates_never():
    rng = np.random.default_rng(5)
    v, f = pg.single_triangle()
    # The same triangle three times: as given, with its corners rotated, and reversed.
    f3 = np.array([[0, 1, 2], [1, 2, 0], [2, 1, 0]], np.int32)
    o = np.array([[0.25, 0.25, 1.0], [0.5, 0.0, 1.0], [0.0, 0.0, 1.0]], np.float32)
    d = np.array([[0, 0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]], np.float32)
    # Inside, on an edge, at a corner (both boundaries of a single triangle: the moved ray decides).
    c = reference.count(v, f3, o, d)
    assert c[0] == 3 and c[1] in (0, 3) and c[2] in (0, 3)
    np.testing.assert_array_equal(
        reference.count(v, f3, o, d, cull="back"), [2, c[1] * 2 // 3, 2 * (c[2] // 3)]
    )
    dv, df, targets = pg.degenerate_triangles(rng, 100)
    o, d = pg.rays_at(targets, pg.unit_vectors(len(targets), rng), 0.5)
    assert reference.count(dv, df, o, d).sum() == 0
    lo, hi = reference.count_range(dv, df, o, d)
    assert hi.sum() == 0


@pytest.mark.parametrize("cull", ["back", "front"])
def test_cull_and_masks_filter_the_crossings(cull):
    rng = np.random.default_rng(6)
    v, f = pg.triangle_soup(400, rng)
    o, d = pg.mixed_rays(pg.bounds(v), 400, rng)
    full = reference.all_hits(v, f, o, d)
    ray = full.ray
    normal = np.cross(*(reference.triangles(v, f)[1:]))
    facing = np.einsum("ij,ij->i", normal[full.prim], d[ray]) < 0  # front faces
    keep = facing if cull == "back" else ~facing
    culled = reference.all_hits(v, f, o, d, cull=cull)
    np.testing.assert_array_equal(culled.prim, full.prim[keep])
    np.testing.assert_array_equal(culled.count, np.bincount(ray[keep], minlength=len(o)))
    face_masks = rng.choice(np.array([1, 2, 6], np.uint32), len(f))
    ray_masks = rng.choice(np.array([1, 4, 0xFFFFFFFF], np.uint32), len(o))
    seen = (face_masks[full.prim] & ray_masks[ray]) != 0
    masked = reference.all_hits(v, f, o, d, ray_masks=ray_masks, face_masks=face_masks)
    np.testing.assert_array_equal(masked.prim, full.prim[seen])
    assert 0 < seen.sum() < len(seen)


def test_window_and_nearest():
    rng = np.random.default_rng(8)
    v, f = pg.triangle_soup(500, rng)
    o, d = pg.aimed_rays(pg.bounds(v), 300, rng)
    full = reference.all_hits(v, f, o, d)
    tmin = rng.uniform(0.0, 1.0, len(o))
    tmax = tmin + rng.uniform(0.0, 1.0, len(o))
    inside = (full.t >= tmin[full.ray]) & (full.t <= tmax[full.ray])
    window = reference.all_hits(v, f, o, d, tmin, tmax)
    np.testing.assert_array_equal(window.prim, full.prim[inside])
    np.testing.assert_array_equal(window.t, full.t[inside])
    kept, truncated = reference.nearest(full, 3)
    np.testing.assert_array_equal(kept.count, np.minimum(full.count, 3))
    np.testing.assert_array_equal(truncated, full.count > 3)
    assert truncated.any() and (full.count == 3).any()
    for i in range(len(o)):
        lo = full.offsets[i]
        np.testing.assert_array_equal(
            kept.prim[kept.offsets[i] : kept.offsets[i + 1]],
            full.prim[lo : min(lo + 3, full.offsets[i + 1])],
        )


def test_shear_perturbation_frame():
    """p and q are the frame's x and y axes: unit, across the dominant axis, and d . (p x q) > 0
    (the frame keeps the winding)."""
    rng = np.random.default_rng(9)
    d = np.concatenate([pg.unit_vectors(200, rng), np.eye(3), -np.eye(3), [[1.0, 1.0, 1.0]]])
    p, q = reference.shear_perturbation(d)
    kz = np.argmax(np.abs(d), axis=1)
    assert np.all(p[np.arange(len(d)), kz] == 0) and np.all(q[np.arange(len(d)), kz] == 0)
    assert np.all(np.einsum("ij,ij->i", d, np.cross(p, q)) > 0)
    np.testing.assert_array_equal(reference.shear_perturbation([[1.0, 1.0, 1.0]])[0], [[0, 1, 0]])
