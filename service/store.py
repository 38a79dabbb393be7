"""Scenes: named sets of triangle meshes, changed atomically, read as immutable snapshots.

A scene's whole state is one frozen ``Snapshot``; a change builds a new snapshot under the store's
lock and swaps it in with one assignment, so a reader that took a snapshot keeps one consistent
version however many changes follow. Arrays are owned by the store and read-only. Every change
checks the limits and the request first and swaps last: a rejected change leaves nothing behind.
With a journal (``persistence.DataDir``), a version is durable before it is swapped in; a change
the journal cannot write (507 or 503, naming the data folder) is not swapped in, and only uses up
its version number.

A mesh is its arrays (a ``Geometry``) placed in the scene by a ``transform`` and seen by rays
through its ``mask``. An instance is a mesh whose ``Geometry`` is its source's own object: the
arrays are held once, an instance follows every change of its source's arrays, and a source cannot
be deleted (or become an instance itself) while instances of it exist.
"""

from __future__ import annotations

import functools
import re
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from dacrt.sensors.physics import DEFAULT_LABEL, DEFAULT_REFLECTIVITY
from dacrt.validation import place_vertices

from .errors import Conflict, Invalid, NotFound, TooLarge
from .footprint import POINT_TRIANGLE_BYTES, TRIANGLE_BYTES
from .wire import FrameChange, MeshArrays, json_ready

if TYPE_CHECKING:
    from .persistence import DataDir

NAME = re.compile(r"[A-Za-z0-9_.\-]{1,64}")
ALL_MASKS = 0xFFFFFFFF  #: a mesh's mask unless one is set: every ray sees it
MAX_INDEX = 2**31 - 1  #: the last index a mesh can have: hit results give a mesh as int32
IDENTITY = np.eye(4)
IDENTITY.setflags(write=False)


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


def _same_end(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Whether two end placements (None: static) are the same."""
    if a is None or b is None:
        return a is b
    return np.array_equal(a, b)


def owned_transform(matrix: np.ndarray | None) -> np.ndarray | None:
    """A checked (4, 4) matrix as the store keeps it: None for the identity, else a read-only
    float64 copy."""
    if matrix is None or np.array_equal(matrix, IDENTITY):
        return None
    return _owned(matrix, "<f8")


class Material(NamedTuple):
    """A mesh's material as a change gives it (checked by ``wire``); None keeps a part."""

    reflectivity: float | None = None
    label: int | None = None


NO_MATERIAL = Material()


@dataclass(frozen=True, eq=False)
class Geometry:
    """A mesh's arrays, as uploaded: shared (never copied) by the mesh and its instances."""

    vertices: np.ndarray  #: (V, 3) float32, read-only
    faces: np.ndarray  #: (F, 3) int32, read-only, every index in [0, V)
    bounds: np.ndarray  #: (2, 3) float32 of the referenced vertices, untransformed

    @property
    def nbytes(self) -> int:
        return self.vertices.nbytes + self.faces.nbytes

    @functools.cached_property
    def _referenced_columns(self) -> np.ndarray:
        """(3, V') the referenced vertices' coordinates, a row per axis (the vertices' own memory
        when every vertex is referenced)."""
        used = np.zeros(len(self.vertices), dtype=bool)
        used[self.faces.ravel()] = True
        return self.vertices.T if used.all() else np.ascontiguousarray(self.vertices[used].T)

    @functools.cached_property
    def _corners(self) -> np.ndarray:
        """(3, 8) float64 the corners of the box of every vertex (referenced or not)."""
        box = self.vertices.min(axis=0), self.vertices.max(axis=0)
        return np.array([[box[i >> a & 1][a] for i in range(8)] for a in range(3)], np.float64)

    def check_placeable(self, transform: np.ndarray, name: str) -> None:
        """The engine's InputError naming the mesh (422 through ``errors``' table) unless
        ``transform`` keeps every vertex within the float32 range."""
        if not len(self.vertices):
            return
        corners = transform[:3, :3] @ self._corners + transform[:3, 3:]
        if np.abs(corners).max() <= np.finfo(np.float32).max:
            return  # every placed vertex lies in the placed box of these corners
        place_vertices(self.vertices, transform, name)

    def placed_bounds(self, transform: np.ndarray | None) -> np.ndarray:
        """(2, 3) float32 bounds in scene space of the referenced vertices placed by
        ``transform`` (computed in float64, as the engine places them)."""
        if transform is None or not len(self.faces):
            return self.bounds
        placed = transform[:3, :3] @ self._referenced_columns + transform[:3, 3:]
        return np.stack([placed.min(axis=1), placed.max(axis=1)]).astype(np.float32)


def new_geometry(arrays: MeshArrays) -> Geometry:
    """A Geometry owning copies of checked arrays."""
    vertices, faces = _owned(arrays.vertices, "<f4"), _owned(arrays.faces, "<i4")
    return Geometry(vertices, faces, referenced_bounds(vertices, faces))


@dataclass(frozen=True, slots=True)
class Mesh:
    """One named mesh of a scene: its arrays, where they are placed and which rays see them."""

    name: str
    index: int  #: the mesh's number in hit results; fixed while the mesh exists
    geometry: Geometry  #: the arrays; an instance holds its source's object
    bounds: np.ndarray  #: (2, 3) float32 scene-space bounds of the placed referenced vertices
    version: int  #: scene version of the mesh's last change (its source's, for an instance)
    mask: int = ALL_MASKS  #: uint32; a ray sees the mesh where ray mask & mask != 0
    transform: np.ndarray | None = None  #: (4, 4) float64 read-only row-major; None: identity
    instance_of: str | None = None  #: the source mesh whose Geometry this instance shares
    reflectivity: float = DEFAULT_REFLECTIVITY  #: in [0, 1]: a lidar's intensity of its hits
    label: int = DEFAULT_LABEL  #: uint32: a semantic class, the label of a lidar's points
    #: (4, 4) float64 read-only: the placement at the end of the frame's interval; None: static
    transform_end: np.ndarray | None = None
    #: (V, 3) float32 read-only: the vertices at the end of the frame's interval; None: static
    vertices_end: np.ndarray | None = None

    @property
    def vertices(self) -> np.ndarray:
        """(V, 3) float32 as uploaded (before ``transform``)."""
        return self.geometry.vertices

    @property
    def faces(self) -> np.ndarray:
        return self.geometry.faces

    @property
    def n_triangles(self) -> int:
        return len(self.geometry.faces)

    @property
    def nbytes(self) -> int:
        """Bytes of the mesh's arrays (an instance's are its source's: see Snapshot.nbytes)."""
        return self.geometry.nbytes

    def info(self, scene: str) -> dict[str, Any]:
        """Mesh info JSON of API.md, with the mesh's mask, transform and source."""
        return {
            "scene": scene,
            "mesh": self.name,
            "index": self.index,
            "vertices": len(self.vertices),
            "triangles": self.n_triangles,
            "bounds": json_ready(self.bounds),
            "version": self.version,
            "mask": self.mask,
            "transform": (IDENTITY if self.transform is None else self.transform).tolist(),
            "transform_end": None if self.transform_end is None else self.transform_end.tolist(),
            # How many end positions the mesh has (its vertices'), or None: it does not deform.
            "vertices_end": None if self.vertices_end is None else len(self.vertices_end),
            "instance_of": self.instance_of,
            "reflectivity": self.reflectivity,
            "label": self.label,
        }


def placed(mesh: Mesh) -> Mesh:
    """``mesh`` with bounds of its geometry as its transform places it (and its transform_end:
    the box of both); 422 if a transform places a vertex beyond the float32 range (the engine
    could not trace it)."""
    if mesh.transform is not None:
        mesh.geometry.check_placeable(mesh.transform, f"transform of mesh {mesh.name!r}")
    bounds = mesh.geometry.placed_bounds(mesh.transform)
    if mesh.transform_end is not None:
        name = f"transform_end of mesh {mesh.name!r}"
        mesh.geometry.check_placeable(mesh.transform_end, name)
        end = mesh.geometry.placed_bounds(mesh.transform_end)
        bounds = np.stack([np.minimum(bounds[0], end[0]), np.maximum(bounds[1], end[1])])
    if mesh.vertices_end is not None:
        end = referenced_bounds(mesh.vertices_end, mesh.faces)
        bounds = np.stack([np.minimum(bounds[0], end[0]), np.maximum(bounds[1], end[1])])
    return replace(mesh, bounds=bounds)


def check_deforming(mesh: Mesh) -> Mesh:
    """``mesh``, or 422 naming ``MESH.vertices_end`` where its end vertices do not fit it: as
    many as its vertices, on a mesh of its own with no placement (the engine deforms meshes
    given in scene space)."""
    if mesh.vertices_end is None:
        return mesh
    name = f"{mesh.name}.vertices_end"
    if mesh.instance_of is not None:
        raise Invalid(f"{name}: mesh {mesh.name!r} is an instance; an instance cannot deform")
    if mesh.transform is not None or mesh.transform_end is not None:
        raise Invalid(
            f"{name}: mesh {mesh.name!r} is placed by a transform; a deforming mesh takes its "
            "vertices in scene space, with no transform"
        )
    if len(mesh.vertices_end) != len(mesh.vertices):
        raise Invalid(
            f"{name} has {len(mesh.vertices_end)} rows; mesh {mesh.name!r} has "
            f"{len(mesh.vertices)} vertices"
        )
    return mesh


def new_mesh(
    name: str,
    arrays: MeshArrays,
    index: int = -1,
    version: int = 0,
    mask: int = ALL_MASKS,
    transform: np.ndarray | None = None,
) -> Mesh:
    """A Mesh owning copies of checked arrays; ``index`` and ``version`` are set by the store."""
    geometry = new_geometry(arrays)
    return placed(Mesh(name, index, geometry, geometry.bounds, version, mask, transform))


@dataclass(frozen=True)
class Snapshot:
    """One version of a scene. Immutable, except a cache of things derived from it."""

    scene: str
    version: int
    meshes: Mapping[str, Mesh]  #: by name, in index order
    next_index: int  #: the index the next new mesh gets (indices are never reused)
    _cache: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)
    _cache_lock: threading.Lock = field(default_factory=threading.Lock, compare=False, repr=False)
    #: the latest earlier version with something cached, whose derived things this version's may
    #: be made from (``earlier``); held until this version caches its own
    _earlier: list[Snapshot] = field(default_factory=list, compare=False, repr=False)

    @functools.cached_property
    def n_triangles(self) -> int:
        """Placed triangles: an instance's count as many as its source's (a version's meshes do
        not change; every query's budget reads it)."""
        return sum(m.n_triangles for m in self.meshes.values())

    @property
    def array_bytes(self) -> int:
        """Bytes of vertices and faces held, each array once however many meshes share it."""
        arrays = {id(a): a.nbytes for m in self.meshes.values() for a in (m.vertices, m.faces)}
        return sum(arrays.values())

    @property
    def nbytes(self) -> int:
        """Bytes the version holds once queried: its arrays, and the engine's scene of every
        placed triangle (an instance's again), footprint.TRIANGLE_BYTES each at the most, and
        POINT_TRIANGLE_BYTES more once point queries have placed them."""
        return self.array_bytes + self.n_triangles * (TRIANGLE_BYTES + POINT_TRIANGLE_BYTES)

    @property
    def held_bytes(self) -> int:
        """Bytes the version holds now: its arrays, and the engine's scene if one was built;
        with those of the earlier version it keeps until its own engine scene is built
        (``_earlier``), each array and engine scene once."""
        versions = [self, *self._earlier]
        arrays = {
            id(a): a.nbytes
            for version in versions
            for m in version.meshes.values()
            for a in (m.vertices, m.faces)
        }
        engines = [version._cache.get("dacrt") for version in versions]
        scenes = {id(e.scene): e.scene.nbytes for e in engines if e is not None}
        return sum(arrays.values()) + sum(scenes.values())

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

    def instances_of(self, name: str) -> list[str]:
        """The names of the instances of mesh ``name``, in index order."""
        return [m.name for m in self.meshes.values() if m.instance_of == name]

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
                self._earlier.clear()  # this version's own is built: the earlier one may go
            return self._cache[key]

    def built(self, key: str) -> Any | None:
        """What the snapshot cached under ``key``, or None where it is not built yet."""
        return self._cache.get(key)

    def earlier(self, key: str) -> tuple[Snapshot, Any] | None:
        """An earlier version of the scene and what it cached under ``key`` (e.g. its engine
        scene, for this version's to reuse what did not change), or None."""
        for earlier in self._earlier:
            if key in earlier._cache:
                return earlier, earlier._cache[key]
        return None

    def _basis(self) -> list[Snapshot]:
        """What a next version keeps as its ``_earlier``: this version if it cached something,
        else this version's own earlier one."""
        return [self] if self._cache else list(self._earlier)


class Store:
    """All scenes of the service, with the limits on their size."""

    def __init__(
        self,
        max_triangles_per_scene: int,
        max_scene_bytes: int,
        journal: DataDir | None = None,
        max_meshes_per_scene: int = 4096,
    ) -> None:
        self.max_triangles_per_scene = max_triangles_per_scene
        self.max_meshes_per_scene = max_meshes_per_scene
        self.max_scene_bytes = max_scene_bytes
        self.journal = journal  #: where each version is made durable before it is served
        self._scenes: dict[str, Snapshot] = {}
        self._last_version: dict[str, int] = {}  # kept after a delete: versions never go back
        self._nbytes = 0
        self._lock = threading.Lock()

    # ---- reading: lock-free, one dict lookup of an immutable snapshot

    @property
    def nbytes(self) -> int:
        """Bytes all scenes may hold once queried (``Snapshot.nbytes``): what
        DACRT_MAX_SCENE_BYTES bounds."""
        return self._nbytes

    def held_bytes(self) -> int:
        """Bytes all scenes hold now (``Snapshot.held_bytes``), for /metrics."""
        return sum(snapshot.held_bytes for snapshot in self.snapshots())

    def snapshot(self, scene: str) -> Snapshot:
        """The current version of a scene (404 if there is none)."""
        snapshot = self._scenes.get(scene)
        if snapshot is None:
            raise NotFound(f"no scene {scene!r}; create it with PUT /v1/scenes/{scene}/meshes/MESH")
        return snapshot

    def snapshots(self) -> list[Snapshot]:
        return [self._scenes[name] for name in sorted(self._scenes.copy())]

    # ---- changing: each builds a new snapshot under the lock, then swaps it in

    def put_mesh(
        self, scene: str, name: str, arrays: MeshArrays, mask: int | None = None
    ) -> tuple[Mesh, bool]:
        """Add or replace a mesh (creating the scene); answers (mesh, created). A replaced mesh
        keeps its transform, and its mask unless ``mask`` is given; it is no longer an instance,
        and it is static (new start vertices without an end: ``_changed``)."""
        check_name("scene", scene), check_name("mesh", name)
        geometry = new_geometry(arrays)
        with self._lock:
            old = self._scenes.get(scene)
            before = old.meshes.get(name) if old is not None else None
            mesh = self._changed(before, name, mask=mask, geometry=geometry, instance_of=None)
            snapshot = self._commit(scene, old, {name: mesh})
            return snapshot.meshes[name], before is None

    def put_instance(
        self,
        scene: str,
        name: str,
        source: str,
        transform: np.ndarray | None = None,
        mask: int | None = None,
    ) -> tuple[Mesh, bool]:
        """Add or replace mesh ``name`` as an instance of mesh ``source`` of the same scene,
        sharing its arrays; answers (mesh, created). ``transform`` (checked, (4, 4)) and
        ``mask`` are the instance's own: a replaced mesh keeps its own where they are None, and
        it is static (new start vertices without an end: ``_changed``)."""
        check_name("scene", scene), check_name("mesh", name), check_name("mesh", source)
        with self._lock:
            old = self.snapshot(scene)
            before = old.meshes.get(name)
            mesh = self._changed(before, name, transform, mask, instance_of=source)
            snapshot = self._commit(scene, old, {name: mesh})
            return snapshot.meshes[name], before is None

    def update_vertices(self, scene: str, name: str, vertices: np.ndarray) -> Mesh:
        """New positions for a mesh's vertices, same count; faces, mask and transform are kept,
        and the mesh is static again (409 on a count change or for an instance)."""
        with self._lock:
            old = self.snapshot(scene)
            before = old.mesh(name)
            mesh = self._changed(before, name, geometry=self._moved(before, vertices, old.scene))
            return self._commit(scene, old, {name: mesh}).meshes[name]

    def set_transform(self, scene: str, name: str, transform: np.ndarray | None) -> Mesh:
        """Place a mesh by a checked (4, 4) matrix (None: the identity); its arrays are kept, and
        it is static again (no transform_end), as after a frame that places it."""
        with self._lock:
            old = self.snapshot(scene)
            matrix = IDENTITY if transform is None else transform
            mesh = self._changed(old.mesh(name), name, transform=matrix)
            return self._commit(scene, old, {name: mesh}).meshes[name]

    def set_mask(self, scene: str, name: str, mask: int) -> Mesh:
        """Set a mesh's visibility mask (a checked uint32); everything else is kept."""
        with self._lock:
            old = self.snapshot(scene)
            mesh = self._changed(old.mesh(name), name, mask=mask)
            return self._commit(scene, old, {name: mesh}).meshes[name]

    def set_material(
        self, scene: str, name: str, reflectivity: float | None, label: int | None
    ) -> Mesh:
        """Set a mesh's reflectivity and label (checked; None keeps one); the rest is kept."""
        with self._lock:
            old = self.snapshot(scene)
            mesh = self._changed(old.mesh(name), name, material=Material(reflectivity, label))
            return self._commit(scene, old, {name: mesh}).meshes[name]

    def apply_frame(
        self,
        scene: str,
        changes: Mapping[str, FrameChange | tuple[np.ndarray, np.ndarray | None]],
    ) -> Snapshot:
        """Change several meshes in one version (``wire.FrameChange``, or a (vertices, faces)
        pair): vertices with faces add or replace a mesh, vertices alone move an existing mesh's
        vertices, ``instance_of`` makes the mesh an instance, and ``transform`` and ``mask`` set
        its placement and mask (kept where not given); ``transform_end`` and ``vertices_end`` set
        its placement and vertices at the interval's end (an end alone keeps the start), and a
        new start (``transform``, ``vertices`` or ``instance_of``) without an end makes the mesh
        static again (``_changed``)."""
        check_name("scene", scene)
        self._check_mesh_count(scene, len(changes))  # before a mesh is built
        changes = {name: FrameChange(*change) for name, change in changes.items()}
        for name in changes:
            check_name("mesh", name)
        added = {
            name: new_geometry(MeshArrays(change.vertices, change.faces))
            for name, change in changes.items()
            if change.faces is not None
        }
        with self._lock:
            old = self._scenes.get(scene)
            meshes: dict[str, Mesh] = {}
            for name, change in changes.items():
                before = old.meshes.get(name) if old is not None else None
                # an end not given is kept, or dropped by a new start (``_changed``)
                end = ... if change.transform_end is None else change.transform_end
                vertices_end = ... if change.vertices_end is None else change.vertices_end
                material = Material(change.reflectivity, change.label)
                if name in added:
                    meshes[name] = self._changed(
                        before,
                        name,
                        change.transform,
                        change.mask,
                        added[name],
                        None,
                        material,
                        transform_end=end,
                        vertices_end=vertices_end,
                    )
                elif change.instance_of is not None:
                    meshes[name] = self._changed(
                        before,
                        name,
                        change.transform,
                        change.mask,
                        instance_of=change.instance_of,
                        material=material,
                        transform_end=end,
                        vertices_end=vertices_end,
                    )
                elif before is None:
                    raise NotFound(
                        f"no mesh {name!r} in scene {scene!r}, so the frame's {name}.* keys "
                        f"have nothing to change; send {name}.vertices and {name}.faces (or "
                        f"{name}.instance_of) to create it"
                    )
                else:
                    moved = None
                    if change.vertices is not None:
                        moved = self._moved(before, change.vertices, scene)
                    meshes[name] = self._changed(
                        before,
                        name,
                        change.transform,
                        change.mask,
                        moved,
                        material=material,
                        transform_end=end,
                        vertices_end=vertices_end,
                    )
            return self._commit(scene, old, meshes)

    def restore(self, snapshots: list[Snapshot], last_versions: Mapping[str, int]) -> None:
        """Serve ``snapshots`` (read back from the journal) and continue after ``last_versions``
        (limits are not checked: the scenes were accepted when they were made)."""
        with self._lock:
            for snapshot in snapshots:
                old = self._scenes.get(snapshot.scene)
                self._nbytes += snapshot.nbytes - (old.nbytes if old is not None else 0)
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
        """Delete a mesh (409 naming its instances while it has any)."""
        with self._lock:
            old = self.snapshot(scene)
            old.mesh(name)
            return self._commit(scene, old, {name: None})

    # ---- helpers, called with the lock held

    @staticmethod
    def _changed(
        before: Mesh | None,
        name: str,
        transform: np.ndarray | None = None,
        mask: int | None = None,
        geometry: Geometry | None = None,
        instance_of: str | None = ...,  # type: ignore[assignment]
        material: Material = NO_MATERIAL,
        transform_end: np.ndarray | None = ...,  # type: ignore[assignment]
        vertices_end: np.ndarray | None = ...,  # type: ignore[assignment]
    ) -> Mesh:
        """``before`` (or a new mesh) with what is given changed; ``instance_of=None`` makes it a
        mesh of its own, ``transform_end=None`` or ``vertices_end=None`` static, ``...`` keeps
        what it was (422 where end vertices do not fit the mesh: ``check_deforming``). An
        instance's geometry is linked by ``_commit``.

        A new start (a transform, vertices or an instance's source) drops every end not given
        with it: a mesh given a new start and no end is static."""
        if before is None:
            before = Mesh(name, -1, geometry or EMPTY, EMPTY.bounds, 0)
        if transform is not None or geometry is not None or instance_of is not ...:
            transform_end = None if transform_end is ... else transform_end
            vertices_end = None if vertices_end is ... else vertices_end
        changes: dict[str, Any] = {}
        if transform is not None:
            changes["transform"] = owned_transform(transform)
        if mask is not None:
            changes["mask"] = int(mask)
        if geometry is not None:
            changes["geometry"] = geometry
        if instance_of is not ...:
            changes["instance_of"] = instance_of
        if material.reflectivity is not None:
            changes["reflectivity"] = float(material.reflectivity)
        if material.label is not None:
            changes["label"] = int(material.label)
        if transform_end is not ... and not _same_end(before.transform_end, transform_end):
            changes["transform_end"] = (
                None if transform_end is None else _owned(transform_end, "<f8")
            )
        if vertices_end is not ... and not (vertices_end is None and before.vertices_end is None):
            changes["vertices_end"] = None if vertices_end is None else _owned(vertices_end, "<f4")
        return placed(check_deforming(replace(before, **changes))) if changes else before

    @staticmethod
    def _moved(mesh: Mesh, vertices: np.ndarray, scene: str) -> Geometry:
        """The mesh's geometry with new vertices (409 for an instance or another count)."""
        if mesh.instance_of is not None:
            raise Conflict(
                f"mesh {mesh.name!r} of scene {scene!r} is an instance of {mesh.instance_of!r}, "
                f"whose vertices it shares; move {mesh.instance_of!r}'s vertices (every instance "
                "follows), place this instance with its transform, or PUT it vertices and faces "
                "of its own"
            )
        if len(vertices) != len(mesh.vertices):
            raise Conflict(
                f"mesh {mesh.name!r} of scene {scene!r} has {len(mesh.vertices)} vertices "
                f"but the update has {len(vertices)}; to change the vertex count, "
                f"PUT the whole mesh to /v1/scenes/{scene}/meshes/{mesh.name}"
            )
        vertices = _owned(vertices, "<f4")
        return Geometry(vertices, mesh.faces, referenced_bounds(vertices, mesh.faces))

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
            elif next_index > MAX_INDEX:
                raise TooLarge(
                    f"scene {scene!r} has given out every mesh index (0 to {MAX_INDEX}, never "
                    f"reused), so it cannot take mesh {name!r}; delete the scene and make it again"
                )
            else:
                index, next_index = next_index, next_index + 1
            meshes[name] = replace(mesh, index=index, version=version)
        self._check_mesh_count(scene, len(meshes))
        _link_instances(scene, meshes, [n for n, m in changes.items() if m is not None], version)
        meshes = dict(sorted(meshes.items(), key=lambda item: item[1].index))
        snapshot = Snapshot(scene, version, MappingProxyType(meshes), next_index)
        if old is not None and _same_faces(old.meshes, meshes):
            # the new version's engine scene can be the old one's changed: hold it until then
            snapshot._earlier.extend(old._basis())
        if snapshot.n_triangles > self.max_triangles_per_scene:
            raise TooLarge(
                f"scene {scene!r} would hold {snapshot.n_triangles} triangles, over the limit "
                f"of {self.max_triangles_per_scene} (DACRT_MAX_TRIANGLES_PER_SCENE; an "
                "instance counts its source's triangles again)"
            )
        nbytes = self._nbytes - (old.nbytes if old else 0) + snapshot.nbytes
        if nbytes > self.max_scene_bytes:
            raise TooLarge(
                f"scenes would hold {nbytes} bytes (vertices and faces, and the engine's "
                f"{TRIANGLE_BYTES + POINT_TRIANGLE_BYTES} bytes a placed triangle), over the "
                f"limit of {self.max_scene_bytes} bytes (DACRT_MAX_SCENE_BYTES)"
            )
        if self.journal is not None:
            self._last_version[scene] = version  # a failed write still uses up its version
            self.journal.write(snapshot)
        self._scenes[scene] = snapshot
        self._last_version[scene] = version
        self._nbytes = nbytes
        return snapshot

    def _check_mesh_count(self, scene: str, count: int) -> None:
        """413 for a scene of more than DACRT_MAX_MESHES_PER_SCENE meshes."""
        if count > self.max_meshes_per_scene:
            raise TooLarge(
                f"scene {scene!r} would hold {count} meshes, over the limit of "
                f"{self.max_meshes_per_scene} (DACRT_MAX_MESHES_PER_SCENE; an instance is a mesh)"
            )


def _same_faces(old: Mapping[str, Mesh], new: Mapping[str, Mesh]) -> bool:
    """Whether two versions' meshes with triangles are the same meshes (indices, in order) with
    the same faces, so that one's engine scene can be changed into the other's
    (``tracing.changed_engine_scene``): only then is an earlier version worth holding."""
    before = [(m.index, m.faces) for m in old.values() if len(m.faces)]
    after = [(m.index, m.faces) for m in new.values() if len(m.faces)]
    return len(before) == len(after) and all(
        a[0] == b[0] and a[1] is b[1] for a, b in zip(before, after)
    )


EMPTY = new_geometry(MeshArrays(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)))


def _link_instances(scene: str, meshes: dict[str, Mesh], changed: Iterable[str], version: int):
    """Give every instance in ``meshes`` its source's geometry, in place.

    A changed instance naming an instance is linked to that instance's own source (404 if there
    is none). An instance whose source is gone, or has become an instance itself, is 409.
    """
    for name in changed:
        mesh = meshes[name]
        if mesh.instance_of is None:
            continue
        source, chain, seen = mesh.instance_of, [name], {name}
        while (
            source not in seen
            and (target := meshes.get(source)) is not None
            and target.instance_of is not None
        ):
            chain.append(source)
            seen.add(source)
            source = target.instance_of
        if source in seen:
            raise Invalid(
                f"mesh {name!r} of scene {scene!r} cannot be an instance of itself"
                if len(chain) == 1
                else f"meshes {chain} of scene {scene!r} would be instances of each other"
            )
        if source not in meshes:
            raise NotFound(
                f"scene {scene!r} has no mesh {source!r} for {name!r} to be an instance of; "
                f"it has {sorted(n for n in meshes if n != name) or 'none'}"
            )
        # every instance on the way links to the same source, so no chain is walked twice
        if mesh.instance_of != source:
            meshes[name] = replace(mesh, instance_of=source)
        for link in chain[1:]:
            if meshes[link].instance_of != source:
                meshes[link] = replace(meshes[link], instance_of=source)
    orphans: dict[str, list[str]] = {}
    for name, mesh in meshes.items():
        if mesh.instance_of is None:
            continue
        source = meshes.get(mesh.instance_of)
        if source is None or source.instance_of is not None:
            orphans.setdefault(mesh.instance_of, []).append(name)
        elif mesh.geometry is not source.geometry:
            meshes[name] = placed(replace(mesh, geometry=source.geometry, version=version))
    for source, names in orphans.items():
        change = (
            "be deleted"
            if source not in meshes
            else f"become an instance of {meshes[source].instance_of!r}"
        )
        raise Conflict(
            f"mesh {source!r} of scene {scene!r} has instances {names}, so it cannot {change}; "
            "delete them first, or PUT them vertices and faces of their own"
        )
