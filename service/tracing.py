"""Queries: how the dacrt engine answers what a request asks (``options``) of a scene.

The only module that runs the engine's queries. It makes one ``dacrt.Scene`` per scene version
(cached in the snapshot), from the earlier version's by ``Scene.with_changes`` where only
placements, vertices and masks changed (a frame that moves actors packs only them), maps the
engine's mesh positions to the meshes' stable indices, picks the answer's keys (``Options.pick``)
and lets the engine's ``InputError`` (bad rays, named by the engine) through: ``errors`` maps it
to 422. With DACRT_DEVICE=cuda, closest, occluded, hits and count run on the GPU where the CUDA
backend answers them, and on the CPU otherwise (``device_for``: deforming meshes, stats, a dask
cluster).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

import dacrt
from dacrt.points import signed
from dacrt.validation import check_max_distance, check_nsamples

from .errors import Invalid, TooLarge
from .options import Options, Query
from .store import Snapshot
from .wire import MeshArrays, Rays, float32_if_shortest

if TYPE_CHECKING:
    from .cluster import Cluster


@dataclass(frozen=True)
class EngineScene:
    """A built ``dacrt.Scene`` and, per engine mesh position, the stable mesh index."""

    scene: Any
    mesh_index: (
        np.ndarray | None
    )  #: (n_meshes + 1,) int32 ending in -1, or None if positions are indices
    #: per engine mesh position, the (index, vertices, faces, mask, transform, transform_end,
    #: vertices_end) it was built from
    meshes: tuple[tuple, ...] = ()

    def map_mesh(self, positions: np.ndarray) -> np.ndarray:
        """Engine mesh positions (-1 on a miss) -> stable indices (-1 on a miss)."""
        if self.mesh_index is None:
            return positions
        return self.mesh_index[positions]  # a miss (-1) picks the trailing -1


def build_engine_scene(
    meshes: Iterable[tuple], scene_type: Any = dacrt.Scene, order: str = "morton"
) -> EngineScene:
    """The engine scene of (index, vertices, faces[, mask[, transform[, transform_end[,
    vertices_end]]]]) tuples (mask: uint32, default all ones; transform: (4, 4) or None, the
    identity; transform_end: (4, 4) or None, static; vertices_end: (V, 3) or None, static);
    meshes without triangles are left out. Meshes may share arrays (instances): the engine
    places each by its own transform.
    ``scene_type`` builds the scene from (meshes, masks=, transforms=): ``dacrt.Scene``, or a
    ``dacrt.distributed.DistributedScene`` bound to a client (``service.cluster``). ``order``
    is a ``dacrt.Scene``'s storage order: "morton" for a stored mesh, packed once for every
    version that keeps it."""
    kept = [tuple(mesh) for mesh in meshes if len(mesh[2])]
    indices = np.array([mesh[0] for mesh in kept] + [-1], dtype=np.int32)
    masks = np.array([mesh[3] if len(mesh) > 3 else 0xFFFFFFFF for mesh in kept], np.uint32)
    transforms = [mesh[4] if len(mesh) > 4 else None for mesh in kept]
    ends = [mesh[5] if len(mesh) > 5 else None for mesh in kept]
    vertex_ends = [_vertices_end(mesh) for mesh in kept]
    # Only a moving scene names transforms_end or vertices_end (a cluster's scene type takes
    # neither).
    moving = {} if all(end is None for end in ends) else {"transforms_end": ends}
    if any(end is not None for end in vertex_ends):
        moving["vertices_end"] = vertex_ends
    scene = scene_type(
        [(mesh[1], mesh[2]) for mesh in kept],
        masks=None if (masks == 0xFFFFFFFF).all() else masks,
        transforms=None if all(t is None for t in transforms) else transforms,
        **moving,
        **({"order": order} if scene_type is dacrt.Scene else {}),
    )
    identity = np.array_equal(indices[:-1], np.arange(len(kept)))
    return EngineScene(scene, None if identity else indices, tuple(kept))


def _snapshot_engine(snapshot: Snapshot, scene_type: Any = dacrt.Scene) -> EngineScene:
    """The engine scene of a version: changed from an earlier version's (``with_changes``,
    which packs only what changed) where the meshes are the same but for their placements,
    vertices and masks; else built whole."""
    meshes = [
        (m.index, m.vertices, m.faces, m.mask, m.transform, m.transform_end, m.vertices_end)
        for m in snapshot.meshes.values()
    ]
    earlier = snapshot.earlier("dacrt") if scene_type is dacrt.Scene else None
    if earlier is not None:
        changed = changed_engine_scene(earlier[1], meshes)
        if changed is not None:
            return changed
    return build_engine_scene(meshes, scene_type)


def changed_engine_scene(engine: EngineScene, meshes: list[tuple]) -> EngineScene | None:
    """``engine`` changed into the engine scene of ``meshes`` (as ``build_engine_scene`` takes
    them, each with mask and transform) by ``Scene.with_changes``, or None where they differ by
    more than placements, vertices (as many, the same faces) and masks."""
    kept = [mesh for mesh in meshes if len(mesh[2])]
    if len(kept) != len(engine.meshes):
        return None
    transforms, vertices, masks, ends, vertex_ends = {}, {}, {}, {}, {}
    for i, (old, new) in enumerate(zip(engine.meshes, kept)):
        if old[0] != new[0] or old[2] is not new[2] or len(old[1]) != len(new[1]):
            return None
        if new[1] is not old[1]:
            vertices[i] = new[1]
        if new[3] != old[3]:
            masks[i] = new[3]
        if not _same_transform(old[4], new[4]):
            transforms[i] = new[4]
        if not _same_transform(_end(old), _end(new)):
            ends[i] = _end(new)
        if _vertices_end(old) is not _vertices_end(new):
            vertex_ends[i] = _vertices_end(new)
    if not (transforms or vertices or masks or ends or vertex_ends):
        return replace(engine, meshes=tuple(kept))
    moving = {"transforms_end": ends} if ends else {}
    if vertex_ends:
        moving["vertices_end"] = vertex_ends
    scene = engine.scene.with_changes(
        transforms=transforms, vertices=vertices, masks=masks, **moving
    )
    return replace(engine, scene=scene, meshes=tuple(kept))


def _end(mesh: tuple) -> np.ndarray | None:
    """A mesh tuple's end placement (None: static)."""
    return mesh[5] if len(mesh) > 5 else None


def _vertices_end(mesh: tuple) -> np.ndarray | None:
    """A mesh tuple's vertices at the end of the interval (None: static)."""
    return mesh[6] if len(mesh) > 6 else None


def _same_transform(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is b
    return a is b or np.array_equal(a, b)


@contextmanager
def meshes_by_name(snapshot: Snapshot, engine: EngineScene) -> Iterator[None]:
    """The engine's errors that name a mesh by its place in the engine scene name it as the
    scene does (422)."""
    try:
        yield
    except dacrt.MeshSpaceError as error:
        index = int(engine.map_mesh(np.array([error.mesh]))[0])
        name = next((m.name for m in snapshot.meshes.values() if m.index == index), index)
        raise dacrt.InputError(
            f"a ray of the batch leaves the float32 range in the space of mesh {name!r}: its "
            "transform's inverse moves the ray's origin or direction beyond it"
        ) from None


def derives_for_points(snapshot: Snapshot) -> bool:
    """Whether a point query on the version derives what point queries read (its engine scene,
    built or not, has not yet: ``dacrt.Scene.derived_for_points``)."""
    engine = snapshot.built("dacrt")
    return engine is None or not engine.scene.derived_for_points


def engine_scene(snapshot: Snapshot) -> EngineScene:
    """The engine scene of one scene version, built once per version (the sensors' too)."""
    return snapshot.cached("dacrt", _snapshot_engine)


@dataclass(frozen=True)
class TraceResult:
    """The arrays of an answer (a query's or a sensor's), the scene version it was traced on,
    and what it cost."""

    arrays: dict[str, np.ndarray]
    version: int
    stats: dict[str, Any] | None
    seconds: float  #: engine build (if not cached) + trace (+ a sensor's arithmetic)
    n_rays: int  #: rays traced
    where: str = "process"  #: where it was traced: "process", or "cluster" (``service.cluster``)
    headers: dict[str, str] = field(default_factory=dict)  #: a sensor's own (X-Depth-Range)
    #: what the CUDA backend lacks, where DACRT_DEVICE=cuda and the CPU traced the query
    fallback: str | None = None


def trace(
    snapshot: Snapshot, rays: Rays, options: Options, cluster: Cluster | None = None
) -> TraceResult:
    """Answer a query on one scene version (the engine scene is built once per version).

    With a ``cluster`` (DACRT_DASK_SCHEDULER), a query of at least its ``min_rays`` rays is traced
    on the cluster's workers, on the same version; in process when the cluster cannot take it."""
    start = time.perf_counter()
    engine = snapshot.cached("dacrt", _snapshot_engine)
    # The cluster's workers trace no motion: rays with times, or a moving scene, stay here.
    timed = rays.time is not None or any(
        mesh.transform_end is not None or mesh.vertices_end is not None
        for mesh in snapshot.meshes.values()
    )
    if cluster is not None and not timed:
        try:
            remote = cluster.engine_for(snapshot, len(rays), _snapshot_engine)
            if remote is not None:
                with meshes_by_name(snapshot, engine):  # the workers' scene has engine's meshes
                    return _run(remote, rays, options, snapshot.version, start, "cluster")
        except (Invalid, dacrt.InputError):  # the query's fault: the same 422 in process
            raise
        except Exception as exc:  # the cluster's: lost, unreachable, too slow
            cluster.failed(exc)
    with meshes_by_name(snapshot, engine):
        return _run(engine, rays, options, snapshot.version, start)


def trace_once(mesh: MeshArrays, rays: Rays, options: Options) -> TraceResult:
    """Answer a query on a mesh sent with the rays (mesh index 0; version 0: no stored scene)."""
    start = time.perf_counter()
    engine = build_engine_scene([(0, mesh.vertices, mesh.faces)], order="auto")
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
    if rays.time is not None:
        kwargs["time"] = rays.time
    if options.kind is Query.HITS:
        kwargs["max_hits"] = options.max_hits
    device, fallback = device_for(engine, options, where)
    if device == "cuda":
        kwargs["device"] = device
    query = getattr(engine.scene, Query(options.kind).value)
    # a bad ray is the engine's InputError, naming the first and how many: 422 (errors.install)
    answer = query(rays.origins, rays.directions, rays.tmin, rays.tmax, **kwargs)
    stats = answer.stats
    arrays = options.pick(partial(getattr, answer))
    if "mesh" in arrays:
        arrays["mesh"] = engine.map_mesh(arrays["mesh"])
    if stats is not None:
        stats = {**stats, "strategy": options.strategy, "where": where}
    seconds = time.perf_counter() - start
    return TraceResult(arrays, version, stats, seconds, len(rays), where, fallback=fallback)


def device_for(engine: EngineScene, options: Options, where: str) -> tuple[str, str | None]:
    """Where a query is traced: ("cuda", None) where DACRT_DEVICE=cuda and the CUDA backend
    answers it; else "cpu" and what that backend lacks ("deforming meshes", "stats", or
    "cluster": a dask cluster's workers trace on their CPUs), None where DACRT_DEVICE=cpu."""
    if options.device != "cuda":
        return "cpu", None
    if where != "process":
        return "cpu", "cluster"
    from dacrt import cuda  # numba.cuda is imported only where DACRT_DEVICE=cuda

    lacking = cuda.lacks(engine.scene, options.stats)
    return ("cpu", lacking) if lacking is not None else ("cuda", None)


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

    def rays(self, n_points: int) -> int:
        """The rays of a query of ``n_points`` points, as DACRT_MAX_RAYS_PER_REQUEST counts
        them: one a point, or with ``sign`` the inside test's, ``nsamples`` a point."""
        return n_points * self.nsamples if self.sign else n_points


def point_options(
    max_distance: float | None,
    sign: bool,
    nsamples: int,
    mask: int | None,
    stats: bool,
    threads: int | None,
    max_rays: int,
) -> PointOptions:
    """Options from query-string values, before the body is read: 413 when one point's inside
    test alone traces more than ``max_rays`` rays (``check_point_rays``), else 422 naming
    ``max_distance`` or ``nsamples`` (the engine's checks) for a bad one. A ``max_distance``
    that is a float32's shortest decimal stands for that float32 (``float32_if_shortest``)."""
    check_max_distance(max_distance)
    # a distance a JSON answer wrote, given back, keeps its answer: that float32, not below it
    limit = None if max_distance is None else float32_if_shortest(max_distance)
    options = PointOptions(limit, sign, nsamples, mask, stats, threads)
    if isinstance(nsamples, int):
        check_point_rays(options, 1, max_rays)
    check_nsamples(nsamples)
    return options


def check_point_rays(options: PointOptions, n_points: int, max_rays: int) -> None:
    """413 when ``n_points`` points' inside test (``nsamples`` rays a point, with ``sign``)
    traces more than ``max_rays`` rays: the rays' budget of one request."""
    if options.sign and options.rays(n_points) > max_rays:
        raise TooLarge(
            f"{n_points} points x nsamples {options.nsamples} is {n_points * options.nsamples} "
            f"rays, over the limit of {max_rays} (DACRT_MAX_RAYS_PER_REQUEST); send fewer "
            "points or a smaller nsamples"
        )


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
        with meshes_by_name(snapshot, engine):
            inside = engine.scene.contains(points, options.nsamples, **shared)
        arrays["inside"] = inside
        arrays["signed_distance"] = signed(found.distance, inside)
    stats = None
    if found.stats is not None:
        # the engine counts nothing of the inside test: its rays, as the metrics count them
        votes = {"inside_rays": options.rays(len(points))} if options.sign else {}
        stats = {**found.stats, **votes, "where": "process"}
    seconds = time.perf_counter() - start
    return TraceResult(arrays, snapshot.version, stats, seconds, options.rays(len(points)))
