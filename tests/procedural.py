"""Small procedural scenes and ray sets for the engine tests.

Meshes are ``(vertices, faces)`` pairs: ``vertices : (v, 3) float32``, ``faces : (f, 3) int32``.
Ray sets are ``(origins, directions)`` pairs of (n, 3) float32 arrays. Everything random takes a
``numpy.random.Generator`` so that tests are seeded.
"""

from __future__ import annotations

import numpy as np

# ---------------------------------------------------------------------------------------------
# Meshes
# ---------------------------------------------------------------------------------------------


def grid(n=16, size=1.0, *, alternate=False):
    """A flat ``n x n`` grid of quads in the plane z = 0, each split into two triangles.

    Vertex ``(i, j)`` (row ``i`` along y, column ``j`` along x) is row ``i * (n + 1) + j`` of the
    vertices, at ``(j * size / n, i * size / n, 0)``; with ``n`` and ``size`` powers of two every
    coordinate, edge midpoint and face centre is exact in float32. Vertices are shared.

    Parameters
    ----------
    n : int
      Quads per side.
    size : float
      Side length.
    alternate : bool
      Alternate the split diagonal in a checkerboard (so vertices have 4 or 8 incident faces).

    Returns
    -------
    vertices : ((n+1)**2, 3) float32
    faces : (2*n*n, 3) int32
      Counter-clockwise seen from +z: normals point to +z.
    """
    ticks = np.arange(n + 1, dtype=np.float64) * (size / n)
    ys, xs = np.meshgrid(ticks, ticks, indexing="ij")
    vertices = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1).astype(np.float32)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()  # (i, j)
    b = a + 1  # (i, j+1)
    c = a + n + 1  # (i+1, j)
    d = c + 1  # (i+1, j+1)
    flip = ((i + j) % 2 == 1).ravel() if alternate else np.zeros(a.size, bool)
    # Diagonal a-d, or b-c where flipped; both keep counter-clockwise order seen from +z.
    t1 = np.where(flip[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    t2 = np.where(flip[:, None], np.stack([b, d, c], 1), np.stack([a, d, c], 1))
    faces = np.stack([t1, t2], axis=1).reshape(-1, 3).astype(np.int32)
    return vertices, faces


def grid_interior_vertices(n):
    """Indices (k,) int64 of the grid vertices not on its boundary, for :func:`grid` ``(n)``."""
    i, j = np.meshgrid(np.arange(1, n), np.arange(1, n), indexing="ij")
    return (i * (n + 1) + j).ravel()


def two_sided_edges(faces):
    """Unique edges shared by exactly two faces, as (e, 2) int64 vertex pairs.

    On a grid these are exactly the edges not on its boundary.
    """
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    return unique[counts == 2]


def rotation(axis, angle):
    """(3, 3) float64 rotation matrix about ``axis`` by ``angle`` radians (Rodrigues)."""
    axis = np.asarray(axis, dtype=np.float64)
    x, y, z = axis / np.linalg.norm(axis)
    c, s = np.cos(angle), np.sin(angle)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) * c + s * k + (1 - c) * np.outer([x, y, z], [x, y, z])


def transform(vertices, matrix=None, offset=(0.0, 0.0, 0.0)):
    """``vertices @ matrix.T + offset`` computed in float64, returned as (v, 3) float32."""
    v = np.asarray(vertices, dtype=np.float64)
    if matrix is not None:
        v = v @ np.asarray(matrix, dtype=np.float64).T
    return (v + np.asarray(offset, dtype=np.float64)).astype(np.float32)


def icosphere(subdivisions=3, radius=1.0):
    """A closed icosphere centred on the origin, with shared vertices.

    Returns
    -------
    vertices : (10 * 4**s + 2, 3) float32
    faces : (20 * 4**s, 3) int32
      Outward-facing (counter-clockwise seen from outside).
    """
    phi = (1.0 + 5.0**0.5) / 2.0
    verts = [
        (-1, phi, 0),
        (1, phi, 0),
        (-1, -phi, 0),
        (1, -phi, 0),
        (0, -1, phi),
        (0, 1, phi),
        (0, -1, -phi),
        (0, 1, -phi),
        (phi, 0, -1),
        (phi, 0, 1),
        (-phi, 0, -1),
        (-phi, 0, 1),
    ]
    faces = [
        (0, 11, 5),
        (0, 5, 1),
        (0, 1, 7),
        (0, 7, 10),
        (0, 10, 11),
        (1, 5, 9),
        (5, 11, 4),
        (11, 10, 2),
        (10, 7, 6),
        (7, 1, 8),
        (3, 9, 4),
        (3, 4, 2),
        (3, 2, 6),
        (3, 6, 8),
        (3, 8, 9),
        (4, 9, 5),
        (2, 4, 11),
        (6, 2, 10),
        (8, 6, 7),
        (9, 8, 1),
    ]
    verts = [np.asarray(p, dtype=np.float64) / np.linalg.norm(p) for p in verts]
    for _ in range(subdivisions):
        midpoint = {}

        def middle(a, b, midpoint=midpoint):
            key = (min(a, b), max(a, b))
            if key not in midpoint:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                midpoint[key] = len(verts) - 1
            return midpoint[key]

        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    vertices = (np.asarray(verts) * radius).astype(np.float32)
    return vertices, np.asarray(faces, dtype=np.int32)


def uv_sphere(n_lat=16, n_lon=32, radius=1.0):
    """A closed latitude-longitude sphere with single pole vertices (fans of ``n_lon`` faces).

    Returns
    -------
    vertices : ((n_lat - 1) * n_lon + 2, 3) float32
    faces : (2 * (n_lat - 1) * n_lon, 3) int32
      Outward-facing.
    """
    theta = np.pi * np.arange(1, n_lat) / n_lat  # polar angles of the rings
    phi = 2 * np.pi * np.arange(n_lon) / n_lon
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack(
        [np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1
    ).reshape(-1, 3)
    vertices = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]]) * radius
    north, south = 0, len(vertices) - 1

    def at(r, k):
        return 1 + r * n_lon + (k % n_lon)

    faces = []
    for k in range(n_lon):
        faces.append((north, at(0, k), at(0, k + 1)))
        for r in range(n_lat - 2):
            faces.append((at(r, k), at(r + 1, k), at(r + 1, k + 1)))
            faces.append((at(r, k), at(r + 1, k + 1), at(r, k + 1)))
        faces.append((at(n_lat - 2, k), south, at(n_lat - 2, k + 1)))
    return vertices.astype(np.float32), np.asarray(faces, dtype=np.int32)


def perturb_radially(vertices, rng, amplitude=0.1, center=(0.0, 0.0, 0.0)):
    """Scale each vertex's distance from ``center`` by a random factor in ``1 +- amplitude``.

    The connectivity is unchanged and the surface stays star-shaped about ``center``, so a closed
    mesh stays closed and every point near ``center`` stays inside.

    Returns
    -------
    vertices : (v, 3) float32
    """
    center = np.asarray(center, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64) - center
    factor = 1.0 + amplitude * rng.uniform(-1.0, 1.0, size=(len(v), 1))
    return (center + v * factor).astype(np.float32)


def _segment_distance(p, a, b):
    """(f,) float64 distances from the point ``p`` (3,) to the segments ``a``-``b`` (f, 3)."""
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(np.einsum("ij,ij->i", p - a, ab) / denom, 0.0, 1.0)
    s = np.where(denom > 0, s, 0.0)
    return np.linalg.norm(a + s[:, None] * ab - p, axis=1)


def inner_radius(vertices, faces, center=(0.0, 0.0, 0.0)):
    """Distance from ``center`` to the nearest point of the mesh's surface.

    For a closed mesh with ``center`` inside, every point closer to ``center`` than this is inside.

    Returns
    -------
    radius : float
    """
    p = np.asarray(center, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    ok = nn > 0
    # Projection of p onto each face's plane; inside the face when all three edge tests agree.
    with np.errstate(divide="ignore", invalid="ignore"):
        height = np.einsum("ij,ij->i", n, p - a) / np.sqrt(nn)
        q = p - (height / np.sqrt(nn))[:, None] * n
    inside = ok.copy()
    for x, y in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(y - x, q - x), n) >= 0
    edge = np.minimum.reduce(
        [_segment_distance(p, a, b), _segment_distance(p, b, c), _segment_distance(p, c, a)]
    )
    return float(np.min(np.where(inside, np.abs(height), edge)))


def triangle_soup(n, rng, *, extent=1.0, size=0.15):
    """``n`` independent random triangles (no shared vertices) with centres in ``[0, extent]^3``.

    Returns
    -------
    vertices : (3n, 3) float32
    faces : (n, 3) int32
    """
    centers = rng.uniform(0.0, extent, size=(n, 1, 3))
    corners = centers + rng.normal(scale=size, size=(n, 3, 3))
    return corners.reshape(-1, 3).astype(np.float32), np.arange(3 * n, dtype=np.int32).reshape(n, 3)


def pinwheel(n, rng, *, radius=1.0):
    """``n`` triangles of circumradius ``radius``, all with their centroid at the origin, randomly
    turned.

    Every centroid is the same point, so a partitioner that splits by centroid finds no extent.

    Returns
    -------
    vertices : (3n, 3) float32
    faces : (n, 3) int32
    """
    angles = np.arange(3) * (2 * np.pi / 3)
    corners = radius * np.stack([np.cos(angles), np.sin(angles), np.zeros(3)], axis=1)  # centroid 0
    turns = np.stack([rotation(rng.normal(size=3), rng.uniform(0.0, np.pi)) for _ in range(n)])
    vertices = np.einsum("nij,kj->nki", turns, corners).reshape(-1, 3)
    return vertices.astype(np.float32), np.arange(3 * n, dtype=np.int32).reshape(n, 3)


def edge_on_soup(n, rng, *, extent=1000.0, size=0.01, axis=0):
    """``n`` small triangles whose planes contain the direction ``axis``,
    scattered in ``[0, extent]^3``.

    Seen along ``axis`` every triangle is edge-on: its projection has (nearly) zero area, and at
    a distance of ``extent`` its projected corners differ only in the last bits of float32. Rays
    nearly parallel to ``axis`` (see :func:`near_axis_rays`) then hit none of them, which a
    ray-triangle test that loses precision gets wrong.

    Returns
    -------
    vertices : (3n, 3) float32
    faces : (n, 3) int32
    """
    centers = rng.uniform(0.0, extent, size=(n, 1, 3))
    phi = rng.uniform(0.0, np.pi, size=(n, 1))
    along = rng.normal(scale=size, size=(n, 3))
    across = rng.normal(scale=size, size=(n, 3))
    offsets = np.zeros((n, 3, 3))
    others = [a for a in range(3) if a != axis]
    offsets[..., axis] = along
    offsets[..., others[0]] = across * np.cos(phi)
    offsets[..., others[1]] = across * np.sin(phi)
    vertices = (centers + offsets).reshape(-1, 3).astype(np.float32)
    return vertices, np.arange(3 * n, dtype=np.int32).reshape(n, 3)


def near_axis_rays(box, n, rng, *, axis=0, spread=1e-3):
    """Rays entering ``box`` through its low face on ``axis``, nearly parallel to ``axis``.

    Returns
    -------
    origins, directions : (n, 3) float32
      Directions are ``e_axis`` plus normal noise of scale ``spread`` on the other components.
    """
    lo, hi = np.asarray(box, dtype=np.float64)
    origins = rng.uniform(lo, hi, size=(n, 3))
    origins[:, axis] = lo[axis] - 0.01 * (hi[axis] - lo[axis])
    directions = rng.normal(scale=spread, size=(n, 3))
    directions[:, axis] = 1.0
    return origins.astype(np.float32), directions.astype(np.float32)


def single_triangle():
    """One triangle ``(0,0,0), (1,0,0), (0,1,0)``: (3, 3) float32 vertices, (1, 3) int32 faces."""
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=np.float32)
    return vertices, np.array([[0, 1, 2]], dtype=np.int32)


def degenerate_triangles(rng, n=64, *, extent=1.0):
    """Zero-area triangles of every kind, exactly degenerate in float32 and float64.

    Kinds, in turn: two equal indices; three equal indices; two distinct vertices with equal
    coordinates; three collinear vertices ``p, p + d, p + 2d`` (dyadic ``p`` and ``d``, so the
    cross product is exactly zero); a sliver whose middle vertex lies between the others.

    Returns
    -------
    vertices : (v, 3) float32
    faces : (n, 3) int32
    targets : (n, 3) float64
      A point on each degenerate triangle (on its segment or at its point), to aim rays at.
    """
    verts, faces, targets = [], [], []

    def dyadic(shape):
        # Multiples of 1/64 in [0, extent]: sums and small multiples stay exact.
        return np.round(rng.uniform(0.0, extent, size=shape) * 64.0) / 64.0

    for k in range(n):
        base = len(verts)
        kind = k % 5
        p = dyadic(3)
        d = (dyadic(3) - extent / 2) / 8.0
        if kind == 0:
            verts += [p, p + d]
            faces.append((base, base, base + 1))
            targets.append(p + d / 2)
        elif kind == 1:
            verts += [p]
            faces.append((base, base, base))
            targets.append(p)
        elif kind == 2:
            verts += [p, p.copy(), p + d]
            faces.append((base, base + 1, base + 2))
            targets.append(p + d / 4)
        elif kind == 3:
            verts += [p, p + d, p + 2 * d]
            faces.append((base, base + 1, base + 2))
            targets.append(p + d * 0.75)
        else:
            verts += [p, p + 2 * d, p + d]
            faces.append((base, base + 1, base + 2))
            targets.append(p + d * 1.5)
    vertices = np.asarray(verts, dtype=np.float32)
    return vertices, np.asarray(faces, dtype=np.int32), np.asarray(targets, dtype=np.float64)


def with_degenerates(rng, n_good=300, n_degenerate=100):
    """A triangle soup with exactly degenerate triangles shuffled in among its faces.

    Returns
    -------
    vertices : (v, 3) float32
    faces : (n_good + n_degenerate, 3) int32
    is_degenerate : (n_good + n_degenerate,) bool
    targets : (n_degenerate, 3) float64
      A point on each degenerate triangle.
    """
    gv, gf = triangle_soup(n_good, rng)
    dv, df, targets = degenerate_triangles(rng, n_degenerate)
    vertices = np.concatenate([gv, dv])
    faces = np.concatenate([gf, df + len(gv)])
    is_degenerate = np.r_[np.zeros(n_good, bool), np.ones(n_degenerate, bool)]
    order = rng.permutation(len(faces))
    return vertices, faces[order].astype(np.int32), is_degenerate[order], targets


def multi_mesh(rng):
    """Four meshes of different kinds side by side: a grid, a perturbed icosphere, a soup, a UV
    sphere.

    Returns
    -------
    meshes : list of ((v, 3) float32, (f, 3) int32)
    """
    gv, gf = grid(8, 2.0)
    sv, sf = icosphere(2, 0.6)
    sv = perturb_radially(sv, rng, 0.1)
    tv, tf = triangle_soup(200, rng, extent=1.5, size=0.1)
    uv, uf = uv_sphere(8, 12, 0.4)
    return [
        (transform(gv, offset=(-1.0, -1.0, -0.5)), gf),
        (transform(sv, offset=(0.2, 0.1, 0.3)), sf),
        (transform(tv, offset=(-0.75, -0.75, -0.2)), tf),
        (transform(uv, offset=(-0.5, 0.6, 0.0)), uf),
    ]


def concat(meshes):
    """Concatenate meshes into one, as the engine numbers triangles globally.

    Parameters
    ----------
    meshes : list of ((v, 3) float, (f, 3) int)

    Returns
    -------
    vertices : (V, 3) float32
    faces : (F, 3) int64
      Faces of mesh ``k`` come after those of meshes ``0..k-1``, re-indexed into ``vertices``.
    offsets : (n_meshes + 1,) int64
      Global index of each mesh's first face; the last entry is F.
    """
    vs, fs, offsets = [], [], [0]
    base = 0
    for vertices, faces in meshes:
        vertices = np.asarray(vertices, dtype=np.float32).reshape(-1, 3)
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        vs.append(vertices)
        fs.append(faces + base)
        base += len(vertices)
        offsets.append(offsets[-1] + len(faces))
    vertices = np.concatenate(vs) if vs else np.zeros((0, 3), np.float32)
    faces = np.concatenate(fs) if fs else np.zeros((0, 3), np.int64)
    return vertices, faces, np.asarray(offsets, dtype=np.int64)


def bounds(vertices, faces=None):
    """(2, 3) float64 ``[min, max]`` of the vertices (of the referenced ones if ``faces`` given)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if faces is not None:
        v = v[np.unique(np.asarray(faces).ravel())]
    return np.stack([v.min(axis=0), v.max(axis=0)])


# ---------------------------------------------------------------------------------------------
# Rays
# ---------------------------------------------------------------------------------------------


def unit_vectors(n, rng):
    """(n, 3) float64 directions uniform on the unit sphere."""
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def random_rays(box, n, rng, *, margin=0.1):
    """Origins uniform in ``box`` grown by ``margin`` of its diagonal, directions uniform.

    Parameters
    ----------
    box : (2, 3) float
      ``[min, max]``.

    Returns
    -------
    origins, directions : (n, 3) float32
      Directions are unit length.
    """
    lo, hi = np.asarray(box, dtype=np.float64)
    pad = margin * np.linalg.norm(hi - lo)
    origins = rng.uniform(lo - pad, hi + pad, size=(n, 3))
    return origins.astype(np.float32), unit_vectors(n, rng).astype(np.float32)


def aimed_rays(box, n, rng):
    """Rays from a sphere around ``box`` towards random points inside it (mostly hits on solid
    scenes).

    Returns
    -------
    origins, directions : (n, 3) float32
      Directions are unit length.
    """
    lo, hi = np.asarray(box, dtype=np.float64)
    center, radius = (lo + hi) / 2, max(np.linalg.norm(hi - lo), 1e-3)
    origins = center + radius * unit_vectors(n, rng)
    targets = rng.uniform(lo, hi, size=(n, 3))
    d = targets - origins
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return origins.astype(np.float32), d.astype(np.float32)


def mixed_rays(box, n, rng):
    """Half :func:`random_rays`, half :func:`aimed_rays`: (n, 3) float32 origins and directions."""
    o1, d1 = random_rays(box, n // 2, rng)
    o2, d2 = aimed_rays(box, n - n // 2, rng)
    return np.concatenate([o1, o2]), np.concatenate([d1, d2])


def camera_rays(box, width=64, height=48, *, view=(1.0, 0.6, 0.8), fov_degrees=55.0, inside=False):
    """Pinhole-camera rays looking at the centre of ``box``.

    The eye sits at ``center + 1.2 * diagonal * view/|view|``, or at the centre looking along
    ``-view`` when ``inside``.

    Returns
    -------
    origins, directions : (width * height, 3) float32
      Directions are unit length; rows in raster order.
    """
    lo, hi = np.asarray(box, dtype=np.float64)
    center, diag = (lo + hi) / 2, np.linalg.norm(hi - lo)
    view = np.asarray(view, dtype=np.float64) / np.linalg.norm(view)
    eye = center if inside else center + 1.2 * diag * view
    forward = -view
    up_hint = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    right = np.cross(forward, up_hint)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = np.tan(np.radians(fov_degrees) / 2)
    xs = (np.arange(width) + 0.5) / width * 2 - 1
    ys = 1 - (np.arange(height) + 0.5) / height * 2
    px, py = np.meshgrid(xs * half * width / height, ys * half)
    d = forward + px.reshape(-1, 1) * right + py.reshape(-1, 1) * up
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(eye, d.shape).astype(np.float32), d.astype(np.float32)


def rays_at(targets, directions, distance=1.0):
    """Rays that pass through ``targets``: origins ``targets - distance * directions``.

    With dyadic targets, directions with small-integer components and a power-of-two
    ``distance`` the origins are exact in float32 and each ray passes exactly through its target.

    Parameters
    ----------
    targets : (n, 3) float
    directions : (n, 3) or (3,) float
      Not normalised.

    Returns
    -------
    origins, directions : (n, 3) float32
    """
    targets = np.asarray(targets, dtype=np.float64)
    directions = np.broadcast_to(np.asarray(directions, dtype=np.float64), targets.shape)
    return (targets - distance * directions).astype(np.float32), np.ascontiguousarray(
        directions, dtype=np.float32
    )


def grid_targets(vertices, faces, n, kind):
    """Points of a :func:`grid` (possibly transformed) to aim rays at, away from its boundary.

    kind : "vertices" (interior vertices), "midpoints" (midpoints of two-sided edges, including
    the diagonals) or "centers" (face centroids).

    Returns
    -------
    targets : (k, 3) float64
      Computed in float64 from the float32 vertices.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if kind == "vertices":
        return v[grid_interior_vertices(n)]
    if kind == "midpoints":
        edges = two_sided_edges(faces)
        return (v[edges[:, 0]] + v[edges[:, 1]]) / 2
    if kind == "centers":
        f = np.asarray(faces, dtype=np.int64)
        return v[f].mean(axis=1)
    raise ValueError(f"unknown kind {kind!r}")


# Directions with small-integer components, pointing down (-z): with dyadic targets and a
# power-of-two distance the origins are exact in float32 and the rays pass exactly through them.
EXACT_DOWN_DIRECTIONS = np.array(
    [[1, 0, -1], [0, 1, -2], [1, 1, -1], [-1, 2, -3], [3, -1, -2], [1, 1, -8]], dtype=np.float64
)


def down_directions(kind, n, rng=None, to_world=None):
    """(n, 3) float64 directions pointing down (-z) through a grid, mapped by ``to_world``.

    kind : "normal" (straight down, axis-aligned on a flat grid), "exact_oblique" (cycling
    through :data:`EXACT_DOWN_DIRECTIONS`, not unit length) or "random_oblique" (unit length, at
    least about 11 degrees above the plane; needs ``rng``).
    to_world : (3, 3) float or None
      Rotation applied to the directions (for a grid that was rotated by it).
    """
    if kind == "normal":
        local = np.tile([0.0, 0.0, -1.0], (n, 1))
    elif kind == "exact_oblique":
        local = EXACT_DOWN_DIRECTIONS[np.arange(n) % len(EXACT_DOWN_DIRECTIONS)]
    elif kind == "random_oblique":
        local = unit_vectors(n, rng)
        local[:, 2] = -np.maximum(np.abs(local[:, 2]), 0.2)
        local /= np.linalg.norm(local, axis=1, keepdims=True)
    else:
        raise ValueError(f"unknown kind {kind!r}")
    return local if to_world is None else local @ np.asarray(to_world, dtype=np.float64).T


def grid_rays(
    vertices,
    faces,
    n,
    target="vertices",
    direction="normal",
    *,
    rng=None,
    to_world=None,
    distance=0.5,
):
    """Rays from above aimed exactly at a :func:`grid`'s interior vertices, edge midpoints or face
    centres.

    Combines :func:`grid_targets`, :func:`down_directions` and :func:`rays_at`; every ray reaches
    its target at ``t = distance``.

    Returns
    -------
    origins, directions : (k, 3) float32
    targets : (k, 3) float64
    """
    targets = grid_targets(vertices, faces, n, target)
    dirs = down_directions(direction, len(targets), rng, to_world)
    origins, directions = rays_at(targets, dirs, distance)
    return origins, directions, targets


def rays_from_inside(center, radius, n, rng):
    """Rays from points uniform in the ball ``(center, radius)``, in uniform directions.

    Returns
    -------
    origins, directions : (n, 3) float32
      Directions are unit length.
    """
    r = radius * rng.uniform(0.0, 1.0, size=(n, 1)) ** (1 / 3)
    origins = np.asarray(center, dtype=np.float64) + r * unit_vectors(n, rng)
    return origins.astype(np.float32), unit_vectors(n, rng).astype(np.float32)
