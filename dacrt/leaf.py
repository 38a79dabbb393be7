"""Leaves: brute-force every active ray of a node against every triangle of it."""
import numpy as np

from .config import inline
from .contracts import MODE_OCCLUDED
from .geometry import intersect_triangle, watertight_setup

# best_tri of a ray with no hit yet: larger than any triangle, so the tie rule needs no branch.
NO_HIT = np.iinfo(np.int32).max


@inline
def intersect_leaf(mode, tri_verts, origins, directions, tmin, best_t, best_tri, hit_u, hit_v,
                   ray_ids, ray_lo, ray_hi, tri_ids, tri_lo, tri_hi):
    """Test rays ``ray_ids[ray_lo:ray_hi]`` against triangles ``tri_ids[tri_lo:tri_hi]``.

    Keeps, per ray, the hit with the smallest (t, triangle index) in [tmin, best_t]; in
    occlusion mode a ray stops at its first hit and its best_t becomes -inf, which culls it
    from every later box. Returns the number of ray-triangle tests made."""
    n_tests = 0
    for r in range(ray_lo, ray_hi):
        ray = ray_ids[r]
        if mode == MODE_OCCLUDED and best_tri[ray] != NO_HIT:
            continue
        kx, ky, kz, sx, sy, sz = watertight_setup(directions[ray, 0], directions[ray, 1],
                                                  directions[ray, 2])
        o = (float(origins[ray, 0]), float(origins[ray, 1]), float(origins[ray, 2]))
        t_lo = tmin[ray]
        for k in range(tri_lo, tri_hi):
            tri = tri_ids[k]
            n_tests += 1
            hit, t64, u, v = intersect_triangle(tri_verts, tri, o, kx, ky, kz, sx, sy, sz)
            if not hit:
                continue
            # Ranges and ties are decided on the float32 t that is reported.
            t = np.float32(t64)
            best = best_t[ray]
            if t >= t_lo and (t < best or (t == best and tri < best_tri[ray])):
                best_t[ray] = t
                best_tri[ray] = tri
                hit_u[ray] = u
                hit_v[ray] = v
                if mode == MODE_OCCLUDED:
                    best_t[ray] = -np.inf
                    break
    return n_tests
