"""The kernels of one level of the breadth-first traversal, one thread per item.

A level ("frontier") holds nodes; node k owns triangle slots tri_lo[k]:tri_lo[k] + tri_n[k]
(kernel rows) and ray slots of its own (ray ids), each slot knowing its node. Leaves test their
rays against their triangles; inner nodes split their triangles at the middle of the longest
axis of their box (or, where that leaves a side empty, by position) and send each ray to the
children whose boxes it reaches.
"""

import numpy as np
from numba import cuda

from .arith import float_bits
from .boxes import cull_distance, hits_box
from .watertight import crossing, ray_frame, triangle_hit

LEAF = 0
# A node split at the middle of its box, or into the halves of its slot range.
SPLIT_MIDDLE = 1
SPLIT_HALVES = 2
# A ray's best key before any hit: larger than every (t, triangle) key.
NO_KEY = np.uint64(0xFFFFFFFFFFFFFFFF)
SIGN32 = np.uint64(0x80000000)
LOW32 = np.uint64(0xFFFFFFFF)


@cuda.jit(device=True)
def tie_order_key(t, tri_id):
    """(t, tri_id) as one uint64 whose order is theirs: t's bits made monotonic, then the id."""
    bits = np.uint64(float_bits(t)) & LOW32
    bits = (bits ^ LOW32) if bits >= SIGN32 else (bits | SIGN32)
    return (bits << np.uint64(32)) | np.uint64(tri_id)


@cuda.jit(device=True)
def side_of(slot, node, kind, tri_lo, tri_n, axis, middle, rows, centroids):
    """0 (first child) or 1 (second) for triangle slot ``slot`` of inner node ``node``."""
    if kind[node] == SPLIT_HALVES:
        return 0 if slot - tri_lo[node] < tri_n[node] // 2 else 1
    return 0 if centroids[rows[slot], axis[node]] < middle[node] else 1


@cuda.jit
def count_first_side(rows, tri_node, kind, tri_lo, tri_n, axis, middle, centroids, first_n):
    """first_n[node] = triangles of each middle-split node on the first side."""
    s = cuda.grid(1)
    if s >= rows.shape[0]:
        return
    node = tri_node[s]
    if kind[node] != SPLIT_MIDDLE:
        return
    if side_of(s, node, kind, tri_lo, tri_n, axis, middle, rows, centroids) == 0:
        cuda.atomic.add(first_n, node, 1)


@cuda.jit
def child_boxes(rows, tri_node, kind, tri_lo, tri_n, axis, middle, centroids, tri_box, boxes):
    """boxes[2 * node + side] = the box of the triangles of each inner node's child."""
    s = cuda.grid(1)
    if s >= rows.shape[0]:
        return
    node = tri_node[s]
    if kind[node] == LEAF:
        return
    child = 2 * node + side_of(s, node, kind, tri_lo, tri_n, axis, middle, rows, centroids)
    row = rows[s]
    for a in range(3):
        cuda.atomic.min(boxes, (child, a), tri_box[row, a])
        cuda.atomic.max(boxes, (child, 3 + a), tri_box[row, 3 + a])


@cuda.jit
def count_child_rays(ray_ids, ray_node, kind, origins, inv_dirs, tmin, tmax, boxes, reach, ray_n):
    """reach[slot] = bit s set where the slot's ray reaches child 2 * node + s;
    ray_n[child] counts them."""
    p = cuda.grid(1)
    if p >= ray_ids.shape[0]:
        return
    node = ray_node[p]
    bits = 0
    if kind[node] != LEAF:
        r = ray_ids[p]
        for side in range(2):
            child = 2 * node + side
            if hits_box(
                origins[r, 0], origins[r, 1], origins[r, 2],
                inv_dirs[r, 0], inv_dirs[r, 1], inv_dirs[r, 2],
                tmin[r], cull_distance(tmax[r]), boxes, child,
            ):  # fmt: skip
                bits |= 1 << side
                cuda.atomic.add(ray_n, child, 1)
    reach[p] = bits


@cuda.jit
def scatter_triangles(
    rows, tri_node, kind, tri_lo, tri_n, axis, middle, centroids, new_index, new_lo, cursor,
    new_rows, new_tri_node,
):  # fmt: skip
    """Copy each inner node's triangle slots to its kept children (new_index >= 0), each at
    new_lo[child] plus a place taken from cursor[child]."""
    s = cuda.grid(1)
    if s >= rows.shape[0]:
        return
    node = tri_node[s]
    if kind[node] == LEAF:
        return
    child = 2 * node + side_of(s, node, kind, tri_lo, tri_n, axis, middle, rows, centroids)
    k = new_index[child]
    if k < 0:
        return
    at = new_lo[k] + cuda.atomic.add(cursor, k, 1)
    new_rows[at] = rows[s]
    new_tri_node[at] = k


@cuda.jit
def scatter_rays(ray_ids, ray_node, reach, new_index, new_lo, cursor, new_ray_ids, new_ray_node):
    """Copy each ray slot to the kept children it reaches (``count_child_rays``)."""
    p = cuda.grid(1)
    if p >= ray_ids.shape[0]:
        return
    node = ray_node[p]
    for side in range(2):
        if reach[p] & (1 << side):
            k = new_index[2 * node + side]
            if k >= 0:
                at = new_lo[k] + cuda.atomic.add(cursor, k, 1)
                new_ray_ids[at] = ray_ids[p]
                new_ray_node[at] = k


@cuda.jit(device=True)
def seen(r, row, ray_masks, tri_masks):
    """Whether ray r's mask sees row ``row`` (no masks: every row)."""
    return ray_masks.shape[0] == 0 or (ray_masks[r] & tri_masks[row]) != 0


@cuda.jit
def leaf_closest(
    ray_ids, ray_node, kind, tri_lo, tri_n, rows, origins, directions, tmin, tmax, verts,
    tri_keys, ray_masks, tri_masks, cull_side, best_key,
):  # fmt: skip
    """Each leaf ray slot's best (t, tie key) over its leaf's triangles, merged into
    best_key[ray] by an atomic min: ties in t go to the lowest key, whatever the order."""
    p = cuda.grid(1)
    if p >= ray_ids.shape[0]:
        return
    node = ray_node[p]
    if kind[node] != LEAF:
        return
    r = ray_ids[p]
    kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_frame(
        origins[r, 0], origins[r, 1], origins[r, 2],
        directions[r, 0], directions[r, 1], directions[r, 2],
    )  # fmt: skip
    best = NO_KEY
    for s in range(tri_lo[node], tri_lo[node] + tri_n[node]):
        row = rows[s]
        if not seen(r, row, ray_masks, tri_masks):
            continue
        hit, t, det, _, _ = triangle_hit(verts, row, kx, ky, kz, sx, sy, sz, okx, oky, okz)
        # Ranges are decided on the float32 t that is reported, as on the CPU.
        if not hit or not (t >= tmin[r] and t <= tmax[r]) or det * cull_side > 0.0:
            continue
        key = tie_order_key(t, tri_keys[row])
        if key < best:
            best = key
    if best != NO_KEY:
        cuda.atomic.min(best_key, r, best)


@cuda.jit
def leaf_any(
    ray_ids, ray_node, kind, tri_lo, tri_n, rows, origins, directions, tmin, tmax, verts,
    ray_masks, tri_masks, cull_side, occluded,
):  # fmt: skip
    """occluded[ray] = 1 where a leaf ray slot hits any of its leaf's triangles."""
    p = cuda.grid(1)
    if p >= ray_ids.shape[0]:
        return
    node = ray_node[p]
    r = ray_ids[p]
    if kind[node] != LEAF or occluded[r]:
        return
    kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_frame(
        origins[r, 0], origins[r, 1], origins[r, 2],
        directions[r, 0], directions[r, 1], directions[r, 2],
    )  # fmt: skip
    for s in range(tri_lo[node], tri_lo[node] + tri_n[node]):
        row = rows[s]
        if not seen(r, row, ray_masks, tri_masks):
            continue
        hit, t, det, _, _ = triangle_hit(verts, row, kx, ky, kz, sx, sy, sz, okx, oky, okz)
        if hit and t >= tmin[r] and t <= tmax[r] and not det * cull_side > 0.0:
            occluded[r] = 1
            return


@cuda.jit(device=True)
def keep_nearest(lists, r, key):
    """Put ``key`` into ray r's row of ``lists`` in place of its largest entry, where it is
    smaller: the row then holds the smallest keys given to it (NO_KEY filling the rest),
    whatever the threads' order. Lock-free: each slot only ever decreases, so a value read
    earlier is at least the slot's value now, and a compare-and-swap on the largest read
    replaces the row's largest now; a failed one was beaten by another thread and retries
    with slots read atomically (plain reads may come from a stale cache line)."""
    exact = False
    while True:
        worst = 0
        worst_key = lists[r, 0] if not exact else cuda.atomic.or_(lists, (r, 0), np.uint64(0))
        for k in range(1, lists.shape[1]):
            held = lists[r, k] if not exact else cuda.atomic.or_(lists, (r, k), np.uint64(0))
            if held > worst_key:
                worst = k
                worst_key = held
        if key >= worst_key:
            return
        if cuda.atomic.cas(lists, (r, worst), worst_key, key) == worst_key:
            return
        exact = True


@cuda.jit
def leaf_crossings(
    ray_ids, ray_node, kind, tri_lo, tri_n, rows, origins, directions, tmin, tmax, verts,
    tri_keys, ray_masks, tri_masks, cull_side, counts, lists,
):  # fmt: skip
    """Each leaf ray slot's crossings (``watertight.crossing``) of its leaf's triangles:
    counts[ray] adds them, and where lists has columns its row keeps the ray's smallest
    (t, tie key) keys (``keep_nearest``). Each triangle lives in one leaf, which a ray visits
    once, so every crossing is counted once."""
    p = cuda.grid(1)
    if p >= ray_ids.shape[0]:
        return
    node = ray_node[p]
    if kind[node] != LEAF:
        return
    r = ray_ids[p]
    kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_frame(
        origins[r, 0], origins[r, 1], origins[r, 2],
        directions[r, 0], directions[r, 1], directions[r, 2],
    )  # fmt: skip
    keep = lists.shape[1] > 0
    found = 0
    for s in range(tri_lo[node], tri_lo[node] + tri_n[node]):
        row = rows[s]
        if not seen(r, row, ray_masks, tri_masks):
            continue
        crossed, t, det = crossing(verts, row, kx, ky, kz, sx, sy, sz, okx, oky, okz)
        # Ranges are decided on the float32 t that is reported, as on the CPU.
        if not crossed or not (t >= tmin[r] and t <= tmax[r]) or det * cull_side > 0.0:
            continue
        found += 1
        if keep:
            keep_nearest(lists, r, tie_order_key(t, tri_keys[row]))
    if found:
        cuda.atomic.add(counts, r, found)


@cuda.jit
def finish_best(
    best_key, row_of_key, origins, directions, verts, no_hit, best_t, best_tri, hit_u, hit_v
):
    """Each ray's winner as the CPU kernels leave it: best_t, kernel row (no_hit for none),
    and u, v recomputed by the same test (0 on a miss)."""
    r = cuda.grid(1)
    if r >= best_key.shape[0]:
        return
    key = best_key[r]
    if key == NO_KEY:
        best_tri[r] = no_hit
        hit_u[r] = 0.0
        hit_v[r] = 0.0
        return
    row = row_of_key[key & LOW32]
    kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_frame(
        origins[r, 0], origins[r, 1], origins[r, 2],
        directions[r, 0], directions[r, 1], directions[r, 2],
    )  # fmt: skip
    _, t, _, u, v = triangle_hit(verts, row, kx, ky, kz, sx, sy, sz, okx, oky, okz)
    best_t[r] = t
    best_tri[r] = row
    hit_u[r] = u
    hit_v[r] = v
