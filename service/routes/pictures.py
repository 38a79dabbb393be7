"""Sensors on a stored scene: a picture (``/render``), a depth camera (``/camera``) and a spinning
lidar (``/lidar``), each a JSON body of a few numbers whose rays the server makes and traces."""

from __future__ import annotations

from collections.abc import Callable

from anyio import from_thread
from anyio.to_thread import run_sync
from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from .. import footprint, openapi, sensing, shading, wire
from ..deps import MetricsDep, SettingsDep, StoreDep, reject_unknown_query, require_token
from ..errors import TooLarge
from ..metrics import Metrics
from ..params import BatchOptionsDep, Cull, SceneName, Stats, Strategy, body_format
from ..pipeline import receive, respond
from ..responses import BuffersResponse
from ..sensor_requests import CameraRequest, LidarRequest, RenderRequest, parse
from ..settings import Settings
from ..store import Store
from ..timing import ServerTiming

router = APIRouter(
    prefix="/v1",
    tags=["sensors"],
    dependencies=[Depends(require_token), Depends(reject_unknown_query)],
)

JsonFormat = body_format(("json",))
PNG = "image/png"
SENSOR_ERRORS = openapi.errors(400, 401, 404, 406, 408, 413, 415, 422)


def json_body(model, description: str) -> dict:
    """``openapi_extra`` of a required JSON body with ``model``'s schema."""
    schema = model.model_json_schema()
    return {
        "requestBody": {
            "required": True,
            "description": description,
            "content": {wire.JSON: {"schema": schema}},
        }
    }


@router.post(
    "/scenes/{scene}/render",
    openapi_extra=json_body(RenderRequest, "a look-at camera, a picture size and a shading"),
    response_class=Response,
    responses={
        200: {
            "description": "the picture: PNG, grey (depth) or RGB (normal, shaded)",
            "content": {PNG: {"schema": {"type": "string", "format": "binary"}}},
        },
        **SENSOR_ERRORS,
    },
)
async def render(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    metrics: MetricsDep,
    strategy: Strategy = None,
    stats: Stats = False,
    cull: Cull = "none",
    format: JsonFormat = None,
) -> Response:
    """A picture of the scene, traced by the engine: pixel (0, 0) is the top-left, ``fov_deg`` the
    vertical field of view (docs/sensors.md)."""
    wire.check_accepts(request.headers.get("accept"), PNG)
    options = sensing.SensorOptions((), strategy, stats, settings.threads, cull)
    options.closest()  # 422 for an unknown strategy or cull before the body is read

    def work(body: memoryview, timing: ServerTiming, admit: Callable):
        with timing("decode"):
            wanted = parse(RenderRequest, body, "render")
            check_pixels(wanted.width, wanted.height, settings)
            admit(wanted.width * wanted.height, "png")
            pinhole = wanted.pinhole()
        with timing("trace"):
            pixels, result = sensing.render(store.snapshot(scene), pinhole, wanted.shading, options)
        with timing("encode"):
            picture = shading.png(pixels)
        return result, [picture], len(picture), PNG

    return await answer(request, settings, store, metrics, scene, format, "render", work)


@router.post(
    "/scenes/{scene}/camera",
    openapi_extra=json_body(
        CameraRequest, "a look-at camera, or OpenCV intrinsics and a camera-to-scene pose"
    ),
    response_class=BuffersResponse,
    responses={
        **openapi.answers("depth, range, mesh, prim (height, width) and normal (height, width, 3)"),
        **SENSOR_ERRORS,
    },
)
async def camera(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    metrics: MetricsDep,
    batch: BatchOptionsDep,
    format: JsonFormat = None,
) -> BuffersResponse:
    """A depth camera: per pixel, the depth along the optical axis (inf on a miss), the range
    along the ray, the mesh, the triangle and its normal (docs/sensors.md)."""
    fields = sensing.pick_fields(batch.fields, sensing.CAMERA_FIELDS, "camera")
    options = sensing.SensorOptions(
        fields, batch.strategy, batch.stats, settings.threads, batch.cull
    )
    options.closest()  # 422 for an unknown strategy or cull before the body is read
    answer_format = wire.negotiate(request.headers.get("accept"), "json")

    def work(body: memoryview, timing: ServerTiming, admit: Callable):
        with timing("decode"):
            wanted = parse(CameraRequest, body, "camera")
            check_pixels(wanted.width, wanted.height, settings)
            admit(wanted.width * wanted.height, answer_format)
            pinhole = wanted.pinhole()
        with timing("trace"):
            result = sensing.depth_camera(
                store.snapshot(scene), pinhole, wanted.near, wanted.max_depth, options
            )
        with timing("encode"):
            return (result, *wire.encode_answer(result.arrays, answer_format))

    return await answer(request, settings, store, metrics, scene, format, "camera", work)


@router.post(
    "/scenes/{scene}/lidar",
    openapi_extra=json_body(
        LidarRequest, "a sensor pose, a beam pattern, rays per revolution and a range window"
    ),
    response_class=BuffersResponse,
    responses={
        **openapi.answers(
            "per point: xyz, range, ring, azimuth, elevation, mesh, prim, return, cos_incidence, "
            "ray"
        ),
        **SENSOR_ERRORS,
    },
)
async def lidar(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    metrics: MetricsDep,
    batch: BatchOptionsDep,
    format: JsonFormat = None,
) -> BuffersResponse:
    """One revolution of a spinning lidar: the points where its beams hit (docs/sensors.md)."""
    fields = sensing.pick_fields(batch.fields, sensing.LIDAR_FIELDS, "lidar")
    options = sensing.SensorOptions(
        fields, batch.strategy, batch.stats, settings.threads, batch.cull
    )
    options.closest()  # 422 for an unknown strategy or cull before the body is read
    answer_format = wire.negotiate(request.headers.get("accept"), "json")

    def work(body: memoryview, timing: ServerTiming, admit: Callable):
        with timing("decode"):
            wanted = parse(LidarRequest, body, "lidar")
            check_rays(wanted.n_rays * wanted.max_returns, settings, "beams x steps x max_returns")
            admit(wanted.n_rays, answer_format, wanted.max_returns)
            scan = wanted.scan()
        with timing("trace"):
            result = sensing.lidar_scan(store.snapshot(scene), scan, wanted.max_returns, options)
        with timing("encode"):
            return (result, *wire.encode_answer(result.arrays, answer_format))

    return await answer(request, settings, store, metrics, scene, format, "lidar", work)


async def answer(
    request: Request,
    settings: Settings,
    store: Store,
    metrics: Metrics,
    scene: str,
    format: str | None,
    sensor: str,
    work: Callable,
) -> Response:
    """Receive a sensor's JSON body, then decode, trace and encode it with ``work(body, timing,
    admit)`` off the event loop, where ``admit(n_rays, answer_format, max_returns=1)`` waits for
    the sensor's memory in the in-flight budget once its rays are known."""
    got = await receive(request, settings, store, scene, format, ("json",), footprint.decode_bytes)

    def admit(n_rays: int, answer_format: str, max_returns: int = 1) -> None:
        nbytes = (
            len(got.body)
            + footprint.sensor_bytes(n_rays, max_returns)
            + footprint.answer_bytes(answer_format)
        )
        what = f"POST /v1/scenes/{scene}/{sensor} of {n_rays} rays"
        from_thread.run(got.ticket.hold, nbytes, what)

    result, *encoded = await run_sync(work, got.body, got.timing, admit)
    return respond(metrics, sensor, result, result.n_rays, encoded, got.timing)


def check_pixels(width: int, height: int, settings: Settings) -> None:
    """413 for a picture over DACRT_MAX_IMAGE_PIXELS (or over DACRT_MAX_RAYS_PER_REQUEST)."""
    if width * height > settings.max_image_pixels:
        raise TooLarge(
            f"{width} x {height} = {width * height} pixels is over the limit of "
            f"{settings.max_image_pixels} pixels (DACRT_MAX_IMAGE_PIXELS)"
        )
    check_rays(width * height, settings, "width x height")


def check_rays(n_rays: int, settings: Settings, what: str) -> None:
    """413 for more rays than DACRT_MAX_RAYS_PER_REQUEST."""
    if n_rays > settings.max_rays_per_request:
        raise TooLarge(
            f"{what} = {n_rays} rays is over the limit of {settings.max_rays_per_request} rays "
            "per request (DACRT_MAX_RAYS_PER_REQUEST)"
        )
