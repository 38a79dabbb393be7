"""Self-checks of the test helpers: the numpy reference against Embree, and the procedural meshes.

If these fail, the engine tests that lean on the helpers cannot be trusted.
"""

from __future__ import annotations

import numpy as np
import procedural as pg
import pytest
import reference


@pytest.mark.parametrize("seed", [0, 1])
def test_reference_matches_embree_on_soup(seed):
    pytest.importorskip("embreex")
    from bench.embree import Embree

    rng = np.random.default_rng(seed)
    v, f = pg.triangle_soup(800, rng)
    o, d = pg.mixed_rays(pg.bounds(v), 800, rng)
    tmin = rng.uniform(0.0, 0.1, len(o))
    tmax = tmin + rng.uniform(0.5, 4.0, len(o))
    ref = reference.closest(v, f, o, d, tmin, tmax)
    emb = Embree([(v, f)]).closest(o, d, tmin, tmax)
    assert ref.hit.sum() > 80
    assert np.mean(ref.hit == emb.hit) >= 0.999
    same = ref.hit & (ref.prim == emb.prim)
    assert same.sum() >= 0.99 * ref.hit.sum()
    np.testing.assert_allclose(ref.t[same], emb.t[same], rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(ref.u[same], emb.u[same], atol=1e-3)
    np.testing.assert_allclose(ref.v[same], emb.v[same], atol=1e-3)
    np.testing.assert_array_equal(reference.occluded(v, f, o, d, tmin, tmax), ref.hit)
    assert np.mean(Embree([(v, f)]).occluded(o, d, tmin, tmax) == ref.hit) >= 0.999


def test_reference_blocks_agree_with_one_block(monkeypatch):
    """Splitting the work into ray and triangle blocks changes nothing, ties included."""
    rng = np.random.default_rng(2)
    v, f = pg.triangle_soup(300, rng)
    f = np.concatenate([f, f])  # every triangle twice: ties everywhere
    o, d = pg.mixed_rays(pg.bounds(v), 300, rng)
    whole = reference.closest_bracket(v, f, o, d)
    monkeypatch.setattr(reference, "PAIRS_PER_BLOCK", 97)
    blocked = reference.closest_bracket(v, f, o, d)
    for a, b in zip(whole, blocked):
        for x, y in zip(a if isinstance(a, tuple) else [a], b if isinstance(b, tuple) else [b]):
            np.testing.assert_array_equal(x, y)
    assert np.all(whole.exact.prim[whole.exact.hit] < 300), "a tie did not go to the lower index"
    np.testing.assert_array_equal(
        whole.outer_second_t[whole.exact.hit], whole.outer.t[whole.exact.hit]
    )


def test_reference_single_triangle_and_conventions():
    v, f = pg.single_triangle()
    o = np.array([[0.25, 0.5, 2.0], [0.25, 0.5, 2.0], [0.9, 0.9, 1.0], [0.25, 0.5, 2.0]])
    d = np.array([[0, 0, -1], [0, 0, -2], [0, 0, -1], [0, 0, -1.0]])
    hits = reference.closest(v, f, o, d, tmax=[np.inf, np.inf, np.inf, 1.0])
    np.testing.assert_array_equal(hits.prim, [0, 0, -1, -1])
    np.testing.assert_allclose(hits.t, [2.0, 1.0, np.inf, np.inf])
    np.testing.assert_allclose(hits.u, [0.25, 0.25, 0, 0])
    np.testing.assert_allclose(hits.v, [0.5, 0.5, 0, 0])
    np.testing.assert_allclose(
        reference.normals(v, f, hits.prim), [[0, 0, 1], [0, 0, 1], [0, 0, 0], [0, 0, 0]]
    )
    empty = reference.closest(v, f, np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty.t.shape == (0,) and empty.prim.dtype == np.int64


def test_reference_never_hits_degenerate_triangles():
    rng = np.random.default_rng(3)
    v, f, targets = pg.degenerate_triangles(rng, 100)
    assert reference.degenerate(v, f).all()
    o, d = pg.rays_at(targets, pg.unit_vectors(len(targets), rng), 0.5)
    assert not reference.occluded(v, f, o, d).any()


@pytest.mark.parametrize("kind", ["icosphere", "uv_sphere", "perturbed"])
def test_procedural_spheres_are_closed_and_outward(kind):
    trimesh = pytest.importorskip("trimesh")
    if kind == "uv_sphere":
        v, f = pg.uv_sphere(12, 20)
    else:
        v, f = pg.icosphere(3)
        if kind == "perturbed":
            v = pg.perturb_radially(v, np.random.default_rng(4), 0.15)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0, "faces point inwards"
    r_in = pg.inner_radius(v, f)
    assert 0.5 < r_in < 1.0


@pytest.mark.parametrize("alternate", [False, True])
def test_procedural_grid_covers_the_square_once(alternate):
    v, f = pg.grid(8, 2.0, alternate=alternate)
    n = reference.normals(v, f, np.arange(len(f)))
    np.testing.assert_array_equal(n, np.tile([0.0, 0.0, 1.0], (len(f), 1)))
    _, e1, e2 = reference.triangles(v, f)
    np.testing.assert_allclose(np.linalg.norm(np.cross(e1, e2), axis=1).sum() / 2, 4.0)
    assert len(pg.two_sided_edges(f)) == 3 * 8 * 8 - 2 * 8  # all edges but the 4 * 8 boundary ones
