"""Queries: what can be asked of a scene, and how the dacrt engine answers it.

The only module that runs the engine's queries. It builds one ``dacrt.Scene`` per scene version
(cached in the snapshot), maps the engine's mesh positions to the meshes' stable indices, and
turns the engine's ``ValueError`` (bad rays, named by the engine) into a 422.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np

import dacrt

from .errors import Invalid
from .store import Snapshot
from .wire import MeshArrays, Rays


class Query(str, Enum):  # noqa: UP042 - StrEnum would change str() and format() of members
    """Kinds of query. Later: HITS (``/hits``) and COUNT (``/count``) join here."""

    CLOSEST = "closest"
    OCCLUDED = "occluded"


#: The answer keys of each query, in answer order; ``?fields=`` picks a subset.
FIELDS: dict[Query, tuple[str, ...]] = {
    Query.CLOSEST: ("t", "mesh", "prim", "u", "v", "normal"),
    Query.OCCLUDED: ("occluded",),
}


def strategies() -> tuple[str, ...]:
    """The engine's partitioning strategies; the first is the default."""
    return tuple(dacrt.STRATEGIES)


#: Face culling modes: the engine's (none, back, front).
CULL_MODES = tuple(dacrt.CULL_MODES)


@dataclass(frozen=True)
class Options:
    """Options of one query, for the whole batch. Later: ``max_hits``."""

    query: Query
    fields: tuple[str, ...]
    strategy: str
    stats: bool = False
    threads: int | None = None
    cull: str = "none"


def make_options(
    query: Query | str,
    fields: str | None = None,
    strategy: str | None = None,
    stats: bool = False,
    threads: int | None = None,
    cull: str = "none",
) -> Options:
    """Options from query-string values; 422 naming the choices for an unknown value."""
    try:
        query = Query(query)
    except ValueError:
        raise Invalid(
            f"unknown query {query!r}; choose from {', '.join(q.value for q in Query)}"
        ) from None
    known = FIELDS[query]
    chosen = known
    if fields is not None:
        names = [name.strip() for name in fields.split(",") if name.strip()]
        unknown = [name for name in names if name not in known]
        if unknown or not names:
            raise Invalid(
                f"?fields={fields} names "
                f"{'unknown fields ' + ', '.join(map(repr, unknown)) if unknown else 'no field'} "
                f"for {query.value}; choose from {', '.join(known)}"
            )
        chosen = tuple(name for name in known if name in names)
    if strategy is None:
        strategy = strategies()[0]
    elif strategy not in strategies():
        raise Invalid(f"unknown strategy {strategy!r}; choose from {', '.join(strategies())}")
    if cull not in CULL_MODES:
        raise Invalid(f"unknown cull {cull!r}; choose from {', '.join(CULL_MODES)}")
    return Options(query, chosen, strategy, stats, threads, cull)


@dataclass(frozen=True)
class EngineScene:
    """A built ``dacrt.Scene`` and, per engine mesh position, the stable mesh index."""

    scene: Any
    mesh_index: (
        np.ndarray | None
    )  #: (n_meshes + 1,) int32 ending in -1, or None if positions are indices

    def map_mesh(self, positions: np.ndarray) -> np.ndarray:
        """Engine mesh positions (-1 on a miss) -> stable indices (-1 on a miss)."""
        if self.mesh_index is None:
            return positions
        return self.mesh_index[positions]  # a miss (-1) picks the trailing -1


def build_engine_scene(meshes: Iterable[tuple]) -> EngineScene:
    """The engine scene of (index, vertices, faces[, mask[, transform]]) tuples (mask: uint32,
    default all ones; transform: (4, 4) or None, the identity); meshes without triangles are left
    out. Meshes may share arrays (instances): the engine places each by its own transform."""
    kept = [tuple(mesh) for mesh in meshes if len(mesh[2])]
    indices = np.array([mesh[0] for mesh in kept] + [-1], dtype=np.int32)
    masks = np.array([mesh[3] if len(mesh) > 3 else 0xFFFFFFFF for mesh in kept], np.uint32)
    transforms = [mesh[4] if len(mesh) > 4 else None for mesh in kept]
    try:
        scene = dacrt.Scene(
            [(mesh[1], mesh[2]) for mesh in kept],
            masks=None if (masks == 0xFFFFFFFF).all() else masks,
            transforms=None if all(t is None for t in transforms) else transforms,
        )
    except ValueError as exc:
        raise Invalid(str(exc)) from None
    identity = np.array_equal(indices[:-1], np.arange(len(kept)))
    return EngineScene(scene, None if identity else indices)


def _snapshot_engine(snapshot: Snapshot) -> EngineScene:
    return build_engine_scene(
        (m.index, m.vertices, m.faces, m.mask, m.transform) for m in snapshot.meshes.values()
    )


@dataclass(frozen=True)
class TraceResult:
    """The arrays of an answer, the scene version it was computed on, and what it cost."""

    arrays: dict[str, np.ndarray]
    version: int
    stats: dict[str, Any] | None
    seconds: float  #: engine build (if not cached) + trace


def trace(snapshot: Snapshot, rays: Rays, options: Options) -> TraceResult:
    """Answer a query on one scene version (the engine scene is built once per version)."""
    start = time.perf_counter()
    engine = snapshot.cached("dacrt", _snapshot_engine)
    return _run(engine, rays, options, snapshot.version, start)


def trace_once(mesh: MeshArrays, rays: Rays, options: Options) -> TraceResult:
    """Answer a query on a mesh sent with the rays (mesh index 0; version 0: no stored scene)."""
    start = time.perf_counter()
    engine = build_engine_scene([(0, mesh.vertices, mesh.faces)])
    return _run(engine, rays, options, 0, start)


def _run(
    engine: EngineScene, rays: Rays, options: Options, version: int, start: float
) -> TraceResult:
    kwargs = {
        "cull": options.cull,
        "strategy": options.strategy,
        "threads": options.threads,
        "stats": options.stats,
    }
    try:
        if options.query is Query.CLOSEST:
            hits = engine.scene.closest(
                rays.origins, rays.directions, rays.tmin, rays.tmax, **kwargs
            )
            stats = hits.stats
            arrays = {name: getattr(hits, name) for name in options.fields}
            if "mesh" in arrays:
                arrays["mesh"] = engine.map_mesh(arrays["mesh"])
        else:
            occlusion = engine.scene.occluded(
                rays.origins, rays.directions, rays.tmin, rays.tmax, **kwargs
            )
            stats = occlusion.stats
            arrays = {"occluded": occlusion.occluded}
    except ValueError as exc:  # the engine names the first bad ray and how many there are
        raise Invalid(str(exc)) from None
    if stats is not None:
        stats = {**stats, "strategy": options.strategy}
    return TraceResult(arrays, version, stats, time.perf_counter() - start)


def warmup() -> float:
    """Compile every engine kernel; answers the seconds taken."""
    return dacrt.warmup()
