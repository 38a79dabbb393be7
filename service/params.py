"""The path and query parameters of the routes, declared once with their descriptions and choices.

Values are checked by the service itself (``store.check_name``, ``tracing.make_options``,
``wire.resolve_format``, ``wire.parse_mask``), whose 422 messages name the fix; the declarations
here tell the OpenAPI document what those checks accept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Path, Query

from . import tracing, wire
from .store import NAME

_NAME = {"pattern": f"^{NAME.pattern}$"}

SceneName = Annotated[
    str, Path(description="1-64 characters of A-Z a-z 0-9 _ - .", json_schema_extra=_NAME)
]
MeshName = Annotated[
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
        json_schema_extra={"enum": list(tracing.strategies())},
    ),
]
Stats = Annotated[bool, Query(description="add the engine's counters as X-Trace-Stats")]
Cull = Annotated[
    str,
    Query(
        description="which faces rays ignore", json_schema_extra={"enum": list(tracing.CULL_MODES)}
    ),
]
Mask = Annotated[
    str | None,
    Query(
        description="the mesh's visibility mask, a uint32 in decimal or 0x hex (default "
        "0xFFFFFFFF for a new mesh; a replaced mesh keeps its own)"
    ),
]
RayMask = Annotated[
    str | None,
    Query(
        description="one visibility mask for every ray of the batch, decimal or 0x hex (a ray "
        "sees a mesh where ray mask & mesh mask != 0); the body's mask instead for one per ray",
        json_schema_extra={"pattern": "^([0-9]+|0[xX][0-9A-Fa-f]+)$"},
    ),
]
MaxHits = Annotated[
    int | None,
    Query(
        description=f"hits kept per ray, nearest first (default {tracing.DEFAULT_MAX_HITS}, "
        "at most the server's DACRT_MAX_HITS); hits only",
        ge=1,
    ),
]
MaxDistance = Annotated[
    float | None,
    Query(
        description="the farthest a point's closest point may be (>= 0); beyond it, distance is "
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
        json_schema_extra={"enum": [q.value for q in tracing.Query]},
    ),
]


@dataclass(frozen=True)
class BatchOptions:
    """The query-string options every query takes, for the whole batch (API.md)."""

    fields: str | None
    strategy: str | None
    stats: bool
    cull: str
    mask: str | None = None

    def for_query(
        self,
        query: tracing.Query | str,
        threads: int | None,
        max_hits: int | None = None,
        max_hits_limit: int | None = None,
    ) -> tracing.Options:
        """The engine options of ``query``; 422 naming the choices for an unknown value."""
        return tracing.make_options(
            query,
            self.fields,
            self.strategy,
            self.stats,
            threads,
            self.cull,
            max_hits,
            None if self.mask is None else wire.parse_mask(self.mask, "?mask"),
            max_hits_limit,
        )


def batch_options(
    fields: Fields = None,
    strategy: Strategy = None,
    stats: Stats = False,
    cull: Cull = "none",
    mask: RayMask = None,
) -> BatchOptions:
    return BatchOptions(fields, strategy, stats, cull, mask)


BatchOptionsDep = Annotated[BatchOptions, Depends(batch_options)]


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
