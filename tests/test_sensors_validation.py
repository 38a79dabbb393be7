"""Bad options of dacrt.sensors.Lidar and Materials raise dacrt.InputError naming the key as the
HTTP body of /lidar names it (``noise.range_sigma must be >= 0``), so the service answers 422."""

from __future__ import annotations

import re

import numpy as np
import pytest

import dacrt
from dacrt.sensors import Lidar, Materials, Pattern

BEAMS = {"model": "VLP-16"}


@pytest.mark.parametrize(
    ("options", "words"),
    [
        ({}, "give exactly one beam pattern"),
        ({"model": "VLP-16", "vertical_angles_deg": [0.0]}, "give exactly one beam pattern"),
        ({"model": "VLP-99"}, "model must be one of VLP-16"),
        ({"vertical_angles_deg": []}, "vertical_angles_deg must be a list of 1 to 1024"),
        ({"vertical_angles_deg": [0.0, 95.0]}, "vertical_angles_deg[1] must be in [-90, 90]"),
        ({"vertical_angles_deg": [np.nan]}, "vertical_angles_deg[0] must be in [-90, 90]"),
        ({**BEAMS, "horizontal_steps": 0}, "horizontal_steps must be >= 1"),
        ({**BEAMS, "horizontal_steps": 2.5}, "horizontal_steps must be an integer"),
        ({**BEAMS, "min_range": -1}, "min_range must be >= 0"),
        ({**BEAMS, "min_range": 5, "max_range": 5}, "max_range must be > 5"),
        ({**BEAMS, "min_range": 1e300, "max_range": None}, "min_range must be <= 3.40282e+38"),
        ({**BEAMS, "max_returns": 65}, "max_returns must be >= 1 and <= 64"),
        ({**BEAMS, "return_mode": "second"}, "return_mode must be one of first, last"),
        ({**BEAMS, "beam_divergence_deg": -0.1}, "beam_divergence_deg must be >= 0"),
        ({**BEAMS, "beam_divergence_deg": 180}, "beam_divergence_deg must be < 180"),
        ({**BEAMS, "beam_samples": 0}, "beam_samples must be >= 1 and <= 64"),
        ({**BEAMS, "range_resolution": np.inf}, "range_resolution must be a finite number"),
        ({**BEAMS, "attenuation": -0.004}, "attenuation must be >= 0"),
        ({**BEAMS, "noise": {"range_sigma": -1}}, "noise.range_sigma must be >= 0"),
        (
            {**BEAMS, "noise": {"range_sigma_per_m": "1"}},
            "noise.range_sigma_per_m must be a number",
        ),
        ({**BEAMS, "noise": {"angle_sigma_deg": np.nan}}, "noise.angle_sigma_deg must be a finite"),
        ({**BEAMS, "noise": {"seed": -2}}, "noise.seed must be >= 0"),
        ({**BEAMS, "noise": {"sigma": 1}}, "noise.sigma is not an option"),
        ({**BEAMS, "noise": 0.1}, "noise must be an object"),
        ({**BEAMS, "dropout": {"rate": 1.5}}, "dropout.rate must be <= 1"),
        ({**BEAMS, "dropout": {"min_intensity": -1}}, "dropout.min_intensity must be >= 0"),
        ({**BEAMS, "dropout": {"seed": True}}, "dropout.seed must be an integer"),
        ({**BEAMS, "non_hits": "zero"}, "non_hits must be one of drop, keep"),
        ({**BEAMS, "organized": 1}, "organized must be true or false"),
        ({"pattern": [0.0, 1.0]}, "pattern must be a dacrt.sensors.Pattern"),
    ],
)
def test_a_bad_option_is_refused_naming_its_key(options, words):
    with pytest.raises(dacrt.InputError) as error:
        Lidar(**options)
    assert words in str(error.value)


@pytest.mark.parametrize(
    ("materials", "words"),
    [
        ({"reflectivity": [0.5, 1.2]}, "reflectivity must be in [0, 1], got 1.2"),
        ({"reflectivity": -0.1}, "reflectivity must be in [0, 1]"),
        ({"reflectivity": ["a"]}, "reflectivity must be numbers"),
        ({"label": [-1]}, "label must be in [0, 4294967295]"),
        ({"label": [1.5]}, "label must be integers"),
    ],
)
def test_bad_materials_are_refused_naming_the_key(materials, words):
    with pytest.raises(dacrt.InputError) as error:
        Materials(**materials)
    assert words in str(error.value)


def test_materials_must_have_one_entry_per_mesh():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    scene = dacrt.Scene([(vertices, [[0, 1, 2]])] * 2)
    with pytest.raises(dacrt.InputError, match="reflectivity has 3 entries for a scene of 2"):
        Lidar("VLP-16", horizontal_steps=4).scan(scene, np.eye(4), Materials([0.1, 0.2, 0.3]))


def test_the_default_materials_and_a_scalar_for_every_mesh():
    assert Materials().per_mesh(2)[0].tolist() == [0.5, 0.5]
    reflectivity, label = Materials(0.25, 9).per_mesh(3)
    assert reflectivity.tolist() == [0.25] * 3 and label.tolist() == [9] * 3
    assert label.dtype == np.uint32


def test_a_max_range_beyond_float32_is_no_limit():
    """The rays' windows are float32: a max_range beyond its largest is as if none were given."""
    vertices = np.array([[-1, -1, 5], [1, -1, 5], [0, 1, 5]], np.float32)
    scene = dacrt.Scene([(vertices, [[0, 1, 2]])])
    beyond = Lidar(vertical_angles_deg=[90.0], horizontal_steps=4, max_range=1e300)
    assert beyond.max_range == np.inf
    np.testing.assert_array_equal(
        beyond.scan(scene, np.eye(4))["range"],
        Lidar(vertical_angles_deg=[90.0], horizontal_steps=4).scan(scene, np.eye(4))["range"],
    )


@pytest.mark.parametrize(
    "options", [{"horizontal_steps": 2**27}, {"horizontal_steps": 2**24, "beam_samples": 8}]
)
def test_a_scan_of_more_rays_than_int32_indexes_is_refused_before_any_is_made(options):
    lidar = Lidar("VLP-16", **options)
    assert lidar.n_traced_rays == 2**31
    with pytest.raises(dacrt.InputError, match=r"a scan \(beams x beam_samples\) has 2,147,"):
        lidar.shot(np.eye(4))


def test_max_returns_alone_asks_for_every_return_as_over_http():
    """A /lidar body with max_returns > 1 and no return_mode means ``all``; so does the same
    sensor in process (not ``first``, which would ignore max_returns)."""
    assert Lidar("VLP-16").return_mode == "first"
    assert Lidar("VLP-16", max_returns=3).return_mode == "all"
    assert Lidar("VLP-16", max_returns=3, return_mode="dual").return_mode == "dual"
    walls = [
        (np.array([[x, -50, -50], [x, 50, -50], [x, 0, 50]], np.float32), [[0, 1, 2]])
        for x in (10.0, 12.0)
    ]
    scene = dacrt.Scene(walls)
    points = Lidar(vertical_angles_deg=[0.0], horizontal_steps=8, max_returns=3).scan(
        scene, np.eye(4)
    )
    along_x = points["ray"] == 0  # the beam along +x crosses both walls
    assert points["range"][along_x].tolist() == [10.0, 12.0]
    assert points["return"][along_x].tolist() == [0, 1]


def test_max_returns_of_two_alone_asks_for_every_return():
    """Any max_returns > 1 without a mode is ``all``."""
    lidar = Lidar("VLP-16", max_returns=2)
    assert lidar.return_mode == "all" and lidar.slots == 2


@pytest.mark.parametrize(
    "options",
    [
        {"model": "VLP-16", "max_returns": 64},
        {"model": "VLP-16", "beam_samples": 64},
        {"vertical_angles_deg": list(np.linspace(-90, 90, 1024))},
    ],
)
def test_the_largest_accepted_values_are_accepted(options):
    """The documented upper bounds are inclusive: 64 returns, 64 sub-rays, 1024 beams, +-90
    degrees."""
    Lidar(**options)


@pytest.mark.parametrize(
    ("options", "words"),
    [
        ({"vertical_angles_deg": [0.0] * 1025}, "vertical_angles_deg must be a list of 1 to 1024"),
        ({"model": "VLP-16", "beam_samples": 65}, "beam_samples must be >= 1 and <= 64"),
    ],
)
def test_one_beyond_the_largest_is_refused(options, words):
    with pytest.raises(dacrt.InputError, match=re.escape(words)):
        Lidar(**options)


def test_a_ray_firing_at_the_sweeps_end_is_within_it():
    """time_s up to period_s inclusive is within the sweep."""
    pattern = Pattern([0.0, 90.0], [0.0, 0.0], time_s=[0.0, 0.1])
    lidar = Lidar(pattern=pattern, period_s=0.1)
    assert lidar.period_s == 0.1
    with pytest.raises(dacrt.InputError, match=r"time_s\[1\] is 0.1, beyond period_s"):
        Lidar(pattern=pattern, period_s=0.05)
