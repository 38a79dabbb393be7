"""Numba's compiled kernels: the server files them in DACRT_CACHE_DIR (default ~/.cache/dacrt)
by the engine's sources, so that the checkout and an installed copy elsewhere share them; and
importing the service or the engine changes nothing (the policy is ``dacrt.cache.use_cache_dir``,
called by the server's start)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from service_helpers import REPO

from dacrt.cache import sources_digest

#: The server's call (``app``'s lifespan), then a traversal kernel's source file and cache folder.
SHOW = (
    "import dacrt.cache, dacrt.traversal as t; dacrt.cache.use_cache_dir(); "
    "k = min((d for d in dacrt.cache.dispatchers() if d.py_func.__module__ == t.__name__), "
    "key=lambda d: d.py_func.__qualname__); print(t.__file__); print(k.stats.cache_path)"
)

#: Imports what a user of the client, the engine or the app imports, and says what changed.
IMPORTS = """
import json, os
from numba.core import caching
environ, locators = dict(os.environ), list(caching.CacheImpl._locator_classes)
import service, service.client, dacrt, service.app
import dacrt.cache
names = environ.keys() | os.environ.keys()
print(json.dumps({
    "changed": sorted(k for k in names if environ.get(k) != os.environ.get(k)),
    "same_locators": caching.CacheImpl._locator_classes == locators,
    "paths": sorted({d.stats.cache_path for d in dacrt.cache.dispatchers()}),
}))
"""

#: The app's start in a fresh process: where the kernels go once its lifespan has begun.
START = """
import asyncio, json, os, sys
import dacrt.cache
from service import warmup
from service.app import create_app

warmup.warm_up = lambda stopping: 0.0  # no child compiling into the empty folder after the exit

async def start():
    app = create_app()
    async with app.router.lifespan_context(app):
        print(json.dumps(sorted({d.stats.cache_path for d in dacrt.cache.dispatchers()})))
        sys.stdout.flush()
        os._exit(0)

asyncio.run(start())
"""


def run_python(code: str, root: Path, env: dict[str, str]) -> str:
    """stdout of ``python -c code`` in a fresh process in ``root``, without our DACRT_*/NUMBA_*."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("DACRT_", "NUMBA_"))}
    done = subprocess.run(
        [sys.executable, "-c", code],
        cwd=root,
        env={**clean, "PYTHONPATH": str(root), **env},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def kernel_folder(root: Path, env: dict[str, str]) -> tuple[str, str]:
    """(the engine module's file, where its kernels are cached) of a fresh process in ``root``."""
    module, folder = run_python(SHOW, root, env).split()
    return module, folder


def test_a_copy_elsewhere_shares_the_checkouts_kernels(tmp_path):
    copy = tmp_path / "installed"
    for package in ("dacrt", "service"):
        shutil.copytree(
            REPO / package, copy / package, ignore=shutil.ignore_patterns("__pycache__")
        )
    env = {"DACRT_CACHE_DIR": str(tmp_path / "cache")}
    here, there = kernel_folder(REPO, env), kernel_folder(copy, env)
    assert here[0] != there[0]  # two copies of the engine...
    assert here[1] == there[1]  # ...one folder of kernels
    assert Path(here[1]).parent == tmp_path / "cache"


def test_changed_sources_get_their_own_folder(tmp_path):
    copy = tmp_path / "changed"
    for package in ("dacrt", "service"):
        shutil.copytree(
            REPO / package, copy / package, ignore=shutil.ignore_patterns("__pycache__")
        )
    with open(copy / "dacrt" / "traversal.py", "a") as source:
        source.write("\n# another version\n")
    env = {"DACRT_CACHE_DIR": str(tmp_path / "cache")}
    assert kernel_folder(REPO, env)[1] != kernel_folder(copy, env)[1]


def test_the_default_folder_is_the_users_cache(tmp_path):
    _, folder = kernel_folder(REPO, {"XDG_CACHE_HOME": str(tmp_path)})
    assert Path(folder).parent == tmp_path / "dacrt"


def test_importing_changes_neither_the_environment_nor_numba(tmp_path):
    cache = tmp_path / "cache"
    out = json.loads(run_python(IMPORTS, REPO, {"DACRT_CACHE_DIR": str(cache)}))
    assert out["changed"] == []  # no NUMBA_CACHE_DIR, nothing else
    assert out["same_locators"]  # Numba's own classes, unpatched
    assert out["paths"] and not any(str(cache) in path for path in out["paths"])


def test_the_server_files_its_kernels_in_dacrt_cache_dir(tmp_path):
    cache = tmp_path / "cache"
    env = {"DACRT_CACHE_DIR": str(cache), "DACRT_LOAD_DEMO": "false"}
    paths = json.loads(run_python(START, REPO, env))
    assert paths and all(Path(p).is_relative_to(cache) for p in paths)
    assert {Path(p).relative_to(cache).parts[0] for p in paths} == {f"dacrt-{sources_digest()}"}
