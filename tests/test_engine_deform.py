"""Deforming meshes: ``Scene(..., vertices_end=...)`` and ``time=`` on the queries.

A mesh whose vertices are v0 at the start of the interval and v1 at its end has, at time tau,
each vertex at float32(v0 + tau (v1 - v0)) computed in float64 (``lerp``, plain NumPy): a ray at
tau must answer as the same ray against the mesh interpolated so and given whole, bit for bit
(t, mesh, prim, u, v, normal), for every query kind, strategy, thread count, culling and masks.
At tau = 0 every answer is the static scene's; a deforming closed mesh is watertight at every
instant; bad vertices_end are InputErrors naming them.
"""

from __future__ import annotations

import functools

import numpy as np
import procedural as pg
import pytest
import sample_scenes

import dacrt
from dacrt.validation import InputError

TIMES = (0.0, 0.125, 0.5, 0.8, 1.0)


def lerp(v0, v1, tau):
    """The vertices at time tau: float32(v0 + tau (v1 - v0)), in float64 from float32 inputs."""
    start = np.asarray(v0, np.float32).astype(np.float64)
    end = np.asarray(v1, np.float32).astype(np.float64)
    return (start + np.float64(np.float32(tau)) * (end - start)).astype(np.float32)


@functools.cache
def _world():
    """A static sphere, a deforming soup (every vertex moved at random) and a deforming sphere
    (swelling and sliding): (meshes, vertices_end)."""
    rng = np.random.default_rng(7)
    sphere = sample_scenes.sphere(3)[0]
    soup = pg.triangle_soup(200, rng)
    swollen = sample_scenes.sphere(5)[0]
    meshes = [sphere, soup, swollen]
    soup_end = (soup[0] + rng.normal(scale=0.1, size=soup[0].shape)).astype(np.float32)
    swollen_end = (swollen[0] * 1.3 + np.float32([0.4, -0.2, 0.1])).astype(np.float32)
    return meshes, [None, soup_end, swollen_end]


def _rays(n, seed=3):
    """Rays from around the world through it, each at one of TIMES."""
    rng = np.random.default_rng(seed)
    origins = rng.uniform(-2.5, 2.5, (n, 3)).astype(np.float32)
    targets = rng.uniform(-0.8, 1.2, (n, 3)).astype(np.float32)
    times = np.asarray(TIMES, np.float32)[rng.integers(0, len(TIMES), n)]
    return origins, (targets - origins).astype(np.float32), times


def _at(meshes, ends, tau):
    """The meshes with each deforming one interpolated at tau in NumPy."""
    return [(v if end is None else lerp(v, end, tau), f) for (v, f), end in zip(meshes, ends)]


def _query(scene, kind, origins, directions, **options):
    if kind == "hits":
        return scene.hits(origins, directions, max_hits=6, **options)
    return getattr(scene, kind)(origins, directions, **options)


def _fields(kind, answer, rays):
    """The answer's arrays for ``rays`` (ids), per ray: comparable across batches."""
    if kind == "closest":
        return [answer.t[rays], answer.mesh[rays], answer.prim[rays], answer.u[rays],
                answer.v[rays], answer.normal[rays]]  # fmt: skip
    if kind == "occluded":
        return [answer.occluded[rays]]
    if kind == "count":
        return [answer.count[rays]]
    rows = np.concatenate([np.arange(answer.offsets[r], answer.offsets[r + 1]) for r in rays])
    rows = rows.astype(np.int64)
    return [answer.counts[rays], answer.truncated[rays], answer.t[rows], answer.mesh[rows],
            answer.prim[rows], answer.u[rows], answer.v[rows], answer.normal[rows]]  # fmt: skip


def _assert_same(expected, got):
    for a, b in zip(expected, got, strict=True):
        np.testing.assert_array_equal(a, b)
        assert a.dtype == b.dtype


def _assert_as_interpolated(meshes, ends, kind, origins, directions, times, **options):
    """Each ray at its time answers as against the meshes interpolated at that time."""
    scene = dacrt.Scene(meshes, vertices_end=ends)
    got = _query(scene, kind, origins, directions, time=times, **options)
    masks = options.pop("mask", None)
    for tau in np.unique(times):
        rays = np.flatnonzero(times == tau)
        static = dacrt.Scene(_at(meshes, ends, tau))
        sub_mask = None if masks is None or np.isscalar(masks) else masks[rays]
        expected = _query(static, kind, origins[rays], directions[rays], mask=sub_mask, **options)
        every = np.arange(len(rays))
        _assert_same(_fields(kind, expected, every), _fields(kind, got, rays))
    return got


@pytest.mark.parametrize("kind", ["closest", "occluded", "hits", "count"])
def test_each_ray_answers_as_the_mesh_at_its_time(kind):
    meshes, ends = _world()
    origins, directions, times = _rays(3000)
    got = _assert_as_interpolated(meshes, ends, kind, origins, directions, times)
    if kind == "closest":  # the deforming meshes are hit, at every time
        assert set(np.unique(got.mesh)) >= {0, 1, 2}


@pytest.mark.parametrize("cull", ["back", "front"])
def test_culling_and_masks_at_each_time(cull):
    meshes, ends = _world()
    origins, directions, times = _rays(2000, seed=5)
    scene_masks = np.array([1, 2, 4], np.uint32)
    ray_masks = np.random.default_rng(9).integers(1, 8, len(origins)).astype(np.uint32)
    for kind in ("closest", "count"):
        scene = dacrt.Scene(meshes, masks=scene_masks, vertices_end=ends)
        got = _query(scene, kind, origins, directions, time=times, cull=cull, mask=ray_masks)
        for tau in np.unique(times):
            rays = np.flatnonzero(times == tau)
            static = dacrt.Scene(_at(meshes, ends, tau), masks=scene_masks)
            expected = _query(
                static, kind, origins[rays], directions[rays], cull=cull, mask=ray_masks[rays]
            )
            _assert_same(_fields(kind, expected, np.arange(len(rays))), _fields(kind, got, rays))
    # One mask for the batch: a mesh it does not see is left out.
    hidden = dacrt.Scene(meshes, masks=scene_masks, vertices_end=ends)
    seen = hidden.closest(origins, directions, time=times, mask=5)
    assert 1 not in set(np.unique(seen.mesh))


def test_grid_through_vertices_and_edges_is_watertight():
    """A grid sliding and scaling by powers of two: at each time its interpolated vertices, and
    the rays through them and through its inner edges' midpoints, are exact; the count rule
    holds (a ray through the grid inside its border crosses it once) and every answer is the
    interpolated grid's."""
    vertices, faces = pg.grid(8, 1.0, alternate=True)
    end = (vertices * np.float32(2.0) + np.float32([0.5, 0.25, 1.0])).astype(np.float32)
    rng = np.random.default_rng(2)
    origins, directions, times = [], [], []
    for tau in (0.0, 0.25, 0.5, 0.75, 1.0):
        at = lerp(vertices, end, tau).astype(np.float64)
        edges = pg.two_sided_edges(faces)  # a boundary edge is crossed by its one side or not
        points = np.concatenate([at[pg.grid_interior_vertices(8)], at[edges].mean(axis=1)])
        above = points + np.array([0.0, 0.0, 2.0])
        tilt = rng.choice([0.0, 0.25, -0.5], size=(len(points), 2))
        start = above.copy()
        start[:, :2] += tilt
        origins.append(start)
        directions.append(points - start)
        times.append(np.full(len(points), tau))
    origins = np.concatenate(origins).astype(np.float32)
    directions = np.concatenate(directions).astype(np.float32)
    times = np.concatenate(times).astype(np.float32)
    meshes, ends = [(vertices, faces)], [end]
    counts = _assert_as_interpolated(meshes, ends, "count", origins, directions, times)
    np.testing.assert_array_equal(counts.count, 1)
    for kind in ("closest", "hits"):
        _assert_as_interpolated(meshes, ends, kind, origins, directions, times)


@pytest.mark.parametrize("kind", ["closest", "occluded", "hits", "count"])
def test_time_zero_is_the_static_scene(kind):
    meshes, ends = _world()
    origins, directions, _ = _rays(2000, seed=11)
    static = _query(dacrt.Scene(meshes), kind, origins, directions)
    every = np.arange(len(origins))
    scene = dacrt.Scene(meshes, vertices_end=ends)
    assert scene.moving
    for time in (None, 0.0, np.zeros(len(origins), np.float32)):
        got = _query(scene, kind, origins, directions, time=time)
        _assert_same(_fields(kind, static, every), _fields(kind, got, every))


@pytest.mark.parametrize("kind", ["closest", "occluded", "hits", "count"])
def test_strategies_and_threads_agree(kind):
    meshes, ends = _world()
    origins, directions, times = _rays(12000, seed=13)
    scene = dacrt.Scene(meshes, vertices_end=ends)
    every = np.arange(len(origins))
    first = _fields(kind, _query(scene, kind, origins, directions, time=times, threads=1), every)
    for strategy in dacrt.STRATEGIES:
        for threads in (1, 2):
            got = _query(
                scene, kind, origins, directions, time=times, strategy=strategy, threads=threads
            )
            _assert_same(first, _fields(kind, got, every))


def test_with_changes_sets_keeps_and_drops_the_end():
    meshes, ends = _world()
    origins, directions, times = _rays(1500, seed=17)
    static = dacrt.Scene(meshes)
    deformed = static.with_changes(vertices_end={1: ends[1], 2: ends[2]})
    direct = dacrt.Scene(meshes, vertices_end=ends)
    every = np.arange(len(origins))
    for kind in ("closest", "hits"):
        _assert_same(
            _fields(kind, _query(direct, kind, origins, directions, time=times), every),
            _fields(kind, _query(deformed, kind, origins, directions, time=times), every),
        )
    # New start vertices keep the end; None makes the mesh static again.
    moved = (meshes[1][0] + np.float32(0.25)).astype(np.float32)
    kept = deformed.with_changes(vertices={1: moved})
    again = dacrt.Scene([meshes[0], (moved, meshes[1][1]), meshes[2]], vertices_end=ends)
    np.testing.assert_array_equal(
        kept.closest(origins, directions, time=times).t,
        again.closest(origins, directions, time=times).t,
    )
    back = deformed.with_changes(vertices_end={1: None, 2: None})
    assert not back.moving
    _assert_same(
        _fields("closest", static.closest(origins, directions), every),
        _fields("closest", back.closest(origins, directions, time=times), every),
    )
    # The untouched deforming level is shared by a version that only masks a mesh.
    assert deformed.with_changes(masks={0: 3})._deforming is deformed._deforming


def test_motion_of_a_deforming_hit():
    meshes, ends = _world()
    scene = dacrt.Scene(meshes, vertices_end=ends)
    origins, directions, times = _rays(500, seed=19)
    hits = scene.closest(origins, directions, time=times)
    on = np.flatnonzero(hits.mesh == 2)
    points = origins[on] + hits.t[on, None] * directions[on]
    velocity = scene.motion(
        hits.mesh[on], points, times[on], prim=hits.prim[on], u=hits.u[on], v=hits.v[on]
    )
    v0, faces = meshes[2]
    change = ends[2].astype(np.float64) - v0
    corners = change[faces[hits.prim[on]]]
    u, v = hits.u[on, None].astype(np.float64), hits.v[on, None].astype(np.float64)
    expected = (1 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]
    np.testing.assert_allclose(velocity, expected)
    with pytest.raises(InputError, match="prim, u and v"):
        scene.motion(hits.mesh[on], points, times[on])
    # bad hits are named, not an IndexError (or a negative prim read from the end)
    prim, u, v = hits.prim[on], hits.u[on], hits.v[on]
    for bad, words in (
        (dict(prim=prim + 10**6, u=u, v=v), "prim must hold triangles of mesh 2"),
        (dict(prim=-1 - prim, u=u, v=v), "prim must hold triangles of mesh 2"),
        (dict(prim=prim[:-1], u=u, v=v), "prim has"),
        (dict(prim=prim, u=u[:1], v=v), "u has 1 entries"),
        (dict(prim=prim.astype(float), u=u, v=v), "prim must be integers"),
    ):
        with pytest.raises(InputError, match=words):
            scene.motion(hits.mesh[on], points, times[on], **bad)
    with pytest.raises(InputError, match="points must be an"):
        scene.motion(hits.mesh[on], [["a", "b", "c"]] * len(on), times[on], prim=prim, u=u, v=v)
    with pytest.raises(InputError, match="mesh must hold -1 or indices below"):
        scene.motion(np.full(len(on), 9), points, times[on], prim=prim, u=u, v=v)
    with pytest.raises(InputError, match="mesh must be integers"):
        scene.motion(hits.mesh[on] + 0.5, points, times[on], prim=prim, u=u, v=v)


def test_point_queries_see_time_zero():
    meshes, ends = _world()
    points = np.random.default_rng(23).uniform(-1.5, 1.5, (300, 3)).astype(np.float32)
    got = dacrt.Scene(meshes, vertices_end=ends).nearest(points)
    expected = dacrt.Scene(meshes).nearest(points)
    np.testing.assert_array_equal(got.distance, expected.distance)
    np.testing.assert_array_equal(got.prim, expected.prim)


def test_bad_vertices_end_name_the_entry():
    meshes, ends = _world()
    soup = meshes[1][0]
    nan = soup.copy()
    nan[4, 1] = np.nan
    cases = [
        ([None, soup[:-1], None], r"vertices_end\[1\] has"),
        ([None, soup[:, :2], None], r"vertices_end\[1\] must have shape"),
        ([None, nan, None], r"vertices_end\[1\]\[4\] is not finite"),
        ([None, "abc", None], r"vertices_end\[1\]"),
        ([None, None], "vertices_end has 2 entries"),
    ]
    for given, message in cases:
        with pytest.raises(InputError, match=message):
            dacrt.Scene(meshes, vertices_end=given)
    with pytest.raises(InputError, match=r"vertices_end\[1\]: mesh 1 is placed"):
        dacrt.Scene(meshes, transforms_end=[None, np.eye(4), None], vertices_end=ends)
    scene = dacrt.Scene(meshes, vertices_end=ends)
    with pytest.raises(InputError, match=r"vertices_end\[2\]: mesh 2 is placed"):
        scene.with_changes(transforms={2: np.eye(4)})
    with pytest.raises(InputError, match=r"vertices_end\[-1\]"):
        scene.with_changes(vertices_end={-1: soup})
    bad = meshes[0][0].copy()
    bad[4, 1] = np.inf
    with pytest.raises(InputError, match=r"vertices_end\[0\]\[4\] is not finite"):
        scene.with_changes(vertices_end={0: bad})


def test_writes_to_the_callers_arrays_change_neither_a_kept_end_nor_motion():
    """A deforming mesh's start, end and faces are the Scene's own copies: after the caller
    writes into the buffers it gave, ``with_changes`` keeps the end as given and ``motion``
    answers the corners' ends less their starts as given (NumPy)."""
    meshes, ends = _world()
    v0, f = meshes[2]
    v1 = ends[2]
    given_v0, given_v1, given_f = v0.copy(), v1.copy(), f.copy()
    scene = dacrt.Scene([meshes[0], (given_v0, given_f)], vertices_end=[None, given_v1])
    origins, directions, times = _rays(800, seed=37)
    hits = scene.closest(origins, directions, time=times)
    on = np.flatnonzero(hits.mesh == 1)
    assert len(on) > 50
    points = origins[on] + hits.t[on, None] * directions[on]
    given_v0 += np.float32(3.0)
    given_v1 += np.float32(50.0)
    given_f[:] = given_f[::-1]
    velocity = scene.motion(
        hits.mesh[on], points, times[on], prim=hits.prim[on], u=hits.u[on], v=hits.v[on]
    )
    change = v1.astype(np.float64) - v0.astype(np.float64)
    corners = change[f[hits.prim[on]]]
    u, v = hits.u[on, None].astype(np.float64), hits.v[on, None].astype(np.float64)
    np.testing.assert_allclose(
        velocity, (1 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]
    )
    # new start vertices of the same values: the end and the faces are those given
    kept = scene.with_changes(vertices={1: v0.copy()})
    fresh = dacrt.Scene([meshes[0], (v0, f)], vertices_end=[None, v1])
    every = np.arange(len(origins))
    expected = _fields("closest", fresh.closest(origins, directions, time=times), every)
    _assert_same(expected, _fields("closest", kept.closest(origins, directions, time=times), every))
    _assert_same(expected, _fields("closest", hits, every))
