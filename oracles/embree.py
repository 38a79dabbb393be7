"""Embree through ``embreex``: the one adapter that the benchmarks time and the tests compare with.

``embreex`` is imported when an ``Embree`` is built, so importing this module never fails.

What ``embreex`` (4.x) does, and what follows here:

- ``TriangleMesh(scene, triangles)`` copies (F, 3, 3) float32 corners into the scene; each mesh
  becomes one Embree geometry, and ``geomID`` is mapped back to the mesh's position in the list
  (empty meshes get no geometry).
- ``EmbreeScene.run(origins, directions, dists=None, query=..., output=None)`` takes float32
  (n, 3) arrays and commits the scene on its first call. ``tnear`` is always 0; ``dists`` is
  ``tfar`` (default 1e37), and a passed array is overwritten with the hit distances, so every
  query passes a fresh one.
- ``query="INTERSECT", output=1`` returns a dict with ``tfar``, ``primID``, ``geomID``, ``u``,
  ``v``, ``Ng``; on a miss ``primID == geomID == -1`` and ``tfar`` is left as passed. The
  barycentrics follow dacrt's convention, ``hit = (1-u-v)*p0 + u*p1 + v*p2``.
- ``query="OCCLUDED"`` is run *without* ``output`` (with it the dict holds garbage); it returns
  (n,) int32, ``-1`` for an unoccluded ray and ``0`` otherwise.
- A ``tmin`` is emulated by moving the origin to ``origin + tmin * direction`` and shortening
  ``tfar`` to ``tmax - tmin``; this rounds in float32, so compare near ``tmin`` with a tolerance.
- Embree is no oracle for degenerate triangles: it hits an exactly collinear triangle when the ray
  passes exactly through its segment. Compare on scenes where that is measure-zero.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

EMPTY3 = np.zeros((0, 3), dtype=np.float32)
# The farthest tfar passed to Embree (embreex's default).
FAR = 1e37


class MeshHits(NamedTuple):
    """Closest hits of ``n`` rays in a list of meshes.

    t : (n,) float64, ``inf`` on a miss
    mesh : (n,) int64, position of the hit mesh in the list; ``-1`` on a miss
    prim : (n,) int64, row of the hit face in that mesh's faces; ``-1`` on a miss
    u, v : (n,) float64, ``0`` on a miss
    normal : (n, 3) float64, Embree's unnormalised geometric normal; ``0`` on a miss
    """

    t: np.ndarray
    mesh: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(n,) bool: whether each ray hit anything."""
        return self.prim >= 0


def embree_rays(origins, directions, tmin=None, tmax=None):
    """Rays as Embree takes them: float32 (n, 3) origins and directions and (n,) tfar, with a
    ``tmin`` folded into the origin (in float64). Returns (origins, directions, tfar, tmin), the
    last (n,) float64 or 0.0, to add to Embree's distances."""
    far = np.minimum(np.inf if tmax is None else tmax, FAR)
    if tmin is None:
        origins32 = np.ascontiguousarray(origins, dtype=np.float32)
        tfar = np.empty(len(origins32), np.float32)
        tfar[:] = far
        return origins32, np.ascontiguousarray(directions, dtype=np.float32), tfar, 0.0
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    lo = np.broadcast_to(np.asarray(tmin, np.float64), (len(origins),))
    hi = np.broadcast_to(np.asarray(far, np.float64), (len(origins),))
    origins32 = np.ascontiguousarray(origins + lo[:, None] * directions, dtype=np.float32)
    tfar = np.ascontiguousarray(np.minimum(hi - lo, FAR), dtype=np.float32)
    return origins32, np.ascontiguousarray(directions, dtype=np.float32), tfar, lo


class Embree:
    """An Embree scene of a list of meshes, built once and queried many times; ``run`` traces one
    ray at a time on one thread.

    meshes : sequence of (vertices (V, 3) float, faces (F, 3) int); each mesh's corners are
        gathered into (F, 3, 3) float32 (part of the build).
    """

    def __init__(self, meshes):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.scene = rtcore_scene.EmbreeScene()
        geom_to_mesh = []
        for index, (vertices, faces) in enumerate(meshes):
            faces = np.asarray(faces).reshape(-1, 3)
            if len(faces) == 0:
                continue
            corners = np.asarray(vertices).reshape(-1, 3)[faces]
            TriangleMesh(self.scene, np.ascontiguousarray(corners, dtype=np.float32))
            geom_to_mesh.append(index)
        self.geom_to_mesh = np.asarray(geom_to_mesh, dtype=np.int64)

    def commit(self):
        """Build Embree's BVH now (embreex commits the scene on its first ``run``)."""
        self.scene.run(EMPTY3, EMPTY3)

    def closest(self, origins, directions, tmin=None, tmax=None) -> MeshHits:
        """Closest hit of each ray ``origins + t * directions`` with tmin <= t <= tmax.

        origins, directions : (n, 3) float; tmin, tmax : None, float or (n,) float
        """
        origins32, directions32, tfar, lo = embree_rays(origins, directions, tmin, tmax)
        n = len(origins32)
        if n == 0 or len(self.geom_to_mesh) == 0:
            return MeshHits(
                t=np.full(n, np.inf),
                mesh=np.full(n, -1, np.int64),
                prim=np.full(n, -1, np.int64),
                u=np.zeros(n),
                v=np.zeros(n),
                normal=np.zeros((n, 3)),
            )
        out = self.scene.run(origins32, directions32, dists=tfar, query="INTERSECT", output=1)
        geom = out["geomID"].astype(np.int64)
        hit = geom >= 0
        mesh = np.full(n, -1, np.int64)
        mesh[hit] = self.geom_to_mesh[geom[hit]]
        return MeshHits(
            t=np.where(hit, out["tfar"].astype(np.float64) + lo, np.inf),
            mesh=mesh,
            prim=np.where(hit, out["primID"].astype(np.int64), -1),
            u=np.where(hit, out["u"].astype(np.float64), 0.0),
            v=np.where(hit, out["v"].astype(np.float64), 0.0),
            normal=np.where(hit[:, None], out["Ng"].astype(np.float64), 0.0),
        )

    def closest_t(self, origins, directions, tmax=None):
        """The closest hit's t (n,) float32 (inf on a miss) and prim (n,) int32 (-1) of rays from
        t = 0, in a scene of one mesh, as Embree gives them: the query the benchmarks time."""
        origins32, directions32, tfar, _ = embree_rays(origins, directions, None, tmax)
        n = len(origins32)
        if n == 0 or len(self.geom_to_mesh) == 0:
            return np.full(n, np.inf, np.float32), np.full(n, -1, np.int32)
        out = self.scene.run(origins32, directions32, dists=tfar, output=1)
        prim = out["primID"]
        return np.where(prim >= 0, out["tfar"], np.float32(np.inf)), prim

    def occluded(self, origins, directions, tmin=None, tmax=None) -> np.ndarray:
        """(n,) bool: whether each ray hits anything with tmin <= t <= tmax."""
        origins32, directions32, tfar, _ = embree_rays(origins, directions, tmin, tmax)
        if len(origins32) == 0 or len(self.geom_to_mesh) == 0:
            return np.zeros(len(origins32), dtype=bool)
        return self.scene.run(origins32, directions32, dists=tfar, query="OCCLUDED") != -1
