"""``Scene(meshes, transforms=...)``: meshes placed by 4x4 affine matrices, and instances.

A placed mesh is an instance, traced in its own space: it must answer as the same mesh placed in
numpy (float64, then float32) and passed whole up to rounding (``placed_checks``: the same hits
but at exact edges, t within a few ulps), and like the reference on the placed triangles
(normals in scene space: the cross product of the placed corners, whatever the matrix does to
orientation). Bad matrices are ValueErrors naming ``transforms[i]``.
"""

from __future__ import annotations

import functools

import assertions as check
import hitlist_checks as hc
import numpy as np
import placed_checks as pc
import procedural as pg
import pytest
import reference
import sample_scenes

import dacrt

BIG = 256  # max_hits that truncates nothing here


def affine(linear=None, offset=(0.0, 0.0, 0.0)):
    """A (4, 4) float64 affine matrix from a 3x3 part and a translation."""
    m = np.eye(4)
    if linear is not None:
        m[:3, :3] = linear
    m[:3, 3] = offset
    return m


MATRICES = {
    "rotation": affine(pg.rotation([1.0, 2.0, 0.5], 0.7), (0.25, -0.5, 0.125)),
    "reflection": affine(np.diag([-1.0, 1.0, 1.0]) @ pg.rotation([0.0, 1.0, 1.0], 0.4), (1, 0, 0)),
    "nonuniform_scale": affine(
        np.diag([3.0, 0.25, 1.5]) @ pg.rotation([1.0, 0.0, 1.0], 0.3), (0, 1, 0)
    ),
    "shear": affine([[1.0, 0.6, 0.0], [0.0, 1.0, -0.4], [0.2, 0.0, 0.9]], (-0.3, 0.2, 0.5)),
    # Far from the origin: float32 arithmetic would round the placed vertices differently.
    "far": affine(pg.rotation([0.3, -1.0, 0.2], 1.1) * 7.0, (1000.0, -2000.0, 500.0)),
}


def place(vertices, matrix):
    """``M[:3, :3] @ p + M[:3, 3]`` for each vertex with numpy's matmul in float64, then float32.

    The contract names this expression: another float64 order of operations can differ in the
    last bit where the terms cancel, and then, rarely, in float32 (the "shear" matrix here moves
    a few corners by one float32 step if the sums are written out term by term).
    """
    v = np.asarray(vertices, dtype=np.float64)
    m = np.asarray(matrix, dtype=np.float64)
    return (v @ m[:3, :3].T + m[:3, 3]).astype(np.float32)


@functools.cache
def _meshes():
    """A closed perturbed icosphere, a soup and a tilted grid (their own copies)."""
    return [
        sample_scenes.sphere(6)[0],
        pg.triangle_soup(400, np.random.default_rng(6)),
        sample_scenes.tilted_grid(6)[0],
    ]


def _queries(scene, o, d, **options):
    return {
        "closest": scene.closest(o, d, **options),
        "occluded": scene.occluded(o, d, **options),
        "hits": scene.hits(o, d, max_hits=BIG, **options),
        "count": scene.count(o, d, **options),
    }


def assert_close_to_placed(got, want, o, d, placed, what):
    """Instances' answers ``got`` against the placed copies' ``want`` (``placed_checks``):
    occluded and count agree but on the rays whose closest hit or miss differs at an edge."""
    flipped = pc.check_closest_close_to_placed(got["closest"], want["closest"], o, d, placed, what)
    clear = np.ones(len(o), bool)
    clear[flipped] = False
    assert clear.mean() > 0.99, what
    np.testing.assert_array_equal(
        got["occluded"].occluded[clear], want["occluded"].occluded[clear], what
    )
    np.testing.assert_array_equal(got["occluded"].occluded, got["closest"].mesh >= 0, what)
    np.testing.assert_array_equal(got["count"].count[clear], want["count"].count[clear], what)
    keep = np.flatnonzero(clear)
    pc.check_hits_close_to_placed(
        subset(got["hits"], keep), subset(want["hits"], keep), o[keep], d[keep], what
    )


def subset(hl, rays):
    """The HitList of rays ``rays`` only."""
    counts = np.diff(hl.offsets)[rays]
    offsets = np.zeros(len(rays) + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    rows = np.concatenate([np.arange(hl.offsets[r], hl.offsets[r + 1]) for r in rays] + [[]])
    rows = rows.astype(np.int64)
    return dacrt.HitList(
        offsets, hl.t[rows], hl.mesh[rows], hl.prim[rows], hl.u[rows], hl.v[rows],
        hl.normal[rows], hl.truncated[rays],
    )  # fmt: skip


def assert_same_answers(a, b, what):
    for query, answer in a.items():
        other = b[query]
        if query == "hits":
            hc.assert_same_hitlist(answer, other, f"{what}: hits")
            continue
        for name, value in vars(answer).items():
            if name != "stats":
                np.testing.assert_array_equal(value, getattr(other, name), f"{what}: {query}")


@pytest.mark.parametrize("kind", sorted(MATRICES))
def test_placed_meshes_answer_as_meshes_placed_in_numpy(kind):
    """Two of three meshes placed by a matrix (one left as given): every query, culled or not,
    answers as the scene of the numpy-placed meshes up to rounding, and matches the reference
    there."""
    meshes = _meshes()
    m = MATRICES[kind]
    matrices = [m, None, m @ MATRICES["rotation"]]
    placed = [(v if m is None else place(v, m), f) for (v, f), m in zip(meshes, matrices)]
    scene = dacrt.Scene(meshes, transforms=matrices)
    whole = dacrt.Scene(placed)
    vertices, faces, offsets = pg.concat(placed)
    rng = np.random.default_rng(7)
    rays = [pg.mixed_rays(pg.bounds(v), n, rng) for (v, _), n in zip(placed, (200, 100, 100))]
    o, d = (np.concatenate(x) for x in zip(*rays))
    for cull in ("none", "back", "front"):
        got = _queries(scene, o, d, cull=cull)
        what = f"{kind}, cull={cull}"
        assert_close_to_placed(got, _queries(whole, o, d, cull=cull), o, d, placed, what)
        hc.check_hitlist_layout(got["hits"], len(o))
        if cull == "front" or kind == "far":
            continue  # the reference's culling is tested elsewhere; two sides are enough here
        ref = reference.all_hits(vertices, faces, o, d, cull=cull)
        assert ref.count.sum() > 200
        hc.check_hits_match_reference(got["hits"], ref, vertices, faces, offsets, o, d, kind)
        np.testing.assert_array_equal(got["count"].count, ref.count)
    if kind == "far":
        return  # the placed copies' float32 corners are the reference's: instances differ more
    check.check_against_reference(
        got["closest"], vertices, faces, o, d, mesh_offsets=offsets, min_hits=100, min_clear=0.8,
        cull="front",
    )  # fmt: skip


# Meshes modelled far from their own origin (in world or georeferenced coordinates) and placed
# back near the scene's: (offset along (1, -0.6, 0.3), the meshes' size).
FAR_MODELLED = [(1e3, 1.0), (1e4, 1.0), (1e4, 10.0), (1e5, 100.0), (1e6, 1.0), (1e6, 1000.0)]
FAR_DIRECTION = np.array([1.0, -0.6, 0.3])


def modelled_far(offset, size, linear):
    """``_meshes()`` scaled by ``size`` and given at ``offset`` along FAR_DIRECTION (rounded to
    float32 there), and matrices that place them back beside the origin by ``linear`` (3, 3):
    (meshes, matrices)."""
    shift = offset * FAR_DIRECTION
    meshes = [((v * size + shift).astype(np.float32), f) for v, f in _meshes()]
    beside = [(0.0, 0.0, 0.0), (3.0 * size, 0.0, 0.0), (0.0, 3.0 * size, 0.0)]
    return meshes, [affine(linear, beside[k] - linear @ shift) for k in range(len(meshes))]


@pytest.mark.parametrize("kind", ["translation", "rotation"])
@pytest.mark.parametrize(("offset", "size"), FAR_MODELLED)
def test_meshes_modelled_far_from_their_origin_answer_as_placed_copies(offset, size, kind):
    """Meshes whose vertices lie up to a million units from their own origin, placed back by a
    translation (the placed copies are then the meshes moved exactly) or a rotation: every
    query answers as the placed copies within the bounds of meshes near their origin."""
    linear = np.eye(3) if kind == "translation" else pg.rotation([1.0, 2.0, 0.5], 0.7)
    meshes, matrices = modelled_far(offset, size, linear)
    placed = [(place(v, m), f) for (v, f), m in zip(meshes, matrices)]
    if kind == "translation":
        for (v, _), m, (p, _) in zip(meshes, matrices, placed):
            np.testing.assert_array_equal(p, v.astype(np.float64) + m[:3, 3])  # exact
    scene = dacrt.Scene(meshes, transforms=matrices)
    whole = dacrt.Scene(placed)
    rng = np.random.default_rng(11)
    rays = [pg.mixed_rays(pg.bounds(v), 300, rng) for v, _ in placed]
    o, d = (np.concatenate(x) for x in zip(*rays))
    for cull in ("none", "back"):
        got = _queries(scene, o, d, cull=cull)
        what = f"{kind}, offset {offset:g}, size {size:g}, cull={cull}"
        assert_close_to_placed(got, _queries(whole, o, d, cull=cull), o, d, placed, what)
        assert (got["closest"].mesh >= 0).sum() > 200, what


def test_a_mesh_far_from_its_origin_is_packed_exactly_relative_to_a_point_of_its_box():
    """A mesh given far from its own origin is packed relative to a point of its box (its frame
    centre), exactly: the packed corners plus that point are the mesh's own corners; a mesh near
    its origin keeps its own coordinates."""
    meshes, matrices = modelled_far(1e5, 1.0, np.eye(3))
    scene = dacrt.Scene(meshes, transforms=matrices)
    for instance, (v, f) in zip(scene._instances, meshes):
        centre = instance.packed.centre.astype(np.float64)
        assert (v.min(axis=0) <= centre).all() and (centre <= v.max(axis=0)).all()
        corners = instance.packed.verts.reshape(-1, 3).astype(np.float64) + centre
        np.testing.assert_array_equal(corners, v[f[instance.packed.ids]].reshape(-1, 3))
    near = dacrt.Scene(_meshes(), transforms=[np.eye(4)] * 3)
    assert not any(instance.packed.centre.any() for instance in near._instances)


@pytest.mark.parametrize("kind", ["reflection", "nonuniform_scale"])
def test_normals_are_those_of_the_placed_corners(kind):
    """Normals are (p1-p0) x (p2-p0) of the placed corners, normalised: for a reflection they
    turn with the winding (a closed sphere then faces inwards), for a non-uniform scale they are
    not the matrix applied to the mesh's normals."""
    (v, f) = _meshes()[0]
    m = MATRICES[kind]
    scene = dacrt.Scene([(v, f)], transforms=[m])
    placed = place(v, m)
    centre = m[:3, 3]
    o, d = pg.rays_at(
        np.broadcast_to(centre, (300, 3)), pg.unit_vectors(300, np.random.default_rng(8)), 8.0
    )
    hits = scene.closest(o, d)
    assert (hits.prim >= 0).all()
    expected = reference.normals(placed, f, hits.prim)
    np.testing.assert_allclose(hits.normal, expected, atol=1e-5)
    naive = reference.normals(v, f, hits.prim) @ m[:3, :3].T
    naive /= np.linalg.norm(naive, axis=1, keepdims=True)
    assert np.abs(naive - expected).max() > 0.1  # the naive normals would fail the check above
    facing = np.einsum("ij,ij->i", hits.normal, d)
    if kind == "reflection":
        # Placed inside out: from outside the first hit is a back face, and culling back faces
        # leaves the far side.
        assert (facing > 0).all()
        far = scene.closest(o, d, cull="back")
        assert (far.prim >= 0).all() and (far.t > hits.t).all()
    else:
        assert (facing < 0).all()
        np.testing.assert_array_equal(scene.closest(o, d, cull="back").t, hits.t)


def test_instances_of_one_mesh_with_their_own_matrices_and_masks():
    """One (vertices, faces) pair three times, side by side along x, each with its own matrix
    and mask: each instance is its own mesh in the answers, prim is the row of the shared faces,
    and per-ray masks pick instances, as with three meshes placed in numpy (up to rounding)."""
    v, f = _meshes()[0]
    matrices = [
        affine(pg.rotation([0, 0, 1.0], 0.3), (0.0, 0.0, 0.0)),
        affine(np.diag([1.0, 0.5, 1.0]), (3.0, 0.0, 0.0)),
        affine(np.diag([-1.0, 1.0, 1.0]), (6.0, 0.0, 0.0)),
    ]
    masks = np.array([0b001, 0b010, 0b100], np.uint32)
    scene = dacrt.Scene([(v, f)] * 3, masks=masks, transforms=matrices)
    placed = [(place(v, m), f) for m in matrices]
    whole = dacrt.Scene(placed, masks=masks)
    rng = np.random.default_rng(9)
    o, d = sample_scenes.mixed_rays(placed, 9, n=600)
    ray_masks = rng.choice(np.array([0b001, 0b010, 0b100, 0b110, 0b111], np.uint32), len(o))
    for mask in (None, ray_masks):
        got = _queries(scene, o, d, mask=mask)
        want = _queries(whole, o, d, mask=mask)
        assert_close_to_placed(got, want, o, d, placed, f"instances, mask={mask is not None}")
    # A ray along +x through the three centres crosses each instance twice, in order.
    hl = scene.hits(np.array([[-5.0, 0.01, 0.02]], np.float32), np.array([[1.0, 0, 0]], np.float32))
    np.testing.assert_array_equal(hl.mesh, [0, 0, 1, 1, 2, 2])
    assert np.all(hl.prim < len(f))
    hl = scene.hits(
        np.array([[-5.0, 0.01, 0.02]], np.float32),
        np.array([[1.0, 0, 0]], np.float32),
        mask=np.uint32(0b101),
    )
    np.testing.assert_array_equal(hl.mesh, [0, 0, 2, 2])


def test_no_transforms_and_identities_change_nothing():
    meshes = _meshes()
    o, d = sample_scenes.mixed_rays(meshes, 10, n=400)
    plain = _queries(dacrt.Scene(meshes), o, d)
    for transforms in ([None] * 3, [np.eye(4), None, np.eye(4).tolist()]):
        got = _queries(dacrt.Scene(meshes, transforms=transforms), o, d)
        assert_same_answers(got, plain, f"transforms={transforms}")


def test_an_identity_gives_the_normals_bits_signs_of_zero_included():
    """Axis-aligned triangles have zero normal components, some of them -0.0: an identity
    placement keeps every bit of the normals (closest and every hit), as the mesh given."""
    flat, flat_faces = pg.grid(4, 1.0)
    upright = flat[:, [2, 0, 1]]  # the same grid in the plane x = 0, and in y = 0
    sideways = flat[:, [1, 2, 0]]
    meshes = [
        (np.float32([[3, 1, 1], [3, 1, 2], [3, 0, 2]]), np.int32([[0, 1, 2]])),
        (flat, flat_faces),
        (upright, flat_faces[:, ::-1].copy()),
        (sideways, flat_faces),
    ]
    rng = np.random.default_rng(21)
    vertices, faces, _ = pg.concat(meshes)
    corners = vertices[faces[rng.integers(0, len(faces), 3000)]]
    weights = rng.dirichlet([1.0, 1.0, 1.0], 3000)[:, :, None]
    o = rng.uniform(-0.5, 3.5, (3000, 3)).astype(np.float32)
    d = ((corners * weights).sum(axis=1) - o).astype(np.float32)  # at a point of a triangle
    o[0], d[0] = [1.5, 1.5, 1.5], [1.5, -0.75, 0.25]
    plain = dacrt.Scene(meshes)
    placed = dacrt.Scene(meshes, transforms=[np.eye(4)] * len(meshes))
    a, b = plain.closest(o, d), placed.closest(o, d)
    assert (a.mesh >= 0).sum() > 2000 and np.signbit(a.normal).any()
    assert a.normal.tobytes() == b.normal.tobytes()
    assert a.t.tobytes() == b.t.tobytes() and a.prim.tobytes() == b.prim.tobytes()
    a, b = plain.hits(o, d, max_hits=BIG), placed.hits(o, d, max_hits=BIG)
    assert a.normal.tobytes() == b.normal.tobytes() and a.t.tobytes() == b.t.tobytes()


BAD_MATRICES = {
    "shape (3, 3)": (np.eye(3), "shape"),
    "shape (4, 3)": (np.eye(4)[:, :3], "shape"),
    "flat (16,)": (np.eye(4).ravel(), "shape"),
    "ragged": ([[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "4x4"),
    "text": ("identity", "4x4|shape"),
    "complex": (np.eye(4) * (1 + 1j), "real numbers, got dtype complex128"),
    "text entries": (np.eye(4).astype(str), "real numbers, got dtype <U32"),
    "booleans": (np.eye(4, dtype=bool), "real numbers, got dtype bool"),
    "nan": (np.where(np.eye(4) == 1, np.eye(4), np.nan), "non-finite"),
    "inf": (affine(offset=(np.inf, 0, 0)), "non-finite"),
    "last row scaled": (np.diag([1.0, 1.0, 1.0, 2.0]), "not affine"),
    "projective": (np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]), "not affine"),
    "zero": (affine(np.zeros((3, 3))), "singular"),
    "flattening": (affine(np.diag([1.0, 1.0, 0.0])), "singular"),
    "rank two": (affine([[1, 2, 3], [2, 4, 6], [0, 0, 1.0]]), "singular"),
    "an axis scaled to 1e-38": (affine(np.diag([1e-38, 1.0, 1.0])), "scales an axis by 1e-38"),
    "all scaled to 1e-13": (affine(np.eye(3) * 1e-13), "under 1e-12"),
}


@pytest.mark.parametrize("case", sorted(BAD_MATRICES))
def test_bad_transforms_are_value_errors_naming_the_entry(case):
    matrix, message = BAD_MATRICES[case]
    meshes = _meshes()
    with pytest.raises(ValueError, match=r"transforms\[1\]") as raised:
        dacrt.Scene(meshes, transforms=[None, matrix, np.eye(4)])
    assert raised.match(message)
    with pytest.raises(ValueError, match=message) as raised:
        dacrt.check_transform(matrix)
    assert raised.match("matrix")
    with pytest.raises(ValueError, match=r"frames\[0\]\.transform"):
        dacrt.check_transform(matrix, name="frames[0].transform")


def test_transforms_of_the_wrong_length_or_out_of_range():
    meshes = _meshes()
    with pytest.raises(ValueError, match="transforms"):
        dacrt.Scene(meshes, transforms=[None, None])
    with pytest.raises(ValueError, match="transforms"):
        dacrt.Scene(meshes, transforms=[None] * 4)
    # A placement beyond the float32 range.
    with pytest.raises(ValueError, match=r"transforms\[2\]"):
        dacrt.Scene(meshes, transforms=[None, None, affine(np.eye(3) * 1e39)])


def test_a_ray_beyond_float32_in_a_mesh_space_is_an_error_naming_the_mesh():
    """A ray whose origin, moved into a placed mesh's space, leaves float32's range cannot be
    traced there: the error names that mesh by its index (``mesh``, for callers' own names)."""
    meshes = _meshes()
    halved = affine(np.eye(3) * 0.5)
    scene = dacrt.Scene(meshes, transforms=[None, halved, None])
    origins = np.array([[0.1, 0.1, 3e38], [0.1, 0.1, 5.0]], np.float32)
    directions = np.array([[0, 0, -1], [0, 0, -1]], np.float32)
    with pytest.raises(dacrt.MeshSpaceError, match="in the space of mesh 1") as raised:
        scene.closest(origins, directions)
    assert raised.value.mesh == 1 and isinstance(raised.value, dacrt.InputError)
    assert len(scene.closest(origins[1:], directions[1:]).t) == 1  # the near ray is traced


def test_many_transforms_checked_at_once_name_the_first_bad_one():
    """A frame of many placements is checked in one pass: the error names the first bad entry,
    whatever its kind, and the scene the frame was to change is left as it was. A placement
    that only the singular values accept (an axis scaled a little over the least scale) is
    accepted, as ``check_transform`` accepts it."""
    sphere = sample_scenes.sphere(6)[0]
    rng = np.random.default_rng(3)
    moves = [affine(pg.rotation(rng.normal(size=3), 0.3), rng.normal(size=3)) for _ in range(50)]
    scene = dacrt.Scene([sphere] * 50, transforms=moves)
    o, d = pg.mixed_rays(np.array([[-4.0, -4, -4], [4, 4, 4]]), 2000, rng)
    before = scene.closest(o, d)
    barely = affine(np.diag([1.5e-12, 1e3, 1e3]))
    np.testing.assert_array_equal(dacrt.check_transform(barely), barely)
    for bad, message in [
        (np.where(np.eye(4) == 1, np.eye(4), np.nan), "non-finite"),
        (affine(np.diag([1.0, 1.0, 0.0])), "singular"),
        (affine(np.eye(3) * 1e-13), "under 1e-12"),
        (np.eye(4)[:3].tolist(), r"shape \(4, 4\)"),
    ]:
        changes = {i: moves[(i + 1) % 50] for i in range(50)}
        changes[41], changes[37] = barely, bad  # the first bad entry, by mesh index, is 37
        changes[45] = "eye"  # a later entry that is no matrix at all is named after it
        with pytest.raises(ValueError, match=r"transforms\[37\]") as raised:
            scene.with_changes(transforms=changes)
        assert raised.match(message)
    changes = {i: moves[(i + 1) % 50] for i in range(50)} | {41: barely}
    moved = scene.with_changes(transforms=changes)
    fresh = dacrt.Scene([sphere] * 50, transforms=[changes[i] for i in range(50)])
    assert_same_answers({"closest": moved.closest(o, d)}, {"closest": fresh.closest(o, d)}, "moved")
    assert_same_answers({"closest": scene.closest(o, d)}, {"closest": before}, "unchanged")
    assert (before.mesh >= 0).mean() > 0.2  # the rays meet the spheres


def test_a_placement_beyond_float32_is_named_in_mesh_order():
    """Each mesh's start placement, then its end, mesh after mesh: the first to place its mesh
    beyond float32 is named (an end of mesh 0 before the start of mesh 1)."""
    sphere = sample_scenes.sphere(4)[0]
    far = affine(np.eye(3) * 1e39)
    with pytest.raises(ValueError, match=r"transforms_end\[0\] places mesh 0 beyond"):
        dacrt.Scene([sphere] * 2, transforms=[np.eye(4), far], transforms_end=[far, None])
    with pytest.raises(ValueError, match=r"^transforms\[0\] places mesh 0 beyond"):
        dacrt.Scene([sphere] * 2, transforms=[far, far], transforms_end=[far, None])


def test_check_transform_returns_the_matrix_as_float64():
    m = MATRICES["shear"]
    got = dacrt.check_transform(m.tolist())
    assert got.dtype == np.float64 and got.shape == (4, 4)
    np.testing.assert_array_equal(got, m)
    np.testing.assert_array_equal(dacrt.check_transform(np.eye(4, dtype=np.float32)), np.eye(4))
    # A reflection is invertible, and so a valid placement.
    np.testing.assert_array_equal(
        dacrt.check_transform(MATRICES["reflection"]), MATRICES["reflection"]
    )


def slab_reaches(origins, directions, tmin, tmax, box, grow):
    """(n,) bool: whether each ray's segment [tmin, tmax] reaches ``box`` (6,) grown by ``grow``
    on every side (negative shrinks it), in float64 NumPy."""
    lo = np.asarray(box[:3], np.float64) - grow
    hi = np.asarray(box[3:], np.float64) + grow
    o = origins.astype(np.float64)
    d = directions.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (lo - o) / d
        b = (hi - o) / d
    near = np.where(d == 0, np.where((o >= lo) & (o <= hi), -np.inf, np.inf), np.minimum(a, b))
    far = np.where(d == 0, np.where((o >= lo) & (o <= hi), np.inf, -np.inf), np.maximum(a, b))
    enter = np.maximum(near.max(axis=1), tmin)
    leave = np.minimum(far.min(axis=1), tmax)
    return enter <= leave


@pytest.mark.parametrize("threads", [1, 3])
def test_rays_reaching_instances_match_a_slab_test(threads):
    """The rays sorted into each instance's box (``Scene._rays_reaching``: more than 64 boxes,
    so two words of bits, in groups; masks; finished occlusion rays; rays along the axes and
    through box corners) are every ray a NumPy slab test says reaches the box shrunk by a
    margin and none it says misses the box grown by it, in increasing order, on any threads."""
    rng = np.random.default_rng(7)
    n_boxes, n_rays = 70, 40_000
    lo = rng.uniform(-10, 10, (n_boxes, 3))
    boxes = np.hstack([lo, lo + rng.uniform(0.2, 3, (n_boxes, 3))]).astype(np.float32)
    origins = rng.uniform(-12, 12, (n_rays, 3)).astype(np.float32)
    directions = rng.normal(size=(n_rays, 3)).astype(np.float32)
    directions[::7, 1:] = 0  # along x
    corners = boxes[rng.integers(0, n_boxes, n_rays // 5), :3]
    directions[::5] = corners - origins[::5]  # through a corner at t = 1
    tmin = rng.uniform(0, 0.5, n_rays).astype(np.float32)
    limit = rng.choice([np.inf, 1.0, 5.0, -np.inf], n_rays).astype(np.float32)
    ray_masks = rng.integers(1, 16, n_rays).astype(np.uint32)
    box_masks = (1 << rng.integers(0, 4, n_boxes)).astype(np.uint32)

    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    faces = np.array([[0, 1, 2]], np.int32)
    scene = dacrt.Scene([(vertices, faces)] * n_boxes, masks=box_masks)
    instances = [type("Placed", (), {"mesh": i}) for i in range(n_boxes)]
    found = scene._rays_reaching(
        instances, list(boxes), origins, directions, tmin, limit, ray_masks, threads
    )
    margin = 1e-4
    for b in range(n_boxes):
        ids = found[b]
        assert np.all(np.diff(ids) > 0)
        seen = (ray_masks & box_masks[b]) != 0
        surely = seen & slab_reaches(origins, directions, tmin, limit, boxes[b], -margin)
        maybe = seen & slab_reaches(origins, directions, tmin, limit, boxes[b], margin)
        chosen = np.zeros(n_rays, bool)
        chosen[ids] = True
        assert np.all(chosen[surely]), f"box {b}: a ray that reaches it is missing"
        assert not np.any(chosen & ~maybe), f"box {b}: a ray that misses it is listed"
        assert surely.sum() > 0
