"""Deforming meshes: vertices that move linearly over the frame's interval, traced as a level of
their own with the same partitions and a leaf that places each triangle at the ray's instant.

A deforming mesh has its vertices at the start (v0) and at the end (v1) of the interval; at time
tau in [0, 1] a vertex is at ``vertex_at(v0, v1, tau)``, in float32. The partitions need no
notion of time: a row's box (``DeformingPacked.bounds``) is the union of its boxes at 0 and 1,
which holds the row at every instant, and its centroid is that box's. The leaf
(``deforming_leaf``) places each of its triangles at the ray's tau and runs the watertight test
on those float32 corners, the arithmetic of the static leaf: a ray at tau gets the answers of the
mesh whose vertices are ``vertex_at(v0, v1, tau)``, bit for bit.

The traversals call ``leaf_for``, which picks the leaf by the triangles' record: a static level
(no end corners) gets the static ``intersect_leaf``, inlined, and a deforming level gets
``deforming_leaf``, called: both kinds of level are one record type, so every traversal
compiles once, and a scene without deforming meshes pays one test a leaf.
"""

import numpy as np

from .config import inline, jit
from .geometry import (
    corners_from_origin,
    crossing,
    culled_side,
    intersect_triangle,
    triangle_normal,
    woop_edges,
)
from .leaf import intersect_leaf, ray_frame, record_crossings, tie_key
from .query import ALL_HITS, ANY_HIT, COLLECT, MASKED
from .rays import BEST_T, TMIN, field, set_field


def vertex_at(v0, v1, tau):
    """A deforming vertex's coordinate at time ``tau``: float32(v0 + tau (v1 - v0)), computed in
    float64 from the float32 v0, v1 and tau. Exact at tau = 0 (v0); v1 at tau = 1 whenever
    v1 - v0 is exact in float64 (the exponents of v0 and v1 within 29 of each other). Works on
    NumPy arrays (elementwise, the same bits) and, compiled, on numbers."""
    start = np.float64(v0)
    return np.float32(start + np.float64(tau) * (np.float64(v1) - start))


vertex_at_kernel = inline(vertex_at)


def corners_at_times(verts, verts_end, rows, times):
    """(k, 9) float32: the corners of ``rows`` (k,) at ``times`` (k,) (``vertex_at``)."""
    return vertex_at(verts[rows], verts_end[rows], np.asarray(times, np.float32)[:, None])


@inline
def corners_at(verts, verts_end, row, tau, out):
    """Row ``row``'s corners at time ``tau`` into out[0] ((1, 9) float64; float32 values)."""
    for c in range(9):
        out[0, c] = vertex_at_kernel(verts[row, c], verts_end[row, c], tau)


@jit
def deforming_leaf(flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch):
    """``intersect_leaf`` for a deforming level's ``Triangles``: each ray against each triangle
    placed at the ray's time (``corners_at``), by the scalar watertight test
    (``intersect_triangle``, the arithmetic of the static leaf's t, u and v), the same rules:
    (t, tie key) in [tmin, best_t], ANY_HIT, MASKED, culling by det, and for COLLECT the
    half-open ``crossing`` and ``record_crossings``. A row degenerate at that instant (edge
    cross product exactly zero, as the static packing drops) never hits. Returns the
    ray-triangle tests made."""
    tri_verts = tris.verts
    verts_end = tris.verts_end
    times = tris.times
    tri_ids = tris.ids
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
    collect = (flags & COLLECT) != 0
    count_only = (flags & ALL_HITS) == 0
    masked = (flags & MASKED) != 0
    cull_side = culled_side(flags)
    _, _, found_tri, _, found_at, found_t, _ = scratch
    capacity = found_at.shape[0]
    corners = np.empty((1, 9), np.float64)
    n_tests = 0
    n_found = 0
    for r in range(ray_lo, ray_hi):
        best = field(rays, BEST_T, r)
        if not collect and best == -np.inf:
            continue  # an occlusion ray that has already hit
        ray = ray_ids[r]
        tau = times[ray]
        t_lo = field(rays, TMIN, r)
        kx, ky, kz, sx, sy, sz, okx, oky, okz = ray_frame(rays, r)
        winner_tri = best_tri[ray]
        winner_key = tie_key(tri_keys, winner_tri)
        for k in range(tri_lo, tri_hi):
            tri = tri_ids[k]
            n_tests += 1
            if masked and (tri_masks[tri] & ray_masks[ray]) == 0:
                continue
            corners_at(tri_verts, verts_end, tri, tau, corners)
            nx, ny, nz = triangle_normal(corners, 0)
            if nx == 0.0 and ny == 0.0 and nz == 0.0:
                continue
            ax, ay, az, bx, by, bz, cx, cy, cz = corners_from_origin(
                corners, 0, okx, oky, okz, kx, ky, kz
            )
            if collect:
                e0, e1, e2, det, noise, scaled_t = woop_edges(
                    ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz
                )
                hit, det = crossing(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz)
                if not hit or det * cull_side > 0.0:
                    continue
                t = np.float32(scaled_t * (1.0 / det))
                if not (t >= t_lo and t <= field(rays, BEST_T, r)):
                    continue
                found_at[n_found] = r
                found_tri[n_found] = tri
                found_t[n_found] = t
                n_found += 1
                if n_found == capacity:
                    record_crossings(
                        count_only, n_hits, list_t, list_tri, tri_keys, rays, ray_ids, scratch,
                        n_found,
                    )  # fmt: skip
                    n_found = 0
                continue
            hit, t64, u, v = intersect_triangle(corners, 0, okx, oky, okz, kx, ky, kz, sx, sy, sz)
            if not hit:
                continue
            t = np.float32(t64)
            key = tri_keys[tri]
            if not (t >= t_lo and (t < best or (t == best and key < winner_key))):
                continue
            if cull_side != 0.0:
                _, _, _, det, _, _ = woop_edges(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz)
                if det * cull_side > 0.0:
                    continue
            best = t
            winner_tri = tri
            winner_key = key
            best_tri[ray] = tri
            hit_u[ray] = u
            hit_v[ray] = v
            if any_hit:
                best = -np.inf
                break
        if collect:
            if n_found:
                record_crossings(
                    count_only, n_hits, list_t, list_tri, tri_keys, rays, ray_ids, scratch, n_found
                )
                n_found = 0
            continue
        set_field(rays, BEST_T, r, best)
    return n_tests


@inline
def leaf_for(flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch):
    """The leaf of the traversals: ``deforming_leaf`` for a deforming level's ``Triangles`` (end
    corners given), else ``intersect_leaf``. Only ``trace_object_split`` inlines it: its
    vectorised loops are fastest beside the scratch's allocation, and the leaf compiles in one
    kernel."""
    if tris.verts_end.shape[0]:
        return deforming_leaf(
            flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch
        )
    return intersect_leaf(
        flags, tris, rays, ray_ids, ray_lo, ray_hi, tri_lo, tri_hi, arrays, scratch
    )
