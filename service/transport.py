"""An httpx transport on urllib3's connection pool: the client's big answers, cheaply.

httpx's own transport (httpcore and h11) reads a response in small pieces and copies each on its
way out; urllib3 reads the socket through ``http.client`` in the 1 MiB pieces handed over, which
costs the client less for a big answer. Only the exchange on the socket changes: requests,
responses, content decoding, redirects, timeouts and errors stay httpx's.

HTTP/1.1 over TCP or TLS; urllib3 pools keep-alive connections per origin, one request at a time
each, and drops those the server has closed, so a client may be shared between threads. Proxies
are httpx's: with HTTP(S)_PROXY set, httpx sends those requests through its own proxy transport.
"""

from __future__ import annotations

import ssl
from collections.abc import Iterator
from contextlib import contextmanager

import httpx
import urllib3
from urllib3.exceptions import (
    ConnectTimeoutError,
    DecodeError,
    NewConnectionError,
    ProtocolError,
    ReadTimeoutError,
)

#: Bytes read from the socket per piece of a response body.
READ_SIZE = 1 << 20
#: Connections kept per origin.
MAX_IDLE_PER_ORIGIN = 8


class PooledTransport(httpx.BaseTransport):
    """``httpx.Client(transport=PooledTransport())``: requests go over a ``urllib3.PoolManager``."""

    def __init__(self, ssl_context: ssl.SSLContext | None = None) -> None:
        self.pool = urllib3.PoolManager(maxsize=MAX_IDLE_PER_ORIGIN, ssl_context=ssl_context)

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        timeout = request.extensions.get("timeout", {})
        with _mapped_errors(request):
            response = self.pool.urlopen(
                request.method,
                str(request.url),
                body=request.stream,
                headers=dict(request.headers.multi_items()),
                chunked=request.headers.get("transfer-encoding", "").lower() == "chunked",
                timeout=urllib3.Timeout(connect=timeout.get("connect"), read=timeout.get("read")),
                preload_content=False,
                decode_content=False,  # httpx decodes
                redirect=False,  # httpx follows redirects
                retries=False,  # a request is sent once; errors are httpx's
            )
        return httpx.Response(
            status_code=response.status,
            headers=list(response.headers.iteritems()),
            stream=_ResponseBody(response, request),
            extensions={
                "http_version": b"HTTP/1.1",
                "reason_phrase": response.reason.encode("latin-1", "replace"),
            },
        )

    def close(self) -> None:
        self.pool.clear()


class _ResponseBody(httpx.SyncByteStream):
    """A response body read READ_SIZE bytes at a time; urllib3 gives the connection back once the
    body is read to its end, and this closes it if the body is left unread."""

    def __init__(self, response: urllib3.BaseHTTPResponse, request: httpx.Request) -> None:
        self._response, self._request = response, request

    def __iter__(self) -> Iterator[bytes]:
        with _mapped_errors(self._request):
            yield from self._response.stream(READ_SIZE, decode_content=False)

    def close(self) -> None:
        if self._response.connection is not None:  # unread: the connection cannot be reused
            self._response.close()
            self._response.release_conn()


@contextmanager
def _mapped_errors(request: httpx.Request) -> Iterator[None]:
    """Raise urllib3's errors as httpx's exceptions."""
    try:
        yield
    except NewConnectionError as error:  # a subclass of ConnectTimeoutError
        raise httpx.ConnectError(str(error), request=request) from error
    except ConnectTimeoutError as error:
        raise httpx.ConnectTimeout(str(error), request=request) from error
    except ReadTimeoutError as error:
        raise httpx.ReadTimeout(str(error), request=request) from error
    except (ProtocolError, DecodeError) as error:  # a cut or malformed response
        raise httpx.RemoteProtocolError(str(error), request=request) from error
    except urllib3.exceptions.HTTPError as error:
        raise httpx.TransportError(str(error), request=request) from error
