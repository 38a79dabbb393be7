"""The physics of dacrt.sensors.Lidar, each option against a plain-NumPy build of the rule that
docs/sensors.md states (``sensor_reference``): intensity on a plane at a known angle, the returns
of a beam across an edge, beam sub-rays, seeded noise, dropout, kept non-hits, organized arrays."""

from __future__ import annotations

import math

import numpy as np
import pytest
import sensor_reference as ref

import dacrt
from dacrt.sensors import Lidar, Materials, physics


def quad(corner, side_a, side_b):
    """(vertices, faces) of the parallelogram corner + s a + r b, normal a x b."""
    corner, a, b = (np.asarray(v, np.float64) for v in (corner, side_a, side_b))
    vertices = np.array([corner, corner + a, corner + a + b, corner + b], np.float32)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


FLOOR = quad((-500, -500, 0), (1000, 0, 0), (0, 1000, 0))
WALL = quad((20, -500, -500), (0, 1000, 0), (0, 0, 1000))  # x = 20, facing -x


def level_pose(height=0.0):
    pose = np.eye(4)
    pose[2, 3] = height
    return pose


@pytest.mark.parametrize("angle", [7.5, 30.0, 62.0])
@pytest.mark.parametrize("reflectivity", [0.8, 1.0])
def test_a_plane_at_a_known_angle_gives_the_intensity_formula(angle, reflectivity):
    height, attenuation = 2.0, 0.01
    scene = dacrt.Scene([FLOOR])
    lidar = Lidar(vertical_angles_deg=[-angle], horizontal_steps=16, attenuation=attenuation)
    points = lidar.scan(scene, level_pose(height), Materials(reflectivity=[reflectivity], label=7))
    assert points.n_points == 16
    distance = height / math.sin(math.radians(angle))
    expected = ref.intensity(reflectivity, math.sin(math.radians(angle)), distance, attenuation)
    np.testing.assert_allclose(points["range"], distance, rtol=1e-6)
    np.testing.assert_allclose(points["cos_incidence"], math.sin(math.radians(angle)), rtol=1e-6)
    np.testing.assert_allclose(points["intensity"], expected, rtol=2e-6)
    np.testing.assert_array_equal(points["label"], np.full(16, 7, np.uint32))
    # each point's intensity is the formula of its own float32 cos_incidence and range
    own = reflectivity * points["cos_incidence"].astype(np.float64)
    own *= np.exp(-attenuation * points["range"].astype(np.float64))
    np.testing.assert_array_equal(points["intensity"], own.astype(np.float32))


def test_materials_go_by_mesh_index():
    scene = dacrt.Scene([FLOOR, WALL])
    lidar = Lidar(vertical_angles_deg=[-10.0, 10.0], horizontal_steps=4)
    points = lidar.scan(scene, level_pose(1.0), Materials(reflectivity=[0.2, 0.9], label=[3, 11]))
    for mesh, (reflectivity, label) in enumerate([(0.2, 3), (0.9, 11)]):
        mine = points["mesh"] == mesh
        assert mine.any()
        assert (points["label"][mine] == label).all()
        own = reflectivity * points["cos_incidence"][mine].astype(np.float64)
        own *= np.exp(-0.004 * points["range"][mine].astype(np.float64))
        np.testing.assert_array_equal(points["intensity"][mine], own.astype(np.float32))


# A beam along +x at the sensor's height: a near plate at x = 10 covers y < 0.05, a far wall at
# x = 12 everything; sub-rays left of y = 0.05 end on the plate, the others on the wall.
PLATE = ((10.0, -5.0, -5.0), (0.0, 5.05, 0.0), (0.0, 0.0, 10.0))
FAR_WALL = ((12.0, -50.0, -50.0), (0.0, 100.0, 0.0), (0.0, 0.0, 100.0))
EDGE_LIDAR = dict(
    vertical_angles_deg=[0.0], horizontal_steps=1, beam_divergence_deg=4.0, beam_samples=7
)


def edge_returns(reflectivities, see_through):
    """The reference returns [(t, mesh, intensity)] of the edge beam: each sub-ray ends on the
    nearer surface it crosses (or crosses both, ``see_through``)."""
    hits = []
    for k, direction in enumerate(ref.subray_directions(np.eye(4), 0.0, 0.0, 4.0, 7)):
        direction = direction.astype(np.float32).astype(np.float64)
        crossed = []
        for mesh, surface in enumerate((PLATE, FAR_WALL)):
            t, normal = ref.hit_rectangle(np.zeros(3), direction, *surface)
            if math.isfinite(t):
                cosine = abs(np.dot(normal, direction)) / np.linalg.norm(direction)
                crossed.append((t, k, mesh, ref.intensity(reflectivities[mesh], cosine, t, 0.004)))
        hits.extend(sorted(crossed) if see_through else sorted(crossed)[:1])
    return ref.beam_returns(hits, 7, 0.1)


@pytest.mark.parametrize("mode", ["first", "last", "strongest", "dual", "all"])
@pytest.mark.parametrize("reflectivities", [(1.0, 0.05), (0.05, 1.0)])
def test_a_beam_across_an_edge_gives_two_returns_and_each_mode_picks_right(mode, reflectivities):
    scene = dacrt.Scene([quad(*PLATE), quad(*FAR_WALL)])
    lidar = Lidar(**EDGE_LIDAR, return_mode=mode, max_returns=4)
    points = lidar.scan(scene, np.eye(4), Materials(reflectivity=list(reflectivities)))
    returns = edge_returns(reflectivities, see_through=mode == "all")
    assert len(returns) == 2
    assert [mesh for _, mesh, _ in returns] == [0, 1]
    assert abs(returns[0][0] - 10) < 0.02 and abs(returns[1][0] - 12) < 0.02
    picked = ref.pick_returns(returns, mode, 4)
    np.testing.assert_array_equal(points["mesh"], [returns[k][1] for k in picked])
    np.testing.assert_array_equal(points["return"], picked)
    np.testing.assert_allclose(points["range"], [returns[k][0] for k in picked], rtol=1e-6)
    np.testing.assert_allclose(points["intensity"], [returns[k][2] for k in picked], rtol=1e-5)
    # a point lies along the beam's nominal direction (+x) at its range
    np.testing.assert_array_equal(points["xyz"][:, 0], points["range"])
    assert not points["xyz"][:, 1:].any()


def test_the_sub_rays_are_the_documented_spiral():
    pose = ref.rigid_pose(20, -5, (1.0, 2.0, 3.0))
    lidar = Lidar(vertical_angles_deg=[-7.0, 3.0], horizontal_steps=5, beam_divergence_deg=1.5,
                  beam_samples=9)  # fmt: skip
    directions = lidar.shot(pose).rays.directions.reshape(10, 9, 3)
    _, axes, ring, azimuth, elevation = ref.lidar_rays(pose, [-7.0, 3.0], 5)
    for beam in range(10):
        expected = ref.subray_directions(pose, azimuth[beam], elevation[beam], 1.5, 9)
        np.testing.assert_array_equal(directions[beam, 0], axes[beam])  # the axis itself
        np.testing.assert_allclose(directions[beam], expected, atol=1e-7)
        spread = np.degrees(np.arccos(np.clip(expected @ expected[0], -1, 1)))
        assert spread.max() == pytest.approx(0.75)  # the last sub-ray on the cone's edge


def test_sub_rays_without_divergence_change_no_point():
    scene = dacrt.Scene([FLOOR, WALL])
    options = dict(vertical_angles_deg=[-20.0, -3.0, 4.0], horizontal_steps=64)
    alone = Lidar(**options).scan(scene, level_pose(1.5))
    sampled = Lidar(**options, beam_samples=7).scan(scene, level_pose(1.5))
    for name in alone:
        if name == "intensity":  # a sum of 7 equal terms / 7
            np.testing.assert_allclose(sampled[name], alone[name], rtol=1e-6)
        else:
            np.testing.assert_array_equal(sampled[name], alone[name], err_msg=name)


WALL_LIDAR = dict(vertical_angles_deg=list(np.linspace(-30, 30, 32)), horizontal_steps=256)


def wall_scene():
    return dacrt.Scene([WALL])


def test_range_noise_follows_the_documented_rule_and_sigma():
    scene = wall_scene()
    exact = Lidar(**WALL_LIDAR).scan(scene, level_pose())
    noise = {"range_sigma": 0.05, "range_sigma_per_m": 0.01, "seed": 7}
    noisy = Lidar(**WALL_LIDAR, noise=noise).scan(scene, level_pose())
    assert noisy.n_points == exact.n_points > 2000
    expected = ref.noisy_ranges(exact["range"], 0.05, 0.01, 7)
    np.testing.assert_array_equal(noisy["range"], expected)
    for name in ("mesh", "prim", "ray", "intensity", "cos_incidence"):
        np.testing.assert_array_equal(noisy[name], exact[name])  # only the range moves
    nominal = Lidar(**WALL_LIDAR).shot(level_pose()).rays.directions
    np.testing.assert_array_equal(noisy["xyz"], noisy["range"][:, None] * nominal[noisy["ray"]])
    r = exact["range"].astype(np.float64)
    z = (noisy["range"] - r) / (0.05 + 0.01 * r)
    assert abs(z.mean()) < 0.1 and 0.9 < z.std() < 1.1


def test_a_noisy_range_beyond_float32_is_no_return():
    """Noise of an accepted (finite) sigma can throw a range past float32's largest: that beam
    returns nothing, as a hit beyond float32's range is a miss, and every point stays finite."""
    scene = wall_scene()
    exact = Lidar(**WALL_LIDAR).scan(scene, level_pose())
    noise = {"range_sigma_per_m": 3e37, "seed": 3}
    noisy = Lidar(**WALL_LIDAR, noise=noise).scan(scene, level_pose())
    expected = ref.noisy_ranges(exact["range"], 0.0, 3e37, 3)
    returned = ~np.isnan(expected)
    assert 0 < returned.sum() < len(expected)  # some beyond, some within
    np.testing.assert_array_equal(noisy["range"], expected[returned])
    np.testing.assert_array_equal(noisy["ray"], exact["ray"][returned])
    assert np.isfinite(noisy["xyz"]).all()


def test_the_same_seed_gives_the_same_points_and_another_seed_others():
    scene = wall_scene()

    def scan(seed):
        noise = {"range_sigma": 0.02, "angle_sigma_deg": 0.1, "seed": seed}
        return Lidar(**WALL_LIDAR, noise=noise).scan(scene, level_pose())

    first, again, other = scan(1), scan(1), scan(2)
    for name in first:
        np.testing.assert_array_equal(first[name], again[name])
    assert not np.array_equal(first["range"], other["range"])


def test_angle_noise_turns_each_beam_by_the_documented_deviates():
    sigma, seed = 0.5, 3
    lidar = Lidar(**WALL_LIDAR, noise={"angle_sigma_deg": sigma, "seed": seed})
    rays = lidar.shot(level_pose()).rays
    _, nominal, _, azimuth, elevation = ref.lidar_rays(
        level_pose(), WALL_LIDAR["vertical_angles_deg"], 256
    )
    offsets = np.random.default_rng(seed).normal(0.0, math.radians(sigma), (len(azimuth), 2))
    _, expected = ref.angle_rays(level_pose(), azimuth + offsets[:, 0], elevation + offsets[:, 1])
    np.testing.assert_array_equal(rays.directions, expected)
    # statistically: the turn of a level beam has mean square 2 sigma^2
    level = np.abs(elevation) < math.radians(3)
    turn = np.arccos(np.clip((rays.directions[level] * nominal[level]).sum(1), -1, 1))
    assert 0.85 < np.mean(turn**2) / (2 * math.radians(sigma) ** 2) < 1.15
    # a point is reported along its beam's nominal direction
    points = lidar.scan(wall_scene(), level_pose())
    np.testing.assert_array_equal(points["xyz"], points["range"][:, None] * nominal[points["ray"]])


def test_dropout_by_rate_and_by_intensity_follows_the_documented_rule():
    scene = wall_scene()
    full = Lidar(**WALL_LIDAR).scan(scene, level_pose())
    threshold = float(np.median(full["intensity"]))
    dropped = Lidar(**WALL_LIDAR, dropout={"rate": 0.3, "min_intensity": threshold, "seed": 5})
    points = dropped.scan(scene, level_pose())
    kept = ref.kept_by_dropout(full["intensity"], 0.3, threshold, 5)
    for name in full:
        np.testing.assert_array_equal(points[name], full[name][kept], err_msg=name)
    assert (points["intensity"] >= threshold).all()
    rate_only = Lidar(**WALL_LIDAR, dropout={"rate": 0.3}).scan(scene, level_pose())
    n = full.n_points
    lost = 1 - rate_only.n_points / n
    assert abs(lost - 0.3) < 5 * math.sqrt(0.3 * 0.7 / n)


def test_non_hits_kept_are_points_of_the_fill_values():
    scene = dacrt.Scene([FLOOR])
    options = dict(model="VLP-16", horizontal_steps=32)
    hits = Lidar(**options).scan(scene, level_pose(1.0))
    every = Lidar(**options, non_hits="keep").scan(scene, level_pose(1.0))
    assert every.n_points == 16 * 32
    np.testing.assert_array_equal(every["ray"], np.arange(16 * 32))
    miss = ~np.isfinite(every["range"])
    assert miss.sum() == 8 * 32  # the upper eight rings see nothing
    assert (every["mesh"][miss] == -1).all() and (every["prim"][miss] == -1).all()
    assert np.isnan(every["xyz"][miss]).all() and (every["intensity"][miss] == 0).all()
    assert (every["return"][miss] == -1).all() and (every["label"][miss] == 0).all()
    np.testing.assert_array_equal(every["ring"], np.repeat(np.arange(16), 32))
    for name in hits:
        np.testing.assert_array_equal(every[name][~miss], hits[name], err_msg=name)


@pytest.mark.parametrize(
    ("options", "shape"),
    [
        ({}, (16, 32)),
        ({"return_mode": "dual", "beam_divergence_deg": 3.0, "beam_samples": 7}, (16, 32, 2)),
        ({"return_mode": "all", "max_returns": 3}, (16, 32, 3)),
    ],
)
def test_organized_answers_have_the_documented_shapes_and_fill(options, shape):
    scene = dacrt.Scene([FLOOR, quad((6, -50, -50), (0, 100, 0), (0, 0, 3))])
    listed = Lidar("VLP-16", horizontal_steps=32, **options).scan(scene, level_pose(1.0))
    grid = Lidar("VLP-16", horizontal_steps=32, organized=True, **options).scan(
        scene, level_pose(1.0)
    )
    assert grid.organized
    for name in grid:
        extra = (3,) if name == "xyz" else ()
        assert grid[name].shape == shape + extra, name
    cells = grid["ring"].reshape(16, 32, -1)
    np.testing.assert_array_equal(cells, np.broadcast_to(np.arange(16)[:, None, None], cells.shape))
    rays = grid["ray"].reshape(16, 32, -1)
    np.testing.assert_array_equal(rays[..., 0], np.arange(16 * 32).reshape(16, 32))
    filled = ~np.isfinite(grid["range"])
    assert filled.any()
    assert (grid["mesh"][filled] == -1).all() and np.isnan(grid["xyz"][filled]).all()
    assert (grid["intensity"][filled] == 0).all() and (grid["return"][filled] == -1).all()
    for name in listed:  # the filled cells hold the list's points, in order
        np.testing.assert_array_equal(grid[name][~filled], listed[name], err_msg=name)


def test_a_label_of_the_largest_uint32_is_a_label():
    """Labels are uint32: 2**32 - 1 is a label."""
    largest = int(np.iinfo(np.uint32).max)
    _, label = Materials(label=[largest, 0]).per_mesh(2)
    assert label.tolist() == [largest, 0] and label.dtype == np.uint32
    with pytest.raises(dacrt.InputError, match="label must be in"):
        Materials(label=[largest + 1])


def test_cos_incidence_is_at_most_one_when_the_float32_direction_is_a_little_long():
    """A float32 direction is unit only up to rounding: |n . d| can come out above 1, and the
    documented value is min(|n . d|, 1)."""
    long = np.float32(1) + np.finfo(np.float32).eps
    directions = np.array([[long, 0, 0], [0, -long, 0], [0.6, 0.8, 0]], np.float32)
    normal = np.array([[1, 0, 0], [0, 1, 0], [1, 0, 0]], np.float32)
    cosine = physics.cos_incidence(directions, normal)
    assert cosine.dtype == np.float32
    np.testing.assert_array_equal(cosine, np.array([1, 1, 0.6], np.float32))


def test_a_range_resolution_of_zero_still_merges_hits_at_the_same_range():
    """Sub-rays of a beam without divergence hit at one range: a return goes on while each hit is
    *within* range_resolution of the one before, so even 0 makes them one return."""
    scene = wall_scene()
    options = dict(vertical_angles_deg=[-3.0, 4.0], horizontal_steps=16)
    alone = Lidar(**options).scan(scene, level_pose())
    sampled = Lidar(**options, beam_samples=4, range_resolution=0.0, max_returns=4).scan(
        scene, level_pose()
    )
    assert alone.n_points > 0
    np.testing.assert_array_equal(sampled["ray"], alone["ray"])
    np.testing.assert_array_equal(sampled["return"], np.zeros(alone.n_points, np.int16))
    np.testing.assert_allclose(sampled["intensity"], alone["intensity"], rtol=1e-6)


def _returns(intensity, beam=None):
    n = len(intensity)
    beam = np.zeros(n, np.int64) if beam is None else np.asarray(beam, np.int64)
    rank = np.concatenate([np.arange(k) for k in np.bincount(beam)]).astype(np.int64)
    return physics.Returns(np.arange(n), beam, rank, np.asarray(intensity, np.float64))


def test_strongest_of_equally_intense_returns_is_the_nearest():
    """Mode strongest (and dual) keeps the nearest of equals."""
    returns = _returns([0.2, 0.5, 0.5, 0.5, 0.1], beam=[0, 0, 0, 1, 1])
    assert physics.select_returns(returns, "strongest", 1).tolist() == [0, 1, 0, 1, 0]
    assert physics.select_returns(returns, "dual", 2).tolist() == [0, 1, 1, 1, 1]


def test_mode_all_keeps_the_nearest_max_returns_of_a_beam():
    """Several sub-rays can make more returns than max_returns: ``all`` keeps the nearest
    max_returns."""
    returns = _returns([0.1, 0.2, 0.3, 0.4, 0.5], beam=[0, 0, 0, 1, 1])
    assert physics.select_returns(returns, "all", 2).tolist() == [1, 1, 0, 1, 1]
    assert physics.select_returns(returns, "all", 1).tolist() == [1, 0, 0, 1, 0]


def test_dropout_keeps_a_point_whose_intensity_is_min_intensity():
    """A point is kept when intensity >= min_intensity."""
    scene = wall_scene()
    full = Lidar(**WALL_LIDAR).scan(scene, level_pose())
    threshold = float(np.sort(full["intensity"])[len(full["intensity"]) // 2])  # a point's own
    points = Lidar(**WALL_LIDAR, dropout={"min_intensity": threshold}).scan(scene, level_pose())
    kept = full["intensity"] >= np.float32(threshold)
    assert (full["intensity"] == np.float32(threshold)).any()
    np.testing.assert_array_equal(points["ray"], full["ray"][kept])


def test_dropout_keeps_a_point_whose_deviate_equals_the_rate():
    """A point is kept when its uniform deviate u >= rate."""
    scene = wall_scene()
    full = Lidar(**WALL_LIDAR).scan(scene, level_pose())
    u = np.random.default_rng(11).random(full.n_points)
    rate = float(u.min())  # every point's u is at least the rate: all are kept
    points = Lidar(**WALL_LIDAR, dropout={"rate": rate, "seed": 11}).scan(scene, level_pose())
    assert points.n_points == full.n_points
    np.testing.assert_array_equal(points["ray"], full["ray"])
