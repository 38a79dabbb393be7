"""A response whose body is buffers (zip headers and answer arrays), sent in order.

Joining them would copy every answer array once more; ASGI lets us send them one by one under a
Content-Length that covers them all. The buffers may be made as they are sent (``wire.NpzBody``'s
CRCs, ``wire.json_pieces``): each is made on a worker thread, so that making a large answer does
not stop the event loop, and with it every other request. Small consecutive buffers (a JSON
answer's keys and brackets, an npz's headers) go out joined, a thread hop and a send for about
WRITE_BYTES of them, not one each.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping

from anyio.to_thread import run_sync
from starlette.responses import Response

from .wire import Buffer

#: Bytes of consecutive small parts joined into one write: a write is a thread hop and a send,
#: and a rig's answer has tens of thousands of parts of a few bytes.
WRITE_BYTES = 64 * 1024


class BuffersResponse(Response):
    """``Response`` with ``parts`` (``length`` bytes in all) as its body, never joined into one
    buffer; each part is taken from ``parts`` only once the one before has been handed over
    (or copied). ``length`` None sends the body chunked."""

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
        while writes := await run_sync(next_writes, parts):
            for write in writes:
                await send({"type": "http.response.body", "body": write, "more_body": True})
        await send({"type": "http.response.body", "body": b""})


def next_writes(parts: Iterator[Buffer]) -> list[Buffer]:
    """The next writes of ``parts`` (none once they are all written): consecutive parts under
    WRITE_BYTES copied into one write of about WRITE_BYTES, a larger part written as it is
    (not copied) after the small ones before it. Empty parts are skipped."""
    joined = bytearray()
    for part in parts:
        if len(part) >= WRITE_BYTES:
            return [bytes(joined), part] if joined else [part]
        joined += part
        if len(joined) >= WRITE_BYTES:
            break
    return [bytes(joined)] if joined else []
