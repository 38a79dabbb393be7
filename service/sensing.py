"""Sensors traced on a scene version: pictures (``/render``), depth images (``/camera``) and lidar
revolutions (``/lidar``).

The rays come from ``cameras`` and ``lidar``; they are traced by ``tracing.trace`` (the same
engine scene, built once per scene version, and the same stable mesh indices as ``/closest``).
"""

from __future__ import annotations

import time

import numpy as np

from dacrt.sensors.motion import poses_at
from dacrt.sensors.physics import beam_directions

from . import shading, tracing
from .cameras import Pinhole
from .lidar import Scan, points
from .options import MOTION_FIELDS, Options, Query
from .sensor_requests import Motion
from .store import Snapshot
from .tracing import TraceResult
from .wire import Rays


def _closest(
    snapshot: Snapshot, origins, directions, tmin, tmax, options: Options, time=None
) -> TraceResult:
    rays = Rays(origins, directions, tmin, tmax, time=time)
    return tracing.trace(snapshot, rays, options.traced_as(Query.CLOSEST))


def render(snapshot: Snapshot, camera: Pinhole, style: str, options: Options) -> TraceResult:
    """The pixels of ``camera``'s view in ``style`` (``shading``), as the answer's ``pixels``."""
    start = time.perf_counter()
    origins, directions = camera.rays()
    result = _closest(snapshot, origins, directions, None, None, options)
    shape = (camera.height, camera.width)
    t = result.arrays["t"].reshape(shape)
    headers = {}
    if style == "depth":
        pixels, span = shading.depth_pixels(t)
        if span is not None:
            headers["X-Depth-Range"] = f"{span[0]!r} {span[1]!r}"
    elif style == "normal":
        pixels = shading.normal_pixels(t, result.arrays["normal"].reshape(*shape, 3))
    else:
        pixels = shading.shaded_pixels(
            t,
            result.arrays["mesh"].reshape(shape),
            result.arrays["normal"].reshape(*shape, 3),
            directions.reshape(*shape, 3),
        )
    seconds = time.perf_counter() - start
    return TraceResult(
        {"pixels": pixels}, result.version, result.stats, seconds, len(origins), headers=headers
    )


def depth_camera(
    snapshot: Snapshot, camera: Pinhole, near: float, far: float, options: Options
) -> TraceResult:
    """``camera``'s depth image: ``depth`` (t of rays whose component along the optical axis is
    1), ``range`` (t |d|), ``mesh``, ``prim`` (-1 on a miss) and ``normal`` (0 on a miss), each of
    shape (height, width[, 3]), for ``near <= depth <= far``."""
    start = time.perf_counter()
    origins, directions = camera.rays()
    result = _closest(snapshot, origins, directions, near, far, options)
    shape = (camera.height, camera.width)
    t = result.arrays["t"]

    def per_pixel(name: str) -> np.ndarray:
        if name == "depth":
            return t.reshape(shape)
        if name == "range":
            length = np.linalg.norm(directions.astype(np.float64), axis=1)
            return (t * length).astype(np.float32).reshape(shape)
        if name == "normal":
            return result.arrays["normal"].reshape(*shape, 3)
        return result.arrays[name].reshape(shape)

    arrays = options.pick(per_pixel)
    seconds = time.perf_counter() - start
    return TraceResult(arrays, result.version, result.stats, seconds, len(origins))


def lidar_scan(
    snapshot: Snapshot, scan: Scan, max_returns: int, options: Options, motion: Motion | None = None
) -> TraceResult:
    """The points of one revolution: the first ``max_returns`` hits of each ray in
    ``[min_range, max_range]``, in ray order, nearest first. One return is ``closest``'s hit; more
    are ``Scene.hits``' list, which counts a crossing of an edge shared by two triangles once.
    With ``motion`` column s fires at tau = s / steps of the sweep, from the sensor's pose at
    tau, into the scene at tau (docs/sensors.md, "Motion and skew")."""
    start = time.perf_counter()
    origins, directions = scan.rays()
    tau = None
    if motion is not None:
        step = np.tile(np.arange(scan.steps), scan.n_rings)
        tau = (step / scan.steps).astype(np.float32)
        if motion.pose_end is not None and not np.array_equal(scan.pose, motion.pose_end):
            poses = poses_at(scan.pose, motion.pose_end, tau)
            elevation, azimuth = scan.angles()
            ring = np.repeat(np.arange(scan.n_rings), scan.steps)
            origins = poses[:, :3, 3].astype(np.float32)
            directions = beam_directions(poses, azimuth[step], elevation[ring])
    if max_returns == 1:
        result = _closest(
            snapshot, origins, directions, scan.min_range, scan.max_range, options, tau
        )
        ray = np.flatnonzero(np.isfinite(result.arrays["t"])).astype(np.int32)
        hits = {name: result.arrays[name][ray] for name in ("t", "mesh", "prim", "normal")}
        returns = np.zeros(len(ray), np.int16)
        version, stats = result.version, result.stats
    else:
        hits, stats = _hit_list(snapshot, origins, directions, scan, max_returns, options, tau)
        offsets = hits["offsets"]
        counts = np.diff(offsets)
        ray = np.repeat(np.arange(len(origins), dtype=np.int32), counts)
        returns = (np.arange(len(ray)) - np.repeat(offsets[:-1], counts)).astype(np.int16)
        version = snapshot.version
    per_point = points(scan, origins, directions, ray, hits["t"], hits["normal"])
    per_point.update({"mesh": hits["mesh"], "prim": hits["prim"], "return": returns, "ray": ray})
    if motion is not None:
        # each point from where its beam started (a moving sensor's origin moves)
        per_point["xyz"] = origins[ray] + hits["t"][:, None] * directions[ray]
        per_point.update(_speeds(snapshot, motion, scan, origins, directions, ray, tau, hits))
    fields = (
        options.fields
        if motion is not None
        else (name for name in options.fields if name not in MOTION_FIELDS)
    )
    arrays = {name: per_point[name] for name in fields}
    seconds = time.perf_counter() - start
    return TraceResult(arrays, version, stats, seconds, len(origins))


def _speeds(snapshot, motion: Motion, scan: Scan, origins, directions, ray, tau, hits) -> dict:
    """A sweep's ``time`` (seconds), ``velocity`` (the hit surface's, scene units a second) and
    ``radial_speed`` ((surface - sensor velocity) along the unit beam, positive receding)."""
    engine = tracing.engine_of(snapshot)
    mesh = hits["mesh"]
    if engine.mesh_index is not None:  # stable indices back to the engine's positions
        position = np.full(int(engine.mesh_index.max()) + 2, -1, np.int64)
        position[engine.mesh_index[:-1]] = np.arange(len(engine.mesh_index) - 1)
        mesh = position[mesh]
    d = directions[ray].astype(np.float64)
    hit_points = origins[ray].astype(np.float64) + hits["t"][:, None].astype(np.float64) * d
    velocity = engine.scene.motion(mesh, hit_points, tau[ray]) / motion.period_s
    sensor = np.zeros(3)
    if motion.pose_end is not None:
        sensor = (motion.pose_end[:3, 3] - scan.pose[:3, 3]) / motion.period_s
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    radial = np.einsum("ij,ij->i", velocity - sensor, unit)
    return {
        "time": (tau[ray] * np.float32(motion.period_s)).astype(np.float32),
        "velocity": velocity.astype(np.float32),
        "radial_speed": radial.astype(np.float32),
    }


def _hit_list(
    snapshot, origins, directions, scan: Scan, max_hits: int, options: Options, time=None
):
    """Every hit of the scan's rays within its range window, at most ``max_hits`` a ray, as the
    ``/hits`` query answers it: (arrays offsets, t, mesh, prim, normal; stats or None)."""
    rays = Rays(origins, directions, scan.min_range, scan.max_range, time=time)
    result = tracing.trace(snapshot, rays, options.traced_as(Query.HITS, max_hits))
    return result.arrays, result.stats
