"""Request plumbing shared by the routes: what a handler uses (settings, store, metrics,
readiness) as ``Annotated`` dependencies, the bearer token, bounded body reading."""

from __future__ import annotations

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


#: Body bytes a ticket grows by at a time while a body of unknown length (chunked) arrives.
UNKNOWN_LENGTH_STEP = 8 * 2**20

#: The peak bytes of a request whose body has this many bytes, in this format (None: not known
#: from Content-Type yet): ``service.footprint``'s estimates.
Estimate = Callable[[int, str | None], int]


async def read_body(request: Request, limit: int, estimate: Estimate) -> memoryview:
    """The whole body (a read-only ``wire.BodyBuffer``), refused (413) as soon as it is known to
    exceed ``limit``, DACRT_MAX_BODY_BYTES. Before a byte is read, the request's ticket holds
    ``estimate(length, format)`` bytes of the in-flight budget (``service.admission``); a body
    of unknown length holds more as it arrives."""
    check_codings(request)
    declared = request.headers.get("content-length")
    expected = int(declared) if declared is not None and declared.isdigit() else None
    if expected is not None and expected > limit:
        raise TooLarge(
            f"body of {expected} bytes is over the limit of {limit} bytes (DACRT_MAX_BODY_BYTES)"
        )
    ticket: Ticket = request.state.ticket
    fmt = wire.declared_format(request.headers.get("content-type"))
    what = f"{request.method} {request.url.path} with a body of {{}} bytes"
    held = expected if expected is not None else UNKNOWN_LENGTH_STEP
    await ticket.hold(estimate(held, fmt), what.format(held))
    body = BodyBuffer(expected)
    async for chunk in request.stream():
        if body.size + len(chunk) > limit:
            raise TooLarge(f"body is over the limit of {limit} bytes (DACRT_MAX_BODY_BYTES)")
        if body.size + len(chunk) > held:
            held = body.size + len(chunk) + UNKNOWN_LENGTH_STEP
            await ticket.hold(estimate(held, fmt), what.format(held))
        body.add(chunk)
    if expected is not None and body.size != expected:
        raise BadBody(f"body ended after {body.size} of its {expected} bytes (Content-Length)")
    return body.finish()


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
    in, with what an .npz's deflated members declare they inflate to, before any is inflated;
    those inflated bytes (0 for other formats)."""
    inflated = await run_sync(wire.inflated_bytes, body, max_bytes) if fmt == "npz" else 0
    ticket: Ticket = request.state.ticket
    what = f"{request.method} {request.url.path} with a {fmt} body of {len(body)} bytes"
    await ticket.hold(estimate(len(body), fmt) + inflated, what)
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
