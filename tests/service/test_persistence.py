"""Scenes in a data folder (``service.persistence``) in-process: every change kind is read back
with its version, versions go on after a restart, a vertex update writes one array, a rejected
or failed change writes nothing that is loaded, and damaged files are logged and skipped."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from service_helpers import grid, quad

from service.errors import Conflict, TooLarge
from service.persistence import DataDir
from service.store import Store
from service.wire import MeshArrays


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
    assert [s.info() for s in restored.snapshots()] == [s.info() for s in original.snapshots()]
    for before in original.snapshots():
        after = restored.snapshot(before.scene)
        for name, mesh in before.meshes.items():
            np.testing.assert_array_equal(after.meshes[name].vertices, mesh.vertices)
            np.testing.assert_array_equal(after.meshes[name].faces, mesh.faces)
            assert after.meshes[name].vertices.dtype == np.float32
            assert after.meshes[name].faces.dtype == np.int32
            assert not after.meshes[name].vertices.flags.writeable


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


def test_indices_stay_and_are_not_reused_after_a_restart(tmp_path, changed):
    restored = open_store(tmp_path)
    restored.put_mesh("s", "d", MeshArrays(*quad(0, 1, 0, 1, 0)))
    indices = {m.name: m.index for m in restored.snapshot("s").meshes.values()}
    assert indices == {"a": 0, "c": 2, "d": 3}


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

    monkeypatch.setattr("service.persistence.np.save", full_disk)
    with pytest.raises(OSError):
        store.update_vertices("s", "a", grid(4, z=1.0)[0])
    assert store.snapshot("s").version == 1
    np.testing.assert_array_equal(store.snapshot("s").meshes["a"].vertices, grid(4)[0])
    monkeypatch.undo()
    assert store.update_vertices("s", "a", grid(4, z=1.0)[0]).version == 3
    assert open_store(tmp_path).snapshot("s").version == 3


def damage_truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def damage_flip(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[-5] ^= 0xFF  # in the array's data: only the checksum can tell
    path.write_bytes(bytes(data))


def damage_garbage(path: Path) -> None:
    path.write_bytes(b"\x00garbage")


@pytest.mark.parametrize(
    "pattern, damage",
    [
        ("*.vertices.npy", damage_truncate),
        ("*.faces.npy", damage_flip),
        ("*.vertices.npy", damage_garbage),
        ("scene.*.json", damage_truncate),
        ("scene.*.json", damage_garbage),
    ],
    ids=["truncated vertices", "corrupted faces", "garbage vertices", "cut manifest", "bad json"],
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
