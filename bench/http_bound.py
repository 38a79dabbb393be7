"""The least a uvicorn service can add to a binary query: a bare ASGI app, no framework.

    uvicorn bench.http_bound:app    (started by ``python -m bench.http_overhead --bound``)

It answers the contract's wire formats (.npy (N, 6) rays in, .npz with all fields out, through
``service.wire`` as the service does) and nothing else: ``PUT`` with an .npz mesh body makes the
one scene, any ``POST`` is a closest query on it, ``GET`` is health. No routing, no parameters,
no checks beyond decoding, no metrics, no errors worth the name: not a service, a lower bound.
The service's overhead can come down to this app's, not below it.

At start it loads the engine's kernels from ``DACRT_CACHE_DIR`` (``bench.entry``), as the
service does; a SIGTERM while they load ends it at once.
"""

from __future__ import annotations

import json
import signal
import time

from anyio.to_thread import run_sync

import dacrt
from bench.entry import use_kernel_cache
from bench.http_floor import read_body
from service import wire

FIELDS = ("t", "mesh", "prim", "u", "v", "normal")
_scene: dacrt.Scene | None = None


async def app(scope, receive, send):
    global _scene
    if scope["type"] == "lifespan":
        while (await receive())["type"] == "lifespan.startup":
            # uvicorn's handler would only note a SIGTERM until the start ends: nothing to undo yet
            handler = signal.signal(signal.SIGTERM, signal.SIG_DFL)
            try:
                use_kernel_cache()
                dacrt.warmup()  # loaded (or compiled) before the port opens
            finally:
                signal.signal(signal.SIGTERM, handler)
            await send({"type": "lifespan.startup.complete"})
        await send({"type": "lifespan.shutdown.complete"})
        return
    if scope["method"] == "GET":
        await _send_json(send, 200, {"status": "ok"})
        return
    start = time.perf_counter()
    body = await read_body(scope, receive)
    received = time.perf_counter() - start
    if scope["method"] == "PUT":
        mesh = wire.decode_mesh(body, "npz")
        _scene = dacrt.Scene([(mesh.vertices, mesh.faces)])
        await _send_json(send, 201, {"triangles": len(mesh.faces)})
        return

    def work():
        timing = {"receive": received}
        start = time.perf_counter()
        rays = wire.decode_rays(body, "npy")
        timing["decode"] = time.perf_counter() - start
        hits = _scene.closest(rays.origins, rays.directions, rays.tmin, rays.tmax)
        timing["trace"] = time.perf_counter() - start - timing["decode"]
        answer = wire.encode_answer({name: getattr(hits, name) for name in FIELDS}, "npz")
        timing["encode"] = time.perf_counter() - start - timing["decode"] - timing["trace"]
        return answer, timing

    (parts, length, media), timing = await run_sync(work)
    server_timing = ", ".join(f"{name};dur={1000 * s:.3f}" for name, s in timing.items())
    await send(
        {
            "type": "http.response.start",
            "status": 200,
            "headers": [
                (b"content-type", media.encode()),
                (b"content-length", str(length).encode()),
                (b"x-scene-version", b"1"),
                (b"server-timing", server_timing.encode()),
            ],
        }
    )
    for part in parts:
        if len(part):
            await send({"type": "http.response.body", "body": part, "more_body": True})
    await send({"type": "http.response.body", "body": b""})


async def _send_json(send, status: int, payload: dict) -> None:
    body = json.dumps(payload).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
