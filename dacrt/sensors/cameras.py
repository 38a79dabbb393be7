"""Pinhole cameras: one ray per pixel (docs/sensors.md, "Cameras"), and ``Camera``, the depth
camera in process.

Conventions:

- An image is row-major: pixel (row i, column j), (0, 0) at the top-left; its ray is number
  ``i * width + j`` of the batch.
- The camera frame is OpenCV's: x right, y down, z forward. Pixel (i, j) looks along
  ``((j - cx) / fx, (i - cy) / fy, 1)`` in that frame: OpenCV's pixel coordinates (u, v) = (j, i)
  put integer coordinates at pixel centres.
- ``pose`` (4, 4, row-major) maps the camera frame to the scene: the rays start at ``pose[:3, 3]``
  and a camera-frame direction ``(x, y, 1)`` becomes ``x * R[:, 0] + (y * R[:, 1] + R[:, 2])``
  with ``R = pose[:3, :3]``, computed in float64 and rounded to float32. Its component along the
  optical axis is 1, so a hit's ``t`` is its depth: the distance along the camera's z axis.
- A look-at camera (``eye``, ``target``, ``up``, ``fov_deg``: the vertical field of view) is the
  pinhole with ``fx = fy = (height / 2) / tan(fov_deg / 2)``, ``cx = (width - 1) / 2``,
  ``cy = (height - 1) / 2`` at ``eye``, with z along ``target - eye``, x along ``z x up`` and
  y = z x x (down in the picture).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..contracts import MISS
from ..validation import InputError, check_row_count
from .batch import Rays, Shot, Traced, capture
from .checks import FLOAT32_MAX, float_array, integer, number

#: |sin| of the angle between up and the view direction below which they count as parallel.
PARALLEL_SINE = 1e-6
#: Largest |R^T R - I| entry of a pose whose rotation counts as orthonormal (float32 input).
ROTATION_TOLERANCE = 1e-4
#: The most pixels a side: a pixel's ray is an int32 index.
MAX_SIDE = 2**31 - 1


class CameraError(InputError):
    """A camera or pose that cannot make an image (the message names the problem): an
    InputError, so the service answers 422."""


@dataclass(frozen=True)
class Pinhole:
    """A pinhole camera in the OpenCV convention (module docstring)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    pose: np.ndarray  #: (4, 4) float64 camera-to-scene, rigid

    @property
    def n_pixels(self) -> int:
        return self.width * self.height

    @property
    def origin(self) -> np.ndarray:
        """(3,) float64: where every ray starts."""
        return self.pose[:3, 3]

    @property
    def forward(self) -> np.ndarray:
        """(3,) float64 unit vector: the optical axis (camera z) in the scene."""
        return self.pose[:3, 2]

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """(origins, directions), each (height * width, 3) float32 C-contiguous, row-major pixels;
        each direction's component along ``forward`` is 1 (before rounding to float32)."""
        x = (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx
        y = (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
        rotation = self.pose[:3, :3]
        # a column's part and a row's part, added in float64 and rounded once to float32
        column = x[:, None] * rotation[:, 0]
        row = y[:, None] * rotation[:, 1] + rotation[:, 2]
        directions = np.empty((self.height, self.width, 3), np.float32)
        with np.errstate(over="ignore"):  # beyond float32 is inf, which the camera refuses
            np.add(column[None, :, :], row[:, None, :], out=directions, casting="same_kind")
        directions = directions.reshape(-1, 3)
        origins = np.tile(self.origin.astype(np.float32), (len(directions), 1))
        return origins, directions


def look_at(eye, target, up, fov_deg: float, width: int, height: int) -> Pinhole:
    """The pinhole of a look-at camera; CameraError if eye == target or up is zero or parallel to
    the view direction, or the field of view is not in (0, 180) degrees."""
    check_fov(fov_deg)
    pose = look_at_pose(eye, target, up)
    focal = fov_focal(fov_deg, height)
    return Pinhole(width, height, focal, focal, (width - 1) / 2, (height - 1) / 2, pose)


def check_fov(fov_deg: float) -> None:
    if not 0 < fov_deg < 180:
        raise CameraError(f"fov_deg must be between 0 and 180 degrees, got {fov_deg}")


def look_at_pose(eye, target, up) -> np.ndarray:
    """(4, 4) float64: the camera-to-scene pose at ``eye`` with z along ``target - eye``, x along
    ``z x up`` and y = z x x; CameraError if eye == target or up is zero or parallel to the view."""
    eye, target, up = (
        float_array(value, key, (3,), CameraError)
        for value, key in ((eye, "eye"), (target, "target"), (up, "up"))
    )
    with np.errstate(over="ignore"):
        view = target - eye
    if not np.isfinite(view).all():
        raise CameraError(
            f"eye {eye.tolist()} and target {target.tolist()} are too far apart: target - eye "
            "is beyond float64"
        )
    if not view.any():
        raise CameraError(
            f"eye and target are the same point {eye.tolist()}: the camera looks nowhere"
        )
    forward = _unit(view)
    if not up.any():
        raise CameraError("up is the zero vector; give the direction that is up in the picture")
    side = np.cross(forward, _unit(up))
    sine = np.linalg.norm(side)
    if sine < PARALLEL_SINE:
        raise CameraError(
            f"up {up.tolist()} is parallel to the view direction target - eye "
            f"{view.tolist()}; give an up that is not"
        )
    right = side / sine
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, forward, eye
    return pose


def _unit(vector: np.ndarray) -> np.ndarray:
    """``vector`` (finite, not zero) over its length, scaled first where the length overflows
    or underflows."""
    with np.errstate(over="ignore", under="ignore"):
        length = np.linalg.norm(vector)
    if not 0 < length < np.inf:
        vector = vector / np.abs(vector).max()
        length = np.linalg.norm(vector)
    return vector / length


def fov_focal(fov_deg: float, height: int) -> float:
    """``(height / 2) / tan(fov_deg / 2)``, the focal length in pixels of a vertical field of
    view; CameraError when it is not finite."""
    tangent = math.tan(math.radians(fov_deg) / 2)  # 0 for a subnormal fov_deg
    focal = (height / 2) / tangent if tangent > 0 else math.inf
    if not math.isfinite(focal):
        raise CameraError(
            f"fov_deg: {fov_deg!r} is too small: the focal length (height / 2) / tan(fov_deg / 2) "
            "is not a finite number"
        )
    return focal


def check_pose(matrix, name: str = "pose") -> np.ndarray:
    """A rigid 4x4 camera- or sensor-to-scene matrix as (4, 4) float64; CameraError naming what is
    wrong: shape, non-finite entries, a last row other than [0, 0, 0, 1], or a 3x3 part that is
    not a rotation (orthonormal within ROTATION_TOLERANCE, determinant +1)."""
    pose = float_array(matrix, name, (4, 4), CameraError)
    if not np.array_equal(pose[3], [0, 0, 0, 1]):
        raise CameraError(f"{name}'s last row must be [0, 0, 0, 1], got {pose[3].tolist()}")
    rotation = pose[:3, :3]
    error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if error > ROTATION_TOLERANCE or np.linalg.det(rotation) <= 0:
        raise CameraError(
            f"{name}[:3, :3] must be a rotation (orthonormal columns, determinant +1): "
            f"R^T R differs from the identity by up to {error:.3g} and det R is "
            f"{np.linalg.det(rotation):.3g}"
        )
    return pose


#: The arrays of a camera's answer, each (height, width); normal (height, width, 3).
CAMERA_FIELDS = ("depth", "range", "mesh", "prim", "normal")


def edge_slope(focal: float, centre: float, pixels: int) -> float:
    """The largest ``|k - centre| / focal`` over the pixel coordinates k of ``pixels``: the
    camera-frame slope of the outermost rays (float64; inf when it overflows)."""
    with np.errstate(over="ignore"):
        return float(np.float64(max(abs(centre), abs(pixels - 1 - centre))) / np.float64(focal))


@dataclass(frozen=True)
class Camera:
    """A depth camera: an OpenCV pinhole's intrinsics (pixels) and the depths it sees,
    ``near <= depth <= far``; placed by a pose when it captures (module docstring).

    ``Camera(640, 480, fx=500, fy=500, cx=319.5, cy=239.5).capture(scene, pose)``, or for a
    look-at camera ``Camera.from_fov(640, 480, fov_deg=45).capture(scene, look_at_pose(eye,
    target, up))``. Bad values raise InputError naming the key (``fx must be > 0, got -1.0``).
    ``near`` is at most float32's largest; a ``far`` beyond it is no limit (the rays' depth
    window is float32, as a lidar's range window is).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    near: float = 0.0
    far: float = math.inf

    def __post_init__(self) -> None:
        integer(self.width, "width", at_least=1, at_most=MAX_SIDE)
        integer(self.height, "height", at_least=1, at_most=MAX_SIDE)
        for key in ("fx", "fy"):
            number(getattr(self, key), key, above=0)
        for key in ("cx", "cy"):
            number(getattr(self, key), key)
        number(self.near, "near", at_least=0, at_most=FLOAT32_MAX)
        number(self.far, "far", above=self.near, infinite=True)
        if self.far > FLOAT32_MAX:  # the rays' windows are float32: beyond it is no limit
            object.__setattr__(self, "far", math.inf)
        x = edge_slope(self.fx, self.cx, self.width)
        y = edge_slope(self.fy, self.cy, self.height)
        # a direction x R[:, 0] + y R[:, 1] + R[:, 2] has components of at most |x| + |y| + 1
        if not x + y + 1 <= FLOAT32_MAX:
            raise self._edge_rays_error("")

    @property
    def n_traced_rays(self) -> int:
        """The rays one capture traces: one a pixel."""
        return self.width * self.height

    @classmethod
    def from_fov(
        cls, width: int, height: int, fov_deg: float = 60.0, near: float = 0.0, far=math.inf
    ) -> Camera:
        """The centred camera of a vertical field of view: ``fx = fy = (height / 2) /
        tan(fov_deg / 2)``, ``cx = (width - 1) / 2``, ``cy = (height - 1) / 2``."""
        integer(width, "width", at_least=1, at_most=MAX_SIDE)
        integer(height, "height", at_least=1, at_most=MAX_SIDE)
        check_fov(number(fov_deg, "fov_deg"))
        focal = fov_focal(fov_deg, height)
        return cls(width, height, focal, focal, (width - 1) / 2, (height - 1) / 2, near, far)

    def pinhole(self, pose) -> Pinhole:
        return Pinhole(
            self.width, self.height, self.fx, self.fy, self.cx, self.cy, check_pose(pose)
        )

    def shot(self, pose) -> Shot:
        """The camera at ``pose`` (4x4 camera-to-scene, rigid), ready to trace."""
        check_row_count(self.n_traced_rays, "an image (width x height)", "pixels")
        origins, directions = self.pinhole(pose).rays()
        # a rotation orthonormal within ROTATION_TOLERANCE may lengthen rays that just fit
        if not np.isfinite(directions).all():
            raise self._edge_rays_error(" at this pose")
        rays = Rays(origins, directions, self.near, self.far)
        return Shot(rays, lambda traced, _materials: self._image(directions, traced))

    def capture(self, scene, pose, **query) -> CameraImage:
        """What the camera at ``pose`` sees of ``scene`` (a ``dacrt.Scene``); ``query`` goes to
        ``Scene.closest`` (strategy, threads, cull, mask, stats)."""
        return capture(scene, [self.shot(pose)], None, **query)[0]

    def _edge_rays_error(self, where: str) -> InputError:
        """The error of edge rays beyond float32, naming the keys of the steeper of them."""
        x = edge_slope(self.fx, self.cx, self.width)
        y = edge_slope(self.fy, self.cy, self.height)
        key, centre_key = ("fx", "cx") if x >= y else ("fy", "cy")
        return InputError(
            f"{key}: {getattr(self, key)!r} is too small for {centre_key} "
            f"{getattr(self, centre_key)!r}{where}: the edge rays' slope is beyond the float32 "
            "range"
        )

    def _image(self, directions: np.ndarray, traced: Traced) -> CameraImage:
        shape = (self.height, self.width)
        length = np.linalg.norm(directions.astype(np.float64), axis=1)
        with np.errstate(over="ignore"):
            distance = (traced.t * length).astype(np.float32)
        t, mesh, prim, normal = traced.t, traced.mesh, traced.prim, traced.normal
        # a hit whose range is beyond float32 is a miss in every key, as one whose t is
        beyond = np.isinf(distance) & np.isfinite(t)
        if beyond.any():
            t = np.where(beyond, np.float32(np.inf), t)
            mesh = np.where(beyond, MISS, mesh)
            prim = np.where(beyond, MISS, prim)
            normal = np.where(beyond[:, None], np.float32(0), normal)
        arrays = {
            "depth": t.reshape(shape),
            "range": distance.reshape(shape),
            "mesh": mesh.reshape(shape),
            "prim": prim.reshape(shape),
            "normal": normal.reshape(*shape, 3),
        }
        return CameraImage(arrays, traced.stats)


@dataclass(frozen=True)
class CameraImage(Mapping):
    """A camera's answer: ``image["depth"]`` ... by the names of CAMERA_FIELDS, row 0 at the top.

    depth float32: distance along the optical axis (inf on a miss); range float32: along the ray;
    mesh, prim int32 (-1 on a miss); normal float32 (height, width, 3), unit, 0 on a miss. A hit
    whose range is beyond float32's range is a miss in every key."""

    arrays: dict[str, np.ndarray]
    stats: dict | None = None  #: the trace's counters when asked with stats=True

    def __getitem__(self, key: str) -> np.ndarray:
        return self.arrays[key]

    def __iter__(self):
        return iter(self.arrays)

    def __len__(self) -> int:
        return len(self.arrays)
