"""Child processes that end with their parent: Linux signals such a child when the thread that
started it ends, so a parent killed outright (SIGKILL, which runs no clean-up) leaves no child
running. Elsewhere a child outlives a parent killed so."""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Callable

#: prctl's option that has Linux signal a process when the thread that started it ends
PR_SET_PDEATHSIG = 1


def ending_with_parent(signum: int) -> Callable[[], None] | None:
    """A ``preexec_fn`` for ``subprocess.Popen`` that has Linux send the child ``signum`` when the
    thread that calls this, and starts the child, ends; None where there is no prctl (not Linux).
    Call it in that thread, just before ``Popen``."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        # Looked up here, in the parent: the child runs as little as it can before its exec.
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    parent = os.getpid()

    def end_with_parent() -> None:
        prctl(PR_SET_PDEATHSIG, signum)
        if os.getppid() != parent:  # the parent ended before prctl: no signal will come
            os.kill(os.getpid(), signal.SIGKILL)

    return end_with_parent
