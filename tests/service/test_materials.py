"""Materials (API.md "Materials"): a mesh's reflectivity and label, set with PUT .../material
(either key alone keeps the other) or MESH.reflectivity and MESH.label in a frame, shown in mesh
info, kept when the mesh's arrays change, refused with a 422 naming the key when out of range."""

from __future__ import annotations

import io

import numpy as np
import pytest
from sensor_helpers import put_room


@pytest.fixture
def room(app_api, scene_name):
    put_room(app_api, scene_name)
    return scene_name


def material(app_client, scene, mesh):
    info = app_client.get(f"/v1/scenes/{scene}/meshes/{mesh}").json()
    return info["reflectivity"], info["label"]


def test_defaults_then_either_key_alone(app_client, room):
    assert material(app_client, room, "sphere") == (0.5, 0)
    url = f"/v1/scenes/{room}/meshes/sphere/material"
    response = app_client.put(url, json={"reflectivity": 0.8})
    assert response.status_code == 200 and response.json()["reflectivity"] == 0.8
    assert response.json()["label"] == 0 and response.json()["version"] == 4
    assert app_client.put(url, json={"label": 12}).json()["reflectivity"] == 0.8
    assert material(app_client, room, "sphere") == (0.8, 12)
    assert material(app_client, room, "floor") == (0.5, 0)
    scene = app_client.get(f"/v1/scenes/{room}").json()
    assert [m["label"] for m in scene["meshes"]] == [0, 12, 0]


def test_a_frame_sets_materials_and_a_new_upload_keeps_them(app_client, room):
    frame = {"floor.reflectivity": 0.1, "box.label": 4294967295, "box.reflectivity": 1}
    response = app_client.post(f"/v1/scenes/{room}/frame", json=frame)
    assert response.status_code == 200, response.text
    assert material(app_client, room, "floor") == (0.1, 0)
    assert material(app_client, room, "box") == (1.0, 4294967295)
    body = io.BytesIO()
    np.savez(body, **{"floor.label": np.array([3], np.uint32)})
    response = app_client.post(
        f"/v1/scenes/{room}/frame",
        content=body.getvalue(),
        headers={"Content-Type": "application/x-npz"},
    )
    assert response.status_code == 200, response.text
    assert material(app_client, room, "floor") == (0.1, 3)
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    faces = np.array([[0, 1, 2]], np.int32)
    app_client.put(
        f"/v1/scenes/{room}/meshes/floor",
        json={"vertices": vertices.tolist(), "faces": faces.tolist()},
    )
    assert material(app_client, room, "floor") == (0.1, 3)  # as its mask is kept


@pytest.mark.parametrize(
    "body, status, words",
    [
        ({"reflectivity": 1.5}, 422, "reflectivity must be a number in [0, 1], got 1.5"),
        ({"reflectivity": -0.1}, 422, "reflectivity must be a number in [0, 1]"),
        ({"reflectivity": "0.5"}, 422, "reflectivity must be a number"),
        ({"reflectivity": None}, 422, "reflectivity must be a number"),
        ({"label": -1}, 422, "label must be an integer from 0 to 4294967295, got -1"),
        ({"label": 2**32}, 422, "label must be an integer"),
        ({"label": 1.0}, 422, "label must be an integer"),
        ({"label": True}, 422, "label must be an integer"),
        # a huge number or a long text is not echoed whole
        ({"reflectivity": 10**400}, 422, "got an integer of 1329 bits"),
        ({"label": "x" * 10000}, 422, "... (10002 characters)"),
        ({}, 400, "names no material key"),
        (
            {"colour": 1},
            400,
            "unknown keys 'colour'; expected keys reflectivity, label (each optional)",
        ),
    ],
)
def test_bad_materials_are_refused_and_change_nothing(app_client, room, body, status, words):
    before = app_client.get(f"/v1/scenes/{room}").json()["version"]
    response = app_client.put(f"/v1/scenes/{room}/meshes/box/material", json=body)
    assert response.status_code == status and words in response.json()["detail"], response.text
    assert app_client.get(f"/v1/scenes/{room}").json()["version"] == before


def test_unknown_mesh_is_404_and_a_bad_frame_value_names_its_key(app_client, room):
    response = app_client.put(f"/v1/scenes/{room}/meshes/nope/material", json={"label": 1})
    assert response.status_code == 404
    response = app_client.post(f"/v1/scenes/{room}/frame", json={"box.reflectivity": 3})
    assert response.status_code == 422 and "box.reflectivity" in response.json()["detail"]
