"""dacrt.distributed on a LocalCluster (2 worker processes, 1 thread each): the answers are
``dacrt.Scene``'s, bit for bit, in input order, for every query; a worker killed mid-batch costs
time, not answers."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import procedural as pg
import pytest
import reference
import sample_scenes

distributed = pytest.importorskip("distributed")

from clusters import two_worker_cluster  # noqa: E402

import dacrt  # noqa: E402
from dacrt.distributed import ClusterError, DistributedScene, shard_bounds  # noqa: E402

#: Small shards, so that the small batches of these tests are cut into several.
SMALL_SHARDS = {"min_shard_rays": 64, "max_shard_rays": 512}


@pytest.fixture(scope="module")
def client():
    """One cluster for the module (``clusters.two_worker_cluster``)."""
    cluster = two_worker_cluster()
    client = distributed.Client(cluster, set_as_default=False)  # as the service's
    client.wait_for_workers(2)
    yield client
    client.close()
    cluster.close()


def same(answer, expected):
    """Every array of two answers of one type equal, bit for bit (NaN-free: inf on a miss)."""
    assert type(answer) is type(expected)
    for name, value in vars(expected).items():
        if name == "stats":
            continue
        got = getattr(answer, name)
        assert got.dtype == value.dtype and got.shape == value.shape, name
        assert np.array_equal(got.view(np.uint8), value.view(np.uint8)), name


def test_shard_bounds():
    assert shard_bounds(0, 4) == [0, 0]
    assert shard_bounds(10, 4, min_rays=100) == [0, 10]
    # a multiple of the threads, each shard at most max_rays
    bounds = shard_bounds(1000, 2, min_rays=10, max_rays=300)
    assert len(bounds) - 1 == 4 and bounds[-1] == 1000
    assert max(np.diff(bounds)) <= 300
    # at least min_rays a shard, even if threads stay idle
    assert len(shard_bounds(250, 8, min_rays=100, max_rays=1000)) - 1 == 2


@pytest.mark.parametrize("seed", [1, 2])
def test_every_query_matches_scene(client, seed):
    meshes = sample_scenes.multi(seed)
    local = dacrt.Scene(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, seed, n=3000)
    tmax = np.random.default_rng(seed).uniform(0.5, 5, len(origins)).astype(np.float32)
    with DistributedScene(client, meshes, **SMALL_SHARDS) as remote:
        for query, kwargs in [
            ("closest", {}),
            ("closest", {"cull": "back", "strategy": "sah"}),
            ("occluded", {"tmax": tmax}),
            ("hits", {"max_hits": 3}),
            ("count", {}),
        ]:
            expected = getattr(local, query)(origins, directions, **kwargs)
            same(getattr(remote, query)(origins, directions, **kwargs), expected)


def test_float64_windows_that_hold_no_float32_see_nothing_as_on_scene(client):
    """Every third ray's window is a quarter of a float32 step above its closest hit's t: it
    holds no float32, so that ray sees nothing (to the nearest float32 it would hit), with any
    mask, as ``Scene`` answers it."""
    meshes = sample_scenes.multi(1)
    local = dacrt.Scene(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, 1, n=600)
    t = local.closest(origins, directions).t.astype(np.float64)
    narrow = np.zeros(len(origins), bool)
    narrow[::3] = np.isfinite(t[::3]) & (t[::3] > 0)
    assert narrow.sum() > 50
    step = np.spacing(t[narrow].astype(np.float32)).astype(np.float64)
    tmin = np.zeros(len(origins))
    tmax = np.full(len(origins), np.inf)
    tmin[narrow] = tmax[narrow] = t[narrow] + step / 4
    masks = np.random.default_rng(1).integers(0, 4, len(origins)).astype(np.uint32)
    with DistributedScene(client, meshes, **SMALL_SHARDS) as remote:
        for query, kwargs in [("closest", {}), ("count", {"mask": 3}), ("hits", {"mask": masks})]:
            expected = getattr(local, query)(origins, directions, tmin, tmax, **kwargs)
            same(getattr(remote, query)(origins, directions, tmin, tmax, **kwargs), expected)
    assert (local.closest(origins, directions, tmin, tmax).mesh[narrow] == -1).all()


def test_order_and_stats(client):
    meshes = sample_scenes.soup(3)
    origins, directions = sample_scenes.mixed_rays(meshes, 3, n=2000)
    order = np.random.default_rng(3).permutation(len(origins))
    with DistributedScene(client, meshes, **SMALL_SHARDS) as remote:
        hits = remote.closest(origins, directions, stats=True)
        shuffled = remote.closest(origins[order], directions[order])
    assert np.array_equal(shuffled.t, hits.t[order])
    assert np.array_equal(shuffled.prim, hits.prim[order])
    assert hits.stats["rays"] == len(origins)
    assert hits.stats["triangles"] == sum(len(f) for _, f in meshes)
    # against the plain-numpy reference, not only the engine
    vertices, faces, _ = pg.concat(meshes)
    ref = reference.closest(vertices, faces, origins, directions)
    assert np.array_equal(np.isfinite(hits.t), np.isfinite(ref.t))
    both = np.isfinite(ref.t)
    assert both.sum() > 100
    np.testing.assert_allclose(hits.t[both], ref.t[both], rtol=1e-4)


def test_masks_and_transforms(client):
    sphere = pg.icosphere(2)
    meshes = [sphere, sphere, sphere]
    transforms = [None, np.eye(4), np.eye(4)]
    transforms[1][:3, 3] = (3, 0, 0)
    transforms[2][:3, 3] = (-3, 0, 0)
    masks = np.array([1, 2, 4], np.uint32)
    rng = np.random.default_rng(4)
    origins = rng.uniform(-6, 6, (1500, 3)).astype(np.float32)
    directions = pg.unit_vectors(1500, rng)
    ray_masks = rng.integers(0, 8, 1500).astype(np.uint32)
    local = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    with DistributedScene(client, meshes, masks=masks, transforms=transforms, **SMALL_SHARDS) as d:
        same(
            d.closest(origins, directions, mask=ray_masks),
            local.closest(origins, directions, mask=ray_masks),
        )
        same(d.count(origins, directions, mask=2), local.count(origins, directions, mask=2))
        same(d.hits(origins, directions, mask=5), local.hits(origins, directions, mask=5))


def test_empty_and_one_ray(client):
    meshes = [pg.icosphere(1)]
    local = dacrt.Scene(meshes)
    none = np.empty((0, 3), np.float32)
    one_o, one_d = np.array([[0, 0, -5]], np.float32), np.array([[0, 0, 1]], np.float32)
    with DistributedScene(client, meshes) as remote:
        for query in ("closest", "occluded", "hits", "count"):
            same(getattr(remote, query)(none, none), getattr(local, query)(none, none))
            same(getattr(remote, query)(one_o, one_d), getattr(local, query)(one_o, one_d))
        hits = remote.closest(one_o, one_d)
    assert hits.t[0] == pytest.approx(4.0, abs=0.1)


def test_bad_input_names_the_ray_of_the_batch(client):
    meshes = [pg.icosphere(1)]
    origins = np.zeros((3000, 3), np.float32)
    directions = np.tile(np.float32([0, 0, 1]), (3000, 1))
    directions[2500] = 0
    with DistributedScene(client, meshes, **SMALL_SHARDS) as remote:
        with pytest.raises(ValueError) as remote_error:
            remote.closest(origins, directions)
        with pytest.raises(ValueError, match="strategy"):
            remote.closest(origins, directions, strategy="best")
        with pytest.raises(TypeError, match="max_hits"):
            remote.closest(origins, directions, max_hits=3)
    with pytest.raises(ValueError) as local_error:
        dacrt.Scene(meshes).closest(origins, directions)
    assert "2500" in str(remote_error.value)
    assert str(remote_error.value) == str(local_error.value)
    with pytest.raises(ValueError, match="mesh 0"):
        DistributedScene(client, [(np.zeros((3, 2)), np.zeros((1, 3), int))])


def test_real_scene(client, load_shared):
    vertices, faces = load_shared("sibenik")
    local = dacrt.Scene([(vertices, faces)])
    box = pg.bounds(vertices, faces)
    origins, directions = pg.camera_rays(box, 160, 120, inside=True)
    rng = np.random.default_rng(5)
    o2, d2 = pg.random_rays(box, 20000, rng)
    origins, directions = np.concatenate([origins, o2]), np.concatenate([directions, d2])
    with DistributedScene(client, [(vertices, faces)], min_shard_rays=4096) as remote:
        same(remote.closest(origins, directions), local.closest(origins, directions))
        same(remote.occluded(origins, directions), local.occluded(origins, directions))


def _worker_pids(client):
    return client.run(os.getpid)


def test_worker_killed_mid_batch(client, load_shared):
    vertices, faces = load_shared("sibenik")
    local = dacrt.Scene([(vertices, faces)])
    rng = np.random.default_rng(6)
    origins, directions = pg.random_rays(pg.bounds(vertices, faces), 800_000, rng)
    expected = local.closest(origins, directions)
    remote = DistributedScene(
        client, [(vertices, faces)], min_shard_rays=10_000, max_shard_rays=25_000
    )
    remote.closest(origins[:1000], directions[:1000])  # both workers build their scene
    pids = _worker_pids(client)
    answer = {}
    batch = threading.Thread(target=lambda: answer.update(h=remote.closest(origins, directions)))
    batch.start()
    while not any(client.processing().values()):
        time.sleep(0.005)
    killed_during_batch = batch.is_alive()
    os.kill(next(iter(pids.values())), signal.SIGKILL)
    batch.join(120)
    assert killed_during_batch and not batch.is_alive()
    same(answer["h"], expected)
    assert remote.resent >= 1
    client.wait_for_workers(2, timeout=60)  # the nanny starts a new worker process
    remote.close()


def test_triangles_lost_with_their_worker_are_sent_again(client, load_shared):
    """dask's memory manager keeps one copy of what was broadcast; when the worker holding it
    dies, the triangles are sent again and the query still answers exactly."""
    vertices, faces = load_shared("sibenik")
    rng = np.random.default_rng(8)
    origins, directions = pg.random_rays(pg.bounds(vertices, faces), 200_000, rng)
    expected = dacrt.Scene([(vertices, faces)]).closest(origins, directions)
    remote = DistributedScene(
        client, [(vertices, faces)], min_shard_rays=10_000, max_shard_rays=25_000
    )
    first_key = remote.key
    deadline = time.monotonic() + 60
    while len(client.who_has([remote._payload])[first_key]) > 1:
        assert time.monotonic() < deadline, "dask kept every copy of the triangles"
        time.sleep(0.1)
    [holder] = client.who_has([remote._payload])[first_key]
    os.kill(_worker_pids(client)[holder], signal.SIGKILL)
    same(remote.closest(origins, directions), expected)
    assert remote.key != first_key
    client.wait_for_workers(2, timeout=60)
    remote.close()


def test_worker_killed_without_retries_is_a_clear_error(client, load_shared):
    vertices, faces = load_shared("sibenik")
    rng = np.random.default_rng(7)
    origins, directions = pg.random_rays(pg.bounds(vertices, faces), 800_000, rng)
    remote = DistributedScene(
        client, [(vertices, faces)], retries=0, min_shard_rays=10_000, max_shard_rays=25_000
    )
    remote.closest(origins[:1000], directions[:1000])
    pids = list(_worker_pids(client).values())
    outcome = {}

    def batch():
        try:
            outcome["answer"] = remote.closest(origins, directions)
        except ClusterError as exc:
            outcome["error"] = exc

    thread = threading.Thread(target=batch)
    thread.start()
    while not any(client.processing().values()):
        time.sleep(0.005)
    killed_during_batch = thread.is_alive()
    os.kill(pids[1], signal.SIGKILL)
    thread.join(120)
    assert killed_during_batch and not thread.is_alive()
    assert "answer" not in outcome
    assert "failed on the cluster (1 of 1 tries)" in str(outcome["error"])
    client.wait_for_workers(2, timeout=60)
    remote.close()


def test_workers_that_stop_answering_cost_the_timeout_at_most(client):
    """Workers that stop answering but keep their connections open (SIGSTOP: a frozen host)
    stay dask's until its worker-ttl (5 minutes): a batch ends at the scene's ``timeout`` with
    ClusterError, sending its shards included, and so does sending a new scene's triangles."""
    timeout, slack = 2, 8
    meshes = [pg.icosphere(1)]
    remote = DistributedScene(client, meshes, timeout=timeout, **SMALL_SHARDS)
    origins = np.zeros((2000, 3), np.float32)
    directions = np.tile(np.float32([0, 0, 1]), (2000, 1))
    remote.closest(origins, directions)  # both workers build their scene
    pids = list(_worker_pids(client).values())
    outcome = {}

    def frozen():
        for name, call in [
            ("batch", lambda: remote.closest(origins, directions)),
            ("scene", lambda: DistributedScene(client, meshes, timeout=timeout)),
        ]:
            start = time.monotonic()
            try:
                call()
            except ClusterError as exc:
                outcome[name] = (str(exc), time.monotonic() - start)

    thread = threading.Thread(target=frozen, daemon=True)
    for pid in pids:
        os.kill(pid, signal.SIGSTOP)
    try:
        thread.start()
        thread.join(2 * (timeout + slack))
        finished = not thread.is_alive()
    finally:
        for pid in pids:
            os.kill(pid, signal.SIGCONT)
    thread.join(120)
    assert finished, f"a call to the frozen cluster outlived its timeout: {outcome}"
    message, seconds = outcome["batch"]
    assert f"took over {timeout} s" in message and timeout <= seconds < timeout + slack
    message, seconds = outcome["scene"]
    assert "could not reach the cluster" in message and seconds < timeout + slack
    same(remote.closest(origins, directions), dacrt.Scene(meshes).closest(origins, directions))
    remote.close()


def test_lost_cluster_is_an_error(client):
    meshes = [pg.icosphere(1)]
    remote = DistributedScene(client, meshes)
    remote.close()
    with pytest.raises(ClusterError, match="closed"):
        remote.closest(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))


@pytest.mark.parametrize("timeout", [600, None])
def test_a_timeout_talking_to_the_cluster_is_not_called_the_batchs(client, monkeypatch, timeout):
    """A TimeoutError from the cluster's comms well within the batch's clock says so, not
    that the batch took over its timeout (which may be None: no limit)."""
    remote = DistributedScene(client, [pg.icosphere(1)], timeout=timeout)

    def submit(*args, **kwargs):
        raise TimeoutError("Timed out trying to connect to tcp://127.0.0.1:1")

    monkeypatch.setattr(client, "submit", submit)
    with pytest.raises(ClusterError) as failed:
        remote.closest(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))
    assert "the cluster stopped answering after" in str(failed.value)
    assert "Timed out trying to connect" in str(failed.value)
    assert "took over" not in str(failed.value)
    monkeypatch.undo()
    remote.close()


def test_a_closed_client_is_a_cluster_error():
    """A client that has closed (its scheduler gone, or closed by its owner) answers
    ClusterError, not dask's own errors."""
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False)
    own = distributed.Client(cluster, set_as_default=False)
    remote = DistributedScene(own, [pg.icosphere(1)])
    own.close()
    with pytest.raises(ClusterError):
        remote.closest(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))
    cluster.close()


def test_motion_deforming_and_order_match_scene(client):
    """``time``, ``transforms_end``, ``vertices_end`` and ``order``: Scene's answers."""
    sphere = pg.icosphere(2)
    grid = pg.grid(8, 4.0)
    moved = np.eye(4)
    moved[:3, 3] = (0.5, -0.25, 1.0)
    ends = [moved, None]
    vertices_end = [None, (grid[0] + np.float32([0, 0, 0.5])).astype(np.float32)]
    local = dacrt.Scene(
        [sphere, grid], transforms_end=ends, vertices_end=vertices_end, order="morton"
    )
    rng = np.random.default_rng(6)
    origins = rng.uniform(-3, 5, (2000, 3)).astype(np.float32)
    directions = pg.unit_vectors(2000, rng)
    times = rng.uniform(0, 1, 2000).astype(np.float32)
    with DistributedScene(
        client, [sphere, grid], transforms_end=ends, vertices_end=vertices_end, order="morton",
        **SMALL_SHARDS,
    ) as remote:  # fmt: skip
        for query in ("closest", "occluded", "hits", "count"):
            expected = getattr(local, query)(origins, directions, time=times)
            same(getattr(remote, query)(origins, directions, time=times), expected)
        same(
            remote.closest(origins, directions, time=0.5),
            local.closest(origins, directions, time=0.5),
        )
        with pytest.raises(ValueError, match=r"time\[3\]"):
            remote.closest(origins, directions, time=np.where(np.arange(2000) == 3, 2.0, 0.5))


def test_bad_arguments_are_named_as_scene_names_them(client):
    meshes = [pg.icosphere(1)]
    origins = np.zeros((3000, 3), np.float32)
    directions = np.tile(np.float32([0, 0, 1]), (3000, 1))
    with DistributedScene(client, meshes, **SMALL_SHARDS) as remote:
        for mask in (-1, 2**33):
            with pytest.raises(ValueError) as remote_error:
                remote.closest(origins, directions, mask=mask)
            with pytest.raises(ValueError) as local_error:
                dacrt.Scene(meshes).closest(origins, directions, mask=mask)
            assert str(remote_error.value) == str(local_error.value)  # the batch's 3000 rays
    for bad in ([pg.icosphere(1), 5], [(np.zeros((3, 3)),)], 7):
        with pytest.raises(dacrt.InputError) as remote_error:
            DistributedScene(client, bad)
        with pytest.raises(dacrt.InputError) as local_error:
            dacrt.Scene(bad)
        assert str(remote_error.value) == str(local_error.value)
    for name in ("min_shard_rays", "max_shard_rays"):
        with pytest.raises(dacrt.InputError, match=name):
            DistributedScene(client, meshes, **{name: 0})
