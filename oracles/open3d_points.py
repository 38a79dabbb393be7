"""Open3D's ``RaycastingScene`` point queries as an oracle and a benchmark rival of
``Scene.nearest``, ``contains`` and ``signed_distance``.

``open3d`` is imported when a function runs, so importing this module never fails; tests that
call it first run ``pytest.importorskip("open3d")``.

What Open3D (0.19-0.20) does, and what follows here:

- ``compute_distance`` and ``compute_closest_points`` measure in float32 (Embree's point query):
  distances agree with the engine's float64 ones to float32 rounding, a few ulps of the
  coordinates' size.
- ``compute_signed_distance(nsamples=k)`` and ``compute_occupancy`` count the crossings of k rays
  from each point with Embree's (not watertight) ray test: a ray through an edge or vertex may
  count it twice or never (Open3D #5105, #5669), so signs are compared on watertight meshes and
  on points away from the surface.
- The BVH is built on the first query of a scene (``build``, untimed, does it beforehand).
"""

from __future__ import annotations

import numpy as np


def scene(vertices, faces):
    """A ``RaycastingScene`` of one mesh: (v, 3) float and (f, 3) int arrays."""
    import open3d

    built = open3d.t.geometry.RaycastingScene()
    built.add_triangles(
        open3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)),
        open3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32).reshape(-1, 3)),
    )
    return built


def tensor(points):
    """Points (n, 3) as the float32 tensor Open3D queries take (a tensor as it is)."""
    import open3d

    if isinstance(points, open3d.core.Tensor):
        return points
    return open3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3))


def build(built):
    """Build the BVH of a scene made by ``scene`` (Open3D builds it on its first query)."""
    built.compute_distance(tensor(np.zeros((1, 3))))
    return built


def distance(built, points) -> np.ndarray:
    """(n,) float32 distance from each of ``points`` ((n, 3) or a ``tensor``) to the scene, by
    ``compute_distance``."""
    return built.compute_distance(tensor(points)).numpy()


def signed_distance(built, points, nsamples=1) -> np.ndarray:
    """(n,) float32, negative inside, by ``compute_signed_distance``."""
    return built.compute_signed_distance(tensor(points), nsamples=nsamples).numpy()
