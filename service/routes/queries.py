"""Ray queries: closest, occluded, hits and count on a stored scene, and the one-shot /trace."""

from __future__ import annotations

from anyio.to_thread import run_sync
from fastapi import APIRouter, Depends, Request

from .. import footprint, openapi, tracing, wire
from ..deps import MetricsDep, SettingsDep, StoreDep, reject_unknown_query, require_token
from ..errors import TooLarge
from ..metrics import Metrics
from ..params import BatchOptionsDep, MaxHits, QueryKind, RayFormat, SceneName, TraceFormat
from ..pipeline import receive, respond
from ..responses import BuffersResponse
from ..settings import Settings
from ..store import Store
from ..tracing import Query

router = APIRouter(
    prefix="/v1",
    tags=["queries"],
    dependencies=[Depends(require_token), Depends(reject_unknown_query)],
)


RAYS_BODY = openapi.request_body(
    wire.RAY_FORMATS, openapi.RAYS_JSON, "rays: .npy (N, 6) or (N, 8) float32, .npz or JSON"
)
TRACE_BODY = openapi.request_body(
    wire.TRACE_FORMATS, openapi.TRACE_JSON, "a mesh and rays: .npz or JSON"
)
QUERY_ERRORS = openapi.errors(400, 401, 404, 406, 408, 413, 415, 422)


@router.post(
    "/scenes/{scene}/closest",
    openapi_extra=RAYS_BODY,
    response_class=BuffersResponse,
    responses={**openapi.answers("t, mesh, prim, u, v, normal per ray"), **QUERY_ERRORS},
)
async def closest(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    metrics: MetricsDep,
    batch: BatchOptionsDep,
    format: RayFormat = None,
):
    """The nearest hit of each ray."""
    options = batch.for_query(Query.CLOSEST, settings.threads)
    return await answer(request, settings, store, metrics, options, scene, format)


@router.post(
    "/scenes/{scene}/occluded",
    openapi_extra=RAYS_BODY,
    response_class=BuffersResponse,
    responses={**openapi.answers("occluded per ray"), **QUERY_ERRORS},
)
async def occluded(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    metrics: MetricsDep,
    batch: BatchOptionsDep,
    format: RayFormat = None,
):
    """Whether each ray hits anything in [tmin, tmax]."""
    options = batch.for_query(Query.OCCLUDED, settings.threads)
    return await answer(request, settings, store, metrics, options, scene, format)


@router.post(
    "/scenes/{scene}/hits",
    openapi_extra=RAYS_BODY,
    response_class=BuffersResponse,
    responses={
        **openapi.answers(
            "every hit of each ray, nearest first, at most max_hits: offsets (N+1) and t, mesh, "
            "prim, u, v, normal per hit (CSR), truncated per ray"
        ),
        **QUERY_ERRORS,
    },
)
async def hits(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    metrics: MetricsDep,
    batch: BatchOptionsDep,
    max_hits: MaxHits = None,
    format: RayFormat = None,
):
    """Every hit along each ray in [tmin, tmax], nearest first, at most ``max_hits``."""
    options = batch.for_query(Query.HITS, settings.threads, max_hits, settings.max_hits)
    return await answer(request, settings, store, metrics, options, scene, format)


@router.post(
    "/scenes/{scene}/count",
    openapi_extra=RAYS_BODY,
    response_class=BuffersResponse,
    responses={**openapi.answers("how many triangles each ray crosses"), **QUERY_ERRORS},
)
async def count(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    metrics: MetricsDep,
    batch: BatchOptionsDep,
    format: RayFormat = None,
):
    """How many triangles each ray crosses in [tmin, tmax] (a shared edge or vertex once)."""
    options = batch.for_query(Query.COUNT, settings.threads)
    return await answer(request, settings, store, metrics, options, scene, format)


@router.post(
    "/trace",
    openapi_extra=TRACE_BODY,
    response_class=BuffersResponse,
    responses={**openapi.answers("the answer of the query"), **QUERY_ERRORS},
)
async def trace(
    request: Request,
    settings: SettingsDep,
    metrics: MetricsDep,
    batch: BatchOptionsDep,
    query: QueryKind = "closest",
    max_hits: MaxHits = None,
    format: TraceFormat = None,
):
    """A stateless one-shot: the mesh comes with the rays (answers carry X-Scene-Version: 0)."""
    options = batch.for_query(query, settings.threads, max_hits, settings.max_hits)
    return await answer(request, settings, None, metrics, options, None, format)


async def answer(
    request: Request,
    settings: Settings,
    store: Store | None,
    metrics: Metrics,
    options: tracing.Options,
    scene: str | None,
    format: str | None,
) -> BuffersResponse:
    """Receive, decode, trace and encode one batch on ``scene`` of ``store`` (or a one-shot
    /trace when ``scene`` is None); the last three off the event loop."""
    accept = request.headers.get("accept")
    declared = format or wire.declared_format(request.headers.get("content-type"))
    answer_format = negotiate(accept, declared or "npz", options)  # again once the body is read
    max_rays = settings.max_rays_per_request

    def peak(n_body: int, fmt: str | None, n_rays: int | None = None) -> int:
        """The request's peak bytes: its body decoded, its rays traced, its answer written."""
        if n_rays is None:
            n_rays = footprint.most_rays(n_body, fmt, max_rays)
        mesh = footprint.mesh_scene_bytes(n_body) if scene is None else 0  # /trace's mesh
        work = footprint.query_bytes(n_rays, options.query.value, options.fields, options.max_hits)
        answer = footprint.answer_bytes(answer_format)
        return footprint.decode_bytes(n_body, fmt) + mesh + work + answer

    formats = wire.RAY_FORMATS if scene is not None else wire.TRACE_FORMATS
    got = await receive(request, settings, store, scene, format, formats, peak)
    answer_format = negotiate(accept, got.fmt, options)
    limits = {"max_rays": max_rays, "max_bytes": settings.max_body_bytes}

    def decode():
        with got.timing("decode"):
            if scene is None:
                return wire.decode_trace(got.body, got.fmt, **limits)
            return None, wire.decode_rays(got.body, got.fmt, **limits)

    mesh, rays = await run_sync(decode)
    check_hit_buffers(len(rays), options, settings.max_hits_bytes)
    what = f"{request.method} {request.url.path} of {len(rays)} rays"
    await got.ticket.hold(peak(len(got.body), None, len(rays)), what)

    def work():
        with got.timing("trace"):
            result = (
                tracing.trace(store.snapshot(scene), rays, options, request.app.state.cluster)
                if scene is not None
                else tracing.trace_once(mesh, rays, options)
            )
        with got.timing("encode"):
            return result, wire.encode_answer(result.arrays, answer_format)

    result, encoded = await run_sync(work)
    return respond(metrics, options.query.value, result, len(rays), encoded, got.timing)


def negotiate(accept: str | None, request_format: str, options: tracing.Options) -> str:
    """The answer format, among those the query's answer can be written in (406 naming them)."""
    why_not = (
        None
        if options.answer_formats == wire.ANSWER_FORMATS
        else f"a {options.query.value} answer with {', '.join(options.fields)} is written in: its "
        f"arrays have different lengths (CSR), so use {wire.NPZ} or {wire.JSON}, or "
        "?fields=truncated for an .npy"
    )
    return wire.negotiate(accept, request_format, options.answer_formats, why_not)


def check_hit_buffers(n_rays: int, options: tracing.Options, limit: int) -> None:
    """413 when a hits query would hold more hit buffers than DACRT_MAX_HITS_BYTES allows."""
    needed = options.hit_buffer_bytes(n_rays)
    if needed > limit:
        raise TooLarge(
            f"{n_rays} rays with max_hits={options.max_hits} need {needed} bytes of hit buffers "
            f"({n_rays} x ({options.max_hits} + 1) x {footprint.HIT_SLOT_BYTES}), over the limit "
            f"of {limit} bytes (DACRT_MAX_HITS_BYTES); send fewer rays or a smaller max_hits"
        )
