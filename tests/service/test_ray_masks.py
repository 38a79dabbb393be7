"""Per-ray visibility masks: ``mask`` in .npz and JSON ray bodies, ``?mask=`` for a whole batch of
any format, on every query kind; bad masks are 422 naming the problem.

A ray sees a mesh where ray mask & mesh mask != 0. The teapot keeps the default mesh mask
0xFFFFFFFF, so a ray sees it unless its mask is 0; the layered scene gives its meshes masks of
their own (``?mask=`` on upload). Answers are compared with the plain-NumPy reference.
"""

from __future__ import annotations

import io
import json
from types import SimpleNamespace

import numpy as np
import procedural
import pytest
import reference
from service_helpers import NPY, NPZ, down_rays, grid, npy_bytes, npz_bytes, rays_at

from service.client import read_answer

QUERIES = ("closest", "occluded", "hits", "count")


@pytest.fixture
def teapot_scene(app_api, scene_name, teapot):
    app_api.put_mesh(scene_name, "teapot", *teapot)
    return scene_name


@pytest.fixture
def teapot_rays(teapot):
    """300 rays towards the teapot (every one hits it) and masks, a third of them 0."""
    origins, directions = rays_at(*teapot, 300, seed=21)
    masks = np.random.default_rng(22).integers(1, 2**32, 300, dtype=np.uint32)
    masks[::3] = 0
    return origins, directions, masks


def answers_agree(answer, query, blind, teapot, origins, directions):
    """``answer`` of ``query`` is the reference's for rays that see the teapot and a miss for the
    ``blind`` ones."""
    if query == "closest":
        expected = reference.closest(*teapot, origins, directions)
        np.testing.assert_allclose(answer.t[~blind], expected.t[~blind], rtol=1e-4)
        assert np.isinf(answer.t[blind]).all() and (answer.prim[blind] == -1).all()
        assert np.isfinite(answer.t[~blind]).all()
    elif query == "occluded":
        assert np.array_equal(answer.occluded, ~blind)
    else:
        expected = reference.count(*teapot, origins, directions, perturbation="shear")
        assert (expected > 0).all(), "every ray crosses the teapot"
        expected[blind] = 0
        got = answer.count if query == "count" else np.diff(answer.offsets)
        assert np.array_equal(got, expected)


@pytest.mark.parametrize("query", QUERIES)
def test_per_ray_masks_in_an_npz_body(app_api, teapot_scene, teapot, teapot_rays, query):
    origins, directions, masks = teapot_rays
    answer = app_api.query(teapot_scene, query, origins, directions, mask=masks)
    answers_agree(answer, query, masks == 0, teapot, origins, directions)


@pytest.mark.parametrize("query", QUERIES)
def test_per_ray_masks_in_a_json_body(
    app_client, app_api, teapot_scene, teapot, teapot_rays, query
):
    origins, directions, masks = teapot_rays
    body = {"origins": origins.tolist(), "directions": directions.tolist(), "mask": masks.tolist()}
    response = app_client.post(f"/v1/scenes/{teapot_scene}/{query}", json=body)
    assert response.status_code == 200, response.text
    answer = read_answer(response)
    answers_agree(SimpleNamespace(**answer), query, masks == 0, teapot, origins, directions)
    binary = app_api.query(teapot_scene, query, origins, directions, mask=masks)
    assert list(answer) == list(binary)
    assert all(np.array_equal(answer[key], binary[key]) for key in binary)


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize(
    "mask, blind",
    [
        ("0", True),
        ("0x0", True),
        ("1", False),
        ("0xFFFFFFFF", False),
        ("4294967295", False),
        ("0x80000000", False),
    ],
)
def test_query_string_mask_for_the_whole_batch(
    app_client, teapot_scene, teapot, query, mask, blind
):
    origins, directions = rays_at(*teapot, 100, seed=23)
    rays = np.hstack([origins, directions]).astype(np.float32)
    bodies = {
        "npy": (npy_bytes(rays), NPY),
        "npz": (npz_bytes(origins=origins, directions=directions), NPZ),
        "json": (
            json_bytes(origins=origins.tolist(), directions=directions.tolist()),
            {"Content-Type": "application/json"},
        ),
    }
    seen = []
    for body, headers in bodies.values():
        response = app_client.post(
            f"/v1/scenes/{teapot_scene}/{query}?mask={mask}",
            content=body,
            headers={**headers, "Accept": "application/x-npz"},
        )
        assert response.status_code == 200, response.text
        with np.load(io.BytesIO(response.content)) as answer:
            seen.append({key: answer[key] for key in answer.files})
    for other in seen[1:]:
        assert all(np.array_equal(other[key], seen[0][key]) for key in seen[0])
    answers_agree(
        SimpleNamespace(**seen[0]), query, np.full(100, blind), teapot, origins, directions
    )


def json_bytes(**values):
    return json.dumps(values).encode()


def test_a_mask_of_one_value_in_the_body_applies_to_every_ray(app_client, teapot_scene, teapot):
    origins, directions = rays_at(*teapot, 20, seed=24)
    for mask, expected in ((0, False), (7, True)):
        body = npz_bytes(origins=origins, directions=directions, mask=np.uint32(mask))
        response = app_client.post(f"/v1/scenes/{teapot_scene}/occluded", content=body, headers=NPZ)
        with np.load(io.BytesIO(response.content)) as answer:
            assert (answer["occluded"] == expected).all()
        document = {"origins": origins.tolist(), "directions": directions.tolist(), "mask": mask}
        response = app_client.post(f"/v1/scenes/{teapot_scene}/count", json=document)
        assert (np.array(response.json()["count"]) > 0).all() == expected


def test_the_one_shot_trace_takes_masks(app_api, teapot, teapot_rays):
    origins, directions, masks = teapot_rays
    for query in QUERIES:
        answer = app_api.trace(*teapot, origins, directions, query=query, mask=masks)
        answers_agree(answer, query, masks == 0, teapot, origins, directions)
    blind = app_api.trace(*teapot, origins, directions, query="count", mask=0)
    assert (blind.count == 0).all()


def test_masks_combine_with_cull_and_bounds(app_api, teapot_scene, teapot, teapot_rays):
    origins, directions, masks = teapot_rays
    tmin, tmax = np.float32(0.5), np.full(300, 1.5, np.float32)  # each ray's target is at t = 1
    answer = app_api.hits(teapot_scene, origins, directions, tmin, tmax, mask=masks, cull="back")
    expected = reference.count(
        *teapot, origins, directions, tmin, tmax, cull="back", perturbation="shear"
    )
    everything = reference.count(*teapot, origins, directions, perturbation="shear")
    assert 50 < expected.sum() < everything.sum(), "vacuous"
    expected[masks == 0] = 0
    assert np.array_equal(np.diff(answer.offsets), expected)


# ---- refusals


def post_npz(app_client, scene, query="closest", params="", **arrays):
    return app_client.post(
        f"/v1/scenes/{scene}/{query}{params}", content=npz_bytes(**arrays), headers=NPZ
    )


RAYS = down_rays(np.zeros((3, 2)))


@pytest.mark.parametrize(
    "mask, detail",
    [
        (
            np.array([1, 2, 3], np.int32),
            "mask must be little-endian uint32, got <i4 (int32); convert with .astype('<u4')",
        ),
        (
            np.array([1, 2, 3], np.uint64),
            "mask must be little-endian uint32, got <u8 (uint64); convert with .astype('<u4')",
        ),
        (
            np.array([1, 2, 3], np.float32),
            "mask must be little-endian uint32, got <f4 (float32); convert with .astype('<u4')",
        ),
        (
            np.array([1, 2, 3], ">u4"),
            "mask must be little-endian uint32, got >u4 (>u4); convert with .astype('<u4')",
        ),
        (np.array([1, 2], np.uint32), "mask has 2 values but there are 3 rays"),
        (np.ones((3, 1), np.uint32), "mask must be one value or shape (N,), got (3, 1)"),
    ],
)
@pytest.mark.parametrize("query", QUERIES)
def test_a_bad_npz_mask_is_422_naming_it(app_client, teapot_scene, query, mask, detail):
    origins, directions = RAYS
    response = post_npz(
        app_client, teapot_scene, query, origins=origins, directions=directions, mask=mask
    )
    assert response.status_code == 422 and response.json()["detail"] == detail


@pytest.mark.parametrize(
    "mask, detail",
    [
        ([1, -1, 3], "mask[1] is -1, outside the uint32 range [0, 2**32) (1 out of range)"),
        (
            [2**32, 0, 2**40],
            "mask[0] is 4294967296, outside the uint32 range [0, 2**32) (2 out of range)",
        ),
        (-5, "mask is -5, outside the uint32 range [0, 2**32) (1 out of range)"),
        ([1, 1.5, 3], "mask must be integers, found the number 1.5"),
        ([1, "0xff", 3], "mask must be integers, found the string '0xff'"),
        ("255", "mask must be integers, found the string '255'"),
        (True, "mask must be integers, found true"),
        ([1, 2], "mask has 2 values but there are 3 rays"),
        ([[1], [2], [3]], "mask must be one integer or a list of integers, not nested lists"),
    ],
)
def test_a_bad_json_mask_is_422_naming_it(app_client, teapot_scene, mask, detail):
    origins, directions = RAYS
    body = {"origins": origins.tolist(), "directions": directions.tolist(), "mask": mask}
    response = app_client.post(f"/v1/scenes/{teapot_scene}/count", json=body)
    assert response.status_code == 422 and response.json()["detail"] == detail


@pytest.mark.parametrize(
    "mask, words",
    [
        ("-1", "?mask=-1 is negative"),
        ("4294967296", "?mask=4294967296 is over 0xFFFFFFFF"),
        ("0x100000000", "?mask=4294967296 is over 0xFFFFFFFF"),
        ("1.5", "?mask='1.5' is not a mask"),
        ("ff", "?mask='ff' is not a mask"),
        ("0x", "?mask='0x' is not a mask"),
        ("", "?mask='' is not a mask"),
        ("1e3", "?mask='1e3' is not a mask"),
    ],
)
def test_a_bad_query_string_mask_is_422_naming_it(app_client, teapot_scene, mask, words):
    body = npy_bytes(np.hstack(RAYS).astype(np.float32))
    response = app_client.post(
        f"/v1/scenes/{teapot_scene}/hits", params={"mask": mask}, content=body, headers=NPY
    )
    assert response.status_code == 422
    assert response.json()["detail"] == (
        f"{words}; a mask is a uint32, in decimal (255) or hex (0xff), from 0 to 0xFFFFFFFF"
    )


def test_a_mask_in_the_body_and_the_query_string_is_422(app_client, teapot_scene):
    origins, directions = RAYS
    response = post_npz(
        app_client,
        teapot_scene,
        "count",
        "?mask=1",
        origins=origins,
        directions=directions,
        mask=np.ones(3, np.uint32),
    )
    assert response.status_code == 422
    assert response.json()["detail"] == (
        "the rays carry a mask in the body and in ?mask= too; send one of them "
        "(?mask= gives every ray of the batch one mask)"
    )


def test_the_client_refuses_masks_it_cannot_send(app_api, teapot_scene):
    origins, directions = RAYS
    for bad, words in (
        (-1, "mask must lie in [0, 2**32)"),
        (2**32, "mask must lie in [0, 2**32)"),
        (1.5, "mask must be an integer"),
        (True, "mask must be an integer"),
        (np.array([1, 2]), "mask must have shape (3,)"),
        (np.array([1, -2, 3]), "mask values must lie in [0, 2**32)"),
        (np.array([1.0, 2.0, 3.0]), "mask must be integers"),
    ):
        with pytest.raises(ValueError) as caught:
            app_api.count(teapot_scene, origins, directions, mask=bad)
        assert words in str(caught.value)


# ---- ray masks against mesh masks


@pytest.fixture
def layered_scene(app_api, scene_name):
    """Four stacked 3 x 3 grids whose meshes have masks 0b001, 0b010, 0b100 and the default."""
    layers = [grid(3, z=z) for z in (0, 1, 2, 3)]
    masks = [0b001, 0b010, 0b100, None]
    for k, (mesh, mask) in enumerate(zip(layers, masks)):
        app_api.put_mesh(scene_name, f"layer{k}", *mesh, mask=mask)
    face_masks = np.concatenate(
        [
            np.full(len(f), 0xFFFFFFFF if m is None else m, np.uint32)
            for (_, f), m in zip(layers, masks)
        ]
    )
    vertices, faces, _ = procedural.concat(layers)
    return scene_name, vertices, faces, face_masks


@pytest.mark.parametrize("query", QUERIES)
def test_ray_masks_meet_mesh_masks_as_the_reference_says(app_api, layered_scene, query):
    scene, vertices, faces, face_masks = layered_scene
    rng = np.random.default_rng(25)
    origins, directions = down_rays(rng.uniform(0.05, 0.95, (300, 2)))
    directions[:, :2] = rng.normal(scale=0.02, size=(300, 2))
    ray_masks = rng.integers(0, 16, 300).astype(np.uint32)  # 8 and 0 see the default mesh only
    every = reference.all_hits(
        vertices,
        faces,
        origins,
        directions,
        ray_masks=ray_masks,
        face_masks=face_masks,
        perturbation="shear",
    )
    answer = app_api.query(scene, query, origins, directions, mask=ray_masks)
    count = np.diff(every.offsets)
    assert set(count.tolist()) >= {0, 1, 2, 3, 4}, "vacuous: masks select too little"
    if query == "count":
        assert np.array_equal(answer.count, count)
    elif query == "occluded":
        assert np.array_equal(answer.occluded, count > 0)
    elif query == "hits":
        assert np.array_equal(answer.offsets, every.offsets)
        first_rows = np.cumsum([0] + [len(faces) // 4] * 3)
        mesh = np.searchsorted(first_rows, every.prim, side="right") - 1
        assert np.array_equal(answer.mesh, mesh)
        assert np.array_equal(answer.prim, every.prim - first_rows[mesh])
        np.testing.assert_allclose(answer.t, every.t, rtol=1e-5)
    else:
        first = every.offsets[:-1][count > 0]
        np.testing.assert_allclose(answer.t[count > 0], every.t[first], rtol=1e-5)
        assert np.isinf(answer.t[count == 0]).all()
    one = app_api.query(scene, query, origins, directions, mask=0b010)
    both = app_api.query(scene, query, origins, directions, mask=np.full(300, 0b010, np.uint32))
    assert all(np.array_equal(one[key], both[key]) for key in one)
