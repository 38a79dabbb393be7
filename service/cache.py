"""Where Numba keeps the compiled kernels: one folder whichever way the service starts.

DACRT_CACHE_DIR wins; else an explicit NUMBA_CACHE_DIR is kept; else ``$XDG_CACHE_HOME/dacrt``
(``~/.cache/dacrt``). Numba files a kernel under a hash of its source folder's path, so the
checkout's ``dacrt`` and an installed copy would compile separately; ``share_between_copies``
files ``dacrt``'s kernels under a hash of the package's sources instead: identical sources share
their kernels wherever they are, and different ones (another version, another checkout) never
overwrite each other's. Numba still keys each kernel by the CPU, so another CPU compiles again
into the same folder. Both run in ``service/__init__``, before anything imports ``dacrt``: Numba
chooses a kernel's cache when the kernel is defined.
"""

from __future__ import annotations

import hashlib
import logging
import os
from importlib.util import find_spec
from pathlib import Path

log = logging.getLogger("service")


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/dacrt``, or ``~/.cache/dacrt``."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "dacrt"


def use_cache_dir() -> Path:
    """Point Numba's cache at the service's folder (before ``dacrt`` is imported); answers it."""
    chosen = os.environ.get("DACRT_CACHE_DIR") or os.environ.get("NUMBA_CACHE_DIR")
    path = Path(chosen).expanduser() if chosen else default_cache_dir()
    os.environ["NUMBA_CACHE_DIR"] = str(path)
    share_between_copies(path)
    return path


def sources_digest(package: Path) -> str:
    """A short hash of the package's Python sources (names and contents)."""
    digest = hashlib.sha256()
    for source in sorted(package.rglob("*.py")):
        digest.update(str(source.relative_to(package)).encode() + b"\0" + source.read_bytes())
    return digest.hexdigest()[:16]


def share_between_copies(cache_dir: Path) -> None:
    """File the kernels of ``dacrt`` under ``cache_dir/dacrt-<sources digest>/``."""
    spec = find_spec("dacrt")  # found, not imported
    if spec is None or not spec.submodule_search_locations:
        return
    package = Path(spec.submodule_search_locations[0]).resolve()
    folder = cache_dir / f"dacrt-{sources_digest(package)}"
    try:
        from numba.core import caching

        class PackageLocator(caching.UserProvidedCacheLocator):
            """Numba's locator for a user cache folder, by sources rather than by path."""

            def __init__(self, py_func, py_file):
                super().__init__(py_func, py_file)
                relative = Path(py_file).resolve().parent.relative_to(package)
                self._cache_path = str(folder / relative)

            @classmethod
            def from_function(cls, py_func, py_file):
                if not Path(py_file).resolve().is_relative_to(package):
                    return None
                return caching._SourceFileBackedLocatorMixin.from_function.__func__(
                    cls, py_func, py_file
                )

        locators = caching.CacheImpl._locator_classes
        if not any(getattr(c, "__name__", "") == "PackageLocator" for c in locators):
            locators.insert(0, PackageLocator)
    except (ImportError, AttributeError) as exc:  # a Numba without these internals: by path
        log.warning("Numba's cache is filed by source path (%s: %s)", type(exc).__name__, exc)
