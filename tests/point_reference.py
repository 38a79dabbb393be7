"""Brute-force point queries in plain numpy: the independent reference of ``Scene.nearest``.

Imports nothing from ``dacrt``. Every point is measured against every triangle in float64, in
blocks of points x triangles so that memory stays bounded. The distance to a triangle is the
least of the distance to its plane (where the point projects inside it) and the distances to its
three edges as segments: no region test, so it shares no code path with the engine's.
:func:`exact_face_distance` measures one point against one triangle's plane in rational
arithmetic, for the accuracy of thin triangles. Conventions follow the engine contract
(docs/engine-api.md):

- degenerate (zero-area) triangles are never the answer;
- the distance is ``inf`` and ``prim`` ``-1`` where no triangle is within ``max_distance``;
- ties go to the lowest global face index (the answer's ``ties`` lists every face within a
  tolerance of the least distance, since float64 rounding differs between methods);
- with ``point_masks`` (n,) and ``face_masks`` (f,) uint32 a point sees a face only where
  ``point_mask & face_mask != 0``.
"""

from __future__ import annotations

from fractions import Fraction
from typing import NamedTuple

import numpy as np

# Point-triangle pairs per block: each (points, triangles) float64 temporary is 8 bytes a pair.
PAIRS_PER_BLOCK = 1 << 18


class Nearest(NamedTuple):
    """The closest face of ``n`` points.

    distance : (n,) float64, ``inf`` for none
    prim : (n,) int64, the lowest global face index at that distance; ``-1`` for none
    distances : (n, f) float64, every point's distance to every face (``inf`` where unseen,
      degenerate or beyond max_distance)
    """

    distance: np.ndarray
    prim: np.ndarray
    distances: np.ndarray

    def ties(self, i, tolerance):
        """The faces within ``tolerance`` of point ``i``'s least distance (increasing)."""
        return np.flatnonzero(self.distances[i] <= self.distance[i] + tolerance)


def _segment_distances(p, a, b):
    """(n, f) distances from points p (n, 1, 3) to segments a-b (1, f, 3)."""
    e = b - a
    length2 = np.einsum("...k,...k->...", e, e)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.einsum("...k,...k->...", p - a, e) / length2
    t = np.clip(np.nan_to_num(t), 0.0, 1.0)
    q = a + t[..., None] * e
    return np.linalg.norm(p - q, axis=-1)


def distances(points, vertices, faces) -> np.ndarray:
    """(n, f) float64: the distance from each point to each face (``inf`` for a degenerate one)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces).reshape(-1, 3)]
    n, f = len(points), len(corners)
    out = np.empty((n, f))
    block = max(1, PAIRS_PER_BLOCK // max(f, 1))
    a, b, c = (corners[None, :, k] for k in range(3))
    normal = np.cross(b - a, c - a)
    area2 = np.einsum("...k,...k->...", normal, normal)
    for lo in range(0, n, block):
        p = points[lo : lo + block, None, :]
        edges = np.minimum(
            np.minimum(_segment_distances(p, a, b), _segment_distances(p, b, c)),
            _segment_distances(p, c, a),
        )
        with np.errstate(invalid="ignore", divide="ignore"):
            # Inside where p's projection is on the inner side of every edge.
            inside = (
                (np.einsum("...k,...k->...", np.cross(b - a, p - a), normal) >= 0)
                & (np.einsum("...k,...k->...", np.cross(c - b, p - b), normal) >= 0)
                & (np.einsum("...k,...k->...", np.cross(a - c, p - c), normal) >= 0)
            )
            plane = np.abs(np.einsum("...k,...k->...", p - a, normal)) / np.sqrt(area2)
        d = np.where(inside, np.minimum(plane, edges), edges)
        d[:, area2[0] == 0] = np.inf
        out[lo : lo + block] = d
    return out


def nearest(
    points, vertices, faces, max_distance=np.inf, *, point_masks=None, face_masks=None
) -> Nearest:
    """Each point's closest face among ``faces`` (global indices), within ``max_distance``."""
    d = distances(points, vertices, faces)
    if point_masks is not None:
        seen = (np.asarray(point_masks, np.uint32)[:, None] & np.asarray(face_masks)[None]) != 0
        d[~seen] = np.inf
    if np.isfinite(max_distance):  # the limit holds for the distance as reported, in float32
        with np.errstate(over="ignore"):
            d[d.astype(np.float32).astype(np.float64) > max_distance] = np.inf
    distance = d.min(axis=1, initial=np.inf)
    found = np.isfinite(distance)
    prim = np.where(found, np.argmin(np.where(d == distance[:, None], 0, 1), axis=1), -1)
    if d.shape[1] == 0:
        prim = np.full(len(d), -1)
    return Nearest(distance, prim.astype(np.int64), d)


def point_on_face(vertices, faces, prim, u, v) -> np.ndarray:
    """(n, 3) float64: (1-u-v)*p0 + u*p1 + v*p2 of face ``prim`` of each point."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)[prim]]
    u = np.asarray(u, dtype=np.float64)[:, None]
    v = np.asarray(v, dtype=np.float64)[:, None]
    return (1 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]


def exact_face_distance(point, corners):
    """The distance from ``point`` (3,) to the plane of ``corners`` (3, 3), and the barycentric
    weights (3,) of the point's projection onto it, in rational arithmetic on the values as
    float64: the squared distance is exact, rounded to float64 before its square root. A weight
    below 0 means the projection lies outside the triangle, whose closest part is then not the
    plane."""
    p, a, b, c = ([Fraction(float(x)) for x in v] for v in (point, *corners))

    def sub(x, y):
        return [x[k] - y[k] for k in range(3)]

    def dot(x, y):
        return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]

    def cross(x, y):
        return [x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]]

    normal = cross(sub(b, a), sub(c, a))
    area2 = dot(normal, normal)
    offset = dot(normal, sub(p, a))
    # The projection's weights: each sub-triangle's signed area over the whole.
    weights = [
        dot(cross(sub(y, p), sub(z, p)), normal) / area2 for y, z in ((b, c), (c, a), (a, b))
    ]
    distance = float(offset * offset / area2) ** 0.5
    return distance, np.array([float(w) for w in weights])
