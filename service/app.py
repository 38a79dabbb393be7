"""The app factory: ``uvicorn service.app:create_app --factory`` (with
``--http service.protocol:GuardedHttpProtocol`` for the deadlines and the connection bound)."""

from __future__ import annotations

import logging
import threading
import time
from contextlib import asynccontextmanager
from importlib.util import find_spec
from pathlib import Path

import numpy as np
from fastapi import Depends, FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

import dacrt.cache
from dacrt import InputError

from . import __version__, allocator, errors, openapi, warmup, wire
from .admission import Admission, AdmissionMiddleware
from .cluster import Cluster
from .deps import Readiness, require_ready
from .errors import ServiceError
from .hosts import HostCheck
from .logs import configure_logging
from .metrics import Metrics, MetricsMiddleware
from .patterns import Patterns
from .persistence import DataDir, FolderLocked, lock_folder
from .protocol import HeadAsGet
from .routes import meshes, ops, pictures, points, queries
from .routes import patterns as pattern_routes
from .settings import Settings, load_settings_or_exit
from .store import Store

log = logging.getLogger("service")

#: Swagger UI's files, from the swagger-ui-py package (found, not imported): /docs needs no network.
SWAGGER_UI = Path(find_spec("swagger_ui").submodule_search_locations[0]) / "static"


def create_app(settings: Settings | None = None) -> FastAPI:
    """A new app with its own store, metrics and settings (from the environment if not given:
    then a bad or unknown DACRT_* variable ends the process with one line)."""
    settings = settings or load_settings_or_exit()
    configure_logging(settings.log_level)
    allocator.cap_arenas()  # before the worker threads: RSS then follows the in-flight budget
    journal = open_data_dir(settings)
    store = Store(
        settings.max_triangles_per_scene,
        settings.max_scene_bytes,
        journal,
        max_meshes_per_scene=settings.max_meshes_per_scene,
    )
    patterns = Patterns(settings.max_patterns, settings.max_pattern_rays, journal)
    metrics = Metrics(store.held_bytes, lambda: len(store.snapshots()), journal)
    admission = Admission(settings.inflight_budget(), settings.admission_wait)
    metrics.watch_admission(admission)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        # Where kernels compile to, before the first one runs: DACRT_CACHE_DIR (``dacrt.cache``)
        dacrt.cache.use_cache_dir(settings.cache_dir)
        if journal is not None:
            restore(store, journal)
            patterns.restore()
        if settings.load_demo:
            load_demo(store, settings)
        threading.Thread(
            target=warm_up,
            args=(app.state.readiness,),
            name="dacrt-warmup",
            daemon=True,
        ).start()
        if app.state.cluster is not None:
            app.state.cluster.start()
        yield
        app.state.readiness.stopping.set()
        if app.state.cluster is not None:
            app.state.cluster.close()
        if journal is not None:
            journal.close()  # the folder's lock: the next server on it may start

    app = FastAPI(
        title="dacrt ray-casting service",
        version=__version__,
        lifespan=lifespan,
        docs_url=None,  # served below from local files
    )
    app.state.settings, app.state.store, app.state.metrics = settings, store, metrics
    app.state.readiness, app.state.admission = Readiness(), admission
    app.state.patterns = patterns
    app.state.cluster = (
        Cluster(settings.dask_scheduler, settings.dask_min_rays, settings.dask_timeout)
        if settings.dask_scheduler is not None
        else None
    )
    errors.install(app)
    # each router carries its full prefix (route templates in metrics) and its /v1 token check
    for module in (meshes, queries, points, pictures, pattern_routes):
        app.include_router(
            module.router, dependencies=[Depends(require_ready)], responses=openapi.errors(503)
        )
    app.include_router(ops.router)
    build_document = app.openapi  # FastAPI's, which caches the document it builds

    def document() -> dict:
        return openapi.with_token_rule(build_document(), settings.token is not None)

    app.openapi = document  # type: ignore[method-assign]
    app.mount("/static/swagger-ui", StaticFiles(directory=str(SWAGGER_UI)), name="swagger-ui")

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url,
            title=f"{app.title} - Swagger UI",
            swagger_js_url="/static/swagger-ui/swagger-ui-bundle.js",
            swagger_css_url="/static/swagger-ui/swagger-ui.css",
            swagger_favicon_url="/static/swagger-ui/favicon-32x32.png",
        )

    app.add_middleware(AdmissionMiddleware, admission=admission)  # a ticket for each request
    app.add_middleware(errors.CatchAll)  # inside the metrics, so that they count its 500s
    # before any ticket is held; inside the metrics, so that an operator sees its refusals
    app.add_middleware(HostCheck, allowed=settings.host_names(), bind=settings.host)
    app.add_middleware(MetricsMiddleware, metrics=metrics, routes=app.router.routes)
    app.add_middleware(HeadAsGet)
    return app


def open_data_dir(settings: Settings) -> DataDir | None:
    """The data folder of DACRT_DATA_DIR (created if needed), locked for this process until the
    app stops; one that another process holds, that cannot be locked, created or written
    (read-only, no permission, failing) ends the process with one line. A full one is opened:
    reads are served and /health says degraded until a change succeeds."""
    if settings.data_dir is None:
        return None
    root = settings.data_dir.expanduser()
    where = f"dacrt-service: {settings.given('data_dir')}"
    try:
        lock = lock_folder(root)  # first: a folder another server holds is neither read nor written
    except FolderLocked as exc:
        raise SystemExit(f"{where}: {exc}") from None
    except OSError as exc:
        raise SystemExit(f"{where}: the data folder cannot be written: {exc}") from None
    try:
        return DataDir(root, lock)
    except OSError as exc:
        lock.close()
        raise SystemExit(f"{where}: the data folder cannot be written: {exc}") from None


def warm_up(readiness: Readiness) -> None:
    """Compile every kernel a request can reach (minutes the first time, in a child process:
    ``service.warmup``; then seconds from Numba's cache)."""
    try:
        seconds = warmup.warm_up(readiness.stopping)
    except warmup.Stopped as stopped:
        log.info("warm-up: %s", stopped)
        return
    except Exception as exc:  # report through /health rather than die in a thread
        log.exception("engine warm-up failed")
        readiness.error, readiness.status = f"{type(exc).__name__}: {exc}", "error"
        return
    readiness.seconds, readiness.status = seconds, "ok"
    log.info("engine ready after %.1f s", readiness.seconds)


def restore(store: Store, journal: DataDir) -> None:
    """Serve the scenes saved in the data folder, at their versions."""
    start = time.perf_counter()
    restored = journal.restore()
    store.restore(restored.snapshots, restored.last_versions)
    log.info(
        "data: restored %d scenes (%d triangles) from %s in %.1f s",
        len(restored.snapshots),
        sum(s.n_triangles for s in restored.snapshots),
        journal.root,
        time.perf_counter() - start,
    )


def load_demo(store: Store, settings: Settings) -> None:
    """Put the demo scene's mesh (named after its file) into scene ``settings.demo_name``,
    unless that scene was restored from the data folder."""
    try:
        path = settings.demo_path()
    except FileNotFoundError as exc:
        log.warning("no demo scene: %s; set DACRT_DEMO_SCENE to an .npz", exc)
        return
    if settings.demo_name in {s.scene for s in store.snapshots()}:
        log.info("demo scene %r: kept as restored from the data folder", settings.demo_name)
        return
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = wire.mesh_arrays(archive["vertices"], archive["faces"])
        store.put_mesh(settings.demo_name, path.stem, arrays)
    except (ServiceError, InputError, OSError, ValueError, KeyError) as exc:
        # the service itself works: say why the demo is missing, and go on
        reason = exc.detail if isinstance(exc, ServiceError) else f"{type(exc).__name__}: {exc}"
        log.warning(
            "no demo scene: %s could not be loaded: %s (DACRT_LOAD_DEMO=false starts without it)",
            path,
            reason,
        )
        return
    log.info("demo scene %r: %s (%d triangles)", settings.demo_name, path, len(arrays.faces))
