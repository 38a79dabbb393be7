"""``bench.motion``'s checks and its Embree program (``bench/embree_motion.cpp``) on a small
synthetic street: a ground grid and boxes moving across it. The program's test is skipped where
it cannot be compiled (no g++ or no Embree 3 headers); nothing here is timed."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import dacrt
from bench import motion as M
from bench.world import grid_patch


def box(size: float = 2.0):
    """A closed cube of side ``size`` on z = 0, centred on the z axis: 12 triangles."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
    vertices = ((corners - [0.5, 0.5, 0.0]) * size).astype(np.float32)
    faces = [[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4]]
    faces += [[2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]]
    return vertices, np.array(faces, np.int32)


def street(k: int = 6, n_rays: int = 20_000, seed: int = 0):
    """(world, car, placements (3, k, 4, 4) float64 of float32 values, o, d, tau): a 40 m ground
    grid, k boxes driving along x (a yaw that turns with the frame), rays from 1.5 m up toward
    random points on the ground and the boxes' lane, at random times."""
    vertices, faces = grid_patch((-20.13, -20.07, 0.0), (40, 0, 0), (0, 40, 0), 20, 20)
    world = SimpleNamespace(vertices=vertices.astype(np.float32), faces=faces)
    rng = np.random.default_rng(seed)
    placements = np.tile(np.eye(4), (3, k, 1, 1))
    start = rng.uniform(-12, 12, k)
    for f in range(3):
        yaw = 0.1 * f + rng.uniform(0, 0.3, k)
        placements[f, :, 0, 0], placements[f, :, 0, 1] = np.cos(yaw), -np.sin(yaw)
        placements[f, :, 1, 0], placements[f, :, 1, 1] = np.sin(yaw), np.cos(yaw)
        placements[f, :, 0, 3] = start + 1.5 * f
        placements[f, :, 1, 3] = np.linspace(-6, 6, k)
    placements = placements.astype(np.float32).astype(np.float64)
    o = np.tile(np.float32([0.31, 0.17, 1.5]), (n_rays, 1))
    target = np.stack(
        [rng.uniform(-18, 18, n_rays), rng.uniform(-8, 8, n_rays), rng.uniform(0, 1.5, n_rays)], 1
    )
    d = (target - o).astype(np.float32)
    tau = rng.uniform(0, 1, n_rays).astype(np.float32)
    return world, box(), placements, o, d, tau


def engine_hits(world, car, placements, o, d, tau, moving: bool):
    meshes = [(world.vertices, world.faces)] + [car] * placements.shape[1]
    ends = {"transforms_end": [None] + list(placements[1])} if moving else {}
    scene = dacrt.Scene(meshes, transforms=[None] + list(placements[0]), **ends)
    return scene.closest(o, d, time=tau if moving else None)


def test_reference_t_is_the_engines_t():
    world, car, placements, o, d, tau = street()
    hits = engine_hits(world, car, placements, o, d, tau, moving=True)
    rays = np.flatnonzero(np.isfinite(hits.t))
    assert (hits.mesh[rays] > 0).sum() > 1000  # the boxes are hit
    exact = M.reference_t(
        rays, hits.mesh[rays], hits.prim[rays], tau, world, car, placements[0], placements[1], o, d
    )
    assert np.median(M.ulps_from(hits.t[rays], exact)) <= 1.0


def test_compare_hits_counts():
    world, car, placements, o, d, tau = street(n_rays=2000)
    hits = engine_hits(world, car, placements, o, d, tau, moving=True)
    t, mesh, prim = hits.t.copy(), hits.mesh.copy(), hits.prim.copy()
    hit = np.flatnonzero(np.isfinite(t))
    t[hit[0]], mesh[hit[0]], prim[hit[0]] = np.inf, -1, -1  # a miss
    prim[hit[1]] = prim[hit[1]] ^ 1  # another triangle, same t
    mesh[hit[2]] = mesh[hit[2]] + 1  # another mesh
    scene = (world, car, placements[0], placements[1], o, d)
    check = M.compare_hits(hits, (t, mesh, prim), tau, scene)
    assert (check["hit_miss_differ"], check["other_mesh"], check["other_prim"]) == (1, 1, 1)
    assert check["other_prim_same_t"] == 1
    assert check["same_prim"] == len(hit) - 3
    assert check["max_dt_m"] == 0.0


@pytest.fixture(scope="module")
def embree_binary(tmp_path_factory):
    from bench.native_embree import AnchorUnavailable, build_anchor

    try:
        return build_anchor(M.MOTION_SOURCE, tmp_path_factory.mktemp("build"))
    except AnchorUnavailable as exc:
        pytest.skip(str(exc))


@pytest.mark.parametrize("mode", ["static", "moving"])
def test_embree_program_agrees_with_the_engine(embree_binary, mode):
    world, car, placements, o, d, tau = street()
    embree = M.EmbreeMotion(embree_binary, world, car, placements, o, d, tau)
    try:
        _, commit, trace, theirs = embree.frame(mode, 2)
    finally:
        embree.close()
    assert commit >= 0 and trace > 0
    hits = engine_hits(world, car, placements, o, d, tau, moving=mode == "moving")
    times = tau if mode == "moving" else np.zeros_like(tau)
    scene = (world, car, placements[0], placements[1], o, d)
    check = M.compare_hits(hits, theirs, times, scene)
    assert check["car_hits_same_prim"] > 1000
    # Embree's triangle test is not watertight: a ray along a shared edge may differ
    assert check["hit_miss_differ"] + check["other_mesh"] <= 5
    assert check["other_prim"] - check["other_prim_same_t"] <= 5
    # near the origin Embree's float32 instance arithmetic stays within micrometres
    assert check["max_dt_m"] < 1e-4
    assert check["embree_cars_within_4_ulps"] > 0.9 * check["car_hits_same_prim"]
    if mode == "moving":  # the rays' times are used: the static frame's answers differ
        static = engine_hits(world, car, placements, o, d, tau, moving=False)
        assert M.compare_hits(static, theirs, times, scene)["hit_miss_differ"] > 100
