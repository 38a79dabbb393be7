"""dacrt.results: the kernels' per-ray results (kernel rows, t) become answers: (mesh, prim)
through the rows' global indices and the meshes' offsets, unit normals of the triangles, inf and
-1 on a miss, +0.0 for a hit at the origin, and each hit's u, v on its triangle."""

from __future__ import annotations

import numpy as np
import pytest

from dacrt import MISS, results
from dacrt.leaf import NO_HIT

#: Two meshes: mesh 0 holds global triangles 0-1, mesh 1 holds 2-4. Kernel row r is global
#: triangle TRI_GLOBAL[r] (rows rise with global indices; triangle 3 is degenerate: no row).
MESH_OFFSETS = np.array([0, 2, 5], np.int64)
TRI_GLOBAL = np.array([0, 1, 2, 4], np.int32)
TRI_VERTS = np.array(
    [
        [0, 0, 0, 1, 0, 0, 0, 1, 0],  # z = 0, normal +z
        [0, 0, 1, 0, 2, 1, 3, 0, 1],  # z = 1, normal -z
        [0, 0, 2, 0, 1, 2, 0, 0, 3],  # x = 0, normal +x
        [5, 5, 5, 6, 5, 5, 5, 5, 7],  # y = 5, normal -y
    ],
    np.float32,
)
#: (mesh, prim) of each kernel row.
ROW_ANSWERS = [(0, 0), (0, 1), (1, 0), (1, 2)]


def normals_of(tri_verts: np.ndarray) -> np.ndarray:
    p0, p1, p2 = tri_verts[:, 0:3], tri_verts[:, 3:6], tri_verts[:, 6:9]
    n = np.cross(p1.astype(float) - p0, p2.astype(float) - p0)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def test_unit_normals_are_the_triangles_normalised_cross_products():
    normals = np.empty((len(TRI_VERTS), 3), np.float32)
    results.unit_normals(TRI_VERTS, normals)
    np.testing.assert_allclose(normals, normals_of(TRI_VERTS), rtol=0, atol=1e-7)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1, rtol=0, atol=1e-6)


def finish_closest(best_t, best_tri, table: bool):
    n = len(best_t)
    mesh, prim = np.empty(n, np.int32), np.empty(n, np.int32)
    normal = np.empty((n, 3), np.float32)
    normals = np.empty((len(TRI_VERTS), 3), np.float32)
    if table:
        results.unit_normals(TRI_VERTS, normals)
    else:
        normals = np.empty((0, 3), np.float32)  # each hit derives its own
    t = best_t.copy()
    results.finish_closest(
        t, best_tri, TRI_GLOBAL, MESH_OFFSETS, TRI_VERTS, normals, mesh, prim, normal
    )
    return t, mesh, prim, normal


@pytest.mark.parametrize("table", [True, False])
def test_closest_answers_name_mesh_and_prim_and_mark_misses(table):
    best_tri = np.array([3, NO_HIT, 0, 2, 1, NO_HIT, 3], np.int32)
    best_t = np.array([2.5, 7.0, -0.0, 1.0, 4.0, np.inf, 0.5], np.float32)
    t, mesh, prim, normal = finish_closest(best_t, best_tri, table)
    hit = best_tri != NO_HIT
    assert np.all(np.isposinf(t[~hit])) and np.all(mesh[~hit] == MISS)
    assert np.all(prim[~hit] == MISS) and np.all(normal[~hit] == 0)
    expected = [ROW_ANSWERS[row] for row in best_tri[hit]]
    assert list(zip(mesh[hit].tolist(), prim[hit].tolist())) == expected
    assert np.array_equal(t[hit], best_t[hit]) and not np.signbit(t[2])  # -0.0 becomes +0.0
    np.testing.assert_allclose(normal[hit], normals_of(TRI_VERTS)[best_tri[hit]], atol=1e-7)


def test_both_ways_of_finding_normals_give_the_same_bits():
    best_tri = np.array([0, 1, 2, 3, NO_HIT], np.int32)
    best_t = np.ones(5, np.float32)
    assert np.array_equal(
        finish_closest(best_t, best_tri, True)[3], finish_closest(best_t, best_tri, False)[3]
    )


def test_every_hit_is_copied_into_its_rays_rows_with_u_v_on_its_triangle():
    # Ray 0 crosses rows 0 (z = 0) and 1 (z = 1) going up; ray 1 hits nothing; ray 2 crosses row
    # 0 only but its list is cut to nothing (offsets say 0 rows); ray 3 crosses row 1.
    origins = np.array([[0.2, 0.3, -1], [9, 9, 9], [0.2, 0.2, -1], [1.0, 0.5, 3]], np.float32)
    directions = np.array([[0, 0, 1], [1, 0, 0], [0, 0, 1], [0, 0, -1]], np.float32)
    list_t = np.array([[1, 2], [np.inf, np.inf], [1, np.inf], [2, np.inf]], np.float32)
    list_tri = np.array([[0, 1], [NO_HIT, NO_HIT], [0, NO_HIT], [1, NO_HIT]], np.int32)
    offsets = np.array([0, 2, 2, 2, 3], np.int64)
    m = int(offsets[-1])
    t, u, v = (np.empty(m, np.float32) for _ in range(3))
    mesh, prim = np.empty(m, np.int32), np.empty(m, np.int32)
    normal = np.empty((m, 3), np.float32)
    results.finish_hits(
        list_t,
        list_tri,
        offsets,
        origins,
        directions,
        TRI_GLOBAL,
        MESH_OFFSETS,
        TRI_VERTS,
        np.empty((0, 3), np.float32),
        t,
        mesh,
        prim,
        u,
        v,
        normal,
    )
    assert t.tolist() == [1, 2, 2]
    assert list(zip(mesh.tolist(), prim.tolist())) == [(0, 0), (0, 1), (0, 1)]
    rows = [0, 1, 1]
    rays = [0, 0, 3]
    for k, (row, ray) in enumerate(zip(rows, rays)):
        p0, p1, p2 = TRI_VERTS[row].reshape(3, 3).astype(float)
        on_triangle = (1 - u[k] - v[k]) * p0 + u[k] * p1 + v[k] * p2
        along_ray = origins[ray] + t[k] * directions[ray].astype(float)
        np.testing.assert_allclose(on_triangle, along_ray, rtol=0, atol=1e-6)
        assert 0 <= u[k] <= 1 and 0 <= v[k] <= 1 and u[k] + v[k] <= 1
    np.testing.assert_allclose(normal, normals_of(TRI_VERTS)[rows], atol=1e-7)
