"""The floor under the HTTP overhead: what moving a 1M-ray request and its answer costs with no
work.

    python -m bench.http_floor [--rays 1000000] [--repeat 21]

Side by side in one run, medians of ``--repeat``, the bytes of a 1M-ray ``closest`` request with
all fields (24 B per ray in as .npy (N, 6), 32 B per ray out):
  plain TCP         two Python processes, ``sendall`` and ``recv_into`` a preallocated buffer
  uvicorn + httpx   a minimal ASGI app (this module's ``app``) that copies the body into a
                    ``wire.BodyBuffer`` and sends a preallocated answer in 4 MB parts; the client
                    sends 1 MiB views and reads the answer into a ``BodyBuffer``, as
                    ``service.client`` does, over httpx's own transport (httpcore, h11)
  ... on urllib3     the same through ``service.transport.PooledTransport``, the client's
The service cannot be cheaper than the last line; ``bench.http_overhead`` measures what it adds.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
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

# E402: the repo root must be on sys.path (above) before the service package is imported
from bench.entry import description  # noqa: E402
from service.transport import PooledTransport  # noqa: E402
from service.wire import BodyBuffer  # noqa: E402

RAY_BYTES, ANSWER_BYTES = 24, 32
ANSWER_PART = 4 << 20
_ANSWER = np.zeros(int(os.environ.get("FLOOR_RAYS", "1000000")) * ANSWER_BYTES, np.uint8)


async def app(scope, receive, send):
    """Read the body into one buffer, answer with ANSWER_BYTES per ray: the least a service does."""
    if scope["type"] != "http":
        return
    await read_body(scope, receive)
    view = memoryview(_ANSWER)
    parts = [view[i : i + ANSWER_PART] for i in range(0, len(view), ANSWER_PART)]
    await send(
        {
            "type": "http.response.start",
            "status": 200,
            "headers": [(b"content-length", str(len(view)).encode())],
        }
    )
    for i, part in enumerate(parts):
        await send({"type": "http.response.body", "body": part, "more_body": i < len(parts) - 1})


async def read_body(scope, receive) -> memoryview:
    """The whole request body, received into one ``BodyBuffer`` of its Content-Length."""
    body = BodyBuffer(int(dict(scope["headers"]).get(b"content-length", b"0")))
    more = True
    while more:
        message = await receive()
        body.add(message.get("body", b""))
        more = message.get("more_body", False)
    return body.finish()


def _tcp_server(port_queue, n_in: int, n_out: int) -> None:
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port_queue.put(listener.getsockname()[1])
        connection, _ = listener.accept()
    connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    received, answer = np.empty(n_in, np.uint8), np.ones(n_out, np.uint8)
    while True:
        view, got = memoryview(received), 0
        while got < n_in:
            n = connection.recv_into(view[got:], n_in - got)
            if n == 0:
                return
            got += n
        connection.sendall(answer)


def time_tcp(n_in: int, n_out: int, repeat: int) -> list[float]:
    port_queue = multiprocessing.Queue()
    server = multiprocessing.Process(
        target=_tcp_server, args=(port_queue, n_in, n_out), daemon=True
    )
    server.start()
    seconds = []
    try:
        with socket.create_connection(("127.0.0.1", port_queue.get())) as connection:
            connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            request, answer = np.ones(n_in, np.uint8), np.empty(n_out, np.uint8)
            for _ in range(repeat):
                start = time.perf_counter()
                connection.sendall(request)
                view, got = memoryview(answer), 0
                while got < n_out:
                    got += connection.recv_into(view[got:], n_out - got)
                seconds.append(time.perf_counter() - start)
    finally:
        server.terminate()
    return seconds


def time_uvicorn(n_rays: int, repeat: int) -> dict[str, list[float]]:
    """Both client transports against one do-nothing server, requests alternating."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uvicorn",
            "bench.http_floor:app",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--log-level",
            "warning",
        ],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO), "FLOOR_RAYS": str(n_rays)},
    )
    rays = np.random.default_rng(0).standard_normal((n_rays, 6)).astype(np.float32)
    view = memoryview(rays).cast("B")
    parts = [view[i : i + (1 << 20)] for i in range(0, len(view), 1 << 20)]
    headers = {"content-length": str(len(view)), "content-type": "application/x-npy"}
    seconds: dict[str, list[float]] = {"httpx": [], "urllib3": []}
    url = f"http://127.0.0.1:{port}"
    clients = {
        "httpx": httpx.Client(base_url=url, timeout=60),
        "urllib3": httpx.Client(base_url=url, timeout=60, transport=PooledTransport()),
    }
    try:
        for _ in range(200):
            try:
                clients["httpx"].get("/")
                break
            except httpx.TransportError:
                time.sleep(0.1)
        for rep in range(repeat + 1):  # the first warms the connections up
            for name, client in clients.items():
                start = time.perf_counter()
                with client.stream("POST", "/", content=parts, headers=headers) as response:
                    answer = BodyBuffer(int(response.headers["content-length"]))
                    for chunk in response.iter_bytes():
                        answer.add(chunk)
                    answer.finish()
                if rep:
                    seconds[name].append(time.perf_counter() - start)
    finally:
        for client in clients.values():
            client.close()
        server.terminate()
        server.wait(timeout=30)
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--rays", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=21)
    args = parser.parse_args()
    n_in, n_out = RAY_BYTES * args.rays, ANSWER_BYTES * args.rays
    tcp, httpx_own, stdlib = [], [], []
    for _ in range(3):  # alternate TCP and uvicorn, a third of the requests at a time
        tcp += time_tcp(n_in, n_out, -(-args.repeat // 3))
        seconds = time_uvicorn(args.rays, -(-args.repeat // 3))
        httpx_own += seconds["httpx"]
        stdlib += seconds["urllib3"]
    print(
        f"{args.rays} rays: {n_in / 1e6:.0f} MB in, {n_out / 1e6:.0f} MB out; "
        f"medians of {len(tcp)}; {os.cpu_count()} cores"
    )
    print(f"plain TCP                          {1000 * statistics.median(tcp):7.1f} ms")
    print(f"uvicorn + httpx (httpx transport)  {1000 * statistics.median(httpx_own):7.1f} ms")
    print(f"uvicorn + httpx on urllib3         {1000 * statistics.median(stdlib):7.1f} ms")


if __name__ == "__main__":
    main()
