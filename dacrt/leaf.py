"""Leaves: brute-force every active ray of a node against every triangle of it."""

import numpy as np

from .config import BY_RAYS_MAX_TRIANGLES, BY_RAYS_MIN_RAYS, LANES, LEAF_BLOCK, inline
from .contracts import NAN32, NEG_INF32
from .geometry import (
    corners_from_origin,
    crossing,
    culled,
    culled_side,
    intersect_triangle,
    pick,
    watertight_setup,
    woop_edges,
    woop_miss,
)
from .query import ALL_HITS, ANY_HIT, COLLECT, CULL_BACK, CULL_FRONT, MASKED
from .rays import BEST_T, DIRECTION, DIRECTION_QUAD, ORIGIN, ORIGIN_QUAD, TMIN, field, set_field

# The flags the leaf over rays does not handle.
FILTERS = CULL_BACK | CULL_FRONT | MASKED
# best_tri of a ray with no hit yet: larger than any triangle, so the tie rule needs no branch.
NO_HIT = np.iinfo(np.int32).max
# Rows 2-8 of a block of rays' scratch (``block_rows``): its rays' ox, oy, oz, dx, dy, dz and
# tmin, copied from the records once and read by the loop of each of the leaf's triangles, which
# then needs no shuffles to read the records' quads.
RAY_ROWS = 7


@inline
def leaf_scratch():
    """Scratch for intersect_leaf, one tuple: a block's corners (9 rows of LEAF_BLOCK) and
    distances; for a block of rays, their best triangles and ``block_rows`` (u and v, then the
    rays' fields: RAY_ROWS); and the crossings found for ``record_crossings`` (records, then
    t; their triangles go in the best-triangle row), up to 2 LEAF_BLOCK; and a block of rays'
    best triangles' tie keys (``tri_keys``). Zeros, so padding lanes that were never written
    compute on ordinary numbers."""
    return (
        np.zeros(9 * LEAF_BLOCK, np.float64),
        np.zeros(LEAF_BLOCK, np.float32),
        np.zeros(2 * LEAF_BLOCK, np.int32),
        np.zeros((2 + RAY_ROWS, LEAF_BLOCK), np.float32),
        np.zeros(2 * LEAF_BLOCK, np.int32),
        np.zeros(2 * LEAF_BLOCK, np.float32),
        np.zeros(LEAF_BLOCK, np.int32),
    )


@inline
def tie_key(tri_keys, row):
    """The tie key of kernel row ``row`` (``QueryArrays.tri_keys``), NO_HIT for no triangle."""
    return NO_HIT if row == NO_HIT else tri_keys[row]


@inline
def woop_hit(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz):
    """(t, u, v) of ``intersect_triangle`` from the corners relative to the ray origin, in the
    ray's axis order: t in float32, NaN for a miss; u, v from the same 1/det, as it computes
    them. Selects only, so loops vectorise; a caller that uses t alone pays for t alone."""
    e0, e1, e2, det, noise, scaled_t = woop_edges(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz)
    inv_det = 1.0 / det
    t = np.float32(scaled_t * inv_det)
    return NAN32 if woop_miss(e0, e1, e2, det, noise) else t, e1 * inv_det, e2 * inv_det


@inline
def block_distances(corners, n, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_block):
    """t_block[k] = the hit distance (``woop_hit``) of one ray to triangle k of a gathered block.

    ``corners`` holds coordinate c of the block's triangle k at [c * LEAF_BLOCK + k]: the rows
    are views of one array, so LLVM needs a single alias check against ``t_block``, and are
    indexed from 0 (see mark_rays_hitting_box)."""
    a_x = corners[kx * LEAF_BLOCK : kx * LEAF_BLOCK + n]
    a_y = corners[ky * LEAF_BLOCK : ky * LEAF_BLOCK + n]
    a_z = corners[kz * LEAF_BLOCK : kz * LEAF_BLOCK + n]
    b_x = corners[(3 + kx) * LEAF_BLOCK : (3 + kx) * LEAF_BLOCK + n]
    b_y = corners[(3 + ky) * LEAF_BLOCK : (3 + ky) * LEAF_BLOCK + n]
    b_z = corners[(3 + kz) * LEAF_BLOCK : (3 + kz) * LEAF_BLOCK + n]
    c_x = corners[(6 + kx) * LEAF_BLOCK : (6 + kx) * LEAF_BLOCK + n]
    c_y = corners[(6 + ky) * LEAF_BLOCK : (6 + ky) * LEAF_BLOCK + n]
    c_z = corners[(6 + kz) * LEAF_BLOCK : (6 + kz) * LEAF_BLOCK + n]
    for k in range(n):
        t_block[k], _, _ = woop_hit(
            a_x[k] - okx,
            a_y[k] - oky,
            a_z[k] - okz,
            b_x[k] - okx,
            b_y[k] - oky,
            b_z[k] - okz,
            c_x[k] - okx,
            c_y[k] - oky,
            c_z[k] - okz,
            sx,
            sy,
            sz,
        )


@inline
def ray_hit(ox, oy, oz, dx, dy, dz, p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z):
    """``woop_hit`` of one ray (origin, direction) and one triangle (corners in float64), for
    the loops over a block of rays: numbers only, so it adds nothing to their vectorised body."""
    kx, ky, kz, sx, sy, sz = watertight_setup(dx, dy, dz)
    okx = pick(kx, np.float64(ox), np.float64(oy), np.float64(oz))
    oky = pick(ky, np.float64(ox), np.float64(oy), np.float64(oz))
    okz = pick(kz, np.float64(ox), np.float64(oy), np.float64(oz))
    return woop_hit(
        pick(kx, p0x, p0y, p0z) - okx,
        pick(ky, p0x, p0y, p0z) - oky,
        pick(kz, p0x, p0y, p0z) - okz,
        pick(kx, p1x, p1y, p1z) - okx,
        pick(ky, p1x, p1y, p1z) - oky,
        pick(kz, p1x, p1y, p1z) - okz,
        pick(kx, p2x, p2y, p2z) - okx,
        pick(ky, p2x, p2y, p2z) - oky,
        pick(kz, p2x, p2y, p2z) - okz,
        sx,
        sy,
        sz,
    )


@inline
def rays_to_rows(rays, block_lo, n, block_rows):
    """Copy records ``block_lo:block_lo + n``'s origin, direction and tmin to rows 2-8 of
    ``block_rows`` (RAY_ROWS), read by every triangle's loop over the block."""
    q0 = rays[ORIGIN_QUAD, 4 * block_lo : 4 * (block_lo + n)]
    q1 = rays[DIRECTION_QUAD, 4 * block_lo : 4 * (block_lo + n)]
    for i in range(n):
        for a in range(3):
            block_rows[2 + a, i] = q0[4 * i + a]
            block_rows[5 + a, i] = q1[4 * i + a]
        block_rows[8, i] = q0[4 * i + 3]


@inline
def update_block(any_hit, n, tri_verts, tri, key, t_block, tri_block, key_block, block_rows):
    """Test the block's n rays (rows 2-8 of ``block_rows``) against one triangle (its tie key
    ``key``) and keep, per ray, the better of its hit and the block's best so far (``t_block``,
    ``tri_block``, ``key_block``, rows 0-1 of ``block_rows``): the leaf of many rays and few
    triangles, one vectorised loop (``watertight_setup`` and ``pick`` are selects).
    u and v come from ``woop_hit``, the same arithmetic as the scalar ``intersect_triangle``:
    the same bits."""
    p0x = np.float64(tri_verts[tri, 0])
    p0y = np.float64(tri_verts[tri, 1])
    p0z = np.float64(tri_verts[tri, 2])
    p1x = np.float64(tri_verts[tri, 3])
    p1y = np.float64(tri_verts[tri, 4])
    p1z = np.float64(tri_verts[tri, 5])
    p2x = np.float64(tri_verts[tri, 6])
    p2y = np.float64(tri_verts[tri, 7])
    p2z = np.float64(tri_verts[tri, 8])
    ox_row = block_rows[2, :n]
    oy_row = block_rows[3, :n]
    oz_row = block_rows[4, :n]
    dx_row = block_rows[5, :n]
    dy_row = block_rows[6, :n]
    dz_row = block_rows[7, :n]
    tmin_row = block_rows[8, :n]
    tri32 = np.int32(tri)
    key32 = np.int32(key)
    u_row = block_rows[0]
    v_row = block_rows[1]
    for i in range(n):
        t, u, v = ray_hit(
            ox_row[i],
            oy_row[i],
            oz_row[i],
            dx_row[i],
            dy_row[i],
            dz_row[i],
            p0x,
            p0y,
            p0z,
            p1x,
            p1y,
            p1z,
            p2x,
            p2y,
            p2z,
        )
        best = t_block[i]
        # A miss is NaN and fails every comparison; ties go to the lower tie key.
        take = (t >= tmin_row[i]) & ((t < best) | ((t == best) & (key32 < key_block[i])))
        t_block[i] = (NEG_INF32 if any_hit else t) if take else best
        tri_block[i] = tri32 if take else tri_block[i]
        key_block[i] = key32 if take else key_block[i]
        u_row[i] = np.float32(u) if take else u_row[i]
        v_row[i] = np.float32(v) if take else v_row[i]


@inline
def intersect_leaf(flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch):
    """Test rays ``ray_lo:ray_hi`` against triangles ``tris.ids[tri_lo:tri_hi]`` (``Triangles``).

    Keeps, per ray, the hit with the smallest (t, tie key) in [tmin, best_t] (``tri_keys``: a
    row's triangle in the meshes' numbering, so storage order changes no tie); best_t
    lives in the ray record, the rest in ``arrays`` (``QueryArrays``) indexed by ray id. With
    ANY_HIT in ``flags`` a ray stops at its first hit and its best_t becomes -inf; with COUNT it
    counts its hits, with ALL_HITS it keeps its nearest in its list (``record_crossings``); culled
    faces and triangles a ray's mask does not see never hit (CULL_BACK, CULL_FRONT, MASKED).
    ``scratch`` is ``leaf_scratch()``. Returns the ray-triangle tests made.

    The tests run as vectorised loops, over rays (a few triangles, at least BY_RAYS_MIN_RAYS
    rays: ``leaf_by_rays``) or over triangles (``leaf_by_triangles``); each is compiled twice, for
    one best hit and for collecting every crossing (COLLECT), by a constant argument. The order
    of tests changes no answer."""
    by_rays = tri_hi - tri_lo < BY_RAYS_MAX_TRIANGLES and ray_hi - ray_lo >= BY_RAYS_MIN_RAYS
    if flags & COLLECT:
        if by_rays:
            return leaf_by_rays(
                True, flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch
            )
        return leaf_by_triangles(
            True, flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch
        )
    # Closest and occluded test culling and masks by triangles only, outside the vectorised
    # loops: a test in those loops slows every query.
    if by_rays and (flags & FILTERS) == 0:
        return leaf_by_rays(
            False, flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch
        )
    return leaf_by_triangles(
        False, flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch
    )


@inline
def leaf_by_rays(
    collect, flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch
):
    """intersect_leaf for few triangles: blocks of LEAF_BLOCK rays, their fields copied to rows
    once (``rays_to_rows``), each block against every triangle in one vectorised loop.

    For one best hit (``collect`` false, no culling or masks) that loop keeps the block's best
    (t, triangle, u, v) (``update_block``), starting with no triangle, so no ray's best is
    gathered first; then the rays whose best changed take it. The loop keeps u and v with t, so
    no better hit needs the scalar test again.
    Collecting (``collect`` true), it gives each ray's distance (``block_crossing_distances``);
    a distance in the ray's [tmin, best_t] is a candidate, confirmed by the half-open
    ``crossing``, the ray's mask and culling, and the block's crossings go to
    ``record_crossings``. ``collect`` is a constant at each call: each variant compiles alone."""
    _, t_block, tri_block, block_rows, found_at, found_t, key_block = scratch
    tri_verts = tris.verts
    tri_ids = tris.ids
    # Arrays are taken from the record once: each access in a loop would count a reference.
    best_tri = arrays.best_tri
    tri_keys = arrays.tri_keys
    hit_u = arrays.hit_u
    hit_v = arrays.hit_v
    ray_masks = arrays.ray_masks
    tri_masks = arrays.tri_masks
    n_hits = arrays.n_hits
    list_t = arrays.list_t
    list_tri = arrays.list_tri
    any_hit = (flags & ANY_HIT) != 0
    count_only = (flags & ALL_HITS) == 0
    masked = (flags & MASKED) != 0
    cull_side = culled_side(flags)
    n_tests = 0
    for block_lo in range(ray_lo, ray_hi, LEAF_BLOCK):
        n = min(LEAF_BLOCK, ray_hi - block_lo)
        rays_to_rows(rays, block_lo, n, block_rows)
        n_found = 0
        if not collect:
            # The block starts from each ray's best t, with no triangle: a tie with that t is
            # settled against the ray's triangle afterwards, only for the rays that have one.
            for i in range(n):
                t_block[i] = field(rays, BEST_T, block_lo + i)
                tri_block[i] = NO_HIT
                key_block[i] = NO_HIT
        for k in range(tri_lo, tri_hi):
            n_tests += n
            tri = tri_ids[k]
            if not collect:
                update_block(
                    any_hit, n, tri_verts, tri, tri_keys[tri], t_block, tri_block, key_block,
                    block_rows,
                )  # fmt: skip
                continue
            block_crossing_distances(n, tri_verts, tri, block_rows, t_block)
            for i in range(n):
                t = t_block[i]
                if not (t >= block_rows[8, i]):
                    continue
                r = block_lo + i
                if not (t <= field(rays, BEST_T, r)):
                    continue
                if masked and (tri_masks[tri] & ray_masks[ray_ids[r]]) == 0:
                    continue
                kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_frame(rays, r)
                ax, ay, az, bx, by, bz, cx, cy, cz = corners_from_origin(
                    tri_verts, tri, okx, oky, okz, kx, ky, kz
                )
                hit, det = crossing(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz)
                if not hit or det * cull_side > 0.0:
                    continue
                found_at[n_found] = r
                tri_block[n_found] = tri
                found_t[n_found] = t
                n_found += 1
            # The next triangle finds at most LEAF_BLOCK more.
            if n_found > LEAF_BLOCK or (n_found and k == tri_hi - 1):
                record_crossings(
                    count_only, n_hits, list_t, list_tri, tri_keys, rays, ray_ids, scratch,
                    n_found,
                )  # fmt: skip
                n_found = 0
        if collect:
            continue
        # The rays whose best the block's beats take it.
        for i in range(n):
            r = block_lo + i
            ray = ray_ids[r]
            tri = tri_block[i]
            if tri == NO_HIT:
                continue
            better = t_block[i] < field(rays, BEST_T, r)
            if not (better or key_block[i] < tie_key(tri_keys, best_tri[ray])):
                continue
            set_field(rays, BEST_T, r, t_block[i])
            best_tri[ray] = tri
            hit_u[ray] = block_rows[0, i]
            hit_v[ray] = block_rows[1, i]
    return n_tests


@inline
def leaf_by_triangles(
    collect, flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch
):
    """intersect_leaf for few rays: triangles go in blocks of LEAF_BLOCK, copied to float64
    rows (``corners``), so each ray's distances to a block come from one vectorised loop
    (``block_distances``); triangles its mask does not see become misses.

    For one best hit (``collect`` false) the nearest distance wins, and the winner's u, v then
    come from the scalar test, which is the same arithmetic. Collecting (``collect`` true), the
    ray's crossings of the block (``collect_hits``) go to ``record_crossings``. ``collect`` is a
    constant at each call."""
    corners, t_block, _, _, _, _, _ = scratch
    tri_verts = tris.verts
    tri_ids = tris.ids
    # Arrays are taken from the record once: each access in a loop would count a reference.
    best_tri = arrays.best_tri
    tri_keys = arrays.tri_keys
    hit_u = arrays.hit_u
    hit_v = arrays.hit_v
    ray_masks = arrays.ray_masks
    tri_masks = arrays.tri_masks
    n_hits = arrays.n_hits
    list_t = arrays.list_t
    list_tri = arrays.list_tri
    any_hit = (flags & ANY_HIT) != 0
    count_only = (flags & ALL_HITS) == 0
    cull_side = culled_side(flags)
    masked = (flags & MASKED) != 0
    n_tests = 0
    for block_lo in range(tri_lo, tri_hi, LEAF_BLOCK):
        n = min(LEAF_BLOCK, tri_hi - block_lo)
        gather_block(tri_verts, tri_ids, block_lo, n, corners)
        n_found = 0
        for r in range(ray_lo, ray_hi):
            best = field(rays, BEST_T, r)
            if not collect and best == -np.inf:
                continue  # an occlusion ray that has already hit
            frame = ray_frame(rays, r)
            kx, ky, kz, sx, sy, sz, okx, oky, okz = frame
            n_tests += n
            # Padding lanes hold stale corners; their distances are never read.
            block_distances(
                corners,
                min(LEAF_BLOCK, -(-n // LANES) * LANES),
                okx,
                oky,
                okz,
                kx,
                ky,
                kz,
                sx,
                sy,
                sz,
                t_block,
            )
            ray = ray_ids[r]
            if masked:
                hide_unseen(ray_masks[ray], tri_masks, tri_ids, block_lo, n, t_block)
            # Ranges and ties are decided on the float32 t that is reported.
            t_lo = field(rays, TMIN, r)
            if collect:
                n_found += collect_hits(
                    n_found, scratch, tri_ids, block_lo, n, t_lo, best, r, frame, cull_side
                )
                # The next ray finds at most LEAF_BLOCK more.
                if n_found > LEAF_BLOCK or (n_found and r == ray_hi - 1):
                    record_crossings(
                        count_only, n_hits, list_t, list_tri, tri_keys, rays, ray_ids, scratch,
                        n_found,
                    )  # fmt: skip
                    n_found = 0
                continue
            # The smallest (t, tie key) below (best, the ray's triangle's) wins; with any_hit, the
            # first such hit. Only a hit that would win is checked for culling: few are.
            winner = -1
            winner_tri = best_tri[ray]
            winner_key = tie_key(tri_keys, winner_tri)
            for k in range(n):
                t = t_block[k]
                if t >= t_lo and (
                    t < best or (t == best and tri_keys[tri_ids[block_lo + k]] < winner_key)
                ):
                    if cull_side != 0.0 and culled(
                        tri_verts,
                        tri_ids[block_lo + k],
                        okx,
                        oky,
                        okz,
                        kx,
                        ky,
                        kz,
                        sx,
                        sy,
                        sz,
                        cull_side,
                    ):
                        continue
                    best = t
                    winner = k
                    winner_tri = tri_ids[block_lo + k]
                    winner_key = tri_keys[winner_tri]
                    if any_hit:
                        break
            if winner >= 0:
                _, _, u, v = intersect_triangle(
                    tri_verts, winner_tri, okx, oky, okz, kx, ky, kz, sx, sy, sz
                )
                best_tri[ray] = winner_tri
                hit_u[ray] = u
                hit_v[ray] = v
                if any_hit:
                    best = -np.inf
            set_field(rays, BEST_T, r, best)
    return n_tests


@inline
def gather_block(tri_verts, tri_ids, block_lo, n, corners):
    """Copy the corners of triangles ``tri_ids[block_lo:block_lo + n]`` to float64 rows:
    coordinate c of the block's triangle k at corners[c * LEAF_BLOCK + k]."""
    for k in range(n):
        tri = tri_ids[block_lo + k]
        for c in range(9):
            corners[c * LEAF_BLOCK + k] = np.float64(tri_verts[tri, c])


@inline
def ray_frame(rays, r):
    """The watertight test's constants of record r (``watertight_setup``) and its origin in
    the ray's axis order, in float64: (kx, ky, kz, sx, sy, sz, okx, oky, okz)."""
    kx, ky, kz, sx, sy, sz = watertight_setup(
        field(rays, DIRECTION, r),
        field(rays, DIRECTION + 1, r),
        field(rays, DIRECTION + 2, r),
    )
    okx = np.float64(field(rays, ORIGIN + kx, r))
    oky = np.float64(field(rays, ORIGIN + ky, r))
    okz = np.float64(field(rays, ORIGIN + kz, r))
    return kx, ky, kz, sx, sy, sz, okx, oky, okz


@inline
def block_crossing_distances(n, tri_verts, tri, block_rows, t_block):
    """t_block[i] = the distance (``woop_hit``, NaN for a miss) of ray i of a block of rays
    (rows 2-7 of ``block_rows``) to triangle ``tri``: one vectorised loop."""
    p0x = np.float64(tri_verts[tri, 0])
    p0y = np.float64(tri_verts[tri, 1])
    p0z = np.float64(tri_verts[tri, 2])
    p1x = np.float64(tri_verts[tri, 3])
    p1y = np.float64(tri_verts[tri, 4])
    p1z = np.float64(tri_verts[tri, 5])
    p2x = np.float64(tri_verts[tri, 6])
    p2y = np.float64(tri_verts[tri, 7])
    p2z = np.float64(tri_verts[tri, 8])
    ox_row = block_rows[2, :n]
    oy_row = block_rows[3, :n]
    oz_row = block_rows[4, :n]
    dx_row = block_rows[5, :n]
    dy_row = block_rows[6, :n]
    dz_row = block_rows[7, :n]
    for i in range(n):
        t_block[i], _, _ = ray_hit(
            ox_row[i],
            oy_row[i],
            oz_row[i],
            dx_row[i],
            dy_row[i],
            dz_row[i],
            p0x,
            p0y,
            p0z,
            p1x,
            p1y,
            p1z,
            p2x,
            p2y,
            p2z,
        )


@inline
def hide_unseen(ray_mask, tri_masks, tri_ids, block_lo, n, t_block):
    """Turn into misses (NaN) the distances of a block's triangles that a ray of mask
    ``ray_mask`` does not see."""
    for k in range(n):
        seen = (tri_masks[tri_ids[block_lo + k]] & ray_mask) != 0
        t_block[k] = t_block[k] if seen else NAN32


@inline
def collect_hits(first, scratch, tri_ids, block_lo, n, t_lo, best, r, frame, cull_side):
    """The crossings of record ``r`` with a block of triangles (``leaf_by_triangles``: corners
    and distances in ``scratch``), into the found rows of ``scratch`` (record, triangle, t) from
    index ``first`` on; returns how many. A distance in [t_lo, best] is a candidate, confirmed
    by the half-open ``crossing`` (a subset of the inclusive test that gave it), then by
    culling. ``frame`` is the ray's ``ray_frame``."""
    corners, t_block, found_tri, _, found_at, found_t, _ = scratch
    kx, ky, kz, sx, sy, sz, okx, oky, okz = frame
    n_found = first
    for k in range(n):
        t = t_block[k]
        if not (t >= t_lo and t <= best):
            continue
        hit, det = crossing(
            corners[kx * LEAF_BLOCK + k] - okx,
            corners[ky * LEAF_BLOCK + k] - oky,
            corners[kz * LEAF_BLOCK + k] - okz,
            corners[(3 + kx) * LEAF_BLOCK + k] - okx,
            corners[(3 + ky) * LEAF_BLOCK + k] - oky,
            corners[(3 + kz) * LEAF_BLOCK + k] - okz,
            corners[(6 + kx) * LEAF_BLOCK + k] - okx,
            corners[(6 + ky) * LEAF_BLOCK + k] - oky,
            corners[(6 + kz) * LEAF_BLOCK + k] - okz,
            sx,
            sy,
            sz,
        )
        if not hit or det * cull_side > 0.0:
            continue
        found_at[n_found] = r
        found_tri[n_found] = tri_ids[block_lo + k]
        found_t[n_found] = t
        n_found += 1
    return n_found - first


@inline
def record_crossings(
    count_only, n_hits, list_t, list_tri, tri_keys, rays, ray_ids, scratch, n_found
):
    """Record a block's ``n_found`` crossings (the found rows of ``scratch``: record, triangle,
    t): count them in ``n_hits`` (``count_only``), or insert each into its ray's list
    (``list_t``, ``list_tri``), kept sorted by (t, tie key: ``tri_keys`` of the row) and at most
    as long as the lists' rows (the farthest falls off). A ray's best_t stays tmax while its
    list has room, then becomes its last entry's t, which bounds the boxes it still visits.
    Crossings are gathered and recorded by the dozen: a call per crossing would count references
    to its arrays each time."""
    _, _, found_tri, _, found_at, found_t, _ = scratch
    list_size = list_t.shape[1]
    last = list_size - 1
    for j in range(n_found):
        r = found_at[j]
        ray = ray_ids[r]
        n_held = n_hits[ray]
        if count_only:
            n_hits[ray] = n_held + 1
            continue
        t = found_t[j]
        tri = found_tri[j]
        key = tri_keys[tri]
        if n_held == list_size and not (
            t < list_t[ray, last]
            or (t == list_t[ray, last] and key < tri_keys[list_tri[ray, last]])
        ):
            continue
        # Insertion: shift the farther entries down by one.
        p = n_held if n_held < list_size else last
        while p > 0 and (
            t < list_t[ray, p - 1]
            or (t == list_t[ray, p - 1] and key < tri_keys[list_tri[ray, p - 1]])
        ):
            list_t[ray, p] = list_t[ray, p - 1]
            list_tri[ray, p] = list_tri[ray, p - 1]
            p -= 1
        list_t[ray, p] = t
        list_tri[ray, p] = tri
        if n_held < list_size:
            n_held += 1
            n_hits[ray] = n_held
        if n_held == list_size:
            set_field(rays, BEST_T, r, list_t[ray, last])
