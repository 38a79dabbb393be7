"""Where Numba keeps the compiled kernels: one folder whichever way the service starts.

Numba reads ``NUMBA_CACHE_DIR`` when a kernel is defined, that is when ``dacrt`` is imported, so
``service/__init__`` calls ``use_cache_dir`` first. DACRT_CACHE_DIR wins; else an explicit
NUMBA_CACHE_DIR is kept; else ``$XDG_CACHE_HOME/dacrt`` (``~/.cache/dacrt``). Numba keys each
entry by the kernel's source file and the CPU, so checkouts never mix, and another CPU compiles
again into the same folder.
"""

from __future__ import annotations

import os
from pathlib import Path


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/dacrt``, or ``~/.cache/dacrt``."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "dacrt"


def use_cache_dir() -> Path:
    """Point Numba's cache at the service's folder (before ``dacrt`` is imported); answers it."""
    chosen = os.environ.get("DACRT_CACHE_DIR") or os.environ.get("NUMBA_CACHE_DIR")
    path = Path(chosen).expanduser() if chosen else default_cache_dir()
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    return path
