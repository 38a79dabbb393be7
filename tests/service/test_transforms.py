"""Transforms and instances in process: ``PUT .../transform``, ``MESH.transform`` in frames,
instances (``{"instance_of": ...}``) sharing their source's arrays. Answers on a placed mesh are
those of the same mesh placed in numpy and uploaded whole, and of the numpy reference; bad
matrices are 422 in the engine's words and change nothing; a restart restores every placement."""

from __future__ import annotations

import in_process
import numpy as np
import pytest
import reference
from service_helpers import NPZ, grid, npz_bytes, quad, rays_at

from service.client import Client
from service.settings import Settings

IDENTITY = np.eye(4).tolist()
JSON = {"Content-Type": "application/json"}


def affine(seed: int, scale: float = 1.0, mirror: bool = False) -> np.ndarray:
    """A (4, 4) float64 placement: a random rotation, scaled (mirrored), then moved."""
    rng = np.random.default_rng(seed)
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    matrix = np.eye(4)
    matrix[:3, :3] = rotation * scale * np.array([-1.0 if mirror else 1.0, 1.0, 1.0])
    matrix[:3, 3] = rng.uniform(-5, 5, 3)
    return matrix


def place(vertices: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """The vertices as the contract places them: in float64, rounded to float32."""
    return (vertices.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)


def box(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(2, 3) float32 bounds of the referenced vertices."""
    used = vertices[np.unique(faces)]
    return np.stack([used.min(axis=0), used.max(axis=0)])


def info(http, scene: str, mesh: str | None = None) -> dict:
    path = f"/v1/scenes/{scene}" + (f"/meshes/{mesh}" if mesh else "")
    response = http.get(path)
    assert response.status_code == 200, response.text
    return response.json()


def upload(http, scene: str, mesh: str, vertices, faces, **params) -> dict:
    response = http.put(
        f"/v1/scenes/{scene}/meshes/{mesh}",
        params=params,
        content=npz_bytes(vertices=vertices, faces=faces),
        headers=NPZ,
    )
    assert response.status_code in (200, 201), response.text
    return response.json()


def set_transform(http, scene: str, mesh: str, matrix):
    matrix = matrix.tolist() if isinstance(matrix, np.ndarray) else matrix
    return http.put(f"/v1/scenes/{scene}/meshes/{mesh}/transform", json={"matrix": matrix})


def instance(http, scene: str, mesh: str, source: str, matrix=None, **params):
    body = {"instance_of": source}
    if matrix is not None:
        body["transform"] = matrix.tolist()
    return http.put(f"/v1/scenes/{scene}/meshes/{mesh}", json=body, params=params)


def same_answers(a, b, rays=None) -> None:
    """The same answers; with ``rays`` (origins, directions), ``a`` is a placed mesh's and ``b``
    its copy placed in numpy's: a placed mesh is traced in its own space (docs/engine.md,
    "Instances"), so the same hits but for rays at an exact edge (at most 1 in 200 here), the
    hit within 8 float32 ulps of the coordinates' magnitude across the surface (|dt| |d| cos)
    and normals within 5e-3 (the copies' float32 corners turn a small triangle's normal by
    that much); u and v follow the hit over the triangle's size, unchecked."""
    if rays is None:
        for name in ("mesh", "prim", "t", "u", "v", "normal"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)
        return
    origins, directions = (np.asarray(x, np.float64) for x in rays)
    agree = (a.mesh == b.mesh) & (a.prim == b.prim)
    assert agree.mean() >= 0.995, f"{(~agree).sum()} rays hit something else"
    hit = agree & (b.mesh >= 0)
    o, d = origins[hit], directions[hit]
    scale = np.maximum(np.abs(o).max(axis=1), np.abs(o + b.t[hit, None] * d).max(axis=1))
    cos = np.abs(np.einsum("ij,ij->i", b.normal[hit], d))
    across = np.abs(a.t[hit].astype(np.float64) - b.t[hit]) * cos
    assert np.all(across <= 8 * np.spacing(scale.astype(np.float32))), across.max()
    np.testing.assert_allclose(a.normal[agree], b.normal[agree], atol=5e-3)


# ---- PUT .../transform


def test_a_transform_places_the_mesh_in_one_version(app_client, scene_name, teapot):
    vertices, faces = teapot
    created = upload(app_client, scene_name, "pot", vertices, faces)
    assert created["transform"] == IDENTITY and created["instance_of"] is None
    np.testing.assert_array_equal(np.float32(created["bounds"]), box(vertices, faces))
    matrix = affine(1, scale=2.5)
    response = set_transform(app_client, scene_name, "pot", matrix)
    assert response.status_code == 200, response.text
    moved = response.json()
    assert moved["transform"] == matrix.tolist()  # float64, exactly
    assert moved["version"] == 2 and moved["index"] == created["index"]
    assert (moved["vertices"], moved["triangles"]) == (len(vertices), len(faces))
    np.testing.assert_allclose(
        moved["bounds"], box(place(vertices, matrix), faces), rtol=1e-6, atol=1e-6
    )
    scene = info(app_client, scene_name)
    assert scene["version"] == 2 and scene["bounds"] == moved["bounds"]
    back = set_transform(app_client, scene_name, "pot", IDENTITY).json()
    assert back["transform"] == IDENTITY and back["bounds"] == created["bounds"]


@pytest.mark.parametrize(
    "matrix",
    [affine(2), affine(3, scale=0.01), affine(4, mirror=True), np.diag([1.0, 3.0, 0.5, 1.0])],
    ids=["rigid", "small", "mirrored", "anisotropic"],
)
def test_closest_on_a_placed_mesh_is_that_of_the_mesh_placed_in_numpy(
    app_api, scene_name, teapot, matrix
):
    vertices, faces = teapot
    floor = quad(100, 101, 100, 101, 0)  # out of the way: it makes the pot mesh 1
    placed = place(vertices, matrix)
    for scene, pot in ((scene_name, vertices), (scene_name + "-numpy", placed)):
        app_api.put_mesh(scene, "floor", *floor)
        app_api.put_mesh(scene, "pot", pot, faces)
    app_api.http.put(
        f"/v1/scenes/{scene_name}/meshes/pot/transform", json={"matrix": matrix.tolist()}
    ).raise_for_status()
    origins, directions = rays_at(placed, faces, 1500, seed=5)
    answer = app_api.closest(scene_name, origins, directions)
    numpy_placed = app_api.closest(scene_name + "-numpy", origins, directions)
    same_answers(answer, numpy_placed, (origins, directions))
    assert (answer.mesh == 1).mean() > 0.99  # every ray aims at a point of a pot's triangle
    expected = reference.closest(placed, faces, origins, directions)
    # Rays aimed at an exact edge may hit or miss by rounding (same_answers).
    agree = answer.prim == expected.prim
    assert agree.mean() >= 0.995
    # Along a grazing ray that rounding is larger: same_answers bounds it across the surface.
    np.testing.assert_allclose(answer.t[agree], expected.t[agree], rtol=1e-4)


BAD_MATRICES = [
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]], "matrix is singular"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "matrix is not affine"),
    ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]], "matrix must have shape (4, 4), got (3, 4)"),
    ([[1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "matrix must be a 4x4 matrix"),
    ([["1", 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "matrix must be numbers"),
    ("eye", "matrix must be a 4x4 matrix (4 rows of 4 numbers), not str"),
    (np.diag([1e39, 1e39, 1e39, 1]).tolist(), "places vertex"),
    (np.diag([1e-38, 1, 1, 1]).tolist(), "matrix scales an axis by 1e-38, under 1e-12"),
]


@pytest.mark.parametrize("matrix, message", BAD_MATRICES)
def test_a_bad_matrix_is_422_with_the_engines_message_and_changes_nothing(
    app_client, scene_name, teapot, matrix, message
):
    upload(app_client, scene_name, "pot", *teapot)
    before = set_transform(app_client, scene_name, "pot", affine(6)).json()
    response = set_transform(app_client, scene_name, "pot", matrix)
    assert response.status_code == 422 and message in response.json()["detail"]
    assert info(app_client, scene_name, "pot") == before


@pytest.mark.parametrize("matrix, message", BAD_MATRICES)
def test_a_frame_of_many_placements_names_its_bad_matrix_and_changes_nothing(
    app_client, scene_name, teapot, matrix, message
):
    """A frame's placements are checked together: the one bad matrix among ten is 422 with the
    engine's message naming its key (or its mesh, for a vertex placed beyond float32)."""
    upload(app_client, scene_name, "car0", *teapot)
    for k in range(1, 10):
        app_client.put(
            f"/v1/scenes/{scene_name}/meshes/car{k}", json={"instance_of": "car0"}
        ).raise_for_status()
    frame = {f"car{k}.transform": affine(k).tolist() for k in range(10)}
    before = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).json()["version"]
    frame["car5.transform"] = matrix
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
    named = "transform of mesh 'car5'" if message == "places vertex" else "car5.transform"
    assert response.status_code == 422, response.text
    assert message.replace("matrix", named, 1) in response.json()["detail"], response.text
    assert named in response.json()["detail"]
    assert info(app_client, scene_name, "car0")["version"] == before


@pytest.mark.parametrize("text", ["NaN", "Infinity", "1e999"])
def test_a_non_finite_matrix_is_422(app_client, scene_name, text):
    upload(app_client, scene_name, "a", *quad(0, 1, 0, 1, 0))
    body = f'{{"matrix": [[{text}, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}}'
    response = app_client.put(
        f"/v1/scenes/{scene_name}/meshes/a/transform", content=body, headers=JSON
    )
    assert response.status_code == 422 and "non-finite" in response.json()["detail"]
    assert info(app_client, scene_name, "a")["version"] == 1


def test_a_ray_beyond_float32_in_a_mesh_space_is_422_naming_the_mesh(app_client, scene_name):
    """A far ray that a placed mesh's inverse moves beyond float32: 422 naming the mesh as the
    scene does (its engine position differs once a mesh before it is deleted)."""
    for name in ("gone", "floor", "car"):
        upload(app_client, scene_name, name, *quad(-1, 1, -1, 1, 0))
    assert app_client.delete(f"/v1/scenes/{scene_name}/meshes/gone").status_code == 204
    set_transform(app_client, scene_name, "car", np.diag([0.5, 0.5, 0.5, 1]).tolist())
    far = {"origins": [[0.1, 0.1, 3e38]], "directions": [[0, 0, -1]]}
    for route, body in (
        ("closest", far),
        ("render", {"width": 1, "height": 1, "eye": [0.1, 0.1, 3e38], "target": [0.1, 0.1, 0]}),
    ):
        response = app_client.post(f"/v1/scenes/{scene_name}/{route}", json=body)
        assert response.status_code == 422, response.text
        assert "in the space of mesh 'car'" in response.json()["detail"], response.text


def test_put_transform_needs_a_mesh_a_matrix_and_json(app_client, scene_name):
    upload(app_client, scene_name, "a", *quad(0, 1, 0, 1, 0))
    assert set_transform(app_client, scene_name, "zz", IDENTITY).status_code == 404
    path = f"/v1/scenes/{scene_name}/meshes/a/transform"
    assert app_client.put(path, json={"matrx": IDENTITY}).status_code == 400
    response = app_client.put(path, content=npz_bytes(matrix=np.eye(4)), headers=NPZ)
    assert response.status_code == 415
    assert info(app_client, scene_name)["version"] == 1


# ---- frames


def test_a_frame_sets_transforms_and_vertices_of_several_meshes_in_one_version(
    app_client, scene_name
):
    upload(app_client, scene_name, "a", *quad(0, 1, 0, 1, 0))
    upload(app_client, scene_name, "b", *quad(0, 1, 0, 1, 0))
    move = np.eye(4)
    move[:3, 3] = [10, 0, 0]
    c_vertices, c_faces = quad(0, 1, 0, 1, 1)
    body = npz_bytes(
        **{
            "a.transform": move,
            "b.vertices": quad(0, 2, 0, 2, 3)[0],
            "b.transform": np.diag([1, 1, 2, 1]).astype(np.float32),
            "c.vertices": c_vertices,
            "c.faces": c_faces,
            "c.transform": move,
        }
    )
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", content=body, headers=NPZ)
    assert response.status_code == 200, response.text
    scene = response.json()
    assert scene["version"] == 3 and [m["version"] for m in scene["meshes"]] == [3, 3, 3]
    bounds = {m["mesh"]: m["bounds"] for m in scene["meshes"]}
    assert bounds == {
        "a": [[10, 0, 0], [11, 1, 0]],
        "b": [[0, 0, 6], [2, 2, 6]],
        "c": [[10, 0, 1], [11, 1, 1]],
    }
    assert scene["bounds"] == [[0, 0, 0], [11, 2, 6]]


def test_a_json_frame_sets_transforms_masks_and_makes_instances(app_client, scene_name):
    upload(app_client, scene_name, "car", *grid(3))
    frame = {f"car{i}.instance_of": "car" for i in range(3)}
    frame.update({f"car{i}.transform": affine(i).tolist() for i in range(3)})
    frame.update({"car1.mask": "0x2", "car.mask": 4})
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
    assert response.status_code == 200, response.text
    meshes = {m["mesh"]: m for m in response.json()["meshes"]}
    assert response.json()["version"] == 2
    assert [meshes[f"car{i}"]["transform"] for i in range(3)] == [
        affine(i).tolist() for i in range(3)
    ]
    assert {name: m["mask"] for name, m in meshes.items()} == {
        "car": 4,
        "car0": 0xFFFFFFFF,
        "car1": 2,
        "car2": 0xFFFFFFFF,
    }
    assert {name: m["instance_of"] for name, m in meshes.items()} == {
        "car": None,
        "car0": "car",
        "car1": "car",
        "car2": "car",
    }


@pytest.mark.parametrize(
    "arrays, status, message",
    [
        ({"a.transform": np.full((4, 4), np.nan)}, 422, "a.transform has a non-finite entry"),
        ({"a.transform": np.eye(3)}, 422, "a.transform must have shape (4, 4), got (3, 3)"),
        ({"a.transform": np.eye(4).astype(bool)}, 422, "a.transform must be a float array"),
        ({"a.transform": np.zeros((4, 4))}, 422, "a.transform is not affine"),
        ({"zz.transform": np.eye(4)}, 404, "no mesh 'zz'"),
        ({"a.instance_of": np.zeros(1)}, 422, "a.instance_of must be a mesh name"),
        (
            {"a.normals": np.eye(4)},
            400,
            "MESH.vertices_end, MESH.mask, MESH.instance_of, MESH.reflectivity or MESH.label",
        ),
    ],
)
def test_a_bad_frame_transform_is_refused_and_changes_nothing(
    app_client, scene_name, arrays, status, message
):
    upload(app_client, scene_name, "a", *quad(0, 1, 0, 1, 0))
    upload(app_client, scene_name, "b", *quad(0, 1, 0, 1, 0))
    body = npz_bytes(**{"b.vertices": quad(0, 1, 0, 1, 7)[0], **arrays})
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", content=body, headers=NPZ)
    assert response.status_code == status and message in response.json()["detail"]
    scene = info(app_client, scene_name)
    assert scene["version"] == 2 and scene["bounds"][1][2] == 0


# ---- instances


def test_instances_share_the_source_and_answer_as_placed_copies(app_api, scene_name, teapot):
    http, vertices, faces = app_api.http, *teapot
    source = upload(http, scene_name, "pot", vertices, faces)
    matrices = [affine(10 + i, scale=0.5 + i) for i in range(3)]
    for i, matrix in enumerate(matrices):
        response = instance(http, scene_name, f"pot{i}", "pot", matrix, mask="0x3")
        assert response.status_code == 201, response.text
        made = response.json()
        assert made["version"] == 2 + i and made["index"] == 1 + i
        assert made["instance_of"] == "pot" and made["transform"] == matrix.tolist()
        assert (made["vertices"], made["triangles"], made["mask"]) == (
            source["vertices"],
            source["triangles"],
            3,
        )
        expected = box(place(vertices, matrix), faces)
        np.testing.assert_allclose(made["bounds"], expected, rtol=1e-6, atol=1e-6)
    copies = scene_name + "-copies"
    upload(http, copies, "pot", vertices, faces)
    for i, matrix in enumerate(matrices):
        upload(http, copies, f"pot{i}", place(vertices, matrix), faces)
    origins, directions = map(
        np.concatenate,
        zip(*[rays_at(place(vertices, m), faces, 400, seed=i) for i, m in enumerate(matrices)]),
    )
    answer = app_api.closest(scene_name, origins, directions)
    same_answers(answer, app_api.closest(copies, origins, directions), (origins, directions))
    assert set(np.unique(answer.mesh)) >= {1, 2, 3}


def test_instances_follow_their_sources_arrays(app_api, scene_name):
    http = app_api.http
    upload(http, scene_name, "car", *quad(0, 1, 0, 1, 0))
    move = np.eye(4)
    move[:3, 3] = [5, 0, 0]
    instance(http, scene_name, "twin", "car", move)
    origins = np.array([[5.5, 0.5, 10], [0.5, 0.5, 10]], np.float32)
    directions = np.array([[0, 0, -1], [0, 0, -1]], np.float32)
    assert app_api.closest(scene_name, origins, directions).t.tolist() == [10, 10]
    response = http.put(
        f"/v1/scenes/{scene_name}/meshes/car/vertices",
        json={"vertices": quad(0, 1, 0, 1, 4)[0].tolist()},
    )
    assert response.status_code == 200
    twin = info(http, scene_name, "twin")
    assert twin["version"] == 3 and twin["bounds"] == [[5, 0, 4], [6, 1, 4]]
    answer = app_api.closest(scene_name, origins, directions)
    assert answer.t.tolist() == [6, 6] and answer.mesh.tolist() == [1, 0]
    upload(http, scene_name, "car", *grid(2, z=2.0))  # replaced, another vertex count
    twin = info(http, scene_name, "twin")
    assert (twin["vertices"], twin["triangles"], twin["version"]) == (9, 8, 4)
    assert app_api.closest(scene_name, origins, directions).t.tolist() == [8, 8]


def test_deleting_a_source_with_instances_is_409_naming_them(app_client, scene_name):
    upload(app_client, scene_name, "car", *quad(0, 1, 0, 1, 0))
    upload(app_client, scene_name, "road", *quad(0, 9, 0, 9, -1))
    for name in ("b", "a"):
        assert instance(app_client, scene_name, name, "car").status_code == 201
    before = info(app_client, scene_name)
    response = app_client.delete(f"/v1/scenes/{scene_name}/meshes/car")
    assert response.status_code == 409
    assert "has instances ['b', 'a'], so it cannot be deleted" in response.json()["detail"]
    response = instance(app_client, scene_name, "car", "road")
    assert response.status_code == 409 and "cannot become an instance of 'road'" in response.text
    assert info(app_client, scene_name) == before
    for name in ("a", "b", "car"):
        assert app_client.delete(f"/v1/scenes/{scene_name}/meshes/{name}").status_code == 204
    assert [m["mesh"] for m in info(app_client, scene_name)["meshes"]] == ["road"]


def test_an_instance_is_moved_by_its_transform_not_its_vertices(app_client, scene_name):
    upload(app_client, scene_name, "car", *quad(0, 1, 0, 1, 0))
    instance(app_client, scene_name, "twin", "car")
    moved = {"vertices": quad(0, 1, 0, 1, 4)[0].tolist()}
    response = app_client.put(f"/v1/scenes/{scene_name}/meshes/twin/vertices", json=moved)
    assert response.status_code == 409 and "is an instance of 'car'" in response.text
    frame = {"twin.vertices": moved["vertices"]}
    assert app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame).status_code == 409
    assert info(app_client, scene_name)["version"] == 2
    own = upload(app_client, scene_name, "twin", *quad(0, 1, 0, 1, 4))  # its own arrays now
    assert own["instance_of"] is None and own["index"] == 1 and own["version"] == 3
    assert app_client.delete(f"/v1/scenes/{scene_name}/meshes/car").status_code == 204


@pytest.mark.parametrize(
    "body, status, message",
    [
        ({"instance_of": "zz"}, 404, "has no mesh 'zz' for 'x' to be an instance of"),
        ({"instance_of": "x"}, 422, "mesh 'x' of scene"),
        ({"instance_of": 3}, 422, "instance_of must be a mesh name (a string), not int"),
        ({"instance_of": "a b"}, 422, "mesh name 'a b' must be 1-64 characters"),
        ({"instance_of": "car", "mask": 1}, 400, "unknown keys 'mask'"),
        ({"instance_of": "car", "transform": [[1]]}, 422, "transform must have shape (4, 4)"),
        ({"instance_of": "car", "vertices": [[0, 0, 0]]}, 400, "unknown keys 'vertices'"),
    ],
)
def test_a_bad_instance_is_refused_and_changes_nothing(
    app_client, scene_name, body, status, message
):
    upload(app_client, scene_name, "car", *quad(0, 1, 0, 1, 0))
    response = app_client.put(f"/v1/scenes/{scene_name}/meshes/x", json=body)
    assert response.status_code == status and message in response.json()["detail"]
    assert [m["mesh"] for m in info(app_client, scene_name)["meshes"]] == ["car"]
    assert info(app_client, scene_name)["version"] == 1


def test_an_instance_of_an_instance_shares_the_first_source(app_client, scene_name):
    upload(app_client, scene_name, "car", *quad(0, 1, 0, 1, 0))
    instance(app_client, scene_name, "twin", "car", affine(1))
    made = instance(app_client, scene_name, "triplet", "twin", affine(2)).json()
    assert made["instance_of"] == "car" and made["transform"] == affine(2).tolist()
    assert instance(app_client, scene_name, "twin", "triplet").json()["instance_of"] == "car"
    frame = {"p.instance_of": "q", "q.instance_of": "p"}
    response = app_client.post(f"/v1/scenes/{scene_name}/frame", json=frame)
    assert response.status_code == 422 and "would be instances of each other" in response.text
    assert info(app_client, scene_name)["version"] == 4


def test_a_frame_moves_100_instances_in_one_version(app_api, scene_name):
    http = app_api.http
    upload(http, scene_name, "car", *grid(4))  # [0, 1]^2 at z = 0
    frame = {f"car{i:03}.instance_of": "car" for i in range(100)}
    assert http.post(f"/v1/scenes/{scene_name}/frame", json=frame).json()["version"] == 2
    moves = np.tile(np.eye(4), (100, 1, 1))
    moves[:, 0, 3] = 2 * np.arange(100) + 2  # instance i covers x in [2i + 2, 2i + 3]
    moves[:, 2, 3] = np.arange(100) % 7
    body = npz_bytes(**{f"car{i:03}.transform": moves[i] for i in range(100)})
    response = http.post(f"/v1/scenes/{scene_name}/frame", content=body, headers=NPZ)
    assert response.status_code == 200, response.text
    scene = response.json()
    assert scene["version"] == 3 and scene["triangles"] == 101 * 32
    assert [m["transform"] for m in scene["meshes"][1:]] == moves.tolist()
    assert [m["version"] for m in scene["meshes"]] == [1] + [3] * 100
    origins = np.column_stack(
        [2 * np.arange(100) + 2.5, np.full(100, 0.3), np.full(100, 20.0)]
    ).astype(np.float32)
    directions = np.tile(np.float32([0, 0, -1]), (100, 1))
    answer = app_api.closest(scene_name, origins, directions)
    assert answer.version == 3
    np.testing.assert_array_equal(answer.mesh, np.arange(1, 101))
    np.testing.assert_allclose(answer.t, 20 - np.arange(100) % 7)


# ---- a restart


def test_a_restart_restores_masks_transforms_and_instances(tmp_path, teapot):
    settings = Settings(token=None, load_demo=False, data_dir=tmp_path)
    vertices, faces = teapot
    origins, directions = rays_at(place(vertices, affine(1)), faces, 300, seed=2)
    with in_process.serve(settings) as http:
        upload(http, "s", "pot", vertices, faces, mask="0x1")
        upload(http, "s", "floor", *quad(-9, 9, -9, 9, -6), mask="6")
        set_transform(http, "s", "pot", affine(1)).raise_for_status()
        for i in range(3):
            instance(
                http, "s", f"pot{i}", "pot", affine(20 + i), mask=str(2 + i)
            ).raise_for_status()
        http.put("/v1/scenes/s/meshes/pot/vertices", json={"vertices": vertices.tolist()})
        before = info(http, "s")
        answer = Client(http=http).closest("s", origins, directions)
    arrays = sorted(p.name for p in (tmp_path / "scenes" / "s").glob("*.npy"))
    assert len(arrays) == 4  # pot's and floor's vertices and faces: instances hold none
    with in_process.serve(settings) as http:
        assert info(http, "s") == before
        again = Client(http=http).closest("s", origins, directions)
        same_answers(again, answer)
        assert again.version == answer.version == before["version"]
        response = http.delete("/v1/scenes/s/meshes/pot")
        assert response.status_code == 409 and "['pot0', 'pot1', 'pot2']" in response.text
