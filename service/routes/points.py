"""Point queries on a stored scene: the closest point on its triangles (``/nearest``), with inside
and the signed distance when asked."""

from __future__ import annotations

from anyio.to_thread import run_sync
from fastapi import APIRouter, Depends, Request

from dacrt.points import vote_rays_at_once

from .. import footprint, openapi, tracing, wire
from ..deps import MetricsDep, SettingsDep, StoreDep, reject_unknown_query, require_token
from ..params import MaxDistance, NSamples, PointFormat, PointMask, SceneName, Sign, Stats
from ..pipeline import receive, respond
from ..responses import BuffersResponse
from ..store import Snapshot

router = APIRouter(
    prefix="/v1",
    tags=["points"],
    dependencies=[Depends(require_token), Depends(reject_unknown_query)],
)

POINTS_BODY = openapi.request_body(
    wire.POINT_FORMATS, openapi.POINTS_JSON, "points: .npy (N, 3) float32, .npz or JSON"
)


@router.post(
    "/scenes/{scene}/nearest",
    openapi_extra=POINTS_BODY,
    response_class=BuffersResponse,
    responses={
        **openapi.answers(
            "distance, point, mesh, prim, u, v per point; with sign=true also inside and "
            "signed_distance"
        ),
        **openapi.errors(400, 401, 404, 406, 408, 413, 415, 422),
    },
)
async def nearest(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    metrics: MetricsDep,
    max_distance: MaxDistance = None,
    sign: Sign = False,
    nsamples: NSamples = 1,
    mask: PointMask = None,
    stats: Stats = False,
    format: PointFormat = None,
):
    """The closest point on any triangle to each point (ties to the lowest mesh and triangle)."""
    point_mask = None if mask is None else wire.parse_mask(mask, "?mask")
    max_points = settings.max_rays_per_request
    options = tracing.point_options(
        max_distance, sign, nsamples, point_mask, stats, settings.threads, max_points
    )
    accept = request.headers.get("accept")
    declared = format or wire.declared_format(request.headers.get("content-type"))
    answer_format = wire.negotiate(accept, declared or "npz")  # again once the body is read

    def peak(
        n_body: int, fmt: str | None, n_points: int | None = None, snapshot: Snapshot | None = None
    ) -> int:
        """The request's peak bytes: its body decoded, its points measured (with the work on
        the triangles of the scene's version ``snapshot``, by default the current one), its
        answer written; before the body is read, the most it can hold."""
        if n_points is None:
            n_points = footprint.most_points(n_body, fmt, max_points)
        snapshot = snapshot or store.snapshot(scene)
        n_triangles = snapshot.n_triangles
        work = footprint.scene_work_bytes(
            n_triangles, n_points, settings.threads, points=True, masked=point_mask is not None,
            setup=tracing.derives_for_points(snapshot),
        )  # fmt: skip
        if sign:  # the inside test's rays, on the same triangles once the points are measured
            rays = vote_rays_at_once(n_points, options.nsamples)
            work = max(work, footprint.scene_work_bytes(n_triangles, rays, settings.threads))
        return (
            footprint.decode_bytes(n_body, fmt)
            + footprint.point_query_bytes(n_points, sign, options.nsamples)
            + work
            + footprint.answer_bytes(answer_format)
        )

    got = await receive(request, settings, store, scene, format, wire.POINT_FORMATS, peak)
    answer_format = wire.negotiate(accept, got.fmt)
    limits = {"max_points": max_points, "max_bytes": settings.max_body_bytes}

    def decode():
        with got.timing("decode"):
            return wire.decode_points(got.body, got.fmt, **limits)

    points = await run_sync(decode)
    tracing.check_point_rays(options, len(points), max_points)
    what = f"{request.method} {request.url.path} of {len(points)} points{request.state.load}"
    # The version measured is the one its peak was held for: a frame that commits meanwhile
    # may bring a first point query's setup.
    snapshot = None
    while snapshot is not store.snapshot(scene):
        snapshot = store.snapshot(scene)
        await got.ticket.hold(peak(len(got.body), None, len(points), snapshot) + got.inflated, what)

    def work():
        with got.timing("trace"):
            result = tracing.nearest(snapshot, points, options)
        with got.timing("encode"):
            return result, wire.encode_answer(result.arrays, answer_format)

    result, encoded = await run_sync(work)
    return respond(metrics, "nearest", result, encoded, got.timing)
