"""The app factory: ``uvicorn service.app:create_app --factory`` (with
``--http service.protocol:GuardedHttpProtocol`` for the deadlines and the connection bound)."""

from __future__ import annotations

import logging
import threading
import time
from contextlib import asynccontextmanager
from pathlib import Path

import numpy as np
from fastapi import FastAPI

from . import __version__, errors, tracing, wire
from .deps import Readiness
from .metrics import Metrics, MetricsMiddleware
from .routes import meshes, ops, queries
from .settings import Settings, load_settings_or_exit
from .store import Store

log = logging.getLogger("service")


def create_app(settings: Settings | None = None) -> FastAPI:
    """A new app with its own store, metrics and settings (from the environment if not given:
    then a bad or unknown DACRT_* variable ends the process with one line)."""
    settings = settings or load_settings_or_exit()
    store = Store(settings.max_triangles_per_scene, settings.max_scene_bytes)
    metrics = Metrics(lambda: store.nbytes, lambda: len(store.snapshots()))

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if settings.load_demo:
            load_demo(store, settings)
        threading.Thread(
            target=warm_up, args=(app.state.readiness,), name="dacrt-warmup", daemon=True
        ).start()
        yield

    app = FastAPI(title="dacrt ray-casting service", version=__version__, lifespan=lifespan)
    app.state.settings, app.state.store, app.state.metrics = settings, store, metrics
    app.state.readiness = Readiness()
    errors.install(app)
    for module in (meshes, queries, ops):  # each router carries its full prefix (route templates
        app.include_router(module.router)  # in metrics) and the token check of its /v1 routes
    app.add_middleware(errors.CatchAll)  # inside the metrics, so that they count its 500s
    app.add_middleware(MetricsMiddleware, metrics=metrics)
    return app


def warm_up(readiness: Readiness) -> None:
    """Compile the engine's kernels (a minute the first time, then from Numba's cache)."""
    start = time.perf_counter()
    try:
        tracing.warmup()
    except Exception as exc:  # report through /health rather than die in a thread
        log.exception("engine warm-up failed")
        readiness.error, readiness.status = f"{type(exc).__name__}: {exc}", "error"
        return
    readiness.seconds, readiness.status = time.perf_counter() - start, "ok"
    log.info("engine ready after %.1f s", readiness.seconds)


def load_demo(store: Store, settings: Settings) -> None:
    """Put the demo scene's mesh (named after its file) into scene ``settings.demo_name``."""
    path = settings.demo_path()
    if path is None:
        log.warning("no demo scene found (looked for scenes/teapot.npz); set DACRT_DEMO_SCENE")
        return
    with np.load(Path(path), allow_pickle=False) as archive:
        arrays = wire.mesh_arrays(archive["vertices"], archive["faces"])
    store.put_mesh(settings.demo_name, Path(path).stem, arrays)
    log.info("demo scene %r: %s (%d triangles)", settings.demo_name, path, len(arrays.faces))
