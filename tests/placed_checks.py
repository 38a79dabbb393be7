"""Instances (traced in mesh space) against the same meshes placed in numpy (float64, then
float32) and passed whole: the same answers up to rounding, as docs/engine.md states it.

Rounding is measured in ulps of a ray's coordinates: ``scale`` is the larger of |origin| and
|hit point| (max norm), and one ulp is float32's spacing there. A hit's position across the
surface (|dt| |d| cos, cos between the ray and the normal) agrees within T_ULPS; where one side
hits and the other misses, or the two hit different triangles that are not one surface within
that rounding, the ray passes within EDGE_ULPS of an edge of the triangle hit.
"""

from __future__ import annotations

import numpy as np

# A hit's position across the surface, in ulps of the ray's coordinates (measured: <= 4.1).
T_ULPS = 8.0
# The distance from a ray to an edge, in the same ulps, within which hit or miss may differ
# (measured: <= 5.6).
EDGE_ULPS = 16.0


def ulp_scale(origins, directions, t):
    """float32 spacing at max(|origin|, |origin + t d|) of each ray (max norm)."""
    o = np.asarray(origins, np.float64)
    point = o + np.asarray(t, np.float64)[:, None] * np.asarray(directions, np.float64)
    scale = np.maximum(np.abs(o).max(axis=1), np.abs(point).max(axis=1))
    return np.spacing(scale.astype(np.float32)).astype(np.float64)


def ray_edge_distance(corners, origins, directions):
    """Distance (float64) from each ray's line to the nearest edge of its triangle.

    corners : (k, 3, 3) float; origins, directions : (k, 3) float."""
    o = np.asarray(origins, np.float64)
    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    best = np.full(len(o), np.inf)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        p = np.asarray(corners[:, a], np.float64)
        e = np.asarray(corners[:, b], np.float64) - p
        w = p - o
        ee = np.einsum("ij,ij->i", e, e)
        de = np.einsum("ij,ij->i", d, e)
        dw = np.einsum("ij,ij->i", d, w)
        ew = np.einsum("ij,ij->i", e, w)
        denom = ee - de * de
        safe = np.where(denom > 1e-300, denom, 1.0)
        s = np.clip(np.where(denom > 1e-300, (de * dw - ew) / safe, 0.0), 0.0, 1.0)
        r = p + s[:, None] * e - o
        perp = r - np.einsum("ij,ij->i", r, d)[:, None] * d
        best = np.minimum(best, np.linalg.norm(perp, axis=1))
    return best


def across_surface_ulps(t_a, t_b, origins, directions, normals):
    """|t_a - t_b| |d| cos, in ulps of each ray's coordinates (``ulp_scale``)."""
    d = np.asarray(directions, np.float64)
    length = np.linalg.norm(d, axis=1)
    cos = np.abs(np.einsum("ij,ij->i", np.asarray(normals, np.float64), d)) / length
    dt = np.abs(np.asarray(t_a, np.float64) - np.asarray(t_b, np.float64))
    return dt * length * cos / ulp_scale(origins, directions, t_b)


def corners_of(placed, mesh, prim):
    """(k, 3, 3) corners of triangles (mesh, prim) of ``placed`` [(vertices, faces), ...]."""
    return np.stack([placed[m][0][placed[m][1][p]] for m, p in zip(mesh, prim)]).reshape(-1, 3, 3)


def check_closest_close_to_placed(got, want, origins, directions, placed, what=""):
    """``got`` (instances) against ``want`` (placed copies), ``Hits`` of the same rays; returns
    the rays whose hit or miss differs (each at an edge)."""
    o = np.asarray(origins, np.float32)
    d = np.asarray(directions, np.float32)
    hit_got, hit_want = got.mesh >= 0, want.mesh >= 0
    same = hit_got & hit_want & (got.mesh == want.mesh) & (got.prim == want.prim)
    err = across_surface_ulps(got.t[same], want.t[same], o[same], d[same], want.normal[same])
    assert err.max(initial=0.0) <= T_ULPS, f"{what}: t off by {err.max()} ulps across the surface"
    # Same triangle: the normal's sign, u and v to float32 rounding of a well-shaped triangle.
    assert (np.einsum("ij,ij->i", got.normal[same], want.normal[same]) > 0.9).all(), what
    others = np.flatnonzero(hit_got & hit_want & ~same)
    if len(others):
        apart = across_surface_ulps(
            got.t[others], want.t[others], o[others], d[others], want.normal[others]
        )
        others = others[apart > T_ULPS]
    flipped = np.flatnonzero(hit_got != hit_want)
    for rays, side in ((others, got), (others, want), (flipped, None)):
        if not len(rays):
            continue
        if side is None:  # the side that hit
            mesh = np.where(hit_got[rays], got.mesh[rays], want.mesh[rays])
            prim = np.where(hit_got[rays], got.prim[rays], want.prim[rays])
            t = np.where(hit_got[rays], got.t[rays], want.t[rays])
        else:
            mesh, prim, t = side.mesh[rays], side.prim[rays], side.t[rays]
        gap = ray_edge_distance(corners_of(placed, mesh, prim), o[rays], d[rays])
        gap /= ulp_scale(o[rays], d[rays], t)
        assert gap.max() <= EDGE_ULPS, (
            f"{what}: ray {rays[np.argmax(gap)]} differs {gap.max()} ulps from an edge"
        )
    return flipped


def check_hits_close_to_placed(got, want, origins, directions, what=""):
    """``HitList`` ``got`` (instances) against ``want`` (placed copies): the same crossings
    (mesh, prim) per ray, each t within T_ULPS across the surface."""
    np.testing.assert_array_equal(np.diff(got.offsets), np.diff(want.offsets), f"{what}: counts")
    n_rays = len(got.offsets) - 1
    ray = np.repeat(np.arange(n_rays), np.diff(got.offsets))
    a = np.lexsort((got.prim, got.mesh, ray))
    b = np.lexsort((want.prim, want.mesh, ray))
    np.testing.assert_array_equal(got.mesh[a], want.mesh[b], what)
    np.testing.assert_array_equal(got.prim[a], want.prim[b], what)
    o = np.asarray(origins, np.float32)[ray[b]]
    d = np.asarray(directions, np.float32)[ray[b]]
    err = across_surface_ulps(got.t[a], want.t[b], o, d, want.normal[b])
    assert err.max(initial=0.0) <= T_ULPS, f"{what}: t off by {err.max()} ulps across the surface"
    np.testing.assert_array_equal(got.truncated, want.truncated, what)
