"""The dacrt package as a user gets it: a typed public API, one version, and every kernel defined
by ``import dacrt`` (so that ``dacrt.cache.use_cache_dir`` reaches them all)."""

from __future__ import annotations

import inspect
import json
import os
import shutil
import subprocess
import sys
import tempfile
from importlib.metadata import version
from pathlib import Path
from typing import get_args

import pytest

import dacrt
from dacrt import scene

REPO = Path(__file__).resolve().parents[1]

QUERIES = ("closest", "occluded", "hits", "count", "nearest", "contains", "signed_distance")


def test_the_package_is_marked_typed():
    assert (Path(dacrt.__file__).parent / "py.typed").is_file()


def test_every_public_method_of_scene_is_annotated():
    for name in ("__init__", *QUERIES):
        signature = inspect.signature(getattr(dacrt.Scene, name))
        unannotated = [
            p.name
            for p in signature.parameters.values()
            if p.name != "self" and p.annotation is inspect.Parameter.empty
        ]
        assert not unannotated, (name, unannotated)
        assert signature.return_annotation is not inspect.Signature.empty, name


def test_each_query_answers_its_own_type():
    answers = {
        "closest": "Hits",
        "occluded": "Occlusion",
        "hits": "HitList",
        "count": "Counts",
        "nearest": "Nearest",
    }
    for query, answer in answers.items():
        returned = inspect.signature(getattr(dacrt.Scene, query)).return_annotation
        assert returned is getattr(dacrt, answer) and answer in dacrt.__all__


def test_the_literal_choices_are_the_engines():
    assert get_args(scene.Strategy) == dacrt.STRATEGIES
    assert get_args(scene.Cull) == dacrt.CULL_MODES


def test_every_export_exists():
    assert all(hasattr(dacrt, name) for name in dacrt.__all__)


def test_the_version_is_the_installed_metadatas():
    assert dacrt.__version__ == version("dacrt-service")


IMPORT_ALL = """
import importlib, json, pkgutil, sys
import dacrt, dacrt.cache

def kernels():
    return sorted(f"{d.py_func.__module__}.{d.py_func.__qualname__}"
                  for d in dacrt.cache.dispatchers())

defined = kernels()
for module in pkgutil.iter_modules(dacrt.__path__, "dacrt."):
    importlib.import_module(module.name)
print(json.dumps([defined, kernels()]))
"""


def test_importing_dacrt_defines_every_kernel():
    done = subprocess.run(
        [sys.executable, "-c", IMPORT_ALL], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    after_import, after_every_module = json.loads(done.stdout)
    assert after_import and after_import == after_every_module


NO_CACHE_FOLDER = """
import json, sys
import dacrt, dacrt.cache
kernels = dacrt.cache.dispatchers()
dacrt.cache.use_cache_dir(sys.argv[1])
print(json.dumps([len(kernels), sorted({str(d._cache._cache_path) for d in kernels})]))
"""


def run_as_nobody(script: str, *args: str) -> subprocess.CompletedProcess:
    """``script`` as uid 65534, whose home does not exist, with no NUMBA_CACHE_DIR."""
    return subprocess.run(
        ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]
        + [sys.executable, "-c", script, *args],
        cwd=REPO,
        env={"HOME": "/nonexistent", "PATH": os.environ.get("PATH", "/usr/bin:/bin")},
        capture_output=True,
        text=True,
        timeout=300,
    )


AS_ROOT = pytest.mark.skipif(
    not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("setpriv") is None,
    reason="runs as another user: needs root and setpriv",
)


@AS_ROOT
def test_a_cache_folder_the_process_cannot_write_is_a_warning():
    done = run_as_nobody(
        "import dacrt, dacrt.cache; dacrt.cache.use_cache_dir('/'); print(dacrt.cache.cache_dir())"
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "None"
    assert "cannot be kept in /, which this process cannot write" in done.stderr


@AS_ROOT
def test_dacrt_imports_where_numba_finds_no_folder_for_its_cache():
    """As a container's random uid: the sources and home are not writable and NUMBA_CACHE_DIR
    is unset, so Numba has nowhere to cache a kernel when it is defined; use_cache_dir then
    gives every kernel its cache in the folder it is given."""
    with tempfile.TemporaryDirectory() as folder:
        os.chmod(folder, 0o777)
        done = run_as_nobody(NO_CACHE_FOLDER, folder)
        assert done.returncode == 0, done.stderr[-2000:]
        count, paths = json.loads(done.stdout)
        assert count > 50 and all(path.startswith(folder + "/dacrt-") for path in paths)
