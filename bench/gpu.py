"""Per-frame times of the CUDA backend (``dacrt.cuda``) against the CPU engine on one machine.

One prepared run for the device machine (an H100 or H200 with numba, numba-cuda, CuPy and
PyTorch; nothing installable there): Sibenik and Sponza with primary rays, and the 3.3M-triangle
street world (``bench.world``) with lidar rays, at about 131K, 1M and 4M rays. It first files the
kernels in ``dacrt.cache.use_cache_dir()``'s folder and compiles (or loads) every CPU kernel
(``dacrt.warmup()``: about a minute on a fresh machine, whose cache is empty), outside every row.
Each row is the median of ``--frames`` closest queries on the GPU and of ``--cpu-frames`` on the
CPU engine (every core), each device's first frame of the row untimed (it compiles the row's GPU
kernels, and no row's figure holds a device's first call), and how many rays' answers differ
(t bit for bit, mesh, prim). The world's rows also hold its 40 cars, placed meshes traced in
their mesh's space (``bench.world``'s frame: the world and the car placed by its first frame's
transforms). The scenes come from a folder given on the command line (the shared folder does
not travel to the device machine: copy sibenik.npz, sponza.npz and the .npz files
``bench.world`` builds the world from into an ignored folder and name it in ``carry``).

    python -m bench.gpu --scenes path/to/scenes [--frames 5] [--cpu-frames 5] [--budget-s 420]

Stops starting new rows once ``--budget-s`` seconds have passed: one command on the device
machine runs at most 10 minutes, and a task has 15 minutes of device time in all, the machine's
start included. Unmeasured so far: no GPU has run it.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from bench.entry import description, use_kernel_cache

RAY_COUNTS = (131_072, 1_048_576, 4_194_304)
CARS = 40  # the world's moving actors, as in ``bench.world``


def log(message: str) -> None:
    print(message, flush=True)


def timed(frames: int, call, *args, **kwargs) -> tuple[float, object]:
    """(median seconds of ``frames`` calls ``call(*args, **kwargs)``, the last answer)."""
    seconds = []
    answer = None
    for _ in range(frames):
        start = time.perf_counter()
        answer = call(*args, **kwargs)
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds), answer


def measure(scene, origins, directions, frames: int, cpu_frames: int):
    """(GPU seconds, CPU seconds, rays differing) of one row: the medians of ``frames`` closest
    queries on the GPU and of ``cpu_frames`` on the CPU, after one untimed query on each."""
    scene.closest(origins, directions, device="cuda")  # compiles the row's kernels, warms up
    gpu_s, gpu = timed(frames, scene.closest, origins, directions, device="cuda")
    scene.closest(origins, directions)  # the CPU's first query of the row, untimed too
    cpu_s, cpu = timed(cpu_frames, scene.closest, origins, directions)
    return gpu_s, cpu_s, differing(gpu, cpu)


def differing(a, b) -> int:
    """Rays whose t (bits), mesh or prim differ between two ``Hits``."""
    t_differs = a.t.view(np.uint32) != b.t.view(np.uint32)
    return int((t_differs | (a.mesh != b.mesh) | (a.prim != b.prim)).sum())


def primary(scene_path: Path, vertices, faces, n: int):
    """n pinhole rays of the scene's view (``scenes/views.json``)."""
    from bench.rays import image_size, primary_rays
    from bench.scene_io import load_view, mesh_bounds

    _, view = load_view(scene_path, mesh_bounds(vertices, faces))
    width, height = image_size(n)
    rays = primary_rays(view, width, height, np.random.default_rng(0), n_rays=n)
    return rays.origins, rays.directions


def lidar(length: float, n: int):
    """About n lidar rays of the world: one lidar per 131072, two frames for 4M."""
    from bench.world import MAX_LIDARS, lidar_poses, lidar_rays

    lidars = max(1, n // 131_072)
    frames = max(1, -(-lidars // MAX_LIDARS))
    poses = [p for f in range(frames) for p in lidar_poses(min(lidars, MAX_LIDARS), f, length)]
    return lidar_rays(poses[:lidars])


def workloads(scenes: Path):
    """(name, dacrt.Scene, rays_of(n)) of each scene found in ``scenes``."""
    import dacrt
    from bench.scene_io import load_mesh

    for name in ("sibenik", "sponza"):
        path = scenes / f"{name}.npz"
        if not path.is_file():
            log(f"{name}: no {path}, skipped")
            continue
        vertices, faces = load_mesh(path)
        scene = dacrt.Scene([(vertices, faces)])
        yield name, scene, (lambda n, p=path, v=vertices, f=faces: primary(p, v, f, n))
    try:
        from bench.world import actor_transforms, build_world, car_mesh

        world = build_world(scenes)
        car = car_mesh(scenes)
    except (OSError, KeyError) as error:
        log(f"world: cannot build it from {scenes} ({error}), skipped")
        return
    placements = actor_transforms(CARS, 1, world.length)[0]
    scene = dacrt.Scene(
        [(world.vertices, world.faces)] + [car] * CARS, transforms=[None, *placements]
    )
    yield f"world + {CARS} cars", scene, (lambda n: lidar(world.length, n))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--scenes", type=Path, required=True, help="folder of the scenes' .npz")
    parser.add_argument("--frames", type=int, default=5, help="timed GPU frames per row")
    parser.add_argument("--cpu-frames", type=int, default=5, help="timed CPU frames per row")
    parser.add_argument(
        "--rays", default=",".join(map(str, RAY_COUNTS)), help="ray counts, comma-separated"
    )
    parser.add_argument("--budget-s", type=float, default=420.0, help="start no row after this")
    args = parser.parse_args(argv)
    if min(args.frames, args.cpu_frames) < 1:
        parser.error("--frames and --cpu-frames at least 1")
    start = time.perf_counter()

    import dacrt
    from dacrt import cuda as dcuda

    if not dcuda.is_available():
        log("no CUDA GPU: nothing measured")
        return 1
    folder = use_kernel_cache()
    log(f"dacrt.warmup(): {dacrt.warmup():.1f} s (kernels in {folder})")
    log("scene | triangles | rays | GPU ms/frame | CPU ms/frame | rays differing")
    for name, scene, rays_of in workloads(args.scenes):
        for n in (int(k) for k in args.rays.split(",")):
            if time.perf_counter() - start > args.budget_s:
                log(f"{name} {n}: budget of {args.budget_s:.0f} s spent, skipped")
                continue
            origins, directions = rays_of(n)
            gpu_s, cpu_s, differ = measure(scene, origins, directions, args.frames, args.cpu_frames)
            log(
                f"{name} | {scene.n_triangles} | {len(origins)} | {1e3 * gpu_s:.1f} | "
                f"{1e3 * cpu_s:.1f} | {differ}"
            )
    log(f"total {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
