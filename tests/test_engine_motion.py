"""Motion: ``Scene(..., transforms_end=...)`` and ``time=`` on the queries.

A mesh placed by M0 at the start of the interval and M1 at its end is, at time tau, each vertex
at (1 - tau) p0 + tau p1: a ray at tau must answer as the same ray against the meshes placed so
in numpy and given whole, up to the instances' rounding (``placed_checks``). At tau = 0 every
answer is the static scene's bit for bit, for every strategy and thread count; a moving closed
mesh is watertight at every instant; bad times and end placements are InputErrors naming them.
"""

from __future__ import annotations

import functools

import numpy as np
import procedural as pg
import pytest
import sample_scenes
from test_engine_instances import (
    MATRICES,
    _queries,
    affine,
    assert_close_to_placed,
    assert_same_answers,
)
from test_engine_world import _four, _rays, _world

import dacrt
from dacrt.validation import InputError

TIMES = (0.0, 0.25, 0.5, 0.8, 1.0)


def place_at(vertices, start, end, tau):
    """Each vertex at (1 - tau) M0 p + tau M1 p, in float64 (numpy's matmul), then float32; a
    None start is the identity."""
    v = np.asarray(vertices, np.float64)
    m0 = np.eye(4) if start is None else np.asarray(start, np.float64)
    m1 = np.asarray(end, np.float64)
    p0 = v @ m0[:3, :3].T + m0[:3, 3]
    p1 = v @ m1[:3, :3].T + m1[:3, 3]
    return ((1.0 - tau) * p0 + tau * p1).astype(np.float32)


@functools.cache
def _moving():
    """A closed sphere turning and moving, a soup sliding from where it is given, a grid
    sheared then rotated, and a static sphere placed by a matrix."""
    meshes = [
        sample_scenes.sphere(40)[0],
        pg.triangle_soup(300, np.random.default_rng(41)),
        sample_scenes.tilted_grid(42)[0],
        sample_scenes.sphere(43)[0],
    ]
    starts = [MATRICES["rotation"], None, MATRICES["shear"], affine(offset=(0.0, 3.0, 0.0))]
    ends = [
        affine(pg.rotation([0.0, 1.0, 0.3], 1.2), (1.5, 0.3, -0.2)),
        affine(offset=(0.5, -0.25, 0.0)),
        affine(pg.rotation([1.0, 0.0, 0.0], 0.5) * 1.5, (0.0, 0.5, 1.0)),
        None,
    ]
    return meshes, starts, ends


def _placed_at(meshes, starts, ends, tau):
    """The meshes as placed at tau (static ones by their start, or as given)."""
    placed = []
    for (v, f), start, end in zip(meshes, starts, ends):
        if end is None and start is None:
            placed.append((v.astype(np.float32), f))
        else:
            placed.append((place_at(v, start, start if end is None else end, tau), f))
    return placed


@functools.cache
def _moving_far():
    """``_moving()``'s placed meshes given 1e5 units from their own origin, moved by the same
    placements after the move back (the soup as given, near the others)."""
    meshes, starts, ends = _moving()
    shift = 1e5 * np.array([1.0, -0.6, 0.3])
    back = affine(offset=-shift)
    far = [(v, f) if m is None else ((v + shift).astype(np.float32), f) for (v, f), m in
           zip(meshes, starts)]  # fmt: skip
    starts = [None if m is None else m @ back for m in starts]
    ends = [e if m is None or e is None else e @ back for m, e in zip(starts, ends)]
    return far, starts, ends


@pytest.mark.parametrize("modelled", ["near", "far"])
@pytest.mark.parametrize("tau", TIMES)
def test_a_ray_at_tau_answers_as_the_meshes_placed_at_tau(tau, modelled):
    """Also for meshes modelled far from their own origin: the rays go into the space of
    M(tau) relative to the mesh's box."""
    meshes, starts, ends = _moving() if modelled == "near" else _moving_far()
    scene = dacrt.Scene(meshes, transforms=starts, transforms_end=ends)
    placed = _placed_at(meshes, starts, ends, tau)
    whole = dacrt.Scene(placed)
    rng = np.random.default_rng(44)
    rays = [pg.mixed_rays(pg.bounds(v), 150, rng) for v, _ in placed]
    o, d = (np.concatenate(x) for x in zip(*rays))
    for cull in ("none", "back", "front"):
        got = _queries(scene, o, d, cull=cull, time=np.full(len(o), tau, np.float32))
        want = _queries(whole, o, d, cull=cull)
        assert_close_to_placed(got, want, o, d, placed, f"{modelled}, tau={tau}, cull={cull}")


def test_a_batch_of_mixed_times_answers_each_ray_at_its_own():
    """Rays at five instants in one batch answer as each instant's rays alone, bit for bit."""
    meshes, starts, ends = _moving()
    scene = dacrt.Scene(meshes, transforms=starts, transforms_end=ends)
    o, d = _rays(meshes, [s if e is None else e for s, e in zip(starts, ends)], n=1000, seed=45)
    times = np.random.default_rng(46).choice(np.float32(TIMES), len(o))
    for cull in ("none", "back"):
        mixed = _queries(scene, o, d, cull=cull, time=times)
        for tau in TIMES:
            rays = np.flatnonzero(times == np.float32(tau))
            alone = _queries(scene, o[rays], d[rays], cull=cull, time=np.float32(tau))
            closest = mixed["closest"]
            for name in ("t", "mesh", "prim", "u", "v", "normal"):
                np.testing.assert_array_equal(
                    getattr(closest, name)[rays], getattr(alone["closest"], name), name
                )
            np.testing.assert_array_equal(mixed["count"].count[rays], alone["count"].count)
            np.testing.assert_array_equal(
                mixed["occluded"].occluded[rays], alone["occluded"].occluded
            )
            hits = mixed["hits"]
            for k, ray in enumerate(rays):
                rows = slice(hits.offsets[ray], hits.offsets[ray + 1])
                own = slice(alone["hits"].offsets[k], alone["hits"].offsets[k + 1])
                np.testing.assert_array_equal(hits.t[rows], alone["hits"].t[own])
                np.testing.assert_array_equal(hits.prim[rows], alone["hits"].prim[own])
                np.testing.assert_array_equal(hits.normal[rows], alone["hits"].normal[own])


def test_a_placement_mirrored_at_some_instants_culls_the_faces_it_shows():
    """A grid going from a rotation (det > 0) to a reflection (det < 0): at 0.25 and 0.75 the
    culled answers are those of the grid placed at that instant (its normals flip)."""
    v, f = sample_scenes.tilted_grid(47)[0]
    start = MATRICES["rotation"]
    end = MATRICES["reflection"]
    scene = dacrt.Scene([(v, f)], transforms=[start], transforms_end=[end])
    rng = np.random.default_rng(48)
    for tau in (0.25, 0.75):
        placed = [(place_at(v, start, end, tau), f)]
        whole = dacrt.Scene(placed)
        o, d = pg.mixed_rays(pg.bounds(placed[0][0]), 400, rng)
        times = np.full(len(o), tau, np.float32)
        for cull in ("back", "front"):
            got = _queries(scene, o, d, cull=cull, time=times)
            want = _queries(whole, o, d, cull=cull)
            assert_close_to_placed(got, want, o, d, placed, f"tau={tau}, cull={cull}")
    # One batch with rays at both instants: each answers as at its own.
    o, d = pg.mixed_rays(pg.bounds(place_at(v, start, end, 0.5)), 400, rng)
    times = np.where(np.arange(len(o)) % 2, np.float32(0.25), np.float32(0.75))
    mixed = scene.closest(o, d, cull="back", time=times)
    for tau in (0.25, 0.75):
        rays = times == np.float32(tau)
        alone = scene.closest(o[rays], d[rays], cull="back", time=tau)
        np.testing.assert_array_equal(mixed.t[rays], alone.t)
        np.testing.assert_array_equal(mixed.normal[rays], alone.normal)


def _moving_world():
    """``test_engine_world``'s world with three of its meshes moving."""
    meshes, transforms, masks = _world()
    ends = [
        None,
        affine(offset=(0.3, 0.0, -0.2)),
        None,
        affine(pg.rotation([0.0, 0.0, 1.0], 0.7), (2.0, 0.5, 0.0)),
        MATRICES["reflection"] @ affine(offset=(0.5, 2.0, 0.0)),
    ]
    return meshes, transforms, ends, masks


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_time_zero_is_the_static_scene_bit_for_bit(strategy, threads):
    meshes, transforms, ends, masks = _moving_world()
    moving = dacrt.Scene(meshes, masks=masks, transforms=transforms, transforms_end=ends)
    static = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    o, d = _rays(meshes, transforms, n=40_000, seed=28)
    ray_masks = np.random.default_rng(29).integers(1, 32, len(o)).astype(np.uint32)
    zero = np.zeros(len(o), np.float32)
    for cull, mask in (("none", None), ("front", ray_masks)):
        options = dict(cull=cull, mask=mask, strategy=strategy, threads=threads)
        want = _four(static, o, d, **options)
        what = f"{strategy}, {threads} threads, cull={cull}"
        assert_same_answers(_four(moving, o, d, **options), want, f"{what}, no time")
        assert_same_answers(_four(moving, o, d, time=zero, **options), want, f"{what}, time 0")


@functools.cache
def _timed_answers():
    meshes, transforms, ends, masks = _moving_world()
    scene = dacrt.Scene(meshes, masks=masks, transforms=transforms, transforms_end=ends)
    o, d = _rays(meshes, transforms, n=40_000, seed=30)
    times = np.random.default_rng(31).uniform(0, 1, len(o)).astype(np.float32)
    times[::3] = 0.0  # a third exactly at the start
    ray_masks = np.random.default_rng(32).integers(1, 32, len(o)).astype(np.uint32)
    return scene, o, d, times, ray_masks


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_times_give_the_same_answers_for_every_strategy_and_thread_count(strategy, threads):
    scene, o, d, times, ray_masks = _timed_answers()
    meshes, transforms, masks = _world()
    static = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    at_zero = np.flatnonzero(times == 0)
    for cull, mask in (("none", None), ("front", ray_masks)):
        want = _four(scene, o, d, cull=cull, mask=mask, time=times, strategy="sampling", threads=1)
        got = _four(
            scene, o, d, cull=cull, mask=mask, time=times, strategy=strategy, threads=threads
        )
        assert_same_answers(got, want, f"{strategy}, {threads} threads, cull={cull}")
        # The rays at 0 answer as the static scene's, bit for bit, in a batch of other times.
        zero_mask = None if mask is None else mask[at_zero]
        still = static.closest(o[at_zero], d[at_zero], cull=cull, mask=zero_mask)
        for name in ("t", "mesh", "prim", "u", "v", "normal"):
            np.testing.assert_array_equal(
                getattr(got["closest"], name)[at_zero], getattr(still, name)
            )


@pytest.mark.parametrize("tau", [0.0, 0.3, 0.5, 0.9, 1.0])
def test_a_moving_closed_mesh_is_watertight_at_every_instant(tau):
    """Rays from inside a closed sphere moving by rotation, scale and translation, through its
    vertices and edge midpoints as placed at tau: every one hits, each counts an odd number."""
    v, f = pg.icosphere(3)
    v = pg.perturb_radially(v, np.random.default_rng(33), 0.1)
    start = MATRICES["far"]
    end = affine(pg.rotation([0.0, 1.0, 0.0], 0.9) * 6.0, (1003.0, -1998.0, 501.0))
    scene = dacrt.Scene([(v, f)], transforms=[start], transforms_end=[end])
    m = (1.0 - tau) * start + tau * end
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    v64 = v.astype(np.float64)
    targets = np.concatenate([v64, v64[edges].mean(axis=1)])
    inside = np.random.default_rng(34).uniform(-0.2, 0.2, (len(targets), 3))
    o = (inside @ m[:3, :3].T + m[:3, 3]).astype(np.float32)
    d = ((targets - inside) @ m[:3, :3].T).astype(np.float32)
    times = np.full(len(o), tau, np.float32)
    hits = scene.closest(o, d, time=times)
    assert (hits.prim >= 0).all(), f"{np.sum(hits.prim < 0)} rays slipped through"
    assert np.all(scene.count(o, d, time=times).count % 2 == 1)
    assert scene.occluded(o, d, time=times).occluded.all()


def test_rays_at_an_instant_where_every_placement_they_reach_is_flat_see_the_rest():
    """A mirror end placement is flat at tau = 0.5: rays at that instant see nothing of that
    mesh (the documented rule), and the meshes behind it answer as usual in every query (the
    query raised a thread pool's error when no instance had a ray left to trace)."""
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float64)
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    mirror = np.diag([-1.0, 1, 1, 1])
    scene = dacrt.Scene(
        [(square, faces), (square + [0, 0, -1], faces)], transforms_end=[mirror, None]
    )
    origins = np.array([[0.2, 0.2, 1], [0.7, 0.7, 1]])
    down = np.array([[0, 0, -1.0], [0, 0, -1]])
    hits = scene.closest(origins, down, time=0.5)
    np.testing.assert_array_equal(hits.t, [2, 2])
    np.testing.assert_array_equal(hits.mesh, [1, 1])
    np.testing.assert_array_equal(scene.count(origins, down, time=0.5).count, [1, 1])
    np.testing.assert_array_equal(scene.hits(origins, down, time=0.5).counts, [1, 1])
    assert scene.occluded(origins, down, time=0.5).occluded.all()
    # ... and no point of the flat placement moves at that instant (no LinAlgError)
    on_flat = scene.motion([0, 0], [[0.0, 0.2, 0], [0.25, 0.7, 0]], [0.5, 0.25])
    np.testing.assert_array_equal(on_flat[0], [0, 0, 0])
    np.testing.assert_allclose(on_flat[1], [-1, 0, 0])  # x = 0.25 at tau 0.25 is 0.5 in mesh space


def test_an_instant_flat_up_to_rounding_is_flat():
    """A half-turn made with cos and sin is flat at tau = 0.5 only up to rounding (an axis
    scaled by 6e-17, not 0): its rays see nothing of the mesh, as at an exactly flat instant,
    and a far ray beside them is no error (its inverse placement took it past float32)."""
    ((vertices, faces),) = sample_scenes.sphere(12)
    turn = np.eye(4)
    turn[:2, :2] = [[np.cos(np.pi), -np.sin(np.pi)], [np.sin(np.pi), np.cos(np.pi)]]
    scene = dacrt.Scene([(vertices, faces)], transforms_end=[turn])
    origins = np.array([[1e23, 0, 0.1], [0.3, -0.2, 5]])
    directions = np.array([[-1.0, 0, 0], [0, 0, -1]])
    np.testing.assert_array_equal(scene.closest(origins, directions, time=0.5).t, [np.inf] * 2)
    np.testing.assert_array_equal(scene.count(origins, directions, time=0.5).count, [0, 0])
    # at another instant the same rays answer as the sphere placed there (numpy)
    placed = dacrt.Scene([(place_at(vertices, None, turn, 0.3), faces)])
    moving, still = (
        scene.closest(origins, directions, time=0.3),
        placed.closest(origins, directions),
    )
    assert moving.prim[1] == still.prim[1] >= 0
    np.testing.assert_allclose(moving.t[1], still.t[1], rtol=1e-6)


def test_a_ray_leaving_float32_in_a_moving_mesh_space_names_both_placements():
    ((vertices, faces),) = sample_scenes.sphere(12)
    small, smaller = np.diag([1e-10, 1e-10, 1e-10, 1.0]), np.diag([2e-10, 2e-10, 2e-10, 1.0])
    scene = dacrt.Scene([(vertices, faces)], transforms=[small], transforms_end=[smaller])
    with pytest.raises(dacrt.MeshSpaceError, match=r"transforms\[0\] to transforms_end\[0\]"):
        scene.closest([[1e30, 0, 0]], [[-1.0, 0, 0]], time=0.5)


def test_with_changes_sets_and_clears_end_placements():
    meshes, starts, ends = _moving()
    scene = dacrt.Scene(meshes, transforms=starts)
    moved = scene.with_changes(transforms_end=dict(enumerate(ends)))
    fresh = dacrt.Scene(meshes, transforms=starts, transforms_end=ends)
    o, d = _rays(meshes, starts, n=600, seed=35)
    times = np.random.default_rng(36).uniform(0, 1, len(o)).astype(np.float32)
    assert_same_answers(_queries(moved, o, d, time=times), _queries(fresh, o, d, time=times), "set")
    still = moved.with_changes(transforms_end=dict.fromkeys(range(len(meshes))))
    assert_same_answers(_queries(still, o, d, time=times), _queries(scene, o, d), "cleared")
    # The scene it came from keeps its answers.
    assert_same_answers(_queries(scene, o, d, time=times), _queries(scene, o, d), "old")
    assert scene.bounds[1, 0] < moved.bounds[1, 0]  # the box holds the end placements


def test_a_scene_without_motion_ignores_time():
    meshes, transforms, masks = _world()
    scene = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    o, d = _rays(meshes, transforms, n=500, seed=37)
    times = np.random.default_rng(38).uniform(0, 1, len(o)).astype(np.float32)
    assert_same_answers(_queries(scene, o, d, time=times), _queries(scene, o, d), "static")


BAD_TIMES = {
    "shape": (np.zeros(3, np.float32), "shape"),
    "nan": (np.array([0.5, np.nan, 0.0, 0.0]), "time[1]"),
    "negative": (np.array([0.5, -0.1, 0.0, 0.0]), "time[1]"),
    "beyond one": (np.array([0.5, 0.0, 0.0, 1.5]), "time[3]"),
    "inf": (np.inf, "time[0]"),
    # checked as given, before rounding to float32 (1.0 and -0.0)
    "just beyond one": (np.array([0.5, 0.0, 1 + 1e-9, 0.0]), "time[2] is 1.000000001"),
    "just below zero": (-1e-50, "time[0] is -1e-50"),
    "strings": (np.array(["a", "b", "c", "d"]), "dtype"),
}


@pytest.mark.parametrize("case", sorted(BAD_TIMES))
def test_bad_times_are_input_errors_naming_time(case):
    value, words = BAD_TIMES[case]
    meshes, starts, ends = _moving()
    scene = dacrt.Scene(meshes, transforms=starts, transforms_end=ends)
    o = np.zeros((4, 3), np.float32)
    d = np.tile(np.float32([1.0, 0.0, 0.0]), (4, 1))
    for query in (scene.closest, scene.occluded, scene.hits, scene.count):
        with pytest.raises(InputError, match="time") as error:
            query(o, d, time=value)
        assert words in str(error.value)


@pytest.mark.parametrize(
    ("points", "words"),
    [
        (np.zeros(6), r"points must have shape \(n, 3\), got \(6,\)"),
        (np.zeros((2, 1, 3)), r"points must have shape \(n, 3\), got \(2, 1, 3\)"),
        ([[0, 0, 0], [0, 0]], "points must be an"),
        ([[0, 0, 0], [0, np.nan, 0]], r"points\[1\] is not finite \(1 rows"),
        ([[np.inf, 0, 0], [0, -np.inf, 0]], r"points\[0\] is not finite \(2 rows"),
        (np.zeros((2, 3), bool), "dtype bool"),
    ],
)
def test_motion_takes_finite_points_n_by_3(points, words):
    meshes, starts, ends = _moving()
    scene = dacrt.Scene(meshes, transforms=starts, transforms_end=ends)
    with pytest.raises(InputError, match=words):
        scene.motion([0, 0], points, 0.5)
    with pytest.raises(InputError, match=r"time\[1\] is 1.000000001"):
        scene.motion([0, 0], np.zeros((2, 3)), [0.5, 1 + 1e-9])


def test_bad_end_placements_are_input_errors_naming_them():
    v, f = sample_scenes.sphere(39)[0]
    with pytest.raises(InputError, match=r"transforms_end has 2 entries for 1 meshes"):
        dacrt.Scene([(v, f)], transforms_end=[None, None])
    with pytest.raises(InputError, match=r"transforms_end\[0\] is singular"):
        dacrt.Scene([(v, f)], transforms_end=[np.diag([1.0, 0.0, 1.0, 1.0])])
    with pytest.raises(InputError, match=r"transforms_end\[0\] places mesh 0 beyond"):
        dacrt.Scene([(v, f)], transforms_end=[affine(offset=(1e39, 0.0, 0.0))])
    scene = dacrt.Scene([(v, f)])
    with pytest.raises(InputError, match=r"transforms_end\[0\] is not affine"):
        scene.with_changes(transforms_end={0: np.ones((4, 4))})
    with pytest.raises(InputError, match=r"transforms_end\[1\]: there is no mesh 1"):
        scene.with_changes(transforms_end={1: np.eye(4)})
