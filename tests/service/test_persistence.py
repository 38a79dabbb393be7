"""Scenes in a data folder (``service.persistence``) in-process: every change kind is read back
with its version, versions go on after a restart, a vertex update writes one array (end vertices
have a file of their own, and a change to another part writes only the manifest), a rejected
or failed change writes nothing that is loaded and leaves no file behind, a folder that cannot
be written is refused when opened, and damaged files, and manifests that break what the API
checks on a change, are logged and their scene skipped."""

from __future__ import annotations

import errno
import json
import logging
import os
import zlib
from pathlib import Path

import numpy as np
import pytest
from faults import fail_in_write
from service_helpers import grid, quad

from dacrt.sensors import Pattern
from service import persistence
from service.errors import Conflict, DataDirUnavailable, InsufficientStorage, TooLarge
from service.patterns import Patterns
from service.persistence import DataDir, checksum
from service.store import Store
from service.wire import FrameChange, MeshArrays


def open_store(folder: Path, max_triangles: int = 100_000) -> Store:
    """A store over ``folder`` with what it holds restored, as the app starts one."""
    journal = DataDir(folder)
    store = Store(max_triangles, 10**9, journal)
    restored = journal.restore()
    store.restore(restored.snapshots, restored.last_versions)
    return store


def files(folder: Path) -> dict[str, int]:
    """Every file under ``folder`` -> its inode (a rewritten file gets a new one)."""
    return {str(p.relative_to(folder)): p.stat().st_ino for p in folder.rglob("*") if p.is_file()}


def assert_same_scenes(restored: Store, original: Store) -> None:
    """The same scenes: info (masks, transforms, sources, bounds), arrays, shared arrays."""
    assert [s.info() for s in restored.snapshots()] == [s.info() for s in original.snapshots()]
    assert restored.nbytes == original.nbytes
    for before in original.snapshots():
        after = restored.snapshot(before.scene)
        for name, mesh in before.meshes.items():
            np.testing.assert_array_equal(after.meshes[name].vertices, mesh.vertices)
            np.testing.assert_array_equal(after.meshes[name].faces, mesh.faces)
            np.testing.assert_array_equal(after.meshes[name].bounds, mesh.bounds)
            assert after.meshes[name].vertices.dtype == np.float32
            assert after.meshes[name].faces.dtype == np.int32
            assert not after.meshes[name].vertices.flags.writeable
            if mesh.transform is None:
                assert after.meshes[name].transform is None
            else:
                assert after.meshes[name].transform.tobytes() == mesh.transform.tobytes()
                assert not after.meshes[name].transform.flags.writeable
            if mesh.vertices_end is None:
                assert after.meshes[name].vertices_end is None
            else:
                assert after.meshes[name].vertices_end.tobytes() == mesh.vertices_end.tobytes()
                assert after.meshes[name].vertices_end.dtype == np.float32
                assert not after.meshes[name].vertices_end.flags.writeable
            if mesh.instance_of is not None:
                source = after.meshes[mesh.instance_of]
                assert after.meshes[name].geometry is source.geometry


@pytest.fixture
def changed(tmp_path) -> Store:
    """A store over tmp_path after every kind of change."""
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    store.put_mesh("s", "b", MeshArrays(*quad(0, 1, 0, 1, 2)))
    store.update_vertices("s", "a", grid(4, z=1.0)[0])
    store.apply_frame("s", {"b": (quad(0, 2, 0, 2, 3)[0], None), "c": quad(0, 1, 0, 1, 5)})
    store.delete_mesh("s", "b")
    store.put_mesh("gone", "a", MeshArrays(*quad(0, 1, 0, 1, 0)))
    store.put_mesh("gone", "a", MeshArrays(*quad(0, 1, 0, 1, 1)))
    store.delete_scene("gone")
    return store


def test_every_change_kind_is_restored_with_its_version(tmp_path, changed):
    restored = open_store(tmp_path)
    assert_same_scenes(restored, changed)
    assert restored.snapshot("s").version == 5
    assert [s.scene for s in restored.snapshots()] == ["s"]


def test_versions_go_on_after_a_restart_also_for_a_deleted_scene(tmp_path, changed):
    restored = open_store(tmp_path)
    assert restored.put_mesh("s", "d", MeshArrays(*quad(0, 1, 0, 1, 0)))[0].version == 6
    assert restored.put_mesh("gone", "a", MeshArrays(*quad(0, 1, 0, 1, 0)))[0].version == 3
    again = open_store(tmp_path)
    assert again.snapshot("gone").version == 3 and again.snapshot("s").version == 6


@pytest.mark.parametrize("restart", [False, True])
def test_a_scene_deleted_and_made_again_keeps_one_manifest(tmp_path, restart):
    """A deleted scene's manifest ({"deleted": true}) goes once the scene is made again, so
    episodes that delete and remake a scene leave one manifest, not one each (also when the
    deletion was read back by a restart)."""
    store = open_store(tmp_path)
    for _ in range(4):
        store.put_mesh("episode", "a", MeshArrays(*quad(0, 1, 0, 1, 0)))
        store.delete_scene("episode")
        if restart:
            store = open_store(tmp_path)
    store.put_mesh("episode", "a", MeshArrays(*quad(0, 1, 0, 1, 0)))
    manifests = sorted(p.name for p in (tmp_path / "scenes" / "episode").glob("scene.*.json"))
    assert manifests == ["scene.5.json"]
    assert open_store(tmp_path).snapshot("episode").version == 5


def test_indices_stay_and_are_not_reused_after_a_restart(tmp_path, changed):
    restored = open_store(tmp_path)
    restored.put_mesh("s", "d", MeshArrays(*quad(0, 1, 0, 1, 0)))
    indices = {m.name: m.index for m in restored.snapshot("s").meshes.values()}
    assert indices == {"a": 0, "c": 2, "d": 3}


def test_meshes_without_triangles_or_vertices_are_written_and_restored(tmp_path):
    store = open_store(tmp_path)
    vertices, _ = grid(2)
    store.put_mesh("s", "no_faces", MeshArrays(vertices, np.zeros((0, 3), np.int32)))
    store.put_mesh(
        "s", "nothing", MeshArrays(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    )
    store.apply_frame("s", {"empty_too": (np.zeros((0, 3), np.float32), np.zeros((0, 3)))})
    restored = open_store(tmp_path)
    assert_same_scenes(restored, store)
    assert restored.snapshot("s").version == 3
    assert sorted(restored.snapshot("s").meshes) == ["empty_too", "no_faces", "nothing"]


def test_a_vertex_update_writes_one_array_and_keeps_the_faces_file(tmp_path):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(8)))
    before = files(tmp_path)
    store.update_vertices("s", "a", grid(8, z=2.0)[0])
    after = files(tmp_path)
    written = {name for name in after if before.get(name) != after[name]}
    assert sorted(Path(n).name for n in written) == ["0.2.vertices.npy", "scene.2.json"]
    faces = [name for name in after if name.endswith("faces.npy")]
    assert len(faces) == 1 and before[faces[0]] == after[faces[0]]
    assert len(after) == 3  # the old vertices and manifest are removed


@pytest.mark.parametrize(
    "change, error",
    [
        (lambda s: s.update_vertices("s", "a", grid(2)[0]), Conflict),
        (lambda s: s.put_mesh("s", "big", MeshArrays(*grid(40))), TooLarge),
    ],
    ids=["vertex count", "over the triangle limit"],
)
def test_a_rejected_change_writes_nothing(tmp_path, change, error):
    store = open_store(tmp_path, max_triangles=1000)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    before = files(tmp_path)
    with pytest.raises(error):
        change(store)
    assert files(tmp_path) == before
    assert open_store(tmp_path).snapshot("s").version == 1


def test_a_failed_write_changes_nothing_served_and_burns_its_version(tmp_path, monkeypatch):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("service.persistence.write_npy", full_disk)
    with pytest.raises(InsufficientStorage):
        store.update_vertices("s", "a", grid(4, z=1.0)[0])
    assert store.snapshot("s").version == 1
    np.testing.assert_array_equal(store.snapshot("s").meshes["a"].vertices, grid(4)[0])
    monkeypatch.undo()
    assert store.update_vertices("s", "a", grid(4, z=1.0)[0]).version == 3
    assert open_store(tmp_path).snapshot("s").version == 3


CHANGES = {
    "new mesh": lambda s: s.put_mesh("s", "b", MeshArrays(*grid(3))),
    "new scene": lambda s: s.put_mesh("t", "a", MeshArrays(*grid(3))),
    "vertices": lambda s: s.update_vertices("s", "a", grid(4, z=1.0)[0]),
    "transform": lambda s: s.set_transform("s", "a", turn(5)),
    "mask": lambda s: s.set_mask("s", "a", 7),
    "frame": lambda s: s.apply_frame("s", {"a": (grid(4, z=2.0)[0], None), "c": grid(2)}),
    "instance": lambda s: s.put_instance("s", "i", "a", turn(9)),
    "delete mesh": lambda s: s.delete_mesh("s", "a"),
    "delete scene": lambda s: s.delete_scene("s"),
}


@pytest.mark.parametrize("only", ["", "scene."], ids=["first file", "manifest"])
@pytest.mark.parametrize("change", CHANGES.values(), ids=CHANGES.keys())
def test_a_change_on_a_full_disk_leaves_the_files_and_the_store_as_they_were(
    tmp_path, monkeypatch, change, only
):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    before, info = files(tmp_path), store.snapshot("s").info()
    fail_in_write(monkeypatch, errno.ENOSPC, only)
    with pytest.raises(InsufficientStorage) as failed:
        change(store)
    assert failed.value.detail == (
        f"the data folder {tmp_path} (DACRT_DATA_DIR) cannot be written: "
        "[Errno 28] No space left on device; nothing was changed"
    )
    assert files(tmp_path) == before  # no temporary file, no array of the failed version
    assert store.snapshot("s").info() == info
    assert store.journal.fault.errno == "ENOSPC" and store.journal.errors == {"ENOSPC": 1}
    assert open_store(tmp_path).snapshot("s").info() == info
    monkeypatch.undo()
    change(store)  # space is back
    assert store.journal.fault is None
    assert_same_scenes(open_store(tmp_path), store)


@pytest.mark.parametrize(
    "code, error",
    [
        (errno.ENOSPC, InsufficientStorage),
        (errno.EDQUOT, InsufficientStorage),
        (errno.EROFS, DataDirUnavailable),
        (errno.EACCES, DataDirUnavailable),
        (errno.EIO, DataDirUnavailable),
    ],
)
def test_a_full_folder_is_507_and_any_other_os_error_503(tmp_path, monkeypatch, code, error):
    store = open_store(tmp_path)
    fail_in_write(monkeypatch, code)
    with pytest.raises(error) as failed:
        store.put_mesh("s", "a", MeshArrays(*grid(2)))
    assert type(failed.value) is error
    assert f"[Errno {code}] {os.strerror(code)}; nothing was changed" in failed.value.detail
    assert store.journal.errors == {errno.errorcode[code]: 1}
    assert not (tmp_path / "scenes" / "s").exists()  # the new scene's folder is removed too


def test_a_manifest_renamed_then_not_synced_is_undone(tmp_path, monkeypatch):
    """The folder's fsync after the manifest's rename fails (an I/O error): the manifest is
    removed (a delete's, which replaced the current one, is written back)."""
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    info, original = store.snapshot("s").info(), persistence.sync_folder

    def sync_folder(folder: Path) -> None:
        if any(folder.glob("scene.*.json")) and not any(folder.glob("*.tmp")):
            if sync_folder.armed:
                sync_folder.armed = False
                raise OSError(errno.EIO, os.strerror(errno.EIO))
        original(folder)

    monkeypatch.setattr(persistence, "sync_folder", sync_folder)
    for change in (CHANGES["transform"], CHANGES["delete scene"]):
        sync_folder.armed = True
        with pytest.raises(DataDirUnavailable):
            change(store)
        assert not sync_folder.armed
        assert open_store(tmp_path).snapshot("s").info() == info
    assert store.snapshot("s").info() == info


def test_a_change_that_cannot_be_undone_stops_the_folder_until_a_restart(tmp_path, monkeypatch):
    """The fsync after the manifest's rename fails, and so does removing the manifest: the
    folder holds a change memory does not. The error says the change may be there after a
    restart, and no later change is taken (it would build on a state that is not known)."""
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    info, sync, unlink = store.snapshot("s").info(), persistence.sync_folder, Path.unlink

    def failing_sync(folder: Path) -> None:
        if (folder / "scene.2.json").exists():  # the new version's manifest is renamed
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        sync(folder)

    def failing_unlink(path: Path, missing_ok: bool = False) -> None:
        if path.name.startswith("scene."):
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        unlink(path, missing_ok=missing_ok)

    monkeypatch.setattr(persistence, "sync_folder", failing_sync)
    monkeypatch.setattr(Path, "unlink", failing_unlink)
    with pytest.raises(DataDirUnavailable) as failed:
        store.set_mask("s", "a", 5)
    assert "nothing was changed" not in failed.value.detail
    assert "the change may or may not be there after a restart" in failed.value.detail
    monkeypatch.undo()  # the disk works again: the folder still takes nothing
    assert store.snapshot("s").info() == info
    with pytest.raises(DataDirUnavailable) as refused:
        store.set_mask("s", "a", 6)
    assert refused.value.detail == failed.value.detail == store.journal.stopped
    assert store.journal.fault.detail == failed.value.detail and store.snapshot("s").info() == info
    assert open_store(tmp_path).snapshot("s").mesh("a").mask == 5  # what the folder held


PATTERN = Pattern([0.0, 90.0], [0.0, 10.0])
OTHER_PATTERN = Pattern([5.0], [-5.0])


def pattern_store(folder: Path, limit: int = 8) -> Patterns:
    patterns = Patterns(limit, 1000, DataDir(folder))
    patterns.restore()
    return patterns


def same_pattern(a: Pattern, b: Pattern) -> bool:
    return np.array_equal(a.azimuth_deg, b.azimuth_deg) and np.array_equal(
        a.elevation_deg, b.elevation_deg
    )


@pytest.mark.parametrize("replaced", [False, True], ids=["new", "replaced"])
def test_a_pattern_renamed_then_not_synced_is_undone(tmp_path, monkeypatch, replaced):
    """One failing fsync of patterns/ after the rename: a new pattern's file is removed, a
    replaced one's written back; memory and the folder keep the pattern as it was."""
    patterns = pattern_store(tmp_path)
    if replaced:
        patterns.put("p", OTHER_PATTERN)
    original = persistence.sync_folder

    def sync_folder(folder: Path) -> None:
        if folder.name == "patterns" and sync_folder.armed:
            sync_folder.armed = False
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        original(folder)

    sync_folder.armed = True
    monkeypatch.setattr(persistence, "sync_folder", sync_folder)
    with pytest.raises(DataDirUnavailable) as failed:
        patterns.put("p", PATTERN)
    assert type(failed.value) is DataDirUnavailable and not sync_folder.armed
    assert "[Errno 5] Input/output error; nothing was changed" in failed.value.detail
    assert patterns.journal.errors == {"EIO": 1}
    for held in (patterns, pattern_store(tmp_path)):
        if replaced:
            assert same_pattern(held.get("p"), OTHER_PATTERN)
        else:
            assert held.names() == []


def test_a_pattern_on_a_full_or_read_only_folder_changes_nothing(tmp_path, monkeypatch):
    patterns = pattern_store(tmp_path)
    patterns.put("p", PATTERN)
    fail_in_write(monkeypatch, errno.ENOSPC)
    with pytest.raises(InsufficientStorage) as full:
        patterns.put("q", PATTERN)
    assert "[Errno 28] No space left on device; nothing was changed" in full.value.detail
    assert patterns.journal.fault.errno == "ENOSPC" and patterns.names() == ["p"]
    monkeypatch.undo()
    unlink = Path.unlink

    def read_only(path: Path, missing_ok: bool = False) -> None:
        if path.parent.name == "patterns":
            raise OSError(errno.EROFS, os.strerror(errno.EROFS))
        unlink(path, missing_ok=missing_ok)

    monkeypatch.setattr(Path, "unlink", read_only)
    with pytest.raises(DataDirUnavailable) as refused:
        patterns.delete("p")
    assert "[Errno 30] Read-only file system; nothing was changed" in refused.value.detail
    assert patterns.names() == ["p"] and patterns.journal.errors == {"ENOSPC": 1, "EROFS": 1}
    monkeypatch.undo()
    patterns.delete("p")
    assert pattern_store(tmp_path).names() == [] and patterns.journal.fault is None


def test_a_restart_restores_at_most_the_pattern_limit(tmp_path, caplog):
    patterns = pattern_store(tmp_path)
    for name in ("c", "a", "b"):
        patterns.put(name, PATTERN)
    with caplog.at_level(logging.ERROR, logger="service"):
        assert pattern_store(tmp_path, limit=2).names() == ["a", "b"]
    assert "skipped pattern c.npz: past DACRT_MAX_PATTERNS (2)" in caplog.text


def test_entries_that_are_not_scenes_or_patterns_are_logged(tmp_path, caplog):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(2)))
    (tmp_path / "scenes" / "gone").symlink_to(tmp_path / "nowhere")
    (tmp_path / "scenes" / "stray.json").write_text("{}")
    (tmp_path / "scenes" / "odd").mkdir()
    (tmp_path / "scenes" / "odd" / "notes.txt").write_text("x")
    (tmp_path / "patterns" / "readme.txt").write_text("x")
    with caplog.at_level(logging.WARNING, logger="service"):
        assert [s.scene for s in open_store(tmp_path).snapshots()] == ["s"]
        pattern_store(tmp_path)
    assert "skipped scenes/gone: a broken link" in caplog.text
    assert "skipped scenes/stray.json: not a folder" in caplog.text
    assert "skipped scenes/odd: it holds no manifest" in caplog.text
    assert "skipped patterns/readme.txt: not a pattern's .npz file" in caplog.text


def test_a_patterns_entry_that_is_a_file_is_refused_when_opened(tmp_path):
    (tmp_path / "patterns").write_text("x")
    with pytest.raises(OSError) as failed:
        DataDir(tmp_path)
    assert failed.value.errno == errno.EEXIST


@pytest.mark.parametrize("code", [errno.EROFS, errno.EACCES, errno.EIO])
def test_a_folder_that_cannot_be_written_is_refused_when_opened(tmp_path, monkeypatch, code):
    fail_in_write(monkeypatch, code)
    with pytest.raises(OSError) as failed:
        DataDir(tmp_path)
    assert failed.value.errno == code
    assert sorted(p.name for p in tmp_path.iterdir()) == ["patterns", "scenes"]  # no probe left


def test_a_full_folder_is_opened_with_its_fault(tmp_path, monkeypatch):
    open_store(tmp_path).put_mesh("s", "a", MeshArrays(*grid(4)))
    fail_in_write(monkeypatch, errno.ENOSPC)
    store = open_store(tmp_path)
    assert store.journal.fault.errno == "ENOSPC"
    assert store.snapshot("s").version == 1  # reads are served
    with pytest.raises(InsufficientStorage):
        store.set_mask("s", "a", 3)
    monkeypatch.undo()
    assert store.set_mask("s", "a", 3).version == 3 and store.journal.fault is None


def damage_truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def damage_flip(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[-5] ^= 0xFF  # in the array's data: only the checksum can tell
    path.write_bytes(bytes(data))


def damage_garbage(path: Path) -> None:
    path.write_bytes(b"\x00garbage")


def damage_misshape(path: Path) -> None:
    """Vertices of another shape, their manifest entry and checksum to match: a folder written
    by an earlier version that stored a GLB's SCALAR positions."""
    vertices = np.load(path).reshape(-1, 1)
    np.save(path, vertices)
    [manifest] = path.parent.glob("scene.*.json")
    document = json.loads(manifest.read_text())
    entry = document["meshes"][0]["vertices"]
    entry.update(shape=list(vertices.shape), crc32=checksum(vertices))
    manifest.write_text(json.dumps(document))


@pytest.mark.parametrize(
    "pattern, damage",
    [
        ("*.vertices.npy", damage_misshape),
        ("*.vertices.npy", damage_truncate),
        ("*.faces.npy", damage_flip),
        ("*.vertices.npy", damage_garbage),
        ("scene.*.json", damage_truncate),
        ("scene.*.json", damage_garbage),
    ],
    ids=[
        "misshapen vertices",
        "truncated vertices",
        "corrupted faces",
        "garbage vertices",
        "cut manifest",
        "bad json",
    ],
)
def test_a_damaged_file_is_logged_and_its_scene_skipped(tmp_path, caplog, pattern, damage):
    store = open_store(tmp_path)
    store.put_mesh("hurt", "a", MeshArrays(*grid(4)))
    store.update_vertices("hurt", "a", grid(4, z=1.0)[0])
    store.put_mesh("fine", "a", MeshArrays(*grid(3)))
    [path] = (tmp_path / "scenes" / "hurt").glob(pattern)
    damage(path)
    with caplog.at_level(logging.ERROR, logger="service"):
        restored = open_store(tmp_path)
    assert [s.scene for s in restored.snapshots()] == ["fine"]
    assert "skipped scene 'hurt' (version 2)" in caplog.text and path.name in caplog.text
    assert restored.put_mesh("hurt", "a", MeshArrays(*grid(2)))[0].version == 3  # not reused


def test_leftovers_of_a_crash_are_ignored_and_removed(tmp_path):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    folder = tmp_path / "scenes" / "s"
    (folder / "0.9.vertices.npy.tmp").write_bytes(b"half")  # written, not renamed
    (folder / "0.9.vertices.npy").write_bytes(b"\x93NUMPY orphan")  # renamed, not named
    (folder / "scene.9.json.tmp").write_bytes(b'{"half')
    restored = open_store(tmp_path)
    assert_same_scenes(restored, store)
    assert sorted(p.name for p in folder.iterdir()) == ["0.1.faces.npy", "0.1.vertices.npy"] + [
        "scene.1.json"
    ]


def test_temporary_files_are_removed_at_start_wherever_they_are(tmp_path, caplog):
    """In a scene folder without a manifest (its first change failed), in a scene skipped as
    damaged, and the start's probe: all removed; the damaged scene's own files are kept."""
    store = open_store(tmp_path)
    store.put_mesh("hurt", "a", MeshArrays(*grid(4)))
    [manifest] = (tmp_path / "scenes" / "hurt").glob("scene.*.json")
    damage_garbage(manifest)
    first = tmp_path / "scenes" / "first"
    first.mkdir()
    leftovers = [
        first / "0.1.vertices.npy.tmp",
        tmp_path / "scenes" / "hurt" / "0.2.faces.npy.tmp",
        tmp_path / persistence.PROBE,
        tmp_path / (persistence.PROBE + persistence.TEMPORARY),
    ]
    for path in leftovers:
        path.write_bytes(b"half")
    with caplog.at_level(logging.ERROR, logger="service"):
        assert open_store(tmp_path).snapshots() == []
    assert not any(path.exists() for path in leftovers)
    assert not first.exists()  # nothing but a temporary file: not a scene
    assert sorted(p.name for p in (tmp_path / "scenes" / "hurt").iterdir()) == [
        "0.1.faces.npy",
        "0.1.vertices.npy",
        "scene.1.json",
    ]


def turn(degrees: float, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(4, 4) float64: a turn about +z (inexact in binary), then a shift."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    matrix = np.eye(4)
    matrix[:2, :2] = [[c, -s], [s, c]]
    matrix[:3, 3] = shift
    return matrix


@pytest.fixture
def placed(tmp_path) -> Store:
    """A store over tmp_path with masks, transforms and instances, after changes of each."""
    store = open_store(tmp_path)
    store.put_mesh("s", "floor", MeshArrays(*quad(-5, 5, -5, 5, 0)), mask=0x10)
    store.put_mesh("s", "car", MeshArrays(*grid(4, z=1.0)), mask=3)
    store.set_transform("s", "car", turn(33.3, shift=(0.1, 0.2, 0.3)))
    for i in range(3):
        store.put_instance("s", f"car{i}", "car", turn(7.7 * i, shift=(i, 0, 0)), mask=1 << i)
    store.update_vertices("s", "car", grid(4, z=2.0)[0])
    store.apply_frame(
        "s",
        {"car1": FrameChange(transform=turn(1.1)), "truck": FrameChange(instance_of="car0")},
    )
    store.set_mask("s", "floor", 0xFFFF0000)
    return store


def test_masks_transforms_and_instances_are_restored(tmp_path, placed):
    restored = open_store(tmp_path)
    assert_same_scenes(restored, placed)
    assert restored.snapshot("s").meshes["truck"].instance_of == "car"
    arrays = sorted(p.name for p in (tmp_path / "scenes" / "s").glob("*.npy"))
    assert len(arrays) == 4  # floor's and car's: the instances' arrays are car's
    again = open_store(tmp_path)
    again.update_vertices("s", "car", grid(4, z=3.0)[0])  # instances follow after a restart too
    assert again.snapshot("s").meshes["car2"].bounds[:, 2].tolist() == [3, 3]


@pytest.mark.parametrize(
    "change",
    [
        lambda s: s.set_transform("s", "car", turn(5)),
        lambda s: s.set_mask("s", "car", 7),
        lambda s: s.put_instance("s", "car9", "car", turn(9)),
        lambda s: s.apply_frame("s", {f"car{i}": FrameChange(transform=turn(i)) for i in range(3)}),
        lambda s: s.delete_mesh("s", "car0"),
    ],
    ids=["transform", "mask", "new instance", "frame of transforms", "delete an instance"],
)
def test_a_placement_change_writes_only_the_manifest(tmp_path, placed, change):
    assert_writes_only_the_manifest(tmp_path, placed, change)


def assert_writes_only_the_manifest(tmp_path, store, change) -> None:
    """``change(store)`` writes the scene's new manifest and no other file, and a store opened
    on the folder then holds what ``store`` holds."""
    before = files(tmp_path)
    change(store)
    after = files(tmp_path)
    written = {name for name in after if before.get(name) != after[name]}
    assert [Path(n).name for n in written] == [f"scene.{store.snapshot('s').version}.json"]
    assert_same_scenes(open_store(tmp_path), store)


def test_materials_are_restored(tmp_path, changed):
    changed.set_material("s", "a", 0.8, None)
    changed.apply_frame("s", {"c": FrameChange(reflectivity=0.25, label=12)})
    restored = open_store(tmp_path)
    assert_same_scenes(restored, changed)
    meshes = restored.snapshot("s").meshes
    assert {name: (m.reflectivity, m.label) for name, m in meshes.items()} == {
        "a": (0.8, 0),
        "c": (0.25, 12),
    }


def test_a_material_change_writes_only_the_manifest(tmp_path):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    before = files(tmp_path)
    store.set_material("s", "a", None, 7)
    after = files(tmp_path)
    arrays = {name: inode for name, inode in before.items() if name.endswith(".npy")}
    assert {name: after[name] for name in arrays} == arrays
    assert open_store(tmp_path).snapshot("s").mesh("a").label == 7


def test_a_format_1_manifest_is_read_with_the_defaults(tmp_path):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    [path] = (tmp_path / "scenes" / "s").glob("scene.*.json")
    record = json.loads(path.read_bytes())
    assert record["format"] == 2 and record["meshes"][0]["mask"] == 0xFFFFFFFF
    record["format"] = 1
    for item in record["meshes"]:
        del item["mask"], item["reflectivity"], item["label"]
    path.write_text(json.dumps(record))
    assert_same_scenes(open_store(tmp_path), store)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda m: m.update(instance_of="nope"), "'car0' is an instance of 'nope'"),
        (lambda m: m.update(instance_of="car1"), "'car0' is an instance of 'car1'"),
        (lambda m: m.update(transform=np.zeros((4, 4)).tolist()), "transform is not affine"),
        (lambda m: m.update(transform=[[1, 2]]), "transform must have shape (4, 4)"),
        (lambda m: m.update(mask=-1), "mask=-1 is negative"),
        (lambda m: m.update(reflectivity=2), "reflectivity must be a number in [0, 1]"),
        (lambda m: m.update(label="x"), "label must be an integer"),
        (lambda m: m.pop("instance_of"), "lacks 'vertices'"),
        (lambda m: m.update(name=5), "holds a value of the wrong type"),
        (lambda m: m.update(name="../x y"), "mesh name '../x y' must be 1-64 characters"),
        (lambda m: m.update(index="0"), "car0.index is '0', not a count"),
        (lambda m: m.update(index=True), "car0.index is True, not a count"),
        (lambda m: m.update(version=None), "car0.version is None, not a count"),
        (lambda m: m.update(version=10**23), "past the manifest's version"),
        (lambda m: m.update(name="car1"), "mesh 'car1' (index 3) repeats a name or an index"),
        (lambda m: m.update(index=1), "mesh 'car0' (index 1) repeats a name or an index"),
        (lambda m: m.update(index=99), "or its index is not below next_index"),
    ],
)
def test_a_manifest_with_a_bad_placement_is_logged_and_skipped(
    tmp_path, placed, caplog, edit, message
):
    [path] = (tmp_path / "scenes" / "s").glob("scene.*.json")
    record = json.loads(path.read_bytes())
    edit(next(m for m in record["meshes"] if m["name"] == "car0"))
    path.write_text(json.dumps(record))
    with caplog.at_level(logging.ERROR, logger="service"):
        assert open_store(tmp_path).snapshots() == []
    assert "skipped scene 's'" in caplog.text and message in caplog.text


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda r: r.update(next_index="2"), "next_index is '2', not a count"),
        (lambda r: r.update(meshes=5), "holds a value of the wrong type"),
        (lambda r: r.update(meshes=[[1]]), "holds a value of the wrong type"),
    ],
)
def test_a_manifest_of_the_wrong_types_is_logged_and_skipped(
    tmp_path, placed, caplog, edit, message
):
    [path] = (tmp_path / "scenes" / "s").glob("scene.*.json")
    record = json.loads(path.read_bytes())
    edit(record)
    path.write_text(json.dumps(record))
    placed.put_mesh("other", "a", MeshArrays(*grid(2)))
    with caplog.at_level(logging.ERROR, logger="service"):
        assert [s.scene for s in open_store(tmp_path).snapshots()] == ["other"]
    assert "skipped scene 's'" in caplog.text and message in caplog.text


def test_a_manifest_nested_too_deep_is_logged_and_skipped(tmp_path, caplog):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(2)))
    store.put_mesh("other", "a", MeshArrays(*grid(2)))
    [path] = (tmp_path / "scenes" / "s").glob("scene.*.json")
    path.write_text("[" * 100_000)
    with caplog.at_level(logging.ERROR, logger="service"):
        assert [s.scene for s in open_store(tmp_path).snapshots()] == ["other"]
    assert "JSON nested too deep" in caplog.text


def test_a_mesh_index_equal_to_next_index_is_logged_and_skipped(tmp_path, placed, caplog):
    [path] = (tmp_path / "scenes" / "s").glob("scene.*.json")
    record = json.loads(path.read_bytes())
    next(m for m in record["meshes"] if m["name"] == "car0")["index"] = record["next_index"]
    path.write_text(json.dumps(record))
    with caplog.at_level(logging.ERROR, logger="service"):
        assert open_store(tmp_path).snapshots() == []
    assert "skipped scene 's'" in caplog.text and "not below next_index" in caplog.text


def test_an_array_file_corrupted_in_place_is_logged_and_skipped(tmp_path, caplog):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    [vertices] = (tmp_path / "scenes" / "s").glob("*.vertices.npy")
    data = bytearray(vertices.read_bytes())
    data[-1] ^= 0x40  # same size, same header: only the checksum tells
    vertices.write_bytes(bytes(data))
    with caplog.at_level(logging.ERROR, logger="service"):
        assert open_store(tmp_path).snapshots() == []
    assert "skipped scene 's'" in caplog.text and "fails its CRC-32 check" in caplog.text


def test_a_manifest_naming_a_file_outside_its_scene_is_logged_and_skipped(tmp_path, caplog):
    store = open_store(tmp_path)
    for scene in ("s", "t"):
        store.put_mesh(scene, "a", MeshArrays(*grid(4)))  # the same arrays: same shape and CRC
    [path] = (tmp_path / "scenes" / "s").glob("scene.*.json")
    [elsewhere] = (tmp_path / "scenes" / "t").glob("*.vertices.npy")
    record = json.loads(path.read_bytes())
    record["meshes"][0]["vertices"]["file"] = f"../t/{elsewhere.name}"
    path.write_text(json.dumps(record))
    with caplog.at_level(logging.ERROR, logger="service"):
        assert [s.scene for s in open_store(tmp_path).snapshots()] == ["t"]
    assert "skipped scene 's'" in caplog.text and "is not a file of the scene" in caplog.text


def test_a_replaced_mesh_is_restored_with_its_new_faces(tmp_path):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    store.put_mesh("s", "a", MeshArrays(*grid(3)))  # new vertices and new faces
    restored = open_store(tmp_path).snapshot("s").mesh("a")
    assert np.array_equal(restored.faces, grid(3)[1])
    assert np.array_equal(restored.vertices, grid(3)[0])


def test_a_manifest_whose_name_and_version_differ_is_logged_and_skipped(tmp_path, caplog):
    store = open_store(tmp_path)
    store.put_mesh("s", "a", MeshArrays(*grid(4)))
    [path] = (tmp_path / "scenes" / "s").glob("scene.*.json")
    path.rename(path.with_name("scene.7.json"))
    with caplog.at_level(logging.ERROR, logger="service"):
        assert open_store(tmp_path).snapshots() == []
    assert "names another scene or version" in caplog.text


def deform(vertices: np.ndarray) -> np.ndarray:
    """(V, 3) float32: end vertices off a grid's (a ripple, inexact in binary)."""
    ripple = np.sin(7.1 * vertices[:, :1]) * np.cos(3.3 * vertices[:, 1:2])
    return (vertices + np.float32(0.3) * ripple.astype(np.float32)).astype(np.float32)


@pytest.fixture
def deforming(tmp_path) -> Store:
    """A store over tmp_path: scene "s" with a mesh "ball", a deforming mesh "def" and an
    instance "inst" of "ball"; scene "other" with one mesh."""
    store = open_store(tmp_path)
    store.put_mesh("s", "ball", MeshArrays(*grid(4)))
    vertices, faces = grid(5, z=2.0)
    store.put_mesh("s", "def", MeshArrays(vertices, faces))
    store.apply_frame("s", {"def": FrameChange(vertices_end=deform(vertices))})
    store.put_instance("s", "inst", "ball", turn(30, shift=(0, -3, 0)))
    store.put_mesh("other", "m", MeshArrays(*grid(2)))
    return store


def manifest(folder: Path) -> tuple[Path, dict]:
    [path] = folder.glob("scene.*.json")
    return path, json.loads(path.read_bytes())


def test_end_vertices_have_their_own_file_with_shape_and_checksum(tmp_path, deforming):
    vertices = grid(5, z=2.0)[0]
    folder = tmp_path / "scenes" / "s"
    path, record = manifest(folder)
    entry = next(m for m in record["meshes"] if m["name"] == "def")["vertices_end"]
    assert entry == {
        "file": "1.3.vertices_end.npy",  # mesh 1's, written at version 3
        "shape": [len(vertices), 3],
        "crc32": zlib.crc32(deform(vertices).tobytes()),
    }
    np.testing.assert_array_equal(np.load(folder / entry["file"]), deform(vertices))
    assert path.stat().st_size < 2000  # numbers of mesh info, no array
    assert_same_scenes(open_store(tmp_path), deforming)


@pytest.mark.parametrize(
    "change",
    [
        lambda s: s.set_mask("s", "ball", 3),
        lambda s: s.set_material("s", "def", 0.5, 9),
        lambda s: s.set_transform("s", "inst", turn(5)),
        lambda s: s.put_instance("s", "inst2", "ball"),
        lambda s: s.apply_frame("s", {"def": FrameChange(mask=2)}),
    ],
    ids=["mask of another mesh", "material", "an instance's transform", "instance", "frame"],
)
def test_a_change_beside_end_vertices_writes_only_the_manifest(tmp_path, deforming, change):
    assert_writes_only_the_manifest(tmp_path, deforming, change)


def test_new_end_vertices_write_one_file_and_a_static_mesh_drops_it(tmp_path, deforming):
    vertices = grid(5, z=2.0)[0]
    folder = tmp_path / "scenes" / "s"
    deforming.apply_frame("s", {"def": FrameChange(vertices_end=vertices + 1)})
    assert sorted(p.name for p in folder.glob("1.*.npy")) == [
        "1.2.faces.npy",
        "1.2.vertices.npy",
        "1.5.vertices_end.npy",
    ]
    assert_same_scenes(open_store(tmp_path), deforming)
    deforming.update_vertices("s", "def", vertices + 2)  # new start vertices: static again
    assert sorted(p.name for p in folder.glob("1.*.npy")) == ["1.2.faces.npy", "1.6.vertices.npy"]
    restored = open_store(tmp_path)
    assert_same_scenes(restored, deforming)
    assert restored.snapshot("s").mesh("def").vertices_end is None


def test_end_vertices_held_in_the_manifest_are_read_and_given_a_file(tmp_path, deforming):
    """A folder written when a manifest held end vertices as rows of numbers."""
    folder = tmp_path / "scenes" / "s"
    path, record = manifest(folder)
    item = next(m for m in record["meshes"] if m["name"] == "def")
    (folder / item["vertices_end"]["file"]).unlink()
    item["vertices_end"] = deform(grid(5, z=2.0)[0]).tolist()  # float32 values, exact in JSON
    path.write_text(json.dumps(record))
    restored = open_store(tmp_path)
    assert_same_scenes(restored, deforming)
    restored.set_mask("s", "ball", 3)  # the next change gives the end vertices a file
    path, record = manifest(folder)
    entry = next(m for m in record["meshes"] if m["name"] == "def")["vertices_end"]
    assert entry["file"] == "1.5.vertices_end.npy" and (folder / entry["file"]).is_file()
    assert_same_scenes(open_store(tmp_path), restored)


def test_end_vertices_corrupted_in_place_are_logged_and_skipped(tmp_path, deforming, caplog):
    [end] = (tmp_path / "scenes" / "s").glob("*.vertices_end.npy")
    damage_flip(end)
    with caplog.at_level(logging.ERROR, logger="service"):
        assert [s.scene for s in open_store(tmp_path).snapshots()] == ["other"]
    assert "skipped scene 's'" in caplog.text and "fails its CRC-32 check" in caplog.text


def rows(count: int, value: float = 0.0) -> list[list[float]]:
    return [[value, value, value]] * count


def end_file(folder: Path, item: dict, vertices: np.ndarray) -> None:
    """Give ``item`` end vertices in a file whose shape and CRC-32 its entry states."""
    np.save(folder / "1.2.vertices_end.npy", vertices)
    item["vertices_end"] = {
        "file": "1.2.vertices_end.npy",
        "shape": list(vertices.shape),
        "crc32": checksum(vertices),
    }


def nan_vertices(folder: Path, item: dict) -> None:
    """Vertices with a NaN, their entry and checksum to match."""
    vertices = np.load(folder / item["vertices"]["file"])
    vertices[3, 1] = np.nan
    np.save(folder / item["vertices"]["file"], vertices)
    item["vertices"].update(crc32=checksum(vertices))


@pytest.mark.parametrize(
    "mesh, edit, message",
    [
        ("def", lambda f, m, r: m.update(vertices_end=rows(5)), "def.vertices_end has 5 rows"),
        (
            "def",
            lambda f, m, r: end_file(f, m, np.zeros((5, 3), np.float32)),
            "def.vertices_end has 5 rows",
        ),
        (
            "def",
            lambda f, m, r: end_file(f, m, np.zeros((36, 2), np.float32)),
            "holds (36, 2), not (n, 3) rows",
        ),
        (
            "def",
            lambda f, m, r: m.update(vertices_end=rows(36, np.nan)),
            "vertices_end[0] is not finite",
        ),
        ("def", lambda f, m, r: m.update(transform=turn(5).tolist()), "placed by a transform"),
        ("inst", lambda f, m, r: m.update(vertices_end=rows(25)), "an instance cannot deform"),
        ("inst", lambda f, m, r: m.update(instance_of=None), "lacks 'vertices'"),
        ("inst", lambda f, m, r: m.update(instance_of=5), "holds a value of the wrong type"),
        ("inst", lambda f, m, r: m.update(instance_of=[]), "holds a value of the wrong type"),
        ("inst", lambda f, m, r: m.update(instance_of="../x"), "mesh name '../x' must be"),
        (
            "inst",
            lambda f, m, r: (m.update(index=2**31), r.update(next_index=2**31 + 1)),
            "next_index 2147483649 is past 2147483647, the last mesh index",
        ),
        (
            "inst",
            lambda f, m, r: (m.update(index=2**31), r.update(next_index=2**31)),
            "inst.index 2147483648 is past 2147483647, the last mesh index",
        ),
        ("def", lambda f, m, r: nan_vertices(f, m), "vertices[3] is not finite"),
    ],
    ids=[
        "too few end rows in the manifest",
        "too few end rows in a file",
        "end rows of 2 columns",
        "end vertices not finite",
        "a deforming mesh placed",
        "an instance deforming",
        "instance_of null",
        "instance_of a number",
        "instance_of a list",
        "instance_of a path",
        "next_index past int32",
        "index past int32",
        "a NaN vertex",
    ],
)
def test_a_manifest_that_breaks_what_a_change_checks_is_logged_and_skipped(
    tmp_path, deforming, caplog, mesh, edit, message
):
    """What the API refuses in a change (``Store._changed``, ``wire.mesh_arrays``), a restart
    refuses in a manifest: the scene is named in the log and skipped, the others served."""
    folder = tmp_path / "scenes" / "s"
    path, record = manifest(folder)
    edit(folder, next(m for m in record["meshes"] if m["name"] == mesh), record)
    path.write_text(json.dumps(record))
    with caplog.at_level(logging.ERROR, logger="service"):
        restored = open_store(tmp_path)
    assert [s.scene for s in restored.snapshots()] == ["other"]
    assert "skipped scene 's' (version 4)" in caplog.text and message in caplog.text, caplog.text
    assert restored.put_mesh("s", "a", MeshArrays(*grid(2)))[0].version == 5  # not reused
