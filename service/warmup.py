"""The service's warm-up: compile every kernel a request can reach before /health says ok.

The engine's checks hand its kernels one layout whatever a body holds (read-only views, strided
columns, JSON lists: ``dacrt.validation``), so ``dacrt.warmup`` compiles every kernel a request
reaches. A server first loads them from the cache (``dacrt.cache``), stopping before the first
compile of its own (another thread's go on). Those missing there compile in a child process,
``python -m service.warmup``, whose log lines the server's log shows and which ends with the
server (on Linux, even one killed outright): a process that has compiled them keeps much of
Numba's and LLVM's memory until it ends (docs/limits.md), so the child keeps it instead of the
server, which then loads the kernels from the cache. Where the child cannot start or fails, the
server compiles them itself and says why; a process that has run a kernel already (one that
embeds the app) compiles what is missing itself.
Every PROGRESS_SECONDS a line says how many have compiled and about how long is left."""

from __future__ import annotations

import logging
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from contextvars import ContextVar

from numba.core import event

import dacrt
import dacrt.cache
from dacrt import compiling

from .children import ending_with_parent

log = logging.getLogger("service")

#: Seconds between progress lines while the kernels compile or load.
PROGRESS_SECONDS = 15.0
#: Kernels a warm-up compiles from an empty cache (``compiling.compiled_kernels()``): the "of
#: about N" of the progress lines and their time left.
EXPECTED_COMPILES = 43
#: What a first start takes, measured from an empty cache (README, First start).
COLD_START = "about a minute on 2 idle cores, up to 15 on 2 cores busy with other work"
#: The process that compiles the kernels for a server, as the Dockerfile runs it at build time.
CHILD = [sys.executable, "-m", "service.warmup"]
#: A line of the child's log (``service.logs.FORMAT``): its level and message.
CHILD_LINE = re.compile(r"(CRITICAL|ERROR|WARNING|INFO|DEBUG):\s+service: (.*)")


class NotCached(Exception):
    """A kernel of dacrt's that is not in the cache for this CPU: loading it would compile it."""


class Stopped(Exception):
    """The server stopped while its child compiled the kernels."""


#: True in the context of a load that refuses to compile (``refusing_compiles``): its thread's,
#: and the copies dacrt's pool threads run its work in (``dacrt.chunks.map_on_threads``).
REFUSING: ContextVar[bool] = ContextVar("dacrt_refusing_compiles", default=False)


class RefuseCompiles(event.Listener):
    """Raises NotCached where Numba is about to compile a kernel of dacrt's in a context that
    REFUSING marks, before it does."""

    def on_start(self, started: event.Event) -> None:
        if not REFUSING.get():
            return
        function = getattr((started.data or {}).get("dispatcher"), "py_func", None)
        name = f"{getattr(function, '__module__', '?')}.{getattr(function, '__qualname__', '?')}"
        if name.startswith("dacrt."):
            raise NotCached(name)

    def on_end(self, ended: event.Event) -> None:
        pass


@contextmanager
def refusing_compiles() -> Iterator[None]:
    """NotCached where the block would compile a kernel of dacrt's, in its thread or in dacrt's
    pool threads on its behalf. Numba's listeners are the whole process's: another thread's
    compiles (an app that embeds the service, running its first query) go on."""
    marked = REFUSING.set(True)
    try:
        with event.install_listener("numba:compile", RefuseCompiles()):
            yield
    finally:
        REFUSING.reset(marked)


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


def engine_has_run() -> bool:
    """Whether a kernel of dacrt's has compiled or loaded in this process: one that embeds the
    app, or the tests'."""
    return any(dispatcher.signatures for dispatcher in dacrt.cache.dispatchers())


def load(only_cached: bool = False) -> int:
    """``dacrt.warmup()``, with a progress line every PROGRESS_SECONDS; answers how many kernels
    compiled. ``only_cached``: NotCached before the first kernel that would compile
    (``refusing_compiles``: another thread's compiles go on)."""
    progress = Progress()
    refusing = refusing_compiles() if only_cached else nullcontext()
    with progress.reporting(), refusing:
        dacrt.warmup()
    return progress.compiled


def warm_up(stopping: threading.Event | None = None) -> float:
    """The server's warm-up: load every kernel from Numba's cache (``dacrt.cache``), where a
    process that has run none yet compiles those missing there in a child process first
    (``compile_in_child``); answers the seconds taken. ``stopping`` set ends that child
    (Stopped)."""
    start = time.perf_counter()
    announce()
    if not engine_has_run():
        try:
            load(only_cached=True)
        except NotCached as missing:
            failure = compile_in_child(str(missing), stopping)
            if failure is None:
                try:
                    load(only_cached=True)
                except NotCached as still:
                    failure = f"{still} is still not in the cache after the child's compile"
            if failure is not None:
                log.warning(
                    "warm-up: compiling the kernels in this process instead (%s); it keeps "
                    "about 2 GB of the compiler's memory until it stops",
                    failure,
                )
    return report(start, load())


def report(start: float, compiled: int) -> float:
    """Log that the kernels are ready, and answer the seconds since ``start``."""
    seconds = time.perf_counter() - start
    log.info(
        "warm-up: the engine's kernels (dacrt.warmup) ready after %.1f s (%d kernels compiled)",
        seconds,
        compiled,
    )
    return seconds


def child_setup(ending: Callable[[], None] | None) -> Callable[[], None]:
    """The warm-up child's ``preexec_fn``: it ignores SIGINT, as a terminal's Ctrl-C is the
    server's to handle (the server then ends the child), and runs ``ending``: Linux signals it
    when the server's warm-up thread, which waits for it, ends (``ending_with_parent``)."""

    def setup() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if ending is not None:
            ending()

    return setup


def compile_in_child(missing: str, stopping: threading.Event | None = None) -> str | None:
    """Run CHILD, which compiles every kernel into this process's cache folder, and log its lines
    as they come; answers None once it succeeded, else why it did not. ``stopping`` set ends it
    (Stopped); on Linux it also ends (SIGTERM) when this process is killed outright."""
    env = dict(os.environ)
    if dacrt.cache.cache_dir() is not None:  # the folder this process loads from, absolute
        env["DACRT_CACHE_DIR"] = str(dacrt.cache.cache_dir().resolve())
    try:
        child = subprocess.Popen(
            CHILD,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
            preexec_fn=child_setup(ending_with_parent(signal.SIGTERM)),
        )
    except OSError as exc:
        return f"the child process {' '.join(CHILD)} could not start: {exc}"
    log.info(
        "warm-up: %s is not in the cache for this CPU: the kernels compile in a child process "
        "(python -m service.warmup, pid %d), whose lines follow; the compiler's memory (about "
        "3 GB at its peak) goes with it, and this server loads the kernels when it is done",
        missing,
        child.pid,
    )
    relay = threading.Thread(target=relay_lines, args=(child,), name="dacrt-warmup-child")
    relay.start()
    try:
        while child.poll() is None:
            if stopping is not None and stopping.wait(0.5):
                raise Stopped(f"the server stopped, and with it child process {child.pid}")
            if stopping is None:
                child.wait()
    finally:
        if child.poll() is None:
            child.terminate()
        child.wait()
        relay.join()
        child.stdout.close()
    if child.returncode < 0:
        return f"the child process {child.pid} was ended by signal {-child.returncode}"
    if child.returncode != 0:
        return f"the child process {child.pid} exited with status {child.returncode}"
    return None


def relay_lines(child: subprocess.Popen) -> None:
    """Log each line the child prints, at its own level; another line (a traceback, Numba's
    warnings) as a warning."""
    for line in child.stdout:
        matched = CHILD_LINE.fullmatch(line.rstrip("\n"))
        if matched is None:
            log.warning("child %d: %s", child.pid, line.rstrip())
        else:
            level, message = matched.groups()
            log.log(logging.getLevelName(level), "child %d: %s", child.pid, message)


def main() -> None:
    """``python -m service.warmup``: compile (or load) every kernel a request reaches into
    DACRT_CACHE_DIR, in this process, then exit; a container build runs it so that the server
    starts in seconds, and a server runs it to compile the kernels missing from the cache."""
    from .logs import configure_logging

    configure_logging("info")
    dacrt.cache.use_cache_dir()
    announce()
    seconds = report(time.perf_counter(), load())
    log.info("warm-up: every kernel ready after %.1f s", seconds)


if __name__ == "__main__":
    main()
