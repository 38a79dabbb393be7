"""Sensors on a stored scene: a picture (``/render``), a depth camera (``/camera``) and a spinning
lidar (``/lidar``), each a JSON body of a few numbers whose rays the server makes and traces."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from .. import footprint, openapi, sensing, shading, wire
from ..deps import MetricsDep, SettingsDep, StoreDep, reject_unknown_query, require_token
from ..errors import TooLarge
from ..params import CameraOptions, LidarOptions, RenderOptions, SceneName, body_format
from ..pipeline import Decoded, Steps, answer, encode_arrays
from ..responses import BuffersResponse
from ..sensor_requests import CameraRequest, LidarRequest, RenderRequest, parse
from ..settings import Settings
from ..tracing import TraceResult

router = APIRouter(
    prefix="/v1",
    tags=["sensors"],
    dependencies=[Depends(require_token), Depends(reject_unknown_query)],
)

JSON_ONLY = ("json",)
JsonFormat = body_format(JSON_ONLY)
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
    options: RenderOptions,
    format: JsonFormat = None,
) -> Response:
    """A picture of the scene, traced by the engine: pixel (0, 0) is the top-left, ``fov_deg`` the
    vertical field of view (docs/sensors.md)."""
    wire.check_accepts(request.headers.get("accept"), PNG)

    def decode(body: memoryview, fmt: str) -> Decoded:
        wanted = parse(RenderRequest, body, "render")
        check_pixels(wanted.width, wanted.height, settings)
        pixels = wanted.width * wanted.height
        return sensor_decoded((wanted.pinhole(), wanted.shading), body, pixels, "png")

    def trace(value) -> TraceResult:
        pinhole, style = value
        return sensing.render(store.snapshot(scene), pinhole, style, options)

    def encode(result: TraceResult, answer_format: str):
        picture = shading.png(result.arrays["pixels"])
        return [picture], len(picture), PNG

    steps = Steps(JSON_ONLY, footprint.decode_bytes, decode, trace, encode)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


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
    options: CameraOptions,
    format: JsonFormat = None,
) -> BuffersResponse:
    """A depth camera: per pixel, the depth along the optical axis (inf on a miss), the range
    along the ray, the mesh, the triangle and its normal (docs/sensors.md)."""
    answer_format = wire.negotiate(request.headers.get("accept"), "json")

    def decode(body: memoryview, fmt: str) -> Decoded:
        wanted = parse(CameraRequest, body, "camera")
        check_pixels(wanted.width, wanted.height, settings)
        value = (wanted.pinhole(), wanted.near, wanted.max_depth)
        return sensor_decoded(value, body, wanted.width * wanted.height, answer_format)

    def trace(value) -> TraceResult:
        pinhole, near, far = value
        return sensing.depth_camera(store.snapshot(scene), pinhole, near, far, options)

    steps = Steps(JSON_ONLY, footprint.decode_bytes, decode, trace, encode_arrays)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


@router.post(
    "/scenes/{scene}/lidar",
    openapi_extra=json_body(
        LidarRequest, "a sensor pose, a beam pattern, rays per revolution and a range window"
    ),
    response_class=BuffersResponse,
    responses={
        **openapi.answers(
            "per point: xyz, range, ring, azimuth, elevation, mesh, prim, return, cos_incidence, "
            "ray; with period_s also time, velocity, radial_speed"
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
    options: LidarOptions,
    format: JsonFormat = None,
) -> BuffersResponse:
    """One revolution of a spinning lidar: the points where its beams hit (docs/sensors.md)."""
    answer_format = wire.negotiate(request.headers.get("accept"), "json")

    def decode(body: memoryview, fmt: str) -> Decoded:
        wanted = parse(LidarRequest, body, "lidar")
        check_rays(wanted.n_rays * wanted.max_returns, settings, "beams x steps x max_returns")
        value = (wanted.scan(), wanted.max_returns, wanted.motion())
        return sensor_decoded(value, body, wanted.n_rays, answer_format, wanted.max_returns)

    def trace(value) -> TraceResult:
        scan, max_returns, motion = value
        return sensing.lidar_scan(store.snapshot(scene), scan, max_returns, options, motion)

    steps = Steps(JSON_ONLY, footprint.decode_bytes, decode, trace, encode_arrays)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


def sensor_decoded(
    value, body: memoryview, n_rays: int, answer_format: str, max_returns: int = 1
) -> Decoded:
    """A sensor's body decoded into ``value``, holding its body, its ``n_rays`` rays traced for
    ``max_returns`` returns each and its answer in ``answer_format``."""
    peak = (
        len(body)
        + footprint.sensor_bytes(n_rays, max_returns)
        + footprint.answer_bytes(answer_format)
    )
    return Decoded(value, n_rays, peak, answer_format)


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
