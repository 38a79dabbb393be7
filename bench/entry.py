"""What every benchmark's entry point does first: its ``--help`` description, and the engine's
compiled kernels from the shared cache.

``use_kernel_cache()`` is the one call a benchmark makes before its first query, and so does every
process it starts that traces: ``bench.run``'s memory processes (given the folder) and
``bench.http_bound``'s server. It files dacrt's kernels where ``dacrt.cache.use_cache_dir()``
puts them (``DACRT_CACHE_DIR``, else ``~/.cache/dacrt``), so they compile once per machine and
version. Without it Numba files them by the path of dacrt's sources (the checkout's
``dacrt/__pycache__``), and a fresh process compiles the whole engine, which takes minutes.
A process started by a benchmark gets the folder through ``kernel_cache_env()``: the service and
``bench.http_bound`` read it, and so do dask workers with ``DASK_PRELOAD``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

#: ``preload=`` of a dask worker that traces: it files the kernels in ``DACRT_CACHE_DIR``.
DASK_PRELOAD = ["dacrt.cache"]


def use_kernel_cache(folder: str | os.PathLike[str] | None = None) -> Path:
    """File dacrt's compiled kernels under ``folder`` (default: ``DACRT_CACHE_DIR``, else
    ``~/.cache/dacrt``); answers that folder, absolute. Call it before the first query."""
    import dacrt.cache

    return Path(dacrt.cache.use_cache_dir(folder)).resolve()


def kernel_cache() -> Path | None:
    """The folder of this process's ``use_kernel_cache``, absolute, or None before it."""
    cache = sys.modules.get("dacrt.cache")
    folder = cache.cache_dir() if cache is not None else None
    return None if folder is None else Path(folder).resolve()


def kernel_cache_env() -> dict[str, str]:
    """The environment a process started by this one needs to load the kernels from the same
    folder: ``DACRT_CACHE_DIR`` (empty before ``use_kernel_cache``: the child's default is then
    this process's too)."""
    folder = kernel_cache()
    return {} if folder is None else {"DACRT_CACHE_DIR": str(folder)}


def description(doc: str) -> str:
    """A module docstring's first paragraph on one line: the ``--help`` description."""
    return " ".join(doc.split("\n\n")[0].split())
