"""Request plumbing shared by the routes: what a handler uses (settings, store, metrics,
readiness) as ``Annotated`` dependencies, the bearer token, bounded body reading."""

from __future__ import annotations

import asyncio
import difflib
import secrets
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated

from anyio.to_thread import run_sync
from fastapi import Depends, Request
from fastapi.routing import APIRoute
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from . import footprint, wire
from .admission import Ticket
from .errors import (
    BadBody,
    Invalid,
    NotImplementedCoding,
    NotReady,
    TooLarge,
    Unauthorized,
    UnsupportedMediaType,
)
from .metrics import Metrics
from .patterns import Patterns
from .settings import Settings
from .store import Store
from .wire.body import BodyBuffer


@dataclass
class Readiness:
    """Warm-up state: ``starting`` until every kernel a request reaches is compiled
    (``service.warmup``), then ``ok`` (or ``error``)."""

    status: str = "starting"
    seconds: float | None = None
    error: str | None = None
    #: set when the app stops: a warm-up still compiling ends its child process
    stopping: threading.Event = field(default_factory=threading.Event)


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_patterns(request: Request) -> Patterns:
    return request.app.state.patterns


def get_metrics(request: Request) -> Metrics:
    return request.app.state.metrics


def get_readiness(request: Request) -> Readiness:
    return request.app.state.readiness


#: What a handler uses, in its signature (tests may override the ``get_*`` functions).
SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
MetricsDep = Annotated[Metrics, Depends(get_metrics)]
PatternsDep = Annotated[Patterns, Depends(get_patterns)]
ReadinessDep = Annotated[Readiness, Depends(get_readiness)]


#: Declares the bearer scheme in the OpenAPI document; ``require_token`` words the refusals.
bearer = HTTPBearer(auto_error=False, description="the server's DACRT_TOKEN, when it has one")


def require_token(
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
) -> None:
    """Dependency of every /v1 route: 401 unless the configured bearer token is presented."""
    token = settings.token
    if token is None:
        return
    if credentials is None or not credentials.credentials.strip():
        raise Unauthorized(
            "this server needs the header 'Authorization: Bearer <token>' on every "
            "/v1 request (the token is the server's DACRT_TOKEN)"
        )
    presented = credentials.credentials.strip().encode()
    if not secrets.compare_digest(presented, token.get_secret_value().encode()):
        raise Unauthorized("the bearer token is wrong; use the server's DACRT_TOKEN")


def require_ready(ready: ReadinessDep, _: Annotated[None, Depends(require_token)]) -> None:
    """Dependency of the scene and query routes: 503 with Retry-After while the kernels compile,
    rather than a request that waits minutes for the compiler. The token is checked first, so a
    caller without it learns nothing of the engine's state (a compile error names paths)."""
    if ready.status == "starting":
        raise NotReady("the engine is compiling its kernels (GET /health says when it is ready)")
    if ready.status == "error":
        raise NotReady(f"the engine failed to compile: {ready.error}; see the server's log")


async def reject_unknown_query(request: Request) -> None:
    """Dependency of every route: 422 for a query parameter the route does not take, which would
    otherwise be ignored silently (``?feilds=t`` answering every field), or one given twice,
    which would answer by its last value (``?fields=t&fields=mesh``)."""
    route = request.scope.get("route")
    known = query_parameters(route)
    unknown = [name for name in request.query_params if name not in known]
    if not unknown:
        for name in request.query_params:  # every parameter takes one value: a repeat is a slip
            given = request.query_params.getlist(name)
            if len(given) > 1:
                raise Invalid(
                    f"query parameter {name!r} is given {len(given)} times "
                    f"({', '.join(map(repr, given[:4]))}); give it once"
                )
        return
    name = unknown[0]
    close = difflib.get_close_matches(name, known, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    takes = f"takes {', '.join(known)}" if known else "takes no query parameters"
    raise Invalid(f"unknown query parameter {name!r}{hint}; {request.method} {route.path} {takes}")


def query_parameters(route: APIRoute) -> tuple[str, ...]:
    """The query parameter names a route and its dependencies declare."""
    names, pending = [], [route.dependant]
    while pending:
        dependant = pending.pop()
        names += [param.alias for param in dependant.query_params if param.alias not in names]
        pending += dependant.dependencies
    return tuple(names)


#: A body whose Content-Length is known holds its whole estimate while it arrives at least this
#: fast (bytes a second), give or take BODY_STEP bytes ...
RESERVED_BODY_RATE = 8 * 2**20
#: ... and once it falls behind (a slow or stalled client), the bytes it has received and this
#: many more, growing as the rest arrives, as a body of unknown length (chunked) does from its
#: start. A huge page: what a partly filled ``wire.BodyBuffer`` may take beyond its bytes.
BODY_STEP = 2 * 2**20

#: The peak bytes of a request whose body has this many bytes, in this format (None: not known
#: from Content-Type yet): ``service.footprint``'s estimates.
Estimate = Callable[[int, str | None], int]


async def read_body(request: Request, limit: int, estimate: Estimate) -> memoryview:
    """The whole body (a read-only ``wire.BodyBuffer``), refused (413) as soon as it is known to
    exceed ``limit``, DACRT_MAX_BODY_BYTES, or its ``estimate(length, format)`` the whole
    in-flight budget (``service.admission``). Before a byte is read, the request's ticket holds
    the estimate of the length Content-Length declares, until the body falls behind
    RESERVED_BODY_RATE (``BodyHold``); the caller holds the estimate again once it is whole."""
    check_codings(request)
    declared = request.headers.get("content-length")
    expected = int(declared) if declared is not None and declared.isdigit() else None
    if expected is not None and expected > limit:
        raise TooLarge(
            f"body of {expected} bytes is over the limit of {limit} bytes (DACRT_MAX_BODY_BYTES)"
        )
    fmt = wire.declared_format(request.headers.get("content-type"))
    hold = BodyHold(request, expected if expected is not None else limit)
    if expected is not None:
        await hold.reserve(estimate(expected, fmt))
    try:
        body = BodyBuffer(expected)
        async for chunk in request.stream():
            size = body.size + len(chunk)
            if size > limit:
                raise TooLarge(f"body is over the limit of {limit} bytes (DACRT_MAX_BODY_BYTES)")
            if size > hold.covered:
                await hold.grow(size, estimate(size, fmt))
            body.add(chunk)
            hold.received = body.size
    finally:
        hold.stop_watching()
    if expected is not None and body.size != expected:
        raise BadBody(f"body ended after {body.size} of its {expected} bytes (Content-Length)")
    return body.finish()


class BodyHold:
    """What a request's ticket holds while its body arrives: the estimate of the whole body
    (``reserve``) while it arrives at RESERVED_BODY_RATE or faster, else the bytes received
    and BODY_STEP more (``grow``). A client that sends its body slowly, or stalls, keeps no
    more of the budget than what it has sent."""

    def __init__(self, request: Request, most: int) -> None:
        self.ticket: Ticket = request.state.ticket
        #: the request in the budget's messages, with its load on a scene (``pipeline.receive``)
        self.route = f"{request.method} {request.url.path}{getattr(request.state, 'load', '')}"
        self.most = most  #: the body's Content-Length, or else DACRT_MAX_BODY_BYTES
        self.received = 0  #: body bytes received
        self.covered = 0  #: body bytes that what the ticket holds covers
        self._start = 0.0
        self._watch: asyncio.TimerHandle | None = None

    async def reserve(self, whole: int) -> None:
        """Hold ``whole``, the whole body's estimate (waiting in line), then watch its pace."""
        await self.ticket.hold(whole, f"{self.route} with a body of {self.most} bytes")
        self.covered = self.most
        loop = asyncio.get_running_loop()
        self._start = loop.time()
        self._watch = loop.call_at(self._due(), self._check_pace)

    async def grow(self, size: int, estimate: int) -> None:
        """Hold ``size`` received bytes and BODY_STEP more (413 once the estimate of ``size``
        bytes exceeds the budget)."""
        what = f"{self.route} with a body of {size} bytes so far"
        self.ticket.check(estimate, what)
        self.covered = min(size + BODY_STEP, self.most)
        await self.ticket.hold(self.covered, what)

    def stop_watching(self) -> None:
        if self._watch is not None:
            self._watch.cancel()

    def _due(self) -> float:
        """When the body falls behind RESERVED_BODY_RATE if no more of it arrives."""
        return self._start + (self.received + BODY_STEP) / RESERVED_BODY_RATE

    def _check_pace(self) -> None:
        loop = asyncio.get_running_loop()
        if loop.time() < self._due():
            self._watch = loop.call_at(self._due(), self._check_pace)
            return
        self._watch = None
        self.covered = min(self.received + BODY_STEP, self.most)
        self.ticket.shrink(self.covered)


def check_codings(request: Request) -> None:
    """415 for a ``Content-Encoding`` (the body is read as sent), 501 for a ``Transfer-Encoding``
    other than chunked."""
    encoding = request.headers.get("content-encoding", "identity").strip().lower()
    if encoding not in ("", "identity"):
        raise UnsupportedMediaType(
            f"Content-Encoding {encoding} is not read: send the body uncompressed (an .npz may "
            "compress its arrays inside)"
        )
    codings = request.headers.get("transfer-encoding", "").lower().replace(" ", "").split(",")
    if any(coding not in ("", "chunked") for coding in codings):
        raise NotImplementedCoding(
            f"Transfer-Encoding {request.headers['transfer-encoding']} is not decoded: only chunked"
        )


async def hold_decoding(
    request: Request, body: memoryview, fmt: str, estimate: Estimate, max_bytes: int
) -> int:
    """Hold the request's ticket at ``estimate`` for the body in the format it turned out to be
    in, with what an .npz's deflated members declare they inflate to, before any is inflated,
    and what a JSON body's structure may take beyond the estimate, before it is parsed; those
    inflated bytes (0 for other formats)."""
    inflated = await run_sync(wire.inflated_bytes, body, max_bytes) if fmt == "npz" else 0
    structure = (
        await run_sync(footprint.structure_bytes, body, fmt)
        if fmt in footprint.JSON_TEXT_FACTORS
        else 0
    )
    ticket: Ticket = request.state.ticket
    what = f"{request.method} {request.url.path} with a {fmt} body of {len(body)} bytes"
    await ticket.hold(estimate(len(body), fmt) + inflated + structure, what)
    return inflated


async def read_change(
    request: Request,
    settings: Settings,
    format: str | None,
    formats: tuple[str, ...],
    estimate: Estimate = footprint.decode_bytes,
) -> tuple[memoryview, str]:
    """The body of a change (a mesh, vertices, a frame, a pattern: ``read_body`` within
    DACRT_MAX_BODY_BYTES, held at ``estimate``, by default the decoders') and its format, 415
    naming ``formats`` and the route."""
    body = await read_body(request, settings.max_body_bytes, estimate)
    route = f"{request.method} {request.scope['route'].path}"
    fmt = wire.resolve_format(request.headers.get("content-type"), format, formats, body, route)
    await hold_decoding(request, body, fmt, estimate, settings.max_body_bytes)
    return body, fmt
