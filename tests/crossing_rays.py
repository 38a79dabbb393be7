"""Closed meshes and rays exactly through their vertices and edges, for the tests of ``hits`` and
``count`` (the half-open crossing rule).

Closed meshes here have dyadic vertices (multiples of ``2**-10``), so edge midpoints, and the
origins of rays through them with small-integer directions and a power-of-two distance, are exact
in float32: each ray passes *exactly* through its vertex or edge.
"""

from __future__ import annotations

import numpy as np
import procedural as pg

CLOSED_MESHES = ("cube", "icosphere", "uv_sphere")  # the names closed_mesh() knows
STEP = 2.0**-10  # grid of the quantised vertices
INSIDE_POINT = np.array([0.125, -0.0625, 0.1875])  # dyadic, inside every mesh of closed_mesh()


def quantize(vertices, step=STEP):
    """Vertices rounded to multiples of ``step``: (v, 3) float32, exact."""
    return (np.round(np.asarray(vertices, np.float64) / step) * step).astype(np.float32)


def closed_mesh(name):
    """A closed, consistently wound mesh around the origin with dyadic vertices.

    name : "cube" (12 faces, corners at +-1), "icosphere" (trimesh's, 320 faces, radius 1) or
    "uv_sphere" (112 faces, pole fans of 8 faces).

    Returns
    -------
    vertices : (v, 3) float32; faces : (f, 3) int32
    """
    import trimesh

    if name == "cube":
        mesh = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    elif name == "icosphere":
        mesh = trimesh.creation.icosphere(subdivisions=2)
    elif name == "uv_sphere":
        v, f = pg.uv_sphere(8, 8)
        mesh = trimesh.Trimesh(v, f, process=False)
    else:
        raise ValueError(f"unknown closed mesh {name!r}")
    return quantize(mesh.vertices), np.asarray(mesh.faces, dtype=np.int32)


def edges(faces):
    """Unique undirected edges, (e, 2) int64 vertex pairs."""
    f = np.asarray(faces, dtype=np.int64)
    pairs = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return np.unique(pairs, axis=0)


def feature_points(vertices, faces):
    """Every vertex, then every edge midpoint, as (k, 3) float64 (exact for dyadic vertices)."""
    v = np.asarray(vertices, dtype=np.float64)
    e = edges(faces)
    return np.concatenate([v[np.unique(np.asarray(faces).ravel())], (v[e[:, 0]] + v[e[:, 1]]) / 2])


def integer_directions(n, rng, high=7):
    """(n, 3) float64 directions with integer components in ``[-high, high]``, none zero."""
    d = rng.integers(-high, high + 1, size=(n, 3)).astype(np.float64)
    d[~d.any(axis=1)] = (1.0, 2.0, 3.0)
    return d


def rays_through(targets, rng, distance=4.0):
    """Rays from outside that pass exactly through ``targets`` at ``t = distance``.

    Returns
    -------
    origins, directions : (k, 3) float32
    """
    origins, directions = pg.rays_at(targets, integer_directions(len(targets), rng), distance)
    assert_exact(origins, directions, targets, distance)
    return origins, directions


def rays_from(point, targets):
    """Rays from ``point`` through ``targets`` at ``t = 1`` (exact for dyadic points).

    Returns
    -------
    origins, directions : (k, 3) float32
    """
    targets = np.asarray(targets, dtype=np.float64)
    directions = (targets - np.asarray(point, dtype=np.float64)).astype(np.float32)
    origins = np.broadcast_to(np.asarray(point, np.float32), directions.shape).copy()
    assert_exact(origins, directions, targets, 1.0)
    return origins, directions


def assert_exact(origins, directions, targets, distance):
    """Fail unless every ``origin + distance * direction`` is exactly its target."""
    reached = origins.astype(np.float64) + distance * directions.astype(np.float64)
    assert np.array_equal(reached, np.asarray(targets, dtype=np.float64)), "inexact ray"
