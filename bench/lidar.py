"""A lidar frame over HTTP: POST the pose to /lidar, against sending the rays to /closest, against
Embree in process.

    python -m bench.lidar [SCENE.npz] [--model HDL-64E] [--steps 2048] [--frames 10] [--view NAME]
    python -m bench.lidar --physics [SCENE.npz] [--threads 2] ...   the physics, in process

One frame is one revolution of a 64-beam sensor at 2048 steps (131,072 rays), the sensor moved
along the scene's view (eye toward target in ``scenes/views.json``) and turned a little every frame.
Side by side in one run, the order turned every frame, medians over the frames (after one untimed
frame of each):

  lidar         POST /v1/scenes/S/lidar with the pose (a JSON body of a few hundred bytes); the
                answer (.npz: xyz, range, ring, azimuth, elevation, mesh, prim, return,
                cos_incidence, ray of the hits) read into numpy by the client
  closest       the client builds the same rays in numpy, POSTs them to /closest as .npy (N, 6)
                and reads the .npz answer (t, mesh, prim, normal), then keeps the hits and makes
                their points: what a caller does without /lidar
  dacrt         the engine in this process: ``Scene.closest`` on the same rays (scene built once,
                as the server keeps it per scene version)
  embree build  Embree (embreex) in this process: a new scene, committed, then the rays traced,
                every frame (a scene that may have changed, as dacrt's per-query partitioning)
  embree trace  the same rays on one Embree scene built before the frames

embreex traces on one thread; the server and ``dacrt`` use every core. Every frame checks that
/lidar's points are /closest's hits of the same rays.

With ``--physics``, in process only (``--threads``, default 2), side by side the same way:

  closest       ``Scene.closest`` on the lidar's rays: the trace alone
  geometry      the rays, ``closest`` and the points as the /lidar route makes them today
                (``dacrt.sensors.lidar.points``: no intensity)
  scan          ``dacrt.sensors.Lidar(model).scan``: the same points with intensity and label
  noise         scan with range and angle noise
  all 2         return mode ``all``, two returns (``Scene.hits``)
  dual 3, dual 7   return mode ``dual`` with beam divergence (0.2 degrees) and 3 or 7 sub-rays
"""

from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import sys
import time
from pathlib import Path

import httpx
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import dacrt  # noqa: E402
from bench.entry import description, use_kernel_cache  # noqa: E402
from bench.http_overhead import cpu_model, start_server  # noqa: E402
from dacrt.sensors import Lidar, Materials  # noqa: E402
from dacrt.sensors.lidar import make_scan  # noqa: E402
from dacrt.sensors.lidar import points as route_points  # noqa: E402
from dacrt.sensors.models import MODELS  # noqa: E402
from oracles.embree import Embree  # noqa: E402
from service.client import Client  # noqa: E402
from service.timing import parse_server_timing  # noqa: E402

SHARED = REPO.parent / "shared" / "scenes"
CLOSEST_FIELDS = "t,mesh,prim,normal"


def sensor_pose(position, forward, up) -> np.ndarray:
    """The 4x4 sensor-to-scene pose: sensor x along ``forward`` (made level), z along ``up``."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    forward = np.asarray(forward, np.float64)
    forward = forward - (forward @ up) * up
    forward /= np.linalg.norm(forward)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = (
        forward,
        np.cross(up, forward),
        up,
        position,
    )
    return pose


def frame_poses(view: dict, n: int) -> list[np.ndarray]:
    """``n`` poses from the view's eye toward its target, each turned 7 degrees about up."""
    eye, target, up = (np.asarray(view[k], np.float64) for k in ("eye", "target", "up"))
    up = up / np.linalg.norm(up)
    ahead = target - eye
    side = np.cross(up, ahead)
    poses = []
    for k in range(n):
        angle = np.radians(7.0 * k)
        heading = np.cos(angle) * ahead + np.sin(angle) * side
        poses.append(sensor_pose(eye + ahead * (0.6 * k / max(n - 1, 1)), heading, up))
    return poses


def scan_rays(pose: np.ndarray, elevations_deg, steps: int):
    """The rays of one revolution, by docs/sensors.md's convention (as a client would build
    them): ray ring * steps + step along cos e (cos a R[:, 0] + sin a R[:, 1]) + sin e R[:, 2]."""
    rotation = pose[:3, :3]
    elevation = np.radians(np.sort(np.asarray(elevations_deg, np.float64)))
    azimuth = 2 * np.pi * np.arange(steps) / steps
    level = np.cos(azimuth)[:, None] * rotation[:, 0] + np.sin(azimuth)[:, None] * rotation[:, 1]
    directions = (
        np.cos(elevation)[:, None, None] * level
        + (np.sin(elevation)[:, None] * rotation[:, 2])[:, None, :]
    )
    directions = directions.reshape(-1, 3).astype(np.float32)
    origins = np.empty_like(directions)
    origins[:] = pose[:3, 3].astype(np.float32)
    return origins, directions


def main() -> None:
    parser = argparse.ArgumentParser(description=description(__doc__))
    default = SHARED / "sibenik.npz"
    parser.add_argument(
        "scene",
        nargs="?",
        default=str(default if default.exists() else REPO / "service/data/teapot.npz"),
    )
    parser.add_argument("--model", default="HDL-64E", choices=list(MODELS))
    parser.add_argument("--steps", type=int, default=2048)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--view", default=None, help="entry of scenes/views.json (default: stem)")
    parser.add_argument("--fields", default=None, help="?fields= of /lidar (default: all)")
    parser.add_argument("--physics", action="store_true", help="the physics' cost, in process")
    parser.add_argument("--threads", type=int, default=2, help="engine threads of --physics")
    args = parser.parse_args()

    with np.load(args.scene) as archive:
        vertices = np.ascontiguousarray(archive["vertices"], np.float32)
        faces = np.ascontiguousarray(archive["faces"], np.int32)
    views = json.loads((REPO / "scenes" / "views.json").read_text())
    view = views[args.view or Path(args.scene).stem]
    elevations = MODELS[args.model].vertical_angles_deg
    n_rays = len(elevations) * args.steps
    poses = frame_poses(view, args.frames + 1)

    use_kernel_cache()
    dacrt.warmup()
    scene = dacrt.Scene([(vertices, faces)])
    if args.physics:
        physics(args, scene, poses, len(faces))
        return
    embree = Embree([(vertices, faces)])
    embree.commit()
    process, url = start_server({"DACRT_MAX_RAYS_PER_REQUEST": str(max(n_rays, 1))})
    http = httpx.Client(base_url=url, timeout=300)
    client = Client(url)
    kinds = ["lidar", "closest", "dacrt", "embree build", "embree trace"]
    seconds = {kind: [] for kind in kinds}
    server_ms = {"lidar": [], "closest": []}
    sizes, points = {}, []
    try:
        client.put_mesh("bench", "mesh", vertices, faces)

        def lidar(pose):
            body = {"pose": pose.tolist(), "model": args.model, "horizontal_steps": args.steps}
            response = http.post(
                "/v1/scenes/bench/lidar",
                json=body,
                params={"fields": args.fields} if args.fields else None,
                headers={"Accept": "application/x-npz"},
            )
            response.raise_for_status()
            with np.load(io.BytesIO(response.content)) as archive:
                answer = {key: archive[key] for key in archive.files}
            sizes["lidar"] = (len(json.dumps(body)), len(response.content))
            return answer, response.headers["server-timing"]

        def closest(pose):
            origins, directions = scan_rays(pose, elevations, args.steps)
            rays = np.hstack([origins, directions])
            answer = client.closest("bench", rays, fields=CLOSEST_FIELDS)
            ray = np.flatnonzero(np.isfinite(answer.t))
            xyz = origins[ray] + answer.t[ray, None] * directions[ray]
            sizes["closest"] = (rays.nbytes + 128, sum(a.nbytes for a in answer.values()))
            return ray, xyz, answer.timing

        def run(kind, pose):
            if kind == "lidar":
                return lidar(pose)
            if kind == "closest":
                return closest(pose)
            origins, directions = scan_rays(pose, elevations, args.steps)
            if kind == "dacrt":
                return scene.closest(origins, directions)
            if kind == "embree build":
                fresh = Embree([(vertices, faces)])
                fresh.commit()
                return fresh.closest_t(origins, directions)
            return embree.closest_t(origins, directions)

        for kind in kinds:  # one untimed frame of each: first touches, the server's scene cache
            run(kind, poses[0])
        for frame, pose in enumerate(poses[1:]):
            turn = frame % len(kinds)
            results = {}
            for kind in kinds[turn:] + kinds[:turn]:
                start = time.perf_counter()
                results[kind] = run(kind, pose)
                seconds[kind].append(time.perf_counter() - start)
            (answer, timing), (ray, xyz, closest_timing) = results["lidar"], results["closest"]
            if "ray" in answer:
                assert np.array_equal(answer["ray"], ray), "lidar's hits differ from closest's"
            if "xyz" in answer:
                assert np.array_equal(answer["xyz"], xyz), "lidar's points differ from closest's"
            server_ms["lidar"].append(parse_server_timing(timing))
            server_ms["closest"].append(closest_timing)
            points.append(len(ray))
    finally:
        http.close()
        client.close()
        process.terminate()
        process.wait(timeout=30)

    def median_ms(values):
        return 1000 * statistics.median(values)

    print(f"machine: {os.cpu_count()} cores, {cpu_model()}; numpy {np.__version__}")
    print(
        f"scene: {Path(args.scene).name} ({len(faces)} triangles); {args.model} "
        f"({len(elevations)} beams) x {args.steps} steps = {n_rays} rays a frame; "
        f"{int(statistics.median(points))} points (median); medians of {args.frames} frames; "
        f"/lidar fields: {args.fields or 'all'}"
    )
    for kind in kinds:
        ms = median_ms(seconds[kind])
        print(f"  {kind:<14} {ms:8.1f} ms a frame  ({n_rays / ms / 1000:.2f} Mrays/s)")
    for kind in ("lidar", "closest"):
        parts = {
            key: statistics.median(t[key] for t in server_ms[kind])
            for key in ("receive", "decode", "trace", "encode")
        }
        shown = ", ".join(f"{key} {value:.1f}" for key, value in parts.items())
        print(f"  server timing of {kind} (ms): {shown}")
    print(
        f"  request body: lidar {sizes['lidar'][0]} bytes, closest {sizes['closest'][0]} bytes; "
        f"answer: lidar {sizes['lidar'][1]} bytes, closest {sizes['closest'][1]} bytes"
    )


#: The lidars of ``--physics`` beside the plain scan, by kind.
PHYSICS = {
    "scan": {},
    "noise": {"noise": {"range_sigma": 0.02, "range_sigma_per_m": 0.001, "angle_sigma_deg": 0.01}},
    "all 2": {"return_mode": "all", "max_returns": 2},
    "dual 3": {"return_mode": "dual", "beam_divergence_deg": 0.2, "beam_samples": 3},
    "dual 7": {"return_mode": "dual", "beam_divergence_deg": 0.2, "beam_samples": 7},
}


def physics(args, scene, poses, n_triangles: int) -> None:
    """Per frame, in process: the trace, today's geometric points, and each physics option."""
    elevations = MODELS[args.model].vertical_angles_deg
    lidars = {
        kind: Lidar(args.model, horizontal_steps=args.steps, **o) for kind, o in PHYSICS.items()
    }
    materials = Materials(0.5, 0)
    threads = args.threads

    def run(kind, pose):
        if kind == "closest":
            rays = lidars["scan"].shot(pose).rays
            return scene.closest(rays.origins, rays.directions, threads=threads)
        if kind == "geometry":
            scan = make_scan(pose, elevations, args.steps, 0.0, np.inf)
            origins, directions = scan.rays()
            hits = scene.closest(origins, directions, threads=threads)
            ray = np.flatnonzero(np.isfinite(hits.t)).astype(np.int32)
            return route_points(scan, origins, directions, ray, hits.t[ray], hits.normal[ray])
        return lidars[kind].scan(scene, pose, materials, threads=threads)

    kinds = ["closest", "geometry", *PHYSICS]
    seconds = {kind: [] for kind in kinds}
    counts = {kind: [] for kind in kinds}
    for kind in kinds:  # one untimed frame of each
        run(kind, poses[0])
    for frame, pose in enumerate(poses[1:]):
        turn = frame % len(kinds)
        for kind in kinds[turn:] + kinds[:turn]:
            start = time.perf_counter()
            answer = run(kind, pose)
            seconds[kind].append(time.perf_counter() - start)
            counts[kind].append(len(answer["range"]) if kind not in ("closest",) else 0)
    n_rays = len(elevations) * args.steps
    print(f"machine: {os.cpu_count()} cores, {cpu_model()}; numpy {np.__version__}")
    print(
        f"scene: {Path(args.scene).name} ({n_triangles} triangles); {args.model} x {args.steps} "
        f"steps = {n_rays} beams a frame; {threads} threads; medians of {args.frames} frames"
    )
    plain = statistics.median(seconds["scan"])
    for kind in kinds:
        ms = 1000 * statistics.median(seconds[kind])
        points = int(statistics.median(counts[kind])) if kind != "closest" else "-"
        ratio = statistics.median(seconds[kind]) / plain
        print(f"  {kind:<10} {ms:8.1f} ms a frame  {ratio:5.2f} x scan  points {points}")


if __name__ == "__main__":
    main()
