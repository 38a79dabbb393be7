"""Open3D's ``RaycastingScene`` (Embree inside) as a second oracle for ``hits`` and ``count``.

``open3d`` is imported when a function runs, so importing this module never fails; tests that
call it first run ``pytest.importorskip("open3d")``.

What Open3D (0.19-0.20) does, and what follows here:

- ``add_triangles(vertices, faces)`` takes float32 (v, 3) and uint32 (f, 3) tensors; one call
  makes one geometry, and ``primitive_ids`` are rows of its faces.
- ``count_intersections(rays)`` and ``list_intersections(rays)`` take (n, 6) float32 rays
  ``[origin, direction]`` and consider every ``t >= 0`` (no ``tmin``, no ``tmax``).
- ``list_intersections`` lists each ray's hits in Embree's traversal order; here they are sorted
  by ``(t, prim)``.
- Each hit is dropped whose ``t`` equals, in float32, that of the hit Embree reported just before
  on another triangle of the same geometry (Open3D's guard against one hit reported twice), so
  coplanar overlapping triangles count once. Compare on rays whose crossings are all apart in t.
- Embree's triangle test is not watertight: a ray exactly through a shared edge may count it
  twice or never. Compare on rays that pass through no edge or vertex.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class ListedHits(NamedTuple):
    """Open3D's hits of ``n`` rays, CSR: ray ``i`` has rows ``offsets[i]:offsets[i+1]``,
    sorted by ``(t, prim)``.

    offsets : (n+1,) int64; t : (m,) float32; prim : (m,) int64; u, v : (m,) float32
    """

    offsets: np.ndarray
    t: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray


def _scene_and_rays(vertices, faces, origins, directions):
    import open3d

    scene = open3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        open3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)),
        open3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32).reshape(-1, 3)),
    )
    rays = np.hstack(
        [
            np.asarray(origins, dtype=np.float32).reshape(-1, 3),
            np.asarray(directions, dtype=np.float32).reshape(-1, 3),
        ]
    )
    return scene, open3d.core.Tensor(np.ascontiguousarray(rays))


def count(vertices, faces, origins, directions) -> np.ndarray:
    """(n,) int64 hits of each ray with ``t >= 0``, by ``count_intersections``."""
    scene, rays = _scene_and_rays(vertices, faces, origins, directions)
    return scene.count_intersections(rays).numpy().astype(np.int64)


def list_hits(vertices, faces, origins, directions) -> ListedHits:
    """Every hit with ``t >= 0`` by ``list_intersections``, sorted by ``(t, prim)`` per ray."""
    scene, rays = _scene_and_rays(vertices, faces, origins, directions)
    out = {k: v.numpy() for k, v in scene.list_intersections(rays).items()}
    ray = out["ray_ids"].astype(np.int64)
    t = out["t_hit"].astype(np.float32)
    prim = out["primitive_ids"].astype(np.int64)
    uv = out["primitive_uvs"].astype(np.float32).reshape(-1, 2)
    order = np.lexsort((prim, t, ray))
    offsets = out["ray_splits"].astype(np.int64)
    return ListedHits(offsets, t[order], prim[order], uv[order, 0], uv[order, 1])
