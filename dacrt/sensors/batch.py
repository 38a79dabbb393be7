"""Sensors traced as one batch: the rays of every sensor concatenated into one ``Scene.closest``
call (and one ``Scene.hits`` call for sensors that see through surfaces), the answers split back
per sensor. A sensor alone is a batch of one; a ray's answer does not depend on the other rays of
its batch, so a sensor answers the same alone and in a rig."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ..chunks import N_CORES, map_on_threads
from ..validation import InputError, check_threads
from .physics import Materials, options

#: The keywords a sensor passes on to ``Scene.closest`` and ``Scene.hits``; the rays, their
#: windows and times are the sensor's own.
QUERY_KEYS = ("threads", "strategy", "stats", "mask", "cull", "device")


@dataclass(frozen=True)
class Rays:
    """One sensor's rays and how to trace them."""

    origins: np.ndarray  #: (n, 3) float32
    directions: np.ndarray  #: (n, 3) float32
    tmin: float
    tmax: float
    max_hits: int | None = None  #: None: each ray's closest hit; else its first max_hits hits
    time: np.ndarray | None = None  #: (n,) float32 in [0, 1]: each ray's instant (None: 0)


@dataclass(frozen=True)
class Traced:
    """One sensor's hits. For closest: one entry per ray (t inf, mesh and prim -1 on a miss) and
    ``offsets`` None; for hits: ray i's hits are entries offsets[i]:offsets[i + 1], nearest
    first."""

    t: np.ndarray  #: float32
    mesh: np.ndarray  #: int32
    prim: np.ndarray  #: int32
    normal: np.ndarray  #: (., 3) float32, unit
    offsets: np.ndarray | None  #: (n + 1,) int64 for hits
    stats: dict | None  #: the counters of the call that traced these rays (shared in a batch)
    #: (., 3) float64: how fast each hit point moves, scene units per interval (``Scene.motion``),
    #: when the rays carry times; else None
    motion: np.ndarray | None = None


@dataclass(frozen=True)
class Shot:
    """A sensor at a pose, ready to trace: its rays, and what makes its answer of their hits and
    the scene's materials."""

    rays: Rays
    finish: Callable[[Traced, Any], Any]


def capture(scene, shots: list[Shot], materials: Materials | dict | None, **query) -> list:
    """Every shot's answer, its rays traced in one batch (``trace``); ``materials`` (None for
    the defaults, or a dict of Materials' keys) are those of ``scene``'s meshes. The shots'
    answers are made side by side on the query's threads (NumPy's gathers and arithmetic let go
    of the GIL). InputError names a ``query`` key other than QUERY_KEYS."""
    check_query(query)
    per_mesh = (options(materials, Materials, "materials") or Materials()).per_mesh(scene.n_meshes)
    traced = trace(scene, [shot.rays for shot in shots], **query)
    return map_on_threads(
        lambda k: shots[k].finish(traced[k], per_mesh), len(shots), workers(len(shots), query)
    )


def batch_stats(answers) -> dict | None:
    """The counters of a batch's whole trace (``stats=True``) from its sensors' answers (their
    ``stats``): its ``Scene.closest`` call's and its ``Scene.hits`` call's, each shared by the
    sensors it traced, added up (the scene's triangles once, the deepest max_depth); None
    without stats."""
    calls = list({id(a.stats): a.stats for a in answers if a.stats is not None}.values())
    if not calls:
        return None
    total = dict(calls[0])
    for counters in calls[1:]:
        for name, value in counters.items():
            if name == "max_depth":
                total[name] = max(total[name], value)
            elif name != "triangles":
                total[name] += value
    return total


def check_query(query: dict) -> None:
    for key in query:
        if key not in QUERY_KEYS:
            raise InputError(
                f"{key} is not a query option of a sensor; its options are "
                f"{', '.join(QUERY_KEYS)} (a sensor makes its own rays, windows and times)"
            )


def workers(n_sensors, query) -> int:
    """Threads for work done sensor by sensor: the query's ``threads`` (checked: InputError
    naming it), at most one a sensor."""
    return min(n_sensors, check_threads(query.get("threads"), N_CORES))


def trace(scene, batch: list[Rays], **query) -> list[Traced]:
    """Every sensor's hits, in ``batch`` order; ``query`` goes to ``Scene.closest`` and
    ``Scene.hits`` (strategy, threads, cull, mask, stats)."""
    answers: list[Traced | None] = [None] * len(batch)
    closest = [k for k, rays in enumerate(batch) if rays.max_hits is None]
    seeing_through = [k for k, rays in enumerate(batch) if rays.max_hits is not None]
    if closest:
        _trace_closest(scene, batch, closest, answers, query)
    if seeing_through:
        _trace_hits(scene, batch, seeing_through, answers, query)
    return answers


def _joined(scene_rays: list[Rays]):
    """(origins, directions, tmin, tmax, time, bounds): the rays end to end, each window a
    scalar when every sensor has the same one, else per ray, and their times (None when no
    sensor's rays carry any, else 0 for those that do not); sensor k's rays are
    bounds[k]:bounds[k + 1]."""
    bounds = np.cumsum([0] + [len(rays.origins) for rays in scene_rays])
    origins = np.concatenate([rays.origins for rays in scene_rays])
    directions = np.concatenate([rays.directions for rays in scene_rays])
    windows = {(rays.tmin, rays.tmax) for rays in scene_rays}
    if len(windows) == 1:  # the bounds round to the nearest float32, as per ray
        tmin, tmax = (np.float32(bound) for bound in windows.pop())
    else:
        counts = np.diff(bounds)
        tmin = np.repeat([rays.tmin for rays in scene_rays], counts).astype(np.float32)
        tmax = np.repeat([rays.tmax for rays in scene_rays], counts).astype(np.float32)
    time = None
    if any(rays.time is not None for rays in scene_rays):
        time = np.concatenate(
            [
                np.zeros(len(rays.origins), np.float32) if rays.time is None else rays.time
                for rays in scene_rays
            ]
        )
    return origins, directions, tmin, tmax, time, bounds


class HitsAt(NamedTuple):
    """Hits' t, mesh, prim, u and v (``Hits`` or ``HitList``), those of some rays."""

    t: np.ndarray
    mesh: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @classmethod
    def of(cls, hits, rows=slice(None)):
        return cls(*(getattr(hits, name)[rows] for name in cls._fields))


def _motion(scene, origins, directions, time, ray, hits):
    """How fast the hit points move (``Traced.motion``), or None without times; ``hits`` holds
    the rays' t, mesh, prim, u and v."""
    if time is None:
        return None
    t = hits.t
    points = origins[ray].astype(np.float64) + t[:, None] * directions[ray].astype(np.float64)
    return scene.motion(hits.mesh, points, time[ray], prim=hits.prim, u=hits.u, v=hits.v)


def _trace_closest(scene, batch, chosen, answers, query) -> None:
    origins, directions, tmin, tmax, time, bounds = _joined([batch[k] for k in chosen])
    hits = scene.closest(origins, directions, tmin, tmax, time=time, **query)
    motion = None
    if time is not None:  # one row per ray, zero where it missed
        rays = np.flatnonzero(np.isfinite(hits.t))
        motion = np.zeros((len(origins), 3))
        motion[rays] = _motion(scene, origins, directions, time, rays, HitsAt.of(hits, rays))
    for k, lo, hi in zip(chosen, bounds[:-1], bounds[1:]):
        part = slice(lo, hi)
        answers[k] = Traced(
            hits.t[part], hits.mesh[part], hits.prim[part], hits.normal[part], None, hits.stats,
            None if motion is None else motion[part],
        )  # fmt: skip


def _trace_hits(scene, batch, chosen, answers, query) -> None:
    origins, directions, tmin, tmax, time, bounds = _joined([batch[k] for k in chosen])
    largest = max(batch[k].max_hits for k in chosen)
    every = scene.hits(origins, directions, tmin, tmax, max_hits=largest, time=time, **query)
    ray = np.repeat(np.arange(len(origins)), np.diff(every.offsets))
    motion = _motion(scene, origins, directions, time, ray, HitsAt.of(every))
    for k, lo, hi in zip(chosen, bounds[:-1], bounds[1:]):
        # a sensor keeps each ray's nearest max_hits of the (nearest first) list
        counts = np.minimum(np.diff(every.offsets[lo : hi + 1]), batch[k].max_hits)
        first = np.repeat(every.offsets[lo:hi], counts)
        rank = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        rows = first + rank
        offsets = np.zeros(hi - lo + 1, np.int64)
        np.cumsum(counts, out=offsets[1:])
        answers[k] = Traced(
            every.t[rows], every.mesh[rows], every.prim[rows], every.normal[rows], offsets,
            every.stats, None if motion is None else motion[rows],
        )  # fmt: skip
