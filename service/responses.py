"""A response whose body is a list of buffers (zip headers and answer arrays), sent in order.

Joining them would copy every answer array once more; ASGI lets us send them one by one under a
Content-Length that covers them all.
"""
from __future__ import annotations

from typing import Mapping, Sequence

from starlette.responses import Response

from .wire import Buffer


class BuffersResponse(Response):
    """``Response`` with ``parts`` as its body, never joined into one buffer."""

    def __init__(self, parts: Sequence[Buffer], media_type: str, headers: Mapping[str, str],
                 status_code: int = 200) -> None:
        self.parts = [part for part in parts if len(part)]
        length = sum(len(part) for part in self.parts)
        super().__init__(b"", status_code, {**headers, "Content-Length": str(length)}, media_type)

    async def __call__(self, scope, receive, send) -> None:
        await send({"type": "http.response.start", "status": self.status_code,
                    "headers": self.raw_headers})
        for position, part in enumerate(self.parts):
            await send({"type": "http.response.body", "body": part,
                        "more_body": position < len(self.parts) - 1})
        if not self.parts:
            await send({"type": "http.response.body", "body": b""})
