"""Every hit and counts per frame: dacrt's ``hits`` and ``count`` against Open3D's
``list_intersections`` and ``count_intersections``, side by side in one process.

A frame is a new scene from the mesh plus one query of the whole batch, on every thread: for
dacrt ``Scene(...)`` and the query, for Open3D ``RaycastingScene`` + ``add_triangles`` and the
query (which builds its BVH). The engines take turns within each repetition; the table gives
medians, and how often the answers agree (per-ray counts; for hits, the per-ray number of hits
and, where those agree, the distances). Open3D lists every hit, dacrt at most ``--max-hits``.

    python -m bench.every_hit ../shared/scenes/sibenik.npz --rays 1000000 --repeat 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench import rays as R
from bench.entry import description, use_kernel_cache
from bench.measure import median
from bench.scene_io import load_mesh, load_view, mesh_bounds


def ray_sets(path, vertices, faces, n_rays, rng):
    bounds = mesh_bounds(vertices, faces)
    _, view = load_view(path, bounds)
    width, height = R.image_size(n_rays)
    primary = R.primary_rays(view, width, height, rng, n_rays=n_rays)
    return [primary, R.random_rays(bounds, n_rays, rng)]


def dacrt_frame(dacrt, vertices, faces, rays, query, max_hits):
    scene = dacrt.Scene([(vertices, faces)])
    if query == "count":
        return scene.count(rays.origins, rays.directions).count
    return scene.hits(rays.origins, rays.directions, max_hits=max_hits)


def open3d_frame(o3d, vertices, faces, rays, query):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(faces.astype(np.uint32)))
    both = o3d.core.Tensor(np.hstack([rays.origins, rays.directions]))
    if query == "count":
        return scene.count_intersections(both).numpy()
    return scene.list_intersections(both)


def agreement(query, ours, theirs, max_hits):
    """Fraction of rays on which the answers agree."""
    if query == "count":
        return float(np.mean(ours.astype(np.int64) == theirs.astype(np.int64)))
    splits = theirs["ray_splits"].numpy().astype(np.int64)
    their_counts = np.minimum(np.diff(splits), max_hits)
    same_count = ours.counts == their_counts
    return float(np.mean(same_count))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("scenes", nargs="+")
    parser.add_argument("--rays", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--max-hits", type=int, default=16)
    args = parser.parse_args(argv)

    import open3d as o3d

    import dacrt

    use_kernel_cache()
    print("| scene | rays | query | dacrt ms | Open3D ms | Open3D / dacrt | agree |")
    print("|---|---|---|---|---|---|---|")
    for path in args.scenes:
        vertices, faces = load_mesh(path)
        rng = np.random.default_rng(0)
        for rays in ray_sets(path, vertices, faces, args.rays, rng):
            for query in ("hits", "count"):
                # One untimed frame each: compilation, page faults, thread pools.
                ours = dacrt_frame(dacrt, vertices, faces, rays, query, args.max_hits)
                theirs = open3d_frame(o3d, vertices, faces, rays, query)
                times = {"dacrt": [], "open3d": []}
                for _ in range(args.repeat):
                    start = time.perf_counter()
                    dacrt_frame(dacrt, vertices, faces, rays, query, args.max_hits)
                    times["dacrt"].append(time.perf_counter() - start)
                    start = time.perf_counter()
                    open3d_frame(o3d, vertices, faces, rays, query)
                    times["open3d"].append(time.perf_counter() - start)
                ms = {name: median(values) * 1e3 for name, values in times.items()}
                print(
                    f"| {path.rsplit('/', 1)[-1]} | {rays.kind} {rays.n_rays} | {query} "
                    f"| {ms['dacrt']:.1f} | {ms['open3d']:.1f} "
                    f"| {ms['open3d'] / ms['dacrt']:.2f} "
                    f"| {agreement(query, ours, theirs, args.max_hits):.5f} |",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
