"""Point queries by divide and conquer: the closest point on the scene's triangles, and inside or
outside by the parity of ray crossings. No structure outlives a query.

``nearest``: each point carries the squared distance of its best triangle so far (its radius,
the analogue of a ray's best t). Seeds first: the triangles' box centres are sorted along a
Morton curve, and each point measures the few triangles beside its own Morton code, which gives
it a radius before any partition. Then, per chunk of points (neighbours on the Morton curve),
one explicit-stack loop over nodes: a node is a range of triangle ids, a range of point ids and
the triangles' box; popping a node keeps the points whose distance to the box is within their
radius, then brute-forces the node or splits its triangles at the middle and pushes both
children, the one nearer the points on top. Leaves measure each pair in float64
(``closest_on_triangle``). The answer of a point does not depend on the chunks,
the seeds or the order of visits: the least squared distance, ties to the lowest global
triangle id.

``contains``: the parity of ``Scene.count``'s crossings along fixed directions
(``sample_directions``), the majority of them.
"""

from collections import namedtuple

import numpy as np

from .chunks import N_CORES, map_on_threads
from .config import (
    MAX_DEPTH,
    POINT_CHUNK,
    POINT_CULL_GROWTH,
    POINT_CULL_SLACK,
    POINT_LEAF_C_P,
    POINT_LEAF_C_T,
    POINT_ORDER_BITS,
    POINT_SEEDS,
    inline,
    jit,
)
from .contracts import (
    FLOAT,
    INDEX,
    MISS,
    POINT_STAT_NAMES,
    STAT_POINT_BOX_TESTS,
    STAT_POINT_LEAVES,
    STAT_POINT_MAX_DEPTH,
    STAT_POINT_NODES,
    STAT_POINT_SEED_TESTS,
    STAT_POINT_TRIANGLE_TESTS,
    Nearest,
)
from .query import ALL_MASKS
from .traversal import split_middle
from .triangles import Triangles, triangle_boxes
from .validation import (
    check_masks,
    check_max_distance,
    check_nsamples,
    check_points,
    check_threads,
)

NearestArrays = namedtuple("NearestArrays", ["d2", "global_id", "u", "v", "point"])
NearestArrays.__doc__ = """What ``nearest`` finds, by point id: the squared distance (float64, inf
for none), the global triangle id (int64, NO_TRIANGLE for none), the barycentrics u, v (float64,
0 for none) and the closest point (N, 3) float64 (inf for none)."""

Seeds = namedtuple("Seeds", ["codes", "rows"])
Seeds.__doc__ = """The triangles a point measures first: the visible rows (int32) sorted by the
Morton codes (int64) of their box centres."""

SceneTriangles = namedtuple(
    "SceneTriangles",
    ["verts", "global_ids", "mesh_offsets", "row_masks", "bounds", "box", "seeds"],
)
SceneTriangles.__doc__ = """What a point query reads of a scene (``Scene._scene_triangles``),
derived once for all its point queries (``scene_triangles``).

verts : (F, 9) float32, each live triangle's corners p0, p1, p2 in scene space
global_ids : (F,) int32, each row's triangle in the meshes' numbering (mesh_offsets[mesh] + prim)
mesh_offsets : (n_meshes + 1,) int64, the first global id of each mesh
row_masks : (F,) uint32, each row's mesh mask
bounds : (F, 6) float32, each row's box
box : (6,) float32, the rows' box
seeds : ``Seeds`` of every row, Morton codes over ``box``
"""


def scene_triangles(
    verts, global_ids, mesh_offsets, row_masks, bounds=None, box=None, threads=None
):
    """``SceneTriangles`` of the rows ``verts``, with their boxes (``bounds`` and ``box`` where
    the caller holds them already: a packed level's own) and every row's seeds, made in parts
    on ``threads`` threads (None: every core)."""
    n_rows = len(verts)
    n_parts = max(1, min(threads or N_CORES, n_rows // MIN_ROWS_PER_PART))
    parts = [slice(k * n_rows // n_parts, (k + 1) * n_rows // n_parts) for k in range(n_parts)]
    if bounds is None:
        bounds = np.empty((n_rows, 6), FLOAT)
        part_boxes = np.empty((n_parts, 6), FLOAT)
        map_on_threads(
            lambda k: triangle_boxes(verts[parts[k]], bounds[parts[k]], part_boxes[k]),
            n_parts,
            n_parts,
        )
        box = np.concatenate([part_boxes[:, :3].min(axis=0), part_boxes[:, 3:].max(axis=0)])
    rows = np.arange(n_rows, dtype=INDEX)
    codes = map_on_threads(lambda k: triangle_codes(bounds, rows[parts[k]], box), n_parts, n_parts)
    codes = codes[0] if n_parts == 1 else np.concatenate(codes)
    by_code = np.argsort(codes, kind="stable")
    seeds = Seeds(codes[by_code], by_code.astype(INDEX))  # the rows, sorted by their codes
    return SceneTriangles(verts, global_ids, mesh_offsets, row_masks, bounds, box, seeds)


def sorted_seeds(tri_bounds, rows, box):
    """``Seeds`` of ``rows``: sorted by the Morton codes of their box centres over ``box``."""
    codes = triangle_codes(tri_bounds, rows, box)
    by_code = np.argsort(codes, kind="stable")
    return Seeds(codes[by_code], rows[by_code].astype(INDEX))


# Bits of a Morton code per axis (30 bits in all, a uint32).
MORTON_BITS = 10
# Rows of a scene's point setup (``scene_triangles``) below which it is made on one thread.
MIN_ROWS_PER_PART = 65536
# Global id of "no triangle" in the kernels' tie rule: above every real id.
NO_TRIANGLE = np.iinfo(np.int32).max
# sin^2 of the angle at a triangle's first corner below which its plane's normal is formed
# with exact products (the angle below 14.5 or above 165.5 degrees), where a float64 cross
# product would cancel.
THIN_SIN2 = 1.0 / 16.0


# ---- Point-triangle distance


@inline
def split_halves(x):
    """x (float64) as hi + lo, each with at most 26 significant bits (Veltkamp's split), so
    that products of halves are exact in float64."""
    t = 134217729.0 * x  # 2^27 + 1
    hi = t - (t - x)
    return hi, x - hi


@inline
def difference_of_products(a, b, c, d):
    """a*b - c*d in float64 with the products kept exact (Dekker's product, no FMA): a
    cancellation between them loses nothing, and the result is within an ulp or so."""
    ah, al = split_halves(a)
    bh, bl = split_halves(b)
    ch, cl = split_halves(c)
    dh, dl = split_halves(d)
    first = a * b
    first_lo = ((ah * bh - first) + ah * bl + al * bh) + al * bl
    second = c * d
    second_lo = ((ch * dh - second) + ch * dl + cl * dh) + cl * dl
    return (first - second) + (first_lo - second_lo)


@inline
def accurate_cross(ux, uy, uz, vx, vy, vz):
    """u x v (float64), each component within an ulp or so however thin the angle between u
    and v (``difference_of_products``)."""
    return (
        difference_of_products(uy, vz, uz, vy),
        difference_of_products(uz, vx, ux, vz),
        difference_of_products(ux, vy, uy, vx),
    )


@inline
def closest_on_edge(px, py, pz, ax, ay, az, bx, by, bz):
    """The point of segment a-b closest to p: (d2, s, qx, qy, qz), its squared distance, its
    weight of b and the point, in float64. Measured from the lexicographically smaller end, so
    the triangles that share an edge give the same d2 bit for bit (ties are then exact)."""
    swap = bx < ax or (bx == ax and (by < ay or (by == ay and bz < az)))
    if swap:
        ax, ay, az, bx, by, bz = bx, by, bz, ax, ay, az
    ex = bx - ax
    ey = by - ay
    ez = bz - az
    t = ((px - ax) * ex + (py - ay) * ey + (pz - az) * ez) / (ex * ex + ey * ey + ez * ez)
    t = min(max(t, 0.0), 1.0)
    qx = ax + t * ex
    qy = ay + t * ey
    qz = az + t * ez
    d2 = (px - qx) * (px - qx) + (py - qy) * (py - qy) + (pz - qz) * (pz - qz)
    return d2, (1.0 - t) if swap else t, qx, qy, qz


@inline
def closest_on_triangle(px, py, pz, verts, row):
    """The point of triangle ``row`` of ``verts`` (F, 9) float32 closest to p (float64):
    (d2, u, v, qx, qy, qz), its squared distance, its barycentrics (q = (1-u-v)*p0 + u*p1 +
    v*p2) and the point, in float64.

    Ericson's region test (Real-Time Collision Detection, 5.1.5) picks the vertex, edge or face
    region of p; an edge is measured by ``closest_on_edge``, the face by the distance to the
    plane, which is 0 exactly for a point on an axis-aligned face. The plane's normal is the
    cross product of the edges at p0, or where its angle is near 0 or 180 degrees that of the
    edges at the largest angle with exact products (``accurate_cross``): a thin triangle's
    face distance is as accurate as any other's."""
    ax = np.float64(verts[row, 0])
    ay = np.float64(verts[row, 1])
    az = np.float64(verts[row, 2])
    bx = np.float64(verts[row, 3])
    by = np.float64(verts[row, 4])
    bz = np.float64(verts[row, 5])
    cx = np.float64(verts[row, 6])
    cy = np.float64(verts[row, 7])
    cz = np.float64(verts[row, 8])
    abx = bx - ax
    aby = by - ay
    abz = bz - az
    acx = cx - ax
    acy = cy - ay
    acz = cz - az
    apx = px - ax
    apy = py - ay
    apz = pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:  # vertex a
        return apx * apx + apy * apy + apz * apz, 0.0, 0.0, ax, ay, az
    bpx = px - bx
    bpy = py - by
    bpz = pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:  # vertex b
        return bpx * bpx + bpy * bpy + bpz * bpz, 1.0, 0.0, bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:  # edge ab
        e2, s, qx, qy, qz = closest_on_edge(px, py, pz, ax, ay, az, bx, by, bz)
        return e2, s, 0.0, qx, qy, qz
    cpx = px - cx
    cpy = py - cy
    cpz = pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:  # vertex c
        return cpx * cpx + cpy * cpy + cpz * cpz, 0.0, 1.0, cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:  # edge ac
        e2, s, qx, qy, qz = closest_on_edge(px, py, pz, ax, ay, az, cx, cy, cz)
        return e2, 0.0, s, qx, qy, qz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:  # edge bc
        e2, s, qx, qy, qz = closest_on_edge(px, py, pz, bx, by, bz, cx, cy, cz)
        return e2, 1.0 - s, s, qx, qy, qz
    # Face: the distance to the plane. Its normal (b - a) x (c - a) cancels where the angle
    # at a is near 0 or 180 degrees (a thin triangle): then it is taken at the largest angle
    # (opposite the longest edge), from the best-conditioned pair of edges, with exact products.
    nx = aby * acz - abz * acy
    ny = abz * acx - abx * acz
    nz = abx * acy - aby * acx
    nn = nx * nx + ny * ny + nz * nz
    ab2 = abx * abx + aby * aby + abz * abz
    ac2 = acx * acx + acy * acy + acz * acz
    wpx, wpy, wpz = apx, apy, apz
    if nn < THIN_SIN2 * ab2 * ac2:
        bcx = cx - bx
        bcy = cy - by
        bcz = cz - bz
        bc2 = bcx * bcx + bcy * bcy + bcz * bcz
        if bc2 >= ab2 and bc2 >= ac2:  # at a: (b - a) x (c - a)
            nx, ny, nz = accurate_cross(abx, aby, abz, acx, acy, acz)
        elif ac2 >= ab2:  # at b: (c - b) x (a - b), the same orientation
            nx, ny, nz = accurate_cross(bcx, bcy, bcz, -abx, -aby, -abz)
            wpx, wpy, wpz = bpx, bpy, bpz
        else:  # at c: (a - c) x (b - c)
            nx, ny, nz = accurate_cross(-acx, -acy, -acz, -bcx, -bcy, -bcz)
            wpx, wpy, wpz = cpx, cpy, cpz
        nn = nx * nx + ny * ny + nz * nz
    along = (nx * wpx + ny * wpy + nz * wpz) / nn
    total = va + vb + vc
    return (
        along * along * nn,
        vb / total,
        vc / total,
        px - along * nx,
        py - along * ny,
        pz - along * nz,
    )


@inline
def box_distance2(px, py, pz, box):
    """Squared distance from p (float64) to the box [x0, y0, z0, x1, y1, z1] (float32), in
    float64: 0 inside."""
    dx = max(np.float64(box[0]) - px, px - np.float64(box[3]), 0.0)
    dy = max(np.float64(box[1]) - py, py - np.float64(box[4]), 0.0)
    dz = max(np.float64(box[2]) - pz, pz - np.float64(box[5]), 0.0)
    return dx * dx + dy * dy + dz * dz


@inline
def reach(best_d2, slack2):
    """The squared distance beyond which a box cannot hold a triangle that ties or beats
    ``best_d2``: grown so that rounding in the triangle's distance never culls it."""
    return best_d2 * POINT_CULL_GROWTH + slack2


@inline
def beats(d2, tri_id, best_d2, best_id):
    """Whether a triangle at squared distance d2 with global id ``tri_id`` is a better answer
    than the best so far: nearer, or as near with a lower id."""
    return d2 < best_d2 or (d2 == best_d2 and tri_id < best_id)


# ---- Morton order: seeds and chunks


@inline
def spread_bits(k):
    """The low 10 bits of k spread to every third bit (bit i to bit 3i)."""
    k = (k | (k << 16)) & 0x030000FF
    k = (k | (k << 8)) & 0x0300F00F
    k = (k | (k << 4)) & 0x030C30C3
    k = (k | (k << 2)) & 0x09249249
    return k


@inline
def morton_code(x, y, z, box):
    """The 30-bit Morton code of (x, y, z) (float64) on a 1024^3 grid over ``box`` (6,),
    clamped to it."""
    cells = (1 << MORTON_BITS) - 1
    code = 0
    for a in range(3):
        value = x if a == 0 else (y if a == 1 else z)
        lo = np.float64(box[a])
        extent = np.float64(box[a + 3]) - lo
        # Clamped before the conversion: a point far outside would overflow the integer.
        k = int(min(max((value - lo) / extent * cells, 0.0), cells)) if extent > 0 else 0
        code |= spread_bits(k) << a
    return code


@jit
def triangle_codes(tri_bounds, rows, box):
    """(len(rows),) int64: the Morton code of the box centre of each row of ``rows``."""
    codes = np.empty(len(rows), np.int64)
    for i in range(len(rows)):
        row = rows[i]
        x = 0.5 * (np.float64(tri_bounds[row, 0]) + np.float64(tri_bounds[row, 3]))
        y = 0.5 * (np.float64(tri_bounds[row, 1]) + np.float64(tri_bounds[row, 4]))
        z = 0.5 * (np.float64(tri_bounds[row, 2]) + np.float64(tri_bounds[row, 5]))
        codes[i] = morton_code(x, y, z, box)
    return codes


@jit
def point_order(points, box, bits):
    """The point ids (int32) sorted by the top ``bits`` bits of their Morton codes over ``box``,
    by counting (stable): neighbours in the order are near each other, so a run of them makes a
    chunk whose points meet few triangles."""
    n = points.shape[0]
    shift = 3 * MORTON_BITS - bits
    keys = np.empty(n, np.int64)
    starts = np.zeros((1 << bits) + 1, np.int64)
    for i in range(n):
        code = morton_code(
            np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2]), box
        )
        keys[i] = code >> shift
        starts[keys[i] + 1] += 1
    for k in range(1 << bits):
        starts[k + 1] += starts[k]
    order = np.empty(n, np.int32)
    for i in range(n):
        order[starts[keys[i]]] = i
        starts[keys[i]] += 1
    return order


# ---- One chunk of points


@jit
def nearest_chunk(
    points,
    chunk_ids,
    point_masks,
    tris,
    tri_global,
    tri_masks,
    root_box,
    seeds,
    n_seeds,
    max_d2,
    slack2,
    out,
    stats,
):
    """The closest triangle of each point ``chunk_ids`` of ``points`` (N, 3) float32, among
    ``tris.ids`` (``Triangles``, permuted in place) whose box is ``root_box``, within squared
    distance ``max_d2``.

    point_masks : (N,) uint32 and tri_masks : (F,) uint32 by kernel row, or both (0,): a point
        sees a row where the masks share a bit
    seeds : ``Seeds``, of which each point measures ``n_seeds`` beside its own Morton code
    slack2 : absolute slack of the cull, in squared distance
    Writes each point's answer to ``out`` (``NearestArrays``) by point id; adds to ``stats``
    (``POINT_STAT_NAMES``)."""
    n = len(chunk_ids)
    masked = len(point_masks) > 0
    # The chunk's points as float64 rows, by local id; the partitions permute local ids.
    xyz = np.empty((n, 3))
    best_d2 = np.full(n, max_d2)
    best_row = np.full(n, -1, np.int64)
    best_id = np.full(n, NO_TRIANGLE, np.int64)
    local_masks = np.empty(n if masked else 0, np.uint32)
    for i in range(n):
        for a in range(3):
            xyz[i, a] = points[chunk_ids[i], a]
        if masked:
            local_masks[i] = point_masks[chunk_ids[i]]

    # Seeds: the triangles beside each point on the Morton curve give it a radius.
    n_seeds = min(n_seeds, len(seeds.rows))
    for i in range(n):
        px, py, pz = xyz[i, 0], xyz[i, 1], xyz[i, 2]
        at = np.searchsorted(seeds.codes, morton_code(px, py, pz, root_box))
        first = min(max(at - n_seeds // 2, 0), len(seeds.rows) - n_seeds)
        for k in range(first, first + n_seeds):
            row = seeds.rows[k]
            if masked and (local_masks[i] & tri_masks[row]) == 0:
                continue
            d2 = closest_on_triangle(px, py, pz, tris.verts, row)[0]
            if beats(d2, tri_global[row], best_d2[i], best_id[i]):
                best_d2[i] = d2
                best_row[i] = row
                best_id[i] = tri_global[row]
        stats[STAT_POINT_SEED_TESTS] += n_seeds

    point_ids = np.arange(n).astype(np.int32)
    culled_ids = np.empty(n, np.int32)  # scratch of the filters
    n_stack = MAX_DEPTH + 2
    stack_tri = np.empty((n_stack, 2), np.int64)
    stack_point = np.empty((n_stack, 2), np.int64)
    stack_depth = np.empty(n_stack, np.int64)
    stack_box = np.empty((n_stack, 6), np.float32)
    boxes = np.empty((3, 6), np.float32)  # the sides' boxes of a split, and scratch
    stack_tri[0, 0] = 0
    stack_tri[0, 1] = len(tris.ids)
    stack_point[0, 0] = 0
    stack_point[0, 1] = n
    stack_depth[0] = 0
    stack_box[0, :] = root_box
    sp = 1
    while sp > 0:
        sp -= 1
        tri_lo = stack_tri[sp, 0]
        tri_hi = stack_tri[sp, 1]
        point_lo = stack_point[sp, 0]
        depth = stack_depth[sp]
        box = stack_box[sp]
        stats[STAT_POINT_NODES] += 1
        stats[STAT_POINT_MAX_DEPTH] = max(stats[STAT_POINT_MAX_DEPTH], depth)
        # Keep the points whose radius reaches the box, at the front in their order (neighbours
        # stay neighbours), with no branch on the test; sum them for the order of the children.
        stats[STAT_POINT_BOX_TESTS] += stack_point[sp, 1] - point_lo
        point_hi = point_lo
        n_culled = 0
        sx = sy = sz = 0.0
        for i in range(point_lo, stack_point[sp, 1]):
            p = point_ids[i]
            x, y, z = xyz[p, 0], xyz[p, 1], xyz[p, 2]
            keep = box_distance2(x, y, z, box) <= reach(best_d2[p], slack2)
            point_ids[point_hi] = p
            culled_ids[n_culled] = p
            point_hi += keep
            n_culled += 1 - keep
            weight = 1.0 if keep else 0.0
            sx += weight * x
            sy += weight * y
            sz += weight * z
        point_ids[point_hi : point_hi + n_culled] = culled_ids[:n_culled]
        n_points = point_hi - point_lo
        n_tris = tri_hi - tri_lo
        if n_points == 0:
            continue
        if (
            n_points * n_tris <= POINT_LEAF_C_P * n_points + POINT_LEAF_C_T * n_tris
            or depth >= MAX_DEPTH
        ):
            stats[STAT_POINT_LEAVES] += 1
            stats[STAT_POINT_TRIANGLE_TESTS] += measure_leaf(
                xyz,
                point_ids,
                point_lo,
                point_hi,
                local_masks,
                tris,
                tri_lo,
                tri_hi,
                tri_global,
                tri_masks,
                slack2,
                best_d2,
                best_row,
                best_id,
            )
            continue
        _, tri_mid = split_middle(tris, tri_lo, tri_hi, box, boxes)
        # The side nearer the points' mean is visited first: its triangles shrink the radii.
        mx = sx / n_points
        my = sy / n_points
        mz = sz / n_points
        left_gap = box_distance2(mx, my, mz, boxes[0])
        right_gap = box_distance2(mx, my, mz, boxes[1])
        if left_gap == right_gap:
            left_gap = centre_distance2(mx, my, mz, boxes[0])
            right_gap = centre_distance2(mx, my, mz, boxes[1])
        left_first = left_gap <= right_gap
        # Push the later child first, so the nearer one is popped next.
        for side in range(2):
            is_left = (side == 0) != left_first
            stack_tri[sp, 0] = tri_lo if is_left else tri_mid
            stack_tri[sp, 1] = tri_mid if is_left else tri_hi
            stack_box[sp, :] = boxes[0] if is_left else boxes[1]
            stack_point[sp, 0] = point_lo
            stack_point[sp, 1] = point_hi
            stack_depth[sp] = depth + 1
            sp += 1

    # The answers, with each closest point measured again from its triangle.
    for i in range(n):
        p = chunk_ids[i]
        out.global_id[p] = best_id[i]
        if best_row[i] >= 0:
            _, u, v, qx, qy, qz = closest_on_triangle(
                xyz[i, 0], xyz[i, 1], xyz[i, 2], tris.verts, best_row[i]
            )
            out.d2[p] = best_d2[i]
            out.u[p] = u
            out.v[p] = v
            out.point[p, 0] = qx
            out.point[p, 1] = qy
            out.point[p, 2] = qz


@inline
def centre_distance2(px, py, pz, box):
    """Squared distance from p to the centre of ``box``."""
    dx = px - 0.5 * (np.float64(box[0]) + np.float64(box[3]))
    dy = py - 0.5 * (np.float64(box[1]) + np.float64(box[4]))
    dz = pz - 0.5 * (np.float64(box[2]) + np.float64(box[5]))
    return dx * dx + dy * dy + dz * dz


@jit
def measure_leaf(
    xyz,
    point_ids,
    point_lo,
    point_hi,
    point_masks,
    tris,
    tri_lo,
    tri_hi,
    tri_global,
    tri_masks,
    slack2,
    best_d2,
    best_row,
    best_id,
):
    """Every point of ``point_ids[point_lo:point_hi]`` against every triangle of
    ``tris.ids[tri_lo:tri_hi]`` whose box its radius reaches, exactly; returns the pairs
    measured."""
    masked = len(point_masks) > 0
    n_measured = 0
    for i in range(point_lo, point_hi):
        p = point_ids[i]
        px, py, pz = xyz[p, 0], xyz[p, 1], xyz[p, 2]
        p_d2 = best_d2[p]
        p_row = best_row[p]
        p_id = best_id[p]
        limit = reach(p_d2, slack2)
        for j in range(tri_lo, tri_hi):
            row = tris.ids[j]
            if masked and (point_masks[p] & tri_masks[row]) == 0:
                continue
            if box_distance2(px, py, pz, tris.bounds[row]) > limit:
                continue
            n_measured += 1
            d2 = closest_on_triangle(px, py, pz, tris.verts, row)[0]
            if beats(d2, tri_global[row], p_d2, p_id):
                p_d2 = d2
                p_row = row
                p_id = tri_global[row]
                limit = reach(p_d2, slack2)
        best_d2[p] = p_d2
        best_row[p] = p_row
        best_id[p] = p_id
    return n_measured


# ---- The query


def nearest(scene_triangles, points, max_distance, point_masks, visible_rows, threads):
    """The closest point of each of ``points`` (N, 3) float32 (finite, checked) on the triangles
    of ``scene_triangles`` (``SceneTriangles``) within ``max_distance`` (float, inf for none).

    point_masks : (N,) uint32 when the points' masks differ, else (0,)
    visible_rows : (k,) int32 rows the points see, or None for every row
    threads : a positive int. Returns ``NearestArrays`` and the counters (a dict)."""
    n_points = len(points)
    verts = scene_triangles.verts
    rows = np.arange(len(verts), dtype=INDEX) if visible_rows is None else visible_rows
    counters = dict.fromkeys(POINT_STAT_NAMES, 0)
    counters["points"] = n_points
    counters["triangles"] = len(rows)
    answer = NearestArrays(
        d2=np.full(n_points, np.inf),
        global_id=np.full(n_points, NO_TRIANGLE, np.int64),
        u=np.zeros(n_points),
        v=np.zeros(n_points),
        point=np.full((n_points, 3), np.inf),
    )
    if n_points == 0 or len(rows) == 0:
        return answer, counters
    tri_bounds = scene_triangles.bounds
    if visible_rows is None:  # every row: the seeds the scene derived once
        box, seeds = scene_triangles.box, scene_triangles.seeds
    else:
        box = visible_box(tri_bounds, rows)
        seeds = sorted_seeds(tri_bounds, rows, box)
    extent = float(np.max(box[3:].astype(np.float64) - box[:3]))
    slack2 = (POINT_CULL_SLACK * max(extent, float(np.max(np.abs(box))))) ** 2
    max_d2 = search_limit2(max_distance)
    order = point_order(points, box, POINT_ORDER_BITS)
    n_chunks = max(min(threads, n_points), -(-n_points // POINT_CHUNK))
    tri_masks = scene_triangles.row_masks if len(point_masks) else np.empty(0, np.uint32)

    def run(chunk):
        chunk_ids = order[chunk * n_points // n_chunks : (chunk + 1) * n_points // n_chunks]
        tris = Triangles(verts, tri_bounds, rows.copy())
        chunk_stats = np.zeros(len(POINT_STAT_NAMES), np.int64)
        nearest_chunk(
            points,
            chunk_ids,
            point_masks,
            tris,
            scene_triangles.global_ids,
            tri_masks,
            box,
            seeds,
            POINT_SEEDS,
            max_d2,
            slack2,
            answer,
            chunk_stats,
        )
        return chunk_stats

    per_chunk = map_on_threads(run, n_chunks, min(threads, n_chunks))
    totals = np.sum(per_chunk, axis=0)
    for k, name in enumerate(POINT_STAT_NAMES):
        if name not in ("points", "triangles", "max_depth"):
            counters[name] = int(totals[k])
    counters["max_depth"] = int(max(c[STAT_POINT_MAX_DEPTH] for c in per_chunk))
    return answer, counters


def search_limit2(max_distance):
    """The squared radius a search within ``max_distance`` covers: every distance that rounds
    to a float32 of at most ``max_distance`` (``nearest_query`` drops the rest), so that a
    distance the query reported, given back as the limit, keeps its answer."""
    above = np.nextafter(np.float32(max_distance), np.float32(np.inf))
    return float(above) ** 2


def visible_box(tri_bounds, rows):
    """(6,) float32: the box of the triangles ``rows``."""
    bounds = tri_bounds[rows]
    return np.concatenate([bounds[:, :3].min(axis=0), bounds[:, 3:].max(axis=0)]).astype(FLOAT)


def mesh_and_prim(global_id, mesh_offsets):
    """(mesh, prim) int32 of each global triangle id (NO_TRIANGLE: -1, -1)."""
    found = global_id != NO_TRIANGLE
    mesh = np.full(len(global_id), MISS, INDEX)
    prim = np.full(len(global_id), MISS, INDEX)
    mesh[found] = np.searchsorted(mesh_offsets, global_id[found], side="right") - 1
    prim[found] = global_id[found] - mesh_offsets[mesh[found]]
    return mesh, prim


# ---- Inside or outside


def sample_directions(n):
    """(n, 3) float32 unit directions, spread over the sphere: a golden-angle spiral (direction
    k at height 1 - (2k + 1)/n, turned k golden angles about z), turned as a whole by a fixed
    rotation so that none lies along an axis or in a coordinate plane."""
    k = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * k + 1.0) / n
    ring = np.sqrt(1.0 - z * z)
    angle = k * np.pi * (3.0 - np.sqrt(5.0))
    spiral = np.stack([ring * np.cos(angle), ring * np.sin(angle), z], axis=1)
    return (spiral @ TILT.T).astype(FLOAT)


def _tilt():
    """A fixed rotation: about the unit axis (1, 2, 3)/sqrt(14) by 1 radian (Rodrigues)."""
    axis = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(1.0) * cross + (1.0 - np.cos(1.0)) * cross @ cross


TILT = _tilt()

# Rays a call of the inside test traces at once: one direction a call would partition the
# scene nsamples times for a handful of points.
VOTE_BATCH_RAYS = 1 << 20


def directions_a_batch(n_points):
    """How many directions of the inside test one engine call traces for ``n_points`` points."""
    return max(1, VOTE_BATCH_RAYS // max(n_points, 1))


def vote_rays_at_once(n_points, nsamples):
    """The most rays one engine call of the inside test traces (for a memory budget)."""
    return n_points * min(nsamples, directions_a_batch(n_points))


def inside_by_votes(count_along, n_points, nsamples):
    """(n_points,) bool: whether most of ``nsamples`` directions (``sample_directions``) cross
    the surface an odd number of times; ``count_along(directions)`` gives the (k, n_points)
    counts of the rays from the points along each of k (k, 3) float32 directions, called with
    as many directions at once as make about ``VOTE_BATCH_RAYS`` rays."""
    votes = np.zeros(n_points, np.int64)
    directions = sample_directions(nsamples)
    per_batch = directions_a_batch(n_points)
    for start in range(0, nsamples, per_batch):
        votes += (count_along(directions[start : start + per_batch]) % 2).sum(axis=0)
    return 2 * votes > nsamples


def signed(distance, inside):
    """float32 distance made negative where ``inside``; 0 stays 0 (a point on the surface)."""
    return np.where(inside & (distance > 0), -distance, distance).astype(FLOAT)


# ---- The public queries (``Scene.nearest``, ``contains``, ``signed_distance``)


def nearest_query(scene, points, max_distance=None, mask=None, threads=None, stats=False):
    """``Scene.nearest``: checks the input, finds each point's closest triangle, returns
    ``Nearest``."""
    points = check_points(points)
    max_distance = check_max_distance(max_distance)
    threads = check_threads(threads, N_CORES)
    triangles = scene._scene_triangles(threads)
    n_points = len(points)
    point_masks = None if mask is None else check_masks(mask, n_points, "mask", "point")
    uniform = point_masks is None or not n_points or (point_masks == point_masks[0]).all()
    visible_rows = None
    if uniform:
        point_mask = ALL_MASKS if point_masks is None or not n_points else point_masks[0]
        seen = (triangles.row_masks & point_mask) != 0
        if not seen.all():
            visible_rows = np.flatnonzero(seen).astype(INDEX)
        point_masks = np.empty(0, np.uint32)
    found, counters = nearest(triangles, points, max_distance, point_masks, visible_rows, threads)
    mesh, prim = mesh_and_prim(found.global_id, triangles.mesh_offsets)
    with np.errstate(over="ignore"):  # a distance beyond float32's range reads inf
        distance = np.sqrt(found.d2).astype(FLOAT)
    point, u, v = found.point.astype(FLOAT), found.u.astype(FLOAT), found.v.astype(FLOAT)
    # A closest point farther than float32 can say is none, as a ray's hit beyond it is a miss;
    # the limit is decided on the reported float32 distance, as a ray's range on its t.
    beyond = (np.isinf(distance) | (distance.astype(np.float64) > max_distance)) & (mesh != MISS)
    if beyond.any():
        mesh[beyond] = prim[beyond] = MISS
        distance[beyond], point[beyond], u[beyond], v[beyond] = np.inf, np.inf, 0.0, 0.0
    return Nearest(
        distance=distance,
        point=point,
        mesh=mesh,
        prim=prim,
        u=u,
        v=v,
        stats=counters if stats else None,
    )


def contains_query(scene, points, nsamples=1, mask=None, threads=None):
    """``Scene.contains``: (n,) bool, by the majority of ``nsamples`` parities."""
    points = check_points(points)
    nsamples = check_nsamples(nsamples)
    threads = check_threads(threads, N_CORES)
    n_points = len(points)
    if mask is not None:
        mask = check_masks(mask, n_points, "mask", "point")

    def count_along(directions):
        k = len(directions)
        origins = np.tile(points, (k, 1))
        along = np.repeat(directions, n_points, axis=0)
        masks = None if mask is None else np.tile(mask, k)
        # count's crossings, answered too where a ray would leave float32 in a placed mesh's space
        counts = scene._inside_counts(origins, along, masks, threads)
        return counts.reshape(k, n_points)

    return inside_by_votes(count_along, len(points), nsamples)


def signed_distance_query(scene, points, nsamples=1, max_distance=None, mask=None, threads=None):
    """``Scene.signed_distance``: (n,) float32, negative inside."""
    points = check_points(points)
    check_nsamples(nsamples)
    found = nearest_query(scene, points, max_distance, mask, threads)
    inside = contains_query(scene, points, nsamples, mask, threads)
    return signed(found.distance, inside)
