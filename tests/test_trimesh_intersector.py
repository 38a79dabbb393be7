"""dacrt.trimesh_ray.RayMeshIntersector against trimesh's own intersectors (``ray_triangle``, and
``ray_pyembree`` on Embree through embreex): the same answers, shapes, dtypes and -1 conventions.

Rays are generic (random origins around the mesh, random targets inside its box): trimesh's
``ray_triangle`` reports a ray through a shared edge on both triangles, where dacrt reports it
once, so rays exactly through edges are avoided here (``test_a_ray_through_a_shared_edge_...``
states dacrt's rule). Several hits of one ray are compared as sets, each hit's location to 1e-9
of the mesh's size.
"""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import procedural
import pytest
import trimesh
from trimesh.ray import ray_pyembree, ray_triangle

from dacrt.trimesh_ray import CONTAINS_DIRECTION, RayMeshIntersector

ORACLES = {
    "ray_triangle": ray_triangle.RayMeshIntersector,
    "embree": ray_pyembree.RayMeshIntersector,
}


def icosphere():
    return trimesh.creation.icosphere(subdivisions=3)


def bumpy_sphere():
    vertices, faces = procedural.icosphere(3)
    rng = np.random.default_rng(1)
    return trimesh.Trimesh(procedural.perturb_radially(vertices, rng, 0.2), faces, process=False)


def soup():
    vertices, faces = procedural.triangle_soup(1500, np.random.default_rng(2))
    return trimesh.Trimesh(vertices, faces, process=False)


def far_box():
    """A box far from the origin, where float32 keeps few digits (the engine traces it moved)."""
    return trimesh.creation.box(extents=(2.0, 3.0, 1.0)).apply_translation((5e4, -3e4, 2e4))


@pytest.fixture(scope="module")
def bunny():
    import sample_scenes

    vertices, faces = sample_scenes.load_shared("bunny")
    return trimesh.Trimesh(vertices, faces, process=False)


MESHES = {"icosphere": icosphere, "bumpy_sphere": bumpy_sphere, "soup": soup, "far_box": far_box}


MESH_NAMES = [*MESHES, "bunny"]
#: Each mesh with each oracle, but for Embree on far_box: Embree traces in float32 too (in a frame
#: scaled to the mesh's box) and gives a few rays there within 1e-4 of a box edge to the face
#: across it, where ray_triangle (float64) agrees with dacrt.
PAIRS = [(m, o) for m in MESH_NAMES for o in ORACLES if (m, o) != ("far_box", "embree")]


@pytest.fixture
def mesh(request):
    """The mesh named by the test's ``mesh`` parameter (indirect)."""
    if request.param == "bunny":
        return request.getfixturevalue("bunny")  # skips without ../shared/scenes
    return MESHES[request.param]()


def generic_rays(mesh, n=1500, seed=0):
    """Rays from random points around the mesh towards random points of its box grown by half,
    with directions of random lengths (trimesh's answers do not depend on them)."""
    rng = np.random.default_rng(seed)
    lo, hi = mesh.bounds
    centre, size = (lo + hi) / 2, np.linalg.norm(hi - lo)
    away = rng.normal(size=(n, 3))
    origins = centre + size * away / np.linalg.norm(away, axis=1, keepdims=True)
    targets = rng.uniform(lo - (hi - lo) / 4, hi + (hi - lo) / 4, (n, 3))
    lengths = rng.uniform(0.1, 10.0, (n, 1))
    return origins, (targets - origins) * lengths


def rays_for(mesh, oracle):
    """Rays per comparison: ray_triangle's rtree walk takes about 35 ms a ray on the bunny."""
    return 200 if oracle == "ray_triangle" and len(mesh.faces) > 10_000 else 1500


def hit_set(index_tri, index_ray):
    return set(zip(index_ray.tolist(), index_tri.tolist()))


@pytest.mark.parametrize("mesh, oracle", PAIRS, indirect=["mesh"])
def test_first_and_any_equal_trimeshs(mesh, oracle):
    origins, directions = generic_rays(mesh, rays_for(mesh, oracle))
    ours, theirs = RayMeshIntersector(mesh), ORACLES[oracle](mesh)
    first = ours.intersects_first(origins, directions)
    assert first.dtype == np.int64 and first.shape == (len(origins),)
    assert 0.1 < (first >= 0).mean() < 0.95, "vacuous: too few or too many misses"
    assert np.array_equal(first, theirs.intersects_first(origins, directions))
    hit = ours.intersects_any(origins, directions)
    assert hit.dtype == bool and np.array_equal(hit, theirs.intersects_any(origins, directions))
    assert np.array_equal(hit, first >= 0)


@pytest.mark.parametrize("mesh, oracle", PAIRS, indirect=["mesh"])
def test_every_hit_equals_trimeshs_as_sets_with_the_same_locations(mesh, oracle):
    origins, directions = generic_rays(mesh, rays_for(mesh, oracle), seed=3)
    ours, theirs = RayMeshIntersector(mesh), ORACLES[oracle](mesh)
    index_tri, index_ray = ours.intersects_id(origins, directions)
    assert index_tri.dtype == index_ray.dtype == np.int64
    expected = theirs.intersects_id(origins, directions, multiple_hits=True)
    assert hit_set(index_tri, index_ray) == hit_set(*expected)
    assert len(index_tri) == len(hit_set(index_tri, index_ray)), "a hit reported twice"
    locations, index_ray, index_tri = ours.intersects_location(origins, directions)
    assert locations.dtype == np.float64 and locations.shape == (len(index_ray), 3)
    their_locations, their_rays, their_tris = theirs.intersects_location(origins, directions)
    where = {pair: k for k, pair in enumerate(zip(their_rays.tolist(), their_tris.tolist()))}
    assert len(where) == len(index_ray)
    matched = [where[pair] for pair in zip(index_ray.tolist(), index_tri.tolist())]
    scale = np.linalg.norm(mesh.extents)
    np.testing.assert_allclose(locations, their_locations[matched], atol=1e-9 * scale, rtol=0)


@pytest.mark.parametrize("mesh", MESH_NAMES, indirect=True)
def test_hits_of_a_ray_come_nearest_first_and_max_hits_keeps_the_nearest(mesh):
    origins, directions = generic_rays(mesh, seed=4)
    intersector = RayMeshIntersector(mesh)
    locations, index_ray, index_tri = intersector.intersects_location(origins, directions)
    assert (np.diff(index_ray) >= 0).all()
    distance = np.einsum("ij,ij->i", locations - origins[index_ray], directions[index_ray])
    same_ray = index_ray[1:] == index_ray[:-1]
    assert (np.diff(distance)[same_ray] >= -1e-9 * np.linalg.norm(mesh.extents) ** 2).all()
    two_tri, two_ray = intersector.intersects_id(origins, directions, max_hits=2)
    rank = np.arange(len(index_ray)) - np.searchsorted(index_ray, index_ray)
    assert hit_set(two_tri, two_ray) == hit_set(index_tri[rank < 2], index_ray[rank < 2])
    every = intersector.intersects_id(origins, directions, max_hits=None)
    assert hit_set(*every) == hit_set(index_tri, index_ray)


@pytest.mark.parametrize("mesh", MESH_NAMES, indirect=True)
def test_first_hit_with_locations_is_the_nearest_of_every_hit(mesh):
    origins, directions = generic_rays(mesh, seed=5)
    intersector = RayMeshIntersector(mesh)
    index_tri, index_ray, locations = intersector.intersects_id(
        origins, directions, multiple_hits=False, return_locations=True
    )
    first = intersector.intersects_first(origins, directions)
    assert np.array_equal(index_ray, np.flatnonzero(first >= 0))
    assert np.array_equal(index_tri, first[first >= 0])
    every, every_ray, _ = intersector.intersects_location(origins, directions)
    nearest = np.searchsorted(every_ray, index_ray)
    np.testing.assert_array_equal(locations, every[nearest])


@pytest.mark.parametrize("oracle", ORACLES)
def test_contains_points_equals_trimeshs_on_closed_meshes(oracle):
    mesh = icosphere()
    rng = np.random.default_rng(6)
    points = rng.uniform(-1.3, 1.3, (2000, 3))
    contains = RayMeshIntersector(mesh).contains_points(points)
    assert contains.dtype == bool and 200 < contains.sum() < 1800
    assert np.array_equal(contains, ORACLES[oracle](mesh).contains_points(points))
    radius = np.linalg.norm(points, axis=1)
    assert contains[radius < 0.98].all() and not contains[radius > 1.0].any()


def test_contains_points_equals_embrees_on_the_bunny(bunny):
    """The bunny has holes: where the parities of the two rays of a point disagree, trimesh tries
    a random direction, and the answer depends on it; everywhere else the answers are equal."""
    rng = np.random.default_rng(7)
    points = rng.uniform(*bunny.bounds, (5000, 3))
    ours = RayMeshIntersector(bunny)
    contains = ours.contains_points(points)
    expected = ray_pyembree.RayMeshIntersector(bunny).contains_points(points)
    both_ways = np.vstack([points, points])
    ray_directions = np.vstack([np.tile(CONTAINS_DIRECTION, (5000, 1))] * 2)
    ray_directions[5000:] *= -1
    counts = ours.backend().count(both_ways, ray_directions).reshape(2, -1)
    agree = (counts[0] % 2) == (counts[1] % 2)
    assert agree.mean() > 0.95 and 500 < contains.sum() < 4500
    assert np.array_equal(contains[agree], expected[agree])


def test_the_one_line_switch_serves_trimeshs_own_queries(bunny):
    mesh = bunny.copy()
    embree = mesh.ray
    mesh.ray = RayMeshIntersector(mesh)
    points = np.random.default_rng(8).uniform(*mesh.bounds, (500, 3))
    origins, directions = generic_rays(mesh, 300, seed=9)
    assert np.array_equal(mesh.contains(points), embree.contains_points(points))
    assert np.array_equal(
        mesh.ray.intersects_first(origins, directions),
        embree.intersects_first(origins, directions),
    )


def test_a_ray_through_a_shared_edge_or_vertex_hits_once():
    """A 2 x 2 grid of quads: rays down through its inner vertex, an inner edge and a diagonal
    report one triangle each (trimesh's ray_triangle reports two or more)."""
    vertices, faces = procedural.grid(2, 2.0)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    origins = np.array([[1.0, 1.0, 1.0], [0.5, 1.0, 1.0], [0.5, 0.5, 1.0]])
    directions = np.tile([0.0, 0.0, -1.0], (3, 1))
    index_tri, index_ray = RayMeshIntersector(mesh).intersects_id(origins, directions)
    assert index_ray.tolist() == [0, 1, 2]
    theirs = ray_triangle.RayMeshIntersector(mesh).intersects_id(origins, directions)
    assert np.bincount(theirs[1], minlength=3).tolist()[0] > 1


@pytest.mark.parametrize("mesh", MESH_NAMES, indirect=True)
def test_empty_inputs_give_typed_empty_answers(mesh):
    nothing = np.zeros((0, 3))
    intersector = RayMeshIntersector(mesh)
    assert intersector.intersects_first(nothing, nothing).dtype == np.int64
    assert intersector.intersects_any(nothing, nothing).shape == (0,)
    index_tri, index_ray, locations = intersector.intersects_id(
        nothing, nothing, return_locations=True
    )
    assert index_tri.shape == index_ray.shape == (0,) and index_tri.dtype == np.int64
    assert locations.shape == (0, 3) and locations.dtype == np.float64
    assert intersector.contains_points(nothing).shape == (0,)


def test_rays_that_cannot_hit_hit_nothing_and_bad_shapes_are_value_errors():
    mesh = icosphere()
    intersector = RayMeshIntersector(mesh)
    origins = np.array([[0.0, 0, 5], [0, 0, 5], [np.nan, 0, 5], [0, 0, 5], [0, 0, 5]])
    directions = np.array([[0.0, 0, -1], [0, 0, 0], [0, 0, -1], [np.inf, 0, -1], [0, 0, 1]])
    assert intersector.intersects_first(origins, directions)[1:].tolist() == [-1] * 4
    assert intersector.intersects_first(origins, directions)[0] >= 0
    assert intersector.intersects_any(origins, directions).tolist() == [True] + [False] * 4
    assert set(intersector.intersects_id(origins, directions)[1].tolist()) == {0}
    with pytest.raises(ValueError, match="don't match"):
        intersector.intersects_first(origins, directions[:2])
    with pytest.raises(ValueError, match="points must be"):
        intersector.contains_points(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="max_hits"):
        intersector.intersects_id(origins, directions, max_hits=1.5)


def test_a_changed_mesh_is_read_again_as_trimeshs_intersectors_read_it():
    """trimesh's intersectors follow the mesh (its content hash): a move, or vertices edited in
    place, answer as a new intersector of the changed mesh; an object without a content hash
    is read once."""
    mesh = icosphere()
    intersector = RayMeshIntersector(mesh)
    points = np.array([[0.0, 0, 0], [10.0, 0, 0]])
    assert intersector.contains_points(points).tolist() == [True, False]
    mesh.apply_translation([10.0, 0, 0])
    assert intersector.contains_points(points).tolist() == [False, True]
    mesh.vertices[:, 1] += 100.0  # in place: trimesh's tracked array changes the hash
    origins, directions = generic_rays(mesh, 200, seed=12)
    fresh = RayMeshIntersector(mesh.copy())
    for method in ("intersects_first", "intersects_location"):
        got, want = (getattr(i, method)(origins, directions) for i in (intersector, fresh))
        for a, b in zip(*((x if isinstance(x, tuple) else (x,)) for x in (got, want))):
            assert np.array_equal(a, b), method
    plain = SimpleNamespace(vertices=mesh.vertices.copy(), faces=mesh.faces)
    once = RayMeshIntersector(plain)
    plain.vertices = plain.vertices + [0.0, -100.0, 0.0]
    np.testing.assert_array_equal(
        once.intersects_first(origins, directions), fresh.intersects_first(origins, directions)
    )


class VersionedMesh:
    """A mesh whose content hash is its ``version`` (trimesh's follows its arrays); a thread
    named "second" asking for the hash sets ``asked``."""

    def __init__(self, vertices, faces, asked):
        self.vertices, self.faces, self.version, self.asked = vertices, faces, 0, asked

    def __hash__(self):
        if threading.current_thread().name == "second":
            self.asked.set()
        return self.version


def test_a_call_while_another_thread_reads_the_changed_mesh_answers_for_the_changed_mesh():
    """A thread finds the mesh moved and builds its backend, held open until a second thread
    has called: the second call waits for that backend rather than answer from the old one
    (which misses the moved mesh, while locations come from the new vertices), and the mesh
    is read again once."""
    asked, building, builds = threading.Event(), threading.Event(), []

    class HeldBuild(RayMeshIntersector):
        def make_backend(self, vertices, faces):
            builds.append(threading.current_thread().name)
            if len(builds) > 1:  # the moved mesh's backend
                building.set()
                assert asked.wait(60)  # a guard against hanging: the second thread asks at once
            return super().make_backend(vertices, faces)

    sphere = icosphere()
    mesh = VersionedMesh(sphere.vertices, sphere.faces, asked)
    intersector = HeldBuild(mesh)
    mesh.vertices, mesh.version = sphere.vertices + [10.0, 0, 0], 1
    rng = np.random.default_rng(13)
    origins = np.array([10.0, 0, 5]) + rng.uniform(-0.5, 0.5, (300, 3)) * [1, 1, 0]
    directions = np.tile([0.0, 0, -1], (300, 1))
    moved = RayMeshIntersector(SimpleNamespace(vertices=mesh.vertices, faces=sphere.faces))
    alone = moved.intersects_location(origins, directions)
    assert len(alone[0]) > 300  # every ray hits the moved sphere, most twice
    answers = {}

    def call():
        name = threading.current_thread().name
        answers[name] = intersector.intersects_location(origins, directions)

    first = threading.Thread(target=call, name="first")
    first.start()
    assert building.wait(60)
    second = threading.Thread(target=call, name="second")
    second.start()
    first.join()
    second.join()
    assert builds == [threading.current_thread().name, "first"]
    for name in ("first", "second"):
        for got, want in zip(answers[name], alone):
            np.testing.assert_array_equal(got, want, err_msg=name)


def test_max_hits_zero_gives_no_hits():
    """max_hits=0 asks for no hit: an empty answer, not an error."""
    intersector = RayMeshIntersector(trimesh.creation.box())
    index_tri, index_ray = intersector.intersects_id([[0.0, 0, -5]], [[0.0, 0, 1]], max_hits=0)
    assert index_tri.tolist() == [] and index_ray.tolist() == []
    assert index_tri.dtype == np.int64 and index_ray.dtype == np.int64


def test_points_on_the_bounding_box_are_not_contained_as_trimesh_says():
    """trimesh's bounds test is strict: a point on a box's face is outside."""
    box = trimesh.creation.box()
    on_faces = np.array([[0.5, 0.1, 0.2], [0.1, -0.5, 0.3], [0.2, 0.1, 0.5], [-0.5, -0.5, 0.1]])
    assert RayMeshIntersector(box).contains_points(on_faces).tolist() == [False] * 4
    assert box.contains(on_faces).tolist() == [False] * 4


def test_a_ray_out_through_a_hole_says_outside():
    """A point whose two opposite rays disagree, one leaving through a hole into free space,
    is outside, whatever the other ray's parity."""
    box = trimesh.creation.box()
    assert (CONTAINS_DIRECTION > 0).all()  # so the -z face is where the backward ray leaves
    open_box = trimesh.Trimesh(box.vertices, box.faces[box.face_normals[:, 2] != -1], process=False)
    point = np.array([[0.1, 0.05, 0.02]])
    assert RayMeshIntersector(open_box).contains_points(point).tolist() == [False]
