"""Scenes: named sets of triangle meshes, changed atomically, read as immutable snapshots.

A scene's whole state is one frozen ``Snapshot``; a change builds a new snapshot under the store's
lock and swaps it in with one assignment, so a reader that took a snapshot keeps one consistent
version however many changes follow. Arrays are owned by the store and read-only. Every change
checks the limits and the request first and swaps last: a rejected change leaves nothing behind.
With a journal (``persistence.DataDir``), a version is durable before it is swapped in.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import Conflict, Invalid, NotFound, TooLarge
from .wire import MeshArrays, json_ready

if TYPE_CHECKING:
    from .persistence import DataDir

NAME = re.compile(r"[A-Za-z0-9_.\-]{1,64}")


def check_name(kind: str, name: str) -> str:
    """422 unless ``name`` is 1-64 characters of ``A-Z a-z 0-9 _ - .`` (and not ``.`` or ``..``)."""
    if not NAME.fullmatch(name) or name in (".", ".."):
        raise Invalid(
            f"{kind} name {name!r} must be 1-64 characters of A-Z a-z 0-9 _ - . "
            "(and not '.' or '..')"
        )
    return name


def _owned(array: np.ndarray, dtype: str) -> np.ndarray:
    """A read-only C-contiguous copy: the store never shares memory with a request or a caller."""
    array = np.array(array, dtype=dtype, order="C", copy=True)
    array.setflags(write=False)
    return array


def referenced_bounds(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(2, 3) float32 [[min], [max]] of the vertices that faces refer to; zeros with no faces."""
    if faces.size == 0:
        return np.zeros((2, 3), np.float32)
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    # column by column, masked in place: a row-wise reduction of (N, 3) and a gather both cost more
    columns = np.ascontiguousarray(vertices.T)
    return np.stack(
        [
            columns.min(axis=1, where=used, initial=np.inf),
            columns.max(axis=1, where=used, initial=-np.inf),
        ]
    ).astype(np.float32)


@dataclass(frozen=True, slots=True)
class Mesh:
    """One named mesh of a scene. Later: ``mask`` and ``transform`` fields fit here."""

    name: str
    index: int  #: the mesh's number in hit results; fixed while the mesh exists
    vertices: np.ndarray  #: (V, 3) float32, read-only
    faces: np.ndarray  #: (F, 3) int32, read-only, every index in [0, V)
    bounds: np.ndarray  #: (2, 3) float32 of the referenced vertices
    version: int  #: scene version of the mesh's last change

    @property
    def n_triangles(self) -> int:
        return len(self.faces)

    @property
    def nbytes(self) -> int:
        return self.vertices.nbytes + self.faces.nbytes

    def info(self, scene: str) -> dict[str, Any]:
        """Mesh info JSON of API.md."""
        return {
            "scene": scene,
            "mesh": self.name,
            "index": self.index,
            "vertices": len(self.vertices),
            "triangles": self.n_triangles,
            "bounds": json_ready(self.bounds),
            "version": self.version,
        }


def new_mesh(name: str, arrays: MeshArrays, index: int = -1, version: int = 0) -> Mesh:
    """A Mesh owning copies of checked arrays; ``index`` and ``version`` are set by the store."""
    vertices, faces = _owned(arrays.vertices, "<f4"), _owned(arrays.faces, "<i4")
    return Mesh(name, index, vertices, faces, referenced_bounds(vertices, faces), version)


@dataclass(frozen=True)
class Snapshot:
    """One version of a scene. Immutable, except a cache of things derived from it."""

    scene: str
    version: int
    meshes: Mapping[str, Mesh]  #: by name, in index order
    next_index: int  #: the index the next new mesh gets (indices are never reused)
    _cache: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)
    _cache_lock: threading.Lock = field(default_factory=threading.Lock, compare=False, repr=False)

    @property
    def n_triangles(self) -> int:
        return sum(m.n_triangles for m in self.meshes.values())

    @property
    def nbytes(self) -> int:
        return sum(m.nbytes for m in self.meshes.values())

    @property
    def bounds(self) -> np.ndarray:
        boxes = [m.bounds for m in self.meshes.values() if m.n_triangles]
        if not boxes:
            return np.zeros((2, 3), np.float32)
        stacked = np.stack(boxes)
        return np.stack([stacked[:, 0].min(axis=0), stacked[:, 1].max(axis=0)])

    def mesh(self, name: str) -> Mesh:
        try:
            return self.meshes[name]
        except KeyError:
            raise NotFound(
                f"scene {self.scene!r} has no mesh {name!r}; it has {sorted(self.meshes) or 'none'}"
            ) from None

    def info(self) -> dict[str, Any]:
        """Scene info JSON of API.md."""
        return {
            "scene": self.scene,
            "version": self.version,
            "triangles": self.n_triangles,
            "bounds": json_ready(self.bounds),
            "meshes": [m.info(self.scene) for m in self.meshes.values()],
        }

    def cached(self, key: str, build: Callable[[Snapshot], Any]) -> Any:
        """``build(self)`` once per snapshot (e.g. the engine's scene), shared by every query."""
        with self._cache_lock:
            if key not in self._cache:
                self._cache[key] = build(self)
            return self._cache[key]


class Store:
    """All scenes of the service, with the limits on their size."""

    def __init__(
        self, max_triangles_per_scene: int, max_scene_bytes: int, journal: DataDir | None = None
    ) -> None:
        self.max_triangles_per_scene = max_triangles_per_scene
        self.max_scene_bytes = max_scene_bytes
        self.journal = journal  #: where each version is made durable before it is served
        self._scenes: dict[str, Snapshot] = {}
        self._last_version: dict[str, int] = {}  # kept after a delete: versions never go back
        self._nbytes = 0
        self._lock = threading.Lock()

    # ---- reading: lock-free, one dict lookup of an immutable snapshot

    @property
    def nbytes(self) -> int:
        """Bytes of vertices and faces held over all scenes."""
        return self._nbytes

    def snapshot(self, scene: str) -> Snapshot:
        """The current version of a scene (404 if there is none)."""
        snapshot = self._scenes.get(scene)
        if snapshot is None:
            raise NotFound(f"no scene {scene!r}; create it with PUT /v1/scenes/{scene}/meshes/MESH")
        return snapshot

    def snapshots(self) -> list[Snapshot]:
        return [self._scenes[name] for name in sorted(self._scenes.copy())]

    # ---- changing: each builds a new snapshot under the lock, then swaps it in

    def put_mesh(self, scene: str, name: str, arrays: MeshArrays) -> tuple[Mesh, bool]:
        """Add or replace a mesh (creating the scene); answers (mesh, created)."""
        check_name("scene", scene), check_name("mesh", name)
        mesh = new_mesh(name, arrays)
        with self._lock:
            old = self._scenes.get(scene)
            snapshot = self._commit(scene, old, {name: mesh})
            return snapshot.meshes[name], old is None or name not in old.meshes

    def update_vertices(self, scene: str, name: str, vertices: np.ndarray) -> Mesh:
        """New positions for a mesh's vertices, same count; faces are kept (409 on a count
        change)."""
        with self._lock:
            old = self.snapshot(scene)
            mesh = self._moved(old.mesh(name), vertices, old.scene)
            return self._commit(scene, old, {name: mesh}).meshes[name]

    def apply_frame(
        self, scene: str, changes: Mapping[str, tuple[np.ndarray, np.ndarray | None]]
    ) -> Snapshot:
        """Change several meshes in one version: (vertices, faces) adds or replaces a mesh,
        (vertices, None) moves an existing one's vertices."""
        check_name("scene", scene)
        for name in changes:
            check_name("mesh", name)
        added = {
            name: new_mesh(name, MeshArrays(vertices, faces))
            for name, (vertices, faces) in changes.items()
            if faces is not None
        }
        with self._lock:
            old = self._scenes.get(scene)
            meshes: dict[str, Mesh] = {}
            for name, (vertices, faces) in changes.items():
                if faces is not None:
                    meshes[name] = added[name]
                elif old is None:
                    raise NotFound(
                        f"no scene {scene!r}, so {name}.vertices has no faces to go "
                        f"with; send {name}.faces too to create it"
                    )
                else:
                    meshes[name] = self._moved(old.mesh(name), vertices, scene)
            return self._commit(scene, old, meshes)

    def restore(self, snapshots: list[Snapshot], last_versions: Mapping[str, int]) -> None:
        """Serve ``snapshots`` (read back from the journal) and continue after ``last_versions``
        (limits are not checked: the scenes were accepted when they were made)."""
        with self._lock:
            for snapshot in snapshots:
                self._nbytes += snapshot.nbytes - self._scenes.get(snapshot.scene, snapshot).nbytes
                self._scenes[snapshot.scene] = snapshot
            for scene, version in last_versions.items():
                self._last_version[scene] = max(version, self._last_version.get(scene, 0))

    def delete_scene(self, scene: str) -> None:
        with self._lock:
            old = self.snapshot(scene)
            if self.journal is not None:
                self.journal.delete(scene, self._last_version[scene])
            del self._scenes[scene]
            self._nbytes -= old.nbytes

    def delete_mesh(self, scene: str, name: str) -> Snapshot:
        with self._lock:
            old = self.snapshot(scene)
            old.mesh(name)
            return self._commit(scene, old, {name: None})

    # ---- helpers, called with the lock held

    @staticmethod
    def _moved(mesh: Mesh, vertices: np.ndarray, scene: str) -> Mesh:
        if len(vertices) != len(mesh.vertices):
            raise Conflict(
                f"mesh {mesh.name!r} of scene {scene!r} has {len(mesh.vertices)} vertices "
                f"but the update has {len(vertices)}; to change the vertex count, "
                f"PUT the whole mesh to /v1/scenes/{scene}/meshes/{mesh.name}"
            )
        vertices = _owned(vertices, "<f4")
        return replace(mesh, vertices=vertices, bounds=referenced_bounds(vertices, mesh.faces))

    def _commit(
        self, scene: str, old: Snapshot | None, changes: Mapping[str, Mesh | None]
    ) -> Snapshot:
        """Check limits, then swap in the next version with ``changes`` (None deletes a mesh)."""
        version = self._last_version.get(scene, 0) + 1
        meshes = dict(old.meshes) if old else {}
        next_index = old.next_index if old else 0
        for name, mesh in changes.items():
            if mesh is None:
                del meshes[name]
                continue
            if name in meshes:
                index = meshes[name].index
            else:
                index, next_index = next_index, next_index + 1
            meshes[name] = replace(mesh, index=index, version=version)
        meshes = dict(sorted(meshes.items(), key=lambda item: item[1].index))
        snapshot = Snapshot(scene, version, MappingProxyType(meshes), next_index)
        if snapshot.n_triangles > self.max_triangles_per_scene:
            raise TooLarge(
                f"scene {scene!r} would hold {snapshot.n_triangles} triangles, over the "
                f"limit of {self.max_triangles_per_scene} (DACRT_MAX_TRIANGLES_PER_SCENE)"
            )
        nbytes = self._nbytes - (old.nbytes if old else 0) + snapshot.nbytes
        if nbytes > self.max_scene_bytes:
            raise TooLarge(
                f"scenes would hold {nbytes} bytes of vertices and faces, over the limit "
                f"of {self.max_scene_bytes} bytes (DACRT_MAX_SCENE_BYTES)"
            )
        if self.journal is not None:
            self._last_version[scene] = version  # a failed write still uses up its version
            self.journal.write(snapshot)
        self._scenes[scene] = snapshot
        self._last_version[scene] = version
        self._nbytes = nbytes
        return snapshot
