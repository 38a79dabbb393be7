"""dacrt.trimesh_ray.ProximityQuery: trimesh's ``mesh.nearest`` interface (``on_surface``,
``signed_distance``) answered by ``Scene.nearest``, against the numpy brute force and trimesh's
own ``contains`` for the sign convention (positive inside)."""

from __future__ import annotations

import numpy as np
import point_reference
import procedural
import pytest
import trimesh

from dacrt.trimesh_ray import ProximityQuery


def bumpy_sphere(offset=(0.0, 0.0, 0.0)):
    vertices, faces = procedural.icosphere(3)
    rng = np.random.default_rng(1)
    vertices = procedural.perturb_radially(vertices, rng, 0.2) + np.asarray(offset, np.float32)
    return trimesh.Trimesh(vertices, faces, process=False)


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (1000.0, -2000.0, 500.0)])
def test_on_surface_matches_the_brute_force(offset):
    mesh = bumpy_sphere(offset)
    mesh.nearest = ProximityQuery(mesh)
    rng = np.random.default_rng(3)
    points = rng.uniform(-2, 2, (300, 3)) + offset
    closest, distance, triangle_id = mesh.nearest.on_surface(points)
    assert closest.shape == (300, 3) and closest.dtype == np.float64
    assert distance.dtype == np.float64 and triangle_id.dtype == np.int64
    # The engine measures the float32 point (moved by the mesh's centre), the reference float64.
    expected = point_reference.nearest(points, mesh.vertices, mesh.faces)
    np.testing.assert_allclose(distance, expected.distance, atol=1e-6)
    for i, face in enumerate(triangle_id):
        assert face in expected.ties(i, 1e-6)
    np.testing.assert_allclose(np.linalg.norm(closest - points, axis=1), distance, atol=1e-6)


def test_signed_distance_is_positive_inside_as_trimesh_says():
    mesh = bumpy_sphere()
    proximity = ProximityQuery(mesh)
    rng = np.random.default_rng(4)
    points = rng.uniform(-1.5, 1.5, (400, 3))
    signed = proximity.signed_distance(points)
    _, distance, _ = proximity.on_surface(points)
    np.testing.assert_array_equal(np.abs(signed), distance)
    np.testing.assert_array_equal(signed > 0, mesh.contains(points))


def test_points_on_the_surface_are_at_distance_zero_and_positive():
    mesh = trimesh.Trimesh(*procedural.grid(4, 1.0), process=False)
    points = mesh.vertices[:5].astype(np.float64)
    proximity = ProximityQuery(mesh)
    assert (proximity.signed_distance(points) == 0).all()
    with pytest.raises(ValueError, match="points"):
        proximity.on_surface(np.zeros((2, 2)))
