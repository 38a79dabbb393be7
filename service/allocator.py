"""The C allocator's arenas. glibc gives a thread that allocates while another holds an arena an
arena of its own, and each arena keeps the heap its threads freed. Every worker thread that once
served a heavy request would then keep that request's peak, so the process would hold several
peaks while the in-flight budget admits one. Capped at ``ARENAS``, the threads share two arenas
and reuse what the last request freed."""

from __future__ import annotations

import ctypes
import logging
import os

log = logging.getLogger("service")

#: ``mallopt``'s parameter for the most arenas (glibc's malloc.h).
M_ARENA_MAX = -8
#: Two: the engine's threads and the request threads seldom allocate at once.
ARENAS = 2


def cap_arenas(arenas: int = ARENAS) -> bool:
    """Cap glibc's arenas at ``arenas`` for the threads this process starts from now on; answers
    whether it did. MALLOC_ARENA_MAX in the environment stands (glibc read it at start), and a C
    library without ``mallopt`` (musl, macOS) is left as it is."""
    if "MALLOC_ARENA_MAX" in os.environ:
        return False
    mallopt = getattr(ctypes.CDLL(None), "mallopt", None)
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    done = mallopt(M_ARENA_MAX, arenas) == 1
    if not done:
        log.warning("the C allocator kept its arenas (mallopt(M_ARENA_MAX, %d) refused)", arenas)
    return done
