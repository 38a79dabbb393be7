"""The data folder: every committed scene version, and every scan pattern, written to
DACRT_DATA_DIR before it is acknowledged, and read back on start.

Layout, one folder per scene (scene names are safe file names), and the patterns::

    DATA_DIR/scenes/SCENE/scene.VERSION.json             the manifest: the commit point of a version
    DATA_DIR/scenes/SCENE/INDEX.VERSION.vertices.npy     (V, 3) float32, written at VERSION
    DATA_DIR/scenes/SCENE/INDEX.VERSION.faces.npy        (F, 3) int32, written at VERSION
    DATA_DIR/scenes/SCENE/INDEX.VERSION.vertices_end.npy (V, 3) float32: a deforming mesh's end
    DATA_DIR/patterns/NAME.npz                           a scan pattern (``Pattern.save``)
    DATA_DIR/lock                                        the serving process's pid and host

An instance has no array files: its manifest entry names its source (``instance_of``) and is
restored sharing the source's arrays. Each entry also holds the mesh's ``mask``, its material
(``reflectivity``, ``label``; read with the defaults where absent) and, unless it is the identity,
its ``transform`` and its ``transform_end`` (16 numbers each, row-major, exact in JSON): values of
a fixed size, so a mask, material or transform change writes only a manifest of a few hundred
bytes a mesh. Manifests of format 1 (without these) are read with the defaults; end vertices
that a manifest holds as rows of numbers (the form older folders hold) are read, and get their
file at the scene's next change.

Every file is written to ``NAME.tmp``, fsynced, renamed to ``NAME``, and its folder fsynced. A
version's arrays are durable before its manifest is written, so a manifest only names complete
files; a change writes only the arrays it changes (a vertices update: one ``.npy`` and the
manifest, never the faces). The newest manifest's number is the scene's last version, even when
its content cannot be read, so versions are never reused; a deleted scene keeps a manifest
``{"deleted": true}`` for that reason. A manifest names each array's shape and CRC-32: a
truncated or corrupted file is reported in the log and its scene skipped, never loaded. So is a
scene whose manifest holds what a change through the API is refused for: ``_read_scene`` applies
the same checks (finite vertices, faces within them, end vertices only on an unplaced mesh of its
own and as many as its vertices, an instance's source a mesh of its own, an index within int32).

A folder that cannot be written is refused at start (a probe file is created, fsynced and
removed), unless it is only full: then the service starts and serves what it holds. A change
that fails (a full disk, a read-only or failing file system) removes what it wrote, changes
nothing in memory and raises ``InsufficientStorage`` (507: ENOSPC, EDQUOT) or
``DataDirUnavailable`` (503: any other OS error) naming the folder and the OS error; the folder's
``fault`` says why until a change succeeds again. A change that fails after its commit point (the
folder's fsync after a rename) and cannot be undone either leaves the folder holding what cannot be
confirmed: the change may or may not be there after a restart, the error says so, and the folder
takes no more changes until the service restarts (``stopped``). Temporary files left by a crash
are removed at start; entries that are not a scene's or a pattern's are logged and left alone.

One process serves a folder: ``lock_folder`` holds an exclusive ``flock`` on ``DATA_DIR`` itself
and one on ``DATA_DIR/lock`` for as long as the folder is open, and a second server on the folder
is refused before it reads or writes a scene or a pattern, also when the file ``lock`` was
removed (the folder's own lock holds; the file names the holder, and on NFS locks it for the
other hosts). The OS releases the locks when the process ends, however it ends (kill -9
included), so a stale lock needs no cleanup.
"""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import re
import socket
from collections.abc import Callable, Iterator, Mapping
from contextlib import suppress
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from types import MappingProxyType
from typing import Any, BinaryIO

import numpy as np

from dacrt import InputError
from dacrt.sensors import Pattern
from dacrt.sensors.physics import DEFAULT_LABEL
from dacrt.sensors.physics import DEFAULT_REFLECTIVITY as REFLECTIVITY

try:
    from isal.isal_zlib import crc32
except ImportError:  # pragma: no cover - isal is a dependency; zlib gives the same checksums
    from zlib import crc32

from .errors import DataDirUnavailable, InsufficientStorage, Invalid
from .store import (
    MAX_INDEX,
    Geometry,
    Mesh,
    Snapshot,
    check_deforming,
    check_name,
    owned_transform,
    placed,
    referenced_bounds,
)
from .wire import (
    check_matrix,
    check_vertices,
    float_array,
    parse_label,
    parse_mask,
    parse_reflectivity,
)

log = logging.getLogger("service")

MANIFEST = re.compile(r"scene\.([0-9]+)\.json")
TEMPORARY = ".tmp"
FORMAT = 2  #: the manifest format this module writes
READ_FORMATS = (1, 2)  #: the manifest formats it reads (1: no masks, transforms or instances)
PROBE = ".write-probe"  #: written (through PROBE.tmp) and removed at start to check the folder
FULL = frozenset({errno.ENOSPC, errno.EDQUOT})  #: OS errors that mean "full": 507, not 503
LOCK = "lock"  #: locked (flock) by the process serving the folder, and naming it
LAST = f"{MAX_INDEX}, the last mesh index (a hit's mesh is int32)"  #: what bounds an index


@dataclass(frozen=True)
class ArrayFile:
    """One array's file, as its manifest names it."""

    name: str
    shape: tuple[int, ...]
    crc32: int


class CorruptScene(Exception):
    """A scene's files cannot be read back as the manifest describes them."""


@dataclass(frozen=True)
class Restored:
    """What a data folder holds: the scenes to serve and every scene's last version."""

    snapshots: list[Snapshot]
    last_versions: dict[str, int]


#: A mesh's array files by kind (``vertices``, ``faces`` and, for a deforming mesh,
#: ``vertices_end``); none for an instance.
MeshFiles = Mapping[str, ArrayFile]


def write_file(path: Path, write) -> None:
    """``write(file)`` into ``path`` atomically: a temporary file, fsync, rename (the folder is
    fsynced by the caller, once for all the files of a change). On failure the temporary file is
    removed and ``path`` is untouched."""
    temporary = path.with_name(path.name + TEMPORARY)
    try:
        with open(temporary, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except BaseException:
        with suppress(OSError):  # a file system that failed the write may fail this too
            temporary.unlink(missing_ok=True)
        raise


def sync_folder(folder: Path) -> None:
    """Make the folder's entries (new names, renames) durable."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _transform(value: Any) -> np.ndarray | None:
    """A manifest's transform (16 numbers as 4 rows, or absent: the identity), checked."""
    return None if value is None else check_matrix(value, "transform")


def _transform_end(value: Any) -> np.ndarray | None:
    """A manifest's end placement (absent: static), checked, read-only."""
    if value is None:
        return None
    matrix = check_matrix(value, "transform_end")
    matrix.setflags(write=False)
    return matrix


def _inline_vertices_end(value: Any) -> np.ndarray:
    """End vertices given in the manifest as rows of numbers (the form older folders hold),
    checked, read-only."""
    vertices = check_vertices(float_array(value, "vertices_end", 3), "vertices_end")
    vertices.setflags(write=False)
    return vertices


def _arrays(mesh: Mesh) -> Iterator[tuple[str, np.ndarray]]:
    """The arrays that a mesh's files hold, by kind; none for an instance (its source's do)."""
    if mesh.instance_of is not None:
        return
    yield "vertices", mesh.vertices
    yield "faces", mesh.faces
    if mesh.vertices_end is not None:
        yield "vertices_end", mesh.vertices_end


def _count(value: Any, key: str, path: Path, at_most: int, limit: str) -> int:
    """A manifest's index or version: an int in [0, ``at_most``] (``limit`` names that bound);
    CorruptScene if not."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise CorruptScene(f"{path.name}: {key} is {value!r:.40}, not a count")
    if value > at_most:
        raise CorruptScene(f"{path.name}: {key} {value} is past {limit}")
    return value


def checksum(array: np.ndarray) -> int:
    # bytes viewed as uint8: a memoryview of an empty array cannot be cast
    return crc32(np.ascontiguousarray(array).reshape(-1).view(np.uint8))


def os_error_text(exc: OSError) -> str:
    """``[Errno 28] No space left on device``: the OS error without the file it names."""
    return f"[Errno {exc.errno}] {exc.strerror}" if exc.strerror else str(exc)


def write_npy(file, array: np.ndarray) -> None:
    """``np.save``'s bytes, the data written through ``file`` (np.save's own ``tofile`` reports
    a full disk as a short write without an errno, which would read as another fault)."""
    np.lib.format.write_array_header_1_0(file, np.lib.format.header_data_from_array_1_0(array))
    file.write(np.ascontiguousarray(array).reshape(-1).view(np.uint8).data)


def errno_name(exc: OSError) -> str:
    """``ENOSPC``: the symbolic name of an OS error's number (``unknown`` without one)."""
    return errno.errorcode.get(exc.errno, "unknown") if exc.errno is not None else "unknown"


class FolderLocked(Exception):
    """The data folder cannot be locked for this process: another process holds its lock, or its
    file system has no ``flock`` (the message says which, in one line)."""


class FolderLock:
    """The locks that hold a data folder for this process, until ``close``: an exclusive
    ``flock`` on the folder itself, and one on its file ``lock``, which names the process."""

    def __init__(self, folder: int, file: BinaryIO) -> None:
        self.folder = folder  #: the folder, open read-only
        self.file = file  #: the file ``lock``

    def close(self) -> None:
        self.file.close()
        os.close(self.folder)


def lock_folder(root: Path) -> FolderLock:
    """Lock ``root`` (created if needed) for this process: an exclusive ``flock`` on the folder
    itself, which cannot be removed while it holds files (the file ``lock`` can be, and a lock
    on that alone would then let a second server in), and one on ``root/lock`` (created if
    needed; on NFS the folder's flock holds for this host only, the file's for every host), with
    this process's pid and host written in it. FolderLocked if another process holds either lock
    or the file system cannot lock; OSError if the folder or the file cannot be created."""
    root.mkdir(parents=True, exist_ok=True)
    path = root / LOCK
    folder = os.open(root, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        try:
            fcntl.flock(folder, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            raise _refusal(exc, root, path) from None
        file = _locked_file(path)
    except BaseException:
        os.close(folder)
        raise
    # not truncated first: a full disk keeps the block the last holder's name used
    with suppress(OSError), open(path, "r+b") as name:  # full or read-only: the probe says so
        name.write(f"pid {os.getpid()} on {socket.gethostname()}\n".encode())
        name.truncate()
    return FolderLock(folder, file)


def _locked_file(path: Path) -> BinaryIO:
    """``path`` (created if needed), open and locked (``flock``) by this process."""
    # read-only: a file held open for writing keeps its disk from being remounted read-only
    file = _open(path, os.O_RDONLY)
    try:
        try:
            fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno != errno.EBADF:
                raise
            file.close()
            file = _open(path, os.O_RDWR)  # NFS locks only a file open for writing
            fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        file.close()
        raise _refusal(exc, path, path) from None
    return file


def _refusal(exc: OSError, locked: Path, names: Path) -> FolderLocked:
    """Why ``flock`` on ``locked`` failed: another process holds it (named by the file ``names``
    where it is there) or the file system cannot lock."""
    if not isinstance(exc, BlockingIOError):
        return FolderLocked(
            f"the data folder cannot be locked (flock on {locked}): {os_error_text(exc)}"
        )
    holder = ""
    with suppress(OSError):  # removed: the folder's lock holds without it
        holder = " ".join(names.read_bytes()[:200].decode(errors="replace").split())
    return FolderLocked(
        f"the data folder is in use by {holder or 'another process'}, which holds "
        f"{names if holder else locked}: a data folder serves one server at a time"
    )


def _open(path: Path, mode: int) -> BinaryIO:
    """``path`` opened with ``mode`` (os.O_RDONLY, os.O_RDWR), created if missing."""
    return open(os.open(path, mode | os.O_CREAT | os.O_CLOEXEC, 0o644), "rb", buffering=0)


@dataclass(frozen=True)
class Fault:
    """Why the data folder cannot be written, as the last failed change found it."""

    errno: str  #: the OS error's name, e.g. ``ENOSPC``
    detail: str  #: the message the change's caller read


class DataDir:
    """The scenes' files under ``root``. Changes are called by the store under its lock.

    Opening checks that ``root`` can be written (OSError if not), except that a full folder is
    opened with its ``fault`` set: reads are served, changes answer 507 until space returns.
    ``lock`` holds the folder for this process (``lock_folder``) until ``close``.
    """

    def __init__(self, root: Path, lock: FolderLock | None = None) -> None:
        self.root = Path(root)
        self.lock = lock
        self.scenes = self.root / "scenes"
        self.patterns = self.root / "patterns"
        self.scenes.mkdir(parents=True, exist_ok=True)
        self.patterns.mkdir(exist_ok=True)
        sync_folder(self.root)
        #: scene -> mesh name -> its array files in the current version
        self._files: dict[str, dict[str, MeshFiles]] = {}
        self._current: dict[str, Snapshot] = {}  #: the snapshot each scene's files hold
        #: the version of each deleted scene's manifest ``{"deleted": true}``, removed once the
        #: scene is made again (its next manifest keeps the versions from being reused)
        self._deleted: dict[str, int] = {}
        #: why the last change failed, until one succeeds: None while the folder takes writes
        self.fault: Fault | None = None
        #: failed changes by OS error name (``ENOSPC``...), since start
        self.errors: dict[str, int] = {}
        #: why changes are refused until a restart (a failed change could not be undone), or None
        self.stopped: str | None = None
        try:
            self._probe()
        except OSError as exc:
            if exc.errno not in FULL:
                raise
            self._failed(exc, [])
            log.warning("data: %s is full at start: reads are served, changes answer 507", root)

    def close(self) -> None:
        """Release the folder's lock: another server may open it."""
        if self.lock is not None:
            self.lock.close()

    def _probe(self) -> None:
        """Create, fsync and remove a file in ``root``: OSError unless the folder takes writes
        (a read-only mount, no permission, a failing disk)."""
        path = self.root / PROBE
        write_file(path, lambda file: file.write(b"dacrt"))
        path.unlink()
        sync_folder(self.root)

    # ---- writing

    def write(self, snapshot: Snapshot) -> None:
        """Make ``snapshot`` durable: its new arrays, then its manifest (the commit point).
        On failure what it wrote is removed and InsufficientStorage/DataDirUnavailable raised."""
        self._check_open()
        old = self._current.get(snapshot.scene)
        old_files = self._files.get(snapshot.scene, {})
        created: list[Path] = []  # what to remove if the change fails
        try:
            folder = self._folder(snapshot.scene, created)
            files: dict[str, MeshFiles] = {}
            for name, mesh in snapshot.meshes.items():
                before = old.meshes.get(name) if old is not None else None
                kept = old_files.get(name, {}) if before is not None else {}
                files[name] = {}  # an instance's stay empty: its source's files hold its arrays
                for kind, array in _arrays(mesh):
                    if kind in kept and getattr(before, kind) is array:
                        files[name][kind] = kept[kind]  # unchanged: its file stands
                    else:
                        files[name][kind] = self._write_array(
                            folder, mesh.index, kind, array, snapshot.version, created
                        )
            sync_folder(folder)  # the arrays' names are durable before a manifest names them
            record = self._manifest(snapshot, files)
            self._write_manifest(folder, snapshot.version, record, created)
        except OSError as exc:
            raise self._failed(exc, created) from None
        self.fault = None
        old_version = old.version if old is not None else self._deleted.pop(snapshot.scene, None)
        self._forget(folder, old_files, files, old_version, snapshot.version)
        self._files[snapshot.scene], self._current[snapshot.scene] = files, snapshot

    def delete(self, scene: str, version: int) -> None:
        """Mark ``scene`` deleted at ``version`` (its last), then remove its arrays. On failure
        its current manifest stands and InsufficientStorage/DataDirUnavailable is raised."""
        self._check_open()
        record = {"format": FORMAT, "scene": scene, "version": version, "deleted": True}
        old = self._current.get(scene)
        old_files = self._files.get(scene, {})
        created: list[Path] = []
        try:
            folder = self._folder(scene, created)
            self._write_manifest(folder, version, record, created)
        except OSError as exc:
            undo: Callable[[], None] | None = None
            replaced = old is not None and old.version == version  # the current manifest
            if replaced and created and created[-1].name == f"scene.{version}.json":
                # the record replaced the current manifest, then the folder's fsync failed
                created.pop()
                current = self._manifest(old, old_files)
                undo = lambda: self._write_manifest(folder, version, current, [])  # noqa: E731
            raise self._failed(exc, created, undo) from None
        self.fault = None
        self._files.pop(scene, None)
        self._current.pop(scene, None)
        self._deleted[scene] = version
        self._forget(folder, old_files, {}, None if old is None else old.version, version)

    def write_pattern(self, name: str, pattern: Pattern, old: Pattern | None) -> None:
        """Make pattern ``name`` durable, replacing ``old`` (None: a new one). On failure what
        it wrote is removed (or ``old`` written back) and InsufficientStorage/DataDirUnavailable
        raised."""
        self._check_open()
        path = self.patterns / f"{name}.npz"
        created: list[Path] = []
        undo: Callable[[], None] | None = None
        try:
            write_file(path, pattern.save)
            if old is None:
                created.append(path)
            else:
                undo = partial(self._put_back, path, old)
            sync_folder(self.patterns)
        except OSError as exc:
            raise self._failed(exc, created, undo) from None
        self.fault = None

    def delete_pattern(self, name: str, old: Pattern) -> None:
        """Remove pattern ``name`` (``old``, written back if the removal cannot be made
        durable); InsufficientStorage/DataDirUnavailable on failure."""
        self._check_open()
        path = self.patterns / f"{name}.npz"
        undo: Callable[[], None] | None = None
        try:
            path.unlink(missing_ok=True)
            undo = partial(self._put_back, path, old)
            sync_folder(self.patterns)
        except OSError as exc:
            raise self._failed(exc, [], undo) from None
        self.fault = None

    def _put_back(self, path: Path, pattern: Pattern) -> None:
        write_file(path, pattern.save)
        sync_folder(self.patterns)

    def _check_open(self) -> None:
        if self.stopped is not None:
            raise DataDirUnavailable(self.stopped)

    def _failed(
        self, exc: OSError, created: list[Path], undo: Callable[[], None] | None = None
    ) -> DataDirUnavailable:
        """Remove what a failed change wrote (``created``, newest first; or ``undo`` it), note
        the fault and count it: the error the change's caller gets. When that fails too, the
        folder's state is unknown and it is ``stopped``."""
        stuck: list[OSError] = []
        for path in reversed(created):
            try:
                path.rmdir() if path.is_dir() else path.unlink(missing_ok=True)
                sync_folder(path.parent)
            except OSError as cleanup:
                log.error("data: cannot remove %s after a failed change: %s", path, cleanup)
                stuck.append(cleanup)
        if undo is not None:
            try:
                undo()
            except OSError as cleanup:
                log.error("data: cannot undo a failed change: %s", cleanup)
                stuck.append(cleanup)
        name = errno_name(exc)
        kind = InsufficientStorage if exc.errno in FULL else DataDirUnavailable
        where = f"the data folder {self.root} (DACRT_DATA_DIR)"
        if stuck:
            self.stopped = (
                f"{where} failed during a change ({os_error_text(exc)}) and undoing it failed "
                f"too ({os_error_text(stuck[0])}): the change may or may not be there after a "
                "restart, and no change is taken until the service is restarted"
            )
            error = kind(self.stopped)
            log.critical("data: %s", self.stopped)
        else:
            error = kind(f"{where} cannot be written: {os_error_text(exc)}; nothing was changed")
        self.fault = Fault(name, error.detail)
        self.errors[name] = self.errors.get(name, 0) + 1
        log.error("data: cannot write in %s: %s (%s)", self.root, exc, name)
        return error

    def _folder(self, scene: str, created: list[Path]) -> Path:
        folder = self.scenes / scene
        if not folder.is_dir():
            folder.mkdir()
            created.append(folder)
            sync_folder(self.scenes)
        return folder

    @staticmethod
    def _write_array(
        folder: Path, index: int, kind: str, array: np.ndarray, version: int, created: list[Path]
    ) -> ArrayFile:
        name = f"{index}.{version}.{kind}.npy"
        write_file(folder / name, lambda file: write_npy(file, array))
        created.append(folder / name)
        return ArrayFile(name, array.shape, checksum(array))

    @staticmethod
    def _manifest(snapshot: Snapshot, files: dict[str, MeshFiles]) -> dict:
        def array(file: ArrayFile) -> dict[str, Any]:
            return {"file": file.name, "shape": list(file.shape), "crc32": file.crc32}

        def entry(mesh: Mesh) -> dict[str, Any]:
            record = {
                "name": mesh.name,
                "index": mesh.index,
                "version": mesh.version,
                "mask": mesh.mask,
                "reflectivity": mesh.reflectivity,
                "label": mesh.label,
            }
            if mesh.transform is not None:
                record["transform"] = mesh.transform.tolist()
            if mesh.transform_end is not None:
                record["transform_end"] = mesh.transform_end.tolist()
            if mesh.instance_of is not None:
                record["instance_of"] = mesh.instance_of
            for kind, file in files[mesh.name].items():
                record[kind] = array(file)
            return record

        return {
            "format": FORMAT,
            "scene": snapshot.scene,
            "version": snapshot.version,
            "next_index": snapshot.next_index,
            "meshes": [entry(mesh) for mesh in snapshot.meshes.values()],
        }

    @staticmethod
    def _write_manifest(
        folder: Path, version: int, record: dict[str, Any], created: list[Path]
    ) -> None:
        text = json.dumps(record, separators=(",", ":")).encode()
        write_file(folder / f"scene.{version}.json", lambda file: file.write(text))
        created.append(folder / f"scene.{version}.json")
        sync_folder(folder)

    @staticmethod
    def _forget(folder: Path, old_files, new_files, old_version: int | None, version: int) -> None:
        """Remove what the new manifest no longer names, the manifest of ``old_version`` (or
        None) included (a crash or a failure here leaves only orphans, removed at the next
        start: the change is made)."""
        kept = {file.name for mesh_files in new_files.values() for file in mesh_files.values()}
        names = {f.name for mesh_files in old_files.values() for f in mesh_files.values()} - kept
        if old_version is not None and old_version != version:
            names.add(f"scene.{old_version}.json")
        for name in names:
            try:
                (folder / name).unlink(missing_ok=True)
            except OSError as exc:
                log.warning("data: cannot remove %s, left for the next start: %s", name, exc)

    # ---- reading

    def restore(self) -> Restored:
        """Every scene's newest version; a scene whose files are damaged is logged and skipped.
        Temporary files are removed everywhere, and a scene folder without a manifest (its
        first change failed) once it is empty."""
        snapshots, last_versions = [], {}
        self._remove_temporary(self.root)
        (self.root / PROBE).unlink(missing_ok=True)  # renamed, then the start failed
        for folder in sorted(self.scenes.iterdir()):
            if not folder.is_dir():
                what = "a broken link" if folder.is_symlink() else "not a folder"
                log.warning("data: skipped scenes/%s: %s, not a scene", folder.name, what)
                continue
            self._remove_temporary(folder)
            manifests = sorted(self._manifests(folder), reverse=True)
            if not manifests:
                try:
                    folder.rmdir()
                except OSError:  # not empty: kept as it is, and never loaded
                    log.warning("data: skipped scenes/%s: it holds no manifest", folder.name)
                continue
            version, path = manifests[0]
            last_versions[folder.name] = version
            try:
                snapshot, files = self._read_scene(folder, path, version)
            except (CorruptScene, OSError, ValueError) as exc:
                log.error("data: skipped scene %r (version %d): %s", folder.name, version, exc)
                continue
            self._clean(folder, path, files)
            if snapshot is not None:
                snapshots.append(snapshot)
                self._files[folder.name], self._current[folder.name] = files, snapshot
            else:
                self._deleted[folder.name] = version
        return Restored(snapshots, last_versions)

    def restore_patterns(self, limit: int) -> dict[str, Pattern]:
        """The patterns of the folder by name, at most ``limit`` (DACRT_MAX_PATTERNS) in name
        order; a temporary file is removed, a file the engine cannot read or past the limit
        logged and skipped."""
        patterns: dict[str, Pattern] = {}
        for path in sorted(self.patterns.iterdir()):
            if path.name.endswith(TEMPORARY):
                path.unlink(missing_ok=True)
                continue
            if path.suffix != ".npz" or not path.is_file():
                log.warning("data: skipped patterns/%s: not a pattern's .npz file", path.name)
                continue
            if len(patterns) == limit:
                log.error(
                    "data: skipped pattern %s: past DACRT_MAX_PATTERNS (%d)", path.name, limit
                )
                continue
            try:
                patterns[check_name("pattern", path.stem)] = Pattern.load(path)
            except (Invalid, InputError, OSError, ValueError) as exc:
                log.error("data: skipped pattern %s: %s", path.name, exc)
        return patterns

    @staticmethod
    def _manifests(folder: Path) -> Iterator[tuple[int, Path]]:
        for path in folder.iterdir():
            match = MANIFEST.fullmatch(path.name)
            if match:
                yield int(match.group(1)), path

    def _read_scene(
        self, folder: Path, path: Path, version: int
    ) -> tuple[Snapshot | None, dict[str, MeshFiles]]:
        try:
            record = json.loads(path.read_bytes())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CorruptScene(f"{path.name} is not JSON ({exc})") from None
        except RecursionError:
            raise CorruptScene(f"{path.name} is not a manifest: JSON nested too deep") from None
        if not isinstance(record, dict) or record.get("format") not in READ_FORMATS:
            raise CorruptScene(
                f"{path.name} is not a manifest of format {' or '.join(map(str, READ_FORMATS))}"
            )
        if record.get("version") != version or record.get("scene") != folder.name:
            raise CorruptScene(f"{path.name} names another scene or version")
        if record.get("deleted"):
            return None, {}
        try:
            meshes, files = {}, {}
            next_index = _count(record["next_index"], "next_index", path, MAX_INDEX + 1, LAST)
            indices = set()
            for item in record["meshes"]:
                name = check_name("mesh", item["name"])
                index = _count(item["index"], f"{name}.index", path, MAX_INDEX, LAST)
                _count(item["version"], f"{name}.version", path, version, "the manifest's version")
                if name in meshes or index in indices or index >= next_index:
                    raise CorruptScene(
                        f"{path.name}: mesh {name!r} (index {index}) repeats a name or an index, "
                        f"or its index is not below next_index {next_index}"
                    )
                indices.add(index)
                instance_of = item.get("instance_of")
                if instance_of is None:
                    geometry, files[name] = self._read_geometry(folder, item)
                else:
                    geometry, files[name] = None, {}
                    check_name("mesh", instance_of)
                meshes[name] = Mesh(
                    name,
                    index,
                    geometry,  # an instance's is its source's, linked below
                    None,
                    item["version"],
                    parse_mask(item.get("mask", 0xFFFFFFFF), "mask"),
                    owned_transform(_transform(item.get("transform"))),
                    instance_of,
                    parse_reflectivity(item.get("reflectivity", REFLECTIVITY), "reflectivity"),
                    parse_label(item.get("label", DEFAULT_LABEL), "label"),
                    _transform_end(item.get("transform_end")),
                    self._read_vertices_end(folder, item, files[name]),
                )
            for name, mesh in meshes.items():
                if mesh.instance_of is not None:
                    source = meshes.get(mesh.instance_of)
                    if source is None or source.instance_of is not None:
                        raise CorruptScene(
                            f"{path.name}: {name!r} is an instance of {mesh.instance_of!r}, "
                            "which is not a mesh of its own"
                        )
                    mesh = replace(mesh, geometry=source.geometry)
                # the checks a change through the API passes (``Store._changed``)
                meshes[name] = placed(check_deforming(mesh))
        except KeyError as exc:
            raise CorruptScene(f"{path.name} lacks {exc}") from None
        except TypeError as exc:  # a list where a name is, a number where a list is...
            raise CorruptScene(f"{path.name} holds a value of the wrong type: {exc}") from None
        except (Invalid, InputError) as exc:  # a value the service or the engine refuses
            raise CorruptScene(f"{path.name}: {exc}") from None
        meshes = dict(sorted(meshes.items(), key=lambda item: item[1].index))
        return Snapshot(folder.name, version, MappingProxyType(meshes), next_index), files

    def _read_geometry(
        self, folder: Path, item: dict[str, Any]
    ) -> tuple[Geometry, dict[str, ArrayFile]]:
        """A mesh's arrays and their files, as its manifest entry names them, checked as an
        upload is (``wire.mesh_arrays``: finite vertices, every face index in [0, V))."""
        vertices = check_vertices(self._read_rows(folder, item["vertices"], np.float32))
        faces = self._read_rows(folder, item["faces"], np.int32)
        if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
            raise CorruptScene(f"{item['faces']['file']} has indices out of range")
        files = {
            "vertices": ArrayFile(
                item["vertices"]["file"], vertices.shape, item["vertices"]["crc32"]
            ),
            "faces": ArrayFile(item["faces"]["file"], faces.shape, item["faces"]["crc32"]),
        }
        return Geometry(vertices, faces, referenced_bounds(vertices, faces)), files

    def _read_vertices_end(
        self, folder: Path, item: dict[str, Any], files: dict[str, ArrayFile]
    ) -> np.ndarray | None:
        """A mesh's end vertices (None: static) from their file, added to ``files``, or from the
        manifest's rows of numbers (the form older folders hold)."""
        entry = item.get("vertices_end")
        if entry is None:
            return None
        if not isinstance(entry, dict):
            return _inline_vertices_end(entry)
        vertices = check_vertices(self._read_rows(folder, entry, np.float32), "vertices_end")
        files["vertices_end"] = ArrayFile(entry["file"], vertices.shape, entry["crc32"])
        return vertices

    def _read_rows(self, folder: Path, item: dict[str, Any], dtype: type) -> np.ndarray:
        """An (n, 3) array of ``dtype`` from the file that ``item`` names (``_read_array``)."""
        array = self._read_array(folder, item, dtype)
        if array.ndim != 2 or array.shape[1] != 3:
            raise CorruptScene(f"{item['file']} holds {array.shape}, not (n, 3) rows")
        return array

    @staticmethod
    def _read_array(folder: Path, item: dict[str, Any], dtype: type) -> np.ndarray:
        path = folder / item["file"]
        if path.parent != folder:
            raise CorruptScene(f"{item['file']!r} is not a file of the scene")
        try:
            array = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:
            raise CorruptScene(f"{path.name} cannot be read as .npy ({exc})") from None
        if array.dtype != dtype or list(array.shape) != item["shape"]:
            raise CorruptScene(
                f"{path.name} holds {array.dtype} {array.shape}, not {np.dtype(dtype)} "
                f"{tuple(item['shape'])}"
            )
        if checksum(array) != item["crc32"]:
            raise CorruptScene(f"{path.name} fails its CRC-32 check")
        array = np.ascontiguousarray(array)
        array.setflags(write=False)
        return array

    @staticmethod
    def _remove_temporary(folder: Path) -> None:
        """Remove the temporary files of writes that a crash or a failure interrupted."""
        for path in folder.glob("*" + TEMPORARY):
            if path.is_file():
                path.unlink(missing_ok=True)

    @staticmethod
    def _clean(folder: Path, manifest: Path, files: dict[str, MeshFiles]) -> None:
        """Remove what a crash left: temporary files, older manifests, arrays nobody names."""
        kept = {manifest.name} | {
            f.name for mesh_files in files.values() for f in mesh_files.values()
        }
        for path in folder.iterdir():
            if path.name not in kept and (
                path.name.endswith(TEMPORARY)
                or path.name.endswith(".npy")
                or MANIFEST.fullmatch(path.name)
            ):
                path.unlink(missing_ok=True)
