"""dacrt.sensors.Lidar without physics options: its rays are bit for bit those of docs/sensors.md's
formulas (re-derived in ``sensor_reference``), its points are ``Scene.closest``'s hits of those
rays (``Scene.hits``' list with return mode ``all``), with the default intensity and label."""

from __future__ import annotations

import numpy as np
import pytest
from sensor_reference import PUBLISHED, lidar_rays
from sensor_scenes import POSES, ROOM

import dacrt
from dacrt.sensors import Lidar


@pytest.fixture(scope="module")
def room():
    return dacrt.Scene(ROOM)


def expected_points(scene, pose, elevations, steps, tmin=0.0, tmax=np.inf):
    """The documented points: closest's hits of the documented rays, intensity 0.5 cos
    exp(-0.004 range), label 0."""
    origins, directions, ring, azimuth, elevation = lidar_rays(pose, elevations, steps)
    hits = scene.closest(origins, directions, tmin, tmax)
    ray = np.flatnonzero(np.isfinite(hits.t))
    d = directions[ray].astype(np.float64)
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    cosine = np.abs((unit * hits.normal[ray]).sum(1)).astype(np.float32)
    t = hits.t[ray]
    return {
        "xyz": origins[ray] + t[:, None] * directions[ray],
        "range": t,
        "ring": ring[ray].astype(np.uint16),
        "azimuth": azimuth[ray].astype(np.float32),
        "elevation": elevation[ray].astype(np.float32),
        "mesh": hits.mesh[ray],
        "prim": hits.prim[ray],
        "return": np.zeros(len(ray), np.int16),
        "cos_incidence": cosine,
        "ray": ray.astype(np.int32),
        "intensity": (0.5 * cosine.astype(np.float64) * np.exp(-0.004 * t)).astype(np.float32),
        "label": np.zeros(len(ray), np.uint32),
    }


def assert_same_points(points, expected):
    assert list(points) == list(expected)
    for name, values in expected.items():
        assert points[name].dtype == values.dtype, name
        if name in ("cos_incidence", "intensity"):  # a dot product's order may differ by an ulp
            np.testing.assert_allclose(points[name], values, rtol=1e-6, atol=1e-7, err_msg=name)
        else:
            np.testing.assert_array_equal(points[name], values, err_msg=name)


@pytest.mark.parametrize("model", list(PUBLISHED))
@pytest.mark.parametrize("pose", range(len(POSES)))
def test_the_rays_are_the_documented_ones_bit_for_bit(model, pose):
    rays = Lidar(model, horizontal_steps=360).shot(POSES[pose]).rays
    origins, directions, *_ = lidar_rays(POSES[pose], PUBLISHED[model], 360)
    assert rays.directions.dtype == np.float32 and rays.directions.flags.c_contiguous
    np.testing.assert_array_equal(rays.directions, directions)
    np.testing.assert_array_equal(rays.origins, origins)


@pytest.mark.parametrize("model", list(PUBLISHED))
@pytest.mark.parametrize("pose", range(len(POSES)))
def test_the_points_are_closest_hits_of_those_rays(room, model, pose):
    points = Lidar(model, horizontal_steps=360).scan(room, POSES[pose])
    expected = expected_points(room, POSES[pose], PUBLISHED[model], 360)
    assert points.n_points > 100
    assert_same_points(points, expected)


def test_explicit_angles_and_the_range_window(room):
    angles = [10.0, -20.0, -5.0, 0.0, -5.0]  # unsorted, with a repeat: rings sort them
    lidar = Lidar(vertical_angles_deg=angles, horizontal_steps=500, min_range=2.0, max_range=7.5)
    points = lidar.scan(room, POSES[1])
    assert_same_points(points, expected_points(room, POSES[1], angles, 500, 2.0, 7.5))
    assert points["range"].min() >= 2.0 and points["range"].max() <= 7.5


def test_return_mode_all_is_the_hit_list(room):
    pose, angles, steps = POSES[0], [-12.0, -4.0, 0.0, 6.0], 256
    points = Lidar(
        vertical_angles_deg=angles, horizontal_steps=steps, return_mode="all", max_returns=3
    ).scan(room, pose)
    origins, directions, *_ = lidar_rays(pose, angles, steps)
    every = room.hits(origins, directions, max_hits=3)
    counts = np.diff(every.offsets)
    assert counts.max() > 1  # some beams cross a ball twice
    ray = np.repeat(np.arange(len(origins)), counts)
    np.testing.assert_array_equal(points["ray"], ray)
    np.testing.assert_array_equal(points["range"], every.t)
    np.testing.assert_array_equal(points["mesh"], every.mesh)
    np.testing.assert_array_equal(points["prim"], every.prim)
    rank = np.arange(len(ray)) - np.repeat(every.offsets[:-1], counts)
    np.testing.assert_array_equal(points["return"], rank)


def test_a_miss_everywhere_is_typed_and_empty():
    scene = dacrt.Scene([(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))])
    points = Lidar("VLP-16", horizontal_steps=8).scan(scene, np.eye(4))
    assert points.n_points == 0
    assert points["xyz"].shape == (0, 3) and points["label"].dtype == np.uint32
