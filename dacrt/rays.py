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
    """Fill ``rays`` (8, >= n) float32 with the records of rows ``ray_ids`` (n,) of the batch.

    Returns whether every record has the same origin, bit for bit (a camera's rays): then the
    partitions need not move the origin rows (``swap_rays``)."""
    same_origin = True
    first = ray_ids[0] if ray_ids.shape[0] > 0 else 0
    for r in range(ray_ids.shape[0]):
        ray = ray_ids[r]
        for a in range(3):
            o = origins[ray, a]
            o0 = origins[first, a]
            # Equal values, and equal signs for zeros (0.0 == -0.0).
            same_origin &= (o == o0) & (np.signbit(o) == np.signbit(o0))
            rays[ORIGIN + a, r] = o
            rays[DIRECTION + a, r] = directions[ray, a]
        rays[TMIN, r] = tmin[ray]
        rays[BEST_T, r] = tmax[ray]
    return same_origin


@jit
def unpack_best_t(rays, ray_ids, best_t):
    """Scatter the records' best_t back to ray order."""
    for r in range(ray_ids.shape[0]):
        best_t[ray_ids[r]] = rays[BEST_T, r]


@inline
def swap_rays(rays, ray_ids, i, j, same_origin=False):
    """Exchange records i and j (and their ids); not their origins when every record has the
    same one (``pack_rays``): a swap costs about 0.6 ns a row."""
    if not same_origin:
        for k in range(ORIGIN, ORIGIN + 3):
            tmp = rays[k, i]
            rays[k, i] = rays[k, j]
            rays[k, j] = tmp
    for k in range(DIRECTION, RECORD_SIZE):
        tmp = rays[k, i]
        rays[k, i] = rays[k, j]
        rays[k, j] = tmp
    tmp_id = ray_ids[i]
    ray_ids[i] = ray_ids[j]
    ray_ids[j] = tmp_id
