"""The app in-process: health before and after warm-up, the demo scene, the error shape."""

from __future__ import annotations

import logging
import os
import re

import anyio
import httpx
import pytest
from server_process import ServerProcess
from service_helpers import quad

from service import app as app_module
from service.app import create_app, load_demo, warm_up
from service.settings import Settings
from service.store import Store
from service.wire import MeshArrays


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
    monkeypatch.setattr(app_module.warmup, "warm_up", lambda stopping: 0.0)
    warm_up(app.state.readiness)
    response = get(app, "/health")
    assert response.status_code == 200 and response.json()["status"] == "ok"


def test_failed_warm_up_is_reported_by_health(monkeypatch, caplog):
    def broken(stopping):
        raise RuntimeError("no compiler")

    app = create_app(plain())
    monkeypatch.setattr(app_module.warmup, "warm_up", broken)
    warm_up(app.state.readiness)
    body = get(app, "/health").json()
    assert body["status"] == "error" and "no compiler" in body["detail"]


def test_demo_scene_is_loaded_from_scenes():
    store = Store(2**30, 2**40)
    load_demo(store, Settings(load_demo=True))
    info = store.snapshot("demo").info()
    assert [m["mesh"] for m in info["meshes"]] == ["teapot"] and info["triangles"] == 6320


def test_a_demo_scene_over_the_limits_is_a_warning_not_a_failed_start(caplog, tmp_path):
    """The service works without its demo: a demo over DACRT_MAX_TRIANGLES_PER_SCENE, or a
    damaged demo file, is named in the log and the start goes on."""
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"PK not a zip")
    for store, settings, words in (
        (Store(1000, 2**40), Settings(load_demo=True), "over the limit of 1000"),
        (Store(2**30, 2**40), Settings(load_demo=True, demo_scene=broken), "ValueError"),
    ):
        with caplog.at_level(logging.WARNING, logger="service"):
            load_demo(store, settings)
        assert store.snapshots() == []
        assert "no demo scene" in caplog.text and words in caplog.text
        assert "DACRT_LOAD_DEMO=false starts without it" in caplog.text
        caplog.clear()


@pytest.mark.parametrize("path, status", [("/nowhere", 404), ("/v1/scenes/x", 404)])
def test_errors_are_json_detail_strings(path, status):
    app = create_app(plain())
    app.state.readiness.status = "ok"
    response = get(app, path)
    assert response.status_code == status and isinstance(response.json()["detail"], str)


def test_a_restored_demo_scene_is_kept(tmp_path):
    store = Store(2**30, 2**40)
    vertices, faces = quad(0, 1, 0, 1, 0)
    store.put_mesh("demo", "mine", MeshArrays(vertices, faces))
    load_demo(store, Settings(load_demo=True))
    assert list(store.snapshot("demo").meshes) == ["mine"]


def test_the_start_page_links_to_the_docs():
    response = get(create_app(plain()), "/")
    assert response.status_code == 200 and response.headers["content-type"].startswith("text/html")
    assert 'href="/docs"' in response.text


def test_docs_are_served_without_the_network():
    app = create_app(plain())
    page = get(app, "/docs").text
    assets = re.findall(r"(?:src|href)=['\"]([^'\"]+)['\"]", page)
    assert assets and all(url.startswith("/static/") for url in assets), assets
    for url in assets:
        response = get(app, url)
        assert response.status_code == 200 and len(response.content) > 100, url


def test_capabilities_show_the_thread_count():
    app = create_app(plain())
    assert get(app, "/v1/capabilities").json()["threads"] == os.cpu_count()
    app = create_app(Settings(token=None, load_demo=False, threads=3))
    assert get(app, "/v1/capabilities").json()["threads"] == 3


def test_the_factory_logs_as_python_m_service_does():
    """Under ``uvicorn --factory`` only uvicorn's loggers have handlers of their own."""
    server = ServerProcess(
        {"DACRT_LOAD_DEMO": "true"},
        command=["uvicorn", "service.app:create_app", "--factory", "--port", "{port}"],
    )
    try:
        server.wait_ready()
        output = server.output()
    finally:
        server.stop()
    assert "INFO:     service: demo scene 'demo'" in output
    assert "INFO:     service: engine ready after" in output
    assert "INFO:     service: warm-up: the engine's kernels (dacrt.warmup) ready after" in output
