"""POST /v1/scenes/{scene}/render: the picture is what ``closest`` answers for the rays that the
documented camera convention gives (built here in numpy), shaded as docs/sensors.md says; the PNG
decodes with the requested size and mode; bad cameras and bodies are refused with a clear 4xx."""

from __future__ import annotations

import numpy as np
import pytest
from sensor_helpers import decode_png, look_at_rays, put_room

from service.timing import parse_server_timing

PALETTE = np.array(
    [
        [222, 200, 160],
        [140, 180, 220],
        [200, 140, 150],
        [150, 200, 150],
        [210, 180, 220],
        [230, 210, 120],
        [130, 200, 200],
        [220, 160, 120],
    ],
    np.float64,
)  # docs/sensors.md
BACKGROUND = (30, 33, 40)

#: A camera at the room's corner looking at the sphere, and one from above; up is +z.
CAMERAS = [
    {"eye": [-6.0, -7.0, 4.0], "target": [1.0, 1.0, 1.0], "up": [0, 0, 1], "fov_deg": 50.0},
    {"eye": [0.5, 0.25, 12.0], "target": [0.0, 0.0, 0.0], "up": [0, 1, 0], "fov_deg": 70.0},
]
SIZES = [(64, 48), (33, 17)]  # odd sizes put pixel centres on the optical axis


@pytest.fixture
def room(app_api, scene_name):
    put_room(app_api, scene_name)
    return scene_name


def render(app_client, scene, camera, width, height, shading, **headers):
    body = {**camera, "width": width, "height": height, "shading": shading}
    return app_client.post(f"/v1/scenes/{scene}/render", json=body, headers=headers)


def closest_image(app_api, scene, camera, width, height):
    """closest's answer (t, mesh, normal) for the camera's rays, as images, and the rays."""
    origins, directions, _ = look_at_rays(
        camera["eye"], camera["target"], camera["up"], camera["fov_deg"], width, height
    )
    hits = app_api.closest(scene, origins, directions, fields="t,mesh,normal")
    return (
        hits.t.reshape(height, width),
        hits.mesh.reshape(height, width),
        hits.normal.reshape(height, width, 3),
        directions.reshape(height, width, 3),
    )


@pytest.mark.parametrize("shading, mode", [("depth", "L"), ("normal", "RGB"), ("shaded", "RGB")])
@pytest.mark.parametrize("width, height", SIZES)
def test_the_answer_is_a_png_of_the_requested_size_and_mode(
    app_client, room, shading, mode, width, height
):
    response = render(app_client, room, CAMERAS[0], width, height, shading)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "image/png"
    assert int(response.headers["x-scene-version"]) == 3
    assert {"decode", "trace", "encode"} <= set(
        parse_server_timing(response.headers["server-timing"])
    )
    image = decode_png(response.content)
    assert image.size == (width, height) and image.mode == mode


@pytest.mark.parametrize("camera", CAMERAS)
@pytest.mark.parametrize("width, height", SIZES)
def test_depth_is_closest_t_along_the_view_axis(app_client, app_api, room, camera, width, height):
    t, _, _, _ = closest_image(app_api, room, camera, width, height)
    response = render(app_client, room, camera, width, height, "depth")
    grey = np.asarray(decode_png(response.content)).astype(int)
    hit = np.isfinite(t)
    assert hit.any() and not hit.all()
    near, far = (float(x) for x in response.headers["x-depth-range"].split())
    assert (near, far) == (float(t[hit].min()), float(t[hit].max()))
    expected = np.rint(255 - 200 * (t[hit].astype(np.float64) - near) / (far - near))
    assert np.array_equal(grey > 0, hit)  # a hit is never black, a miss always is
    assert np.abs(grey[hit] - expected).max() <= 1
    assert grey[hit].max() == 255 and grey[hit].min() == 55


@pytest.mark.parametrize("camera", CAMERAS)
def test_normal_picture_is_closest_normals(app_client, app_api, room, camera):
    t, _, normal, _ = closest_image(app_api, room, camera, 40, 30)
    response = render(app_client, room, camera, 40, 30, "normal")
    rgb = np.asarray(decode_png(response.content))
    hit = np.isfinite(t)
    expected = np.rint((normal.astype(np.float64) + 1) * 127.5)
    assert np.array_equal(rgb[hit], expected[hit])
    assert (rgb[~hit] == 0).all()


@pytest.mark.parametrize("camera", CAMERAS)
def test_shaded_picture_is_each_meshs_colour_lit_from_the_eye(app_client, app_api, room, camera):
    t, mesh, normal, directions = closest_image(app_api, room, camera, 40, 30)
    response = render(app_client, room, camera, 40, 30, "shaded")
    rgb = np.asarray(decode_png(response.content)).astype(int)
    hit = np.isfinite(t)
    d = directions.astype(np.float64)
    cosine = np.abs((d * normal).sum(-1)) / np.linalg.norm(d, axis=-1)
    expected = PALETTE[mesh[hit] % 8] * (0.15 + 0.85 * cosine[hit])[:, None]
    assert np.abs(rgb[hit] - expected).max() <= 1
    assert (rgb[~hit] == BACKGROUND).all()
    assert set(np.unique(mesh[hit])) == {0, 1, 2}  # the camera sees every mesh


def test_a_scene_that_is_missed_everywhere_is_black_without_a_depth_range(app_client, room):
    camera = {"eye": [0, 0, 20.0], "target": [0, 0, 30.0], "up": [0, 1, 0]}  # looking up
    response = render(app_client, room, camera, 8, 6, "depth")
    assert response.status_code == 200
    assert "x-depth-range" not in response.headers
    assert (np.asarray(decode_png(response.content)) == 0).all()


def test_defaults_are_up_y_a_60_degree_field_of_view_and_shaded(app_client, app_api, room):
    body = {"width": 20, "height": 10, "eye": [0.0, -9.0, 1.0], "target": [0.0, 0.0, 1.0]}
    response = app_client.post(f"/v1/scenes/{room}/render", json={**body, "up": [0, 0, 1]})
    explicit = render(
        app_client, room, {**body, "up": [0, 0, 1], "fov_deg": 60.0}, 20, 10, "shaded"
    )
    assert response.content == explicit.content
    default_up = app_client.post(f"/v1/scenes/{room}/render", json=body)
    assert default_up.status_code == 422  # up (0, 1, 0) is along the view: named below
    assert "parallel" in default_up.json()["detail"]


BASE = {
    "width": 8,
    "height": 6,
    "eye": [0.0, -5.0, 1.0],
    "target": [0.0, 0.0, 1.0],
    "up": [0, 0, 1],
}


@pytest.mark.parametrize(
    "change, words",
    [
        ({"target": [0.0, -5.0, 1.0]}, "same point"),
        ({"up": [0, 1, 0]}, "parallel"),
        ({"up": [0, -2, 0]}, "parallel"),
        ({"up": [0, 0, 0]}, "zero vector"),
        ({"fov_deg": 0}, "fov_deg"),
        ({"fov_deg": 180}, "fov_deg"),
        ({"width": 0}, "width"),
        ({"height": -3}, "height"),
        ({"width": 2.5}, "width"),
        ({"width": True}, "width"),
        ({"eye": [0, "1", 2]}, "eye[1]"),
        ({"eye": [0, 1]}, "eye"),
        ({"shading": "phong"}, "shading"),
    ],
)
def test_bad_cameras_and_values_are_422_naming_the_problem(app_client, room, change, words):
    response = app_client.post(f"/v1/scenes/{room}/render", json={**BASE, **change})
    assert response.status_code == 422, response.text
    assert words in response.json()["detail"]


@pytest.mark.parametrize("number", ["1e400", "NaN", "-Infinity"])
def test_numbers_must_be_finite(app_client, room, number):
    content = b'{"width": 8, "height": 6, "eye": [0, 0, 0], "target": [0, 1, %s]}' % number.encode()
    response = app_client.post(
        f"/v1/scenes/{room}/render", content=content, headers={"Content-Type": "application/json"}
    )
    assert response.status_code == 422, response.text
    assert "target[2]: Input should be a finite number" in response.json()["detail"]


@pytest.mark.parametrize(
    "content, status, words",
    [
        (b'{"width": 8, "height": 6, "eye": [0, -5, 1]}', 400, "target: missing"),
        (b'{"width": 8, "height": 6, "eye": [0,0,0], "target": [1,0,0], "zoom": 2}', 400, "zoom"),
        (b'{"width": 8,', 400, "not valid JSON"),
        (b"[1, 2]", 400, "object"),
    ],
)
def test_bodies_with_wrong_keys_or_no_json_object_are_400(app_client, room, content, status, words):
    response = app_client.post(
        f"/v1/scenes/{room}/render", content=content, headers={"Content-Type": "application/json"}
    )
    assert response.status_code == status, response.text
    assert words in response.json()["detail"]


def test_other_requests_are_refused_with_their_status(app_client, room, scene_name):
    url = f"/v1/scenes/{room}/render"
    too_large = {**BASE, "width": 2049, "height": 2048}  # 4 MiB + 2048 pixels
    response = app_client.post(url, json=too_large)
    assert response.status_code == 413 and "DACRT_MAX_IMAGE_PIXELS" in response.json()["detail"]
    for width, height in ((2**31, 1), (10**12, 10**12)):  # sides beyond the engine's 2**31 - 1
        response = app_client.post(url, json={**BASE, "width": width, "height": height})
        assert response.status_code == 413 and "DACRT_MAX_IMAGE_PIXELS" in response.text
    response = app_client.post(
        url, content=b"\x93NUMPY", headers={"Content-Type": "application/x-npy"}
    )
    assert response.status_code == 415
    response = app_client.post(url, json=BASE, headers={"Accept": "application/json"})
    assert response.status_code == 406 and "image/png" in response.json()["detail"]
    assert app_client.post(url, json=BASE, headers={"Accept": "image/*"}).status_code == 200
    response = app_client.post(url, json=BASE, headers={"Accept": "image/png;q=0, */*;q=0"})
    assert response.status_code == 406
    response = app_client.post(url, json=BASE, headers={"Accept": "image/png;q=0, */*;q=0.1"})
    assert response.status_code == 406 and "does not admit image/png" in response.json()["detail"]
    response = app_client.post(url + "?strategy=fast", json=BASE)
    assert response.status_code == 422 and "strategy" in response.json()["detail"]
    response = app_client.post(f"/v1/scenes/{scene_name}-none/render", json=BASE)
    assert response.status_code == 404
    response = app_client.post(url + "?fields=t", json=BASE)
    assert response.status_code == 422 and "fields" in response.json()["detail"]


def test_render_counts_its_rays_in_the_metrics(app_client, room):
    assert render(app_client, room, CAMERAS[0], 10, 10, "shaded").status_code == 200
    metrics = app_client.get("/metrics").text
    line = next(
        x for x in metrics.splitlines() if x.startswith('dacrt_rays_traced_total{query="render"}')
    )
    assert float(line.split()[-1]) >= 100
