"""The engine against Embree (through ``embreex``) on procedural scenes and the shared real scenes.

Skips cleanly when ``embreex`` is not installed or ``../shared/scenes`` is absent. Embree is an
independent float32 ray caster, so the comparison is statistical where rounding may differ
(hit/miss on >= 99.9% of rays, t on >= 99.9% of rays both hit) and exact elsewhere (t, u, v on
rays where both hit the same triangle at a non-grazing angle).
"""

from __future__ import annotations

import assertions as check
import numpy as np
import procedural as pg
import pytest
import sample_scenes

import dacrt
from oracles.embree import Embree

embreex = pytest.importorskip("embreex")

MIN_AGREEMENT = 0.999


@pytest.mark.parametrize("scene_name", ["soup", "sphere", "tilted_grid", "multi"])
def test_procedural_closest_matches_embree(scene_name):
    meshes = sample_scenes.SCENES[scene_name](50)
    vertices, faces, offsets = pg.concat(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, 50, n=3000)
    hits = dacrt.Scene(meshes).closest(origins, directions)
    oracle = Embree(meshes).closest(origins, directions)
    check.check_against_embree(
        hits,
        oracle,
        vertices,
        faces,
        origins,
        directions,
        mesh_offsets=offsets,
        min_agreement=MIN_AGREEMENT,
        min_hits=300,
    )


# (scene, camera inside the bounds?): architecture is seen from inside, objects from outside.
SHARED = [
    ("teapot", False),
    ("bunny", False),
    ("sibenik", True),
    ("conference", True),
    ("dragon", False),
]


@pytest.fixture(scope="module")
def shared_setup(load_shared):
    """Per shared scene: engine scene, Embree oracle, and its rays (random + camera), built once."""
    cache = {}

    def get(name, inside):
        if name not in cache:
            v, f = load_shared(name)
            box = pg.bounds(v, f)
            o1, d1 = pg.random_rays(box, 3000, np.random.default_rng(60), margin=0.0)
            o2, d2 = pg.camera_rays(box, 64, 48, inside=inside)
            rays = np.concatenate([o1, o2]), np.concatenate([d1, d2])
            cache[name] = (v, f, dacrt.Scene([(v, f)]), Embree([(v, f)]), rays)
        return cache[name]

    return get


@pytest.mark.parametrize("name,inside", SHARED)
def test_shared_scene_closest_matches_embree(name, inside, shared_setup):
    v, f, scene, oracle, (origins, directions) = shared_setup(name, inside)
    hits = scene.closest(origins, directions)
    check.check_layout(hits, len(origins))
    check.check_geometry(hits, v, f, origins, directions)
    expected = oracle.closest(origins, directions)
    check.check_against_embree(
        hits, expected, v, f, origins, directions, min_agreement=MIN_AGREEMENT, min_hits=500
    )


@pytest.mark.parametrize("name,inside", SHARED)
def test_shared_scene_occluded_matches_embree(name, inside, shared_setup):
    """Shadow-ray style: per-ray tmax cutting some rays short of their first hit."""
    v, f, scene, oracle, (origins, directions) = shared_setup(name, inside)
    rng = np.random.default_rng(61)
    diag = float(np.linalg.norm(np.ptp(pg.bounds(v, f), axis=0)))
    tmax = rng.uniform(0.0, 0.5 * diag, len(origins)).astype(np.float32)
    occ = scene.occluded(origins, directions, tmax=tmax).occluded
    expected = oracle.occluded(origins, directions, tmax=tmax)
    agree = np.mean(occ == expected)
    assert agree >= MIN_AGREEMENT, f"occluded agrees with Embree on {agree:.5f} of rays"
    assert 0.05 < expected.mean() < 0.95, "vacuous: tmax lets (almost) all or no rays through"
    np.testing.assert_array_equal(occ, np.isfinite(scene.closest(origins, directions, tmax=tmax).t))


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_shared_scene_strategies_match_embree(strategy, shared_setup):
    v, f, scene, oracle, (origins, directions) = shared_setup("sibenik", True)
    hits = scene.closest(origins, directions, strategy=strategy)
    check.check_geometry(hits, v, f, origins, directions)
    check.check_against_embree(
        hits,
        oracle.closest(origins, directions),
        v,
        f,
        origins,
        directions,
        min_agreement=MIN_AGREEMENT,
        min_hits=500,
    )
