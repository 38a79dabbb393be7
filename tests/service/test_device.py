"""DACRT_DEVICE=cuda: queries traced by the CUDA backend where it answers them (the same answers
as the CPU's, under Numba's CUDA simulator in a subprocess), and on the CPU, naming what the
backend lacks, where it does not."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
from service_helpers import REPO, quad

import dacrt.cache
from service import tracing, wire
from service.options import Sensor, make_options

IDENTITY = np.eye(4)
SHIFTED = np.eye(4)
SHIFTED[:3, 3] = 1.0


def rays(**extra) -> wire.Rays:
    origins = np.array([[0.5, 0.5, 1], [2.5, 0.5, 1], [1.0, 1.0, 1]], np.float32)
    return wire.Rays(origins, np.tile(np.float32([0, 0, -1]), (3, 1)), None, None, **extra)


def test_the_cpu_traces_what_the_cuda_backend_lacks_and_says_what():
    vertices, faces = quad(0, 1, 0, 1, 0)
    plain = tracing.build_engine_scene([(0, vertices, faces)])
    placed = tracing.build_engine_scene([(0, vertices, faces, 1, IDENTITY, SHIFTED)])
    deforming = tracing.build_engine_scene([(0, vertices, faces, 1, None, None, vertices + 1)])
    for kind in ("closest", "occluded", "hits", "count"):
        cuda = make_options(kind, device="cuda")
        assert tracing.device_for(plain, cuda, "process") == ("cuda", None)
        assert tracing.device_for(placed, cuda, "process") == ("cuda", None)  # moving too
        assert tracing.device_for(deforming, cuda, "process") == ("cpu", "deforming meshes")
        assert tracing.device_for(plain, cuda, "cluster") == ("cpu", "cluster")
        assert tracing.device_for(plain, make_options(kind), "process") == ("cpu", None)
    stats = make_options("hits", stats=True, device="cuda")
    assert tracing.device_for(plain, stats, "process") == ("cpu", "stats")


def test_sensors_go_to_the_gpu_where_the_backend_answers():
    vertices, faces = quad(0, 1, 0, 1, 0)
    placed = tracing.build_engine_scene([(0, vertices, faces, 1, IDENTITY, SHIFTED)])
    deforming = tracing.build_engine_scene([(0, vertices, faces, 1, None, None, vertices + 1)])
    for kind in (Sensor.LIDAR, Sensor.CAMERA, Sensor.RENDER, Sensor.RIG):
        cuda = make_options(kind, device="cuda")
        assert tracing.device_for(placed, cuda, "process") == ("cuda", None)
        assert tracing.device_for(placed, make_options(kind), "process") == ("cpu", None)
        assert tracing.device_for(deforming, cuda, "process") == ("cpu", "deforming meshes")
    stats = make_options(Sensor.LIDAR, stats=True, device="cuda")
    assert tracing.device_for(placed, stats, "process") == ("cpu", "stats")


# Run under the simulator: DACRT_DEVICE=cuda is accepted, and its answers are the CPU's.
UNDER_SIMULATOR = """
import numpy as np
from service_helpers import quad

import dacrt.cache
from service import tracing, wire
from service.options import make_options
from service.settings import load_settings
from service.store import Store

settings = load_settings()
assert settings.device == "cuda", settings.device
dacrt.cache.use_cache_dir(settings.cache_dir)  # the CPU kernels the tests' warm-up compiled
store = Store(2**20, 2**30)
for name, x in (("a", 0), ("b", 1)):
    store.put_mesh("s", name, wire.mesh_arrays(*quad(x, x + 1, 0, 1, 0)))
# Through a quad's middle, its shared diagonal's end, the edge between the quads, and beside.
origins = np.array([[0.5, 0.5, 1], [1, 1, 1], [1, 0.5, 1], [0.25, 0.75, 1], [3, 3, 1]], np.float32)
rays = wire.Rays(origins, np.tile(np.float32([0, 0, -1]), (5, 1)), None, None)
for kind, stats in (("closest", False), ("count", False), ("hits", False), ("closest", True)):
    gpu = tracing.trace(
        store.snapshot("s"), rays, make_options(kind, stats=stats, device=settings.device)
    )
    cpu = tracing.trace(store.snapshot("s"), rays, make_options(kind, stats=stats))
    assert gpu.fallback == ("stats" if stats else None), gpu.fallback
    assert gpu.arrays.keys() == cpu.arrays.keys()
    for name, array in gpu.arrays.items():
        assert array.dtype == cpu.arrays[name].dtype, name
        assert array.tobytes() == cpu.arrays[name].tobytes(), (kind, name)
    print(kind, "stats" if stats else "", {k: v.tolist() for k, v in gpu.arrays.items()})
# A lidar above the quads, on the GPU and on the CPU: the same points.
from dacrt.sensors import Lidar
from service import sensing
from service.options import Sensor

pose = np.eye(4)
pose[:3, 3] = (1.0, 0.5, 0.5)
lidar = Lidar(vertical_angles_deg=[-60, -30], horizontal_steps=8)
gpu = sensing.sense(store.snapshot("s"), lidar, pose, make_options(Sensor.LIDAR, device="cuda"))
cpu = sensing.sense(store.snapshot("s"), lidar, pose, make_options(Sensor.LIDAR))
assert gpu.fallback is None and len(cpu.arrays["range"]) > 0
for name, array in cpu.arrays.items():
    assert array.tobytes() == gpu.arrays[name].tobytes(), ("lidar", name)
print("ok")
"""


def test_cuda_device_answers_as_the_cpu_under_the_simulator():
    env = {
        **{k: v for k, v in os.environ.items() if not k.startswith("DACRT_")},
        "NUMBA_ENABLE_CUDASIM": "1",
        "DACRT_DEVICE": "cuda",
        "DACRT_CACHE_DIR": str(dacrt.cache.chosen_cache_dir()),
        "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "tests" / "service")]),
    }
    done = subprocess.run(
        [sys.executable, "-c", UNDER_SIMULATOR],
        env=env,
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert done.stdout.rstrip().endswith("ok")
    # Along a diagonal and the quads' shared edge one crossing; the outline's corner (1, 1) none.
    assert "count  {'count': [1, 0, 1, 1, 0]}" in done.stdout, done.stdout
