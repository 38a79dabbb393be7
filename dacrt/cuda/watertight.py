"""The CPU engine's watertight ray-triangle test (``dacrt.geometry``) as CUDA device functions.

The same float64 operations in the same order, products through ``arith.mul`` so that none is
fused: the same bits for t, u and v as ``geometry.intersect_triangle`` and ``leaf.woop_hit``.
"""

import numpy as np

from ..config import EDGE_ON_TOLERANCE
from .arith import device, mul


@device
def pick(k, x, y, z):
    """Component k of (x, y, z)."""
    return x if k == 0 else (y if k == 1 else z)


@device
def ray_frame(ox, oy, oz, dx, dy, dz):
    """``geometry.watertight_setup`` and the permuted float64 origin: (kx, ky, kz, sx, sy, sz,
    okx, oky, okz)."""
    dx = np.float64(dx)
    dy = np.float64(dy)
    dz = np.float64(dz)
    abs_x = abs(dx)
    abs_y = abs(dy)
    abs_z = abs(dz)
    x_dominant = (abs_x >= abs_y) and (abs_x >= abs_z)
    kz = 0 if x_dominant else (1 if abs_y >= abs_z else 2)
    dk = pick(kz, dx, dy, dz)
    kx = kz + 1 if kz < 2 else 0
    ky = kx + 1 if kx < 2 else 0
    # Swap to keep the winding, so the sign of det tells front from back.
    if dk < 0:
        kx, ky = ky, kx
    sx = pick(kx, dx, dy, dz) / dk
    sy = pick(ky, dx, dy, dz) / dk
    sz = 1.0 / dk
    ox = np.float64(ox)
    oy = np.float64(oy)
    oz = np.float64(oz)
    return kx, ky, kz, sx, sy, sz, pick(kx, ox, oy, oz), pick(ky, ox, oy, oz), pick(kz, ox, oy, oz)


@device
def triangle_hit(verts, row, kx, ky, kz, sx, sy, sz, okx, oky, okz):
    """(hit, t float32, det, u, v) of ``verts[row]`` for a ray frame (``ray_frame``): the
    arithmetic of ``geometry.woop_edges``, ``woop_miss`` and ``leaf.woop_hit``; t, u and v are
    only meaningful on a hit."""
    ax = np.float64(verts[row, kx]) - okx
    ay = np.float64(verts[row, ky]) - oky
    az = np.float64(verts[row, kz]) - okz
    bx = np.float64(verts[row, 3 + kx]) - okx
    by = np.float64(verts[row, 3 + ky]) - oky
    bz = np.float64(verts[row, 3 + kz]) - okz
    cx = np.float64(verts[row, 6 + kx]) - okx
    cy = np.float64(verts[row, 6 + ky]) - oky
    cz = np.float64(verts[row, 6 + kz]) - okz
    # The shear that maps the ray onto +z.
    ax = ax - mul(sx, az)
    ay = ay - mul(sy, az)
    bx = bx - mul(sx, bz)
    by = by - mul(sy, bz)
    cx = cx - mul(sx, cz)
    cy = cy - mul(sy, cz)
    cxby = mul(cx, by)
    cybx = mul(cy, bx)
    axcy = mul(ax, cy)
    aycx = mul(ay, cx)
    bxay = mul(bx, ay)
    byax = mul(by, ax)
    e0 = cxby - cybx
    e1 = axcy - aycx
    e2 = bxay - byax
    det = e0 + e1 + e2
    noise = mul(
        abs(cxby) + abs(cybx) + abs(axcy) + abs(aycx) + abs(bxay) + abs(byax), EDGE_ON_TOLERANCE
    )
    mixed = ((e0 < 0.0) or (e1 < 0.0) or (e2 < 0.0)) and ((e0 > 0.0) or (e1 > 0.0) or (e2 > 0.0))
    if mixed or abs(det) <= noise:
        return False, np.float32(0.0), det, 0.0, 0.0
    scaled_t = mul(e0, mul(sz, az)) + mul(e1, mul(sz, bz)) + mul(e2, mul(sz, cz))
    inv_det = 1.0 / det
    # +0.0 turns a -0.0 into +0.0: the CPU engine's comparisons treat them as one t.
    t = np.float32(mul(scaled_t, inv_det)) + np.float32(0.0)
    return True, t, det, mul(e1, inv_det), mul(e2, inv_det)
