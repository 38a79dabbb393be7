"""Request and answer bodies, filled chunk by chunk into one NumPy buffer."""

from __future__ import annotations

import numpy as np


class BodyBuffer:
    """A body filled chunk by chunk into one read-only NumPy buffer (server requests and client
    answers alike).

    For big bodies NumPy asks the kernel for huge pages, so filling one costs far fewer page
    faults than joining its chunks into one ``bytes``. The expected size (Content-Length) is
    allocated up front; its pages cost nothing until written.
    """

    def __init__(self, expected: int | None = None) -> None:
        self._buffer = np.empty(expected or 0, np.uint8)
        self._extra: list[bytes] = []  # what arrives beyond the expected size (or without one)
        self.size = 0

    def add(self, chunk: bytes) -> None:
        if not self._extra and self.size + len(chunk) <= len(self._buffer):
            self._buffer[self.size : self.size + len(chunk)] = np.frombuffer(chunk, np.uint8)
        else:
            self._extra.append(chunk)
        self.size += len(chunk)

    def finish(self) -> memoryview:
        """The body; views of it (rays, vertices, answers) are read-only, as views of bytes are."""
        filled = self.size - sum(map(len, self._extra))
        buffer = self._buffer[:filled]
        if self._extra:
            buffer = np.concatenate([buffer, *(np.frombuffer(c, np.uint8) for c in self._extra)])
        buffer.flags.writeable = False
        return memoryview(buffer)
