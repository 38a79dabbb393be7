"""The CPU engine's conservative slab test (``geometry.intersect_box``) and its grown far limit
(``geometry.cull_distance``) as device functions."""

import numpy as np

from ..config import CULL_MARGIN, SLAB_GROWTH
from .arith import device

GROWTH32 = np.float32(SLAB_GROWTH - 1.0)
INF32 = np.float32(np.inf)
MARGIN32 = np.float32(CULL_MARGIN)


@device
def cull_distance(best_t):
    """The far limit of a box test for hits up to ``best_t``: slightly beyond it, so that a box
    whose entry rounds above a hit's t still holds that hit (as on the CPU)."""
    grown = best_t + abs(best_t) * MARGIN32
    return grown if grown >= best_t else best_t


@device
def hits_box(ox, oy, oz, ix, iy, iz, t_lo, t_hi, box, node):
    """Whether the segment [t_lo, t_hi] of a ray (origin, 1/direction) reaches box[node]
    (x0, y0, z0, x1, y1, z1), in float32, the exit grown by 1 + 2 gamma(3) as on the CPU."""
    ax = (box[node, 0] - ox) * ix
    bx = (box[node, 3] - ox) * ix
    ay = (box[node, 1] - oy) * iy
    by = (box[node, 4] - oy) * iy
    az = (box[node, 2] - oz) * iz
    bz = (box[node, 5] - oz) * iz
    near_x = ax if ix >= 0 else bx
    far_x = bx if ix >= 0 else ax
    near_y = ay if iy >= 0 else by
    far_y = by if iy >= 0 else ay
    near_z = az if iz >= 0 else bz
    far_z = bz if iz >= 0 else az
    near = t_lo
    near = near_x if near_x > near else near
    near = near_y if near_y > near else near
    near = near_z if near_z > near else near
    far = INF32
    far = far_x if far_x < far else far
    far = far_y if far_y < far else far
    far = far_z if far_z < far else far
    far = far + abs(far) * GROWTH32
    far = t_hi if t_hi < far else far
    return near <= far
