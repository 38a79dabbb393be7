"""A sensor that moves during its sweep: its pose at time tau in [0, 1] between ``pose`` (the
sweep's start) and ``pose_end`` (its end), the translation linear and the rotation spherical-
linear (slerp of unit quaternions, the shorter way round). At tau 0 and 1 the poses are the
given ones exactly."""

from __future__ import annotations

import numpy as np


def quaternion(rotation: np.ndarray) -> np.ndarray:
    """(4,) float64 unit quaternion (w, x, y, z) of a 3x3 rotation (Shepperd's method: from the
    largest of the four diagonal combinations, for accuracy)."""
    r = rotation
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    candidates = [trace, r[0, 0], r[1, 1], r[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [s / 4, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, s / 4, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, s / 4, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, s / 4]
    q = np.array(q)
    return q / np.linalg.norm(q)


def rotations(q: np.ndarray) -> np.ndarray:
    """(n, 3, 3) float64 rotations of unit quaternions ``q`` (n, 4) (w, x, y, z)."""
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


# Below this angle between the quaternions slerp is linear interpolation (sin(angle) ~ 0).
SLERP_LINEAR_BELOW = 1e-6


def slerp(q0: np.ndarray, q1: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions from ``q0`` to ``q1`` (4,) at ``tau`` (n,), the shorter way."""
    dot = float(np.dot(q0, q1))
    if dot < 0:  # q and -q are one rotation: take the nearer
        q1, dot = -q1, -dot
    angle = np.arccos(min(dot, 1.0))
    tau = np.asarray(tau, np.float64)[:, None]
    if angle < SLERP_LINEAR_BELOW:
        q = (1 - tau) * q0 + tau * q1
    else:
        q = (np.sin((1 - tau) * angle) * q0 + np.sin(tau * angle) * q1) / np.sin(angle)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def poses_at(pose: np.ndarray, pose_end: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(n, 4, 4) float64: the sensor's pose at each of ``tau`` (n,) in [0, 1], from ``pose``
    to ``pose_end`` (rigid 4x4 each): translation linear, rotation slerp; exactly the given
    pose at 0 and 1."""
    tau = np.asarray(tau, np.float64)
    n = len(tau)
    poses = np.zeros((n, 4, 4))
    poses[:, 3, 3] = 1.0
    poses[:, :3, 3] = (1 - tau)[:, None] * pose[:3, 3] + tau[:, None] * pose_end[:3, 3]
    if np.array_equal(pose[:3, :3], pose_end[:3, :3]):
        poses[:, :3, :3] = pose[:3, :3]
    else:
        poses[:, :3, :3] = rotations(
            slerp(quaternion(pose[:3, :3]), quaternion(pose_end[:3, :3]), tau)
        )
    poses[tau == 0] = pose
    poses[tau == 1] = pose_end
    return poses
