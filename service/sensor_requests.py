"""The JSON bodies of ``/render``, ``/camera``, ``/lidar`` and ``/sensors`` (a rig), as pydantic
models that become the engine's sensors (``dacrt.sensors``).

``parse`` reads a body into a model: a body that is not a JSON object, or that lacks a required
key or has an unknown one (at any depth: ``noise.sigma``), is 400 (API.md: "wrong keys"); a value of
the wrong JSON type is 422, naming the key (``pose[3][0]: ...``). Numbers must be JSON numbers (not
strings or booleans), finite and within float32's range (the rays are float32); ``null`` stands for
a default where the model says so. Each model's ``sensor`` makes the engine's ``Camera`` or
``Lidar``, whose own checks (ranges, poses, edge rays) raise ``dacrt.InputError`` naming the same
key (``noise.range_sigma must be >= 0``): 422 through ``errors``' table.

A message spells out the first ``SHOWN_ERRORS`` errors and counts the rest, and a rig's sensors are
read one by one up to the first that is wrong, so a body's errors cost time and memory in
proportion to one sensor's keys and values, never to the whole rig's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from itertools import islice
from typing import Annotated, Any, Literal, TypeVar

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    StringConstraints,
    ValidationError,
    model_validator,
)
from pydantic_core import PydanticCustomError

from dacrt.sensors import MODELS, RETURN_MODES, Camera, Lidar, Pattern, check_pose, look_at_pose
from dacrt.sensors.lidar import FRAMES, MAX_BEAMS, MAX_RETURNS, NON_HITS

from . import wire
from .errors import BadBody, Invalid, TooLarge
from .shading import SHADINGS
from .store import NAME

#: The largest float32: every number of a sensor ends up in float32 rays or bounds.
FLOAT32_MAX = float(np.finfo(np.float32).max)
#: The errors a message spells out; the others are counted ("and 1,019 more").
SHOWN_ERRORS = 5
#: The error type of an object's unknown keys, all of them in one error.
UNKNOWN_KEYS = "unknown_keys"


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
Integer = Annotated[int, Field(strict=True)]
Positive = Annotated[float, Field(strict=True, gt=0, allow_inf_nan=False), Float32]
NonNegative = Annotated[float, Field(strict=True, ge=0, allow_inf_nan=False), Float32]
FieldOfView = Annotated[
    float,
    Field(
        strict=True,
        gt=0,
        lt=180,
        allow_inf_nan=False,
        description="vertical field of view, degrees",
    ),
]
Name = Annotated[str, StringConstraints(pattern=f"^{NAME.pattern}$")]


class Body(BaseModel):
    """A request body: unknown keys are refused, values are not converted between JSON types."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        # all of an object's unknown keys in one error, before extra="forbid" makes one a key
        known = cls.model_fields.keys()
        if isinstance(data, dict) and not data.keys() <= known:
            unknown = (key for key in data if key not in known)
            shown = list(islice(unknown, SHOWN_ERRORS))
            count = len(shown) + sum(1 for _ in unknown)
            raise PydanticCustomError(UNKNOWN_KEYS, "unknown key", {"keys": shown, "count": count})
        return data


class LookAtCamera(Body):
    """A camera at ``eye`` looking at ``target``; ``up`` is up in the picture."""

    width: Pixels
    height: Pixels
    eye: Vector3
    target: Vector3
    up: Vector3 = [0.0, 1.0, 0.0]
    fov_deg: FieldOfView = 60.0

    def sensor(self) -> tuple[Camera, np.ndarray]:
        """(the engine's camera, its camera-to-scene pose); CameraError (422) for eye == target,
        up zero or parallel to the view, or a field of view too small for float32."""
        camera = Camera.from_fov(self.width, self.height, self.fov_deg)
        return camera, look_at_pose(self.eye, self.target, self.up)


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
        return self

    def missing(self) -> list[str]:
        """The keys the chosen kind of camera still needs."""
        if any(k in self.model_fields_set for k in INTRINSIC_KEYS):
            return [k for k in INTRINSIC_KEYS if getattr(self, k) is None]
        return [k for k in ("eye", "target") if getattr(self, k) is None]

    def sensor(self) -> tuple[Camera, np.ndarray]:
        """(the engine's camera, its camera-to-scene pose); its InputError (422) names the key."""
        far = math.inf if self.far is None else self.far
        if self.pose is None:
            camera = Camera.from_fov(self.width, self.height, self.fov_deg, self.near, far)
            return camera, look_at_pose(self.eye, self.target, self.up)
        camera = Camera(self.width, self.height, self.fx, self.fy, self.cx, self.cy, self.near, far)
        return camera, check_pose(self.pose)


class NoiseBody(Body):
    """``noise``: Gaussian noise of range and direction (the engine checks the bounds)."""

    range_sigma: Finite = 0.0
    range_sigma_per_m: Finite = 0.0
    angle_sigma_deg: Finite = 0.0
    seed: Integer = 0


class DropoutBody(Body):
    """``dropout``: points lost below an intensity and at a rate (the engine checks the bounds)."""

    rate: Finite = 0.0
    min_intensity: Finite = 0.0
    seed: Integer = 0


Elevation = Annotated[float, Field(strict=True, ge=-90, le=90, allow_inf_nan=False)]
Elevations = Annotated[list[Elevation], Field(min_length=1, max_length=MAX_BEAMS)]
#: The lidar options passed to the engine's ``Lidar`` as they are (it checks their bounds).
PHYSICS_KEYS = (
    "beam_divergence_deg",
    "beam_samples",
    "range_resolution",
    "attenuation",
    "non_hits",
    "organized",
)


class LidarRequest(Body):
    """``POST /lidar``: a sensor pose, a beam pattern (``model``, ``vertical_angles_deg`` or an
    uploaded ``pattern``), the rays per revolution, the range window, the returns and the physics
    of API.md "Lidar physics"."""

    pose: Matrix4
    model: Literal[tuple(MODELS)] | None = None
    vertical_angles_deg: Elevations | None = None
    pattern: Name | None = None
    horizontal_steps: Pixels = 1024
    min_range: NonNegative = 0.0
    max_range: Positive | None = None
    max_returns: Annotated[int, Field(strict=True, ge=1, le=MAX_RETURNS)] = 1
    return_mode: Literal[RETURN_MODES] | None = None
    beam_divergence_deg: Finite = 0.0
    beam_samples: Integer = 1
    range_resolution: Finite = 0.1
    attenuation: Finite = 0.004
    noise: NoiseBody | None = None
    dropout: DropoutBody | None = None
    non_hits: Literal[NON_HITS] = "drop"
    organized: bool = Field(False, strict=True)
    period_s: Positive | None = None  #: the sweep's duration: its columns fire over it (motion)
    pose_end: Matrix4 | None = None  #: the sensor's pose at the sweep's end (needs period_s)
    #: what xyz (and velocity) are in: the scene, or the sensor's frame at the sweep's start
    frame: Literal[FRAMES] = "scene"

    @model_validator(mode="after")
    def _one_pattern(self) -> LidarRequest:
        if self.pose_end is not None and self.period_s is None:
            raise ValueError("pose_end needs period_s (the sweep's duration in seconds)")
        given = [self.model, self.vertical_angles_deg, self.pattern]
        if sum(value is not None for value in given) != 1:
            raise ValueError(
                "give exactly one beam pattern: model (one of "
                f"{', '.join(MODELS)}), vertical_angles_deg (a list of elevations in degrees) "
                "or pattern (the name of an uploaded pattern)"
            )
        if self.max_range is not None and self.max_range <= self.min_range:
            raise ValueError(
                f"max_range ({self.max_range}) must be greater than min_range ({self.min_range})"
            )
        return self

    def sensor(self, patterns: Callable[[str], Pattern]) -> tuple[Lidar, np.ndarray]:
        """(the engine's lidar, its sensor-to-scene pose); ``patterns`` gives the uploaded
        pattern of a name. Without ``return_mode``, ``max_returns`` > 1 means ``all`` (every
        surface the beam crosses), as in process."""
        lidar = Lidar(
            model=self.model,
            vertical_angles_deg=self.vertical_angles_deg,
            pattern=None if self.pattern is None else patterns(self.pattern),
            horizontal_steps=self.horizontal_steps,
            min_range=self.min_range,
            max_range=self.max_range,
            max_returns=self.max_returns,
            return_mode=self.return_mode,
            noise=None if self.noise is None else self.noise.model_dump(),
            dropout=None if self.dropout is None else self.dropout.model_dump(),
            **{key: getattr(self, key) for key in PHYSICS_KEYS},
            period_s=self.period_s,
            frame=self.frame,
        )
        return lidar, check_pose(self.pose)

    def end_pose(self) -> np.ndarray | None:
        """The sensor's pose at the sweep's end (None: it stays at ``pose``); CameraError (422)
        naming ``pose_end`` when it is not rigid."""
        return None if self.pose_end is None else check_pose(self.pose_end, "pose_end")


class LidarInRig(LidarRequest):
    kind: Literal["lidar"]


class CameraInRig(CameraRequest):
    kind: Literal["camera"]


class SensorsRequest(Body):
    """``POST /sensors``: a rig, named sensors each with the body of ``/lidar`` or ``/camera``
    and its ``kind``."""

    sensors: Annotated[
        dict[Name, Annotated[LidarInRig | CameraInRig, Discriminator("kind")]],
        Field(min_length=1),
    ]


Model = TypeVar("Model", bound=Body)

#: Error types that mean the body has the wrong keys (400) rather than wrong values (422): a key
#: missing or unknown at any depth, or a rig's sensor without its ``kind``.
_KEY_ERRORS = ("missing", UNKNOWN_KEYS, "union_tag_not_found")


def parse(
    model: type[Model], body: wire.Buffer, what: str, max_sensors: int | None = None
) -> Model:
    """``body`` (JSON) as ``model``: 400 if it is not a JSON object or has wrong keys, 422 naming
    the bad values (a rig's: those of its first wrong sensor); 413 for a rig of more than
    ``max_sensors`` sensors, before they are read."""
    keys = ", ".join(model.model_fields)
    doc = wire.read_json(body, f"keys {keys}")
    if max_sensors is not None:
        check_rig_size(doc, max_sensors)
    try:
        value = validate_rig(doc) if model is SensorsRequest else model.model_validate(doc)
    except ValidationError as error:
        errors = error.errors(include_url=False, include_input=False)
        wrong_keys = [e for e in errors if e["type"] in _KEY_ERRORS]
        if wrong_keys:
            raise BadBody(f"{what}: {describe(wrong_keys)}; the body's keys are {keys}") from None
        raise Invalid(f"{what}: {describe(errors)}") from None
    cameras = {"": value} if isinstance(value, CameraRequest) else {}
    if isinstance(value, SensorsRequest):
        sensors = value.sensors.items()
        cameras = {f"sensors.{name}: ": s for name, s in sensors if s.kind == "camera"}
    for where, camera in cameras.items():
        missing = camera.missing()
        if missing:
            raise BadBody(
                f"{what}: {where}the camera lacks {', '.join(missing)}; the body's keys are {keys}"
            )
    return value


def validate_rig(doc: dict[str, Any]) -> SensorsRequest:
    """``doc`` as a rig, its sensors validated one by one: the ValidationError of the first wrong
    sensor only (the whole rig's at once would hold every sensor's errors)."""
    sensors = doc.get("sensors")
    if not isinstance(sensors, dict) or not sensors:
        return SensorsRequest.model_validate(doc)
    others = {key: value for key, value in doc.items() if key != "sensors"}
    checked = {}
    for name, sensor in sensors.items():
        checked |= SensorsRequest.model_validate({**others, "sensors": {name: sensor}}).sensors
    # each sensor is checked above: the rig holds them as they are
    return SensorsRequest.model_construct(sensors=checked)


def check_rig_size(doc, max_sensors: int) -> None:
    """413 for a rig body whose ``sensors`` object holds more than ``max_sensors`` entries."""
    sensors = doc.get("sensors") if isinstance(doc, dict) else None
    if isinstance(sensors, dict) and len(sensors) > max_sensors:
        raise TooLarge(
            f"sensors: {len(sensors)} sensors is over the limit of {max_sensors} sensors per "
            "rig (DACRT_MAX_RIG_SENSORS)"
        )


#: What a rig's sensor name may be, for a 422.
NAME_RULE = "1-64 characters of A-Z a-z 0-9 _ - ."


def describe(errors: list[dict]) -> str:
    """The first SHOWN_ERRORS pydantic errors, a clause each (``pose[3][0]: Input should be a
    finite number``; a rig's ``sensors.NAME.KEY``, without the tag of its kind), and the count of
    the others."""
    clauses = [clause for error in errors for clause in error_clauses(error)]
    total = sum(error["ctx"]["count"] if error["type"] == UNKNOWN_KEYS else 1 for error in errors)
    shown = "; ".join(clauses[:SHOWN_ERRORS])
    hidden = total - min(len(clauses), SHOWN_ERRORS)
    return f"{shown}; and {hidden:,} more" if hidden else shown


def error_clauses(error: dict) -> list[str]:
    """The clauses of one pydantic error: one, or one per unknown key it names."""
    loc = list(error["loc"])
    if loc[:1] == ["sensors"] and len(loc) == 3 and loc[2] == "[key]":
        return [f"sensor name {wire.quoted(loc[1])} must be {NAME_RULE}"]
    if loc[:1] == ["sensors"] and len(loc) >= 3 and loc[2] in ("lidar", "camera"):
        del loc[2]  # the discriminator's tag, which the body does not name
    if error["type"] == UNKNOWN_KEYS:
        return [f"{key_path([*loc, key])}: unknown key" for key in error["ctx"]["keys"]]
    path = key_path(loc)
    message = error["msg"].removeprefix("Value error, ")
    if error["type"] == "missing":
        message = "missing"
    elif error["type"] == "union_tag_not_found":  # a rig's sensor without its kind
        message = "missing kind ('lidar' or 'camera')"
    elif error["type"] == "union_tag_invalid":
        message = f"kind {wire.quoted(str(error['ctx']['tag']))} is not 'lidar' or 'camera'"
    return [f"{path}: {message}" if path else message]


def key_path(loc: list) -> str:
    """``pose[3][0]``, ``sensors.roof.noise.seed``: a key of a body's own, however long, is
    cut (``wire.quoted``)."""
    parts = (f"[{p}]" if isinstance(p, int) else f".{short_key(p)}" for p in loc)
    return "".join(parts).removeprefix(".")


def short_key(key: str) -> str:
    """A key as a message names it: past 80 characters, its start and its length."""
    return key if len(key) <= 80 else wire.quoted(key)
