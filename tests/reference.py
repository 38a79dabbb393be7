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

:func:`all_hits` and :func:`count` (every crossing of each ray, for ``hits`` and ``count``) are
exact instead, for any float inputs: Plücker side tests decided in float64 where that is provably
right and in Python integers elsewhere, with the half-open rule at shared edges and vertices made
by a symbolic perturbation of the ray (notes above :class:`HitList`). :func:`count_range` gives
the least and greatest count over every way of moving a ray off the edges and vertices it meets.
"""

from __future__ import annotations

from fractions import Fraction
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


# ---------------------------------------------------------------------------------------------
# Every crossing of each ray (hits and count), with the half-open rule at shared edges
# ---------------------------------------------------------------------------------------------
#
# A ray crosses triangle (X0, X1, X2) when the three edge sides
#     s_k = d . ((Xi - o) x (Xj - o)),  edges k = (X0->X1, X1->X2, X2->X0),
# are all positive or all negative (Plücker's line-triangle test), the triangle is not edge-on
# (d . n != 0, n = (X1-X0) x (X2-X0); s_0 + s_1 + s_2 = d . n) and t = n . (X0-o) / (d . n) lies
# in [tmin, tmax]. A side that is exactly 0 (the line meets the edge's line) takes the sign the
# side gets when the ray is moved by eps*p + eps**2*q, eps -> 0+: moving the origin by w changes
# s_k by d . ((Xj - Xi) x w), so the sign is that of d . ((Xj-Xi) x p), else of d . ((Xj-Xi) x q).
# Every triangle sees the same moved ray and a shared edge gets exactly opposite sides in its two
# triangles, so a crossing through an edge or vertex counts once (twice or never at a fold).
#
# Exactness. Every decision is exact for any float inputs: float64 decides a sign only where
# its value exceeds a bound on its rounding error (1e-11 of the sum of the magnitudes of its
# terms, hundreds of times the worst case), and every other ray-triangle pair is decided again
# in integers (Python ints: the float inputs scaled by one power of two). t, u and v are
# reported in float64 (correctly rounded from the exact ratio on the integer path).

# Relative bound on float64 rounding of the side and t expressions (see above).
_FILTER = 1e-11
# The perturbation of a ray (p, q) when none is given: fixed, generic; the second pair serves
# rays whose direction lies (nearly) in the plane of the first pair, where the rule needs another.
_PERTURBATIONS = (
    (np.array([0.5377, -0.3128, 0.7834]), np.array([-0.2591, 0.8632, 0.4307])),
    (np.array([0.1913, 0.6284, -0.7541]), np.array([0.8419, -0.2207, 0.0938])),
)
_EDGES = ((0, 1), (1, 2), (2, 0))


class HitList(NamedTuple):
    """Every crossing of ``n`` rays, in CSR layout, each ray's sorted by ``(t, prim)``.

    offsets : (n+1,) int64
      Crossings of ray ``i`` are rows ``offsets[i]:offsets[i+1]``.
    t : (m,) float64
    prim : (m,) int64
      Global face index.
    u, v : (m,) float64
      Barycentrics, ``(1-u-v)*p0 + u*p1 + v*p2``.
    """

    offsets: np.ndarray
    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @property
    def count(self) -> np.ndarray:
        """(n,) int64 crossings per ray."""
        return np.diff(self.offsets)

    @property
    def ray(self) -> np.ndarray:
        """(m,) int64 the ray of each crossing."""
        return np.repeat(np.arange(len(self.offsets) - 1), self.count)

    def __len__(self) -> int:
        return len(self.offsets) - 1


class _Crossings(NamedTuple):
    """Crossed ray-triangle pairs (unsorted) and the pairs the ray touches at an edge or vertex."""

    ray: np.ndarray
    prim: np.ndarray
    t: np.ndarray
    u: np.ndarray
    v: np.ndarray
    # (ray, prim, _Exact) of the pairs with an exactly zero side.
    touched: list


def shear_perturbation(directions):
    """The perturbation ``(p, q)`` of the engine contract's sheared 2D frame, per ray.

    The frame of the watertight test (Woop, Benthin & Wald 2013): ``kz`` is the axis of the
    direction's largest component (ties to the lower axis), ``kx = kz + 1``, ``ky = kx + 1``
    (mod 3), ``kx`` and ``ky`` swapped when ``d[kz] < 0``. Moving the ray by ``+delta`` along the
    frame's x and ``+delta**2`` along its y is moving its origin by ``delta * e_kx`` and
    ``delta**2 * e_ky``.

    Returns
    -------
    p, q : (n, 3) float64
      Unit axis vectors.
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    a = np.abs(d)
    kz = np.where(
        (a[:, 0] >= a[:, 1]) & (a[:, 0] >= a[:, 2]), 0, np.where(a[:, 1] >= a[:, 2], 1, 2)
    )
    kx, ky = (kz + 1) % 3, (kz + 2) % 3
    negative = d[np.arange(len(d)), kz] < 0
    kx, ky = np.where(negative, ky, kx), np.where(negative, kx, ky)
    eye = np.eye(3)
    return eye[kx], eye[ky]


def _perturbations(directions, perturbation):
    """Per-ray (p, q), each (n, 3) float64, from None, "shear" or a pair of (3,) or (n, 3)."""
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if isinstance(perturbation, str):
        assert perturbation == "shear", perturbation
        return shear_perturbation(d)
    if perturbation is not None:
        p, q = (np.broadcast_to(np.asarray(x, np.float64), d.shape) for x in perturbation)
        return np.array(p), np.array(q)
    (p1, q1), (p2, q2) = _PERTURBATIONS
    # d . (p x q) must not vanish (see the module notes): take the pair farther from d's plane.
    norm = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
    first = np.abs(d @ np.cross(p1, q1)) >= 0.1 * norm
    p = np.where(first[:, None], p1, p2)
    q = np.where(first[:, None], q1, q2)
    return p, q


def _scale(*values) -> int:
    """The least power of two ``2**k`` that makes every float in ``values`` an integer."""
    return max(float(x).as_integer_ratio()[1] for v in values for x in np.ravel(v))


def _exact_ints(*values):
    """Python ints ``x * _scale(*values)`` for every float in ``values`` (arrays), in order.

    Every float is ``num / 2**j``; one common power of two makes all of them integers and keeps
    the sign of every homogeneous polynomial in them.
    """
    ratios = [float(x).as_integer_ratio() for v in values for x in np.ravel(v)]
    scale = max(den for _, den in ratios)
    return [num * (scale // den) for num, den in ratios]


def _det3(a, b, c):
    """a . (b x c) for 3-sequences of ints."""
    return (
        a[0] * (b[1] * c[2] - b[2] * c[1])
        - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0])
    )


def _sign(x) -> int:
    return (x > 0) - (x < 0)


class _Exact(NamedTuple):
    """One ray-triangle pair in exact integers, before any perturbation.

    signs : the sign of each side (0 where the line meets that edge's line)
    d, edges : the direction and the three edges ``Xj - Xi`` as int 3-lists (their own scales)
    t, u, v : float64, correctly rounded
    """

    signs: tuple
    d: list
    edges: list
    t: float
    u: float
    v: float

    @property
    def touched(self) -> bool:
        """Whether the ray meets an edge or a vertex of the triangle (some side is exactly 0)."""
        return 0 in self.signs

    def crossed(self, p, q) -> bool:
        """Whether the ray moved by ``eps * p + eps**2 * q`` crosses the triangle."""
        if not self.touched:
            return True
        pq = None
        signs = []
        for sign, edge in zip(self.signs, self.edges):
            if sign == 0:
                pq = pq or (_exact_ints(p), _exact_ints(q))
                sign = _sign(_det3(self.d, edge, pq[0])) or _sign(_det3(self.d, edge, pq[1]))
                # Both vanish only for an edge along d on the line, which makes d . n == 0.
                assert sign != 0, "the perturbation (p, q) spans a plane containing d"
            signs.append(sign)
        return signs[0] == signs[1] == signs[2]


def _exact_pair(origin, direction, corners, lo, hi, cull):
    """One ray against one triangle in exact integer arithmetic: an :class:`_Exact`, or None when
    no perturbation makes the ray cross (edge-on or degenerate, sides of both signs, outside
    ``[lo, hi]``, culled)."""
    ints = _exact_ints(origin, corners)
    o, xs = ints[0:3], [ints[3:6], ints[6:9], ints[9:12]]
    d = _exact_ints(direction)
    rel = [[x[c] - o[c] for c in range(3)] for x in xs]
    sides = [_det3(d, rel[i], rel[j]) for i, j in _EDGES]
    dn = sum(sides)  # d . n, n = (X1 - X0) x (X2 - X0)
    if dn == 0:  # edge-on (the line lies in the triangle's plane) or degenerate
        return None
    if (cull == "back" and dn > 0) or (cull == "front" and dn < 0):
        return None
    signs = tuple(_sign(x) for x in sides)
    if 1 in signs and -1 in signs:
        return None
    edges = [[xs[j][c] - xs[i][c] for c in range(3)] for i, j in _EDGES]
    # t = n . (X0 - o) / (d . n): positions cubed over positions squared times d, so the ratio
    # carries the scale of positions over that of d, which _exact_ints undoes here.
    na = -_det3(rel[0], edges[0], edges[2])
    t = Fraction(na, dn) * Fraction(_scale(direction), _scale(origin, corners))
    if t < Fraction(lo) or (np.isfinite(hi) and t > Fraction(hi)):
        return None
    return _Exact(signs, d, edges, float(t), sides[2] / dn, sides[0] / dn)


def _crossings(
    vertices,
    faces,
    origins,
    directions,
    tmin,
    tmax,
    cull="none",
    ray_masks=None,
    face_masks=None,
    perturbation=None,
) -> _Crossings:
    """Every crossed ray-triangle pair, by a float64 filter and exact integers where it is unsure.

    A bounding-sphere test first drops the pairs whose triangle lies clearly off the ray's line.
    """
    assert cull in ("none", "back", "front"), cull
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    n_rays = len(origins)
    verts = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    corners = verts[faces]  # (f, 3 corners, 3)
    n_tris = len(faces)
    lo, hi = ray_ranges(n_rays, tmin, tmax)
    all_ones = np.uint32(0xFFFFFFFF)
    ray_masks = np.broadcast_to(
        np.asarray(all_ones if ray_masks is None else ray_masks, np.uint32), (n_rays,)
    )
    face_masks = np.broadcast_to(
        np.asarray(all_ones if face_masks is None else face_masks, np.uint32), (n_tris,)
    )
    p_all, q_all = _perturbations(directions, perturbation)
    empty_f = np.zeros(0)
    parts = []
    touched = []
    if n_rays == 0 or n_tris == 0:
        e = np.zeros(0, np.int64)
        return _Crossings(e, e, empty_f, empty_f, empty_f, touched)

    # Bounding spheres, grown by far more than their rounding.
    centre = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centre[:, None], axis=2).max(axis=1) * (1 + 1e-9)
    centre_norm = np.linalg.norm(centre, axis=1)
    origin_norm = np.linalg.norm(origins, axis=1)
    d_norm2 = np.einsum("ij,ij->i", directions, directions)

    tri_block = min(n_tris, PAIRS_PER_BLOCK)
    ray_block = max(1, PAIRS_PER_BLOCK // tri_block)
    for k0 in range(0, n_tris, tri_block):
        k1 = min(n_tris, k0 + tri_block)
        for r0 in range(0, n_rays, ray_block):
            r1 = min(n_rays, r0 + ray_block)
            wx, wy, wz = (centre[None, k0:k1, c] - origins[r0:r1, c, None] for c in range(3))
            dx, dy, dz = (directions[r0:r1, c, None] for c in range(3))
            # |(c - o) x d|^2 <= R^2 |d|^2: the line passes within R of the centre.
            dist2 = (wy * dz - wz * dy) ** 2 + (wz * dx - wx * dz) ** 2 + (wx * dy - wy * dx) ** 2
            reach = radius[None, k0:k1] + 1e-12 * (
                centre_norm[None, k0:k1] + origin_norm[r0:r1, None]
            )
            near = dist2 <= reach * reach * d_norm2[r0:r1, None]
            near &= (ray_masks[r0:r1, None] & face_masks[None, k0:k1]) != 0
            ri, fi = np.nonzero(near)
            if len(ri):
                parts.append(
                    _decide(
                        ri + r0, fi + k0, origins, directions, corners, lo, hi, cull,
                        p_all, q_all, touched,
                    )
                )  # fmt: skip
    if not parts:
        e = np.zeros(0, np.int64)
        return _Crossings(e, e, empty_f, empty_f, empty_f, touched)
    cols = [np.concatenate(c) for c in zip(*parts)]
    return _Crossings(*cols, touched)


def _decide(ri, fi, origins, directions, corners, lo, hi, cull, p_all, q_all, touched):
    """Crossed pairs among candidate pairs (ri, fi): float64 where sure, exact integers elsewhere.

    Appends the pairs with an exactly zero side to ``touched``. Returns (ray, prim, t, u, v).
    """
    o = origins[ri]
    d = directions[ri]
    a = corners[fi, 0] - o
    b = corners[fi, 1] - o
    c = corners[fi, 2] - o
    sides = np.stack(
        [np.einsum("ij,ij->i", d, np.cross(x, y)) for x, y in ((a, b), (b, c), (c, a))], axis=1
    )
    e1 = corners[fi, 1] - corners[fi, 0]
    e2 = corners[fi, 2] - corners[fi, 0]
    n = np.cross(e1, e2)
    dn = np.einsum("ij,ij->i", d, n)
    na = np.einsum("ij,ij->i", n, a)
    reach = np.max(np.abs(np.concatenate([a, b, c], axis=1)), axis=1)
    d_max = np.max(np.abs(d), axis=1)
    # Each side and d . n is a sum of 6 (24 for d . n) products |d| * reach^2 or less.
    bound_s = _FILTER * 24.0 * d_max * reach * reach
    bound_na = _FILTER * 48.0 * reach**3
    sure = np.abs(sides) > bound_s[:, None]
    positive = sure & (sides > 0)
    negative = sure & (sides < 0)
    mixed = positive.any(axis=1) & negative.any(axis=1)
    crossed = positive.all(axis=1) | negative.all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = na / dn
        # Absolute error of t: (error of na + |t| * error of dn) / |dn|, doubled.
        t_err = 2.0 * (bound_na + np.abs(t) * bound_s) / np.abs(dn)
    rlo, rhi = lo[ri], hi[ri]
    with np.errstate(invalid="ignore"):  # inf - inf where a ray runs along a plane
        near_bound = (np.abs(t - rlo) <= t_err) | (np.abs(t - rhi) <= t_err)
    unsure = ~mixed & (~crossed | near_bound)
    keep = crossed & ~near_bound & (t >= rlo) & (t <= rhi)
    if cull == "back":
        keep &= dn < 0
    elif cull == "front":
        keep &= dn > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        u = sides[:, 2] / dn
        v = sides[:, 0] / dn
    out_ray, out_prim = [ri[keep]], [fi[keep]]
    out_t, out_u, out_v = [t[keep]], [u[keep]], [v[keep]]
    for k in np.flatnonzero(unsure):
        i, f = int(ri[k]), int(fi[k])
        exact = _exact_pair(origins[i], directions[i], corners[f], lo[i], hi[i], cull)
        if exact is None:
            continue
        if exact.touched:
            touched.append((i, f, exact))
        if exact.crossed(p_all[i], q_all[i]):
            out_ray.append([i])
            out_prim.append([f])
            out_t.append([exact.t])
            out_u.append([exact.u])
            out_v.append([exact.v])
    return (
        np.concatenate(out_ray).astype(np.int64),
        np.concatenate(out_prim).astype(np.int64),
        np.concatenate(out_t).astype(np.float64),
        np.concatenate(out_u).astype(np.float64),
        np.concatenate(out_v).astype(np.float64),
    )


def all_hits(
    vertices,
    faces,
    origins,
    directions,
    tmin=None,
    tmax=None,
    *,
    cull="none",
    ray_masks=None,
    face_masks=None,
    perturbation=None,
) -> HitList:
    """Every triangle each ray crosses in ``[tmin, tmax]``, with the half-open rule (exact).

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    origins, directions : (n, 3) float
    tmin, tmax : None, float or (n,) float
      Inclusive range of ``t``; defaults 0 and ``inf``.
    cull : "none", "back" or "front"
      Back faces have ``d . n > 0``, front faces ``d . n < 0``; edge-on faces never cross.
    ray_masks : None, int or (n,) uint32; face_masks : None, int or (f,) uint32
      A ray sees a face only where ``ray_mask & face_mask != 0``.
    perturbation : None, "shear" or (p, q), each (3,) or (n, 3) float
      How a ray exactly through an edge or vertex is moved (module notes): None for a fixed
      generic pair, "shear" for :func:`shear_perturbation` (the engine contract's frame).

    Returns
    -------
    hits : HitList
      Each ray's crossings sorted by ``(t, prim)``.
    """
    found = _crossings(
        vertices, faces, origins, directions, tmin, tmax, cull, ray_masks, face_masks, perturbation
    )
    n_rays = len(np.asarray(origins).reshape(-1, 3))
    order = np.lexsort((found.prim, found.t, found.ray))
    offsets = np.zeros(n_rays + 1, dtype=np.int64)
    np.cumsum(np.bincount(found.ray, minlength=n_rays), out=offsets[1:])
    return HitList(
        offsets=offsets,
        t=found.t[order],
        prim=found.prim[order],
        u=found.u[order],
        v=found.v[order],
    )


def count(
    vertices,
    faces,
    origins,
    directions,
    tmin=None,
    tmax=None,
    *,
    cull="none",
    ray_masks=None,
    face_masks=None,
    perturbation=None,
) -> np.ndarray:
    """(n,) int64 number of triangles each ray crosses; parameters as :func:`all_hits`."""
    found = _crossings(
        vertices, faces, origins, directions, tmin, tmax, cull, ray_masks, face_masks, perturbation
    )
    return np.bincount(found.ray, minlength=len(np.asarray(origins).reshape(-1, 3)))


def count_range(
    vertices,
    faces,
    origins,
    directions,
    tmin=None,
    tmax=None,
    *,
    cull="none",
    ray_masks=None,
    face_masks=None,
):
    """The least and the greatest :func:`count` of each ray over every perturbation.

    A ray exactly through an edge or vertex is counted for each direction ``theta`` in the plane
    across the ray (``p = cos(theta) e1 + sin(theta) e2``): the count changes only where ``p``
    turns parallel to the projection of an edge that the ray meets, so one ``theta`` inside each
    arc between those angles gives every count a moved ray can have. Where the ray crosses (the
    faces around what it meets all face one way) the two are equal; at a fold they differ by 2.
    Parameters as :func:`all_hits` (no ``perturbation``).

    Returns
    -------
    lo, hi : (n,) int64
    """
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    found = _crossings(
        vertices, faces, origins, directions, tmin, tmax, cull, ray_masks, face_masks
    )
    n_rays = len(origins)
    counts = np.bincount(found.ray, minlength=n_rays)
    lo_count, hi_count = counts.copy(), counts.copy()
    if not found.touched:
        return lo_count, hi_count
    crossed = set(zip(found.ray.tolist(), found.prim.tolist()))
    by_ray = {}
    for ray, prim, exact in found.touched:
        by_ray.setdefault(ray, []).append((prim, exact))
    for ray, pairs in by_ray.items():
        d = directions[ray]
        e1 = np.cross(d, np.eye(3)[np.argmin(np.abs(d))])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(d / np.linalg.norm(d), e1)
        g1, g2 = np.cross(e1, d), np.cross(e2, d)
        angles = []
        for _, exact in pairs:
            for sign, edge in zip(exact.signs, exact.edges):
                if sign == 0:
                    edge = np.array([float(x) for x in edge])
                    # p(theta) x d is perpendicular to the edge at theta0 and theta0 + pi.
                    theta0 = np.arctan2(-(edge @ g1), edge @ g2)
                    angles += [theta0 % (2 * np.pi), (theta0 + np.pi) % (2 * np.pi)]
        angles = np.sort(angles)
        angles = angles[np.r_[True, np.diff(angles) > 1e-9]]
        samples = (angles + np.diff(np.r_[angles, angles[0] + 2 * np.pi]) / 2) % (2 * np.pi)
        fixed = counts[ray] - sum((ray, prim) in crossed for prim, _ in pairs)
        seen = []
        for theta in samples:
            p = np.cos(theta) * e1 + np.sin(theta) * e2
            q = -np.sin(theta) * e1 + np.cos(theta) * e2
            seen.append(fixed + sum(exact.crossed(p, q) for _, exact in pairs))
        lo_count[ray], hi_count[ray] = min(seen), max(seen)
    return lo_count, hi_count


def nearest(hits: HitList, max_hits: int):
    """The first ``max_hits`` crossings of each ray of ``hits``.

    Returns
    -------
    kept : HitList
    truncated : (n,) bool
      Whether a ray had more than ``max_hits``.
    """
    counts = hits.count
    rank = np.arange(len(hits.t)) - np.repeat(hits.offsets[:-1], counts)
    keep = rank < max_hits
    offsets = np.zeros_like(hits.offsets)
    np.cumsum(np.minimum(counts, max_hits), out=offsets[1:])
    return (
        HitList(offsets, hits.t[keep], hits.prim[keep], hits.u[keep], hits.v[keep]),
        counts > max_hits,
    )
