"""What the OpenAPI document says of bodies and answers that FastAPI cannot see.

The handlers read their bodies themselves (binary formats are parsed by ``wire``), so each route
declares here the media types it reads and writes, the JSON shapes of its bodies, and its error
answers: ``{"detail": "<message>"}`` for every status.
"""

from __future__ import annotations

from typing import Any

from . import wire
from .store import NAME

_BINARY = {"type": "string", "format": "binary"}
_NUMBER = {"type": "number"}
_POINTS = {
    "type": "array",
    "items": {"type": "array", "items": _NUMBER, "minItems": 3, "maxItems": 3},
}
_TRIANGLES = {
    "type": "array",
    "items": {"type": "array", "items": {"type": "integer"}, "minItems": 3, "maxItems": 3},
}
_BOUND = {
    "anyOf": [
        _NUMBER,
        {"type": "array", "items": {"anyOf": [_NUMBER, {"type": "null"}]}},
        {"type": "null"},
    ],
    "description": "one value for the batch or one per ray; null means the default",
}


def _object(required: dict[str, Any], optional: dict[str, Any] | None = None) -> dict[str, Any]:
    return {
        "type": "object",
        "required": list(required),
        "properties": {**required, **(optional or {})},
        "additionalProperties": False,
    }


_MASK_VALUE = {"type": "integer", "minimum": 0, "maximum": 0xFFFFFFFF}
_MASK = {
    "anyOf": [_MASK_VALUE, {"type": "array", "items": _MASK_VALUE}, {"type": "null"}],
    "description": "visibility mask, one for the batch or one per ray (decimal); null: all ones",
}
_TIME = {
    "anyOf": [
        {"type": "number", "minimum": 0, "maximum": 1},
        {"type": "array", "items": {"type": "number", "minimum": 0, "maximum": 1}},
        {"type": "null"},
    ],
    "description": "each ray's instant in the frame's interval, in [0, 1]; null: 0",
}
RAYS_JSON = _object(
    {"origins": _POINTS, "directions": _POINTS},
    {"tmin": _BOUND, "tmax": _BOUND, "mask": _MASK, "time": _TIME},
)
POINTS_JSON = _object({"points": _POINTS})
MESH_JSON = _object({"vertices": _POINTS, "faces": _TRIANGLES})
VERTICES_JSON = _object({"vertices": _POINTS})
_MATRIX = {
    "type": "array",
    "items": {"type": "array", "items": _NUMBER, "minItems": 4, "maxItems": 4},
    "minItems": 4,
    "maxItems": 4,
    "description": "4x4 row-major affine matrix: last row [0, 0, 0, 1], invertible",
}
_MASK = {
    "anyOf": [
        {"type": "integer", "minimum": 0, "maximum": 0xFFFFFFFF},
        {"type": "string", "pattern": "^([0-9]+|0[xX][0-9a-fA-F]+)$"},
    ],
    "description": "uint32: a ray sees the mesh where ray mask & mesh mask != 0",
}
_MESH_NAME = {"type": "string", "pattern": f"^{NAME.pattern}$"}
INSTANCE_JSON = _object({"instance_of": _MESH_NAME}, {"transform": _MATRIX})
TRANSFORM_JSON = _object({"matrix": _MATRIX})
MASK_JSON = _object({"mask": _MASK})
_REFLECTIVITY = {"type": "number", "minimum": 0, "maximum": 1, "description": "lidar intensity"}
_LABEL = {"type": "integer", "minimum": 0, "maximum": 0xFFFFFFFF, "description": "a class"}
MATERIAL_JSON = {
    **_object({}, {"reflectivity": _REFLECTIVITY, "label": _LABEL}),
    "minProperties": 1,
}
FRAME_JSON = {
    "type": "object",
    "minProperties": 1,
    "additionalProperties": False,
    "patternProperties": {
        r"^.+\.vertices$": _POINTS,
        r"^.+\.faces$": _TRIANGLES,
        r"^.+\.transform$": _MATRIX,
        r"^.+\.transform_end$": _MATRIX,
        r"^.+\.vertices_end$": _POINTS,
        r"^.+\.mask$": _MASK,
        r"^.+\.instance_of$": _MESH_NAME,
        r"^.+\.reflectivity$": _REFLECTIVITY,
        r"^.+\.label$": _LABEL,
    },
}
TRACE_JSON = _object(
    {"vertices": _POINTS, "faces": _TRIANGLES, "origins": _POINTS, "directions": _POINTS},
    {"tmin": _BOUND, "tmax": _BOUND, "mask": _MASK, "time": _TIME},
)
ERROR = {
    "type": "object",
    "required": ["detail"],
    "additionalProperties": False,
    "properties": {"detail": {"type": "string", "description": "what is wrong, for a person"}},
}

PATTERN_INFO = _object(
    {"pattern": {"type": "string"}, "rays": {"type": "integer", "minimum": 1}},
    {"time_s": {"type": "boolean"}, "channel": {"type": "boolean"}},
)

_BOUNDS = {"type": "array", "items": _POINTS["items"], "minItems": 2, "maxItems": 2}
MESH_INFO = {
    "type": "object",
    "required": [
        "scene",
        "mesh",
        "index",
        "vertices",
        "triangles",
        "bounds",
        "version",
        "mask",
        "transform",
        "transform_end",
        "vertices_end",
        "instance_of",
        "reflectivity",
        "label",
    ],
    "properties": {
        "scene": {"type": "string"},
        "mesh": {"type": "string"},
        "index": {"type": "integer", "description": "the mesh's number in hit results"},
        "vertices": {"type": "integer"},
        "triangles": {"type": "integer"},
        "bounds": {**_BOUNDS, "description": "[[min x, y, z], [max x, y, z]] in scene space"},
        "version": {"type": "integer", "description": "scene version of the mesh's last change"},
        "mask": {"type": "integer", "description": "the mesh's visibility mask (uint32)"},
        "transform": {**_MATRIX, "description": "the mesh's placement (identity by default)"},
        "transform_end": {
            "anyOf": [_MATRIX, {"type": "null"}],
            "description": "its placement at the end of the frame's interval; null: static",
        },
        "vertices_end": {
            "anyOf": [{"type": "integer"}, {"type": "null"}],
            "description": "how many vertices it has at the end of the frame's interval (as "
            "many as at the start: it deforms); null: it does not deform",
        },
        "instance_of": {
            "anyOf": [{"type": "string"}, {"type": "null"}],
            "description": "the mesh whose arrays this instance shares; null for a mesh",
        },
        "reflectivity": _REFLECTIVITY,
        "label": _LABEL,
    },
}
SCENE_INFO = {
    "type": "object",
    "required": ["scene", "version", "triangles", "bounds", "meshes"],
    "properties": {
        "scene": {"type": "string"},
        "version": {"type": "integer", "description": "the scene's version (X-Scene-Version)"},
        "triangles": {"type": "integer", "description": "placed triangles, instances' too"},
        "bounds": {**_BOUNDS, "description": "[[min x, y, z], [max x, y, z]] in scene space"},
        "meshes": {"type": "array", "items": MESH_INFO},
    },
}
SCENE_LIST = _object({"scenes": {"type": "array", "items": SCENE_INFO}})
HEALTH = {
    "type": "object",
    "required": ["status", "service", "scenes"],
    "properties": {
        "status": {"type": "string", "enum": ["starting", "ok", "degraded", "error"]},
        "service": {"type": "string", "description": "the service's version"},
        "scenes": {"type": "integer"},
        "warmup_seconds": {"type": "number"},
        "detail": {"type": "string", "description": "why the warm-up failed"},
        "cluster": {
            "type": "object",
            "description": "the dask cluster of DACRT_DASK_SCHEDULER, when set (degraded: "
            "unreachable, queries traced in process); with the token only",
        },
        "data_dir": {
            "type": "object",
            "description": "the data folder of DACRT_DATA_DIR, when set: status ok or unwritable "
            "(with errno and detail); with the token only",
        },
    },
}

#: The error statuses a route may answer besides its own, with when (API.md's table).
ERROR_STATUSES = {
    400: "the body cannot be parsed",
    401: "a token is configured and missing or wrong",
    404: "unknown scene or mesh",
    406: "Accept names no answer format",
    409: "the vertex count differs from the mesh's, or the change contradicts an instance",
    408: "the body arrived too slowly",
    413: "over a configured limit",
    415: "unsupported Content-Type",
    422: "invalid values or parameters",
    503: "the engine is still compiling, or the requests in flight hold the memory budget "
    "(Retry-After says when to try again), or the data folder cannot be written",
    507: "the data folder (DACRT_DATA_DIR) is full: the change is not made",
}


def request_body(
    formats: tuple[str, ...], json_schema: dict[str, Any] | None, description: str
) -> dict[str, Any]:
    """``openapi_extra`` declaring a required body in ``formats`` (see ``wire``)."""
    content = {
        wire.MEDIA_TYPES[fmt]: {"schema": json_schema if fmt == "json" else _BINARY}
        for fmt in formats
    }
    return {"requestBody": {"required": True, "description": description, "content": content}}


def _header(description: str, schema: dict[str, Any] | None = None) -> dict[str, Any]:
    return {"description": description, "schema": schema or {"type": "string"}}


#: The headers an error status carries (RFC 9110's for 401 and 503).
ERROR_HEADERS = {
    401: {"WWW-Authenticate": _header("Bearer: the scheme the token is sent in")},
    503: {"Retry-After": _header("seconds to wait before trying again", {"type": "integer"})},
}
#: The headers of every query's and sensor's answer.
ANSWER_HEADERS = {
    "X-Scene-Version": _header(
        "the scene version the answer was traced on (0 for /v1/trace)", {"type": "integer"}
    ),
    "Server-Timing": _header("receive, decode, trace and encode durations in ms"),
    "X-Trace-Stats": _header("the engine's counters as JSON, with ?stats=true"),
}


def errors(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """``responses`` entries for error statuses, each with the ``{"detail": str}`` schema (and
    the headers ERROR_HEADERS names)."""
    return {
        status: {
            "description": ERROR_STATUSES[status],
            "content": {"application/json": {"schema": ERROR}},
            **({"headers": ERROR_HEADERS[status]} if status in ERROR_HEADERS else {}),
        }
        for status in statuses
    }


def inlined(schema: dict[str, Any]) -> dict[str, Any]:
    """A JSON schema with each ``{"$ref": "#/$defs/NAME"}`` replaced by that definition (the
    models' definitions hold no cycles) and ``$defs`` removed, as are discriminators, whose
    mappings name definitions (each ``oneOf`` member's ``kind`` tells them apart)."""
    definitions = schema.get("$defs", {})

    def put(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref", "")
            if ref.startswith("#/$defs/"):
                rest = {key: value for key, value in node.items() if key != "$ref"}
                return {**put(definitions[ref.removeprefix("#/$defs/")]), **put(rest)}
            dropped = ("$defs", "discriminator")
            return {key: put(value) for key, value in node.items() if key not in dropped}
        if isinstance(node, list):
            return [put(item) for item in node]
        return node

    return put(schema)


def json_answer(description: str, schema: dict[str, Any]) -> dict[str, Any]:
    """A ``responses`` entry of a JSON answer with ``schema``."""
    return {"description": description, "content": {"application/json": {"schema": schema}}}


#: A query's JSON answer: ``{KEY: [...]}``.
ARRAYS_JSON = {"type": "object", "additionalProperties": {"type": "array"}}
#: A rig's JSON answer: each sensor's answer by its name, ``{NAME: {KEY: [...]}}``.
RIG_JSON = {
    "type": "object",
    "propertyNames": {"pattern": f"^{NAME.pattern}$"},
    "additionalProperties": ARRAYS_JSON,
}


def answers(
    description: str,
    formats: tuple[str, ...] = ("npz", "npy", "json"),
    json_schema: dict[str, Any] = ARRAYS_JSON,
) -> dict[int | str, dict[str, Any]]:
    """The 200 of a query: the answer arrays in ``formats`` (.npz, .npy, JSON with
    ``json_schema``; a lidar's PCD too), by ``Accept``."""
    content = {wire.MEDIA_TYPES[fmt]: {"schema": _BINARY} for fmt in formats if fmt != "json"}
    if "json" in formats:
        content[wire.JSON] = {"schema": json_schema}
    return {200: {"description": description, "content": content, "headers": ANSWER_HEADERS}}


#: The bearer token may be sent and need not be: /health shows its details only with it.
_TOKEN_OPTIONAL = [{}, {"HTTPBearer": []}]


def with_token_rule(document: dict[str, Any], token_set: bool) -> dict[str, Any]:
    """``document`` (changed in place) with each operation's security as this server asks it:
    the token on /v1 when DACRT_TOKEN is set, optional on /health and, without a token, on /v1
    (FastAPI declares every route that reads it as requiring it)."""
    for path, operations in document["paths"].items():
        for operation in operations.values():
            if "security" in operation and (path == "/health" or not token_set):
                operation["security"] = _TOKEN_OPTIONAL
    return document
