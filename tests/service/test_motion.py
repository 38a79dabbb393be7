"""Motion through the service: ``MESH.transform_end`` in frames and ``time`` in ray bodies
(../shared/API.md, "Motion"). A ray at time tau sees a mesh where the linear interpolation of
its placements puts it (a numpy reference: a floor moving up); a frame that places a mesh and
gives no end makes it static again; mesh info and a restart keep the end; bad values are 422
naming them."""

from __future__ import annotations

import in_process
import numpy as np
import pytest
from sensor_reference import read_pcd
from service_helpers import NPZ, npz_bytes, quad

import dacrt
from dacrt.sensors import Lidar
from service.settings import Settings

RISE = 4.0  # the floor rises this far over the interval


def lift(z: float) -> list[list[float]]:
    m = np.eye(4)
    m[2, 3] = z
    return m.tolist()


def rays(n: int = 64, seed: int = 1):
    """Rays straight down onto the floor's middle from z = 10, at times spread over [0, 1]."""
    rng = np.random.default_rng(seed)
    origins = np.column_stack([rng.uniform(-4, 4, (n, 2)), np.full(n, 10.0)]).astype(np.float32)
    directions = np.tile(np.float32([0, 0, -1]), (n, 1))
    times = rng.uniform(0, 1, n).astype(np.float32)
    times[:4] = [0, 1, 0.5, 0.25]
    return origins, directions, times


def upload_floor(http, scene: str) -> None:
    response = http.put(
        f"/v1/scenes/{scene}/meshes/floor",
        content=npz_bytes(**dict(zip(("vertices", "faces"), quad(-9, 9, -9, 9, 0)))),
        headers=NPZ,
    )
    assert response.status_code == 201, response.text


def closest_json(http, scene: str, origins, directions, times=None) -> dict:
    body = {"origins": origins.tolist(), "directions": directions.tolist()}
    if times is not None:
        body["time"] = times.tolist()
    response = http.post(f"/v1/scenes/{scene}/closest", json=body)
    assert response.status_code == 200, response.text
    return response.json()


def test_rays_at_their_times_see_a_mesh_moving_during_the_frame(app_client, scene_name):
    upload_floor(app_client, scene_name)
    o, d, times = rays()
    # The version before the frame has its engine scene: the frame's is derived from it.
    np.testing.assert_allclose(closest_json(app_client, scene_name, o, d, times)["t"], 10.0)
    frame = {"floor.transform": lift(1.0), "floor.transform_end": lift(1.0 + RISE)}
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
    assert response.status_code == 200, response.text
    mesh = {m["mesh"]: m for m in response.json()["meshes"]}["floor"]
    assert mesh["transform_end"] == lift(1.0 + RISE)
    assert mesh["bounds"] == [[-9, -9, 1], [9, 9, 1 + RISE]]
    want = 10.0 - (1.0 + RISE * times.astype(np.float64))
    np.testing.assert_allclose(closest_json(app_client, scene_name, o, d, times)["t"], want, 1e-6)
    # npz bodies carry time too; no time is every ray at 0
    body = npz_bytes(origins=o, directions=d, time=times)
    answer = app_client.post(
        f"/v1/scenes/{scene_name}/closest",
        content=body,
        headers={**NPZ, "Accept": "application/json"},
    )
    assert answer.status_code == 200, answer.text
    np.testing.assert_allclose(answer.json()["t"], want, 1e-6)
    np.testing.assert_allclose(closest_json(app_client, scene_name, o, d)["t"], 9.0)
    # a frame that places the floor and gives no end makes it static
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json={"floor.transform": lift(2)})
    assert {m["mesh"]: m for m in response.json()["meshes"]}["floor"]["transform_end"] is None
    np.testing.assert_allclose(closest_json(app_client, scene_name, o, d, times)["t"], 8.0)
    # an end alone keeps the start
    frame = {"floor.transform_end": lift(3)}
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
    np.testing.assert_allclose(
        closest_json(app_client, scene_name, o, d, times)["t"], 8.0 - times, 1e-6
    )


def test_bad_ends_and_times_are_422_naming_them(app_client, scene_name):
    upload_floor(app_client, scene_name)
    frame = {"floor.transform_end": np.zeros((4, 4)).tolist()}
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
    assert response.status_code == 422 and "floor.transform_end" in response.text
    o, d, times = rays(4)
    for bad, words in (
        ([0.0, 0.5, 1.5, 0.0], "time[2]"),
        ([0.0, 0.5], "time has 2 values"),
        # outside [0, 1] as written, though float32 would round it into the range
        ([0.0, 1.000000001, 0.0, 0.0], "time[1] is 1.000000001"),
        ([0.0, 0.0, -1e-50, 0.0], "time[2] is -1e-50"),
        (1.000000001, "time[0] is 1.000000001"),
        ([0.0, None, 0.0, 0.0], "time[1] is null"),
    ):
        body = {"origins": o.tolist(), "directions": d.tolist(), "time": bad}
        response = app_client.post(f"/v1/scenes/{scene_name}/closest", json=body)
        assert response.status_code == 422 and words in response.text, response.text


def test_a_restart_restores_end_placements(tmp_path):
    settings = Settings(token=None, load_demo=False, data_dir=tmp_path)
    o, d, times = rays()
    with in_process.serve(settings) as http:
        upload_floor(http, "s")
        frame = {"floor.transform_end": lift(RISE)}
        assert http.post("/v1/scenes/s/frame", json=frame).status_code == 200
        before = http.get("/v1/scenes/s/meshes/floor").json()
        answer = closest_json(http, "s", o, d, times)["t"]
    with in_process.serve(settings) as http:
        assert http.get("/v1/scenes/s/meshes/floor").json() == before
        assert before["transform_end"] == lift(RISE)
        np.testing.assert_array_equal(closest_json(http, "s", o, d, times)["t"], answer)


def box_frame(name: str, lo, hi) -> dict:
    """A frame adding a closed axis-aligned box named ``name``."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[(lo, hi)[k >> a & 1][a] for a in range(3)] for k in range(8)])
    f = [[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
         [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]]  # fmt: skip
    return {f"{name}.vertices": v.tolist(), f"{name}.faces": f}


def lidar_npz(http, scene: str, body: dict) -> dict:
    response = http.post(
        f"/v1/scenes/{scene}/lidar", json=body, headers={"Accept": "application/x-npz"}
    )
    assert response.status_code == 200, response.text
    import io

    with np.load(io.BytesIO(response.content)) as archive:
        return dict(archive)


def test_a_lidar_sweep_over_time_sees_a_moving_box_skewed_with_its_velocity(app_client, scene_name):
    """A box passing the lidar's +y side at 20 m/s: each column sees it where it is at its
    instant (the numpy slab reference), with its velocity and its radial speed; a moving sensor
    fires each column from where it is."""
    period, speed = 0.1, 20.0
    frame = box_frame("car", (-1.0, 9.0, -1.0), (1.0, 11.0, 1.0))
    frame["car.transform_end"] = [
        [1, 0, 0, speed * period],
        [0, 1, 0, 0],
        [0, 0, 1, 0],
        [0] * 3 + [1],
    ]
    assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).status_code == 200
    steps = 720
    body = {"pose": np.eye(4).tolist(), "vertical_angles_deg": [0.0], "horizontal_steps": steps}
    still = lidar_npz(app_client, scene_name, body)
    assert "velocity" not in still and "time" not in still
    points = lidar_npz(app_client, scene_name, {**body, "period_s": period})
    ray = points["ray"]
    tau = ray / steps
    a = 2 * np.pi * ray / steps
    d = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)
    lo = np.array([-1.0, 9.0, -1.0]) + np.outer(tau, [speed * period, 0, 0])
    hi = np.array([1.0, 11.0, 1.0]) + np.outer(tau, [speed * period, 0, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (lo - 0) / d, (hi - 0) / d
    near = np.nanmax(np.minimum(t0, t1), axis=1)
    np.testing.assert_allclose(points["range"], near, rtol=1e-5)
    np.testing.assert_allclose(points["time"], tau * period, rtol=1e-6)
    np.testing.assert_allclose(points["velocity"], np.tile([speed, 0, 0], (len(ray), 1)), atol=1e-3)
    np.testing.assert_allclose(points["radial_speed"], speed * np.cos(a), atol=1e-3)
    # seen about a quarter of the sweep in: half a metre further on
    assert points["xyz"][:, 0].max() > still["xyz"][:, 0].max() + 0.4
    # the same sweep in process (dacrt.sensors) answers the same points
    scene = dacrt.Scene(
        [(np.asarray(frame["car.vertices"], np.float32), np.asarray(frame["car.faces"]))],
        transforms_end=[np.asarray(frame["car.transform_end"], float)],
    )
    local = dacrt.sensors.Lidar(vertical_angles_deg=[0.0], horizontal_steps=steps, period_s=period)
    mine = local.scan(scene, np.eye(4))
    for name in ("xyz", "range", "time", "velocity", "radial_speed", "ray"):
        np.testing.assert_allclose(points[name], mine[name], rtol=1e-6, atol=1e-6, err_msg=name)
    # a sensor moving along +x at 10 m/s: the box's radial speed is relative to it
    end = np.eye(4)
    end[0, 3] = 10.0 * period
    moving = lidar_npz(
        app_client, scene_name, {**body, "period_s": period, "pose_end": end.tolist()}
    )
    a = 2 * np.pi * moving["ray"] / steps
    np.testing.assert_allclose(moving["radial_speed"], (speed - 10.0) * np.cos(a), atol=1e-3)
    start_x = 10.0 * period * moving["ray"] / steps
    np.testing.assert_allclose(
        moving["xyz"][:, 0], start_x + moving["range"] * np.cos(a), atol=1e-4
    )


def test_a_lidar_end_pose_needs_a_period(app_client, scene_name):
    upload_floor(app_client, scene_name)
    body = {"pose": np.eye(4).tolist(), "model": "VLP-16", "pose_end": np.eye(4).tolist()}
    response = app_client.post(f"/v1/scenes/{scene_name}/lidar", json=body)
    assert response.status_code == 422 and "pose_end needs period_s" in response.text
    body = {"pose": np.eye(4).tolist(), "model": "VLP-16", "period_s": 0}
    response = app_client.post(f"/v1/scenes/{scene_name}/lidar", json=body)
    assert response.status_code == 422 and "period_s" in response.text


def test_a_rigs_lidar_takes_period_and_end_pose_as_lidar_does(app_client, scene_name):
    frame = box_frame("wall", (-50.0, 10.0, -5.0), (50.0, 11.0, 5.0))
    assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).status_code == 200
    end = np.eye(4)
    end[0, 3] = 1.0
    body = {
        "pose": np.eye(4).tolist(),
        "vertical_angles_deg": [0.0],
        "horizontal_steps": 64,
        "period_s": 0.1,
        "pose_end": end.tolist(),
    }
    alone = lidar_npz(app_client, scene_name, body)
    rig = {"sensors": {"roof": {"kind": "lidar", **body}}}
    response = app_client.post(
        f"/v1/scenes/{scene_name}/sensors", json=rig, headers={"Accept": "application/x-npz"}
    )
    assert response.status_code == 200, response.text
    import io

    with np.load(io.BytesIO(response.content)) as archive:
        for name in ("xyz", "range", "time", "velocity", "radial_speed"):
            np.testing.assert_array_equal(archive[f"roof.{name}"], alone[name])
    np.testing.assert_allclose(
        alone["radial_speed"], -10.0 * np.cos(2 * np.pi * alone["ray"] / 64), atol=1e-4
    )


def test_a_lidar_answers_in_the_sensor_frame_as_in_process(app_client, scene_name):
    """``"frame": "sensor"``: the points of the in-process ``Lidar(frame="sensor")``, bit for
    bit, which are the scene's moved into the start pose's frame."""
    wall = box_frame("wall", (-50.0, 10.0, -5.0), (50.0, 11.0, 5.0))
    assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=wall).status_code == 200
    start, end = np.eye(4), np.eye(4)
    start[:3, 3], end[:3, 3] = [0.5, 0.0, 0.2], [1.5, 0.0, 0.2]
    body = {
        "pose": start.tolist(),
        "vertical_angles_deg": [0.0, 3.0],
        "horizontal_steps": 64,
        "period_s": 0.1,
        "pose_end": end.tolist(),
    }
    in_scene = lidar_npz(app_client, scene_name, body)
    in_sensor = lidar_npz(app_client, scene_name, {**body, "frame": "sensor"})
    scene = dacrt.Scene([(np.asarray(wall["wall.vertices"], np.float32), wall["wall.faces"])])
    expected = Lidar(
        vertical_angles_deg=[0.0, 3.0], horizontal_steps=64, period_s=0.1, frame="sensor"
    ).scan(scene, start, pose_end=end)
    for key in ("xyz", "velocity", "range"):
        np.testing.assert_array_equal(in_sensor[key], expected[key], err_msg=key)
    np.testing.assert_allclose(in_sensor["xyz"], in_scene["xyz"] - start[:3, 3], atol=1e-5)


def floor_at(z: float) -> list[list[float]]:
    """The floor's vertices (``upload_floor``) at height z."""
    return quad(-9, 9, -9, 9, z)[0].tolist()


def test_rays_at_their_times_see_a_deforming_mesh(app_client, scene_name):
    upload_floor(app_client, scene_name)
    o, d, times = rays()
    frame = {"floor.vertices_end": floor_at(RISE)}
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
    assert response.status_code == 200, response.text
    mesh = {m["mesh"]: m for m in response.json()["meshes"]}["floor"]
    assert mesh["vertices_end"] == 4 and mesh["bounds"] == [[-9, -9, 0], [9, 9, RISE]]
    # Each vertex at float32(v0 + tau (v1 - v0)) (numpy): the floor at RISE tau.
    height = (np.float64(times) * RISE).astype(np.float32).astype(np.float64)
    t = closest_json(app_client, scene_name, o, d, times)["t"]
    np.testing.assert_allclose(t, 10 - height, rtol=1e-6)  # t in float32
    np.testing.assert_allclose(closest_json(app_client, scene_name, o, d)["t"], 10.0)
    # new start vertices and no end: static again
    frame = {"floor.vertices": floor_at(1.0)}
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
    assert {m["mesh"]: m for m in response.json()["meshes"]}["floor"]["vertices_end"] is None
    np.testing.assert_allclose(closest_json(app_client, scene_name, o, d, times)["t"], 9.0)
    # start and end in one frame, .npz
    body = npz_bytes(**{"floor.vertices": np.float32(floor_at(0)), "floor.vertices_end":
                        np.float32(floor_at(-RISE))})  # fmt: skip
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", content=body, headers=NPZ)
    assert response.status_code == 200, response.text
    np.testing.assert_allclose(
        closest_json(app_client, scene_name, o, d, times)["t"], 10 + height, rtol=1e-6
    )


def test_a_mesh_put_again_drops_its_end_vertices(app_client, scene_name):
    """End vertices belong to the vertices they were given with: a whole mesh PUT again (of the
    same vertex count or not) or an instance over it is static, not swept to the old ends."""
    upload_floor(app_client, scene_name)
    o, d, times = rays()
    frame = {"floor.vertices_end": floor_at(RISE)}
    assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).status_code == 200
    for vertices, faces in (quad(-9, 9, -9, 9, 2.0), tri_fan(2.0)):
        body = {"vertices": vertices.tolist(), "faces": faces.tolist()}
        response = app_client.put(f"/v1/scenes/{scene_name}/meshes/floor", json=body)
        assert response.status_code == 200 and response.json()["vertices_end"] is None, (
            response.text
        )
        np.testing.assert_allclose(closest_json(app_client, scene_name, o, d, times)["t"], 8.0)
        frame = {"floor.vertices_end": (vertices + [0, 0, RISE]).tolist()}
        assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).status_code == 200
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/other",
        json={"vertices": [[0, 0, 0]] * 3, "faces": [[0, 1, 2]]},
    )
    assert response.status_code == 201, response.text
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/floor", json={"instance_of": "other"}
    )
    assert response.status_code == 200 and response.json()["vertices_end"] is None, response.text


def tri_fan(z: float) -> tuple[np.ndarray, np.ndarray]:
    """A floor at height z of 5 vertices (the quad's 4 and its centre), 4 triangles."""
    vertices = np.array([[-9, -9, z], [9, -9, z], [9, 9, z], [-9, 9, z], [0, 0, z]], np.float32)
    return vertices, np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], np.int32)


def test_bad_vertices_end_are_422_naming_the_key(app_client, scene_name):
    upload_floor(app_client, scene_name)
    bad = np.float32(floor_at(1.0))
    bad[2, 1] = np.nan
    frames = [
        {"floor.vertices_end": floor_at(1.0)[:3]},
        {"floor.vertices_end": [[1, 2], [3, 4]]},
        {"floor.vertices_end": floor_at(1.0), "floor.transform": lift(1)},
        npz_bytes(**{"floor.vertices_end": bad}),
    ]
    for frame in frames:
        if isinstance(frame, dict):
            response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
        else:
            url = f"/v1/scenes/{scene_name}/frame"
            response = app_client.post(url, content=frame, headers=NPZ)
        assert response.status_code == 422, response.text
        assert "floor.vertices_end" in response.text, response.text


def test_a_restart_restores_end_vertices(tmp_path):
    settings = Settings(token=None, load_demo=False, data_dir=tmp_path)
    o, d, times = rays()
    with in_process.serve(settings) as http:
        upload_floor(http, "s")
        frame = {"floor.vertices_end": floor_at(RISE)}
        assert http.post("/v1/scenes/s/frame", json=frame).status_code == 200
        before = http.get("/v1/scenes/s/meshes/floor").json()
        answer = closest_json(http, "s", o, d, times)["t"]
    with in_process.serve(settings) as http:
        assert http.get("/v1/scenes/s/meshes/floor").json() == before
        assert before["vertices_end"] == 4
        np.testing.assert_array_equal(closest_json(http, "s", o, d, times)["t"], answer)


#: The PCD columns of the vector keys: (key, axis).
PCD_COLUMNS = {
    **{axis: ("xyz", k) for k, axis in enumerate("xyz")},
    **{f"velocity_{axis}": ("velocity", k) for k, axis in enumerate("xyz")},
}


@pytest.mark.parametrize(
    "fields, want",
    [
        ("velocity", ["velocity_x", "velocity_y", "velocity_z"]),
        ("range,velocity", ["range", "velocity_x", "velocity_y", "velocity_z"]),
        ("xyz,velocity,time", ["x", "y", "z", "velocity_x", "velocity_y", "velocity_z", "time"]),
        ("velocity_z,time,x,velocity_x", ["velocity_z", "time", "x", "velocity_x"]),
        ("velocity_y,velocity,y", ["velocity_y", "velocity_x", "velocity_z", "y"]),
    ],
)
def test_a_pcd_holds_velocity_as_three_fields(app_client, scene_name, fields, want):
    frame = box_frame("car", (-1.0, 9.0, -1.0), (1.0, 11.0, 1.0))
    frame["car.transform_end"] = [[1, 0, 0, 2.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).status_code == 200
    body = {
        "pose": np.eye(4).tolist(),
        "vertical_angles_deg": [0.0],
        "horizontal_steps": 360,
        "period_s": 0.1,
    }
    points = lidar_npz(app_client, scene_name, body)
    response = app_client.post(
        f"/v1/scenes/{scene_name}/lidar",
        params={"fields": fields},
        json=body,
        headers={"Accept": "application/x-pcd"},
    )
    assert response.status_code == 200, response.text
    header, records = read_pcd(response.content)
    assert header["FIELDS"] == want
    assert int(header["POINTS"][0]) == int(header["WIDTH"][0]) == len(points["ray"]) > 10
    assert header["HEIGHT"] == ["1"]
    # the fields in the order asked, a vector key's columns by their axis
    for name in want:
        key, axis = PCD_COLUMNS.get(name, (name, None))
        values = points[key] if axis is None else points[key][:, axis]
        np.testing.assert_array_equal(records[name], values)
    if "velocity_x" in want:
        np.testing.assert_allclose(records["velocity_x"], 20.0, atol=1e-3)


@pytest.mark.parametrize("accept", ["application/x-pcd", "application/json", "application/x-npz"])
def test_fields_a_lidar_without_period_does_not_answer_are_422(app_client, scene_name, accept):
    """Speeds and times come with period_s: asking only for them, of a lidar without it, would
    be an empty answer (a PCD of no field), so it is refused naming why."""
    frame = box_frame("car", (-1.0, 9.0, -1.0), (1.0, 11.0, 1.0))
    assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).status_code == 200
    body = {"pose": np.eye(4).tolist(), "vertical_angles_deg": [0.0], "horizontal_steps": 360}
    url = f"/v1/scenes/{scene_name}/lidar"
    for fields in ("velocity", "time,radial_speed"):
        response = app_client.post(
            url, params={"fields": fields}, json=body, headers={"Accept": accept}
        )
        assert response.status_code == 422, response.text
        assert "need period_s" in response.json()["detail"], response.text
    response = app_client.post(
        url, params={"fields": "range,velocity"}, json=body, headers={"Accept": accept}
    )
    assert response.status_code == 200, response.text  # the range, as a rig's sensor answers


def test_a_rig_sensor_that_answers_none_of_the_fields_is_422_naming_it(app_client, scene_name):
    """A rig's sensors answer ?fields= as each does alone: one that would answer nothing (the
    speeds of a lidar without period_s, a lidar's keys of a camera) is refused naming it."""
    frame = box_frame("car", (-1.0, 9.0, -1.0), (1.0, 11.0, 1.0))
    assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).status_code == 200
    still = {"kind": "lidar", "pose": np.eye(4).tolist(), "vertical_angles_deg": [0.0]}
    moving = {**still, "period_s": 0.1}
    camera = {
        "kind": "camera",
        "width": 4,
        "height": 3,
        "eye": [0, 0, 0],
        "target": [0, 10, 0],
        "up": [0, 0, 1],
    }
    url = f"/v1/scenes/{scene_name}/sensors"
    cases = [
        ({"roof": still}, "time", "sensors.roof: ?fields=time: this lidar answers none"),
        ({"spin": moving, "roof": still}, "velocity", "sensors.roof: ?fields=velocity: this"),
        ({"roof": moving, "front": camera}, "xyz,time", "sensors.front: ?fields=xyz,time: this "
         "camera answers none of them; it answers depth, range, mesh, prim, normal"),
    ]  # fmt: skip
    for sensors, fields, words in cases:
        response = app_client.post(url, params={"fields": fields}, json={"sensors": sensors})
        assert response.status_code == 422, response.text
        assert response.json()["detail"].startswith(words), response.text
    response = app_client.post(
        url, params={"fields": "range,velocity"}, json={"sensors": {"spin": moving, "roof": still}}
    )
    assert response.status_code == 200, response.text
    assert sorted(response.json()) == ["roof", "spin"]
    assert sorted(response.json()["roof"]) == ["range"]


def test_a_new_start_without_an_end_makes_a_mesh_static(app_client, scene_name):
    """A frame's new start placement of either kind (vertices, or a transform) and no end makes
    a mesh static whichever way it moved, and it may then take an end of the other kind."""
    upload_floor(app_client, scene_name)
    url = f"/v1/scenes/{scene_name}/frame"
    o, d, times = rays()
    info = lambda response: {m["mesh"]: m for m in response.json()["meshes"]}["floor"]  # noqa: E731
    moving = {"floor.transform": lift(0), "floor.transform_end": lift(RISE)}
    for frame in ({"floor.vertices": floor_at(1.0)}, {"floor.vertices": floor_at(1.0),
                  "floor.faces": quad(-9, 9, -9, 9, 0)[1].tolist()}):  # fmt: skip
        assert app_client.post(url, json=moving).status_code == 200
        response = app_client.post(url, json=frame)
        assert response.status_code == 200 and info(response)["transform_end"] is None
        np.testing.assert_allclose(closest_json(app_client, scene_name, o, d, times)["t"], 9.0)
    assert app_client.post(url, json=moving).status_code == 200
    frame = {"floor.vertices": floor_at(0), "floor.vertices_end": floor_at(RISE)}
    response = app_client.post(url, json=frame)
    assert response.status_code == 200, response.text
    assert info(response)["transform_end"] is None and info(response)["vertices_end"] == 4
    # the deforming floor placed by a transform and no end: static, as PUT .../transform makes it
    response = app_client.post(url, json={"floor.transform": lift(1.0)})
    assert response.status_code == 200, response.text
    assert info(response)["vertices_end"] is None
    np.testing.assert_allclose(closest_json(app_client, scene_name, o, d, times)["t"], 9.0)
