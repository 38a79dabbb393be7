"""dacrt.rays: a ray batch packed into records reads back field by field, in the order of its
ids; a bad ray of each kind makes the pack invalid; the uniform-origin check compares bits; a
swap moves whole records with their ids."""

from __future__ import annotations

import numpy as np
import pytest

from dacrt import rays

FIELDS = {"origin": rays.ORIGIN, "tmin": rays.TMIN, "direction": rays.DIRECTION, "t": rays.BEST_T}


def batch(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    origins = rng.uniform(-5, 5, (n, 3)).astype(np.float32)
    directions = rng.normal(size=(n, 3)).astype(np.float32)
    tmin = rng.uniform(0, 1, n).astype(np.float32)
    tmax = (tmin + rng.uniform(0, 10, n)).astype(np.float32)
    return origins, directions, tmin, tmax


def read(records: np.ndarray, name: str, r: int, lanes: int = 1) -> list[float]:
    return [float(rays.field(records, FIELDS[name] + a, r)) for a in range(lanes)]


@pytest.mark.parametrize("n", [0, 1, 1000, 4097])
def test_new_records_hold_n_rays_in_rows_that_are_no_power_of_two(n):
    records = rays.new_records(n)
    assert records.dtype == np.float32 and records.shape[0] == 2
    m = records.shape[1] // 4
    assert records.shape[1] == 4 * m and m >= n
    assert m % rays.ROW_ALIGN == rays.ROW_SKEW  # quads of one record never share a cache set


@pytest.mark.parametrize("n", [1, 31, 100])  # within one pack block and across several
def test_packed_records_read_back_in_the_order_of_their_ids(n):
    origins, directions, tmin, tmax = batch(2 * n)
    ray_ids = np.random.default_rng(1).permutation(2 * n)[:n].astype(np.int32)
    records = rays.new_records(n)
    assert rays.pack_rays(origins, directions, tmin, tmax, ray_ids, records)
    for r, ray in enumerate(ray_ids):
        assert read(records, "origin", r, 3) == origins[ray].tolist()
        assert read(records, "direction", r, 3) == directions[ray].tolist()
        assert read(records, "tmin", r) == [tmin[ray]] and read(records, "t", r) == [tmax[ray]]
    best_t = np.full(2 * n, -1.0, np.float32)
    rays.unpack_best_t(records, ray_ids, best_t)
    assert np.array_equal(best_t[ray_ids], tmax[ray_ids])  # back in ray order
    untouched = np.setdiff1d(np.arange(2 * n), ray_ids)
    assert np.all(best_t[untouched] == -1.0)


BAD = {
    "nan origin": ("origins", (0,), np.nan),
    "infinite origin": ("origins", (2,), np.inf),
    "nan direction": ("directions", (1,), np.nan),
    "infinite direction": ("directions", (0,), -np.inf),
    "zero direction": ("directions", slice(None), 0.0),
    "nan tmin": ("tmin", (), np.nan),
    "infinite tmin": ("tmin", (), -np.inf),
    "tmin above tmax": ("tmin", (), 100.0),
    "nan tmax": ("tmax", (), np.nan),
}


@pytest.mark.parametrize("kind", list(BAD))
@pytest.mark.parametrize("bad_ray", [0, 37, 99])
def test_one_bad_ray_makes_the_pack_invalid(kind, bad_ray):
    arrays = dict(zip(("origins", "directions", "tmin", "tmax"), batch(100)))
    name, where, value = BAD[kind]
    arrays[name][(bad_ray, *where) if where != slice(None) else (bad_ray, where)] = value
    ids = np.arange(100, dtype=np.int32)
    assert not rays.pack_rays(*arrays.values(), ids, rays.new_records(100))
    others = np.delete(ids, bad_ray)  # the same batch without that ray is valid
    assert rays.pack_rays(*arrays.values(), others, rays.new_records(99))


def test_an_infinite_tmax_is_valid():
    origins, directions, tmin, tmax = batch(10)
    tmax[:] = np.inf
    ids = np.arange(10, dtype=np.int32)
    assert rays.pack_rays(origins, directions, tmin, tmax, ids, rays.new_records(10))


def packed(origins: np.ndarray, tmin: np.ndarray) -> np.ndarray:
    n = len(origins)
    directions = np.tile(np.float32([0, 0, 1]), (n, 1))
    records = rays.new_records(n)
    ids = np.arange(n, dtype=np.int32)
    rays.pack_rays(origins, directions, tmin, np.full(n, np.inf, np.float32), ids, records)
    return records


@pytest.mark.parametrize("odd_one", [1, 300, 999])  # in the first check block and later ones
def test_a_uniform_origin_is_the_same_bits_for_every_ray(odd_one):
    n = 1000
    origins = np.tile(np.float32([1, 2, 3]), (n, 1))
    tmin = np.zeros(n, np.float32)
    assert rays.uniform_origin(packed(origins, tmin), n)
    moved = origins.copy()
    moved[odd_one, 2] = np.nextafter(np.float32(3), np.float32(4))
    assert not rays.uniform_origin(packed(moved, tmin), n)
    later = tmin.copy()
    later[odd_one] = 0.5
    assert not rays.uniform_origin(packed(origins, later), n)
    signed = tmin.copy()
    signed[odd_one] = -0.0  # equal as numbers, not as bits
    assert not rays.uniform_origin(packed(origins, signed), n)
    assert rays.uniform_origin(packed(moved, tmin), odd_one)  # only the first n records count


def test_no_records_have_no_uniform_origin():
    assert not rays.uniform_origin(rays.new_records(0), 0)


@pytest.mark.parametrize("fixed_origin", [False, True])
def test_a_swap_exchanges_whole_records_and_their_ids(fixed_origin):
    origins, directions, tmin, tmax = batch(8)
    ids = np.arange(8, dtype=np.int32)
    records = rays.new_records(8)
    rays.pack_rays(origins, directions, tmin, tmax, ids, records)
    before = records.copy()
    rays.swap_rays(rays.quad_view(records), ids, 2, 5, fixed_origin)
    assert ids.tolist() == [0, 1, 5, 3, 4, 2, 6, 7]
    quads = before.reshape(2, -1, 4)[:, :8]  # records past n are uninitialised
    after = records.reshape(2, -1, 4)[:, :8]
    moved = [rays.DIRECTION_QUAD] if fixed_origin else [rays.ORIGIN_QUAD, rays.DIRECTION_QUAD]
    for quad in (rays.ORIGIN_QUAD, rays.DIRECTION_QUAD):
        expected = quads[quad].copy()
        if quad in moved:
            expected[[2, 5]] = expected[[5, 2]]
        assert np.array_equal(after[quad], expected)
