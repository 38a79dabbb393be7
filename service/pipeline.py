"""The one path of a query or a sensor, ``answer``: its options come built (``params``), then
``receive`` (404, the body within the in-flight budget, its format), the route's ``Steps`` off the
event loop (decode, then trace and encode, the budget held for their peak in between), then
``respond`` (metrics and headers).

    route (options: params) -> receive -> decode (wire, sensor_requests)
        -> trace (tracing, sensing) -> encode (wire, shading) -> respond
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from anyio.to_thread import run_sync
from fastapi import Request

from . import wire
from .admission import Ticket
from .deps import Estimate, hold_decoding, read_body
from .metrics import Metrics
from .options import Options
from .responses import BuffersResponse
from .settings import Settings
from .store import Store, check_name
from .timing import ServerTiming
from .tracing import TraceResult

#: An answer's body: buffers to send in order, its length (None: unknown), its Content-Type.
Encoded = tuple[Iterable[wire.Buffer], int | None, str]


@dataclass(frozen=True)
class Decoded:
    """A body decoded: what the route's trace step takes, and what tracing it will hold."""

    value: Any  #: rays, a mesh and rays, or the engine's sensors and their poses
    n_rays: int
    peak: int  #: bytes the request holds at its peak from here on (body, work and answer)
    answer_format: str  #: npz, npy or json (``wire.negotiate``), or png


@dataclass(frozen=True)
class Steps:
    """What a query or sensor route does between receiving its body and answering."""

    formats: tuple[str, ...]  #: the body formats it reads (415 names them)
    estimate: Estimate  #: peak bytes of a body of n bytes in a format, before it is decoded
    decode: Callable[[memoryview, str], Decoded]  #: the body, in its format
    trace: Callable[[Any], TraceResult]  #: the engine's answer to ``Decoded.value``
    encode: Callable[[TraceResult, str], Encoded]  #: the answer in ``Decoded.answer_format``
    #: bytes it holds on the scene whatever its body (a sensor's one ray), for a 413's advice,
    #: where ``estimate`` of an empty body does not say
    least: Callable[[], int] | None = None
    #: what a 413 advises for a body too heavy for the budget, where batches do not apply
    advice: str | None = None


async def answer(
    request: Request,
    settings: Settings,
    store: Store | None,
    metrics: Metrics,
    options: Options,
    scene: str | None,
    format: str | None,
    steps: Steps,
) -> BuffersResponse:
    """Receive the body sent to ``scene`` of ``store`` (None: a one-shot /trace), decode it,
    hold the in-flight budget for its peak (``Decoded.peak``: with the work on the scene's
    triangles), trace and encode it, and answer; the steps run off the event loop."""
    request.state.ticket.advice = steps.advice
    got = await receive(
        request, settings, store, scene, format, steps.formats, steps.estimate, steps.least
    )

    def decode() -> Decoded:
        with got.timing("decode"):
            return steps.decode(got.body, got.fmt)

    decoded = await run_sync(decode)
    load = getattr(request.state, "load", "")  # on a scene: its triangles (``receive``)
    what = f"{request.method} {request.url.path} of {decoded.n_rays} rays{load}"
    await got.ticket.hold(decoded.peak + got.inflated, what)

    def work() -> tuple[TraceResult, Encoded]:
        with got.timing("trace"):
            result = steps.trace(decoded.value)
        with got.timing("encode"):
            return result, steps.encode(result, decoded.answer_format)

    result, encoded = await run_sync(work)
    return respond(metrics, options.kind.value, result, encoded, got.timing)


@dataclass
class Received:
    """A request's body, read within the budget."""

    body: memoryview
    fmt: str  #: the body's format (``wire.resolve_format``)
    ticket: Ticket  #: the request's share of the in-flight budget
    inflated: int  #: bytes an .npz body's deflated members inflate to (held with its estimate)
    timing: ServerTiming = field(default_factory=ServerTiming)


async def receive(
    request: Request,
    settings: Settings,
    store: Store | None,
    scene: str | None,
    format: str | None,
    formats: tuple[str, ...],
    estimate: Estimate,
    least: Callable[[], int] | None = None,
) -> Received:
    """404 for an unknown scene before the body is read, then the body (its estimated peak held
    in the budget) and its format (415 naming ``formats``); the estimate is held again for the
    format the body turned out to be in, with what a compressed .npz inflates to."""
    if scene is not None:  # the trace step takes the scene's version current by then
        n_triangles = store.snapshot(check_name("scene", scene)).n_triangles
        # what the budget's messages say of the request's load (``deps.BodyHold``)
        request.state.load = f" on the {n_triangles} triangles of scene {scene!r}"
        # its work on them, whatever its body (``least``: where the estimate does not hold it)
        request.state.ticket.least = max(estimate(0, None), least() if least else 0)
    timing = ServerTiming()
    with timing("receive"):
        body = await read_body(request, settings.max_body_bytes, estimate)
    route = request.scope["route"].path
    fmt = wire.resolve_format(
        request.headers.get("content-type"), format, formats, body, f"POST {route}"
    )
    inflated = await hold_decoding(request, body, fmt, estimate, settings.max_body_bytes)
    return Received(body, fmt, request.state.ticket, inflated, timing)


def encode_arrays(result: TraceResult, answer_format: str) -> Encoded:
    """An answer's arrays as an npz, npy or JSON body (``wire.encode_answer``)."""
    return wire.encode_answer(result.arrays, answer_format)


def respond(
    metrics: Metrics, kind: str, result: TraceResult, encoded: Encoded, timing: ServerTiming
) -> BuffersResponse:
    """The answer of a query or sensor ``kind``: counted in the metrics (with its CPU fallback,
    where DACRT_DEVICE=cuda), with X-Scene-Version,
    Server-Timing (with the cluster's time when it traced), X-Trace-Stats and the result's own
    headers."""
    metrics.traced(kind, result.n_rays, result.seconds)
    if result.fallback is not None:
        metrics.cuda_fallbacks.labels(result.fallback).inc()
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
