"""Numba's compiled kernels: in DACRT_CACHE_DIR (default ~/.cache/dacrt), filed by the engine's
sources, so that the checkout and an installed copy elsewhere share them."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from service_helpers import REPO

SHOW = (
    "import service, dacrt.traversal as t; "
    "print(t.__file__); print(t.trace_object_split._cache._cache_path)"
)


def kernel_folder(root: Path, env: dict[str, str]) -> tuple[str, str]:
    """(the engine module's file, where its kernels are cached) of a fresh process in ``root``."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("DACRT_", "NUMBA_"))}
    done = subprocess.run(
        [sys.executable, "-c", SHOW],
        cwd=root,
        env={**clean, "PYTHONPATH": str(root), **env},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    module, folder = done.stdout.split()
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
