"""Geometry kernels: the conservative ray-box slab test and the watertight ray-triangle test.

Both are inlined into the traversal loops. They take scalars, so the callers decide the layout.
"""

import numpy as np

from .config import CULL_MARGIN, EDGE_ON_TOLERANCE, SLAB_GROWTH, inline
from .contracts import INF32, NAN32, ONE32
from .query import CULL_BACK, CULL_FRONT

# float32 constants keep the box test in float32, so loops over rays vectorise.
_GROWTH32 = np.float32(SLAB_GROWTH - 1.0)
_MARGIN32 = np.float32(CULL_MARGIN)


@inline
def inverse(d):
    """1/d of a direction component for the slab test: +-inf for a zero one (the ray never
    reaches those planes), NaN where 1/d overflows a nonzero one (|d| < 1/FLT_MAX): NaN leaves
    that axis out of the test, which is conservative, where +-inf would put a plane the ray
    reaches (an origin 1e-45 from it, d = 1e-40) at an infinite distance."""
    inv = ONE32 / d
    return inv if d == 0 or abs(inv) < INF32 else NAN32


@inline
def intersect_box(ox, oy, oz, ix, iy, iz, t_lo, t_hi, x0, y0, z0, x1, y1, z1):
    """Slab test of the ray segment [t_lo, t_hi] against the box [x0,x1]x[y0,y1]x[z0,z1].

    ``ix, iy, iz`` are ``inverse(direction)`` (+-inf for a zero component, NaN where 1/d
    overflows). Returns whether it hits.
    Conservative: the exit distance is grown by 1 + 2*gamma(3) (pbrt); a 0*inf NaN, from a ray
    lying in a slab's plane, or of an overflowed inverse, never tightens the interval because
    comparisons with NaN are false.
    Written with selects only, no branches, so loops over rays vectorise; float32 throughout.
    """
    ax = (x0 - ox) * ix
    bx = (x1 - ox) * ix
    ay = (y0 - oy) * iy
    by = (y1 - oy) * iy
    az = (z0 - oz) * iz
    bz = (z1 - oz) * iz
    # Near and far planes by the sign of the inverse direction.
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
    far = far + abs(far) * _GROWTH32
    far = t_hi if t_hi < far else far
    return near <= far


@inline
def cull_distance(best_t):
    """The distance beyond which a box cannot hold a hit that beats ``best_t``: slightly larger
    than ``best_t`` so that rounding in a triangle's ``t`` never culls a hit. -inf (a finished
    occlusion ray) stays -inf, so ``intersect_box`` culls such a ray from every box (the sum
    alone would give NaN, which the box test's selects pass over)."""
    grown = best_t + abs(best_t) * _MARGIN32
    return grown if grown >= best_t else best_t


@inline
def pick(k, x, y, z):
    """Component k of (x, y, z), as selects."""
    return x if k == 0 else (y if k == 1 else z)


@inline
def watertight_setup(dx, dy, dz):
    """Per-ray constants of the watertight test (Woop, Benthin & Wald 2013).

    Returns the axis permutation (kx, ky, kz), kz being the dominant direction axis, and the
    shear constants (sx, sy, sz) that map the ray onto +z. Selects only, so a loop over rays
    that calls it vectorises."""
    dx = np.float64(dx)
    dy = np.float64(dy)
    dz = np.float64(dz)
    abs_x = abs(dx)
    abs_y = abs(dy)
    abs_z = abs(dz)
    x_dominant = (abs_x >= abs_y) & (abs_x >= abs_z)
    kz = 0 if x_dominant else (1 if abs_y >= abs_z else 2)
    dk = pick(kz, dx, dy, dz)
    kx = kz + 1 if kz < 2 else 0
    ky = kx + 1 if kx < 2 else 0
    # Swap to keep the winding, so the sign of det tells front from back.
    kx, ky = (ky, kx) if dk < 0 else (kx, ky)
    return kx, ky, kz, pick(kx, dx, dy, dz) / dk, pick(ky, dx, dy, dz) / dk, 1.0 / dk


@inline
def corners_from_origin(tri_verts, tri, okx, oky, okz, kx, ky, kz):
    """Triangle ``tri``'s corners minus the ray origin, in float64 and the ray's axis order."""
    return (
        np.float64(tri_verts[tri, kx]) - okx,
        np.float64(tri_verts[tri, ky]) - oky,
        np.float64(tri_verts[tri, kz]) - okz,
        np.float64(tri_verts[tri, 3 + kx]) - okx,
        np.float64(tri_verts[tri, 3 + ky]) - oky,
        np.float64(tri_verts[tri, 3 + kz]) - okz,
        np.float64(tri_verts[tri, 6 + kx]) - okx,
        np.float64(tri_verts[tri, 6 + ky]) - oky,
        np.float64(tri_verts[tri, 6 + kz]) - okz,
    )


@inline
def intersect_triangle(tri_verts, tri, okx, oky, okz, kx, ky, kz, sx, sy, sz):
    """Watertight ray-triangle test in float64 on float32 data.

    ``okx, oky, okz`` are the ray origin's coordinates in the permuted order (kx, ky, kz).
    Returns (hit, t, u, v) with hit = (1-u-v)*p0 + u*p1 + v*p2. A ray through an edge or
    vertex shared by two triangles hits at least one of them: each shared edge's function is
    computed from the same transformed vertices, so its sign agrees on both sides.
    Degenerate triangles give det == 0.
    """
    ax, ay, az, bx, by, bz, cx, cy, cz = corners_from_origin(
        tri_verts, tri, okx, oky, okz, kx, ky, kz
    )
    e0, e1, e2, det, noise, scaled_t = woop_edges(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz)
    if woop_miss(e0, e1, e2, det, noise):
        return False, 0.0, 0.0, 0.0
    inv_det = 1.0 / det
    return True, scaled_t * inv_det, e1 * inv_det, e2 * inv_det


@inline
def crossing(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz):
    """The half-open watertight test of ``hits`` and ``count``, from the corners relative to the
    ray origin in the ray's axis order (``corners_from_origin``): returns (hit, det).

    An edge function that is exactly zero (the ray through an edge or vertex) takes the sign it
    would have with the ray moved by (delta, delta**2) in the sheared plane, delta -> 0+: its
    x-derivative's sign, or its y-derivative's if that is zero. Two triangles on either side of a
    shared edge get opposite signs from the same bits, so exactly one holds the crossing. A hit
    here is also a hit of ``intersect_triangle``, which gives its t, u and v."""
    e0, e1, e2, det, noise, _ = woop_edges(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz)
    ax, ay, bx, by, cx, cy = shear(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy)
    s0 = perturbed_sign(e0, cy - by, bx - cx)
    s1 = perturbed_sign(e1, ay - cy, cx - ax)
    s2 = perturbed_sign(e2, by - ay, ax - bx)
    hit = s0 != 0 and s0 == s1 and s0 == s2 and abs(det) > noise
    return hit, det


@inline
def perturbed_sign(e, slope_x, slope_y):
    """The sign (-1, 0, 1) of an edge function ``e`` at the ray moved by (delta, delta**2)."""
    s = e if e != 0.0 else (slope_x if slope_x != 0.0 else slope_y)
    return 1 if s > 0.0 else (-1 if s < 0.0 else 0)


@inline
def shear(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy):
    """The corners' x and y after the shear that maps the ray onto +z through the origin."""
    return ax - sx * az, ay - sy * az, bx - sx * bz, by - sy * bz, cx - sx * cz, cy - sy * cz


@inline
def woop_edges(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz):
    """The watertight test's arithmetic, from the corners relative to the ray origin in the
    ray's axis order: (e0, e1, e2, det, noise, scaled_t). No branches, so loops vectorise, and
    every caller gets the same bits from the same operations."""
    ax, ay, bx, by, cx, cy = shear(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy)
    # Scaled barycentrics: edge functions of the projected triangle.
    e0 = cx * by - cy * bx
    e1 = ax * cy - ay * cx
    e2 = bx * ay - by * ax
    det = e0 + e1 + e2
    # A triangle seen exactly edge-on projects to a segment: det is then rounding noise and so
    # would be t. det within the edge functions' rounding error counts as zero (a miss).
    noise = (
        abs(cx * by) + abs(cy * bx) + abs(ax * cy) + abs(ay * cx) + abs(bx * ay) + abs(by * ax)
    ) * EDGE_ON_TOLERANCE
    scaled_t = e0 * (sz * az) + e1 * (sz * bz) + e2 * (sz * cz)
    return e0, e1, e2, det, noise, scaled_t


@inline
def woop_miss(e0, e1, e2, det, noise):
    """Whether the ray misses: edge functions of both signs, or an edge-on triangle."""
    mixed = ((e0 < 0.0) | (e1 < 0.0) | (e2 < 0.0)) & ((e0 > 0.0) | (e1 > 0.0) | (e2 > 0.0))
    return mixed | (abs(det) <= noise)


@inline
def triangle_normal(tri_verts, row):
    """Unnormalised geometric normal (p1 - p0) x (p2 - p0) of a triangle, in float64."""
    e1x = np.float64(tri_verts[row, 3]) - np.float64(tri_verts[row, 0])
    e1y = np.float64(tri_verts[row, 4]) - np.float64(tri_verts[row, 1])
    e1z = np.float64(tri_verts[row, 5]) - np.float64(tri_verts[row, 2])
    e2x = np.float64(tri_verts[row, 6]) - np.float64(tri_verts[row, 0])
    e2y = np.float64(tri_verts[row, 7]) - np.float64(tri_verts[row, 1])
    e2z = np.float64(tri_verts[row, 8]) - np.float64(tri_verts[row, 2])
    return e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x


@inline
def culled(tri_verts, tri, okx, oky, okz, kx, ky, kz, sx, sy, sz, cull_side):
    """Whether the query culls triangle ``tri`` for this ray (arguments as for
    ``intersect_triangle``): det * cull_side > 0, det from the same arithmetic that decides the
    hit, so the same bits."""
    ax, ay, az, bx, by, bz, cx, cy, cz = corners_from_origin(
        tri_verts, tri, okx, oky, okz, kx, ky, kz
    )
    _, _, _, det, _, _ = woop_edges(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz)
    return det * cull_side > 0.0


@inline
def culled_side(flags):
    """The sign of det (``woop_edges``) of the faces a query culls, or 0 for none: det < 0 for
    a back face, whose normal (p1 - p0) x (p2 - p0) points along the ray (``watertight_setup``
    keeps the winding), so a face is culled where det * culled_side > 0. The same det decides
    the hit, so a culled face is culled over all of it, edges included."""
    if flags & CULL_BACK:
        return -1.0
    if flags & CULL_FRONT:
        return 1.0
    return 0.0
