"""Sensors over time (``Lidar(period_s=...)``, ``scan(..., pose_end=...)``): each column of a
spinning lidar fires at tau = s / steps of the sweep (a pattern's ray at time_s / period_s), from
the sensor's pose at tau, into the scene at tau; points carry time, velocity and radial_speed.

The references are plain NumPy (slab intersections with a box at tau, a plane's range): nothing
of them comes from dacrt.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from sensor_scenes import box_mesh

import dacrt
from dacrt.sensors import Lidar, Pattern
from dacrt.validation import InputError

PERIOD = 0.1  # seconds a sweep


def translation(offset):
    m = np.eye(4)
    m[:3, 3] = offset
    return m


def yaw_pose(yaw_deg, position=(0.0, 0.0, 0.0)):
    a = math.radians(yaw_deg)
    pose = np.eye(4)
    pose[:3, :3] = [[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]]
    pose[:3, 3] = position
    return pose


def slab_entry(origins, directions, lo, hi):
    """(t_enter, t_exit) float64 of rays against boxes [lo, hi] (each (n, 3))."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - origins) / directions
        t1 = (hi - origins) / directions
    near = np.nanmax(np.minimum(t0, t1), axis=1)
    far = np.nanmin(np.maximum(t0, t1), axis=1)
    return near, far


def spinning_reference(elevations_deg, steps, origins_at, lo_at, hi_at):
    """Per beam (ring-major): tau, direction (float64 unit), and the entry range into the box
    [lo_at(tau), hi_at(tau)] from origins_at(tau) (inf for a miss), and how far the ray passes
    from the box's silhouette (as the slab gap, for skipping grazing beams)."""
    e = np.radians(np.sort(elevations_deg))
    s = np.arange(steps)
    ring, step = np.repeat(np.arange(len(e)), steps), np.tile(s, len(e))
    tau = step / steps
    a = 2 * np.pi * step / steps
    d = np.stack([np.cos(e[ring]) * np.cos(a), np.cos(e[ring]) * np.sin(a), np.sin(e[ring])], 1)
    o = origins_at(tau)
    near, far = slab_entry(o, d, lo_at(tau), hi_at(tau))
    hit = (near <= far) & (far > 0)
    return tau, o, d, np.where(hit, near, np.inf), far - near


def test_a_box_passing_a_spinning_lidar_is_skewed_and_has_its_velocity():
    """A box moving along +x at 20 m/s in front of the lidar's +y side: each column sees it where
    it is at that column's instant; velocity is the box's; radial speed is its part along the
    beam."""
    velocity = np.array([20.0, 0.0, 0.0])
    v, f = box_mesh((-1.0, 9.0, -1.0), (1.0, 11.0, 1.0))
    scene = dacrt.Scene(
        [(v, f)], transforms=[np.eye(4)], transforms_end=[translation(velocity * PERIOD)]
    )
    elevations = [-3.0, 0.0, 3.0]
    steps = 720
    lidar = Lidar(vertical_angles_deg=elevations, horizontal_steps=steps, period_s=PERIOD)
    points = lidar.scan(scene, np.eye(4))
    tau, o, d, want_range, gap = spinning_reference(
        np.array(elevations),
        steps,
        lambda tau: np.zeros((len(tau), 3)),
        lambda tau: np.array([-1.0, 9.0, -1.0]) + np.outer(tau, velocity * PERIOD),
        lambda tau: np.array([1.0, 11.0, 1.0]) + np.outer(tau, velocity * PERIOD),
    )
    clear = np.abs(gap) > 1e-3  # away from the box's silhouette
    got = np.full(len(tau), np.inf)
    got[points["ray"]] = points["range"]
    np.testing.assert_array_equal(np.isfinite(got)[clear], np.isfinite(want_range)[clear])
    both = np.isfinite(got) & np.isfinite(want_range)
    np.testing.assert_allclose(got[both], want_range[both], rtol=1e-5)
    assert both.sum() > 50
    # The skew: the box was seen over a spread of instants, and each point lies on the box as it
    # was at its beam's instant.
    ray = points["ray"]
    np.testing.assert_allclose(points["time"], tau[ray] * PERIOD, rtol=1e-6)
    assert np.ptp(points["time"]) > 0.03 * PERIOD  # the box spans about 12 degrees
    want_xyz = o[ray] + want_range[ray, None] * d[ray]
    np.testing.assert_allclose(points["xyz"], want_xyz, atol=1e-4)
    np.testing.assert_allclose(points["velocity"], np.tile(velocity, (len(ray), 1)), atol=1e-3)
    np.testing.assert_allclose(points["radial_speed"], d[ray] @ velocity, atol=1e-3)
    # The same scan without motion sees the box where it starts.
    still = Lidar(vertical_angles_deg=elevations, horizontal_steps=steps).scan(scene, np.eye(4))
    assert "velocity" not in still
    assert still["xyz"][:, 0].max() < 1.0 + 1e-4 < points["xyz"][:, 0].max()


def test_a_moving_sensor_fires_each_column_from_where_it_is():
    """The lidar moves along +x at 10 m/s past a wall y = 10: beams start from the sensor's
    position at their instant and the static wall's radial speed is minus the sensor's speed
    along the beam."""
    speed = 10.0
    v, f = box_mesh((-50.0, 10.0, -5.0), (50.0, 11.0, 5.0))
    scene = dacrt.Scene([(v, f)])
    steps = 360
    lidar = Lidar(vertical_angles_deg=[0.0], horizontal_steps=steps, period_s=PERIOD)
    start, end = np.eye(4), translation((speed * PERIOD, 0.0, 0.0))
    points = lidar.scan(scene, start, pose_end=end)
    ray = points["ray"]
    tau = ray / steps
    a = 2 * np.pi * ray / steps
    origin_x = speed * PERIOD * tau
    np.testing.assert_allclose(points["range"], 10.0 / np.sin(a), rtol=1e-5)
    np.testing.assert_allclose(points["xyz"][:, 0], origin_x + 10.0 / np.tan(a), atol=1e-4)
    np.testing.assert_allclose(points["xyz"][:, 1], 10.0, atol=1e-4)
    np.testing.assert_allclose(points["velocity"], 0.0, atol=1e-6)
    np.testing.assert_allclose(points["radial_speed"], -speed * np.cos(a), atol=1e-4)


@pytest.mark.parametrize("sensor", ["spinning", "pattern"])
def test_the_radial_speed_of_a_receding_plane_is_its_speed(sensor):
    speed = 3.0
    v, f = box_mesh((10.0, -20.0, -20.0), (11.0, 20.0, 20.0))
    scene = dacrt.Scene(
        [(v, f)], transforms=[np.eye(4)], transforms_end=[translation((speed * PERIOD, 0, 0))]
    )
    if sensor == "spinning":
        lidar = Lidar(vertical_angles_deg=[0.0], horizontal_steps=8, period_s=PERIOD)
        fired = 0.0  # column 0 (azimuth 0) fires at the start
    else:
        pattern = Pattern(azimuth_deg=[0.0], elevation_deg=[0.0], time_s=[0.05])
        lidar = Lidar(pattern=pattern, period_s=PERIOD)
        fired = 0.05
    points = lidar.scan(scene, np.eye(4))
    along = np.flatnonzero(points["ray"] == 0)[0]
    assert points["radial_speed"][along] == pytest.approx(speed, rel=1e-5)
    assert points["range"][along] == pytest.approx(10.0 + speed * fired, rel=1e-6)
    assert points["time"][along] == pytest.approx(fired)


def test_a_turning_sensor_aims_each_column_by_the_slerped_rotation():
    """A yaw of 0 to 90 degrees over the sweep: column s's beam at azimuth a points at
    a + 90 tau in the scene (the slerp of a rotation about one axis is linear in its angle)."""
    steps = 16
    lidar = Lidar(vertical_angles_deg=[0.0, 10.0], horizontal_steps=steps, period_s=PERIOD)
    rays = lidar.shot(yaw_pose(0.0), yaw_pose(90.0, (1.0, 2.0, 0.0))).rays
    ring, step = np.divmod(np.arange(2 * steps), steps)
    tau = step / steps
    heading = 2 * np.pi * step / steps + np.radians(90.0) * tau
    e = np.radians([0.0, 10.0])[ring]
    want = np.stack([np.cos(e) * np.cos(heading), np.cos(e) * np.sin(heading), np.sin(e)], 1)
    np.testing.assert_allclose(rays.directions, want, atol=1e-6)
    np.testing.assert_allclose(rays.origins, np.outer(tau, [1.0, 2.0, 0.0]), atol=1e-6)
    np.testing.assert_array_equal(rays.time, tau.astype(np.float32))


def test_organized_points_over_time_fill_empty_cells():
    v, f = box_mesh((5.0, -1.0, -1.0), (6.0, 1.0, 1.0))
    scene = dacrt.Scene([(v, f)], transforms_end=[translation((1.0, 0.0, 0.0))])
    lidar = Lidar(vertical_angles_deg=[0.0], horizontal_steps=32, period_s=PERIOD, organized=True)
    points = lidar.scan(scene, np.eye(4))
    assert points["velocity"].shape == (1, 32, 3)
    assert np.isnan(points["velocity"][0, 16]).all()  # backwards: nothing there
    np.testing.assert_allclose(points["velocity"][0, 0], [1.0 / PERIOD, 0.0, 0.0], rtol=1e-5)
    np.testing.assert_allclose(points["time"][0], np.arange(32) / 32 * PERIOD, rtol=1e-6)


def test_a_rig_passes_each_lidar_its_end_pose():
    v, f = box_mesh((-50.0, 10.0, -5.0), (50.0, 11.0, 5.0))
    scene = dacrt.Scene([(v, f)])
    lidar = Lidar(vertical_angles_deg=[0.0], horizontal_steps=64, period_s=PERIOD)
    end = translation((1.0, 0.0, 0.0))
    alone = lidar.scan(scene, np.eye(4), pose_end=end)
    rig = dacrt.sensors.Rig({"roof": lidar, "still": Lidar(model="VLP-16")})
    both = rig.capture(scene, {"roof": np.eye(4), "still": np.eye(4)}, poses_end={"roof": end})
    for name in ("xyz", "range", "velocity", "radial_speed", "time"):
        np.testing.assert_array_equal(both["roof"][name], alone[name])
    with pytest.raises(InputError, match="poses_end.nobody"):
        rig.capture(scene, {"roof": np.eye(4), "still": np.eye(4)}, poses_end={"nobody": end})


BAD = {
    "period not positive": (lambda: Lidar(model="VLP-16", period_s=0.0), "period_s"),
    "period under a microsecond": (
        lambda: Lidar(model="VLP-16", period_s=5e-324),
        r"period_s must be >= 1e-06",
    ),
    "pattern without times": (
        lambda: Lidar(pattern=Pattern(azimuth_deg=[0.0], elevation_deg=[0.0]), period_s=0.1),
        "time_s",
    ),
    "pattern beyond the period": (
        lambda: Lidar(
            pattern=Pattern(azimuth_deg=[0.0, 1.0], elevation_deg=[0.0, 0.0], time_s=[0, 0.2]),
            period_s=0.1,
        ),
        r"time_s\[1\] is 0\.2, beyond period_s \(0\.1\)",
    ),
    "end pose without period": (
        lambda: Lidar(model="VLP-16").shot(np.eye(4), np.eye(4)),
        "pose_end needs period_s",
    ),
    "a speed beyond float32": (
        lambda: Lidar(model="VLP-16", period_s=0.1).shot(np.eye(4), translation(3e38)),
        "pose_end: a move of 3e[+]38 in period_s [(]0.1[)] is a speed beyond float32",
    ),
    "end pose not rigid": (
        lambda: Lidar(model="VLP-16", period_s=0.1).shot(np.eye(4), np.diag([2.0, 1, 1, 1])),
        "pose_end",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_motion_options_are_input_errors_naming_them(case):
    make, words = BAD[case]
    with pytest.raises(ValueError, match=words):
        make()


def test_points_in_the_sensor_frame_at_the_sweep_start():
    """frame="sensor": xyz and velocity are the scene's moved into the start pose's frame."""
    v, f = box_mesh((-50.0, 10.0, -5.0), (50.0, 11.0, 5.0))
    scene = dacrt.Scene([(v, f)], transforms_end=[translation((0.0, 1.0, 0.0))])
    start = yaw_pose(30.0, (1.0, 2.0, 0.5))
    end = yaw_pose(40.0, (2.0, 2.0, 0.5))
    options = dict(vertical_angles_deg=[0.0, 2.0], horizontal_steps=90, period_s=PERIOD)
    scene_points = Lidar(**options).scan(scene, start, pose_end=end)
    sensor_points = Lidar(**options, frame="sensor").scan(scene, start, pose_end=end)
    r, t = start[:3, :3], start[:3, 3]
    np.testing.assert_allclose(sensor_points["xyz"], (scene_points["xyz"] - t) @ r, atol=1e-4)
    np.testing.assert_allclose(sensor_points["velocity"], scene_points["velocity"] @ r, atol=1e-5)
    np.testing.assert_array_equal(sensor_points["radial_speed"], scene_points["radial_speed"])
    with pytest.raises(InputError, match="frame"):
        Lidar(model="VLP-16", frame="vehicle")
