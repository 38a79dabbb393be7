"""The path and query parameters of the routes, declared once with their descriptions and choices,
and the dependencies that build a query's or sensor's one ``options.Options`` from them.

Values are checked by the service itself (``store.check_name``, ``options.make_options``,
``wire.resolve_format``, ``wire.parse_mask``), whose 422 messages name the fix; the declarations
here tell the OpenAPI document what those checks accept.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path, Query

from . import options, wire
from .deps import SettingsDep
from .options import Options, Sensor, make_options
from .store import NAME

_NAME = {"pattern": f"^{NAME.pattern}$"}

SceneName = Annotated[
    str, Path(description="1-64 characters of A-Z a-z 0-9 _ - .", json_schema_extra=_NAME)
]
MeshName = Annotated[
    str, Path(description="1-64 characters of A-Z a-z 0-9 _ - .", json_schema_extra=_NAME)
]
PatternName = Annotated[
    str, Path(description="1-64 characters of A-Z a-z 0-9 _ - .", json_schema_extra=_NAME)
]
Fields = Annotated[
    str | None,
    Query(description="comma-separated answer keys to send (default: all of the query's keys)"),
]
Strategy = Annotated[
    str | None,
    Query(
        description="the engine's partitioning strategy (default: the first); answers are the same",
        json_schema_extra={"enum": list(options.strategies())},
    ),
]
Stats = Annotated[bool, Query(description="add the engine's counters as X-Trace-Stats")]
Cull = Annotated[
    str,
    Query(
        description="which faces rays ignore", json_schema_extra={"enum": list(options.CULL_MODES)}
    ),
]
Mask = Annotated[
    str | None,
    Query(
        description="the mesh's visibility mask, a uint32 in decimal or 0x hex (default "
        "0xFFFFFFFF for a new mesh; a replaced mesh keeps its own)"
    ),
]
#: A mask in the query string: decimal or 0x hex.
MASK_PATTERN = "^([0-9]+|0[xX][0-9A-Fa-f]+)$"
RayMask = Annotated[
    str | None,
    Query(
        description="one visibility mask for every ray of the batch, decimal or 0x hex (a ray "
        "sees a mesh where ray mask & mesh mask != 0); the body's mask instead for one per ray",
        json_schema_extra={"pattern": MASK_PATTERN},
    ),
]
PointMask = Annotated[
    str | None,
    Query(
        description="one visibility mask for every point, decimal or 0x hex (a point sees a "
        "mesh where point mask & mesh mask != 0)",
        json_schema_extra={"pattern": MASK_PATTERN},
    ),
]
MaxHits = Annotated[
    int | None,
    Query(
        description=f"hits kept per ray, nearest first (default {options.DEFAULT_MAX_HITS}, "
        "at most the server's DACRT_MAX_HITS); hits only",
        ge=1,
    ),
]
MaxDistance = Annotated[
    float | None,
    Query(
        description="the farthest a point's closest point may be (>= 0; a float32's shortest "
        "decimal, as JSON answers write distances, is that float32); beyond it, distance is "
        "inf and mesh, prim are -1 (default: no limit)"
    ),
]
Sign = Annotated[bool, Query(description="add inside (bool) and signed_distance (negative inside)")]
NSamples = Annotated[
    int,
    Query(
        description="rays from each point (odd) whose majority of odd crossing counts says "
        "inside; with sign=true",
        ge=1,
    ),
]
QueryKind = Annotated[
    str,
    Query(
        description="what the one-shot trace answers",
        json_schema_extra={"enum": [q.value for q in options.Query]},
    ),
]


def _options(
    kind: options.Query | Sensor | str,
    settings: SettingsDep,
    fields: str | None = None,
    strategy: str | None = None,
    stats: bool = False,
    cull: str = "none",
    mask: str | None = None,
    max_hits: int | None = None,
) -> Options:
    """A request's options: the query string's values, the server's threads, DACRT_MAX_HITS and
    DACRT_DEVICE."""
    return make_options(
        kind,
        fields,
        strategy,
        stats,
        settings.threads,
        cull,
        max_hits,
        None if mask is None else wire.parse_mask(mask, "?mask"),
        settings.max_hits,
        settings.device,
    )


def options_of(kind: options.Query | Sensor):
    """The options of a route answering ``kind`` from a batch's query parameters: ``?fields=``,
    ``?strategy=``, ``?stats=``, ``?cull=`` and ``?mask=``."""

    def batch_options(
        settings: SettingsDep,
        fields: Fields = None,
        strategy: Strategy = None,
        stats: Stats = False,
        cull: Cull = "none",
        mask: RayMask = None,
    ) -> Options:
        return _options(kind, settings, fields, strategy, stats, cull, mask)

    return Annotated[Options, Depends(batch_options)]


def hits_options(
    settings: SettingsDep,
    fields: Fields = None,
    strategy: Strategy = None,
    stats: Stats = False,
    cull: Cull = "none",
    mask: RayMask = None,
    max_hits: MaxHits = None,
) -> Options:
    """A hits query's options: a batch's, and ``?max_hits=``."""
    return _options(options.Query.HITS, settings, fields, strategy, stats, cull, mask, max_hits)


def trace_options(
    settings: SettingsDep,
    fields: Fields = None,
    strategy: Strategy = None,
    stats: Stats = False,
    cull: Cull = "none",
    mask: RayMask = None,
    query: QueryKind = "closest",
    max_hits: MaxHits = None,
) -> Options:
    """A one-shot trace's options: a batch's, the ``?query=`` and its ``?max_hits=``."""
    return _options(query, settings, fields, strategy, stats, cull, mask, max_hits)


def render_options(
    settings: SettingsDep, strategy: Strategy = None, stats: Stats = False, cull: Cull = "none"
) -> Options:
    """A picture's options: ``?strategy=``, ``?stats=`` and ``?cull=`` (a PNG has no fields)."""
    return _options(Sensor.RENDER, settings, None, strategy, stats, cull)


#: The one options record of each query and sensor route, built before its body is read.
ClosestOptions = options_of(options.Query.CLOSEST)
OccludedOptions = options_of(options.Query.OCCLUDED)
CountOptions = options_of(options.Query.COUNT)
HitsOptions = Annotated[Options, Depends(hits_options)]
TraceOptions = Annotated[Options, Depends(trace_options)]
RenderOptions = Annotated[Options, Depends(render_options)]
CameraOptions = options_of(Sensor.CAMERA)
LidarOptions = options_of(Sensor.LIDAR)
RigOptions = options_of(Sensor.RIG)


def body_format(formats: tuple[str, ...]):
    """``?format=``: the body's format when Content-Type does not say it, one of ``formats``."""
    return Annotated[
        str | None,
        Query(
            description="the body's format, overriding Content-Type",
            json_schema_extra={"enum": list(formats)},
        ),
    ]


RayFormat = body_format(wire.RAY_FORMATS)
PointFormat = body_format(wire.POINT_FORMATS)
MeshFormat = body_format(wire.MESH_FORMATS)
VertexFormat = body_format(wire.VERTEX_FORMATS)
FrameFormat = body_format(wire.FRAME_FORMATS)
TraceFormat = body_format(wire.TRACE_FORMATS)
