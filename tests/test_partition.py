"""dacrt.partition (and rayspace.partition_rays) against plain numpy: binning, the split sweep,
the in-place partitions of triangle ids and of ray records. Seeded and parametrised."""

from __future__ import annotations

import numpy as np
import procedural as pg
import pytest

from dacrt.partition import (
    PARTITION_BLOCK,
    bin_scale,
    bin_triangles,
    centroid_bounds,
    partition_binned,
    partition_by_mask,
    partition_scratch,
    partition_triangles,
    sweep_bins,
    triangle_bounds,
)
from dacrt.rays import new_records, pack_rays
from dacrt.rayspace import compare_scratch, partition_rays
from dacrt.triangles import Triangles, triangle_boxes

N_BINS = 16
SEEDS = (0, 1, 2)
NO_CORNERS = np.empty((0, 9), np.float32)  # the partitions of triangles read boxes only


def triangles(tri_bounds, ids):
    """The ``Triangles`` record of boxes ``tri_bounds`` and ids ``ids`` (ids are permuted in
    place)."""
    return Triangles(NO_CORNERS, tri_bounds, ids)


def soup_bounds(seed, n=600):
    """Boxes (n, 6) float32 of a random triangle soup, and a shuffled id range over them."""
    rng = np.random.default_rng(seed)
    v, f = pg.triangle_soup(n, rng)
    tri_verts = np.ascontiguousarray(v[f].reshape(-1, 9), dtype=np.float32)
    tri_bounds = np.empty((n, 6), np.float32)
    triangle_boxes(tri_verts, tri_bounds, np.empty(6, np.float32))
    return tri_bounds, rng.permutation(n).astype(np.int32), rng


def numpy_bins(tri_bounds, ids, axis, c_min, scale, n_bins):
    """Each triangle's bin, as the kernels define it: int((centre - c_min) * scale), clamped."""
    lo = tri_bounds[ids, axis].astype(np.float64)
    hi = tri_bounds[ids, axis + 3].astype(np.float64)
    return np.clip(((0.5 * (lo + hi) - c_min) * scale).astype(np.int64), 0, n_bins - 1)


def numpy_box(tri_bounds, ids):
    """Box (6,) of the triangles ``ids`` (empty: +inf then -inf)."""
    if len(ids) == 0:
        return np.array([np.inf] * 3 + [-np.inf] * 3, np.float32)
    return np.concatenate([tri_bounds[ids, :3].min(axis=0), tri_bounds[ids, 3:].max(axis=0)])


def binning(tri_bounds, ids, lo, hi, axis):
    """c_min and scale for N_BINS bins of ids[lo:hi] along ``axis``."""
    centres = 0.5 * (tri_bounds[ids[lo:hi], axis] + tri_bounds[ids[lo:hi], axis + 3])
    c_min, c_max = float(np.float32(centres.min())), float(np.float32(centres.max()))
    return c_min, bin_scale(c_min, c_max, N_BINS)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("seed", SEEDS)
def test_centroid_and_triangle_bounds_match_numpy(seed, axis):
    tri_bounds, ids, _ = soup_bounds(seed)
    lo, hi = 17, 17 + 300 + 50 * axis
    sub = ids[lo:hi]
    out = np.empty(6, np.float32)
    centroid_bounds(triangles(tri_bounds, ids), lo, hi, out)
    centres = 0.5 * (tri_bounds[sub, :3].astype(np.float64) + tri_bounds[sub, 3:])
    expected = np.concatenate([centres.min(axis=0), centres.max(axis=0)]).astype(np.float32)
    np.testing.assert_array_equal(out, expected)
    triangle_bounds(triangles(tri_bounds, ids), lo, hi, out)
    np.testing.assert_array_equal(out, numpy_box(tri_bounds, sub))


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("seed", SEEDS)
def test_bins_and_sweep_match_numpy(seed, axis):
    tri_bounds, ids, _ = soup_bounds(seed)
    lo, hi = 5, len(ids) - 3
    c_min, scale = binning(tri_bounds, ids, lo, hi, axis)
    bin_count = np.empty(N_BINS, np.int64)
    bin_box = np.empty((N_BINS, 6), np.float32)
    tri_bins = np.zeros(len(ids), np.uint8)
    tris = triangles(tri_bounds, ids)
    bin_triangles(tris, lo, hi, axis, c_min, scale, N_BINS, bin_count, bin_box, tri_bins)
    bins = numpy_bins(tri_bounds, ids[lo:hi], axis, c_min, scale, N_BINS)
    np.testing.assert_array_equal(tri_bins[lo:hi], bins)
    np.testing.assert_array_equal(bin_count, np.bincount(bins, minlength=N_BINS))
    for b in range(N_BINS):
        np.testing.assert_array_equal(bin_box[b], numpy_box(tri_bounds, ids[lo:hi][bins == b]))

    left_count = np.empty(N_BINS - 1, np.int64)
    right_count = np.empty(N_BINS - 1, np.int64)
    left_box = np.empty((N_BINS - 1, 6), np.float32)
    right_box = np.empty((N_BINS - 1, 6), np.float32)
    sweep_bins(N_BINS, bin_count, bin_box, left_count, left_box, right_count, right_box)
    for j in range(N_BINS - 1):
        left, right = ids[lo:hi][bins <= j], ids[lo:hi][bins > j]
        assert (left_count[j], right_count[j]) == (len(left), len(right))
        np.testing.assert_array_equal(left_box[j], numpy_box(tri_bounds, left))
        np.testing.assert_array_equal(right_box[j], numpy_box(tri_bounds, right))


@pytest.mark.parametrize("split", [0, 3, 7, 14])
@pytest.mark.parametrize("seed", SEEDS)
def test_triangle_partitions_keep_the_ids_and_put_each_on_its_side(seed, split):
    tri_bounds, ids, rng = soup_bounds(seed)
    lo, hi = 11, len(ids) - 7
    axis = int(rng.integers(0, 3))
    c_min, scale = binning(tri_bounds, ids, lo, hi, axis)
    by_box = ids.copy()
    box_left = np.empty(6, np.float32)
    box_right = np.empty(6, np.float32)
    mid = partition_triangles(
        triangles(tri_bounds, by_box),
        lo,
        hi,
        axis,
        c_min,
        scale,
        N_BINS,
        split,
        box_left,
        box_right,
    )
    bins = numpy_bins(tri_bounds, ids[lo:hi], axis, c_min, scale, N_BINS)
    assert mid - lo == np.count_nonzero(bins <= split)
    np.testing.assert_array_equal(by_box[:lo], ids[:lo])  # outside [lo, hi): untouched
    np.testing.assert_array_equal(by_box[hi:], ids[hi:])
    np.testing.assert_array_equal(np.sort(by_box[lo:hi]), np.sort(ids[lo:hi]))
    for side, (a, b), box in (("left", (lo, mid), box_left), ("right", (mid, hi), box_right)):
        side_bins = numpy_bins(tri_bounds, by_box[a:b], axis, c_min, scale, N_BINS)
        assert (side_bins <= split).all() if side == "left" else (side_bins > split).all()
        np.testing.assert_array_equal(box, numpy_box(tri_bounds, by_box[a:b]))

    # The binned partition makes the same moves from the stored bins.
    by_bin = ids.copy()
    tri_bins = np.zeros(len(ids), np.uint8)
    bin_triangles(
        triangles(tri_bounds, by_bin),
        lo,
        hi,
        axis,
        c_min,
        scale,
        N_BINS,
        np.empty(N_BINS, np.int64),
        np.empty((N_BINS, 6), np.float32),
        tri_bins,
    )
    assert partition_binned(triangles(tri_bounds, by_bin), tri_bins, lo, hi, split) == mid
    np.testing.assert_array_equal(by_bin, by_box)


def packed(rng, n):
    """n random rays as records, their ids and the batch they came from."""
    origins = rng.normal(size=(n, 3)).astype(np.float32)
    directions = rng.normal(size=(n, 3)).astype(np.float32)
    tmin = rng.uniform(0, 1, n).astype(np.float32)
    tmax = (tmin + rng.uniform(0, 5, n)).astype(np.float32)
    ray_ids = rng.permutation(n).astype(np.int32)
    rays = new_records(n)
    assert pack_rays(origins, directions, tmin, tmax, ray_ids, rays)
    return rays, ray_ids, np.column_stack([origins, tmin, directions, tmax])


def records(rays, ray_ids):
    """Each record's eight fields, in record order."""
    n = len(ray_ids)
    return np.column_stack([rays[0, : 4 * n].reshape(n, 4), rays[1, : 4 * n].reshape(n, 4)])


@pytest.mark.parametrize("to_back", [False, True])
@pytest.mark.parametrize("density", [0.0, 0.03, 0.5, 0.97, 1.0])
@pytest.mark.parametrize("n", [0, 1, PARTITION_BLOCK - 1, 2 * PARTITION_BLOCK + 1, 3000])
def test_ray_partition_moves_whole_records_to_their_side(n, density, to_back):
    rng = np.random.default_rng(n + int(100 * density))
    rays, ray_ids, batch = packed(rng, n + 9)
    lo, hi = 4, 4 + n
    mask = rng.random(n + 9) < density
    chosen = set(ray_ids[lo:hi][mask[lo:hi]].tolist())
    before_ids = ray_ids.copy()
    mid = partition_by_mask(rays, ray_ids, lo, hi, mask, partition_scratch(), to_back, False)
    first, second = ray_ids[lo:mid], ray_ids[mid:hi]
    front = not to_back
    assert set((first if front else second).tolist()) == chosen
    assert not chosen & set((second if front else first).tolist())
    np.testing.assert_array_equal(np.sort(ray_ids[lo:hi]), np.sort(before_ids[lo:hi]))
    np.testing.assert_array_equal(ray_ids[:lo], before_ids[:lo])
    np.testing.assert_array_equal(ray_ids[hi:], before_ids[hi:])
    np.testing.assert_array_equal(records(rays, ray_ids), batch[ray_ids])  # ids travel along


@pytest.mark.parametrize("dim", [0, 1, 2, 3, 4])
@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("seed", SEEDS)
def test_partition_rays_splits_on_origin_or_slope(seed, axis, dim):
    """Origins compare in float64 against the split; slopes u, v (the direction's components
    after the dominant ``axis``, over its magnitude) as lane < split * |axis lane| in float32."""
    rng = np.random.default_rng(seed)
    n = 1000  # several blocks of comparisons
    rays, ray_ids, batch = packed(rng, n)
    if dim < 3:
        split = float(np.median(batch[:, dim]))
        below = batch[:, dim].astype(np.float64) < split
    else:
        lane = 4 + (axis + 1 if dim == 3 else axis + 2) % 3
        slopes = batch[:, lane] / np.abs(batch[:, 4 + axis])
        split = float(np.median(slopes))
        below = batch[:, lane] < np.float32(split) * np.abs(batch[:, 4 + axis])
    lo, hi = 3, n - 5
    before_ids = ray_ids.copy()
    scratch = np.zeros(n, np.bool_)
    mid = partition_rays(
        rays,
        ray_ids,
        lo,
        hi,
        axis,
        dim,
        split,
        scratch,
        partition_scratch(),
        compare_scratch(),
        False,
    )
    assert set(ray_ids[lo:mid].tolist()) == set(
        before_ids[lo:hi][below[before_ids[lo:hi]]].tolist()
    )
    assert not below[ray_ids[mid:hi]].any()
    np.testing.assert_array_equal(records(rays, ray_ids), batch[ray_ids])
