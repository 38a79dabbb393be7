"""Mesh visibility masks in process: ``?mask=`` on upload, ``PUT .../mask``, ``MESH.mask`` in
frames; shown in mesh info, kept by the other changes, refused (422 naming the value, nothing
changed) when not a uint32; and what the engine scene of a version sees, against the numpy
reference with per-ray masks."""

from __future__ import annotations

import json

import numpy as np
import pytest
import reference
from service_helpers import NPZ, down_rays, grid, npz_bytes, quad

from service import tracing
from service.store import Store
from service.wire import MeshArrays

ALL = 0xFFFFFFFF
JSON = {"Content-Type": "application/json"}


def put(http, scene: str, mesh: str = "a", mask: str | None = None, z: float = 0.0):
    vertices, faces = quad(0, 1, 0, 1, z)
    params = {} if mask is None else {"mask": mask}
    return http.put(
        f"/v1/scenes/{scene}/meshes/{mesh}",
        params=params,
        content=npz_bytes(vertices=vertices, faces=faces),
        headers=NPZ,
    )


def info(http, scene: str, mesh: str = "a") -> dict:
    response = http.get(f"/v1/scenes/{scene}/meshes/{mesh}")
    assert response.status_code == 200, response.text
    return response.json()


@pytest.mark.parametrize(
    "text, value",
    [("5", 5), ("0x10", 16), ("0XfF", 255), ("0", 0), ("4294967295", ALL), ("0xFFFFFFFF", ALL)],
)
def test_upload_mask_in_decimal_or_hex_is_shown_as_an_int(app_client, scene_name, text, value):
    response = put(app_client, scene_name, mask=text)
    assert response.status_code == 201, response.text
    assert response.json()["mask"] == value and response.json()["version"] == 1
    assert info(app_client, scene_name)["mask"] == value


def test_the_default_mask_is_all_ones(app_client, scene_name):
    assert put(app_client, scene_name).json()["mask"] == ALL


@pytest.mark.parametrize(
    "text, named",
    [
        ("-1", "-1 is negative"),
        ("4294967296", "4294967296 is over 0xFFFFFFFF"),
        ("0x100000000", "4294967296 is over 0xFFFFFFFF"),
        ("abc", "'abc' is not a mask"),
        ("1.5", "'1.5' is not a mask"),
        ("0x", "'0x' is not a mask"),
        ("", "'' is not a mask"),
    ],
)
def test_a_bad_upload_mask_is_422_naming_it_and_changes_nothing(
    app_client, scene_name, text, named
):
    put(app_client, scene_name, mask="7")
    response = put(app_client, scene_name, mask=text, z=5.0)
    assert response.status_code == 422
    assert named in response.json()["detail"] and "0xFFFFFFFF" in response.json()["detail"]
    after = info(app_client, scene_name)
    assert after["version"] == 1 and after["mask"] == 7 and after["bounds"][1][2] == 0
    assert put(app_client, scene_name, mesh="b", mask=text).status_code == 422
    assert [m["mesh"] for m in app_client.get(f"/v1/scenes/{scene_name}").json()["meshes"]] == ["a"]


def test_put_mask_changes_the_mask_alone_in_one_version(app_client, scene_name):
    put(app_client, scene_name, mask="3")
    before = info(app_client, scene_name)
    for version, (body, value) in enumerate([({"mask": 12}, 12), ({"mask": "0x30"}, 48)], 2):
        response = app_client.put(f"/v1/scenes/{scene_name}/meshes/a/mask", json=body)
        assert response.status_code == 200, response.text
        assert response.json() == {**before, "mask": value, "version": version}
    assert app_client.get(f"/v1/scenes/{scene_name}").json()["version"] == 3


@pytest.mark.parametrize(
    "body, status, named",
    [
        ({"mask": -2}, 422, "mask=-2 is negative"),
        ({"mask": 2**32}, 422, "mask=4294967296 is over"),
        ({"mask": "0xfffffffff"}, 422, "mask=68719476735 is over"),
        ({"mask": 1.0}, 422, "not float"),
        ({"mask": True}, 422, "not bool"),
        ({"mask": None}, 422, "not NoneType"),
        ({"mask": "ten"}, 422, "mask='ten' is not a mask"),
        ({"mask": 1, "extra": 2}, 400, "unknown keys 'extra'"),
        ({}, 400, "lacks 'mask'"),
    ],
)
def test_a_bad_put_mask_is_refused_and_changes_nothing(app_client, scene_name, body, status, named):
    put(app_client, scene_name, mask="3")
    response = app_client.put(f"/v1/scenes/{scene_name}/meshes/a/mask", json=body)
    assert response.status_code == status and named in response.json()["detail"]
    assert (
        info(app_client, scene_name)["version"] == 1 and info(app_client, scene_name)["mask"] == 3
    )


def test_put_mask_needs_a_mesh_and_json(app_client, scene_name):
    put(app_client, scene_name)
    path = f"/v1/scenes/{scene_name}/meshes/zz/mask"
    assert app_client.put(path, json={"mask": 1}).status_code == 404
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/a/mask", content=npz_bytes(mask=np.uint32(1)), headers=NPZ
    )
    assert response.status_code == 415 and "application/json" in response.json()["detail"]


def test_the_mask_is_kept_by_every_other_change(app_client, scene_name):
    put(app_client, scene_name, mask="0x5")
    path = f"/v1/scenes/{scene_name}/meshes/a"
    moved = quad(0, 1, 0, 1, 2)[0]
    assert app_client.put(f"{path}/vertices", json={"vertices": moved.tolist()}).json()["mask"] == 5
    matrix = np.eye(4)
    matrix[:3, 3] = [1, 2, 3]
    response = app_client.put(f"{path}/transform", json={"matrix": matrix.tolist()})
    assert response.json()["mask"] == 5
    frame = app_client.post(
        f"/v1/scenes/{scene_name}/frame", content=npz_bytes(**{"a.vertices": moved}), headers=NPZ
    )
    assert frame.json()["meshes"][0]["mask"] == 5
    assert put(app_client, scene_name).json()["mask"] == 5  # a replaced mesh keeps its mask
    assert put(app_client, scene_name, mask="9").json()["mask"] == 9
    assert info(app_client, scene_name)["version"] == 6


@pytest.mark.parametrize(
    "fmt, value", [("npz", np.uint32(0xF0)), ("npz", np.array([240], np.int64)), ("json", "0xf0")]
)
def test_a_frame_sets_masks(app_client, scene_name, fmt, value):
    put(app_client, scene_name)
    v, f = quad(0, 1, 0, 1, 1)
    if fmt == "npz":
        body, headers = npz_bytes(**{"a.mask": value, "b.vertices": v, "b.faces": f}), NPZ
    else:
        doc = {"a.mask": value, "b.vertices": v.tolist(), "b.faces": f.tolist(), "b.mask": 3}
        body, headers = json.dumps(doc).encode(), JSON
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", content=body, headers=headers)
    assert response.status_code == 200, response.text
    masks = {m["mesh"]: m["mask"] for m in response.json()["meshes"]}
    assert masks == {"a": 0xF0, "b": 3 if fmt == "json" else ALL}
    assert response.json()["version"] == 2


@pytest.mark.parametrize(
    "value, named",
    [
        (np.float32(1), "a.mask must be an integer (an array of dtype uint32, say), got float32"),
        (np.array([1, 2], np.uint32), "a.mask must be one value, got 2 values"),
        (np.int64(-3), "a.mask=-3 is negative"),
        (np.uint64(2**40), "a.mask=1099511627776 is over"),
    ],
)
def test_a_bad_frame_mask_is_422_and_changes_nothing(app_client, scene_name, value, named):
    put(app_client, scene_name)
    body = npz_bytes(**{"a.mask": value, "a.vertices": quad(0, 1, 0, 1, 9)[0]})
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", content=body, headers=NPZ)
    assert response.status_code == 422 and named in response.json()["detail"]
    assert info(app_client, scene_name)["version"] == 1
    assert info(app_client, scene_name)["bounds"][1][2] == 0


# ---- what the engine scene of a version sees


def stacked_store() -> tuple[Store, list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """Four grids stacked in z (the lowest first), masks 1, 2, 4 and 6; the mesh before them was
    deleted, so their indices start at 1. Answers the store, the meshes and their masks."""
    store = Store(10**6, 10**9)
    store.put_mesh("s", "gone", MeshArrays(*quad(0, 1, 0, 1, 9)))
    meshes, masks = [grid(6, z=float(z)) for z in range(4)], np.array([1, 2, 4, 6], np.uint32)
    for i, ((vertices, faces), mask) in enumerate(zip(meshes, masks)):
        store.put_mesh("s", f"m{i}", MeshArrays(vertices, faces), int(mask))
    store.delete_mesh("s", "gone")
    return store, meshes, masks


@pytest.mark.parametrize(
    "ray_masks, every_ray",
    [
        (None, "hits"),
        (1, "hits"),
        (2, None),
        (4, None),
        (8, "misses"),
        (3, "hits"),
        ("mixed", None),
    ],
)
def test_the_engine_scene_sees_each_mesh_through_its_mask(ray_masks, every_ray):
    store, meshes, masks = stacked_store()
    engine = tracing._snapshot_engine(store.snapshot("s"))
    rng = np.random.default_rng(3)
    origins, directions = down_rays(rng.uniform(0.01, 0.99, (200, 2)), z=-5.0)
    directions = -directions  # upwards: the lowest grid first
    if ray_masks == "mixed":
        ray_masks = rng.choice(np.array([1, 2, 4, 8, 5, 0xFFFFFFFF], np.uint32), 200)
    hits = engine.scene.closest(origins, directions, mask=ray_masks)
    vertices = np.concatenate([v for v, _ in meshes])
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    faces = np.concatenate([f + offset for (_, f), offset in zip(meshes, offsets)])
    face_masks = np.repeat(masks, [len(f) for _, f in meshes])
    expected = reference.closest(
        vertices, faces, origins, directions, ray_masks=ray_masks, face_masks=face_masks
    )
    face_mesh = np.repeat(np.arange(4), [len(f) for _, f in meshes])
    expected_mesh = np.where(expected.hit, face_mesh[np.maximum(expected.prim, 0)] + 1, -1)
    np.testing.assert_array_equal(engine.map_mesh(hits.mesh), expected_mesh)
    np.testing.assert_allclose(hits.t, expected.t, rtol=1e-6)
    if every_ray == "hits":
        assert (hits.mesh >= 0).all()
    elif every_ray == "misses":
        assert (hits.mesh == -1).all()  # no mesh has bit 3
