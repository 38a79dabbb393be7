"""The service through service.client (and raw httpx where the wire itself is under test): in
process (``app_api``, ``app_client``), and end to end on a real uvicorn process (``client``,
``http``) for warm-up, chunked bodies, streamed answers and one reference check. Answers are
compared with a plain-NumPy brute force."""

from __future__ import annotations

import io
import json
import zipfile

import httpx
import numpy as np
import placed_checks
import pytest
import reference
from service_helpers import NPY, NPZ, down_rays, grid, npy_bytes, npz_bytes, quad, rays_at

import dacrt
from service import wire
from service.client import Answer, APIError, Client, rays_array

CLOSEST_FIELDS = ("t", "mesh", "prim", "u", "v", "normal")


@pytest.fixture
def teapot_scene(app_api, scene_name, teapot):
    app_api.put_mesh(scene_name, "teapot", *teapot)
    return scene_name


@pytest.fixture
def server_teapot_scene(client, scene_name, teapot):
    """``teapot_scene`` on the real server."""
    client.put_mesh(scene_name, "teapot", *teapot)
    return scene_name


def assert_same_answer(a: Answer, b: Answer) -> None:
    assert list(a) == list(b)
    for key in a:
        assert a[key].dtype == b[key].dtype and np.array_equal(a[key], b[key]), key


# ---- operations


def test_health_is_ok_once_warm(client):
    health = client.health()
    assert health["status"] == "ok" and health["warmup_seconds"] >= 0


def test_capabilities_list_formats_fields_strategies_and_limits(app_api):
    caps = app_api.capabilities()
    assert caps["fields"]["closest"] == list(CLOSEST_FIELDS) and caps["fields"]["occluded"] == [
        "occluded"
    ]
    assert caps["strategies"][0] == caps["default_strategy"] and len(caps["strategies"]) >= 1
    assert (
        "model/obj" in caps["formats"]["meshes"] and "application/x-npy" in caps["formats"]["rays"]
    )
    assert caps["limits"]["max_rays_per_request"] == 16 * 2**20 and caps["auth"] is False
    lidar = caps["fields"]["lidar"]
    assert lidar[-4:] == ["label", "time", "velocity", "radial_speed"]
    assert "pcd" not in caps["fields"]
    assert "application/x-pcd" in caps["formats"]["lidar_answers"]
    assert caps["limits"]["max_patterns"] == 64
    assert caps["limits"]["max_meshes_per_scene"] == 4096


def test_metrics_count_requests_rays_and_memory(app_api, app_client, teapot_scene):
    app_api.closest(teapot_scene, *down_rays(np.zeros((7, 2))))
    text = app_client.get("/metrics").text
    assert (
        'dacrt_requests_total{method="POST",route="/v1/scenes/{scene}/closest",status="200"}'
        in text
    )
    assert 'dacrt_rays_traced_total{query="closest"}' in text
    assert "dacrt_trace_seconds_bucket" in text
    memory = float(
        next(
            line.split()[-1]
            for line in text.splitlines()
            if line.startswith("dacrt_scene_memory_bytes ")
        )
    )
    assert memory >= 3644 * 12 + 6320 * 12


# ---- meshes and scenes


def test_put_mesh_is_201_then_200_with_mesh_info(app_client, scene_name):
    vertices, faces = quad(-1, 2, 0, 1, 3)
    body = npz_bytes(vertices=vertices, faces=faces)
    first = app_client.put(f"/v1/scenes/{scene_name}/meshes/floor", content=body, headers=NPZ)
    again = app_client.put(f"/v1/scenes/{scene_name}/meshes/floor", content=body, headers=NPZ)
    assert (first.status_code, again.status_code) == (201, 200)
    assert first.json() == {
        "scene": scene_name,
        "mesh": "floor",
        "index": 0,
        "vertices": 4,
        "triangles": 2,
        "bounds": [[-1, 0, 3], [2, 1, 3]],
        "version": 1,
        "mask": 0xFFFFFFFF,
        "transform": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        "instance_of": None,
        "reflectivity": 0.5,
        "label": 0,
        "transform_end": None,
        "vertices_end": None,
    }
    assert again.json()["version"] == 2 and again.json()["index"] == 0


def test_json_mesh_body(app_client, scene_name):
    vertices, faces = quad(0, 1, 0, 1, 0)
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/m",
        json={"vertices": vertices.tolist(), "faces": faces.tolist()},
    )
    assert response.status_code == 201 and response.json()["triangles"] == 2


def test_scene_info_and_list(app_api, scene_name):
    app_api.put_mesh(scene_name, "a", *quad(0, 1, 0, 1, 0))
    app_api.put_mesh(scene_name, "b", *grid(2, z=5))
    info = app_api.scene(scene_name)
    assert info["version"] == 2 and info["triangles"] == 10
    assert info["bounds"] == [[0, 0, 0], [1, 1, 5]]
    assert [(m["mesh"], m["index"], m["version"]) for m in info["meshes"]] == [
        ("a", 0, 1),
        ("b", 1, 2),
    ]
    assert info in app_api.scenes()
    assert app_api.http.get(f"/v1/scenes/{scene_name}/meshes/b").json() == info["meshes"][1]


def test_delete_mesh_and_scene(app_api, scene_name):
    app_api.put_mesh(scene_name, "a", *quad(0, 1, 0, 1, 0))
    app_api.put_mesh(scene_name, "b", *quad(0, 1, 0, 1, 1))
    app_api.delete_mesh(scene_name, "a")
    assert [m["mesh"] for m in app_api.scene(scene_name)["meshes"]] == ["b"]
    app_api.delete(scene_name)
    with pytest.raises(APIError) as caught:
        app_api.scene(scene_name)
    assert caught.value.status == 404
    assert all(s["scene"] != scene_name for s in app_api.scenes())


def test_update_vertices_moves_the_mesh_and_keeps_faces(app_api, scene_name):
    app_api.put_mesh(scene_name, "m", *quad(0, 1, 0, 1, 0))
    info = app_api.update_vertices(scene_name, "m", quad(0, 1, 0, 1, 4)[0])
    assert info["version"] == 2 and info["triangles"] == 2 and info["bounds"][0][2] == 4
    hits = app_api.closest(scene_name, *down_rays([[0.5, 0.5]]))
    assert hits.t.tolist() == [6.0] and hits.version == 2


def test_json_vertices_update(app_client, app_api, scene_name):
    app_api.put_mesh(scene_name, "m", *quad(0, 1, 0, 1, 0))
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/m/vertices",
        json={"vertices": quad(0, 1, 0, 1, 2)[0].tolist()},
    )
    assert response.status_code == 200 and response.json()["bounds"][1][2] == 2


def test_frame_moves_and_adds_meshes_in_one_version(app_api, scene_name):
    app_api.put_mesh(scene_name, "a", *quad(0, 1, 0, 1, 0))
    info = app_api.frame(scene_name, {"a": quad(0, 1, 0, 1, 2)[0], "b.part": quad(1, 2, 0, 1, 3)})
    assert info["version"] == 2 and [m["mesh"] for m in info["meshes"]] == ["a", "b.part"]
    hits = app_api.closest(scene_name, *down_rays([[0.5, 0.5], [1.5, 0.5]]))
    assert hits.t.tolist() == [8.0, 7.0] and hits.mesh.tolist() == [0, 1]


# ---- queries


def test_closest_matches_the_reference(client, server_teapot_scene, teapot):
    vertices, faces = teapot
    origins, directions = rays_at(vertices, faces, 400, seed=1)
    directions[::4] *= -1  # a quarter point away: mostly misses
    hits = client.closest(server_teapot_scene, origins, directions)
    expected = reference.closest(vertices, faces, origins, directions)
    t, prim = expected.t, expected.prim
    assert np.isfinite(t).sum() > 250
    np.testing.assert_allclose(hits.t, t, rtol=1e-4)
    assert np.mean(hits.prim == prim) > 0.99
    hit = hits.prim >= 0
    assert (hits.mesh[hit] == 0).all() and (hits.mesh[~hit] == -1).all()
    # the hit point from u, v lies on the ray; the normal is the unit geometric normal
    p = vertices[faces[hits.prim[hit]]].astype(np.float64)
    u, v = hits.u[hit, None], hits.v[hit, None]
    on_triangle = (1 - u - v) * p[:, 0] + u * p[:, 1] + v * p[:, 2]
    on_ray = origins[hit] + hits.t[hit, None] * directions[hit]
    np.testing.assert_allclose(on_triangle, on_ray, atol=1e-3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    np.testing.assert_allclose(
        hits.normal[hit], n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-4
    )
    assert (hits.normal[~hit] == 0).all() and (hits.u[~hit] == 0).all()


def test_chunked_ray_body_without_content_length_gets_the_same_answer(
    http, client, server_teapot_scene, teapot
):
    origins, directions = rays_at(*teapot, 3000, seed=4)
    body = npy_bytes(np.hstack([origins, directions]).astype(np.float32))
    pieces = (body[i : i + 4096] for i in range(0, len(body), 4096))  # a generator: sent chunked
    response = http.post(
        f"/v1/scenes/{server_teapot_scene}/closest",
        content=pieces,
        headers={**NPY, "Accept": wire.NPZ},
    )
    assert response.status_code == 200 and "content-length" not in response.request.headers
    chunked = np.load(io.BytesIO(response.content))
    expected = client.closest(server_teapot_scene, origins, directions)
    assert np.isfinite(expected.t).sum() > 1000
    assert np.array_equal(chunked["t"], expected.t) and np.array_equal(
        chunked["prim"], expected.prim
    )


def test_query_errors_raise_api_error_with_the_servers_message(app_api, teapot_scene, scene_name):
    origins, directions = down_rays(np.full((3, 2), 0.5))
    with pytest.raises(APIError) as missing:
        app_api.closest(scene_name + "-missing", origins, directions)
    assert missing.value.status == 404 and "missing" in missing.value.detail
    directions[1] = np.nan
    with pytest.raises(APIError) as bad:
        app_api.occluded(teapot_scene, origins, directions)
    assert bad.value.status == 422 and "directions[1]" in bad.value.detail


def test_occluded_equals_closest_within_tmax(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 300, seed=2)
    tmax = np.random.default_rng(3).uniform(0.5, 1.5, 300).astype(np.float32)
    hits = app_api.closest(teapot_scene, origins, directions)
    occluded = app_api.occluded(teapot_scene, origins, directions, tmax=tmax)
    assert occluded.occluded.dtype == bool
    assert np.array_equal(occluded.occluded, hits.t <= tmax)


@pytest.mark.parametrize("cull", ["back", "front"])
def test_cull_is_the_engines(app_api, teapot_scene, teapot, cull):
    """?cull= on closest, occluded and the one-shot trace answers as the engine does."""
    origins, directions = rays_at(*teapot, 300, seed=4)
    engine = dacrt.Scene([teapot])
    expected = engine.closest(origins, directions, cull=cull)
    assert (expected.prim >= 0).sum() > 50, "vacuous: few hits"
    hits = app_api.closest(teapot_scene, origins, directions, cull=cull)
    assert np.array_equal(hits.t, expected.t) and np.array_equal(hits.prim, expected.prim)
    occluded = app_api.occluded(teapot_scene, origins, directions, cull=cull)
    assert np.array_equal(occluded.occluded, np.isfinite(expected.t))
    once = app_api.trace(*teapot, origins, directions, cull=cull)
    assert np.array_equal(once.t, expected.t) and np.array_equal(once.prim, expected.prim)
    if cull == "front":
        assert not np.array_equal(hits.t, engine.closest(origins, directions).t), "vacuous"


def test_tmin_and_tmax_bound_the_hits(app_api, scene_name):
    app_api.put_mesh(scene_name, "near", *quad(0, 1, 0, 1, 5))
    app_api.put_mesh(scene_name, "far", *quad(0, 1, 0, 1, 1))
    origins, directions = down_rays(np.full((3, 2), 0.5))
    hits = app_api.closest(
        scene_name, origins, directions, tmin=[0, 6, 0], tmax=[np.inf, np.inf, 4]
    )
    assert hits.t.tolist() == [5, 9, np.inf] and hits.mesh.tolist() == [0, 1, -1]


def test_fields_limit_the_answer(app_api, teapot_scene):
    hits = app_api.closest(teapot_scene, *down_rays([[0, 0]], z=10), fields="t,prim")
    assert list(hits) == ["t", "prim"]


def test_every_strategy_gives_the_same_answer(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 300, seed=4)
    answers = [
        app_api.closest(teapot_scene, origins, directions, strategy=s)
        for s in app_api.capabilities()["strategies"]
    ]
    for other in answers[1:]:
        assert_same_answer(answers[0], other)


def test_stats_header_has_the_engine_counters(app_api, teapot_scene, teapot):
    hits = app_api.closest(teapot_scene, *rays_at(*teapot, 100), stats=True)
    for key in (
        "rays",
        "triangles",
        "ray_box_tests",
        "ray_triangle_tests",
        "nodes",
        "sampled_nodes",
        "skipped_filterings",
    ):
        assert isinstance(hits.stats[key], int), key
    assert hits.stats["rays"] == 100 and hits.stats["triangles"] == 6320
    occluded = app_api.occluded(teapot_scene, *rays_at(*teapot, 100), stats=True)
    assert occluded.stats["rays"] == 100
    assert app_api.closest(teapot_scene, *rays_at(*teapot, 5)).stats is None


@pytest.mark.parametrize("query", ["closest", "occluded"])
def test_every_query_answer_has_version_and_server_timing(app_client, teapot_scene, query):
    response = app_client.post(
        f"/v1/scenes/{teapot_scene}/{query}",
        headers=NPY,
        content=npy_bytes(np.hstack(down_rays([[0, 0]])).astype(np.float32)),
    )
    assert response.status_code == 200 and response.headers["x-scene-version"] == "1"
    timing = response.headers["server-timing"]
    assert all(f"{name};dur=" in timing for name in ("decode", "trace", "encode"))


def test_json_binary_and_npy_answers_are_equal(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 200, seed=5)
    directions[::3] *= -1
    npz = app_api.closest(teapot_scene, origins, directions)
    for answer in ("json", "npy"):
        assert_same_answer(npz, app_api.closest(teapot_scene, origins, directions, answer=answer))
    single = app_api.closest(teapot_scene, origins, directions, answer="npy", fields="t")
    assert np.array_equal(single.t, npz.t)
    occluded = app_api.occluded(teapot_scene, origins, directions)
    assert_same_answer(occluded, app_api.occluded(teapot_scene, origins, directions, answer="json"))
    assert_same_answer(occluded, app_api.occluded(teapot_scene, origins, directions, answer="npy"))


def test_json_request_gets_json_with_null_for_misses(app_client, app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 50, seed=6)
    directions[::2] *= -1
    body = {"origins": origins.tolist(), "directions": directions.tolist(), "tmax": None}
    response = app_client.post(f"/v1/scenes/{teapot_scene}/closest", json=body)
    assert response.headers["content-type"] == "application/json"
    document = response.json()
    binary = app_api.closest(teapot_scene, origins, directions)
    t = np.array([np.inf if x is None else x for x in document["t"]], np.float32)
    assert None in document["t"] and np.array_equal(t, binary.t)
    assert document["mesh"] == binary.mesh.tolist()
    assert np.array_equal(np.array(document["normal"], np.float32), binary.normal)


def test_npz_answer_is_a_zip_whose_every_crc_is_right(http, client, server_teapot_scene, teapot):
    """The server takes each member's CRC-32 as it sends the answer (wire.NpzBody)."""
    origins, directions = rays_at(*teapot, 300, seed=11)
    body = npy_bytes(np.hstack([origins, directions]).astype(np.float32))
    response = http.post(f"/v1/scenes/{server_teapot_scene}/closest", content=body, headers=NPY)
    assert int(response.headers["content-length"]) == len(response.content)
    archive = zipfile.ZipFile(io.BytesIO(response.content))
    assert archive.testzip() is None and archive.namelist() == [
        f"{key}.npy" for key in CLOSEST_FIELDS
    ]
    expected = client.closest(server_teapot_scene, origins, directions)
    assert np.isfinite(expected.t).all()  # every ray hits the teapot
    with np.load(io.BytesIO(response.content)) as got:
        for key in CLOSEST_FIELDS:
            assert np.array_equal(got[key], expected[key]), key


def test_npz_ray_body_equals_npy_ray_body(app_client, app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 50, seed=7)
    tmax = np.float32(2.0)
    body = npz_bytes(True, origins=origins, directions=directions, tmax=tmax)
    response = app_client.post(f"/v1/scenes/{teapot_scene}/closest", content=body, headers=NPZ)
    with np.load(io.BytesIO(response.content)) as got:
        assert np.array_equal(
            got["t"], app_api.closest(teapot_scene, origins, directions, tmax=tmax).t
        )


@pytest.mark.parametrize(
    "query, key, shape", [("closest", "normal", (0, 3)), ("occluded", "occluded", (0,))]
)
def test_empty_batch_answers_empty_arrays(app_api, teapot_scene, query, key, shape):
    answer = app_api.query(teapot_scene, query, np.zeros((0, 3)), np.zeros((0, 3)))
    assert answer[key].shape == shape
    assert (
        app_api.query(teapot_scene, query, np.zeros((0, 3)), np.zeros((0, 3)), answer="json")[
            key
        ].shape
        == shape
    )


def test_scene_without_triangles_answers_misses(app_api, scene_name):
    app_api.put_mesh(scene_name, "empty", np.zeros((0, 3)), np.zeros((0, 3)))
    hits = app_api.closest(scene_name, *down_rays(np.zeros((4, 2))))
    assert np.isinf(hits.t).all() and (hits.mesh == -1).all() and (hits.prim == -1).all()
    assert not app_api.occluded(scene_name, *down_rays(np.zeros((4, 2)))).occluded.any()
    app_api.delete_mesh(scene_name, "empty")
    assert np.isinf(app_api.closest(scene_name, *down_rays(np.zeros((2, 2)))).t).all()


def test_hits_report_each_mesh_by_its_stable_index(app_api, scene_name):
    for i, name in enumerate(["a", "b", "c"]):
        app_api.put_mesh(scene_name, name, *quad(i, i + 1, 0, 1, 0))
    app_api.delete_mesh(scene_name, "b")
    app_api.put_mesh(scene_name, "d", *quad(1, 2, 0, 1, 0))  # where b was: gets a new index, 3
    app_api.put_mesh(scene_name, "e", np.zeros((0, 3)), np.zeros((0, 3)))  # no triangles: index 4
    app_api.put_mesh(scene_name, "f", *quad(3, 4, 0, 1, 0))
    hits = app_api.closest(
        scene_name, *down_rays([[0.5, 0.5], [1.5, 0.5], [2.5, 0.5], [3.5, 0.5], [9, 9]])
    )
    assert hits.mesh.tolist() == [0, 3, 2, 5, -1]
    assert {m["mesh"]: m["index"] for m in app_api.scene(scene_name)["meshes"]} == {
        "a": 0,
        "c": 2,
        "d": 3,
        "e": 4,
        "f": 5,
    }


def test_prim_is_the_row_in_its_own_mesh(app_api, scene_name):
    app_api.put_mesh(scene_name, "first", *grid(4, z=0))
    app_api.put_mesh(scene_name, "second", *quad(0, 1, 0, 1, 3))
    hits = app_api.closest(scene_name, *down_rays([[0.25, 0.75]]))
    assert (hits.mesh[0], hits.prim[0]) == (1, 1)  # the second triangle of the quad


# ---- one-shot


def test_one_shot_trace_equals_a_stored_scene(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 200, seed=8)
    stored = app_api.closest(teapot_scene, origins, directions)
    once = app_api.trace(*teapot, origins, directions)
    assert once.version == 0
    assert_same_answer(stored, once)
    occluded = app_api.trace(*teapot, origins, directions, tmax=0.5, query="occluded")
    assert np.array_equal(occluded.occluded, stored.t <= 0.5)


def test_one_shot_trace_with_json(app_client):
    vertices, faces = quad(0, 1, 0, 1, 0)
    origins, directions = down_rays([[0.5, 0.5], [5, 5]])
    response = app_client.post(
        "/v1/trace?query=closest&fields=t,mesh",
        json={
            "vertices": vertices.tolist(),
            "faces": faces.tolist(),
            "origins": origins.tolist(),
            "directions": directions.tolist(),
        },
    )
    assert response.status_code == 200 and response.headers["x-scene-version"] == "0"
    assert response.json() == {"t": [10.0, None], "mesh": [0, -1]}


# ---- mesh files


def _mesh_file(fmt: str) -> tuple[bytes, int, np.ndarray]:
    """A two-object file (a 2x2x2 box at the origin, a ball at x = 4): body, triangles, bounds."""
    import trimesh

    box = trimesh.creation.box(extents=[2, 2, 2])
    ball = trimesh.creation.icosphere(subdivisions=2)
    ball.apply_translation([4, 0, 0])
    scene = trimesh.Scene({"box": box, "ball": ball})
    data = scene.to_mesh().export(file_type=fmt) if fmt == "off" else scene.export(file_type=fmt)
    return (
        (data.encode() if isinstance(data, str) else data),
        len(box.faces) + len(ball.faces),
        scene.bounds,
    )


@pytest.mark.parametrize(
    "fmt, content_type",
    [
        ("obj", "model/obj"),
        ("ply", "application/ply"),
        ("stl", "model/stl"),
        ("glb", "model/gltf-binary"),
        ("off", "model/off"),
    ],
)
def test_mesh_files_by_content_type(app_client, app_api, scene_name, fmt, content_type):
    body, n_faces, bounds = _mesh_file(fmt)
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/things",
        content=body,
        headers={"Content-Type": content_type},
    )
    assert response.status_code == 201, response.text
    info = response.json()
    assert info["triangles"] == n_faces
    np.testing.assert_allclose(info["bounds"], bounds, atol=1e-5)
    hits = app_api.closest(scene_name, [[0, 0, 10], [4, 0, 10]], [[0, 0, -1], [0, 0, -1]])
    assert hits.t[0] == 9 and 9 <= hits.t[1] < 9.2  # the box's top, then the ball's


@pytest.mark.parametrize("fmt", ["obj", "ply", "stl", "glb", "off"])
def test_mesh_files_by_format_parameter(app_client, app_api, scene_name, tmp_path, fmt):
    body, n_faces, _ = _mesh_file(fmt)
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/raw",
        content=body,
        params={"format": fmt},
        headers={"Content-Type": "application/octet-stream"},
    )
    assert response.status_code == 201 and response.json()["triangles"] == n_faces
    path = tmp_path / f"things.{fmt}"
    path.write_bytes(body)
    assert app_api.put_mesh(scene_name, "from-file", file=path)["triangles"] == n_faces


# ---- hits, count, masks and the intersector through the client


def test_hits_and_count_through_the_client_match_the_engine(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 300, seed=31)
    engine = dacrt.Scene([teapot])
    hits = app_api.hits(teapot_scene, origins, directions, max_hits=3, cull="back")
    expected = engine.hits(origins, directions, max_hits=3, cull="back")
    for key in ("offsets", "t", "mesh", "prim", "u", "v", "normal", "truncated"):
        assert np.array_equal(hits[key], getattr(expected, key)), key
    assert expected.truncated.any() and hits.version == 1
    count = app_api.count(teapot_scene, origins, directions, tmax=1.5, answer="npy")
    assert np.array_equal(count.count, engine.count(origins, directions, tmax=1.5).count)
    ray_array = np.hstack([origins, directions, np.zeros((300, 1)), np.full((300, 1), 1.5)])
    assert np.array_equal(app_api.count(teapot_scene, ray_array).count, count.count)


@pytest.mark.parametrize("query", ["closest", "occluded", "hits", "count"])
def test_mask_on_every_query_of_the_client(app_api, teapot_scene, teapot, query):
    """One mask (sent as ?mask=) or one per ray (sent in an .npz body), with the JSON answer."""
    origins, directions = rays_at(*teapot, 60, seed=32)
    masks = np.where(np.arange(60) % 2 == 0, 0, 0xF0).astype(np.uint32)
    engine = dacrt.Scene([teapot])
    for mask in (masks, 0, 0x10):
        answer = app_api.query(teapot_scene, query, origins, directions, mask=mask, answer="json")
        expected = getattr(engine, query)(origins, directions, mask=mask)
        for key in answer:
            assert np.array_equal(answer[key], getattr(expected, key)), (mask, key)
    once = app_api.trace(*teapot, origins, directions, query=query, mask=masks)
    expected = getattr(engine, query)(origins, directions, mask=masks)
    assert all(np.array_equal(once[key], getattr(expected, key)) for key in once)


def recording_client(answers: dict[str, dict]) -> tuple[Client, list[httpx.Request]]:
    """A client whose requests are recorded and answered with ``answers[path]`` (JSON)."""
    sent = []

    def handle(request: httpx.Request) -> httpx.Response:
        sent.append(request)
        return httpx.Response(200, json=answers[request.url.path])

    http = httpx.Client(base_url="http://recorded", transport=httpx.MockTransport(handle))
    return Client(http=http), sent


def test_set_transform_and_mesh_masks_send_what_the_contract_says():
    info = {"scene": "s", "mesh": "m", "index": 0}
    client, sent = recording_client(
        {"/v1/scenes/s/meshes/m/transform": info, "/v1/scenes/s/meshes/m": info}
    )
    matrix = np.eye(4)
    matrix[:3, 3] = [1, 2, 3.5]
    assert client.set_transform("s", "m", matrix) == info
    request = sent[-1]
    assert request.method == "PUT" and request.headers["content-type"] == "application/json"
    assert json.loads(request.content) == {
        "matrix": [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3.5], [0, 0, 0, 1]]
    }
    client.put_mesh("s", "m", *quad(0, 1, 0, 1, 0), mask=0xF0)
    assert sent[-1].url.params["mask"] == "240" and sent[-1].method == "PUT"
    client.put_mesh("s", "m", file=b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", format="obj", mask=3)
    assert dict(sent[-1].url.params) == {"format": "obj", "mask": "3"}
    client.put_mesh("s", "m", *quad(0, 1, 0, 1, 0))
    assert "mask" not in sent[-1].url.params
    with pytest.raises(ValueError, match="mask must lie in"):
        client.put_mesh("s", "m", *quad(0, 1, 0, 1, 0), mask=-1)


RAY = np.array([0, 1.5, -10.0]), np.array([0, 0, 1.0])
TWO = np.zeros((2, 3)), np.tile([0, 0, 1.0], (2, 1))


@pytest.mark.parametrize(
    "call, phrase",
    [
        (lambda c: c.closest("s", *RAY), r"origins must have shape \(n, 3\), got \(3,\)"),
        (lambda c: c.closest("s", np.zeros((2, 2)), TWO[1]), r"origins .* got \(2, 2\)"),
        (lambda c: c.hits("s", TWO[0], np.array([0, 0, 1])), r"directions .* got \(3,\)"),
        (lambda c: c.count("s", TWO[0], TWO[1][:1]), "origins has 2 rows but directions has 1"),
        (lambda c: c.occluded("s", *TWO, tmin=[0, 1, 2]), r"tmin .* shape \(2,\).* got \(3,\)"),
        (lambda c: c.closest("s", *TWO, tmax=np.ones((2, 1))), r"tmax .* got \(2, 1\)"),
        (lambda c: c.closest("s", np.zeros((2, 6)), tmax=[1, 2, 3]), r"tmax .* got \(3,\)"),
        (lambda c: c.closest("s", [["0", "0", "0"]], [[0, 0, 1]]), "origins must be numbers"),
        (lambda c: c.closest("s", *TWO, mask=[1, 2, 3]), r"mask must have shape \(2,\)"),
        (lambda c: c.trace(*quad(0, 1, 0, 1, 0), *RAY), r"origins .* got \(3,\)"),
        (lambda c: c.trace(*quad(0, 1, 0, 1, 0), *TWO, tmin=np.zeros(5)), r"tmin .* got \(5,\)"),
        (lambda c: c.trace(*quad(0, 1, 0, 1, 0), *TWO, mask=np.ones((2, 2), int)), "mask must"),
    ],
)
def test_rays_of_a_wrong_shape_raise_naming_the_argument_and_send_nothing(call, phrase):
    client, sent = recording_client({})
    with pytest.raises(ValueError, match=phrase):
        call(client)
    assert sent == []


V3 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
I4 = np.eye(4)


@pytest.mark.parametrize(
    "call, phrase",
    [
        (lambda c: c.put_mesh("s", "m", V3, [[0, 1, 2.9]]), "faces must be integers"),
        (lambda c: c.put_mesh("s", "m", V3, np.array([[0, 1, 2**32 + 3]])), "beyond int32"),
        (lambda c: c.put_mesh("s", "m", V3), "give faces"),
        (lambda c: c.put_mesh("s", "m"), "give vertices and faces, or file="),
        (lambda c: c.put_mesh("s", "m", file=b"v", format="fbx"), "format must be one of npz"),
        (lambda c: c.put_mesh("s", "m", file="mesh.xyz"), "the suffix '.xyz' names none"),
        (lambda c: c.frame("s", {"m": (V3, [[0, 1, 2.5]])}), r"meshes\['m'\] faces must be"),
        (lambda c: c.trace(V3, [[0, 1, 9.5]], *TWO), "faces must be integers"),
        (lambda c: c.put_pattern("p", [0.0], [0.0], channel=np.array([70000])), "channel"),
        (lambda c: c.put_pattern("p", [0.0], [0.0], channel=[0.5]), "channel must be integers"),
        (lambda c: c.closest("s", *TWO, answer="xml"), "answer must be one of npz, npy, json"),
        (lambda c: c.query("s", "bogus", *TWO), "query must be one of closest"),
        (lambda c: c.closest("s", *TWO, fields=[1]), "fields must be names"),
        (lambda c: c.set_transform("s", "m", np.full((4, 4), np.nan)), r"matrix\[0\]\[0\] is nan"),
        (lambda c: c.set_material("s", "m", reflectivity=np.inf), "reflectivity is inf"),
        (
            lambda c: c.lidar("s", pose=np.eye(4), noise={"range_sigma": np.nan}),
            "noise.range_sigma",
        ),
        (lambda c: c.camera("s", eye=[np.inf, 0, 0]), r"eye\[0\] is inf"),
        (lambda c: c.scene(""), "scene name must be"),
        (lambda c: c.delete(".."), "scene name must be"),
        (lambda c: c.put_pattern("a b", [0.0], [0.0]), "pattern name must be"),
        (lambda c: c.put_mesh("s", 5, V3, [[0, 1, 2]]), "mesh name must be"),
        (lambda c: c.closest("s", *TWO, time=[0.0, 1.5]), r"time\[1\] is 1.5: each time must"),
        (lambda c: c.hits("s", *TWO, time=np.nan), r"time\[0\] is nan"),
        (lambda c: c.count("s", *TWO, time=[0.5]), r"time must be a scalar or .*\(2,\)"),
        (lambda c: c.occluded("s", *TWO, time=["0", "1"]), "time must be numbers"),
        (lambda c: c.trace(V3, [[0, 1, 2]], *TWO, time=-0.5), r"time\[0\] is -0.5"),
        (lambda c: c.frame("s", {"m": {"colour": 1}}), r"meshes\['m'\] has 'colour', not a"),
        (lambda c: c.frame("s", {"m": (V3,)}), r"meshes\['m'\] is a tuple of 1: give"),
        (lambda c: c.frame("s", {"m": {"label": -1}}), r"meshes\['m'\] label must lie in"),
        (lambda c: c.frame("s", {"m": {"mask": 2.0}}), r"meshes\['m'\] mask must be an"),
        (lambda c: c.frame("s", {"m": {"instance_of": "a/b"}}), r"meshes\['m'\] instance_of"),
        (lambda c: c.frame("s", {"m": {"transform": "I"}}), r"meshes\['m'\] transform must"),
        (lambda c: c.set_mask("s", "m", 2**32), "mask must lie in"),
        (lambda c: c.put_instance("s", "m", "c/d"), "source mesh name must be"),
        (lambda c: c.put_instance("s", "m", "car", mask=-1), "mask must lie in"),
        (lambda c: c.mesh("s", "m?x"), "mesh name must be"),
    ],
)
def test_misuse_raises_naming_the_argument_and_sends_nothing(call, phrase):
    """Nothing is rounded, wrapped or dropped on the way: faces that are not whole numbers or
    beyond int32, channels beyond the server's range and NaN in a JSON body are the caller's
    errors, named, as are unknown formats and choices."""
    client, sent = recording_client({})
    with pytest.raises(ValueError, match=phrase):
        call(client)
    assert sent == []


@pytest.mark.parametrize(
    "call",
    [
        lambda c: c.delete("cl#anything"),
        lambda c: c.scene("cl/meshes/x"),
        lambda c: c.put_mesh("cl", "y#z", V3, [[0, 1, 2]]),
        lambda c: c.closest("a?b=1", *TWO),
        lambda c: c.delete_pattern("p/q"),
        lambda c: c.delete_mesh("s", "m%2Fx"),
        lambda c: c.scene("x" * 65),
    ],
)
def test_a_name_that_is_not_one_path_segment_is_refused(call):
    """Names are checked as the server checks them: ``delete("cl#x")`` deleted scene ``cl``, and
    the server decodes ``%2F`` before routing, so quoting would not keep a name one segment."""
    client, sent = recording_client({})
    with pytest.raises(ValueError, match="name must be 1-64 characters"):
        call(client)
    assert sent == []


def test_answers_that_are_not_the_services_raise_api_error():
    def handle(request: httpx.Request) -> httpx.Response:
        if request.url.path == "/health":
            return httpx.Response(503, text="<html>bad gateway</html>")
        if request.url.path == "/v1/scenes/moved":
            return httpx.Response(307, headers={"location": "/v1/scenes"})
        return httpx.Response(200, content=b"PK not a zip", headers={"content-type": wire.NPZ})

    client = Client(http=httpx.Client(base_url="http://x", transport=httpx.MockTransport(handle)))
    assert client.health() == {
        "status": "error",
        "http_status": 503,
        "detail": "<html>bad gateway</html>",
    }
    with pytest.raises(APIError) as moved:
        client.scene("moved")
    assert moved.value.status == 307
    with pytest.raises(APIError, match="the answer cannot be read") as unreadable:
        client.closest("s", *TWO)
    assert unreadable.value.status == 200


def test_the_service_intersector_answers_as_the_in_process_one(app_client, teapot):
    import trimesh

    from dacrt.trimesh_ray import RayMeshIntersector as InProcess
    from service.intersector import RayMeshIntersector as OnService

    mesh = trimesh.Trimesh(*teapot, process=False)
    local = InProcess(mesh)
    origins, directions = rays_at(*teapot, 300, seed=33)
    directions[::3] *= -1
    points = np.random.default_rng(34).uniform(*mesh.bounds, (400, 3))
    api = Client(http=app_client)
    with OnService(mesh, client=api) as remote:
        scene = remote.scene
        assert api.scene(scene)["triangles"] == len(mesh.faces)
        for method in ("intersects_first", "intersects_any", "intersects_location"):
            got = getattr(remote, method)(origins, directions)
            want = getattr(local, method)(origins, directions)
            for a, b in zip(*((x if isinstance(x, tuple) else (x,)) for x in (got, want))):
                assert a.dtype == b.dtype and np.array_equal(a, b), method
        index_tri, index_ray = remote.intersects_id(origins, directions, max_hits=2)
        want_tri, want_ray = local.intersects_id(origins, directions, max_hits=2)
        assert np.array_equal(index_tri, want_tri) and np.array_equal(index_ray, want_ray)
        assert np.array_equal(remote.contains_points(points), local.contains_points(points))
    with pytest.raises(APIError) as gone:
        api.scene(scene)
    assert gone.value.status == 404
    kept = OnService(mesh, client=api, scene="kept-" + scene, mesh_name="pot")
    kept.close()
    assert [m["mesh"] for m in api.scene("kept-" + scene)["meshes"]] == ["pot"]
    with pytest.raises(ValueError, match=r"holds other meshes \(pot\)"):
        OnService(mesh, client=api, scene="kept-" + scene)  # its answers would name pot's
    assert [m["mesh"] for m in api.scene("kept-" + scene)["meshes"]] == ["pot"]
    api.delete("kept-" + scene)


def test_the_service_intersector_keeps_precision_far_away_and_follows_the_mesh(app_client):
    """A sphere at map coordinates (5e5, 5e6) answers as in process (its box centre is moved to
    the origin on both); a moved mesh is uploaded again; a dropped intersector's scene is
    deleted, with a ResourceWarning."""
    import gc

    import trimesh

    from dacrt.trimesh_ray import RayMeshIntersector as InProcess
    from service.intersector import RayMeshIntersector as OnService

    mesh = trimesh.creation.icosphere(2, radius=5.0).apply_translation((5e5, 5e6, 100.0))
    rng = np.random.default_rng(36)
    points = mesh.bounding_box.sample_volume(1000, seed=37)
    origins = mesh.centroid + rng.normal(size=(500, 3)) * 20
    directions = mesh.centroid + rng.normal(size=(500, 3)) - origins
    api = Client(http=app_client)
    with OnService(mesh, client=api) as remote:
        local = InProcess(mesh)
        inside = remote.contains_points(points)
        assert np.array_equal(inside, local.contains_points(points)) and 300 < inside.sum() < 700
        first = remote.intersects_first(origins, directions)
        assert np.array_equal(first, local.intersects_first(origins, directions))
        mesh.apply_translation((100.0, 0.0, 0.0))
        assert not remote.contains_points(points).any()  # uploaded again, moved
        version = api.scene(remote.scene)["version"]
        remote.contains_points(points)
        assert api.scene(remote.scene)["version"] == version  # unchanged: not sent again
    dropped = OnService(mesh, client=api)
    scene = dropped.scene
    with pytest.warns(ResourceWarning, match=scene):
        del dropped
        gc.collect()
    with pytest.raises(APIError) as gone:
        api.scene(scene)
    assert gone.value.status == 404


def down_the_sphere(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rays straight down from z = 5 onto a unit sphere at the origin, most of them hits."""
    rng = np.random.default_rng(seed)
    origins = np.column_stack([rng.uniform(-0.8, 0.8, (n, 2)), np.full(n, 5.0)])
    return origins, np.tile([0.0, 0.0, -1.0], (n, 1))


def test_a_call_that_another_thread_outruns_answers_from_the_mesh_it_read(app_client):
    """Thread A's intersects_first is held before its request goes while thread B rotates the
    mesh and queries, which uploads the rotated mesh over A's: A still answers for the mesh A
    read and B for the rotated one, each as trimesh's own intersector on its mesh; the spare
    scene that answered A is deleted once A's call returns."""
    import threading

    import trimesh
    from trimesh.ray.ray_triangle import RayMeshIntersector as TrimeshIntersector

    from service.intersector import RayMeshIntersector as OnService

    held, release = threading.Event(), threading.Event()

    class HoldingClient(Client):
        def closest(self, *args, **kwargs):
            if threading.current_thread().name == "A" and not release.is_set():
                held.set()
                release.wait(60)
            return super().closest(*args, **kwargs)

    mesh = trimesh.creation.icosphere(subdivisions=2)
    as_a_read = mesh.copy()
    origins, directions = down_the_sphere(200, seed=41)
    api = HoldingClient(http=app_client)
    before = {s["scene"] for s in api.scenes()}
    answers = {}
    with OnService(mesh, client=api) as remote:
        a = threading.Thread(
            target=lambda: answers.update(a=remote.intersects_first(origins, directions)),
            name="A",
        )
        a.start()
        assert held.wait(60)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(0.7, [1, 1, 0]))
        answers["b"] = remote.intersects_first(origins, directions)
        release.set()
        a.join(60)
        want_a = TrimeshIntersector(as_a_read).intersects_first(origins, directions)
        want_b = TrimeshIntersector(mesh).intersects_first(origins, directions)
        assert (want_a != want_b).sum() > 150  # the rotation changes most rays' triangles
        assert np.array_equal(answers["a"], want_a)
        assert np.array_equal(answers["b"], want_b)
        assert {s["scene"] for s in api.scenes()} - before == {remote.scene}
        assert [m["mesh"] for m in api.scene(remote.scene)["meshes"]] == ["mesh"]
    assert {s["scene"] for s in api.scenes()} == before


def test_readings_leave_no_scenes_or_meshes_behind(app_client):
    """300 readings of a turning mesh keep one scene of one mesh; 10 of them held as calls in
    flight hold them, and asked after newer ones replaced them, answer for their own mesh (as
    trimesh's intersector) from spare scenes that go when they are dropped, or at close()."""
    import gc

    import trimesh
    from trimesh.ray.ray_triangle import RayMeshIntersector as TrimeshIntersector

    from service.intersector import RayMeshIntersector as OnService

    api = Client(http=app_client)
    before = {s["scene"] for s in api.scenes()}
    mesh = trimesh.creation.icosphere(subdivisions=1)
    origins, directions = down_the_sphere(50, seed=42)
    turn = trimesh.transformations.rotation_matrix(0.05, [1, 1, 0])
    with OnService(mesh, client=api) as remote:
        held = []
        for k in range(300):
            mesh.apply_transform(turn)
            reading = remote.reading()
            if k % 30 == 0:
                held.append((reading, mesh.copy()))
        del reading
        remote.intersects_any(origins, directions)  # the current reading: its own scene
        assert {s["scene"] for s in api.scenes()} - before == {remote.scene}
        assert len(api.scene(remote.scene)["meshes"]) == 1
        for reading, as_read in held:
            prim = reading.backend.closest(origins, directions)[0]
            assert np.array_equal(
                prim, TrimeshIntersector(as_read).intersects_first(origins, directions)
            )
        assert len({s["scene"] for s in api.scenes()} - before) == 1 + len(held)
        del held[:5], reading, as_read
        gc.collect()
        assert len({s["scene"] for s in api.scenes()} - before) == 1 + len(held)
    assert {s["scene"] for s in api.scenes()} == before
    del held
    gc.collect()
    assert {s["scene"] for s in api.scenes()} == before


def test_set_transform_places_the_mesh_for_hits_and_count(app_api, scene_name, teapot):
    """An instance placed by a rotation, a scale and a shift answers as the mesh placed in numpy."""
    import procedural

    vertices, faces = teapot
    app_api.put_mesh(scene_name, "pot", vertices, faces)
    matrix = np.eye(4)
    matrix[:3, :3] = 0.5 * procedural.rotation([1.0, 2.0, 0.5], 0.7)
    matrix[:3, 3] = [10, -4, 2]
    info = app_api.set_transform(scene_name, "pot", matrix)
    assert info["version"] == 2
    placed = (vertices.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
    origins, directions = rays_at(placed, faces, 200, seed=35)
    hits = app_api.hits(scene_name, origins, directions)
    expected = reference.all_hits(placed, faces, origins, directions, perturbation="shear")
    assert np.array_equal(hits.offsets, expected.offsets) and expected.offsets[-1] > 300
    assert np.array_equal(hits.prim, expected.prim) and (hits.mesh == 0).all()
    # The instance is traced in its mesh's space: t agrees across the surface within the
    # rounding docs/engine.md states (grazing hits may differ more along the ray).
    ray = np.repeat(np.arange(len(origins)), np.diff(expected.offsets))
    corners = placed[faces[expected.prim]].astype(np.float64)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    err = placed_checks.across_surface_ulps(
        hits.t, expected.t, origins[ray], directions[ray], normals
    )
    assert err.max() <= placed_checks.T_ULPS
    count = app_api.count(scene_name, origins, directions).count
    assert np.array_equal(count, np.diff(expected.offsets))


# ---- sensors through the client, on the real server


@pytest.fixture
def server_room(client, scene_name):
    from sensor_helpers import put_room

    put_room(client, scene_name)
    return scene_name


def test_client_sensors_answer_what_the_engine_answers(client, server_room):
    """``render``, ``camera``, ``lidar`` and ``sensors`` over uvicorn equal ``dacrt.sensors`` in
    process on the same meshes and materials, bit for bit."""
    from sensor_helpers import MESHES, rigid_pose

    from dacrt.sensors import Camera, Lidar, Materials, Rig, look_at_pose

    client.set_material(server_room, "sphere", reflectivity=0.9, label=3)
    info = client.set_material(server_room, "box", label=8)
    assert (info["reflectivity"], info["label"]) == (0.5, 8)
    scene = dacrt.Scene(list(MESHES.values()))
    materials = Materials(reflectivity=[0.5, 0.9, 0.5], label=[0, 3, 8])
    pose = rigid_pose(15, 0, (0.0, -3.0, 1.2))
    physics = {"return_mode": "dual", "beam_divergence_deg": 1.0, "beam_samples": 3,
               "noise": {"range_sigma": 0.01, "seed": 2}}  # fmt: skip
    points = client.lidar(server_room, pose=pose, model="VLP-16", horizontal_steps=180, **physics)
    expected = Lidar("VLP-16", horizontal_steps=180, **physics).scan(scene, pose, materials)
    assert points.version == 5 and list(points) == list(expected) and expected.n_points > 100
    for key in expected:
        assert (
            np.array_equal(points[key], expected[key]) and points[key].dtype == expected[key].dtype
        )
    assert set(np.unique(points.label)) == {0, 3, 8}
    look = {"eye": [6.0, -6.0, 4.0], "target": [0.0, 0.0, 0.5], "up": [0.0, 0.0, 1.0]}
    image = client.camera(server_room, width=32, height=24, fov_deg=50.0, **look)
    camera = Camera.from_fov(32, 24, 50.0)
    want = camera.capture(scene, look_at_pose(**look))
    assert all(np.array_equal(image[k], want[k]) for k in want) and list(image) == list(want)
    png = client.render(server_room, width=32, height=24, shading="depth", **look)
    assert png.startswith(b"\x89PNG")
    roof = {"kind": "lidar", "pose": pose, "model": "VLP-16", "horizontal_steps": 180, **physics}
    rig = {"roof": roof, "front": {"kind": "camera", "width": 32, "height": 24, **look}}
    rig["front"]["fov_deg"] = 50.0
    both = client.sensors(server_room, rig, stats=True)
    assert set(both) == {"roof", "front"} and both["roof"].version == 5
    assert both["roof"].stats["rays"] == 16 * 180 * 3 + 32 * 24  # one batch
    together = Rig({"roof": Lidar("VLP-16", horizontal_steps=180, **physics), "front": camera})
    poses = {"roof": pose, "front": look_at_pose(**look)}
    for name, arrays in together.capture(scene, poses, materials).items():
        assert list(both[name]) == list(arrays)
        assert all(np.array_equal(both[name][k], arrays[k], equal_nan=True) for k in arrays)
    pcd = client.lidar(server_room, pose=pose, model="VLP-16", horizontal_steps=180, pcd=True)
    assert pcd.startswith(b"# .PCD v0.7") and b"\nDATA binary\n" in pcd
    with pytest.raises(APIError) as refused:
        client.lidar(server_room, pose=pose, model="VLP-16", noise={"range_sigma": -1})
    assert refused.value.status == 422 and "noise.range_sigma" in refused.value.detail


def test_client_patterns(client, server_room, scene_name):
    from sensor_helpers import rigid_pose

    azimuth, elevation = np.linspace(-40, 40, 200), np.linspace(-20, 5, 200)
    info = client.put_pattern(scene_name, azimuth, elevation, time_s=np.linspace(0, 0.1, 200))
    assert info == {"pattern": scene_name, "rays": 200, "time_s": True, "channel": False}
    assert info in client.patterns()
    assert np.array_equal(client.pattern(scene_name)["azimuth_deg"], azimuth)
    points = client.lidar(server_room, pose=rigid_pose(0, 0, (-6.0, 0.0, 1.0)), pattern=scene_name)
    assert len(points.ray) > 50 and points.time.dtype == np.float32
    client.delete_pattern(scene_name)
    with pytest.raises(APIError) as gone:
        client.pattern(scene_name)
    assert gone.value.status == 404


def test_the_all_ones_mask_is_a_mask():
    client, sent = recording_client({"/v1/scenes/s/meshes/m": {"mesh": "m"}})
    client.put_mesh("s", "m", V3, [[0, 1, 2]], mask=0xFFFFFFFF)
    assert sent[-1].url.params["mask"] == "4294967295"


def test_an_n_by_8_array_keeps_its_tmin_when_only_tmax_is_given():
    rays = np.zeros((2, 8), np.float32)
    rays[:, 5] = 1
    rays[:, 6], rays[:, 7] = [0.25, 0.5], [10, 20]
    made = rays_array(rays, tmax=5.0)
    assert made[:, 6].tolist() == [0.25, 0.5] and made[:, 7].tolist() == [5.0, 5.0]
    made = rays_array(rays, tmin=0.125)
    assert made[:, 6].tolist() == [0.125, 0.125] and made[:, 7].tolist() == [10, 20]


# ---- motion, frames, instances, masks and JSON answers through the client, on the real server

RISE = 2.0  # the floor's transform_end lifts it this far in z


def moving_scene(client: Client, scene: str) -> None:
    """A floor on [0, 4]^2 at z = 0 lifted by RISE over the frame (``transform_end``) and a sheet
    on [5, 9] x [0, 4] at z = 0 whose corners rise by 0..3 (``vertices_end``), set by frames."""
    floor, sheet = quad(0, 4, 0, 4, 0), quad(5, 9, 0, 4, 0)
    client.frame(scene, {"floor": floor, "sheet": sheet})
    lifted = np.eye(4)
    lifted[2, 3] = RISE
    sheet_end = sheet[0] + np.array([[0, 0, 0], [0, 0, 1], [0, 0, 3], [0, 0, 2]], np.float32)
    info = client.frame(
        scene,
        {
            "floor": {"transform": np.eye(4), "transform_end": lifted},
            "sheet": {"vertices": sheet[0], "vertices_end": sheet_end},
        },
    )
    assert [(m["mesh"], m["version"]) for m in info["meshes"]] == [("floor", 2), ("sheet", 2)]


def placed_at(tau: float) -> tuple[np.ndarray, np.ndarray]:
    """``moving_scene``'s triangles at time ``tau`` in plain NumPy (float64): each vertex at the
    linear interpolation of its placements at 0 and 1 (floor's faces first)."""
    floor, sheet = quad(0, 4, 0, 4, 0), quad(5, 9, 0, 4, 0)
    rise = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 3], [0, 0, 2]], np.float64)
    vertices = np.concatenate(
        [floor[0] + [0, 0, RISE * tau], sheet[0].astype(np.float64) + tau * rise]
    )
    return vertices, np.concatenate([floor[1], sheet[1] + 4])


def moving_rays(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays down from z = 10 onto either mesh (away from their edges), each at one of a few
    times."""
    rng = np.random.default_rng(seed)
    xy = np.column_stack([rng.uniform(0.2, 8.8, n), rng.uniform(0.2, 3.8, n)])
    xy[np.abs(xy[:, 0] - 4.5) < 0.7, 0] += 1.5  # none through the gap's edges
    times = rng.choice(np.array([0.0, 0.25, 0.5, 0.75, 1.0], np.float32), n)
    return (*down_rays(xy), times)


def test_queries_at_each_rays_time_see_the_meshes_where_a_frame_moved_them(client, scene_name):
    """``time=`` on every query (and ``frame``'s ``transform_end`` and ``vertices_end``) answers
    each ray on the meshes placed at its time in NumPy."""
    moving_scene(client, scene_name)
    origins, directions, times = moving_rays(300, seed=51)
    want_t, want_prim, want_count = np.empty(300), np.empty(300, int), np.empty(300, int)
    for tau in np.unique(times):
        rows = times == tau
        vertices, faces = placed_at(float(tau))
        hits = reference.closest(vertices, faces, origins[rows], directions[rows])
        want_t[rows], want_prim[rows] = hits.t, hits.prim
        want_count[rows] = reference.count(vertices, faces, origins[rows], directions[rows])
    assert (want_prim >= 0).all() and len(np.unique(times)) == 5
    for answer in ("npz", "json"):
        closest = client.closest(scene_name, origins, directions, time=times, answer=answer)
        np.testing.assert_allclose(closest.t, want_t, rtol=1e-6)
        assert np.array_equal(closest.mesh, want_prim // 2)
        assert np.array_equal(closest.prim, want_prim % 2)
    tmax = want_t.astype(np.float32) + np.where(np.arange(300) % 2 == 0, 0.01, -0.01)
    occluded = client.occluded(scene_name, origins, directions, tmax=tmax, time=times)
    assert np.array_equal(occluded.occluded, np.arange(300) % 2 == 0)
    hits = client.hits(scene_name, origins, directions, time=times, mask=np.full(300, 1))
    assert np.array_equal(np.diff(hits.offsets), want_count)
    np.testing.assert_allclose(hits.t, want_t, rtol=1e-6)  # one hit a ray here
    count = client.query(scene_name, "count", origins, directions, time=times, answer="npy")
    assert np.array_equal(count.count, want_count)
    # one time for every ray; no time is time 0
    at_end = client.closest(scene_name, origins, directions, time=1.0).t
    np.testing.assert_allclose(
        at_end, reference.closest(*placed_at(1.0), origins, directions).t, 1e-6
    )
    at_start = client.closest(scene_name, origins, directions).t
    np.testing.assert_allclose(
        at_start, reference.closest(*placed_at(0.0), origins, directions).t, 1e-6
    )
    # a one-shot mesh is static: its rays' times are sent and checked, and change nothing
    once = client.trace(*quad(0, 4, 0, 4, 0), origins, directions, time=times)
    still = reference.closest(*quad(0, 4, 0, 4, 0), origins, directions)
    assert np.array_equal(once.t, still.t.astype(np.float32)) and np.isinf(once.t).any()


def test_time_is_sent_as_the_contract_says():
    """``time`` goes in an .npz body as little-endian float32 (N,), beside origins and
    directions (and tmin, tmax, mask); one value is repeated for every ray."""
    client, sent = recording_client({})
    for call in (
        lambda: client.closest("s", *TWO, time=[0.0, 0.5]),
        lambda: client.hits("s", np.zeros((2, 8)) + [0, 0, 0, 0, 0, 1, 0, 5], time=0.25, mask=3),
        lambda: client.trace(V3, [[0, 1, 2]], *TWO, time=np.array([1, 0])),
    ):
        with pytest.raises(KeyError):  # the recording client has no answer for the query
            call()
    bodies = [np.load(io.BytesIO(request.content)) for request in sent]
    assert [request.headers["content-type"] for request in sent] == [wire.NPZ] * 3
    assert bodies[0].files == ["origins", "directions", "time"]
    assert bodies[1].files == ["origins", "directions", "tmin", "tmax", "time"]
    assert sent[1].url.params["mask"] == "3"
    assert bodies[2].files == ["vertices", "faces", "origins", "directions", "time"]
    for body, want in zip(bodies, ([0.0, 0.5], [0.25, 0.25], [1.0, 0.0])):
        assert body["time"].dtype == np.dtype("<f4") and body["time"].tolist() == want


def test_frame_sends_every_part_a_frame_may_carry():
    """Arrays as .npz keys ``NAME.PART`` in their wire dtypes; a frame with ``instance_of``
    (text, which an .npz cannot hold) as JSON."""
    client, sent = recording_client({"/v1/scenes/s/frame": {"scene": "s"}})
    matrix = np.eye(4)
    matrix[:3, 3] = [1, 2, 3]
    client.frame(
        "s",
        {
            "a.b": {"vertices": V3, "faces": [[0, 1, 2]], "vertices_end": V3 + 1.0},
            "c": {"transform": matrix, "transform_end": np.eye(4), "mask": 0xF0},
            "d": {"reflectivity": 0.25, "label": 7},
        },
    )
    body = np.load(io.BytesIO(sent[-1].content))
    assert sent[-1].headers["content-type"] == wire.NPZ
    dtypes = {key: (body[key].dtype.str, body[key].shape) for key in body.files}
    assert dtypes == {
        "a.b.vertices": ("<f4", (4, 3)),
        "a.b.faces": ("<i4", (1, 3)),
        "a.b.vertices_end": ("<f4", (4, 3)),
        "c.transform": ("<f8", (4, 4)),
        "c.transform_end": ("<f8", (4, 4)),
        "c.mask": ("<u4", ()),
        "d.reflectivity": ("<f8", ()),
        "d.label": ("<u4", ()),
    }
    assert np.array_equal(body["c.transform"], matrix) and body["c.mask"] == 0xF0
    assert body["d.reflectivity"] == 0.25 and body["d.label"] == 7
    client.frame("s", {"car": (V3, [[0, 1, 2]]), "car2": {"instance_of": "car", "mask": 1}})
    assert sent[-1].headers["content-type"] == "application/json"
    assert json.loads(sent[-1].content) == {
        "car.vertices": V3.tolist(),
        "car.faces": [[0, 1, 2]],
        "car2.instance_of": "car",
        "car2.mask": 1,
    }


def test_frame_parts_instances_masks_and_mesh_info(client, scene_name):
    """A frame's transform, mask, materials and instance_of, ``put_instance`` and ``set_mask``
    change what rays see as the placements and masks computed in NumPy say; ``mesh`` answers
    the mesh's info and ``metrics`` the Prometheus text."""
    vertices, faces = quad(0, 1, 0, 1, 0)
    shifted = np.eye(4)
    shifted[:3, 3] = [3, 0, 1]
    info = client.frame(
        scene_name,
        {
            "tile": {"vertices": vertices, "faces": faces, "mask": 0b01},
            "copy": {"instance_of": "tile", "transform": shifted, "label": 4},
        },
    )
    assert [m["mesh"] for m in info["meshes"]] == ["tile", "copy"]
    copy = client.mesh(scene_name, "copy")
    assert copy == info["meshes"][1] and copy["instance_of"] == "tile" and copy["label"] == 4
    assert copy["transform"] == shifted.tolist() and copy["mask"] == 0xFFFFFFFF
    scaled = np.diag([2.0, 2.0, 1.0, 1.0])
    scaled[:3, 3] = [6, 0, 2]
    third = client.put_instance(scene_name, "third", "tile", scaled, mask=0b10)
    assert (third["instance_of"], third["mask"], third["index"]) == ("tile", 0b10, 2)
    assert (
        client.frame(scene_name, {"tile": {"reflectivity": 0.75}})["meshes"][0]["reflectivity"]
        == 0.75
    )
    # rays down onto each placement, in NumPy: vertices placed by each matrix
    placements = [np.eye(4), shifted, scaled]
    xy = np.array([[0.5, 0.5], [3.5, 0.5], [7.0, 1.0]])
    origins, directions = down_rays(xy)
    expected_t = [10.0 - m[2, 3] for m in placements]
    for index, matrix in enumerate(placements):
        placed = vertices.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
        hit = reference.closest(placed, faces, origins[index : index + 1], directions[:1])
        assert hit.t[0] == expected_t[index]
    answer = client.closest(scene_name, origins, directions)
    assert answer.t.tolist() == expected_t and answer.mesh.tolist() == [0, 1, 2]
    masked = client.closest(scene_name, origins, directions, mask=0b01)
    assert masked.mesh.tolist() == [0, 1, -1]  # tile's mask 0b01, copy all ones, third 0b10
    assert client.set_mask(scene_name, "copy", 0b100)["mask"] == 0b100
    assert client.closest(scene_name, origins, directions, mask=0b01).mesh.tolist() == [0, -1, -1]
    assert client.mesh(scene_name, "copy")["mask"] == 0b100
    text = client.metrics()
    route = 'route="/v1/scenes/{scene}/meshes/{mesh}/mask",status="200"'
    assert "dacrt_requests_total{" in text and route in text


def test_nearest_signed_distance_beyond_max_distance_keeps_its_sign_in_json(client, scene_name):
    """Inside a closed box, beyond ``max_distance``, ``signed_distance`` is -inf in every answer
    format (JSON writes it as null, as it does +inf)."""
    from sensor_helpers import BOX

    client.put_mesh(scene_name, "box", *BOX)  # [-4, -2.5] x [2, 3.5] x [0, 1.5]
    lo, hi = BOX[0].min(0).astype(np.float64), BOX[0].max(0).astype(np.float64)
    rng = np.random.default_rng(52)
    points = rng.uniform(lo - 1, hi + 1, (60, 3)).astype(np.float32)
    inside = np.all((points > lo) & (points < hi), axis=1)
    assert 5 < inside.sum() < 55
    gap = np.minimum(points - lo, hi - points).min(axis=1)  # inside: the distance to the box
    for max_distance in (0.05, 0.3):
        answers = [
            client.nearest(scene_name, points, max_distance, sign=True, answer=fmt)
            for fmt in ("npz", "npy", "json")
        ]
        for answer in answers[1:]:
            assert_same_answer(answer, answers[0])
        far = ~np.isfinite(answers[0].distance)
        assert np.array_equal(answers[0].inside, inside)
        assert (far & inside).any() and (far & ~inside).any()
        signed = answers[0].signed_distance
        assert np.array_equal(signed[far], np.where(inside[far], -np.inf, np.inf))
        near = inside & ~far
        np.testing.assert_allclose(signed[near], -gap[near], rtol=1e-5)


def test_read_answer_of_json_equals_the_npz_answer(http, client, server_room):
    """``read_answer`` of a JSON lidar, rig or nearest answer has the keys, dtypes, shapes and
    values (NaN fills included) of the .npz answer, read here with ``np.load``."""
    from sensor_helpers import npz, rigid_pose

    from service.client import read_answer

    pose = rigid_pose(10, 0, (0.0, -3.0, 1.2)).tolist()
    beams = {"pose": pose, "horizontal_steps": 90, "period_s": 0.1}
    lidar = {**beams, "model": "VLP-16"}
    look = {"eye": [6.0, -6.0, 4.0], "target": [0.0, 0.0, 0.5], "width": 8, "height": 6}
    scene = f"/v1/scenes/{server_room}"
    bodies = [
        (f"{scene}/lidar", {**lidar, "non_hits": "keep"}),
        (f"{scene}/lidar", {**lidar, "organized": True, "return_mode": "dual"}),
        (f"{scene}/lidar", {**beams, "vertical_angles_deg": [80.0]}),  # no points
        (f"{scene}/sensors", {"sensors": {"roof": {"kind": "lidar", **lidar, "non_hits": "keep"},
                                          "front": {"kind": "camera", **look}}}),
    ]  # fmt: skip
    for path, body in bodies:
        as_json = http.post(path, json=body)
        as_npz = http.post(path, json=body, headers={"Accept": wire.NPZ})
        assert as_json.headers["content-type"] == "application/json", as_json.text
        got, want = read_answer(as_json), npz(as_npz.content)
        assert list(got) == list(want), path
        for key in want:
            assert got[key].dtype == want[key].dtype and got[key].shape == want[key].shape, key
            assert np.array_equal(got[key], want[key], equal_nan=True), key
        fills = [want[k] for k in want if k.endswith(("xyz", "velocity", "radial_speed"))]
        assert any(np.isnan(fill).any() for fill in fills) or want["velocity"].shape == (0, 3)
    from sensor_helpers import BOX

    box = f"/v1/scenes/{server_room}-box"
    client.put_mesh(f"{server_room}-box", "box", *BOX)  # closed: [-4, -2.5] x [2, 3.5] x [0, 1.5]
    points = np.array([[-3.2, 2.7, 0.7], [0, 0, 30], [-3.2, 2.7, 30]], np.float32)
    params = {"sign": "true", "max_distance": "0.1"}
    as_json = http.post(f"{box}/nearest", json={"points": points.tolist()}, params=params)
    as_npz = http.post(f"{box}/nearest", content=npy_bytes(points), params=params, headers=NPY)
    got, want = read_answer(as_json), npz(as_npz.content)
    assert want["signed_distance"].tolist() == [-np.inf, np.inf, np.inf]
    assert all(np.array_equal(got[k], want[k]) and got[k].dtype == want[k].dtype for k in want)


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_put_mesh_takes_a_mesh_body_saved_as_a_file(client, scene_name, tmp_path, suffix):
    vertices, faces = grid(3, z=1.0)
    path = tmp_path / f"mesh{suffix}"
    if suffix == ".npz":
        np.savez(path, vertices=vertices, faces=faces)
    else:
        path.write_text(json.dumps({"vertices": vertices.tolist(), "faces": faces.tolist()}))
    info = client.put_mesh(scene_name, "from-file", file=path, mask=5)
    assert (info["vertices"], info["triangles"], info["mask"]) == (16, 18, 5)
    again = client.put_mesh(scene_name, "as-bytes", file=path.read_bytes(), format=suffix[1:])
    assert again["triangles"] == 18
    origins, directions = down_rays(np.random.default_rng(53).uniform(0.05, 0.95, (40, 2)))
    answer = client.closest(scene_name, origins, directions, mask=1)  # sees from-file only
    want = reference.closest(vertices, faces, origins, directions)
    np.testing.assert_allclose(answer.t, want.t, rtol=1e-6)
    assert np.array_equal(answer.prim, want.prim) and (answer.mesh == 0).all()
