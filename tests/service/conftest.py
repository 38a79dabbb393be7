"""Fixtures of the service tests: the app in process (``app_client``, ``app_api``: most tests),
real servers (``python -m service``) and their clients, and small meshes.

Three servers start together once per session (Numba's first compile in a server takes about a
minute; later starts load the cache): ``server`` with default settings, ``secure_server`` with a
bearer token and tiny limits, and ``hostile_server`` for the hostile corpus, all configured
through DACRT_* environment variables.
"""

from __future__ import annotations

import re
import uuid

import httpx
import in_process
import numpy as np
import pytest
from server_process import ServerProcess
from service_helpers import HOSTILE_BODY_LIMIT, REPO, SECURE_LIMITS, TOKEN

from service.client import Client
from service.settings import Settings


@pytest.fixture(scope="session")
def teapot() -> tuple[np.ndarray, np.ndarray]:
    with np.load(REPO / "service" / "data" / "teapot.npz") as archive:
        return archive["vertices"], archive["faces"]


@pytest.fixture
def scene_name(request) -> str:
    """A scene name no other test uses."""
    return re.sub(r"[^A-Za-z0-9_.-]", "-", request.node.name)[:40] + "-" + uuid.uuid4().hex[:8]


# ---- the app in process


@pytest.fixture(scope="session")
def app_client():
    """An httpx client of one in-process app with default settings (no token, no demo)."""
    with in_process.serve(Settings(token=None, load_demo=False)) as client:
        yield client


@pytest.fixture
def app_api(app_client):
    """``service.client.Client`` over the in-process app."""
    return Client(http=app_client)


# ---- servers


@pytest.fixture(scope="session")
def _servers():
    """Start the servers at once so that their warm-ups overlap; stop them at the end."""
    processes = {
        "plain": ServerProcess({}),
        "secure": ServerProcess({"DACRT_TOKEN": TOKEN, **SECURE_LIMITS}),
        "hostile": ServerProcess({"DACRT_MAX_BODY_BYTES": HOSTILE_BODY_LIMIT}),
    }
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
