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

The engine traces in float32; the mesh is traced with its bounding-box centre moved to the origin
(rays too: ``centre_of``), which keeps float32 precision for meshes far from the origin. ``t`` is
never exposed, so directions are normalised (as trimesh's embree intersector does).

The intersector follows the mesh as trimesh's own do: a ``trimesh.Trimesh`` is read again when
its content hash (``hash(mesh)``, which trimesh keeps up to date as its arrays change) is not the
one it was read at; another object with ``vertices`` and ``faces`` is read once. Threads may
share an intersector: each call answers from one reading of the mesh (its arrays and backend,
published together once the backend is built), and a call that finds the mesh changed while
another thread reads it again waits for that reading.

Any object with the four ray methods of ``EngineBackend`` can answer for the mesh (the service's
``service.intersector`` sends them to a server); ``ProximityQuery`` also asks ``nearest``.

``ProximityQuery`` has trimesh's ``on_surface``, ``signed_distance`` and ``vertex``: the closest
point by ``Scene.nearest`` (measured in float64 for the point rounded to float32; ties to the
lowest triangle, where trimesh takes any; a degenerate triangle, of no area, is never the
closest), and trimesh's sign convention (positive inside, by
``RayMeshIntersector.contains_points``; a point on the surface, as far as its rounding to
float32 can tell, is positive). ``vertex`` is trimesh's
own (a KD-tree of the vertices, which needs scipy).
"""

import threading
from typing import NamedTuple

import numpy as np

from .scene import Scene

#: The ray direction of trimesh's ``contains_points`` (``trimesh.ray.ray_util``).
CONTAINS_DIRECTION = np.array([0.4395064455, 0.617598629942, 0.652231566745])
#: Seed of the extra directions ``contains_points`` tries where its two parities disagree.
RETRY_SEED = 2463534242


def centre_of(vertices, faces):
    """(3,) float64: the centre of the box of the vertices ``faces`` uses (the origin for none),
    which a backend moves to the origin before it rounds the mesh to float32."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    corners = vertices[faces.ravel()] if faces.size else np.zeros((1, 3))
    return (corners.min(axis=0) + corners.max(axis=0)) / 2


def rounding_slack(points, shift):
    """(n,) float64: how far each of ``points`` moves when rounded to float32 after the move by
    -``shift`` (a point, or a vertex of the mesh as traced)."""
    moved = np.asarray(points, dtype=np.float64) - shift
    return np.linalg.norm(moved.astype(np.float32) - moved, axis=1)


class EngineBackend:
    """The queries an intersector asks, answered in process by a ``dacrt.Scene`` of one mesh.

    vertices : (V, 3) float; faces : (F, 3) int. Rays arrive as float64 (n, 3) origins and unit
    directions, every one finite.
    """

    def __init__(self, vertices, faces):
        vertices = np.asarray(vertices, dtype=np.float64)
        #: The mesh is traced moved by -shift (float64 -> float32 after the move).
        self.shift = centre_of(vertices, faces)
        self.scene = Scene([((vertices - self.shift).astype(np.float32), np.asarray(faces))])

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


class MeshReading(NamedTuple):
    """One read of an intersector's mesh, never changed after it is made: a call answers from
    one reading throughout."""

    #: The mesh's content hash when read (None: read once, not again).
    content_hash: object
    #: What answers the queries for this mesh.
    backend: object
    #: (V, 3) float64 and (F, 3) int64, read-only copies of the mesh's arrays.
    vertices: np.ndarray
    faces: np.ndarray
    #: (2, 3) float64 box of the corners the faces use (None for no faces), read-only.
    bounds: object
    #: (the backend's shift, the most a vertex moves when rounded to float32 after it).
    rounding: tuple


class RayMeshIntersector:
    """Ray queries on one triangle mesh, with trimesh's interface.

    mesh : a ``trimesh.Trimesh`` (read again whenever its content changes), or any object with
        ``vertices`` (V, 3) float and ``faces`` (F, 3) int (read once)
    backend : what answers the queries, for the mesh as it is now (then the mesh is read once);
        default an ``EngineBackend`` made by ``make_backend`` whenever the mesh is read

    Each call answers from one ``reading()`` (threads may share the intersector).
    """

    def __init__(self, mesh, backend=None):
        self.mesh = mesh
        self._fixed_backend = backend
        self._lock = threading.Lock()  # one thread reads the mesh again; the others wait for it
        self._reading = self._read()

    def make_backend(self, vertices, faces):
        """The backend of the mesh's ``vertices`` (V, 3) float64 and ``faces`` (F, 3) int64."""
        return EngineBackend(vertices, faces)

    def reading(self):
        """The ``MeshReading`` of the mesh as it is now: read again if its content hash
        changed, and published whole once its backend is built."""
        reading = self._reading
        if reading.content_hash is None or _content_hash(self.mesh) == reading.content_hash:
            return reading
        with self._lock:
            reading = self._reading  # another thread may have read it again meanwhile
            if _content_hash(self.mesh) != reading.content_hash:
                reading = self._reading = self._read()
        return reading

    def backend(self):
        """The backend of the mesh as it is now: read again if its content hash changed."""
        return self.reading().backend

    def _read(self):
        """A new ``MeshReading`` of the mesh (the hash first: an edit meanwhile reads again)."""
        mesh = self.mesh
        # a given backend answers for the mesh as it was: the mesh is then read once too
        content_hash = _content_hash(mesh) if self._fixed_backend is None else None
        vertices = np.array(mesh.vertices, dtype=np.float64)  # a copy: edits come again
        faces = np.array(mesh.faces, dtype=np.int64).reshape(-1, 3)
        vertices.flags.writeable = faces.flags.writeable = False
        if self._fixed_backend is not None:
            backend = self._fixed_backend
        else:
            backend = self.make_backend(vertices, faces)
        bounds = None
        if len(faces):
            corners = vertices[faces.ravel()]
            bounds = np.stack([corners.min(axis=0), corners.max(axis=0)])
            bounds.flags.writeable = False
        shift = getattr(backend, "shift", np.zeros(3))
        rounding = (shift, rounding_slack(vertices, shift).max(initial=0.0))
        return MeshReading(content_hash, backend, vertices, faces, bounds, rounding)

    def rounding(self):
        """(the backend's shift, the most a vertex moves when the mesh is rounded to float32
        after that shift), for the mesh as it is now."""
        return self.reading().rounding

    def intersects_first(self, ray_origins, ray_directions):
        """The index of the first triangle each ray hits.

        ray_origins, ray_directions : (n, 3) float
        Returns triangle_index : (n,) int64, -1 where the ray hits nothing.
        """
        backend = self.backend()
        origins, directions, valid = _rays(ray_origins, ray_directions)
        first = np.full(len(valid), -1, dtype=np.int64)
        if valid.any():
            first[valid] = backend.closest(origins[valid], directions[valid])[0]
        return first

    def intersects_any(self, ray_origins, ray_directions):
        """Whether each ray hits the mesh.

        ray_origins, ray_directions : (n, 3) float
        Returns hit : (n,) bool.
        """
        backend = self.backend()
        origins, directions, valid = _rays(ray_origins, ray_directions)
        hit = np.zeros(len(valid), dtype=bool)
        if valid.any():
            hit[valid] = backend.occluded(origins[valid], directions[valid])
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
        reading = self.reading()
        backend = reading.backend
        origins, directions, valid = _rays(ray_origins, ray_directions)
        rays = np.flatnonzero(valid)
        if not len(rays):
            prim = index_ray = np.zeros(0, dtype=np.int64)
            u = v = np.zeros(0)
        elif multiple_hits:
            offsets, prim, u, v = _every_hit(backend, origins[rays], directions[rays], max_hits)
            index_ray = np.repeat(rays, np.diff(offsets))
        else:
            prim, u, v = backend.closest(origins[rays], directions[rays])
            hit = prim >= 0
            prim, u, v, index_ray = prim[hit], u[hit], v[hit], rays[hit]
        index_tri = np.asarray(prim, dtype=np.int64)
        index_ray = np.asarray(index_ray, dtype=np.int64)
        if return_locations:
            locations = self._locations(reading, index_tri, index_ray, origins, directions, u, v)
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
        return self._contains(self.reading(), points)

    def _contains(self, reading, points):
        """``contains_points`` for the mesh as ``reading`` read it."""
        backend, bounds = reading.backend, reading.bounds
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError("points must be (n,3)")
        contains = np.zeros(len(points), dtype=bool)
        if bounds is None:
            return contains
        # Strictly inside the box, as trimesh's bounds.contains.
        todo = np.flatnonzero((points > bounds[0]).all(axis=1) & (points < bounds[1]).all(axis=1))
        directions = [CONTAINS_DIRECTION, _unit(np.random.default_rng(RETRY_SEED).random(3) - 0.5)]
        for direction in directions:
            if not len(todo):
                break
            todo_points = points[todo]
            ray_directions = np.tile(direction, (len(todo), 1))
            counts = backend.count(
                np.vstack((todo_points, todo_points)), np.vstack((ray_directions, -ray_directions))
            )
            both = np.asarray(counts).reshape(2, -1)
            odd = both % 2 == 1
            agree = odd[0] == odd[1]
            contains[todo[agree]] = odd[0][agree]
            # Rays that disagree with one in free space say outside (the default False).
            todo = todo[~agree & (both != 0).all(axis=0)]
        return contains

    def _locations(self, reading, prim, index_ray, origins, directions, u, v):
        """(m, 3) float64 points where rays ``index_ray`` meet the planes of triangles ``prim``
        of the mesh as ``reading`` read it (for a triangle nearly edge-on to its ray,
        (1-u-v)*p0 + u*p1 + v*p2)."""
        corners = reading.vertices[reading.faces[prim]]
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

    mesh, backend : as for ``RayMeshIntersector`` (a ``trimesh.Trimesh`` is read again whenever
        its content changes)
    """

    def __init__(self, mesh, backend=None):
        self._intersector = RayMeshIntersector(mesh, backend)

    def on_surface(self, points):
        """The closest point of the mesh to each point.

        points : (m, 3) float
        Returns closest : (m, 3) float64, distance : (m,) float64, triangle_id : (m,) int64
        (-1, with inf, for an empty mesh).
        """
        return self._on_surface(self._intersector.reading(), _points(points))

    def _on_surface(self, reading, points):
        """``on_surface`` of finite (m, 3) float64 points, for the mesh as ``reading`` read it."""
        prim, closest, distance = reading.backend.nearest(points)
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
        reading = self._intersector.reading()  # the distance and the sign of one mesh
        _, distance, _ = self._on_surface(reading, points)
        # the distance is between the point and the mesh as rounded to float32: within their
        # rounding, the point may be on the surface
        shift, mesh_rounding = reading.rounding
        slack = rounding_slack(points, shift) + mesh_rounding
        on_surface = distance <= slack * (1 + 2**-22)
        inside = self._intersector._contains(reading, points) | on_surface
        return np.where(inside, distance, -distance)

    def vertex(self, points):
        """trimesh's own ``vertex`` (a KD-tree of the mesh's vertices; needs scipy): the
        distance to the closest vertex of each point, and its index.

        points : (m, 3) float
        Returns distance : (m,) float64, vertex_id : (m,) int64.
        """
        from trimesh.proximity import ProximityQuery as TrimeshQuery

        return TrimeshQuery(self._intersector.mesh).vertex(points)


def _every_hit(backend, origins, directions, max_hits):
    """(offsets, prim, u, v) of every hit, at most ``max_hits`` per ray (None: all)."""
    if max_hits is None:
        max_hits = max(1, int(np.max(backend.count(origins, directions), initial=0)))
    elif isinstance(max_hits, bool) or not isinstance(max_hits, (int, np.integer)):
        raise ValueError(f"max_hits must be a positive integer or None, got {max_hits!r}")
    elif max_hits < 1:
        empty = np.zeros(0, dtype=np.int64)
        return np.zeros(len(origins) + 1, dtype=np.int64), empty, empty, empty
    return backend.hits(origins, directions, int(max_hits))


def _content_hash(mesh):
    """A ``trimesh.Trimesh``'s content hash (trimesh keeps it current as its arrays change), or
    None for an object whose hash does not follow its content (it is read once)."""
    if type(mesh).__hash__ in (None, object.__hash__):
        return None
    return hash(mesh)


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
