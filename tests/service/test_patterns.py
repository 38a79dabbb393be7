"""Scan patterns (API.md "Patterns"): PUT, GET, DELETE /v1/patterns/{name}, bounded by
DACRT_MAX_PATTERNS and DACRT_MAX_PATTERN_RAYS, persisted in the data folder, and traced by
``"pattern": NAME`` in /lidar: ray m along (cos e cos a, cos e sin a, sin e) in the sensor frame,
its point's ``ring`` the channel, ``time`` its time_s, ``ray`` its row."""

from __future__ import annotations

import io

import in_process
import numpy as np
import pytest
from sensor_helpers import MESHES, npz, put_room, rigid_pose

import dacrt
from dacrt.sensors import Lidar, Pattern
from service.client import Client
from service.settings import Settings

NPZ = {"Content-Type": "application/x-npz"}
RNG = np.random.default_rng(5)
M = 500
#: A Livox-like rosette: azimuths and elevations that never repeat a spinning lidar's grid.
ARRAYS = {
    "azimuth_deg": RNG.uniform(-35, 35, M),
    "elevation_deg": RNG.uniform(-25, 10, M),
    "time_s": np.sort(RNG.uniform(0, 0.1, M)),
    "channel": RNG.integers(0, 6, M).astype(np.uint16),
}
POSE = rigid_pose(30, 0, (-1.0, -4.0, 1.5))


def npz_body(**arrays) -> bytes:
    out = io.BytesIO()
    np.savez(out, **arrays)
    return out.getvalue()


@pytest.fixture
def pattern_name(app_client, scene_name):
    response = app_client.put(f"/v1/patterns/{scene_name}", content=npz_body(**ARRAYS), headers=NPZ)
    assert response.status_code == 201, response.text
    yield scene_name
    app_client.delete(f"/v1/patterns/{scene_name}")


def test_put_get_list_delete(app_client, pattern_name):
    url = f"/v1/patterns/{pattern_name}"
    info = {"pattern": pattern_name, "rays": M, "time_s": True, "channel": True}
    assert app_client.put(url, content=npz_body(**ARRAYS), headers=NPZ).json() == info
    assert app_client.put(url, content=npz_body(**ARRAYS), headers=NPZ).status_code == 200
    assert info in app_client.get("/v1/patterns").json()["patterns"]
    back = npz(app_client.get(url).content)
    assert set(back) == set(ARRAYS)
    for key, values in ARRAYS.items():
        assert np.array_equal(back[key], values) and back[key].dtype == values.dtype, key
    assert app_client.delete(url).status_code == 204
    assert app_client.get(url).status_code == 404
    assert app_client.delete(url).status_code == 404


def test_json_patterns_and_the_optional_keys(app_client, scene_name):
    body = {"azimuth_deg": [0, 90.5], "elevation_deg": [0, -10]}
    response = app_client.put(f"/v1/patterns/{scene_name}", json=body)
    assert response.status_code == 201, response.text
    assert response.json() == {"pattern": scene_name, "rays": 2, "time_s": False, "channel": False}
    back = npz(app_client.get(f"/v1/patterns/{scene_name}").content)
    assert set(back) == {"azimuth_deg", "elevation_deg"}
    assert np.array_equal(back["azimuth_deg"], [0, 90.5])


def test_lidar_traces_the_pattern_as_the_engine_does(app_client, app_api, scene_name, pattern_name):
    put_room(app_api, scene_name)
    body = {"pose": POSE.tolist(), "pattern": pattern_name, "max_range": 40.0}
    response = app_client.post(
        f"/v1/scenes/{scene_name}/lidar", json=body, headers={"Accept": "application/x-npz"}
    )
    assert response.status_code == 200, response.text
    answer = npz(response.content)
    scene = dacrt.Scene(list(MESHES.values()))
    expected = Lidar(pattern=Pattern(**ARRAYS), max_range=40.0).scan(scene, POSE)
    assert list(answer) == list(expected) and "time" in answer
    for key in expected:
        assert (
            np.array_equal(answer[key], expected[key]) and answer[key].dtype == expected[key].dtype
        )
    # the rule, in NumPy: the points lie along each row's direction; ring, time from the row
    ray = answer["ray"]
    a, e = np.radians(ARRAYS["azimuth_deg"][ray]), np.radians(ARRAYS["elevation_deg"][ray])
    local = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], 1)
    along = (answer["xyz"] - POSE[:3, 3]) / answer["range"][:, None]
    assert len(ray) > 100 and np.allclose(along, local @ POSE[:3, :3].T, atol=1e-5)
    assert np.array_equal(answer["ring"], ARRAYS["channel"][ray].astype(np.uint16))
    assert np.array_equal(answer["time"], ARRAYS["time_s"][ray].astype(np.float32))


@pytest.mark.parametrize(
    "arrays, status, words",
    [
        ({**ARRAYS, "elevation_deg": np.full(M, 91.0)}, 422, "elevation_deg[0] must be in [-90"),
        ({**ARRAYS, "time_s": -ARRAYS["time_s"] - 1}, 422, "time_s[0] must be >= 0"),
        ({**ARRAYS, "channel": np.full(M, -1, np.int32)}, 422, "channel[0] must be in [0, 65535]"),
        ({**ARRAYS, "azimuth_deg": np.full(M, np.nan)}, 422, "azimuth_deg[0] must be a finite"),
        ({**ARRAYS, "azimuth_deg": np.zeros((M, 2))}, 422, "azimuth_deg must be a list"),
        ({**ARRAYS, "azimuth_deg": np.zeros(3)}, 422, "elevation_deg has 500 rays and azimuth"),
        ({**ARRAYS, "channel": np.zeros(M)}, 422, "channel must hold integers"),
        ({"azimuth_deg": ARRAYS["azimuth_deg"]}, 400, "lacks 'elevation_deg'"),
        ({**ARRAYS, "colour": ARRAYS["channel"]}, 400, "unknown keys 'colour'"),
    ],
)
def test_bad_patterns_are_refused_naming_the_key(app_client, scene_name, arrays, status, words):
    url = f"/v1/patterns/{scene_name}"
    response = app_client.put(url, content=npz_body(**arrays), headers=NPZ)
    assert response.status_code == status and words in response.json()["detail"], response.text
    assert app_client.get(url).status_code == 404


@pytest.mark.parametrize(
    "body, words",
    [
        ({"azimuth_deg": ["0"], "elevation_deg": [0]}, "azimuth_deg must be numbers"),
        ({"azimuth_deg": [[0]], "elevation_deg": [0]}, "azimuth_deg must be a list of numbers"),
        ({"azimuth_deg": [0], "elevation_deg": [0], "channel": [0.5]}, "channel must be integers"),
        ({"azimuth_deg": [0], "elevation_deg": [0], "channel": [2**70]}, "channel holds a number"),
        ({"azimuth_deg": 0, "elevation_deg": [0]}, "azimuth_deg must be a list"),
    ],
)
def test_bad_json_patterns_are_422(app_client, scene_name, body, words):
    response = app_client.put(f"/v1/patterns/{scene_name}", json=body)
    assert response.status_code == 422 and words in response.json()["detail"], response.text


def test_limits_and_the_data_folder(tmp_path):
    settings = Settings(token=None, max_patterns=2, max_pattern_rays=M, data_dir=tmp_path)
    with in_process.serve(settings) as http:
        for name in ("a", "b"):
            assert http.put(f"/v1/patterns/{name}", content=npz_body(**ARRAYS), headers=NPZ)
        third = http.put("/v1/patterns/c", content=npz_body(**ARRAYS), headers=NPZ)
        assert third.status_code == 413 and "DACRT_MAX_PATTERNS" in third.json()["detail"]
        big = {key: np.concatenate([v, v[:1]]) for key, v in ARRAYS.items()}
        response = http.put("/v1/patterns/a", content=npz_body(**big), headers=NPZ)
        assert response.status_code == 413 and "DACRT_MAX_PATTERN_RAYS" in response.text
        assert http.delete("/v1/patterns/b").status_code == 204
        bad = http.post("/v1/scenes/x/lidar", json={"pose": np.eye(4).tolist(), "pattern": "b"})
        assert bad.status_code == 404  # no scene x: before the body is read
    with in_process.serve(settings) as http:  # restored from the data folder
        assert [p["pattern"] for p in http.get("/v1/patterns").json()["patterns"]] == ["a"]
        back = npz(http.get("/v1/patterns/a").content)
        assert all(np.array_equal(back[key], ARRAYS[key]) for key in ARRAYS)
        api = Client(http=http)
        put_room(api, "room")
        body = {"pose": POSE.tolist(), "pattern": "b"}
        response = http.post("/v1/scenes/room/lidar", json=body)
        assert response.status_code == 422 and "pattern: no pattern 'b'" in response.text
        body["pattern"], body["organized"] = "a", True
        response = http.post("/v1/scenes/room/lidar", json=body)
        assert response.status_code == 422 and "organized needs a spinning lidar" in response.text
