"""Partitioning: binning, split choice helpers, and in-place partition of index ranges.

Every function works on a half-open range ``[lo, hi)`` of an index array and allocates nothing;
the caller owns the scratch arrays. Triangles come as one ``Triangles`` record: the range is of
``tris.ids``, and ``tris.bounds`` holds each kernel row's box [x0, y0, z0, x1, y1, z1].
"""

import numpy as np

from .config import BIN_SHRINK, PARTITION_BLOCK, inline
from .geometry import cull_distance, intersect_box, inverse
from .rays import DIRECTION_QUAD, ORIGIN_QUAD, quad_view, swap_rays


@inline
def centroid(tri_bounds, tri, axis):
    """Centre of a triangle's box along ``axis`` (what binning sorts by)."""
    return 0.5 * (np.float64(tri_bounds[tri, axis]) + np.float64(tri_bounds[tri, axis + 3]))


@inline
def bin_of(c, c_min, scale, n_bins):
    """Bin of a centroid coordinate; the same expression for binning and partitioning, so
    the partition matches the binned counts exactly."""
    b = int((c - c_min) * scale)
    if b < 0:
        return 0
    if b >= n_bins:
        return n_bins - 1
    return b


@inline
def bin_scale(c_min, c_max, n_bins):
    return n_bins * BIN_SHRINK / (c_max - c_min)


@inline
def centroid_bounds(tris, lo, hi, out):
    """Box of the centroids of triangles ``tris.ids[lo:hi]`` into ``out`` (6,).

    Running bounds in locals, since LLVM cannot keep a float32 ``out`` in registers. Rounded
    once at the end, which gives what rounding each update would (rounding is monotonic)."""
    tri_bounds = tris.bounds
    x0 = y0 = z0 = np.inf
    x1 = y1 = z1 = -np.inf
    for tri_id in tris.ids[lo:hi]:
        tri = np.uint32(tri_id)  # unsigned: no index wraparound (see partition_by_mask)
        cx = centroid(tri_bounds, tri, 0)
        cy = centroid(tri_bounds, tri, 1)
        cz = centroid(tri_bounds, tri, 2)
        x0 = min(x0, cx)
        y0 = min(y0, cy)
        z0 = min(z0, cz)
        x1 = max(x1, cx)
        y1 = max(y1, cy)
        z1 = max(z1, cz)
    set_box(out, x0, y0, z0, x1, y1, z1)


@inline
def triangle_bounds(tris, lo, hi, out):
    """Box of the triangles ``tris.ids[lo:hi]`` into ``out`` (6,), in locals as above."""
    tri_bounds = tris.bounds
    x0 = y0 = z0 = np.float32(np.inf)
    x1 = y1 = z1 = np.float32(-np.inf)
    for tri_id in tris.ids[lo:hi]:
        tri = np.uint32(tri_id)  # unsigned: no index wraparound
        x0, y0, z0, x1, y1, z1 = grow_box(x0, y0, z0, x1, y1, z1, tri_bounds, tri)
    set_box(out, x0, y0, z0, x1, y1, z1)


@inline
def longest_axis(box):
    ex = box[3] - box[0]
    ey = box[4] - box[1]
    ez = box[5] - box[2]
    if ex >= ey and ex >= ez:
        return 0, ex
    if ey >= ez:
        return 1, ey
    return 2, ez


@inline
def box_area(box):
    ex = box[3] - box[0]
    ey = box[4] - box[1]
    ez = box[5] - box[2]
    return ex * ey + ey * ez + ez * ex


@inline
def bin_triangles(tris, lo, hi, axis, c_min, scale, n_bins, bin_count, bin_box, tri_bins):
    """Count triangles ``tris.ids[lo:hi]`` per bin and the box of each bin's triangles; each
    position's bin goes to ``tri_bins[lo:hi]``, for ``partition_binned``.

    A run of triangles in one bin (the usual case: ranges keep much of the mesh's spatial order)
    is bounded in locals and added to its bin when the run ends; updating the bin's box for every
    triangle made each wait on the previous one's store."""
    tri_ids = tris.ids
    tri_bounds = tris.bounds
    for b in range(n_bins):
        bin_count[b] = 0
        for a in range(3):
            bin_box[b, a] = np.inf
            bin_box[b, a + 3] = -np.inf
    cur = -1
    cnt = 0
    x0 = y0 = z0 = np.float32(np.inf)
    x1 = y1 = z1 = np.float32(-np.inf)
    for i in range(lo, hi):
        tri = np.uint32(tri_ids[i])  # unsigned: no index wraparound
        b = bin_of(centroid(tri_bounds, tri, axis), c_min, scale, n_bins)
        tri_bins[i] = b
        if b != cur:
            if cur >= 0:
                flush_bin(bin_count, bin_box, cur, cnt, x0, y0, z0, x1, y1, z1)
            cur = b
            cnt = 0
            x0 = y0 = z0 = np.float32(np.inf)
            x1 = y1 = z1 = np.float32(-np.inf)
        cnt += 1
        x0, y0, z0, x1, y1, z1 = grow_box(x0, y0, z0, x1, y1, z1, tri_bounds, tri)
    if cur >= 0:
        flush_bin(bin_count, bin_box, cur, cnt, x0, y0, z0, x1, y1, z1)


@inline
def flush_bin(bin_count, bin_box, b, cnt, x0, y0, z0, x1, y1, z1):
    """Add a run of ``cnt`` triangles bounded by (x0, y0, z0)-(x1, y1, z1) to bin ``b``."""
    bin_count[b] += cnt
    bin_box[b, 0] = min(bin_box[b, 0], x0)
    bin_box[b, 1] = min(bin_box[b, 1], y0)
    bin_box[b, 2] = min(bin_box[b, 2], z0)
    bin_box[b, 3] = max(bin_box[b, 3], x1)
    bin_box[b, 4] = max(bin_box[b, 4], y1)
    bin_box[b, 5] = max(bin_box[b, 5], z1)


@inline
def sweep_bins(n_bins, bin_count, bin_box, left_count, left_box, right_count, right_box):
    """Candidate split j puts bins [0, j] left and [j+1, n_bins) right: their counts and boxes."""
    count = 0
    for a in range(6):
        left_box[0, a] = bin_box[0, a]
    for j in range(n_bins - 1):
        count += bin_count[j]
        left_count[j] = count
        if j > 0:
            for a in range(3):
                left_box[j, a] = min(left_box[j - 1, a], bin_box[j, a])
                left_box[j, a + 3] = max(left_box[j - 1, a + 3], bin_box[j, a + 3])
    count = 0
    for j in range(n_bins - 2, -1, -1):
        count += bin_count[j + 1]
        right_count[j] = count
        if j == n_bins - 2:
            for a in range(6):
                right_box[j, a] = bin_box[j + 1, a]
        else:
            for a in range(3):
                right_box[j, a] = min(right_box[j + 1, a], bin_box[j + 1, a])
                right_box[j, a + 3] = max(right_box[j + 1, a + 3], bin_box[j + 1, a + 3])


@inline
def partition_triangles(tris, lo, hi, axis, c_min, scale, n_bins, split_bin, box_left, box_right):
    """Move triangles of ``tris.ids[lo:hi]`` whose bin is <= split_bin to the front; returns the
    first right index.

    The boxes of both sides go to ``box_left`` and ``box_right`` (6,), bounded in the same pass
    (each triangle is looked at once) instead of two more passes over the triangles."""
    tri_bounds = tris.bounds
    ids = tris.ids[lo:hi]
    one = np.uint64(1)
    i = np.uint64(0)
    j = np.uint64(hi - lo)
    lx0 = ly0 = lz0 = rx0 = ry0 = rz0 = np.float32(np.inf)
    lx1 = ly1 = lz1 = rx1 = ry1 = rz1 = np.float32(-np.inf)
    while i < j:
        tri_id = ids[i]
        tri = np.uint32(tri_id)  # unsigned: no index wraparound
        if bin_of(centroid(tri_bounds, tri, axis), c_min, scale, n_bins) <= split_bin:
            lx0, ly0, lz0, lx1, ly1, lz1 = grow_box(lx0, ly0, lz0, lx1, ly1, lz1, tri_bounds, tri)
            i += one
        else:
            rx0, ry0, rz0, rx1, ry1, rz1 = grow_box(rx0, ry0, rz0, rx1, ry1, rz1, tri_bounds, tri)
            j -= one
            ids[i] = ids[j]
            ids[j] = tri_id
    set_box(box_left, lx0, ly0, lz0, lx1, ly1, lz1)
    set_box(box_right, rx0, ry0, rz0, rx1, ry1, rz1)
    return lo + np.int64(i)


@inline
def partition_binned(tris, tri_bins, lo, hi, split_bin):
    """Move triangles of ``tris.ids[lo:hi]`` whose bin (``tri_bins``, from ``bin_triangles``)
    is <= split_bin to the front; returns the first right index. The same moves as
    ``partition_triangles``, so the same order, but each triangle's bin is read, not derived
    again from its box; the sides' boxes are the split's candidate boxes (``sweep_bins``)."""
    tri_ids = tris.ids
    i = lo
    j = hi
    while i < j:
        if tri_bins[i] <= split_bin:
            i += 1
        else:
            j -= 1
            tri_id = tri_ids[i]
            tri_ids[i] = tri_ids[j]
            tri_ids[j] = tri_id
            tri_bins[i] = tri_bins[j]
    return i


@inline
def grow_box(x0, y0, z0, x1, y1, z1, tri_bounds, tri):
    """The box (x0, y0, z0)-(x1, y1, z1) grown to hold triangle ``tri``'s box."""
    return (
        min(x0, tri_bounds[tri, 0]),
        min(y0, tri_bounds[tri, 1]),
        min(z0, tri_bounds[tri, 2]),
        max(x1, tri_bounds[tri, 3]),
        max(y1, tri_bounds[tri, 4]),
        max(z1, tri_bounds[tri, 5]),
    )


@inline
def set_box(box, x0, y0, z0, x1, y1, z1):
    """Write a box held in locals to ``box`` (6,)."""
    box[0] = x0
    box[1] = y0
    box[2] = z0
    box[3] = x1
    box[4] = y1
    box[5] = z1


@inline
def mark_rays_hitting_box(rays, lo, hi, box, hit_mask, fixed_origin=False):
    """hit_mask[i] = can ray i hit ``box`` within [tmin, best_t], for i in [lo, hi).

    A branch-free loop over the records' quads: LLVM vectorises it. The loop runs over views
    that start at ``lo`` with an index from 0: Numba wraps negative indices, and an index LLVM
    cannot prove non-negative turns every load into a gather.
    With ``fixed_origin`` (every record starts at one point) the origin is read once: the slab
    distances to the box planes are then the same for every ray."""
    x0 = box[0]
    y0 = box[1]
    z0 = box[2]
    x1 = box[3]
    y1 = box[4]
    z1 = box[5]
    q0 = rays[ORIGIN_QUAD, 4 * lo : 4 * hi]
    q1 = rays[DIRECTION_QUAD, 4 * lo : 4 * hi]
    mask = hit_mask[lo:hi]
    if fixed_origin and hi > lo:
        ox0 = q0[0]
        oy0 = q0[1]
        oz0 = q0[2]
        t0 = q0[3]
        for i in range(hi - lo):
            hit = intersect_box(
                ox0,
                oy0,
                oz0,
                inverse(q1[4 * i]),
                inverse(q1[4 * i + 1]),
                inverse(q1[4 * i + 2]),
                t0,
                cull_distance(q1[4 * i + 3]),
                x0,
                y0,
                z0,
                x1,
                y1,
                z1,
            )
            mask[i] = hit
        return
    for i in range(hi - lo):
        # inverse(d) is +-inf for a zero component, which the slab test expects.
        hit = intersect_box(
            q0[4 * i],
            q0[4 * i + 1],
            q0[4 * i + 2],
            inverse(q1[4 * i]),
            inverse(q1[4 * i + 1]),
            inverse(q1[4 * i + 2]),
            q0[4 * i + 3],
            cull_distance(q1[4 * i + 3]),
            x0,
            y0,
            z0,
            x1,
            y1,
            z1,
        )
        mask[i] = hit


@inline
def filter_rays(rays, ray_ids, lo, hi, box, hit_mask, offsets, fixed_origin):
    """Gather the rays that can hit ``box`` (within [tmin, best_t]) at one end of the range,
    the end that needs fewer swaps; returns their range (lo, lo + k) or (hi - k, hi).
    ``hit_mask`` is scratch, one entry per ray; ``offsets`` is ``partition_scratch()``;
    ``fixed_origin``: every record has the same origin quad (see ``swap_rays``).

    Going to the front, the hits outside the first k records move; going to the back, those
    in the first n - k: both are counted (two vectorised passes over the mask) and the smaller
    taken. The count is a pass of its own, so that the box-test loop vectorises."""
    mark_rays_hitting_box(rays, lo, hi, box, hit_mask, fixed_origin)
    n_hits = count_true(hit_mask, lo, hi)
    swaps_to_front = n_hits - count_true(hit_mask, lo, lo + n_hits)
    swaps_to_back = count_true(hit_mask, lo, hi - n_hits)
    if swaps_to_back < swaps_to_front:
        partition_by_mask(rays, ray_ids, lo, hi, hit_mask, offsets, True, fixed_origin)
        return hi - n_hits, hi
    partition_by_mask(rays, ray_ids, lo, hi, hit_mask, offsets, False, fixed_origin)
    return lo, lo + n_hits


@inline
def count_true(mask, lo, hi):
    """How many of mask[lo:hi] are true (a vectorised loop)."""
    view = mask[lo:hi]
    n = 0
    for i in range(hi - lo):
        n += np.int64(view[i])
    return n


@inline
def partition_scratch():
    """Scratch for partition_by_mask: the offsets of misplaced records in two blocks."""
    return np.empty(2 * PARTITION_BLOCK, np.int64)


@inline
def partition_by_mask(rays, ray_ids, lo, hi, mask, offsets, to_back=False, fixed_origin=False):
    """Move the ray records whose ``mask`` entry is true to the front of [lo, hi) (to the back
    with ``to_back``: the others to the front); returns the index of the first record of the
    second group. Only misplaced records are swapped, each once. ``to_back`` is a constant at
    every call, so inlining specialises the loops.

    BlockQuicksort (Edelkamp & Weiss 2016): a block of PARTITION_BLOCK records from each end
    records the offsets of its misplaced records without a branch, then the pairs are swapped
    in a loop of known length, so rays that split unpredictably cost no mispredictions. What is
    left in the middle (at most two blocks) goes the plain way. ``mask`` is left stale for the
    records swapped before that."""
    records = quad_view(rays)[:, lo:hi]
    ids = ray_ids[lo:hi]
    keep = mask[lo:hi]
    block = np.int64(PARTITION_BLOCK)
    off_l = offsets[:PARTITION_BLOCK]
    off_r = offsets[PARTITION_BLOCK:]
    left = np.int64(0)  # every record before `left` is in place (front group)
    right = np.int64(hi - lo)  # every record from `right` on is in place (back group)
    num_l = np.int64(0)  # misplaced records of the current left block not yet swapped ...
    num_r = np.int64(0)
    start_l = np.int64(0)  # ... from this position of its offsets on
    start_r = np.int64(0)
    while right - left > 2 * block:
        if num_l == 0:
            start_l = 0
            head = keep[left : left + block]
            for k in range(block):
                off_l[num_l] = k
                num_l += 0 if head[k] != to_back else 1
        if num_r == 0:
            start_r = 0
            tail = keep[right - block : right]
            for k in range(block):
                off_r[num_r] = k
                num_r += 1 if tail[block - 1 - k] != to_back else 0
        num = min(num_l, num_r)
        for k in range(num):
            swap_rays(
                records,
                ids,
                np.uint64(left + off_l[start_l + k]),
                np.uint64(right - 1 - off_r[start_r + k]),
                fixed_origin,
            )
        num_l -= num
        num_r -= num
        start_l += num
        start_r += num
        if num_l == 0:
            left += block
        if num_r == 0:
            right -= block
    # A block still pending has swapped records whose mask entries are stale: fix them for
    # the plain loop.
    if num_l > 0:
        for k in range(start_l):
            keep[left + off_l[k]] = not to_back
    if num_r > 0:
        for k in range(start_r):
            keep[right - 1 - off_r[k]] = to_back
    return lo + partition_plain(records, ids, keep, left, right, to_back, fixed_origin)


@inline
def partition_plain(records, ids, keep, left, right, to_back, fixed_origin):
    """partition_by_mask of records ``left:right`` of views, one branch per record.

    Unsigned indices: Numba does not wrap those, which saves two instructions on every access."""
    one = np.uint64(1)
    i = np.uint64(left)
    j = np.uint64(right)
    while i < j:
        if keep[i] != to_back:
            i += one
        else:
            j -= one
            if keep[j] != to_back:
                swap_rays(records, ids, i, j, fixed_origin)
                i += one
    return np.int64(i)
