"""The service with DACRT_DASK_SCHEDULER: large queries traced on a LocalCluster (2 worker
processes, 1 thread each) give the in-process answers; small ones stay in process; a new scene
version replaces the old one on the workers; an unreachable scheduler means in-process answers
and a degraded /health. A scheduler or worker that stops answering with its connections open
(SIGSTOP) costs a query DACRT_DASK_TIMEOUT at most, and /health none of it."""

from __future__ import annotations

import os
import signal
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import httpx
import in_process
import numpy as np
import pytest
import reference
from server_process import ServerProcess
from service_helpers import grid

import dacrt
from service.client import Client
from service.settings import Settings, SettingsError, load_settings

distributed = pytest.importorskip("distributed")

from clusters import ProcessCluster, two_worker_cluster  # noqa: E402

MIN_RAYS = 2000


@pytest.fixture(scope="module")
def cluster():
    cluster = two_worker_cluster()
    yield cluster
    cluster.close()


@pytest.fixture(scope="module")
def api(cluster):
    settings = Settings(
        token=None,
        load_demo=False,
        dask_scheduler=cluster.scheduler_address,
        dask_min_rays=MIN_RAYS,
    )
    with in_process.serve(settings) as http:
        deadline = time.monotonic() + 30  # the connection to the scheduler is made in background
        while http.get("/health").json()["status"] != "ok" and time.monotonic() < deadline:
            time.sleep(0.1)
        yield Client(http=http)


@pytest.fixture(scope="module")
def workers(cluster):
    """A client of the cluster of its own, to look into the workers."""
    with distributed.Client(cluster) as client:
        yield client


def held_scenes(workers) -> set[str]:
    """The keys of the Scenes built on the workers."""
    held = workers.run(lambda: sorted(__import__("dacrt.distributed").distributed._SCENES))
    return {key for keys in held.values() for key in keys}


def rays(n, seed, z=5.0):
    rng = np.random.default_rng(seed)
    origins = np.column_stack([rng.uniform(-0.2, 1.2, (n, 2)), np.full(n, z)]).astype(np.float32)
    directions = np.column_stack([rng.uniform(-0.02, 0.02, (n, 2)), -np.ones(n)]).astype(np.float32)
    return origins, directions


def test_health_and_capabilities_show_the_cluster(api):
    health = api.http.get("/health").json()
    assert health["status"] == "ok"
    assert health["cluster"]["status"] == "ok"
    assert health["cluster"]["workers"] == 2 and health["cluster"]["threads"] == 2
    caps = api.http.get("/v1/capabilities").json()
    assert caps["cluster"]["workers"] == 2 and caps["cluster"]["min_rays"] == MIN_RAYS


def test_large_queries_run_on_the_cluster(api, scene_name):
    vertices, faces = grid(24)
    api.put_mesh(scene_name, "ground", vertices, faces)
    local = dacrt.Scene([(vertices, faces)])
    origins, directions = rays(6000, 1)
    answer = api.closest(scene_name, origins, directions, stats=True)
    assert "cluster" in answer.timing and answer.stats["where"] == "cluster"
    expected = local.closest(origins, directions)
    for name in ("t", "prim", "u", "v", "normal"):
        assert np.array_equal(answer[name], getattr(expected, name)), name
    assert (answer["mesh"][np.isfinite(answer["t"])] == 0).all()
    counts = api.query(scene_name, "count", origins, directions)
    assert np.array_equal(counts["count"], local.count(origins, directions).count)
    hits = api.query(scene_name, "hits", origins, directions, max_hits=2)
    assert np.array_equal(hits["offsets"], local.hits(origins, directions, max_hits=2).offsets)
    small = api.closest(scene_name, origins[: MIN_RAYS - 1], directions[: MIN_RAYS - 1])
    assert "cluster" not in small.timing
    assert np.array_equal(small["t"], expected.t[: MIN_RAYS - 1])


def test_a_ray_beyond_float32_in_a_mesh_space_names_the_mesh_on_the_cluster(api, scene_name):
    """The 422 names the mesh as the scene does, on the cluster as in process."""
    vertices, faces = grid(4)
    for name in ("ground", "tiny"):
        api.put_mesh(scene_name, name, vertices, faces)
    api.set_transform(scene_name, "tiny", np.diag([1e-6, 1e-6, 1e-6, 1.0]))
    origins, directions = rays(MIN_RAYS + 10, 3)
    origins[7] = (0.0, 0.0, -3e34)
    directions[7] = (0.0, 0.0, 1.0)
    response = api.http.post(
        f"/v1/scenes/{scene_name}/closest",
        json={"origins": origins.tolist(), "directions": directions.tolist()},
    )
    assert response.status_code == 422, response.text
    assert "in the space of mesh 'tiny'" in response.json()["detail"], response.text


def test_a_new_version_replaces_the_old_on_the_workers(api, workers, scene_name):
    vertices, faces = grid(8)
    api.put_mesh(scene_name, "ground", vertices, faces)
    origins, directions = rays(4000, 2)
    before = held_scenes(workers)
    first = api.closest(scene_name, origins, directions)
    first_keys = held_scenes(workers) - before
    # the same mesh raised by 1: every hit comes 1 closer
    api.put_mesh(scene_name, "ground", vertices + np.float32([0, 0, 1]), faces)
    second = api.closest(scene_name, origins, directions)
    assert second.version == first.version + 1 and "cluster" in second.timing
    hit = np.isfinite(first["t"]) & np.isfinite(second["t"])
    assert hit.sum() > 1500
    np.testing.assert_allclose(second["t"][hit], first["t"][hit] - 1, atol=1e-4)
    after = held_scenes(workers)
    assert len(first_keys) == 1 and not first_keys & after  # the old version is gone
    assert after - before  # the new one is there


def test_a_snapshot_that_goes_while_its_thread_holds_the_cluster_lock_is_released():
    """A weak reference's callback runs where the snapshot's last reference goes: in a thread
    that may hold the cluster's lock (a temporary reference dropped under it, a collection)."""
    import threading
    import weakref

    from service.cluster import Cluster

    cluster = Cluster("tcp://127.0.0.1:9", min_rays=1)  # never started: no connection

    class Snapshot:
        pass

    snapshot = Snapshot()
    ref = weakref.ref(snapshot)
    engine = type("Engine", (), {"scene": type("S", (), {"close": lambda *a, **k: None})()})()
    cluster._sent["s"] = (1, None, engine, ref)

    def drop_under_the_lock():
        with cluster._lock:
            cluster._gone("s", ref)

    worker = threading.Thread(target=drop_under_the_lock, daemon=True)
    worker.start()
    worker.join(5)
    assert not worker.is_alive() and "s" not in cluster._sent


def test_unreachable_scheduler_falls_back(scene_name):
    settings = Settings(
        token=None, load_demo=False, dask_scheduler="tcp://127.0.0.1:9", dask_min_rays=10
    )
    with in_process.serve(settings) as http:
        api = Client(http=http)
        health = http.get("/health")
        assert health.status_code == 200 and health.json()["status"] == "degraded"
        assert health.json()["cluster"]["status"] == "unreachable"
        vertices, faces = grid(8)
        api.put_mesh(scene_name, "ground", vertices, faces)
        origins, directions = rays(500, 3)
        answer = api.closest(scene_name, origins, directions, stats=True)
        assert "cluster" not in answer.timing and answer.stats["where"] == "process"
        expected = dacrt.Scene([(vertices, faces)]).closest(origins, directions)
        assert np.array_equal(answer["t"], expected.t)


def test_settings(monkeypatch):
    monkeypatch.setenv("DACRT_DASK_SCHEDULER", "tcp://10.0.0.5:8786")
    monkeypatch.setenv("DACRT_DASK_MIN_RAYS", "2_000_000")
    settings = load_settings()
    assert settings.dask_scheduler == "tcp://10.0.0.5:8786" and settings.dask_min_rays == 2_000_000
    monkeypatch.setenv("DACRT_DASK_MIN_RAYS", "0")
    with pytest.raises(SettingsError, match="DACRT_DASK_MIN_RAYS"):
        load_settings()
    monkeypatch.setenv("DACRT_DASK_MIN_RAYS", "1")
    monkeypatch.setenv("DACRT_DASK_SCHEDULER", "")
    assert load_settings().dask_scheduler is None
    monkeypatch.setenv("DACRT_DASK_TIMEOUT", "2.5")
    assert load_settings().dask_timeout == 2.5
    for bad in ("0", "-1", "soon"):
        monkeypatch.setenv("DACRT_DASK_TIMEOUT", bad)
        with pytest.raises(SettingsError, match="DACRT_DASK_TIMEOUT"):
            load_settings()
    monkeypatch.delenv("DACRT_DASK_TIMEOUT")
    assert load_settings().dask_timeout == 30
    monkeypatch.setenv("DACRT_DASK_SCHEDULR", "tcp://x:1")
    with pytest.raises(SettingsError, match="did you mean DACRT_DASK_SCHEDULER"):
        load_settings()


# ---- a scheduler or a worker that stops answering (SIGSTOP: its connections stay open)

#: DACRT_DASK_TIMEOUT of the service below, and the time an answer may take beyond it
DEADLINE, SLACK = 3, 12


@pytest.fixture(scope="module")
def own_cluster():
    """A scheduler and a worker in processes of their own (``clusters.ProcessCluster``)."""
    own = ProcessCluster()
    yield own
    own.close()


@pytest.fixture(scope="module")
def frozen_api(own_cluster):
    """A real server (uvicorn's thread pool, clients that give up) on ``own_cluster``, with a
    short DACRT_DASK_TIMEOUT; its client gives up DEADLINE + SLACK seconds into a request."""
    server = ServerProcess(
        {
            "DACRT_DASK_SCHEDULER": own_cluster.address,
            "DACRT_DASK_MIN_RAYS": str(MIN_RAYS),
            "DACRT_DASK_TIMEOUT": str(DEADLINE),
        }
    )
    try:
        url = server.wait_ready()  # "ok": the cluster's too
        api = Client(base_url=url, timeout=DEADLINE + SLACK)
        yield api
        api.close()
    finally:
        server.stop()


@contextmanager
def stopped(pid):
    """The process ``pid`` stopped (SIGSTOP) inside the block: alive, its sockets open."""
    os.kill(pid, signal.SIGSTOP)
    try:
        yield
    finally:
        os.kill(pid, signal.SIGCONT)


def wait_for_health(api, status, seconds):
    """/health's body once its status is ``status``; every answer comes within 2 s."""
    deadline = time.monotonic() + seconds
    while True:
        body = api.http.get("/health", timeout=2).json()
        if body["status"] == status or time.monotonic() > deadline:
            assert body["status"] == status, body
            return body
        time.sleep(0.2)


def traced(api, scene, origins, directions, expected):
    """The query's ``where`` and its seconds; its answer is the reference's."""
    start = time.monotonic()
    answer = api.closest(scene, origins, directions, stats=True)
    seconds = time.monotonic() - start
    np.testing.assert_allclose(answer["t"], expected.t[: len(origins)], rtol=1e-5)
    assert np.mean(answer["prim"] == expected.prim[: len(origins)]) > 0.99
    return answer.stats["where"], seconds


def frozen_scene(api, scene_name):
    """A stored grid, a large batch onto it and the reference's answer; the batch has run on
    the cluster once (its triangles are on the worker)."""
    vertices, faces = grid(24)
    api.put_mesh(scene_name, "ground", vertices, faces)
    origins, directions = rays(3 * MIN_RAYS, 11)
    expected = reference.closest(vertices, faces, origins, directions)
    assert np.isfinite(expected.t).sum() > MIN_RAYS
    assert traced(api, scene_name, origins, directions, expected)[0] == "cluster"
    return origins, directions, expected


def test_a_frozen_scheduler_leaves_health_and_queries_answering(
    frozen_api, own_cluster, scene_name
):
    """docs/cluster.md: while the scheduler is unreachable, /health answers 200 degraded and
    every query is traced in process; a query that was sent to it costs DACRT_DASK_TIMEOUT at
    most. /health never waits on the scheduler, so that probes given up by their callers (a load
    balancer's) take none of the threads that queries need."""
    api = frozen_api
    origins, directions, expected = frozen_scene(api, scene_name)
    with stopped(own_cluster.scheduler.pid):
        where, seconds = traced(api, scene_name, origins, directions, expected)
        assert where == "process" and seconds < DEADLINE + SLACK
        body = wait_for_health(api, "degraded", 10)
        assert body["cluster"]["status"] == "unreachable", body
        url = str(api.http.base_url.join("/health"))
        with ThreadPoolExecutor(48) as pool:
            probes = list(pool.map(lambda _: httpx.get(url, timeout=2), range(48)))
        assert [probe.status_code for probe in probes] == [200] * 48
        where, seconds = traced(api, scene_name, origins[:10], directions[:10], expected)
        assert where == "process"
        where, seconds = traced(api, scene_name, origins, directions, expected)
        assert where == "process" and seconds < DEADLINE  # the cluster is not asked again
    wait_for_health(api, "ok", 60)
    assert traced(api, scene_name, origins, directions, expected)[0] == "cluster"


def test_a_frozen_worker_costs_a_query_its_deadline_at_most(frozen_api, own_cluster, scene_name):
    """A worker that stops answering stays the scheduler's for dask's worker-ttl (5 minutes):
    the query that sent it a shard is traced in process after DACRT_DASK_TIMEOUT, and /health
    is degraded until the worker answers again."""
    api = frozen_api
    origins, directions, expected = frozen_scene(api, scene_name)
    with stopped(own_cluster.worker.pid):
        where, seconds = traced(api, scene_name, origins, directions, expected)
        assert where == "process" and DEADLINE <= seconds < DEADLINE + SLACK
        body = wait_for_health(api, "degraded", 10)
        assert body["cluster"]["status"] == "unreachable", body
        time.sleep(DEADLINE)  # the monitor's task for the worker goes unanswered too
        assert api.http.get("/health").json()["status"] == "degraded"
    wait_for_health(api, "ok", 60)
    assert traced(api, scene_name, origins, directions, expected)[0] == "cluster"
