"""The CPU engine's watertight ray-triangle test (``dacrt.geometry``) as CUDA device functions.

The same float64 operations in the same order, products through ``arith.mul`` so that none is
fused: the same bits for t, u and v as ``geometry.intersect_triangle`` and ``leaf.woop_hit``,
and the same crossings as ``geometry.crossing``.
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
def sheared_corners(verts, row, kx, ky, kz, sx, sy, okx, oky, okz):
    """``verts[row]``'s corners relative to the ray origin in the ray's axis order, x and y
    sheared so that the ray is +z (``geometry.corners_from_origin`` then ``shear``): (ax, ay,
    az, bx, by, bz, cx, cy, cz)."""
    ax = np.float64(verts[row, kx]) - okx
    ay = np.float64(verts[row, ky]) - oky
    az = np.float64(verts[row, kz]) - okz
    bx = np.float64(verts[row, 3 + kx]) - okx
    by = np.float64(verts[row, 3 + ky]) - oky
    bz = np.float64(verts[row, 3 + kz]) - okz
    cx = np.float64(verts[row, 6 + kx]) - okx
    cy = np.float64(verts[row, 6 + ky]) - oky
    cz = np.float64(verts[row, 6 + kz]) - okz
    ax = ax - mul(sx, az)
    ay = ay - mul(sy, az)
    bx = bx - mul(sx, bz)
    by = by - mul(sy, bz)
    cx = cx - mul(sx, cz)
    cy = cy - mul(sy, cz)
    return ax, ay, az, bx, by, bz, cx, cy, cz


@device
def edge_functions(ax, ay, bx, by, cx, cy):
    """The sheared corners' edge functions, their sum and its rounding bound
    (``geometry.woop_edges``): (e0, e1, e2, det, noise)."""
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
    return e0, e1, e2, det, noise


@device
def distance(e0, e1, e2, det, sz, az, bz, cz):
    """t in float32 and 1/det, from the edge functions (``geometry.woop_edges``'s scaled_t)."""
    scaled_t = mul(e0, mul(sz, az)) + mul(e1, mul(sz, bz)) + mul(e2, mul(sz, cz))
    inv_det = 1.0 / det
    # +0.0 turns a -0.0 into +0.0: the CPU engine's comparisons treat them as one t.
    return np.float32(mul(scaled_t, inv_det)) + np.float32(0.0), inv_det


@device
def triangle_hit(verts, row, kx, ky, kz, sx, sy, sz, okx, oky, okz):
    """(hit, t float32, det, u, v) of ``verts[row]`` for a ray frame (``ray_frame``): the
    arithmetic of ``geometry.woop_edges``, ``woop_miss`` and ``leaf.woop_hit``; t, u and v are
    only meaningful on a hit."""
    ax, ay, az, bx, by, bz, cx, cy, cz = sheared_corners(
        verts, row, kx, ky, kz, sx, sy, okx, oky, okz
    )
    e0, e1, e2, det, noise = edge_functions(ax, ay, bx, by, cx, cy)
    mixed = ((e0 < 0.0) or (e1 < 0.0) or (e2 < 0.0)) and ((e0 > 0.0) or (e1 > 0.0) or (e2 > 0.0))
    if mixed or abs(det) <= noise:
        return False, np.float32(0.0), det, 0.0, 0.0
    t, inv_det = distance(e0, e1, e2, det, sz, az, bz, cz)
    return True, t, det, mul(e1, inv_det), mul(e2, inv_det)


@device
def perturbed_sign(e, slope_x, slope_y):
    """The sign (-1, 0, 1) of an edge function ``e`` at the ray moved by (delta, delta**2)
    (``geometry.perturbed_sign``)."""
    s = e if e != 0.0 else (slope_x if slope_x != 0.0 else slope_y)
    return 1 if s > 0.0 else (-1 if s < 0.0 else 0)


@device
def crossing(verts, row, kx, ky, kz, sx, sy, sz, okx, oky, okz):
    """(crossed, t float32, det) of ``verts[row]`` for a ray frame by the half-open test of
    ``hits`` and ``count`` (``geometry.crossing``): a ray through an edge or vertex shared by
    several triangles crosses one. A crossing is a hit of ``triangle_hit``, with its t; t is
    only meaningful on a crossing."""
    ax, ay, az, bx, by, bz, cx, cy, cz = sheared_corners(
        verts, row, kx, ky, kz, sx, sy, okx, oky, okz
    )
    e0, e1, e2, det, noise = edge_functions(ax, ay, bx, by, cx, cy)
    s0 = perturbed_sign(e0, cy - by, bx - cx)
    s1 = perturbed_sign(e1, ay - cy, cx - ax)
    s2 = perturbed_sign(e2, by - ay, ax - bx)
    if not (s0 != 0 and s0 == s1 and s0 == s2 and abs(det) > noise):
        return False, np.float32(0.0), det
    t, _ = distance(e0, e1, e2, det, sz, az, bz, cz)
    return True, t, det
