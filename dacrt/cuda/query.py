"""``closest``, ``occluded``, ``hits`` and ``count`` on the GPU: ``Scene``'s own queries, each
level (the base level, each batch of instances in its mesh's space) traced breadth-first here
(``traversal``), the levels' answers checked, merged and finished by the CPU engine's code."""

import threading
import weakref
from typing import NamedTuple

import numpy as np
from numba import cuda

from ..contracts import FLOAT, INDEX
from ..leaf import NO_HIT
from ..query import (
    ALL_HITS,
    ANY_HIT,
    COLLECT,
    CULL_BACK,
    CULL_FRONT,
    MASKED,
    QueryArrays,
)
from ..scene import Traced
from ..validation import (
    InputError,
    check_rays,
    explain_bad_rays,
)
from . import kernels
from .traversal import MAX_PAIRS, launch, traverse

# A level's masks where the query checks none.
NO_MASKS = np.zeros(0, np.uint32)
# The most device memory a trace's hit lists take at once: 8 bytes a key, min(max_hits,
# triangles) + 1 keys a ray; more rays are traced in chunks.
MAX_LIST_BYTES = 1 << 31


def lacks(scene, stats=False):
    """What of a query this backend does not have: "deforming meshes" (vertices_end) or
    "stats"; None where it answers it."""
    if scene._deforming is not None:
        return "deforming meshes"
    if stats:
        return "stats"
    return None


def is_available() -> bool:
    """Whether a CUDA GPU (or the simulator, ``NUMBA_ENABLE_CUDASIM=1``) can run the kernels."""
    try:
        return bool(cuda.is_available())
    except Exception:  # a driver that fails to load means no GPU
        return False


def check_available():
    """InputError where no CUDA GPU is available (rather than the driver's error)."""
    if not is_available():
        raise InputError(
            "device='cuda': no CUDA GPU is available here (no CUDA driver, or no GPU it can "
            "use); use device='cpu'"
        )


def check_supported(scene, max_pairs):
    """InputError naming an option this backend does not have yet, or a bad ``max_pairs``."""
    if isinstance(max_pairs, bool) or not isinstance(max_pairs, int | np.integer) or max_pairs < 1:
        raise InputError(f"max_pairs must be a positive integer, got {max_pairs!r}")
    if lacks(scene) == "deforming meshes":
        raise InputError("device='cuda' does not support deforming meshes yet (vertices_end)")


class DeviceLevel(NamedTuple):
    """A level's rows on the device, as the kernels read them."""

    verts: object  #: (F, 9) float32: each row's corners
    keys: object  #: (F,) int32: each row's tie key (``Packed.ids``)
    centroids: object  #: (F, 3) float32
    tri_box: object  #: (F, 6) float32: each row's box
    box: np.ndarray  #: (6,) float32 on the host: the rows' box
    row_of_key: np.ndarray  #: (largest key + 1,) int32 on the host: each key's row, -1 for none
    row_of_key_device: object  #: the same on the device
    n_rows: int


def upload_rows(verts, ids):
    """``DeviceLevel`` of rows (``verts`` (F, 9) float32, tie keys ``ids``), F > 0."""
    verts = np.ascontiguousarray(verts)
    corners = verts.reshape(-1, 3, 3)
    tri_box = np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1).astype(FLOAT)
    centroids = (corners.sum(axis=1) / np.float32(3)).astype(FLOAT)
    box = np.concatenate([tri_box[:, :3].min(axis=0), tri_box[:, 3:].max(axis=0)])
    row_of_key = np.full(int(ids.max()) + 1, -1, np.int32)
    row_of_key[ids] = np.arange(len(ids), dtype=np.int32)
    return DeviceLevel(
        cuda.to_device(verts),
        cuda.to_device(np.ascontiguousarray(ids, np.int32)),
        cuda.to_device(centroids),
        cuda.to_device(tri_box),
        box.astype(FLOAT),
        row_of_key,
        cuda.to_device(row_of_key),
        len(ids),
    )


# Each level's rows on the device, uploaded on its first trace and kept while the level lives:
# a scene version shares the levels of the meshes it did not change (``Scene.with_changes``),
# so a frame that moves actors uploads no static triangle again.
DEVICE_LEVELS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def device_level(level, visible_rows):
    """``level``'s rows on the device (``DeviceLevel``, kept with it), or only ``visible_rows``
    (the rows a batch with one mask sees: uploaded for the query)."""
    if visible_rows is not None:
        return upload_rows(level.verts[visible_rows], level.ids[visible_rows])
    found = DEVICE_LEVELS.get(level)
    if found is None:
        found = DEVICE_LEVELS[level] = upload_rows(level.verts, level.ids)
    return found


# One level traced at a time: a query's instance batches run side by side on host threads.
DEVICE_LOCK = threading.Lock()


def level_tracer(max_pairs=MAX_PAIRS):
    """What traces each level of a query on the GPU, in place of ``Scene._trace_level`` (same
    arguments; ``times`` is for deforming levels, which this backend refuses earlier): the base
    level, then each instance batch in its mesh's space, as the CPU engine merges them. Returns
    ``Traced``: best_t; for closest best_tri (the level's kernel row), hit_u and hit_v; for
    ANY_HIT a row where the ray is blocked; for COUNT and ALL_HITS n_hits and the lists
    (``collected``); no stats."""

    def trace(level, flags, origins, directions, tmin, tmax, ray_masks, visible_rows,
              tri_masks, threads, list_size, times=None):  # fmt: skip
        # A bad ray (or one that leaves float32 in a mesh's space) is named, not sent.
        origins, directions, tmin, tmax = check_query_rays(origins, directions, tmin, tmax)
        check_available()  # after the query's own checks: bad input is named first
        n = len(origins)
        best_t = np.array(tmax, FLOAT)
        best_tri = np.full(n, NO_HIT, INDEX)
        u = np.zeros(n, FLOAT)
        v = np.zeros(n, FLOAT)
        rays = (origins, directions, tmin, tmax)
        if not flags & MASKED:
            ray_masks, tri_masks = NO_MASKS, NO_MASKS
        n_rows = len(level) if visible_rows is None else len(visible_rows)
        if not (n and n_rows):
            if flags & COLLECT:
                return collected(flags, np.zeros(n, INDEX), None, None, tmax)
            return Traced(best_t, QueryArrays(best_tri, u, v, *([NO_MASKS] * 9)), [])
        with DEVICE_LOCK:
            rows = device_level(level, visible_rows)
            if flags & COLLECT:
                return trace_collect(
                    rows, visible_rows, flags, rays, ray_masks, tri_masks, list_size, max_pairs
                )
            cull_side = culling_side(flags)
            if flags & ANY_HIT:
                blocked = trace_any(rows, rays, ray_masks, tri_masks, cull_side, max_pairs)
                best_tri[blocked] = 0
            else:
                best_t, best_tri, u, v = trace_closest(
                    rows, rays, ray_masks, tri_masks, cull_side, max_pairs
                )
        if visible_rows is not None:
            found = best_tri != NO_HIT
            best_tri[found] = visible_rows[best_tri[found]]
        arrays = QueryArrays(best_tri, u, v, *([NO_MASKS] * 9))
        return Traced(best_t, arrays, [])

    return trace


def culling_side(flags):
    """det * side > 0 culls (``geometry.culled_side``): -1 for back, 1 for front, 0 for none."""
    return -1.0 if flags & CULL_BACK else (1.0 if flags & CULL_FRONT else 0.0)


def trace_collect(rows, visible_rows, flags, rays, ray_masks, tri_masks, list_size, max_pairs):
    """``Traced`` of a COUNT or ALL_HITS trace of a level's rows (``DeviceLevel``; kernel rows
    ``visible_rows`` of the level, or None for all): n_hits, each ray's crossings (COUNT) or the
    hits its list holds (ALL_HITS: its ``list_size`` nearest, list_t and list_tri in (t, tie
    key) order)."""
    n = len(rays[0])
    width = min(list_size, rows.n_rows) if flags & ALL_HITS else 0
    counts = np.zeros(n, INDEX)
    keys = np.full((n, width), kernels.NO_KEY, np.uint64)
    trace_crossings(rows, rays, ray_masks, tri_masks, culling_side(flags), counts, keys, max_pairs)
    return collected(flags, counts, keys, rows.row_of_key, rays[3], visible_rows)


def collected(flags, counts, keys, row_of_key, tmax, visible_rows=None):
    """``Traced`` of crossing ``counts`` and, for ALL_HITS, unsorted ``keys`` (n, width)
    (None: no rows, no hits); ``row_of_key`` maps keys to rows, then ``visible_rows`` (or
    None) to the level's; best_t is the rays' ``tmax``."""
    n = len(counts)
    list_t = np.empty((0, 0), FLOAT)
    list_tri = np.empty((0, 0), INDEX)
    if flags & ALL_HITS:
        if keys is None:
            keys = np.full((n, 0), kernels.NO_KEY, np.uint64)
        keys.sort(axis=1)  # nearest first: (t, tie key) order
        held = keys != kernels.NO_KEY
        counts = np.minimum(counts, keys.shape[1]).astype(INDEX)
        list_t = key_distances(keys)
        list_tri = np.full(keys.shape, NO_HIT, INDEX)
        if held.any():
            found = row_of_key[(keys[held] & kernels.LOW32).astype(np.int64)]
            list_tri[held] = found if visible_rows is None else visible_rows[found]
    empty = np.zeros(0, np.uint32)
    arrays = QueryArrays(
        np.zeros(0, INDEX), np.zeros(0, FLOAT), np.zeros(0, FLOAT), empty, empty, empty, counts,
        list_t, list_tri, empty, empty, empty,
    )  # fmt: skip
    return Traced(np.array(tmax, FLOAT), arrays, [])


def trace_crossings(rows, rays, ray_masks, tri_masks, cull_side, counts, keys, max_pairs):
    """Each ray's crossings of a level's rows (``DeviceLevel``) into ``counts``, and its
    ``keys.shape[1]`` smallest (t, tie key) keys, unsorted, into ``keys`` (NO_KEY where it has
    fewer); the rays in chunks whose lists fit MAX_LIST_BYTES."""
    n, width = keys.shape
    per_chunk = max(1, MAX_LIST_BYTES // (8 * max(width, 1)))
    for lo in range(0, n, per_chunk):
        part = slice(lo, min(n, lo + per_chunk))
        masks = ray_masks[part] if len(ray_masks) else ray_masks
        chunk = device_rays(*(a[part] for a in rays), masks, tri_masks)
        counts[part], keys[part] = crossings_of_chunk(
            rows, chunk, cull_side, counts[part], keys[part], max_pairs
        )


def crossings_of_chunk(rows, chunk, cull_side, counts, keys, max_pairs):
    """(counts, keys) of one chunk of rays (``device_rays``) on a level's rows."""
    o, d, inv_d, lo, hi, ray_masks, tri_masks = chunk
    counts_d = cuda.to_device(counts)
    keys_d = cuda.to_device(keys)

    def run_leaves(frontier, kind):
        launch(
            kernels.leaf_crossings, frontier.ray_ids.shape[0], frontier.ray_ids,
            frontier.ray_node, kind, cuda.to_device(frontier.tri_lo),
            cuda.to_device(frontier.tri_n), frontier.rows, o, d, lo, hi, rows.verts, rows.keys,
            ray_masks, tri_masks, cull_side, counts_d, keys_d,
        )  # fmt: skip

    traverse((rows.centroids, rows.tri_box, rows.box), (o, inv_d, lo, hi), run_leaves, max_pairs)
    return counts_d.copy_to_host(), keys_d.copy_to_host()


def device_rays(origins, directions, tmin, tmax, ray_masks, tri_masks):
    """A level's rays and masks on the device: origins, directions, inverse directions, tmin,
    tmax, ray masks, row masks."""
    with np.errstate(divide="ignore", over="ignore"):
        inv_dirs = (np.float32(1.0) / directions).astype(FLOAT)
    # NaN where 1/d overflows a nonzero component, as geometry.inverse: that axis is left out
    inv_dirs[(directions != 0) & np.isinf(inv_dirs)] = np.nan
    return tuple(
        cuda.to_device(np.ascontiguousarray(a))
        for a in (origins, directions, inv_dirs, tmin, tmax, ray_masks, tri_masks)
    )


def trace_closest(rows, rays, ray_masks, tri_masks, cull_side, max_pairs):
    """Each ray's nearest hit on a level's rows (``DeviceLevel``): (best_t, best_tri, u, v),
    best_t tmax and best_tri NO_HIT on a miss."""
    n = len(rays[0])
    o, d, inv_d, lo, hi, ray_masks, tri_masks = device_rays(*rays, ray_masks, tri_masks)
    best_key = cuda.to_device(np.full(n, kernels.NO_KEY, np.uint64))

    def run_leaves(frontier, kind):
        launch(
            kernels.leaf_closest, frontier.ray_ids.shape[0], frontier.ray_ids,
            frontier.ray_node, kind, cuda.to_device(frontier.tri_lo),
            cuda.to_device(frontier.tri_n), frontier.rows, o, d, lo, hi, rows.verts, rows.keys,
            ray_masks, tri_masks, cull_side, best_key,
        )  # fmt: skip

    traverse((rows.centroids, rows.tri_box, rows.box), (o, inv_d, lo, hi), run_leaves, max_pairs)
    out = [
        cuda.to_device(a)
        for a in (np.array(rays[3], FLOAT), np.full(n, NO_HIT, INDEX), np.zeros(n, FLOAT),
                  np.zeros(n, FLOAT))
    ]  # fmt: skip
    launch(kernels.finish_best, n, best_key, rows.row_of_key_device, o, d, rows.verts, NO_HIT, *out)
    return tuple(a.copy_to_host() for a in out)


def trace_any(rows, rays, ray_masks, tri_masks, cull_side, max_pairs):
    """Whether each ray hits any of a level's rows (``DeviceLevel``) in its window: (n,)
    bool."""
    n = len(rays[0])
    o, d, inv_d, lo, hi, ray_masks, tri_masks = device_rays(*rays, ray_masks, tri_masks)
    hit = cuda.to_device(np.zeros(n, np.uint8))

    def run_leaves(frontier, kind):
        launch(
            kernels.leaf_any, frontier.ray_ids.shape[0], frontier.ray_ids, frontier.ray_node,
            kind, cuda.to_device(frontier.tri_lo), cuda.to_device(frontier.tri_n),
            frontier.rows, o, d, lo, hi, rows.verts, ray_masks, tri_masks, cull_side, hit,
        )  # fmt: skip

    traverse((rows.centroids, rows.tri_box, rows.box), (o, inv_d, lo, hi), run_leaves, max_pairs)
    return hit.copy_to_host().astype(bool)


def check_query_rays(origins, directions, tmin, tmax):
    """ValueError naming the first bad ray, before any is sent to the device."""
    # float32 bounds (the host's checked ones) leave no window empty (``ray_window``)
    origins, directions, tmin, tmax, _ = check_rays(origins, directions, tmin, tmax)
    explain_bad_rays(origins, directions, tmin, tmax)  # nothing for a valid batch
    return origins, directions, tmin, tmax


def closest(scene, origins, directions, tmin=None, tmax=None, *, cull="none", mask=None,
            time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.closest`` on the GPU: the same ``Hits``, bit for bit (no ``stats``); the levels
    are traced here, their answers merged on the host as the CPU engine merges them."""
    check_supported(scene, max_pairs)
    tracer = level_tracer(max_pairs)
    return scene._closest(
        origins, directions, tmin, tmax, cull, mask, "sampling", None, False, time, tracer
    )


def occluded(scene, origins, directions, tmin=None, tmax=None, *, cull="none", mask=None,
             time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.occluded`` on the GPU: the same ``Occlusion`` (no ``stats``)."""
    check_supported(scene, max_pairs)
    tracer = level_tracer(max_pairs)
    return scene._occluded(
        origins, directions, tmin, tmax, cull, mask, "sampling", None, False, time, tracer
    )


def count(scene, origins, directions, tmin=None, tmax=None, *, cull="none", mask=None,
          time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.count`` on the GPU: the same ``Counts`` (no ``stats``)."""
    check_supported(scene, max_pairs)
    tracer = level_tracer(max_pairs)
    return scene._count(
        origins, directions, tmin, tmax, cull, mask, "sampling", None, False, time, tracer
    )


def hits(scene, origins, directions, tmin=None, tmax=None, *, max_hits=16, cull="none",
         mask=None, time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.hits`` on the GPU: the same ``HitList`` (no ``stats``).

    Each ray keeps its min(max_hits, triangles) + 1 nearest keys on the device, 8 bytes each;
    a batch whose lists need more than ``MAX_LIST_BYTES`` (2 GiB) is traced in chunks of rays
    that fit."""
    check_supported(scene, max_pairs)
    tracer = level_tracer(max_pairs)
    return scene._hits(
        origins, directions, tmin, tmax, max_hits, cull, mask, "sampling", None, False, time,
        tracer,
    )  # fmt: skip


def key_distances(keys):
    """The float32 t of ``kernels.tie_order_key`` keys (the inverse of its monotonic bits)."""
    bits = keys >> np.uint64(32)
    positive = bits >= kernels.SIGN32
    bits = np.where(positive, bits ^ kernels.SIGN32, bits ^ kernels.LOW32)
    return bits.astype(np.uint32).view(FLOAT)
