"""hits and count through a real server: what a 1M-ray request costs, split by Server-Timing.

    python -m bench.http_hits [SCENE.npz] [--rays 1000000] [--max-hits 16] [--repeat 3]
                              [--fields t,mesh,prim]

Starts ``uvicorn service.app:create_app`` on loopback, uploads the scene, and sends the same
random rays (origins uniform in the scene's box, directions uniform on the sphere: the rays of
``bench.rays.random_rays``) as one ``.npy`` body to ``/hits?max_hits=K`` and to ``/count``,
answers ``.npz``, through ``service.client``. In the same rounds, alternating, the engine's own
``Scene.hits`` and ``Scene.count`` in this process (the scene built once, as the server caches
it). Medians of ``--repeat`` rounds after one untimed round. Prints, per query, the client's wall
time, the server's receive / decode / trace / encode, the engine's time, the answer's bytes and
the hits it holds.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from bench import rays as R
from bench.entry import description, use_kernel_cache
from bench.http_overhead import start_server
from bench.scene_io import load_mesh, mesh_bounds

REPO = Path(__file__).resolve().parent.parent


def main() -> None:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("scene", nargs="?", default=str(REPO.parent / "shared/scenes/sibenik.npz"))
    parser.add_argument("--rays", type=int, default=1_000_000)
    parser.add_argument("--max-hits", type=int, default=16)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--fields", help="?fields= of the hits requests (default: every key)")
    args = parser.parse_args()

    import dacrt
    from service.client import Client

    use_kernel_cache()
    vertices, faces = load_mesh(args.scene)
    rays = R.random_rays(mesh_bounds(vertices, faces), args.rays, np.random.default_rng(0))
    engine = dacrt.Scene([(vertices, faces)])
    process, url = start_server({"DACRT_LOAD_DEMO": "false"})
    rows: dict[str, dict[str, list[float]]] = {}
    try:
        with Client(url) as client:
            client.put_mesh("bench", "scene", vertices, faces)
            queries = {
                "hits": (
                    lambda: client.hits(
                        "bench",
                        rays.origins,
                        rays.directions,
                        max_hits=args.max_hits,
                        fields=args.fields,
                    ),
                    lambda: engine.hits(rays.origins, rays.directions, max_hits=args.max_hits),
                ),
                "count": (
                    lambda: client.count("bench", rays.origins, rays.directions),
                    lambda: engine.count(rays.origins, rays.directions),
                ),
            }
            for round_ in range(args.repeat + 1):
                for name, (over_http, in_process) in queries.items():
                    start = time.perf_counter()
                    answer = over_http()
                    wall = time.perf_counter() - start
                    start = time.perf_counter()
                    in_process()
                    alone = time.perf_counter() - start
                    if round_ == 0:
                        continue  # untimed: the server's first answer of each kind
                    row = rows.setdefault(name, {})
                    for key, value in {
                        "wall": wall * 1000,
                        **answer.timing,
                        "engine": alone * 1000,
                        "bytes": sum(array.nbytes for array in answer.values()),
                    }.items():
                        row.setdefault(key, []).append(value)
                    if name == "hits":
                        row.setdefault("hits", []).append(int(answer.offsets[-1]))
                        truncated = answer.truncated.sum() if "truncated" in answer else -1
                        row.setdefault("truncated", []).append(int(truncated))
    finally:
        process.terminate()
        process.wait()

    print(
        f"{Path(args.scene).stem}: {len(faces)} triangles, {args.rays} random rays, "
        f"max_hits={args.max_hits}, fields={args.fields or 'all'}, medians of {args.repeat}"
    )
    keys = ("wall", "receive", "decode", "trace", "encode", "engine")
    print(f"{'query':6} " + " ".join(f"{k + ' ms':>11}" for k in keys) + f" {'answer MB':>10}")
    for name, row in rows.items():
        cells = " ".join(f"{statistics.median(row[k]):11.1f}" for k in keys)
        extra = ""
        if name == "hits":
            extra = (
                f"  ({statistics.median(row['hits']):.0f} hits, "
                f"{statistics.median(row['truncated']):.0f} rays truncated)"
            )
        print(f"{name:6} {cells} {statistics.median(row['bytes']) / 1e6:10.1f}{extra}")


if __name__ == "__main__":
    main()
