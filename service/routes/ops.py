"""Operations: the start page / (the viewer), /health, /metrics (no token), /v1/capabilities."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, JSONResponse, PlainTextResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from dacrt.chunks import N_CORES

from .. import __version__, openapi, tracing, wire
from ..cluster import Cluster
from ..deps import (
    MetricsDep,
    ReadinessDep,
    SettingsDep,
    StoreDep,
    reject_unknown_query,
    require_token,
)


def get_cluster(request: Request) -> Cluster | None:
    return request.app.state.cluster


#: The dask cluster of DACRT_DASK_SCHEDULER, or None.
ClusterDep = Annotated[Cluster | None, Depends(get_cluster)]

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
        }
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
    },
)
async def health(ready: ReadinessDep, store: StoreDep, cluster: ClusterDep) -> JSONResponse:
    # one string, so that the OpenAPI description stays one line
    (
        """200 ``{"status": "ok", ...}`` once the engine is compiled (``degraded``: its dask """
        """cluster is unreachable); 503 ``starting``/``error`` before."""
    )
    body = {
        "status": ready.status,
        "service": __version__,
        "scenes": len(store.snapshots()),
    }
    if ready.seconds is not None:
        body["warmup_seconds"] = round(ready.seconds, 3)
    if ready.error:
        body["detail"] = ready.error
    if cluster is not None:
        body["cluster"] = await run_in_threadpool(cluster.describe)
        if ready.status == "ok" and body["cluster"]["status"] != "ok":
            body["status"] = "degraded"
    return JSONResponse(body, status_code=503 if ready.status in ("starting", "error") else 200)


@router.get(
    "/metrics",
    dependencies=unauthenticated,
    response_class=PlainTextResponse,
    responses={
        200: {
            "description": "Prometheus text format",
            "content": {"text/plain": {"schema": {"type": "string"}}},
        }
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
        "queries": [q.value for q in tracing.Query] + ["trace"],
        "fields": {q.value: list(names) for q, names in tracing.FIELDS.items()},
        "strategies": list(tracing.strategies()),
        "default_strategy": tracing.strategies()[0],
        "cull": list(tracing.CULL_MODES),
        "formats": {
            "rays": media(wire.RAY_FORMATS),
            "meshes": media(wire.MESH_FORMATS),
            "vertices": media(wire.VERTEX_FORMATS),
            "frame": media(wire.FRAME_FORMATS),
            "trace": media(wire.TRACE_FORMATS),
            "answers": media(wire.ANSWER_FORMATS),
        },
        "limits": settings.limits(),
        "auth": settings.token is not None,
        "threads": settings.threads or N_CORES,
        "cluster": None if cluster is None else await run_in_threadpool(cluster.describe),
    }
