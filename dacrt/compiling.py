"""Saying when Numba compiles the engine's kernels: a count a warm-up reports as progress, and one
notice on the first compile in process, which would otherwise look like a hang.

A query whose kernels are not compiled for its argument types compiles them first: the whole
engine takes minutes (``docs/engine-api.md`` gives the range), once per machine and version;
afterwards Numba loads them from its cache (``dacrt.cache``) in seconds. ``watch()`` registers a
listener of Numba's compile events, once: ``Scene()`` and ``dacrt.warmup()`` call it, importing
does not. The first compile of a dacrt kernel outside a warm-up logs one warning on the ``dacrt``
logger that names ``dacrt.warmup()`` and the cache folder.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from numba.core import event

log = logging.getLogger("dacrt")

FIRST_COMPILE = (
    "dacrt: compiling the engine's kernels for this machine (%s first); the first queries take "
    "minutes, once per machine and version: Numba keeps them in %s and later processes load "
    "them in seconds. Call dacrt.warmup() at start to compile them all up front, and "
    "dacrt.cache.use_cache_dir() to choose the folder."
)
MISSED_COMPILE = (
    "dacrt: compiling %s for argument types dacrt.warmup() did not cover (seconds to a minute, "
    "once per machine; kept in %s)"
)

_lock = threading.Lock()
_watcher = None  # the registered listener, once watch() has run


def watch() -> None:
    """Count and announce compiles of dacrt's kernels from now on (idempotent)."""
    global _watcher
    with _lock:
        if _watcher is not None:
            return
        _watcher = _Watcher()
        event.register("numba:compile", _watcher)


def latest_kernel() -> str | None:
    """The dacrt kernel whose compile started last (``module.function``), or None."""
    return None if _watcher is None else _watcher.latest


def compiled_kernels() -> int:
    """How many times a dacrt kernel has compiled (not loaded from the cache) since ``watch()``:
    once per kernel and argument types."""
    return 0 if _watcher is None else _watcher.compiled


@contextmanager
def warming_up() -> Iterator[None]:
    """A deliberate warm-up: its compiles are counted but not announced; a later compile is one
    the warm-up missed, and says so."""
    watch()
    with _lock:
        _watcher.warming += 1
    try:
        yield
    finally:
        with _lock:
            _watcher.warming -= 1
            _watcher.warmed = True


def _kernel_name(dispatcher: object) -> str:
    function = getattr(dispatcher, "py_func", None)
    return f"{getattr(function, '__module__', '?')}.{getattr(function, '__qualname__', '?')}"


def _cache_path(dispatcher: object) -> str:
    try:
        return dispatcher.stats.cache_path
    except AttributeError:
        return "Numba's cache"


class _Watcher(event.Listener):
    """Counts the numba:compile events of dacrt's dispatchers (one per kernel and signature;
    Numba sends them one at a time, under its compiler lock)."""

    def __init__(self) -> None:
        self.compiled = 0
        self.warming = 0
        self.warmed = False
        self.noticed = False
        self.latest: str | None = None

    def on_start(self, started: event.Event) -> None:
        dispatcher = (started.data or {}).get("dispatcher")
        name = _kernel_name(dispatcher)
        if not name.startswith("dacrt."):
            return
        self.compiled += 1
        self.latest = name
        if self.warming or self.noticed:
            return
        self.noticed = True
        message = MISSED_COMPILE if self.warmed else FIRST_COMPILE
        log.warning(message, name, _cache_path(dispatcher))

    def on_end(self, ended: event.Event) -> None:
        pass
