"""The sensor routes are the engine's sensors: for the same request, ``/camera``, ``/lidar`` and
``/sensors`` answer bit for bit what ``dacrt.sensors`` answers in process on a ``dacrt.Scene`` of
the same meshes (with the same materials), physics included."""

from __future__ import annotations

import numpy as np
import pytest
from sensor_helpers import MESHES, npz, put_room, rigid_pose
from sensor_reference import read_pcd

import dacrt
from dacrt.sensors import Camera, Lidar, Materials, Rig, look_at_pose, pcd_bytes

NPZ_ANSWER = {"Accept": "application/x-npz"}
POSE = rigid_pose(20, -5, (0.0, -3.0, 1.2))
#: Each mesh's material, by index (floor, sphere, box), set over HTTP and given in process.
REFLECTIVITY = [0.2, 0.9, 0.6]
LABEL = [7, 12, 4000000000]
LIDARS = {
    "plain": {"model": "VLP-16", "horizontal_steps": 360},
    "returns": {"vertical_angles_deg": [-12.0, -4.0, 0.0, 3.0], "horizontal_steps": 400,
                "max_returns": 3, "min_range": 0.5, "max_range": 30.0},
    "dual": {"model": "VLP-16", "horizontal_steps": 300, "return_mode": "dual",
             "beam_divergence_deg": 2.0, "beam_samples": 7, "range_resolution": 0.05},
    "noisy": {"model": "VLP-16", "horizontal_steps": 300, "return_mode": "strongest",
              "beam_divergence_deg": 1.0, "beam_samples": 3, "attenuation": 0.05,
              "noise": {"range_sigma": 0.02, "range_sigma_per_m": 0.001,
                        "angle_sigma_deg": 0.05, "seed": 3},
              "dropout": {"rate": 0.2, "min_intensity": 0.05, "seed": 4}},
    "organized": {"model": "VLP-16", "horizontal_steps": 200, "organized": True,
                  "return_mode": "all", "max_returns": 2},
    "kept": {"model": "VLP-16", "horizontal_steps": 200, "non_hits": "keep",
             "return_mode": "last"},
}  # fmt: skip


@pytest.fixture
def room(app_client, app_api, scene_name):
    put_room(app_api, scene_name)
    for mesh, reflectivity, label in zip(MESHES, REFLECTIVITY, LABEL):
        body = {"reflectivity": reflectivity, "label": label}
        response = app_client.put(f"/v1/scenes/{scene_name}/meshes/{mesh}/material", json=body)
        assert response.status_code == 200, response.text
    return scene_name


@pytest.fixture(scope="module")
def scene():
    return dacrt.Scene(list(MESHES.values()))  # mesh positions = upload order = indices


MATERIALS = Materials(reflectivity=REFLECTIVITY, label=LABEL)


def assert_identical(answer, expected):
    assert list(answer) == list(expected)
    for name in expected:
        assert answer[name].dtype == expected[name].dtype, name
        assert answer[name].shape == expected[name].shape, name
        assert np.array_equal(answer[name], expected[name], equal_nan=True), name


def lidar_kwargs(body):
    """The in-process Lidar of a /lidar body: the same keys (``max_returns`` > 1 alone means
    return_mode all, as API.md keeps /lidar's multi-return)."""
    kwargs = dict(body)
    if "return_mode" not in kwargs and kwargs.get("max_returns", 1) > 1:
        kwargs["return_mode"] = "all"
    return kwargs


@pytest.mark.parametrize("name", list(LIDARS))
def test_lidar_answers_what_the_engine_answers(app_client, room, scene, name):
    body = {"pose": POSE.tolist(), **LIDARS[name]}
    response = app_client.post(f"/v1/scenes/{room}/lidar", json=body, headers=NPZ_ANSWER)
    assert response.status_code == 200, response.text
    expected = Lidar(**lidar_kwargs(LIDARS[name])).scan(scene, POSE, MATERIALS)
    assert expected.n_points > 100
    assert_identical(npz(response.content), expected)


def test_the_materials_reach_the_points(app_client, room):
    body = {"pose": POSE.tolist(), **LIDARS["plain"]}
    answer = npz(app_client.post(f"/v1/scenes/{room}/lidar", json=body, headers=NPZ_ANSWER).content)
    assert set(np.unique(answer["mesh"])) == {0, 1, 2}
    assert np.array_equal(answer["label"], np.array(LABEL, np.uint32)[answer["mesh"]])
    # API.md: reflectivity x cos_incidence x exp(-0.004 range), in NumPy here
    rho = np.array(REFLECTIVITY)[answer["mesh"]]
    rule = rho * answer["cos_incidence"] * np.exp(-0.004 * answer["range"].astype(np.float64))
    assert np.allclose(answer["intensity"], rule, rtol=1e-6)


PCD_ANSWER = {"Accept": "application/x-pcd"}
#: ``?fields=`` of a PCD answer as the docs list them: a key's columns (``x y z``) or the key
#: itself (``xyz``), in any order; each is the list ``pcd_bytes`` takes in process.
PCD_FIELDS = [
    None,
    "x,y,z,intensity,ring,label",
    "xyz,intensity,ring,label",
    "label,ring,intensity,xyz",
    "intensity,z,x",
    "range,y,mesh,cos_incidence,x,return,z",
]


def pcd_columns(points, fields):
    """FIELDS of a PCD of ``points`` with ``fields``, and each one's values, from the points
    (``xyz`` is the columns x y z, written out here; None: every key of the points)."""
    names = list(points) if fields is None else fields
    columns = {}
    for name in names:
        if name == "xyz" or name in ("x", "y", "z"):
            for axis in "xyz" if name == "xyz" else name:
                columns[axis] = points["xyz"][..., "xyz".index(axis)].reshape(-1)
        else:
            columns[name] = points[name].reshape(-1)
    return columns


@pytest.mark.parametrize("name", ["plain", "organized"])
@pytest.mark.parametrize("fields", PCD_FIELDS)
def test_a_pcd_answer_is_the_engines_pcd_file(app_client, room, scene, name, fields):
    """``Accept: application/x-pcd`` with ``?fields=`` is byte for byte ``pcd_bytes`` of the
    same list in process: the same names (x y z, or xyz) in the order asked."""
    body = {"pose": POSE.tolist(), **LIDARS[name]}
    params = {} if fields is None else {"fields": fields}
    response = app_client.post(
        f"/v1/scenes/{room}/lidar", params=params, json=body, headers=PCD_ANSWER
    )
    assert response.status_code == 200, response.text
    points = Lidar(**lidar_kwargs(LIDARS[name])).scan(scene, POSE, MATERIALS)
    asked = None if fields is None else fields.split(",")
    assert response.content == pcd_bytes(points, asked)
    # read by hand: the fields asked, in that order, with the points' values
    header, records = read_pcd(response.content)
    want = pcd_columns(points, asked)
    assert header["FIELDS"] == list(want) and len(records) == points["range"].size > 100
    for column, values in want.items():
        assert np.array_equal(records[column], values, equal_nan=True), column


def test_a_pcd_field_asked_twice_is_written_once_where_first_asked(app_client, room, scene):
    """``pcd_bytes`` refuses a field named twice; the service's ``?fields=`` takes each name once
    (as for every answer), so ``x,xyz`` is the PCD of x y z."""
    body = {"pose": POSE.tolist(), **LIDARS["plain"]}
    response = app_client.post(
        f"/v1/scenes/{room}/lidar",
        params={"fields": "ring,x,xyz,ring,label"},
        json=body,
        headers=PCD_ANSWER,
    )
    assert response.status_code == 200, response.text
    points = Lidar(**LIDARS["plain"]).scan(scene, POSE, MATERIALS)
    assert response.content == pcd_bytes(points, ["ring", "x", "y", "z", "label"])


CAMERAS = {
    "pinhole": (
        {"width": 40, "height": 30, "fx": 30.0, "fy": 30.0, "cx": 19.5, "cy": 14.5,
         "pose": rigid_pose(0, 0, (0.0, -7.0, 1.0)) @ np.array(
             [[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1.0]]), "far": 9.0},
        lambda: Camera(40, 30, 30.0, 30.0, 19.5, 14.5, far=9.0),
    ),
    "look-at": (
        {"width": 32, "height": 24, "eye": [6.0, -6.0, 4.0], "target": [0.0, 0.0, 0.5],
         "up": [0.0, 0.0, 1.0], "fov_deg": 50.0},
        lambda: Camera.from_fov(32, 24, 50.0),
    ),
}  # fmt: skip


def camera_pose(body):
    if "pose" in body:
        return np.asarray(body["pose"])
    return look_at_pose(body["eye"], body["target"], body["up"])


@pytest.mark.parametrize("name", list(CAMERAS))
def test_camera_answers_what_the_engine_answers(app_client, room, scene, name):
    body, make = CAMERAS[name]
    body = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in body.items()}
    response = app_client.post(f"/v1/scenes/{room}/camera", json=body, headers=NPZ_ANSWER)
    assert response.status_code == 200, response.text
    expected = make().capture(scene, camera_pose(body))
    assert np.isfinite(expected["depth"]).sum() > 100
    assert_identical(npz(response.content), expected)


def test_a_rig_answers_what_the_engine_rig_answers(app_client, room, scene):
    camera_body = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                   for k, v in CAMERAS["pinhole"][0].items()}  # fmt: skip
    body = {
        "sensors": {
            "roof": {"kind": "lidar", "pose": POSE.tolist(), **LIDARS["dual"]},
            "front": {"kind": "camera", **camera_body},
            "low": {"kind": "lidar", "pose": POSE.tolist(), **LIDARS["returns"]},
        }
    }
    response = app_client.post(f"/v1/scenes/{room}/sensors", json=body, headers=NPZ_ANSWER)
    assert response.status_code == 200, response.text
    answer = npz(response.content)
    rig = Rig(
        {
            "roof": Lidar(**LIDARS["dual"]),
            "front": CAMERAS["pinhole"][1](),
            "low": Lidar(**lidar_kwargs(LIDARS["returns"])),
        }
    )
    poses = {"roof": POSE, "front": camera_pose(camera_body), "low": POSE}
    expected = rig.capture(scene, poses, MATERIALS)
    for sensor, arrays in expected.items():
        assert_identical({k.split(".", 1)[1]: v for k, v in answer.items()
                          if k.startswith(sensor + ".")}, arrays)  # fmt: skip
    # ... and, sensor by sensor, what each answers alone over HTTP
    alone = app_client.post(
        f"/v1/scenes/{room}/lidar",
        json={"pose": POSE.tolist(), **LIDARS["returns"]},
        headers=NPZ_ANSWER,
    )
    assert_identical({k[4:]: v for k, v in answer.items() if k.startswith("low.")},
                     npz(alone.content))  # fmt: skip
