"""A scene and the rays of the sensors, built in plain numpy from the conventions that
docs/sensors.md states (nothing here imports the service's cameras or lidar code), for the tests
of /render, /camera, /lidar and the viewer."""

from __future__ import annotations

import io
import math

import numpy as np
import procedural
from PIL import Image

#: A z-up room: a floor, a sphere and a box, three meshes (indices 0, 1, 2 in upload order).
_GRID, _BALL = procedural.grid(8, 16.0), procedural.icosphere(2, 1.0)
FLOOR = (procedural.transform(_GRID[0], offset=(-8.0, -8.0, 0.0)), _GRID[1])
SPHERE = (procedural.transform(_BALL[0], offset=(3.0, 1.0, 1.0)), _BALL[1])
_CUBE_VERTICES = np.array(
    [[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32
)  # vertex 4x + 2y + z
_CUBE_FACES = np.array(
    [
        [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],  # x = 0, x = 1
        [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],  # y = 0, y = 1
        [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],  # z = 0, z = 1
    ],
    np.int32,
)  # fmt: skip
BOX = (procedural.transform(_CUBE_VERTICES * 1.5, offset=(-4.0, 2.0, 0.0)), _CUBE_FACES)
MESHES = {"floor": FLOOR, "sphere": SPHERE, "box": BOX}


def put_room(api, scene: str) -> None:
    """Upload MESHES to ``scene`` through ``service.client.Client`` ``api``."""
    for name, (vertices, faces) in MESHES.items():
        api.put_mesh(scene, name, vertices, faces)


def room_triangles() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, faces, mesh of each face) of MESHES merged, for ``reference``."""
    vertices, faces, mesh, offset = [], [], [], 0
    for index, (v, f) in enumerate(MESHES.values()):
        vertices.append(v), faces.append(f + offset), mesh.append(np.full(len(f), index))
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces), np.concatenate(mesh)


def look_at_rays(eye, target, up, fov_deg, width, height):
    """(origins, directions, forward) of a look-at camera: pixel (i, j) at row i from the top,
    ray i * width + j, direction x * right + (y * down + forward) with
    x = (j - (width - 1) / 2) / f,
    y = (i - (height - 1) / 2) / f, f = (height / 2) / tan(fov / 2), in float64, then float32."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, up / np.linalg.norm(up))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    f = (height / 2) / math.tan(math.radians(fov_deg) / 2)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, down, forward, eye
    origins, directions = pinhole_rays(f, f, (width - 1) / 2, (height - 1) / 2, pose, width, height)
    return origins, directions, forward


def pinhole_rays(fx, fy, cx, cy, pose, width, height):
    """(origins, directions) of an OpenCV pinhole with camera-to-scene ``pose``: camera-frame
    direction ((j - cx) / fx, (i - cy) / fy, 1), mapped as x R[:, 0] + (y R[:, 1] + R[:, 2])."""
    pose = np.asarray(pose, np.float64)
    rotation = pose[:3, :3]
    i, j = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    x = ((j - cx) / fx).reshape(-1, 1)
    y = ((i - cy) / fy).reshape(-1, 1)
    directions = (x * rotation[:, 0] + (y * rotation[:, 1] + rotation[:, 2])).astype(np.float32)
    origins = np.tile(pose[:3, 3], (len(directions), 1)).astype(np.float32)
    return origins, directions


def lidar_rays(pose, elevations_deg, steps):
    """(origins, directions, ring, azimuth, elevation) of one revolution: ray ring * steps + step
    along (cos e cos a, cos e sin a, sin e) in the sensor frame (x forward, y left, z up), e the
    ring's elevation (rings sorted from the lowest), a = 2 pi step / steps; in the scene
    cos e (cos a R[:, 0] + sin a R[:, 1]) + sin e R[:, 2], in float64, then float32."""
    pose = np.asarray(pose, np.float64)
    rotation = pose[:3, :3]
    elevation = np.radians(np.sort(np.asarray(elevations_deg, np.float64), kind="stable"))
    azimuth = 2 * np.pi * np.arange(steps) / steps
    ring = np.repeat(np.arange(len(elevation)), steps)
    e, a = elevation[ring], np.tile(azimuth, len(elevation))
    level = np.cos(a)[:, None] * rotation[:, 0] + np.sin(a)[:, None] * rotation[:, 1]
    directions = (np.cos(e)[:, None] * level + np.sin(e)[:, None] * rotation[:, 2]).astype(
        np.float32
    )
    origins = np.tile(pose[:3, 3], (len(directions), 1)).astype(np.float32)
    return origins, directions, ring, a, e


def rigid_pose(yaw_deg: float, pitch_deg: float, position) -> np.ndarray:
    """A 4x4 rigid pose: a rotation about z by yaw, then about the rotated y by pitch."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    rz = np.array(
        [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]]
    )
    ry = np.array(
        [[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0], [-math.sin(pitch), 0, math.cos(pitch)]]
    )
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rz @ ry, position
    return pose


def decode_png(content: bytes) -> Image.Image:
    """The PNG of an answer, fully read."""
    image = Image.open(io.BytesIO(content))
    image.load()
    assert image.format == "PNG"
    return image


def npz(content: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(content), allow_pickle=False) as archive:
        return {key: archive[key] for key in archive.files}
