"""``closest`` and ``occluded`` on the GPU: check the query as the CPU engine does, trace the
scene's base level breadth-first (``traversal``), finish the answers with the CPU's code."""

import numpy as np
from numba import cuda

from ..contracts import FLOAT, INDEX, Hits, Occlusion
from ..leaf import NO_HIT
from ..query import CULL_BACK, CULL_FLAGS, CULL_FRONT
from ..results import finish_closest
from ..validation import InputError, check_cull, check_masks, check_rays, explain_bad_rays
from . import kernels
from .traversal import MAX_PAIRS, launch, traverse


def check_supported(scene, time):
    """InputError naming an option this backend does not have yet."""
    if scene._instances:
        raise InputError(
            "device='cuda' does not support placed meshes yet (transforms, transforms_end)"
        )
    if time is not None:
        raise InputError("device='cuda' does not support time= yet")


def prepare(scene, origins, directions, tmin, tmax, cull, mask):
    """The checked query's device arrays, culling side and masks."""
    origins, directions, tmin, tmax = check_rays(origins, directions, tmin, tmax)
    bad = (
        ~np.isfinite(origins).all(axis=1)
        | ~np.isfinite(directions).all(axis=1)
        | ~directions.any(axis=1)
        | ~np.isfinite(tmin)
        | np.isnan(tmax)
        | (tmin > tmax)
    )
    if bad.any():
        explain_bad_rays(origins, directions, tmin, tmax)
    flags = CULL_FLAGS[check_cull(cull)]
    # det * cull_side > 0 culls, as ``geometry.culled_side``.
    cull_side = -1.0 if flags & CULL_BACK else (1.0 if flags & CULL_FRONT else 0.0)
    n = len(origins)
    if mask is None:
        ray_masks = np.zeros(0, np.uint32)
        tri_masks = np.zeros(0, np.uint32)
    else:
        ray_masks = check_masks(mask, n, "mask", "ray")
        tri_masks = scene._row_masks
    with np.errstate(divide="ignore"):
        inv_dirs = (np.float32(1.0) / directions).astype(FLOAT)
    device = tuple(
        cuda.to_device(np.ascontiguousarray(a))
        for a in (origins, directions, inv_dirs, tmin, tmax, ray_masks, tri_masks)
    )
    return origins, directions, tmin, tmax, cull_side, device


def scene_arrays(scene):
    """The base level's rows on the device: corners (F, 9), tie keys (global ids), centroids,
    per-row boxes; and the root box, on the host."""
    verts = np.ascontiguousarray(scene._base.verts)
    corners = verts.reshape(-1, 3, 3)
    tri_box = np.concatenate([corners.min(axis=1), corners.max(axis=1)], axis=1).astype(FLOAT)
    centroids = (corners.sum(axis=1) / np.float32(3)).astype(FLOAT)
    box = np.concatenate([tri_box[:, :3].min(axis=0), tri_box[:, 3:].max(axis=0)])
    return (
        cuda.to_device(verts),
        cuda.to_device(np.ascontiguousarray(scene._base.ids, np.int32)),
        cuda.to_device(centroids),
        cuda.to_device(tri_box),
        box.astype(FLOAT),
    )


def closest(scene, origins, directions, tmin=None, tmax=None, *, cull="none", mask=None,
            time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.closest`` on the GPU: the same ``Hits``, bit for bit (no ``stats``)."""
    check_supported(scene, time)
    origins, directions, tmin, tmax, cull_side, device = prepare(
        scene, origins, directions, tmin, tmax, cull, mask
    )
    n = len(origins)
    t = tmax.copy()
    best_tri = np.full(n, NO_HIT, np.int32)
    u = np.zeros(n, FLOAT)
    v = np.zeros(n, FLOAT)
    if n and len(scene._base.ids):
        o, d, inv_d, lo, hi, ray_masks, tri_masks = device
        verts, keys, centroids, tri_box, box = scene_arrays(scene)
        best_key = cuda.to_device(np.full(n, kernels.NO_KEY, np.uint64))

        def run_leaves(frontier, kind):
            launch(
                kernels.leaf_closest, frontier.ray_ids.shape[0], frontier.ray_ids,
                frontier.ray_node, kind, cuda.to_device(frontier.tri_lo),
                cuda.to_device(frontier.tri_n), frontier.rows, o, d, lo, hi, verts, keys,
                ray_masks, tri_masks, cull_side, best_key,
            )  # fmt: skip

        traverse((centroids, tri_box, box), (o, inv_d, lo, hi), run_leaves, max_pairs)
        row_of_key = np.full(scene.n_triangles, -1, np.int32)
        row_of_key[scene._base.ids] = np.arange(len(scene._base.ids), dtype=np.int32)
        out = [cuda.to_device(a) for a in (t, best_tri, u, v)]
        launch(
            kernels.finish_best, n, best_key, cuda.to_device(row_of_key), o, d, verts,
            NO_HIT, *out,
        )  # fmt: skip
        t, best_tri, u, v = (a.copy_to_host() for a in out)
    mesh = np.empty(n, INDEX)
    prim = np.empty(n, INDEX)
    normal = np.empty((n, 3), FLOAT)
    base = scene._base
    finish_closest(
        t, best_tri, base.ids, scene.mesh_offsets, base.verts, scene._no_normals, mesh, prim,
        normal,
    )  # fmt: skip
    return Hits(t, mesh, prim, u, v, normal)


def occluded(scene, origins, directions, tmin=None, tmax=None, *, cull="none", mask=None,
             time=None, max_pairs=MAX_PAIRS):  # fmt: skip
    """``Scene.occluded`` on the GPU: the same ``Occlusion`` (no ``stats``)."""
    check_supported(scene, time)
    origins, directions, tmin, tmax, cull_side, device = prepare(
        scene, origins, directions, tmin, tmax, cull, mask
    )
    n = len(origins)
    if not (n and len(scene._base.ids)):
        return Occlusion(np.zeros(n, bool))
    o, d, inv_d, lo, hi, ray_masks, tri_masks = device
    verts, _, centroids, tri_box, box = scene_arrays(scene)
    hit = cuda.to_device(np.zeros(n, np.uint8))

    def run_leaves(frontier, kind):
        launch(
            kernels.leaf_any, frontier.ray_ids.shape[0], frontier.ray_ids, frontier.ray_node,
            kind, cuda.to_device(frontier.tri_lo), cuda.to_device(frontier.tri_n),
            frontier.rows, o, d, lo, hi, verts, ray_masks, tri_masks, cull_side, hit,
        )  # fmt: skip

    traverse((centroids, tri_box, box), (o, inv_d, lo, hi), run_leaves, max_pairs)
    return Occlusion(hit.copy_to_host().astype(bool))
