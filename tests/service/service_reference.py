"""A deliberately simple ray caster in plain NumPy (float64 Moller-Trumbore, brute force).

Imports nothing from dacrt or service: it is the reference the service's answers are checked
against. Ties in t go to the lowest triangle index; zero-area triangles never hit.
"""

from __future__ import annotations

import numpy as np


def closest(vertices, faces, origins, directions, tmin=0.0, tmax=np.inf):
    """Nearest hit per ray -> (t (N,) float64 with inf on a miss, prim (N,) int64 with -1)."""
    origins = np.asarray(origins, np.float64)
    directions = np.asarray(directions, np.float64)
    n = len(origins)
    tmin = np.broadcast_to(np.asarray(tmin, np.float64), (n,))
    tmax = np.broadcast_to(np.asarray(tmax, np.float64), (n,))
    t = np.full(n, np.inf)
    prim = np.full(n, -1, np.int64)
    if len(faces) == 0 or n == 0:
        return t, prim
    p0, p1, p2 = (np.asarray(vertices, np.float64)[np.asarray(faces)[:, k]] for k in range(3))
    e1, e2 = p1 - p0, p2 - p0
    has_area = np.linalg.norm(np.cross(e1, e2), axis=1) > 0
    step = max(1, 4_000_000 // len(faces))
    for lo in range(0, n, step):
        o = origins[lo : lo + step, None, :]
        d = directions[lo : lo + step, None, :]
        pvec = np.cross(d, e2)
        det = np.einsum("rtk,tk->rt", pvec, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tvec = o - p0
            u = np.einsum("rtk,rtk->rt", tvec, pvec) * inv
            qvec = np.cross(tvec, e1)
            v = np.einsum("rtk,rtk->rt", d, qvec) * inv
            dist = np.einsum("tk,rtk->rt", e2, qvec) * inv
        ok = (
            has_area
            & (det != 0)
            & (u >= 0)
            & (v >= 0)
            & (u + v <= 1)
            & (dist >= tmin[lo : lo + step, None])
            & (dist <= tmax[lo : lo + step, None])
        )
        dist = np.where(ok, dist, np.inf)
        best = np.argmin(dist, axis=1)  # first minimum: the lowest index wins a tie
        best_t = dist[np.arange(len(best)), best]
        t[lo : lo + step] = best_t
        prim[lo : lo + step] = np.where(np.isfinite(best_t), best, -1)
    return t, prim
