"""Turning the kernels' per-ray results into the public answers (mesh, prim, normal, misses)."""
import numpy as np

from .config import jit
from .geometry import triangle_normal
from .leaf import NO_HIT


@jit
def finish_closest(best_t, best_tri, tri_global, mesh_offsets, tri_verts, mesh, prim, normal):
    """Turn the kernels' per-ray results into the answers: ``best_t`` becomes t in place (inf
    on a miss), and mesh, prim, normal (preallocated with their miss values) are filled for the
    rays that hit. hit_u and hit_v are u and v as they are (0 where a ray never hit).

    best_tri holds kernel rows; tri_global maps them to global triangle indices, and
    mesh_offsets (n_meshes+1,) to (mesh, prim)."""
    m = 0
    for ray in range(best_t.shape[0]):
        row = best_tri[ray]
        if row == NO_HIT:
            best_t[ray] = np.inf
            continue
        tri = tri_global[row]
        # Neighbouring rays mostly hit the same mesh: search only when the previous hit's mesh
        # does not hold this triangle (one mesh never searches): 5.4 ms per 1M hits, 6.0 with a
        # search for every hit.
        if not mesh_offsets[m] <= tri < mesh_offsets[m + 1]:
            m = np.searchsorted(mesh_offsets, tri, side="right") - 1
        best_t[ray] = best_t[ray] + np.float32(0.0)  # -0.0 (a hit at the origin) as +0.0
        mesh[ray] = m
        prim[ray] = tri - mesh_offsets[m]
        # Geometric normal (p1 - p0) x (p2 - p0), normalised in float64.
        nx, ny, nz = triangle_normal(tri_verts, row)
        inv_length = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
        normal[ray, 0] = nx * inv_length
        normal[ray, 1] = ny * inv_length
        normal[ray, 2] = nz * inv_length
