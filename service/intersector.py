"""trimesh's ray intersector interface, answered by a dacrt server: switch with one line.

    mesh.ray = service.intersector.RayMeshIntersector(mesh, url="http://127.0.0.1:8000")

The intersector uploads the mesh into a scene of the server (``scene``: by default a new one,
named ``trimesh-<random>``, deleted again by ``close()``) and sends every query there through
``service.client``; answers are as ``dacrt.trimesh_ray.RayMeshIntersector``'s (the same class,
with a ``ServiceBackend``). Every mesh of that scene is hit: give the intersector a scene of its
own. The mesh is sent as it is (no move to the origin), so the scene holds the caller's
coordinates.
"""

from __future__ import annotations

import uuid
from typing import Any

import numpy as np

from dacrt import trimesh_ray

from .client import APIError, Client


class ServiceBackend:
    """The queries of ``dacrt.trimesh_ray.EngineBackend``, sent to scene ``scene`` of a server
    with only the answer fields the intersector reads."""

    def __init__(self, client: Client, scene: str) -> None:
        self.client, self.scene = client, scene

    def closest(self, origins: np.ndarray, directions: np.ndarray):
        answer = self.client.closest(self.scene, origins, directions, fields="prim,u,v")
        return answer.prim, answer.u, answer.v

    def occluded(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        return self.client.occluded(self.scene, origins, directions).occluded

    def hits(self, origins: np.ndarray, directions: np.ndarray, max_hits: int):
        answer = self.client.hits(
            self.scene, origins, directions, max_hits=max_hits, fields="prim,u,v"
        )
        return answer.offsets, answer.prim, answer.u, answer.v

    def count(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        return self.client.count(self.scene, origins, directions).count


class RayMeshIntersector(trimesh_ray.RayMeshIntersector):
    """trimesh's intersector interface on a server.

    mesh : a ``trimesh.Trimesh`` (or anything with ``vertices`` and ``faces``), uploaded now
    url : the server's base URL; token : its bearer token, if it has one
    scene : the scene to upload into (default: a new scene, deleted by ``close()``)
    mesh_name : the mesh's name in that scene
    client : a ``service.client.Client`` to use instead of ``url`` and ``token``
    """

    def __init__(
        self,
        mesh: Any,
        url: str = "http://127.0.0.1:8000",
        scene: str | None = None,
        mesh_name: str = "mesh",
        token: str | None = None,
        client: Client | None = None,
    ) -> None:
        self._owns_client = client is None
        self.client = client if client is not None else Client(url, token=token)
        self._owns_scene = scene is None
        self.scene = scene if scene is not None else f"trimesh-{uuid.uuid4().hex[:16]}"
        try:
            self.client.put_mesh(self.scene, mesh_name, mesh.vertices, mesh.faces)
        except BaseException:
            self.close()
            raise
        super().__init__(mesh, ServiceBackend(self.client, self.scene))

    def close(self) -> None:
        """Delete the scene if this intersector made it, and close its own client."""
        try:
            if self._owns_scene:
                self.client.delete(self.scene)
        except APIError as error:
            if error.status != 404:  # already gone (or never made: the upload failed)
                raise
        finally:
            if self._owns_client:
                self.client.close()

    def __enter__(self) -> RayMeshIntersector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
