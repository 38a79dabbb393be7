"""Leaves: brute-force every active ray of a node against every triangle of it."""
import numpy as np

from .config import inline
from .contracts import MODE_OCCLUDED
from .geometry import _EDGE_ON_TOLERANCE, intersect_triangle, watertight_setup
from .rays import BEST_T, DIRECTION, ORIGIN, TMIN

# best_tri of a ray with no hit yet: larger than any triangle, so the tie rule needs no branch.
NO_HIT = np.iinfo(np.int32).max
# Triangles a leaf gathers at a time into float64 rows (see intersect_leaf).
LEAF_BLOCK = 64
_NAN32 = np.float32(np.nan)


@inline
def leaf_scratch():
    """Scratch for intersect_leaf: a block's corners (9 rows of LEAF_BLOCK) and distances."""
    return np.empty(9 * LEAF_BLOCK, np.float64), np.empty(LEAF_BLOCK, np.float32)


@inline
def block_distances(corners, n, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_block):
    """t_block[k] = the float32 hit distance of the ray on triangle k of the block, NaN for a
    miss: the arithmetic of ``intersect_triangle``, without branches, so the loop vectorises.

    ``corners`` holds coordinate c of the block's triangle k at [c * LEAF_BLOCK + k]; one array,
    so LLVM needs a single alias check against ``t_block``."""
    ax_row = kx * LEAF_BLOCK
    ay_row = ky * LEAF_BLOCK
    az_row = kz * LEAF_BLOCK
    for k in range(n):
        ax = corners[ax_row + k] - okx
        ay = corners[ay_row + k] - oky
        az = corners[az_row + k] - okz
        bx = corners[3 * LEAF_BLOCK + ax_row + k] - okx
        by = corners[3 * LEAF_BLOCK + ay_row + k] - oky
        bz = corners[3 * LEAF_BLOCK + az_row + k] - okz
        cx = corners[6 * LEAF_BLOCK + ax_row + k] - okx
        cy = corners[6 * LEAF_BLOCK + ay_row + k] - oky
        cz = corners[6 * LEAF_BLOCK + az_row + k] - okz
        ax = ax - sx * az
        ay = ay - sy * az
        bx = bx - sx * bz
        by = by - sy * bz
        cx = cx - sx * cz
        cy = cy - sy * cz
        e0 = cx * by - cy * bx
        e1 = ax * cy - ay * cx
        e2 = bx * ay - by * ax
        mixed = ((e0 < 0.0) | (e1 < 0.0) | (e2 < 0.0)) & ((e0 > 0.0) | (e1 > 0.0) | (e2 > 0.0))
        det = e0 + e1 + e2
        noise = (abs(cx * by) + abs(cy * bx) + abs(ax * cy) + abs(ay * cx) + abs(bx * ay)
                 + abs(by * ax)) * _EDGE_ON_TOLERANCE
        scaled_t = e0 * (sz * az) + e1 * (sz * bz) + e2 * (sz * cz)
        t = np.float32(scaled_t * (1.0 / det))
        t_block[k] = _NAN32 if mixed | (abs(det) <= noise) else t


@inline
def intersect_leaf(mode, tri_verts, rays, ray_ids, ray_lo, ray_hi, tri_ids, tri_lo, tri_hi,
                   best_tri, hit_u, hit_v, corners, t_block):
    """Test rays ``ray_lo:ray_hi`` against triangles ``tri_ids[tri_lo:tri_hi]``.

    Keeps, per ray, the hit with the smallest (t, triangle index) in [tmin, best_t]; best_t
    lives in the ray record, the rest in arrays indexed by ray id. In occlusion mode a ray
    stops at its first hit and its best_t becomes -inf. Returns the ray-triangle tests made.

    Triangles go in blocks of LEAF_BLOCK, copied to float64 rows (``corners``) so each ray's
    tests over a block run as one vectorised loop (``block_distances``); the winner's u, v are
    then recomputed by the scalar test, which is the same arithmetic."""
    n_tests = 0
    for block_lo in range(tri_lo, tri_hi, LEAF_BLOCK):
        n = min(LEAF_BLOCK, tri_hi - block_lo)
        for k in range(n):
            tri = tri_ids[block_lo + k]
            for c in range(9):
                corners[c * LEAF_BLOCK + k] = np.float64(tri_verts[tri, c])
        for r in range(ray_lo, ray_hi):
            best = rays[BEST_T, r]
            if best == -np.inf:
                continue  # an occlusion ray that has already hit
            kx, ky, kz, sx, sy, sz = watertight_setup(
                rays[DIRECTION, r], rays[DIRECTION + 1, r], rays[DIRECTION + 2, r])
            okx = np.float64(rays[ORIGIN + kx, r])
            oky = np.float64(rays[ORIGIN + ky, r])
            okz = np.float64(rays[ORIGIN + kz, r])
            n_tests += n
            block_distances(corners, n, okx, oky, okz, kx, ky, kz, sx, sy, sz, t_block)
            # Ranges and ties are decided on the float32 t that is reported.
            t_lo = rays[TMIN, r]
            ray = ray_ids[r]
            winner = -1
            winner_tri = best_tri[ray]
            for k in range(n):
                t = t_block[k]
                if t >= t_lo and (t < best or (t == best and tri_ids[block_lo + k] < winner_tri)):
                    best = t
                    winner = k
                    winner_tri = tri_ids[block_lo + k]
                    if mode == MODE_OCCLUDED:
                        break
            if winner >= 0:
                _, _, u, v = intersect_triangle(tri_verts, winner_tri, okx, oky, okz, kx, ky,
                                                kz, sx, sy, sz)
                best_tri[ray] = winner_tri
                hit_u[ray] = u
                hit_v[ray] = v
                if mode == MODE_OCCLUDED:
                    best = -np.inf
            rays[BEST_T, r] = best
    return n_tests


@inline
def intersect_leaf_scalar(mode, tri_verts, rays, ray_ids, ray_lo, ray_hi, tri_ids, tri_lo,
                          tri_hi, best_tri, hit_u, hit_v):
    """The one-pair-at-a-time form of intersect_leaf (kept to compare against)."""
    n_tests = 0
    for r in range(ray_lo, ray_hi):
        best = rays[BEST_T, r]
        if best == -np.inf:
            continue  # an occlusion ray that has already hit
        kx, ky, kz, sx, sy, sz = watertight_setup(rays[DIRECTION, r], rays[DIRECTION + 1, r],
                                                  rays[DIRECTION + 2, r])
        okx = np.float64(rays[ORIGIN + kx, r])
        oky = np.float64(rays[ORIGIN + ky, r])
        okz = np.float64(rays[ORIGIN + kz, r])
        t_lo = rays[TMIN, r]
        ray = ray_ids[r]
        for k in range(tri_lo, tri_hi):
            tri = tri_ids[k]
            n_tests += 1
            hit, t64, u, v = intersect_triangle(tri_verts, tri, okx, oky, okz, kx, ky, kz, sx, sy,
                                                 sz)
            if not hit:
                continue
            # Ranges and ties are decided on the float32 t that is reported.
            t = np.float32(t64)
            if t >= t_lo and (t < best or (t == best and tri < best_tri[ray])):
                best = t
                best_tri[ray] = tri
                hit_u[ray] = u
                hit_v[ray] = v
                if mode == MODE_OCCLUDED:
                    best = -np.inf
                    break
        rays[BEST_T, r] = best
    return n_tests
