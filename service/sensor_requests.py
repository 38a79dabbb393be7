"""The JSON bodies of ``/render``, ``/camera`` and ``/lidar``, as pydantic models.

``parse`` reads a body into a model: a body that is not a JSON object, or that lacks a required
key or has an unknown one, is 400 (API.md: "wrong keys"); a value of the wrong type or out of range
is 422, naming the key (``pose[3][0]: ...``). Numbers must be JSON numbers (not strings or
booleans), finite and within float32's range (the rays are float32); ``null`` stands for a default
where the model says so. What the values make is checked here too, so that no request reaches the
engine with rays it would refuse: a camera's focal length must keep its edge rays within float32.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, NamedTuple, TypeVar

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, model_validator

from . import wire
from .cameras import Pinhole, check_pose, look_at
from .errors import BadBody, Invalid
from .lidar import MODELS, Scan, make_scan
from .shading import SHADINGS

#: Most beams (rings) of a lidar pattern, and most returns per ray.
MAX_BEAMS = 1024
MAX_RETURNS = 64

#: The largest float32: every number of a sensor ends up in float32 rays or bounds.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _within_float32(value: float) -> float:
    if abs(value) > FLOAT32_MAX:
        raise ValueError(f"{value!r} is beyond the float32 range (at most {FLOAT32_MAX:.7g})")
    return value


Float32 = AfterValidator(_within_float32)
Finite = Annotated[float, Field(strict=True, allow_inf_nan=False), Float32]
Vector3 = Annotated[list[Finite], Field(min_length=3, max_length=3)]
Matrix4 = Annotated[
    list[Annotated[list[Finite], Field(min_length=4, max_length=4)]],
    Field(min_length=4, max_length=4, description="4x4, row-major"),
]
Pixels = Annotated[int, Field(strict=True, gt=0)]
Positive = Annotated[float, Field(strict=True, gt=0, allow_inf_nan=False), Float32]
NonNegative = Annotated[float, Field(strict=True, ge=0, allow_inf_nan=False), Float32]
FieldOfView = Annotated[
    float,
    Field(strict=True, gt=0, lt=180, description="vertical field of view, degrees"),
]


class Body(BaseModel):
    """A request body: unknown keys are refused, values are not converted between JSON types."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class LookAtCamera(Body):
    """A camera at ``eye`` looking at ``target``; ``up`` is up in the picture."""

    width: Pixels
    height: Pixels
    eye: Vector3
    target: Vector3
    up: Vector3 = [0.0, 1.0, 0.0]
    fov_deg: FieldOfView = 60.0

    def pinhole(self) -> Pinhole:
        """The camera as a pinhole; CameraError (422) for eye == target, or up zero or parallel to
        the view."""
        return look_at(self.eye, self.target, self.up, self.fov_deg, self.width, self.height)


class RenderRequest(LookAtCamera):
    """``POST /render``: a look-at camera and a shading."""

    shading: Literal[SHADINGS] = "shaded"


LOOK_AT_KEYS = ("eye", "target", "up", "fov_deg")
INTRINSIC_KEYS = ("fx", "fy", "cx", "cy", "pose")


class CameraRequest(Body):
    """``POST /camera``: a look-at camera (``eye``, ``target``, ``up``, ``fov_deg``) or an OpenCV
    pinhole (``fx``, ``fy``, ``cx``, ``cy`` in pixels and a rigid camera-to-scene ``pose``), and
    the depths it sees, ``near <= depth <= far`` (``far`` null: no limit)."""

    width: Pixels
    height: Pixels
    eye: Vector3 | None = None
    target: Vector3 | None = None
    up: Vector3 = [0.0, 1.0, 0.0]
    fov_deg: FieldOfView = 60.0
    fx: Positive | None = None
    fy: Positive | None = None
    cx: Finite | None = None
    cy: Finite | None = None
    pose: Matrix4 | None = None
    near: NonNegative = 0.0
    far: Positive | None = None

    @model_validator(mode="after")
    def _one_camera(self) -> CameraRequest:
        given = self.model_fields_set
        look_at_keys = [k for k in LOOK_AT_KEYS if k in given]
        intrinsic_keys = [k for k in INTRINSIC_KEYS if k in given]
        if look_at_keys and intrinsic_keys:
            raise ValueError(
                f"give either a look-at camera ({', '.join(LOOK_AT_KEYS)}) or intrinsics and a "
                f"pose ({', '.join(INTRINSIC_KEYS)}), not both: the body has "
                f"{', '.join(look_at_keys + intrinsic_keys)}"
            )
        if self.far is not None and self.far <= self.near:
            raise ValueError(f"far ({self.far}) must be greater than near ({self.near})")
        intrinsics = (self.fx, self.cx, self.fy, self.cy)
        if None not in intrinsics:  # else 400 for the missing keys (``parse``)
            check_edge_rays(self.fx, self.cx, self.width, self.fy, self.cy, self.height)
        return self

    def missing(self) -> list[str]:
        """The keys the chosen kind of camera still needs."""
        if any(k in self.model_fields_set for k in INTRINSIC_KEYS):
            return [k for k in INTRINSIC_KEYS if getattr(self, k) is None]
        return [k for k in ("eye", "target") if getattr(self, k) is None]

    def pinhole(self) -> Pinhole:
        if self.pose is None:
            return LookAtCamera(
                width=self.width,
                height=self.height,
                eye=self.eye,
                target=self.target,
                up=self.up,
                fov_deg=self.fov_deg,
            ).pinhole()
        pose = check_pose(self.pose)  # CameraError (422) naming the pose's fault
        return Pinhole(self.width, self.height, self.fx, self.fy, self.cx, self.cy, pose)

    @property
    def max_depth(self) -> float:
        return math.inf if self.far is None else self.far


def edge_ray(focal: float, centre: float, pixels: int) -> float:
    """The largest ``|k - centre| / focal`` over the pixel coordinates k of ``pixels``: the
    camera-frame slope of the outermost rays (float64; inf when it overflows)."""
    with np.errstate(over="ignore"):
        return float(np.float64(max(abs(centre), abs(pixels - 1 - centre))) / np.float64(focal))


def check_edge_rays(fx: float, cx: float, width: int, fy: float, cy: float, height: int) -> None:
    """ValueError naming fx or fy if the rays of the picture's edge overflow float32: a direction
    ``x * R[:, 0] + y * R[:, 1] + R[:, 2]`` (R a rotation) has components of at most
    ``|x| + |y| + 1``, which must stay within FLOAT32_MAX."""
    x, y = edge_ray(fx, cx, width), edge_ray(fy, cy, height)
    if x + y + 1 <= FLOAT32_MAX:
        return
    key, focal, centre_key, centre, slope, along = (
        ("fx", fx, "cx", cx, x, "column") if x >= y else ("fy", fy, "cy", cy, y, "row")
    )
    raise ValueError(
        f"{key}: {focal!r} is too small for {centre_key} {centre!r}: the slope of the edge rays, "
        f"({along} - {centre_key}) / {key}, reaches {slope:.3g}, beyond the float32 range"
    )


Elevation = Annotated[float, Field(strict=True, ge=-90, le=90, allow_inf_nan=False)]
Elevations = Annotated[list[Elevation], Field(min_length=1, max_length=MAX_BEAMS)]


class LidarRequest(Body):
    """``POST /lidar``: a sensor pose, a beam pattern (``model`` or ``vertical_angles_deg``), the
    rays per revolution, the range window and the returns per ray."""

    pose: Matrix4
    model: Literal[tuple(MODELS)] | None = None
    vertical_angles_deg: Elevations | None = None
    horizontal_steps: Pixels = 1024
    min_range: NonNegative = 0.0
    max_range: Positive | None = None
    max_returns: Annotated[int, Field(strict=True, ge=1, le=MAX_RETURNS)] = 1
    period_s: Positive | None = None  #: the sweep's duration: columns fire over it (motion)
    pose_end: Matrix4 | None = None  #: the sensor's pose at the sweep's end (needs period_s)

    @model_validator(mode="after")
    def _one_pattern(self) -> LidarRequest:
        if self.pose_end is not None and self.period_s is None:
            raise ValueError("pose_end needs period_s (the sweep's duration in seconds)")
        if (self.model is None) == (self.vertical_angles_deg is None):
            raise ValueError(
                "give exactly one beam pattern: model (one of "
                f"{', '.join(MODELS)}) or vertical_angles_deg (a list of elevations in degrees)"
            )
        if self.max_range is not None and self.max_range <= self.min_range:
            raise ValueError(
                f"max_range ({self.max_range}) must be greater than min_range ({self.min_range})"
            )
        return self

    @property
    def elevations_deg(self) -> list[float]:
        if self.model is not None:
            return list(MODELS[self.model].vertical_angles_deg)
        return self.vertical_angles_deg

    @property
    def n_rays(self) -> int:
        return len(self.elevations_deg) * self.horizontal_steps

    def motion(self) -> Motion | None:
        """The sweep over time (None: one instant); CameraError (422) for a pose_end that is not
        rigid."""
        if self.period_s is None:
            return None
        end = None if self.pose_end is None else check_pose(self.pose_end, "pose_end")
        return Motion(self.period_s, end)

    def scan(self) -> Scan:
        """The revolution to trace; CameraError (422) for a pose that is not rigid."""
        return make_scan(
            self.pose,
            self.elevations_deg,
            self.horizontal_steps,
            self.min_range,
            math.inf if self.max_range is None else self.max_range,
        )


class Motion(NamedTuple):
    """A lidar sweep over time: its duration, and the sensor's pose at its end (None: still)."""

    period_s: float
    pose_end: np.ndarray | None


Model = TypeVar("Model", bound=Body)

#: Error types that mean the body has the wrong keys (400) rather than wrong values (422).
_KEY_ERRORS = ("missing", "extra_forbidden")


def parse(model: type[Model], body: wire.Buffer, what: str) -> Model:
    """``body`` (JSON) as ``model``: 400 if it is not a JSON object or has wrong keys, 422 naming
    each bad value."""
    keys = ", ".join(model.model_fields)
    doc = wire.read_json(body, f"keys {keys}")
    try:
        value = model.model_validate(doc)
    except ValidationError as error:
        errors = error.errors(include_url=False)
        wrong_keys = [e for e in errors if e["type"] in _KEY_ERRORS and len(e["loc"]) == 1]
        if wrong_keys:
            raise BadBody(f"{what}: {describe(wrong_keys)}; the body's keys are {keys}") from None
        raise Invalid(f"{what}: {describe(errors)}") from None
    missing = value.missing() if isinstance(value, CameraRequest) else []
    if missing:
        raise BadBody(f"{what}: the camera lacks {', '.join(missing)}; the body's keys are {keys}")
    return value


def describe(errors: list[dict]) -> str:
    """One clause per pydantic error: ``pose[3][0]: Input should be a finite number``."""
    parts = []
    for error in errors:
        path = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in error["loc"])
        path = path.removeprefix(".")
        message = error["msg"].removeprefix("Value error, ")
        if error["type"] == "missing":
            message = "missing"
        elif error["type"] == "extra_forbidden":
            message = "unknown key"
        parts.append(f"{path}: {message}" if path else message)
    return "; ".join(parts)
