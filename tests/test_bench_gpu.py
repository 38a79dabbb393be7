"""``bench.gpu``, the device machine's prepared run: each row leaves each device's first query
out of its medians, and the whole run goes through under Numba's CUDA simulator (a subprocess:
the simulator must be chosen before numba is imported) on a scene folder of one small mesh."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

import dacrt.cache
from bench import gpu

REPO = Path(__file__).resolve().parents[1]
FIRST_CALL_S = 0.3  # what each device's first query costs in the fake scene


class FirstCallSlow:
    """A scene whose first ``closest`` on each device takes ``FIRST_CALL_S`` (a compile), the
    later ones nothing; it notes every call's device."""

    def __init__(self, n_rays: int):
        self.calls = []
        self.answer = SimpleNamespace(
            t=np.linspace(1, 2, n_rays, dtype=np.float32),
            mesh=np.zeros(n_rays, np.int32),
            prim=np.arange(n_rays, dtype=np.int32),
        )

    def closest(self, origins, directions, device="cpu"):
        if device not in self.calls:
            time.sleep(FIRST_CALL_S)
        self.calls.append(device)
        return self.answer


def test_a_row_leaves_each_devices_first_query_out():
    scene = FirstCallSlow(8)
    rays = np.zeros((8, 3), np.float32)
    gpu_s, cpu_s, differ = gpu.measure(scene, rays, rays, frames=5, cpu_frames=5)
    assert scene.calls == ["cuda"] * 6 + ["cpu"] * 6  # one untimed query on each, then 5
    assert gpu_s < FIRST_CALL_S / 3 and cpu_s < FIRST_CALL_S / 3
    assert differ == 0


def test_the_run_goes_through_under_the_cuda_simulator(tmp_path):
    # a closed box around Sibenik's view (scenes/views.json): every primary ray hits it
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
    vertices = ((corners - 0.5) * 2000).astype(np.float32)
    faces = [[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4]]
    faces += [[2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]]
    np.savez(tmp_path / "sibenik.npz", vertices=vertices, faces=np.array(faces, np.int32))
    path = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    done = subprocess.run(
        [sys.executable, "-m", "bench.gpu", "--scenes", str(tmp_path), "--rays", "64,128"],
        env={**os.environ, "PYTHONPATH": path, "NUMBA_ENABLE_CUDASIM": "1"},
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    out = done.stdout
    assert done.returncode == 0, out[-3000:] + done.stderr[-3000:]
    # the CPU kernels, filed where the tests' are, compiled or loaded before the first row
    assert f"(kernels in {dacrt.cache.chosen_cache_dir()})" in out
    rows = [line.split(" | ") for line in out.splitlines() if line.startswith("sibenik |")]
    assert [(row[1], row[2], row[5]) for row in rows] == [("12", "64", "0"), ("12", "128", "0")]
    assert "sponza: no " in out and "world: cannot build it" in out
