"""Operations: the start page / (the viewer), /health, /metrics (no token), /v1/capabilities.

/health answers everyone its status; its details (the dask scheduler's address and error, the
warm-up's error, the data folder and its OS error) only a request that may read /v1: with the
bearer token, or any request when no DACRT_TOKEN is set.
"""

from __future__ import annotations

import secrets
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request, Response
from fastapi.responses import HTMLResponse, JSONResponse, PlainTextResponse
from fastapi.security import HTTPAuthorizationCredentials
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from dacrt.chunks import N_CORES

from .. import __version__, openapi, options, tracing, wire
from ..cluster import Cluster
from ..deps import (
    MetricsDep,
    ReadinessDep,
    SettingsDep,
    StoreDep,
    bearer,
    reject_unknown_query,
    require_token,
)
from ..persistence import DataDir


def get_cluster(request: Request) -> Cluster | None:
    return request.app.state.cluster


#: The dask cluster of DACRT_DASK_SCHEDULER, or None.
ClusterDep = Annotated[Cluster | None, Depends(get_cluster)]


#: What /health answers a request without the token: nothing that names an address, a path or
#: an error.
PUBLIC_HEALTH = ("status", "service", "scenes", "warmup_seconds")


def may_see_details(
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
) -> bool:
    """Whether the request may read what /health knows beyond its status: no DACRT_TOKEN is set,
    or it presents the token ``deps.require_token`` accepts (a wrong or missing one is no error
    here: probes need no token)."""
    if settings.token is None:
        return True
    if credentials is None or not credentials.credentials.strip():
        return False
    presented = credentials.credentials.strip().encode()
    return secrets.compare_digest(presented, settings.token.get_secret_value().encode())


def data_dir_health(journal: DataDir) -> dict[str, Any]:
    """The data folder for /health: ``ok``, or ``unwritable`` with the last failed change's OS
    error (cleared by the next change that succeeds)."""
    fault = journal.fault
    if fault is None:
        return {"status": "ok", "path": str(journal.root)}
    return {
        "status": "unwritable",
        "path": str(journal.root),
        "errno": fault.errno,
        "detail": fault.detail,
    }


router = APIRouter(tags=["operations"])
unauthenticated = [Depends(reject_unknown_query)]

#: The start page: the viewer (one HTML file, plain JavaScript), with links to /docs, /health and
#: /metrics.
START_PAGE = (
    (Path(__file__).resolve().parents[1] / "static" / "viewer.html")
    .read_text(encoding="utf-8")
    .replace("{{version}}", __version__)
)


@router.get(
    "/",
    dependencies=unauthenticated,
    response_class=HTMLResponse,
    responses={
        200: {
            "description": "the viewer: a scene rendered by the server, orbited with the mouse",
            "content": {"text/html": {}},
        },
        **openapi.errors(422),  # a query parameter it does not take
    },
)
async def start_page() -> HTMLResponse:
    return HTMLResponse(START_PAGE)


@router.get(
    "/health",
    dependencies=unauthenticated,
    responses={
        200: openapi.json_answer("every kernel a request reaches is compiled", openapi.HEALTH),
        503: openapi.json_answer(
            "the kernels are compiling (starting) or failed to (error)", openapi.HEALTH
        ),
        **openapi.errors(422),
    },
)
async def health(
    ready: ReadinessDep,
    store: StoreDep,
    cluster: ClusterDep,
    details: Annotated[bool, Depends(may_see_details)],
) -> JSONResponse:
    # one string, so that the OpenAPI description stays one line
    (
        """200 ``{"status": "ok", ...}`` once the engine is compiled (``degraded``: its dask """
        """cluster is unreachable or its data folder cannot be written); 503 """
        """``starting``/``error`` before. Details (``detail``, ``cluster``, ``data_dir``) only """
        """with the bearer token when DACRT_TOKEN is set."""
    )
    body: dict[str, Any] = {
        "status": ready.status,
        "service": __version__,
        "scenes": len(store.snapshots()),
    }
    if ready.seconds is not None:
        body["warmup_seconds"] = round(ready.seconds, 3)
    if ready.error:
        body["detail"] = ready.error
    degraded = False
    if cluster is not None:
        body["cluster"] = cluster.describe()  # the monitor's last answer: never waits
        degraded = body["cluster"]["status"] != "ok"
    if store.journal is not None:
        body["data_dir"] = data_dir_health(store.journal)
        degraded = degraded or body["data_dir"]["status"] != "ok"
    if ready.status == "ok" and degraded:
        body["status"] = "degraded"
    if not details:  # addresses, paths and error texts are for those who may use /v1
        body = {key: body[key] for key in PUBLIC_HEALTH if key in body}
    return JSONResponse(body, status_code=503 if ready.status in ("starting", "error") else 200)


@router.get(
    "/metrics",
    dependencies=unauthenticated,
    response_class=PlainTextResponse,
    responses={
        200: {
            "description": "Prometheus text format",
            "content": {"text/plain": {"schema": {"type": "string"}}},
        },
        **openapi.errors(422),
    },
)
async def metrics(metrics: MetricsDep) -> Response:
    return Response(generate_latest(metrics.registry), media_type=CONTENT_TYPE_LATEST)


@router.get(
    "/v1/capabilities",
    dependencies=[Depends(require_token), Depends(reject_unknown_query)],
    responses=openapi.errors(401, 422),
)
async def capabilities(settings: SettingsDep, cluster: ClusterDep) -> dict:
    """Formats, fields, strategies, the limits in force and the dask cluster (or null)."""

    def media(formats):
        return [wire.MEDIA_TYPES[f] for f in formats]

    return {
        "api": "v1",
        "queries": [q.value for q in options.Query] + ["trace", "nearest"],
        "fields": {
            **{q.value: list(names) for q, names in options.FIELDS.items()},
            "nearest": [*tracing.NEAREST_FIELDS, *tracing.SIGN_FIELDS],
            **{s.value: list(names) for s, names in options.SENSOR_FIELDS.items() if names},
        },
        "strategies": list(options.strategies()),
        "default_strategy": options.strategies()[0],
        "cull": list(options.CULL_MODES),
        "formats": {
            "rays": media(wire.RAY_FORMATS),
            "points": media(wire.POINT_FORMATS),
            "meshes": media(wire.MESH_FORMATS),
            "vertices": media(wire.VERTEX_FORMATS),
            "frame": media(wire.FRAME_FORMATS),
            "trace": media(wire.TRACE_FORMATS),
            "answers": media(wire.ANSWER_FORMATS),
            "patterns": media(wire.PATTERN_FORMATS),
            "lidar_answers": media((*wire.ANSWER_FORMATS, "pcd")),
        },
        "limits": settings.limits(),
        "auth": settings.token is not None,
        "threads": settings.threads or N_CORES,
        "cluster": None if cluster is None else cluster.describe(),
    }
