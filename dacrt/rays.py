"""The kernels' working copy of a ray batch: float32 records, permuted in place.

Partitioning moves whole records rather than ids, so every pass over a node's rays streams
through memory instead of gathering from arrays indexed by ray id. A record is two quads of four
float32, each quad in a row of its own, ``rays[quad, 4 * i + lane]`` with shape (2, 4 m),
m >= n (see ``new_records``):

    quad 0 (ORIGIN_QUAD):     ox, oy, oz, tmin
    quad 1 (DIRECTION_QUAD):  dx, dy, dz, best_t

where best_t starts at tmax, shrinks as closer hits are found, and is -inf once an occlusion
ray has hit (which culls it from every later box). The ray's id travels in a parallel int32
array. 32 bytes per ray; 1/d is recomputed where needed, which costs less than moving it.

A swap moves each quad as one 16-byte value (a complex128 view of the rows, ``quad_view``):
partitions touch two places per record, where a row per field would be eight. Loops over a range
of records read a quad's lanes at 4 i + lane with constant lanes, which LLVM vectorises with
shuffles (a lane chosen at run time makes it gather).
"""

import numpy as np

from .config import PACK_BLOCK, ROW_ALIGN, ROW_SKEW, UNIFORM_CHECK_BLOCK, inline, jit

ORIGIN_QUAD = 0
DIRECTION_QUAD = 1
# A field is (quad << 2) | lane; ``field`` and ``set_field`` read and write one.
ORIGIN = 0
TMIN = 3
DIRECTION = 4
BEST_T = 7


def new_records(n):
    """Uninitialised records for n rays: float32 (2, 4 m) with m >= n; the kernels use
    records [0, n) only."""
    m = -(-n // ROW_ALIGN) * ROW_ALIGN + ROW_SKEW
    return np.empty((2, 4 * m), np.float32)


@inline
def field(rays, f, r):
    """Field ``f`` (ORIGIN + a, TMIN, DIRECTION + a, BEST_T) of record ``r``."""
    return rays[f >> 2, 4 * r + (f & 3)]


@inline
def set_field(rays, f, r, value):
    rays[f >> 2, 4 * r + (f & 3)] = value


@inline
def quad_view(rays):
    """The records as (2, m) complex128: one element per quad, for swaps."""
    return rays.view(np.complex128)


@jit
def pack_rays(origins, directions, tmin, tmax, ray_ids, rays):
    """Fill ``rays`` (2, >= 4 n) float32 with the records of rows ``ray_ids`` (n,) of the
    batch; returns whether all those rays are valid: finite origin and direction, a non-zero
    direction, finite tmin, tmin <= tmax (tmax may be +inf).

    Checking here, in each chunk's thread, rather than in a pass of its own, reads the batch
    once, on every thread. The checks accumulate without a branch; only a bad batch pays for
    finding which ray is bad (``validation.explain_bad_rays``).

    PACK_BLOCK records at a time are built in a small buffer, then copied to the rows as one
    run of floats per quad (cheaper than writing each field straight into the rows), and
    checked in a loop of their own (which vectorises)."""
    block = np.empty((2, PACK_BLOCK, 4), np.float32)
    block0 = block[ORIGIN_QUAD].reshape(4 * PACK_BLOCK)
    block1 = block[DIRECTION_QUAD].reshape(4 * PACK_BLOCK)
    valid = True
    for lo in range(0, ray_ids.shape[0], PACK_BLOCK):
        n = min(PACK_BLOCK, ray_ids.shape[0] - lo)
        for i in range(n):
            ray = ray_ids[lo + i]
            for a in range(3):
                block[ORIGIN_QUAD, i, a] = origins[ray, a]
                block[DIRECTION_QUAD, i, a] = directions[ray, a]
            block[ORIGIN_QUAD, i, 3] = tmin[ray]
            block[DIRECTION_QUAD, i, 3] = tmax[ray]
        q0 = rays[ORIGIN_QUAD, 4 * lo : 4 * (lo + n)]
        q1 = rays[DIRECTION_QUAD, 4 * lo : 4 * (lo + n)]
        for i in range(4 * n):
            q0[i] = block0[i]
            q1[i] = block1[i]
        for i in range(n):
            finite = True
            moves = False
            for a in range(3):
                o = block[ORIGIN_QUAD, i, a]
                d = block[DIRECTION_QUAD, i, a]
                finite &= np.isfinite(o) & np.isfinite(d)
                moves |= d != 0
            t0 = block[ORIGIN_QUAD, i, 3]
            t1 = block[DIRECTION_QUAD, i, 3]
            valid &= finite & moves & np.isfinite(t0) & (t0 <= t1)
    return valid


@jit
def uniform_origin(rays, n):
    """Whether all n records share their origin quad (origin and tmin) bit for bit: a camera's
    rays with one tmin. The partitions need not move that quad (``swap_rays``), and the box
    test reads the origin once.

    The quads are compared as integers (their bit patterns: 0.0 and -0.0 differ, as they must),
    a count per block: the loop vectorises."""
    bits = rays[ORIGIN_QUAD].view(np.uint32)
    if n == 0:
        return False
    f0 = bits[0]
    f1 = bits[1]
    f2 = bits[2]
    f3 = bits[3]
    for lo in range(0, n, UNIFORM_CHECK_BLOCK):
        block = bits[4 * lo : 4 * min(lo + UNIFORM_CHECK_BLOCK, n)]
        m = block.shape[0] // 4
        same = 0
        for i in range(m):
            same += (
                1
                if (
                    (block[4 * i] == f0)
                    & (block[4 * i + 1] == f1)
                    & (block[4 * i + 2] == f2)
                    & (block[4 * i + 3] == f3)
                )
                else 0
            )
        if same != m:
            return False
    return True


@jit
def unpack_best_t(rays, ray_ids, best_t):
    """Scatter the records' best_t back to ray order."""
    q1 = rays[DIRECTION_QUAD]
    for r in range(ray_ids.shape[0]):
        best_t[ray_ids[r]] = q1[4 * r + 3]


@inline
def swap_rays(records, ray_ids, i, j, fixed_origin=False):
    """Exchange records i and j (and their ids) of ``records`` (``quad_view``), except the
    origin quad when every record shares it (``uniform_origin``)."""
    if not fixed_origin:
        tmp = records[ORIGIN_QUAD, i]
        records[ORIGIN_QUAD, i] = records[ORIGIN_QUAD, j]
        records[ORIGIN_QUAD, j] = tmp
    tmp = records[DIRECTION_QUAD, i]
    records[DIRECTION_QUAD, i] = records[DIRECTION_QUAD, j]
    records[DIRECTION_QUAD, j] = tmp
    tmp_id = ray_ids[i]
    ray_ids[i] = ray_ids[j]
    ray_ids[j] = tmp_id
