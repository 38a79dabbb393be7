"""The public query surface: ``Scene``, ``Scene.closest`` and ``Scene.occluded``.

This is the only module that checks and converts input. A Scene keeps its triangles and what is
O(F) and cheap to derive from them (gathered vertices, boxes); every query partitions rays and
triangles from scratch and keeps nothing afterwards.
"""

import functools
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .config import inline, jit
from .contracts import (
    FLOAT,
    INDEX,
    MODE_CLOSEST,
    MODE_OCCLUDED,
    STAT_NAMES,
    STAT_RAYS,
    STAT_TRIANGLES,
    STRATEGY_CODES,
    Hits,
)
from .leaf import NO_HIT
from .rays import new_records, pack_rays, uniform_origin, unpack_best_t
from .rayspace import trace_ray_space
from .results import finish_closest, unit_normals
from .traversal import trace_object_split
from .triangles import gather_triangles, triangle_boxes
from .validation import (
    check_mesh,
    check_rays,
    check_strategy,
    check_threads,
    explain_bad_rays,
)

N_CORES = os.cpu_count() or 1
# Below this many rays a single thread is quicker than splitting the triangles' work twice.
MIN_RAYS_PER_THREAD = 16384
# Rays from about one point (a camera, a point light: origins within this fraction of the
# scene's size) are traced in contiguous chunks of at most COHERENT_CHUNK_RAYS, in input
# order: a chunk's records stay in cache (8 MiB), its rays see fewer triangles, and chunks
# balance the threads. With several threads, at least COHERENT_CHUNKS_PER_THREAD each: bands
# of an image differ in cost, and more chunks even the threads out. Measured on 1M camera rays
# (Sibenik, Sponza) against 131,072-ray chunks: sampling 1.06-1.13x on one thread (each chunk
# repeats the work on the triangles, and ray sampling gains with more rays per node),
# 1.03-1.09x on two with 6 chunks (4 chunks lost 1-11 %). On one thread, a chunk's records
# have the cache to themselves, and a scene with many triangles takes chunks of at least
# COHERENT_RAYS_PER_TRIANGLE rays a triangle, up to COHERENT_CHUNK_RAYS_ONE_THREAD (16 MiB):
# each chunk repeats the work on the triangles. 524,288 against 262,144 on one thread,
# sampling, side by side: Sponza (262K triangles) 1000² 1.11x (two runs), 2048² 1.09x; but
# Sibenik (74K) 1000² 0.96-0.97x (two runs; 1024² 0.99-1.01x), conference (69K) 0.98-1.00x,
# dragon (100K) 1.00x; two threads, 2048²: Sibenik 0.98x, Sponza 1.02x.
# Other rays go as one chunk per thread: contiguous ranges when neighbours in input order start
# near each other (rays from an image's hit points), else slabs of origins (see _chunk_plan).
COHERENT_ORIGIN_SPREAD = 0.1
COHERENT_CHUNK_RAYS = 262144
COHERENT_CHUNK_RAYS_ONE_THREAD = 524288
COHERENT_RAYS_PER_TRIANGLE = 2
COHERENT_CHUNKS_PER_THREAD = 3
# Input order counts as coherent when consecutive origins are closer than this fraction of the
# distance between origins far apart in the batch (sampled).
ORDERED_NEIGHBOUR_DISTANCE = 0.5
# Rays sampled for that test and to place the slabs' boundaries.
CHUNK_SAMPLE_RAYS = 4096
# Slabs are cut so that each holds the same estimated work, a sample ray's weight being
# sqrt(1 + triangles whose centre lies in its origin's cell of a DENSITY_GRID^3 grid over the
# scene): a ray that starts among many triangles costs more. Measured on uniform random rays,
# two slabs traced alone (the slower one, ms): Sibenik 111 -> 101, conference 86 -> 79, dragon
# 127 -> 122, armadillo 135 -> 124, Sponza 146 -> 147 (density 1 weighed too much: Sibenik 113).
DENSITY_GRID = 16


@inline
def grid_index(value, lo, extent, n):
    """The cell holding ``value`` along one axis of n cells over [lo, lo + extent], clamped."""
    k = int((value - lo) / extent * n) if extent > 0 else 0
    return min(max(k, 0), n - 1)


@jit
def centre_counts(tri_bounds, box, n):
    """How many triangles have their box's centre in each cell of an n^3 grid over ``box``."""
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
    """sqrt(1 + the count of each point's cell); points outside ``box`` weigh 1."""
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
    the slab, side by side with the other slabs' threads: a counting pass, then a compaction
    with no branch on the values (they fall on either side of a cut at random). 1M rays, two
    threads: 1.1 ms each, where grouping every slab's ids on the calling thread took 2.2 ms."""
    n = 0
    for i in range(len(values)):
        n += 1 if slab_of(values[i], cuts) == k else 0
    ids = np.empty(n + 1, np.int32)  # the compaction writes once past the last id
    j = 0
    for i in range(len(values)):
        ids[j] = i
        j += 1 if slab_of(values[i], cuts) == k else 0
    return ids[:n]


@functools.cache
def _pool(n_workers):
    """A thread pool of n_workers, kept for later queries with the same thread count."""
    return ThreadPoolExecutor(max_workers=n_workers, thread_name_prefix="dacrt")


def _map_on_threads(fn, n_items, n_workers):
    """[fn(0), ..., fn(n_items - 1)], on n_workers threads (a queue: each takes the next item
    when done with one), or in this thread for one."""
    if n_workers == 1:
        return [fn(k) for k in range(n_items)]
    return list(_pool(n_workers).map(fn, range(n_items)))


def chunk_ids(plan, n_rays, n_chunks, k):
    """The ray ids (int32, increasing) of chunk k of n_chunks, as ``Scene._chunk_plan`` cut
    the batch."""
    if plan is None:
        return np.arange(k * n_rays // n_chunks, (k + 1) * n_rays // n_chunks, dtype=INDEX)
    values, cuts = plan
    return slab_ids(values, cuts, k)


class Scene:
    """Triangle meshes to cast rays into.

    meshes : sequence of (vertices (V, 3) float, faces (F, 3) int) pairs; hits report a mesh by
        its position in this sequence and a triangle by its row in that mesh's faces.
    """

    def __init__(self, meshes):
        meshes = list(meshes)
        checked = [check_mesh(i, vertices, faces) for i, (vertices, faces) in enumerate(meshes)]
        counts = [len(faces) for _, faces in checked]
        self.n_meshes = len(checked)
        self.mesh_offsets = np.zeros(self.n_meshes + 1, np.int64)
        self.mesh_offsets[1:] = np.cumsum(counts)
        self.n_triangles = int(self.mesh_offsets[-1])

        tri_verts = np.empty((self.n_triangles, 9), FLOAT)
        live = np.empty(self.n_triangles, np.bool_)
        corner_box = np.array([np.inf] * 3 + [-np.inf] * 3, FLOAT)
        for (vertices, faces), first_row in zip(checked, self.mesh_offsets):
            gather_triangles(vertices, faces, first_row, tri_verts, live, corner_box)
        # Degenerate (zero-area) triangles never hit: leave them out of every query.
        if live.all():
            self._tri_global = np.arange(self.n_triangles, dtype=INDEX)
        else:
            self._tri_global = np.flatnonzero(live).astype(INDEX)
            tri_verts = tri_verts[live]
        self._tri_verts = tri_verts
        self._tri_bounds = np.empty((len(tri_verts), 6), FLOAT)
        self._box = np.empty(6, FLOAT)
        triangle_boxes(tri_verts, self._tri_bounds, self._box)
        if not len(tri_verts):
            self._box[:] = 0
        # Bounds of the referenced vertices: every corner, degenerate triangles included.
        self.bounds = corner_box.reshape(2, 3) if self.n_triangles else np.zeros((2, 3), FLOAT)

    @property
    def nbytes(self):
        """Bytes held by the scene's arrays, with those derived on demand once they exist."""
        derived = [
            self.__dict__[name]
            for name in ("_unit_normals", "_centre_counts")
            if name in self.__dict__
        ]
        return int(
            self._tri_verts.nbytes
            + self._tri_bounds.nbytes
            + self._tri_global.nbytes
            + self.mesh_offsets.nbytes
            + sum(array.nbytes for array in derived)
        )

    @functools.cached_property
    def _centre_counts(self):
        """Triangle centres per cell of the DENSITY_GRID grid, for slab cuts: derived once per
        scene, on its first incoherent query on several threads (1 ms on Sponza)."""
        return centre_counts(self._tri_bounds, self._box, DENSITY_GRID)

    @functools.cached_property
    def _unit_normals(self):
        """Each kernel row's unit normal (12 bytes a triangle), for batches of many rays:
        derived once per scene, on its first such ``closest`` (0.3 ms on Sibenik)."""
        normals = np.empty((len(self._tri_verts), 3), FLOAT)
        unit_normals(self._tri_verts, normals)
        return normals

    _no_normals = np.empty((0, 3), FLOAT)

    def __repr__(self):
        return f"Scene({self.n_meshes} meshes, {self.n_triangles} triangles)"

    def closest(
        self,
        origins,
        directions,
        tmin=None,
        tmax=None,
        *,
        strategy="sampling",
        threads=None,
        stats=False,
    ):
        """Nearest hit of each ray ``origins + t * directions`` with tmin <= t <= tmax.

        origins, directions : (n, 3) float; directions need not be unit, t is in their units
        tmin, tmax : None, a number, or (n,) float (defaults 0 and +inf)
        strategy : one of ``dacrt.STRATEGIES``; all give the same answers
        threads : None for every core, or a positive int
        Returns ``Hits``; ties in t go to the lowest (mesh, triangle).
        """
        t, best_tri, u, v, counters = self._trace(
            MODE_CLOSEST, origins, directions, tmin, tmax, strategy, threads
        )
        n = len(t)
        mesh = np.empty(n, INDEX)  # every element is written by finish_closest
        prim = np.empty(n, INDEX)
        normal = np.empty((n, 3), FLOAT)
        # A batch with at least as many rays as triangles looks up each triangle's normal,
        # derived once per scene; a smaller one derives each hit's (1M hits: 2.7 against 6.2 ms).
        normals = self._unit_normals if n >= self.n_triangles else self._no_normals
        # In place: t, u, v are the trace's own arrays (12 bytes a ray not allocated, not copied).
        # In as many parts as the trace had threads (2.7 ns a hit with the table, 6.2 without,
        # on one thread).
        n_parts = max(1, min(check_threads(threads, N_CORES), n // MIN_RAYS_PER_THREAD))
        bounds = [k * n // n_parts for k in range(n_parts + 1)]

        def finish(k):
            part = slice(bounds[k], bounds[k + 1])
            finish_closest(
                t[part],
                best_tri[part],
                self._tri_global,
                self.mesh_offsets,
                self._tri_verts,
                normals,
                mesh[part],
                prim[part],
                normal[part],
            )

        _map_on_threads(finish, n_parts, n_parts)
        return Hits(t, mesh, prim, u, v, normal, counters if stats else None)

    def occluded(
        self,
        origins,
        directions,
        tmin=None,
        tmax=None,
        *,
        strategy="sampling",
        threads=None,
        stats=False,
    ):
        """Whether each ray hits anything with tmin <= t <= tmax (it stops at its first hit).

        Same arguments as ``closest``. Returns (n,) bool, or (occluded, stats dict) when
        ``stats`` is true."""
        _, best_tri, _, _, counters = self._trace(
            MODE_OCCLUDED, origins, directions, tmin, tmax, strategy, threads
        )
        occluded = best_tri != NO_HIT
        return (occluded, counters) if stats else occluded

    def _from_one_point(self, origins):
        """Whether the rays (a sample of up to 1024) start within COHERENT_ORIGIN_SPREAD of
        the scene's size of each other."""
        sample = origins[:: max(1, len(origins) // 1024)]
        spread = float(np.max(sample.max(axis=0) - sample.min(axis=0)))
        size = float(np.max(self._box[3:] - self._box[:3]))
        return spread <= COHERENT_ORIGIN_SPREAD * size

    def _chunk_plan(self, origins, n_chunks, keep_order):
        """How the batch is cut into chunks (``chunk_ids``): None for contiguous runs in input
        order, else (values, cuts): slab k holds the rays whose values fall in it.

        In input order when ``keep_order`` (rays from one point) or when that order is already
        coherent (consecutive origins much closer than origins far apart in the batch, as for
        rays from an image's hit points). Otherwise slabs of about equal work along the axis
        where the origins spread most, cut at weighted quantiles of a sample (DENSITY_GRID): a
        slab's rays start near each other, so the chunks repeat less of each other's work (two
        threads, 1M rays: 1.08-1.16x on Sponza's rays from a sphere around it and on uniform
        random rays, 1.01-1.08x on Sibenik's). Answers do not depend on the chunks."""
        step = max(1, len(origins) // CHUNK_SAMPLE_RAYS)
        if keep_order or n_chunks == 1 or step == 1:
            return None
        sample = origins[::step]
        near = np.linalg.norm(origins[1::step] - origins[:-1:step], axis=1)  # input neighbours
        far = np.linalg.norm(sample - sample[::-1], axis=1)
        if np.mean(near) < ORDERED_NEIGHBOUR_DISTANCE * np.mean(far):
            return None
        axis = int(np.argmax(sample.max(axis=0) - sample.min(axis=0)))
        weights = origin_weights(sample, self._centre_counts, self._box, DENSITY_GRID)
        order = np.argsort(sample[:, axis], kind="stable")
        cumulative = np.cumsum(weights[order])
        at = np.searchsorted(cumulative, np.arange(1, n_chunks) / n_chunks * cumulative[-1])
        cuts = sample[order[np.minimum(at, len(order) - 1)], axis].astype(origins.dtype)
        return np.ascontiguousarray(origins[:, axis]), cuts  # one signature for slab_ids

    def _trace(self, mode, origins, directions, tmin, tmax, strategy, threads):
        """Run the kernels; returns best_t, best_tri (kernel rows), u, v and the counters."""
        strategy = check_strategy(strategy)
        threads = check_threads(threads, N_CORES)
        origins, directions, tmin, tmax = check_rays(origins, directions, tmin, tmax)
        n_rays = len(origins)
        best_t = tmax.copy()  # the records' best_t, scattered back after the trace
        best_tri = np.full(n_rays, NO_HIT, INDEX)
        hit_u = np.zeros(n_rays, FLOAT)
        hit_v = np.zeros(n_rays, FLOAT)
        counters = dict.fromkeys(STAT_NAMES, 0)
        counters["rays"] = n_rays
        counters["triangles"] = self.n_triangles
        n_live = len(self._tri_verts)
        if n_rays == 0 or n_live == 0:
            explain_bad_rays(origins, directions, tmin, tmax)  # no kernel will check them
            return best_t, best_tri, hit_u, hit_v, counters
        n_chunks = max(1, min(threads, n_rays // MIN_RAYS_PER_THREAD))
        code = STRATEGY_CODES[strategy]
        ray_space = code == STRATEGY_CODES["rayspace"]
        # The values are not checked yet (each chunk checks its own): a bad ray may make
        # the choice of chunks poor, never wrong.
        with np.errstate(invalid="ignore", over="ignore"):
            coherent = self._from_one_point(origins)
            if coherent:
                chunk_rays = COHERENT_CHUNK_RAYS
                if threads == 1:
                    chunk_rays = min(
                        COHERENT_CHUNK_RAYS_ONE_THREAD,
                        max(chunk_rays, COHERENT_RAYS_PER_TRIANGLE * n_live),
                    )
                n_chunks = max(n_chunks, -(-n_rays // chunk_rays))
                if threads > 1:
                    n_chunks = max(
                        n_chunks,
                        min(threads * COHERENT_CHUNKS_PER_THREAD, n_rays // MIN_RAYS_PER_THREAD),
                    )
            # rayspace splits the rays by origin and direction itself: it keeps the input order.
            plan = self._chunk_plan(origins, n_chunks, coherent or ray_space)

        def run(chunk):
            ray_ids = chunk_ids(plan, n_rays, n_chunks, chunk)
            rays = new_records(len(ray_ids))
            if not pack_rays(origins, directions, tmin, tmax, ray_ids, rays):
                return None  # a bad ray: no kernel traces this chunk
            fixed_origin = uniform_origin(rays, len(ray_ids))
            tri_ids = np.arange(n_live, dtype=INDEX)
            chunk_stats = np.zeros(len(STAT_NAMES), np.int64)
            hit_mask = np.empty(len(ray_ids), np.bool_)
            tri_bins = np.empty(n_live, np.uint8)
            if ray_space:
                trace_ray_space(
                    mode,
                    self._tri_verts,
                    self._tri_bounds,
                    self._box,
                    rays,
                    ray_ids,
                    tri_ids,
                    best_tri,
                    hit_u,
                    hit_v,
                    hit_mask,
                    tri_bins,
                    chunk_stats,
                    fixed_origin,
                )
            else:
                trace_object_split(
                    code,
                    mode,
                    self._tri_verts,
                    self._tri_bounds,
                    self._box,
                    rays,
                    ray_ids,
                    0,
                    len(ray_ids),
                    tri_ids,
                    0,
                    n_live,
                    best_tri,
                    hit_u,
                    hit_v,
                    hit_mask,
                    tri_bins,
                    chunk_stats,
                    fixed_origin,
                )
            unpack_best_t(rays, ray_ids, best_t)
            return chunk_stats

        per_chunk = _map_on_threads(run, n_chunks, min(threads, n_chunks))
        if any(chunk_stats is None for chunk_stats in per_chunk):
            explain_bad_rays(origins, directions, tmin, tmax)
            raise ValueError("the batch holds an invalid ray")  # explain_bad_rays names it
        totals = np.sum(per_chunk, axis=0)
        for i, name in enumerate(STAT_NAMES):
            if i not in (STAT_RAYS, STAT_TRIANGLES):
                counters[name] = int(totals[i])
        counters["max_depth"] = int(max(c[STAT_NAMES.index("max_depth")] for c in per_chunk))
        return best_t, best_tri, hit_u, hit_v, counters
