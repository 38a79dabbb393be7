"""Sensors traced on a scene version: pictures (``/render``), depth images (``/camera``) and lidar
revolutions (``/lidar``).

The rays come from ``cameras`` and ``lidar``; they are traced by ``tracing.trace`` (the same
engine scene, built once per scene version, and the same stable mesh indices as ``/closest``).
"""

from __future__ import annotations

import time

import numpy as np

from . import shading, tracing
from .cameras import Pinhole
from .lidar import Scan, points
from .options import Options, Query
from .store import Snapshot
from .tracing import TraceResult
from .wire import Rays


def _closest(snapshot: Snapshot, origins, directions, tmin, tmax, options: Options) -> TraceResult:
    rays = Rays(origins, directions, tmin, tmax)
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


def lidar_scan(snapshot: Snapshot, scan: Scan, max_returns: int, options: Options) -> TraceResult:
    """The points of one revolution: the first ``max_returns`` hits of each ray in
    ``[min_range, max_range]``, in ray order, nearest first. One return is ``closest``'s hit; more
    are ``Scene.hits``' list, which counts a crossing of an edge shared by two triangles once."""
    start = time.perf_counter()
    origins, directions = scan.rays()
    if max_returns == 1:
        result = _closest(snapshot, origins, directions, scan.min_range, scan.max_range, options)
        ray = np.flatnonzero(np.isfinite(result.arrays["t"])).astype(np.int32)
        hits = {name: result.arrays[name][ray] for name in ("t", "mesh", "prim", "normal")}
        returns = np.zeros(len(ray), np.int16)
        version, stats = result.version, result.stats
    else:
        hits, stats = _hit_list(snapshot, origins, directions, scan, max_returns, options)
        offsets = hits["offsets"]
        counts = np.diff(offsets)
        ray = np.repeat(np.arange(len(origins), dtype=np.int32), counts)
        returns = (np.arange(len(ray)) - np.repeat(offsets[:-1], counts)).astype(np.int16)
        version = snapshot.version
    per_point = points(scan, origins, directions, ray, hits["t"], hits["normal"])
    per_point.update({"mesh": hits["mesh"], "prim": hits["prim"], "return": returns, "ray": ray})
    arrays = options.pick(per_point.__getitem__)
    seconds = time.perf_counter() - start
    return TraceResult(arrays, version, stats, seconds, len(origins))


def _hit_list(snapshot, origins, directions, scan: Scan, max_hits: int, options: Options):
    """Every hit of the scan's rays within its range window, at most ``max_hits`` a ray, as the
    ``/hits`` query answers it: (arrays offsets, t, mesh, prim, normal; stats or None)."""
    rays = Rays(origins, directions, scan.min_range, scan.max_range)
    result = tracing.trace(snapshot, rays, options.traced_as(Query.HITS, max_hits))
    return result.arrays, result.stats
