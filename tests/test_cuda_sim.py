"""The CUDA backend under Numba's CUDA simulator: the same answers as the CPU engine.

The simulator must be chosen before numba is imported, so the comparison runs in a subprocess
(``cuda_sim_check.py``): closest, occluded, count and hits (lists truncated by a small
max_hits) on random soups (two meshes with masks; culling, masks, tmin/tmax, frontiers cut into
runs), and on a grid with rays through its vertices and edges over a coplanar duplicate of
itself (ties in t go to the lower mesh; each mesh crossed once); no rays, no triangles, and
hit lists over the device bound refused.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import dacrt
from dacrt.validation import InputError

CHECK = Path(__file__).with_name("cuda_sim_check.py")
PTX_CHECK = Path(__file__).with_name("cuda_ptx_check.py")
REPO = Path(__file__).resolve().parents[1]


def checkout_env(**extra: str) -> dict[str, str]:
    """The environment with this checkout's dacrt first on the path: a script's own folder
    (tests/) comes first otherwise, and an installed copy of the package would answer."""
    path = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    return {**os.environ, "PYTHONPATH": path, **extra}


def test_cuda_answers_match_cpu_under_simulator():
    done = subprocess.run(
        [sys.executable, str(CHECK)],
        env=checkout_env(NUMBA_ENABLE_CUDASIM="1"),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert done.stdout.rstrip().endswith("ok")


def test_cuda_kernels_compile_to_ptx_without_fused_float64_products():
    """Only where numba-cuda and its NVVM are installed (not in CI): see cuda_ptx_check.py."""
    pytest.importorskip("numba_cuda")
    done = subprocess.run(
        [sys.executable, str(PTX_CHECK)],
        env=checkout_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]


def test_cuda_refuses_unsupported_options():
    from dacrt import cuda as dcuda

    verts = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    placed = dacrt.Scene(
        [(verts, [[0, 1, 2]])],
        transforms=[[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]],
    )
    assert dcuda.lacks(placed) is None
    scene = dacrt.Scene([(verts, [[0, 1, 2]])])
    shifted = np.eye(4)
    shifted[:3, 3] = 1.0
    moving = dacrt.Scene([(verts, [[0, 1, 2]])], transforms_end=[shifted])
    assert dcuda.lacks(moving) is None and dcuda.lacks(scene) is None
    with pytest.raises(InputError, match="stats"):
        scene.closest([[0.2, 0.2, 1]], [[0, 0, -1]], device="cuda", stats=True)
    with pytest.raises(InputError, match="stats"):
        scene.hits([[0.2, 0.2, 1]], [[0, 0, -1]], device="cuda", stats=True)
    with pytest.raises(InputError, match="max_hits"):
        dcuda.hits(scene, [[0.2, 0.2, 1]], [[0, 0, -1]], max_hits=0)
    deforming = dacrt.Scene([(verts, [[0, 1, 2]])], vertices_end=[np.add(verts, 0.5)])
    assert dcuda.lacks(deforming) == "deforming meshes"
    with pytest.raises(InputError, match="vertices_end"):
        deforming.closest([[0.2, 0.2, 1]], [[0, 0, -1]], device="cuda")
    with pytest.raises(InputError, match="unknown device"):
        scene.occluded([[0.2, 0.2, 1]], [[0, 0, -1]], device="tpu")
    # strategy and threads do not apply on the GPU, but are checked as on the CPU
    for bad in ({"strategy": "bogus"}, {"threads": 0}, {"threads": 1.5}, {"threads": True}):
        with pytest.raises(InputError, match=next(iter(bad))):
            scene.closest([[0.2, 0.2, 1]], [[0, 0, -1]], device="cuda", **bad)
    for bad in (0, -5, 2.5, True):
        with pytest.raises(InputError, match="max_pairs"):
            dcuda.count(scene, [[0.2, 0.2, 1]], [[0, 0, -1]], max_pairs=bad)


def test_cuda_where_no_gpu_is_available_is_an_input_error(monkeypatch):
    """No CUDA driver, or no GPU it can use: InputError saying so, not the driver's error; the
    query's own checks come first."""
    from dacrt import cuda as dcuda
    from dacrt.cuda import query

    monkeypatch.setattr(query.cuda, "is_available", lambda: False)
    assert not dcuda.is_available()
    scene = dacrt.Scene([([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])])
    o, d = [[0.2, 0.2, 1]], [[0, 0, -1]]
    for query_name in ("closest", "occluded", "count", "hits"):
        with pytest.raises(InputError, match="device='cuda': no CUDA GPU is available"):
            getattr(scene, query_name)(o, d, device="cuda")
        with pytest.raises(InputError, match="no CUDA GPU is available"):
            getattr(dcuda, query_name)(scene, o, d)
    with pytest.raises(InputError, match="unknown strategy"):
        scene.closest(o, d, device="cuda", strategy="bogus")
    with pytest.raises(InputError, match=r"directions\[0\] is zero"):
        scene.closest(o, [[0, 0, 0]], device="cuda")
