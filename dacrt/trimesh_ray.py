"""trimesh's ray intersector and proximity interfaces, answered by dacrt: switch with one line.

    mesh.ray = dacrt.trimesh_ray.RayMeshIntersector(mesh)   # mesh: a trimesh.Trimesh
    mesh.ray.intersects_location(origins, directions)       # and mesh.contains(points) use it
    mesh.nearest = dacrt.trimesh_ray.ProximityQuery(mesh)
    mesh.nearest.on_surface(points)                         # closest, distance, triangle_id

The methods, argument names, shapes, dtypes and ``-1`` conventions are those of
``trimesh.ray.ray_pyembree.RayMeshIntersector`` (and ``ray_triangle``'s): ``intersects_first``,
``intersects_any``, ``intersects_id``, ``intersects_location``, ``contains_points``. What differs:

- A ray crossing a shared edge or vertex of the mesh reports that crossing once (trimesh's
  ``ray_triangle`` reports both triangles); coplanar duplicate triangles are each reported. Several
  hits of one ray come nearest first, rays in input order (trimesh's order is its own).
- ``contains_points`` counts crossings with ``Scene.count``, which is exact at edges and
  vertices, along trimesh's fixed direction and its opposite; where the two parities disagree
  and both rays hit something it tries one more direction (from a fixed seed, so answers repeat),
  as trimesh does with a random one.
- A ray with a non-finite component or a zero direction hits nothing (no error).
- Locations are where the ray meets the hit triangle's plane, in float64 from the caller's
  origins and directions (as trimesh computes them): the engine picks the triangles, float64
  places the points.

The engine traces in float32; the in-process backend moves the mesh's bounding-box centre to the
origin first (rays too), which keeps float32 precision for meshes far from the origin. ``t`` is
never exposed, so directions are normalised (as trimesh's embree intersector does).

Any object with the four ray methods of ``EngineBackend`` can answer for the mesh (the service's
``service.intersector`` sends them to a server); ``ProximityQuery`` also asks ``nearest``.

``ProximityQuery`` has trimesh's ``on_surface`` and ``signed_distance`` (not ``vertex``): the
closest point by ``Scene.nearest`` (exact in float64 for the float32 point; ties to the lowest
triangle, where trimesh takes any), and trimesh's sign convention (positive inside, by
``RayMeshIntersector.contains_points``; a point on the surface is positive).
"""

import numpy as np

from .scene import Scene

#: The ray direction of trimesh's ``contains_points`` (``trimesh.ray.ray_util``).
CONTAINS_DIRECTION = np.array([0.4395064455, 0.617598629942, 0.652231566745])
#: Seed of the extra directions ``contains_points`` tries where its two parities disagree.
RETRY_SEED = 2463534242


class EngineBackend:
    """The queries an intersector asks, answered in process by a ``dacrt.Scene`` of one mesh.

    vertices : (V, 3) float; faces : (F, 3) int. Rays arrive as float64 (n, 3) origins and unit
    directions, every one finite.
    """

    def __init__(self, vertices, faces):
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces)
        corners = vertices[faces.ravel()] if faces.size else np.zeros((1, 3))
        #: The mesh is traced moved by -shift (float64 -> float32 after the move).
        self.shift = (corners.min(axis=0) + corners.max(axis=0)) / 2
        self.scene = Scene([((vertices - self.shift).astype(np.float32), faces)])

    def _rays(self, origins, directions):
        return (origins - self.shift).astype(np.float32), directions.astype(np.float32)

    def closest(self, origins, directions):
        """The nearest hit of each ray: prim (n,) int (-1 on a miss), u, v (n,) float."""
        hits = self.scene.closest(*self._rays(origins, directions))
        return hits.prim, hits.u, hits.v

    def occluded(self, origins, directions):
        """(n,) bool: whether each ray hits anything."""
        return self.scene.occluded(*self._rays(origins, directions)).occluded

    def hits(self, origins, directions, max_hits):
        """Every hit of each ray, nearest first, at most ``max_hits``: offsets (n+1,) int and
        prim, u, v per hit."""
        hits = self.scene.hits(*self._rays(origins, directions), max_hits=max_hits)
        return hits.offsets, hits.prim, hits.u, hits.v

    def count(self, origins, directions):
        """(n,) int: the triangles each ray crosses (a shared edge or vertex once)."""
        return self.scene.count(*self._rays(origins, directions)).count

    def nearest(self, points):
        """The closest point of the mesh to each of ``points`` (n, 3) float64, every one finite:
        prim (n,) int (-1 for none: an empty mesh), the point (n, 3) float64 and the distance
        (n,) float."""
        found = self.scene.nearest((points - self.shift).astype(np.float32))
        return found.prim, found.point.astype(np.float64) + self.shift, found.distance


class RayMeshIntersector:
    """Ray queries on one triangle mesh, with trimesh's interface.

    mesh : a ``trimesh.Trimesh``, or any object with ``vertices`` (V, 3) float and ``faces``
        (F, 3) int; it is read once, when the intersector is made.
    backend : what answers the queries; default an ``EngineBackend`` of the mesh (in process).
    """

    def __init__(self, mesh, backend=None):
        self.mesh = mesh
        self._vertices = np.asarray(mesh.vertices, dtype=np.float64)
        self._faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
        self._backend = backend if backend is not None else EngineBackend(mesh.vertices, mesh.faces)
        if len(self._faces):
            corners = self._vertices[self._faces.ravel()]
            self._bounds = np.stack([corners.min(axis=0), corners.max(axis=0)])
        else:
            self._bounds = None

    def intersects_first(self, ray_origins, ray_directions):
        """The index of the first triangle each ray hits.

        ray_origins, ray_directions : (n, 3) float
        Returns triangle_index : (n,) int64, -1 where the ray hits nothing.
        """
        origins, directions, valid = _rays(ray_origins, ray_directions)
        first = np.full(len(valid), -1, dtype=np.int64)
        if valid.any():
            first[valid] = self._backend.closest(origins[valid], directions[valid])[0]
        return first

    def intersects_any(self, ray_origins, ray_directions):
        """Whether each ray hits the mesh.

        ray_origins, ray_directions : (n, 3) float
        Returns hit : (n,) bool.
        """
        origins, directions, valid = _rays(ray_origins, ray_directions)
        hit = np.zeros(len(valid), dtype=bool)
        if valid.any():
            hit[valid] = self._backend.occluded(origins[valid], directions[valid])
        return hit

    def intersects_id(
        self,
        ray_origins,
        ray_directions,
        multiple_hits=True,
        max_hits=100,
        return_locations=False,
    ):
        """The triangles hit by each ray: every hit (nearest first, at most ``max_hits`` a ray;
        None: no limit) or, with ``multiple_hits=False``, the first.

        ray_origins, ray_directions : (n, 3) float
        Returns index_tri : (m,) int64 (rows of mesh.faces), index_ray : (m,) int64, and with
        ``return_locations`` locations : (m, 3) float64.
        """
        origins, directions, valid = _rays(ray_origins, ray_directions)
        rays = np.flatnonzero(valid)
        if not len(rays):
            prim = index_ray = np.zeros(0, dtype=np.int64)
            u = v = np.zeros(0)
        elif multiple_hits:
            offsets, prim, u, v = self._every_hit(origins[rays], directions[rays], max_hits)
            index_ray = np.repeat(rays, np.diff(offsets))
        else:
            prim, u, v = self._backend.closest(origins[rays], directions[rays])
            hit = prim >= 0
            prim, u, v, index_ray = prim[hit], u[hit], v[hit], rays[hit]
        index_tri = np.asarray(prim, dtype=np.int64)
        index_ray = np.asarray(index_ray, dtype=np.int64)
        if return_locations:
            locations = self._locations(index_tri, index_ray, origins, directions, u, v)
            return index_tri, index_ray, locations
        return index_tri, index_ray

    def intersects_location(self, ray_origins, ray_directions, multiple_hits=True):
        """Where each ray hits the mesh (every hit, or the first with ``multiple_hits=False``).

        ray_origins, ray_directions : (n, 3) float
        Returns locations : (m, 3) float64, index_ray : (m,) int64, index_tri : (m,) int64.
        """
        index_tri, index_ray, locations = self.intersects_id(
            ray_origins, ray_directions, multiple_hits=multiple_hits, return_locations=True
        )
        return locations, index_ray, index_tri

    def contains_points(self, points):
        """Whether the mesh contains each point, by the parity of ray crossings (a point on
        the surface may go either way).

        points : (n, 3) float
        Returns contains : (n,) bool.
        """
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError("points must be (n,3)")
        contains = np.zeros(len(points), dtype=bool)
        if self._bounds is None:
            return contains
        # Strictly inside the box, as trimesh's bounds.contains.
        todo = np.flatnonzero(
            (points > self._bounds[0]).all(axis=1) & (points < self._bounds[1]).all(axis=1)
        )
        directions = [CONTAINS_DIRECTION, _unit(np.random.default_rng(RETRY_SEED).random(3) - 0.5)]
        for direction in directions:
            if not len(todo):
                break
            todo_points = points[todo]
            ray_directions = np.tile(direction, (len(todo), 1))
            counts = self._backend.count(
                np.vstack((todo_points, todo_points)), np.vstack((ray_directions, -ray_directions))
            )
            both = np.asarray(counts).reshape(2, -1)
            odd = both % 2 == 1
            agree = odd[0] == odd[1]
            contains[todo[agree]] = odd[0][agree]
            # Rays that disagree with one in free space say outside (the default False).
            todo = todo[~agree & (both != 0).all(axis=0)]
        return contains

    def _every_hit(self, origins, directions, max_hits):
        """(offsets, prim, u, v) of every hit, at most ``max_hits`` per ray (None: all)."""
        if max_hits is None:
            max_hits = max(1, int(np.max(self._backend.count(origins, directions), initial=0)))
        elif isinstance(max_hits, bool) or not isinstance(max_hits, (int, np.integer)):
            raise ValueError(f"max_hits must be a positive integer or None, got {max_hits!r}")
        elif max_hits < 1:
            empty = np.zeros(0, dtype=np.int64)
            return np.zeros(len(origins) + 1, dtype=np.int64), empty, empty, empty
        return self._backend.hits(origins, directions, int(max_hits))

    def _locations(self, prim, index_ray, origins, directions, u, v):
        """(m, 3) float64 points where rays ``index_ray`` meet the planes of triangles ``prim``
        (for a triangle nearly edge-on to its ray, (1-u-v)*p0 + u*p1 + v*p2)."""
        corners = self._vertices[self._faces[prim]]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        o, d = origins[index_ray], directions[index_ray]
        facing = np.einsum("ij,ij->i", normals, d)
        along = np.einsum("ij,ij->i", normals, corners[:, 0] - o)
        steep = np.abs(facing) > 1e-6 * np.linalg.norm(normals, axis=1)
        t = np.divide(along, facing, out=np.zeros_like(along), where=steep)
        u = np.asarray(u, dtype=np.float64)[:, None]
        v = np.asarray(v, dtype=np.float64)[:, None]
        on_triangle = (1 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]
        return np.where(steep[:, None], o + t[:, None] * d, on_triangle)


class ProximityQuery:
    """Closest points on one triangle mesh, with trimesh's ``mesh.nearest`` interface.

    mesh : a ``trimesh.Trimesh``, or any object with ``vertices`` and ``faces``; read once.
    backend : what answers the queries; default an ``EngineBackend`` of the mesh (in process).
    """

    def __init__(self, mesh, backend=None):
        self._backend = backend if backend is not None else EngineBackend(mesh.vertices, mesh.faces)
        self._intersector = RayMeshIntersector(mesh, self._backend)

    def on_surface(self, points):
        """The closest point of the mesh to each point.

        points : (m, 3) float
        Returns closest : (m, 3) float64, distance : (m,) float64, triangle_id : (m,) int64
        (-1, with inf, for an empty mesh).
        """
        points = _points(points)
        prim, closest, distance = self._backend.nearest(points)
        return (
            np.asarray(closest, dtype=np.float64),
            np.asarray(distance, dtype=np.float64),
            np.asarray(prim, dtype=np.int64),
        )

    def signed_distance(self, points):
        """The distance to the mesh, positive inside (``contains_points``) and on the surface,
        negative outside: trimesh's convention.

        points : (n, 3) float
        Returns signed_distance : (n,) float64.
        """
        points = _points(points)
        _, distance, _ = self.on_surface(points)
        inside = self._intersector.contains_points(points) | (distance == 0)
        return np.where(inside, distance, -distance)


def _points(points):
    """float64 (n, 3) points; ValueError for another shape or a non-finite value."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (n, 3), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("points must be finite")
    return points


def _unit(vectors):
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def _rays(ray_origins, ray_directions):
    """float64 origins, unit directions and (n,) bool: which rays can hit anything (finite,
    with a non-zero direction); ValueError for shapes trimesh refuses."""
    origins = np.asarray(ray_origins, dtype=np.float64)
    directions = np.asarray(ray_directions, dtype=np.float64)
    if origins.shape != directions.shape:
        raise ValueError("Ray origin and direction don't match!")
    if origins.ndim != 2 or origins.shape[1] != 3:
        raise ValueError(f"rays must be (n, 3) arrays, got {origins.shape}")
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        length = np.linalg.norm(directions, axis=1)
        directions = directions / length[:, None]
        valid = (
            (np.abs(origins) < np.finfo(np.float32).max).all(axis=1)
            & np.isfinite(directions).all(axis=1)
            & (length > 0)
        )
    return origins, directions, valid
