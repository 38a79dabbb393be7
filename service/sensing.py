"""Sensors traced on a scene version: pictures (``/render``), depth images (``/camera``) and lidar
revolutions (``/lidar``).

The rays come from ``cameras`` and ``lidar``; they are traced by ``tracing.trace`` (the same
engine scene, built once per scene version, and the same stable mesh indices as ``/closest``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import shading, tracing
from .cameras import Pinhole
from .errors import Invalid
from .lidar import Scan, points
from .store import Snapshot
from .tracing import Query
from .wire import Rays

#: The arrays of a ``/camera`` answer, each (height, width) (normal: (height, width, 3)).
CAMERA_FIELDS = ("depth", "range", "mesh", "prim", "normal")
#: The arrays of a ``/lidar`` answer, one row per point.
LIDAR_FIELDS = (
    "xyz",
    "range",
    "ring",
    "azimuth",
    "elevation",
    "mesh",
    "prim",
    "return",
    "cos_incidence",
    "ray",
)
#: What the sensors ask of ``closest``.
_HIT_FIELDS = "t,mesh,prim,normal"


@dataclass(frozen=True)
class SensorOptions:
    """The query-string options of a sensor request."""

    fields: tuple[str, ...]  #: the answer arrays to send, in answer order
    strategy: str | None = None
    stats: bool = False
    threads: int | None = None
    cull: str = "none"

    def closest(self) -> tracing.Options:
        return tracing.make_options(
            Query.CLOSEST, _HIT_FIELDS, self.strategy, self.stats, self.threads, self.cull
        )

    def hits(self, max_hits: int) -> tracing.Options:
        return tracing.make_options(
            Query.HITS,
            _HIT_FIELDS,
            self.strategy,
            self.stats,
            self.threads,
            self.cull,
            max_hits=max_hits,
        )


def pick_fields(fields: str | None, known: tuple[str, ...], what: str) -> tuple[str, ...]:
    """``?fields=`` as a tuple in ``known``'s order (all of them if None); 422 naming the choices
    for an unknown or empty list."""
    if fields is None:
        return known
    names = [name.strip() for name in fields.split(",") if name.strip()]
    unknown = [name for name in names if name not in known]
    if unknown or not names:
        named = "unknown fields " + ", ".join(map(repr, unknown)) if unknown else "no field"
        raise Invalid(f"?fields={fields} names {named} for {what}; choose from {', '.join(known)}")
    return tuple(name for name in known if name in names)


@dataclass(frozen=True)
class SensorResult:
    """An answer's arrays (or picture), the scene version it was traced on, and what it cost."""

    arrays: dict[str, np.ndarray]
    version: int
    stats: dict[str, Any] | None
    seconds: float  #: engine build (if not cached) + trace + the answer's arithmetic
    n_rays: int
    headers: dict[str, str]
    where: str = "process"  #: sensors trace in process


def _closest(
    snapshot: Snapshot, origins, directions, tmin, tmax, options: SensorOptions
) -> tracing.TraceResult:
    return tracing.trace(snapshot, Rays(origins, directions, tmin, tmax), options.closest())


def render(
    snapshot: Snapshot, camera: Pinhole, style: str, options: SensorOptions
) -> tuple[np.ndarray, SensorResult]:
    """The pixels of ``camera``'s view in ``style`` (``shading``), and what they cost."""
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
    return pixels, SensorResult({}, result.version, result.stats, seconds, len(origins), headers)


def depth_camera(
    snapshot: Snapshot, camera: Pinhole, near: float, far: float, options: SensorOptions
) -> SensorResult:
    """``camera``'s depth image: ``depth`` (t of rays whose component along the optical axis is
    1), ``range`` (t |d|), ``mesh``, ``prim`` (-1 on a miss) and ``normal`` (0 on a miss), each of
    shape (height, width[, 3]), for ``near <= depth <= far``."""
    start = time.perf_counter()
    origins, directions = camera.rays()
    result = _closest(snapshot, origins, directions, near, far, options)
    shape = (camera.height, camera.width)
    t = result.arrays["t"]
    arrays = {}
    for name in options.fields:
        if name == "depth":
            arrays[name] = t.reshape(shape)
        elif name == "range":
            length = np.linalg.norm(directions.astype(np.float64), axis=1)
            arrays[name] = (t * length).astype(np.float32).reshape(shape)
        elif name == "normal":
            arrays[name] = result.arrays["normal"].reshape(*shape, 3)
        else:
            arrays[name] = result.arrays[name].reshape(shape)
    seconds = time.perf_counter() - start
    return SensorResult(arrays, result.version, result.stats, seconds, len(origins), {})


def lidar_scan(
    snapshot: Snapshot, scan: Scan, max_returns: int, options: SensorOptions
) -> SensorResult:
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
    arrays = {name: per_point[name] for name in options.fields}
    seconds = time.perf_counter() - start
    return SensorResult(arrays, version, stats, seconds, len(origins), {})


def _hit_list(snapshot, origins, directions, scan: Scan, max_hits: int, options: SensorOptions):
    """Every hit of the scan's rays within its range window, at most ``max_hits`` a ray, as the
    ``/hits`` query answers it: (arrays offsets, t, mesh, prim, normal; stats or None)."""
    hits = options.hits(max_hits)
    result = tracing.trace(
        snapshot, Rays(origins, directions, scan.min_range, scan.max_range), hits
    )
    return result.arrays, result.stats
