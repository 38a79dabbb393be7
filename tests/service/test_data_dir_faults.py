"""A data folder (DACRT_DATA_DIR) that is full, read-only or failing, over HTTP: every write
answers 507 (full) or 503 naming the folder and the OS error and changes nothing, reads go on,
/health says degraded (its details only with the token) and /metrics counts it; writes resume
when space returns, no temporary file is left, a restart loses nothing acknowledged, and a folder
that cannot be written at start ends the process with one line. A scene whose manifest breaks
what a change is checked for is skipped at start, and the other scenes are served.

In process the faults are injected where the folder writes its files (``faults``); against a real
server (``python -m service``) the folder is a tiny tmpfs, filled or remounted read-only, where
mounting is permitted.
"""

from __future__ import annotations

import errno
import io
import json
import os
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import anyio
import httpx
import in_process
import numpy as np
import pytest
from faults import fail_in_write, temporary_files
from server_process import ServerProcess
from service_helpers import NPY, NPZ, TOKEN, down_rays, grid, npy_bytes, npz_bytes

from service import app as app_module
from service.app import open_data_dir
from service.settings import Settings

AUTH = {"Authorization": f"Bearer {TOKEN}"}
WRONG_TOKEN = {"Authorization": "Bearer wrong"}
SHIFT = [[1, 0, 0, 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]  #: +1 along x
PUBLIC_HEALTH = {"status", "service", "scenes", "warmup_seconds"}


def mesh_body(n: int) -> dict:
    vertices, faces = grid(n)
    return {"content": npz_bytes(vertices=vertices, faces=faces), "headers": NPZ}


#: Each kind of write, as (method, path, keyword arguments of httpx's request), on a scene "s"
#: holding the mesh "a" of ``grid(4)``.
WRITES: dict[str, tuple[str, str, dict]] = {
    "upload": ("PUT", "/v1/scenes/s/meshes/b", mesh_body(3)),
    "new scene": ("PUT", "/v1/scenes/t/meshes/a", mesh_body(3)),
    "vertices": (
        "PUT",
        "/v1/scenes/s/meshes/a/vertices",
        {"content": npy_bytes(grid(4, z=1.0)[0]), "headers": NPY},
    ),
    "transform": ("PUT", "/v1/scenes/s/meshes/a/transform", {"json": {"matrix": SHIFT}}),
    "mask": ("PUT", "/v1/scenes/s/meshes/a/mask", {"json": {"mask": 7}}),
    "frame": ("POST", "/v1/scenes/s/frame", {"json": {"a.vertices": grid(4, z=2.0)[0].tolist()}}),
    "delete mesh": ("DELETE", "/v1/scenes/s/meshes/a", {}),
    "delete scene": ("DELETE", "/v1/scenes/s", {}),
}


def upload(http: httpx.Client, scene: str, mesh: str, n: int = 4) -> None:
    response = http.put(f"/v1/scenes/{scene}/meshes/{mesh}", **mesh_body(n))
    assert response.status_code in (200, 201), response.text


def metric(text: str, name: str) -> float | None:
    """The value of the sample ``name`` (with its labels) in Prometheus text, or None."""
    for line in text.splitlines():
        if line.startswith(name + " "):
            return float(line.split()[-1])
    return None


def assert_public(body: dict) -> None:
    """A /health body without the token: status only, nothing naming a path or an error."""
    assert set(body) <= PUBLIC_HEALTH, body
    text = repr(body)
    assert "Errno" not in text and "/" not in text, body


# ---- in process


@contextmanager
def serving(data: Path, monkeypatch, **settings) -> Iterator[httpx.Client]:
    """The app in process over the data folder ``data``, with the token; its warm-up compiles
    nothing (these tests trace no rays)."""
    monkeypatch.setattr(app_module.warmup, "warm_up", lambda *args, **kwargs: 0.0)
    values = {"token": TOKEN, "load_demo": False, "data_dir": data, **settings}
    with in_process.serve(Settings(**values)) as http:
        http.headers.update(AUTH)
        yield http


@pytest.mark.parametrize("write", WRITES.values(), ids=WRITES.keys())
def test_a_write_on_a_full_disk_is_507_and_changes_nothing_until_space_returns(
    tmp_path, monkeypatch, write
):
    data = tmp_path / "data"
    method, path, request = write
    with serving(data, monkeypatch) as http:
        upload(http, "s", "a")
        scenes = http.get("/v1/scenes").json()
        with monkeypatch.context() as full:
            fail_in_write(full, errno.ENOSPC)
            refused = http.request(method, path, **request)
            assert refused.status_code == 507, refused.text
            assert refused.json()["detail"] == (
                f"the data folder {data} (DACRT_DATA_DIR) cannot be written: "
                "[Errno 28] No space left on device; nothing was changed"
            )
            assert http.get("/v1/scenes").json() == scenes  # same versions: reads go on
            assert temporary_files(data) == []
            health = http.get("/health")
            assert health.status_code == 200 and health.json()["status"] == "degraded"
            assert health.json()["data_dir"] == {
                "status": "unwritable",
                "path": str(data),
                "errno": "ENOSPC",
                "detail": refused.json()["detail"],
            }
            public = http.get("/health", headers=WRONG_TOKEN)
            assert public.json()["status"] == "degraded"
            assert_public(public.json())
            metrics = http.get("/metrics").text
            assert metric(metrics, 'dacrt_data_dir_errors_total{errno="ENOSPC"}') == 1
            assert metric(metrics, "dacrt_data_dir_writable") == 0
        done = http.request(method, path, **request)  # space is back
        assert done.status_code < 300, done.text
        assert http.get("/health").json()["status"] == "ok"
        assert metric(http.get("/metrics").text, "dacrt_data_dir_writable") == 1
        acknowledged = http.get("/v1/scenes").json()
    with serving(data, monkeypatch) as http:  # a restart
        assert http.get("/v1/scenes").json() == acknowledged
    assert temporary_files(data) == []


@pytest.mark.parametrize(
    "code, status",
    [(errno.ENOSPC, 507), (errno.EDQUOT, 507), (errno.EROFS, 503), (errno.EIO, 503)],
)
def test_the_status_says_full_or_unwritable(tmp_path, monkeypatch, code, status):
    with serving(tmp_path / "data", monkeypatch) as http:
        fail_in_write(monkeypatch, code)
        refused = http.put("/v1/scenes/s/meshes/a/mask", json={"mask": 1})
        assert refused.status_code == 404  # no change is tried on what does not exist
        refused = http.put("/v1/scenes/s/meshes/a", **mesh_body(2))
        assert refused.status_code == status
        assert f"[Errno {code}] {os.strerror(code)}" in refused.json()["detail"]
        assert http.get("/v1/scenes").json() == {"scenes": []}
        errors = http.get("/metrics").text
        assert (
            metric(errors, f'dacrt_data_dir_errors_total{{errno="{errno.errorcode[code]}"}}') == 1
        )


def health(app, headers: dict[str, str] | None = None) -> httpx.Response:
    """GET /health of an app whose lifespan is not run (nothing started, nothing restored)."""
    transport = httpx.ASGITransport(app=app)

    async def fetch() -> httpx.Response:
        async with httpx.AsyncClient(transport=transport, base_url="http://app") as client:
            return await client.get("/health", headers=headers)

    return anyio.run(fetch)


@pytest.mark.parametrize(
    "headers",
    [None, WRONG_TOKEN, {"Authorization": "Basic " + TOKEN}],
    ids=["no token", "wrong token", "not bearer"],
)
def test_health_shows_details_only_with_the_token(tmp_path, headers):
    settings = Settings(
        token=TOKEN,
        load_demo=False,
        data_dir=tmp_path / "data",
        dask_scheduler="tcp://127.0.0.1:9",
    )
    app = app_module.create_app(settings)
    app.state.readiness.status = "ok"
    public = health(app, headers)
    assert public.status_code == 200 and public.json()["status"] == "degraded"  # the cluster
    assert_public(public.json())
    assert "127.0.0.1" not in public.text and "tcp:" not in public.text
    full = health(app, AUTH).json()
    assert full["cluster"]["scheduler"] == "tcp://127.0.0.1:9"
    assert full["data_dir"] == {"status": "ok", "path": str(tmp_path / "data")}
    app.state.readiness.status, app.state.readiness.error = "error", "no compiler in /opt/llvm"
    public = health(app, headers)
    assert public.status_code == 503 and public.json()["status"] == "error"
    assert_public(public.json())
    assert health(app, AUTH).json()["detail"] == "no compiler in /opt/llvm"


def test_health_shows_details_to_everyone_without_a_token(tmp_path):
    app = app_module.create_app(Settings(token=None, load_demo=False, data_dir=tmp_path))
    app.state.readiness.status = "ok"
    assert health(app).json()["data_dir"] == {"status": "ok", "path": str(tmp_path)}


@pytest.mark.parametrize("code", [errno.EROFS, errno.EACCES, errno.EIO])
def test_a_folder_that_cannot_be_written_ends_the_start_with_one_line(tmp_path, monkeypatch, code):
    fail_in_write(monkeypatch, code)
    with pytest.raises(SystemExit) as exited:
        open_data_dir(Settings(data_dir=tmp_path / "data"))
    message = str(exited.value)
    assert message.startswith(
        f"dacrt-service: DACRT_DATA_DIR={str(tmp_path / 'data')!r}: the data folder cannot be "
        f"written: [Errno {code}] {os.strerror(code)}"
    )
    assert "\n" not in message


def test_a_full_folder_at_start_serves_reads_and_says_degraded(tmp_path, monkeypatch):
    data = tmp_path / "data"
    with serving(data, monkeypatch) as http:
        upload(http, "s", "a")
    fail_in_write(monkeypatch, errno.ENOSPC)
    with serving(data, monkeypatch) as http:
        assert http.get("/v1/scenes/s").json()["version"] == 1
        assert http.get("/health").json()["data_dir"]["errno"] == "ENOSPC"
        assert http.put("/v1/scenes/s/meshes/a/mask", json={"mask": 1}).status_code == 507


def end_rows(count: int) -> list[list[float]]:
    """End vertices as a manifest once held them, rows of numbers."""
    return [[0.5, 0.5, 1.0]] * count


#: Edits of scene "s"'s manifest entries (by mesh name) and record that the API would refuse
#: as a change: "def" is a deforming grid(4), "inst" an instance of grid(4) "ball".
BROKEN_MANIFESTS = {
    "end rows fewer than the faces use": lambda m, r: m["def"].update(vertices_end=end_rows(5)),
    "instance_of null": lambda m, r: m["inst"].update(instance_of=None),
    "an instance deforming": lambda m, r: m["inst"].update(vertices_end=end_rows(25)),
    "a mesh index past int32": lambda m, r: (
        m["inst"].update(index=2**31),
        r.update(next_index=2**31 + 1),
    ),
}


@pytest.mark.parametrize("edit", BROKEN_MANIFESTS.values(), ids=BROKEN_MANIFESTS.keys())
def test_a_scene_whose_manifest_a_change_would_break_is_skipped_at_start(
    tmp_path, monkeypatch, caplog, edit
):
    data = tmp_path / "data"
    with serving(data, monkeypatch) as http:
        upload(http, "s", "ball")
        upload(http, "s", "def")
        frame = {"def.vertices_end": (grid(4)[0] + [0, 0, 1]).tolist()}
        assert http.post("/v1/scenes/s/frame", json=frame).status_code == 200
        instance = {"instance_of": "ball", "transform": SHIFT}
        assert http.put("/v1/scenes/s/meshes/inst", json=instance).status_code == 201
        upload(http, "other", "m")
    [path] = (data / "scenes" / "s").glob("scene.*.json")
    record = json.loads(path.read_bytes())
    edit({item["name"]: item for item in record["meshes"]}, record)
    path.write_text(json.dumps(record))
    with caplog.at_level("ERROR", logger="service"), serving(data, monkeypatch) as http:
        assert http.get("/health").json()["status"] == "ok"
        assert http.get("/v1/scenes/other").json()["version"] == 1
        response = http.post("/v1/scenes/s/closest", content=RAYS, headers=NPY)
        assert response.status_code == 404, response.text
        assert http.put("/v1/scenes/s/meshes/a", **mesh_body(2)).json()["version"] == 5
    assert f"data: skipped scene 's' (version 4): {path.name}" in caplog.text


# ---- a real server over a tiny tmpfs


@pytest.fixture
def small_disk(tmp_path) -> Iterator[Path]:
    """A 2 MiB tmpfs, mounted for the test (skipped where mounting is not permitted)."""
    mount = tmp_path / "disk"
    mount.mkdir()
    try:
        done = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)],
            capture_output=True,
            text=True,
        )
    except FileNotFoundError:
        pytest.skip("no mount command: the real-server variant needs a tmpfs it can fill")
    if done.returncode:
        pytest.skip(
            f"cannot mount a tmpfs here ({done.stderr.strip()}): the real-server variant needs "
            "root or CAP_SYS_ADMIN; the in-process tests inject the same faults"
        )
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(disk: Path, leave: int = 0) -> Path:
    """Write a file until the disk is full, then give ``leave`` bytes back; answers the file
    (remove it to give the space back)."""
    filler = disk / "filler"
    with open(filler, "wb", buffering=0) as file:  # unbuffered: close has nothing to flush
        try:
            while True:
                file.write(b"\0" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
    os.truncate(filler, max(0, filler.stat().st_size - leave))
    return filler


def remount(disk: Path, options: str) -> None:
    subprocess.run(["mount", "-o", f"remount,{options}", str(disk)], check=True)


def wait_for(check: Callable[[], bool], seconds: float) -> None:
    deadline = time.monotonic() + seconds
    while not check():
        assert time.monotonic() < deadline, f"not done after {seconds} s"
        time.sleep(0.05)


RAYS = npy_bytes(np.hstack(down_rays(np.random.default_rng(2).uniform(0, 1, (32, 2)))))


def closest(http: httpx.Client) -> dict[str, np.ndarray]:
    response = http.post("/v1/scenes/s/closest", content=RAYS, headers=NPY)
    assert response.status_code == 200, response.text
    with np.load(io.BytesIO(response.content)) as archive:
        return dict(archive)


FULL_DETAIL = "cannot be written: [Errno 28] No space left on device; nothing was changed"


def test_a_real_server_on_a_full_then_read_only_disk(small_disk):
    stack = ExitStack()  # closes the first server's client
    data = small_disk / "data"
    env = {"DACRT_DATA_DIR": str(data), "DACRT_TOKEN": TOKEN}
    first = ServerProcess(env)
    try:
        http = httpx.Client(base_url=first.wait_ready(), headers=AUTH, timeout=30)
        stack.callback(http.close)
        upload(http, "s", "a")
        answer, scenes = closest(http), http.get("/v1/scenes").json()
        filler = fill(small_disk)
        for method, path, request in WRITES.values():
            refused = http.request(method, path, **request)
            assert refused.status_code == 507, (path, refused.text)
            assert refused.json()["detail"] == f"the data folder {data} (DACRT_DATA_DIR) " + (
                FULL_DETAIL
            )
        filler = fill(small_disk, leave=256 * 1024)  # a mesh of 1.4 MB fails half-written
        big = http.put("/v1/scenes/s/meshes/big", **mesh_body(200))
        assert big.status_code == 507, big.text
        assert http.get("/v1/scenes").json() == scenes
        assert closest(http).keys() == answer.keys()
        for key, values in closest(http).items():
            np.testing.assert_array_equal(values, answer[key])
        assert temporary_files(data) == []
        assert http.get("/health").json()["data_dir"]["errno"] == "ENOSPC"
        public = httpx.get(f"{first.url}/health").json()
        assert public["status"] == "degraded"
        assert_public(public)
        metrics = http.get("/metrics").text
        assert metric(metrics, 'dacrt_data_dir_errors_total{errno="ENOSPC"}') == len(WRITES) + 1
        assert metric(metrics, "dacrt_data_dir_writable") == 0
        filler.unlink()  # space is back
        upload(http, "s", "b")
        assert http.get("/health").json()["status"] == "ok"
        acknowledged = http.get("/v1/scenes").json()
        remount(small_disk, "ro")
        refused = http.put("/v1/scenes/s/meshes/a/mask", json={"mask": 1})
        assert refused.status_code == 503
        assert "[Errno 30] Read-only file system; nothing was changed" in refused.json()["detail"]
        assert http.get("/health").json()["data_dir"]["errno"] == "EROFS"
        first.kill()
    finally:
        stack.close()
        first.stop()

    second = ServerProcess(env)  # on the read-only disk: refused in one line
    try:
        wait_for(lambda: second.process.poll() is not None, 120)
        lines = second.output().strip().splitlines()
        assert second.process.returncode != 0
        assert lines[-1].startswith(
            f"dacrt-service: DACRT_DATA_DIR={str(data)!r}: the data folder cannot be written: "
            "[Errno 30] Read-only file system"
        ), lines
    finally:
        second.stop()

    remount(small_disk, "rw")
    third = ServerProcess(env)
    try:
        with httpx.Client(base_url=third.wait_ready(), headers=AUTH, timeout=30) as http:
            assert http.get("/v1/scenes").json() == acknowledged
        assert temporary_files(data) == []
    finally:
        third.stop()
