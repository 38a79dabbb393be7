"""dacrt.sensors.Pattern: a pattern that lists a spinning lidar's rays scans what that lidar
scans; time_s and channel travel to the points; a pattern survives its .npz file."""

from __future__ import annotations

import io

import numpy as np
import pytest
from sensor_reference import PUBLISHED, lidar_rays, rigid_pose
from sensor_scenes import ROOM

import dacrt
from dacrt.sensors import Lidar, Pattern

POSE = rigid_pose(35, -10, (-2.0, -1.0, 1.8))


def spinning_pattern(steps: int, with_time: bool) -> Pattern:
    """The VLP-16's revolution as a pattern: ray ring * steps + step, channel = ring."""
    _, _, ring, azimuth, elevation = lidar_rays(POSE, PUBLISHED["VLP-16"], steps)
    time = np.tile(np.arange(steps), 16) / steps * 0.1 if with_time else None
    return Pattern(np.degrees(azimuth), np.degrees(elevation), time, ring.astype(np.uint16))


def test_a_pattern_equals_the_lidar_whose_rays_it_lists():
    scene = dacrt.Scene(ROOM)
    spinning = Lidar("VLP-16", horizontal_steps=180).scan(scene, POSE)
    listed = Lidar(pattern=spinning_pattern(180, False)).scan(scene, POSE)
    assert listed.n_points == spinning.n_points > 500
    for name in ("ring", "ray", "mesh", "return", "label"):
        np.testing.assert_array_equal(listed[name], spinning[name], err_msg=name)
    for name in ("range", "azimuth", "elevation", "cos_incidence", "intensity"):
        np.testing.assert_allclose(listed[name], spinning[name], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(listed["xyz"], spinning["xyz"], atol=1e-4)
    assert "time" not in listed


def test_time_and_channel_reach_the_points():
    scene = dacrt.Scene(ROOM)
    pattern = spinning_pattern(90, True)
    points = Lidar(pattern=pattern, non_hits="keep").scan(scene, POSE)
    np.testing.assert_array_equal(points["time"], pattern.time_s.astype(np.float32))
    np.testing.assert_array_equal(points["ring"], pattern.channel)


def test_a_pattern_without_channels_is_ring_zero():
    pattern = Pattern([0.0, 90.0, 180.0], [-10.0, -10.0, -10.0])
    points = Lidar(pattern=pattern, non_hits="keep").scan(dacrt.Scene(ROOM), POSE)
    np.testing.assert_array_equal(points["ring"], [0, 0, 0])


def test_a_pattern_survives_its_npz_file():
    pattern = spinning_pattern(16, True)
    buffer = io.BytesIO()
    pattern.save(buffer)
    buffer.seek(0)
    loaded = Pattern.load(buffer)
    for name in ("azimuth_deg", "elevation_deg", "time_s", "channel"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(pattern, name))


@pytest.mark.parametrize(
    ("arguments", "words"),
    [
        (([0.0, 1.0], [0.0, 91.0]), "elevation_deg[1] must be in [-90, 90]"),
        (([0.0, np.nan], [0.0, 1.0]), "azimuth_deg[1] must be a finite number"),
        (([1e308], [0.0]), "azimuth_deg[0] must be a finite number within float32"),
        (([0.0, 1.0], [0.0, 0.0], [0.0, 1e39]), "time_s[1] must be a finite number within"),
        (([0.0, 1.0], [0.0]), "elevation_deg has 1 rays and azimuth_deg 2"),
        (([], []), "azimuth_deg must be a list of numbers"),
        (([0.0], [0.0], [-1.0]), "time_s[0] must be >= 0"),
        (([0.0], [0.0], None, [70000]), "channel[0] must be in [0, 65535]"),
        (([0.0], [0.0], None, [0.5]), "channel must hold integers"),
    ],
)
def test_a_bad_pattern_is_refused_naming_its_key(arguments, words):
    with pytest.raises(dacrt.InputError) as error:
        Pattern(*arguments)
    assert words in str(error.value)


def test_an_organized_pattern_is_refused():
    with pytest.raises(dacrt.InputError, match="organized"):
        Lidar(pattern=Pattern([0.0], [0.0]), organized=True)


def _npz(**arrays) -> io.BytesIO:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    return buffer


def _npy(array) -> io.BytesIO:
    buffer = io.BytesIO()
    np.save(buffer, array)
    buffer.seek(0)
    return buffer


@pytest.mark.parametrize(
    ("file", "words"),
    [
        (io.BytesIO(b"garbage"), "a pattern file is an .npz archive"),
        (io.BytesIO(b"PK\x03\x04 not a zip"), "File is not a zip file"),
        (io.BytesIO(b""), "a pattern file is an .npz archive"),
        (_npy(np.arange(3.0)), "got one array"),
        (_npz(azimuth_deg=np.array([0.0, "a"], object), elevation_deg=[0.0, 0.0]), "Object"),
        (_npz(azimuth_deg=[0.0]), "a pattern needs elevation_deg"),
        (_npz(azimuth_deg=[0.0], elevation_deg=[0.0], colour=[1]), "colour is not a key"),
    ],
)
def test_a_bad_pattern_file_is_refused(file, words):
    with pytest.raises(dacrt.InputError) as error:
        Pattern.load(file)
    assert words in str(error.value)


def test_the_extreme_elevations_and_channel_are_accepted():
    """Elevation in [-90, 90] and channel in [0, 65535] are inclusive."""
    pattern = Pattern([0.0, 0.0, 0.0], [-90.0, 90.0, 0.0], channel=[0, 65535, 7])
    assert pattern.channel.tolist() == [0, 65535, 7] and pattern.channel.dtype == np.uint16
    with pytest.raises(dacrt.InputError, match=r"elevation_deg\[0\] must be in \[-90, 90\]"):
        Pattern([0.0], [90.5])
    with pytest.raises(dacrt.InputError, match=r"channel\[0\] must be in \[0, 65535\]"):
        Pattern([0.0], [0.0], channel=[65536])
