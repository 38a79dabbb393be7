"""POST /v1/scenes/{scene}/nearest: the engine's ``Scene.nearest`` (and, with ?sign=true,
``contains`` and ``signed_distance``) over HTTP, in every body and answer format, against the
plain-NumPy brute force (``point_reference``); and the 4xx of bad requests, each naming the
request's key."""

from __future__ import annotations

import json

import numpy as np
import point_reference
import procedural
import pytest
from service_helpers import NPY, NPZ, metric_sample, npy_bytes, npz_bytes

from dacrt.points import sample_directions
from service import wire
from service.client import APIError
from service.client import read_answer as read

NEAREST_FIELDS = ("distance", "point", "mesh", "prim", "u", "v")
JSON = {"Content-Type": "application/json"}


@pytest.fixture
def sphere_scene(app_api, scene_name):
    """A closed sphere (mesh index 1) and a quad below it (mesh index 0)."""
    vertices, faces = procedural.icosphere(2)
    app_api.put_mesh(scene_name, "floor", *procedural.grid(2, 4.0))
    app_api.put_mesh(scene_name, "ball", vertices + [2.0, 2.0, 3.0], faces)
    return scene_name


def _points(n=300, seed=0):
    return np.random.default_rng(seed).uniform(-1, 5, (n, 3)).astype(np.float32)


def _expected(points):
    """The reference's answer on sphere_scene's meshes, as (distance, mesh, global face)."""
    floor = procedural.grid(2, 4.0)
    vertices, faces = procedural.icosphere(2)
    meshes = [floor, (vertices + [2.0, 2.0, 3.0], faces)]
    all_vertices, all_faces, offsets = procedural.concat(meshes)
    return point_reference.nearest(points, all_vertices, all_faces), offsets


def test_nearest_matches_the_reference(app_api, sphere_scene):
    points = _points()
    answer = app_api.nearest(sphere_scene, points)
    assert list(answer) == list(NEAREST_FIELDS)
    expected, offsets = _expected(points)
    np.testing.assert_allclose(answer.distance, expected.distance, rtol=1e-6, atol=1e-6)
    global_face = offsets[answer.mesh] + answer.prim
    for i, face in enumerate(global_face):
        assert face in expected.ties(i, 1e-6)
    measured = np.linalg.norm(answer.point.astype(np.float64) - points, axis=1)
    np.testing.assert_allclose(measured, expected.distance, rtol=1e-5, atol=1e-6)
    assert answer.distance.dtype == np.float32 and answer.point.shape == (len(points), 3)
    assert answer.mesh.dtype == np.int32 and answer.prim.dtype == np.int32
    assert answer.version == 2


@pytest.mark.parametrize("body_format", ["npy", "npz", "json"])
@pytest.mark.parametrize("answer_format", ["npz", "npy", "json"])
def test_every_body_and_answer_format_gives_the_same_answer(
    app_client, app_api, sphere_scene, body_format, answer_format
):
    points = _points(40, seed=1)
    points[0] = [100.0, 0, 0]  # beyond max_distance: inf, -1 (null in JSON)
    bodies = {
        "npy": (npy_bytes(points), NPY),
        "npz": (npz_bytes(points=points), NPZ),
        "json": (json.dumps({"points": points.tolist()}).encode(), JSON),
    }
    body, headers = bodies[body_format]
    media = {"npz": "application/x-npz", "npy": "application/x-npy", "json": "application/json"}
    response = app_client.post(
        f"/v1/scenes/{sphere_scene}/nearest?max_distance=10&sign=true&nsamples=3",
        content=body,
        headers={**headers, "Accept": media[answer_format]},
    )
    assert response.status_code == 200, response.text
    got = read(response)
    want = app_api.nearest(sphere_scene, points, 10.0, sign=True, nsamples=3)
    assert list(got) == [*NEAREST_FIELDS, "inside", "signed_distance"]
    for key in want:
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    assert want.distance[0] == np.inf and want.prim[0] == -1 and want.mesh[0] == -1


def test_sign_says_inside_the_ball(app_api, sphere_scene):
    rng = np.random.default_rng(2)
    directions = procedural.unit_vectors(200, rng)
    radii = np.concatenate([rng.uniform(0, 0.8, 100), rng.uniform(1.2, 2, 100)])
    points = (directions * radii[:, None] + [2.0, 2.0, 3.0]).astype(np.float32)
    answer = app_api.nearest(sphere_scene, points, sign=True, nsamples=5)
    np.testing.assert_array_equal(answer.inside, radii < 1)
    np.testing.assert_array_equal(
        answer.signed_distance, np.where(radii < 1, -1, 1) * answer.distance
    )
    assert answer.inside.dtype == bool and answer.signed_distance.dtype == np.float32


def test_max_distance_mask_and_stats(app_api, sphere_scene):
    points = _points(200, seed=3)
    near = app_api.nearest(sphere_scene, points, 0.5, stats=True)
    expected, _ = _expected(points)
    within = expected.distance <= 0.5
    np.testing.assert_array_equal(np.isfinite(near.distance), within)
    assert (near.prim[~within] == -1).all()
    assert near.stats["points"] == len(points) and near.stats["where"] == "process"
    # the ball alone, by mask
    app_api.put_mesh(sphere_scene, "floor", *procedural.grid(2, 4.0), mask=0x1)
    app_api.put_mesh(sphere_scene, "ball", *_ball(), mask=0x2)
    ball_only = app_api.nearest(sphere_scene, points, mask=0x2)
    assert (ball_only.mesh == 1).all()


@pytest.mark.parametrize("sign, nsamples", [(False, 1), (True, 1), (True, 5)])
def test_stats_count_the_inside_tests_rays_as_the_metrics_do(
    app_client, sphere_scene, sign, nsamples
):
    """X-Trace-Stats (API.md: the engine's counters for this batch) with ?sign=true counts the
    inside test's rays, points x nsamples, as dacrt_rays_traced_total does."""
    points = _points(3, seed=4).tolist()
    sample = 'dacrt_rays_traced_total{query="nearest"}'
    before = metric_sample(app_client.get("/metrics").text, sample)
    query = f"stats=true&sign={str(sign).lower()}&nsamples={nsamples}"
    answer = app_client.post(f"/v1/scenes/{sphere_scene}/nearest?{query}", json={"points": points})
    assert answer.status_code == 200, answer.text
    counted = metric_sample(app_client.get("/metrics").text, sample) - before
    stats = json.loads(answer.headers["x-trace-stats"])
    assert stats["points"] == 3 and stats["where"] == "process"
    if sign:
        assert stats["inside_rays"] == 3 * nsamples == counted
    else:
        assert "inside_rays" not in stats and counted == 3


@pytest.mark.parametrize("answer", ["npz", "json"])
def test_a_closest_point_just_beyond_max_distance_is_none_in_every_key(app_api, scene_name, answer):
    """The engine's answer: a distance that rounds just above ?max_distance (float32 1 and
    the next float32 above it) reads inf, and so does the signed distance, with mesh and prim
    -1 and point inf; a distance at the limit is kept."""
    vertices = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    app_api.put_mesh(scene_name, "triangle", vertices, np.int32([[0, 1, 2]]))
    above_one = np.nextafter(np.float32(1), np.float32(2))
    points = np.array([[0.2, 0.2, above_one], [0.2, 0.2, 1.0]], np.float32)
    near = app_api.nearest(scene_name, points, 1.0, sign=True, answer=answer)
    np.testing.assert_array_equal(near.distance, [np.inf, 1.0])
    np.testing.assert_array_equal(near.mesh, [-1, 0])
    np.testing.assert_array_equal(near.prim, [-1, 0])
    assert np.isinf(near.point[0]).all()
    np.testing.assert_array_equal(np.abs(near.signed_distance), [np.inf, 1.0])


def test_a_json_distance_given_back_as_max_distance_keeps_its_answer(app_client, sphere_scene):
    """JSON writes a float32 distance as its shortest decimal, whose float64 may lie below it:
    ?max_distance= reads that decimal as the float32, so the answer stays; the previous
    float32's decimal, and a longer decimal between the two, drop it (inward, as ever)."""
    points = _points(16, seed=5)
    url = f"/v1/scenes/{sphere_scene}/nearest"
    written = app_client.post(url, json={"points": points.tolist()}).json()
    for i, reported in enumerate(written["distance"]):
        distance = np.float32(reported)
        below = np.nextafter(distance, np.float32(0))
        between = (float(distance) + float(below)) / 2  # no float32's shortest decimal
        for limit, kept in ((repr(reported), True), (str(below), False), (repr(between), False)):
            got = app_client.post(
                url, params={"max_distance": limit}, json={"points": [points[i].tolist()]}
            ).json()
            want = written["prim"][i] if kept else -1
            assert got["prim"] == [want], (i, limit, got)


@pytest.mark.parametrize(
    ("given", "read"),
    [
        ("0.054568082", float(np.float32(0.054568082))),  # a float32's shortest decimal
        ("0.1", float(np.float32(0.1))),
        ("0.5", 0.5),
        ("3.4028235e+38", float(np.finfo(np.float32).max)),
        ("0.10000000000000002", 0.10000000000000002),  # no float32's shortest decimal
        ("0.0545680821", 0.0545680821),
        ("1e39", 1e39),  # beyond float32: no limit, as before
        ("inf", np.inf),
    ],
)
def test_max_distance_reads_a_float32s_shortest_decimal_as_that_float32(given, read):
    assert wire.float32_if_shortest(float(given)) == read


def test_sign_far_from_a_mesh_placed_small(app_api, scene_name):
    """A point 1e33 before a sphere placed at 1e-6 of its size along the inside test's ray: the
    ray starts near the sphere in its space (from the point it would reach 1e39), so the point
    is answered, outside, and the centre inside."""
    app_api.put_mesh(scene_name, "ball", *procedural.icosphere(2))
    app_api.set_transform(scene_name, "ball", np.diag([1e-6, 1e-6, 1e-6, 1.0]))
    points = np.array([-1e33 * sample_directions(1)[0], [0, 0, 0]], np.float32)
    answer = app_api.nearest(scene_name, points, sign=True)
    np.testing.assert_array_equal(answer.inside, [False, True])
    assert answer.signed_distance[1] < 0 < answer.signed_distance[0] < np.inf


def _ball():
    vertices, faces = procedural.icosphere(2)
    return vertices + [2.0, 2.0, 3.0], faces


def test_an_empty_batch_and_an_unknown_scene(app_api, app_client, sphere_scene):
    empty = app_api.nearest(sphere_scene, np.zeros((0, 3), np.float32))
    assert empty.distance.shape == (0,) and empty.point.shape == (0, 3)
    missing = app_client.post(
        "/v1/scenes/no-such-scene/nearest", content=npy_bytes(_points(2)), headers=NPY
    )
    assert missing.status_code == 404


@pytest.mark.parametrize(
    ("query", "body", "headers", "status", "phrase"),
    [
        ("max_distance=-1", None, NPY, 422, "max_distance must be >= 0"),
        ("max_distance=nan", None, NPY, 422, "max_distance"),
        ("max_distance=far", None, NPY, 422, "max_distance"),
        ("nsamples=2", None, NPY, 422, "nsamples must be a positive odd integer"),
        ("nsamples=0", None, NPY, 422, "nsamples"),
        ("sign=maybe", None, NPY, 422, "sign"),
        # the inside test traces nsamples rays a point, within the request's rays
        ("sign=true&nsamples=" + "9" * 31, None, NPY, 413, "1 points x nsamples 99999"),
        ("sign=true&nsamples=6000001", None, NPY, 413, "3 points x nsamples 6000001 is 18000003"),
        ("mask=-3", None, NPY, 422, "mask"),
        ("feilds=distance", None, NPY, 422, "unknown query parameter 'feilds'"),
        ("", npy_bytes(np.zeros((2, 2), np.float32)), NPY, 422, "points must have shape (N, 3)"),
        ("", npy_bytes(np.zeros((2, 3), np.float64)), NPY, 422, "points must be little-endian"),
        ("", npy_bytes(np.array([[0, 0, 0], [0, np.nan, 0]], np.float32)), NPY, 422, "points[1]"),
        ("", b'{"points": [[0, 0, "x"]]}', JSON, 422, "points must be numbers"),
        ("", b'{"points": [[0, 0, 0]], "extra": 1}', JSON, 400, "unknown keys 'extra'"),
        ("", b'{"pts": [[0, 0, 0]]}', JSON, 400, "lacks 'points'"),
        ("", npz_bytes(origins=np.zeros((1, 3), np.float32)), NPZ, 400, "lacks 'points'"),
    ],
)
def test_bad_requests_name_the_key(app_client, sphere_scene, query, body, headers, status, phrase):
    body = npy_bytes(_points(3)) if body is None else body
    response = app_client.post(
        f"/v1/scenes/{sphere_scene}/nearest?{query}", content=body, headers=headers
    )
    assert response.status_code == status, response.text
    assert phrase in response.json()["detail"], response.json()["detail"]


def test_the_client_raises_the_servers_error(app_api, sphere_scene):
    with pytest.raises(APIError) as caught:
        app_api.nearest(sphere_scene, _points(3), nsamples=4)
    assert caught.value.status == 422 and "nsamples" in caught.value.detail


def test_capabilities_name_the_point_query(app_api):
    caps = app_api.capabilities()
    assert "nearest" in caps["queries"] and "application/x-npy" in caps["formats"]["points"]
    assert caps["fields"]["nearest"] == [*NEAREST_FIELDS, "inside", "signed_distance"]
