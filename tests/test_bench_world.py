"""The street world of ``bench.world`` (world frames): its size, determinism, actors and
lidar rays. Skipped without the shared scenes; nothing here is timed."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from bench import world as W

SHARED = W.find_shared()
pytestmark = pytest.mark.skipif(SHARED is None, reason="no ../shared/scenes beside the repository")


@pytest.fixture(scope="module", autouse=True)
def warm_engine():
    """These tests use no engine kernel: override the session's warm-up (tests/conftest.py)."""
    return None


def test_world_size_and_determinism():
    target = 500_000
    world = W.build_world(SHARED / "scenes", target, seed=3)
    assert target - 69_451 <= len(world.faces) <= target
    assert sum(world.parts.values()) == len(world.faces)
    assert world.vertices.dtype == np.float32 and world.faces.dtype == np.int32
    assert world.faces.min() >= 0 and world.faces.max() < len(world.vertices)
    assert world.vertices[:, 2].min() >= -1e-4  # everything stands on the ground
    again = W.build_world(SHARED / "scenes", target, seed=3)
    assert np.array_equal(world.vertices, again.vertices)
    assert np.array_equal(world.faces, again.faces)


def test_actors_are_rigid_and_seeded():
    moves = W.actor_transforms(9, 3, 200.0, seed=1)
    assert moves.shape == (3, 9, 4, 4)
    rotations = moves[..., :3, :3]
    eye = np.broadcast_to(np.eye(3), rotations.shape)
    assert np.allclose(rotations @ np.swapaxes(rotations, -1, -2), eye)
    assert np.all(np.abs(moves[..., 0, 3]) <= 100.0)
    assert not np.allclose(moves[0], moves[1])  # they move
    assert np.array_equal(moves, W.actor_transforms(9, 3, 200.0, seed=1))


def test_lidar_rays_are_the_servers():
    poses = W.lidar_poses(3, 2, 300.0)
    origins, directions = W.lidar_rays(poses)
    assert origins.shape == directions.shape == (3 * 64 * W.STEPS, 3)
    assert np.allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-6)
    assert np.array_equal(origins[0], poses[0][:3, 3].astype(np.float32))


def test_git_state_names_the_commit_and_uncommitted_changes(tmp_path):
    assert W.git_state(tmp_path) == {"commit": None, "dirty": None}  # not a checkout

    def git(*args):
        command = ["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t", *args]
        return subprocess.run(command, capture_output=True, text=True, check=True).stdout.strip()

    git("init", "-q")
    (tmp_path / "a.txt").write_text("one")
    git("add", "a.txt")
    git("commit", "-q", "-m", "one")
    head = git("rev-parse", "HEAD")
    (tmp_path / "new.txt").write_text("untracked")  # an untracked file leaves it clean
    assert W.git_state(tmp_path) == {"commit": head, "dirty": False}
    (tmp_path / "a.txt").write_text("two")
    assert W.git_state(tmp_path) == {"commit": head, "dirty": True}
    assert W.describe_code(W.git_state(tmp_path)) == f"commit {head[:7]}, with uncommitted changes"
    assert W.describe_code(None) == "commit unknown"  # a result written before the field
