"""Ray sampling's own kernels against plain numpy: Algorithm 2's counts, and the split axis.

Answers cannot show these: every strategy gives the same answers, whatever splits it picks.
"""

from __future__ import annotations

import numpy as np

from dacrt.config import N_BINS, N_SAMPLE_RAYS
from dacrt.rays import new_records, pack_rays
from dacrt.traversal import PADDED_CANDIDATES, sample_rays, sampled_axis


def _records(origins, directions):
    """Ray records as the kernels hold them (``dacrt.rays``), tmin 0, best_t +inf; and the
    float32 origins and directions they hold."""
    n = len(origins)
    origins = np.asarray(origins, np.float32)
    directions = np.asarray(directions, np.float32)
    rays = new_records(n)
    assert pack_rays(
        origins,
        directions,
        np.zeros(n, np.float32),
        np.full(n, np.inf, np.float32),
        np.arange(n, dtype=np.int32),
        rays,
    )
    return rays, origins, directions


def _slab_hits(origins, directions, lo, hi):
    """Plain slab test (float64) of each ray against one box: whether it hits."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions
        a = (lo - origins) * inv
        b = (hi - origins) * inv
    near = np.maximum(np.minimum(a, b).max(axis=1), 0.0)
    far = np.maximum(a, b).min(axis=1)
    return near <= far


def test_sample_rays_counts_match_algorithm_2():
    """For every candidate: sample rays hitting each side, and the vote of those hitting both,
    going up the axis or down; equal to a numpy count over the same strided samples. Empty
    candidates (a side without triangles) count nothing."""
    rng = np.random.default_rng(60)
    n_rays, axis = 5_000, 1
    origins = rng.uniform(-4, 4, (n_rays, 3))
    directions = rng.normal(size=(n_rays, 3))
    rays, origins32, directions32 = _records(origins, directions)
    n_cand = N_BINS - 1
    lows = rng.uniform(-2, 0, (n_cand, 2, 3))
    left_box = np.concatenate([lows[:, 0], lows[:, 0] + rng.uniform(1, 3, (n_cand, 3))], 1)
    right_box = np.concatenate([lows[:, 1], lows[:, 1] + rng.uniform(1, 3, (n_cand, 3))], 1)
    left_count = rng.integers(1, 100, n_cand)
    right_count = rng.integers(1, 100, n_cand)
    left_count[[3, n_cand // 2 + 2]] = 0  # no triangles on one side: not a candidate
    right_count[n_cand - 2] = 0
    counts = np.full((3, PADDED_CANDIDATES), -7, np.int32)  # stale scratch
    n_tests = sample_rays(
        rays,
        0,
        n_rays,
        left_count,
        left_box.astype(np.float32),
        right_count,
        right_box.astype(np.float32),
        axis,
        np.empty((12, PADDED_CANDIDATES), np.float32),
        counts,
    )
    outputs = counts[:, :n_cand]

    picked = (np.arange(N_SAMPLE_RAYS) * n_rays) // N_SAMPLE_RAYS
    o = origins32[picked].astype(np.float64)
    d = directions32[picked].astype(np.float64)
    real = (left_count > 0) & (right_count > 0)
    assert n_tests == 2 * N_SAMPLE_RAYS * real.sum()
    for j in range(n_cand):
        hit_l = _slab_hits(o, d, left_box[j, :3], left_box[j, 3:])
        hit_r = _slab_hits(o, d, right_box[j, :3], right_box[j, 3:])
        votes = np.where(d[:, axis] >= 0, 1, -1)[hit_l & hit_r].sum()
        expected = [hit_l.sum(), hit_r.sum(), votes]
        got = [out[j] for out in outputs]
        assert got == (expected if real[j] else [0, 0, 0]), j
    assert (counts[:, n_cand:] == 0).all()  # padding lanes: empty boxes that every ray misses
    assert outputs[0].sum() > 2 * n_cand and np.abs(outputs[2]).max() > 0


def test_sampled_axis_prefers_an_axis_across_the_rays():
    """Centroids spread 4 x 3 x 1: rays running along x make y the split axis; rays along z, or
    in every direction, leave the longest axis, x. Centroids in one point give extent 0 (the
    caller then splits in the middle)."""
    rng = np.random.default_rng(61)
    n = 2_000
    c_box = np.array([0, 0, 0, 4, 3, 1], np.float32)
    along_x = np.column_stack([np.ones(n), rng.normal(0, 0.1, (n, 2))]) * 5.0  # not unit
    along_z = np.column_stack([rng.normal(0, 0.1, (n, 2)), -np.ones(n)])
    everywhere = rng.normal(size=(n, 3))
    origins = np.zeros((n, 3))
    for directions, expected in ((along_x, 1), (along_z, 0), (everywhere, 0)):
        axis, extent = sampled_axis(_records(origins, directions)[0], 0, n, c_box)
        assert (axis, extent) == (expected, c_box[expected + 3] - c_box[expected])
    point = np.array([1, 2, 3, 1, 2, 3], np.float32)  # all centroids in one place
    assert sampled_axis(_records(origins, along_x)[0], 0, n, point)[1] == 0
