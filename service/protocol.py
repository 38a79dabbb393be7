"""uvicorn's HTTP/1.1 protocol (httptools) with deadlines for slow clients and a connection bound.

uvicorn waits forever for a request's headers and body; a client that sends nothing, or one byte at
a time, would hold its connection (and a slot of the server) for good. This protocol gives every
request ``header_timeout`` seconds from its first byte (or from the connection's opening) to
complete its headers and ``body_timeout`` seconds from then to complete its body; past a deadline
it answers 408 where it still can and closes the connection. Connections opened while
``max_connections`` others are open get a 503 with ``Retry-After`` to their first request.

``python -m service`` uses it; with uvicorn's CLI, pass
``--http service.protocol:GuardedHttpProtocol`` (it then reads the DACRT_* environment).
"""

from __future__ import annotations

import asyncio
import functools
import json
from typing import Any, ClassVar

from uvicorn.protocols.http.httptools_impl import STATUS_LINE, HttpToolsProtocol

from .errors import ServiceError, TimedOut, TooManyConnections, status_of
from .settings import Settings, load_settings_or_exit

RETRY_AFTER_SECONDS = 1  # connections free up as soon as requests finish


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


def refusal_app(error: ServiceError, extra: dict[str, str]):
    """An ASGI app that answers every request with ``error`` and closes the connection."""
    status, headers, body = error_parts(error, extra)

    async def refuse(scope, receive, send) -> None:
        await send({"type": "http.response.start", "status": status, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    return refuse


class GuardedHttpProtocol(HttpToolsProtocol):
    """HttpToolsProtocol with a header deadline, a body deadline and a bound on connections."""

    #: None: the settings of the environment (for ``uvicorn --http service.protocol:...``)
    settings: ClassVar[Settings | None] = None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        settings = self.settings or environment_settings()
        self.header_timeout, self.body_timeout = settings.header_timeout, settings.body_timeout
        self.max_connections = settings.max_connections
        self.header_deadline: asyncio.TimerHandle | None = None
        self.body_deadline: asyncio.TimerHandle | None = None
        self.request_begun = False  # a byte of the awaited request has arrived

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        if len(self.connections) > self.max_connections:  # the set includes this connection
            # uvicorn starts ``self.app`` for each request of this connection: refuse them all
            self.app = refusal_app(
                TooManyConnections(
                    f"the server holds its limit of {self.max_connections} connections "
                    "(DACRT_MAX_CONNECTIONS); retry shortly"
                ),
                {"retry-after": str(RETRY_AFTER_SECONDS)},
            )
        self.header_deadline = self.loop.call_later(self.header_timeout, self.headers_too_slow)

    def connection_lost(self, exc: Exception | None) -> None:
        self.cancel_deadlines()
        super().connection_lost(exc)

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self.request_begun = True
        if self.header_deadline is None:  # a later request on a keep-alive connection
            self.header_deadline = self.loop.call_later(self.header_timeout, self.headers_too_slow)

    def on_headers_complete(self) -> None:
        if self.header_deadline is not None:
            self.header_deadline.cancel()
            self.header_deadline = None
        super().on_headers_complete()

    def _start_asgi_task(self, cycle, app) -> None:
        # a pipelined request's body is read only from here on, so its deadline starts here
        super()._start_asgi_task(cycle, app)
        if cycle.more_body:
            self.body_deadline = self.loop.call_later(self.body_timeout, self.body_too_slow, cycle)

    def on_message_complete(self) -> None:
        if self.body_deadline is not None:
            self.body_deadline.cancel()
            self.body_deadline = None
        super().on_message_complete()

    def cancel_deadlines(self) -> None:
        for deadline in (self.header_deadline, self.body_deadline):
            if deadline is not None:
                deadline.cancel()
        self.header_deadline = self.body_deadline = None

    def headers_too_slow(self) -> None:
        self.header_deadline = None
        if self.transport.is_closing():
            return
        if self.cycle is not None and not self.cycle.response_complete:
            self.cycle.keep_alive = False  # a pipelined request: end after the answer in progress
        elif self.request_begun:
            self.answer_and_close(
                TimedOut(
                    f"request headers not received within {self.header_timeout:g} s "
                    "(DACRT_HEADER_TIMEOUT)"
                )
            )
        else:
            self.transport.close()  # nothing was asked: there is no one to answer

    def body_too_slow(self, cycle) -> None:
        self.body_deadline = None
        if self.transport.is_closing():
            return
        if cycle.response_started:
            self.transport.close()
            return
        cycle.disconnected = True  # the app's receive() sees a disconnect and its send() is mute
        cycle.message_event.set()
        self.answer_and_close(
            TimedOut(
                f"request body not received within {self.body_timeout:g} s (DACRT_BODY_TIMEOUT)"
            )
        )

    def answer_and_close(self, error: ServiceError) -> None:
        """Write ``error`` as a whole response outside any ASGI cycle, then close."""
        status, headers, body = error_parts(error, {})
        lines = [STATUS_LINE[status]]
        for name, value in [*self.server_state.default_headers, *headers]:
            lines += [name, b": ", value, b"\r\n"]
        self.transport.write(b"".join([*lines, b"\r\n", body]))
        self.transport.close()
