"""The DACRT driver for ray-space partitions: ``rayspace`` (5D ray hierarchies).

Rays are grouped by the axis and sign of their dominant direction component; within a group a
ray is (origin x, y, z; u, v), u and v being its direction's slopes against the dominant axis.
A node is a range of ray ids and a range of triangle ids: popping it bounds its rays by a
frustum (origin box, slope box, distance range), culls the triangles whose boxes lie outside,
then brute-forces it if R*G < C_r*R + C_g*G, else halves its rays along the widest of the five
dimensions and pushes both halves with the surviving triangles.
"""

import numpy as np

from .config import (
    COMPARE_BLOCK,
    MAX_DEPTH,
    RAYSPACE_C_G,
    RAYSPACE_C_R,
    RAYSPACE_KEPT_TO_GIVE_UP,
    RAYSPACE_MIN_DEPTH_TO_GIVE_UP,
    RAYSPACE_ORIGIN_SPREAD_TO_GIVE_UP,
    RAYSPACE_TOLERANCE,
    inline,
    jit,
)
from .contracts import (
    SAMPLING,
    STAT_BOX_TESTS,
    STAT_MAX_DEPTH,
    STAT_NODES,
)
from .geometry import cull_distance, pick
from .partition import partition_by_mask, partition_scratch, triangle_bounds
from .query import ANY_HIT, FIXED_ORIGIN, with_strategy
from .ranges import RangeTree
from .rays import BEST_T, DIRECTION, DIRECTION_QUAD, ORIGIN_QUAD, field, quad_view, swap_rays
from .traversal import trace_object_split

# Frustum rows: origin min (3), origin max (3), u min/max, v min/max, distance min/max.
_O_MIN = 0
_O_MAX = 3
_U = 6
_V = 8
_S = 10
_FRUSTUM_SIZE = 12


@inline
def dominant_class(dx, dy, dz):
    """0..5: 2*axis + (1 if the dominant component is negative)."""
    ax = abs(dx)
    ay = abs(dy)
    az = abs(dz)
    if ax >= ay and ax >= az:
        return 0 if dx >= 0 else 1
    if ay >= az:
        return 2 if dy >= 0 else 3
    return 4 if dz >= 0 else 5


@jit
def bound_rays(rays, lo, hi, axis, frustum):
    """Frustum of the ray records ``lo:hi`` of one group into ``frustum`` (12,)."""
    q0 = rays[ORIGIN_QUAD, 4 * lo : 4 * hi]
    q1 = rays[DIRECTION_QUAD, 4 * lo : 4 * hi]
    u_axis = (axis + 1) % 3
    v_axis = (axis + 2) % 3
    x_lo = y_lo = z_lo = u_lo = v_lo = s_lo = np.inf
    x_hi = y_hi = z_hi = u_hi = v_hi = s_hi = -np.inf
    for r in range(hi - lo):
        x = np.float64(q0[4 * r])
        y = np.float64(q0[4 * r + 1])
        z = np.float64(q0[4 * r + 2])
        dx = np.float64(q1[4 * r])
        dy = np.float64(q1[4 * r + 1])
        dz = np.float64(q1[4 * r + 2])
        da = abs(pick(axis, dx, dy, dz))
        u = pick(u_axis, dx, dy, dz) / da
        v = pick(v_axis, dx, dy, dz) / da
        # Distance along the dominant axis: t * |d_axis|.
        near = np.float64(q0[4 * r + 3]) * da
        far = np.float64(cull_distance(q1[4 * r + 3])) * da
        x_lo = x if x < x_lo else x_lo
        x_hi = x if x > x_hi else x_hi
        y_lo = y if y < y_lo else y_lo
        y_hi = y if y > y_hi else y_hi
        z_lo = z if z < z_lo else z_lo
        z_hi = z if z > z_hi else z_hi
        u_lo = u if u < u_lo else u_lo
        u_hi = u if u > u_hi else u_hi
        v_lo = v if v < v_lo else v_lo
        v_hi = v if v > v_hi else v_hi
        s_lo = near if near < s_lo else s_lo
        s_hi = far if far > s_hi else s_hi
    frustum[_O_MIN] = x_lo
    frustum[_O_MIN + 1] = y_lo
    frustum[_O_MIN + 2] = z_lo
    frustum[_O_MAX] = x_hi
    frustum[_O_MAX + 1] = y_hi
    frustum[_O_MAX + 2] = z_hi
    frustum[_U] = u_lo
    frustum[_U + 1] = u_hi
    frustum[_V] = v_lo
    frustum[_V + 1] = v_hi
    frustum[_S] = s_lo
    frustum[_S + 1] = s_hi


@inline
def slope_range(o_lo, o_hi, s_lo, s_hi, lo, hi):
    """Range of o + w*s over o in [o_lo, o_hi], w in [lo, hi], s in [s_lo, s_hi]."""
    p0 = lo * s_lo
    p1 = lo * s_hi
    p2 = hi * s_lo
    p3 = hi * s_hi
    return o_lo + min(min(p0, p1), min(p2, p3)), o_hi + max(max(p0, p1), max(p2, p3))


@jit
def cull_triangles(tris, lo, hi, frustum, axis, negative, tolerance, keep, bounds):
    """Move the triangles of ``tris.ids[lo:hi]`` (``Triangles``) whose boxes a ray of the
    frustum can pass through to the front; returns how many they are.

    Conservative: interval arithmetic over the five ray dimensions and the distance range,
    ``tolerance`` (world units) absorbing rounding. ``keep`` (one entry per triangle) and
    ``bounds`` (6 float32 rows of as many) are scratch: the boxes are gathered into rows first,
    so the tests, written with selects only, run as one vectorised loop."""
    tri_ids = tris.ids
    tri_bounds = tris.bounds
    a1 = (axis + 1) % 3
    a2 = (axis + 2) % 3
    n = hi - lo
    lo0 = bounds[0]
    hi0 = bounds[1]
    lo1 = bounds[2]
    hi1 = bounds[3]
    lo2 = bounds[4]
    hi2 = bounds[5]
    ids = tri_ids[lo:hi]
    for k in range(n):
        tri = np.uint32(ids[k])  # unsigned: no index wraparound
        lo0[k] = tri_bounds[tri, axis]
        hi0[k] = tri_bounds[tri, axis + 3]
        lo1[k] = tri_bounds[tri, a1]
        hi1[k] = tri_bounds[tri, a1 + 3]
        lo2[k] = tri_bounds[tri, a2]
        hi2[k] = tri_bounds[tri, a2 + 3]
    # The frustum in locals (loads from an array would be repeated in the loop). Distances
    # along the dominant axis to a slab [b_lo, b_hi] are b_lo - o_far .. b_hi - o_near, or
    # mirrored for a negative direction: s = sign * b + offset.
    sign = -1.0 if negative else 1.0
    o_near = frustum[_O_MAX + axis] if negative else frustum[_O_MIN + axis]
    o_far = frustum[_O_MIN + axis] if negative else frustum[_O_MAX + axis]
    s_min = frustum[_S] - tolerance
    s_max = frustum[_S + 1] + tolerance
    o1_lo = frustum[_O_MIN + a1]
    o1_hi = frustum[_O_MAX + a1]
    o2_lo = frustum[_O_MIN + a2]
    o2_hi = frustum[_O_MAX + a2]
    u_lo = frustum[_U]
    u_hi = frustum[_U + 1]
    v_lo = frustum[_V]
    v_hi = frustum[_V + 1]
    for k in range(n):
        b_lo = lo0[k] - tolerance
        b_hi = hi0[k] + tolerance
        near_plane = b_hi if negative else b_lo
        far_plane = b_lo if negative else b_hi
        s_lo = max(sign * (near_plane - o_far), s_min)
        s_hi = min(sign * (far_plane - o_near), s_max)
        p_lo, p_hi = slope_range(o1_lo, o1_hi, s_lo, s_hi, u_lo, u_hi)
        q_lo, q_hi = slope_range(o2_lo, o2_hi, s_lo, s_hi, v_lo, v_hi)
        # ~(a > b) rather than a <= b: a NaN never culls.
        keep[k] = (
            ~(s_lo > s_hi)
            & ~(p_hi < lo1[k] - tolerance)
            & ~(p_lo > hi1[k] + tolerance)
            & ~(q_hi < lo2[k] - tolerance)
            & ~(q_lo > hi2[k] + tolerance)
        )
    i = 0
    j = n
    while i < j:
        if keep[i]:
            i += 1
        else:
            j -= 1
            if keep[j]:
                tri = tri_ids[lo + i]
                tri_ids[lo + i] = tri_ids[lo + j]
                tri_ids[lo + j] = tri
                i += 1
    return i


@inline
def compare_scratch():
    """Scratch for partition_rays: two float32 rows of COMPARE_BLOCK lanes."""
    return np.empty((2, COMPARE_BLOCK), np.float32)


@jit
def partition_rays(rays, ray_ids, lo, hi, axis, dim, split, below, offsets, lanes, fixed_origin):
    """Move rays whose coordinate ``dim`` (0-2: origin x, y, z; 3, 4: slopes u, v of the
    direction against the dominant ``axis``) is below ``split`` to the front; returns the index
    of the first other ray. ``below`` is scratch, one entry per ray; ``offsets`` is
    ``partition_scratch()``, ``lanes`` is ``compare_scratch()``.

    The coordinates are compared first, COMPARE_BLOCK rays at a time: their lanes are copied out
    of the quads (``lane_into``), then compared in a vectorised loop. A slope is compared as
    lane < split * |axis lane| in float32: which side a ray near the split goes to does not
    matter, since each side's frustum is bounded from its own rays."""
    quad = rays[ORIGIN_QUAD if dim < 3 else DIRECTION_QUAD, 4 * lo : 4 * hi]
    mask = below[lo:hi]
    n = hi - lo
    values = lanes[0]
    scale = lanes[1]
    split32 = np.float32(split)
    slope = (axis + 1 if dim == 3 else axis + 2) % 3
    for b in range(0, n, COMPARE_BLOCK):
        m = min(COMPARE_BLOCK, n - b)
        block = quad[4 * b : 4 * (b + m)]
        out = mask[b : b + m]
        if dim < 3:
            lane_into(block, m, dim, values)
            for i in range(m):
                out[i] = np.float64(values[i]) < split
        else:
            lane_into(block, m, slope, values)
            lane_into(block, m, axis, scale)
            for i in range(m):
                out[i] = values[i] < split32 * abs(scale[i])
    return partition_by_mask(rays, ray_ids, lo, hi, below, offsets, False, fixed_origin)


@inline
def lane_into(block, m, lane, out):
    """out[:m] = lane ``lane`` (0-2) of the first m quads of ``block``. One loop per lane, so
    that the lane is a constant: a lane chosen inside the loop, or two lanes read in one loop,
    makes LLVM gather or give up."""
    if lane == 0:
        for i in range(m):
            out[i] = block[4 * i]
    elif lane == 1:
        for i in range(m):
            out[i] = block[4 * i + 1]
    else:
        for i in range(m):
            out[i] = block[4 * i + 2]


@jit
def drop_finished_rays(rays, ray_ids, lo, hi, fixed_origin):
    """Occlusion: move rays that already hit something out of the range; returns the new end."""
    records = quad_view(rays)
    i = lo
    j = hi
    while i < j:
        if field(rays, BEST_T, i) != -np.inf:
            i += 1
        else:
            j -= 1
            swap_rays(records, ray_ids, i, j, fixed_origin)
    return i


@inline
def group_by_direction(rays, ray_ids, fixed_origin, group_start):
    """Sort the records into the six groups of ``dominant_class`` (a counting pass per group,
    in place); group g's records are group_start[g]:group_start[g + 1] of ``group_start`` (7,)."""
    records = quad_view(rays)
    n_rays = ray_ids.shape[0]
    lo = 0
    for g in range(6):
        group_start[g] = lo
        j = n_rays
        i = lo
        while i < j:
            if (
                dominant_class(
                    field(rays, DIRECTION, i),
                    field(rays, DIRECTION + 1, i),
                    field(rays, DIRECTION + 2, i),
                )
                == g
            ):
                i += 1
            else:
                j -= 1
                swap_rays(records, ray_ids, i, j, fixed_origin)
        lo = i
    group_start[6] = n_rays


@inline
def widest_dimension(frustum, scene_size):
    """The dimension (0-2: origin x, y, z; 3, 4: slopes u, v) along which a node's rays spread
    most, and its middle: (dim, split), dim -1 when they are alike in every dimension. Slopes
    are weighed by the distance they travel across the scene, so both kinds are in world
    units."""
    spread = 0.0
    # Not a literal -1: Numba types a call with the literal first, and would compile
    # partition_rays for it as well.
    dim = np.int64(-1)
    for d in range(5):
        if d < 3:
            extent = frustum[_O_MAX + d] - frustum[_O_MIN + d]
        else:
            k = _U if d == 3 else _V
            extent = (frustum[k + 1] - frustum[k]) * scene_size
        if extent > spread:
            spread = extent
            dim = d
    if dim < 0:
        return dim, 0.0
    if dim < 3:
        return dim, 0.5 * (frustum[_O_MIN + dim] + frustum[_O_MAX + dim])
    k = _U if dim == 3 else _V
    return dim, 0.5 * (frustum[k] + frustum[k + 1])


@jit
def trace_ray_space(flags, tris, scene_box, rays, ray_ids, arrays):
    """Trace the ray records ``rays`` against the triangles ``tris.ids`` (``Triangles``), whose
    box is ``scene_box`` (both permuted in place).

    ``flags`` and ``arrays`` (``QueryArrays``) are the query's, as for ``trace_object_split``.
    A node the termination rule makes a leaf goes to the object-split driver, with ray
    sampling: a small one becomes its leaf, and one that still holds many triangles (incoherent
    rays the frustum cannot cull for) is split further instead of brute-forced."""
    hit_mask = arrays.hit_mask
    stats = arrays.stats
    any_hit = (flags & ANY_HIT) != 0
    fixed_origin = (flags & FIXED_ORIGIN) != 0
    n_tris_all = tris.ids.shape[0]
    no_tree = RangeTree(np.empty((0, 6), np.float32), 0, 0, 0)
    scene_size = 0.0
    for a in range(3):
        scene_size = max(
            scene_size,
            np.float64(scene_box[a + 3] - scene_box[a]),
            abs(np.float64(scene_box[a])),
            abs(np.float64(scene_box[a + 3])),
        )
    tolerance = RAYSPACE_TOLERANCE * scene_size
    group_start = np.zeros(7, np.int64)
    group_by_direction(rays, ray_ids, fixed_origin, group_start)

    n_stack = MAX_DEPTH + 2
    stack = np.empty((n_stack, 5), np.int64)  # ray_lo, ray_hi, tri_lo, tri_hi, depth
    frustum = np.empty(_FRUSTUM_SIZE)
    node_box = np.empty(6, np.float32)
    offsets = partition_scratch()
    lanes = compare_scratch()
    keep = np.empty(n_tris_all, np.bool_)
    bounds = np.empty((6, n_tris_all), np.float32)  # exact copies of the boxes
    for g in range(6):
        if group_start[g + 1] == group_start[g]:
            continue
        axis = g // 2
        negative = g % 2 == 1
        stack[0, 0] = group_start[g]
        stack[0, 1] = group_start[g + 1]
        stack[0, 2] = 0
        stack[0, 3] = n_tris_all
        stack[0, 4] = 0
        sp = 1
        while sp > 0:
            sp -= 1
            ray_lo = stack[sp, 0]
            ray_hi = stack[sp, 1]
            tri_lo = stack[sp, 2]
            tri_hi = stack[sp, 3]
            depth = stack[sp, 4]
            stats[STAT_NODES] += 1
            if depth > stats[STAT_MAX_DEPTH]:
                stats[STAT_MAX_DEPTH] = depth
            if any_hit:
                ray_hi = drop_finished_rays(rays, ray_ids, ray_lo, ray_hi, fixed_origin)
            n_rays = ray_hi - ray_lo
            if n_rays == 0 or tri_hi == tri_lo:
                continue
            bound_rays(rays, ray_lo, ray_hi, axis, frustum)
            n_tris_before = tri_hi - tri_lo
            stats[STAT_BOX_TESTS] += n_tris_before
            tri_hi = tri_lo + cull_triangles(
                tris, tri_lo, tri_hi, frustum, axis, negative, tolerance, keep, bounds
            )
            n_tris = tri_hi - tri_lo
            if n_tris == 0:
                continue
            # Rays too incoherent for their frustum to cull: dividing them further only repeats
            # the cull, so object splits take over.
            origin_spread = 0.0
            for a in range(3):
                origin_spread = max(origin_spread, frustum[_O_MAX + a] - frustum[_O_MIN + a])
            incoherent = n_tris > RAYSPACE_KEPT_TO_GIVE_UP * n_tris_before and (
                depth >= RAYSPACE_MIN_DEPTH_TO_GIVE_UP
                or origin_spread > RAYSPACE_ORIGIN_SPREAD_TO_GIVE_UP * scene_size
            )
            stop = (
                n_rays * n_tris < RAYSPACE_C_R * n_rays + RAYSPACE_C_G * n_tris
                or depth >= MAX_DEPTH
                or incoherent
            )
            ray_mid = ray_lo
            if not stop:
                # Split the rays at the middle of their widest dimension; rays alike in every
                # dimension leave nothing to divide.
                dim, split = widest_dimension(frustum, scene_size)
                if dim >= 0:
                    ray_mid = partition_rays(
                        rays,
                        ray_ids,
                        ray_lo,
                        ray_hi,
                        axis,
                        dim,
                        split,
                        hit_mask,
                        offsets,
                        lanes,
                        fixed_origin,
                    )
                stop = not ray_lo < ray_mid < ray_hi
            if stop:
                # Finish the node with object splits, whose kernel holds the leaf: a leaf of
                # its own here would compile it twice.
                triangle_bounds(tris, tri_lo, tri_hi, node_box)
                trace_object_split(
                    with_strategy(flags, SAMPLING),
                    tris,
                    no_tree,
                    node_box,
                    rays,
                    ray_ids,
                    ray_lo,
                    ray_hi,
                    tri_lo,
                    tri_hi,
                    arrays,
                )
                continue
            for half in range(2):
                stack[sp, 0] = ray_mid if half == 0 else ray_lo
                stack[sp, 1] = ray_hi if half == 0 else ray_mid
                stack[sp, 2] = tri_lo
                stack[sp, 3] = tri_hi
                stack[sp, 4] = depth + 1
                sp += 1
