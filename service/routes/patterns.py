"""Scan patterns: a lidar's rays listed one by one (``PUT``, ``GET``, ``DELETE``
``/v1/patterns/{name}``), for ``"pattern": NAME`` in ``/lidar`` and rigs."""

from __future__ import annotations

import io
from functools import partial

from anyio.to_thread import run_sync
from fastapi import APIRouter, Depends, Request, Response

from dacrt.sensors import Pattern

from .. import openapi, wire
from ..deps import PatternsDep, SettingsDep, read_change, reject_unknown_query, require_token
from ..params import PatternName, body_format
from ..store import check_name

router = APIRouter(
    prefix="/v1/patterns",
    tags=["sensors"],
    dependencies=[Depends(require_token), Depends(reject_unknown_query)],
)

PatternFormat = body_format(wire.PATTERN_FORMATS)
_DEGREES = {"type": "array", "items": {"type": "number"}}
PATTERN_BODY = openapi.request_body(
    wire.PATTERN_FORMATS,
    {
        "type": "object",
        "required": ["azimuth_deg", "elevation_deg"],
        "additionalProperties": False,
        "properties": {
            "azimuth_deg": _DEGREES,
            "elevation_deg": _DEGREES,
            "time_s": _DEGREES,
            "channel": {"type": "array", "items": {"type": "integer", "minimum": 0}},
        },
    },
    "the rays: azimuth_deg, elevation_deg (M,), optional time_s (M,) and channel (M,) uint16",
)


def info(name: str, pattern: Pattern) -> dict:
    """What a pattern holds, as its routes answer it."""
    return {
        "pattern": name,
        "rays": pattern.n_rays,
        "time_s": pattern.time_s is not None,
        "channel": pattern.channel is not None,
    }


@router.put(
    "/{name}",
    openapi_extra=PATTERN_BODY,
    status_code=200,
    responses={
        200: openapi.json_answer("a replaced pattern: its info", openapi.PATTERN_INFO),
        201: openapi.json_answer("a new pattern: its info", openapi.PATTERN_INFO),
        **openapi.errors(400, 401, 408, 413, 415, 422, 503, 507),
    },
)
async def put_pattern(
    name: PatternName,
    request: Request,
    response: Response,
    settings: SettingsDep,
    patterns: PatternsDep,
    format: PatternFormat = None,
) -> dict:
    """Add (201) or replace (200) a scan pattern: its info."""
    check_name("pattern", name)
    body, fmt = await read_change(request, settings, format, wire.PATTERN_FORMATS)
    decode = partial(wire.decode_pattern, body, fmt, patterns.max_rays, settings.max_body_bytes)
    pattern = await run_sync(decode)
    created = await run_sync(patterns.put, name, pattern)
    response.status_code = 201 if created else 200
    return info(name, pattern)


@router.get("", responses=openapi.errors(401, 422))
async def list_patterns(patterns: PatternsDep) -> dict:
    return {"patterns": [info(name, patterns.get(name)) for name in patterns.names()]}


@router.get(
    "/{name}",
    response_class=Response,
    responses={
        200: {
            "description": "the pattern as the .npz it was uploaded as",
            "content": {wire.NPZ: {"schema": {"type": "string", "format": "binary"}}},
        },
        **openapi.errors(401, 404, 422),
    },
)
async def get_pattern(name: PatternName, patterns: PatternsDep) -> Response:
    """The pattern's .npz (``azimuth_deg``, ``elevation_deg``, ``time_s``, ``channel``)."""
    out = io.BytesIO()
    patterns.get(name).save(out)
    return Response(out.getvalue(), media_type=wire.NPZ)


@router.delete("/{name}", status_code=204, responses=openapi.errors(401, 404, 422, 503))
async def delete_pattern(name: PatternName, patterns: PatternsDep) -> Response:
    await run_sync(patterns.delete, name)
    return Response(status_code=204)
