"""Uploaded scan patterns (``PUT /v1/patterns/{name}``): the engine's ``dacrt.sensors.Pattern`` by
name, for ``"pattern": NAME`` in ``/lidar`` and rigs.

At most DACRT_MAX_PATTERNS patterns of at most DACRT_MAX_PATTERN_RAYS rays each (413 naming the
limit). With a data folder (DACRT_DATA_DIR), a pattern is written to ``DATA_DIR/patterns/NAME.npz``
(atomically, as ``persistence`` writes scenes) before it is acknowledged, and read back on start;
a file that cannot be read back is logged and skipped.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

from dacrt import InputError
from dacrt.sensors import Pattern

from .errors import DataDirUnavailable, Invalid, NotFound, TooLarge
from .persistence import TEMPORARY, os_error_text, sync_folder, write_file
from .store import check_name

log = logging.getLogger("service")


class Patterns:
    """The patterns of the service, by name, within their limits."""

    def __init__(self, max_patterns: int, max_rays: int, data_dir: Path | None = None) -> None:
        self.max_patterns = max_patterns
        self.max_rays = max_rays  #: most rays of one pattern (wire.decode_pattern checks it)
        self.folder = None if data_dir is None else Path(data_dir) / "patterns"
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
            created = name not in self._patterns
            if created and len(self._patterns) >= self.max_patterns:
                raise TooLarge(
                    f"the service holds {len(self._patterns)} patterns, the limit "
                    f"(DACRT_MAX_PATTERNS); delete one first"
                )
            if self.folder is not None:
                try:
                    self.folder.mkdir(parents=True, exist_ok=True)
                    write_file(self.folder / f"{name}.npz", pattern.save)
                    sync_folder(self.folder)
                except OSError as exc:
                    raise DataDirUnavailable(
                        f"cannot write pattern {name!r} to {self.folder}: {os_error_text(exc)}; "
                        "nothing was changed"
                    ) from None
            self._patterns[name] = pattern
            return created

    def delete(self, name: str) -> None:
        """Delete a pattern (404 if there is none)."""
        self.get(name)
        with self._lock:
            if self.folder is not None:
                (self.folder / f"{name}.npz").unlink(missing_ok=True)
                sync_folder(self.folder)
            self._patterns.pop(name, None)

    def restore(self) -> None:
        """Read the data folder's patterns back (temporary files of an interrupted write are
        removed; a file the engine cannot read is logged and skipped)."""
        if self.folder is None or not self.folder.is_dir():
            return
        for path in sorted(self.folder.iterdir()):
            if path.name.endswith(TEMPORARY):
                path.unlink(missing_ok=True)
                continue
            if path.suffix != ".npz":
                continue
            try:
                self._patterns[check_name("pattern", path.stem)] = Pattern.load(path)
            except (Invalid, InputError, OSError, ValueError) as exc:
                log.error("data: skipped pattern %s: %s", path.name, exc)
