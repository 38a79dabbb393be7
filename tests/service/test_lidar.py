"""POST /v1/scenes/{scene}/lidar: the points are exactly what ``closest`` answers for the rays that
the documented convention gives (built here in numpy: x forward, y left, z up, azimuth from +x
toward +y, ring k the k-th lowest elevation, ray = ring * steps + step); the named beam patterns
are the data sheets' angles; bad requests are refused with a clear 4xx."""

from __future__ import annotations

import json

import in_process
import numpy as np
import procedural
import pytest
from sensor_helpers import MESHES, lidar_rays, npz, put_room, rigid_pose

import dacrt
from service.settings import Settings

NPZ_ANSWER = {"Accept": "application/x-npz"}
FIELDS = (
    "xyz",
    "range",
    "ring",
    "azimuth",
    "elevation",
    "mesh",
    "prim",
    "return",
    "cos_incidence",
    "ray",
    "intensity",
    "label",
)
#: The data sheets' vertical angles, written out here independently of service/lidar.py.
PUBLISHED = {
    "VLP-16": [-15, -13, -11, -9, -7, -5, -3, -1, 1, 3, 5, 7, 9, 11, 13, 15],
    "HDL-32E": [round((4 * k - 92) / 3, 2) for k in range(32)],  # 4/3 apart, printed to 0.01
    "HDL-64E": [2 - k / 3 for k in range(32)] + [-53 / 6 - k / 2 for k in range(32)],
    "OS1-64": [-22.5 + 45 * k / 63 for k in range(64)],
    "OS1-128": [-22.5 + 45 * k / 127 for k in range(128)],
}
POSES = [
    rigid_pose(0, 0, (0.0, -3.0, 1.2)),
    rigid_pose(35, -10, (-2.0, -1.0, 1.8)),
]


@pytest.fixture
def room(app_api, scene_name):
    put_room(app_api, scene_name)
    return scene_name


@pytest.fixture
def inside_sphere(app_api, scene_name):
    """A closed sphere of radius 40 around the origin: every beam of a sensor inside hits it."""
    vertices, faces = procedural.icosphere(3, 40.0)
    app_api.put_mesh(scene_name, "dome", vertices, faces)
    return scene_name


def lidar(app_client, scene, body, query="", **headers):
    return app_client.post(
        f"/v1/scenes/{scene}/lidar{query}", json=body, headers={**NPZ_ANSWER, **headers}
    )


def expected_points(app_api, scene, pose, elevations, steps, tmin=None, tmax=None):
    """The points the convention gives, from closest on the numpy-built rays."""
    origins, directions, ring, azimuth, elevation = lidar_rays(pose, elevations, steps)
    hits = app_api.closest(scene, origins, directions, tmin, tmax)
    ray = np.flatnonzero(np.isfinite(hits.t))
    d = directions[ray].astype(np.float64)
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    cosine = np.abs((unit * hits.normal[ray]).sum(1))
    return {
        "xyz": origins[ray] + hits.t[ray, None] * directions[ray],  # float32 arithmetic
        "range": hits.t[ray],
        "ring": ring[ray].astype(np.uint16),
        "azimuth": azimuth[ray].astype(np.float32),
        "elevation": elevation[ray].astype(np.float32),
        "mesh": hits.mesh[ray],
        "prim": hits.prim[ray],
        "return": np.zeros(len(ray), np.int16),
        "cos_incidence": cosine.astype(np.float32),
        "ray": ray.astype(np.int32),
        # API.md: reflectivity (0.5 by default) x cos_incidence x exp(-0.004 range)
        "intensity": (0.5 * cosine * np.exp(-0.004 * hits.t[ray])).astype(np.float32),
        "label": np.zeros(len(ray), np.uint32),  # every mesh's default label
    }


def assert_same_points(answer, expected):
    assert list(answer) == list(FIELDS)
    for name in FIELDS:
        assert answer[name].dtype == expected[name].dtype, name
        if name in ("cos_incidence", "intensity"):  # a dot product: an ulp's difference
            assert np.allclose(answer[name], expected[name], rtol=1e-6, atol=1e-7), name
        else:
            assert np.array_equal(answer[name], expected[name]), name


@pytest.mark.parametrize("model", list(PUBLISHED))
@pytest.mark.parametrize("pose", range(len(POSES)))
def test_each_model_answers_what_closest_answers_for_its_rays(
    app_client, app_api, room, model, pose
):
    body = {"pose": POSES[pose].tolist(), "model": model, "horizontal_steps": 360}
    response = lidar(app_client, room, body)
    assert response.status_code == 200, response.text
    assert int(response.headers["x-scene-version"]) == 3
    answer = npz(response.content)
    expected = expected_points(app_api, room, POSES[pose], PUBLISHED[model], 360)
    assert len(answer["ray"]) > 100  # the floor and more are in view
    assert_same_points(answer, expected)


def test_explicit_angles_and_the_range_window(app_client, app_api, room):
    angles = [10.0, -20.0, -5.0, 0.0, -5.0]  # unsorted, with a repeat: rings sort them
    body = {
        "pose": POSES[1].tolist(),
        "vertical_angles_deg": angles,
        "horizontal_steps": 500,
        "min_range": 2.0,
        "max_range": 7.5,
    }
    answer = npz(lidar(app_client, room, body).content)
    expected = expected_points(app_api, room, POSES[1], angles, 500, 2.0, 7.5)
    assert_same_points(answer, expected)
    assert answer["range"].min() >= 2.0 and answer["range"].max() <= 7.5
    assert set(np.unique(answer["ring"])) <= {0, 1, 2, 3, 4}


@pytest.mark.parametrize("model", list(PUBLISHED))
def test_rings_are_the_published_elevations_lowest_first(app_client, inside_sphere, model):
    """From inside a closed sphere every ray hits, so every ring and step is in the answer."""
    steps = 64
    body = {"pose": np.eye(4).tolist(), "model": model, "horizontal_steps": steps}
    answer = npz(lidar(app_client, inside_sphere, body).content)
    n_rings = len(PUBLISHED[model])
    assert np.array_equal(answer["ray"], np.arange(n_rings * steps))
    elevation = answer["elevation"].reshape(n_rings, steps)
    assert (elevation == elevation[:, :1]).all()
    published = np.radians(np.sort(PUBLISHED[model]))
    assert np.allclose(elevation[:, 0], published, atol=np.radians(0.006))  # two decimals
    assert np.array_equal(answer["ring"], np.repeat(np.arange(n_rings), steps).astype(np.uint16))
    # ring 0 looks lowest: its points have the least height over the sensor, per azimuth
    z = answer["xyz"][:, 2].reshape(n_rings, steps)
    assert (np.diff(z, axis=0) > 0).all()
    assert np.allclose(np.linalg.norm(answer["xyz"], axis=1), answer["range"], rtol=1e-6)


def test_azimuth_runs_from_x_toward_y(app_client, inside_sphere):
    body = {"pose": np.eye(4).tolist(), "vertical_angles_deg": [0.0], "horizontal_steps": 8}
    answer = npz(lidar(app_client, inside_sphere, body).content)
    assert np.allclose(answer["azimuth"], np.arange(8) * np.pi / 4)
    xy = answer["xyz"][:, :2] / answer["range"][:, None]
    expected = np.stack([np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)], 1)
    assert np.allclose(xy, expected, atol=1e-6)  # step 2 looks along +y (left)
    # a sensor turned by the pose: yaw 90 degrees makes its forward the scene's +y
    body["pose"] = rigid_pose(90, 0, (1.0, 2.0, 3.0)).tolist()
    answer = npz(lidar(app_client, inside_sphere, body).content)
    first = (answer["xyz"][0] - [1.0, 2.0, 3.0]) / answer["range"][0]
    assert np.allclose(first, [0, 1, 0], atol=1e-6)


@pytest.mark.parametrize("max_returns", [2, 3, 8])
def test_multiple_returns_are_what_hits_answers_for_the_rays(app_client, room, max_returns):
    """Against the engine's ``Scene.hits`` on the same rays, in process: every hit in the range
    window, nearest first, at most max_returns a ray; return k is the k-th."""
    angles, steps = [-12.0, -4.0, 0.0, 3.0], 720
    body = {
        "pose": POSES[0].tolist(),
        "vertical_angles_deg": angles,
        "horizontal_steps": steps,
        "min_range": 0.5,
        "max_range": 30.0,
        "max_returns": max_returns,
    }
    answer = npz(lidar(app_client, room, body).content)
    origins, directions, ring, azimuth, elevation = lidar_rays(POSES[0], angles, steps)
    scene = dacrt.Scene(list(MESHES.values()))  # mesh positions = upload order = indices
    expected = scene.hits(origins, directions, 0.5, 30.0, max_hits=max_returns)
    counts = np.diff(expected.offsets)
    ray = np.repeat(np.arange(len(origins)), counts)
    assert np.array_equal(answer["ray"], ray)
    assert np.array_equal(answer["return"], np.concatenate([np.arange(c) for c in counts]))
    assert np.array_equal(answer["range"], expected.t)
    assert np.array_equal(answer["mesh"], expected.mesh)
    assert np.array_equal(answer["prim"], expected.prim)
    assert np.array_equal(answer["xyz"], origins[ray] + expected.t[:, None] * directions[ray])
    assert np.array_equal(answer["ring"], ring[ray]) and np.array_equal(
        answer["azimuth"], azimuth[ray].astype(np.float32)
    )
    assert np.array_equal(answer["elevation"], elevation[ray].astype(np.float32))
    # into and out of the sphere or the box, then the floor: three hits at most
    assert answer["return"].max() == min(max_returns, 3) - 1
    # the first returns are the single-return answer, but where a ray grazes a shared edge
    first = npz(lidar(app_client, room, {**body, "max_returns": 1}).content)
    assert np.mean(np.isin(answer["ray"][answer["return"] == 0], first["ray"])) > 0.999


def test_a_small_request_answers_json_and_fields_pick_arrays(app_client, room):
    body = {"pose": POSES[0].tolist(), "model": "VLP-16", "horizontal_steps": 16}
    as_json = app_client.post(f"/v1/scenes/{room}/lidar", json=body).json()
    answer = npz(lidar(app_client, room, body).content)
    assert list(as_json) == list(FIELDS)
    assert np.array_equal(np.array(as_json["xyz"], np.float32).reshape(-1, 3), answer["xyz"])
    assert np.array_equal(np.array(as_json["ray"]), answer["ray"])
    picked = npz(lidar(app_client, room, body, "?fields=ray,xyz").content)
    assert list(picked) == ["xyz", "ray"] and np.array_equal(picked["xyz"], answer["xyz"])


def test_a_miss_everywhere_answers_empty_arrays(app_client, room):
    body = {
        "pose": rigid_pose(0, 0, (0, 0, 50.0)).tolist(),
        "vertical_angles_deg": [5.0, 10.0],
        "horizontal_steps": 90,
    }
    answer = npz(lidar(app_client, room, body).content)
    assert list(answer) == list(FIELDS)
    assert answer["xyz"].shape == (0, 3) and answer["ring"].dtype == np.uint16
    assert all(len(a) == 0 for a in answer.values())


POSE = np.eye(4).tolist()


@pytest.mark.parametrize(
    "body, status, words",
    [
        ({"pose": POSE, "model": "VLP-16", "vertical_angles_deg": [0.0]}, 422, "exactly one"),
        ({"pose": POSE}, 422, "exactly one"),
        ({"pose": POSE, "model": "VLP-32"}, 422, "'VLP-16'"),
        ({"pose": POSE, "model": "VLP-16", "horizontal_steps": 0}, 422, "horizontal_steps"),
        ({"pose": POSE, "vertical_angles_deg": []}, 422, "vertical_angles_deg"),
        ({"pose": POSE, "vertical_angles_deg": [91.0]}, 422, "vertical_angles_deg[0]"),
        ({"pose": POSE, "model": "VLP-16", "min_range": 5.0, "max_range": 5.0}, 422, "max_range"),
        ({"pose": POSE, "model": "VLP-16", "min_range": -1.0}, 422, "min_range"),
        ({"pose": POSE, "model": "VLP-16", "max_returns": 0}, 422, "max_returns"),
        ({"pose": POSE, "model": "VLP-16", "max_returns": 65}, 422, "max_returns"),
        (
            {"pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]], "model": "VLP-16"},
            422,
            "rotation",
        ),  # fmt: skip
        ({"pose": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "model": "VLP-16"}, 422, "pose"),
        ({"model": "VLP-16"}, 400, "pose: missing"),
        ({"pose": POSE, "model": "VLP-16", "rpm": 600}, 400, "rpm: unknown key"),
        (
            {"pose": POSE, "model": "OS1-128", "horizontal_steps": 131073},
            413,
            "DACRT_MAX_RAYS_PER_REQUEST",
        ),  # fmt: skip
        (
            {"pose": POSE, "model": "VLP-16", "horizontal_steps": 10**9},
            413,
            "DACRT_MAX_RAYS_PER_REQUEST",
        ),  # beyond the engine's int32 rays too: the request's limit is named first
    ],
)
def test_bad_requests_are_refused_naming_the_problem(app_client, room, body, status, words):
    response = lidar(app_client, room, body)
    assert response.status_code == status, response.text
    assert words in response.json()["detail"]


def test_query_options_are_those_of_the_queries(app_client, app_api, room):
    body = {"pose": POSES[1].tolist(), "model": "VLP-16", "horizontal_steps": 180}
    plain = npz(lidar(app_client, room, body).content)
    for strategy in dacrt.STRATEGIES:
        same = npz(lidar(app_client, room, body, f"?strategy={strategy}").content)
        assert all(np.array_equal(same[k], plain[k]) for k in FIELDS), strategy
    response = lidar(app_client, room, body, "?stats=true")
    stats = json.loads(response.headers["x-trace-stats"])
    assert stats["rays"] == 16 * 180 and stats["strategy"] == dacrt.STRATEGIES[0]
    culled = npz(lidar(app_client, room, body, "?cull=front").content)
    expected = expected_points(app_api, room, POSES[1], PUBLISHED["VLP-16"], 180)
    origins, directions, *_ = lidar_rays(POSES[1], PUBLISHED["VLP-16"], 180)
    front = app_api.closest(room, origins, directions, cull="front")
    assert np.array_equal(culled["ray"], np.flatnonzero(np.isfinite(front.t)))
    assert np.array_equal(culled["range"], front.t[np.isfinite(front.t)])
    assert len(culled["ray"]) < len(expected["ray"])  # the floor faces up: rays from above pass
    for query, words in [("?strategy=fast", "strategy"), ("?cull=both", "cull")]:
        response = lidar(app_client, room, body, query)
        assert response.status_code == 422 and words in response.json()["detail"]


def test_a_rigs_trace_stats_count_every_sensor(app_client, room):
    """A rig of a lidar that sees through surfaces (traced by the engine's hits) and one that
    does not (closest): X-Trace-Stats counts both calls' rays."""
    body = {"pose": POSES[1].tolist(), "model": "VLP-16", "horizontal_steps": 30}
    rig = {
        "sensors": {
            "first": {"kind": "lidar", **body},
            "every": {"kind": "lidar", **body, "return_mode": "all", "max_returns": 2},
        }
    }
    response = app_client.post(f"/v1/scenes/{room}/sensors?stats=true", json=rig)
    assert response.status_code == 200, response.text
    assert json.loads(response.headers["x-trace-stats"])["rays"] == 2 * 16 * 30


@pytest.mark.parametrize("max_returns", [1, 3])
def test_the_query_strings_mask_is_every_beams_ray_mask(app_client, inside_sphere, max_returns):
    """``?mask=`` masks a lidar's rays as a query's: mask 0 sees nothing, so no point returns."""
    body = {"pose": POSES[0].tolist(), "model": "VLP-16", "horizontal_steps": 8}
    body["max_returns"] = max_returns
    assert len(npz(lidar(app_client, inside_sphere, body).content)["xyz"]) == 16 * 8
    hidden = npz(lidar(app_client, inside_sphere, body, "?mask=0").content)
    assert len(hidden["xyz"]) == 0


def read_pcd(content: bytes) -> tuple[dict[str, str], np.ndarray]:
    """(header, records) of a binary PCD v0.7 file, read by its own rules: header lines up to
    ``DATA binary``, then the points, each field's SIZE and TYPE in FIELDS order, no padding."""
    end = content.index(b"DATA binary\n") + len(b"DATA binary\n")
    lines = content[:end].decode("ascii").splitlines()
    header = dict(line.split(" ", 1) for line in lines if not line.startswith("#"))
    names, sizes, kinds = (header[k].split() for k in ("FIELDS", "SIZE", "TYPE"))
    letters = {"F": "f", "I": "i", "U": "u"}
    dtype = np.dtype([(n, f"<{letters[t]}{s}") for n, s, t in zip(names, sizes, kinds)])
    return header, np.frombuffer(content[end:], dtype)


def test_accept_pcd_answers_the_points_as_a_binary_pcd_file(app_client, room):
    body = {"pose": POSES[0].tolist(), "model": "VLP-16", "horizontal_steps": 90}
    points = npz(lidar(app_client, room, body).content)
    response = lidar(app_client, room, body, "?fields=xyz,intensity,ring,label", Accept=PCD)
    assert response.status_code == 200 and response.headers["content-type"] == PCD
    header, records = read_pcd(response.content)
    assert header["VERSION"] == "0.7" and header["FIELDS"] == "x y z intensity ring label"
    assert header["TYPE"] == "F F F F U U" and header["SIZE"] == "4 4 4 4 2 4"
    assert int(header["POINTS"]) == int(header["WIDTH"]) == len(points["xyz"]) > 100
    assert header["HEIGHT"] == "1"
    for axis, name in enumerate("xyz"):
        assert np.array_equal(records[name], points["xyz"][:, axis])
    for name in ("ring", "intensity", "label"):
        assert np.array_equal(records[name], points[name])
    # an organized scan is HEIGHT rings by WIDTH steps
    organized = lidar(app_client, room, {**body, "organized": True}, "?fields=xyz", Accept=PCD)
    header, records = read_pcd(organized.content)
    assert (header["HEIGHT"], header["WIDTH"]) == ("16", "90") and len(records) == 16 * 90
    # a camera has no PCD form
    camera = {"width": 4, "height": 3, "eye": [0, -5, 1], "target": [0, 0, 1], "up": [0, 0, 1]}
    refused = app_client.post(f"/v1/scenes/{room}/camera", json=camera, headers={"Accept": PCD})
    assert refused.status_code == 406


PCD = "application/x-pcd"
STEPS = 64
LIDAR_KEYS = ", ".join(FIELDS + ("time", "velocity", "radial_speed"))


@pytest.mark.parametrize("accept", ["application/x-npz", "application/x-npy", "application/json"])
def test_pcd_columns_are_fields_of_a_pcd_answer_only(app_client, room, accept):
    """x y z (velocity_x ...) name a PCD's columns; the arrays of the other formats are the keys
    (xyz), so those names are unknown there, and the 422 says where they belong."""
    body = {"pose": POSES[0].tolist(), "model": "VLP-16", "horizontal_steps": 8}
    response = lidar(app_client, room, body, "?fields=x,y,z,ring", Accept=accept)
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert detail.startswith(
        f"?fields=x,y,z,ring names unknown fields 'x', 'y', 'z' for lidar; choose from {LIDAR_KEYS}"
    )
    assert "x, y, z, velocity_x, velocity_y, velocity_z name the columns of a PCD answer" in detail
    assert lidar(app_client, room, body, "?fields=xyz,ring", Accept=accept).status_code == 200


def test_an_unknown_field_is_422_naming_the_fields_of_each_format(app_client, room):
    body = {"pose": POSES[0].tolist(), "model": "VLP-16", "horizontal_steps": 8}
    for accept in (PCD, "application/x-npz"):
        response = lidar(app_client, room, body, "?fields=x,colour", Accept=accept)
        assert response.status_code == 422, response.text
        assert response.json()["detail"] == (
            f"?fields=x,colour names unknown fields 'colour' for lidar; choose from {LIDAR_KEYS}"
            " (and, for a PCD answer, x, y, z, velocity_x, velocity_y, velocity_z)"
        )
    # a rig answers no PCD: its fields are the keys
    rig = {"sensors": {"roof": {"kind": "lidar", **body}}}
    response = app_client.post(f"/v1/scenes/{room}/sensors?fields=x,ring", json=rig)
    assert response.status_code == 422, response.text
    assert "unknown fields 'x' for sensors; choose from xyz," in response.json()["detail"]


def test_return_modes_and_max_returns(app_client, inside_sphere):
    """From inside one closed sphere, every beam returns exactly one surface: every mode gives
    one point a beam; max_returns > 1 without return_mode sees through (here: still one)."""
    body = {"pose": np.eye(4).tolist(), "model": "VLP-16", "horizontal_steps": STEPS}
    counts = {}
    for mode in ("first", "last", "strongest", "dual", "all"):
        answer = npz(lidar(app_client, inside_sphere, {**body, "return_mode": mode}).content)
        counts[mode] = len(answer["ray"])
        assert np.array_equal(answer["ray"], np.arange(16 * STEPS)), mode
        assert np.allclose(answer["range"], 40.0, rtol=0.02)  # the sphere's radius
    assert set(counts.values()) == {16 * STEPS}


def test_non_hits_keep_and_organized_answers(app_client, room):
    body = {"pose": POSES[0].tolist(), "vertical_angles_deg": [-10.0, 30.0], "horizontal_steps": 8}
    hits = npz(lidar(app_client, room, body).content)
    kept = npz(lidar(app_client, room, {**body, "non_hits": "keep"}).content)
    assert np.array_equal(kept["ray"], np.arange(16))  # one point a beam, in ray order
    silent = ~np.isin(kept["ray"], hits["ray"])
    assert silent.any() and np.isinf(kept["range"][silent]).all()
    assert (kept["mesh"][silent] == -1).all() and np.isnan(kept["xyz"][silent]).all()
    assert np.array_equal(kept["range"][~silent], hits["range"])
    grid = npz(lidar(app_client, room, {**body, "organized": True}).content)
    assert grid["range"].shape == (2, 8) and grid["xyz"].shape == (2, 8, 3)
    assert np.array_equal(grid["range"].reshape(-1), kept["range"])


def test_noise_is_seeded_and_dropout_drops(app_client, room):
    body = {"pose": POSES[0].tolist(), "model": "VLP-16", "horizontal_steps": 180}
    plain = npz(lidar(app_client, room, body).content)
    noise = {"range_sigma": 0.05, "seed": 11}
    noisy = npz(lidar(app_client, room, {**body, "noise": noise}).content)
    again = npz(lidar(app_client, room, {**body, "noise": noise}).content)
    other = npz(lidar(app_client, room, {**body, "noise": {**noise, "seed": 12}}).content)
    assert np.array_equal(noisy["range"], again["range"])
    assert not np.array_equal(noisy["range"], other["range"])
    error = noisy["range"].astype(np.float64) - plain["range"]
    assert 0.03 < error.std() < 0.07 and abs(error.mean()) < 0.01
    dropped = npz(lidar(app_client, room, {**body, "dropout": {"rate": 0.5, "seed": 1}}).content)
    assert 0.4 < len(dropped["ray"]) / len(plain["ray"]) < 0.6
    assert np.isin(dropped["ray"], plain["ray"]).all()


def test_every_sub_ray_counts_against_the_ray_limit(app_client, room):
    body = {"pose": POSE, "model": "OS1-128", "horizontal_steps": 2049, "beam_samples": 64}
    response = lidar(app_client, room, body)
    assert response.status_code == 413, response.text
    assert "DACRT_MAX_RAYS_PER_REQUEST" in response.json()["detail"]
    rig = {"sensors": {f"l{k}": {"kind": "lidar", **body, "beam_samples": 32} for k in range(2)}}
    response = app_client.post(f"/v1/scenes/{room}/sensors", json=rig)
    assert response.status_code == 413 and "together" in response.json()["detail"]


def test_a_rig_of_more_sensors_than_the_limit_is_413():
    """DACRT_MAX_RIG_SENSORS bounds a rig before its sensors are read; an answer of more than
    65,535 arrays (a zip's 16-bit count) could not be sent otherwise."""
    settings = Settings(token=None, max_rig_sensors=3)
    one_ray = {"kind": "lidar", "pose": POSE, "vertical_angles_deg": [0], "horizontal_steps": 1}
    with in_process.serve(settings) as http:
        assert http.get("/v1/capabilities").json()["limits"]["max_rig_sensors"] == 3
        wall = {"vertices": [[5, -5, -5], [5, 5, -5], [5, 0, 5]], "faces": [[0, 1, 2]]}
        assert http.put("/v1/scenes/limits/meshes/wall", json=wall).status_code == 201
        for count, status in ((3, 200), (4, 413)):
            rig = {"sensors": {f"l{k}": one_ray for k in range(count)}}
            response = http.post("/v1/scenes/limits/sensors", json=rig)
            assert response.status_code == status, response.text
        detail = response.json()["detail"]
        assert "4 sensors" in detail and "DACRT_MAX_RIG_SENSORS" in detail


def test_a_rig_of_many_bad_values_is_422_naming_the_first_in_a_short_message(app_client, room):
    """Every elevation of every sensor out of range: the message names the first bad key,
    spells out a few errors of that sensor and counts its others; the sensors after it are not
    read (their errors together would be the rig's size times a sensor's)."""
    bad = {"kind": "lidar", "pose": POSE, "vertical_angles_deg": [100.0] * 1024}
    good = {"kind": "lidar", "pose": POSE, "model": "VLP-16"}
    rig = {"sensors": {"good": good, **{f"s{k}": bad for k in range(64)}}}
    response = app_client.post(f"/v1/scenes/{room}/sensors", json=rig)
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    first = "sensors: sensors.s0.vertical_angles_deg[0]: Input should be less than or equal to 90;"
    assert detail.startswith(first)
    assert detail.count("vertical_angles_deg[") == 5 and detail.endswith("; and 1,019 more")
    assert len(detail) < 1000


KEYS = {f"a{k}": 0 for k in range(10_000)}


@pytest.mark.parametrize(
    "route, body, first",
    [
        ("lidar", {"pose": POSE, "model": "VLP-16", **KEYS}, "lidar: a0: unknown key; a1:"),
        ("lidar", {"pose": POSE, "model": "VLP-16", "noise": KEYS}, "lidar: noise.a0: unknown"),
        (
            "sensors",
            {"sensors": {"roof": {"kind": "lidar", "pose": POSE, "model": "VLP-16", **KEYS}}},
            "sensors: sensors.roof.a0: unknown key;",
        ),
        ("sensors", {"sensors": {}, **KEYS}, "sensors: a0: unknown key;"),
    ],
)
def test_a_body_of_many_unknown_keys_is_400_naming_the_first_few(
    app_client, room, route, body, first
):
    response = app_client.post(f"/v1/scenes/{room}/{route}", json=body)
    assert response.status_code == 400, response.text
    detail = response.json()["detail"]
    assert detail.startswith(first) and "a4: unknown key; and 9,995 more;" in detail
    assert len(detail) < 1000


def test_a_long_unknown_key_is_cut_in_the_message(app_client, room):
    body = {"pose": POSE, "model": "VLP-16", "noise": {"x" * 100_000: 0}}
    response = app_client.post(f"/v1/scenes/{room}/lidar", json=body)
    assert response.status_code == 400, response.text
    detail = response.json()["detail"]
    assert (
        detail.startswith("lidar: noise.'xxxxxxxx")
        and "... (100000 characters): unknown key" in detail
    )
    assert len(detail) < 1000


def test_a_rig_naming_a_sensor_twice_is_400(app_client, room):
    """JSON keeps the last of a repeated key: a rig of two sensors named alike would answer one
    of them silently, so the body is refused naming the key."""
    one = json.dumps({"kind": "lidar", "pose": POSE, "model": "VLP-16"})
    body = f'{{"sensors": {{"roof": {one}, "roof": {one}}}}}'
    response = app_client.post(
        f"/v1/scenes/{room}/sensors", content=body, headers={"Content-Type": "application/json"}
    )
    assert response.status_code == 400, response.text
    assert "gives the key 'roof' twice" in response.json()["detail"]


@pytest.mark.parametrize(
    "kind, words",
    [
        ({}, "sensors.roof: missing kind ('lidar' or 'camera')"),
        ({"kind": "radar"}, "sensors.roof: kind 'radar' is not 'lidar' or 'camera'"),
    ],
)
def test_a_rig_sensor_without_a_known_kind_is_named(app_client, room, kind, words):
    rig = {"sensors": {"roof": {**kind, "pose": POSE, "model": "VLP-16"}}}
    response = app_client.post(f"/v1/scenes/{room}/sensors", json=rig)
    assert response.status_code in (400, 422), response.text
    assert words in response.json()["detail"]
    assert "discriminator" not in response.text and "tag" not in response.text


def test_a_pcd_of_no_points_is_a_header_only_file(app_client, room):
    """Every point dropped: the PCD has its fields, WIDTH 0, HEIGHT 1, POINTS 0 and no data, as
    PCL writes an empty cloud (docs/sensors.md says which readers take it)."""
    body = {"pose": POSES[0].tolist(), "vertical_angles_deg": [0.0], "horizontal_steps": 8}
    response = lidar(
        app_client, room, {**body, "dropout": {"rate": 1.0}}, "?fields=xyz", Accept=PCD
    )
    assert response.status_code == 200 and response.headers["content-type"] == PCD
    header, records = read_pcd(response.content)
    assert header["FIELDS"] == "x y z" and len(records) == 0
    assert (header["WIDTH"], header["HEIGHT"], header["POINTS"]) == ("0", "1", "0")
    assert response.content.endswith(b"DATA binary\n")
