"""Watertightness: rays through shared vertices and edges, and rays from inside closed meshes.

A closed or gap-free mesh leaves no crack for a ray to slip through, however exactly the ray
hits a shared vertex or edge. These tests fire such rays, for every strategy, and assert hits.
"""

from __future__ import annotations

import numpy as np
import procedural as pg
import pytest

import dacrt

GRID_N = 16  # quads per side; a power of two keeps vertices and midpoints exact in float32


def _grid(plane, alternate):
    """Grid vertices and faces, the plane's unit normal, and a matrix taking grid axes to world."""
    v, f = pg.grid(GRID_N, 1.0, alternate=alternate)
    if plane == "flat":
        return v, f, np.array([0.0, 0.0, 1.0]), np.eye(3)
    if plane == "jittered":
        # Interior vertices moved in the plane by up to a quarter cell: no longer dyadic, still flat
        # and unfolded, so a ray exactly through a vertex meets rounding in every incident face.
        v = v.astype(np.float64)
        inner = np.zeros(len(v), bool)
        inner[pg.grid_interior_vertices(GRID_N)] = True
        v[inner, :2] += np.random.default_rng(31).uniform(-0.25, 0.25, (inner.sum(), 2)) / GRID_N
        return v.astype(np.float32), f, np.array([0.0, 0.0, 1.0]), np.eye(3)
    rot = pg.rotation([1.0, 2.0, 0.5], 0.7)
    offset = (0.25, -0.5, 0.125) if plane == "tilted" else (1000.0, -2000.0, 500.0)  # "far"
    return pg.transform(v, rot, offset), f, rot @ [0.0, 0.0, 1.0], rot


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("direction", ["normal", "exact_oblique", "random_oblique"])
@pytest.mark.parametrize("target", ["vertices", "midpoints", "centers"])
@pytest.mark.parametrize(
    "plane,alternate",
    [("flat", False), ("flat", True), ("jittered", True), ("tilted", True), ("far", True)],
)
def test_rays_through_grid_vertices_and_edges_all_hit(
    plane, alternate, target, direction, strategy
):
    vertices, faces, _, to_world = _grid(plane, alternate)
    rng = np.random.default_rng(len(target) * 7 + len(direction))
    origins, directions, targets = pg.grid_rays(
        vertices, faces, GRID_N, target, direction, rng=rng, to_world=to_world, distance=0.5
    )
    scene = dacrt.Scene([(vertices, faces)])
    hits = scene.closest(origins, directions, strategy=strategy)
    missed = np.flatnonzero(hits.prim < 0)
    assert len(missed) == 0, (
        f"{len(missed)} of {len(origins)} rays slipped through the grid, first index {missed[0]}: "
        f"origin {origins[missed[0]].tolist()}, direction {directions[missed[0]].tolist()}, "
        f"target {targets[missed[0]].tolist()}"
    )
    # Every ray reaches its target at t = 0.5 (exactly so, up to float32, on the flat grid).
    np.testing.assert_allclose(hits.t, 0.5, rtol={"tilted": 1e-4, "far": 1e-2}.get(plane, 1e-5))
    assert scene.occluded(origins, directions, strategy=strategy).occluded.all()
    # Tighter ranges around the target still see it.
    assert scene.occluded(
        origins, directions, tmin=0.49, tmax=0.51, strategy=strategy
    ).occluded.all()


def _closed_mesh(kind, seed):
    rng = np.random.default_rng(seed)
    if kind == "icosphere":
        v, f = pg.icosphere(4)  # 5120 faces; vertices with 5 and 6 neighbours
    else:
        v, f = pg.uv_sphere(24, 40)  # pole fans of 40 faces
    center = np.array([0.1, -0.2, 0.3])
    v = pg.perturb_radially(pg.transform(v, offset=center), rng, 0.15, center)
    return v, f, center


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("kind", ["icosphere", "uv_sphere"])
def test_rays_from_inside_closed_perturbed_sphere_all_hit(kind, strategy):
    vertices, faces, center = _closed_mesh(kind, 21)
    r_in = pg.inner_radius(vertices, faces, center)
    origins, directions = pg.rays_from_inside(center, 0.9 * r_in, 20_000, np.random.default_rng(22))
    scene = dacrt.Scene([(vertices, faces)])
    hits = scene.closest(origins, directions, strategy=strategy)
    missed = np.flatnonzero(hits.prim < 0)
    assert len(missed) == 0, (
        f"{len(missed)} of 20000 rays escaped the closed mesh, first index {missed[0]}: "
        f"origin {origins[missed[0]].tolist()}, direction {directions[missed[0]].tolist()}"
    )
    points = origins + hits.t[:, None].astype(np.float64) * directions
    inside = np.linalg.norm(points - center, axis=1) < r_in * (1 - 1e-5)
    assert not inside.any(), f"hit points inside the inscribed ball: {np.flatnonzero(inside)[:5]}"
    assert scene.occluded(origins, directions, strategy=strategy).occluded.all()


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("kind", ["icosphere", "uv_sphere"])
def test_rays_from_centre_through_every_vertex_hit(kind, strategy):
    """A ray from the centre aimed at a vertex crosses the surface exactly there."""
    vertices, faces, center = _closed_mesh(kind, 23)
    origins = np.broadcast_to(center.astype(np.float32), vertices.shape)
    directions = (vertices.astype(np.float64) - origins).astype(np.float32)
    scene = dacrt.Scene([(vertices, faces)])
    hits = scene.closest(origins, directions, strategy=strategy)
    missed = np.flatnonzero(hits.prim < 0)
    assert len(missed) == 0, (
        f"{len(missed)} rays through vertices missed, first: vertex {missed[0]}"
    )
    np.testing.assert_allclose(hits.t, 1.0, rtol=1e-4)
    # The vertex is on the hit triangle: one of its corners.
    corner = np.any(faces[hits.prim] == np.arange(len(vertices))[:, None], axis=1)
    assert corner.all(), f"hit a triangle not incident to the vertex: {np.flatnonzero(~corner)[:5]}"
