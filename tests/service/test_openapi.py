"""The OpenAPI document describes what the service reads and answers: bodies with their media
types, answers, errors as ``{"detail": str}``, names, choices and the bearer scheme; real
answers validate against its schemas."""

from __future__ import annotations

import jsonschema
import numpy as np
import pytest
from service_helpers import TOKEN, quad

from service import wire
from service.app import create_app
from service.settings import Settings

DOCUMENT = create_app(Settings(token=None, load_demo=False)).openapi()
#: The document of a server with a bearer token (DACRT_TOKEN).
TOKEN_DOCUMENT = create_app(Settings(token=TOKEN, load_demo=False)).openapi()
#: The operation's security without and with DACRT_TOKEN (API.md "Operations").
TOKEN_OPTIONAL = [{}, {"HTTPBearer": []}]
TOKEN_REQUIRED = [{"HTTPBearer": []}]
OPERATIONS = [
    (method.upper(), path, operation)
    for path, methods in DOCUMENT["paths"].items()
    for method, operation in methods.items()
]
BODIES = {
    ("PUT", "/v1/scenes/{scene}/meshes/{mesh}"): wire.MESH_FORMATS,
    ("PUT", "/v1/scenes/{scene}/meshes/{mesh}/vertices"): wire.VERTEX_FORMATS,
    ("PUT", "/v1/scenes/{scene}/meshes/{mesh}/transform"): ("json",),
    ("PUT", "/v1/scenes/{scene}/meshes/{mesh}/mask"): ("json",),
    ("PUT", "/v1/scenes/{scene}/meshes/{mesh}/material"): ("json",),
    ("POST", "/v1/scenes/{scene}/frame"): wire.FRAME_FORMATS,
    ("POST", "/v1/scenes/{scene}/closest"): wire.RAY_FORMATS,
    ("POST", "/v1/scenes/{scene}/occluded"): wire.RAY_FORMATS,
    ("POST", "/v1/scenes/{scene}/hits"): wire.RAY_FORMATS,
    ("POST", "/v1/scenes/{scene}/count"): wire.RAY_FORMATS,
    ("POST", "/v1/scenes/{scene}/nearest"): wire.POINT_FORMATS,
    ("POST", "/v1/trace"): wire.TRACE_FORMATS,
    ("POST", "/v1/scenes/{scene}/render"): ("json",),
    ("POST", "/v1/scenes/{scene}/camera"): ("json",),
    ("POST", "/v1/scenes/{scene}/lidar"): ("json",),
    ("POST", "/v1/scenes/{scene}/sensors"): ("json",),
    ("PUT", "/v1/patterns/{name}"): wire.PATTERN_FORMATS,
}


@pytest.mark.parametrize("method, path", list(BODIES))
def test_each_body_is_declared_with_its_media_types(method, path):
    body = DOCUMENT["paths"][path][method.lower()]["requestBody"]
    assert body["required"] is True
    assert set(body["content"]) == {wire.MEDIA_TYPES[fmt] for fmt in BODIES[method, path]}


def test_no_other_operation_takes_a_body():
    taking = {(m, p) for m, p, op in OPERATIONS if "requestBody" in op}
    assert taking == set(BODIES)


def test_every_error_is_a_detail_string():
    for method, path, operation in OPERATIONS:
        for status, response in operation["responses"].items():
            if int(status) >= 400 and path != "/health":
                schema = response["content"]["application/json"]["schema"]
                assert schema["properties"] == {
                    "detail": {"type": "string", "description": "what is wrong, for a person"}
                }, (method, path, status)
    assert "HTTPValidationError" not in DOCUMENT.get("components", {}).get("schemas", {})


def test_scene_and_query_routes_declare_503_and_the_bearer_scheme():
    for method, path, operation in OPERATIONS:
        if path.startswith("/v1/scenes") or path == "/v1/trace":
            assert "503" in operation["responses"], (method, path)
    for document in (DOCUMENT, TOKEN_DOCUMENT):
        scheme = document["components"]["securitySchemes"]["HTTPBearer"]
        assert scheme["type"] == "http" and scheme["scheme"] == "bearer"


def test_v1_needs_the_token_only_where_one_is_set():
    for method, path, operation in OPERATIONS:
        if path.startswith("/v1"):
            assert operation["security"] == TOKEN_OPTIONAL, (method, path)
            secure = TOKEN_DOCUMENT["paths"][path][method.lower()]
            assert secure["security"] == TOKEN_REQUIRED, (method, path)
            assert "401" in secure["responses"], (method, path)
        elif path != "/health":
            assert "security" not in operation, (method, path)


def test_health_takes_the_token_and_needs_none():
    """/health answers without the token; with it, its details too."""
    for document in (DOCUMENT, TOKEN_DOCUMENT):
        health = document["paths"]["/health"]["get"]
        assert health["security"] == TOKEN_OPTIONAL
        assert "401" not in health["responses"]


def test_answers_have_their_media_types():
    mesh = DOCUMENT["paths"]["/v1/scenes/{scene}/meshes/{mesh}"]["put"]["responses"]
    assert "version" in mesh["201"]["content"]["application/json"]["schema"]["properties"]
    closest = DOCUMENT["paths"]["/v1/scenes/{scene}/closest"]["post"]["responses"]["200"]
    assert set(closest["content"]) == {wire.MEDIA_TYPES[f] for f in wire.ANSWER_FORMATS}
    metrics = DOCUMENT["paths"]["/metrics"]["get"]["responses"]["200"]
    assert list(metrics["content"]) == ["text/plain"]


def test_names_have_their_pattern_and_choices_their_enums():
    put = DOCUMENT["paths"]["/v1/scenes/{scene}/meshes/{mesh}"]["put"]
    names = {p["name"]: p for p in put["parameters"]}
    for name in ("scene", "mesh"):
        assert names[name]["schema"]["pattern"] == "^[A-Za-z0-9_.\\-]{1,64}$"
    closest = DOCUMENT["paths"]["/v1/scenes/{scene}/closest"]["post"]
    for parameter in closest["parameters"]:
        assert parameter.get("description"), parameter["name"]
    enums = {p["name"]: p["schema"] for p in closest["parameters"]}
    assert "sampling" in str(enums["strategy"]) and "npy" in str(enums["format"])


def test_every_reference_resolves_within_the_document():
    """A ``$ref`` names a place in this document: the sensors' bodies had ``#/$defs/...``
    references, which point into the root, where there are none."""
    references = []

    def walk(node):
        if isinstance(node, dict):
            if isinstance(node.get("$ref"), str):
                references.append(node["$ref"])
            for value in node.values():
                walk(value)
        elif isinstance(node, list):
            for item in node:
                walk(item)

    walk(DOCUMENT)
    for reference in references:
        assert reference.startswith("#/"), reference
        place = DOCUMENT
        for key in reference[2:].split("/"):
            place = place[key]
    lidar = DOCUMENT["paths"]["/v1/scenes/{scene}/lidar"]["post"]["requestBody"]
    noise = lidar["content"]["application/json"]["schema"]["properties"]["noise"]
    assert "range_sigma" in str(noise)  # the definition, in place


def test_a_pattern_put_declares_201_for_a_new_one():
    responses = DOCUMENT["paths"]["/v1/patterns/{name}"]["put"]["responses"]
    assert {"200", "201"} <= set(responses)
    schema = responses["201"]["content"]["application/json"]["schema"]
    assert schema["required"] == ["pattern", "rays"]


def test_a_sensors_answers_are_declared_in_the_formats_it_writes():
    lidar = DOCUMENT["paths"]["/v1/scenes/{scene}/lidar"]["post"]["responses"]["200"]
    assert set(lidar["content"]) == {wire.NPZ, wire.NPY, wire.JSON, wire.PCD}
    rig = DOCUMENT["paths"]["/v1/scenes/{scene}/sensors"]["post"]["responses"]["200"]
    assert set(rig["content"]) == {wire.NPZ, wire.JSON}


@pytest.mark.parametrize("path", ["/", "/health", "/metrics", "/v1/patterns"])
def test_a_route_that_refuses_unknown_query_parameters_declares_422(path):
    assert "422" in DOCUMENT["paths"][path]["get"]["responses"]


def test_answers_and_errors_declare_their_headers():
    closest = DOCUMENT["paths"]["/v1/scenes/{scene}/closest"]["post"]["responses"]
    assert {"X-Scene-Version", "Server-Timing", "X-Trace-Stats"} <= set(closest["200"]["headers"])
    assert "Retry-After" in closest["503"]["headers"]
    assert "WWW-Authenticate" in closest["401"]["headers"]
    lidar = DOCUMENT["paths"]["/v1/scenes/{scene}/lidar"]["post"]["responses"]
    assert "X-Scene-Version" in lidar["200"]["headers"]
    render = DOCUMENT["paths"]["/v1/scenes/{scene}/render"]["post"]["responses"]
    assert {"X-Scene-Version", "Server-Timing"} <= set(render["200"]["headers"])


@pytest.mark.parametrize(
    "method, path, required",
    [
        ("get", "/v1/scenes", ["scenes"]),
        ("get", "/v1/scenes/{scene}", ["scene", "version", "triangles", "bounds", "meshes"]),
        ("post", "/v1/scenes/{scene}/frame", ["scene", "version", "triangles", "bounds", "meshes"]),
        ("get", "/v1/scenes/{scene}/meshes/{mesh}", ["scene", "mesh", "index"]),
        ("put", "/v1/scenes/{scene}/meshes/{mesh}/vertices", ["scene", "mesh", "index"]),
        ("put", "/v1/scenes/{scene}/meshes/{mesh}/transform", ["scene", "mesh", "index"]),
        ("put", "/v1/scenes/{scene}/meshes/{mesh}/mask", ["scene", "mesh", "index"]),
        ("put", "/v1/scenes/{scene}/meshes/{mesh}/material", ["scene", "mesh", "index"]),
    ],
)
def test_scene_and_mesh_info_answers_are_typed(method, path, required):
    answer = DOCUMENT["paths"][path][method]["responses"]["200"]
    schema = answer["content"]["application/json"]["schema"]
    assert schema["required"][: len(required)] == required


# ---- real answers against the document's schemas


def json_schema(method: str, path: str, status: str = "200") -> dict:
    answer = DOCUMENT["paths"][path][method]["responses"][status]
    return answer["content"]["application/json"]["schema"]


@pytest.fixture
def floor(app_client, scene_name):
    """A scene with one mesh, ``floor``: a quad at z = 0."""
    vertices, faces = quad(-1, 1, -1, 1, 0)
    body = {"vertices": vertices.tolist(), "faces": faces.tolist()}
    response = app_client.put(f"/v1/scenes/{scene_name}/meshes/floor", json=body)
    assert response.status_code == 201, response.text
    return scene_name


def test_mesh_info_answers_validate_and_declare_every_key(app_client, floor):
    url = f"/v1/scenes/{floor}/meshes/floor"
    answers = {
        "/v1/scenes/{scene}/meshes/{mesh}": app_client.get(url),
        "/v1/scenes/{scene}/meshes/{mesh}/material": app_client.put(
            f"{url}/material", json={"reflectivity": 0.25, "label": 7}
        ),
    }
    for path, response in answers.items():
        assert response.status_code == 200, response.text
        schema = json_schema("get" if path.endswith("{mesh}") else "put", path)
        jsonschema.validate(response.json(), schema)
        assert set(response.json()) == set(schema["properties"]) == set(schema["required"])
    scene = app_client.get(f"/v1/scenes/{floor}").json()
    jsonschema.validate(scene, json_schema("get", "/v1/scenes/{scene}"))


def test_a_rigs_json_answer_validates(app_client, floor):
    camera = {"kind": "camera", "eye": [0, 0, 2], "target": [0, 0, 0], "width": 2, "height": 2}
    body = {"sensors": {"cam": camera, "cam.2": {**camera, "eye": [0, 0, 3]}}}
    response = app_client.post(f"/v1/scenes/{floor}/sensors", json=body)
    assert response.status_code == 200, response.text
    answer = response.json()
    assert set(answer) == {"cam", "cam.2"} and np.allclose(answer["cam"]["depth"], 2, atol=0.1)
    jsonschema.validate(answer, json_schema("post", "/v1/scenes/{scene}/sensors"))
    closest = {"origins": [[0, 0, 1]], "directions": [[0, 0, -1]]}
    response = app_client.post(f"/v1/scenes/{floor}/closest?format=json", json=closest)
    assert response.status_code == 200, response.text
    jsonschema.validate(response.json(), json_schema("post", "/v1/scenes/{scene}/closest"))


def test_a_renders_headers_are_declared(app_client, floor):
    body = {"eye": [0, 0, 2], "target": [0, 0, 0], "width": 4, "height": 3}
    response = app_client.post(f"/v1/scenes/{floor}/render", json=body)
    assert response.status_code == 200, response.text
    render = DOCUMENT["paths"]["/v1/scenes/{scene}/render"]["post"]["responses"]["200"]
    for name in render["headers"]:
        if name != "X-Trace-Stats":  # with ?stats=true only
            assert name.lower() in response.headers, name
    assert int(response.headers["x-scene-version"]) >= 1
