"""Uploaded scan patterns (``PUT /v1/patterns/{name}``): the engine's ``dacrt.sensors.Pattern`` by
name, for ``"pattern": NAME`` in ``/lidar`` and rigs.

At most DACRT_MAX_PATTERNS patterns of at most DACRT_MAX_PATTERN_RAYS rays each (413 naming the
limit). With a data folder (DACRT_DATA_DIR), a pattern is written to ``DATA_DIR/patterns/NAME.npz``
(atomically, as ``persistence`` writes scenes) before it is acknowledged, and read back on start;
a file that cannot be read back is logged and skipped.
"""

from __future__ import annotations

import threading

from dacrt.sensors import Pattern

from .errors import Invalid, NotFound, TooLarge
from .persistence import DataDir
from .store import check_name


class Patterns:
    """The patterns of the service, by name, within their limits; durable in ``journal``."""

    def __init__(self, max_patterns: int, max_rays: int, journal: DataDir | None = None) -> None:
        self.max_patterns = max_patterns
        self.max_rays = max_rays  #: most rays of one pattern (wire.decode_pattern checks it)
        self.journal = journal
        self._patterns: dict[str, Pattern] = {}
        self._lock = threading.Lock()

    def get(self, name: str) -> Pattern:
        """The pattern called ``name`` (404 if there is none)."""
        pattern = self._patterns.get(check_name("pattern", name))
        if pattern is None:
            raise NotFound(f"no pattern {name!r}; upload it with PUT /v1/patterns/{name}")
        return pattern

    def for_lidar(self, name: str) -> Pattern:
        """The pattern a lidar names: 422 naming the body's key if there is none."""
        pattern = self._patterns.get(name)
        if pattern is None:
            raise Invalid(
                f"pattern: no pattern {name!r}; upload it with PUT /v1/patterns/{name} "
                f"(there are {sorted(self._patterns) or 'none'})"
            )
        return pattern

    def names(self) -> list[str]:
        return sorted(self._patterns)

    def put(self, name: str, pattern: Pattern) -> bool:
        """Add or replace a pattern, durable first when there is a data folder; answers whether
        it is new (413 when it would pass DACRT_MAX_PATTERNS)."""
        check_name("pattern", name)
        with self._lock:
            old = self._patterns.get(name)
            if old is None and len(self._patterns) >= self.max_patterns:
                raise TooLarge(
                    f"the service holds {len(self._patterns)} patterns, the limit "
                    f"(DACRT_MAX_PATTERNS); delete one first"
                )
            if self.journal is not None:
                self.journal.write_pattern(name, pattern, old)
            self._patterns[name] = pattern
            return old is None

    def delete(self, name: str) -> None:
        """Delete a pattern (404 if there is none)."""
        with self._lock:
            old = self.get(name)
            if self.journal is not None:
                self.journal.delete_pattern(name, old)
            del self._patterns[name]

    def restore(self) -> None:
        """Read the data folder's patterns back (``DataDir.restore_patterns``)."""
        if self.journal is not None:
            self._patterns.update(self.journal.restore_patterns(self.max_patterns))
