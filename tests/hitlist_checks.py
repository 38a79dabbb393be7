"""Checks of ``dacrt.HitList`` answers: layout and order, agreement with the reference's
crossings (``reference.all_hits``), with ``closest``, and with another HitList bit for bit."""

from __future__ import annotations

import numpy as np
import reference

import dacrt

HITLIST_DTYPES = {"t": np.float32, "mesh": np.int32, "prim": np.int32, "u": np.float32}
HITLIST_FIELDS = ("offsets", "t", "mesh", "prim", "u", "v", "normal", "truncated")


def check_hitlist_layout(hl, n_rays):
    """Shapes, dtypes and CSR structure of a HitList; each ray's hits sorted by (t, mesh, prim)."""
    assert isinstance(hl, dacrt.HitList) and len(hl) == n_rays
    assert hl.offsets.dtype == np.int64 and hl.offsets.shape == (n_rays + 1,)
    assert hl.offsets[0] == 0 and np.all(np.diff(hl.offsets) >= 0)
    m = int(hl.offsets[-1])
    for name in ("t", "mesh", "prim", "u", "v"):
        a = getattr(hl, name)
        dtype = HITLIST_DTYPES.get(name, np.float32)
        assert a.dtype == dtype and a.shape == (m,), f"{name}: {a.dtype} {a.shape}"
    assert hl.normal.dtype == np.float32 and hl.normal.shape == (m, 3)
    assert hl.truncated.dtype == np.bool_ and hl.truncated.shape == (n_rays,)
    assert np.all(np.isfinite(hl.t)) and np.all(hl.mesh >= 0) and np.all(hl.prim >= 0)
    ray = np.repeat(np.arange(n_rays), np.diff(hl.offsets))
    same = ray[1:] == ray[:-1]
    t0, t1 = hl.t[:-1], hl.t[1:]
    key0 = hl.mesh[:-1].astype(np.int64) << 32 | hl.prim[:-1]
    key1 = hl.mesh[1:].astype(np.int64) << 32 | hl.prim[1:]
    in_order = (t1 > t0) | ((t1 == t0) & (key1 > key0))
    bad = np.flatnonzero(same & ~in_order)
    assert not len(bad), f"hits of ray {ray[bad[0]]} not sorted by (t, mesh, prim)"


def check_hits_match_reference(hl, ref, vertices, faces, offsets, origins, directions, what=""):
    """The engine's crossings are the reference's: the same triangles per ray; t, u, v and the
    normal to float32 tolerance (a grazing ray's t and u, v within a looser bound)."""
    n_rays = len(origins)
    counts = np.diff(hl.offsets)
    bad = np.flatnonzero(counts != ref.count)
    assert not len(bad), (
        f"{what}: {len(bad)} rays with another number of hits, first ray {bad[0]}: origin "
        f"{origins[bad[0]].tolist()}, direction {directions[bad[0]].tolist()}, "
        f"expected {ref.count[bad[0]]}, got {counts[bad[0]]}"
    )
    ray = np.repeat(np.arange(n_rays), counts)
    gprim = np.asarray(offsets)[hl.mesh] + hl.prim
    ours = np.lexsort((gprim, ray))
    theirs = np.lexsort((ref.prim, ref.ray))
    bad = np.flatnonzero(gprim[ours] != ref.prim[theirs])
    assert not len(bad), (
        f"{what}: other triangles, first on ray {ray[ours][bad[0]]}: "
        f"expected {ref.prim[theirs][bad[0]]}, got {gprim[ours][bad[0]]}"
    )
    t_ref, u_ref, v_ref = ref.t[theirs], ref.u[theirs], ref.v[theirs]
    d = np.asarray(directions, np.float64)[ray[ours]]
    normal = reference.normals(vertices, faces, ref.prim[theirs])
    cos = np.abs(np.einsum("ij,ij->i", normal, d)) / np.linalg.norm(d, axis=1)
    scale = np.linalg.norm(np.ptp(np.asarray(vertices, np.float64), axis=0))
    slack = 1.0 / np.maximum(cos, 1e-2)
    t_tol = 2e-6 * (t_ref + scale / np.linalg.norm(d, axis=1)) * slack
    t_err = np.abs(hl.t[ours] - t_ref)
    assert np.all(t_err <= t_tol), f"{what}: t off by {t_err.max()}"
    uv_err = np.maximum(np.abs(hl.u[ours] - u_ref), np.abs(hl.v[ours] - v_ref))
    assert np.all(uv_err <= 1e-4 * slack), f"{what}: u, v off by {uv_err.max()}"
    n_err = np.abs(hl.normal[ours] - normal).max(initial=0.0)
    assert n_err <= 1e-5, f"{what}: normals off by {n_err}"


def check_first_hit_is_closest(hl, hits):
    """For rays through no edge, a list's first hit is ``closest``'s, bit for bit."""
    has = np.diff(hl.offsets) > 0
    np.testing.assert_array_equal(has, hits.prim >= 0)
    first = hl.offsets[:-1][has]
    for name in ("t", "mesh", "prim", "u", "v", "normal"):
        np.testing.assert_array_equal(getattr(hl, name)[first], getattr(hits, name)[has], name)


def assert_same_hitlist(a, b, what):
    for name in HITLIST_FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), f"{what}: {name}")
