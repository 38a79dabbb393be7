"""Face culling (``cull=``) and masks (``Scene(masks=)``, ``mask=``) of ``dacrt.Scene`` queries.

Against the numpy reference with the culled faces or the unseen meshes dropped, against the
engine's own unfiltered answers on scenes that leave those faces out (bit for bit: a ray's answer
depends on no other ray and no other triangle), and every strategy and thread count against the
default, bit for bit.
"""

from __future__ import annotations

import assertions as check
import numpy as np
import procedural as pg
import pytest
import sample_scenes

import dacrt

CULLS = ("back", "front")
# Mesh masks of the multi-mesh scenes, and the ray masks drawn for them: each sees a different
# subset (0b0001: mesh 0 and the mesh of mask 0b0011; 0b1000: none but the all-ones mesh).
MESH_MASKS = np.array([0b0001, 0b0010, 0b0110, 0xFFFFFFFF], np.uint32)
RAY_MASKS = np.array([0b0001, 0b0010, 0b0100, 0b1000, 0b0011, 0xFFFFFFFF], np.uint32)


def ray_masks(n, seed):
    return np.random.default_rng(seed).choice(RAY_MASKS, n)


def face_masks(masks, meshes):
    """Each face's mesh mask, for the reference (global face numbering)."""
    return np.repeat(masks, [len(f) for _, f in meshes]).astype(np.uint32)


def normals(vertices, faces):
    """(F, 3) float64 geometric normals (p1 - p0) x (p2 - p0)."""
    p = np.asarray(vertices, np.float64)[np.asarray(faces)]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def collapse(vertices, faces, drop):
    """The mesh with the faces ``drop`` (F,) bool made degenerate (all corners on one vertex):
    they never hit, and every other face keeps its row."""
    faces = np.array(faces)
    faces[drop] = faces[drop][:, :1]
    return vertices, faces


# ---------------------------------------------------------------------------------------------
# Culling
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cull", CULLS)
@pytest.mark.parametrize("scene_name", sorted(sample_scenes.SCENES))
def test_cull_matches_reference(scene_name, cull):
    meshes = sample_scenes.SCENES[scene_name](5)
    scene = dacrt.Scene(meshes)
    vertices, faces, offsets = pg.concat(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, 5)
    hits = scene.closest(origins, directions, cull=cull)
    check.check_layout(hits, len(origins))
    check.check_against_reference(
        hits, vertices, faces, origins, directions, mesh_offsets=offsets, min_hits=50, cull=cull
    )
    occ = scene.occluded(origins, directions, cull=cull).occluded
    check.check_occluded_against_reference(occ, vertices, faces, origins, directions, cull=cull)
    np.testing.assert_array_equal(occ, np.isfinite(hits.t))
    # A culled hit's normal faces the ray (front faces kept) or points along it.
    dots = np.einsum("ij,ij->i", hits.normal, directions)[hits.prim >= 0]
    assert (dots < 0).all() if cull == "back" else (dots > 0).all()


@pytest.mark.parametrize("cull", CULLS)
@pytest.mark.parametrize(
    "target, direction",
    [("vertices", "exact_oblique"), ("midpoints", "normal"), ("midpoints", "exact_oblique")],
)
def test_cull_through_edges_and_vertices_equals_dropping_the_faces(target, direction, cull):
    """Parallel rays exactly through a grid's vertices and edges, from above and from below:
    culling equals a scene whose culled faces are degenerate, bit for bit, and rays through the
    kept side still hit (watertight)."""
    v, f = pg.grid(16, 1.0, alternate=True)
    origins, directions, _ = pg.grid_rays(v, f, 16, target, direction)
    for sign in (1, -1):
        d = directions * np.float32(sign)
        o = (origins - np.float32(2 * sign) * directions) if sign < 0 else origins
        n = normals(v, f)
        # One direction per batch for "normal"; oblique batches cycle, so take one at a time.
        for dir_row in np.unique(d, axis=0):
            rows = (d == dir_row).all(axis=1)
            along = n @ dir_row.astype(np.float64) > 0
            drop = along if cull == "back" else ~along
            got = dacrt.Scene([(v, f)]).closest(o[rows], d[rows], cull=cull)
            want = dacrt.Scene([collapse(v, f, drop)]).closest(o[rows], d[rows])
            check.assert_bitwise_equal(got, want, f"cull={cull} vs dropped faces")
            # The grid's normal is +z: rays from above see its front.
            if (sign > 0) == (cull == "back"):
                assert (got.prim >= 0).all(), "a ray through an edge or vertex missed"
            else:
                assert (got.prim < 0).all(), "a culled face was hit"


@pytest.mark.parametrize("cull", CULLS)
def test_cull_on_a_closed_sphere_keeps_one_side(cull):
    """From outside, every ray through a closed mesh hits it with either culling: the near side
    with back faces culled, the far side with front faces culled; rays just inside its vertices
    included."""
    v, f = pg.icosphere(3)
    targets = np.concatenate([v[:300] * 0.999, v[:300] * 0.5])
    d = pg.unit_vectors(len(targets), np.random.default_rng(8))
    origins, directions = pg.rays_at(targets, d, 4.0)
    scene = dacrt.Scene([(v, f)])
    plain = scene.closest(origins, directions)
    culled = scene.closest(origins, directions, cull=cull)
    assert (plain.prim >= 0).all() and (culled.prim >= 0).all(), "a ray through the sphere missed"
    if cull == "back":
        check.assert_bitwise_equal(culled, plain, "back culling from outside a closed mesh")
    else:
        assert (culled.t > plain.t).all()


# ---------------------------------------------------------------------------------------------
# Masks
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", (0, 1))
def test_masks_match_reference(seed):
    meshes = sample_scenes.multi(seed)
    scene = dacrt.Scene(meshes, masks=MESH_MASKS)
    vertices, faces, offsets = pg.concat(meshes)
    origins, directions = sample_scenes.mixed_rays(meshes, seed)
    masks = ray_masks(len(origins), seed)
    filters = {"ray_masks": masks, "face_masks": face_masks(MESH_MASKS, meshes)}
    hits = scene.closest(origins, directions, mask=masks)
    check.check_against_reference(
        hits, vertices, faces, origins, directions, mesh_offsets=offsets, min_hits=100, **filters
    )
    occ = scene.occluded(origins, directions, mask=masks).occluded
    check.check_occluded_against_reference(occ, vertices, faces, origins, directions, **filters)
    np.testing.assert_array_equal(occ, np.isfinite(hits.t))
    seen = (masks[:, None] & MESH_MASKS[None, :]) != 0
    hit = hits.mesh >= 0
    assert seen[hit, hits.mesh[hit]].all(), "a ray hit a mesh its mask does not see"


@pytest.mark.parametrize("uniform", [True, False], ids=["one_mask", "mixed_masks"])
@pytest.mark.parametrize("query", ["closest", "occluded"])
def test_masks_equal_the_scene_of_the_seen_meshes(query, uniform):
    """Each ray's answer equals its answer in a scene whose unseen meshes are empty, bit for bit;
    a batch of one mask and a batch of mixed masks (two ways through the engine) alike."""
    meshes = sample_scenes.multi(3)
    scene = dacrt.Scene(meshes, masks=MESH_MASKS)
    origins, directions = sample_scenes.mixed_rays(meshes, 3, n=3000)
    masks = ray_masks(len(origins), 3)
    for m in RAY_MASKS:
        rows = masks == m
        got = getattr(scene, query)(origins, directions, mask=m if uniform else masks)
        seen_only = dacrt.Scene(
            [(v, f if MESH_MASKS[k] & m else f[:0]) for k, (v, f) in enumerate(meshes)]
        )
        want = getattr(seen_only, query)(origins[rows], directions[rows])
        if query == "closest":
            got = dacrt.Hits(
                *(getattr(got, k)[rows] for k in ("t", "mesh", "prim", "u", "v", "normal"))
            )
            check.assert_bitwise_equal(got, want, f"mask {m:#x}")
        else:
            np.testing.assert_array_equal(got.occluded[rows], want.occluded, f"mask {m:#x}")


def test_a_mesh_of_mask_zero_is_never_seen():
    meshes = sample_scenes.multi(4)
    origins, directions = sample_scenes.mixed_rays(meshes, 4)
    scene = dacrt.Scene(meshes, masks=[0, 1, 1, 1])
    hits = scene.closest(origins, directions)
    assert (hits.mesh != 0).all() and (hits.mesh >= 0).any()
    assert not dacrt.Scene(meshes, masks=0).occluded(origins, directions).occluded.any()
    assert not scene.occluded(origins, directions, mask=0).occluded.any()


# ---------------------------------------------------------------------------------------------
# Every strategy and thread count, bit for bit
# ---------------------------------------------------------------------------------------------


def _cases():
    multi = sample_scenes.multi(42)
    grid_v, grid_f = pg.grid(16, 1.0, alternate=True)
    o1, d1, _ = pg.grid_rays(grid_v, grid_f, 16, "vertices", "exact_oblique")
    o2, d2, _ = pg.grid_rays(grid_v, grid_f, 16, "midpoints", "normal")
    grid_o = np.concatenate([o1, o2, o1 + d1])  # the last from below, going up
    grid_d = np.concatenate([d1, d2, -d1])
    ((sv, sf),) = sample_scenes.sphere(40)
    so, sd = pg.rays_from_inside((0, 0, 0), 0.9 * pg.inner_radius(sv, sf), 3000, rng(40))
    teapot = sample_scenes.load_shared("teapot")
    to, td = pg.camera_rays(pg.bounds(*teapot), 64, 48)
    return {
        "multi": (multi, *sample_scenes.mixed_rays(multi, 42, n=3000)),
        "grid_edges_vertices": ([(grid_v, grid_f)], grid_o, grid_d),
        "inside_sphere": ([(sv, sf)], so, sd),
        "many_rays": (multi, *sample_scenes.mixed_rays(multi, 43, n=40000)),
        "teapot_camera": ([teapot], to, td),
    }


def rng(seed):
    return np.random.default_rng(seed)


@pytest.fixture(scope="module")
def cases():
    return _cases()


VARIANTS = {
    "cull_back": {"cull": "back"},
    "cull_front": {"cull": "front"},
    "masks": {"masks": True},
    "masks_cull_back": {"masks": True, "cull": "back"},
}


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize(
    "case", ["multi", "grid_edges_vertices", "inside_sphere", "many_rays", "teapot_camera"]
)
def test_every_strategy_and_thread_count_agree(cases, case, variant, strategy, threads):
    meshes, o, d = cases[case]
    options = dict(VARIANTS[variant])
    mesh_masks = None
    if options.pop("masks", False):
        mesh_masks = MESH_MASKS[np.arange(len(meshes)) % len(MESH_MASKS)]
        options["mask"] = ray_masks(len(o), 9)
    scene = dacrt.Scene(meshes, masks=mesh_masks)
    default = scene.closest(o, d, **options)
    assert (default.prim >= 0).any(), "vacuous: no hits"
    hits = scene.closest(o, d, strategy=strategy, threads=threads, **options)
    check.assert_bitwise_equal(hits, default, f"{variant}: {strategy}, threads={threads}")
    occ = scene.occluded(o, d, strategy=strategy, threads=threads, **options).occluded
    np.testing.assert_array_equal(occ, np.isfinite(default.t), f"{variant}: occluded")


# ---------------------------------------------------------------------------------------------
# Input checks
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "masks, message",
    [
        ([1, 2], "masks must be a scalar or have shape (4,), one per mesh, got (2,)"),
        (np.ones(4, np.float32), "masks must be an integer (uint32) array, got dtype float32"),
        ([1, 2, -1, 3], "masks[2] is outside the uint32 range"),
        ([1, 2, 3, 2**32], "masks[3] is outside the uint32 range"),
    ],
)
def test_bad_mesh_masks_are_named(masks, message):
    with pytest.raises(ValueError) as info:
        dacrt.Scene(sample_scenes.multi(0), masks=masks)
    assert message in str(info.value)


@pytest.mark.parametrize("query", ["closest", "occluded"])
@pytest.mark.parametrize(
    "options, message",
    [
        ({"mask": np.ones(3, np.uint32)}, "mask must be a scalar or have shape (2,), one per ray"),
        ({"mask": np.ones(2, np.float64)}, "mask must be an integer (uint32) array"),
        ({"mask": [1, -2]}, "mask[1] is outside the uint32 range"),
        ({"cull": "sideways"}, "unknown cull 'sideways'; use one of none, back, front"),
    ],
)
def test_bad_ray_masks_and_cull_are_named(query, options, message):
    scene = dacrt.Scene(sample_scenes.multi(0))
    o = np.zeros((2, 3), np.float32)
    d = np.ones((2, 3), np.float32)
    with pytest.raises(ValueError) as info:
        getattr(scene, query)(o, d, **options)
    assert message in str(info.value)
