"""Sensors on a stored scene: a picture (``/render``), a depth camera (``/camera``), a lidar
(``/lidar``) and a rig of several (``/sensors``), each a JSON body of a few numbers that becomes the
engine's sensors (``sensor_requests``), traced by ``dacrt.sensors`` (``sensing``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from dacrt.sensors import CAMERA_FIELDS, Camera, Lidar

from .. import footprint, openapi, sensing, shading, wire
from ..deps import (
    MetricsDep,
    PatternsDep,
    SettingsDep,
    StoreDep,
    reject_unknown_query,
    require_token,
)
from ..errors import Invalid, TooLarge
from ..options import Options
from ..params import (
    CameraOptions,
    LidarOptions,
    RenderOptions,
    RigOptions,
    SceneName,
    body_format,
)
from ..patterns import Patterns
from ..pipeline import Decoded, Steps, answer, encode_arrays
from ..responses import BuffersResponse
from ..sensor_requests import (
    CameraRequest,
    LidarRequest,
    LookAtCamera,
    RenderRequest,
    SensorsRequest,
    parse,
)
from ..settings import Settings
from ..store import Store
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
#: A lidar answers a PCD file too (``Accept: application/x-pcd``); a rig npz or JSON.
LIDAR_FORMATS = (*wire.ANSWER_FORMATS, "pcd")
RIG_FORMATS = ("npz", "json")


def json_body(model, description: str) -> dict:
    """``openapi_extra`` of a required JSON body with ``model``'s schema, its ``$defs`` put in
    place (their ``#/$defs/...`` references would point into the OpenAPI document's root)."""
    schema = openapi.inlined(model.model_json_schema())
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
            "headers": openapi.ANSWER_HEADERS,
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

    work = triangles_work(store, scene, options)

    def decode(body: memoryview, fmt: str) -> Decoded:
        wanted = parse(RenderRequest, body, "render")
        check_pixels({"render": wanted}, settings)
        camera, pose = wanted.sensor()
        check_sensors({"render": camera}, settings)
        return sensor_decoded((camera, pose, wanted.shading), body, [camera], "png", work)

    def trace(value) -> TraceResult:
        camera, pose, style = value
        return sensing.render(store.snapshot(scene), camera, pose, style, options)

    def encode(result: TraceResult, answer_format: str):
        picture = shading.png(result.arrays["pixels"])
        return [picture], len(picture), PNG

    steps = sensor_steps(decode, trace, encode, work, PIXELS_ADVICE)
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

    work = triangles_work(store, scene, options)

    def decode(body: memoryview, fmt: str) -> Decoded:
        wanted = parse(CameraRequest, body, "camera")
        check_pixels({"camera": wanted}, settings)
        sensor, pose = wanted.sensor()
        check_sensors({"camera": sensor}, settings)
        return sensor_decoded((sensor, pose), body, [sensor], answer_format, work)

    def trace(value) -> TraceResult:
        return sensing.sense(store.snapshot(scene), *value, options)

    steps = sensor_steps(decode, trace, encode_arrays, work, PIXELS_ADVICE + NPZ_ADVICE)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


@router.post(
    "/scenes/{scene}/lidar",
    openapi_extra=json_body(
        LidarRequest,
        "a sensor pose, a beam pattern (model, vertical_angles_deg or an uploaded pattern), "
        "rays per revolution, a range window, returns and the lidar's physics",
    ),
    response_class=BuffersResponse,
    responses={
        **openapi.answers(
            "per point: xyz, range, ring, azimuth, elevation, mesh, prim, return, cos_incidence, "
            "ray, intensity, label (and time with a pattern's times); or a binary PCD file",
            LIDAR_FORMATS,
        ),
        **SENSOR_ERRORS,
    },
)
async def lidar(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    patterns: PatternsDep,
    metrics: MetricsDep,
    options: LidarOptions,
    format: JsonFormat = None,
) -> BuffersResponse:
    """One sweep of a lidar: the points where its beams return, with intensity and label
    (docs/sensors.md)."""
    answer_format = wire.negotiate(request.headers.get("accept"), "json", LIDAR_FORMATS)
    options.check_columns(answer_format)

    work = triangles_work(store, scene, options)

    def decode(body: memoryview, fmt: str) -> Decoded:
        wanted = parse(LidarRequest, body, "lidar")
        sensor, pose = wanted.sensor(patterns.for_lidar)
        check_answered_fields(options.fields, sensor)
        check_sensors({"lidar": sensor}, settings)
        return sensor_decoded(
            (sensor, pose, wanted.end_pose()), body, [sensor], answer_format, work
        )

    def trace(value) -> TraceResult:
        sensor, pose, pose_end = value
        return sensing.sense(store.snapshot(scene), sensor, pose, options, pose_end)

    def encode(result: TraceResult, answer_format: str):
        # a PCD's fields come in the order asked, as pcd_bytes writes them in process
        pcd_fields = options.pcd_fields(result.arrays)
        return wire.encode_answer(result.arrays, answer_format, pcd_fields)

    steps = sensor_steps(decode, trace, encode, work, LIDAR_ADVICE + NPZ_ADVICE)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


@router.post(
    "/scenes/{scene}/sensors",
    openapi_extra=json_body(
        SensorsRequest,
        "a rig: named sensors, each the body of /lidar or /camera with its kind",
    ),
    response_class=BuffersResponse,
    responses={
        **openapi.answers(
            "each sensor's answer: .npz keys NAME.KEY (roof.xyz, front.depth), or JSON "
            "{NAME: {KEY: ...}}",
            RIG_FORMATS,
            openapi.RIG_JSON,
        ),
        **SENSOR_ERRORS,
    },
)
async def sensors(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    patterns: PatternsDep,
    metrics: MetricsDep,
    options: RigOptions,
    format: JsonFormat = None,
) -> BuffersResponse:
    """A rig: every sensor's rays traced as one batch on one scene version; each sensor answers
    what it answers alone (``?fields=`` picks the keys each has)."""
    answer_format = wire.negotiate(request.headers.get("accept"), "json", RIG_FORMATS)

    work = triangles_work(store, scene, options)

    def decode(body: memoryview, fmt: str) -> Decoded:
        wanted = parse(SensorsRequest, body, "sensors", settings.max_rig_sensors)
        check_pixels(
            {name: s for name, s in wanted.sensors.items() if s.kind == "camera"}, settings
        )
        rig, ends = rig_sensors(wanted, patterns)
        for name, (sensor, _) in rig.items():
            check_answered_fields(options.fields, sensor, f"sensors.{name}: ")
        check_sensors({name: sensor for name, (sensor, _) in rig.items()}, settings)
        sensors = [sensor for sensor, _ in rig.values()]
        return sensor_decoded((rig, ends), body, sensors, answer_format, work)

    def trace(value) -> TraceResult:
        rig, ends = value
        return sensing.sense_rig(store.snapshot(scene), rig, options, ends)

    def encode(result: TraceResult, answer_format: str):
        return wire.encode_rig_answer(result.arrays, answer_format)

    steps = sensor_steps(decode, trace, encode, work, RIG_ADVICE + NPZ_ADVICE)
    return await answer(request, settings, store, metrics, options, scene, format, steps)


def rig_sensors(
    wanted: SensorsRequest, patterns: Patterns
) -> tuple[dict[str, sensing.Placed], dict[str, np.ndarray]]:
    """Each sensor of a rig as the engine's, at its pose, and each moving lidar's end pose; an
    InputError names the sensor."""
    placed, ends = {}, {}
    for name, body in wanted.sensors.items():
        try:
            placed[name] = (
                body.sensor(patterns.for_lidar) if body.kind == "lidar" else body.sensor()
            )
            if body.kind == "lidar" and body.pose_end is not None:
                ends[name] = body.end_pose()
        except ValueError as error:  # the engine's InputError: 422
            raise type(error)(f"sensors.{name}: {error}") from None
        except Invalid as error:  # a pattern that is not there
            raise Invalid(f"sensors.{name}: {error.detail}") from None
    return placed, ends


#: A 413's advice for a sensor too heavy for the budget, where smaller batches do not apply.
PIXELS_ADVICE = "make fewer pixels (a smaller width and height)"
LIDAR_ADVICE = "make fewer rays (fewer horizontal_steps or beam_samples)"
RIG_ADVICE = "make fewer rays (fewer sensors, steps or pixels)"
NPZ_ADVICE = ", or ask for an .npz answer (Accept: application/x-npz) rather than JSON"


def sensor_steps(decode, trace, encode, work: Callable[[int], int], advice: str) -> Steps:
    """A sensor route's ``Steps``: a JSON body, held at its decode until it says how many rays
    it makes; ``work`` (``triangles_work``) of one ray is the least it holds on the scene, for
    a 413's ``advice``."""
    return Steps(JSON_ONLY, footprint.decode_bytes, decode, trace, encode, lambda: work(1), advice)


def triangles_work(store: Store, scene: str, options: Options) -> Callable[[int], int]:
    """The work of a batch of so many rays on the triangles of ``scene``'s current version
    (``footprint.scene_work_bytes``)."""
    return lambda n_rays: footprint.scene_work_bytes(
        store.snapshot(scene).n_triangles, n_rays, options.threads
    )


def sensor_decoded(
    value, body: memoryview, sensors: list, answer_format: str, work: Callable[[int], int]
) -> Decoded:
    """Sensors' body decoded into ``value``, holding its body, the sensors' rays and hits, the
    work of so many rays on the scene's triangles (``work``) and its answer in
    ``answer_format``."""
    peak = len(body) + footprint.answer_bytes(answer_format)
    n_rays = 0
    for sensor in sensors:
        rays = sensor.n_traced_rays
        peak += footprint.sensor_bytes(rays, sensing.hits_per_ray(sensor))
        if isinstance(sensor, Lidar) and (sensor.organized or sensor.non_hits == "keep"):
            peak += sensor.n_beams * sensor.slots * footprint.FILLED_POINT_BYTES
        n_rays += rays
    return Decoded(value, n_rays, peak + work(n_rays), answer_format)


def check_answered_fields(fields: tuple[str, ...], sensor: Lidar | Camera, where: str = "") -> None:
    """422 when ``?fields=`` names only keys this sensor does not answer (its answer would be
    empty): the times and speeds of a lidar without ``period_s``, or in a rig (``where``: the
    sensor's name) only a camera's keys for a lidar or a lidar's for a camera."""
    lidar = isinstance(sensor, Lidar)
    answered = sensor.fields if lidar else CAMERA_FIELDS
    if not set(fields) & set(answered):
        why = (
            " (velocity and radial_speed need period_s; time needs period_s or a pattern with "
            "time_s)"
            if lidar
            else ""
        )
        raise Invalid(
            f"{where}?fields={','.join(fields)}: this {'lidar' if lidar else 'camera'} answers "
            f"none of them{why}; it answers {', '.join(answered)}"
        )


#: What a sensor's rays are, for a 413.
RAY_WORDS = {
    Camera: "width x height",
    Lidar: "beams x beam_samples (x max_returns with return_mode all)",
}


def check_pixels(pictures: dict[str, LookAtCamera | CameraRequest], settings: Settings) -> None:
    """413 for a picture of a body over DACRT_MAX_IMAGE_PIXELS, before its camera is made: a side
    too long for the engine's Camera (422) is over that limit first."""
    for name, picture in pictures.items():
        pixels = picture.width * picture.height
        if pixels > settings.max_image_pixels:
            # sides of thousands of digits are named, not written out
            sizes = f"{picture.width} x {picture.height} = {pixels}" if pixels < 10**30 else None
            raise TooLarge(
                f"{name}: {sizes or 'width x height'} pixels is over the limit "
                f"of {settings.max_image_pixels} pixels (DACRT_MAX_IMAGE_PIXELS)"
            )


def check_sensors(sensors: dict, settings: Settings) -> None:
    """413 for more rays (and hits) than DACRT_MAX_RAYS_PER_REQUEST in all the sensors of a
    request together."""
    total = 0
    for sensor in sensors.values():
        total += sensing.request_rays(sensor)
    if total > settings.max_rays_per_request:
        (name, sensor), *others = sensors.items()
        what = "the sensors' rays together" if others else RAY_WORDS[type(sensor)]
        raise TooLarge(
            f"{what} = {total} rays is over the limit of "
            f"{settings.max_rays_per_request} rays per request (DACRT_MAX_RAYS_PER_REQUEST)"
        )
