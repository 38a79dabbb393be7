"""Leaves: brute-force every active ray of a node against every triangle of it."""
import numpy as np

from .config import inline
from .contracts import MODE_OCCLUDED
from .geometry import intersect_triangle, watertight_setup
from .rays import BEST_T, DIRECTION, ORIGIN, TMIN

# best_tri of a ray with no hit yet: larger than any triangle, so the tie rule needs no branch.
NO_HIT = np.iinfo(np.int32).max


@inline
def intersect_leaf(mode, tri_verts, rays, ray_ids, ray_lo, ray_hi, tri_ids, tri_lo, tri_hi,
                   best_tri, hit_u, hit_v):
    """Test rays ``ray_lo:ray_hi`` against triangles ``tri_ids[tri_lo:tri_hi]``.

    Keeps, per ray, the hit with the smallest (t, triangle index) in [tmin, best_t]; best_t
    lives in the ray record, the rest in arrays indexed by ray id. In occlusion mode a ray
    stops at its first hit and its best_t becomes -inf. Returns the ray-triangle tests made."""
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
