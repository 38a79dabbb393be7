"""Brute-force ray-triangle queries in plain numpy: the one independent reference of the engine and
service tests.

Imports nothing from ``dacrt``. Every ray is tested against every triangle with Möller–Trumbore
in float64, in blocks of rays x triangles so that memory stays bounded (about 2000 rays x 5000
triangles take a second or two). Conventions follow the engine contract (docs/engine-api.md):

- a ray is ``origin + t * direction`` for ``tmin <= t <= tmax``; ``t`` is in units of the
  direction's length; defaults ``tmin = 0``, ``tmax = inf``;
- ``t`` is ``inf`` and ``prim`` is ``-1`` on a miss (``u = v = 0`` there);
- ``hit = (1 - u - v) * p0 + u * p1 + v * p2``;
- degenerate (zero-area) triangles never hit;
- ties in ``t`` go to the lowest face index;
- ``cull="back"`` drops faces whose normal ``(p1-p0) x (p2-p0)`` points along the ray
  (``dot > 0``), ``cull="front"`` those whose normal points against it;
- with ``ray_masks`` (n,) and ``face_masks`` (f,) uint32 a ray sees a face only where
  ``ray_mask & face_mask != 0`` (a mesh's mask repeated over its faces).

Float64 Möller–Trumbore is not watertight: a ray exactly through a shared edge or vertex may
miss here. Tests that need a robust verdict use ``eps`` (a slack on the barycentric range and the
``[tmin, tmax]`` interval) and :func:`closest_bracket`, which answers for a shrunk, an exact and a
widened acceptance in one pass.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

# Ray-triangle pairs per block: each (rays, triangles) float64 temporary is 8 bytes a pair.
PAIRS_PER_BLOCK = 1 << 18


class Hits(NamedTuple):
    """Closest hits of ``n`` rays.

    t : (n,) float64
      Distance in units of the direction's length; ``inf`` on a miss.
    prim : (n,) int64
      Global face index; ``-1`` on a miss.
    u, v : (n,) float64
      Barycentrics of the hit, ``(1-u-v)*p0 + u*p1 + v*p2``; ``0`` on a miss.
    """

    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(n,) bool: whether each ray hit anything."""
        return self.prim >= 0


class Bracket(NamedTuple):
    """Closest hits under three acceptances, from one pass of :func:`closest_bracket`.

    exact : Hits
      Plain acceptance (``eps = 0``), the same as :func:`closest`.
    inner : Hits
      Shrunk acceptance (``-eps``): a ray hit here hits well inside a triangle and well inside
      ``[tmin, tmax]``; any correct engine must hit too.
    outer : Hits
      Widened acceptance (``+eps``): any hit of a correct engine is a hit here, no closer than
      ``outer.t``.
    outer_second_t : (n,) float64
      Second-smallest ``t`` under the widened acceptance (``inf`` if fewer than two hits); when
      it is close to ``outer.t`` another triangle competes for the closest hit.
    """

    exact: Hits
    inner: Hits
    outer: Hits
    outer_second_t: np.ndarray


def triangles(vertices, faces):
    """Corner and edges of every face, in float64.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int

    Returns
    -------
    p0, e1, e2 : (f, 3) float64
      ``p0 = vertices[faces[:, 0]]``, ``e1 = p1 - p0``, ``e2 = p2 - p0``.
    """
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    p0 = vertices[faces[:, 0]]
    return p0, vertices[faces[:, 1]] - p0, vertices[faces[:, 2]] - p0


def degenerate(vertices, faces) -> np.ndarray:
    """(f,) bool: faces whose float64 cross product ``(p1-p0) x (p2-p0)`` is exactly zero.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    """
    _, e1, e2 = triangles(vertices, faces)
    return ~np.any(np.cross(e1, e2) != 0.0, axis=1)


def normals(vertices, faces, prim) -> np.ndarray:
    """Unit geometric normals ``(p1-p0) x (p2-p0)`` normalised, of the faces ``prim``.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    prim : (n,) int
      Face indices; ``-1`` gives a zero normal.

    Returns
    -------
    normal : (n, 3) float64
    """
    prim = np.asarray(prim, dtype=np.int64)
    out = np.zeros((len(prim), 3))
    hit = prim >= 0
    _, e1, e2 = triangles(vertices, np.asarray(faces).reshape(-1, 3)[prim[hit]])
    cross = np.cross(e1, e2)
    with np.errstate(divide="ignore", invalid="ignore"):
        out[hit] = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    return out


def barycentric_points(vertices, faces, prim, u, v) -> np.ndarray:
    """Points ``(1-u-v)*p0 + u*p1 + v*p2`` on the faces ``prim`` (``nan`` where ``prim < 0``).

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    prim : (n,) int
    u, v : (n,) float

    Returns
    -------
    points : (n, 3) float64
    """
    prim = np.asarray(prim, dtype=np.int64)
    out = np.full((len(prim), 3), np.nan)
    hit = prim >= 0
    p0, e1, e2 = triangles(vertices, np.asarray(faces).reshape(-1, 3)[prim[hit]])
    uh = np.asarray(u, dtype=np.float64)[hit, None]
    vh = np.asarray(v, dtype=np.float64)[hit, None]
    out[hit] = p0 + uh * e1 + vh * e2
    return out


def ray_ranges(n_rays, tmin=None, tmax=None):
    """Per-ray ``tmin`` and ``tmax`` as (n,) float64 from None, a scalar or an (n,) array."""
    lo = (
        np.zeros(n_rays)
        if tmin is None
        else np.broadcast_to(np.asarray(tmin, np.float64), (n_rays,))
    )
    hi = (
        np.full(n_rays, np.inf)
        if tmax is None
        else np.broadcast_to(np.asarray(tmax, np.float64), (n_rays,))
    )
    return np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64)


def _barycentrics(p0, e1, e2, origins, directions):
    """Möller–Trumbore for matching rows: ``(t, u, v, det)``, each (n,) float64
    (inf/nan where det == 0)."""
    pvec = np.cross(directions, e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    svec = origins - p0
    qvec = np.cross(svec, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        u = np.einsum("ij,ij->i", svec, pvec) * inv
        v = np.einsum("ij,ij->i", directions, qvec) * inv
        t = np.einsum("ij,ij->i", e2, qvec) * inv
    return t, u, v, det


def _widen(bound, eps):
    """``bound + eps * |bound|``, leaving infinite bounds alone (``inf * 0`` would be nan)."""
    return np.where(np.isfinite(bound), bound + eps * np.abs(bound), bound)


def _scan(
    vertices,
    faces,
    origins,
    directions,
    tmin,
    tmax,
    eps_list,
    cull="none",
    ray_masks=None,
    face_masks=None,
):
    """Every ray against every face; for each slack in ``eps_list``: best t, best face, second t.

    Returns a list of ``(t, prim, second_t)`` triples of (n,) arrays, one per slack.
    """
    assert cull in ("none", "back", "front"), cull
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    n_rays = len(origins)
    p0, e1, e2 = triangles(vertices, faces)
    n_tris = len(p0)
    valid_tri = np.any(np.cross(e1, e2) != 0.0, axis=1)
    lo, hi = ray_ranges(n_rays, tmin, tmax)
    all_ones = np.uint32(0xFFFFFFFF)
    ray_masks = np.broadcast_to(
        np.asarray(all_ones if ray_masks is None else ray_masks, np.uint32), (n_rays,)
    )
    face_masks = np.broadcast_to(
        np.asarray(all_ones if face_masks is None else face_masks, np.uint32), (n_tris,)
    )

    results = [
        (np.full(n_rays, np.inf), np.full(n_rays, -1, dtype=np.int64), np.full(n_rays, np.inf))
        for _ in eps_list
    ]
    if n_rays == 0 or n_tris == 0:
        return results

    tri_block = min(n_tris, PAIRS_PER_BLOCK)
    ray_block = max(1, PAIRS_PER_BLOCK // tri_block)
    # Components as separate (1, tris) rows: componentwise products beat np.cross on 3-D blocks.
    for k0 in range(0, n_tris, tri_block):
        k1 = min(n_tris, k0 + tri_block)
        ax, ay, az = (p0[None, k0:k1, c] for c in range(3))
        bx, by, bz = (e1[None, k0:k1, c] for c in range(3))
        cx, cy, cz = (e2[None, k0:k1, c] for c in range(3))
        tri_ok = valid_tri[None, k0:k1]
        tri_masks = face_masks[None, k0:k1]
        for r0 in range(0, n_rays, ray_block):
            r1 = min(n_rays, r0 + ray_block)
            ox, oy, oz = (origins[r0:r1, c, None] for c in range(3))
            dx, dy, dz = (directions[r0:r1, c, None] for c in range(3))
            # pvec = d x e2, det = e1 . pvec
            px = dy * cz - dz * cy
            py = dz * cx - dx * cz
            pz = dx * cy - dy * cx
            det = bx * px + by * py + bz * pz
            # svec = o - p0, qvec = svec x e1
            sx, sy, sz = ox - ax, oy - ay, oz - az
            qx = sy * bz - sz * by
            qy = sz * bx - sx * bz
            qz = sx * by - sy * bx
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                inv = 1.0 / det
                u = (sx * px + sy * py + sz * pz) * inv
                v = (dx * qx + dy * qy + dz * qz) * inv
                t = (cx * qx + cy * qy + cz * qz) * inv
                base = tri_ok & (det != 0.0) & ((ray_masks[r0:r1, None] & tri_masks) != 0)
                # det = e1 . (d x e2) = -d . n: negative for a back face.
                if cull == "back":
                    base &= det > 0.0
                elif cull == "front":
                    base &= det < 0.0
                rlo, rhi = lo[r0:r1, None], hi[r0:r1, None]
                for (best_t, best_prim, second_t), eps in zip(results, eps_list):
                    ok = (
                        base
                        & (u >= -eps)
                        & (v >= -eps)
                        & (u + v <= 1.0 + eps)
                        & (t >= _widen(rlo, -eps))
                        & (t <= _widen(rhi, eps))
                    )
                    tm = np.where(ok, t, np.inf)
                    arg = np.argmin(tm, axis=1)  # first minimum: lowest face index on a tie
                    blk_best = tm[np.arange(r1 - r0), arg]
                    if tm.shape[1] > 1:
                        blk_second = np.partition(tm, 1, axis=1)[:, 1]
                    else:
                        blk_second = np.full(r1 - r0, np.inf)
                    old_best = best_t[r0:r1].copy()
                    # Strict <: an earlier block (lower face indices) keeps a tie.
                    better = blk_best < old_best
                    best_t[r0:r1] = np.where(better, blk_best, old_best)
                    best_prim[r0:r1] = np.where(better, arg + k0, best_prim[r0:r1])
                    # The two smallest of the union are among the two smallest of each part.
                    four = np.stack([old_best, second_t[r0:r1], blk_best, blk_second], axis=1)
                    second_t[r0:r1] = np.sort(four, axis=1)[:, 1]
    return results


def _hits(vertices, faces, origins, directions, t, prim) -> Hits:
    """Wrap a scan result, computing u and v of the chosen faces."""
    u = np.zeros(len(prim))
    v = np.zeros(len(prim))
    hit = prim >= 0
    if np.any(hit):
        p0, e1, e2 = triangles(vertices, np.asarray(faces).reshape(-1, 3)[prim[hit]])
        o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)[hit]
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)[hit]
        _, u[hit], v[hit], _ = _barycentrics(p0, e1, e2, o, d)
    return Hits(t=t, prim=prim, u=u, v=v)


def closest(
    vertices,
    faces,
    origins,
    directions,
    tmin=None,
    tmax=None,
    *,
    eps=0.0,
    cull="none",
    ray_masks=None,
    face_masks=None,
) -> Hits:
    """Closest hit of each ray, by brute force.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    origins : (n, 3) float
    directions : (n, 3) float
      Need not be unit length; ``t`` is in units of their length.
    tmin, tmax : None, float or (n,) float
      Accepted range of ``t``, inclusive; defaults 0 and ``inf``.
    eps : float
      Slack: accept ``u, v >= -eps``, ``u + v <= 1 + eps`` and ``t`` within ``[tmin, tmax]``
      widened by ``eps`` times their magnitude. Negative shrinks. 0 is the plain test.
    cull : "none", "back" or "front"
      Faces that never hit: back faces (normal along the ray) or front faces.
    ray_masks : None, int or (n,) uint32; face_masks : None, int or (f,) uint32
      A ray sees a face only where ``ray_mask & face_mask != 0`` (default all ones).

    Returns
    -------
    hits : Hits
      ``t`` (n,) float64, ``prim`` (n,) int64, ``u``, ``v`` (n,) float64.
    """
    ((t, prim, _),) = _scan(
        vertices, faces, origins, directions, tmin, tmax, [eps], cull, ray_masks, face_masks
    )
    return _hits(vertices, faces, origins, directions, t, prim)


def occluded(
    vertices,
    faces,
    origins,
    directions,
    tmin=None,
    tmax=None,
    *,
    eps=0.0,
    cull="none",
    ray_masks=None,
    face_masks=None,
) -> np.ndarray:
    """Whether each ray hits anything with ``tmin <= t <= tmax``, by brute force.

    Parameters are those of :func:`closest`.

    Returns
    -------
    occluded : (n,) bool
    """
    ((t, _, _),) = _scan(
        vertices, faces, origins, directions, tmin, tmax, [eps], cull, ray_masks, face_masks
    )
    return np.isfinite(t)


def closest_bracket(
    vertices,
    faces,
    origins,
    directions,
    tmin=None,
    tmax=None,
    *,
    eps=1e-4,
    cull="none",
    ray_masks=None,
    face_masks=None,
) -> Bracket:
    """Closest hits under shrunk (``-eps``), exact and widened (``+eps``) acceptance, in one pass.

    Parameters are those of :func:`closest`; ``eps`` must be positive.

    Returns
    -------
    bracket : Bracket
    """
    scans = _scan(
        vertices,
        faces,
        origins,
        directions,
        tmin,
        tmax,
        [0.0, -eps, eps],
        cull,
        ray_masks,
        face_masks,
    )
    exact, inner, outer = (_hits(vertices, faces, origins, directions, t, p) for t, p, _ in scans)
    return Bracket(exact=exact, inner=inner, outer=outer, outer_second_t=scans[2][2])
