"""A real server killed with SIGKILL in the middle of a stream of acknowledged changes, restarted
on the same DACRT_DATA_DIR: every acknowledged change is there with its version, identical rays
get identical answers, and versions are not reused."""

from __future__ import annotations

import io
import threading
import time

import httpx
import numpy as np
from server_process import ServerProcess
from service_helpers import NPY, NPZ, down_rays, grid, npy_bytes, npz_bytes

#: Acknowledged changes before the kill.
CHANGES_BEFORE_KILL = 24
RAYS = npy_bytes(np.hstack(down_rays(np.random.default_rng(1).uniform(0, 1, (64, 2)))))


def answer(http: httpx.Client, scene: str) -> tuple[int, dict[str, np.ndarray]]:
    response = http.post(f"/v1/scenes/{scene}/closest", content=RAYS, headers=NPY)
    response.raise_for_status()
    with np.load(io.BytesIO(response.content)) as archive:
        return int(response.headers["X-Scene-Version"]), dict(archive)


class Stream:
    """Uploads and vertex updates over three scenes, one at a time, each answered (2xx) change
    recorded with its version, then a query of the scene recorded with its answer."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.scene_versions: dict[str, int] = {}
        self.mesh_versions: dict[tuple[str, str], int] = {}
        self.answers: dict[str, tuple[int, dict[str, np.ndarray]]] = {}
        self.acknowledged = 0
        self.error: Exception | None = None
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        last_mesh: dict[str, str] = {}
        try:
            with httpx.Client(base_url=self.url, timeout=30) as http:
                for step in range(10_000):
                    scene = f"s{step % 3}"
                    vertices, faces = grid(12, z=0.01 * step)
                    if step % 2 and scene in last_mesh:
                        mesh = last_mesh[scene]
                        path = f"/v1/scenes/{scene}/meshes/{mesh}/vertices"
                        response = http.put(path, content=npy_bytes(vertices), headers=NPY)
                    else:
                        mesh = last_mesh[scene] = f"m{step // 6}"
                        body = npz_bytes(vertices=vertices, faces=faces)
                        path = f"/v1/scenes/{scene}/meshes/{mesh}"
                        response = http.put(path, content=body, headers=NPZ)
                    response.raise_for_status()
                    version = response.json()["version"]
                    self.scene_versions[scene] = self.mesh_versions[scene, mesh] = version
                    self.acknowledged += 1
                    self.answers[scene] = answer(http, scene)
        except (httpx.TransportError, httpx.HTTPStatusError) as exc:
            self.error = exc  # the kill


def test_acknowledged_changes_survive_sigkill(tmp_path):
    env = {"DACRT_DATA_DIR": str(tmp_path / "data")}
    first = ServerProcess(env)
    try:
        stream = Stream(first.wait_ready())
        deadline = time.monotonic() + 120
        while stream.acknowledged < CHANGES_BEFORE_KILL and time.monotonic() < deadline:
            time.sleep(0.005)
        first.kill()  # while the stream has its next change in flight
        stream.thread.join(timeout=60)
    finally:
        first.stop()
    assert stream.acknowledged >= CHANGES_BEFORE_KILL and stream.error is not None

    second = ServerProcess(env)
    try:
        url = second.wait_ready()
        with httpx.Client(base_url=url, timeout=30) as http:
            compared = 0
            for scene, acknowledged in stream.scene_versions.items():
                info = http.get(f"/v1/scenes/{scene}").json()
                # the change in flight at the kill may have become durable, unacknowledged
                assert info["version"] in (acknowledged, acknowledged + 1), (scene, info)
                if info["version"] != acknowledged:
                    continue
                meshes = {m["mesh"]: m["version"] for m in info["meshes"]}
                for (in_scene, mesh), version in stream.mesh_versions.items():
                    if in_scene == scene:
                        assert meshes[mesh] == version, (scene, mesh, meshes)
                recorded_version, recorded = stream.answers.get(scene, (None, None))
                if recorded_version == acknowledged:
                    version, arrays = answer(http, scene)
                    assert version == acknowledged and arrays.keys() == recorded.keys()
                    for key in recorded:
                        np.testing.assert_array_equal(arrays[key], recorded[key], err_msg=key)
                    compared += 1
            assert compared >= 2
            vertices, faces = grid(2)
            body = npz_bytes(vertices=vertices, faces=faces)
            for scene in stream.scene_versions:
                before = http.get(f"/v1/scenes/{scene}").json()["version"]
                put = http.put(f"/v1/scenes/{scene}/meshes/new", content=body, headers=NPZ)
                assert put.json()["version"] == before + 1  # never a version seen before
        assert "data: restored 3 scenes" in second.output()
    finally:
        second.stop()
