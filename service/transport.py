"""An httpx transport on the standard library's ``http.client``: the client's big answers, cheaply.

httpx's own transport (httpcore and h11) reads a response 64 KiB at a time and copies every piece
twice more on its way out. For the 32 MB answer of a 1M-ray query that costs about 10 ms of the
client's time; ``http.client`` reads the socket straight into the 1 MiB pieces it hands over
(``python -m bench.http_floor``, docs/benchmarks.md, HTTP). Only the exchange on the socket
changes: requests, responses, content decoding, timeouts and errors stay httpx's.

HTTP/1.1 over TCP or TLS; keep-alive connections are pooled per origin, one request at a time
each, so a client may be shared between threads. Proxies are httpx's: with HTTP(S)_PROXY set,
httpx sends those requests through its own proxy transport instead.
"""

from __future__ import annotations

import http.client
import select
import ssl
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import httpx

#: Bytes read from the socket per piece of a response body.
READ_SIZE = 1 << 20
#: Idle connections kept per origin.
MAX_IDLE_PER_ORIGIN = 8

Origin = tuple[str, str, int]


class StdlibTransport(httpx.BaseTransport):
    """``httpx.Client(transport=StdlibTransport())``: requests go over ``http.client``."""

    def __init__(self, ssl_context: ssl.SSLContext | None = None) -> None:
        self._ssl_context = ssl_context
        self._idle: dict[Origin, list[http.client.HTTPConnection]] = {}
        self._lock = threading.Lock()
        self._closed = False

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        timeout = request.extensions.get("timeout", {})
        url = request.url
        origin = (
            url.scheme,
            url.raw_host.decode("ascii"),  # IDNA-encoded, as on the wire
            url.port or (443 if url.scheme == "https" else 80),
        )
        connection = self._checkout(origin)
        try:
            response = _exchange(connection, request, timeout)
        except BaseException:
            connection.close()
            raise
        return httpx.Response(
            status_code=response.status,
            headers=response.getheaders(),
            stream=_ResponseBody(self, origin, connection, response, request),
            extensions={
                "http_version": b"HTTP/1.1",
                "reason_phrase": response.reason.encode("latin-1", "replace"),
            },
        )

    def close(self) -> None:
        with self._lock:
            self._closed = True
            idle, self._idle = self._idle, {}
        for connections in idle.values():
            for connection in connections:
                connection.close()

    def _checkout(self, origin: Origin) -> http.client.HTTPConnection:
        """An idle connection to ``origin`` that the server has not closed, else a new one."""
        while True:
            with self._lock:
                idle = self._idle.get(origin)
                connection = idle.pop() if idle else None
            if connection is None:
                break
            if not _closed_by_peer(connection):
                return connection
            connection.close()
        scheme, host, port = origin
        if scheme == "https":
            return http.client.HTTPSConnection(
                host, port, context=self._ssl_context or ssl.create_default_context()
            )
        return http.client.HTTPConnection(host, port)

    def _checkin(self, origin: Origin, connection: http.client.HTTPConnection) -> None:
        with self._lock:
            idle = self._idle.setdefault(origin, [])
            if not self._closed and len(idle) < MAX_IDLE_PER_ORIGIN:
                idle.append(connection)
                return
        connection.close()


class _ResponseBody(httpx.SyncByteStream):
    """A response body read READ_SIZE bytes at a time; gives the connection back once the body
    has been read to its end (and the server keeps it alive), else closes it."""

    def __init__(
        self,
        transport: StdlibTransport,
        origin: Origin,
        connection: http.client.HTTPConnection,
        response: http.client.HTTPResponse,
        request: httpx.Request,
    ) -> None:
        self._transport, self._origin = transport, origin
        self._connection, self._response, self._request = connection, response, request

    def __iter__(self) -> Iterator[bytes]:
        with _mapped_errors(self._request, httpx.ReadTimeout, httpx.ReadError):
            while chunk := self._response.read(READ_SIZE):
                yield chunk
        if self._response.length:  # http.client ends a body cut short without a word
            raise httpx.RemoteProtocolError(
                f"the server closed the connection {self._response.length} bytes before the end "
                "of the body",
                request=self._request,
            )

    def close(self) -> None:
        if self._connection is None:
            return
        connection, self._connection = self._connection, None
        if self._response.isclosed() and not self._response.will_close:
            self._transport._checkin(self._origin, connection)
        else:
            connection.close()


def _exchange(
    connection: http.client.HTTPConnection, request: httpx.Request, timeout: dict[str, float | None]
) -> http.client.HTTPResponse:
    """Send ``request`` on ``connection`` and read the response's status line and headers."""
    if connection.sock is None:
        connection.timeout = timeout.get("connect")
        with _mapped_errors(request, httpx.ConnectTimeout, httpx.ConnectError):
            connection.connect()
    with _mapped_errors(request, httpx.WriteTimeout, httpx.WriteError):
        connection.sock.settimeout(timeout.get("write"))
        # httpx has set Host, Accept-Encoding, Content-Length or Transfer-Encoding.
        connection.putrequest(
            request.method,
            request.url.raw_path.decode("ascii"),
            skip_host=True,
            skip_accept_encoding=True,
        )
        for name, value in request.headers.raw:
            connection.putheader(name, value)
        connection.endheaders()
        chunked = request.headers.get("transfer-encoding", "").lower() == "chunked"
        for chunk in request.stream:
            if not chunked:
                connection.send(chunk)
            elif len(chunk):
                connection.send(b"%x\r\n" % len(chunk))
                connection.send(chunk)
                connection.send(b"\r\n")
        if chunked:
            connection.send(b"0\r\n\r\n")
    with _mapped_errors(request, httpx.ReadTimeout, httpx.ReadError):
        connection.sock.settimeout(timeout.get("read"))
        return connection.getresponse()


def _closed_by_peer(connection: http.client.HTTPConnection) -> bool:
    """Whether an idle kept-alive socket is readable: the server closed it (or sent what it
    should not have); either way it cannot carry another request."""
    if connection.sock is None:
        return True
    readable, _, _ = select.select([connection.sock], [], [], 0)
    return bool(readable)


@contextmanager
def _mapped_errors(
    request: httpx.Request,
    timeout_error: type[httpx.TransportError],
    network_error: type[httpx.TransportError],
) -> Iterator[None]:
    """Raise socket and http.client errors as httpx's exceptions: ``timeout_error`` for a
    timeout, RemoteProtocolError for a cut or malformed response, ``network_error`` for any
    other OS error."""
    try:
        yield
    except httpx.HTTPError:
        raise
    except TimeoutError as error:
        raise timeout_error(str(error) or "timed out", request=request) from error
    except (http.client.HTTPException, ConnectionResetError) as error:
        raise httpx.RemoteProtocolError(
            str(error) or type(error).__name__, request=request
        ) from error
    except OSError as error:
        raise network_error(str(error), request=request) from error
