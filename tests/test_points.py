"""``Scene.nearest``, ``contains`` and ``signed_distance`` against the numpy brute force
(``point_reference``), the exact crossing count (``reference.count``), trimesh and Open3D.

The engine's distance is measured in float64 and then rounded to float32; the reference measures
by another method in float64, so distances agree to float32 rounding and the engine's face is
one of the reference's within a tolerance of the least distance. Where the geometry is dyadic
(an axis-aligned grid) both are exact, and a tie must go to the lowest face. On thin triangles
the face distance is checked against exact rational arithmetic
(``point_reference.exact_face_distance``).
"""

from __future__ import annotations

import numpy as np
import point_reference as pr
import procedural as pg
import pytest
import reference
import sample_scenes

import dacrt
import dacrt.points
from dacrt.points import sample_directions

SCENES = ("soup", "sphere", "tilted_grid", "multi", "degenerate_mix", "pinwheel")
MESH_MASKS = np.array([0b0001, 0b0010, 0b0110, 0xFFFFFFFF], np.uint32)
POINT_MASKS = np.array([0b0001, 0b0010, 0b0100, 0b1000, 0b0011, 0xFFFFFFFF], np.uint32)


def _scene_and_soup(name):
    meshes = sample_scenes.SCENES[name](3)
    vertices, faces, offsets = pg.concat(meshes)
    return meshes, vertices, faces, offsets


def _points(vertices, n, rng, margin=0.5):
    """Points uniform in the vertices' box grown by ``margin`` of its size."""
    lo, hi = pg.bounds(vertices)
    grow = margin * (hi - lo).max()
    return rng.uniform(lo - grow, hi + grow, (n, 3)).astype(np.float32)


def _size(vertices):
    lo, hi = pg.bounds(vertices)
    return float(np.max(hi - lo))


def _check_against_reference(found, expected, vertices, faces, offsets, points):
    """The engine's answer is the reference's: distance to float32 rounding, a face among the
    least ones, and a closest point on that face at that distance."""
    scale = max(_size(vertices), float(np.abs(points).max()))
    tolerance = 4e-7 * scale
    has = np.isfinite(expected.distance)
    np.testing.assert_array_equal(np.isfinite(found.distance), has)
    np.testing.assert_allclose(
        found.distance[has], expected.distance[has], rtol=1e-6, atol=tolerance
    )
    assert (found.prim[~has] == -1).all() and (found.mesh[~has] == -1).all()
    global_prim = offsets[found.mesh[has]] + found.prim[has]
    for i, g in zip(np.flatnonzero(has), global_prim):
        assert g in expected.ties(i, tolerance), (i, g, expected.ties(i, tolerance))
    on_face = pr.point_on_face(vertices, faces, global_prim, found.u[has], found.v[has])
    np.testing.assert_allclose(found.point[has], on_face, atol=tolerance)
    measured = np.linalg.norm(found.point[has].astype(np.float64) - points[has], axis=1)
    np.testing.assert_allclose(measured, expected.distance[has], rtol=1e-5, atol=tolerance)


@pytest.mark.parametrize("name", SCENES)
def test_nearest_matches_the_brute_force(name):
    meshes, vertices, faces, offsets = _scene_and_soup(name)
    points = _points(vertices, 400, np.random.default_rng(1))
    found = dacrt.Scene(meshes).nearest(points)
    expected = pr.nearest(points, vertices, faces)
    _check_against_reference(found, expected, vertices, faces, offsets, points)


def test_a_first_point_query_derives_once_and_holds_up_no_other_scene():
    """What point queries read is derived on a scene's first, under that scene's own lock: a
    second first query on the scene waits for it and derives nothing, while another scene's
    first query answers meanwhile; all answer as the brute force over placed copies."""
    import threading

    meshes, vertices, faces, _ = _scene_and_soup("sphere")
    moved = np.eye(4)
    moved[:3, 3] = (3.0, 0.0, 0.0)
    held = dacrt.Scene([meshes[0]] * 2, transforms=[None, moved])
    other = dacrt.Scene([meshes[0]] * 2, transforms=[None, moved])
    points = _points(vertices, 50, np.random.default_rng(4))
    derived, started, release = [], threading.Event(), threading.Event()
    derive = held._placed_triangles

    def slow_derive(threads):
        derived.append(1)
        started.set()
        release.wait(30)
        return derive(threads)

    held._placed_triangles = slow_derive
    answers = [None, None]

    def query(k):
        answers[k] = held.nearest(points)

    first = threading.Thread(target=query, args=(0,))
    first.start()
    assert started.wait(30)
    second = threading.Thread(target=query, args=(1,))
    second.start()
    beside = threading.Thread(target=other.nearest, args=(points,))
    beside.start()
    beside.join(30)
    assert not beside.is_alive() and first.is_alive() and second.is_alive()
    release.set()
    first.join(30)
    second.join(30)
    assert derived == [1] and held.derived_for_points
    placed_vertices = np.vstack([vertices, vertices + np.float32([3.0, 0.0, 0.0])])
    placed_faces = np.vstack([faces, faces + len(vertices)])
    expected = pr.nearest(points, placed_vertices, placed_faces)
    for answer in answers:
        np.testing.assert_allclose(answer.distance, expected.distance, rtol=1e-6, atol=1e-7)
        np.testing.assert_array_equal(answer.distance, answers[0].distance)


@pytest.mark.parametrize("name", ["soup", "sphere"])
def test_points_far_away(name):
    meshes, vertices, faces, offsets = _scene_and_soup(name)
    directions = pg.unit_vectors(200, np.random.default_rng(2))
    points = (directions * 1000.0 * _size(vertices)).astype(np.float32)
    found = dacrt.Scene(meshes).nearest(points)
    expected = pr.nearest(points, vertices, faces)
    _check_against_reference(found, expected, vertices, faces, offsets, points)


def test_points_at_the_edge_of_float32():
    meshes, vertices, faces, offsets = _scene_and_soup("soup")
    points = np.array([[1e30, 0, 0], [-3e38, 3e38, 0], [0.5, 0.5, -1e20]], np.float32)
    found = dacrt.Scene(meshes).nearest(points)
    expected = pr.nearest(points, vertices, faces)
    with np.errstate(over="ignore"):  # the second is beyond float32's range: inf
        np.testing.assert_allclose(found.distance, expected.distance.astype(np.float32), rtol=1e-6)
    # A closest point farther than float32's range is none, as for max_distance.
    np.testing.assert_array_equal(found.prim >= 0, [True, False, True])
    np.testing.assert_array_equal(found.prim[[0, 2]], expected.prim[[0, 2]])
    assert np.isinf(found.point[1]).all() and found.u[1] == 0 and found.v[1] == 0
    assert np.isinf(dacrt.Scene(meshes).signed_distance(points[1:2], 3)).all()


@pytest.mark.parametrize("modelled", ["near", "far"])
def test_placed_meshes_answer_in_scene_space(modelled):
    """Transforms place the triangles before anything else: the answers are those of the placed
    vertices, prim the row of the mesh's own faces; also for a mesh given 1e5 units from its
    own origin (traced relative to its box's centre) and placed back."""
    vertices, faces = pg.icosphere(2)
    matrix = np.array([[0, -2, 0, 1], [2, 0, 0, 0], [0, 0, 2, -3], [0, 0, 0, 1]], np.float64)
    if modelled == "far":
        shift = np.array([1e5, -6e4, 3e4])
        vertices = (vertices + shift).astype(np.float32)
        matrix = matrix @ np.vstack([np.hstack([np.eye(3), -shift[:, None]]), [0, 0, 0, 1]])
    placed = (vertices.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
    points = _points(placed, 300, np.random.default_rng(19))
    moved = dacrt.Scene([(vertices, faces)], transforms=[matrix]).nearest(points)
    plain = dacrt.Scene([(placed, faces)]).nearest(points)
    for field in ("distance", "point", "prim", "u", "v"):
        np.testing.assert_array_equal(getattr(moved, field), getattr(plain, field))


@pytest.mark.parametrize(
    ("corners", "offset"),
    [
        ([[0, 0, 0], [64, 0, 0], [128, 1, 0]], [0, 1e9, 0]),  # y rounds to 1e9: collinear
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [1e9, 0, 0]),  # x rounds to 1e9: two corners meet
    ],
)
def test_a_triangle_its_placement_collapses_is_never_the_answer(corners, offset):
    """A placed mesh's triangle whose float32 corners the placement makes degenerate is never
    the answer, as in the placed copy: the other triangle is, or none beyond max_distance."""
    vertices = np.array([*corners, [0, 0, 50], [256, 0, 50], [0, 256, 50]], np.float32)
    faces = np.array([[0, 1, 2], [3, 4, 5]], np.int32)
    matrix = np.eye(4)
    matrix[:3, 3] = offset
    placed = (vertices.astype(np.float64) + offset).astype(np.float32)
    points = (placed[:3].astype(np.float64).mean(axis=0) + [[0, 0, 10], [0, 0, -5]]).astype(
        np.float32
    )
    moved = dacrt.Scene([(vertices, faces)], transforms=[matrix]).nearest(points)
    plain = dacrt.Scene([(placed, faces)]).nearest(points)
    expected = pr.nearest(points, placed, faces)
    np.testing.assert_array_equal(moved.prim, expected.prim)
    np.testing.assert_array_equal(moved.prim, [1, 1])
    for field in ("distance", "point", "prim", "u", "v"):
        np.testing.assert_array_equal(getattr(moved, field), getattr(plain, field))
    limited = dacrt.Scene([(vertices, faces)], transforms=[matrix]).nearest(points, 20.0)
    np.testing.assert_array_equal(limited.prim, [-1, -1])


@pytest.mark.parametrize("name", ["sphere", "tilted_grid", "soup"])
def test_points_on_vertices_edges_and_faces(name):
    meshes, vertices, faces, offsets = _scene_and_soup(name)
    rng = np.random.default_rng(4)
    corners = vertices[faces].astype(np.float64)
    on_vertices = vertices[faces[:, 0]]
    on_edges = (0.5 * (corners[:, 0] + corners[:, 1])).astype(np.float32)
    weights = rng.dirichlet([1, 1, 1], len(faces))
    on_faces = np.einsum("fk,fka->fa", weights, corners).astype(np.float32)
    points = np.concatenate([on_vertices, on_edges, on_faces])
    found = dacrt.Scene(meshes).nearest(points)
    expected = pr.nearest(points, vertices, faces)
    _check_against_reference(found, expected, vertices, faces, offsets, points)
    assert (found.distance <= 1e-6 * _size(vertices)).all()


def test_exact_points_on_a_grid_tie_to_the_lowest_face():
    """On a dyadic grid in z = 0 every distance is exact: a point on a vertex, an edge or a face
    is at distance 0, and of the faces that touch it the lowest is the answer."""
    vertices, faces = pg.grid(8, 2.0, alternate=True)
    corners = vertices[faces].astype(np.float64)
    on_vertices = vertices.copy()
    on_edges = 0.5 * (corners[:, 0] + corners[:, 1])
    on_faces = (corners[:, 0] + corners[:, 1] + 2 * corners[:, 2]) / 4
    above = on_faces + [0, 0, 0.25]
    points = np.concatenate([on_vertices, on_edges, on_faces, above]).astype(np.float32)
    found = dacrt.Scene([(vertices, faces)]).nearest(points)
    expected = pr.nearest(points, vertices, faces)
    np.testing.assert_array_equal(found.distance, expected.distance.astype(np.float32))
    n_on = len(points) - len(above)
    assert (found.distance[:n_on] == 0).all()
    assert (found.distance[n_on:] == 0.25).all()
    # The lowest face at the least distance: exact here, no tolerance.
    np.testing.assert_array_equal(found.prim, expected.prim)
    np.testing.assert_array_equal(found.point[:n_on], points[:n_on])


def test_max_distance():
    meshes, vertices, faces, offsets = _scene_and_soup("sphere")
    points = _points(vertices, 400, np.random.default_rng(6), margin=1.0)
    scene = dacrt.Scene(meshes)
    for max_distance in (0.0, 0.1, 0.5, 2.0):
        found = scene.nearest(points, max_distance)
        expected = pr.nearest(points, vertices, faces, max_distance)
        _check_against_reference(found, expected, vertices, faces, offsets, points)
        assert (found.distance[np.isfinite(found.distance)] <= max_distance).all()
        missed = ~np.isfinite(found.distance)
        assert (found.u[missed] == 0).all() and np.isinf(found.point[missed]).all()


def test_a_reported_distance_given_back_as_max_distance_keeps_its_answer():
    """The limit is decided on the float32 distance the query reports: given back as
    ``max_distance``, every reported distance keeps its answer, and the next float32 below it
    drops it, also where the float64 distance rounds down."""
    vertices, faces = pg.grid(3, 3.0)
    points = _points(vertices, 400, np.random.default_rng(16), margin=2.0)
    points[:, 2] += np.float32(0.25)
    scene = dacrt.Scene([(vertices, faces)])
    found = scene.nearest(points)
    expected = pr.nearest(points, vertices, faces)
    rounded_down = found.distance.astype(np.float64) < expected.distance
    assert rounded_down.sum() > 20  # the cases a float64 limit would lose
    for k in range(len(points)):
        again = scene.nearest(points[k : k + 1], max_distance=float(found.distance[k]))
        assert again.distance[0] == found.distance[k] and again.prim[0] == found.prim[k], k
        below = float(np.nextafter(found.distance[k], np.float32(0)))
        assert scene.nearest(points[k : k + 1], max_distance=below).prim[0] == -1, k


def test_a_closest_point_just_beyond_max_distance_is_none_in_every_field():
    """The search covers the distances that round just above the limit (``search_limit2``);
    those the query then drops read as none: distance and point inf, mesh and prim -1, and the
    signed distance inf, also for a limit float32 holds exactly."""
    scene = dacrt.Scene([pg.single_triangle()])
    above_one = np.nextafter(np.float32(1), np.float32(2))
    points = np.array([[0.2, 0.2, above_one], [0.2, 0.2, 1.0], [0.2, 0.2, -1.0]], np.float32)
    for limit, kept in ((1.0, [False, True, True]), (0.99999999, [False, False, False])):
        found = scene.nearest(points, max_distance=limit)
        np.testing.assert_array_equal(found.distance, np.where(kept, np.float32(1), np.inf))
        np.testing.assert_array_equal(found.mesh, np.where(kept, 0, -1))
        np.testing.assert_array_equal(found.prim, np.where(kept, 0, -1))
        assert np.isinf(found.point[~np.array(kept)]).all()
        signed = scene.signed_distance(points, 1, limit)
        np.testing.assert_array_equal(np.abs(signed), found.distance)


def test_max_distance_zero_keeps_points_on_the_surface():
    vertices, faces = pg.grid(4, 1.0)
    points = np.array([[0.5, 0.5, 0.0], [0.5, 0.5, 1e-3]], np.float32)
    found = dacrt.Scene([(vertices, faces)]).nearest(points, max_distance=0)
    assert found.distance[0] == 0 and found.prim[0] >= 0
    assert found.distance[1] == np.inf and found.prim[1] == -1


@pytest.mark.parametrize("kind", ["one mask", "per point"])
def test_masks(kind):
    meshes, vertices, faces, offsets = _scene_and_soup("multi")
    points = _points(vertices, 300, np.random.default_rng(7))
    rng = np.random.default_rng(8)
    if kind == "one mask":
        point_masks = np.full(len(points), 0b0010, np.uint32)
        mask = 0b0010
    else:
        point_masks = rng.choice(POINT_MASKS, len(points))
        mask = point_masks
    face_masks = np.repeat(MESH_MASKS, np.diff(offsets))
    found = dacrt.Scene(meshes, masks=MESH_MASKS).nearest(points, mask=mask)
    expected = pr.nearest(points, vertices, faces, point_masks=point_masks, face_masks=face_masks)
    _check_against_reference(found, expected, vertices, faces, offsets, points)


def test_a_mask_that_sees_nothing():
    meshes, vertices, faces, offsets = _scene_and_soup("multi")
    points = _points(vertices, 50, np.random.default_rng(9))
    found = dacrt.Scene(meshes, masks=0b0001).nearest(points, mask=0b0010)
    assert np.isinf(found.distance).all() and (found.prim == -1).all()


def test_every_thread_count_gives_the_same_answers():
    """Enough points for several chunks (dacrt.config.POINT_CHUNK) on each thread count."""
    meshes, vertices, faces, _ = _scene_and_soup("sphere")
    rng = np.random.default_rng(10)
    points = np.concatenate([_points(vertices, 60000, rng), vertices[faces[:, 1]]])
    scene = dacrt.Scene(meshes)
    one = scene.nearest(points, threads=1, stats=True)
    two = scene.nearest(points, threads=2, stats=True)
    for field in ("distance", "point", "mesh", "prim", "u", "v"):
        np.testing.assert_array_equal(getattr(one, field), getattr(two, field))
    assert one.stats["points"] == len(points) and one.stats["leaves"] > 0
    sample = rng.choice(len(points), 300, replace=False)
    expected = pr.nearest(points[sample], vertices, faces)
    np.testing.assert_allclose(one.distance[sample], expected.distance, rtol=1e-6, atol=1e-7)


def test_shuffling_triangles_changes_no_distance():
    meshes, vertices, faces, _ = _scene_and_soup("soup")
    points = _points(vertices, 500, np.random.default_rng(11))
    order = np.random.default_rng(12).permutation(len(faces))
    first = dacrt.Scene([(vertices, faces)]).nearest(points)
    shuffled = dacrt.Scene([(vertices, faces[order])]).nearest(points)
    np.testing.assert_array_equal(first.distance, shuffled.distance)


def test_empty_scene_and_no_points():
    empty = dacrt.Scene([])
    found = empty.nearest(np.zeros((3, 3), np.float32))
    assert np.isinf(found.distance).all() and (found.mesh == -1).all() and (found.prim == -1).all()
    assert not empty.contains(np.zeros((3, 3))).any()
    assert np.isinf(empty.signed_distance(np.zeros((3, 3)))).all()
    scene = dacrt.Scene(sample_scenes.SCENES["sphere"](0))
    none = scene.nearest(np.zeros((0, 3)))
    assert none.distance.shape == (0,) and none.point.shape == (0, 3)
    assert none.distance.dtype == np.float32 and none.prim.dtype == np.int32
    assert scene.contains(np.zeros((0, 3))).shape == (0,)


def test_a_max_distance_beyond_float32_is_no_limit():
    """Distances are float32: a limit beyond its largest number limits nothing (1e200 raised
    an OverflowError squaring it)."""
    scene = dacrt.Scene(sample_scenes.SCENES["sphere"](0))
    points = np.array([[0.1, 0.2, 0.3], [5.0, 0, 0]])
    unlimited = scene.nearest(points)
    for limit in (1e39, 1e200, np.finfo(np.float64).max, 10**400):
        np.testing.assert_array_equal(scene.nearest(points, limit).distance, unlimited.distance)
    signed = scene.signed_distance(points, max_distance=1e200)
    np.testing.assert_array_equal(np.abs(signed), unlimited.distance)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda s: s.nearest(np.zeros((3, 2))), "points must have shape"),
        (lambda s: s.nearest([[0, 0, np.nan]]), r"points\[0\]"),
        (lambda s: s.nearest(np.zeros((1, 3)), -1.0), "max_distance"),
        (lambda s: s.nearest(np.zeros((1, 3)), float("nan")), "max_distance"),
        (lambda s: s.nearest(np.zeros((1, 3)), "far"), "max_distance"),
        (lambda s: s.nearest(np.zeros((2, 3)), mask=[1, 2, 3]), "mask"),
        (lambda s: s.nearest(np.zeros((1, 3)), threads=0), "threads"),
        (lambda s: s.contains(np.zeros((1, 3)), nsamples=2), "nsamples"),
        (lambda s: s.contains(np.zeros((1, 3)), nsamples=0), "nsamples"),
        (lambda s: s.contains(np.zeros((1, 3)), nsamples=True), "nsamples"),
        (lambda s: s.signed_distance(np.zeros((1, 3)), nsamples=4), "nsamples"),
        # beyond the bound: it looped for hours (2**63 - 1) or asked 16 GiB (2**31 + 1)
        (lambda s: s.contains(np.zeros((1, 3)), nsamples=2**63 - 1), "up to 16777215"),
        (lambda s: s.signed_distance(np.zeros((1, 3)), nsamples=2**31 + 1), "up to 16777215"),
        (lambda s: s.signed_distance(np.zeros((1, 4))), "points"),
        (lambda s: s.nearest([[0, 0, 1], [0, 0]]), "points must be an"),
        (lambda s: s.contains([[0, 0, 1], [0, 0]]), "points must be an"),
        (lambda s: s.signed_distance([[0, 0, 1], [0, 0]]), "points must be an"),
    ],
)
def test_bad_input_names_the_argument(call, message):
    scene = dacrt.Scene(sample_scenes.SCENES["sphere"](0))
    with pytest.raises(dacrt.InputError, match=message):
        call(scene)


# ---- contains and signed_distance


def _parity_votes(vertices, faces, points, nsamples):
    """(n,) bool: the majority of odd exact crossing counts along ``sample_directions``."""
    votes = np.zeros(len(points), np.int64)
    for direction in sample_directions(nsamples):
        directions = np.tile(direction, (len(points), 1))
        votes += reference.count(vertices, faces, points, directions) % 2
    return 2 * votes > nsamples


@pytest.mark.parametrize("nsamples", [1, 3])
@pytest.mark.parametrize("name", ["sphere", "multi", "tilted_grid"])
def test_contains_is_the_parity_of_exact_crossings(name, nsamples):
    meshes, vertices, faces, _ = _scene_and_soup(name)
    rng = np.random.default_rng(13)
    points = np.concatenate([_points(vertices, 300, rng, margin=0.1), vertices[faces[:40, 0]]])
    scene = dacrt.Scene(meshes)
    inside = scene.contains(points, nsamples)
    distance = scene.nearest(points).distance
    # A point on the surface may go either way (a crossing at t = 0).
    off = distance > 0
    expected = _parity_votes(vertices, faces, points[off], nsamples)
    np.testing.assert_array_equal(inside[off], expected)
    signed = scene.signed_distance(points, nsamples)
    np.testing.assert_array_equal(np.abs(signed), distance)
    np.testing.assert_array_equal(signed < 0, inside & (distance > 0))
    assert (signed[distance == 0] == 0).all()


def test_contains_in_a_closed_sphere():
    """Points well inside and well outside a closed mesh, whatever nsamples."""
    vertices, faces = pg.icosphere(3)
    rng = np.random.default_rng(14)
    directions = pg.unit_vectors(500, rng)
    radii = np.concatenate([rng.uniform(0, 0.9, 250), rng.uniform(1.1, 3, 250)])
    points = (directions * radii[:, None]).astype(np.float32)
    scene = dacrt.Scene([(vertices, faces)])
    for nsamples in (1, 3, 5):
        np.testing.assert_array_equal(scene.contains(points, nsamples), radii < 1)
    signed = scene.signed_distance(points, max_distance=0.5)
    far = np.abs(radii - 1) > 0.55
    assert np.isinf(signed[far]).all()
    np.testing.assert_array_equal(signed[far] < 0, radii[far] < 1)


@pytest.mark.parametrize("nsamples", [1, 3])
def test_contains_far_from_a_mesh_placed_small(nsamples):
    """A point 1e33 from a sphere placed at 1e-6 of its size, beside a floor as given: its rays
    would leave float32 in the sphere's space (1e39), so they start near its box; the point is
    outside, and the points in and around the sphere are answered as before."""
    sphere, sphere_faces = pg.icosphere(2)
    floor, floor_faces = pg.grid(2, 4.0)
    floor = (floor - [2, 2, 1]).astype(np.float32)
    matrix = np.diag([1e-6, 1e-6, 1e-6, 1.0])
    scene = dacrt.Scene([(floor, floor_faces), (sphere, sphere_faces)], transforms=[None, matrix])
    placed = (sphere.astype(np.float64) * 1e-6).astype(np.float32)
    vertices, faces, _ = pg.concat([(floor, floor_faces), (placed, sphere_faces)])
    rng = np.random.default_rng(20)
    # the first points are 1e33 before the sphere along each direction of the inside test
    directions = np.concatenate([-sample_directions(nsamples), pg.unit_vectors(60, rng)])
    n_far = 20 + nsamples
    radii = np.concatenate([np.full(n_far, 1e33), rng.uniform(0, 0.8e-6, 20), np.full(20, 2e-6)])
    points = (directions * radii[:, None]).astype(np.float32)
    near = _parity_votes(vertices, faces, points[n_far:], nsamples)
    expected = np.concatenate([np.zeros(n_far, bool), near])
    inside = scene.contains(points, nsamples)
    np.testing.assert_array_equal(inside, expected)
    signed = scene.signed_distance(points, nsamples)
    np.testing.assert_array_equal(signed < 0, expected)
    assert np.isfinite(signed).all()


def test_far_rays_into_a_mesh_placed_small_keep_their_parity():
    """An open grid placed at 1e-11 of its size, seen from points 1e28 away whose ray aims at
    it: the rays start near its box in its space (from the points they would reach 1e39), and
    each point's answer is the exact crossing parity of the placed copy."""
    grid, faces = pg.grid(4, 2.0)
    turn = pg.rotation([1.0, 2.0, 0.5], 0.7)
    vertices = ((grid - [1, 1, 0]).astype(np.float64) @ turn.T * 1e33).astype(np.float32)
    matrix = np.diag([1e-11, 1e-11, 1e-11, 1.0])
    placed = (vertices.astype(np.float64) * 1e-11).astype(np.float32)
    rng = np.random.default_rng(21)
    in_plane = np.c_[rng.uniform(-1.3, 1.3, (80, 2)), np.zeros(80)]
    targets = in_plane @ turn.T * 1e22  # on the grid's plane, some beside the grid
    points = (targets - 1e28 * sample_directions(1)[0]).astype(np.float32)
    inside = dacrt.Scene([(vertices, faces)], transforms=[matrix]).contains(points)
    expected = _parity_votes(placed, faces, points, 1)
    np.testing.assert_array_equal(inside, expected)
    assert 10 < expected.sum() < 70  # rays through the grid and beside it


def test_signed_distance_masks():
    meshes, vertices, faces, offsets = _scene_and_soup("multi")
    points = _points(vertices, 200, np.random.default_rng(15))
    scene = dacrt.Scene(meshes, masks=MESH_MASKS)
    seen = np.repeat(MESH_MASKS, np.diff(offsets)) & 0b0010 != 0
    inside = scene.contains(points, mask=0b0010)
    np.testing.assert_array_equal(inside, _parity_votes(vertices, faces[seen], points, 1))


@pytest.mark.parametrize("batch_rays", [1, 250, 1000, 1 << 20])
def test_contains_traces_directions_in_batches(batch_rays, monkeypatch):
    """Directions go to the engine several at a time (a batch of about ``batch_rays`` rays, the
    last one short), with a mask a point: the votes are the reference's whatever the batch."""
    monkeypatch.setattr(dacrt.points, "VOTE_BATCH_RAYS", batch_rays)
    meshes, vertices, faces, offsets = _scene_and_soup("multi")
    points = _points(vertices, 120, np.random.default_rng(16), margin=0.1)
    point_masks = np.resize(np.array([0b0010, 0b0100, 0xFFFFFFFF], np.uint32), len(points))
    scene = dacrt.Scene(meshes, masks=MESH_MASKS)
    inside = scene.contains(points, 9, mask=point_masks)
    row_masks = np.repeat(MESH_MASKS, np.diff(offsets))
    for mask in np.unique(point_masks):
        these = point_masks == mask
        expected = _parity_votes(vertices, faces[row_masks & mask != 0], points[these], 9)
        np.testing.assert_array_equal(inside[these], expected)


def test_sample_directions_are_unit_and_spread():
    for n in (1, 3, 5, 15):
        directions = sample_directions(n).astype(np.float64)
        np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1, rtol=1e-6)
        assert (np.abs(directions) > 1e-3).all()  # none in a coordinate plane
    assert abs(sample_directions(15).astype(np.float64).mean(axis=0)).max() < 0.2


# ---- Real scenes, trimesh and Open3D


def _shared_points(vertices, n, seed):
    """Half uniform in the box, half near the surface (vertices moved by 1 % of the size)."""
    rng = np.random.default_rng(seed)
    size = _size(vertices)
    near = vertices[rng.integers(0, len(vertices), n - n // 2)].astype(np.float64)
    near += rng.normal(scale=0.01 * size, size=near.shape)
    return np.concatenate([_points(vertices, n // 2, rng, margin=0.05), near]).astype(np.float32)


@pytest.mark.parametrize("name", ["bunny", "dragon"])
def test_shared_scene_matches_the_brute_force(name, load_shared):
    vertices, faces = load_shared(name)
    points = _shared_points(vertices, 200, 16)
    found = dacrt.Scene([(vertices, faces)]).nearest(points, threads=2)
    expected = pr.nearest(points, vertices, faces)
    offsets = np.array([0, len(faces)])
    _check_against_reference(found, expected, vertices, faces, offsets, points)


@pytest.mark.parametrize("name", ["dragon", "armadillo"])
def test_closed_shared_scene_against_trimesh_and_open3d(name, load_shared):
    """On watertight meshes: inside as trimesh's ``contains`` says, distances as Open3D's
    (float32), and signs as Open3D's, on points not within 0.1 % of the size of the surface."""
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("open3d")
    from oracles import open3d_points

    vertices, faces = load_shared(name)
    points = _shared_points(vertices, 4000, 17)
    scene = dacrt.Scene([(vertices, faces)])
    found = scene.nearest(points)
    apart = found.distance > 1e-3 * _size(vertices)
    inside = scene.contains(points, 3)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    np.testing.assert_array_equal(inside[apart], mesh.contains(points[apart]))

    rival = open3d_points.scene(vertices, faces)
    theirs = open3d_points.distance(rival, points)
    np.testing.assert_allclose(found.distance, theirs, rtol=1e-4, atol=1e-6 * _size(vertices))
    their_sign = open3d_points.signed_distance(rival, points, nsamples=3)
    signed = scene.signed_distance(points, 3)
    np.testing.assert_array_equal(signed[apart] < 0, their_sign[apart] < 0)


def _thin_triangles(kind, n, rng):
    """(n, 3, 3) float32 triangles of unit size whose third corner lies within 1e-6 of the line
    of the others: near its middle (``cap``, an angle near 180 degrees) or next to the second
    corner (``needle``, two long edges and a short one)."""
    a, b = rng.uniform(-1, 1, (2, n, 3))
    if kind == "cap":
        c = a + (b - a) * rng.uniform(0.1, 0.9, (n, 1)) + rng.normal(0, 1e-6, (n, 3))
    else:
        c = b + rng.normal(0, 1e-6, (n, 3))
    return np.stack([a, b, c], axis=1).astype(np.float32)


# A sliver of unit size 1e-6 high and a point 1e-7 off its face, where a normal taken at the
# corner of a small angle cancels.
SLIVER = np.array(
    [
        [0.7916008830070496, 0.7952451705932617, 0.01469050720334053],
        [-0.7664663195610046, -0.8265353441238403, 0.9378830194473267],
        [0.012567698024213314, -0.015644792467355728, 0.47628602385520935],
    ],
    np.float32,
)
SLIVER_POINT = np.array(
    [0.012567495927214622, -0.01564505137503147, 0.47628653049468994], np.float32
)


@pytest.mark.parametrize("kind", ["sliver", "cap", "needle"])
def test_a_thin_triangles_face_distance_is_accurate(kind):
    """The distance to a thin triangle's face is the exact (rational) one to float64 rounding
    of the triangle's size, then rounded to float32, as for any other triangle: points 1e-9 to
    1e-3 off the face of triangles 1e-6 high, their projections well inside the face."""
    rng = np.random.default_rng(41)
    if kind == "sliver":
        triangles, points = SLIVER[None], SLIVER_POINT[None]
    else:
        triangles = _thin_triangles(kind, 60, rng)
        corners = triangles.astype(np.float64)
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        weights = rng.dirichlet([4, 4, 4], len(triangles))
        offsets = rng.choice([1e-9, 1e-7, 1e-5, 1e-3], len(triangles)) * rng.choice([-1, 1])
        inner = np.einsum("nk,nka->na", weights, corners)
        points = (inner + offsets[:, None] * normals).astype(np.float32)
    checked = 0
    for corners, point in zip(triangles, points):
        exact, weights = pr.exact_face_distance(point, corners)
        if weights.min() < 0.01:  # float32 rounding moved the point near or past an edge
            continue
        found = dacrt.Scene([(corners, np.array([[0, 1, 2]]))]).nearest(point[None])
        size = max(np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1))
        # float64 rounding of the size (2^-53 a unit), then float32 rounding of the distance.
        bound = 3 * 2.0**-53 * (size + exact) + np.spacing(np.float32(exact)) / 2
        assert abs(float(found.distance[0]) - exact) <= bound, (corners, point, exact)
        checked += 1
    assert checked >= len(triangles) * 0.8
