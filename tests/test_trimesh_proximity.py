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


def test_points_on_edges_and_faces_are_positive_as_trimesh_says():
    """Edge midpoints and face centres lie on the surface in float64; their distance, measured
    from the point rounded to float32, is within that rounding, so they count as on it."""
    mesh = trimesh.creation.icosphere(3)
    edges = mesh.vertices[mesh.edges_unique].mean(axis=1)
    centres = mesh.triangles_center
    proximity = ProximityQuery(mesh)
    for points in (edges, centres):
        signed = proximity.signed_distance(points)
        assert (signed >= 0).all() and signed.max() < 1e-6
    outside = edges * 1.01  # a step off the surface keeps its sign
    assert (proximity.signed_distance(outside) < 0).all()


def test_a_changed_mesh_is_read_again_as_trimesh_reads_it():
    mesh = bumpy_sphere()
    proximity = ProximityQuery(mesh)
    point = np.array([[10.0, 0.0, 0.0]])
    assert proximity.signed_distance(point)[0] < -8
    mesh.apply_translation([10.0, 0.0, 0.0])  # the sphere's centre is now the point
    assert proximity.signed_distance(point)[0] > 0.5
    _, distance, _ = proximity.on_surface(point)
    np.testing.assert_allclose(distance, ProximityQuery(mesh).on_surface(point)[1])


def test_vertex_is_trimeshs_own():
    pytest.importorskip("scipy")  # trimesh's KD-tree of the vertices
    mesh = bumpy_sphere()
    points = np.random.default_rng(5).uniform(-1.5, 1.5, (50, 3))
    distance, vertex = ProximityQuery(mesh).vertex(points)
    brute = np.linalg.norm(points[:, None] - mesh.vertices[None], axis=2)
    np.testing.assert_array_equal(vertex, brute.argmin(axis=1))
    np.testing.assert_allclose(distance, brute.min(axis=1))


def test_points_exactly_on_the_surface_have_a_positive_zero():
    """On the surface counts as inside: the signed distance is +0.0, not -0.0."""
    box = trimesh.creation.box()
    signed = ProximityQuery(box).signed_distance(box.vertices)
    assert (signed == 0).all()
    assert not np.signbit(signed).any()
