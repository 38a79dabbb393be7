"""The one path of a query or a sensor: ``receive`` (404, the body within the in-flight budget,
its format), the route's work off the event loop, then ``respond`` (metrics and headers).

    route -> receive -> wire decode -> engine (tracing, sensing) -> wire encode -> respond
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from fastapi import Request

from . import wire
from .admission import Ticket
from .deps import Estimate, read_body
from .metrics import Metrics
from .responses import BuffersResponse
from .settings import Settings
from .store import Snapshot, Store, check_name
from .timing import ServerTiming


@dataclass
class Received:
    """A request's body, read within the budget, and what it was sent to."""

    snapshot: Snapshot | None  #: the scene's version when the request arrived (None: /trace)
    body: memoryview
    fmt: str  #: the body's format (``wire.resolve_format``)
    ticket: Ticket  #: the request's share of the in-flight budget
    timing: ServerTiming = field(default_factory=ServerTiming)


async def receive(
    request: Request,
    settings: Settings,
    store: Store | None,
    scene: str | None,
    format: str | None,
    formats: tuple[str, ...],
    estimate: Estimate,
) -> Received:
    """404 for an unknown scene before the body is read, then the body (its estimated peak held
    in the budget) and its format (415 naming ``formats``); the estimate is held again for the
    format the body turned out to be in."""
    snapshot = store.snapshot(check_name("scene", scene)) if scene is not None else None
    timing = ServerTiming()
    with timing("receive"):
        body = await read_body(request, settings.max_body_bytes, estimate)
    route = request.scope["route"].path
    fmt = wire.resolve_format(
        request.headers.get("content-type"), format, formats, body, f"POST {route}"
    )
    ticket: Ticket = request.state.ticket
    await ticket.hold(estimate(len(body), fmt), f"POST {request.url.path} with a {fmt} body")
    return Received(snapshot, body, fmt, ticket, timing)


def respond(
    metrics: Metrics,
    kind: str,
    result: Any,
    n_rays: int,
    encoded: tuple[Iterable[wire.Buffer], int | None, str],
    timing: ServerTiming,
) -> BuffersResponse:
    """The answer of a query or sensor ``kind``: counted in the metrics, with X-Scene-Version,
    Server-Timing (with the cluster's time when it traced), X-Trace-Stats and the result's own
    headers."""
    metrics.traced(kind, n_rays, result.seconds)
    if result.where != "process":  # e.g. cluster;dur=...: traced on the dask cluster
        timing.seconds[result.where] = result.seconds
    headers = {
        "X-Scene-Version": str(result.version),
        "Server-Timing": timing.header(),
        **result.headers,
    }
    if result.stats is not None:
        headers["X-Trace-Stats"] = json.dumps(result.stats, separators=(",", ":"))
    return BuffersResponse(*encoded, headers)
