"""Closest-hit and occlusion queries of ``dacrt.Scene`` against the brute-force reference.

Every test is seeded; every comparison is with ``tests/reference.py`` (plain numpy, nothing from
dacrt) or with a property that holds for any correct ray caster.
"""

from __future__ import annotations

import assertions as check
import numpy as np
import procedural as pg
import pytest
import reference
import sample_scenes

import dacrt
from dacrt.geometry import cull_distance, intersect_box

SEEDS = (0, 1)


def build(meshes):
    """The engine scene and the concatenated reference scene (vertices, faces, offsets)."""
    return dacrt.Scene(meshes), *pg.concat(meshes)


# ---------------------------------------------------------------------------------------------
# Against the reference
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("scene_name", sorted(sample_scenes.SCENES))
def test_closest_matches_reference(scene_name, seed):
    meshes = sample_scenes.SCENES[scene_name](seed)
    scene, vertices, faces, offsets = build(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, seed)
    hits = scene.closest(origins, directions)
    check.check_layout(hits, len(origins))
    check.check_geometry(hits, vertices, faces, origins, directions, offsets)
    check.check_against_reference(
        hits, vertices, faces, origins, directions, mesh_offsets=offsets, min_hits=200
    )


@pytest.mark.parametrize("scene_name", sorted(sample_scenes.SCENES))
def test_occluded_matches_reference_and_closest(scene_name):
    meshes = sample_scenes.SCENES[scene_name](7)
    scene, vertices, faces, _ = build(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, 7)
    occ = scene.occluded(origins, directions).occluded
    check.check_occluded_against_reference(occ, vertices, faces, origins, directions)
    np.testing.assert_array_equal(occ, np.isfinite(scene.closest(origins, directions).t))


def test_rays_from_inside_sphere_match_reference():
    meshes = sample_scenes.sphere(3)
    scene, vertices, faces, _ = build(meshes)
    r_in = pg.inner_radius(vertices, faces)
    origins, directions = pg.rays_from_inside((0, 0, 0), 0.9 * r_in, 1500, np.random.default_rng(3))
    hits = scene.closest(origins, directions)
    check.check_geometry(hits, vertices, faces, origins, directions)
    check.check_against_reference(hits, vertices, faces, origins, directions, min_hits=1500)


# ---------------------------------------------------------------------------------------------
# Ray ranges
# ---------------------------------------------------------------------------------------------


def _ranges(kind, first_t, rng):
    """tmin, tmax for the rays, given the reference's first-hit distances ``first_t``."""
    n = len(first_t)
    if kind == "scalar":
        return 0.35, 1.1
    if kind == "scalar_tmin":
        return 0.6, None
    if kind == "scalar_tmax":
        return None, 0.8
    # Per ray: windows just past the first hit, just short of it, around it, and random.
    t = np.where(np.isfinite(first_t), first_t, 1.0)
    tmin, tmax = rng.uniform(0.0, 1.0, n), rng.uniform(1.0, 3.0, n)
    k = rng.integers(0, 4, n)
    tmin = np.where(k == 0, t * 1.01, np.where(k == 2, t * 0.5, tmin))
    tmax = np.where(k == 0, t * 3.0, np.where(k == 1, t * 0.99, np.where(k == 2, t * 1.5, tmax)))
    tmin = np.where(k == 1, 0.0, tmin)
    return tmin.astype(np.float32), tmax.astype(np.float32)


@pytest.mark.parametrize("kind", ["scalar", "scalar_tmin", "scalar_tmax", "per_ray"])
@pytest.mark.parametrize("scene_name", ["soup", "multi"])
def test_ray_ranges_honoured(scene_name, kind):
    meshes = sample_scenes.SCENES[scene_name](11)
    scene, vertices, faces, offsets = build(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, 11)
    first = reference.closest(vertices, faces, origins, directions)
    tmin, tmax = _ranges(kind, first.t, np.random.default_rng(11))
    hits = scene.closest(origins, directions, tmin, tmax)
    check.check_layout(hits, len(origins))
    lo, hi = reference.ray_ranges(len(origins), tmin, tmax)
    hit = hits.prim >= 0
    assert np.all(hits.t[hit] >= lo[hit].astype(np.float32)), "t < tmin"
    assert np.all(hits.t[hit] <= hi[hit].astype(np.float32)), "t > tmax"
    check.check_against_reference(
        hits, vertices, faces, origins, directions, tmin, tmax, mesh_offsets=offsets, min_hits=100
    )
    occ = scene.occluded(origins, directions, tmin, tmax).occluded
    np.testing.assert_array_equal(
        occ, np.isfinite(hits.t), err_msg="occluded != isfinite(closest.t)"
    )


def test_per_ray_range_skips_first_hit():
    """Two parallel triangles: a window past the first returns the second; one before it, a miss."""
    v, f = pg.single_triangle()
    vertices = np.concatenate([v, v + np.float32([0, 0, -1])])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    scene = dacrt.Scene([(vertices, faces)])
    origins = np.tile(np.float32([0.25, 0.25, 1.0]), (4, 1))
    directions = np.tile(np.float32([0, 0, -1]), (4, 1))
    tmin = np.float32([0.0, 1.5, 0.0, 1.0])
    tmax = np.float32([np.inf, np.inf, 0.5, 1.0])  # the last: tmin == tmax == t, inclusive
    hits = scene.closest(origins, directions, tmin, tmax)
    np.testing.assert_array_equal(hits.prim, [0, 1, -1, 0])
    np.testing.assert_allclose(hits.t, [1.0, 2.0, np.inf, 1.0], rtol=1e-6)
    np.testing.assert_array_equal(
        scene.occluded(origins, directions, tmin, tmax).occluded, [True, True, False, True]
    )


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("scene_name", ["soup", "sphere", "multi", "pinwheel"])
def test_range_ends_are_inclusive_and_exact(scene_name, strategy):
    """With tmax, or tmin, set to the ray's own closest t (float32), that very hit is still found;
    with tmax one float below it, nothing is."""
    meshes = sample_scenes.SCENES[scene_name](17)
    scene = dacrt.Scene(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, 17)
    first = scene.closest(origins, directions, strategy=strategy)
    hit = first.prim >= 0
    o, d, t = origins[hit], directions[hit], first.t[hit]
    below = np.nextafter(t, np.float32(0))
    for tmin, tmax, what in [
        (None, t, "tmax = t"),
        (t, None, "tmin = t"),
        (t, t, "tmin = tmax = t"),
    ]:
        again = scene.closest(o, d, tmin, tmax, strategy=strategy)
        np.testing.assert_array_equal(again.t, t, err_msg=what)
        np.testing.assert_array_equal(again.prim, first.prim[hit], err_msg=what)
        assert scene.occluded(o, d, tmin, tmax, strategy=strategy).occluded.all(), what
    assert not scene.occluded(o, d, None, below, strategy=strategy).occluded.any(), (
        "tmax just below the closest t"
    )
    assert np.all(np.isinf(scene.closest(o, d, None, below, strategy=strategy).t))


@pytest.mark.parametrize("length", [1e-12, 1e-3, 0.5, 3.7, 250.0, 1e12])
def test_t_scales_inversely_with_direction_length(length):
    meshes = sample_scenes.soup(5)
    scene, vertices, faces, _ = build(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, 5)
    unit = scene.closest(origins, directions)
    scaled_dirs = (directions.astype(np.float64) * length).astype(np.float32)
    scaled = scene.closest(origins, scaled_dirs)
    check.check_against_reference(scaled, vertices, faces, origins, scaled_dirs, min_hits=200)
    same = (unit.prim >= 0) & (unit.prim == scaled.prim)
    assert same.sum() >= 0.99 * (unit.prim >= 0).sum(), (
        "scaling the directions changed which triangles are hit"
    )
    np.testing.assert_allclose(scaled.t[same] * np.float64(length), unit.t[same], rtol=1e-5)
    np.testing.assert_allclose(scaled.u[same], unit.u[same], atol=1e-5)
    # The range is in the same units as t.
    tmax = 0.5 * np.where(np.isfinite(unit.t), unit.t, 1.0) / length
    np.testing.assert_array_equal(
        scene.occluded(origins, scaled_dirs, tmax=tmax).occluded,
        np.isfinite(scene.closest(origins, scaled_dirs, tmax=tmax).t),
    )


# ---------------------------------------------------------------------------------------------
# Invariance
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("scene_name", ["soup", "sphere", "tilted_grid"])
def test_shuffling_triangles_changes_no_t(scene_name, seed):
    ((vertices, faces),) = sample_scenes.SCENES[scene_name](seed)
    rng = np.random.default_rng(seed)
    origins, directions = sample_scenes.mixed_rays([(vertices, faces)], seed)
    base = dacrt.Scene([(vertices, faces)]).closest(origins, directions)
    order = rng.permutation(len(faces))
    # Also renumber the vertices: a triangle's coordinates, and so its t, stay the same.
    vperm = rng.permutation(len(vertices))
    inverse = np.argsort(vperm)
    shuffled = dacrt.Scene([(vertices[vperm], inverse[faces[order]])]).closest(origins, directions)
    np.testing.assert_array_equal(shuffled.prim >= 0, base.prim >= 0, err_msg="hit/miss changed")
    same_tri = (base.prim >= 0) & (order[np.maximum(shuffled.prim, 0)] == base.prim)
    assert same_tri.sum() >= 0.99 * (base.prim >= 0).sum()
    np.testing.assert_array_equal(shuffled.t[same_tri], base.t[same_tri])
    np.testing.assert_array_equal(shuffled.u[same_tri], base.u[same_tri])
    np.testing.assert_allclose(shuffled.t, base.t, rtol=1e-5)


def test_rotating_face_corners_keeps_t_and_maps_barycentrics():
    ((vertices, faces),) = sample_scenes.soup(4)
    origins, directions = sample_scenes.mixed_rays([(vertices, faces)], 4)
    base = dacrt.Scene([(vertices, faces)]).closest(origins, directions)
    rot = dacrt.Scene([(vertices, faces[:, [1, 2, 0]])]).closest(origins, directions)
    same = (base.prim >= 0) & (rot.prim == base.prim)
    assert same.sum() >= 0.99 * (base.prim >= 0).sum()
    np.testing.assert_allclose(rot.t[same], base.t[same], rtol=1e-5)
    # (1-u-v) p0 + u p1 + v p2 == (1-u'-v') p1 + u' p2 + v' p0  =>  u' = v, v' = 1 - u - v.
    np.testing.assert_allclose(rot.u[same], base.v[same], atol=1e-4)
    np.testing.assert_allclose(rot.v[same], 1 - base.u[same] - base.v[same], atol=1e-4)
    np.testing.assert_allclose(rot.normal[same], base.normal[same], atol=1e-5)


def test_float64_and_int64_inputs_give_the_same_answers():
    meshes = sample_scenes.multi(2)
    origins, directions = sample_scenes.mixed_rays(meshes, 2)
    tmin = np.full(len(origins), 0.01, np.float32)
    tmax = np.full(len(origins), 5.0, np.float32)
    a = dacrt.Scene(meshes).closest(origins, directions, tmin, tmax)
    wide = [(v.astype(np.float64), f.astype(np.int64)) for v, f in meshes]
    b = dacrt.Scene(wide).closest(
        origins.astype(np.float64),
        directions.astype(np.float64),
        tmin.astype(np.float64),
        tmax.astype(np.float64),
    )
    check.assert_bitwise_equal(a, b, "float64/int64 inputs")


@pytest.mark.parametrize("dtype", [np.int16, np.uint16, np.uint32, np.uint64])
def test_other_integer_face_dtypes_give_the_same_answers(dtype):
    meshes = sample_scenes.soup(3)
    origins, directions = sample_scenes.mixed_rays(meshes, 3)
    a = dacrt.Scene(meshes).closest(origins, directions)
    b = dacrt.Scene([(v, f.astype(dtype)) for v, f in meshes]).closest(origins, directions)
    check.assert_bitwise_equal(a, b, f"faces as {np.dtype(dtype)}")


def test_non_contiguous_inputs_give_the_same_answers():
    meshes = sample_scenes.soup(6)
    origins, directions = sample_scenes.mixed_rays(meshes, 6)
    a = dacrt.Scene(meshes).closest(origins, directions)
    ((v, f),) = meshes
    v_strided = np.zeros((len(v), 6), np.float32)
    v_strided[:, ::2] = v
    f_fortran = np.asfortranarray(f)
    rays = np.zeros((len(origins), 7), np.float32)
    rays[:, 0:3], rays[:, 4:7] = origins, directions
    b = dacrt.Scene([(v_strided[:, ::2], f_fortran)]).closest(rays[:, 0:3], rays[:, 4:7])
    check.assert_bitwise_equal(a, b, "strided / Fortran-ordered inputs")


@pytest.mark.parametrize("scene_name", sorted(sample_scenes.SCENES))
def test_small_and_large_batches_give_the_same_answers(scene_name):
    """A batch with at least as many rays as triangles looks normals up per triangle, a
    smaller one computes each hit's: the same rays answer alike in either, bit for bit."""
    meshes = sample_scenes.SCENES[scene_name](3)
    scene, vertices, faces, offsets = build(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, 3)
    assert len(origins) >= scene.n_triangles > 10
    whole = scene.closest(origins, directions)
    small = scene.n_triangles - 1
    parts = [
        scene.closest(origins[i : i + small], directions[i : i + small])
        for i in range(0, len(origins), small)
    ]
    for name in ("t", "mesh", "prim", "u", "v", "normal"):
        joined = np.concatenate([getattr(part, name) for part in parts])
        np.testing.assert_array_equal(
            joined.view(np.uint8),
            getattr(whole, name).view(np.uint8),
            err_msg=f"{scene_name}: {name} differs between batch sizes",
        )
    check.check_against_reference(
        whole, vertices, faces, origins, directions, mesh_offsets=offsets, min_hits=200
    )


def test_inputs_are_not_modified():
    meshes = sample_scenes.multi(8)
    origins, directions = sample_scenes.mixed_rays(meshes, 8)
    tmin = np.zeros(len(origins), np.float32)
    tmax = np.full(len(origins), np.inf, np.float32)
    copies = [a.copy() for m in meshes for a in m] + [
        origins.copy(),
        directions.copy(),
        tmin.copy(),
        tmax.copy(),
    ]
    scene = dacrt.Scene(meshes)
    scene.closest(origins, directions, tmin, tmax)
    scene.occluded(origins, directions, tmin, tmax)
    for before, after in zip(
        copies, [a for m in meshes for a in m] + [origins, directions, tmin, tmax]
    ):
        np.testing.assert_array_equal(before, after)


# ---------------------------------------------------------------------------------------------
# Scene attributes and multi-mesh numbering
# ---------------------------------------------------------------------------------------------


def test_scene_attributes():
    meshes = sample_scenes.multi(9)
    # An unreferenced vertex far away must not count in the bounds.
    v0, f0 = meshes[0]
    meshes[0] = (np.concatenate([v0, np.float32([[100.0, 100.0, 100.0]])]), f0)
    scene = dacrt.Scene(meshes)
    vertices, faces, offsets = pg.concat(meshes)
    assert scene.n_meshes == len(meshes)
    assert scene.n_triangles == len(faces)
    assert scene.mesh_offsets.dtype == np.int64
    np.testing.assert_array_equal(scene.mesh_offsets, offsets)
    assert scene.bounds.dtype == np.float32 and scene.bounds.shape == (2, 3)
    np.testing.assert_array_equal(scene.bounds, pg.bounds(vertices, faces).astype(np.float32))
    assert isinstance(scene.nbytes, (int, np.integer)) and scene.nbytes > 0
    # A batch of at least as many rays as triangles derives a table of unit normals (12 bytes
    # a triangle), which the scene then holds and counts.
    before = scene.nbytes
    origins = np.zeros((scene.n_triangles, 3), np.float32)
    directions = np.tile(np.float32([0, 0, 1]), (scene.n_triangles, 1))
    scene.closest(origins[:-1], directions[:-1])
    assert scene.nbytes == before
    scene.closest(origins, directions)
    assert scene.nbytes == before + 12 * scene.n_triangles


def test_point_queries_place_triangles_the_scene_counts():
    """A point query reads the scene's triangles placed in scene space, their boxes and Morton
    order, derived once and counted in ``nbytes``: a scene of untransformed meshes reads its own
    packed rows and boxes, and holds their masks (4 bytes a triangle) and order (12) more; one
    with a placed mesh holds every row again as 9 corners, an id, a mask and a box (68 bytes a
    triangle), beside the base rows' masks. A second query derives nothing more; the boxes are
    each row's corners' (NumPy) either way."""
    rng = np.random.default_rng(51)
    a, b = pg.triangle_soup(300, rng), pg.triangle_soup(200, rng)
    plain = dacrt.Scene([a, b])
    before = plain.nbytes
    plain.nearest(np.zeros((4, 3), np.float32))
    assert plain.nbytes == before + (4 + 12) * 500
    plain.nearest(np.ones((4, 3), np.float32), mask=np.arange(1, 5, dtype=np.uint32))
    assert plain.nbytes == before + (4 + 12) * 500
    moved = np.eye(4)
    moved[:3, 3] = (5.0, 0.0, 0.0)
    placed = dacrt.Scene([a, b], transforms=[None, moved])
    before = placed.nbytes
    placed.nearest(np.zeros((4, 3), np.float32))
    assert placed.nbytes == before + (44 + 24 + 12) * 500 + 4 * 300
    for scene in (plain, placed):
        read = scene._scene_triangles()
        corners = read.verts.reshape(-1, 3, 3)
        np.testing.assert_array_equal(read.bounds, np.hstack([corners.min(1), corners.max(1)]))
        np.testing.assert_array_equal(
            read.box, np.hstack([corners.min((0, 1)), corners.max((0, 1))])
        )


def test_empty_mesh_between_others_keeps_numbering():
    rng = np.random.default_rng(12)
    a, b = pg.triangle_soup(100, rng), pg.triangle_soup(100, rng)
    empty = (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    meshes = [a, empty, b]
    scene, vertices, faces, offsets = build(meshes)
    np.testing.assert_array_equal(scene.mesh_offsets, [0, 100, 100, 200])
    origins, directions = pg.aimed_rays(pg.bounds(vertices), 1000, rng)
    hits = scene.closest(origins, directions)
    assert not np.any(hits.mesh == 1), "a hit in the empty mesh"
    check.check_against_reference(
        hits, vertices, faces, origins, directions, mesh_offsets=offsets, min_hits=100
    )


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_many_identical_triangles_tie_to_the_first(strategy):
    """2000 copies of one triangle: deep partitions of identical boxes, and every hit a tie."""
    v, f = pg.single_triangle()
    scene = dacrt.Scene([(v, np.repeat(f, 2000, axis=0))])
    rng = np.random.default_rng(16)
    targets = np.c_[rng.uniform(0.05, 0.45, (5000, 2)), np.zeros(5000)]
    origins, directions = pg.rays_at(
        targets, pg.unit_vectors(5000, rng) * [0.5, 0.5, 0.1] + [0, 0, -1]
    )
    hits = scene.closest(origins, directions, strategy=strategy)
    np.testing.assert_array_equal(hits.prim, 0)
    np.testing.assert_allclose(hits.t, 1.0, rtol=1e-5)


@pytest.mark.parametrize("first,second", [(0, 3), (4, 1), (2, 2)])
def test_tie_goes_to_lowest_global_index(first, second):
    """The same triangle twice (in one mesh, or once in each of two meshes): the lower index
    wins."""
    rng = np.random.default_rng(first * 10 + second)
    tri_v, tri_f = pg.single_triangle()
    soup_v, soup_f = pg.triangle_soup(6, rng, extent=0.2, size=0.01)
    soup_v = soup_v + np.float32([5, 5, 5])  # out of the way
    if first == second:
        # Across meshes: mesh 0 = soup + triangle at row `first`; mesh 1 = the triangle alone.
        f0 = np.insert(soup_f, first, tri_f[0] + len(soup_v), axis=0)
        meshes = [(np.concatenate([soup_v, tri_v]), f0), (tri_v, tri_f)]
        expect_mesh, expect_prim = 0, first
    else:
        v = np.concatenate([soup_v, tri_v])
        f = soup_f.copy()
        f = np.insert(f, min(first, second), tri_f[0] + len(soup_v), axis=0)
        f = np.insert(f, max(first, second), tri_f[0] + len(soup_v), axis=0)
        meshes = [(v, f)]
        expect_mesh, expect_prim = 0, min(first, second)
    scene = dacrt.Scene(meshes)
    origins, directions = pg.rays_at(
        rng.uniform(0.05, 0.45, size=(64, 3)) * [1, 1, 0],
        pg.unit_vectors(64, rng) * [1, 1, 0.2] + [0, 0, -1],
    )
    for strategy in dacrt.STRATEGIES:
        hits = scene.closest(origins, directions, strategy=strategy)
        np.testing.assert_array_equal(hits.mesh, expect_mesh, err_msg=strategy)
        np.testing.assert_array_equal(hits.prim, expect_prim, err_msg=strategy)


# ---------------------------------------------------------------------------------------------
# Small and empty inputs
# ---------------------------------------------------------------------------------------------


def test_single_triangle_exact_hit_front_and_back():
    scene = dacrt.Scene([pg.single_triangle()])
    origins = np.float32([[0.25, 0.5, 2.0], [0.25, 0.5, -2.0], [0.75, 0.75, 1.0], [0.0, 0.0, 1.0]])
    directions = np.float32([[0, 0, -1], [0, 0, 0.5], [0, 0, -1], [0, 0, -1]])
    hits = scene.closest(origins, directions)
    check.check_layout(hits, 4)
    # Both sides hit (no culling); the geometric normal does not flip with the ray.
    np.testing.assert_array_equal(hits.prim, [0, 0, -1, 0])
    np.testing.assert_allclose(hits.t, [2.0, 4.0, np.inf, 1.0], rtol=1e-6)
    np.testing.assert_allclose(hits.u, [0.25, 0.25, 0, 0], atol=1e-6)
    np.testing.assert_allclose(hits.v, [0.5, 0.5, 0, 0], atol=1e-6)
    np.testing.assert_allclose(hits.normal, [[0, 0, 1], [0, 0, 1], [0, 0, 0], [0, 0, 1]], atol=1e-6)


def test_origin_on_the_triangle_hits_at_t_zero():
    """tmin <= t is inclusive: a ray starting on a triangle hits it at t = 0
    (but not with tmin > 0)."""
    scene = dacrt.Scene([pg.single_triangle()])
    origins = np.float32([[0.25, 0.25, 0.0], [0.25, 0.25, 0.0]])
    directions = np.float32([[0, 0, 1], [0.5, 0.25, -1]])
    hits = scene.closest(origins, directions)
    np.testing.assert_array_equal(hits.prim, [0, 0])
    np.testing.assert_array_equal(np.abs(hits.t), [0.0, 0.0])
    assert scene.occluded(origins, directions, 0.0, 0.0).occluded.all()
    assert not scene.occluded(origins, directions, 1e-6, np.inf).occluded.any()


@pytest.mark.parametrize("query", ["closest", "occluded"])
def test_zero_rays_give_typed_empty_arrays(query):
    scene = dacrt.Scene(sample_scenes.soup(0))
    empty = np.zeros((0, 3), np.float32)
    if query == "closest":
        hits = scene.closest(empty, empty)
        check.check_layout(hits, 0)
        hits = scene.closest(
            empty, empty, np.zeros(0, np.float32), np.zeros(0, np.float32), stats=True
        )
        check.check_layout(hits, 0)
        assert hits.stats["rays"] == 0
    else:
        occ = scene.occluded(empty, empty).occluded
        assert occ.dtype == np.bool_ and occ.shape == (0,)
        answer = scene.occluded(empty, empty, stats=True)
        occ, stats = answer.occluded, answer.stats
        assert occ.dtype == np.bool_ and occ.shape == (0,) and stats["rays"] == 0


@pytest.mark.parametrize("kind", ["no_meshes", "empty_mesh", "two_empty_meshes"])
def test_scene_without_triangles_misses_everything(kind):
    empty = (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    meshes = {"no_meshes": [], "empty_mesh": [empty], "two_empty_meshes": [empty, empty]}[kind]
    scene = dacrt.Scene(meshes)
    assert scene.n_triangles == 0 and scene.n_meshes == len(meshes)
    np.testing.assert_array_equal(scene.bounds, np.zeros((2, 3), np.float32))
    np.testing.assert_array_equal(scene.mesh_offsets, np.zeros(len(meshes) + 1))
    origins, directions = pg.random_rays([[-1, -1, -1], [1, 1, 1]], 100, np.random.default_rng(0))
    for strategy in dacrt.STRATEGIES:
        hits = scene.closest(origins, directions, strategy=strategy)
        check.check_layout(hits, 100)
        assert np.all(hits.prim == -1)
        assert not np.any(scene.occluded(origins, directions, strategy=strategy).occluded)


def test_rays_pointing_away_all_miss():
    meshes = sample_scenes.multi(13)
    scene, vertices, _, _ = build(meshes)
    lo, hi = pg.bounds(vertices)
    center = (lo + hi) / 2
    d = pg.unit_vectors(500, np.random.default_rng(13))
    origins = (center + np.linalg.norm(hi - lo) * d).astype(np.float32)
    hits = scene.closest(origins, d.astype(np.float32))
    check.check_layout(hits, 500)
    assert np.all(hits.prim == -1)
    assert not np.any(scene.occluded(origins, d.astype(np.float32)).occluded)


# ---------------------------------------------------------------------------------------------
# Degenerate triangles
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
def test_degenerate_triangles_never_hit(seed):
    rng = np.random.default_rng(seed)
    vertices, faces, targets = pg.degenerate_triangles(rng, 100)
    assert np.all(reference.degenerate(vertices, faces))
    scene = dacrt.Scene([(vertices, faces)])
    # Through each degenerate triangle's segment or point, from random and axis directions.
    dirs = np.concatenate(
        [
            pg.unit_vectors(len(targets), rng),
            np.tile(np.eye(3), (len(targets) // 3 + 1, 1))[: len(targets)],
        ]
    )
    origins, directions = pg.rays_at(np.concatenate([targets, targets]), dirs, distance=0.5)
    for strategy in dacrt.STRATEGIES:
        hits = scene.closest(origins, directions, strategy=strategy)
        assert np.all(hits.prim == -1), (
            f"{strategy}: degenerate triangles hit: {np.flatnonzero(hits.prim >= 0)[:5]}"
        )
        assert not np.any(scene.occluded(origins, directions, strategy=strategy).occluded), strategy


def test_degenerate_triangles_mixed_in_are_never_the_hit():
    rng = np.random.default_rng(14)
    vertices, faces, is_degenerate, targets = pg.with_degenerates(rng, n_good=300, n_degenerate=100)
    scene = dacrt.Scene([(vertices, faces)])
    o1, d1 = pg.rays_at(targets, pg.unit_vectors(len(targets), rng), distance=0.5)
    o2, d2 = pg.mixed_rays(pg.bounds(vertices), 1000, rng)
    origins, directions = np.concatenate([o1, o2]), np.concatenate([d1, d2])
    hits = scene.closest(origins, directions)
    assert not np.any(is_degenerate[hits.prim[hits.prim >= 0]]), "a degenerate triangle was hit"
    assert scene.n_triangles == len(faces), "n_triangles must count degenerate triangles too"


# ---------------------------------------------------------------------------------------------
# Numerically hard triangles
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_false_hits_on_far_edge_on_slivers(seed, strategy):
    """Tiny triangles seen edge-on from far away: their projected edge functions are all
    cancellation. A hit must still lie on its triangle, and only where the reference
    (with generous slack) hits too."""
    rng = np.random.default_rng(seed)
    vertices, faces = pg.edge_on_soup(400, rng)
    origins, directions = pg.near_axis_rays(pg.bounds(vertices), 4000, rng)
    hits = dacrt.Scene([(vertices, faces)]).closest(origins, directions, strategy=strategy)
    loose = reference.closest(vertices, faces, origins, directions, eps=1e-2)
    false = np.flatnonzero((hits.prim >= 0) & (loose.prim < 0))
    assert len(false) == 0, (
        f"{len(false)} false hits, first ray {false[0]}: origin {origins[false[0]].tolist()}, "
        f"direction {directions[false[0]].tolist()}, "
        f"engine prim {hits.prim[false[0]]} at t {hits.t[false[0]]}"
    )
    check.check_geometry(hits, vertices, faces, origins, directions)


# Found on conference.npz (faces 57980, 62353, 62354): the three triangles form one leaf; the
# ray passes 230 units from the first (a 6 mm sliver seen edge-on) and hits none of them.
CONFERENCE_LEAF = np.array(
    [
        [1638.146728515625, 1015.1870727539062, -0.1397857666015625],
        [1638.140380859375, 1015.1880493164062, -0.1397857666015625],
        [1638.140380859375, 1015.1851196289062, -0.1339874267578125],
        [-1017.9334106445312, 1042.62109375, 210.8332061767578],
        [-1017.9334106445312, 1042.62109375, 650.2925415039062],
        [-1020.1306762695312, 1035.880615234375, 210.8332061767578],
        [1467.161865234375, -555.58837890625, 187.56381225585938],
        [1469.047119140625, -555.58837890625, 181.7612762451172],
        [1467.161865234375, -555.58837890625, 181.46266174316406],
    ],
    dtype=np.float32,
)
CONFERENCE_RAY = (
    np.float32([[55.33673095703125, 954.3300170898438, 600.7444458007812]]),
    np.float32([[0.9902759790420532, -0.10602521896362305, -0.09006760269403458]]),
)


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_conference_sliver_is_not_hit(strategy):
    scene = dacrt.Scene([(CONFERENCE_LEAF, np.arange(9).reshape(3, 3))])
    assert (
        reference.closest(
            CONFERENCE_LEAF, np.arange(9).reshape(3, 3), *CONFERENCE_RAY, eps=1e-2
        ).prim[0]
        == -1
    )
    hits = scene.closest(*CONFERENCE_RAY, strategy=strategy)
    assert hits.prim[0] == -1, (
        f"false hit: prim {hits.prim[0]}, t {hits.t[0]}, u {hits.u[0]}, v {hits.v[0]}"
    )
    assert not scene.occluded(*CONFERENCE_RAY, strategy=strategy).occluded[0]


# ---------------------------------------------------------------------------------------------
# Stats
# ---------------------------------------------------------------------------------------------

STAT_KEYS = (
    "rays",
    "triangles",
    "ray_box_tests",
    "ray_triangle_tests",
    "nodes",
    "leaves",
    "sampled_nodes",
    "skipped_filterings",
    "max_depth",
)


def _check_stats(stats, n_rays):
    assert isinstance(stats, dict)
    missing = [k for k in STAT_KEYS if k not in stats]
    assert not missing, f"stats keys missing: {missing}"
    for key in STAT_KEYS:
        value = stats[key]
        assert isinstance(value, int) and not isinstance(value, bool), (
            f"stats[{key!r}] is {type(value).__name__}, not int"
        )
        assert value >= 0, f"stats[{key!r}] = {value} < 0"
    assert stats["rays"] == n_rays


@pytest.fixture(scope="module")
def stats_scene():
    """A perturbed icosphere of 5120 faces seen by a 120 x 90 camera (10,800 rays, about half hit).

    Enough rays per node for the cost-driven strategies to use their cost function below the
    top levels (rays per triangle > 1.5), and more than MIN_RAYS_TO_SAMPLE (5,000) rays there
    for ray sampling.
    """
    v, f = pg.icosphere(4)
    v = pg.perturb_radially(v, np.random.default_rng(15), 0.1)
    origins, directions = pg.camera_rays(pg.bounds(v), 120, 90, fov_degrees=30.0)
    return dacrt.Scene([(v, f)]), origins, directions


@pytest.mark.parametrize("threads", [None, 1])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_stats_counters(stats_scene, strategy, threads):
    scene, origins, directions = stats_scene
    hits = scene.closest(origins, directions, strategy=strategy, threads=threads, stats=True)
    stats = hits.stats
    _check_stats(stats, len(origins))
    n_hits = int(np.sum(hits.prim >= 0))
    assert n_hits > len(origins) // 4
    assert stats["ray_triangle_tests"] >= n_hits, "fewer triangle tests than hits"
    assert stats["triangles"] == scene.n_triangles
    assert stats["nodes"] >= stats["leaves"] >= 1
    assert stats["skipped_filterings"] <= stats["nodes"]
    assert 0 < stats["max_depth"] <= stats["nodes"]
    if strategy == "sampling":
        assert stats["sampled_nodes"] > 0, (
            "ray sampling never sampled on 10,800 rays x 5120 triangles"
        )
    if strategy == "sah":
        assert stats["sampled_nodes"] == 0
    answer = scene.occluded(origins, directions, strategy=strategy, threads=threads, stats=True)
    occ, occ_stats = answer.occluded, answer.stats
    _check_stats(occ_stats, len(origins))
    np.testing.assert_array_equal(occ, hits.prim >= 0)
    assert occ_stats["ray_triangle_tests"] > 0


def test_finished_occlusion_ray_misses_every_box():
    """A ray that is done (best_t = -inf) must fail the box test, even against a box it
    starts in: else it goes on into every node it crosses."""
    inf, one = np.float32(np.inf), np.float32(1.0)
    t_hi = cull_distance(np.float32(-np.inf))
    zero = np.float32(0.0)
    assert not intersect_box(0.5, 0.5, 0.5, inf, inf, one, zero, t_hi, 0, 0, 0, 1, 1, 1)
    assert intersect_box(0.5, 0.5, 0.5, inf, inf, one, zero, cull_distance(inf), 0, 0, 0, 1, 1, 1)


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_occlusion_stops_at_the_first_hit(strategy):
    """Eight stacked grids, rays up through them: every ray hits the first. A closest-hit query
    culls the layers behind each hit by its t; an occlusion query must do no more, because a
    ray that has hit anything is done (before the fix: 7-8x more triangle tests)."""
    v, f = pg.grid(32)
    verts = np.concatenate([pg.transform(v, offset=(0, 0, z)) for z in range(1, 9)])
    faces = np.concatenate([f + k * len(v) for k in range(8)])
    rng = np.random.default_rng(3)
    n = 20000
    origins = np.column_stack([rng.uniform(0.2, 0.8, (n, 2)), np.zeros(n)]).astype(np.float32)
    directions = np.column_stack([rng.uniform(-0.02, 0.02, (n, 2)), np.ones(n)]).astype(np.float32)
    scene = dacrt.Scene([(verts, faces)])
    hits = scene.closest(origins, directions, strategy=strategy, stats=True)
    answer = scene.occluded(origins, directions, strategy=strategy, stats=True)
    occ, occ_stats = answer.occluded, answer.stats
    assert occ.all() and (hits.prim < len(f)).all(), "every ray should hit the first layer"
    assert occ_stats["ray_triangle_tests"] <= 1.25 * hits.stats["ray_triangle_tests"], (
        f"occlusion made {occ_stats['ray_triangle_tests']} triangle tests, closest hits "
        f"{hits.stats['ray_triangle_tests']}: rays that are done went on"
    )


def test_stats_absent_unless_asked(stats_scene):
    scene, origins, directions = stats_scene
    assert scene.closest(origins[:10], directions[:10]).stats is None
    answer = scene.occluded(origins[:10], directions[:10])
    assert isinstance(answer, dacrt.Occlusion) and answer.stats is None
    assert isinstance(answer.occluded, np.ndarray) and answer.occluded.dtype == np.bool_


@pytest.mark.parametrize("placed", ["plain", "placed", "deforming"])
def test_a_hit_beyond_float32s_range_is_a_miss(placed):
    """A ray whose t at the surface rounds to inf in float32 (a direction of subnormal length,
    or a short one from far away) misses, in every query: t is never inf on a hit."""
    square = np.array([[-1, -1, 0], [2, -1, 0], [2, 2, 0], [-1, 2, 0]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    shift = np.eye(4)
    shift[0, 3] = 0.125
    if placed == "plain":
        scene = dacrt.Scene([(square, faces)])
    elif placed == "placed":
        scene = dacrt.Scene([(square, faces)], transforms=[shift])
    else:
        scene = dacrt.Scene([(square, faces)], vertices_end=[square + [0.125, 0, 0]])
    near, far = np.float32(-1.0), np.float32(-1e30)
    cases = [  # (origin z, direction z): t = -z / d
        (near, 1e-45),
        (near, 1e-41),
        (near, 2e-39),
        (far, 1e-9),
        (near, 1e-37),
        (near, 1e-30),
        (near, 1.0),
        (far, 1e-8),
    ]
    origins = np.array([[0.25, 0.25, z] for z, _ in cases], np.float32)
    directions = np.array([[0, 0, d] for _, d in cases], np.float32)
    expected_t = -origins[:, 2].astype(np.float64) / directions[:, 2].astype(np.float64)
    with np.errstate(over="ignore"):
        hit = np.isfinite(expected_t.astype(np.float32))
    assert hit.tolist() == [False] * 4 + [True] * 4
    for tmax in (None, np.full(len(cases), np.inf, np.float32)):
        closest = scene.closest(origins, directions, tmax=tmax)
        np.testing.assert_array_equal(closest.mesh >= 0, hit)
        assert np.isinf(closest.t[~hit]).all()
        np.testing.assert_allclose(closest.t[hit], expected_t[hit], rtol=1e-6)
        np.testing.assert_array_equal(scene.occluded(origins, directions, tmax=tmax).occluded, hit)
        np.testing.assert_array_equal(scene.count(origins, directions, tmax=tmax).count, hit)
        every = scene.hits(origins, directions, tmax=tmax)
        np.testing.assert_array_equal(every.counts, hit)
        assert np.isfinite(every.t).all()
    assert np.isinf(tmax).all()  # the caller's array is not changed
