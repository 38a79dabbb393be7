"""uvicorn's HTTP/1.1 protocol (httptools) with deadlines for slow clients and connection bounds.

uvicorn waits forever for a request's headers and body; a client that sends nothing, or one byte at
a time, would hold its connection (and a slot of the server) for good. This protocol gives every
request ``header_timeout`` seconds from its first byte (or from the connection's opening) to
complete its headers, ``body_timeout`` seconds from then to complete its body, and
``body_idle_timeout`` seconds between two reads of its body (the clock stops while the server
itself does not read: the app has not asked for more, or the client waits for ``100 Continue``);
past a deadline it answers 408 where it still can and closes the connection. Bytes between two
requests (even an empty line) start the next one's header clock. An answer the client reads
none of for ``answer_idle_timeout`` seconds ends its connection, so that it gives back its share
of the in-flight budget.

A request's line and headers may take MAX_HEADER_BYTES (431 over); a connection queues at most
MAX_PIPELINED requests behind the one being answered, and ends after answering them when sent
more. A request that is not HTTP/1.1 is answered 400 ``{"detail": ...}``, or, behind requests
still being answered, ends the connection after their answers, which keep their order. An
``Upgrade`` the server does not speak (``h2c``) is not taken: the request is answered over
HTTP/1.1, its body included (400 for a chunked one).

A connection opened while ``max_connections`` others are open, or while its client address holds
``max_connections_per_client``, is over a bound: its bodiless ``GET``/``HEAD`` of ``/health`` and
``/metrics`` are served (and the connection then closed), so that a monitor can always see a full
server; any other request gets 503 with ``Retry-After`` naming the setting.

Each answer it writes itself, and each 503 of a connection over a bound, is counted in the app's
``dacrt_requests_total`` under route ``protocol`` (``app_metrics``).

``python -m service`` uses it; with uvicorn's CLI, pass
``--http service.protocol:GuardedHttpProtocol`` (it then reads the DACRT_* environment).
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import time
import weakref
from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar

import httptools
from uvicorn.protocols.http.flow_control import FlowControl
from uvicorn.protocols.http.httptools_impl import STATUS_LINE, HttpToolsProtocol
from uvicorn.server import ServerState

from .errors import (
    CUT_OFF,
    BadBody,
    HeadersTooLarge,
    ServiceError,
    TimedOut,
    TooManyConnections,
    status_of,
)
from .logs import untrusted
from .metrics import CLIENT_METHOD, PROTOCOL_ROUTE, UNKNOWN_METHOD
from .settings import Settings, load_settings_or_exit

if TYPE_CHECKING:
    from .metrics import Metrics

log = logging.getLogger("service")

RETRY_AFTER_SECONDS = 1  # connections free up as soon as requests finish
#: Bytes of a request's line and headers (a read's worth more may be held before it is known).
MAX_HEADER_BYTES = 64 * 1024
#: Requests a connection may queue behind the one being answered (pipelining).
MAX_PIPELINED = 16
#: What a connection over a bound may still ask: cheap, bodiless, what monitors poll.
PROBE_METHODS, PROBE_PATHS = ("GET", "HEAD"), ("/health", "/metrics")

#: Open connections per client address, per server (its ServerState).
_PER_CLIENT: weakref.WeakKeyDictionary[ServerState, Counter[str]] = weakref.WeakKeyDictionary()


def guarded_protocol(settings: Settings) -> type[GuardedHttpProtocol]:
    """The protocol class with the deadlines and the connection bound of ``settings``."""
    return type("GuardedHttpProtocol", (GuardedHttpProtocol,), {"settings": settings})


@functools.cache
def environment_settings() -> Settings:
    """The settings of the environment, read once (protocols are made per connection)."""
    return load_settings_or_exit()


def error_parts(
    error: ServiceError, extra: dict[str, str]
) -> tuple[int, list[tuple[bytes, bytes]], bytes]:
    """Status, headers and ``{"detail": ...}`` body of an answer that closes the connection."""
    body = json.dumps({"detail": error.detail}).encode()
    headers = [
        (b"content-type", b"application/json"),
        (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"),
        *((name.encode(), value.encode()) for name, value in extra.items()),
    ]
    return status_of(error), headers, body


def app_metrics(app) -> Metrics | None:
    """The service's metrics (``app.state.metrics``) of the app uvicorn serves, found inside
    the middleware uvicorn wraps it in (each holds the next as ``app``); None for another app."""
    while app is not None:
        metrics = getattr(getattr(app, "state", None), "metrics", None)
        if metrics is not None:
            return metrics
        app = getattr(app, "app", None)
    return None


def refusal_app(error: ServiceError, extra: dict[str, str], metrics: Metrics | None):
    """An ASGI app that answers every request with ``error`` and closes the connection,
    counting each answer in ``metrics`` under route ``protocol``."""
    status, headers, body = error_parts(error, extra)

    async def refuse(scope, receive, send) -> None:
        start = time.perf_counter()
        await send({"type": "http.response.start", "status": status, "headers": headers})
        await send({"type": "http.response.body", "body": body})
        if metrics is not None:
            seconds = time.perf_counter() - start
            metrics.answered(scope["method"], PROTOCOL_ROUTE, status, seconds)

    return refuse


def declares_body(headers: list[tuple[bytes, bytes]]) -> bool:
    """Whether a request's headers (lower-case names) announce a body."""
    return any(
        (name == b"content-length" and value.strip() not in (b"", b"0"))
        or name == b"transfer-encoding"
        for name, value in headers
    )


def is_probe(scope) -> bool:
    """A bodiless GET or HEAD of /health or /metrics."""
    return (
        scope["method"] in PROBE_METHODS
        and scope["path"] in PROBE_PATHS
        and not declares_body(scope["headers"])
    )


def reserve_app(app, error: ServiceError, extra: dict[str, str], metrics: Metrics | None):
    """The app of a connection over a bound: ``app`` for probes (``is_probe``), answered with
    ``Connection: close``; 503 ``error`` for anything else (counted in ``metrics``)."""
    refuse = refusal_app(error, extra, metrics)

    async def serve(scope, receive, send) -> None:
        if not is_probe(scope):
            await refuse(scope, receive, send)
            return

        async def send_and_close(message) -> None:
            if message["type"] == "http.response.start":
                headers = [*message.get("headers", []), (b"connection", b"close")]
                message = {**message, "headers": headers}
            await send(message)

        await app(scope, receive, send_and_close)

    return serve


class HeadAsGet:
    """ASGI middleware: a ``HEAD`` is answered as its ``GET`` is, without the body (RFC 9110
    9.3.2); FastAPI's routes take only the methods they name."""

    def __init__(self, app) -> None:
        self.app = app

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return

        async def headers_only(message) -> None:
            if message["type"] == "http.response.body":
                message = {**message, "body": b""}
            await send(message)

        # the metrics, inside, count the method the client sent
        await self.app({**scope, "method": "GET", CLIENT_METHOD: "HEAD"}, receive, headers_only)


class WatchedFlow(FlowControl):
    """uvicorn's read/write flow control, calling ``on_resume`` when reading resumes."""

    def __init__(self, transport: asyncio.Transport, on_resume: Callable[[], None]) -> None:
        super().__init__(transport)
        self.on_resume = on_resume

    def resume_reading(self) -> None:
        if self.read_paused:
            self.on_resume()
        super().resume_reading()


class HeadersOverBound(Exception):
    """Raised in a parser callback when the request line and headers pass MAX_HEADER_BYTES."""


def headers_too_large() -> HeadersTooLarge:
    return HeadersTooLarge(
        f"request line and headers over {MAX_HEADER_BYTES} bytes; send fewer or shorter headers"
    )


class GuardedHttpProtocol(HttpToolsProtocol):
    """HttpToolsProtocol with header and body deadlines and bounds on connections."""

    #: None: the settings of the environment (for ``uvicorn --http service.protocol:...``)
    settings: ClassVar[Settings | None] = None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        settings = self.settings or environment_settings()
        self.header_timeout, self.body_timeout = settings.header_timeout, settings.body_timeout
        self.body_idle_timeout = settings.body_idle_timeout
        self.max_connections = settings.max_connections
        self.max_per_client = settings.max_connections_per_client
        self.header_deadline: asyncio.TimerHandle | None = None
        self.body_deadline: asyncio.TimerHandle | None = None
        self.body_idle_check: asyncio.TimerHandle | None = None
        self.body_active_at = 0.0  # loop time of the body's last byte, or of reading resumed
        self.request_begun = False  # a byte of the awaited request has arrived
        self.client_host: str | None = None  # counted in _PER_CLIENT while open
        self.answer_idle_timeout = settings.answer_idle_timeout
        self.answer_deadline: asyncio.TimerHandle | None = None
        self.awaiting_headers = True  # between requests, or within a request's line and headers
        self.boundary_seen = False  # a request's headers or body ended within the data being read
        self.header_bytes = 0  # bytes read while the awaited headers were incomplete
        self.message_header_bytes = 0  # the request line and headers parsed of this request
        self.ending = False  # the connection ends after its answers; later bytes are ignored
        self.answering = None  # the cycle whose answer is being made (pipelining: not self.cycle)
        self.upgrade_body_left = 0  # bytes of a body after an Upgrade not taken, still to come
        self.metrics: Metrics | None = None  # the app's, where its answers are counted
        self.request_method = UNKNOWN_METHOD  # of the request being read, once its line names it
        self.header_clock_start = 0.0  # loop time the awaited request's header clock started

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self.flow = WatchedFlow(transport, self.body_read_resumed)
        self.metrics = app_metrics(self.app)
        per_client = _PER_CLIENT.setdefault(self.server_state, Counter())
        if self.client:  # a Unix socket has no client address
            self.client_host = self.client[0]
            per_client[self.client_host] += 1
        # both counts include this connection
        if self.client_host is not None and per_client[self.client_host] > self.max_per_client:
            refusal = TooManyConnections(
                f"client address {self.client_host} holds its limit of {self.max_per_client} "
                "connections (DACRT_MAX_CONNECTIONS_PER_CLIENT); retry shortly"
            )
        elif len(self.connections) > self.max_connections:
            refusal = TooManyConnections(
                f"the server holds its limit of {self.max_connections} connections "
                "(DACRT_MAX_CONNECTIONS); retry shortly"
            )
        else:
            refusal = None
        if refusal is not None:
            # uvicorn starts ``self.app`` for each request of this connection
            retry = {"retry-after": str(RETRY_AFTER_SECONDS)}
            self.app = reserve_app(self.app, refusal, retry, self.metrics)
        self.start_header_clock()

    def connection_lost(self, exc: Exception | None) -> None:
        self.cancel_deadlines()
        self.uncount_client()
        # uvicorn marks only the last request read as gone; the one being answered, and those
        # queued, would write to a closed transport
        queued = [cycle for cycle, _ in self.pipeline]
        for cycle in [self.answering, *queued]:
            if cycle is not None and not cycle.response_complete:
                cycle.disconnected = True
                cycle.message_event.set()
        super().connection_lost(exc)

    def handle_websocket_upgrade(self) -> None:
        self.cancel_deadlines()
        self.uncount_client()  # the websocket protocol takes the connection over
        super().handle_websocket_upgrade()

    def uncount_client(self) -> None:
        if self.client_host is None:
            return
        per_client = _PER_CLIENT.get(self.server_state)
        if per_client is not None:
            per_client[self.client_host] -= 1
            if per_client[self.client_host] <= 0:
                del per_client[self.client_host]
        self.client_host = None

    def data_received(self, data: bytes) -> None:
        if self.ending:
            return
        if self.upgrade_body_left:
            data = self.take_upgrade_body(data)
            if not data:
                return
        if self.awaiting_headers and self.header_deadline is None:
            # bytes between requests, even an empty line, start the next one's header clock
            self.start_header_clock()
        self._unset_keepalive_if_required()
        self.boundary_seen = False
        try:
            self.parser.feed_data(data)
        except httptools.HttpParserError as error:
            if self.message_header_bytes > MAX_HEADER_BYTES:  # raised by a callback below
                self.refuse(headers_too_large())
                return
            reason = str(error).strip().rstrip(".") or type(error).__name__
            self.refuse(BadBody(f"the request is not valid HTTP/1.1: {reason}"))
            return
        except httptools.HttpParserUpgrade as upgrade:
            if self.ending:  # a request past the pipeline's bound: not answered
                return
            if self._should_upgrade():
                self.handle_websocket_upgrade()
            elif self.ignore_upgrade(upgrade):
                self.data_received(data[upgrade.args[0] :])
            return
        if not self.awaiting_headers or self.boundary_seen:
            self.header_bytes = 0  # what follows a boundary in this read is at most a read
        elif not self.ending:
            self.header_bytes += len(data)
            if self.header_bytes > MAX_HEADER_BYTES:
                self.refuse(headers_too_large())

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self.request_begun = True
        self.message_header_bytes = 0
        self.request_method = UNKNOWN_METHOD
        if self.header_deadline is None:  # a later request on a keep-alive connection
            self.start_header_clock()

    def start_header_clock(self) -> None:
        self.header_deadline = self.loop.call_later(self.header_timeout, self.headers_too_slow)
        self.header_clock_start = self.loop.time()

    def on_url(self, url: bytes) -> None:
        # the parser has read the method (one of those llhttp knows) before the target
        self.request_method = self.parser.get_method().decode("ascii")
        self.count_header_bytes(len(url) + 2)  # with the request line's spaces
        super().on_url(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        self.count_header_bytes(len(name) + len(value) + 4)  # with ": " and the line's end
        super().on_header(name, value)

    def count_header_bytes(self, n: int) -> None:
        """Bound the request line and headers as they are parsed, also those that arrive and
        end within one read (the reads' count alone lets one read of up to 64 KiB more in)."""
        self.message_header_bytes += n
        if self.message_header_bytes > MAX_HEADER_BYTES:
            raise HeadersOverBound  # out of the parser: data_received answers 431

    def on_headers_complete(self) -> None:
        if self.header_deadline is not None:
            self.header_deadline.cancel()
            self.header_deadline = None
        self.awaiting_headers, self.boundary_seen = False, True
        if self.ending:
            return
        answering = self.cycle is not None and not self.cycle.response_complete
        if answering and len(self.pipeline) >= MAX_PIPELINED:
            self.end_after_answers()  # this request and any later one go unanswered
            return
        super().on_headers_complete()

    def on_body(self, body: bytes) -> None:
        if not self.ending:
            self.body_active_at = self.loop.time()
            super().on_body(body)

    def _start_asgi_task(self, cycle, app) -> None:
        # a pipelined request's body is read only from here on, so its deadlines start here
        self.answering = cycle
        super()._start_asgi_task(cycle, app)
        if cycle.more_body:
            self.start_body_deadlines(cycle)

    def start_body_deadlines(self, cycle) -> None:
        self.body_deadline = self.loop.call_later(self.body_timeout, self.body_too_slow, cycle)
        self.body_active_at = self.loop.time()
        self.body_idle_check = self.loop.call_later(
            self.body_idle_timeout, self.body_stalled, cycle
        )

    def body_read_resumed(self) -> None:
        self.body_active_at = self.loop.time()  # the client could not send while we did not read

    def on_message_complete(self) -> None:
        for deadline in (self.body_deadline, self.body_idle_check):
            if deadline is not None:
                deadline.cancel()
        self.body_deadline = self.body_idle_check = None
        self.awaiting_headers, self.boundary_seen = True, True
        if not self.ending:
            super().on_message_complete()

    def pause_writing(self) -> None:
        super().pause_writing()
        if self.answer_deadline is None:
            self.answer_deadline = self.loop.call_later(
                self.answer_idle_timeout, self.answer_stalled
            )

    def resume_writing(self) -> None:
        if self.answer_deadline is not None:
            self.answer_deadline.cancel()
            self.answer_deadline = None
        super().resume_writing()

    def answer_stalled(self) -> None:
        """End a connection whose client has read nothing of its answer for
        ``answer_idle_timeout`` seconds: its request ends as a client gone, its budget freed."""
        self.answer_deadline = None
        self.transport.abort()

    def end_after_answers(self) -> None:
        """End the connection once the requests it is answering are answered, in order; read
        nothing more of it."""
        self.ending = True
        last = self.pipeline[0][0] if self.pipeline else self.cycle
        last.keep_alive = False
        self.flow.pause_reading()

    def refuse(self, error: ServiceError) -> None:
        """``error`` for what the parser read, then close; behind answers in progress the
        connection ends after them instead (an answer out of order would answer another)."""
        if self.cycle is not None and not self.cycle.response_complete:
            self.end_after_answers()
            return
        self.answer_unread(error)

    def ignore_upgrade(self, upgrade: httptools.HttpParserUpgrade) -> bool:
        """Answer a request whose ``Upgrade`` the server does not speak (``h2c``, as ``curl
        --http2`` asks) over HTTP/1.1, as RFC 9110 7.8 allows: the parser hands what follows its
        headers to the upgrade, so its ``Content-Length`` body is taken here (a new parser reads
        what comes after it). A chunked body is refused (400 naming the header)."""
        headers = dict(self.headers or [])
        cycle = self.cycle
        length = headers.get(b"content-length", b"0").strip() or b"0"
        # where the bytes after the headers begin in the data read, as the parser says
        located = bool(upgrade.args) and isinstance(upgrade.args[0], int)
        if b"transfer-encoding" in headers or not length.isdigit() or not located:
            upgrade = untrusted(headers.get(b"upgrade", b"").decode("latin-1"))
            self.cut_off_body(
                cycle,
                BadBody(
                    f"Upgrade: {upgrade} with a chunked body is not served (HTTP/1.1 only); "
                    "send the request without Upgrade"
                ),
            )
            return False
        self.parser = httptools.HttpRequestParser(self)
        if hasattr(self.parser, "set_dangerous_leniencies"):  # as uvicorn sets its parser
            self.parser.set_dangerous_leniencies(lenient_data_after_close=True)
        self.upgrade_body_left = int(length)
        if self.upgrade_body_left and cycle is not None:
            cycle.more_body = True  # the parser called it complete at its headers
            self.awaiting_headers = False
            if cycle is self.answering:
                self.start_body_deadlines(cycle)
        return True

    def take_upgrade_body(self, data: bytes) -> bytes:
        """The body of a request whose Upgrade was not taken (``ignore_upgrade``), from
        ``data``; answers what follows it."""
        body, rest = data[: self.upgrade_body_left], data[self.upgrade_body_left :]
        self.upgrade_body_left -= len(body)
        self.on_body(body)
        if not self.upgrade_body_left:
            self.on_message_complete()
        return rest

    def cancel_deadlines(self) -> None:
        deadlines = (
            self.header_deadline,
            self.body_deadline,
            self.body_idle_check,
            self.answer_deadline,
        )
        for deadline in deadlines:
            if deadline is not None:
                deadline.cancel()
        self.header_deadline = self.body_deadline = self.body_idle_check = None
        self.answer_deadline = None

    def headers_too_slow(self) -> None:
        self.header_deadline = None
        if self.transport.is_closing():
            return
        if self.cycle is not None and not self.cycle.response_complete:
            self.cycle.keep_alive = False  # a pipelined request: end after the answer in progress
        elif self.request_begun:
            self.answer_unread(
                TimedOut(
                    f"request headers not received within {self.header_timeout:g} s "
                    "(DACRT_HEADER_TIMEOUT)"
                )
            )
        else:
            self.transport.close()  # nothing was asked: there is no one to answer

    def body_too_slow(self, cycle) -> None:
        self.body_deadline = None
        self.cut_off_body(
            cycle,
            TimedOut(
                f"request body not received within {self.body_timeout:g} s (DACRT_BODY_TIMEOUT)"
            ),
        )

    def body_stalled(self, cycle) -> None:
        """Cut the body off if no byte came for ``body_idle_timeout`` seconds while we read."""
        self.body_idle_check = None
        now = self.loop.time()
        if self.flow.read_paused or cycle.waiting_for_100_continue:
            self.body_active_at = now  # the client may not send now: not its stall
        idle = now - self.body_active_at
        if idle < self.body_idle_timeout:
            self.body_idle_check = self.loop.call_later(
                self.body_idle_timeout - idle, self.body_stalled, cycle
            )
            return
        self.cut_off_body(
            cycle,
            TimedOut(
                f"request body stalled: no byte for {self.body_idle_timeout:g} s "
                "(DACRT_BODY_IDLE_TIMEOUT)"
            ),
        )

    def cut_off_body(self, cycle, error: ServiceError) -> None:
        """End a request whose body cannot be read (it came too slowly, or went to an upgrade):
        ``error`` unless its answer has begun; close."""
        for deadline in (self.body_deadline, self.body_idle_check):
            if deadline is not None:
                deadline.cancel()
        self.body_deadline = self.body_idle_check = None
        if self.transport.is_closing():
            return
        if cycle.response_started:
            self.transport.close()
            return
        cycle.scope["state"][CUT_OFF] = error  # counted as this answer, not as a client gone
        cycle.disconnected = True  # the app's receive() sees a disconnect and its send() is mute
        cycle.message_event.set()
        self.answer_and_close(error, f"{cycle.scope['method']} {untrusted(cycle.scope['path'])}")

    def answer_unread(self, error: ServiceError) -> None:
        """Answer ``error`` to a request whose line and headers the app never got, counted in
        the metrics under route ``protocol`` and the method read (``unknown`` before it), and
        close."""
        if self.metrics is not None:
            seconds = self.loop.time() - self.header_clock_start
            self.metrics.answered(self.request_method, PROTOCOL_ROUTE, status_of(error), seconds)
        self.answer_and_close(error, f"{self.request_method} request")

    def answer_and_close(self, error: ServiceError, request: str) -> None:
        """Write ``error`` as a whole response outside any ASGI cycle, then close; log it with
        ``request``, what was read of the request (its method and its path, ``untrusted``)."""
        status, headers, body = error_parts(error, {})
        log.info("%s: %s answered %d: %s", self.peer(), request, status, error.detail)
        lines = [STATUS_LINE[status]]
        for name, value in [*self.server_state.default_headers, *headers]:
            lines += [name, b": ", value, b"\r\n"]
        self.transport.write(b"".join([*lines, b"\r\n", body]))
        self.transport.close()

    def peer(self) -> str:
        """The client's address and port, as the access log writes them."""
        return f"{self.client[0]}:{self.client[1]}" if self.client else "-"
