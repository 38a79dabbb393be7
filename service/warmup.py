"""The service's warm-up: compile every kernel a request can reach before /health says ok.

The engine's checks hand its kernels one layout whatever a body holds (read-only views, strided
columns, JSON lists: ``dacrt.validation``), so ``dacrt.warmup`` compiles every kernel a request
reaches. This runs it and logs whether it loads the kernels from the cache or compiles them, and
every PROGRESS_SECONDS how many have compiled and about how long is left.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import dacrt
import dacrt.cache
from dacrt import compiling

log = logging.getLogger("service")

#: Seconds between progress lines while the kernels compile or load.
PROGRESS_SECONDS = 15.0
#: Kernels a warm-up compiles from an empty cache (``compiling.compiled_kernels()``): the "of
#: about N" of the progress lines and their time left.
EXPECTED_COMPILES = 49
#: What a first start takes, measured from an empty cache (README, First start).
COLD_START = "about a minute on 2 idle cores, up to 15 on 2 cores busy with other work"


class Progress:
    """The warm-up's progress: the kernels compiled since ``start``."""

    def __init__(self) -> None:
        self.start = time.perf_counter()
        self.first_count = compiling.compiled_kernels()

    @property
    def compiled(self) -> int:
        return compiling.compiled_kernels() - self.first_count

    def line(self) -> str:
        """One progress line: counts and time, never the same twice."""
        elapsed = time.perf_counter() - self.start
        compiled = self.compiled
        if not compiled:
            return f"warm-up: loading the engine's kernels from the cache ({elapsed:.0f} s)"
        kernel = compiling.latest_kernel()
        if compiled >= EXPECTED_COMPILES:
            return f"warm-up: compiling kernel {compiled} ({kernel}), {elapsed:.0f} s so far"
        # Kernels differ tenfold in compile time: a rate means something after a quarter of them.
        left = (
            f", ~{elapsed / compiled * (EXPECTED_COMPILES - compiled):.0f} s left"
            if compiled >= EXPECTED_COMPILES / 4
            else ""
        )
        return (
            f"warm-up: compiling kernel {compiled} of about {EXPECTED_COMPILES} ({kernel}), "
            f"{elapsed:.0f} s so far{left}"
        )

    @contextmanager
    def reporting(self) -> Iterator[None]:
        """A progress line every PROGRESS_SECONDS until the block ends."""
        done = threading.Event()

        def report() -> None:
            while not done.wait(PROGRESS_SECONDS):
                log.info("%s", self.line())

        threading.Thread(target=report, name="dacrt-warmup-progress", daemon=True).start()
        try:
            yield
        finally:
            done.set()


def announce() -> None:
    """Say whether the kernels load from the cache or compile, and where they go."""
    if dacrt.cache.cache_dir() is None:
        log.info("warm-up: kernels go where Numba puts them (dacrt.cache.use_cache_dir not called)")
        return
    folder = dacrt.cache.kernels_folder(dacrt.cache.cache_dir())
    if folder.is_dir() and any(folder.rglob("*.nbi")):
        log.info(
            "warm-up: loading the compiled kernels from %s (seconds; those of another CPU "
            "compile again)",
            folder,
        )
    else:
        log.info(
            "warm-up: compiling the engine's kernels for this CPU into %s, once: about %d "
            "kernels, %s",
            folder,
            EXPECTED_COMPILES,
            COLD_START,
        )


def warm_up() -> float:
    """Compile (or load from Numba's cache: ``dacrt.cache``) every kernel; answers the seconds
    taken."""
    announce()
    progress = Progress()
    with progress.reporting():
        dacrt.warmup()
    seconds = time.perf_counter() - progress.start
    log.info(
        "warm-up: the engine's kernels (dacrt.warmup) ready after %.1f s (%d kernels compiled)",
        seconds,
        progress.compiled,
    )
    return seconds


def main() -> None:
    """``python -m service.warmup``: compile (or load) every kernel a request reaches into
    DACRT_CACHE_DIR, then exit; a container build runs it so that the server starts in seconds."""
    from .logs import configure_logging

    configure_logging("info")
    dacrt.cache.use_cache_dir()
    seconds = warm_up()
    log.info("warm-up: every kernel ready after %.1f s", seconds)


if __name__ == "__main__":
    main()
