"""Ray queries: closest, occluded, hits and count on a stored scene, and the one-shot /trace."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request

from .. import footprint, openapi, tracing, wire
from ..deps import MetricsDep, SettingsDep, StoreDep, reject_unknown_query, require_token
from ..errors import TooLarge
from ..options import Options
from ..params import (
    ClosestOptions,
    CountOptions,
    HitsOptions,
    OccludedOptions,
    RayFormat,
    SceneName,
    TraceFormat,
    TraceOptions,
)
from ..pipeline import Decoded, Steps, answer, encode_arrays
from ..responses import BuffersResponse
from ..settings import Settings
from ..store import Store

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
    options: ClosestOptions,
    format: RayFormat = None,
):
    """The nearest hit of each ray."""
    steps = ray_steps(request, settings, store, options, scene, format)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


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
    options: OccludedOptions,
    format: RayFormat = None,
):
    """Whether each ray hits anything in [tmin, tmax]."""
    steps = ray_steps(request, settings, store, options, scene, format)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


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
    options: HitsOptions,
    format: RayFormat = None,
):
    """Every hit along each ray in [tmin, tmax], nearest first, at most ``max_hits``."""
    steps = ray_steps(request, settings, store, options, scene, format)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


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
    options: CountOptions,
    format: RayFormat = None,
):
    """How many triangles each ray crosses in [tmin, tmax] (a shared edge or vertex once)."""
    steps = ray_steps(request, settings, store, options, scene, format)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


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
    options: TraceOptions,
    format: TraceFormat = None,
):
    """A stateless one-shot: the mesh comes with the rays (answers carry X-Scene-Version: 0)."""
    steps = ray_steps(request, settings, None, options, None, format)
    return await answer(request, settings, None, metrics, options, None, format, steps)


def ray_steps(
    request: Request,
    settings: Settings,
    store: Store | None,
    options: Options,
    scene: str | None,
    format: str | None,
) -> Steps:
    """A batch of rays for ``scene`` of ``store`` (a one-shot /trace's mesh and rays when
    ``scene`` is None): decoded by ``wire``, traced by ``tracing``, encoded by ``wire`` in the
    format ``Accept`` picks among those of the answer (406 before the body is read)."""
    accept = request.headers.get("accept")
    declared = format or wire.declared_format(request.headers.get("content-type"))
    guessed = negotiate(accept, declared or "npz", options)  # a JSON body may still make it json
    max_rays = settings.max_rays_per_request
    limits = {"max_rays": max_rays, "max_bytes": settings.max_body_bytes}

    def peak(
        n_body: int,
        fmt: str | None,
        answer_format: str,
        n_rays: int | None = None,
        n_mesh_triangles: int | None = None,
    ) -> int:
        """The request's peak bytes: its body decoded, its rays traced (with the work on the
        triangles of the scene, or of a one-shot /trace's mesh: ``n_mesh_triangles`` once it
        is decoded), its answer written; before the body is read, the most it can hold."""
        if n_rays is None:
            n_rays = footprint.most_rays(n_body, fmt, max_rays)
        mesh = 0
        if scene is None:  # /trace's mesh, of at most the triangles its body can hold
            if n_mesh_triangles is None:
                n_mesh_triangles = footprint.most_triangles(n_body)
            mesh = n_mesh_triangles * footprint.TRIANGLE_BYTES
            n_triangles = n_mesh_triangles
        else:
            n_triangles = store.snapshot(scene).n_triangles
        work = footprint.query_bytes(n_rays, options.kind.value, options.fields, options.max_hits)
        work += footprint.scene_work_bytes(n_triangles, n_rays, options.threads)
        return (
            footprint.decode_bytes(n_body, fmt)
            + mesh
            + work
            + footprint.answer_bytes(answer_format)
        )

    def decode(body: memoryview, fmt: str) -> Decoded:
        answer_format = negotiate(accept, fmt, options)
        if scene is None:
            mesh, rays = wire.decode_trace(body, fmt, **limits)
            check_trace_mesh(mesh, settings.max_triangles_per_scene)
        else:
            mesh, rays = None, wire.decode_rays(body, fmt, **limits)
        check_hit_buffers(len(rays), options, settings.max_hits_bytes)
        n_mesh_triangles = None if mesh is None else len(mesh.faces)
        held = peak(len(body), None, answer_format, len(rays), n_mesh_triangles)
        return Decoded((mesh, rays), len(rays), held, answer_format)

    def trace(value) -> tracing.TraceResult:
        mesh, rays = value
        if scene is None:
            return tracing.trace_once(mesh, rays, options)
        return tracing.trace(store.snapshot(scene), rays, options, request.app.state.cluster)

    def estimate(n_body: int, fmt: str | None) -> int:
        return peak(n_body, fmt, guessed)

    formats = wire.RAY_FORMATS if scene is not None else wire.TRACE_FORMATS
    return Steps(formats, estimate, decode, trace, encode_arrays)


def check_trace_mesh(mesh: wire.MeshArrays, max_triangles: int) -> None:
    """413 when a one-shot trace's mesh holds more triangles than a stored scene may."""
    if len(mesh.faces) > max_triangles:
        raise TooLarge(
            f"the trace's mesh has {len(mesh.faces)} triangles, over the limit of "
            f"{max_triangles} (DACRT_MAX_TRIANGLES_PER_SCENE)"
        )


def negotiate(accept: str | None, request_format: str, options: Options) -> str:
    """The answer format, among those the query's answer can be written in (406 naming them)."""
    return wire.negotiate(accept, request_format, options.answer_formats, options.why_not_npy)


def check_hit_buffers(n_rays: int, options: Options, limit: int) -> None:
    """413 when a hits query would hold more hit buffers than DACRT_MAX_HITS_BYTES allows."""
    needed = options.hit_buffer_bytes(n_rays)
    if needed > limit:
        raise TooLarge(
            f"{n_rays} rays with max_hits={options.max_hits} need {needed} bytes of hit buffers "
            f"({n_rays} x ({options.max_hits} + 1) x {footprint.HIT_SLOT_BYTES}), over the limit "
            f"of {limit} bytes (DACRT_MAX_HITS_BYTES); send fewer rays or a smaller max_hits"
        )
