"""The halves of the storage order (``dacrt.ranges``): their boxes, and traces that use them.

A node's rows follow from its heap number alone; its box must hold exactly its rows' boxes. The
traces where the halves do the first splits (few rays a triangle) must give the brute-force
reference's answers, and the same bits for every strategy, thread count and storage order.
"""

from __future__ import annotations

import assertions as check
import numpy as np
import procedural as pg
import pytest
import reference

import dacrt
from dacrt.chunks import map_on_threads
from dacrt.config import RANGE_LEAF_ROWS
from dacrt.ranges import node_rows, range_tree


def _rows(node, n_rows):
    """Node ``node``'s rows by halving from the root, independently of the closed form."""
    lo, hi = 0, n_rows
    path = bin(node)[3:]  # the bits below the leading one: 0 left, 1 right
    for depth, bit in enumerate(path, start=1):
        j = int(path[:depth], 2)
        mid = ((2 * (j >> 1) + 1) * n_rows) >> depth
        lo, hi = (lo, mid) if bit == "0" else (mid, hi)
    return lo, hi


@pytest.mark.parametrize("n_rows", [1, 2, 7, 8, 9, 17, 1000, 12_345])
def test_every_node_boxes_exactly_its_rows(n_rows):
    rng = np.random.default_rng(n_rows)
    lo = rng.normal(size=(n_rows, 3)).astype(np.float32)
    bounds = np.concatenate([lo, lo + rng.uniform(0, 0.1, (n_rows, 3)).astype(np.float32)], 1)
    for threads in (1, 2):
        tree = range_tree(bounds, lambda f, n, t=threads: map_on_threads(f, n, t))
        assert tree.n_rows == n_rows and tree.root == 1
        leaves = range(1 << tree.depth, 2 << tree.depth)
        sizes = [np.subtract(*node_rows(k, n_rows))[()] * -1 for k in leaves]
        assert 1 <= min(sizes) and max(sizes) <= RANGE_LEAF_ROWS
        assert tree.depth == 0 or -(-n_rows // (1 << (tree.depth - 1))) > RANGE_LEAF_ROWS
        for node in range(1, 2 << tree.depth):
            a, b = node_rows(node, n_rows)
            assert (a, b) == _rows(node, n_rows)
            if node > 1:  # children tile their parent
                pa, pb = node_rows(node >> 1, n_rows)
                assert (a, b) == (
                    (pa, node_rows(node | 1, n_rows)[0]) if node % 2 == 0 else (a, pb)
                )
            expected = np.concatenate([bounds[a:b, :3].min(0), bounds[a:b, 3:].max(0)])
            np.testing.assert_array_equal(tree.boxes[node], expected, err_msg=f"node {node}")


def _sparse_rays_into(vertices, faces, n_rays, seed):
    """Rays aimed at random faces' centres from random points around the mesh: far fewer rays
    than triangles, so the halves make the first splits."""
    rng = np.random.default_rng(seed)
    box = pg.bounds(vertices, faces)
    origins, directions = pg.aimed_rays(box, n_rays, rng)
    return origins, directions


@pytest.mark.parametrize("order", ["morton", "file"])
def test_few_rays_a_triangle_match_the_reference(order):
    """A 12,000-triangle soup, and a 7,200-triangle grid with rays through its vertices and edge
    midpoints, at under one ray a triangle: closest, occluded and count as the brute force
    gives them."""
    rng = np.random.default_rng(61)
    v, f = pg.triangle_soup(12_000, rng, size=0.05)
    o, d = _sparse_rays_into(v, f, 2000, 61)
    scene = dacrt.Scene([(v, f)], order=order)
    hits = scene.closest(o, d)
    check.check_against_reference(hits, v, f, o, d, min_hits=500)
    np.testing.assert_array_equal(scene.occluded(o, d).occluded, reference.occluded(v, f, o, d))
    np.testing.assert_array_equal(scene.count(o, d).count, reference.count(v, f, o, d))

    gv, gf = pg.grid(60, 1.0, alternate=True)
    o1, d1, _ = pg.grid_rays(gv, gf, 60, "vertices", "exact_oblique")
    o2, d2, _ = pg.grid_rays(gv, gf, 60, "midpoints", "normal")
    go, gd = np.concatenate([o1, o2])[::3], np.concatenate([d1, d2])[::3]
    grid = dacrt.Scene([(gv, gf)], order=order)
    assert len(go) < len(gf)
    hits = grid.closest(go, gd)
    assert np.all(hits.prim >= 0), "a ray through a vertex or an edge went through the grid"
    check.check_against_reference(hits, gv, gf, go, gd, min_hits=len(go), min_clear=0)
    np.testing.assert_array_equal(grid.count(go, gd).count, reference.count(gv, gf, go, gd))


def test_few_rays_a_triangle_same_bits_for_every_strategy_threads_and_order():
    rng = np.random.default_rng(62)
    v, f = pg.triangle_soup(30_000, rng, size=0.04)
    o, d = _sparse_rays_into(v, f, 40_000, 62)  # enough for two threads, under 1.5 a triangle
    expected = dacrt.Scene([(v, f)], order="file").closest(o, d, strategy="sah", threads=1)
    assert np.count_nonzero(expected.prim >= 0) > 1000
    for order in ("morton", "file"):
        scene = dacrt.Scene([(v, f)], order=order)
        for strategy in dacrt.STRATEGIES:
            for threads in (1, 2):
                hits = scene.closest(o, d, strategy=strategy, threads=threads)
                check.assert_bitwise_equal(hits, expected, f"{order}, {strategy}, {threads}")
