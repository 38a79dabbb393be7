"""The DACRT driver for object partitions: ``middle``, ``sah`` and ``sampling``.

One explicit-stack loop over nodes; a node is a range of triangle ids, a range of ray ids and
a box. Popping a node filters its rays by the box (unless ray sampling said the filter would
not pay), then either brute-forces the node or splits its triangles in place and pushes both
children, the one the rays reach first on top. No tree outlives the call.
"""

import numpy as np

from .config import (
    AXIS_SAMPLE_RAYS,
    BOX_TO_TRIANGLE_COST,
    LEAF_C_R,
    LEAF_C_T,
    MAX_DEPTH,
    MIN_OCCLUSION_RAYS_TO_SAMPLE,
    MIN_RAYS_TO_SAMPLE,
    N_BINS,
    N_SAMPLE_RAYS,
    RANGE_LEAF_C_NODE,
    RANGE_LEAF_C_R,
    RAYS_PER_TRIANGLE_FOR_COST,
    SAH_C_I,
    SAH_C_T,
    inline,
    jit,
)
from .contracts import (
    INF32,
    MIDDLE,
    ONE32,
    SAMPLING,
    STAT_BOX_TESTS,
    STAT_LEAVES,
    STAT_MAX_DEPTH,
    STAT_NODES,
    STAT_SAMPLE_BOX_TESTS,
    STAT_SAMPLED,
    STAT_SKIPPED,
    STAT_TRIANGLE_TESTS,
)
from .deforming import leaf_for
from .geometry import cull_distance, intersect_box, inverse
from .leaf import leaf_scratch
from .partition import (
    bin_scale,
    bin_triangles,
    box_area,
    centroid_bounds,
    filter_rays,
    longest_axis,
    partition_binned,
    partition_scratch,
    partition_triangles,
    sweep_bins,
    triangle_bounds,
)
from .query import ANY_HIT, FIXED_ORIGIN, strategy_of
from .ranges import node_rows
from .rays import BEST_T, DIRECTION, ORIGIN, TMIN, field

# Split candidates (N_BINS - 1) padded to whole 16-float vectors, for sample_rays.
PADDED_CANDIDATES = (N_BINS - 1 + 15) // 16 * 16


@jit
def trace_object_split(
    flags, tris, tree, root_box, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays
):
    """Trace ray records ``ray_lo:ray_hi`` against triangles ``tris.ids[tri_lo:tri_hi]``
    (``Triangles``), whose box is ``root_box`` (both ranges are permuted in place).

    ``tree`` (``ranges.RangeTree``) gives the boxes of the halves of the storage order, its
    root node's rows being ``tri_lo:tri_hi`` (or ``ranges.NO_TREE``): a node of those halves
    with few rays a triangle splits into its two halves, which moves no id and reads no
    triangle; others split by the strategy, and their descendants leave the halves.

    ``flags`` is the query's flags word (``dacrt.query``), its strategy ``middle``, ``sah`` or
    ``sampling``; best_t stays in the records, the rest of each ray's answer goes to ``arrays``
    (``QueryArrays``) by ray id (``ray_ids``), with the scratch and the counters."""
    hit_mask = arrays.hit_mask
    tri_bins = arrays.tri_bins
    stats = arrays.stats
    fixed_origin = (flags & FIXED_ORIGIN) != 0
    n_stack = MAX_DEPTH + 2
    stack_tri = np.empty((n_stack, 2), np.int64)
    stack_ray = np.empty((n_stack, 2), np.int64)
    stack_depth = np.empty(n_stack, np.int64)
    stack_filter = np.empty(n_stack, np.bool_)
    stack_box = np.empty((n_stack, 6), np.float32)
    stack_node = np.empty(n_stack, np.int64)  # the node of ``tree``, or 0
    first_leaf_node = 1 << tree.depth
    split_scratch = new_split_scratch()
    boxes = split_scratch[-1]  # the sides' boxes of each split
    leaf = leaf_scratch()
    offsets = partition_scratch()

    stack_tri[0, 0] = tri_lo
    stack_tri[0, 1] = tri_hi
    stack_ray[0, 0] = ray_lo
    stack_ray[0, 1] = ray_hi
    stack_depth[0] = 0
    stack_filter[0] = True
    stack_box[0, :] = root_box
    stack_node[0] = tree.root
    sp = 1
    while sp > 0:
        sp -= 1
        tri_lo = stack_tri[sp, 0]
        tri_hi = stack_tri[sp, 1]
        ray_lo = stack_ray[sp, 0]
        ray_hi = stack_ray[sp, 1]
        depth = stack_depth[sp]
        node = stack_node[sp]
        stats[STAT_NODES] += 1
        if depth > stats[STAT_MAX_DEPTH]:
            stats[STAT_MAX_DEPTH] = depth
        # Ray filtering: keep the rays that can reach this node's box.
        if stack_filter[sp]:
            stats[STAT_BOX_TESTS] += ray_hi - ray_lo
            ray_lo, ray_hi = filter_rays(
                rays, ray_ids, ray_lo, ray_hi, stack_box[sp], hit_mask, offsets, fixed_origin
            )
        else:
            stats[STAT_SKIPPED] += 1
        n_rays = ray_hi - ray_lo
        n_tris = tri_hi - tri_lo
        if n_rays == 0 or n_tris == 0:
            continue
        halve = 0 < node < first_leaf_node and n_rays <= RAYS_PER_TRIANGLE_FOR_COST * n_tris
        if halve and n_rays * n_tris > RANGE_LEAF_C_R * n_rays + RANGE_LEAF_C_NODE:
            if depth < MAX_DEPTH:
                left = 2 * node
                tri_mid = node_rows(left + 1, tree.n_rows)[0]
                left_first = left_is_nearer(rays, ray_lo, tree.boxes, left)
                # Push the later child first, so the nearer one is popped next.
                for side in range(2):
                    child = left + 1 if (side == 0) == left_first else left
                    stack_tri[sp, 0] = tri_lo if child == left else tri_mid
                    stack_tri[sp, 1] = tri_mid if child == left else tri_hi
                    stack_box[sp, :] = tree.boxes[child]
                    stack_filter[sp] = True
                    stack_ray[sp, 0] = ray_lo
                    stack_ray[sp, 1] = ray_hi
                    stack_depth[sp] = depth + 1
                    stack_node[sp] = child
                    sp += 1
                continue
        if halve or n_rays * n_tris <= LEAF_C_R * n_rays + LEAF_C_T * n_tris or depth >= MAX_DEPTH:
            stats[STAT_LEAVES] += 1
            stats[STAT_TRIANGLE_TESTS] += leaf_for(
                flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, leaf
            )
            continue

        # Split the triangles: left in [tri_lo, tri_mid), the sides' boxes in ``boxes``.
        tri_mid, left_first, filter_left, filter_right = split_node(
            flags,
            tris,
            rays,
            ray_lo,
            ray_hi,
            tri_lo,
            tri_hi,
            stack_box[sp],
            tri_bins,
            stats,
            split_scratch,
        )
        # Push the later child first, so the nearer one is popped next.
        for side in range(2):
            is_left = (side == 0) != left_first
            if is_left:
                stack_tri[sp, 0] = tri_lo
                stack_tri[sp, 1] = tri_mid
                stack_box[sp, :] = boxes[0]
                stack_filter[sp] = filter_left
            else:
                stack_tri[sp, 0] = tri_mid
                stack_tri[sp, 1] = tri_hi
                stack_box[sp, :] = boxes[1]
                stack_filter[sp] = filter_right
            stack_ray[sp, 0] = ray_lo
            stack_ray[sp, 1] = ray_hi
            stack_depth[sp] = depth + 1
            stack_node[sp] = 0
            sp += 1


@inline
def left_is_nearer(rays, ray_lo, boxes, left):
    """Whether the rays meet halves node ``left`` before its sibling: the sibling's centre lies
    farther along the first active ray's direction."""
    along = 0.0
    for a in range(3):
        d = np.float64(field(rays, DIRECTION + a, ray_lo))
        ahead = np.float64(boxes[left + 1, a]) + np.float64(boxes[left + 1, a + 3])
        behind = np.float64(boxes[left, a]) + np.float64(boxes[left, a + 3])
        along += d * (ahead - behind)
    return along >= 0


@inline
def new_split_scratch():
    """Scratch for ``split_node``, reused by every node of a trace, one tuple: the bins' counts
    and boxes; the candidates' counts and boxes on each side; ``sample_rays``' padded boxes and
    its counts (hits left, hits right, votes for going left first); and three boxes (the two
    sides', then the centroids')."""
    return (
        np.empty(N_BINS, np.int64),
        np.empty((N_BINS, 6), np.float32),
        np.empty(N_BINS - 1, np.int64),
        np.empty((N_BINS - 1, 6), np.float32),
        np.empty(N_BINS - 1, np.int64),
        np.empty((N_BINS - 1, 6), np.float32),
        np.empty((12, PADDED_CANDIDATES), np.float32),
        np.empty((3, PADDED_CANDIDATES), np.int32),
        np.empty((3, 6), np.float32),
    )


@jit
def split_node(
    flags, tris, rays, ray_lo, ray_hi, tri_lo, tri_hi, node_box, tri_bins, stats, scratch
):
    """Split a node's triangles ``tris.ids[tri_lo:tri_hi]`` in place by the query's strategy:
    binned by ray sampling or SAH where there are enough rays a triangle (Afra's rule), else (or
    when no candidate splits) at the middle (``split_middle``). The sides' boxes go to rows 0
    and 1 of ``scratch``'s last array (``new_split_scratch``).

    Returns (tri_mid, left_first, filter_left, filter_right): the first right triangle, whether
    the rays visit the left side first, and whether each side's rays are filtered by its box.
    ``tri_bins`` and ``stats`` are the query's (``QueryArrays``).

    Compiled on its own rather than inlined into the driver's loop: inlined, it made queries
    2-3 % slower side by side (count and closest, 131K and 1M rays)."""
    bin_count, bin_box, left_count, left_box, right_count, right_box = scratch[:6]
    candidate_boxes, sample_counts, boxes = scratch[6:]
    any_hit = (flags & ANY_HIT) != 0
    strategy = strategy_of(flags)
    n_rays = ray_hi - ray_lo
    n_tris = tri_hi - tri_lo
    min_rays_to_sample = MIN_OCCLUSION_RAYS_TO_SAMPLE if any_hit else MIN_RAYS_TO_SAMPLE
    # sample_rays' counts per candidate, as rows of sample_counts.
    hits_left = sample_counts[0]
    hits_right = sample_counts[1]
    forward_left = sample_counts[2]
    c_box = boxes[2]
    tri_mid = tri_lo
    axis = 0
    sampled = False
    split = -1
    if strategy != MIDDLE and n_rays > RAYS_PER_TRIANGLE_FOR_COST * n_tris:
        sample_node = strategy == SAMPLING and n_rays > min_rays_to_sample
        centroid_bounds(tris, tri_lo, tri_hi, c_box)
        if sample_node and not any_hit:
            axis, extent = sampled_axis(rays, ray_lo, ray_hi, c_box)
        else:
            axis, extent = longest_axis(c_box)
        if extent > 0:
            c_min = np.float64(c_box[axis])
            scale = bin_scale(c_min, np.float64(c_box[axis + 3]), N_BINS)
            bin_triangles(
                tris,
                tri_lo,
                tri_hi,
                axis,
                c_min,
                scale,
                N_BINS,
                bin_count,
                bin_box,
                tri_bins,
            )
            sweep_bins(N_BINS, bin_count, bin_box, left_count, left_box, right_count, right_box)
            if sample_node:
                sampled = True
                stats[STAT_SAMPLED] += 1
                n_sample_tests = sample_rays(
                    rays,
                    ray_lo,
                    ray_hi,
                    left_count,
                    left_box,
                    right_count,
                    right_box,
                    axis,
                    candidate_boxes,
                    sample_counts,
                )
                stats[STAT_BOX_TESTS] += n_sample_tests
                stats[STAT_SAMPLE_BOX_TESTS] += n_sample_tests
                split = cheapest_sampled_split(left_count, right_count, hits_left, hits_right)
            else:
                split = cheapest_sah_split(left_count, left_box, right_count, right_box, node_box)
            if split >= 0:
                tri_mid = partition_binned(tris, tri_bins, tri_lo, tri_hi, split)
                boxes[0, :] = left_box[split]
                boxes[1, :] = right_box[split]
    if split < 0:
        axis, tri_mid = split_middle(tris, tri_lo, tri_hi, node_box, boxes)

    # Traversal order and ray-filter skipping. Afra's order: the first active ray's direction
    # along the split axis.
    first_ray_left = field(rays, DIRECTION + axis, ray_lo) >= 0
    if not sampled:
        return tri_mid, first_ray_left, True, True
    n_samples = min(N_SAMPLE_RAYS, n_rays)
    if any_hit:
        # Any hit ends a ray, and a ray that is done is culled from the other side: first the
        # side more sample rays reach.
        left_first = hits_left[split] >= hits_right[split]
    else:
        # Only rays reaching both sides care which is first: their majority direction along the
        # axis.
        votes = forward_left[split]
        left_first = votes > 0 or (votes == 0 and first_ray_left)
    # Eq. (5)-(6): skip filtering a child that most sample rays reach anyway.
    filter_left = hits_left[split] <= skip_threshold(tri_mid - tri_lo) * n_samples
    filter_right = hits_right[split] <= skip_threshold(tri_hi - tri_mid) * n_samples
    return tri_mid, left_first, filter_left, filter_right


@inline
def strided_sample(ray_lo, n_rays, s, n_samples):
    """The record of sample ray s of n_samples, evenly strided over n_rays from ray_lo."""
    return ray_lo + (s * n_rays) // n_samples


@jit
def sample_rays(
    rays,
    ray_lo,
    ray_hi,
    left_count,
    left_box,
    right_count,
    right_box,
    axis,
    candidate_boxes,
    sample_counts,
):
    """Algorithm 2 of Nabata et al.: test sample rays against both sides of every candidate.

    Per candidate j: how many sample rays hit the left and right boxes, and of those that hit
    both, how many more go up ``axis`` (left to right) than down. Samples are evenly strided
    over the active rays. The inner loop runs over the candidates, whose boxes are copied to
    ``candidate_boxes`` (12, PADDED_CANDIDATES) float32 by coordinate and padded with empty
    boxes (which every ray misses), so that it vectorises with no remainder. The three counts
    go to the rows of ``sample_counts`` (3, PADDED_CANDIDATES) int32, in that order; a
    candidate with an empty side counts nothing. Returns the box tests counted (those of real
    candidates)."""
    n_rays = ray_hi - ray_lo
    n_samples = min(N_SAMPLE_RAYS, n_rays)
    n_tests = 0
    for j in range(PADDED_CANDIDATES):
        real = j < left_count.shape[0] and left_count[j] > 0 and right_count[j] > 0
        n_tests += 2 * n_samples if real else 0
        for a in range(3):
            candidate_boxes[a, j] = left_box[j, a] if real else INF32
            candidate_boxes[a + 3, j] = left_box[j, a + 3] if real else -INF32
            candidate_boxes[a + 6, j] = right_box[j, a] if real else INF32
            candidate_boxes[a + 9, j] = right_box[j, a + 3] if real else -INF32
    sample_counts[:, :] = 0
    lx0, ly0, lz0, lx1, ly1, lz1 = (
        candidate_boxes[0],
        candidate_boxes[1],
        candidate_boxes[2],
        candidate_boxes[3],
        candidate_boxes[4],
        candidate_boxes[5],
    )
    rx0, ry0, rz0, rx1, ry1, rz1 = (
        candidate_boxes[6],
        candidate_boxes[7],
        candidate_boxes[8],
        candidate_boxes[9],
        candidate_boxes[10],
        candidate_boxes[11],
    )
    n_left, n_right, n_forward = sample_counts[0], sample_counts[1], sample_counts[2]
    for s in range(n_samples):
        r = strided_sample(ray_lo, n_rays, s, n_samples)
        ox = field(rays, ORIGIN, r)
        oy = field(rays, ORIGIN + 1, r)
        oz = field(rays, ORIGIN + 2, r)
        ix = inverse(field(rays, DIRECTION, r))
        iy = inverse(field(rays, DIRECTION + 1, r))
        iz = inverse(field(rays, DIRECTION + 2, r))
        t_lo = field(rays, TMIN, r)
        t_hi = cull_distance(field(rays, BEST_T, r))
        # 1/d has the sign of d, also for a zero component (+-inf); inverse's NaN has none.
        going_up = ONE32 / field(rays, DIRECTION + axis, r) >= 0
        step = np.int32(1) if going_up else np.int32(-1)
        for j in range(PADDED_CANDIDATES):
            hit_l = intersect_box(
                ox, oy, oz, ix, iy, iz, t_lo, t_hi, lx0[j], ly0[j], lz0[j], lx1[j], ly1[j], lz1[j]
            )
            hit_r = intersect_box(
                ox, oy, oz, ix, iy, iz, t_lo, t_hi, rx0[j], ry0[j], rz0[j], rx1[j], ry1[j], rz1[j]
            )
            n_left[j] += np.int32(1) if hit_l else np.int32(0)
            n_right[j] += np.int32(1) if hit_r else np.int32(0)
            n_forward[j] += step if hit_l and hit_r else np.int32(0)
    return n_tests


@jit
def sampled_axis(rays, ray_lo, ray_hi, c_box):
    """The axis to bin a sampled node's triangles along: the largest geometric mean of the
    centroids' extent and their apparent extent seen along the sample rays (the extent times
    the mean sine of the angle between ray and axis), over AXIS_SAMPLE_RAYS evenly strided
    sample rays. Returns (axis, extent).

    Rays that run along an axis cross both halves of a split on it, which then divides them
    poorly; the longest axis alone (what ``sah`` bins) ignores that. The mean of the two rather
    than the apparent extent alone, because a split along the rays still lets the nearer half's
    hits cull the farther half's rays. Closest hits only: occlusion rays stop at their first hit,
    and the longest axis serves them better."""
    n_rays = ray_hi - ray_lo
    n_samples = min(AXIS_SAMPLE_RAYS, n_rays)
    sin_x = 0.0
    sin_y = 0.0
    sin_z = 0.0
    for s in range(n_samples):
        r = strided_sample(ray_lo, n_rays, s, n_samples)
        dx = np.float64(field(rays, DIRECTION, r))
        dy = np.float64(field(rays, DIRECTION + 1, r))
        dz = np.float64(field(rays, DIRECTION + 2, r))
        length2 = dx * dx + dy * dy + dz * dz
        sin_x += np.sqrt(max(0.0, 1.0 - dx * dx / length2))
        sin_y += np.sqrt(max(0.0, 1.0 - dy * dy / length2))
        sin_z += np.sqrt(max(0.0, 1.0 - dz * dz / length2))
    axis = 0
    extent = 0.0
    best = -1.0
    for a in range(3):
        a_extent = np.float64(c_box[a + 3] - c_box[a])
        mean_sin = (sin_x if a == 0 else (sin_y if a == 1 else sin_z)) / n_samples
        score = a_extent * np.sqrt(mean_sin)
        if a_extent > 0 and score > best:
            axis = a
            extent = a_extent
            best = score
    return axis, extent


@jit
def skip_threshold(n_child_tris):
    """Eq. (5): the sampled hit ratio above which filtering a child's rays does not pay.

    An inner child has two boxes to test (1 - C_bv / (2 C_bv) = 0.5, Eq. 6); a child that will
    be a leaf has its triangles, each a C_tri test, so skipping pays only at higher ratios."""
    if n_child_tris > LEAF_C_R:
        return 0.5
    return 1.0 - BOX_TO_TRIANGLE_COST / n_child_tris


@jit
def cheapest_sampled_split(left_count, right_count, hits_left, hits_right):
    """Eq. (2): the candidate minimising alpha_L*N_L + alpha_R*N_R (alphas from sample rays)."""
    best = -1
    best_cost = np.inf
    for j in range(left_count.shape[0]):
        if left_count[j] == 0 or right_count[j] == 0:
            continue
        cost = SAH_C_T + SAH_C_I * np.float64(
            hits_left[j] * left_count[j] + hits_right[j] * right_count[j]
        )
        if cost <= best_cost:
            best_cost = cost
            best = j
    return best


@jit
def cheapest_sah_split(left_count, left_box, right_count, right_box, node_box):
    """Binned SAH: the candidate minimising (A_L*N_L + A_R*N_R) / A."""
    best = -1
    best_cost = np.inf
    area = max(box_area(node_box), 1e-30)
    for j in range(left_count.shape[0]):
        if left_count[j] == 0 or right_count[j] == 0:
            continue
        cost = (
            SAH_C_T
            + SAH_C_I
            * (box_area(left_box[j]) * left_count[j] + box_area(right_box[j]) * right_count[j])
            / area
        )
        if cost <= best_cost:
            best_cost = cost
            best = j
    return best


@jit
def split_middle(tris, tri_lo, tri_hi, node_box, boxes):
    """Keller & Waechter: split ``tris.ids[tri_lo:tri_hi]`` at the middle of the node box's
    longest axis.

    Falls back to the middle of the centroids' box, then to the median index, so both sides are
    never empty. Returns (axis, tri_mid); the sides' boxes go to rows 0 and 1 of ``boxes``
    (3, 6) float32, whose row 2 is scratch."""
    box_a = boxes[0]
    box_b = boxes[1]
    c_box = boxes[2]
    axis, extent = longest_axis(node_box)
    if extent > 0:
        c_min = np.float64(node_box[axis])
        tri_mid = partition_triangles(
            tris,
            tri_lo,
            tri_hi,
            axis,
            c_min,
            2.0 / (np.float64(node_box[axis + 3]) - c_min),
            2,
            0,
            box_a,
            box_b,
        )
        if tri_lo < tri_mid < tri_hi:
            return axis, tri_mid
    centroid_bounds(tris, tri_lo, tri_hi, c_box)
    c_axis, c_extent = longest_axis(c_box)
    if c_extent > 0:
        c_min = np.float64(c_box[c_axis])
        tri_mid = partition_triangles(
            tris,
            tri_lo,
            tri_hi,
            c_axis,
            c_min,
            bin_scale(c_min, np.float64(c_box[c_axis + 3]), 2),
            2,
            0,
            box_a,
            box_b,
        )
        if tri_lo < tri_mid < tri_hi:
            return c_axis, tri_mid
    tri_mid = (tri_lo + tri_hi) // 2
    triangle_bounds(tris, tri_lo, tri_mid, box_a)
    triangle_bounds(tris, tri_mid, tri_hi, box_b)
    return axis, tri_mid
