"""What transforms save a dynamic scene: 100 moving copies of one mesh, moved every frame.

    python -m bench.instances [--grid 71] [--copies 100] [--repeat 20] [--rays 1000]

One real uvicorn server on loopback holds two scenes of the same mesh (a bumpy ``--grid`` grid,
``2 * grid**2`` triangles: 10,082 with the default) placed ``--copies`` times:
  transforms  the mesh uploaded once and ``--copies`` instances of it; a frame is one
              ``POST .../frame`` .npz of ``carNNN.transform`` (4, 4) float64 matrices
  vertices    ``--copies`` meshes of their own; a frame is one ``POST .../frame`` .npz of
              ``carNNN.vertices`` (V, 3) float32, placed in numpy by the client beforehand
Every round moves every copy by new random rigid placements (the same in both scenes) and times,
side by side (the order swapped every round, after two untimed rounds), medians of ``--repeat``:
  frame           encoding the body, the request and the answer (the client's numpy placement of
                  the vertices, done before, is shown apart)
  frame + query   the frame, then ``closest`` of ``--rays`` rays: the first query of a version
                  builds its engine scene, which places the instances' vertices
and the bytes each frame sends. Both scenes answer the same rays identically (checked).
"""

from __future__ import annotations

import argparse
import io
import statistics
import time

import httpx
import numpy as np

from bench.http_overhead import cpu_model, start_server
from bench.persistence import grid

NPZ = {"Content-Type": "application/x-npz"}
NPY = {"Content-Type": "application/x-npy"}


def npz(**arrays: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.savez(out, **arrays)
    return out.getvalue()


def placements(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4, 4) float64 rigid placements: a random rotation each, spread over a 40 x 40 area."""
    rotations, _ = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    matrices = np.tile(np.eye(4), (n, 1, 1))
    matrices[:, :3, :3] = rotations
    matrices[:, :3, 3] = rng.uniform([-20, -20, -1], [20, 20, 1], (n, 3))
    return matrices


def place(vertices: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return (vertices.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--grid", type=int, default=71)
    parser.add_argument("--copies", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--rays", type=int, default=1000)
    args = parser.parse_args()
    rng = np.random.default_rng(7)
    vertices, faces = grid(args.grid)
    vertices[:, 2] = rng.uniform(0, 0.05, len(vertices))  # bumpy, so rotations matter
    names = [f"car{i:03}" for i in range(args.copies)]
    origins = np.zeros((args.rays, 3), np.float32) + np.float32([0, 0, 30])
    targets = rng.uniform([-20, -20, -1], [20, 20, 1], (args.rays, 3))
    rays = npz(origins=origins, directions=(targets - origins).astype(np.float32))
    process, url = start_server({"DACRT_LOAD_DEMO": "false"})
    seconds: dict[str, list[float]] = {
        f"{scene} {what}": [] for scene in ("transforms", "vertices") for what in ("frame", "+q")
    }
    sent: dict[str, int] = {}
    placing: list[float] = []
    try:
        with httpx.Client(base_url=url, timeout=300) as http:
            first = placements(rng, args.copies)
            mesh = npz(vertices=vertices, faces=faces)
            for scene in ("transforms", "vertices"):  # "car" is mesh 0, copy i mesh i + 1
                http.put(f"/v1/scenes/{scene}/meshes/car", content=mesh, headers=NPZ)
            made = {f"{name}.instance_of": "car" for name in names}
            made |= {f"{name}.transform": m.tolist() for name, m in zip(names, first)}
            http.post("/v1/scenes/transforms/frame", json=made).raise_for_status()
            copies = {f"{name}.vertices": place(vertices, m) for name, m in zip(names, first)}
            copies |= {f"{name}.faces": faces for name in names}
            http.post("/v1/scenes/vertices/frame", content=npz(**copies), headers=NPZ)
            for round_ in range(args.repeat + 2):
                matrices = placements(rng, args.copies)
                start = time.perf_counter()
                moved = [place(vertices, m) for m in matrices]
                placing.append(time.perf_counter() - start)
                answers = {}
                order = ("transforms", "vertices") if round_ % 2 else ("vertices", "transforms")
                for scene in order:
                    start = time.perf_counter()
                    if scene == "transforms":
                        body = npz(**{f"{n}.transform": m for n, m in zip(names, matrices)})
                    else:
                        body = npz(**{f"{n}.vertices": v for n, v in zip(names, moved)})
                    http.post(f"/v1/scenes/{scene}/frame", content=body, headers=NPZ)
                    framed = time.perf_counter()
                    answer = http.post(f"/v1/scenes/{scene}/closest", content=rays, headers=NPZ)
                    done = time.perf_counter()
                    answer.raise_for_status()
                    answers[scene] = dict(np.load(io.BytesIO(answer.content)))
                    sent[scene] = len(body)
                    if round_ >= 2:
                        seconds[f"{scene} frame"].append(framed - start)
                        seconds[f"{scene} +q"].append(done - start)
                for key in ("t", "mesh", "prim"):
                    np.testing.assert_array_equal(
                        answers["transforms"][key], answers["vertices"][key]
                    )
    finally:
        process.terminate()
        process.wait()
    print(
        f"{args.copies} copies of a {len(faces):,}-triangle mesh ({len(vertices):,} vertices) "
        f"moved by one POST .../frame, {args.repeat} rounds, medians; CPU: {cpu_model()}"
    )
    print(f"  {'':12s} {'frame':>10s} {'frame + query':>15s} {'bytes sent':>12s}")
    for scene in ("transforms", "vertices"):
        frame = 1000 * statistics.median(seconds[f"{scene} frame"])
        query = 1000 * statistics.median(seconds[f"{scene} +q"])
        print(f"  {scene:12s} {frame:8.2f} ms {query:12.2f} ms {sent[scene]:12,d}")
    print(
        f"  the client's numpy placement of the {args.copies} copies' vertices (vertices only): "
        f"{1000 * statistics.median(placing):.2f} ms; query: {args.rays} rays, answers identical"
    )


if __name__ == "__main__":
    main()
