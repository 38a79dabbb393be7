"""The ``Server-Timing`` header: named durations of one request, in milliseconds."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class ServerTiming:
    """Collects ``name -> seconds``; ``header()`` gives ``decode;dur=1.234, trace;dur=...``."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start

    def header(self) -> str:
        return ", ".join(f"{name};dur={1000 * s:.3f}" for name, s in self.seconds.items())


def parse_server_timing(header: str) -> dict[str, float]:
    """``"decode;dur=1.5, trace;dur=20"`` -> ``{"decode": 1.5, "trace": 20.0}`` (milliseconds)."""
    out = {}
    for part in header.split(","):
        name, *params = [p.strip() for p in part.split(";")]
        for param in params:
            key, _, value = param.partition("=")
            if key == "dur" and name:
                out[name] = float(value)
    return out
