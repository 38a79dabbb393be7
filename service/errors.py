"""Domain errors, and the one table that maps them to HTTP statuses.

The rest of the service raises these (never ``HTTPException``); ``install`` turns every error,
including FastAPI's own, into ``{"detail": "<message a person can act on>"}``. The engine's
``dacrt.InputError`` (and ``cameras.CameraError``, one of its kind) is 422 here and nowhere else,
in the engine's words, which name the caller's key (``car.faces[1]``, ``pose``). This module
imports nothing from FastAPI at import time, so ``wire`` and ``client`` stay light.
"""

from __future__ import annotations

import json
import logging

from .logs import untrusted

log = logging.getLogger("service")


class ServiceError(Exception):
    """A request the service refuses; ``detail`` is the message the client reads."""

    headers: dict[str, str] | None = None  #: sent with the answer

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


class BadBody(ServiceError):
    """The body cannot be parsed: not npy/npz/JSON/mesh file, truncated, wrong keys."""


class Unauthorized(ServiceError):
    """A token is configured and the request lacks it or has a wrong one."""

    headers = {"WWW-Authenticate": "Bearer"}


class NotFound(ServiceError):
    """Unknown scene or mesh."""


class TimedOut(ServiceError):
    """The client did not send its request's headers or body within the configured time."""


class NotAcceptable(ServiceError):
    """``Accept`` names no answer format the service can write."""


class Conflict(ServiceError):
    """The request contradicts the scene's state (vertex count of a vertices update)."""


class TooLarge(ServiceError):
    """Body, ray count or scene size over a configured limit; the message names the limit."""


class HeadersTooLarge(ServiceError):
    """A request's line and headers over the protocol's bound (``protocol.MAX_HEADER_BYTES``)."""


class NotImplementedCoding(ServiceError):
    """A ``Transfer-Encoding`` the server does not decode (only ``chunked``)."""


class UnsupportedMediaType(ServiceError):
    """``Content-Type`` (or ``?format=``) is not one the endpoint reads."""


class Invalid(ServiceError):
    """A well-formed body or parameter with invalid values: shapes, dtypes, non-finite, indices."""


class NotReady(ServiceError):
    """The engine is not compiled yet."""

    headers = {
        "Retry-After": "5"
    }  #: seconds; the first compile takes minutes, a cached one seconds


class TooManyConnections(ServiceError):
    """The server holds as many connections as DACRT_MAX_CONNECTIONS allows."""


class Overloaded(ServiceError):
    """The requests in flight hold the memory budget (DACRT_MAX_INFLIGHT_BYTES) for longer than
    DACRT_ADMISSION_WAIT."""

    headers = {"Retry-After": "2"}  #: seconds; budgets free up as answers are sent


class DataDirUnavailable(ServiceError):
    """The data folder (DACRT_DATA_DIR) cannot be written: read-only, no permission, I/O error.
    Nothing was changed."""


class InsufficientStorage(DataDirUnavailable):
    """The data folder (DACRT_DATA_DIR) is full (no space, or over its quota). Nothing was
    changed."""


STATUS: dict[type[ServiceError], int] = {
    BadBody: 400,
    Unauthorized: 401,
    NotFound: 404,
    NotAcceptable: 406,
    TimedOut: 408,
    Conflict: 409,
    TooLarge: 413,
    UnsupportedMediaType: 415,
    HeadersTooLarge: 431,
    NotImplementedCoding: 501,
    Invalid: 422,
    NotReady: 503,
    TooManyConnections: 503,
    Overloaded: 503,
    DataDirUnavailable: 503,
    InsufficientStorage: 507,
}


#: The status counted (never sent: nobody is listening) for a client that left mid-request,
#: as nginx logs it, so that /metrics keeps it apart from the server's own failures.
CLIENT_GONE = 499


#: Key, in a request's ``scope["state"]``, of the error that the HTTP protocol answered the request
#: with when it cut its body off (``protocol.GuardedHttpProtocol.cut_off_body``): the app then
#: sees a client gone, but the request is counted as that answer's status, not CLIENT_GONE.
CUT_OFF = "dacrt.cut_off"


def status_of(error: ServiceError) -> int:
    """HTTP status for a domain error (500 for a ServiceError subclass missing from STATUS)."""
    for cls in type(error).__mro__:
        if cls in STATUS:
            return STATUS[cls]
    return 500


def install(app) -> None:
    """Register the exception handlers that give every error the ``{"detail": str}`` shape."""
    from fastapi.exceptions import RequestValidationError
    from fastapi.responses import JSONResponse, Response
    from starlette.exceptions import HTTPException
    from starlette.requests import ClientDisconnect

    from dacrt import InputError

    async def on_service_error(request, exc: ServiceError):
        return JSONResponse({"detail": exc.detail}, status_code=status_of(exc), headers=exc.headers)

    async def on_http_error(request, exc: HTTPException):
        return JSONResponse(
            {"detail": str(exc.detail)},
            status_code=exc.status_code,
            headers=getattr(exc, "headers", None),
        )

    async def on_validation_error(request, exc: RequestValidationError):
        return JSONResponse({"detail": describe_validation(exc.errors())}, status_code=422)

    async def on_client_gone(request, exc: ClientDisconnect):
        cut_off = request.scope.get("state", {}).get(CUT_OFF)
        if cut_off is not None:  # the protocol answered (and logged) it: the client is told
            return Response(status_code=status_of(cut_off))
        log.info(
            "%s %s: the client went away before sending the whole body",
            request.method,
            untrusted(request.url.path),
        )
        return Response(status_code=CLIENT_GONE)

    async def on_input_error(request, exc: InputError):
        return JSONResponse({"detail": str(exc)}, status_code=STATUS[Invalid])

    app.add_exception_handler(ServiceError, on_service_error)
    app.add_exception_handler(InputError, on_input_error)  # the engine's: it names the argument
    app.add_exception_handler(ClientDisconnect, on_client_gone)
    app.add_exception_handler(HTTPException, on_http_error)
    app.add_exception_handler(RequestValidationError, on_validation_error)


def describe_validation(errors) -> str:
    """One line per FastAPI validation error,
    e.g. ``query parameter 'stats': Input should be ...``."""
    parts = []
    for err in errors:
        loc = [str(x) for x in err.get("loc", ())]
        where = {"query": "query parameter", "path": "path parameter", "header": "header"}.get(
            loc[0] if loc else "", loc[0] if loc else "request"
        )
        name = ".".join(loc[1:])
        parts.append(
            f"{where} {name!r}: {err.get('msg', 'invalid')}"
            if name
            else f"{where}: {err.get('msg')}"
        )
    return "; ".join(parts) or "invalid request"


class CatchAll:
    """ASGI middleware: an exception nothing else handled becomes a logged JSON 500.

    Without it the server answers a bare text 500 and drops the connection.
    """

    BODY = json.dumps(
        {"detail": "the server failed on this request; the error is in its log"}
    ).encode()

    def __init__(self, app) -> None:
        self.app = app

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        started = False

        async def send_and_note(message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, send_and_note)
        except Exception:
            log.exception("unhandled error in %s %s", scope["method"], untrusted(scope["path"]))
            if started:  # half an answer is out: only closing the connection is honest now
                raise
            await send(
                {
                    "type": "http.response.start",
                    "status": 500,
                    "headers": [
                        (b"content-type", b"application/json"),
                        (b"content-length", str(len(self.BODY)).encode()),
                    ],
                }
            )
            await send({"type": "http.response.body", "body": self.BODY})
