"""The app in-process: health before and after warm-up, the demo scene, the error shape."""

from __future__ import annotations

import anyio
import httpx
import pytest

from service import app as app_module
from service.app import create_app, load_demo, warm_up
from service.settings import Settings
from service.store import Store


def plain() -> Settings:
    """Settings whatever DACRT_* the test run has: no token, no demo."""
    return Settings(token=None, load_demo=False)


def get(app, path: str) -> httpx.Response:
    async def fetch():
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://app") as client:
            return await client.get(path)

    return anyio.run(fetch)


def test_health_is_503_starting_until_warm_up_returns(monkeypatch):
    app = create_app(plain())
    response = get(app, "/health")
    assert response.status_code == 503 and response.json()["status"] == "starting"
    monkeypatch.setattr(app_module.tracing, "warmup", lambda: 0.0)
    warm_up(app.state.readiness)
    response = get(app, "/health")
    assert response.status_code == 200 and response.json()["status"] == "ok"


def test_failed_warm_up_is_reported_by_health(monkeypatch, caplog):
    def broken():
        raise RuntimeError("no compiler")

    app = create_app(plain())
    monkeypatch.setattr(app_module.tracing, "warmup", broken)
    warm_up(app.state.readiness)
    body = get(app, "/health").json()
    assert body["status"] == "error" and "no compiler" in body["detail"]


def test_demo_scene_is_loaded_from_scenes():
    store = Store(2**30, 2**40)
    load_demo(store, Settings(load_demo=True))
    info = store.snapshot("demo").info()
    assert [m["mesh"] for m in info["meshes"]] == ["teapot"] and info["triangles"] == 6320


@pytest.mark.parametrize("path, status", [("/nowhere", 404), ("/v1/scenes/x", 404)])
def test_errors_are_json_detail_strings(path, status):
    response = get(create_app(plain()), path)
    assert response.status_code == status and isinstance(response.json()["detail"], str)
