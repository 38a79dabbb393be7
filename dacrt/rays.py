"""The kernels' working copy of a ray batch: float32 records, permuted in place.

Partitioning moves whole records rather than ids, so every pass over a node's rays streams
through memory instead of gathering from arrays indexed by ray id. The records are stored as a
structure of arrays, ``rays[field, i]`` with shape (8, m), m >= n (see ``new_records``), so
the ray-box loop vectorises.
The fields are

    ox, oy, oz, dx, dy, dz, tmin, best_t

where best_t starts at tmax, shrinks as closer hits are found, and is -inf once an occlusion
ray has hit (which culls it from every later box). The ray's id travels in a parallel int32
array. 32 bytes per ray; 1/d is recomputed where needed, which costs less than moving it.
"""

import numpy as np

from .config import inline, jit

ORIGIN = 0
DIRECTION = 3
TMIN = 6
BEST_T = 7
RECORD_SIZE = 8
# Rays per block of pack_rays (32 measured best of 16-256).
PACK_BLOCK = 32
# Records per block of uniform_rows' check.
UNIFORM_CHECK_BLOCK = 256
# Rows are padded to a whole number of 4 KiB plus one cache line. Rows of exactly 1 MiB (a
# 262,144-ray chunk) put a record's eight fields at the same low 12 address bits and in the same
# cache set; a swap's loads then wait on the stores before them. Sibenik 1024² primary rays, one
# thread: sah 188 -> 178 ms, sampling 148 -> 142.
ROW_ALIGN = 1024
ROW_SKEW = 16


def new_records(n):
    """Uninitialised records for n rays: float32 (RECORD_SIZE, m) with m >= n; the kernels use
    columns [0, n) only."""
    row = -(-n // ROW_ALIGN) * ROW_ALIGN + ROW_SKEW
    return np.empty((RECORD_SIZE, row), np.float32)


@jit
def pack_rays(origins, directions, tmin, tmax, ray_ids, rays):
    """Fill ``rays`` (8, >= n) float32 with the records of rows ``ray_ids`` (n,) of the batch;
    returns whether all those rays are valid: finite origin and direction, a non-zero
    direction, finite tmin, tmin <= tmax (tmax may be +inf).

    Checking here, in each chunk's thread, instead of in a pass of its own before the trace
    reads the batch once, on every thread: 1M rays, two threads, 2.3 ms less on the calling
    thread (docs/benchmark-history.md). The checks accumulate without a branch; only a bad
    batch pays for finding which ray is bad (``validation.explain_bad_rays``).

    PACK_BLOCK rays at a time are read into a small buffer, then copied to the records row by
    row. Storing each ray's fields straight into the eight rows, between its loads, cost more
    (1M rays in 262,144-ray chunks: 3.6 against 2.9 ms from two (N, 3) arrays, 5.3 against
    3.1 from the two halves of one (N, 6) array)."""
    block = np.empty((RECORD_SIZE, PACK_BLOCK), np.float32)
    valid = True
    for lo in range(0, ray_ids.shape[0], PACK_BLOCK):
        n = min(PACK_BLOCK, ray_ids.shape[0] - lo)
        for i in range(n):
            ray = ray_ids[lo + i]
            for a in range(3):
                block[ORIGIN + a, i] = origins[ray, a]
                block[DIRECTION + a, i] = directions[ray, a]
            block[TMIN, i] = tmin[ray]
            block[BEST_T, i] = tmax[ray]
        for k in range(RECORD_SIZE):
            row = rays[k, lo:lo + n]
            for i in range(n):
                row[i] = block[k, i]
        # The checks, in a loop of their own over the buffer, vectorise: kept in the loads'
        # loop above they cost 3.2-3.5 against 2.9-3.2 ms per 1M rays.
        for i in range(n):
            finite = True
            moves = False
            for a in range(3):
                o = block[ORIGIN + a, i]
                d = block[DIRECTION + a, i]
                finite &= np.isfinite(o) & np.isfinite(d)
                moves |= d != 0
            t0 = block[TMIN, i]
            t1 = block[BEST_T, i]
            valid &= finite & moves & np.isfinite(t0) & (t0 <= t1)
    return valid


@jit
def uniform_rows(rays, n):
    """Bitmask of the rows (bit k: row k) that hold one value in all n records, bit for bit:
    the origin of a camera's rays, a tmin shared by the batch, the direction of parallel rays
    (best_t changes during the trace, so never). The partitions need not move those rows
    (``swap_rays``). A row stops being checked at the first block that differs.

    The rows are compared as integers (their bit patterns: 0.0 and -0.0 differ, as they must),
    a count per block: the loop vectorises. Comparing floats and their signs did not: 0.34 ms
    against 0.045 per 262,144 camera rays."""
    bits = rays.view(np.uint32)
    fixed = 0
    for k in range(BEST_T):
        row = bits[k, :n]
        first = row[0] if n > 0 else np.uint32(0)
        uniform = True
        for lo in range(0, n, UNIFORM_CHECK_BLOCK):
            block = row[lo:min(lo + UNIFORM_CHECK_BLOCK, n)]
            same = 0
            for i in range(block.shape[0]):
                same += 1 if block[i] == first else 0
            if same != block.shape[0]:
                uniform = False
                break
        if uniform:
            fixed |= 1 << k
    return fixed


@jit
def unpack_best_t(rays, ray_ids, best_t):
    """Scatter the records' best_t back to ray order."""
    for r in range(ray_ids.shape[0]):
        best_t[ray_ids[r]] = rays[BEST_T, r]


@inline
def swap_rays(rays, ray_ids, i, j, fixed_rows=0):
    """Exchange records i and j (and their ids), except the rows in the bitmask ``fixed_rows``
    (``uniform_rows``: the same value in every record): a swap costs about 0.6 ns a row."""
    for k in range(RECORD_SIZE):
        if (fixed_rows >> k) & 1 == 0:
            tmp = rays[k, i]
            rays[k, i] = rays[k, j]
            rays[k, j] = tmp
    tmp_id = ray_ids[i]
    ray_ids[i] = ray_ids[j]
    ray_ids[j] = tmp_id
