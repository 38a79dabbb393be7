"""Queries: what can be asked of a scene, and how the dacrt engine answers it.

The only module that runs the engine's queries. It builds one ``dacrt.Scene`` per scene version
(cached in the snapshot), maps the engine's mesh positions to the meshes' stable indices, and
lets the engine's ``InputError`` (bad rays, named by the engine) through: ``errors`` maps it to
422.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any

import numpy as np

import dacrt
from dacrt.points import signed
from dacrt.validation import check_cull, check_max_distance, check_nsamples, check_strategy

from . import footprint
from .errors import Invalid
from .store import Snapshot
from .wire import ANSWER_FORMATS, MeshArrays, Rays

if TYPE_CHECKING:
    from .cluster import Cluster


class Query(str, Enum):  # noqa: UP042 - StrEnum would change str() and format() of members
    """Kinds of query."""

    CLOSEST = "closest"
    OCCLUDED = "occluded"
    HITS = "hits"
    COUNT = "count"


#: The answer keys of each query, in answer order; ``?fields=`` picks a subset.
FIELDS: dict[Query, tuple[str, ...]] = {
    Query.CLOSEST: ("t", "mesh", "prim", "u", "v", "normal"),
    Query.OCCLUDED: ("occluded",),
    Query.HITS: ("offsets", "t", "mesh", "prim", "u", "v", "normal", "truncated"),
    Query.COUNT: ("count",),
}
#: The keys of a hits answer with one value per hit: they come with ``offsets`` (CSR), listed in
#: ``?fields=`` or not.
PER_HIT_FIELDS = ("t", "mesh", "prim", "u", "v", "normal")
#: ``max_hits`` of a hits query that does not give it (API.md).
DEFAULT_MAX_HITS = 16


def strategies() -> tuple[str, ...]:
    """The engine's partitioning strategies; the first is the default."""
    return tuple(dacrt.STRATEGIES)


#: Face culling modes: the engine's (none, back, front).
CULL_MODES = tuple(dacrt.CULL_MODES)


@dataclass(frozen=True)
class Options:
    """Options of one query, for the whole batch."""

    query: Query
    fields: tuple[str, ...]
    strategy: str
    stats: bool = False
    threads: int | None = None
    cull: str = "none"
    max_hits: int | None = None  #: hits kept per ray (hits only)
    mask: int | None = None  #: ``?mask=``: one mask for every ray of the batch

    def hit_buffer_bytes(self, n_rays: int) -> int:
        """Bytes of the engine's hit buffers for ``n_rays`` rays (0 but for hits)."""
        if self.query is not Query.HITS:
            return 0
        return n_rays * (self.max_hits + 1) * footprint.HIT_SLOT_BYTES

    @property
    def answer_formats(self) -> tuple[str, ...]:
        """The formats the answer can be written in: npy needs one row per ray in every array
        (a hits answer with ``offsets`` or a per-hit key is CSR: npz and JSON only)."""
        if self.query is Query.HITS and set(self.fields) & {"offsets", *PER_HIT_FIELDS}:
            return tuple(fmt for fmt in ANSWER_FORMATS if fmt != "npy")
        return ANSWER_FORMATS


def make_options(
    query: Query | str,
    fields: str | None = None,
    strategy: str | None = None,
    stats: bool = False,
    threads: int | None = None,
    cull: str = "none",
    max_hits: int | None = None,
    mask: int | None = None,
    max_hits_limit: int | None = None,
) -> Options:
    """Options from query-string values; 422 naming the choices for an unknown value (the
    engine's checks for strategy and cull).

    ``max_hits`` (hits only; default DEFAULT_MAX_HITS) must lie in [1, ``max_hits_limit``]."""
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
        if query is Query.HITS and set(chosen) & set(PER_HIT_FIELDS):
            chosen = ("offsets", *(name for name in chosen if name != "offsets"))
    if query is Query.HITS:
        max_hits = DEFAULT_MAX_HITS if max_hits is None else max_hits
        max_hits = check_max_hits(max_hits, max_hits_limit)
    elif max_hits is not None:
        raise Invalid(f"max_hits applies to the hits query only, not to {query.value}")
    # the engine's own checks, before the body is read: its InputError is 422 (errors.STATUS)
    strategy = strategies()[0] if strategy is None else check_strategy(strategy)
    cull = check_cull(cull)
    return Options(query, chosen, strategy, stats, threads, cull, max_hits, mask)


def check_max_hits(max_hits: int, limit: int | None) -> int:
    """422 unless ``max_hits`` is an integer in [1, limit] (limit: DACRT_MAX_HITS)."""
    within = f"1 to {limit} (DACRT_MAX_HITS)" if limit is not None else "at least 1"
    if isinstance(max_hits, bool) or not isinstance(max_hits, int):
        raise Invalid(f"max_hits must be an integer from {within}, got {max_hits!r}")
    if max_hits < 1 or (limit is not None and max_hits > limit):
        raise Invalid(f"max_hits must be an integer from {within}, got {max_hits}")
    return max_hits


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


def build_engine_scene(meshes: Iterable[tuple], scene_type: Any = dacrt.Scene) -> EngineScene:
    """The engine scene of (index, vertices, faces[, mask[, transform]]) tuples (mask: uint32,
    default all ones; transform: (4, 4) or None, the identity); meshes without triangles are left
    out. Meshes may share arrays (instances): the engine places each by its own transform.
    ``scene_type`` builds the scene from (meshes, masks=, transforms=): ``dacrt.Scene``, or a
    ``dacrt.distributed.DistributedScene`` bound to a client (``service.cluster``)."""
    kept = [tuple(mesh) for mesh in meshes if len(mesh[2])]
    indices = np.array([mesh[0] for mesh in kept] + [-1], dtype=np.int32)
    masks = np.array([mesh[3] if len(mesh) > 3 else 0xFFFFFFFF for mesh in kept], np.uint32)
    transforms = [mesh[4] if len(mesh) > 4 else None for mesh in kept]
    scene = scene_type(
        [(mesh[1], mesh[2]) for mesh in kept],
        masks=None if (masks == 0xFFFFFFFF).all() else masks,
        transforms=None if all(t is None for t in transforms) else transforms,
    )
    identity = np.array_equal(indices[:-1], np.arange(len(kept)))
    return EngineScene(scene, None if identity else indices)


def _snapshot_engine(snapshot: Snapshot, scene_type: Any = dacrt.Scene) -> EngineScene:
    return build_engine_scene(
        ((m.index, m.vertices, m.faces, m.mask, m.transform) for m in snapshot.meshes.values()),
        scene_type,
    )


@dataclass(frozen=True)
class TraceResult:
    """The arrays of an answer, the scene version it was computed on, and what it cost."""

    arrays: dict[str, np.ndarray]
    version: int
    stats: dict[str, Any] | None
    seconds: float  #: engine build (if not cached) + trace
    where: str = "process"  #: where it was traced: "process", or "cluster" (``service.cluster``)
    headers: dict[str, str] = field(default_factory=dict)  #: none: a sensor's answer has some


def trace(
    snapshot: Snapshot, rays: Rays, options: Options, cluster: Cluster | None = None
) -> TraceResult:
    """Answer a query on one scene version (the engine scene is built once per version).

    With a ``cluster`` (DACRT_DASK_SCHEDULER), a query of at least its ``min_rays`` rays is traced
    on the cluster's workers, on the same version; in process when the cluster cannot take it."""
    start = time.perf_counter()
    engine = snapshot.cached("dacrt", _snapshot_engine)
    if cluster is not None:
        try:
            remote = cluster.engine_for(snapshot, len(rays), _snapshot_engine)
            if remote is not None:
                return _run(remote, rays, options, snapshot.version, start, "cluster")
        except (Invalid, dacrt.InputError):  # the query's fault: the same 422 in process
            raise
        except Exception as exc:  # the cluster's: lost, unreachable, too slow
            cluster.failed(exc)
    return _run(engine, rays, options, snapshot.version, start)


def trace_once(mesh: MeshArrays, rays: Rays, options: Options) -> TraceResult:
    """Answer a query on a mesh sent with the rays (mesh index 0; version 0: no stored scene)."""
    start = time.perf_counter()
    engine = build_engine_scene([(0, mesh.vertices, mesh.faces)])
    return _run(engine, rays, options, 0, start)


def ray_mask(rays: Rays, options: Options) -> np.ndarray | int | None:
    """The batch's masks: the body's ``mask`` or ``?mask=`` (422 for both), else None."""
    if rays.mask is not None and options.mask is not None:
        raise Invalid(
            "the rays carry a mask in the body and in ?mask= too; send one of them "
            "(?mask= gives every ray of the batch one mask)"
        )
    return options.mask if rays.mask is None else rays.mask


def _run(
    engine: EngineScene,
    rays: Rays,
    options: Options,
    version: int,
    start: float,
    where: str = "process",
) -> TraceResult:
    kwargs = {
        "cull": options.cull,
        "mask": ray_mask(rays, options),
        "strategy": options.strategy,
        # threads of this machine; each shard on a cluster's worker takes one of its threads
        "threads": options.threads if where == "process" else None,
        "stats": options.stats,
    }
    if options.query is Query.HITS:
        kwargs["max_hits"] = options.max_hits
    query = getattr(engine.scene, options.query.value)
    # a bad ray is the engine's InputError, naming the first and how many: 422 (errors.STATUS)
    answer = query(rays.origins, rays.directions, rays.tmin, rays.tmax, **kwargs)
    stats = answer.stats
    arrays = {name: getattr(answer, name) for name in options.fields}
    if "mesh" in arrays:
        arrays["mesh"] = engine.map_mesh(arrays["mesh"])
    if stats is not None:
        stats = {**stats, "strategy": options.strategy, "where": where}
    return TraceResult(arrays, version, stats, time.perf_counter() - start, where)


#: The answer keys of a point query (``/nearest``), and those ``?sign=true`` adds.
NEAREST_FIELDS = ("distance", "point", "mesh", "prim", "u", "v")
SIGN_FIELDS = ("inside", "signed_distance")


@dataclass(frozen=True)
class PointOptions:
    """Options of one point query, for the whole batch (API.md, "Point queries")."""

    max_distance: float | None = None
    sign: bool = False  #: add inside and signed_distance
    nsamples: int = 1  #: rays whose majority says inside (odd)
    mask: int | None = None  #: ``?mask=``: one mask for every point
    stats: bool = False
    threads: int | None = None

    @property
    def fields(self) -> tuple[str, ...]:
        return NEAREST_FIELDS + (SIGN_FIELDS if self.sign else ())


def point_options(
    max_distance: float | None,
    sign: bool,
    nsamples: int,
    mask: int | None,
    stats: bool,
    threads: int | None,
) -> PointOptions:
    """Options from query-string values; 422 naming ``max_distance`` or ``nsamples`` (the
    engine's checks) for a bad one, before the body is read."""
    check_max_distance(max_distance)
    check_nsamples(nsamples)
    return PointOptions(max_distance, sign, nsamples, mask, stats, threads)


def nearest(snapshot: Snapshot, points: np.ndarray, options: PointOptions) -> TraceResult:
    """The closest point on one scene version to each of ``points`` (N, 3) float32, with inside
    and the signed distance when asked; always in process."""
    start = time.perf_counter()
    engine = snapshot.cached("dacrt", _snapshot_engine)
    shared = {"mask": options.mask, "threads": options.threads}
    # a bad point is the engine's InputError, naming the first and how many: 422
    found = engine.scene.nearest(points, options.max_distance, stats=options.stats, **shared)
    arrays = {name: getattr(found, name) for name in NEAREST_FIELDS}
    arrays["mesh"] = engine.map_mesh(arrays["mesh"])
    if options.sign:
        inside = engine.scene.contains(points, options.nsamples, **shared)
        arrays["inside"] = inside
        arrays["signed_distance"] = signed(found.distance, inside)
    stats = None if found.stats is None else {**found.stats, "where": "process"}
    return TraceResult(arrays, snapshot.version, stats, time.perf_counter() - start)


def warmup() -> float:
    """Compile every engine kernel; answers the seconds taken."""
    return dacrt.warmup()
