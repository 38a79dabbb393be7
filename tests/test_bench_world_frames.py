"""``bench.world``'s engines on a small street (a ground grid, two box buildings, box cars): the
anchor and its copy that takes the rays in dynamic chunks give the same answers, each service
engine's frame makes a new engine scene on the server, and a run's JSON and report hold both
anchors' columns and the git commit. Nothing here is timed; the anchors' tests are skipped where
they cannot be compiled (no g++ or no Embree 3 headers)."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

import dacrt
import service.tracing
from bench import world as W
from bench.native_embree import AnchorUnavailable, build_anchor
from service.settings import Settings
from tests.service.in_process import serve

LENGTH = 60.0  # of the small street
CARS = 3


def small_world() -> W.World:
    """A ground grid and a box building each side of the street."""
    meshes = [W.grid_patch((-40.13, -30.07, 0.0), (80, 0, 0), (0, 60, 0), 40, 30)]
    for side in (-1.0, 1.0):
        y0, y1 = sorted(side * np.array([W.SIDEWALK[1], W.SIDEWALK[1] + 10]))
        meshes += W.box_building(-20.0, 5.0, y0, y1, 12.0)
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    vertices = np.concatenate([v for v, _ in meshes]).astype(np.float32)
    faces = np.concatenate([f + o for (_, f), o in zip(meshes, offsets)]).astype(np.int32)
    return W.World(vertices, faces, LENGTH, {"ground and boxes": len(faces)})


def box_car() -> tuple[np.ndarray, np.ndarray]:
    """A closed 4 x 2 x 1.5 m box on z = 0, centred on the z axis: 12 triangles."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
    vertices = ((corners - [0.5, 0.5, 0.0]) * [4.0, 2.0, 1.5]).astype(np.float32)
    faces = [[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4]]
    faces += [[2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]]
    return vertices, np.array(faces, np.int32)


@pytest.fixture(scope="module")
def build_dir(tmp_path_factory):
    """Both anchors compiled into one folder (``bench.world --build-dir``)."""
    folder = tmp_path_factory.mktemp("anchors")
    shared = W.find_shared()
    if shared is None:
        pytest.skip("no ../shared beside the repository (the anchor's source)")
    try:
        for source in (shared / "anchors" / "embree_instances.cpp", W.DYNAMIC_ANCHOR):
            build_anchor(source, folder)
    except AnchorUnavailable as exc:
        pytest.skip(str(exc))
    return folder


def test_the_dynamic_anchor_answers_as_the_anchor_and_the_engine(build_dir):
    world, car = small_world(), box_car()
    transforms = W.actor_transforms(CARS, 2, LENGTH)
    rays = [W.lidar_rays(W.lidar_poses(2, f, LENGTH)) for f in range(2)]
    answers = {}
    for name in ("embree_instances", "embree_instances_dynamic"):
        anchor = W.EmbreeAnchor(build_dir / name, world, car, threads=2)
        try:
            times, answers[name] = anchor.frame(list(transforms), rays)
        finally:
            anchor.close()
        assert times["trace"] > 0 and times["commit"] >= 0
    assert np.array_equal(answers["embree_instances"], answers["embree_instances_dynamic"])
    scene = dacrt.Scene(
        [(world.vertices, world.faces)] + [car] * CARS, transforms=[None, *transforms[1]]
    )
    ours = scene.closest(*rays[1]).t
    check = W.agreement(ours, answers["embree_instances_dynamic"], world.diagonal)
    assert check["agree"] > 0.999 and 0.2 < check["hit_share"] < 1.0


def test_each_service_engine_pays_a_frame_of_its_own(monkeypatch):
    """Each service engine's frame after the first changes its scene's engine scene with
    ``with_changes``: no frame reuses the engine scene of the version before (a frame with
    nothing to change), and the answers are dacrt's in process."""
    made = []  # (engine scene before, after) of every version changed from an earlier one
    changed = service.tracing.changed_engine_scene

    def counted(engine, meshes):
        after = changed(engine, meshes)
        made.append((engine.scene, after.scene if after is not None else None))
        return after

    monkeypatch.setattr(service.tracing, "changed_engine_scene", counted)
    world, car = small_world(), box_car()
    frames = 4
    transforms = W.actor_transforms(CARS, frames, LENGTH)
    poses_of = [W.lidar_poses(2, f, LENGTH) for f in range(frames)]
    rays_of = [W.lidar_rays(poses) for poses in poses_of]
    with serve(Settings(token=None, load_demo=False)) as http:
        through = W.ThroughService(world, car, CARS, 1, 1 << 20, http=http)
        assert through.has_rig and through.scenes == W.SERVICE_SCENES
        in_process = W.InProcess(dacrt, world, car, threads=1)
        runners = W.make_runners({}, in_process, through, transforms, rays_of, poses_of)
        record = W.run_frames(runners, frames, world.diagonal, in_process, "test")
        versions = {
            scene: http.get(f"/v1/scenes/{scene}").json()["version"]
            for scene in through.scenes.values()
        }
    assert set(record["frames"]) == {"dacrt", "dacrt changes", "service", "service rig"}
    assert record["service_identical"]
    # frame 0 builds each scene whole; every later frame of each engine changes its own
    assert len(made) == 2 * (frames - 1)
    assert all(after is not None and after is not before for before, after in made)
    assert len({id(after) for _, after in made}) == len(made)
    assert len(set(versions.values())) == 1  # as many versions in each engine's scene


def test_a_run_holds_both_anchors_and_its_commit(build_dir, tmp_path):
    out = tmp_path / "run"
    argv = ["--triangles", "1e5", "--lidars", "1", "--frames", "1", "--actors", "3"]
    argv += ["--engines", "embree,embree-dynamic,dacrt", "--build-dir", str(build_dir)]
    assert W.main([*argv, "--out", str(out)]) == 0
    result = json.loads((out / "world.json").read_text())
    head = git("rev-parse", "HEAD")
    dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    assert result["git"] == {"commit": head, "dirty": dirty}
    record = result["counts"]["1"]
    assert set(record["frames"]) == {"embree", "embree dynamic", "dacrt", "dacrt changes"}
    assert all(frame["trace"] > 0 for frame in record["frames"]["embree dynamic"])
    assert record["anchors_identical"] and record["checks"][0]["agree"] > 0.999
    table = (out / "world.md").read_text()
    assert f"commit {head[:7]}" in table
    assert "Embree two-level, rays in dynamic chunks" in table
    assert "Embree / it, Embree dynamic / it" in table
    assert "Answers of Embree dynamic identical to Embree's: 1 lidars yes" in table


def git(*args: str) -> str:
    """A git command's output in this checkout."""
    folder = W.REPO
    return subprocess.run(
        ["git", "-C", str(folder), *args], capture_output=True, text=True, check=True
    ).stdout.strip()
