"""HTTP overhead of the service: what a 1M-ray binary query costs beyond the engine's own time.

    python -m bench.http_overhead [SCENE.npz] [--rays 1000000] [--repeat 5] [--fields ...] [--bound]

Side by side in one run, alternating (the order swapped every round), medians of ``--repeat``,
after one untimed round of each:
  engine      ``dacrt.Scene(...).closest`` in this process (the scene built once, as the server
              caches it)
  end to end  the same rays through a real uvicorn server on loopback with httpx: .npy (N, 6) in,
              .npz out (all fields), including the client's encoding and its reading of the answer
The overhead is ``end to end - engine``: receive + decode + encode + transport, on both sides.
The server's own Server-Timing (receive, decode, trace, encode) is shown too. BENCHMARKS.md asks
for at most 10% of the trace time; the service issue for at most ~15%.

With ``--bound``, also ``bench.http_bound``'s bare ASGI app on a second uvicorn server, in the same
rounds: the least any uvicorn service could add (no framework, no checks), the service's floor.

With ``--frame``, also the per-frame loop of a dynamic scene, side by side in the same run:
  http frame    upload the mesh (moved a little every frame, .npz) then POST the rays
  dacrt frame   a new ``dacrt.Scene`` plus ``closest``, in process
  embree frame  a new Embree scene (embreex) plus ``run``, in process (needs embreex)
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import signal
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import dacrt  # noqa: E402
from bench.entry import description, kernel_cache_env, use_kernel_cache  # noqa: E402
from oracles.embree import Embree  # noqa: E402
from service.children import ending_with_parent  # noqa: E402
from service.client import Client  # noqa: E402


def make_rays(vertices: np.ndarray, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rays from a sphere around the scene towards random points in its bounds (most hit)."""
    rng = np.random.default_rng(seed)
    lo, hi = vertices.min(0), vertices.max(0)
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    away = rng.normal(size=(n, 3))
    origins = centre + 2 * radius * away / np.linalg.norm(away, axis=1, keepdims=True)
    targets = rng.uniform(lo, hi, (n, 3))
    return origins.astype(np.float32), (targets - origins).astype(np.float32)


def start_server(
    env: dict[str, str], app: tuple[str, ...] = ("service.app:create_app", "--factory")
) -> tuple[subprocess.Popen, str]:
    """A uvicorn server of ``app`` on a free loopback port, once its /health answers ok. It loads
    dacrt's kernels from this process's folder (``bench.entry.kernel_cache_env``), and ends with
    the thread that starts it."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uvicorn",
            *app,
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--log-level",
            "warning",
        ],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO), **kernel_cache_env(), **env},
        preexec_fn=ending_with_parent(signal.SIGKILL),
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise SystemExit(f"server exited with {process.returncode}")
        try:
            if httpx.get(f"{url}/health", timeout=2).json().get("status") == "ok":
                return process, url
        except (httpx.HTTPError, ValueError):
            pass
        time.sleep(0.25)
    process.terminate()
    raise SystemExit("server not ready after 300 s")


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def main() -> None:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("scene", nargs="?", default=str(REPO / "service" / "data" / "teapot.npz"))
    parser.add_argument("--rays", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--fields", default=None, help="e.g. t,mesh,prim (default: all)")
    parser.add_argument(
        "--bound",
        action="store_true",
        help="also time bench.http_bound's bare ASGI app (the service's floor)",
    )
    parser.add_argument(
        "--frame",
        action="store_true",
        help="also time the per-frame loop (new mesh + rays) against Embree",
    )
    args = parser.parse_args()

    with np.load(args.scene) as archive:
        vertices = np.ascontiguousarray(archive["vertices"], np.float32)
        faces = np.ascontiguousarray(archive["faces"], np.int32)
    origins, directions = make_rays(vertices, args.rays)
    rays = np.hstack(
        [origins, directions]
    )  # the (N, 6) body, built once, as a caller would hold it

    use_kernel_cache()
    dacrt.warmup()
    scene = dacrt.Scene([(vertices, faces)])
    env = {"DACRT_MAX_RAYS_PER_REQUEST": str(max(args.rays, 1))}
    servers = {"http": start_server(env)}
    if args.bound:
        servers["bound"] = start_server(env, ("bench.http_bound:app",))
    clients = {kind: Client(url) for kind, (_, url) in servers.items()}
    seconds = {"engine": [], **{kind: [] for kind in servers}}
    server = {kind: [] for kind in servers}
    frames = None
    try:
        for client in clients.values():
            client.put_mesh("bench", "mesh", vertices, faces)
            # One untimed round of each at full size: the first 1M-ray request of a fresh server
            # touches its body and answer memory for the first time (page faults; receive took
            # 60 ms instead of 4-5 in the first two requests), and so does the first engine call.
            client.closest(
                "bench", rays, fields=args.fields
            )  # the server builds and caches its scene
        reference = scene.closest(origins, directions)
        kinds = list(seconds)
        for repeat in range(args.repeat):
            # The order turns every round: whichever runs after another can be slowed by what
            # the one before leaves to do (a fixed order once made the second 1.5 ms slower).
            turn = repeat % len(kinds)
            order = kinds[turn:] + kinds[:turn]
            for kind in order[::-1] if (repeat // len(kinds)) % 2 else order:
                start = time.perf_counter()
                if kind == "engine":
                    scene.closest(origins, directions)
                    seconds[kind].append(time.perf_counter() - start)
                else:
                    answer = clients[kind].closest("bench", rays, fields=args.fields)
                    seconds[kind].append(time.perf_counter() - start)
                    server[kind].append(answer.timing)
                    assert np.array_equal(answer.t, reference.t), (
                        f"{kind}: the answer differs from the engine's"
                    )
        if args.frame:
            frames = time_frames(clients["http"], vertices, faces, origins, directions, rays, args)
    finally:
        for client in clients.values():
            client.close()
        for process, _ in servers.values():
            process.terminate()
            process.wait(timeout=30)

    def median_ms(values):
        return 1000 * statistics.median(values)

    engine = seconds["engine"]
    engine_ms = median_ms(engine)
    print(f"machine: {os.cpu_count()} cores, {cpu_model()}; numpy {np.__version__}")
    print(
        f"scene: {Path(args.scene).name} ({len(faces)} triangles); {args.rays} rays; "
        f"fields: {args.fields or 'all'}; medians of {args.repeat}"
    )
    print(
        f"engine in-process      {engine_ms:9.1f} ms   ({args.rays / engine_ms / 1000:.2f} Mrays/s)"
    )
    for kind, title in (("http", "the service"), ("bound", "bench.http_bound (the floor)")):
        if kind not in servers:
            continue
        e2e_ms = median_ms(seconds[kind])
        overhead_ms = e2e_ms - engine_ms
        print(f"end to end over HTTP, {title}: {e2e_ms:.1f} ms")
        for key in ("receive", "decode", "trace", "encode"):
            print(
                f"  server {key:<8}      "
                f"{statistics.median(t.get(key, 0.0) for t in server[kind]):9.1f} ms"
            )
        server_trace_ms = statistics.median(t.get("trace", 0.0) for t in server[kind])
        print(
            f"HTTP overhead          {overhead_ms:9.1f} ms = "
            f"{100 * overhead_ms / engine_ms:.1f}% of engine time"
        )
        print(
            f"  (end to end - server trace = {e2e_ms - server_trace_ms:.1f} ms = "
            f"{100 * (e2e_ms - server_trace_ms) / server_trace_ms:.1f}% of the server's trace time)"
        )
        # Each request against the engine call of its round: steadier when the machine's load
        # drifts.
        paired = [e - g for e, g in zip(seconds[kind], engine)]
        paired_ms = median_ms(paired)
        print(
            f"  (median of paired differences = {paired_ms:.1f} ms = "
            f"{100 * paired_ms / engine_ms:.1f}% "
            f"of engine time; they ranged {1000 * min(paired):.1f} to {1000 * max(paired):.1f} ms)"
        )
    if frames:
        print(f"per frame (new mesh + {args.rays} rays), medians of {args.repeat}:")
        for name, seconds in frames.items():
            print(f"  {name:<14} {median_ms(seconds):9.1f} ms")
        if "embree frame" in frames:
            embree_ms = median_ms(frames["embree frame"])
            for name in ("http frame", "dacrt frame"):
                print(f"  {name} / embree frame = {median_ms(frames[name]) / embree_ms:.2f}")
    print(f"load average during the run: {os.getloadavg()[0]:.2f}")


def time_frames(client, vertices, faces, origins, directions, rays, args):
    """Per-frame loops, alternating: every frame the mesh moves, so nothing can be reused."""
    with_embree = importlib.util.find_spec("embreex") is not None
    seconds = {"http frame": [], "dacrt frame": []}
    if with_embree:
        seconds["embree frame"] = []
    for frame in range(args.repeat):
        moved = vertices + np.float32(1e-3 * (frame + 1))
        start = time.perf_counter()
        client.put_mesh("bench", "mesh", moved, faces)
        client.closest("bench", rays, fields=args.fields)
        seconds["http frame"].append(time.perf_counter() - start)
        start = time.perf_counter()
        dacrt.Scene([(moved, faces)]).closest(origins, directions)
        seconds["dacrt frame"].append(time.perf_counter() - start)
        if with_embree:
            start = time.perf_counter()
            Embree([(moved, faces)]).closest_t(origins, directions)
            seconds["embree frame"].append(time.perf_counter() - start)
    return seconds


if __name__ == "__main__":
    main()
