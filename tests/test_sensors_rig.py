"""dacrt.sensors.Rig: several sensors traced as one batch answer bit for bit what each answers
alone."""

from __future__ import annotations

import numpy as np
import pytest
from sensor_reference import rigid_pose
from sensor_scenes import POSES, ROOM

import dacrt
from dacrt.sensors import Camera, Lidar, Materials, Rig, look_at_pose
from dacrt.sensors.batch import batch_stats

SENSORS = {
    "roof": Lidar("VLP-16", horizontal_steps=120, return_mode="dual", beam_divergence_deg=2.0,
                  beam_samples=7, noise={"range_sigma": 0.01, "angle_sigma_deg": 0.05},
                  dropout={"rate": 0.1, "seed": 3}),
    "front": Camera.from_fov(40, 30, fov_deg=50, near=0.5),
    "bumper": Lidar(vertical_angles_deg=[-5.0, 0.0, 5.0], horizontal_steps=200,
                    return_mode="all", max_returns=3, min_range=0.3, max_range=9.0),
    "side": Camera(32, 24, fx=30.0, fy=31.0, cx=15.0, cy=12.5, far=20.0),
    "grid": Lidar("VLP-16", horizontal_steps=60, organized=True),
}  # fmt: skip
POSE_OF = {
    "roof": POSES[0],
    "front": look_at_pose((0.0, -6.0, 2.0), (0.0, 0.0, 1.0), (0.0, 0.0, 1.0)),
    "bumper": POSES[1],
    "side": rigid_pose(90, 0, (0.0, -2.0, 1.0))
    @ np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], np.float64),
    "grid": POSES[1],
}
MATERIALS = Materials(reflectivity=[0.2, 0.7, 0.95], label=[4, 5, 6])


def test_a_rig_answers_what_each_sensor_answers_alone():
    scene = dacrt.Scene(ROOM)
    together = Rig(SENSORS).capture(scene, POSE_OF, MATERIALS)
    assert list(together) == list(SENSORS)
    for name, sensor in SENSORS.items():
        if isinstance(sensor, Lidar):
            alone = sensor.scan(scene, POSE_OF[name], MATERIALS)
        else:
            alone = sensor.capture(scene, POSE_OF[name])
        assert list(together[name]) == list(alone), name
        for key in alone:
            np.testing.assert_array_equal(together[name][key], alone[key], err_msg=f"{name}.{key}")
        assert np.isfinite(alone["range"]).any(), name


def test_poses_must_match_the_sensors():
    rig = Rig(SENSORS)
    with pytest.raises(dacrt.InputError, match="missing \\['side'\\]"):
        rig.capture(dacrt.Scene(ROOM), {k: v for k, v in POSE_OF.items() if k != "side"})


def test_a_bad_pose_names_its_sensor():
    bad = dict(POSE_OF, front=np.zeros((4, 4)))
    with pytest.raises(dacrt.InputError, match="sensors.front: pose"):
        Rig(SENSORS).capture(dacrt.Scene(ROOM), bad)


@pytest.mark.parametrize("threads", [0, -1, 1.5, "2", True])
def test_bad_threads_are_named(threads):
    """The rig's sensors are made on the query's threads: a bad count is the caller's error,
    named, before any sensor is made."""
    with pytest.raises(dacrt.InputError, match="threads must be a positive integer or None"):
        Rig(SENSORS).capture(dacrt.Scene(ROOM), POSE_OF, threads=threads)


def test_sensors_and_poses_must_be_mappings_of_names():
    with pytest.raises(dacrt.InputError, match="sensors must be a mapping of sensor names"):
        Rig([SENSORS["roof"]])
    rig = Rig(SENSORS)
    with pytest.raises(dacrt.InputError, match="poses must be a mapping of sensor names"):
        rig.capture(dacrt.Scene(ROOM), list(POSE_OF.values()))
    with pytest.raises(dacrt.InputError, match="poses_end must be a mapping"):
        rig.capture(dacrt.Scene(ROOM), POSE_OF, poses_end=[POSE_OF["roof"]])


@pytest.mark.parametrize("key", ["time", "tmin", "tmax", "pose_end", "max_hits", "colour"])
def test_a_query_option_a_sensor_sets_itself_is_named(key):
    """The rays, their windows and times are the sensors' own: a query naming one is the
    caller's error, named, not a TypeError from Scene.closest."""
    scene = dacrt.Scene(ROOM)
    words = f"{key} is not a query option of a sensor"
    with pytest.raises(dacrt.InputError, match=words):
        Rig(SENSORS).capture(scene, POSE_OF, **{key: 0.5})
    if key != "pose_end":  # a lidar's scan takes a pose_end of its own
        with pytest.raises(dacrt.InputError, match=words):
            SENSORS["roof"].scan(scene, POSE_OF["roof"], **{key: 0.5})
    with pytest.raises(dacrt.InputError, match=words):
        SENSORS["front"].capture(scene, POSE_OF["front"], **{key: 0.5})


def test_materials_as_a_dict_answer_as_materials():
    scene = dacrt.Scene(ROOM)
    given = {"reflectivity": [0.2, 0.7, 0.95], "label": [4, 5, 6]}
    as_dict = Rig(SENSORS).capture(scene, POSE_OF, given)
    as_materials = Rig(SENSORS).capture(scene, POSE_OF, MATERIALS)
    for name in SENSORS:
        for key in as_materials[name]:
            np.testing.assert_array_equal(as_dict[name][key], as_materials[name][key])
    assert set(np.unique(as_dict["roof"]["label"])) <= {4, 5, 6}
    with pytest.raises(dacrt.InputError, match="materials.colour is not an option"):
        SENSORS["roof"].scan(scene, POSE_OF["roof"], {"colour": 1})
    with pytest.raises(dacrt.InputError, match="materials must be an object of its options"):
        SENSORS["roof"].scan(scene, POSE_OF["roof"], [0.5, 0.5, 0.5])


def test_a_rig_tracing_more_rays_than_int32_indexes_is_refused(monkeypatch):
    """Each sensor alone within the bound, the rig's batch beyond it (the bound made small)."""
    scene = dacrt.Scene(ROOM)
    sensors = {"a": Camera(4, 4, 1.0, 1.0, 1.5, 1.5), "b": Camera(4, 3, 1.0, 1.0, 1.5, 1.0)}
    monkeypatch.setattr(dacrt.validation, "MAX_ROWS", 20)
    rig = Rig(sensors)
    poses = dict.fromkeys(sensors, np.eye(4))
    with pytest.raises(dacrt.InputError, match=r"the rig's batch \(.*\) has 28 rays"):
        rig.capture(scene, poses)
    assert sensors["a"].capture(scene, np.eye(4))["depth"].shape == (4, 4)


def test_a_rigs_counters_add_up_its_closest_and_hits_calls():
    """A rig traces its sensors in a closest call and a hits call (sensors that see through
    surfaces); its counters are both calls' together."""
    scene = dacrt.Scene(ROOM)
    answers = Rig(SENSORS).capture(scene, POSE_OF, MATERIALS, stats=True)
    total = batch_stats(answers.values())
    assert total["rays"] == sum(sensor.n_traced_rays for sensor in SENSORS.values())
    assert total["triangles"] == scene.n_triangles
    alone = [
        Rig({k: SENSORS[k]}).capture(scene, {k: POSE_OF[k]}, MATERIALS, stats=True)[k].stats
        for k in ("bumper", "front")
    ]
    assert total["max_depth"] >= max(c["max_depth"] for c in alone)
    assert batch_stats(Rig(SENSORS).capture(scene, POSE_OF, MATERIALS).values()) is None
