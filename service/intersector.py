"""trimesh's ray intersector interface, answered by a dacrt server: switch with one line.

    mesh.ray = service.intersector.RayMeshIntersector(mesh, url="http://127.0.0.1:8000")

The intersector uploads the mesh into a scene of the server (``scene``: by default a new one,
named ``trimesh-<random>``) and sends every query there through ``service.client``; answers are
as ``dacrt.trimesh_ray.RayMeshIntersector``'s (the same class, with a ``ServiceBackend``). As in
process, the mesh is sent with its box centre moved to the origin (``trimesh_ray.centre_of``),
rays too, which keeps float32 precision far from the origin; a ``trimesh.Trimesh`` that changes
is uploaded again at the next query. Every mesh of the scene is hit, so a named ``scene`` that
holds another mesh is refused (``ValueError``). ``close()`` (or leaving a ``with`` block)
deletes a scene the intersector made; one dropped without it is deleted when it is
garbage-collected, or when the interpreter exits, with a ``ResourceWarning``, as
``tempfile.TemporaryDirectory`` does.
"""

from __future__ import annotations

import uuid
import warnings
import weakref
from contextlib import suppress
from typing import Any

import numpy as np

from dacrt import trimesh_ray

from .client import APIError, Client


class ServiceBackend:
    """The queries of ``dacrt.trimesh_ray.EngineBackend``, sent to scene ``scene`` of a server
    with only the answer fields the intersector reads; the scene holds the mesh moved by
    -``shift``, so the rays are moved too."""

    def __init__(self, client: Client, scene: str, shift: np.ndarray) -> None:
        self.client, self.scene, self.shift = client, scene, shift

    def closest(self, origins: np.ndarray, directions: np.ndarray):
        answer = self.client.closest(
            self.scene, origins - self.shift, directions, fields="prim,u,v"
        )
        return answer.prim, answer.u, answer.v

    def occluded(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        return self.client.occluded(self.scene, origins - self.shift, directions).occluded

    def hits(self, origins: np.ndarray, directions: np.ndarray, max_hits: int):
        answer = self.client.hits(
            self.scene, origins - self.shift, directions, max_hits=max_hits, fields="prim,u,v"
        )
        return answer.offsets, answer.prim, answer.u, answer.v

    def count(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        return self.client.count(self.scene, origins - self.shift, directions).count


class RayMeshIntersector(trimesh_ray.RayMeshIntersector):
    """trimesh's intersector interface on a server.

    mesh : a ``trimesh.Trimesh`` (or anything with ``vertices`` and ``faces``), uploaded now
        and again whenever a ``trimesh.Trimesh`` changes
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
        self.client = client if client is not None else Client(url, token=token)
        self.scene = scene if scene is not None else f"trimesh-{uuid.uuid4().hex[:16]}"
        self.mesh_name = mesh_name
        owned = (self.client if client is None else None, self.client if scene is None else None)
        self._finalizer = weakref.finalize(self, _clean_up, *owned, self.scene, implicit=True)
        try:
            if scene is not None:
                self._check_scene_is_its_own()
            super().__init__(mesh)
        except BaseException:
            self.close()
            raise

    def _check_scene_is_its_own(self) -> None:
        """ValueError where the scene holds another mesh: every mesh of a scene is hit, and
        the answers would name that mesh's triangles as this one's."""
        try:
            meshes = [m["mesh"] for m in self.client.scene(self.scene)["meshes"]]
        except APIError as error:
            if error.status == 404:  # a new scene
                return
            raise
        others = [name for name in meshes if name != self.mesh_name]
        if others:
            raise ValueError(
                f"scene {self.scene!r} holds other meshes ({', '.join(others)}): an intersector "
                "needs a scene of its own (leave scene out for a new one)"
            )

    def make_backend(self, vertices: np.ndarray, faces: np.ndarray) -> ServiceBackend:
        """Upload the mesh (moved by -its box centre) into the scene, the mesh it replaces."""
        shift = trimesh_ray.centre_of(vertices, faces)
        self.client.put_mesh(self.scene, self.mesh_name, vertices - shift, faces)
        return ServiceBackend(self.client, self.scene, shift)

    def close(self) -> None:
        """Delete the scene if this intersector made it, and close its own client (once)."""
        found = self._finalizer.detach()
        if found is not None:
            _, clean_up, args, _ = found
            clean_up(*args)

    def __enter__(self) -> RayMeshIntersector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _clean_up(
    own_client: Client | None, scene_owner: Client | None, scene: str, implicit: bool = False
) -> None:
    """Delete ``scene`` through ``scene_owner`` (None: a scene the caller named, kept), then
    close ``own_client`` (None: the caller's). Run once: by ``close()``, or ``implicit``ly by the
    finalizer of an intersector dropped without it, which warns and gives up on any error (the
    server may be gone by then)."""
    if implicit:
        warnings.warn(
            f"deleting the scene {scene!r} of an intersector that was not closed: call close() "
            "or use it in a with block",
            ResourceWarning,
            stacklevel=2,
        )
        with suppress(Exception):
            _clean_up(own_client, scene_owner, scene)
        return
    try:
        if scene_owner is not None:
            try:
                scene_owner.delete(scene)
            except APIError as error:
                if error.status != 404:  # already gone (or never made: the upload failed)
                    raise
    finally:
        if own_client is not None:
            own_client.close()
