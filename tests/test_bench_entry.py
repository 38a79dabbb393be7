"""``bench.entry``: every benchmark and every process it starts that traces loads dacrt's kernels
from the benchmark's cache folder instead of compiling them (which takes minutes), a server it
starts ends with it, and every ``--help`` gives its module's whole first paragraph. Each child
process runs with ``NUMBA_CACHE_DIR`` at an empty folder, where a child that skipped the cache
would file what it compiled. Nothing here is timed."""

from __future__ import annotations

import ast
import os
import runpy
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import dacrt.cache
from bench import dask as bench_dask
from bench import entry
from bench.http_overhead import start_server
from bench.measure import measure_memory

REPO = Path(__file__).resolve().parents[1]
BENCH = sorted((REPO / "bench").glob("*.py"))
ENTRY_POINTS = [path.stem for path in BENCH if 'if __name__ == "__main__"' in path.read_text()]


@pytest.fixture
def shared_cache(tmp_path, monkeypatch):
    """This process's kernels folder (warm: the tests' warm-up), Numba's own rule pointed at an
    empty folder; answers (kernels folder, that empty folder)."""
    folder = entry.use_kernel_cache(dacrt.cache.cache_dir())
    numba_rule = tmp_path / "numba"
    numba_rule.mkdir()
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(numba_rule))
    monkeypatch.delenv("DACRT_CACHE_DIR", raising=False)
    return folder, numba_rule


def compiled_files(folder: Path) -> list[Path]:
    return list(folder.rglob("*.nbi"))


def running(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, ended but not yet reaped, does not)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def test_a_memory_process_loads_the_kernels_from_the_benchmarks_folder(shared_cache, tmp_path):
    folder, numba_rule = shared_cache
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    np.savez(tmp_path / "mesh.npz", vertices=vertices, faces=np.array([[0, 1, 2]], np.int32))
    origins = np.array([[0.2, 0.2, 1.0]] * 300, np.float32)
    directions = np.array([[0.0, 0.0, -1.0]] * 300, np.float32)
    np.savez(tmp_path / "rays.npz", origins=origins, directions=directions)
    spec = {"family": "dacrt", "strategy": "sampling", "threads": 1, "kind": "primary"}
    spec |= {"query": "closest", "tmax": float("inf")}
    (out,) = measure_memory(
        [spec], str(tmp_path / "mesh.npz"), {"primary": str(tmp_path / "rays.npz")}
    )
    assert "error" not in out, out
    assert out["kernel_cache"] == str(folder)
    assert out["kernels_compiled"] == 0
    assert compiled_files(numba_rule) == []


def test_the_bound_server_loads_the_kernels_and_ends_with_its_parent(shared_cache, tmp_path):
    folder, numba_rule = shared_cache
    parent = textwrap.dedent(
        """
        import sys, time
        from bench.entry import use_kernel_cache
        from bench.http_overhead import start_server

        use_kernel_cache(sys.argv[1])
        process, url = start_server({}, ("bench.http_bound:app",))
        print(process.pid, flush=True)
        time.sleep(600)
        """
    )
    started = subprocess.Popen(
        [sys.executable, "-c", parent, str(folder)],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        server = int(started.stdout.readline())  # once its /health answers
        assert compiled_files(numba_rule) == []
    finally:
        started.kill()
        started.wait()
        started.stdout.close()
    deadline = time.monotonic() + 20
    while running(server) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not running(server), "the server outlived its parent"


def test_the_bound_server_ends_on_sigterm_while_its_kernels_compile(tmp_path):
    empty = tmp_path / "cache"
    command = [sys.executable, "-m", "uvicorn", "bench.http_bound:app", "--port", "0"]
    env = {**os.environ, "PYTHONPATH": str(REPO), "DACRT_CACHE_DIR": str(empty)}
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba")
    server = subprocess.Popen(command, cwd=REPO, env=env, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not compiled_files(empty) and time.monotonic() < deadline:  # compiling, in its start
            time.sleep(0.1)
        assert compiled_files(empty), "no kernel compiled into DACRT_CACHE_DIR"
        server.send_signal(signal.SIGTERM)
        assert server.wait(timeout=20) == -signal.SIGTERM
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()


def test_a_started_service_is_given_the_kernels_folder(shared_cache, monkeypatch):
    folder, _ = shared_cache
    seen = {}

    def popen(command, env, **kwargs):
        seen.update(env)
        raise SystemExit("not started")

    monkeypatch.setattr(subprocess, "Popen", popen)
    with pytest.raises(SystemExit):
        start_server({})
    assert seen["DACRT_CACHE_DIR"] == str(folder)


def test_dask_workers_load_the_kernels_from_the_benchmarks_folder(shared_cache):
    pytest.importorskip("distributed")
    folder, numba_rule = shared_cache
    local, client = bench_dask.cluster(1)
    try:
        (worker_folder,) = client.run(dacrt.cache.cache_dir).values()
    finally:
        client.close()
        local.close()
    assert Path(worker_folder) == folder
    assert compiled_files(numba_rule) == []


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_every_entry_point_files_the_kernels_through_bench_entry(name):
    tree = ast.parse((REPO / "bench" / f"{name}.py").read_text())
    called = {
        getattr(node.func, "attr", getattr(node.func, "id", None))
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
    }
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    imported |= {
        alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.Import)
        for alias in node.names
    }
    assert "use_cache_dir" not in called  # bench.entry's call, not one of its own
    if any(module and module.split(".")[0] == "dacrt" for module in imported):
        assert "use_kernel_cache" in called


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_help_gives_the_docstrings_whole_first_paragraph(name, monkeypatch, capsys):
    module = f"bench.{name}"
    doc = ast.get_docstring(ast.parse((REPO / "bench" / f"{name}.py").read_text()), clean=False)
    first = " ".join(doc.split("\n\n")[0].split())
    monkeypatch.setattr(sys, "argv", [module, "--help"])
    monkeypatch.delitem(sys.modules, module, raising=False)  # run as __main__, not the import
    with pytest.raises(SystemExit) as done:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    assert done.value.code == 0
    shown = capsys.readouterr().out
    assert "".join(first.split()) in "".join(shown.split())  # argparse wraps it, hyphens too
    assert first.endswith((".", ":", ")")), first
