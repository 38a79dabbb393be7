"""Point queries side by side: dacrt's ``nearest`` / ``signed_distance`` against Open3D's
``compute_distance`` / ``compute_signed_distance`` and trimesh's ``nearest.on_surface``.

    python -m bench.points [--scenes bunny,dragon,sibenik] [--points 1000000] [--threads 2]
                           [--repeats 1] [--trimesh-points 20000] [--json out.json]
                           [--scene-dir ../shared/scenes]

Per scene (``../shared/scenes/NAME.npz``) and point set (``uniform``: uniform in the scene's box;
``near``: vertices moved by a normal offset of 1 % of the box's size), in one run:

  frame    a new scene and the query (what a scene that changes every frame costs)
  query    the query alone, on a scene made and queried once before (Open3D builds its BVH
           on its first query)
  signed   a new scene and the signed distance (nsamples=1 for both)

dacrt runs on ``--threads`` threads, Open3D on all (``nthreads=0``), trimesh on one (its
``nearest.on_surface`` is slow, so it measures ``--trimesh-points`` points and the table gives
its rate; it needs scipy, and is left out without it). Each figure is the median of
``--repeats`` runs, the engines in turn. The distances are compared: the largest difference
between dacrt's and Open3D's, relative to the box's size.
"""

from __future__ import annotations

import argparse
import gc
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import dacrt  # noqa: E402
from bench.entry import description, use_kernel_cache  # noqa: E402
from oracles import open3d_points  # noqa: E402

SHARED_SCENES = REPO.parent / "shared" / "scenes"


def timed(fn):
    """(seconds, result) of fn(), the collector off meanwhile."""
    gc.collect()
    gc.disable()
    try:
        start = time.perf_counter()
        out = fn()
        return time.perf_counter() - start, out
    finally:
        gc.enable()


def point_sets(vertices, n, seed=0):
    """{"uniform": (n, 3), "near": (n, 3)} float32 points."""
    rng = np.random.default_rng(seed)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    uniform = rng.uniform(lo, hi, (n, 3))
    near = vertices[rng.integers(0, len(vertices), n)].astype(np.float64)
    near += rng.normal(scale=0.01 * float(np.max(hi - lo)), size=near.shape)
    return {"uniform": uniform.astype(np.float32), "near": near.astype(np.float32)}


def measure(vertices, faces, points, threads, trimesh_points):
    """{figure name: seconds} and the distances' largest difference, for one point set."""
    import trimesh

    # Scenes made, and queried once, before the clock: Open3D builds its BVH on the first query.
    scene = dacrt.Scene([(vertices, faces)])
    scene.nearest(points[:1])
    rival = open3d_points.build(open3d_points.scene(vertices, faces))
    query = open3d_points.tensor(points)  # Open3D's input, made once as dacrt's is
    runs = {
        "dacrt frame": lambda: dacrt.Scene([(vertices, faces)]).nearest(points, threads=threads),
        "dacrt query": lambda: scene.nearest(points, threads=threads),
        "dacrt signed": lambda: dacrt.Scene([(vertices, faces)]).signed_distance(
            points, threads=threads
        ),
        "open3d frame": lambda: open3d_points.distance(open3d_points.scene(vertices, faces), query),
        "open3d query": lambda: open3d_points.distance(rival, query),
        "open3d signed": lambda: open3d_points.signed_distance(
            open3d_points.scene(vertices, faces), query
        ),
    }
    seconds = {name: timed(run) for name, run in runs.items()}
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    few = points[:trimesh_points]
    try:
        trimesh_seconds, _ = timed(lambda: mesh.nearest.on_surface(few))
    except ImportError:  # trimesh's nearest needs scipy
        trimesh_seconds = float("nan")
    ours = seconds["dacrt query"][1].distance
    theirs = seconds["open3d query"][1]
    size = float(np.max(vertices.max(axis=0) - vertices.min(axis=0)))
    difference = float(np.max(np.abs(ours.astype(np.float64) - theirs))) / size
    figures = {name: s for name, (s, _) in seconds.items()}
    figures["trimesh per 1M"] = trimesh_seconds * len(points) / len(few)
    return figures, difference


def main(argv=None):
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--scenes", default="bunny,dragon,sibenik")
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--trimesh-points", type=int, default=20000)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--scene-dir", type=Path, default=SHARED_SCENES)
    args = parser.parse_args(argv)
    use_kernel_cache()
    dacrt.warmup()
    rows = []
    for name in args.scenes.split(","):
        with np.load(args.scene_dir / f"{name}.npz") as z:
            vertices = z["vertices"].astype(np.float32)
            faces = z["faces"].astype(np.int32)
        for kind, points in point_sets(vertices, args.points).items():
            runs = [
                measure(vertices, faces, points, args.threads, args.trimesh_points)
                for _ in range(args.repeats)
            ]
            figures = {key: statistics.median(run[0][key] for run in runs) for key in runs[0][0]}
            difference = max(run[1] for run in runs)
            rows.append({"scene": name, "points": kind, **figures, "difference": difference})
            print(table_row(rows[-1]), flush=True)
    print()
    print(TABLE_HEAD)
    for row in rows:
        print(table_row(row))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


TABLE_HEAD = (
    "| scene | points | dacrt frame | Open3D frame | × | dacrt query | Open3D query | × "
    "| dacrt signed | Open3D signed | × | trimesh (per 1M) | max difference |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
)


def table_row(row):
    """One markdown row: seconds, and Open3D's time over dacrt's."""

    def pair(kind):
        ours, theirs = row[f"dacrt {kind}"], row[f"open3d {kind}"]
        return f"{ours:.2f} s | {theirs:.2f} s | {theirs / ours:.1f}"

    return (
        f"| {row['scene']} | {row['points']} | {pair('frame')} | {pair('query')} "
        f"| {pair('signed')} | {row['trimesh per 1M']:.0f} s | {row['difference']:.1e} |"
    )


if __name__ == "__main__":
    main()
