"""The server's warm-up (``service.warmup``): kernels missing from the cache compile in a child
process, whose lines the server's log shows, and the server loads them from the cache; where the
child cannot start or fails, the server compiles them itself and says why."""

from __future__ import annotations

import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import numba
import pytest
from server_process import ServerProcess
from service_helpers import REPO

import dacrt.cache
import dacrt.chunks
from service import warmup
from service.app import create_app, warm_up
from service.settings import Settings

#: What a child prints as ``service.logs`` formats it, then a line of its own.
PRINTS = (
    "import sys; print('INFO:     service: warm-up: compiling kernel 1 of about 49 (k), 1 s so "
    "far'); print('NumbaWarning: something'); "
)


@pytest.fixture
def cold(monkeypatch, tmp_path):
    """A process that has run no kernel, whose cache lacks them until the child has run: the
    engine's warm-up stands in as a check of the child's mark (``tmp_path / "compiled"``)."""
    mark = tmp_path / "compiled"
    loads = []

    def load(only_cached: bool = False) -> int:
        loads.append(only_cached)
        if only_cached and not mark.exists():
            raise warmup.NotCached("dacrt.traversal.trace")
        return 0 if mark.exists() else 49

    monkeypatch.setattr(warmup, "engine_has_run", lambda: False)
    monkeypatch.setattr(warmup, "load", load)
    return mark, loads


def child(monkeypatch, code: str) -> None:
    monkeypatch.setattr(warmup, "CHILD", [sys.executable, "-c", code])


def test_missing_kernels_compile_in_a_child_whose_lines_the_log_shows(cold, monkeypatch, caplog):
    mark, loads = cold
    child(monkeypatch, PRINTS + f"open({str(mark)!r}, 'w').close()")
    with caplog.at_level(logging.INFO, logger="service"):
        warmup.warm_up()
    assert loads == [True, True, False]  # tried, loaded what the child filed, checked
    lines = caplog.text.splitlines()
    started = next(line for line in lines if "compile in a child process" in line)
    assert "dacrt.traversal.trace is not in the cache" in started
    pid = started.split("pid ")[1].split(")")[0]
    relayed = [
        (r.levelname, r.getMessage())
        for r in caplog.records
        if r.getMessage().startswith(f"child {pid}: ")
    ]
    assert relayed == [
        ("INFO", f"child {pid}: warm-up: compiling kernel 1 of about 49 (k), 1 s so far"),
        ("WARNING", f"child {pid}: NumbaWarning: something"),
    ]
    assert "in this process instead" not in caplog.text
    assert "(0 kernels compiled)" in lines[-1]  # this process compiled none


@pytest.mark.parametrize(
    "code, why",
    [
        (PRINTS + "sys.exit(3)", "exited with status 3"),
        ("import os, signal; os.kill(os.getpid(), signal.SIGKILL)", "ended by signal 9"),
        ("pass", "dacrt.traversal.trace is still not in the cache after the child's compile"),
    ],
    ids=["fails", "killed", "files nothing"],
)
def test_a_failed_child_leaves_the_compile_to_the_server_which_says_why(
    cold, monkeypatch, caplog, code, why
):
    _, loads = cold
    child(monkeypatch, code)
    with caplog.at_level(logging.INFO, logger="service"):
        warmup.warm_up()
    assert loads[-1] is False  # the in-process compile
    instead = [r.getMessage() for r in caplog.records if "in this process instead" in r.msg]
    assert len(instead) == 1 and why in instead[0], caplog.text
    assert "(49 kernels compiled)" in caplog.text.splitlines()[-1]


def test_a_child_that_cannot_start_leaves_the_compile_to_the_server(cold, monkeypatch, caplog):
    monkeypatch.setattr(warmup, "CHILD", ["/nonexistent/python", "-m", "service.warmup"])
    with caplog.at_level(logging.INFO, logger="service"):
        warmup.warm_up()
    instead = [r.getMessage() for r in caplog.records if "in this process instead" in r.msg]
    assert (
        len(instead) == 1 and "/nonexistent/python -m service.warmup could not start" in instead[0]
    )


def test_a_compile_that_fails_after_the_child_is_reported_by_health(cold, monkeypatch):
    child(monkeypatch, "raise SystemExit(1)")
    monkeypatch.setattr(warmup, "report", lambda start, compiled: time.perf_counter() - start)

    def load(only_cached: bool = False) -> int:
        if only_cached:
            raise warmup.NotCached("dacrt.traversal.trace")
        raise RuntimeError("no compiler")

    monkeypatch.setattr(warmup, "load", load)
    app = create_app(Settings(token=None, load_demo=False))
    warm_up(app.state.readiness)
    assert app.state.readiness.status == "error" and "no compiler" in app.state.readiness.error


def warming_with_child(monkeypatch, pid_file: Path, code: str):
    """(app, its warm-up thread) once the child running ``code`` (which writes ``pid_file``)
    has written it."""
    child(monkeypatch, code)
    app = create_app(Settings(token=None, load_demo=False))
    thread = threading.Thread(target=warm_up, args=(app.state.readiness,))
    thread.start()
    deadline = time.monotonic() + 60
    while not pid_file.exists() or not pid_file.read_text():
        assert time.monotonic() < deadline
        time.sleep(0.1)
    return app, thread


def test_a_server_that_stops_ends_its_child(cold, monkeypatch, tmp_path):
    pid_file = tmp_path / "pid"
    app, thread = warming_with_child(
        monkeypatch,
        pid_file,
        f"import os, time; open({str(pid_file)!r}, 'w').write(str(os.getpid())); time.sleep(600)",
    )
    app.state.readiness.stopping.set()  # as the app's lifespan does when it ends
    thread.join(10)
    assert not thread.is_alive()
    assert app.state.readiness.status == "starting"
    assert not Path(f"/proc/{pid_file.read_text()}").exists()


def test_the_child_leaves_a_terminals_ctrl_c_to_the_server(cold, monkeypatch, tmp_path):
    """A terminal's Ctrl-C reaches the server's whole process group: the child ignores it (no
    traceback of an interrupted compile in the server's log), and ends when the server stops."""
    pid_file = tmp_path / "pid"
    app, thread = warming_with_child(
        monkeypatch,
        pid_file,
        "import os, signal, time; ignored = signal.getsignal(signal.SIGINT) == signal.SIG_IGN; "
        f"open({str(pid_file)!r}, 'w').write(f'{{os.getpid()}} {{ignored}}'); time.sleep(600)",
    )
    pid, ignored = pid_file.read_text().split()
    assert ignored == "True"
    os.kill(int(pid), signal.SIGINT)
    time.sleep(0.5)
    assert alive(int(pid)) and thread.is_alive()
    app.state.readiness.stopping.set()
    thread.join(10)
    assert not thread.is_alive() and not alive(int(pid))


def test_loading_only_from_the_cache_stops_before_a_compile():
    def plus_one(x):
        return x + 1

    plus_one.__module__ = "dacrt.example"  # one of dacrt's kernels, as the refusal sees it
    kernel = numba.njit(plus_one)
    with warmup.refusing_compiles():
        with pytest.raises(warmup.NotCached, match=r"^dacrt\.example\..*plus_one$"):
            kernel(1)
    assert kernel.signatures == []  # nothing compiled
    assert kernel(1) == 2


def dacrt_kernel(name: str) -> numba.core.registry.CPUDispatcher:
    """A fresh kernel, not yet compiled, that the refusal takes for one of dacrt's."""

    def plus_one(x):
        return x + 1

    plus_one.__module__, plus_one.__qualname__ = "dacrt.example", name
    return numba.njit(plus_one)


def test_loading_only_from_the_cache_refuses_its_own_compiles_only(monkeypatch):
    """Numba's listeners are the whole process's: while the warm-up loads from the cache, another
    thread's first query (an app that embeds the service) compiles; the warm-up's own compiles,
    in its thread and in dacrt's pool threads on its behalf, do not."""
    others, pooled, own = dacrt_kernel("others"), dacrt_kernel("pooled"), dacrt_kernel("own")
    answers = []

    def query() -> None:
        try:
            answers.append(others(1))
        except warmup.NotCached as refused:
            answers.append(refused)

    def engine_warmup() -> None:  # dacrt.warmup, in the warm-up's thread
        other = threading.Thread(target=query)
        other.start()
        other.join()
        caller, pool_ran = threading.current_thread(), threading.Event()

        def item(k: int) -> int | None:
            if threading.current_thread() is caller:  # leaves the compile to a pool thread
                assert pool_ran.wait(30)
                return None
            try:
                return pooled(k)
            finally:
                pool_ran.set()

        with pytest.raises(warmup.NotCached, match=r"^dacrt\.example\.pooled$"):
            dacrt.chunks.map_on_threads(item, 2, 2)
        own(1)

    monkeypatch.setattr(dacrt, "warmup", engine_warmup)
    with pytest.raises(warmup.NotCached, match=r"^dacrt\.example\.own$"):
        warmup.load(only_cached=True)
    assert answers == [2], answers
    assert pooled.signatures == own.signatures == []  # refused before they compiled


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs: it exists and is not a zombie awaiting its reaper."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_server_killed_outright_takes_its_child_with_it(tmp_path):
    """A server killed with SIGKILL runs no clean-up: the child it started to compile the
    kernels (here one that sleeps) ends with it rather than compile on for minutes."""
    pid_file = tmp_path / "pid"
    sleeper = f"import os, time; open({str(pid_file)!r}, 'w').write(str(os.getpid())); "
    sleeper += "time.sleep(600)"
    server = (  # compile_in_child in a thread of its own, as the server's warm-up runs it
        "import sys, threading; from service import warmup; "
        f"warmup.CHILD = [sys.executable, '-c', {sleeper!r}]; "
        "threading.Thread(target=warmup.compile_in_child, args=('dacrt.example',)).start()"
    )
    pythonpath = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    parent = subprocess.Popen(
        [sys.executable, "-c", server], cwd=REPO, env={**os.environ, "PYTHONPATH": pythonpath}
    )
    child = None
    try:
        deadline = time.monotonic() + 60
        while not pid_file.exists() or not pid_file.read_text():
            assert parent.poll() is None and time.monotonic() < deadline, parent.returncode
            time.sleep(0.1)
        child = int(pid_file.read_text())
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 5
        while alive(child) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not alive(child), f"child {child} runs on after its server was killed"
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        if child is not None and alive(child):
            os.kill(child, signal.SIGKILL)


#: Seconds for a server to start when one kernel compiles (2 cores busy with other work).
START_SECONDS = 600
GiB = 2**30
#: The kernel the test below takes out of the cache: small, and reached by every warm-up.
MISSING = "chunks.slab_ids"


def vm(pid: int, name: str) -> int:
    """``VmHWM`` (peak) or ``VmRSS`` of process ``pid``, in bytes."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(name + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(name)


def test_a_kernel_missing_from_the_cache_compiles_in_a_child_and_the_server_compiles_none(
    tmp_path,
):
    """A copy of the warm cache less one kernel's files: /health goes to ok, that kernel
    compiles in a child (which keeps the compiler's memory: about 3 GB for all of them, measured
    in docs/limits.md), and the server loads every kernel from the cache, compiling none; a
    query then answers."""
    warm = dacrt.cache.kernels_folder()
    if not warm.is_dir():
        pytest.skip(f"no warm kernel cache at {warm} (python -m service.warmup fills it)")
    cache = tmp_path / "cache"
    shutil.copytree(warm, cache / warm.name)
    taken = list((cache / warm.name).rglob(f"{MISSING}-*"))
    assert taken, f"no cached files of {MISSING} in {warm}"
    for path in taken:
        path.unlink()
    server = ServerProcess({"DACRT_CACHE_DIR": str(cache)})
    statuses = []
    try:
        deadline = time.monotonic() + START_SECONDS
        while statuses[-1:] != ["ok"]:
            assert server.process.poll() is None and time.monotonic() < deadline, server.output()
            try:
                status = httpx.get(f"{server.url}/health", timeout=5).json()["status"]
            except (httpx.HTTPError, ValueError):  # not listening yet
                status = None
            if status is not None and statuses[-1:] != [status]:
                statuses.append(status)
            time.sleep(0.2)
        vertices, faces = [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]
        rays = {"origins": [[0.2, 0.2, 1]], "directions": [[0, 0, -1]]}
        answer = httpx.post(
            f"{server.url}/v1/trace?query=closest",
            json={"vertices": vertices, "faces": faces, **rays},
            timeout=60,
        )
        peak = vm(server.process.pid, "VmHWM")
        output = server.output(last=10**8)
    finally:
        server.stop()
    assert set(statuses) <= {"starting", "ok"} and statuses[-1] == "ok", statuses
    assert answer.status_code == 200 and answer.json()["t"] == [1.0], answer.text
    assert peak < GiB, peak
    assert list((cache / warm.name).rglob(f"{MISSING}-*")), "the child filed nothing"
    lines = output.splitlines()
    assert any("the kernels compile in a child process" in line for line in lines), output
    assert any(MISSING in line for line in lines if "is not in the cache" in line), output
    compiled = [line for line in lines if "kernels compiled)" in line]
    assert any(" child " in line and "(0 kernels compiled)" not in line for line in compiled)
    ours = [line for line in compiled if " child " not in line]
    assert len(ours) == 1 and "(0 kernels compiled)" in ours[0], compiled  # loaded, not compiled
    assert "in this process instead" not in output
