"""Scale-out benchmark of ``dacrt.distributed``: ``python -m bench.dask``.

For each scene (Sibenik, Sponza by default), ray kind (primary, random) and batch size (4M, 16M),
closest hits are traced on a LocalCluster of 1 worker and of 2 workers (processes, one thread
each), the median of ``--repeats`` runs side by side, with the speed-up. Each run reports where its
time went: scattering the rays (send) and the workers' traces (trace, summed over shards); they
overlap (a shard is traced while the next is sent), and the answers come back after each trace.
Per scene: the seconds to send the triangles to the workers and build each worker's Scene.
``--shards`` first measures one thread's throughput against the shard size, the figure behind
``dacrt.distributed.MIN_SHARD_RAYS``.

Then, on paper: the bytes of a scene version and of a shard, and what they predict for 8 and 32
machines on a 10 Gbit/s network, each machine tracing at the measured 2-worker rate.

Needs the ``dask`` extra. The machine may be shared: quote medians and ratios of one run, with
the 1-minute load average printed beside each (above the machine's cores, other work took CPU).
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import time
from pathlib import Path

import numpy as np

from bench import rays as ray_gen
from bench.entry import DASK_PRELOAD, description, kernel_cache_env, use_kernel_cache
from bench.scene_io import load_mesh, load_view, mesh_bounds

SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
#: bytes over the wire per ray: origins, directions, tmin, tmax in; a closest answer out
RAY_BYTES_IN = 4 * (3 + 3 + 1 + 1)
CLOSEST_BYTES_OUT = 4 * (1 + 1 + 1 + 1 + 1 + 3)
LINK_BYTES_PER_S = 10e9 / 8  # 10 Gbit/s


def parse_count(text: str) -> int:
    text = text.strip().upper()
    scale = {"K": 10**3, "M": 2**20}.get(text[-1:], 1)
    return int(float(text.rstrip("KM")) * scale)


def make_rays(kind, vertices, faces, n, seed, path):
    rng = np.random.default_rng(seed)
    bounds = mesh_bounds(vertices, faces)
    if kind == "random":
        return ray_gen.random_rays(bounds, n, rng)
    _, view = load_view(path, bounds)
    width, height = ray_gen.image_size(n)
    return ray_gen.primary_rays(view, width, height, rng, n_rays=n)


def cluster(n_workers):
    import distributed

    local = distributed.LocalCluster(
        n_workers=n_workers,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":0",  # never a fixed port: other clusters may run
        silence_logs=logging.ERROR,
        preload=DASK_PRELOAD,  # each worker loads the kernels from this process's folder
        env=kernel_cache_env(),
    )
    return local, distributed.Client(local)


def shard_sizes(vertices, faces, path, sizes):
    """One thread's Mrays/s tracing random rays in shards of each size (in process)."""
    import dacrt

    scene = dacrt.Scene([(vertices, faces)])
    total = max(sizes)
    rays = make_rays("random", vertices, faces, total, 7, path)
    print(f"\nshard size against one thread's throughput ({path.stem}, random rays, {total:,})")
    for size in sizes:
        start = time.perf_counter()
        for a in range(0, total, size):
            scene.closest(rays.origins[a : a + size], rays.directions[a : a + size], threads=1)
        seconds = time.perf_counter() - start
        print(f"  shards of {size:>9,}: {total / seconds / 1e6:6.2f} Mrays/s")


def run(args):
    from dacrt.distributed import DistributedScene

    counts = [parse_count(c) for c in args.rays.split(",")]
    rows, scenes = [], {}
    meshes = {name: load_mesh(SCENES / f"{name}.npz") for name in args.scenes.split(",")}
    if args.shards:
        name = next(iter(meshes))
        sizes = [parse_count(c) for c in args.shards.split(",")]
        shard_sizes(*meshes[name], SCENES / f"{name}.npz", sizes)
    for n_workers in (1, 2):
        local, client = cluster(n_workers)
        try:
            for name, (vertices, faces) in meshes.items():
                start = time.perf_counter()
                remote = DistributedScene(client, [(vertices, faces)])
                scatter = time.perf_counter() - start
                build = remote.build()
                scenes[name, n_workers] = (scatter, build, remote.payload_bytes)
                for kind in args.kinds.split(","):
                    for n in counts:
                        batch = make_rays(kind, vertices, faces, n, 1, SCENES / f"{name}.npz")
                        runs = []
                        for _ in range(args.repeats):
                            remote.closest(batch.origins, batch.directions)
                            runs.append(dict(remote.last_query))
                        load = os.getloadavg()[0]  # the machine may be shared
                        wall = statistics.median(r["wall"] for r in runs)
                        rows.append(
                            {
                                "scene": name,
                                "kind": kind,
                                "rays": n,
                                "workers": n_workers,
                                "wall": wall,
                                "send": statistics.median(r["send"] for r in runs),
                                "trace": statistics.median(r["trace"] for r in runs),
                                "shards": runs[0]["shards"],
                                "load": load,
                            }
                        )
                        print(
                            f"{name:8} {kind:8} {n / 2**20:5.0f}M  {n_workers} worker(s): "
                            f"wall {wall:7.2f} s  send {rows[-1]['send']:6.2f} s  "
                            f"trace {rows[-1]['trace']:7.2f} s (summed, "
                            f"{rows[-1]['shards']} shards), load {load:.1f}",
                            flush=True,
                        )
                remote.close()
        finally:
            client.close()
            local.close()
    report(rows, scenes, counts)


def report(rows, scenes, counts):
    print(
        "\n| scene | rays | 1 worker | 2 workers | speed-up "
        "| 2 workers: send / trace per worker (overlapping) | load (1 / 2 workers) |"
    )
    print("|---|---|---|---|---|---|---|")
    by = {(r["scene"], r["kind"], r["rays"], r["workers"]): r for r in rows}
    rates = []
    for scene, kind, n, workers in by:
        if workers != 1 or (scene, kind, n, 2) not in by:
            continue
        one, two = by[scene, kind, n, 1], by[scene, kind, n, 2]
        rates.append(n / two["wall"])
        print(
            f"| {scene} {kind} | {n / 2**20:.0f}M | {one['wall']:.2f} s | {two['wall']:.2f} s "
            f"| {one['wall'] / two['wall']:.2f}x | {two['send']:.2f} / {two['trace'] / 2:.2f} s "
            f"| {one['load']:.1f} / {two['load']:.1f} |"
        )
    print("\n| scene | triangles: bytes | scatter (1 / 2 workers) | Scene build on a worker |")
    print("|---|---|---|---|")
    for (scene, workers), (scatter, build, nbytes) in scenes.items():
        if workers == 2:
            one = scenes[scene, 1][0]
            print(
                f"| {scene} | {nbytes / 2**20:.1f} MiB | {one:.2f} / {scatter:.2f} s "
                f"| {build:.2f} s |"
            )
    if not rates:
        return
    rate = statistics.median(rates)  # rays/s of one 2-core machine
    print(f"\nOn paper, 10 Gbit/s links, each machine at {rate / 1e6:.2f} Mrays/s (measured here):")
    per_ray = RAY_BYTES_IN + CLOSEST_BYTES_OUT
    for (scene, workers), (_, _, nbytes) in scenes.items():
        if workers != 2:
            continue
        for machines in (8, 32):
            send_scene = machines * nbytes / LINK_BYTES_PER_S
            print(
                f"  {scene}, {machines} machines: triangles {nbytes / 2**20:.1f} MiB to each, "
                f"{send_scene:.2f} s per scene version from one client link"
            )
    for n in counts:
        for machines in (8, 32):
            trace = n / (machines * rate)
            wire = n * per_ray / LINK_BYTES_PER_S
            print(
                f"  {n / 2**20:.0f}M rays, {machines} machines: trace {trace:.2f} s, rays and "
                f"answers {n * per_ray / 2**20:.0f} MiB through the client's link {wire:.2f} s "
                f"({per_ray} bytes a ray) -> {max(trace, wire):.2f} s, "
                f"{'network' if wire > trace else 'trace'}-bound"
            )


def main(argv=None):
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--scenes", default="sibenik,sponza")
    parser.add_argument("--kinds", default="primary,random")
    parser.add_argument("--rays", default="4M,16M", help="batch sizes, e.g. 4M,16M")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--shards", default="", help="shard sizes to measure, e.g. 64K,256K,1M")
    args = parser.parse_args(argv)
    use_kernel_cache()
    run(args)


if __name__ == "__main__":
    main()
