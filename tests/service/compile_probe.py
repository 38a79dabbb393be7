"""Run as a script in a fresh process: once the in-process app says ready, send the first request
of every kind and print (JSON) the Numba kernels that compiled for it: ``{}`` when the warm-up
covered them all. Counting each dispatcher's signatures needs no timing."""

from __future__ import annotations

import importlib
import json
import pkgutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parents[1])]

import in_process  # noqa: E402
import numpy as np  # noqa: E402
from numba.core.registry import CPUDispatcher  # noqa: E402
from service_helpers import NPY, NPZ, npy_bytes, npz_bytes, quad  # noqa: E402

import dacrt  # noqa: E402
from service.settings import Settings  # noqa: E402


def signature_counts() -> dict[str, int]:
    counts = {}
    for module in pkgutil.walk_packages(dacrt.__path__, "dacrt."):
        for value in vars(importlib.import_module(module.name)).values():
            if isinstance(value, CPUDispatcher):
                name = f"{value.py_func.__module__}.{value.py_func.__qualname__}"
                counts[name] = len(value.signatures)
    return counts


NPZ_TYPE = NPZ["Content-Type"]


def mesh_files() -> dict[str, bytes]:
    """A quad as every mesh file format the service reads."""
    import trimesh

    vertices, faces = quad(0, 1, 0, 1, 0)
    square = trimesh.Trimesh(vertices, faces, process=False)
    files = {fmt: square.export(file_type=fmt) for fmt in ("ply", "stl", "glb")}
    files["obj"] = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
    files["off"] = b"OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"
    return {fmt: data if isinstance(data, bytes) else data.encode() for fmt, data in files.items()}


def first_requests(http) -> None:
    vertices, faces = quad(0, 1, 0, 1, 0)
    rays = np.array([[0.3, 0.6, 1, 0, 0, -1, 0, 5], [3, 3, 1, 0, 0, -1, 0, 5]], np.float32)
    mesh = {"vertices": vertices.tolist(), "faces": faces.tolist()}
    rays_json = {"origins": rays[:, :3].tolist(), "directions": rays[:, 3:6].tolist()}
    sent = [
        http.put(
            "/v1/scenes/p/meshes/npz",
            content=npz_bytes(vertices=vertices, faces=faces),
            headers=NPZ,
        ),
        http.put("/v1/scenes/p/meshes/json", json=mesh),
        http.put("/v1/scenes/p/meshes/npz/vertices", content=npy_bytes(vertices + 1), headers=NPY),
        http.post("/v1/scenes/p/frame", json={"json.vertices": (vertices + 2).tolist()}),
    ]
    for fmt, data in mesh_files().items():
        sent.append(http.put(f"/v1/scenes/p/meshes/{fmt}", content=data, params={"format": fmt}))
    sent.append(http.put("/v1/scenes/p/meshes/masked?mask=0x2", json=mesh))
    sent.append(http.put("/v1/scenes/p/meshes/json/transform", json={"matrix": np.eye(4).tolist()}))
    for query in ("closest", "occluded", "hits", "count"):
        for body in (npy_bytes(rays[:, :6]), npy_bytes(rays)):
            sent.append(http.post(f"/v1/scenes/p/{query}", content=body, headers=NPY))
        sent.append(http.post(f"/v1/scenes/p/{query}", json=rays_json))
        sent.append(http.post(f"/v1/scenes/p/{query}", json={**rays_json, "mask": [1, 2]}))
        sent.append(http.post(f"/v1/scenes/p/{query}?cull=back&mask=0x2", json=rays_json))
        sent.append(http.post(f"/v1/trace?query={query}", json={**mesh, **rays_json}))
    from dacrt.chunks import MIN_RAYS_PER_THREAD  # batches this big run on several threads

    scattered = np.random.default_rng(0).uniform(-1, 2, (4 * MIN_RAYS_PER_THREAD, 8))
    scattered[:, 6:] = [0, 10]
    for columns in (6, 8):
        body = npy_bytes(scattered[:, :columns].astype(np.float32))
        sent.append(http.post("/v1/scenes/p/closest", content=body, headers=NPY))
    sent.append(http.post("/v1/scenes/p/closest?stats=true", content=npy_bytes(rays), headers=NPY))
    for accept in ("application/x-npy", "application/json"):
        sent.append(
            http.post(
                "/v1/scenes/p/closest", content=npy_bytes(rays), headers={**NPY, "Accept": accept}
            )
        )
    look = {"width": 64, "height": 48, "eye": [0.5, 0.5, 3], "target": [0.5, 0.5, 0]}
    for shading in ("depth", "normal", "shaded"):
        sent.append(http.post("/v1/scenes/p/render", json={**look, "shading": shading}))
    sent.append(http.post("/v1/scenes/p/camera", json=look))
    pose = [[1, 0, 0, 0.5], [0, 1, 0, 0.5], [0, 0, 1, 1], [0, 0, 0, 1]]
    for returns in (1, 3):
        lidar = {"pose": pose, "model": "VLP-16", "horizontal_steps": 2048, "max_returns": returns}
        sent.append(http.post("/v1/scenes/p/lidar", json=lidar, headers={"Accept": NPZ_TYPE}))
    bad = [(r.request.url.path, r.status_code, r.text) for r in sent if r.status_code >= 300]
    assert not bad, bad


def main() -> None:
    with in_process.serve(Settings(token=None, load_demo=False)) as http:
        before = signature_counts()
        first_requests(http)
        after = signature_counts()
    print(json.dumps({k: [before.get(k, 0), n] for k, n in after.items() if n != before.get(k)}))


if __name__ == "__main__":
    main()
