"""Scenes of a static world and moving instances: ``Scene.with_changes`` and the two-level trace.

A scene made by ``with_changes`` answers as a new Scene of the same meshes, bit for bit, and the
scene it came from keeps its answers; instances give the same answers for every strategy and
thread count, and each is watertight in its own space.
"""

from __future__ import annotations

import functools

import numpy as np
import procedural as pg
import pytest
import sample_scenes
from test_engine_instances import BIG, MATRICES, _queries, affine, assert_same_answers

import dacrt


@functools.cache
def _world():
    """Five meshes: two as given (a soup, a sphere), a grid and two instances of one sphere
    (the same arrays), placed."""
    sphere = sample_scenes.sphere(21)[0]
    meshes = [
        pg.triangle_soup(300, np.random.default_rng(22)),
        sample_scenes.sphere(23)[0],
        sample_scenes.tilted_grid(24)[0],
        sphere,
        sphere,
    ]
    transforms = [
        None,
        None,
        MATRICES["shear"],
        affine(pg.rotation([0, 1.0, 0], 0.4), (2.5, 0.0, 0.0)),
        MATRICES["reflection"] @ affine(offset=(0.0, 2.0, 0.0)),
    ]
    masks = np.array([1, 2, 4, 8, 16], np.uint32)
    return meshes, transforms, masks


def _rays(meshes, transforms, n=800, seed=25):
    """Mixed rays over the placed scene's box."""
    corners = []
    for (v, _), m in zip(meshes, transforms):
        v = v.astype(np.float64)
        corners.append(v if m is None else v @ m[:3, :3].T + m[:3, 3])
    return pg.mixed_rays(pg.bounds(np.concatenate(corners)), n, np.random.default_rng(seed))


def _all_queries(scene, o, d, ray_masks):
    answers = {}
    for cull in ("none", "back"):
        for mask in (None, np.uint32(0b11010), ray_masks):
            label = "per-ray" if mask is ray_masks else mask
            for name, answer in _queries(scene, o, d, cull=cull, mask=mask).items():
                answers[f"{name}, cull={cull}, mask={label}"] = answer
    return answers


CHANGES = {
    "move an instance": dict(transforms={3: affine(offset=(2.0, 1.0, 0.5))}),
    "deform a base mesh": dict(vertices={1: "scaled"}),
    "deform an instance": dict(vertices={4: "scaled"}),
    "place a base mesh": dict(transforms={0: MATRICES["rotation"]}),
    "put an instance as given": dict(transforms={2: None}),
    "masks": dict(masks={0: 3, 3: 0}),
    "all at once": dict(
        transforms={0: MATRICES["nonuniform_scale"], 2: None, 3: MATRICES["far"]},
        vertices={1: "scaled", 3: "scaled"},
        masks={4: 7},
    ),
}


def _resolved(change, meshes):
    """``change`` with "scaled" vertices made: the mesh's vertices times 1.1."""
    vertices = {i: meshes[i][0] * np.float32(1.1) for i in change.get("vertices", {})}
    return {**change, "vertices": vertices} if vertices else change


@pytest.mark.parametrize("case", sorted(CHANGES))
def test_with_changes_answers_as_a_new_scene_and_leaves_the_old_one(case):
    meshes, transforms, masks = _world()
    o, d = _rays(meshes, transforms)
    ray_masks = np.random.default_rng(26).integers(1, 32, len(o)).astype(np.uint32)
    old = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    before = _all_queries(old, o, d, ray_masks)
    change = _resolved(CHANGES[case], meshes)
    new = old.with_changes(**change)
    # The same meshes, masks and transforms, given whole.
    new_meshes = [(change.get("vertices", {}).get(i, v), f) for i, (v, f) in enumerate(meshes)]
    new_transforms = list(transforms)
    for i, m in change.get("transforms", {}).items():
        new_transforms[i] = m
    new_masks = masks.copy()
    for i, m in change.get("masks", {}).items():
        new_masks[i] = m
    fresh = dacrt.Scene(new_meshes, masks=new_masks, transforms=new_transforms)
    got = _all_queries(new, o, d, ray_masks)
    assert_same_answers(got, _all_queries(fresh, o, d, ray_masks), case)
    assert_same_answers(_all_queries(old, o, d, ray_masks), before, f"{case}: the old scene")
    assert new.n_triangles == fresh.n_triangles and new.n_meshes == fresh.n_meshes
    np.testing.assert_array_equal(new.masks, fresh.masks)
    np.testing.assert_array_equal(new.bounds, fresh.bounds)
    # A chain of versions: changing back gives the first answers again.
    if case == "move an instance":
        back = new.with_changes(transforms={3: transforms[3]})
        assert_same_answers(_all_queries(back, o, d, ray_masks), before, f"{case}: back")


def test_with_changes_shares_what_did_not_change():
    meshes, transforms, masks = _world()
    old = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    # Instances of one (vertices, faces) pair share one packing.
    assert old._parts[3] is old._parts[4]
    moved = old.with_changes(transforms={3: affine(offset=(0.0, 0.0, 5.0))}, masks={1: 9})
    assert moved._base is old._base
    assert all(moved._parts[i] is old._parts[i] for i in range(len(meshes)))
    assert moved._instance_of[2] is old._instance_of[2]
    deformed = old.with_changes(vertices={3: meshes[3][0] + np.float32(0.5)})
    assert deformed._base is old._base
    assert deformed._parts[3] is not old._parts[3] and deformed._parts[4] is old._parts[4]
    rebased = old.with_changes(vertices={1: meshes[1][0] * np.float32(2)})
    assert rebased._base is not old._base and rebased._parts[3] is old._parts[3]


def test_mesh_offsets_and_bounds_are_read_only():
    """Every version of a scene shares its mesh_offsets, and bounds answers one cached array:
    writing into either raises (as into masks), and neither changes."""
    meshes, transforms, masks = _world()
    old = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    moved = old.with_changes(transforms={3: affine(offset=(0.0, 0.0, 5.0))})
    offsets = [0, *np.cumsum([len(faces) for _, faces in meshes])]
    bounds = old.bounds.copy()
    for array in (old.mesh_offsets, moved.mesh_offsets, old.bounds, moved.bounds, old.masks):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 7
    assert old.mesh_offsets.tolist() == offsets and moved.mesh_offsets.tolist() == offsets
    np.testing.assert_array_equal(old.bounds, bounds)


def _collapsed(vertices, faces, rows):
    """``vertices`` with each of ``faces[rows]``'s second corner moved onto its first: those
    triangles (and their neighbours' shared corners) degenerate or move."""
    out = vertices.copy()
    out[faces[rows, 1]] = out[faces[rows, 0]]
    return out


def _mesh_rows(scene, i):
    """Mesh i's face rows in the order the scene stores its rows."""
    part = scene._parts[i]
    if isinstance(part, dacrt.packed.Packed):
        return part.ids
    return scene._base.ids[part.lo : part.hi] - scene.mesh_offsets[i]


@pytest.mark.parametrize("placed", [False, True], ids=["as given", "placed"])
def test_new_vertices_keep_the_storage_order_and_answer_as_a_new_scene(placed):
    # A soup stored in Morton order; new vertices of the same faces are gathered in that order
    # (a refit), not sorted again, with the answers of a new Scene, also where triangles become
    # degenerate (they lose their row) or stop being so (theirs comes after the others).
    rng = np.random.default_rng(28)
    v, f = pg.triangle_soup(400, rng)
    other = sample_scenes.sphere(29)[0]
    transforms = [affine(pg.rotation([1.0, 0, 0], 0.3), (0.2, 0, 0)) if placed else None, None]
    flat = _collapsed(v, f, np.arange(0, 400, 7))
    scene = dacrt.Scene([(flat, f), other], transforms=transforms, order="morton")
    o, d = _rays([(v, f), other], transforms, n=600, seed=30)
    ray_masks = np.ones(len(o), np.uint32)
    moved = v + rng.normal(0, 0.2, v.shape)  # another Morton order of its own
    steps = [v, _collapsed(v, f, np.arange(3, 400, 5)), moved]
    for step, vertices in enumerate(steps):
        vertices = vertices.astype(np.float32)
        new = scene.with_changes(vertices={0: vertices})
        fresh = dacrt.Scene([(vertices, f), other], transforms=transforms, order="morton")
        live = set(_mesh_rows(dacrt.Scene([(vertices, f)], order="file"), 0).tolist())
        before = _mesh_rows(scene, 0).tolist()
        after = before + [r for r in range(len(f)) if r not in before]
        assert _mesh_rows(new, 0).tolist() == [r for r in after if r in live], step
        assert_same_answers(
            _all_queries(new, o, d, ray_masks), _all_queries(fresh, o, d, ray_masks), step
        )
        scene = new
    assert not np.array_equal(_mesh_rows(new, 0), _mesh_rows(fresh, 0))  # not sorted again


def test_one_vertex_array_for_two_meshes_with_other_faces():
    v, f = sample_scenes.sphere(31)[0]
    flipped = np.ascontiguousarray(f[::-1, ::-1])
    shifted = (f + 1) % len(v)
    transforms = [affine(offset=(0.0, 0.0, 0.0)), affine(offset=(0.0, 0.5, 0.0))]
    scene = dacrt.Scene([(v, flipped), (v, shifted)], transforms=transforms)
    moved = v * np.float32(1.2)
    new = scene.with_changes(vertices={0: moved, 1: moved})
    fresh = dacrt.Scene([(moved, flipped), (moved, shifted)], transforms=transforms)
    o, d = _rays([(moved, f)] * 2, transforms, n=600, seed=32)
    masks = np.ones(len(o), np.uint32)
    assert_same_answers(_all_queries(new, o, d, masks), _all_queries(fresh, o, d, masks), "one")


def test_a_mesh_with_seven_instances_is_packed_once():
    v, f = sample_scenes.sphere(27)[0]
    matrices = [affine(offset=(3.0 * k, 0.0, 0.0)) for k in range(7)]
    one = dacrt.Scene([(v, f)], transforms=matrices[:1])
    seven = dacrt.Scene([(v, f)] * 7, transforms=matrices)
    assert seven.nbytes - one.nbytes == 8 * 6  # mesh_offsets grow; the packed arrays do not


BAD_CHANGES = {
    "not a dict": (dict(transforms=[np.eye(4)]), "transforms must be a dict"),
    "key out of range": (dict(transforms={5: np.eye(4)}), r"transforms\[5\]: there is no mesh 5"),
    "negative key": (dict(masks={-1: 1}), r"masks\[-1\]"),
    "key not an int": (dict(vertices={"a": np.zeros((3, 3))}), "vertices has key 'a'"),
    "bad matrix": (dict(transforms={2: np.eye(3)}), r"transforms\[2\] must have shape"),
    "singular matrix": (
        dict(transforms={2: affine(np.zeros((3, 3)))}),
        r"transforms\[2\].*singular",
    ),
    "beyond float32": (dict(transforms={1: affine(np.eye(3) * 1e39)}), r"transforms\[1\]"),
    "rows": (dict(vertices={3: np.zeros((12, 3))}), r"vertices\[3\] has 12 rows; mesh 3 has"),
    "shape": (dict(vertices={3: np.zeros((12, 2))}), r"vertices\[3\] must have shape"),
    "not finite": (dict(vertices={0: "nan"}), r"vertices\[0\]\[5\] is not finite"),
    "mask range": (dict(masks={2: 2**32}), r"masks\[2\]"),
    "mask type": (dict(masks={2: 1.5}), r"masks\[2\]"),
}


@pytest.mark.parametrize("case", sorted(BAD_CHANGES))
def test_bad_changes_are_input_errors_naming_the_argument(case):
    meshes, transforms, masks = _world()
    scene = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    change, message = BAD_CHANGES[case]
    if change.get("vertices", {}).get(0) == "nan":
        bad = meshes[0][0].copy()
        bad[5, 1] = np.nan
        change = dict(vertices={0: bad})
    o, d = _rays(meshes, transforms, n=200)
    before = scene.closest(o, d)
    with pytest.raises(dacrt.InputError, match=message):
        scene.with_changes(**change)
    after = scene.closest(o, d)
    np.testing.assert_array_equal(after.t, before.t)
    np.testing.assert_array_equal(after.prim, before.prim)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_instances_give_the_same_answers_for_every_strategy_and_thread_count(strategy, threads):
    meshes, transforms, masks = _world()
    scene = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    # Enough rays for two chunks on two threads.
    o, d = _rays(meshes, transforms, n=40_000, seed=28)
    ray_masks = np.random.default_rng(29).integers(1, 32, len(o)).astype(np.uint32)
    expected = _strategy_answers("sampling", 1)
    for cull, mask in (("none", None), ("front", ray_masks)):
        got = _four(scene, o, d, cull=cull, mask=mask, strategy=strategy, threads=threads)
        assert_same_answers(got, expected[cull], f"{strategy}, {threads} threads, cull={cull}")


def _four(scene, o, d, **options):
    """The four queries' answers (hits with max_hits=4, which truncates some)."""
    return {
        "closest": scene.closest(o, d, **options),
        "occluded": scene.occluded(o, d, **options),
        "hits": scene.hits(o, d, max_hits=4, **options),
        "count": scene.count(o, d, **options),
    }


@functools.cache
def _strategy_answers(strategy, threads):
    meshes, transforms, masks = _world()
    scene = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    o, d = _rays(meshes, transforms, n=40_000, seed=28)
    ray_masks = np.random.default_rng(29).integers(1, 32, len(o)).astype(np.uint32)
    answers = {}
    for cull, mask in (("none", None), ("front", ray_masks)):
        answers[cull] = _four(scene, o, d, cull=cull, mask=mask, strategy=strategy, threads=threads)
    return answers


def test_hits_across_instances_are_merged_and_truncated():
    """Three instances along x: a ray through them crosses each twice; max_hits keeps the
    nearest across instances and says so."""
    v, f = sample_scenes.sphere(30)[0]
    matrices = [affine(offset=(3.0 * k, 0.0, 0.0)) for k in range(3)]
    scene = dacrt.Scene([(v, f)] * 3, transforms=matrices)
    o = np.array([[-5.0, 0.01, 0.02], [-5.0, 9.0, 0.0]], np.float32)
    d = np.array([[1.0, 0, 0], [1.0, 0, 0]], np.float32)
    every = scene.hits(o, d, max_hits=BIG)
    np.testing.assert_array_equal(every.mesh, [0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(every.truncated, [False, False])
    assert np.all(np.diff(every.t) > 0)
    three = scene.hits(o, d, max_hits=3)
    np.testing.assert_array_equal(three.offsets, [0, 3, 3])
    np.testing.assert_array_equal(three.mesh, [0, 0, 1])
    np.testing.assert_array_equal(three.t, every.t[:3])
    np.testing.assert_array_equal(three.truncated, [True, False])
    np.testing.assert_array_equal(scene.count(o, d).count, [6, 0])
    stats = scene.closest(o, d, stats=True).stats
    assert stats["rays"] == 2 and stats["triangles"] == 3 * len(f)
    assert stats["ray_triangle_tests"] > 0


@pytest.mark.parametrize(
    "kind",
    ["rotation", "reflection", "nonuniform_scale", "far", "modelled far", "modelled far 1e6"],
)
def test_each_instance_is_watertight(kind):
    """Rays from inside a closed sphere placed by a matrix, through its vertices, edge
    midpoints and random directions: every one hits, and each counts an odd number of
    crossings. "modelled far": the sphere given 1e5 (or 1e6) units from its own origin and
    placed back by a rotation."""
    v, f = pg.icosphere(3)
    v = pg.perturb_radially(v, np.random.default_rng(31), 0.1)
    centre = np.zeros(3)
    if kind.startswith("modelled far"):
        centre = (1e6 if kind.endswith("1e6") else 1e5) * np.array([1.0, -0.6, 0.3])
        v = (v + centre).astype(np.float32)
        linear = MATRICES["rotation"][:3, :3]
        m = affine(linear, (0.5, 0.0, 0.0) - linear @ centre)
    else:
        m = MATRICES[kind]
    scene = dacrt.Scene([(v, f)], transforms=[m])
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    v64 = v.astype(np.float64)
    targets = np.concatenate([v64, v64[edges].mean(axis=1)])
    inside = centre + np.random.default_rng(32).uniform(-0.2, 0.2, (len(targets), 3))
    directions = np.concatenate(
        [targets - inside, pg.unit_vectors(2000, np.random.default_rng(33))]
    )
    starts = np.concatenate([inside, np.broadcast_to(centre, (2000, 3))])
    # The rays in scene space: the mesh-space rays placed by the matrix.
    o = (starts @ m[:3, :3].T + m[:3, 3]).astype(np.float32)
    d = (directions @ m[:3, :3].T).astype(np.float32)
    hits = scene.closest(o, d)
    missed = np.flatnonzero(hits.prim < 0)
    assert not len(missed), f"{len(missed)} rays slipped through, first {missed[0]}"
    assert np.all(scene.count(o, d).count % 2 == 1)
    assert scene.occluded(o, d).occluded.all()


@functools.cache
def _far_world():
    """``_world()``'s meshes given 1e5 units from their own origin along (1, -0.6, 0.3) and
    placed back where ``_world()`` places them, but meshes 0 and 1, which stay as given (far), and
    a sixth: mesh 1's arrays again, placed back."""
    meshes, transforms, masks = _world()
    shift = 1e5 * np.array([1.0, -0.6, 0.3])
    back = affine(offset=-shift)
    moved = {}  # one far array per array of ``_world()``: its two spheres stay one
    far = [(moved.setdefault(id(v), (v + shift).astype(np.float32)), f) for v, f in meshes]
    far.append(far[1])
    placed = [None, None] + [(np.eye(4) if m is None else m) @ back for m in transforms[2:]]
    placed.append(affine(pg.rotation([1.0, 1.0, 0.0], 0.5), (0.0, -2.5, 0.0)) @ back)
    return far, placed, np.append(masks, np.uint32(32))


FAR_CHANGES = {
    "move an instance": dict(transforms={3: affine(offset=(2.0 - 1e5, 1.0 + 6e4, 0.5 - 3e4))}),
    "deform an instance": dict(vertices={4: "moved"}),
    "place a base mesh": dict(transforms={0: affine(offset=(-1e5, 6e4, -3e4))}),
    "put an instance as given": dict(transforms={2: None}),
    "put the far mesh's instance as given": dict(transforms={5: None}),
}


@pytest.mark.parametrize("case", sorted(FAR_CHANGES))
def test_with_changes_of_meshes_modelled_far_answers_as_a_new_scene(case):
    """Meshes far from their own origin, as given and placed back (the same arrays both ways
    too), changed by ``with_changes``: the answers are a new Scene's, bit for bit."""
    meshes, transforms, masks = _far_world()
    o, d = _rays(meshes[2:], transforms[2:])
    ray_masks = np.random.default_rng(26).integers(1, 64, len(o)).astype(np.uint32)
    old = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    change = FAR_CHANGES[case]
    if "vertices" in change:
        change = dict(vertices={i: meshes[i][0] + np.float32(0.25) for i in change["vertices"]})
    new = old.with_changes(**change)
    # One packing of the spheres' arrays, relative to their box's centre, kept by the move.
    assert old._parts[3] is old._parts[4] and old._parts[3].centre.any()
    if case == "move an instance":
        assert new._parts[3] is old._parts[3] and new._parts[4] is old._parts[4]
    new_meshes = [(change.get("vertices", {}).get(i, v), f) for i, (v, f) in enumerate(meshes)]
    new_transforms = list(transforms)
    for i, m in change.get("transforms", {}).items():
        new_transforms[i] = m
    fresh = dacrt.Scene(new_meshes, masks=masks, transforms=new_transforms)
    got = _all_queries(new, o, d, ray_masks)
    assert (got["closest, cull=none, mask=None"].mesh >= 0).sum() > 150
    assert_same_answers(got, _all_queries(fresh, o, d, ray_masks), case)
    np.testing.assert_array_equal(new.bounds, fresh.bounds)
    np.testing.assert_array_equal(new.nearest(o[:200]).point, fresh.nearest(o[:200]).point)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
def test_instances_of_meshes_modelled_far_answer_alike_for_every_strategy(strategy, threads):
    meshes, transforms, masks = _far_world()
    scene = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    o, d = _rays(meshes[2:], transforms[2:], n=33_000, seed=28)
    expected = _far_strategy_answers()
    got = _four(scene, o, d, strategy=strategy, threads=threads)
    assert_same_answers(got, expected, f"{strategy}, {threads} threads")


@functools.cache
def _far_strategy_answers():
    meshes, transforms, masks = _far_world()
    scene = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    o, d = _rays(meshes[2:], transforms[2:], n=33_000, seed=28)
    return _four(scene, o, d, strategy="sampling", threads=1)


def _random_change(rng, meshes, state):
    """One random ``with_changes`` argument set over the chain's ``state`` (transforms, ends,
    vertices, vertices_end, masks: each mesh's current value), 1 to 3 meshes changed."""
    n = len(meshes)
    change = {}
    for i in rng.choice(n, size=rng.integers(1, 4), replace=False):
        i = int(i)
        # A deforming mesh takes no placement, and a placed one no end vertices.
        deforming = state["vertices_end"][i] is not None
        placed = state["transforms"][i] is not None or state["ends"][i] is not None
        kinds = ["vertices", "mask"] + ([] if deforming else ["transform", "end"])
        kind = rng.choice(kinds + ([] if placed else ["vertices_end"] * 2))
        if kind == "transform":
            names = sorted(MATRICES)
            name = names[rng.integers(len(names))]
            matrix = None if rng.random() < 0.3 else MATRICES[name]  # None: back as given
            change.setdefault("transforms", {})[i] = matrix
        elif kind == "end":
            offset = rng.normal(0, 0.3, 3)
            start = state["transforms"][i]
            end = None if rng.random() < 0.3 else (start if start is not None else np.eye(4)).copy()
            if end is not None:
                end[:3, 3] += offset
            change.setdefault("transforms_end", {})[i] = end
        elif kind == "vertices_end":
            base = state["vertices"][i]
            end = None if rng.random() < 0.3 else base + rng.normal(0, 0.05, base.shape)
            change.setdefault("vertices_end", {})[i] = (
                None if end is None else end.astype(np.float32)
            )
        elif kind == "vertices":
            v, f = meshes[i]
            new = v * np.float32(rng.uniform(0.8, 1.2))
            if rng.random() < 0.4:  # some triangles degenerate, others back
                new = _collapsed(new, f, rng.choice(len(f), size=len(f) // 6, replace=False))
            change.setdefault("vertices", {})[i] = new.astype(np.float32)
        else:
            change.setdefault("masks", {})[i] = int(rng.integers(0, 32))
    return change


@pytest.mark.parametrize("seed", range(6))
def test_a_chain_of_random_changes_answers_as_new_scenes(seed):
    # Every version of a seeded chain of changes (moves, ends, deformations, masks, triangles
    # becoming degenerate and back, shared packings) against a new Scene of the same meshes.
    meshes, transforms, masks = _world()
    rng = np.random.default_rng(40 + seed)
    state = {
        "transforms": list(transforms),
        "ends": [None] * len(meshes),
        "vertices": [v for v, _ in meshes],
        "vertices_end": [None] * len(meshes),
        "masks": masks.copy(),
    }
    o, d = _rays(meshes, transforms, n=400, seed=50 + seed)
    ray_masks = rng.integers(1, 32, len(o)).astype(np.uint32)
    times = rng.random(len(o)).astype(np.float32)
    scene = dacrt.Scene(meshes, masks=masks, transforms=transforms)
    for step in range(10):
        change = _random_change(rng, meshes, state)
        scene = scene.with_changes(**change)
        for key, values in change.items():
            target = {"transforms_end": "ends", "masks": "masks"}.get(key, key)
            for i, value in values.items():
                state[target][i] = value
        fresh = dacrt.Scene(
            [(v, f) for v, (_, f) in zip(state["vertices"], meshes)],
            masks=state["masks"],
            transforms=state["transforms"],
            transforms_end=state["ends"],
            vertices_end=state["vertices_end"],
        )
        what = f"seed {seed}, step {step}: {sorted((k, sorted(v)) for k, v in change.items())}"
        for time in (None, times):
            got = _queries(scene, o, d, mask=ray_masks, time=time)
            assert_same_answers(got, _queries(fresh, o, d, mask=ray_masks, time=time), what)


def _placed_box(vertices, faces, matrix):
    """(2, 3) float32: the box of the corners ``faces`` refer to, placed by ``matrix`` in
    float64 then rounded, as plain NumPy."""
    used = vertices[np.unique(faces)].astype(np.float64)
    placed = (used @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)
    return np.array([placed.min(axis=0), placed.max(axis=0)])


def test_writes_to_the_callers_arrays_after_a_scene_is_built_change_none_of_its_answers():
    """A Scene keeps arrays of its own, also of those given in the kernels' layout (float32
    vertices, int32 faces, C-contiguous and writable): a caller that reuses its buffers changes
    neither ``bounds`` (derived on first use) nor what ``with_changes`` packs again from the
    faces as given."""
    v, f = pg.triangle_soup(200, np.random.default_rng(33))
    matrix = affine(pg.rotation([0.0, 0.0, 1.0], 0.3), (5.0, 0.0, 0.0))
    given_v, given_f = v.copy(), f.copy()
    # a placed mesh (its bounds read its vertices) and the same arrays as given (the base level)
    scene = dacrt.Scene([(given_v, given_f), (given_v, given_f)], transforms=[matrix, None])
    o, d = _rays([(v, f), (v, f)], [matrix, None], n=600, seed=34)
    before = scene.closest(o, d)
    given_v += np.float32(100.0)
    given_f[:] = given_f[::-1]
    expected = _placed_box(v, f, matrix)
    expected = np.array([np.minimum(expected[0], v.min(axis=0)), np.maximum(expected[1], v.max(0))])
    np.testing.assert_array_equal(scene.bounds, expected)
    fresh = dacrt.Scene([(v, f), (v, f)], transforms=[matrix, None])
    np.testing.assert_array_equal(scene.bounds, fresh.bounds)
    # the same vertex values again, for each mesh: the faces are still those given
    new = scene.with_changes(vertices={0: v.copy(), 1: v.copy()})
    masks = np.ones(len(o), np.uint32)
    assert_same_answers(_all_queries(new, o, d, masks), _all_queries(fresh, o, d, masks), "new")
    for name in ("t", "mesh", "prim", "u", "v", "normal"):
        np.testing.assert_array_equal(getattr(new.closest(o, d), name), getattr(before, name))
