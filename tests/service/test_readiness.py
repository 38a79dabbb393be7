"""Readiness: /health says ok only once every kernel a request reaches is compiled, and /v1
scene and query routes answer 503 with Retry-After before that."""

from __future__ import annotations

import json
import subprocess
import sys

import anyio
import httpx
import pytest
from service_helpers import REPO

from service.app import create_app
from service.settings import Settings


def get(app, path: str) -> httpx.Response:
    async def fetch():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://app") as client:
            return await client.get(path)

    return anyio.run(fetch)


@pytest.mark.parametrize("path", ["/v1/scenes", "/v1/scenes/demo", "/v1/scenes/demo/meshes/m"])
def test_scene_routes_are_503_with_retry_after_while_compiling(path):
    app = create_app(Settings(token=None, load_demo=False))
    response = get(app, path)
    assert response.status_code == 503 and response.headers["Retry-After"].isdigit()
    assert "compiling" in response.json()["detail"]
    app.state.readiness.status = "ok"
    assert get(app, path).status_code != 503


def test_a_caller_without_the_token_learns_nothing_of_a_failed_compile():
    app = create_app(Settings(token="s3cret", load_demo=False))
    app.state.readiness.status, app.state.readiness.error = "error", "ERR at /srv/cache/x.nbi"
    response = get(app, "/v1/scenes")
    assert response.status_code == 401 and "/srv/cache" not in response.text
    health = get(app, "/health")
    assert health.status_code == 503 and health.json()["status"] == "error"
    assert "/srv/cache" not in health.text


def test_operations_answer_while_compiling():
    app = create_app(Settings(token=None, load_demo=False))
    assert get(app, "/health").json()["status"] == "starting"
    assert get(app, "/v1/capabilities").status_code == 200


def test_no_kernel_compiles_for_the_first_requests_after_ready():
    probe = subprocess.run(
        [sys.executable, str(REPO / "tests" / "service" / "compile_probe.py")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert probe.returncode == 0, probe.stderr[-3000:]
    compiled_after_ready = json.loads(probe.stdout.strip().splitlines()[-1])
    assert compiled_after_ready == {}
