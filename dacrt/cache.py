"""Where Numba keeps the engine's compiled kernels: one explicit call, never an import side effect.

Every kernel is compiled with ``cache=True``. Until ``use_cache_dir`` is called, Numba's own rule
files them (``NUMBA_CACHE_DIR``, else ``__pycache__`` beside dacrt's sources, else
``~/.cache/numba``), by the path of the source file: a checkout and an installed copy of the same
sources compile separately. Where the process can write none of those (a container's random
uid), the kernels are not cached until ``use_cache_dir``; where it cannot write that folder
either, it says so in a warning and every process compiles them.

``use_cache_dir(path)`` files dacrt's kernels, and only dacrt's (the process's other Numba code
keeps Numba's rule, and the environment is left alone), under ``path/dacrt-<digest>/``, the
digest being a hash of the package's sources: identical sources share their kernels wherever they
are installed, and another version never loads or overwrites them. Numba still keys each kernel
by the CPU, so another CPU compiles again into the same folder. The service calls it at start;
in process, call it once before the first query, and a dask worker calls it with
``--preload dacrt.cache`` (``dask_setup``).

It replaces the cache of each of dacrt's dispatchers with one whose locator is a subclass of
Numba's ``UserProvidedCacheLocator``: Numba's caching classes, used without changing them.
"""

from __future__ import annotations

import hashlib
import logging
import os
import sys
from functools import cache
from pathlib import Path

log = logging.getLogger("dacrt")

#: The package's folder: the sources whose digest names the kernels' folder.
PACKAGE = Path(__file__).resolve().parent

_chosen: Path | None = None  # the folder of the last use_cache_dir, for cache_dir()


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/dacrt``, or ``~/.cache/dacrt``."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "dacrt"


def chosen_cache_dir(path: str | os.PathLike[str] | None = None) -> Path:
    """``path`` if given, else ``DACRT_CACHE_DIR``, else ``NUMBA_CACHE_DIR``, else
    ``default_cache_dir()``."""
    chosen = path or os.environ.get("DACRT_CACHE_DIR") or os.environ.get("NUMBA_CACHE_DIR")
    return Path(chosen).expanduser() if chosen else default_cache_dir()


@cache
def sources_digest(package: Path = PACKAGE) -> str:
    """A short hash of the package's Python sources (names and contents)."""
    digest = hashlib.sha256()
    for source in sorted(package.rglob("*.py")):
        digest.update(str(source.relative_to(package)).encode() + b"\0" + source.read_bytes())
    return digest.hexdigest()[:16]


def kernels_folder(path: str | os.PathLike[str] | None = None) -> Path:
    """The folder ``use_cache_dir(path)`` files this copy's kernels in."""
    return chosen_cache_dir(path) / f"dacrt-{sources_digest()}"


def use_cache_dir(path: str | os.PathLike[str] | None = None) -> Path:
    """File dacrt's compiled kernels under ``path`` (default: ``chosen_cache_dir()``), in
    ``kernels_folder(path)``; answers ``path``. Call it before the first query: a kernel already
    compiled in this process keeps its code, and its new signatures go to the new folder."""
    global _chosen
    root = chosen_cache_dir(path)
    folder = kernels_folder(root)
    try:
        cache_class = package_cache(folder)
        caches = [(dispatcher, cache_class(dispatcher.py_func)) for dispatcher in dispatchers()]
    except (ImportError, AttributeError, TypeError) as exc:  # a Numba without these classes
        log.warning(
            "dacrt: compiled kernels stay where Numba puts them, not in %s (%s: %s)",
            root,
            type(exc).__name__,
            exc,
        )
        return root
    except RuntimeError as exc:  # Numba's "no locator available": nowhere it may write
        log.warning(
            "dacrt: compiled kernels cannot be kept in %s, which this process cannot write "
            "(%s); every process compiles them again",
            root,
            exc,
        )
        return root
    for dispatcher, kernel_cache in caches:
        dispatcher._cache = kernel_cache
    _chosen = root
    return root


def cache_dir() -> Path | None:
    """The folder of the last ``use_cache_dir`` call in this process, or None."""
    return _chosen


def dispatchers() -> list:
    """Every caching Numba dispatcher of dacrt's imported modules (``config.jit``'s: with
    Numba's cache, or with its cache deferred where Numba found no folder for it)."""
    from numba.core.caching import NullCache
    from numba.core.dispatcher import Dispatcher

    found = {}
    for name, module in list(sys.modules.items()):
        if module is None or not (name == "dacrt" or name.startswith("dacrt.")):
            continue
        for value in vars(module).values():
            if isinstance(value, Dispatcher) and (
                not isinstance(value._cache, NullCache) or getattr(value, "cache_deferred", False)
            ):
                found[id(value)] = value
    return list(found.values())


def package_cache(folder: Path) -> type:
    """A Numba ``FunctionCache`` class that files a dacrt kernel under ``folder``, at its source
    file's place in the package (``folder/traversal``, ...)."""
    from numba.core import caching

    class PackageLocator(caching.UserProvidedCacheLocator):
        """Numba's locator for a user folder, by the package's sources rather than their path."""

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            relative = Path(py_file).resolve().parent.relative_to(PACKAGE)
            self._cache_path = str(folder / relative)

        @classmethod
        def from_function(cls, py_func, py_file):
            if not Path(py_file).resolve().is_relative_to(PACKAGE):
                return None
            # The source-file mixin's check, without UserProvidedCacheLocator's NUMBA_CACHE_DIR one.
            return caching._SourceFileBackedLocatorMixin.from_function.__func__(
                cls, py_func, py_file
            )

    class PackageCacheImpl(caching.CompileResultCacheImpl):
        _locator_classes = [PackageLocator, *caching.CompileResultCacheImpl._locator_classes]

    class PackageCache(caching.FunctionCache):
        _impl_class = PackageCacheImpl

    return PackageCache


def dask_setup(worker: object) -> None:
    """``dask worker ... --preload dacrt.cache``: the worker files the kernels as the service
    does (``DACRT_CACHE_DIR``)."""
    use_cache_dir()
