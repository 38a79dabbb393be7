"""POST /v1/scenes/{scene}/hits and /count, and /v1/trace?query=hits|count, against the plain-NumPy
reference (``reference.all_hits``, ``reference.count``: exact, with the engine contract's
half-open rule at shared edges and vertices)."""

from __future__ import annotations

import io

import in_process
import numpy as np
import procedural
import pytest
import reference
from service_helpers import NPY, NPZ, down_rays, grid, npy_bytes, npz_bytes, quad, rays_at

from service import wire
from service.client import APIError, Client
from service.settings import Settings

HIT_FIELDS = ("offsets", "t", "mesh", "prim", "u", "v", "normal", "truncated")


@pytest.fixture
def teapot_scene(app_api, scene_name, teapot):
    app_api.put_mesh(scene_name, "teapot", *teapot)
    return scene_name


def expected_hits(meshes, indices, origins, directions, max_hits=16, **options):
    """The reference's hits on the meshes [(vertices, faces)] reported by their ``indices``:
    (offsets, t, mesh, prim, u, v, truncated) as the service answers them."""
    vertices, faces, first_rows = procedural.concat(meshes)
    every = reference.all_hits(
        vertices, faces, origins, directions, perturbation="shear", **options
    )
    kept, truncated = reference.nearest(every, max_hits)
    position = np.searchsorted(first_rows, kept.prim, side="right") - 1
    mesh = np.asarray(indices)[position]
    return kept.offsets, kept.t, mesh, kept.prim - first_rows[position], kept.u, kept.v, truncated


def assert_hits_equal(answer, expected):
    offsets, t, mesh, prim, u, v, truncated = expected
    assert np.array_equal(answer.offsets, offsets)
    assert np.array_equal(answer.truncated, truncated)
    assert np.array_equal(answer.mesh, mesh) and np.array_equal(answer.prim, prim)
    np.testing.assert_allclose(answer.t, t, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(answer.u, u, atol=1e-4)
    np.testing.assert_allclose(answer.v, v, atol=1e-4)


# ---- answers against the reference


def test_hits_match_the_reference_on_the_teapot(app_api, teapot_scene, teapot):
    vertices, faces = teapot
    origins, directions = rays_at(vertices, faces, 400, seed=1)
    directions[::5] *= -1  # some point away: fewer hits, some none
    answer = app_api.hits(teapot_scene, origins, directions)
    assert list(answer) == list(HIT_FIELDS)
    expected = expected_hits([teapot], [0], origins, directions)
    assert expected[0][-1] > 800 and (np.diff(expected[0]) == 0).sum() > 20, "vacuous"
    assert_hits_equal(answer, expected)
    assert answer.offsets.dtype == np.int64 and answer.truncated.dtype == bool
    for key in ("t", "u", "v", "normal"):
        assert answer[key].dtype == np.float32, key
    # normals: the unit geometric normal of each hit triangle
    p = vertices[faces[answer.prim]].astype(np.float64)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    np.testing.assert_allclose(answer.normal, n / np.linalg.norm(n, axis=1)[:, None], atol=1e-4)
    # each ray's hits are sorted by t; the first is closest's
    ray = np.repeat(np.arange(len(origins)), np.diff(answer.offsets))
    assert (np.diff(answer.t)[ray[1:] == ray[:-1]] >= 0).all()
    closest = app_api.closest(teapot_scene, origins, directions)
    first = answer.offsets[:-1][np.diff(answer.offsets) > 0]
    np.testing.assert_array_equal(answer.t[first], closest.t[np.isfinite(closest.t)])


@pytest.mark.parametrize("max_hits", [1, 2, 4])
def test_hits_keep_the_nearest_max_hits_and_flag_truncated(app_api, teapot_scene, teapot, max_hits):
    origins, directions = rays_at(*teapot, 300, seed=2)
    answer = app_api.hits(teapot_scene, origins, directions, max_hits=max_hits)
    expected = expected_hits([teapot], [0], origins, directions, max_hits)
    assert expected[-1].sum() > 5, "vacuous: few truncated rays"
    assert_hits_equal(answer, expected)
    assert np.diff(answer.offsets).max() == max_hits


def test_count_matches_the_reference_and_the_hits(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 400, seed=3)
    directions[::4] *= -1
    count = app_api.count(teapot_scene, origins, directions)
    assert list(count) == ["count"] and count.count.dtype == np.int32
    expected = reference.count(*teapot, origins, directions, perturbation="shear")
    assert expected.max() >= 4 and (expected == 0).sum() > 20, "vacuous"
    assert np.array_equal(count.count, expected)
    hits = app_api.hits(teapot_scene, origins, directions, max_hits=64)
    assert not hits.truncated.any() and np.array_equal(np.diff(hits.offsets), count.count)


def test_hits_and_count_report_stable_mesh_indices(app_api, scene_name):
    """Meshes stacked along z, one deleted: hits name the meshes by their index, not position."""
    layers = {name: grid(3, z=z) for name, z in (("a", 0), ("b", 1), ("c", 2), ("d", 3))}
    for name, mesh in layers.items():
        app_api.put_mesh(scene_name, name, *mesh)
    app_api.delete_mesh(scene_name, "b")
    rng = np.random.default_rng(4)
    origins, directions = down_rays(rng.uniform(-0.2, 1.2, (200, 2)))
    directions[:, :2] = rng.normal(scale=0.05, size=(200, 2))
    answer = app_api.hits(scene_name, origins, directions)
    kept = [layers[name] for name in ("a", "c", "d")]
    expected = expected_hits(kept, [0, 2, 3], origins, directions)
    assert set(expected[2].tolist()) == {0, 2, 3}
    assert_hits_equal(answer, expected)
    count = app_api.count(scene_name, origins, directions).count
    assert np.array_equal(count, np.diff(expected[0]))


@pytest.mark.parametrize("cull", ["back", "front"])
def test_cull_applies_to_hits_and_count(app_api, teapot_scene, teapot, cull):
    origins, directions = rays_at(*teapot, 300, seed=5)
    answer = app_api.hits(teapot_scene, origins, directions, cull=cull)
    expected = expected_hits([teapot], [0], origins, directions, cull=cull)
    assert_hits_equal(answer, expected)
    count = app_api.count(teapot_scene, origins, directions, cull=cull).count
    expected = reference.count(*teapot, origins, directions, cull=cull, perturbation="shear")
    assert np.array_equal(count, expected)
    assert 0 < count.sum() < app_api.count(teapot_scene, origins, directions).count.sum()


def test_tmin_and_tmax_bound_hits_and_count(app_api, scene_name):
    for z in (1, 3, 5):
        app_api.put_mesh(scene_name, f"at{z}", *quad(0, 1, 0, 1, z))
    origins, directions = down_rays(np.full((4, 2), 0.3))
    tmin, tmax = [0, 6, 5, 0], [np.inf, np.inf, 7, 4]  # t = 5, 7, 9 on the three quads
    answer = app_api.hits(scene_name, origins, directions, tmin, tmax)
    assert answer.offsets.tolist() == [0, 3, 5, 7, 7]
    assert answer.t.tolist() == [5, 7, 9, 7, 9, 5, 7] and answer.mesh.tolist() == [
        2,
        1,
        0,
        1,
        0,
        2,
        1,
    ]
    assert app_api.count(scene_name, origins, directions, tmin, tmax).count.tolist() == [3, 2, 2, 0]


# ---- the crossing rule at shared edges and vertices


def test_a_ray_through_a_shared_edge_or_vertex_counts_once(app_api, scene_name):
    """A 4 x 4 grid: rays through its inner vertices, edges and diagonals cross it once."""
    vertices, faces = grid(4)
    app_api.put_mesh(scene_name, "grid", vertices, faces)
    points = np.array([[0.25, 0.25], [0.5, 0.5], [0.75, 0.25], [0.125, 0.125], [0.5, 0.125]])
    origins, directions = down_rays(points)
    assert app_api.count(scene_name, origins, directions).count.tolist() == [1] * 5
    hits = app_api.hits(scene_name, origins, directions)
    assert hits.offsets.tolist() == [0, 1, 2, 3, 4, 5] and (hits.t == 10).all()


def test_rays_through_the_vertices_of_a_closed_mesh_count_odd_from_inside(app_api, scene_name):
    vertices, faces = procedural.icosphere(2)
    app_api.put_mesh(scene_name, "sphere", vertices, faces)
    inside = np.zeros_like(vertices)
    outside = -2 * vertices  # from beyond the far side, through the centre and a vertex
    from_inside = app_api.count(scene_name, inside, vertices).count
    from_outside = app_api.count(scene_name, outside, vertices - outside).count
    assert (from_inside == 1).all() and (from_outside == 2).all()


# ---- formats, fields and options


def test_json_npz_answers_are_equal(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 200, seed=6)
    directions[::3] *= -1
    for query in ("hits", "count"):
        npz = app_api.query(teapot_scene, query, origins, directions)
        json = app_api.query(teapot_scene, query, origins, directions, answer="json")
        assert list(npz) == list(json)
        for key in npz:
            assert npz[key].dtype == json[key].dtype and np.array_equal(npz[key], json[key]), key
    npy = app_api.count(teapot_scene, origins, directions, answer="npy")
    assert np.array_equal(npy.count, app_api.count(teapot_scene, origins, directions).count)


def test_a_json_request_gets_json(app_client, teapot_scene):
    origins, directions = down_rays([[0, 0], [9, 9]])
    body = {"origins": origins.tolist(), "directions": directions.tolist()}
    response = app_client.post(f"/v1/scenes/{teapot_scene}/hits?fields=t,truncated", json=body)
    assert response.headers["content-type"] == "application/json"
    document = response.json()
    assert list(document) == ["offsets", "t", "truncated"]
    assert document["offsets"][0] == 0 and document["offsets"][2] == document["offsets"][1]
    count = app_client.post(f"/v1/scenes/{teapot_scene}/count", json=body).json()
    assert count == {"count": [document["offsets"][1], 0]}


@pytest.mark.parametrize(
    "fields, keys",
    [
        ("t", ["offsets", "t"]),
        ("prim,mesh", ["offsets", "mesh", "prim"]),
        ("truncated", ["truncated"]),
        ("offsets", ["offsets"]),
        ("truncated,normal,offsets", ["offsets", "normal", "truncated"]),
    ],
)
def test_fields_pick_the_hits_keys_and_offsets_come_with_per_hit_keys(
    app_api, teapot_scene, teapot, fields, keys
):
    origins, directions = rays_at(*teapot, 30, seed=7)
    answer = app_api.hits(teapot_scene, origins, directions, fields=fields)
    assert list(answer) == keys
    full = app_api.hits(teapot_scene, origins, directions)
    for key in keys:
        assert np.array_equal(answer[key], full[key]), key


def test_npy_answers_only_where_every_array_has_a_row_per_ray(app_client, app_api, teapot_scene):
    rays = npy_bytes(np.hstack(down_rays([[0, 0]])).astype(np.float32))
    path = f"/v1/scenes/{teapot_scene}/hits"
    refused = app_client.post(path, content=rays, headers={**NPY, "Accept": wire.NPY})
    assert refused.status_code == 406
    assert "different lengths" in refused.json()["detail"] and wire.NPZ in refused.json()["detail"]
    second_choice = app_client.post(
        path, content=rays, headers={**NPY, "Accept": f"{wire.NPY}, {wire.NPZ};q=0.5"}
    )
    assert second_choice.headers["content-type"] == wire.NPZ
    truncated = app_client.post(
        path + "?fields=truncated", content=rays, headers={**NPY, "Accept": wire.NPY}
    )
    assert np.load(io.BytesIO(truncated.content)).tolist() == [False]
    answer = app_api.hits(teapot_scene, *down_rays([[0, 0]]), fields="truncated", answer="npy")
    assert answer.truncated.tolist() == [False]


def test_every_strategy_gives_the_same_hits(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 300, seed=8)
    strategies = app_api.capabilities()["strategies"]
    answers = [app_api.hits(teapot_scene, origins, directions, strategy=s) for s in strategies]
    counts = [app_api.count(teapot_scene, origins, directions, strategy=s) for s in strategies]
    for answer, count in zip(answers[1:], counts[1:]):
        for key in HIT_FIELDS:
            assert np.array_equal(answer[key], answers[0][key]), key
        assert np.array_equal(count.count, counts[0].count)


def test_stats_version_and_server_timing(app_client, app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 100)
    assert app_api.hits(teapot_scene, origins, directions, stats=True).stats["rays"] == 100
    count = app_api.count(teapot_scene, origins, directions, stats=True)
    assert count.stats["triangles"] == 6320 and count.version == 1
    assert app_api.count(teapot_scene, origins, directions).stats is None
    for query in ("hits", "count"):
        response = app_client.post(
            f"/v1/scenes/{teapot_scene}/{query}",
            content=npy_bytes(np.hstack([origins, directions])),
            headers=NPY,
        )
        assert response.status_code == 200 and response.headers["x-scene-version"] == "1"
        timing = response.headers["server-timing"]
        assert all(f"{name};dur=" in timing for name in ("decode", "trace", "encode"))


def test_metrics_count_hits_and_count_rays(app_client, app_api, teapot_scene):
    def traced(query):
        line = f'dacrt_rays_traced_total{{query="{query}"}} '
        text = app_client.get("/metrics").text
        return float(next((x.split()[-1] for x in text.splitlines() if x.startswith(line)), 0))

    before = traced("hits"), traced("count")
    app_api.hits(teapot_scene, *down_rays(np.zeros((7, 2))))
    app_api.count(teapot_scene, *down_rays(np.zeros((5, 2))))
    assert (traced("hits"), traced("count")) == (before[0] + 7, before[1] + 5)
    text = app_client.get("/metrics").text
    assert 'route="/v1/scenes/{scene}/hits",status="200"' in text


def test_capabilities_list_hits_count_and_their_limits(app_api):
    caps = app_api.capabilities()
    assert {"hits", "count"} <= set(caps["queries"])
    assert caps["fields"]["hits"] == list(HIT_FIELDS) and caps["fields"]["count"] == ["count"]
    assert caps["limits"]["max_hits"] == 1024 and caps["limits"]["max_hits_bytes"] == 2 * 2**30


# ---- edge cases


def test_empty_batch_answers_empty_arrays(app_api, teapot_scene):
    nothing = np.zeros((0, 3))
    for answer in ("npz", "json"):
        hits = app_api.hits(teapot_scene, nothing, nothing, answer=answer)
        assert hits.offsets.tolist() == [0] and hits.offsets.dtype == np.int64
        assert hits.t.shape == (0,) and hits.normal.shape == (0, 3) and hits.truncated.shape == (0,)
        count = app_api.count(teapot_scene, nothing, nothing, answer=answer)
        assert count.count.shape == (0,) and count.count.dtype == np.int32


def test_scene_without_triangles_answers_no_hits(app_api, scene_name):
    app_api.put_mesh(scene_name, "empty", np.zeros((0, 3)), np.zeros((0, 3)))
    origins, directions = down_rays(np.zeros((3, 2)))
    hits = app_api.hits(scene_name, origins, directions)
    assert hits.offsets.tolist() == [0, 0, 0, 0] and not hits.truncated.any()
    assert app_api.count(scene_name, origins, directions).count.tolist() == [0, 0, 0]


def test_one_shot_trace_answers_hits_and_count(app_api, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 200, seed=9)
    for query, options in (("hits", {"max_hits": 3}), ("count", {})):
        once = app_api.trace(*teapot, origins, directions, query=query, **options)
        stored = app_api.query(teapot_scene, query, origins, directions, **options)
        assert once.version == 0 and list(once) == list(stored)
        for key in stored:
            assert np.array_equal(once[key], stored[key]), key


# ---- refusals


@pytest.mark.parametrize(
    "max_hits, words",
    [
        ("0", "greater than or equal to 1"),
        ("-1", "greater than or equal to 1"),
        ("1025", "1 to 1024 (DACRT_MAX_HITS)"),
        ("99999999999999999999999", "1 to 1024 (DACRT_MAX_HITS)"),
        ("abc", "valid integer"),
        ("1.5", "valid integer"),
        ("", "valid integer"),
    ],
)
def test_bad_max_hits_is_422_naming_it(app_client, teapot_scene, max_hits, words):
    rays = npy_bytes(np.hstack(down_rays([[0, 0]])).astype(np.float32))
    response = app_client.post(
        f"/v1/scenes/{teapot_scene}/hits?max_hits={max_hits}", content=rays, headers=NPY
    )
    assert response.status_code == 422
    assert "max_hits" in response.json()["detail"] and words in response.json()["detail"]


def test_max_hits_belongs_to_hits_only(app_client, teapot_scene, teapot):
    rays = npy_bytes(np.hstack(down_rays([[0, 0]])).astype(np.float32))
    response = app_client.post(
        f"/v1/scenes/{teapot_scene}/count?max_hits=3", content=rays, headers=NPY
    )
    assert response.status_code == 422 and "'max_hits'" in response.json()["detail"]
    vertices, faces = teapot
    body = npz_bytes(
        vertices=vertices,
        faces=faces,
        origins=np.zeros((1, 3), np.float32),
        directions=np.ones((1, 3), np.float32),
    )
    once = app_client.post("/v1/trace?query=closest&max_hits=3", content=body, headers=NPZ)
    assert once.status_code == 422
    assert once.json()["detail"] == "max_hits applies to the hits query only, not to closest"


def test_unknown_hits_field_is_422(app_client, teapot_scene):
    rays = npy_bytes(np.hstack(down_rays([[0, 0]])).astype(np.float32))
    response = app_client.post(
        f"/v1/scenes/{teapot_scene}/hits?fields=t,occluded", content=rays, headers=NPY
    )
    assert response.status_code == 422
    assert response.json()["detail"] == (
        "?fields=t,occluded names unknown fields 'occluded' for hits; "
        "choose from offsets, t, mesh, prim, u, v, normal, truncated"
    )


def test_bad_rays_are_422_naming_the_first(app_api, teapot_scene):
    origins, directions = down_rays(np.zeros((4, 2)))
    directions[2] = 0
    for query in ("hits", "count"):
        with pytest.raises(APIError) as caught:
            app_api.query(teapot_scene, query, origins, directions)
        assert caught.value.status == 422 and "directions[2] is zero" in caught.value.detail


@pytest.fixture(scope="module")
def small_hits_api():
    """A client of an app whose hit buffers are limited to 300 kB (and max_hits to 64)."""
    settings = Settings(token=None, load_demo=False, max_hits=64, max_hits_bytes=300_000)
    with in_process.serve(settings) as http:
        yield Client(http=http)


def test_hit_buffers_over_the_limit_are_413_naming_it(small_hits_api, scene_name, teapot):
    small_hits_api.put_mesh(scene_name, "teapot", *teapot)
    origins, directions = rays_at(*teapot, 1000, seed=10)
    # 1000 rays x (5 + 1) x 48 bytes = 288000: within the limit
    assert len(small_hits_api.hits(scene_name, origins, directions, max_hits=5).truncated) == 1000
    with pytest.raises(APIError) as caught:
        small_hits_api.hits(scene_name, origins, directions, max_hits=6)
    assert caught.value.status == 413
    assert caught.value.detail == (
        "1000 rays with max_hits=6 need 336000 bytes of hit buffers (1000 x (6 + 1) x 48), "
        "over the limit of 300000 bytes (DACRT_MAX_HITS_BYTES); send fewer rays or a smaller "
        "max_hits"
    )
    with pytest.raises(APIError) as over:
        small_hits_api.hits(scene_name, origins[:1], directions[:1], max_hits=65)
    assert over.value.status == 422 and "1 to 64 (DACRT_MAX_HITS)" in over.value.detail
    assert small_hits_api.count(scene_name, origins, directions).count.sum() > 1000
