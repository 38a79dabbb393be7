"""Motion: what a frame costs when its actors move during it, against the same frame
without motion and against Embree's motion blur, side by side in one run.

    python -m bench.motion                       # 1M static triangles, 40 cars, 8 lidars (1M rays)
    python -m bench.motion --triangles 3.3e6 --lidars 16 --reps 5 --out /tmp/motion
    python -m bench.motion --embree-threads 1,2  # Embree on 1 thread and on 2
    python -m bench.motion --no-embree           # the engine's three frames alone

The world and the cars are ``bench.world``'s (the shared scenes: a street, buildings, statues,
teapot cars in four lanes). A frame's rays are ``--lidars`` HDL-64E revolutions of 2048 steps
(131,072 rays each) along the street; in the moving frame column s of each fires at
tau = s / 2048 (so the times spread evenly over [0, 1]) and each car moves from its placement in
one frame to its placement in the next (``bench.world.actor_transforms``, rounded to float32 for
every variant: the placements Embree is given). Per repetition, the variants' order turned each
time, medians of ``--reps`` after an untimed first:

  static         ``dacrt.Scene(world + cars, transforms=M0)`` (``scene``), ``closest`` (``trace``)
  moving         the same with ``transforms_end=M1``, ``closest(..., time=tau)``
  moving, t=0    the moving scene, every ray at 0 (the static path: it should cost as ``static``)
  Embree static  ``bench/embree_motion.cpp static``: the world and the car built once (not part
                 of the frame), each car an instance with one transform (M0); the frame is the K
                 transforms + the top level's commit (``commit``), then the rays (``trace``)
  Embree moving  ``bench/embree_motion.cpp moving``: each car an instance with two time steps
                 (M0, M1), each ray at its tau (``RTCRay.time``); the same frame

Embree runs in its own process per variant and repetition (compiled with ``g++`` on first use,
as ``bench.native_embree`` compiles its anchor), on ``--embree-threads`` (default ``--threads``):
it builds the world and the car once, runs a frame with other placements untimed, then the timed
frame. Embree 3 places a moving instance at time tau by the linear interpolation of its two
matrices, (1 - tau) M0 + tau M1, in float32 (then inverts it), as the engine does in float64.

Checks: the moving frame's answers against the static one where nothing moves (rays that hit the
static world in both and no car in either agree exactly), the moving scene at t=0 against the
static one (bit for bit), and each engine frame against Embree's of the same kind: rays whose hit
or miss differ, whose hit is on another mesh or triangle, and the difference in t in float32 ulps
among the rays both hit on the same triangle (counted, not asserted). Prints Markdown tables;
``--out`` gets ``motion.json`` and ``motion.md``; ``--report motion.json`` prints its tables again.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import dacrt
from bench.entry import description, use_kernel_cache
from bench.world import actor_transforms, build_world, car_mesh, find_shared, lidar_poses

STEPS = 2048
VARIANTS = ("static", "moving", "moving, t=0")
MOTION_SOURCE = Path(__file__).resolve().with_name("embree_motion.cpp")


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


class EmbreeMotion:
    """``bench/embree_motion.cpp``, one process a call; the world, the car, the placements and
    the rays written once to a scratch folder."""

    def __init__(self, binary: Path, world, car, placements, o, d, tau):
        """``placements``: (3, K, 4, 4); the timed frame goes from 0 to 1, the untimed one
        before it from 1 to 2 (so the timed frame's transforms are new to the scene)."""
        self.binary = binary
        self.folder = Path(tempfile.mkdtemp(prefix="motion-embree-"))
        folder = self.folder
        np.ascontiguousarray(world.vertices, np.float32).tofile(folder / "static_vertices.f32")
        np.ascontiguousarray(world.faces, np.int32).tofile(folder / "static_faces.i32")
        np.ascontiguousarray(car[0], np.float32).tofile(folder / "object_vertices.f32")
        np.ascontiguousarray(car[1], np.int32).tofile(folder / "object_faces.i32")
        k = placements.shape[1]
        frames = np.stack(
            [
                np.stack([placements[1], placements[2]], 1),
                np.stack([placements[0], placements[1]], 1),
            ]
        )  # (2 frames, K, 2 steps, 4, 4)
        np.ascontiguousarray(frames[..., :3, :], np.float32).tofile(folder / "transforms.f32")
        table = np.zeros((len(o), 9), np.float32)
        table[:, :3], table[:, 3:6], table[:, 7], table[:, 8] = o, d, np.inf, tau
        table.tofile(folder / "rays.f32")
        (folder / "frames.txt").write_text(f"2 {k}")

    def frame(self, mode: str, threads: int):
        """(one-time build ms, commit ms, trace ms, (t, mesh, prim)) of the timed frame."""
        out = subprocess.run(
            [str(self.binary), str(self.folder), str(threads), mode],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.split("\n")
        commit, trace = (float(x) for x in out[2].split())
        hits = tuple(
            np.fromfile(self.folder / name, dtype)
            for name, dtype in (
                ("t.f32", np.float32),
                ("inst.i32", np.int32),
                ("prim.i32", np.int32),
            )
        )
        return float(out[0]), commit, trace, hits

    def close(self):
        shutil.rmtree(self.folder, ignore_errors=True)


def reference_t(rays, mesh, prim, tau, world, car, starts, ends, o, d) -> np.ndarray:
    """float64 t of each ray of ``rays`` against its triangle ``prim`` of ``mesh`` (0: the world;
    1 + j: car j placed by (1 - tau) M0 + tau M1, each vertex in float64), by Moeller-Trumbore:
    the answer both engines round, to measure each one's error in ulps."""
    tri = np.empty((len(rays), 3, 3))
    on_world = mesh == 0
    tri[on_world] = world.vertices[world.faces[prim[on_world]]]
    cars = ~on_world
    j = mesh[cars] - 1
    s = tau[rays][cars].astype(np.float64)[:, None, None]
    matrix = (1 - s) * starts[j] + s * ends[j]
    local = car[0].astype(np.float64)[car[1][prim[cars]]]
    tri[cars] = local @ matrix[:, :3, :3].transpose(0, 2, 1) + matrix[:, None, :3, 3]
    origin, direction = o[rays].astype(np.float64), d[rays].astype(np.float64)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(direction, e2)
    q = np.cross(origin - tri[:, 0], e1)
    return np.einsum("ij,ij->i", e2, q) / np.einsum("ij,ij->i", e1, p)


def ulps_from(t: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """|t - exact| in float32 ulps at ``exact``."""
    return np.abs(t.astype(np.float64) - exact) / np.spacing(exact.astype(np.float32))


def compare_hits(ours, theirs, tau, scene) -> dict:
    """How the engine's Hits ``ours`` and Embree's (t, mesh, prim) ``theirs`` differ: counts of
    rays whose hit or miss differ, whose hit is on another mesh or another triangle; for the
    rays both hit on the same triangle, each engine's t against the float64 t (``reference_t``
    with rays at ``tau``; ``scene``: its other arguments) in float32 ulps, apart for the world's
    hits and the cars', and the largest difference between the two engines' t in metres."""
    t, mesh, prim = theirs
    ours_hit, theirs_hit = np.isfinite(ours.t), np.isfinite(t)
    both = ours_hit & theirs_hit
    same_mesh = both & (ours.mesh == mesh)
    same = same_mesh & (ours.prim == prim)
    rays = np.flatnonzero(same)
    other = np.flatnonzero(same_mesh & ~same)
    exact = reference_t(rays, mesh[rays], prim[rays], tau, *scene)
    on_car = mesh[rays] > 0
    result = {
        "rays": int(len(t)),
        "hits": int(both.sum()),
        "hit_miss_differ": int((ours_hit != theirs_hit).sum()),
        "other_mesh": int((both & ~same_mesh).sum()),
        "other_prim": int((same_mesh & ~same).sum()),
        "same_prim": int(same.sum()),
        "car_hits_same_prim": int(on_car.sum()),
        # another triangle at the same t: a tie at an edge or vertex the two triangles share
        "other_prim_same_t": int(
            (ulps_from(t[other], ours.t[other].astype(np.float64)) <= 4).sum()
        ),
        "max_dt_m": float(np.abs(ours.t[rays].astype(np.float64) - t[rays]).max()),
    }
    for engine, values in (("dacrt", ours.t[rays]), ("embree", t[rays])):
        ulps = ulps_from(values, exact)
        for part, where in (("world", ~on_car), ("cars", on_car)):
            result[f"{engine}_{part}_max_ulps"] = float(ulps[where].max()) if where.any() else 0.0
            result[f"{engine}_{part}_within_4_ulps"] = int((ulps[where] <= 4).sum())
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--triangles", type=float, default=1e6, help="static triangles")
    parser.add_argument("--actors", type=int, default=40)
    parser.add_argument("--lidars", type=int, default=8, help="131,072 rays each")
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--embree-threads", default=None, help="comma list of Embree's thread counts (--threads)"
    )
    parser.add_argument("--no-embree", action="store_true", help="the engine's frames alone")
    parser.add_argument("--build-dir", type=Path, default=None, help="where Embree's program goes")
    parser.add_argument("--shared", type=Path, default=find_shared())
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--report", type=Path, default=None, help="print a motion.json's tables")
    args = parser.parse_args(argv)
    if args.report:
        print(markdown(json.loads(args.report.read_text())))
        return 0
    if args.shared is None:
        parser.error("the shared scenes are not found: give --shared")
    use_kernel_cache()
    embree_threads = [int(x) for x in (args.embree_threads or str(args.threads)).split(",") if x]
    world = build_world(args.shared / "scenes", int(args.triangles))
    car = car_mesh(args.shared / "scenes")
    # float32 placements, as Embree takes them: both engines place the cars alike
    placements = actor_transforms(args.actors, 3, world.length).astype(np.float32)
    placements = placements.astype(np.float64)
    meshes = [(world.vertices, world.faces)] + [car] * args.actors
    starts = [None] + list(placements[0])
    ends = [None] + list(placements[1])
    o, d, tau = frame_rays(args.lidars, world.length)
    variants = list(VARIANTS)
    embree = None
    missing = None
    if not args.no_embree:
        from bench.native_embree import BUILD_DIR, AnchorUnavailable, build_anchor

        try:
            binary = build_anchor(MOTION_SOURCE, args.build_dir or BUILD_DIR)
            embree = EmbreeMotion(binary, world, car, placements, o, d, tau)
        except AnchorUnavailable as exc:
            missing = str(exc)
            print(f"Embree left out: {exc}", flush=True)
    embree_of = {}  # an Embree variant's name: (embree_motion's mode, threads)
    if embree:
        for threads in embree_threads:
            for mode in ("static", "moving"):
                plural = "s" if threads > 1 else ""
                suffix = f", {threads} thread{plural}" if len(embree_threads) > 1 else ""
                embree_of[f"Embree {mode}{suffix}"] = (mode, threads)
        variants += list(embree_of)
    print(
        f"world {len(world.faces):,} triangles, {args.actors} cars of {len(car[1]):,}, "
        f"{len(o):,} rays, {args.threads} threads (Embree {embree_threads})",
        flush=True,
    )
    times = {name: {"scene": [], "trace": []} for name in variants}
    embree_build = []
    answers = {}
    try:
        for rep in range(args.reps + 1):
            turn = rep % len(variants)
            for name in variants[turn:] + variants[:turn]:
                if name in VARIANTS:
                    build, trace, hits = run_variant(
                        name, meshes, starts, ends, o, d, tau, args.threads
                    )
                else:
                    mode, threads = embree_of[name]
                    once, build, trace, hits = embree.frame(mode, threads)
                    embree_build.append(once)
                if rep:  # the first is untimed
                    times[name]["scene"].append(build)
                    times[name]["trace"].append(trace)
                answers[name] = hits
                print(f"  rep {rep} {name}: scene {build:.0f} ms, trace {trace:.0f} ms", flush=True)
    finally:
        if embree:
            embree.close()
    static, moving, at_zero = (answers[name] for name in VARIANTS)
    for name in ("t", "mesh", "prim", "normal"):
        np.testing.assert_array_equal(getattr(at_zero, name), getattr(static, name))
    world_only = (static.mesh == 0) & (moving.mesh == 0)
    same = np.mean(moving.t[world_only] == static.t[world_only])
    assert same == 1.0, f"the static world's hits differ ({same:.6f})"
    checks = {}
    reference = (world, car, placements[0], placements[1], o, d)
    for name, (mode, _) in embree_of.items():
        rays_tau = tau if mode == "moving" else np.zeros_like(tau)
        checks[name] = compare_hits(answers[mode], answers[name], rays_tau, reference)
    result = {
        "triangles": int(len(world.faces)),
        "actors": args.actors,
        "rays": int(len(o)),
        "threads": args.threads,
        "embree_threads": embree_threads if embree else [],
        "embree_missing": missing,
        "embree_variants": embree_of,
        "reps": args.reps,
        "ms": {n: {k: statistics.median(v) for k, v in t.items()} for n, t in times.items()},
        "all_ms": times,  # every timed repetition, in order
        "embree_build_ms": statistics.median(embree_build) if embree_build else None,
        "car_hits": {n: int(np.sum(mesh_of(answers[n]) > 0)) for n in variants},
        "tests": {n: int(answers[n].stats["ray_triangle_tests"]) for n in VARIANTS},
        "checks": checks,
    }
    table = markdown(result)
    print(table)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "motion.json").write_text(json.dumps(result, indent=1))
        (args.out / "motion.md").write_text(table)
    return 0


def mesh_of(answer):
    """The mesh of each ray's hit (-1 on a miss): the engine's Hits or Embree's (t, mesh, prim)."""
    return answer.mesh if hasattr(answer, "mesh") else answer[1]


def markdown(result: dict) -> str:
    ms, embree_of = result["ms"], result["embree_variants"]
    static_of = {threads: name for name, (mode, threads) in embree_of.items() if mode == "static"}
    lines = [
        f"{result['rays']:,} rays, {result['triangles']:,} static triangles, "
        f"{result['actors']} cars, {result['threads']} threads "
        f"(Embree {', '.join(map(str, result['embree_threads'])) or 'left out'}), "
        f"median of {result['reps']}",
        "",
        "| frame | scene or commit ms | trace ms (min) | frame ms (min) | frame vs its static "
        "| ray-triangle tests | car hits |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, parts in ms.items():
        frame = parts["scene"] + parts["trace"]
        static = ms[static_of[embree_of[name][1]]] if name in embree_of else ms["static"]
        tests = result["tests"].get(name)
        each = result["all_ms"][name]
        fastest = min(a + b for a, b in zip(each["scene"], each["trace"]))
        lines.append(
            f"| {name} | {parts['scene']:.1f} | {parts['trace']:.0f} ({min(each['trace']):.0f}) "
            f"| {frame:.0f} ({fastest:.0f}) "
            f"| {frame / (static['scene'] + static['trace']):.2f}x "
            f"| {'' if tests is None else f'{tests:,}'} | {result['car_hits'][name]:,} |"
        )
    if not result["checks"]:
        return "\n".join(lines) + "\n"
    lines += [
        "",
        "dacrt's frame against Embree's of the same kind (above 1: Embree is faster), and where "
        "their answers differ:",
        "",
        "| Embree frame | dacrt / Embree, frame | trace | hit or miss differ | other mesh "
        "| other triangle (at the same t) | same triangle | of which cars |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, check in result["checks"].items():
        ours, theirs = ms[embree_of[name][0]], ms[name]
        ratio = (ours["scene"] + ours["trace"]) / (theirs["scene"] + theirs["trace"])
        lines.append(
            f"| {name} | {ratio:.2f} | {ours['trace'] / theirs['trace']:.2f} "
            f"| {check['hit_miss_differ']:,} | {check['other_mesh']:,} "
            f"| {check['other_prim']:,} ({check['other_prim_same_t']:,}) "
            f"| {check['same_prim']:,} | {check['car_hits_same_prim']:,} |"
        )
    lines += [
        "",
        "t of the rays both hit on the same triangle, against the float64 t of that triangle "
        "placed at the ray's time (float32 ulps; dacrt, Embree):",
        "",
        "| Embree frame | world: max ulps | cars: within 4 ulps | cars: max ulps "
        "| largest dacrt - Embree, m |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, c in result["checks"].items():
        cars = max(c["car_hits_same_prim"], 1)
        lines.append(
            f"| {name} | {c['dacrt_world_max_ulps']:.1f}, {c['embree_world_max_ulps']:.1f} "
            f"| {c['dacrt_cars_within_4_ulps'] / cars:.2%}, "
            f"{c['embree_cars_within_4_ulps'] / cars:.2%} "
            f"| {c['dacrt_cars_max_ulps']:.1f}, {c['embree_cars_max_ulps']:.1f} "
            f"| {c['max_dt_m']:.2e} |"
        )
    if result["embree_build_ms"] is not None:
        build = result["embree_build_ms"]
        lines += ["", f"Embree's one-time build (world, car, top level): {build:.0f} ms (median)."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
