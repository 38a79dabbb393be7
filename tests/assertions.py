"""Checks shared by the engine tests: result layout, agreement with the reference and with Embree.

Every check compares an engine result (``dacrt`` hits: ``t``, ``mesh``, ``prim``, ``u``, ``v``,
``normal``) with something independent and fails with a message naming the first offending ray.

Tolerances. The engine works in float32, the reference in float64, so near a triangle's edge or
at a grazing angle the two may honestly disagree. The checks therefore

- bracket hit/miss between a shrunk and a widened reference acceptance
  (``reference.closest_bracket``) instead of demanding the exact verdict;
- compare ``prim``, ``u`` and ``v`` only on *clear* rays: the reference hits well inside one
  triangle, with no other triangle near in ``t`` and not at a grazing angle;
- allow ``t`` an error of ``T_RTOL * t`` plus ``T_ATOL`` of the scene's scale, divided by the
  cosine of the incidence angle (a plane error becomes a ``t`` error / cos).
"""

from __future__ import annotations

import numpy as np
import reference

T_RTOL = 1e-4
T_ATOL = 1e-5  # in units of the scene scale (its diagonal plus the origin's distance from it)
UV_ATOL = 2e-4
BARY_SLACK = 1e-6
GRAZING_COS = 1e-2  # below this cosine of incidence a ray is grazing: no exact comparison there
HIT_DTYPES = {"t": np.float32, "mesh": np.int32, "prim": np.int32, "u": np.float32, "v": np.float32}


def _first(mask) -> str:
    """'k rays, first index i' for a boolean mask of failures."""
    idx = np.flatnonzero(mask)
    return f"{len(idx)} rays, first index {idx[0]}" if len(idx) else "none"


def absdiff(a, b) -> np.ndarray:
    """|a - b| in float64, 0 where a == b (so inf - inf gives 0, not nan and a warning)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(a == b, 0.0, np.abs(a - b))


def global_prim(hits, mesh_offsets) -> np.ndarray:
    """(n,) int64 global triangle index of each engine hit, ``-1`` on a miss."""
    mesh = np.asarray(hits.mesh, dtype=np.int64)
    prim = np.asarray(hits.prim, dtype=np.int64)
    offsets = np.asarray(mesh_offsets, dtype=np.int64)
    return np.where(mesh >= 0, offsets[np.maximum(mesh, 0)] + prim, -1)


def scene_scale(vertices, origins) -> np.ndarray:
    """(n,) float64 length scale per ray: the scene's diagonal plus the origin's distance from its
    centre."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    if len(v) == 0:
        return np.linalg.norm(o, axis=1) + 1.0
    lo, hi = v.min(axis=0), v.max(axis=0)
    return np.linalg.norm(hi - lo) + np.linalg.norm(o - (lo + hi) / 2, axis=1)


def incidence_cos(vertices, faces, prim, directions) -> np.ndarray:
    """(n,) float64 |cos| between each ray and the normal of face ``prim``
    (0 where ``prim < 0``)."""
    n = reference.normals(vertices, faces, prim)
    d = np.asarray(directions, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.abs(np.einsum("ij,ij->i", n, d)) / np.linalg.norm(d, axis=1)
    return np.nan_to_num(c)


def t_tolerance(t, directions, scale, cos) -> np.ndarray:
    """(n,) float64 allowed |engine t - reference t| (see module docstring)."""
    d_len = np.linalg.norm(np.asarray(directions, dtype=np.float64), axis=1)
    t = np.where(np.isfinite(t), t, 0.0)
    return T_RTOL * np.abs(t) + T_ATOL * scale / (d_len * np.maximum(cos, GRAZING_COS))


def check_layout(hits, n_rays) -> None:
    """Shapes and dtypes of a closest-hit result, and the miss convention (inf, -1, 0)."""
    for name, dtype in HIT_DTYPES.items():
        a = getattr(hits, name)
        assert isinstance(a, np.ndarray), f"hits.{name} is {type(a).__name__}, not ndarray"
        assert a.dtype == dtype, f"hits.{name}.dtype is {a.dtype}, expected {np.dtype(dtype)}"
        assert a.shape == (n_rays,), f"hits.{name}.shape is {a.shape}, expected {(n_rays,)}"
    assert hits.normal.dtype == np.float32, f"hits.normal.dtype is {hits.normal.dtype}"
    assert hits.normal.shape == (n_rays, 3), f"hits.normal.shape is {hits.normal.shape}"
    miss = hits.prim < 0
    assert np.array_equal(miss, hits.mesh < 0), (
        f"mesh and prim disagree on misses: {_first(miss != (hits.mesh < 0))}"
    )
    assert np.all(hits.prim[miss] == -1) and np.all(hits.mesh[miss] == -1), (
        "a miss has mesh/prim other than -1"
    )
    assert np.array_equal(miss, ~np.isfinite(hits.t)), (
        f"finite t on a miss or inf t on a hit: {_first(miss == np.isfinite(hits.t))}"
    )
    assert np.all(np.isposinf(hits.t[miss])), "a miss has t other than +inf"
    assert np.all(hits.u[miss] == 0) and np.all(hits.v[miss] == 0), (
        f"u/v not 0 on a miss: {_first(miss & ((hits.u != 0) | (hits.v != 0)))}"
    )
    assert np.all(hits.normal[miss] == 0), (
        f"normal not 0 on a miss: {_first(miss & np.any(hits.normal != 0, axis=1))}"
    )
    assert not np.any(np.isnan(hits.t)), f"nan t: {_first(np.isnan(hits.t))}"


def check_geometry(hits, vertices, faces, origins, directions, mesh_offsets=None) -> None:
    """Each hit lies on its triangle: ``o + t d`` equals the barycentric point; normals are right.

    vertices, faces : the concatenated scene (global face numbering, see ``procedural.concat``).
    """
    offsets = np.array([0, len(faces)]) if mesh_offsets is None else mesh_offsets
    gp = global_prim(hits, offsets)
    hit = gp >= 0
    if not np.any(hit):
        return
    assert np.all(gp[hit] < len(faces)), "global prim out of range"
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    u = hits.u.astype(np.float64)
    v = hits.v.astype(np.float64)
    bad = hit & ((u < -BARY_SLACK) | (v < -BARY_SLACK) | (u + v > 1 + BARY_SLACK))
    assert not np.any(bad), f"barycentrics outside the triangle: {_first(bad)}"

    cos = incidence_cos(vertices, faces, gp, d)
    scale = scene_scale(vertices, o)
    along_ray = o + hits.t.astype(np.float64)[:, None] * d
    on_triangle = reference.barycentric_points(vertices, faces, gp, u, v)
    dist = np.linalg.norm(along_ray - on_triangle, axis=1)
    tol = 2 * T_ATOL * scale / np.maximum(cos, GRAZING_COS)
    bad = hit & ~(dist <= tol)
    assert not np.any(bad), (
        f"o + t*d is not the point (1-u-v)p0+u*p1+v*p2: {_first(bad)}; "
        f"distance {dist[bad][:3]} > tolerance {tol[bad][:3]}"
    )

    normal = hits.normal.astype(np.float64)
    length = np.linalg.norm(normal, axis=1)
    bad = hit & ~(np.abs(length - 1) <= 1e-5)
    assert not np.any(bad), f"normal not unit length: {_first(bad)}; lengths {length[bad][:3]}"
    expected = reference.normals(vertices, faces, gp)
    # A sliver's float32 cross product loses bits in proportion to |e1||e2| / |e1 x e2|.
    p0, e1, e2 = reference.triangles(vertices, np.asarray(faces)[np.maximum(gp, 0)])
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = (
            np.linalg.norm(e1, axis=1)
            * np.linalg.norm(e2, axis=1)
            / np.linalg.norm(np.cross(e1, e2), axis=1)
        )
    err = np.linalg.norm(normal - expected, axis=1)
    bad = hit & ~(err <= 1e-5 + 1e-6 * cond)
    assert not np.any(bad), (
        f"normal is not normalise((p1-p0)x(p2-p0)): {_first(bad)}; "
        f"got {normal[bad][:2]}, expected {expected[bad][:2]}"
    )


def check_against_reference(
    hits,
    vertices,
    faces,
    origins,
    directions,
    tmin=None,
    tmax=None,
    *,
    mesh_offsets=None,
    min_hits=1,
    min_clear=0.9,
    eps=1e-4,
    **filters,
):
    """Compare an engine closest-hit result with the brute-force reference (see module docstring).

    Parameters
    ----------
    hits : engine result for ``n`` rays
    vertices : (v, 3) float, faces : (f, 3) int
      The concatenated scene, global face numbering.
    origins, directions : (n, 3) float
    tmin, tmax : None, float or (n,) float
    mesh_offsets : (m+1,) int or None
      Global index of each mesh's first face (None: one mesh).
    min_hits : int
      The reference must hit at least this many rays (guards against a vacuous test).
    min_clear : float
      At least this fraction of the reference's hits must be clear (prim compared exactly).
    filters : ``cull``, ``ray_masks``, ``face_masks`` of the reference (faces a ray ignores).

    Returns
    -------
    bracket : reference.Bracket
    """
    n = len(origins)
    offsets = np.array([0, len(faces)]) if mesh_offsets is None else np.asarray(mesh_offsets)
    br = reference.closest_bracket(
        vertices, faces, origins, directions, tmin, tmax, eps=eps, **filters
    )
    ex, inner, outer = br.exact, br.inner, br.outer
    assert ex.hit.sum() >= min_hits, (
        f"vacuous test: the reference hits only {ex.hit.sum()} of {n} rays"
    )

    gp = global_prim(hits, offsets)
    eng_hit = gp >= 0
    d = np.asarray(directions, dtype=np.float64)
    scale = scene_scale(vertices, origins)
    cos_eng = incidence_cos(vertices, faces, gp, d)
    cos_inner = incidence_cos(vertices, faces, inner.prim, d)
    cos_ex = incidence_cos(vertices, faces, ex.prim, d)
    t = hits.t.astype(np.float64)

    # Hit/miss, bracketed.
    bad = inner.hit & (cos_inner > GRAZING_COS / 10) & ~eng_hit
    assert not np.any(bad), (
        f"engine misses rays that hit well inside a triangle: {_first(bad)}; "
        f"reference prim {inner.prim[bad][:5]}, t {inner.t[bad][:5]}"
    )
    bad = eng_hit & (cos_eng > GRAZING_COS / 10) & ~outer.hit
    assert not np.any(bad), (
        f"engine hits where the reference (with slack) misses: {_first(bad)}; "
        f"engine prim {gp[bad][:5]}, t {t[bad][:5]}"
    )

    # t, bracketed: no closer than the widened reference, no farther than the shrunk one.
    tol_eng = t_tolerance(t, d, scale, cos_eng)
    bad = eng_hit & (cos_eng > GRAZING_COS / 10) & (t < outer.t - tol_eng)
    assert not np.any(bad), (
        f"engine t closer than any reference hit: {_first(bad)}; "
        f"engine {t[bad][:3]}, reference {outer.t[bad][:3]}"
    )
    tol_inner = t_tolerance(inner.t, d, scale, cos_inner)
    bad = inner.hit & (cos_inner > GRAZING_COS / 10) & (t > inner.t + tol_inner)
    assert not np.any(bad), (
        f"engine t beyond a clear reference hit: {_first(bad)}; "
        f"engine {t[bad][:3]}, reference {inner.t[bad][:3]}"
    )

    # t in the requested range.
    lo, hi = reference.ray_ranges(n, tmin, tmax)
    bad = eng_hit & ((hits.t < lo.astype(np.float32)) | (hits.t > hi.astype(np.float32)))
    assert not np.any(bad), (
        f"t outside [tmin, tmax]: {_first(bad)}; "
        f"t {hits.t[bad][:3]}, tmin {lo[bad][:3]}, tmax {hi[bad][:3]}"
    )

    # Clear rays: exact prim, t, u, v.
    tol_ex = t_tolerance(ex.t, d, scale, cos_ex)
    gap = 10 * tol_ex
    clear = (
        ex.hit
        & (inner.prim == ex.prim)
        & (outer.prim == ex.prim)
        & (br.outer_second_t > ex.t + gap)
        & (cos_ex > GRAZING_COS)
    )
    assert clear.sum() >= min_clear * ex.hit.sum(), (
        f"vacuous test: only {clear.sum()} of {ex.hit.sum()} reference hits are clear"
    )
    bad = clear & (gp != ex.prim)
    assert not np.any(bad), (
        f"engine hit a different triangle: {_first(bad)}; "
        f"engine {gp[bad][:5]}, reference {ex.prim[bad][:5]}"
    )
    bad = clear & ~(absdiff(t, ex.t) <= tol_ex)
    assert not np.any(bad), (
        f"t differs from the reference: {_first(bad)}; "
        f"engine {t[bad][:3]}, reference {ex.t[bad][:3]}"
    )
    for name in ("u", "v"):
        got, want = getattr(hits, name).astype(np.float64), getattr(ex, name)
        bad = clear & ~(absdiff(got, want) <= UV_ATOL)
        assert not np.any(bad), (
            f"{name} differs from the reference: {_first(bad)}; "
            f"engine {got[bad][:3]}, reference {want[bad][:3]}"
        )

    # Mesh numbering of the reference's clear hits.
    ref_mesh = np.searchsorted(offsets, ex.prim, side="right") - 1
    bad = clear & (
        (hits.mesh != ref_mesh) | (hits.prim != ex.prim - offsets[np.maximum(ref_mesh, 0)])
    )
    assert not np.any(bad), f"(mesh, prim) do not map to the global triangle: {_first(bad)}"
    return br


def check_occluded_against_reference(
    occ, vertices, faces, origins, directions, tmin=None, tmax=None, *, eps=1e-4, **filters
):
    """Engine ``occluded`` within the reference's shrunk and widened verdicts (grazing rays
    excepted); ``filters`` as for ``check_against_reference``."""
    br = reference.closest_bracket(
        vertices, faces, origins, directions, tmin, tmax, eps=eps, **filters
    )
    d = np.asarray(directions, dtype=np.float64)
    cos_inner = incidence_cos(vertices, faces, br.inner.prim, d)
    assert occ.dtype == np.bool_ and occ.shape == (len(origins),), (
        f"occluded: dtype {occ.dtype}, shape {occ.shape}"
    )
    bad = br.inner.hit & (cos_inner > GRAZING_COS / 10) & ~occ
    assert not np.any(bad), f"occluded is False for rays that clearly hit: {_first(bad)}"
    bad = occ & ~br.outer.hit
    assert not np.any(bad), (
        f"occluded is True for rays that the reference (with slack) misses: {_first(bad)}"
    )
    return br


def check_against_embree(
    hits,
    oracle,
    vertices,
    faces,
    origins,
    directions,
    *,
    mesh_offsets=None,
    min_agreement=0.999,
    min_hits=1,
):
    """Agreement with Embree: hit/miss on >= ``min_agreement`` of rays, ``t`` on rays both hit.

    ``oracle`` is an ``oracles.embree.MeshHits`` for the same rays; vertices/faces the concatenated
    scene.
    """
    n = len(origins)
    offsets = np.array([0, len(faces)]) if mesh_offsets is None else np.asarray(mesh_offsets)
    gp = global_prim(hits, offsets)
    emb_gp = np.where(oracle.mesh >= 0, offsets[np.maximum(oracle.mesh, 0)] + oracle.prim, -1)
    eng_hit, emb_hit = gp >= 0, emb_gp >= 0
    assert emb_hit.sum() >= min_hits, f"vacuous test: Embree hits only {emb_hit.sum()} of {n} rays"
    agree = np.mean(eng_hit == emb_hit) if n else 1.0
    assert agree >= min_agreement, (
        f"hit/miss agrees with Embree on {agree:.5f} of rays (< {min_agreement}); "
        f"engine-only hits {_first(eng_hit & ~emb_hit)}, "
        f"Embree-only hits {_first(emb_hit & ~eng_hit)}"
    )
    both = eng_hit & emb_hit
    d = np.asarray(directions, dtype=np.float64)
    scale = scene_scale(vertices, origins)
    cos = incidence_cos(vertices, faces, emb_gp, d)
    t = hits.t.astype(np.float64)
    close = absdiff(t, oracle.t) <= t_tolerance(oracle.t, d, scale, cos)
    frac = np.mean(close[both]) if np.any(both) else 1.0
    assert frac >= min_agreement, (
        f"t agrees with Embree on {frac:.5f} of rays both hit; differing: {_first(both & ~close)}"
    )
    same = both & (gp == emb_gp) & (cos > GRAZING_COS)
    bad = same & ~close
    assert not np.any(bad), (
        f"t differs from Embree on the same triangle: {_first(bad)}; "
        f"engine {t[bad][:3]}, Embree {oracle.t[bad][:3]}"
    )
    for name in ("u", "v"):
        got, want = getattr(hits, name).astype(np.float64), getattr(oracle, name)
        bad = same & ~(absdiff(got, want) <= 1e-3)
        assert not np.any(bad), f"{name} differs from Embree on the same triangle: {_first(bad)}"


def assert_bitwise_equal(a, b, what="") -> None:
    """Two closest-hit results are bitwise identical in t, mesh, prim, u, v and normal."""
    for name in ("t", "mesh", "prim", "u", "v", "normal"):
        x, y = np.ascontiguousarray(getattr(a, name)), np.ascontiguousarray(getattr(b, name))
        assert x.dtype == y.dtype and x.shape == y.shape, (
            f"{what}: {name} dtype/shape {x.dtype}{x.shape} vs {y.dtype}{y.shape}"
        )
        xb = x.view(np.uint8).reshape(len(x), -1) if len(x) else x
        yb = y.view(np.uint8).reshape(len(y), -1) if len(y) else y
        differ = np.any(xb != yb, axis=1) if len(x) else np.zeros(0, bool)
        assert not np.any(differ), (
            f"{what}: {name} differs bitwise: {_first(differ)}; {x[differ][:3]} vs {y[differ][:3]}"
        )
