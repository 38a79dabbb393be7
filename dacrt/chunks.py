"""Thread scheduling: how a batch is cut into chunks of rays, and the threads that trace them.

Rays from about one point (a camera, a point light) go in contiguous chunks in input order.
Other rays go as one chunk per thread: contiguous runs when the input order is already coherent
(rays from an image's hit points), else slabs of origins along the axis where they spread most,
cut so that each slab holds about the same work. Answers do not depend on the chunks.
"""

import contextvars
import itertools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .config import (
    CHUNK_SAMPLE_RAYS,
    COHERENT_CHUNK_RAYS,
    COHERENT_CHUNK_RAYS_ONE_THREAD,
    COHERENT_CHUNKS_PER_THREAD,
    COHERENT_ORIGIN_SPREAD,
    COHERENT_RAYS_PER_TRIANGLE,
    DENSITY_GRID,
    MIN_RAYS_PER_THREAD,
    MIN_RAYS_TO_SPLIT_TRIANGLES,
    ORDERED_NEIGHBOUR_DISTANCE,
    ORIGIN_SPREAD_SAMPLE_RAYS,
    SPLIT_TRIANGLES_RAYS_PER_TRIANGLE,
    inline,
    jit,
)
from .contracts import INDEX


def usable_cores(cgroup: Path = Path("/sys/fs/cgroup")) -> int:
    """The cores this process may use: those its CPU affinity allows (``taskset``, a container's
    cpuset), fewer where a cgroup's CPU quota (``docker run --cpus``) is lower."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    quotas = [("cpu.max",), ("cpu/cpu.cfs_quota_us", "cpu/cpu.cfs_period_us")]  # cgroup v2, v1
    for files in quotas:
        try:
            text = " ".join((cgroup / name).read_text() for name in files).split()
            quota, period = int(text[0]), int(text[1])
        except (OSError, ValueError, IndexError):  # no such cgroup, or "max": no quota
            continue
        if quota > 0 and period > 0:
            cores = min(cores or 1, math.ceil(quota / period))
    return max(1, cores or 1)


N_CORES = usable_cores()


@inline
def grid_index(value, lo, extent, n):
    """The cell holding ``value`` along one axis of n cells over [lo, lo + extent], clamped."""
    k = int((value - lo) / extent * n) if extent > 0 else 0
    return min(max(k, 0), n - 1)


@jit
def centre_counts(tri_bounds, box, n):
    """How many triangles have their box's centre in each cell of an n^3 grid over ``box``.

    tri_bounds : (F, 6) float32; box : (6,) float32. Returns (n^3,) int64."""
    counts = np.zeros(n * n * n, np.int64)
    for row in range(tri_bounds.shape[0]):
        cell = 0
        for a in range(3):
            centre = 0.5 * (tri_bounds[row, a] + tri_bounds[row, a + 3])
            cell = cell * n + grid_index(centre, box[a], box[a + 3] - box[a], n)
        counts[cell] += 1
    return counts


@jit
def origin_weights(points, counts, box, n):
    """sqrt(1 + the count of each point's cell); points outside ``box`` weigh 1.

    points : (m, 3) float32; counts : (n^3,) int64 (``centre_counts``). Returns (m,) float64."""
    weights = np.ones(points.shape[0])
    for i in range(points.shape[0]):
        cell = 0
        inside = True
        for a in range(3):
            extent = box[a + 3] - box[a]
            offset = points[i, a] - box[a]
            if extent <= 0 or not 0 <= offset <= extent:  # NaN too: a bad ray, named later
                inside = False
                break
            cell = cell * n + grid_index(points[i, a], box[a], extent, n)
        if inside:
            weights[i] = np.sqrt(1.0 + counts[cell])
    return weights


@inline
def slab_of(value, cuts):
    """The slab holding ``value``: how many of the sorted ``cuts`` are at or below it (slab k:
    cuts[k-1] <= value < cuts[k]; NaN falls in slab 0)."""
    k = 0
    for c in range(len(cuts)):
        k += 1 if value >= cuts[c] else 0
    return k


@jit
def slab_ids(values, cuts, k):
    """The ids (int32, increasing) of the values in slab k, gathered by the thread that traces
    the slab: a counting pass, then a compaction with no branch on the values (they fall on
    either side of a cut at random)."""
    n = 0
    for i in range(len(values)):
        n += 1 if slab_of(values[i], cuts) == k else 0
    ids = np.empty(n + 1, np.int32)  # the compaction writes once past the last id
    j = 0
    for i in range(len(values)):
        ids[j] = i
        j += 1 if slab_of(values[i], cuts) == k else 0
    return ids[:n]


#: The most threads the shared pool starts: more than any useful ``threads`` on this machine
POOL_THREADS = max(32, 4 * (os.cpu_count() or 1))
#: The threads queries share. It starts a thread only when none is idle, so it holds as many as
#: calls have needed at once, whatever ``threads`` they asked for.
POOL = ThreadPoolExecutor(max_workers=POOL_THREADS, thread_name_prefix="dacrt")


def map_on_threads(fn, n_items, n_workers):
    """[fn(0), ..., fn(n_items - 1)], on this thread and up to n_workers - 1 of the shared
    pool's, each taking the next item when done with one. This thread works too, and does not
    wait for pool threads that have not started (busy with other queries): a query never
    queues behind another, at worst it runs on its own thread."""
    if n_workers <= 1 or n_items <= 1:
        return [fn(k) for k in range(n_items)]
    results = [None] * n_items
    taken = itertools.count()  # next() of a count is atomic: each item is taken once
    failed = []  # an item raised: the others are not started

    def work():
        while not failed and (k := next(taken)) < n_items:
            try:
                results[k] = fn(k)
            except BaseException:
                failed.append(k)
                raise

    # Each helper runs in a copy of this thread's context: what the caller set holds for its items.
    helpers = [
        POOL.submit(contextvars.copy_context().run, work)
        for _ in range(min(n_workers, n_items) - 1)
    ]
    try:
        work()
    finally:
        for helper in helpers:
            if not helper.cancel():  # started: it is running an item of this call
                helper.exception()  # waits; its error is raised below
    for helper in helpers:
        if not helper.cancelled() and helper.exception() is not None:
            raise helper.exception()
    return results


def from_one_point(origins, box):
    """Whether the rays (a sample of up to ORIGIN_SPREAD_SAMPLE_RAYS) start within
    COHERENT_ORIGIN_SPREAD of the size of ``box`` (6,) of each other."""
    sample = origins[:: max(1, len(origins) // ORIGIN_SPREAD_SAMPLE_RAYS)]
    spread = float(np.max(sample.max(axis=0) - sample.min(axis=0)))
    size = float(np.max(box[3:] - box[:3]))
    return spread <= COHERENT_ORIGIN_SPREAD * size


def splits_triangles(n_rays, n_triangles, threads):
    """Whether a closest or occlusion batch of n_rays goes to two threads as halves of the
    triangles (``Scene._trace_halves``) rather than as chunks of rays."""
    return (
        threads > 1
        and n_rays >= MIN_RAYS_TO_SPLIT_TRIANGLES
        and n_rays < SPLIT_TRIANGLES_RAYS_PER_TRIANGLE * n_triangles
    )


def count_chunks(n_rays, n_triangles, threads, coherent):
    """How many chunks to cut a batch of n_rays into, for ``threads`` threads; ``coherent``:
    the rays start from about one point (``from_one_point``)."""
    n_chunks = max(1, min(threads, n_rays // MIN_RAYS_PER_THREAD))
    if not coherent:
        return n_chunks
    # Each chunk repeats the work on the triangles: at least two rays a triangle in each.
    chunk_rays = max(COHERENT_CHUNK_RAYS, COHERENT_RAYS_PER_TRIANGLE * n_triangles)
    if threads == 1:
        chunk_rays = min(COHERENT_CHUNK_RAYS_ONE_THREAD, chunk_rays)
    n_chunks = max(n_chunks, -(-n_rays // chunk_rays))
    if threads > 1:
        n_chunks = max(
            n_chunks,
            min(
                threads * COHERENT_CHUNKS_PER_THREAD,
                n_rays // MIN_RAYS_PER_THREAD,
                n_rays // (COHERENT_RAYS_PER_TRIANGLE * n_triangles),
            ),
        )
        if n_chunks > threads:  # as many chunks on every thread
            n_chunks = -(-n_chunks // threads) * threads
    return n_chunks


def plan_chunks(origins, n_chunks, keep_order, box, density):
    """How the batch is cut into chunks (``chunk_ids``): None for contiguous runs in input
    order, else (values, cuts): slab k holds the rays whose values fall in it.

    origins : (n, 3) float32; box : (6,) float32, the scene's; density : a function of no
    arguments returning the scene's ``centre_counts`` over DENSITY_GRID (called only when slabs
    are cut). In input order when ``keep_order`` or when that order is already coherent
    (consecutive origins much closer than origins far apart in the batch). Otherwise slabs of
    about equal work along the axis where the origins spread most, cut at weighted quantiles of
    a sample: a slab's rays start near each other, so the chunks repeat less of each other's
    work."""
    step = max(1, len(origins) // CHUNK_SAMPLE_RAYS)
    if keep_order or n_chunks == 1 or step == 1:
        return None
    sample = origins[::step]
    near = np.linalg.norm(origins[1::step] - origins[:-1:step], axis=1)  # input neighbours
    far = np.linalg.norm(sample - sample[::-1], axis=1)
    if np.mean(near) < ORDERED_NEIGHBOUR_DISTANCE * np.mean(far):
        return None
    axis = int(np.argmax(sample.max(axis=0) - sample.min(axis=0)))
    weights = origin_weights(sample, density(), box, DENSITY_GRID)
    order = np.argsort(sample[:, axis], kind="stable")
    cumulative = np.cumsum(weights[order])
    at = np.searchsorted(cumulative, np.arange(1, n_chunks) / n_chunks * cumulative[-1])
    cuts = sample[order[np.minimum(at, len(order) - 1)], axis].astype(origins.dtype)
    return np.ascontiguousarray(origins[:, axis]), cuts  # one signature for slab_ids


def chunk_ids(plan, n_rays, n_chunks, k):
    """The ray ids (int32, increasing) of chunk k of n_chunks, as ``plan_chunks`` cut the
    batch."""
    if plan is None:
        return np.arange(k * n_rays // n_chunks, (k + 1) * n_rays // n_chunks, dtype=INDEX)
    values, cuts = plan
    return slab_ids(values, cuts, k)
