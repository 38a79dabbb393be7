"""``closest``, ``occluded``, ``hits`` and ``count`` on the GPU: check the query as the CPU
engine does, trace the scene's base level breadth-first (``traversal``), finish the answers with
the CPU's code."""

import threading
from typing import NamedTuple

import numpy as np
from numba import cuda

from ..contracts import FLOAT, INDEX, Counts, HitList
from ..leaf import NO_HIT
from ..query import ALL_MASKS, ANY_HIT, CULL_BACK, CULL_FLAGS, CULL_FRONT, MASKED, QueryArrays
from ..scene import Traced
from ..validation import (
    InputError,
    check_cull,
    check_masks,
    check_max_hits,
    check_rays,
    check_time,
    explain_bad_rays,
)
from . import kernels
from .traversal import MAX_PAIRS, launch, traverse

# A level's masks where the query checks none.
NO_MASKS = np.zeros(0, np.uint32)
# The most device memory ``hits`` takes for its lists: 8 bytes a key, min(max_hits, triangles)
# keys a ray.
MAX_LIST_BYTES = 1 << 31


def lacks(scene, time=None, stats=False, kind="closest"):
    """What of a query of ``kind`` ("closest", "occluded", "hits", "count") this backend does
    not have: "placed meshes" (the scene's transforms, for hits and count), "deforming meshes"
    (vertices_end), "time" or "stats"; None where it answers it."""
    if scene._instances and kind in ("hits", "count"):
        return "placed meshes"
    if scene._deforming is not None:
        return "deforming meshes"
    if time is not None and scene._moving:  # where nothing moves, every instant is the same
        return "time"
    if stats:
        return "stats"
    return None


def check_supported(scene, time, max_pairs, kind):
    """InputError naming an option this backend does not have yet for a query of ``kind``, or
    a bad ``max_pairs``."""
    if isinstance(max_pairs, bool) or not isinstance(max_pairs, int | np.integer) or max_pairs < 1:
        raise InputError(f"max_pairs must be a positive integer, got {max_pairs!r}")
    lacking = lacks(scene, time, kind=kind)
    if lacking == "placed meshes":
        raise InputError(
            f"device='cuda' does not support placed meshes in {kind} yet (transforms, "
            "transforms_end); closest and occluded take them"
        )
    if lacking == "deforming meshes":
        raise InputError("device='cuda' does not support deforming meshes yet (vertices_end)")
    if lacking == "time":
        raise InputError("device='cuda' does not support time= in a scene that moves yet")


def prepare(scene, origins, directions, tmin, tmax, cull, mask):
    """The checked query's device arrays, culling side and masks."""
    origins, directions, tmin, tmax = check_query_rays(origins, directions, tmin, tmax)
    flags = CULL_FLAGS[check_cull(cull)]
    # det * cull_side > 0 culls, as ``geometry.culled_side``.
    cull_side = -1.0 if flags & CULL_BACK else (1.0 if flags & CULL_FRONT else 0.0)
    n = len(origins)
    if mask is None and scene.masks.all():  # the default mask sees every mesh: no masks to test
        ray_masks = np.zeros(0, np.uint32)
        tri_masks = np.zeros(0, np.uint32)
    else:  # a mesh with mask 0 is hidden from the default mask too
        ray_masks = check_masks(ALL_MASKS if mask is None else mask, n, "mask", "ray")
        tri_masks = scene._row_masks
    device = device_rays(origins, directions, tmin, tmax, ray_masks, tri_masks)
    return origins, directions, tmin, tmax, cull_side, device


def level_arrays(verts, ids):
    """A level's rows on the device: corners (F, 9), tie keys (global ids), centroids, per-row
    boxes; and the root box, on the host."""
    verts = np.ascontiguousarray(verts)
    corners = verts.reshape(-1, 3, 3)
    tri_box = np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1).astype(FLOAT)
    centroids = (corners.sum(axis=1) / np.float32(3)).astype(FLOAT)
    box = np.concatenate([tri_box[:, :3].min(axis=0), tri_box[:, 3:].max(axis=0)])
    return (
        cuda.to_device(verts),
        cuda.to_device(np.ascontiguousarray(ids, np.int32)),
        cuda.to_device(centroids),
        cuda.to_device(tri_box),
        box.astype(FLOAT),
    )


def scene_arrays(scene):
    """The base level's rows on the device (``level_arrays``)."""
    return level_arrays(scene._base.verts, scene._base.ids)


# One level traced at a time: a query's instance batches run side by side on host threads.
DEVICE_LOCK = threading.Lock()


def level_tracer(max_pairs=MAX_PAIRS):
    """What traces each level of a ``closest`` or ``occluded`` query on the GPU, in place of
    ``Scene._trace_level`` (same arguments): the base level, then each instance batch in its
    mesh's space, as the CPU engine merges them. Returns ``Traced``: best_t, and best_tri
    (the level's kernel row; for ANY_HIT any row where the ray is blocked), hit_u, hit_v; no
    stats."""

    def trace(level, flags, origins, directions, tmin, tmax, ray_masks, visible_rows,
              tri_masks, threads, list_size, times=None):  # fmt: skip
        # A bad ray (or one that leaves float32 in a mesh's space) is named, not sent.
        origins, directions, tmin, tmax = check_query_rays(origins, directions, tmin, tmax)
        n = len(origins)
        best_t = np.array(tmax, FLOAT)
        best_tri = np.full(n, NO_HIT, INDEX)
        u = np.zeros(n, FLOAT)
        v = np.zeros(n, FLOAT)
        verts, ids = level.verts, level.ids
        if visible_rows is not None:  # the rows a batch with one mask sees
            verts, ids = verts[visible_rows], ids[visible_rows]
        if not flags & MASKED:
            ray_masks, tri_masks = NO_MASKS, NO_MASKS
        if n and len(ids):
            cull_side = -1.0 if flags & CULL_BACK else (1.0 if flags & CULL_FRONT else 0.0)
            rays = (origins, directions, tmin, tmax)
            with DEVICE_LOCK:
                if flags & ANY_HIT:
                    blocked = trace_any(
                        verts, ids, rays, ray_masks, tri_masks, cull_side, max_pairs
                    )
                    best_tri[blocked] = 0
                else:
                    best_t, best_tri, u, v = trace_closest(
                        verts, ids, rays, ray_masks, tri_masks, cull_side, max_pairs
                    )
            if visible_rows is not None:
                found = best_tri != NO_HIT
                best_tri[found] = visible_rows[best_tri[found]]
        arrays = QueryArrays(best_tri, u, v, *([NO_MASKS] * 9))
        return Traced(best_t, arrays, [])

    return trace


def device_rays(origins, directions, tmin, tmax, ray_masks, tri_masks):
    """A level's rays and masks on the device: origins, directions, inverse directions, tmin,
    tmax, ray masks, row masks."""
    with np.errstate(divide="ignore"):
        inv_dirs = (np.float32(1.0) / directions).astype(FLOAT)
    return tuple(
        cuda.to_device(np.ascontiguousarray(a))
        for a in (origins, directions, inv_dirs, tmin, tmax, ray_masks, tri_masks)
    )


def trace_closest(verts, ids, rays, ray_masks, tri_masks, cull_side, max_pairs):
    """Each ray's nearest hit on the rows (``verts``, tie keys ``ids``): (best_t, best_tri,
    u, v), best_t tmax and best_tri NO_HIT on a miss."""
    n = len(rays[0])
    o, d, inv_d, lo, hi, ray_masks, tri_masks = device_rays(*rays, ray_masks, tri_masks)
    verts, keys, centroids, tri_box, box = level_arrays(verts, ids)
    best_key = cuda.to_device(np.full(n, kernels.NO_KEY, np.uint64))

    def run_leaves(frontier, kind):
        launch(
            kernels.leaf_closest, frontier.ray_ids.shape[0], frontier.ray_ids,
            frontier.ray_node, kind, cuda.to_device(frontier.tri_lo),
            cuda.to_device(frontier.tri_n), frontier.rows, o, d, lo, hi, verts, keys,
            ray_masks, tri_masks, cull_side, best_key,
        )  # fmt: skip

    traverse((centroids, tri_box, box), (o, inv_d, lo, hi), run_leaves, max_pairs)
    row_of_key = np.full(int(ids.max()) + 1, -1, np.int32)
    row_of_key[ids] = np.arange(len(ids), dtype=np.int32)
    out = [
        cuda.to_device(a)
        for a in (np.array(rays[3], FLOAT), np.full(n, NO_HIT, INDEX), np.zeros(n, FLOAT),
                  np.zeros(n, FLOAT))
    ]  # fmt: skip
    launch(kernels.finish_best, n, best_key, cuda.to_device(row_of_key), o, d, verts, NO_HIT, *out)
    return tuple(a.copy_to_host() for a in out)


def trace_any(verts, ids, rays, ray_masks, tri_masks, cull_side, max_pairs):
    """Whether each ray hits any of the rows (``verts``) in its window: (n,) bool."""
    n = len(rays[0])
    o, d, inv_d, lo, hi, ray_masks, tri_masks = device_rays(*rays, ray_masks, tri_masks)
    verts, _, centroids, tri_box, box = level_arrays(verts, ids)
    hit = cuda.to_device(np.zeros(n, np.uint8))

    def run_leaves(frontier, kind):
        launch(
            kernels.leaf_any, frontier.ray_ids.shape[0], frontier.ray_ids, frontier.ray_node,
            kind, cuda.to_device(frontier.tri_lo), cuda.to_device(frontier.tri_n),
            frontier.rows, o, d, lo, hi, verts, ray_masks, tri_masks, cull_side, hit,
        )  # fmt: skip

    traverse((centroids, tri_box, box), (o, inv_d, lo, hi), run_leaves, max_pairs)
    return hit.copy_to_host().astype(bool)


def check_query_rays(origins, directions, tmin, tmax):
    """ValueError naming the first bad ray, before any is sent to the device."""
    origins, directions, tmin, tmax = check_rays(origins, directions, tmin, tmax)
    bad = (
        ~np.isfinite(origins).all(axis=1)
        | ~np.isfinite(directions).all(axis=1)
        | ~directions.any(axis=1)
        | ~np.isfinite(tmin)
        | np.isnan(tmax)
        | (tmin > tmax)
    )
    if bad.any():
        explain_bad_rays(origins, directions, tmin, tmax)
    return origins, directions, tmin, tmax


def closest(scene, origins, directions, tmin=None, tmax=None, *, cull="none", mask=None,
            time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.closest`` on the GPU: the same ``Hits``, bit for bit (no ``stats``); the levels
    are traced here, their answers merged on the host as the CPU engine merges them."""
    check_supported(scene, time, max_pairs, "closest")
    tracer = level_tracer(max_pairs)
    return scene._closest(
        origins, directions, tmin, tmax, cull, mask, "sampling", None, False, time, tracer
    )


def occluded(scene, origins, directions, tmin=None, tmax=None, *, cull="none", mask=None,
             time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.occluded`` on the GPU: the same ``Occlusion`` (no ``stats``)."""
    check_supported(scene, time, max_pairs, "occluded")
    tracer = level_tracer(max_pairs)
    return scene._occluded(
        origins, directions, tmin, tmax, cull, mask, "sampling", None, False, time, tracer
    )


def count(scene, origins, directions, tmin=None, tmax=None, *, cull="none", mask=None,
          time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.count`` on the GPU: the same ``Counts`` (no ``stats``)."""
    check_supported(scene, time, max_pairs, "count")
    counts, _, _ = crossings(scene, origins, directions, tmin, tmax, cull, mask, time, 0, max_pairs)
    return Counts(counts)


def hits(scene, origins, directions, tmin=None, tmax=None, *, max_hits=16, cull="none",
         mask=None, time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.hits`` on the GPU: the same ``HitList`` (no ``stats``).

    Each ray keeps its min(max_hits, triangles) nearest keys on the device, 8 bytes each: a
    batch that needs more than ``MAX_LIST_BYTES`` (2 GiB) for them is refused (InputError
    naming max_hits); split it into batches of fewer rays."""
    check_supported(scene, time, max_pairs, "hits")
    max_hits = check_max_hits(max_hits)
    counts, keys, checked = crossings(
        scene, origins, directions, tmin, tmax, cull, mask, time, max_hits, max_pairs
    )
    origins, directions = checked
    # Each row's keys, nearest first (NO_KEY, the largest, after the held ones).
    keys.sort(axis=1)
    held = keys != kernels.NO_KEY
    row_of_key = np.zeros(scene.n_triangles, INDEX)
    row_of_key[scene._base.ids] = np.arange(len(scene._base.ids), dtype=INDEX)
    rows = row_of_key[np.where(held, keys & kernels.LOW32, 0).astype(np.int64)]
    lists = CrossingLists(counts, key_distances(keys), rows)
    offsets, t, mesh, prim, u, v, normal = scene._finish_hits(
        TracedLists(lists), origins, directions, scene._base, scene.mesh_offsets, max_hits
    )
    return HitList(offsets, t, mesh, prim, u, v, normal, counts > max_hits)


class CrossingLists(NamedTuple):
    """The fields of ``QueryArrays`` that ``Scene._finish_hits`` reads: each ray's crossing
    count, and its nearest crossings' t and kernel rows, sorted by (t, tie key)."""

    n_hits: np.ndarray
    list_t: np.ndarray
    list_tri: np.ndarray


class TracedLists(NamedTuple):
    """A trace's answer as ``Scene._finish_hits`` takes it."""

    arrays: CrossingLists


def key_distances(keys):
    """The float32 t of ``kernels.tie_order_key`` keys (the inverse of its monotonic bits)."""
    bits = keys >> np.uint64(32)
    positive = bits >= kernels.SIGN32
    bits = np.where(positive, bits ^ kernels.SIGN32, bits ^ kernels.LOW32)
    return bits.astype(np.uint32).view(FLOAT)


def crossings(scene, origins, directions, tmin, tmax, cull, mask, time, max_hits, max_pairs):
    """Each ray's crossing count (int32) and, for max_hits > 0, its min(max_hits, triangles)
    smallest (t, tie key) keys, unsorted, NO_KEY where it has fewer: (counts, keys (n, K)
    uint64, (origins, directions) checked)."""
    origins, directions, tmin, tmax, cull_side, device = prepare(
        scene, origins, directions, tmin, tmax, cull, mask
    )
    n = len(origins)
    check_time(time, n)  # checked as on the CPU; nothing moves, so every instant is 0's
    n_rows = len(scene._base.ids)
    width = min(max_hits, n_rows)
    if n * width * 8 > MAX_LIST_BYTES:
        raise InputError(
            f"max_hits={max_hits} for {n} rays needs {n * width * 8 / 2**30:.1f} GiB of device "
            f"memory for the hit lists, over device='cuda''s {MAX_LIST_BYTES / 2**30:.0f} GiB: "
            "pass fewer rays a call or a smaller max_hits"
        )
    counts = np.zeros(n, INDEX)
    keys = np.full((n, width), kernels.NO_KEY, np.uint64)
    if n and n_rows:
        o, d, inv_d, lo, hi, ray_masks, tri_masks = device
        verts, tie_keys, centroids, tri_box, box = scene_arrays(scene)
        counts_d = cuda.to_device(counts)
        keys_d = cuda.to_device(keys)

        def run_leaves(frontier, kind):
            launch(
                kernels.leaf_crossings, frontier.ray_ids.shape[0], frontier.ray_ids,
                frontier.ray_node, kind, cuda.to_device(frontier.tri_lo),
                cuda.to_device(frontier.tri_n), frontier.rows, o, d, lo, hi, verts, tie_keys,
                ray_masks, tri_masks, cull_side, counts_d, keys_d,
            )  # fmt: skip

        traverse((centroids, tri_box, box), (o, inv_d, lo, hi), run_leaves, max_pairs)
        counts = counts_d.copy_to_host()
        keys = keys_d.copy_to_host()
    return counts, keys, (origins, directions)
