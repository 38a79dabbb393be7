"""Pinhole cameras: one ray per pixel, for ``/render`` and ``/camera`` (docs/sensors.md).

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
from dataclasses import dataclass

import numpy as np

from dacrt import InputError

#: |sin| of the angle between up and the view direction below which they count as parallel.
PARALLEL_SINE = 1e-6
#: Largest |R^T R - I| entry of a pose whose rotation counts as orthonormal (float32 input).
ROTATION_TOLERANCE = 1e-4


class CameraError(InputError):
    """A camera that cannot make an image (the message names the problem): the engine's
    InputError, so a request's is 422 by ``errors``' one table."""


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
        np.add(column[None, :, :], row[:, None, :], out=directions, casting="same_kind")
        directions = directions.reshape(-1, 3)
        origins = np.tile(self.origin.astype(np.float32), (len(directions), 1))
        return origins, directions


def look_at(eye, target, up, fov_deg: float, width: int, height: int) -> Pinhole:
    """The pinhole of a look-at camera; CameraError if eye == target or up is zero or parallel to
    the view direction, or the field of view is not in (0, 180) degrees."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    if not 0 < fov_deg < 180:
        raise CameraError(f"fov_deg must be between 0 and 180 degrees, got {fov_deg}")
    view = target - eye
    length = np.linalg.norm(view)
    if length == 0 or not np.isfinite(length):
        raise CameraError(
            f"eye and target are the same point {eye.tolist()}: the camera looks nowhere"
        )
    forward = view / length
    up_length = np.linalg.norm(up)
    if up_length == 0:
        raise CameraError("up is the zero vector; give the direction that is up in the picture")
    side = np.cross(forward, up / up_length)
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
    tangent = math.tan(math.radians(fov_deg) / 2)  # 0 for a subnormal fov_deg
    focal = (height / 2) / tangent if tangent > 0 else math.inf
    if not math.isfinite(focal):
        raise CameraError(
            f"fov_deg: {fov_deg!r} is too small: the focal length (height / 2) / tan(fov_deg / 2) "
            "is not a finite number"
        )
    return Pinhole(width, height, focal, focal, (width - 1) / 2, (height - 1) / 2, pose)


def check_pose(matrix, name: str = "pose") -> np.ndarray:
    """A rigid 4x4 camera- or sensor-to-scene matrix as (4, 4) float64; CameraError naming what is
    wrong: shape, non-finite entries, a last row other than [0, 0, 0, 1], or a 3x3 part that is
    not a rotation (orthonormal within ROTATION_TOLERANCE, determinant +1)."""
    pose = np.asarray(matrix, dtype=np.float64)
    if pose.shape != (4, 4):
        raise CameraError(f"{name} must be 4x4 (row-major), got shape {pose.shape}")
    if not np.isfinite(pose).all():
        raise CameraError(f"{name} has non-finite entries")
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
