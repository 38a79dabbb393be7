"""Motion (issue 36): what a frame costs when its actors move during it, against the same frame
without motion, side by side in one run.

    python -m bench.motion                       # 1M static triangles, 40 cars, 8 lidars (1M rays)
    python -m bench.motion --triangles 3.3e6 --lidars 16 --reps 5 --out /tmp/motion

The world and the cars are ``bench.world``'s (the shared scenes: a street, buildings, statues,
teapot cars in four lanes). A frame's rays are ``--lidars`` HDL-64E revolutions of 2048 steps
(131,072 rays each) along the street; in the moving frame column s of each fires at
tau = s / 2048 (so the times spread evenly over [0, 1]) and each car moves from its placement in
one frame to its placement in the next (``bench.world.actor_transforms``). Per repetition, the
variants' order turned each time, medians of ``--reps`` after an untimed first:

  static      ``dacrt.Scene(world + cars, transforms=M0)`` (``scene``), ``closest`` (``trace``)
  moving      the same with ``transforms_end=M1``, ``closest(..., time=tau)``
  moving, t=0 the moving scene, every ray at 0 (the static path: it should cost as ``static``)

The moving frame's answers are checked against the static one where nothing moves (rays that
hit the static world in both and no car in either agree exactly: the world is the same). Prints
a Markdown table; ``--out`` gets ``motion.json`` and ``motion.md``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

import dacrt
from bench.world import actor_transforms, build_world, car_mesh, find_shared, lidar_poses

STEPS = 2048
VARIANTS = ("static", "moving", "moving, t=0")


def frame_rays(n_lidars: int, length: float):
    """(origins, directions, tau) of ``n_lidars`` HDL-64E revolutions, column s at s / STEPS."""
    lidar = dacrt.sensors.Lidar("HDL-64E", horizontal_steps=STEPS, period_s=0.1)
    rays = [lidar.shot(pose).rays for pose in lidar_poses(n_lidars, 0, length)]
    origins = np.concatenate([r.origins for r in rays])
    directions = np.concatenate([r.directions for r in rays])
    tau = np.concatenate([r.time for r in rays])
    return origins, directions, tau


def timed(call):
    start = time.perf_counter()
    result = call()
    return result, (time.perf_counter() - start) * 1e3


def run_variant(name, meshes, starts, ends, o, d, tau, threads):
    """(ms to build the scene, ms to trace, Hits) of one variant."""
    if name == "static":
        scene, build = timed(lambda: dacrt.Scene(meshes, transforms=starts))
        hits, trace = timed(lambda: scene.closest(o, d, threads=threads, stats=True))
        return build, trace, hits
    scene, build = timed(lambda: dacrt.Scene(meshes, transforms=starts, transforms_end=ends))
    time_of_rays = tau if name == "moving" else np.zeros_like(tau)
    hits, trace = timed(lambda: scene.closest(o, d, threads=threads, stats=True, time=time_of_rays))
    return build, trace, hits


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--triangles", type=float, default=1e6, help="static triangles")
    parser.add_argument("--actors", type=int, default=40)
    parser.add_argument("--lidars", type=int, default=8, help="131,072 rays each")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--shared", type=Path, default=find_shared())
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.shared is None:
        parser.error("the shared scenes are not found: give --shared")
    world = build_world(args.shared / "scenes", int(args.triangles))
    car = car_mesh(args.shared / "scenes")
    placements = actor_transforms(args.actors, 2, world.length)
    meshes = [(world.vertices, world.faces)] + [car] * args.actors
    starts = [None] + list(placements[0])
    ends = [None] + list(placements[1])
    o, d, tau = frame_rays(args.lidars, world.length)
    print(
        f"world {len(world.faces):,} triangles, {args.actors} cars of {len(car[1]):,}, "
        f"{len(o):,} rays, {args.threads} threads",
        flush=True,
    )
    times = {name: {"scene": [], "trace": []} for name in VARIANTS}
    answers = {}
    for rep in range(args.reps + 1):
        order = VARIANTS[rep % 3 :] + VARIANTS[: rep % 3]
        for name in order:
            build, trace, hits = run_variant(name, meshes, starts, ends, o, d, tau, args.threads)
            if rep:  # the first is untimed
                times[name]["scene"].append(build)
                times[name]["trace"].append(trace)
            answers[name] = hits
            print(f"  rep {rep} {name}: scene {build:.0f} ms, trace {trace:.0f} ms", flush=True)
    static, moving, at_zero = (answers[name] for name in VARIANTS)
    for name in ("t", "mesh", "prim", "normal"):
        np.testing.assert_array_equal(getattr(at_zero, name), getattr(static, name))
    world_only = (static.mesh == 0) & (moving.mesh == 0)
    same = np.mean(moving.t[world_only] == static.t[world_only])
    assert same == 1.0, f"the static world's hits differ ({same:.6f})"
    result = {
        "triangles": int(len(world.faces)),
        "actors": args.actors,
        "rays": int(len(o)),
        "threads": args.threads,
        "reps": args.reps,
        "ms": {n: {k: statistics.median(v) for k, v in t.items()} for n, t in times.items()},
        "car_hits": {n: int(np.sum(answers[n].mesh > 0)) for n in VARIANTS},
        "tests": {n: int(answers[n].stats["ray_triangle_tests"]) for n in VARIANTS},
    }
    table = markdown(result)
    print(table)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "motion.json").write_text(json.dumps(result, indent=1))
        (args.out / "motion.md").write_text(table)
    return 0


def markdown(result: dict) -> str:
    base = result["ms"]["static"]["trace"]
    lines = [
        f"{result['rays']:,} rays, {result['triangles']:,} static triangles, "
        f"{result['actors']} cars, {result['threads']} threads, median of {result['reps']}",
        "",
        "| frame | scene ms | trace ms | trace vs static | ray-triangle tests | car hits |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name in VARIANTS:
        ms = result["ms"][name]
        lines.append(
            f"| {name} | {ms['scene']:.0f} | {ms['trace']:.0f} | {ms['trace'] / base:.2f}x | "
            f"{result['tests'][name]:,} | {result['car_hits'][name]:,} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
