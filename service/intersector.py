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

Threads may share one, as in process: each call answers from the mesh as one reading read it.
A reading's upload records the scene version it made, and an answer computed on another version
(another thread uploaded a newer reading meanwhile, or another client changed the scene) is not
used: that reading's mesh is uploaded into a spare scene of its own (``trimesh-<random>``),
asked again there, and the spare scene is deleted once no call holds that reading (or by
``close()``). A call on the current reading costs one request, as before.
"""

from __future__ import annotations

import threading
import uuid
import warnings
import weakref
from contextlib import suppress
from typing import Any

import numpy as np

from dacrt import trimesh_ray

from .client import APIError, Client


class ServiceBackend:
    """The queries of ``dacrt.trimesh_ray.EngineBackend``, sent to a server with only the answer
    fields the intersector reads, for one reading of the mesh: ``vertices`` (V, 3) float64 and
    ``faces`` (F, 3) int, uploaded moved by -``shift`` as mesh ``mesh`` of ``scene``, whose
    upload made scene version ``version``.

    An answer from another version of ``scene`` is not this reading's: the mesh is then uploaded
    into a spare scene of its own (its name kept in ``spares``, the intersector's, until it is
    deleted) and the query is sent there; the spare scene is deleted when the backend is dropped.
    """

    def __init__(
        self,
        client: Client,
        scene: str,
        mesh: str,
        version: int,
        vertices: np.ndarray,
        faces: np.ndarray,
        shift: np.ndarray,
        spares: set[str],
    ) -> None:
        self.client, self.mesh, self.shift = client, mesh, shift
        self.vertices, self.faces, self.spares = vertices, faces, spares
        #: (the scene that holds this reading's mesh, the version its upload made)
        self.where = (scene, version)
        self._lock = threading.Lock()  # one thread makes the spare scene; the others use it

    def _ask(self, query):
        """``query(scene)``'s answer, computed on the scene version that holds this reading."""
        scene, version = self.where
        answer = query(scene)
        if answer.version == version:
            return answer
        scene, version = self._move_to_a_spare_scene(scene)
        answer = query(scene)
        if answer.version != version:
            raise RuntimeError(
                f"the intersector's scene {scene!r} changed under it (version {answer.version}, "
                f"uploaded as {version}): another client writes into it"
            )
        return answer

    def _move_to_a_spare_scene(self, stale: str) -> tuple[str, int]:
        """Upload this reading's mesh into a new scene, unless another thread did once ``stale``
        answered another version; the new scene is deleted when the backend is dropped."""
        with self._lock:
            if self.where[0] != stale:
                return self.where
            spare = f"trimesh-{uuid.uuid4().hex[:16]}"
            self.spares.add(spare)  # before the upload: close() deletes a half-made one too
            finalizer = weakref.finalize(self, _delete_spare, self.client, spare, self.spares)
            finalizer.atexit = False  # the intersector's own clean-up deletes the spares then
            info = self.client.put_mesh(spare, self.mesh, self.vertices - self.shift, self.faces)
            self.where = (spare, info["version"])
            return self.where

    def closest(self, origins: np.ndarray, directions: np.ndarray):
        rays = (origins - self.shift, directions)
        answer = self._ask(lambda scene: self.client.closest(scene, *rays, fields="prim,u,v"))
        return answer.prim, answer.u, answer.v

    def occluded(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        rays = (origins - self.shift, directions)
        return self._ask(lambda scene: self.client.occluded(scene, *rays)).occluded

    def hits(self, origins: np.ndarray, directions: np.ndarray, max_hits: int):
        rays = (origins - self.shift, directions)
        answer = self._ask(
            lambda scene: self.client.hits(scene, *rays, max_hits=max_hits, fields="prim,u,v")
        )
        return answer.offsets, answer.prim, answer.u, answer.v

    def count(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        rays = (origins - self.shift, directions)
        return self._ask(lambda scene: self.client.count(scene, *rays)).count


def _delete_spare(client: Client, spare: str, spares: set[str]) -> None:
    """Delete a dropped backend's spare scene. It runs where the backend's last reference goes,
    where no caller can handle an error: a spare it cannot delete stays in ``spares`` for the
    intersector's ``close()``."""
    if spare not in spares:  # close() deleted it
        return
    with suppress(Exception):
        _delete_scene(client, spare)
        spares.discard(spare)


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
        #: the spare scenes of readings that calls still hold (``ServiceBackend``), to delete
        self._spares: set[str] = set()
        owned = (scene is None, client is None)  # (its scene, its client) to delete and close
        self._finalizer = weakref.finalize(
            self, _clean_up, self.client, self.scene, self._spares, *owned, implicit=True
        )
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
        info = self.client.put_mesh(self.scene, self.mesh_name, vertices - shift, faces)
        return ServiceBackend(
            self.client,
            self.scene,
            self.mesh_name,
            info["version"],
            vertices,
            faces,
            shift,
            self._spares,
        )

    def close(self) -> None:
        """Delete the scene if this intersector made it, and every spare scene of its readings,
        and close its own client (once)."""
        found = self._finalizer.detach()
        if found is not None:
            _, clean_up, args, _ = found
            clean_up(*args)

    def __enter__(self) -> RayMeshIntersector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _clean_up(
    client: Client,
    scene: str,
    spares: set[str],
    own_scene: bool,
    own_client: bool,
    implicit: bool = False,
) -> None:
    """Delete the ``spares`` and, if ``own_scene`` (one the intersector made), ``scene``, then
    close ``client`` if it is the intersector's ``own_client``. Run once: by ``close()``, or
    ``implicit``ly by the finalizer of an intersector dropped without it, which warns and gives
    up on any error (the server may be gone by then)."""
    if implicit:
        warnings.warn(
            f"deleting the scene {scene!r} of an intersector that was not closed: call close() "
            "or use it in a with block",
            ResourceWarning,
            stacklevel=2,
        )
        with suppress(Exception):
            _clean_up(client, scene, spares, own_scene, own_client)
        return
    try:
        while spares:
            _delete_scene(client, spares.pop())
        if own_scene:
            _delete_scene(client, scene)
    finally:
        if own_client:
            client.close()


def _delete_scene(client: Client, scene: str) -> None:
    """Delete ``scene``; one already gone (or never made: its upload failed) is no error."""
    try:
        client.delete(scene)
    except APIError as error:
        if error.status != 404:
            raise
