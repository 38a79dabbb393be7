"""POST /v1/scenes/{scene}/camera: a depth camera's arrays are ``closest``'s answer for the rays of
the documented OpenCV convention (built here in numpy), its depth is the distance along the
optical axis (checked against the plain-numpy reference), and bad cameras are refused."""

from __future__ import annotations

import io

import numpy as np
import pytest
import reference
from sensor_helpers import (
    look_at_rays,
    npz,
    pinhole_rays,
    put_room,
    rigid_pose,
    room_triangles,
)

NPZ_ANSWER = {"Accept": "application/x-npz"}
FIELDS = ("depth", "range", "mesh", "prim", "normal")
LOOK = {"eye": [-6.0, -7.0, 4.0], "target": [1.0, 1.0, 1.0], "up": [0, 0, 1], "fov_deg": 50.0}
#: An OpenCV camera at (0, -7, 1) looking along +y: x right = +x, y down = -z, z forward = +y.
LEVEL_POSE = [[1.0, 0, 0, 0], [0, 0, 1.0, -7.0], [0, -1.0, 0, 1.0], [0, 0, 0, 1]]


@pytest.fixture
def room(app_api, scene_name):
    put_room(app_api, scene_name)
    return scene_name


def camera(app_client, scene, body, query="", **headers):
    return app_client.post(
        f"/v1/scenes/{scene}/camera{query}", json=body, headers={**NPZ_ANSWER, **headers}
    )


def check_against_closest(app_api, scene, answer, origins, directions, height, width, near=None,
                          far=None):  # fmt: skip
    hits = app_api.closest(scene, origins, directions, near, far)
    assert set(answer) == set(FIELDS)
    for name in ("depth", "range", "mesh", "prim"):
        assert answer[name].shape == (height, width), name
    assert answer["normal"].shape == (height, width, 3)
    assert answer["depth"].dtype == np.float32 and answer["mesh"].dtype == np.int32
    assert np.array_equal(answer["depth"].ravel(), hits.t)  # bit for bit: the same rays
    assert np.array_equal(answer["mesh"].ravel(), hits.mesh)
    assert np.array_equal(answer["prim"].ravel(), hits.prim)
    assert np.array_equal(answer["normal"].reshape(-1, 3), hits.normal)
    length = np.linalg.norm(directions.astype(np.float64), axis=1)
    assert np.array_equal(answer["range"].ravel(), (hits.t * length).astype(np.float32))
    return hits


@pytest.mark.parametrize("width, height", [(40, 30), (7, 12)])
def test_a_look_at_camera_answers_closest_for_its_pixels(app_client, app_api, room, width, height):
    response = camera(app_client, room, {**LOOK, "width": width, "height": height})
    assert response.status_code == 200, response.text
    assert int(response.headers["x-scene-version"]) == 3
    origins, directions, _ = look_at_rays(
        LOOK["eye"], LOOK["target"], LOOK["up"], LOOK["fov_deg"], width, height
    )
    check_against_closest(app_api, room, npz(response.content), origins, directions, height, width)


@pytest.mark.parametrize("yaw, pitch", [(0, 0), (30, 20), (-120, -35)])
def test_intrinsics_and_a_pose_answer_closest_for_their_pixels(
    app_client, app_api, room, yaw, pitch
):
    to_opencv = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1.0]])
    pose = rigid_pose(yaw, pitch, (-7.0, -6.0, 2.5)) @ to_opencv  # camera z along the body's x
    body = {"width": 36, "height": 20, "fx": 30.0, "fy": 24.0, "cx": 15.5, "cy": 11.25}
    response = camera(app_client, room, {**body, "pose": pose.tolist()})
    assert response.status_code == 200, response.text
    origins, directions = pinhole_rays(30.0, 24.0, 15.5, 11.25, pose, 36, 20)
    check_against_closest(app_api, room, npz(response.content), origins, directions, 20, 36)


def test_depth_is_the_distance_along_the_optical_axis(app_client, room):
    """Against the plain-numpy reference: depth = (hit - eye) . forward, range = |hit - eye|."""
    response = camera(app_client, room, {**LOOK, "width": 40, "height": 30})
    answer = npz(response.content)
    origins, directions, forward = look_at_rays(
        LOOK["eye"], LOOK["target"], LOOK["up"], LOOK["fov_deg"], 40, 30
    )
    vertices, faces, mesh_of_face = room_triangles()
    expected = reference.closest(vertices, faces, origins, directions)
    depth, ranges = answer["depth"].ravel(), answer["range"].ravel()
    both = expected.hit & np.isfinite(depth)
    assert both.sum() >= 0.99 * expected.hit.sum() and both.sum() >= 0.99 * np.isfinite(depth).sum()
    points = origins + expected.t[:, None] * directions.astype(np.float64)
    offsets = points - np.asarray(LOOK["eye"])
    assert np.allclose(depth[both], offsets[both] @ forward, rtol=1e-5)
    assert np.allclose(ranges[both], np.linalg.norm(offsets[both], axis=1), rtol=1e-5)
    assert np.array_equal(answer["mesh"].ravel()[both], mesh_of_face[expected.prim[both]])
    missed = ~np.isfinite(depth)
    assert np.isposinf(depth[missed]).all() and np.isposinf(ranges[missed]).all()
    assert (answer["mesh"].ravel()[missed] == -1).all()
    assert (answer["prim"].ravel()[missed] == -1).all()
    assert (answer["normal"].reshape(-1, 3)[missed] == 0).all()


def test_pixel_0_0_is_top_left_x_right_y_down(app_client, room):
    """The level camera sees sky in its top rows, the floor in its bottom rows, the sphere (at
    x = 3) right of the centre and the box (x < -2.5) left of it."""
    body = {"width": 64, "height": 48, "fx": 40.0, "fy": 40.0, "cx": 31.5, "cy": 23.5}
    answer = npz(camera(app_client, room, {**body, "pose": LEVEL_POSE}).content)
    mesh = answer["mesh"]
    assert (mesh[0] == -1).all() and np.isinf(answer["depth"][0]).all()
    assert (mesh[-1] == 0).all()
    sphere_columns, box_columns = np.nonzero(mesh == 1)[1], np.nonzero(mesh == 2)[1]
    assert len(sphere_columns) and len(box_columns)
    assert sphere_columns.min() > 31.5 > box_columns.max()
    # the same camera as a look-at: the same answer
    look_at = {"eye": [0.0, -7.0, 1.0], "target": [0.0, 0.0, 1.0], "up": [0.0, 0.0, 1.0]}
    fov = float(np.degrees(2 * np.arctan(24 / 40)))
    same = npz(
        camera(app_client, room, {**look_at, "fov_deg": fov, "width": 64, "height": 48}).content
    )
    assert np.array_equal(same["mesh"], mesh) and np.allclose(same["depth"], answer["depth"])


def test_near_and_far_limit_the_depth(app_client, app_api, room):
    body = {**LOOK, "width": 24, "height": 16, "near": 9.0, "far": 12.0}
    answer = npz(camera(app_client, room, body).content)
    origins, directions, _ = look_at_rays(
        LOOK["eye"], LOOK["target"], LOOK["up"], LOOK["fov_deg"], 24, 16
    )
    check_against_closest(app_api, room, answer, origins, directions, 16, 24, 9.0, 12.0)
    depth = answer["depth"][np.isfinite(answer["depth"])]
    assert len(depth) and depth.min() >= 9.0 and depth.max() <= 12.0


def test_fields_pick_arrays_and_formats_follow_accept(app_client, room):
    body = {**LOOK, "width": 6, "height": 4}
    answer = npz(camera(app_client, room, body, "?fields=mesh,depth").content)
    assert list(answer) == ["depth", "mesh"]
    response = camera(app_client, room, body, "?fields=depth", Accept="application/x-npy")
    depth = np.load(io.BytesIO(response.content), allow_pickle=False)
    assert depth.shape == (4, 6) and np.array_equal(depth, answer["depth"], equal_nan=True)
    as_json = app_client.post(f"/v1/scenes/{room}/camera", json=body).json()  # JSON by default
    assert list(as_json) == list(FIELDS)
    json_depth = np.array([[np.inf if x is None else x for x in row] for row in as_json["depth"]])
    assert np.array_equal(json_depth.astype(np.float32), answer["depth"])
    refused_json = camera(app_client, room, body, Accept="application/json;q=0, */*")
    assert refused_json.headers["content-type"] == "application/x-npz"
    response = camera(app_client, room, body, "?fields=depth,t")
    assert response.status_code == 422
    assert "'t'" in response.json()["detail"] and "depth, range" in response.json()["detail"]


BASE = {"width": 8, "height": 6}
INTRINSICS = {"fx": 10.0, "fy": 10.0, "cx": 3.5, "cy": 2.5, "pose": LEVEL_POSE}


@pytest.mark.parametrize(
    "body, status, words",
    [
        ({**BASE, **INTRINSICS, "eye": [0, 0, 0]}, 422, "not both"),
        ({**BASE, **INTRINSICS, "fov_deg": 40}, 422, "not both"),
        ({**BASE, "fx": 10.0, "fy": 10.0, "cx": 3.5, "cy": 2.5}, 400, "lacks pose"),
        ({**BASE, "eye": [0, 0, 0]}, 400, "lacks target"),
        ({**BASE, **INTRINSICS, "fx": 0}, 422, "fx"),
        ({**BASE, **INTRINSICS, "pose": [[2.0, 0, 0, 0], *LEVEL_POSE[1:]]}, 422, "rotation"),
        ({**BASE, **INTRINSICS, "pose": [[-1.0, 0, 0, 0], *LEVEL_POSE[1:]]}, 422, "determinant"),
        ({**BASE, **INTRINSICS, "pose": [*LEVEL_POSE[:3], [0, 0, 1, 1]]}, 422, "last row"),
        ({**BASE, **INTRINSICS, "pose": LEVEL_POSE[:3]}, 422, "pose"),
        ({**BASE, **INTRINSICS, "near": 5.0, "far": 5.0}, 422, "far"),
        ({**BASE, **INTRINSICS, "near": -1.0}, 422, "near"),
        ({**BASE, "eye": [1, 1, 1], "target": [1, 1, 1]}, 422, "same point"),
        ({**BASE, "eye": [0, 0, 0], "target": [0, 5, 0]}, 422, "parallel"),
    ],
)
def test_bad_cameras_are_refused_naming_the_problem(app_client, room, body, status, words):
    response = camera(app_client, room, body)
    assert response.status_code == status, response.text
    assert words in response.json()["detail"]


@pytest.mark.parametrize(
    "width, height",
    [(4096, 1025), (2**31, 1), (1, 2**31), (10**12, 10**12), (10**4000, 3)],
    ids=["4096x1025", "2**31x1", "1x2**31", "10**12x10**12", "10**4000x3"],
)
def test_a_picture_over_the_pixel_limit_is_413_whatever_its_sides(app_client, room, width, height):
    """Sides beyond the engine's own bound (2**31 - 1, 422) are over the pixel limit first."""
    body = {**LOOK, "width": width, "height": height}
    response = camera(app_client, room, body)
    assert response.status_code == 413 and "DACRT_MAX_IMAGE_PIXELS" in response.json()["detail"]
    rig = {"sensors": {"front": {**body, "kind": "camera"}}}
    response = app_client.post(f"/v1/scenes/{room}/sensors", json=rig)
    assert response.status_code == 413, response.text
    assert response.json()["detail"].startswith("front: ")
    assert "DACRT_MAX_IMAGE_PIXELS" in response.json()["detail"]


@pytest.mark.parametrize("width", [0, -(2**31), 2.5, True])
def test_a_side_that_is_not_a_positive_integer_is_still_422(app_client, room, width):
    response = camera(app_client, room, {**LOOK, "width": width, "height": 10**12})
    assert response.status_code == 422 and "width" in response.json()["detail"]


def test_the_query_strings_mask_is_every_pixels_ray_mask(app_client, app_api, room):
    """``?mask=`` (the batch options every query takes) masks a camera's rays as a query's."""
    body = {**LOOK, "width": 8, "height": 6}
    seen = npz(camera(app_client, room, body).content)
    assert (seen["mesh"] >= 0).any()
    same = npz(camera(app_client, room, body, "?mask=0xFFFFFFFF").content)
    assert np.array_equal(same["depth"], seen["depth"])
    hidden = npz(camera(app_client, room, body, "?mask=0").content)
    assert (hidden["mesh"] == -1).all() and np.isinf(hidden["depth"]).all()


@pytest.mark.parametrize(
    "route, body, key",
    [
        ("camera", b'{"width": %s, "height": 2, "eye": [3, 3, 3], "target": [0, 0, 0]}', "width"),
        (
            "sensors",
            b'{"sensors": {"front": {"kind": "camera", "width": 4, "height": %s, "eye": [3, 3, 3],'
            b' "target": [0, 0, 0]}}}',
            "sensors.front.height",
        ),
    ],
)
def test_an_integer_too_long_to_convert_is_422_naming_its_key(app_client, room, route, body, key):
    """Valid JSON: Python's limit on converting long integers is not the body's fault."""
    body = body % (b"1" + b"0" * 5000)
    response = app_client.post(
        f"/v1/scenes/{room}/{route}", content=body, headers={"Content-Type": "application/json"}
    )
    assert response.status_code == 422, response.text
    assert f"{key} is an integer of 5001 digits" in response.json()["detail"]


def test_edge_rays_a_legal_pose_takes_beyond_float32_are_named_by_the_cameras_keys(
    app_client, room
):
    pose = [[1.00004, 0, 0, 0.5], [0, 1.0, 0, 0.5], [0, 0, 1.0, -3.0], [0, 0, 0, 1]]  # legal
    tight = {"width": 2, "height": 1, "fx": 1 / 3.4028234663852886e38, "fy": 1.0, "cx": 0.0}
    body = {**tight, "cy": 0.0, "pose": pose}
    response = camera(app_client, room, body)
    assert response.status_code == 422, response.text
    assert response.json()["detail"].startswith("fx: ")
    assert "at this pose" in response.json()["detail"]
    rig = {"sensors": {"ok": {**LOOK, "width": 3, "height": 3, "kind": "camera"}}}
    rig["sensors"]["bad"] = {**body, "kind": "camera"}
    response = app_client.post(f"/v1/scenes/{room}/sensors", json=rig)
    assert response.status_code == 422, response.text
    assert response.json()["detail"].startswith("sensors.bad: fx: ")


def test_a_hit_whose_range_is_beyond_float32_is_a_miss_in_every_key(
    app_api, app_client, scene_name
):
    x, half = 1.6e38, 3.3e38
    wall = np.array([[x, -half, -half], [x, half, -half], [x, 0, half]], np.float32)
    app_api.put_mesh(scene_name, "wall", wall, np.array([[0, 1, 2]], np.int32))
    pose = [[0, 0, 1, -x], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]]
    body = {"width": 3, "height": 1, "fx": 2.5, "fy": 2.5, "cx": 1.0, "cy": 0.0, "pose": pose}
    image = npz(camera(app_client, scene_name, body).content)
    hit = np.isfinite(image["depth"])
    assert hit.tolist() == [[False, True, False]]  # the side pixels' range is 3.45e38
    np.testing.assert_array_equal(np.isfinite(image["range"]), hit)
    np.testing.assert_array_equal(image["mesh"] >= 0, hit)
    np.testing.assert_array_equal(image["normal"].any(axis=2), hit)
