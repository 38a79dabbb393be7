"""Prometheus metrics: requests, rays traced, trace seconds, scene memory, the data folder's
failed writes.

Each app gets its own registry, so several apps (tests) can live in one process.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector
from starlette.routing import BaseRoute, Match

from .errors import CUT_OFF, status_of

if TYPE_CHECKING:
    from .admission import Admission
    from .persistence import DataDir

#: Scope key of the method the client sent, where a middleware outside the metrics serves the
#: request as another (``protocol.HeadAsGet``: a HEAD as its GET)
CLIENT_METHOD = "dacrt.client_method"
#: The route label of a request that no route matched (a 404)
UNMATCHED_ROUTE = "unmatched"
#: The route label of an answer the HTTP protocol writes itself (``service.protocol``): to
#: headers too slow, too large or not HTTP/1.1, and to a connection over a bound
PROTOCOL_ROUTE = "protocol"
#: The route label of a request ``hosts.HostCheck`` refused (its 403), and the scope key that
#: marks it: no route ran
REFUSED_ROUTE = "refused"
#: The method label of a request answered before its method was read
UNKNOWN_METHOD = "unknown"

_SECONDS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60)


class Metrics:
    """The service's metrics in their own registry (served by GET /metrics)."""

    def __init__(
        self,
        scene_bytes: Callable[[], float],
        scene_count: Callable[[], float],
        data_dir: DataDir | None = None,
    ) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "dacrt_requests",
            "HTTP requests by method, route and status",
            ("method", "route", "status"),
            registry=self.registry,
        )
        self.request_seconds = Histogram(
            "dacrt_request_seconds",
            "HTTP request time by route",
            ("route",),
            buckets=_SECONDS,
            registry=self.registry,
        )
        self.rays = Counter(
            "dacrt_rays_traced",
            "Rays traced, by query, as DACRT_MAX_RAYS_PER_REQUEST counts them: a query's rays, a "
            "picture's pixels, a lidar's beams x beam_samples (x max_returns with return_mode "
            "all), a point query's points (x nsamples with sign=true)",
            ("query",),
            registry=self.registry,
        )
        self.cuda_fallbacks = Counter(
            "dacrt_cuda_fallbacks",
            "Queries traced on the CPU although DACRT_DEVICE=cuda, by what the CUDA backend lacks",
            ("reason",),
            registry=self.registry,
        )
        self.trace_seconds = Histogram(
            "dacrt_trace_seconds",
            "Engine time per query batch",
            ("query",),
            buckets=_SECONDS,
            registry=self.registry,
        )
        Gauge(
            "dacrt_scene_memory_bytes",
            "Bytes held by all scenes: vertices and faces, and each version's engine scene once "
            "queried",
            registry=self.registry,
        ).set_function(scene_bytes)
        Gauge("dacrt_scenes", "Scenes held", registry=self.registry).set_function(scene_count)
        if data_dir is not None:
            self.registry.register(DataDirCollector(data_dir))

    def watch_admission(self, admission: Admission) -> None:
        """Gauges of the in-flight budget (``service.admission``) and a count of its refusals."""
        Gauge(
            "dacrt_inflight_bytes",
            "Bytes the requests in flight hold in the budget DACRT_MAX_INFLIGHT_BYTES",
            registry=self.registry,
        ).set_function(lambda: admission.held)
        Gauge(
            "dacrt_inflight_budget_bytes",
            "DACRT_MAX_INFLIGHT_BYTES in force",
            registry=self.registry,
        ).set_function(lambda: admission.budget)
        admission.on_refused = Counter(
            "dacrt_admission_refused",
            "Requests answered 503 for lack of room in the in-flight budget",
            registry=self.registry,
        ).inc

    def answered(self, method: str, route: str, status: int, seconds: float) -> None:
        """Count a request answered ``status`` after ``seconds``."""
        self.requests.labels(method, route, str(status)).inc()
        self.request_seconds.labels(route).observe(seconds)

    def traced(self, query: str, n_rays: int, seconds: float) -> None:
        self.rays.labels(query).inc(n_rays)
        self.trace_seconds.labels(query).observe(seconds)


class DataDirCollector(Collector):
    """The data folder's state, read from it at each scrape: its failed changes by OS error
    (``dacrt_data_dir_errors_total{errno="ENOSPC"}``) and whether it takes writes."""

    def __init__(self, data_dir: DataDir) -> None:
        self.data_dir = data_dir

    def collect(self):
        errors = CounterMetricFamily(
            "dacrt_data_dir_errors",
            "Changes the data folder (DACRT_DATA_DIR) failed to write, by OS error",
            labels=("errno",),
        )
        for name, count in sorted(dict(self.data_dir.errors).items()):
            errors.add_metric((name,), count)
        yield errors
        yield GaugeMetricFamily(
            "dacrt_data_dir_writable",
            "1 while the data folder takes writes, 0 after a change failed (until one succeeds)",
            value=float(self.data_dir.fault is None),
        )


class MetricsMiddleware:
    """Pure ASGI middleware counting every HTTP request by the method the client sent and the
    template of the route (of ``routes``, the app's) that served it, not its path."""

    def __init__(self, app, metrics: Metrics, routes: list[BaseRoute]) -> None:
        self.app, self.metrics, self.routes = app, metrics, routes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        status = 500
        start = time.perf_counter()
        arrived = dict(scope)  # the router rewrites what it matches (a mount's root_path)

        async def send_and_note(message):
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_and_note)
        finally:
            cut_off = scope.get("state", {}).get(CUT_OFF)
            if cut_off is not None:  # what the client got; the app's own answer went nowhere
                status = status_of(cut_off)
            route = route_template(scope, arrived, self.routes)
            method = scope.get(CLIENT_METHOD, scope["method"])
            self.metrics.answered(method, route, status, time.perf_counter() - start)


def route_template(scope, arrived, routes: list[BaseRoute]) -> str:
    """The path template of the route that served a request: its FastAPI route's, which the
    router puts in ``scope``, else that of the first of ``routes`` that the request as it
    ``arrived`` matches whole (Starlette's own: ``/openapi.json``, a mount's
    ``/static/swagger-ui/{path}``); REFUSED_ROUTE for a request the host check refused;
    UNMATCHED_ROUTE when none matches."""
    route = scope.get("route")
    if route is not None:
        return route.path
    if scope.get(REFUSED_ROUTE):
        return REFUSED_ROUTE
    for candidate in routes:
        if candidate.matches(arrived)[0] is Match.FULL:
            return candidate.path_format
    return UNMATCHED_ROUTE
