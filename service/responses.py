"""A response whose body is buffers (zip headers and answer arrays), sent in order.

Joining them would copy every answer array once more; ASGI lets us send them one by one under a
Content-Length that covers them all. The buffers may be made as they are sent (``wire.NpzBody``'s
CRCs, ``wire.json_pieces``): each is made on a worker thread, so that making a large answer does
not stop the event loop, and with it every other request.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from anyio.to_thread import run_sync
from starlette.responses import Response

from .wire import Buffer


class BuffersResponse(Response):
    """``Response`` with ``parts`` (``length`` bytes in all) as its body, never joined into one
    buffer; each part is taken from ``parts`` only once the one before has been handed over.
    ``length`` None sends the body chunked."""

    def __init__(
        self,
        parts: Iterable[Buffer],
        length: int | None,
        media_type: str,
        headers: Mapping[str, str],
        status_code: int = 200,
    ) -> None:
        self.parts = parts
        super().__init__(b"", status_code, headers, media_type)
        # without a Content-Length (a JSON answer written as it goes) the body goes chunked
        del self.headers["content-length"]
        if length is not None:
            self.headers["content-length"] = str(length)

    async def __call__(self, scope, receive, send) -> None:
        await send(
            {"type": "http.response.start", "status": self.status_code, "headers": self.raw_headers}
        )
        parts = iter(self.parts)
        while (part := await run_sync(next, parts, None)) is not None:
            if len(part):
                await send({"type": "http.response.body", "body": part, "more_body": True})
        await send({"type": "http.response.body", "body": b""})
