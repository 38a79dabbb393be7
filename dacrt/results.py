"""Turning the kernels' per-ray results into the public answers (mesh, prim, normal, misses)."""

import numpy as np

from .config import inline, jit
from .contracts import MISS
from .geometry import intersect_triangle, pick, triangle_normal, watertight_setup
from .leaf import NO_HIT


@jit
def unit_normals(tri_verts, normals):
    """Fill ``normals`` (n_tri, 3) float32 with each kernel row's unit geometric normal."""
    for row in range(tri_verts.shape[0]):
        normals[row, 0], normals[row, 1], normals[row, 2] = unit_normal(tri_verts, row)


@inline
def unit_normal(tri_verts, row):
    """Geometric normal (p1 - p0) x (p2 - p0) of a kernel row, normalised in float64."""
    nx, ny, nz = triangle_normal(tri_verts, row)
    inv_length = 1.0 / np.sqrt(nx * nx + ny * ny + nz * nz)
    return nx * inv_length, ny * inv_length, nz * inv_length


@jit
def finish_closest(
    best_t, best_tri, tri_global, mesh_offsets, tri_verts, normals, mesh, prim, normal
):
    """Turn the kernels' per-ray results into the answers: ``best_t`` becomes t in place (inf
    on a miss), and mesh, prim, normal are written for every ray (MISS, MISS, 0 on a miss).
    hit_u and hit_v are u and v as they are (0 where a ray never hit).

    best_tri holds kernel rows; tri_global maps them to global triangle indices, and
    mesh_offsets (n_meshes+1,) to (mesh, prim). ``normals`` holds every row's unit normal
    (``unit_normals``), or no rows: then each hit computes its own, for batches with fewer rays
    than the scene has triangles."""
    have_normals = normals.shape[0] > 0
    m = 0
    for ray in range(best_t.shape[0]):
        row = best_tri[ray]
        if row == NO_HIT:
            best_t[ray] = np.inf
            mesh[ray] = MISS
            prim[ray] = MISS
            normal[ray, 0] = normal[ray, 1] = normal[ray, 2] = 0.0
            continue
        tri = tri_global[row]
        # Neighbouring rays mostly hit the same mesh: search only when the previous hit's mesh
        # does not hold this triangle (one mesh never searches).
        if not mesh_offsets[m] <= tri < mesh_offsets[m + 1]:
            m = np.searchsorted(mesh_offsets, tri, side="right") - 1
        best_t[ray] = best_t[ray] + np.float32(0.0)  # -0.0 (a hit at the origin) as +0.0
        mesh[ray] = m
        prim[ray] = tri - mesh_offsets[m]
        if have_normals:
            normal[ray, 0] = normals[row, 0]
            normal[ray, 1] = normals[row, 1]
            normal[ray, 2] = normals[row, 2]
        else:
            normal[ray, 0], normal[ray, 1], normal[ray, 2] = unit_normal(tri_verts, row)


@jit
def finish_hits(
    list_t,
    list_tri,
    offsets,
    origins,
    directions,
    tri_global,
    mesh_offsets,
    tri_verts,
    normals,
    t,
    mesh,
    prim,
    u,
    v,
    normal,
):
    """Copy the first offsets[i + 1] - offsets[i] entries of each ray i's list (t and kernel
    row, sorted by (t, tie key)) into the CSR rows offsets[i]:offsets[i + 1], as (mesh, prim),
    with u and v from the ray's watertight test (the arithmetic that found the hit, so the same
    bits) and unit normals (``normals`` as for ``finish_closest``). The tie key is ``tri_global``
    of the row, so the lists' order is the (t, mesh, prim) order."""
    have_normals = normals.shape[0] > 0
    m = 0
    for ray in range(offsets.shape[0] - 1):
        first = offsets[ray]
        n = offsets[ray + 1] - first
        if n == 0:
            continue
        kx, ky, kz, sx, sy, sz = watertight_setup(
            directions[ray, 0], directions[ray, 1], directions[ray, 2]
        )
        okx = np.float64(pick(kx, origins[ray, 0], origins[ray, 1], origins[ray, 2]))
        oky = np.float64(pick(ky, origins[ray, 0], origins[ray, 1], origins[ray, 2]))
        okz = np.float64(pick(kz, origins[ray, 0], origins[ray, 1], origins[ray, 2]))
        for k in range(n):
            out = first + k
            row = list_tri[ray, k]
            tri = tri_global[row]
            if not mesh_offsets[m] <= tri < mesh_offsets[m + 1]:
                m = np.searchsorted(mesh_offsets, tri, side="right") - 1
            t[out] = list_t[ray, k] + np.float32(0.0)  # -0.0 (a hit at the origin) as +0.0
            mesh[out] = m
            prim[out] = tri - mesh_offsets[m]
            _, _, u[out], v[out] = intersect_triangle(
                tri_verts, row, okx, oky, okz, kx, ky, kz, sx, sy, sz
            )
            if have_normals:
                normal[out, 0] = normals[row, 0]
                normal[out, 1] = normals[row, 1]
                normal[out, 2] = normals[row, 2]
            else:
                normal[out, 0], normal[out, 1], normal[out, 2] = unit_normal(tri_verts, row)
