"""dacrt.chunks: however a batch is cut, its chunks hold every ray exactly once, in increasing
order; the counts of chunks and threads follow their rules; the density grid counts every
triangle once."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from dacrt import chunks

MIN = chunks.MIN_RAYS_PER_THREAD


def box_of(points: np.ndarray) -> np.ndarray:
    return np.concatenate([points.min(axis=0), points.max(axis=0)]).astype(np.float32)


def scattered(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (n, 3)).astype(np.float32)


def every_chunk(plan, n_rays: int, n_chunks: int) -> list[np.ndarray]:
    return [chunks.chunk_ids(plan, n_rays, n_chunks, k) for k in range(n_chunks)]


def assert_a_partition(parts: list[np.ndarray], n_rays: int) -> None:
    """Every ray id in exactly one chunk, each chunk increasing int32."""
    for ids in parts:
        assert ids.dtype == np.int32 and np.all(np.diff(ids) > 0)
    joined = np.concatenate(parts)
    assert len(joined) == n_rays and np.array_equal(np.sort(joined), np.arange(n_rays))


@pytest.mark.parametrize("n_chunks", [1, 2, 3, 7])
@pytest.mark.parametrize("n_rays", [0, 1, 5, 1000])
def test_contiguous_runs_hold_every_ray_once(n_rays, n_chunks):
    parts = every_chunk(None, n_rays, n_chunks)
    assert_a_partition(parts, n_rays)
    assert max(map(len, parts)) - min(map(len, parts)) <= 1  # as even as can be


@pytest.mark.parametrize("n_chunks", [2, 3, 8])
@pytest.mark.parametrize("seed", [0, 1])
def test_slabs_of_scattered_origins_hold_every_ray_once(n_chunks, seed):
    origins = scattered(50_000, seed)
    box = box_of(origins)
    triangles = np.hstack([origins[:500], origins[:500]])  # boxes of zero size, for the density
    plan = chunks.plan_chunks(
        origins,
        n_chunks,
        keep_order=False,
        box=box,
        density=lambda: chunks.centre_counts(triangles, box, chunks.DENSITY_GRID),
    )
    assert plan is not None  # scattered in input order: slabs, not runs
    values, cuts = plan
    assert len(cuts) == n_chunks - 1 and np.all(np.diff(cuts) >= 0)
    parts = every_chunk(plan, len(origins), n_chunks)
    assert_a_partition(parts, len(origins))
    for k, ids in enumerate(parts):  # slab k: cuts[k-1] <= value < cuts[k]
        if k > 0:
            assert np.all(values[ids] >= cuts[k - 1])
        if k < n_chunks - 1:
            assert np.all(values[ids] < cuts[k])


def test_origins_in_a_coherent_order_keep_their_order():
    # a scan line by line: consecutive origins are close, the first and last far apart
    line = np.linspace(-1, 1, 250, dtype=np.float32)
    y, x = np.meshgrid(line, line, indexing="ij")
    origins = np.stack([x.ravel(), y.ravel(), np.zeros(x.size, np.float32)], axis=1)
    plan = chunks.plan_chunks(origins, 4, False, box_of(origins), density=None)
    assert plan is None  # density is not even asked for


def test_keep_order_and_one_chunk_cut_no_slabs():
    origins = scattered(50_000)
    for keep_order, n_chunks in ((True, 4), (False, 1)):
        assert chunks.plan_chunks(origins, n_chunks, keep_order, box_of(origins), None) is None


def test_nan_values_fall_in_the_first_slab():
    values = np.array([0.5, np.nan, -1.0, 2.0], np.float32)
    cuts = np.array([0.0, 1.0], np.float32)
    slabs = [list(chunks.slab_ids(values, cuts, k)) for k in range(3)]
    assert slabs == [[1, 2], [0], [3]]


@pytest.mark.parametrize("threads", [1, 2, 4])
@pytest.mark.parametrize("n_rays", [1, MIN - 1, 2 * MIN, 5 * MIN + 3, 10**6])
@pytest.mark.parametrize("n_triangles", [10, 10**5])
def test_chunk_counts(threads, n_rays, n_triangles):
    scattered_chunks = chunks.count_chunks(n_rays, n_triangles, threads, coherent=False)
    assert 1 <= scattered_chunks <= threads  # one chunk per thread at most
    assert scattered_chunks == 1 or n_rays // scattered_chunks >= MIN
    coherent_chunks = chunks.count_chunks(n_rays, n_triangles, threads, coherent=True)
    assert coherent_chunks >= scattered_chunks
    if threads > 1 and coherent_chunks > threads:
        assert coherent_chunks % threads == 0  # as many chunks on every thread


def test_triangles_are_split_only_for_few_rays_a_triangle_on_several_threads():
    rule = chunks.SPLIT_TRIANGLES_RAYS_PER_TRIANGLE
    least = chunks.MIN_RAYS_TO_SPLIT_TRIANGLES
    many_triangles = int(4 * MIN / rule) + 1
    assert chunks.splits_triangles(least, many_triangles, 2)
    assert chunks.splits_triangles(2 * MIN, many_triangles, 2)
    assert not chunks.splits_triangles(2 * MIN, many_triangles, 1)  # one thread
    assert not chunks.splits_triangles(least - 1, many_triangles, 2)  # too few rays
    assert not chunks.splits_triangles(2 * MIN, int(2 * MIN / rule), 2)  # enough rays a triangle


def test_rays_from_one_point_are_told_from_scattered_ones():
    box = np.array([-10, -10, -10, 10, 10, 10], np.float32)
    camera = np.tile(np.float32([1, 2, 3]), (1000, 1))
    assert chunks.from_one_point(camera + scattered(1000) * 1e-3, box)
    assert not chunks.from_one_point(scattered(1000) * 10, box)


def test_the_density_grid_counts_every_triangle_once_in_its_centres_cell():
    bounds = np.array([[0, 0, 0, 0.1, 0.1, 0.1], [0.9, 0.9, 0.9, 1, 1, 1], [0, 0, 0, 1, 1, 1]])
    box = np.array([0, 0, 0, 1, 1, 1], np.float32)
    counts = chunks.centre_counts(bounds.astype(np.float32), box, 4)
    assert counts.shape == (64,) and counts.sum() == 3
    assert counts[0] == 1 and counts[63] == 1  # the corners' cells
    assert counts[(2 * 4 + 2) * 4 + 2] == 1  # the centre (0.5, 0.5, 0.5) is in cell (2, 2, 2)
    points = np.array([[0.05, 0.05, 0.05], [2, 2, 2], [np.nan, 0, 0]], np.float32)
    weights = chunks.origin_weights(points, counts, box, 4)
    assert np.array_equal(weights, [np.sqrt(2.0), 1.0, 1.0])  # outside the box (or NaN): 1


@pytest.mark.parametrize("n_workers", [1, 3])
def test_map_on_threads_answers_in_order(n_workers):
    seen = set()

    def work(k):
        seen.add(threading.current_thread().name)
        return k * k

    assert chunks.map_on_threads(work, 20, n_workers) == [k * k for k in range(20)]
    if n_workers == 1:
        assert seen == {threading.current_thread().name}  # in the caller's thread


def test_a_call_does_not_queue_behind_a_busy_pool():
    """Another query holds every thread of the shared pool: this call's items all run on the
    caller's thread, and it returns without waiting for the pool."""
    release = threading.Event()
    blockers = [chunks.POOL.submit(release.wait, 30) for _ in range(chunks.POOL_THREADS)]
    try:
        threads = []

        def work(k):
            threads.append(threading.current_thread().name)
            return -k

        started = time.perf_counter()
        assert chunks.map_on_threads(work, 6, 3) == [-k for k in range(6)]
        assert time.perf_counter() - started < 5
        assert set(threads) == {threading.current_thread().name}
    finally:
        release.set()
    assert all(blocker.result(timeout=30) for blocker in blockers)


def test_one_pool_serves_every_count():
    """Calls with threads=2..12, one after another, share one pool of at most 12 threads (a pool
    per count starts 66), and each still uses its own count of threads."""
    before = set(threading.enumerate())
    largest = 12
    for n_workers in range(2, largest + 1):
        used = set()
        entered = threading.Barrier(n_workers)

        def work(k, used=used, entered=entered):
            used.add(threading.current_thread())
            if k < entered.parties:
                entered.wait(30)  # the first n_workers items each hold a thread of their own
            return k

        assert chunks.map_on_threads(work, 3 * n_workers, n_workers) == list(range(3 * n_workers))
        assert len(used) == n_workers
    started = set(threading.enumerate()) - before
    assert len(started) <= largest, f"{len(started)} threads started"


def test_an_item_that_raises_stops_the_others_and_raises():
    ran = []

    def work(k):
        ran.append(k)
        if k == 2:
            raise ValueError("item 2")
        time.sleep(0.01)
        return k

    with pytest.raises(ValueError, match="item 2"):
        chunks.map_on_threads(work, 200, 2)
    assert len(ran) < 200


def test_usable_cores_follow_affinity_and_a_cgroup_quota(tmp_path):
    """``DACRT_THREADS``'s default in a container: the cpuset's cores, fewer under ``--cpus``."""
    allowed = len(os.sched_getaffinity(0))
    assert chunks.usable_cores(tmp_path) == allowed  # no cgroup files: the affinity
    (tmp_path / "cpu.max").write_text("max 100000\n")
    assert chunks.usable_cores(tmp_path) == allowed
    (tmp_path / "cpu.max").write_text("50000 100000\n")
    assert chunks.usable_cores(tmp_path) == 1  # half a core still runs one thread
    (tmp_path / "cpu.max").unlink()
    (tmp_path / "cpu").mkdir()
    (tmp_path / "cpu" / "cpu.cfs_quota_us").write_text("-1\n")
    (tmp_path / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    assert chunks.usable_cores(tmp_path) == allowed
    (tmp_path / "cpu" / "cpu.cfs_quota_us").write_text("100000\n")
    assert chunks.usable_cores(tmp_path) == 1
