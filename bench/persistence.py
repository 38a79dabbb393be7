"""What persistence (DACRT_DATA_DIR) costs a per-frame vertex update.

    python -m bench.persistence [--grid 362] [--repeat 30]

Two real uvicorn servers side by side, one in memory and one with a data folder (here a
temporary folder on the disk of ``--data``), each holding the same grid mesh (``2 * grid**2``
triangles: 262,088 with the default). Each round sends ``PUT .../vertices`` (.npy, the grid moved
a little) to both, the order swapped every round, after two untimed rounds; medians of
``--repeat`` rounds of the request's wall time and of the store's part of it. With persistence
the update writes the vertex array as one .npy and the scene's manifest, each fsynced with its
folder; the faces are never rewritten.
"""

from __future__ import annotations

import argparse
import io
import statistics
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

from bench.entry import description
from bench.http_overhead import cpu_model, start_server


def grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """An n x n grid of quads: 2 n^2 triangles."""
    xs = np.linspace(0.0, 1.0, n + 1, dtype=np.float32)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size, np.float32)], axis=1)
    ids = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = (
        ids[:-1, :-1].ravel(),
        ids[1:, :-1].ravel(),
        ids[1:, 1:].ravel(),
        ids[:-1, 1:].ravel(),
    )
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    return vertices, faces


def npy(array: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.save(out, array)
    return out.getvalue()


def main() -> None:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--grid", type=int, default=362)
    parser.add_argument("--repeat", type=int, default=30)
    parser.add_argument("--data", default=tempfile.gettempdir(), help="where the data folder goes")
    args = parser.parse_args()
    vertices, faces = grid(args.grid)
    mesh = io.BytesIO()
    np.savez(mesh, vertices=vertices, faces=faces)
    with tempfile.TemporaryDirectory(dir=args.data) as data:
        servers = {
            "memory": start_server({"DACRT_LOAD_DEMO": "false"}),
            "persisted": start_server({"DACRT_LOAD_DEMO": "false", "DACRT_DATA_DIR": data}),
        }
        times: dict[str, list[float]] = {name: [] for name in servers}
        try:
            clients = {
                name: httpx.Client(base_url=url, timeout=60) for name, (_, url) in servers.items()
            }
            for client in clients.values():
                client.put(
                    "/v1/scenes/b/meshes/grid",
                    content=mesh.getvalue(),
                    headers={"Content-Type": "application/x-npz"},
                ).raise_for_status()
            for round_ in range(args.repeat + 2):
                moved = npy(vertices + np.float32(0.001 * round_))
                order = list(clients) if round_ % 2 else list(reversed(clients))
                for name in order:
                    start = time.perf_counter()
                    clients[name].put(
                        "/v1/scenes/b/meshes/grid/vertices",
                        content=moved,
                        headers={"Content-Type": "application/x-npy"},
                    ).raise_for_status()
                    if round_ >= 2:
                        times[name].append(time.perf_counter() - start)
            files = sorted(p.name for p in Path(data).rglob("*") if p.is_file())
        finally:
            for process, _ in servers.values():
                process.terminate()
                process.wait()
    print(
        f"PUT vertices of a {len(faces):,}-triangle mesh ({len(vertices):,} vertices, "
        f"{len(moved):,} bytes of .npy), {args.repeat} rounds, medians; CPU: {cpu_model()}"
    )
    for name, values in times.items():
        print(
            f"  {name:10s} {1000 * statistics.median(values):7.2f} ms  "
            f"(min {1000 * min(values):.2f}, max {1000 * max(values):.2f})"
        )
    print("  data folder after the updates:", ", ".join(files))


if __name__ == "__main__":
    main()
