"""One decorator policy for every kernel, and every tuning constant of the engine.

Kernels are compiled with ``cache=True`` (compiled once per machine), ``nogil=True`` (ray chunks
run on Python threads side by side) and ``error_model="numpy"`` (division by zero gives inf, no
exception check). No fastmath: the slab test relies on IEEE infinities, and contraction into FMA
could give one ray-triangle pair two different ``t`` in two call sites, which would break the
promise that every strategy gives the same answer.

The constants are read by the kernels when they compile: Numba freezes them into the compiled
code, and its cache does not notice a change here, so clear the kernels' cache (``dacrt.cache``)
after changing one. docs/benchmarks.md gives the measurements behind each value.
"""

import logging

import numba

log = logging.getLogger("dacrt")


def _njit(**options):
    """``numba.njit(cache=True, **options)``, or without Numba's cache where Numba finds no
    folder to file it in when the kernel is defined (sources and home read-only, no
    NUMBA_CACHE_DIR): ``dacrt.cache.use_cache_dir`` gives every kernel its cache then."""
    cached, uncached = numba.njit(cache=True, **options), numba.njit(**options)

    def decorate(function):
        try:
            return cached(function)
        except RuntimeError as exc:  # "cannot cache function ...: no locator available"
            if "no locator available" not in str(exc):
                raise
            log.debug("dacrt: %s; its cache comes from dacrt.cache.use_cache_dir", exc)
            kernel = uncached(function)
            kernel.cache_deferred = True  # for dacrt.cache.dispatchers
            return kernel

    return decorate


jit = _njit(nogil=True, boundscheck=False, error_model="numpy")
inline = _njit(nogil=True, boundscheck=False, error_model="numpy", inline="always")

# ---- Object splits (traversal)
# Binned splits: 16 bins (Nabata et al. 2013, Sec. 5: 32): most binned nodes hold few triangles,
# and each pays per bin.
N_BINS = 16
# Afra's rule: use the cost function only when rays / triangles exceeds this, else split in the
# middle.
RAYS_PER_TRIANGLE_FOR_COST = 1.5
# SAH constants (C_T: node, C_I: triangle), as ratios.
SAH_C_T = 1.0
SAH_C_I = 1.0
# Leaves: brute force a node of R rays and T triangles when R*T <= LEAF_C_R*R + LEAF_C_T*T, its
# R*T tests against what going on would cost, counted in tests: filtering each ray, binning and
# partitioning each triangle. Always so at T <= LEAF_C_R or R <= LEAF_C_T.
LEAF_C_R = 4
LEAF_C_T = 16
# Halves of the storage order (``ranges``): a leaf range holds at most RANGE_LEAF_ROWS rows. A
# halved node of R rays and T triangles is brute-forced when R*T <= RANGE_LEAF_C_R*R +
# RANGE_LEAF_C_NODE: going on filters each ray against two boxes and pays two nodes' overhead,
# counted in tests, but reads no triangle.
RANGE_LEAF_ROWS = 8
RANGE_LEAF_C_R = 4
RANGE_LEAF_C_NODE = 32
# Deepest node; below it a node is brute-forced (keeps the explicit stack small and bounded).
MAX_DEPTH = 64

# ---- Ray sampling (traversal, the ``sampling`` strategy)
# 100 sample rays (the paper's count), only when more than 5,000 rays are active (the paper:
# 1,000): below that, a node's sample box tests cost more than the better split saves.
N_SAMPLE_RAYS = 100
MIN_RAYS_TO_SAMPLE = 5000
# ... and for occlusion rays only above 10,000: a ray that stops at its first hit does less work
# below a node than the sampled cost counts.
MIN_OCCLUSION_RAYS_TO_SAMPLE = 10000
# Fewer sample rays choose the split axis: it needs three means, not every candidate's counts.
AXIS_SAMPLE_RAYS = 32
# Cost of a ray-box test over a ray-triangle test (C_bv / C_tri of Eq. 5), as measured here: a
# vectorised filter step against a watertight triangle test.
BOX_TO_TRIANGLE_COST = 0.25

# ---- Ray-space hierarchies (rayspace)
# Termination: R*G < C_r*R + C_g*G.
RAYSPACE_C_R = 16.0
RAYSPACE_C_G = 16.0
# A ray-space leaf goes on with object splits (``trace_object_split``), which hold the one leaf;
# so does a node, at this depth or deeper, whose frustum kept more than this fraction of its
# parent's triangles (rays too incoherent for ray-space splits to pay).
RAYSPACE_MIN_DEPTH_TO_GIVE_UP = 8
RAYSPACE_KEPT_TO_GIVE_UP = 0.8
# ... at any depth when the rays' origins spread over more than this fraction of the scene
# (secondary and random rays): each hand-off re-partitions the triangles, so hand off early.
RAYSPACE_ORIGIN_SPREAD_TO_GIVE_UP = 0.1

# ---- Numerical margins (geometry, partition, rayspace)
# A box is culled only when its entry is beyond the ray's best t by more than this (relative):
# keeps culling conservative with respect to the rounding of triangle t.
CULL_MARGIN = 1e-5
# pbrt's robust slab test: grow the exit distance by 1 + 2*gamma(3) for float32.
SLAB_GROWTH = 1.0 + 2.0 * (3 * 2.0**-24) / (1 - 3 * 2.0**-24)
# Relative size of det below which a triangle counts as edge-on (float64 edge functions).
EDGE_ON_TOLERANCE = 1e-12
# Binning scales the centroids' extent by this, so the largest centroid falls in the last bin.
BIN_SHRINK = 1.0 - 1e-6
# Ray-space culling's slack, relative to the scene's size: absorbs the rounding of the frustum.
RAYSPACE_TOLERANCE = 1e-5

# ---- Leaves (leaf)
# Triangles a leaf gathers at a time into float64 rows, and rays per block of a leaf of few
# triangles.
LEAF_BLOCK = 64
# Lanes of the vectorised loops (8 float64 with AVX-512): a block of triangles is padded to a
# multiple of this, because the loop's scalar remainder costs several times a vectorised test.
LANES = 8
# A leaf of fewer than BY_RAYS_MAX_TRIANGLES triangles goes by rays (one vectorised loop over a
# block of rays per triangle) from BY_RAYS_MIN_RAYS rays: a block of rays copied to rows pays for
# itself from there.
BY_RAYS_MAX_TRIANGLES = 8
BY_RAYS_MIN_RAYS = 16

# ---- Ray records and partitions (rays, partition, rayspace)
# Rays per block of pack_rays: the fastest of 16-256 measured.
PACK_BLOCK = 32
# Records per block of uniform_origin's check.
UNIFORM_CHECK_BLOCK = 256
# Record rows are padded to a whole number of ROW_ALIGN records (4 KiB) plus ROW_SKEW: rows of
# exactly a power of two put a record's quads at the same low 12 address bits and in the same
# cache set, and a swap's loads then wait on the stores before them.
ROW_ALIGN = 1024
ROW_SKEW = 16
# Records per block of partition_by_mask: the fastest of 32-256 measured.
PARTITION_BLOCK = 128
# Rays per block of rayspace.partition_rays' comparisons.
COMPARE_BLOCK = 256

# ---- Threads and chunks (chunks, Scene)
# Below this many rays a single thread is quicker than splitting the triangles' work twice.
MIN_RAYS_PER_THREAD = 16384
# A closest or occlusion batch of fewer rays than this per triangle, on several threads, splits
# the triangles between two threads instead of the rays: each thread then does half the work
# on the triangles, which such a batch spends most of its time on.
SPLIT_TRIANGLES_RAYS_PER_TRIANGLE = 0.3
# ... from this many rays: the two threads' extra passes (a copy of the records each, the
# merge) cost less than a thread's half of the trace above it.
MIN_RAYS_TO_SPLIT_TRIANGLES = 4096
# Origins within this fraction of the scene's size count as one point ...
COHERENT_ORIGIN_SPREAD = 0.1
# ... judged on a sample of at most this many rays.
ORIGIN_SPREAD_SAMPLE_RAYS = 1024
# Rays from one point go in chunks of at most this many: a chunk's records stay in cache ...
COHERENT_CHUNK_RAYS = 262144
# ... unless that leaves a chunk fewer than this many rays a triangle: each chunk repeats the
# work on the triangles.
COHERENT_RAYS_PER_TRIANGLE = 2
# On one thread a chunk's records have the cache to themselves, so chunks may be larger.
COHERENT_CHUNK_RAYS_ONE_THREAD = 524288
# With several threads, at least this many chunks each (bands of an image differ in cost), while
# each keeps COHERENT_RAYS_PER_TRIANGLE.
COHERENT_CHUNKS_PER_THREAD = 3
# Input order counts as coherent when consecutive origins are closer than this fraction of the
# distance between origins far apart in the batch (sampled).
ORDERED_NEIGHBOUR_DISTANCE = 0.5
# Rays sampled for that test and to place the slabs' boundaries.
CHUNK_SAMPLE_RAYS = 4096
# A sample ray weighs sqrt(1 + the triangle centres in its origin's cell of a DENSITY_GRID^3 grid
# over the scene): a ray that starts among many triangles costs more.
DENSITY_GRID = 16

# ---- Storage order (packed)
# A mesh's rows go along a Morton curve of their box centres (``Scene(order=)``): a node's
# triangles then share cache lines whatever order the faces came in. "auto" sorts a mesh whose
# faces come incoherent: more than INCOHERENT_JUMPS of consecutive faces in different cells of
# a 2^COHERENCE_BITS grid (shuffled faces: 0.98-0.99; Sibenik, Sponza, conference, dragon as
# stored: 0.03-0.11; armadillo 0.87, bunny 0.56); a coherent one keeps its order and its
# packing cost.
COHERENCE_BITS = 9
INCOHERENT_JUMPS = 0.5
# "auto" sorts a mesh of this many rows whatever its order: the halves of its storage order
# (``ranges``) then box compact pieces, which a large mesh's file order need not give.
AUTO_MORTON_ROWS = 1 << 20

# ---- Frame centres of placed meshes (packed)
# A placed mesh whose box's centre lies farther than FAR_SIDES times the box's largest side from
# its origin along an axis is packed relative to that centre on that axis: its rays then move
# into coordinates of the mesh's size (a grid 2 units wide given 16 units out and placed back:
# 40 ulps across its surface become 0). Meshes nearer keep their own coordinates, and their
# answers' bits (an identity's too); at least 1.5 keeps every corner within a factor of two of
# the centre, so that corner - centre is exact (Sterbenz).
FAR_SIDES = 4.0

# ---- Point queries (points)
# Triangles beside a point's Morton code that it measures before any partition: its first radius.
POINT_SEEDS = 4
# Points per chunk: a run of the Morton order, so a chunk's points meet few triangles.
POINT_CHUNK = 32768
# Top bits of the points' Morton codes that order them into chunks (a counting sort).
POINT_ORDER_BITS = 18
# Leaves: brute force a node of P points and T triangles when P*T <= C_P*P + C_T*T.
POINT_LEAF_C_P = 8
POINT_LEAF_C_T = 8
# A box is culled only beyond a point's best squared distance times this, plus the square of
# this fraction of the scene's size: rounding in a triangle's distance never culls it.
POINT_CULL_GROWTH = 1.0 + 1e-9
POINT_CULL_SLACK = 1e-9

# ---- Shards on a cluster (distributed)
# Fewest rays in a shard (but for a batch smaller than this): a worker's DACRT gains with rays
# per node, and one thread traces shards of this size at 0.4 to 0.7 of its rate on shards of 1 Mi
# rays (docs/cluster.md has the figures); smaller shards would leave threads idle on batches of
# a few million rays instead.
MIN_SHARD_RAYS = 1 << 18
# Most rays in a shard: bounds a worker's memory per shard (about 60 bytes a ray in and out for
# closest) and the work sent again when a worker is lost.
MAX_SHARD_RAYS = 1 << 21
# Times a lost shard is sent again before the query gives up.
SHARD_RETRIES = 3
