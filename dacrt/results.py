"""Turning the kernels' per-ray results into the public answers (mesh, prim, normal, misses)."""
import numpy as np

from .config import jit
from .geometry import triangle_normal
from .leaf import NO_HIT


@jit
def finish_closest(best_t, best_tri, hit_u, hit_v, tri_global, mesh_offsets, tri_verts,
                   t, mesh, prim, u, v, normal):
    """Fill the answer arrays (preallocated with their miss values) for the rays that hit.

    best_tri holds kernel rows; tri_global maps them to global triangle indices, and
    mesh_offsets (n_meshes+1,) to (mesh, prim)."""
    for ray in range(best_t.shape[0]):
        row = best_tri[ray]
        if row == NO_HIT:
            continue
        tri = tri_global[row]
        m = np.searchsorted(mesh_offsets, tri, side="right") - 1
        t[ray] = best_t[ray] + np.float32(0.0)  # -0.0 (a hit at the origin) as +0.0
        mesh[ray] = m
        prim[ray] = tri - mesh_offsets[m]
        u[ray] = hit_u[ray]
        v[ray] = hit_v[ray]
        # Geometric normal (p1 - p0) x (p2 - p0), normalised in float64.
        nx, ny, nz = triangle_normal(tri_verts, row)
        inv_length = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
        normal[ray, 0] = nx * inv_length
        normal[ray, 1] = ny * inv_length
        normal[ray, 2] = nz * inv_length
