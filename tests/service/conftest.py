"""Fixtures of the service tests: real uvicorn servers, clients, and small meshes.

Three servers start together once per session (Numba's first compile in a server takes about a
minute; later starts load the cache): ``server`` with default settings, ``secure_server`` with a
bearer token and tiny limits, and ``hostile_server`` for the hostile corpus, all configured
through DACRT_* environment variables.
"""
from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import tempfile
import time
import uuid

import httpx
import numpy as np
import pytest

from service.client import Client
from service_helpers import HOSTILE_BODY_LIMIT, REPO, SECURE_LIMITS, TOKEN

STARTUP_SECONDS = 180


@pytest.fixture(scope="session")
def teapot() -> tuple[np.ndarray, np.ndarray]:
    with np.load(REPO / "scenes" / "teapot.npz") as archive:
        return archive["vertices"], archive["faces"]


@pytest.fixture
def scene_name(request) -> str:
    """A scene name no other test uses."""
    return re.sub(r"[^A-Za-z0-9_.-]", "-", request.node.name)[:40] + "-" + uuid.uuid4().hex[:8]


# ---- servers


class ServerProcess:
    """``python -m uvicorn service.app:create_app --factory`` on a free loopback port."""

    def __init__(self, env: dict[str, str]) -> None:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = tempfile.TemporaryFile()
        # settings come only from ``env``, whatever DACRT_* the test run itself has
        inherited = {k: v for k, v in os.environ.items() if not k.startswith("DACRT_")}
        pythonpath = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
        self.process = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "service.app:create_app", "--factory",
             "--host", "127.0.0.1", "--port", str(self.port), "--log-level", "warning",
             "--timeout-graceful-shutdown", "5"],
            cwd=REPO, env={**inherited, "PYTHONPATH": pythonpath, **env},
            stdout=self.log, stderr=subprocess.STDOUT)

    def output(self) -> str:
        self.log.seek(0)
        return self.log.read().decode(errors="replace")[-4000:]

    def wait_ready(self) -> str:
        """Wait until /health says ok; fail with the server's output if it dies or times out."""
        deadline = time.monotonic() + STARTUP_SECONDS
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                pytest.fail(f"server exited with {self.process.returncode}:\n{self.output()}")
            try:
                if httpx.get(f"{self.url}/health", timeout=2).json().get("status") == "ok":
                    return self.url
            except (httpx.HTTPError, ValueError):
                pass
            time.sleep(0.25)
        pytest.fail(f"server not ready after {STARTUP_SECONDS} s:\n{self.output()}")

    def stop(self) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        self.log.close()


@pytest.fixture(scope="session")
def _servers():
    """Start both servers at once so their warm-ups overlap; stop them at the end."""
    processes = {"plain": ServerProcess({}),
                 "secure": ServerProcess({"DACRT_TOKEN": TOKEN, **SECURE_LIMITS}),
                 "hostile": ServerProcess({"DACRT_MAX_BODY_BYTES": HOSTILE_BODY_LIMIT})}
    yield processes
    for process in processes.values():
        process.stop()


@pytest.fixture(scope="session")
def server(_servers) -> str:
    """Base URL of a server with default settings."""
    return _servers["plain"].wait_ready()


@pytest.fixture(scope="session")
def secure_server(_servers) -> str:
    """Base URL of a server with DACRT_TOKEN and tiny limits (SECURE_LIMITS)."""
    return _servers["secure"].wait_ready()


@pytest.fixture(scope="session")
def hostile_server(_servers) -> ServerProcess:
    """A server of its own for the hostile corpus, whose memory is measured (4 MiB bodies)."""
    _servers["hostile"].wait_ready()
    return _servers["hostile"]


@pytest.fixture
def client(server):
    with Client(server) as c:
        yield c


@pytest.fixture
def http(server):
    """A plain httpx client for raw requests (headers, bodies, statuses)."""
    with httpx.Client(base_url=server, timeout=120) as c:
        yield c
