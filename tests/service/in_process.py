"""The app in process: ``create_app(settings)`` behind ``httpx.ASGITransport``, its lifespan
(warm-up thread, demo scene) run as a server runs it, served to synchronous httpx clients.

The app's event loop runs in a thread of its own (an anyio blocking portal), so the tests and
``service.client.Client`` stay synchronous while handlers await and offload as they do in uvicorn.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

import anyio.from_thread
import httpx
import pytest

from service.app import create_app
from service.settings import Settings

BASE_URL = "http://in-process"
WARM_UP_SECONDS = 180


class InProcessTransport(httpx.BaseTransport):
    """A synchronous httpx transport that hands each request to the app through
    ``httpx.ASGITransport`` on the portal's event loop."""

    def __init__(self, app, portal: anyio.from_thread.BlockingPortal) -> None:
        self._asgi = httpx.ASGITransport(app=app)
        self._portal = portal

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        body = request.read()  # a synchronous body (bytes or an iterator) becomes one piece
        headers = [
            (name, value)
            for name, value in request.headers.multi_items()
            if name.lower() not in ("content-length", "transfer-encoding")
        ]
        if body or request.method in ("POST", "PUT", "PATCH"):
            headers.append(("content-length", str(len(body))))
        forwarded = httpx.Request(request.method, request.url, headers=headers, content=body)
        return self._portal.call(self._send, forwarded)

    async def _send(self, request: httpx.Request) -> httpx.Response:
        response = await self._asgi.handle_async_request(request)
        content = await response.aread()
        return httpx.Response(response.status_code, headers=response.headers, content=content)


@contextmanager
def serve(settings: Settings) -> Iterator[httpx.Client]:
    """An httpx client of a new app with ``settings``, once its engine is warm."""
    app = create_app(settings)
    with (
        anyio.from_thread.start_blocking_portal() as portal,
        portal.wrap_async_context_manager(app.router.lifespan_context(app)),
        httpx.Client(transport=InProcessTransport(app, portal), base_url=BASE_URL) as client,
    ):
        deadline = time.monotonic() + WARM_UP_SECONDS
        while client.get("/health").status_code != 200:
            if time.monotonic() > deadline:
                pytest.fail(f"in-process app not ready: {client.get('/health').text}")
            time.sleep(0.1)
        yield client
