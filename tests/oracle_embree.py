"""Embree, through ``embreex``, as an independent oracle for the engine tests.

Tests that use it call ``pytest.importorskip("embreex")`` first; this module imports ``embreex``
lazily so that importing it never fails.

What ``embreex`` (4.x) does, checked in this venv, and what follows here:

- ``EmbreeScene.run(origins, directions, dists=None, query=..., output=None)`` takes float32
  (n, 3) arrays. ``tnear`` is always 0; ``dists`` is ``tfar`` (default 1e37) and a passed array is
  overwritten in place with the hit distances, so we always pass a fresh copy.
- ``query="INTERSECT", output=1`` returns a dict with ``tfar``, ``primID``, ``geomID``, ``u``,
  ``v``, ``Ng``; on a miss ``primID == geomID == -1`` and ``tfar`` is left at the input value.
  Embree's barycentrics follow the same convention as the engine,
  ``hit = (1-u-v)*p0 + u*p1 + v*p2``.
- ``query="OCCLUDED"`` must be run *without* ``output`` (with it the dict holds garbage); it returns
  (n,) int32, ``-1`` for an unoccluded ray and ``0`` otherwise.
- A ``tmin`` is emulated by moving the origin to ``origin + tmin * direction`` and shortening
  ``tfar`` to ``tmax - tmin``; this rounds in float32, so compare near ``tmin`` with a tolerance.
- Embree is no oracle for degenerate triangles: it hits an exactly collinear triangle when the ray
  passes exactly through its segment (seen here). Compare on scenes where that is measure-zero.
- Each mesh becomes one Embree geometry; ``geomID`` is mapped back to the mesh's position in the
  list (empty meshes get no geometry).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from reference import Hits  # the same answer type as the numpy reference


class MeshHits(NamedTuple):
    """Closest hits of ``n`` rays in a list of meshes.

    t : (n,) float64
      ``inf`` on a miss.
    mesh : (n,) int64
      Position of the hit mesh in the list; ``-1`` on a miss.
    prim : (n,) int64
      Row of the hit face in that mesh's faces; ``-1`` on a miss.
    u, v : (n,) float64
      ``0`` on a miss.
    """

    t: np.ndarray
    mesh: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray


class EmbreeOracle:
    """An Embree scene built once from a list of meshes, queried many times.

    Parameters
    ----------
    meshes : list of ((v, 3) float, (f, 3) int)
    """

    def __init__(self, meshes):
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh

        self.scene = rtcs.EmbreeScene()
        self.geom_to_mesh = []
        self._keep = []  # Embree shares our buffers: keep them alive as long as the scene.
        for index, (vertices, faces) in enumerate(meshes):
            vertices = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
            faces = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
            if len(faces) == 0:
                continue
            self._keep.append((vertices, faces, TriangleMesh(self.scene, vertices, faces)))
            self.geom_to_mesh.append(index)
        self.geom_to_mesh = np.asarray(self.geom_to_mesh, dtype=np.int64)

    def _rays(self, origins, directions, tmin, tmax):
        """Float32 origins, directions and tfar with ``tmin`` folded into the origin."""
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        n = len(origins)
        lo = np.zeros(n) if tmin is None else np.broadcast_to(np.asarray(tmin, np.float64), (n,))
        hi = (
            np.full(n, np.inf)
            if tmax is None
            else np.broadcast_to(np.asarray(tmax, np.float64), (n,))
        )
        o32 = np.ascontiguousarray(origins + lo[:, None] * directions, dtype=np.float32)
        d32 = np.ascontiguousarray(directions, dtype=np.float32)
        tfar = np.ascontiguousarray(np.minimum(hi - lo, 1e37), dtype=np.float32)
        return o32, d32, tfar, lo

    def closest(self, origins, directions, tmin=None, tmax=None) -> MeshHits:
        """Closest hit of each ray.

        Parameters
        ----------
        origins, directions : (n, 3) float
        tmin, tmax : None, float or (n,) float

        Returns
        -------
        hits : MeshHits
        """
        o32, d32, tfar, lo = self._rays(origins, directions, tmin, tmax)
        n = len(o32)
        if n == 0 or len(self.geom_to_mesh) == 0:
            return MeshHits(
                t=np.full(n, np.inf),
                mesh=np.full(n, -1, np.int64),
                prim=np.full(n, -1, np.int64),
                u=np.zeros(n),
                v=np.zeros(n),
            )
        out = self.scene.run(o32, d32, dists=tfar.copy(), query="INTERSECT", output=1)
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
        )

    def occluded(self, origins, directions, tmin=None, tmax=None) -> np.ndarray:
        """(n,) bool: whether each ray hits anything in its range."""
        o32, d32, tfar, _ = self._rays(origins, directions, tmin, tmax)
        if len(o32) == 0 or len(self.geom_to_mesh) == 0:
            return np.zeros(len(o32), dtype=bool)
        return self.scene.run(o32, d32, dists=tfar.copy(), query="OCCLUDED") != -1


def closest_meshes(meshes, origins, directions, tmin=None, tmax=None) -> MeshHits:
    """Closest hits in a list of meshes, through a one-off Embree scene (see
    :class:`EmbreeOracle`)."""
    return EmbreeOracle(meshes).closest(origins, directions, tmin, tmax)


def closest(vertices, faces, origins, directions, tmin=None, tmax=None) -> Hits:
    """Closest hit of each ray in one mesh, shaped like ``reference.closest``.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    origins, directions : (n, 3) float
    tmin, tmax : None, float or (n,) float

    Returns
    -------
    hits : Hits
      ``t`` (n,) float64 (``inf`` on a miss), ``prim`` (n,) int64 (``-1``),
      ``u``, ``v`` (n,) float64.
    """
    h = closest_meshes([(vertices, faces)], origins, directions, tmin, tmax)
    return Hits(t=h.t, prim=h.prim, u=h.u, v=h.v)


def occluded(vertices, faces, origins, directions, tmin=None, tmax=None) -> np.ndarray:
    """(n,) bool: whether each ray hits the mesh in its range, by Embree."""
    return EmbreeOracle([(vertices, faces)]).occluded(origins, directions, tmin, tmax)
