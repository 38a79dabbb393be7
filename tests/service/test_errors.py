"""Every error status of API.md on a real server: the status, a {"detail": str} body whose message
names the problem, and (for changes) that a rejected request changes nothing."""

from __future__ import annotations

import asyncio
import json
import logging
import re

import httpx
import numpy as np
import pytest
from mesh_files import BAD_MESH_FILES, GLB, png, triangle_glb
from service_helpers import NPY, NPZ, TOKEN, down_rays, grid, npy_bytes, npz_bytes, quad

from service.client import APIError, Client
from service.errors import CatchAll

RAYS = np.hstack(down_rays([[0.5, 0.5], [0.2, 0.7]])).astype(np.float32)


@pytest.fixture
def quad_scene(app_api, scene_name):
    app_api.put_mesh(scene_name, "m", *quad(0, 1, 0, 1, 0))
    return scene_name


def detail(response: httpx.Response, status: int) -> str:
    """The detail of an error answer, after checking its status and shape."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json"
    body = response.json()
    assert list(body) == ["detail"] and isinstance(body["detail"], str) and body["detail"]
    return body["detail"]


def state(app_api: Client, scene: str) -> dict:
    """What a rejected request must leave unchanged: scene info (version, meshes, bounds) and
    the answer of a query."""
    return {
        "info": app_api.scene(scene),
        "t": app_api.closest(scene, *down_rays([[0.5, 0.5], [0.9, 0.1]])).t.tolist(),
    }


# ---- 400: the body cannot be parsed


@pytest.mark.parametrize(
    "path, body, headers, message",
    [
        ("closest", b"\x93NUMPY garbage", NPY, "not a readable .npy"),
        ("closest", npy_bytes(RAYS)[:-7], NPY, "truncated"),
        ("closest", b"PK\x03\x04 nope", NPZ, "not a readable .npz"),
        ("closest", npz_bytes(origins=RAYS[:, :3]), NPZ, "lacks 'directions'"),
        (
            "closest",
            b'{"origins": [[0,0,0]], "directions": ',
            {"Content-Type": "application/json"},
            "not valid JSON",
        ),
        (
            "occluded",
            b'{"origin": [], "directions": []}',
            {"Content-Type": "application/json"},
            "lacks 'origins'",
        ),
        ("meshes/m", npz_bytes(vertices=quad(0, 1, 0, 1, 0)[0]), NPZ, "lacks 'faces'"),
        (
            "meshes/m",
            b"not an obj at all",
            {"Content-Type": "model/obj"},
            "no triangles found in the OBJ",
        ),
        ("meshes/m", b"ply\ngarbage", {"Content-Type": "application/ply"}, "cannot be read as PLY"),
        ("frame", npz_bytes(**{"m.normals": RAYS}), NPZ, "not MESH.vertices or MESH.faces"),
    ],
)
def test_unparseable_bodies_are_400(app_client, app_api, quad_scene, path, body, headers, message):
    before = state(app_api, quad_scene)
    method = "PUT" if path.startswith("meshes") else "POST"
    assert message in detail(
        app_client.request(
            method, f"/v1/scenes/{quad_scene}/{path}", content=body, headers=headers
        ),
        400,
    )
    assert state(app_api, quad_scene) == before


def test_a_body_of_many_unknown_keys_names_a_few_and_counts_the_others(app_client, quad_scene):
    """However many unknown keys a body has, and however long, the message names the first few
    (cut) and counts the others."""
    keys = {"x" * 100_000: 0, **{f"a{k}": 0 for k in range(10_000)}}
    body = {"origins": RAYS[:, :3].tolist(), "directions": RAYS[:, 3:].tolist(), **keys}
    message = detail(app_client.post(f"/v1/scenes/{quad_scene}/closest", json=body), 400)
    assert message.startswith("body has unknown keys 'xxxxxxxx")
    assert "... (100000 characters), 'a0', 'a1', 'a2', 'a3' and 9,996 more; expected" in message
    assert len(message) < 1000


# ---- 401: token configured


@pytest.fixture
def secure(secure_server):
    with httpx.Client(base_url=secure_server, timeout=60) as c:
        yield c


@pytest.mark.parametrize(
    "headers, message",
    [
        ({}, "Authorization: Bearer"),
        ({"Authorization": "Bearer wrong"}, "token is wrong"),
        ({"Authorization": f"Basic {TOKEN}"}, "Authorization: Bearer"),
        ({"Authorization": "Bearer"}, "Bearer"),
    ],
)
@pytest.mark.parametrize(
    "method, path",
    [
        ("GET", "/v1/scenes"),
        ("GET", "/v1/capabilities"),
        ("PUT", "/v1/scenes/s/meshes/m"),
        ("POST", "/v1/scenes/s/closest"),
        ("POST", "/v1/trace"),
        ("DELETE", "/v1/scenes/s"),
    ],
)
def test_every_v1_route_needs_the_token(secure, headers, message, method, path):
    response = secure.request(method, path, headers=headers, content=b"")
    assert message in detail(response, 401) and response.headers["www-authenticate"] == "Bearer"


def test_the_right_token_works_and_health_and_metrics_are_open(secure_server, scene_name):
    with Client(secure_server, token=TOKEN) as client:
        client.put_mesh(scene_name, "m", *quad(0, 1, 0, 1, 0))
        assert client.closest(scene_name, RAYS).t.tolist() == [10, 10]
        assert client.capabilities()["auth"] is True
        client.delete(scene_name)
    assert httpx.get(f"{secure_server}/health").json()["status"] == "ok"
    assert httpx.get(f"{secure_server}/metrics").status_code == 200


# ---- 404: unknown scene or mesh


@pytest.mark.parametrize(
    "method, path, message",
    [
        ("GET", "/v1/scenes/{missing}", "no scene"),
        ("DELETE", "/v1/scenes/{missing}", "no scene"),
        ("POST", "/v1/scenes/{missing}/closest", "no scene"),
        ("POST", "/v1/scenes/{missing}/occluded", "no scene"),
        ("GET", "/v1/scenes/{scene}/meshes/nope", "has no mesh 'nope'"),
        ("DELETE", "/v1/scenes/{scene}/meshes/nope", "has no mesh 'nope'"),
        ("PUT", "/v1/scenes/{scene}/meshes/nope/vertices", "has no mesh 'nope'"),
        ("PUT", "/v1/scenes/{missing}/meshes/m/vertices", "no scene"),
        ("GET", "/v1/nowhere", "Not Found"),
    ],
)
def test_unknown_things_are_404(app_client, quad_scene, method, path, message):
    url = path.format(scene=quad_scene, missing=quad_scene + "-missing")
    assert message in detail(
        app_client.request(method, url, content=npy_bytes(RAYS), headers=NPY), 404
    )


def test_frame_moving_an_unknown_mesh_is_404_and_changes_nothing(app_client, app_api, quad_scene):
    before = state(app_api, quad_scene)
    body = npz_bytes(
        **{"m.vertices": quad(0, 1, 0, 1, 3)[0], "ghost.vertices": quad(0, 1, 0, 1, 3)[0]}
    )
    assert "no mesh 'ghost'" in detail(
        app_client.post(f"/v1/scenes/{quad_scene}/frame", content=body, headers=NPZ), 404
    )
    assert state(app_api, quad_scene) == before


# ---- 406, 409


def test_unacceptable_accept_is_406(app_client, quad_scene):
    response = app_client.post(
        f"/v1/scenes/{quad_scene}/closest",
        content=npy_bytes(RAYS),
        headers={**NPY, "Accept": "text/csv"},
    )
    assert "application/x-npz" in detail(response, 406)


@pytest.mark.parametrize("route", ["vertices", "frame"])
def test_vertex_count_change_is_409_and_changes_nothing(app_client, app_api, quad_scene, route):
    app_api.put_mesh(quad_scene, "other", *quad(5, 6, 0, 1, 0))
    before = state(app_api, quad_scene)
    nine = grid(2, z=1)[0]
    if route == "vertices":
        response = app_client.put(
            f"/v1/scenes/{quad_scene}/meshes/m/vertices", content=npy_bytes(nine), headers=NPY
        )
    else:  # the first mesh of the frame is fine: it must not be applied either
        response = app_client.post(
            f"/v1/scenes/{quad_scene}/frame",
            headers=NPZ,
            content=npz_bytes(**{"other.vertices": quad(5, 6, 0, 1, 2)[0], "m.vertices": nine}),
        )
    assert "has 4 vertices but the update has 9" in detail(response, 409)
    assert state(app_api, quad_scene) == before


# ---- 413: limits (on the secure server: 64 KiB bodies, 1000 rays, 1000 triangles, 200000 bytes)


@pytest.fixture
def limited(secure_server):
    with Client(secure_server, token=TOKEN) as client:
        yield client


def test_body_over_the_limit_is_413(limited, scene_name):
    limited.put_mesh(scene_name, "m", *quad(0, 1, 0, 1, 0))
    with pytest.raises(APIError) as caught:
        limited.closest(scene_name, np.zeros((3000, 6), np.float32))  # 72 KB
    assert caught.value.status == 413 and "DACRT_MAX_BODY_BYTES" in caught.value.detail
    assert "65536" in caught.value.detail


def test_too_many_rays_is_413(limited, scene_name):
    limited.put_mesh(scene_name, "m", *quad(0, 1, 0, 1, 0))
    with pytest.raises(APIError) as caught:
        limited.closest(scene_name, *down_rays(np.zeros((1001, 2))))
    assert caught.value.status == 413
    assert caught.value.detail.startswith("1001 rays") and "limit of 1000" in caught.value.detail


def test_too_many_triangles_is_413_and_changes_nothing(limited, scene_name):
    limited.put_mesh(scene_name, "a", *grid(20))  # 800 triangles
    before = limited.scene(scene_name)
    for call in (
        lambda: limited.put_mesh(scene_name, "b", *grid(15)),  # +450
        lambda: limited.frame(scene_name, {"a": grid(20, z=1)[0], "b": grid(15)}),
    ):
        with pytest.raises(APIError) as caught:
            call()
        assert caught.value.status == 413 and "1250 triangles" in caught.value.detail
        assert "DACRT_MAX_TRIANGLES_PER_SCENE" in caught.value.detail
    assert limited.scene(scene_name) == before
    limited.delete(scene_name)


def test_a_one_shot_trace_of_too_many_triangles_is_413(limited):
    """/v1/trace builds a scene of its mesh: the limit of a stored scene bounds it too."""
    rays = down_rays(np.zeros((2, 2)))
    with pytest.raises(APIError) as caught:
        limited.trace(*grid(23), *rays)  # 1058 triangles
    assert caught.value.status == 413
    assert caught.value.detail == (
        "the trace's mesh has 1058 triangles, over the limit of 1000 "
        "(DACRT_MAX_TRIANGLES_PER_SCENE)"
    )
    assert len(limited.trace(*grid(22), *rays).t) == 2  # 968 triangles


def test_total_scene_memory_over_the_limit_is_413(limited, scene_name):
    mesh = grid(16)  # 289 vertices and 512 faces: 9612 bytes, and 512 x 168 of engine scene
    limited.put_mesh(scene_name + "-1", "m", *mesh)
    limited.put_mesh(scene_name + "-2", "m", *mesh)
    try:
        with pytest.raises(APIError) as caught:
            limited.put_mesh(scene_name + "-3", "m", *mesh)
        assert caught.value.status == 413 and "DACRT_MAX_SCENE_BYTES" in caught.value.detail
        assert scene_name + "-3" not in [s["scene"] for s in limited.scenes()]
    finally:
        limited.delete(scene_name + "-1")
        limited.delete(scene_name + "-2")


# ---- 415: unsupported Content-Type


@pytest.mark.parametrize(
    "path, headers, params",
    [
        ("closest", {"Content-Type": "text/plain"}, {}),
        ("closest", {"Content-Type": "application/x-www-form-urlencoded"}, {}),
        ("closest", {"Content-Type": "model/obj"}, {}),
        ("closest", NPY, {"format": "csv"}),
        ("meshes/m", {"Content-Type": "image/png"}, {}),
        ("meshes/m/vertices", {"Content-Type": "model/stl"}, {}),
        ("frame", NPY, {}),
    ],
)
def test_unsupported_content_type_is_415(app_client, app_api, quad_scene, path, headers, params):
    before = state(app_api, quad_scene)
    method = "PUT" if path.startswith("meshes") else "POST"
    response = app_client.request(
        method,
        f"/v1/scenes/{quad_scene}/{path}",
        content=npy_bytes(RAYS),
        headers=headers,
        params=params,
    )
    assert "use one of" in detail(response, 415)
    assert state(app_api, quad_scene) == before


# ---- 403 and 415: pages of other sites, and DNS rebinding


@pytest.fixture
def loopback(app_client):
    """The in-process app as a request arriving on the loopback address sees it."""
    with httpx.Client(transport=app_client._transport, base_url="http://localhost") as client:
        yield client


FRAME = json.dumps({"evil.vertices": quad(0, 1, 0, 1, 0)[0].tolist(), "evil.faces": [[0, 1, 2]]})


@pytest.mark.parametrize(
    "headers, params, status, message",
    [
        (
            {"Content-Type": "text/plain;charset=UTF-8"},
            {"format": "json"},
            415,
            "is not the format",
        ),
        (
            {"Content-Type": "application/json", "Origin": "http://attacker.example"},
            {},
            403,
            "from the page of another origin (http://attacker.example) is refused",
        ),
        ({"Content-Type": "application/json", "Origin": "null"}, {}, 403, "another origin"),
        (
            {"Content-Type": "application/json", "Host": "attacker.example"},
            {},
            403,
            "Host 'attacker.example' is not one this server answers to",
        ),
        (
            {"Content-Type": "application/json", "Host": "attacker.example:8000"},
            {},
            403,
            "DACRT_ALLOWED_HOSTS",
        ),
    ],
)
def test_a_page_of_another_site_cannot_change_a_scene(
    loopback, app_api, quad_scene, headers, params, status, message
):
    before = state(app_api, quad_scene)
    url = f"/v1/scenes/{quad_scene}/frame"
    response = loopback.post(url, content=FRAME, headers=headers, params=params)
    assert message in detail(response, status)
    assert state(app_api, quad_scene) == before


@pytest.mark.parametrize(
    "headers",
    [
        {"Origin": "http://localhost"},  # the server's own page (the viewer)
        {"Host": "127.0.0.1:8000", "Origin": "http://127.0.0.1:8000"},
        {"Host": "[::1]:8000"},
        {"Host": "LOCALHOST"},
    ],
)
def test_the_servers_own_pages_and_loopback_names_are_answered(loopback, quad_scene, headers):
    headers = {"Content-Type": "application/json", **headers}
    response = loopback.post(f"/v1/scenes/{quad_scene}/frame", content=FRAME, headers=headers)
    assert response.status_code == 200, response.text


# ---- 422: well-formed, invalid values


def _bad_faces() -> bytes:
    vertices = np.zeros((90000, 3), np.float32)
    faces = np.zeros((1100, 3), np.int32)
    faces[1043, 1] = 90211
    return npz_bytes(vertices=vertices, faces=faces)


def _nan_vertex() -> bytes:
    vertices, faces = quad(0, 1, 0, 1, 0)
    vertices[2, 1] = np.nan
    return npz_bytes(vertices=vertices, faces=faces)


@pytest.mark.parametrize(
    "path, body, message",
    [
        (
            "meshes/m",
            _bad_faces(),
            "faces[1043] refers to vertex 90211, but there are 90000 vertices",
        ),
        ("meshes/m", _nan_vertex(), "vertices[2] is not finite"),
        (
            "meshes/m",
            npz_bytes(vertices=np.zeros((3, 3)), faces=np.zeros((1, 3), np.int32)),
            "must be little-endian float32",
        ),
        (
            "meshes/m",
            npz_bytes(vertices=np.zeros((3, 3), np.float32), faces=np.zeros((1, 3), np.int64)),
            "int32 or uint32",
        ),
        (
            "meshes/m",
            npz_bytes(
                vertices=np.zeros((3, 3), np.float32), faces=np.array([None, 1], dtype=object)
            ),
            "Python objects",
        ),
        ("meshes/m/vertices", npy_bytes(np.zeros((4, 2), np.float32)), "shape (N, 3)"),
        (
            "meshes/m/vertices",
            npy_bytes(np.full((4, 3), np.inf, np.float32)),
            "vertices[0] is not finite",
        ),
        ("closest", npy_bytes(np.zeros((2, 6), np.float64)), "float32, got <f8"),
        ("closest", npy_bytes(np.array([{"x": 1}], dtype=object)), "Python objects"),
        (
            "frame",
            npz_bytes(
                **{
                    "m.vertices": quad(0, 1, 0, 1, 1)[0],
                    "bad name.vertices": quad(0, 1, 0, 1, 0)[0],
                }
            ),
            "mesh name 'bad name'",
        ),
    ],
)
def test_invalid_values_are_422_and_change_nothing(
    app_client, app_api, quad_scene, path, body, message
):
    before = state(app_api, quad_scene)
    method = "PUT" if path.startswith("meshes") else "POST"
    headers = NPY if body.startswith(b"\x93NUMPY") else NPZ
    assert message in detail(
        app_client.request(
            method, f"/v1/scenes/{quad_scene}/{path}", content=body, headers=headers
        ),
        422,
    )
    assert state(app_api, quad_scene) == before


# ---- mesh files: malformed or hostile files are 400, 413 or 422 and change nothing


@pytest.mark.parametrize("body, headers, status, message", BAD_MESH_FILES)
def test_bad_mesh_files_are_4xx_and_change_nothing(
    app_client, app_api, quad_scene, body, headers, status, message
):
    before = state(app_api, quad_scene)
    response = app_client.put(f"/v1/scenes/{quad_scene}/meshes/m", content=body, headers=headers)
    assert message in detail(response, status)
    assert state(app_api, quad_scene) == before


def test_glb_textures_are_not_decoded_and_the_mesh_is_stored(app_client, scene_name):
    image = png(8000, 8000)  # 192 MB decoded
    body = triangle_glb(images=[image, image])
    response = app_client.put(f"/v1/scenes/{scene_name}/meshes/m", content=body, headers=GLB)
    assert response.status_code == 201 and response.json()["triangles"] == 1
    app_client.delete(f"/v1/scenes/{scene_name}")


@pytest.mark.parametrize(
    "method, url",
    [
        ("GET", "/v1/scenes/bad%20name"),
        ("GET", "/v1/scenes/{scene}/meshes/a%2Ab"),
        ("GET", "/v1/scenes/" + "x" * 65),
        ("POST", "/v1/scenes/bad$/closest"),
        ("DELETE", "/v1/scenes/a%3Ab"),
    ],
)
def test_bad_names_are_422(app_client, quad_scene, method, url):
    response = app_client.request(
        method, url.format(scene=quad_scene), content=npy_bytes(RAYS), headers=NPY
    )
    assert "1-64 characters of A-Z a-z 0-9 _ - ." in detail(response, 422)


def test_bad_name_on_upload_is_422(app_client, scene_name):
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/caf%C3%A9",
        headers=NPZ,
        content=npz_bytes(vertices=quad(0, 1, 0, 1, 0)[0], faces=quad(0, 1, 0, 1, 0)[1]),
    )
    assert "mesh name 'café'" in detail(response, 422)
    assert app_client.get(f"/v1/scenes/{scene_name}").status_code == 404


def _bad_rays(kind: str, rows=(3, 8), n: int = 10) -> np.ndarray:
    """(n, 8) rays straight down at the quad, made bad at ``rows`` in the way ``kind`` says."""
    rays = np.zeros((n, 8), np.float32)
    rays[:, 0:3], rays[:, 3:6], rays[:, 7] = [0.5, 0.5, 10], [0, 0, -1], np.inf
    for row in rows:
        if kind == "nan-origin":
            rays[row, 0] = np.nan
        elif kind == "inf-direction":
            rays[row, 4] = np.inf
        elif kind == "zero-direction":
            rays[row, 3:6] = 0
        elif kind == "tmin-over-tmax":
            rays[row, 6:8] = [5, 4]
    return rays


@pytest.mark.parametrize(
    "kind", ["nan-origin", "inf-direction", "zero-direction", "tmin-over-tmax"]
)
@pytest.mark.parametrize("query", ["closest", "occluded"])
def test_bad_rays_are_422_naming_the_first_one_and_the_count(app_client, quad_scene, kind, query):
    body = npy_bytes(_bad_rays(kind))
    message = detail(
        app_client.post(f"/v1/scenes/{quad_scene}/{query}", content=body, headers=NPY), 422
    )
    assert re.search(r"\b3\b", message) and re.search(r"\b2\b", message), message


MANY_FIELDS = ",".join(f"f{k}" for k in range(6000))  # 34,889 characters: not echoed whole


@pytest.mark.parametrize(
    "params, message",
    [
        ({"fields": "t,depth"}, "unknown fields 'depth'"),
        ({"fields": ","}, "no field"),
        (
            {"fields": MANY_FIELDS},
            f"?fields={MANY_FIELDS[:100]}... ({len(MANY_FIELDS)} characters) names unknown fields "
            "'f0', 'f1', 'f2', 'f3', 'f4' and 5995 more",
        ),
        ({"strategy": "magic"}, "unknown strategy 'magic'"),
        ({"stats": "maybe"}, "query parameter 'stats'"),
        ({"cull": "sideways"}, "unknown cull 'sideways'; use one of none, back, front"),
    ],
)
def test_bad_options_are_422(app_client, quad_scene, params, message):
    response = app_client.post(
        f"/v1/scenes/{quad_scene}/closest", content=npy_bytes(RAYS), headers=NPY, params=params
    )
    assert message in detail(response, 422)


def test_bad_one_shot_query_kind_is_422(app_client):
    vertices, faces = quad(0, 1, 0, 1, 0)
    body = npz_bytes(
        vertices=vertices, faces=faces, origins=RAYS[:, :3].copy(), directions=RAYS[:, 3:].copy()
    )
    assert "unknown query 'hitz'" in detail(
        app_client.post("/v1/trace?query=hitz", content=body, headers=NPZ), 422
    )


def test_client_raises_api_error_with_the_detail(app_api):
    with pytest.raises(APIError) as caught:
        app_api.scene("does-not-exist")
    assert caught.value.status == 404 and "no scene 'does-not-exist'" in caught.value.detail
    assert json.loads(caught.value.response.text) == {"detail": caught.value.detail}


async def _collect(app, path="/x"):
    sent = []

    async def send(message):
        sent.append(message)

    await CatchAll(app)({"type": "http", "method": "GET", "path": path}, None, send)
    return sent


def test_an_error_after_the_answer_started_closes_the_connection_rather_than_answer_twice():
    async def app(scope, receive, send):
        await send({"type": "http.response.start", "status": 200, "headers": []})
        raise RuntimeError("failed mid-answer")

    with pytest.raises(RuntimeError, match="failed mid-answer"):
        asyncio.run(_collect(app))


def test_an_error_before_the_answer_is_a_json_500():
    async def app(scope, receive, send):
        raise RuntimeError("failed")

    sent = asyncio.run(_collect(app))
    assert [m["type"] for m in sent] == ["http.response.start", "http.response.body"]
    assert sent[0]["status"] == 500 and b"the error is in its log" in sent[1]["body"]


def test_an_unhandled_error_logs_its_path_escaped_on_one_line(caplog):
    """A path is percent-decoded: its %0a and %1b must not start a log line or colour one."""

    async def app(scope, receive, send):
        raise RuntimeError("failed")

    with caplog.at_level(logging.ERROR, logger="service"):
        asyncio.run(_collect(app, "/x\nERROR:    service: forged\x1b[31m"))
    [record] = caplog.records
    assert record.getMessage() == "unhandled error in GET /x\\nERROR:    service: forged\\x1b[31m"
