"""The public query surface: ``Scene`` and its queries ``closest``, ``occluded``, ``hits`` and
``count``; the point queries ``nearest``, ``contains`` and ``signed_distance`` are ``points``'.

This is the only module that checks and converts input. A Scene keeps its triangles and what is
O(F) and cheap to derive from them (gathered vertices, boxes); every query partitions rays and
triangles from scratch and keeps nothing afterwards. How a batch is cut into chunks and spread
over threads is ``chunks``.
"""

import functools
from collections import namedtuple
from collections.abc import Iterable, Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from . import points as point_queries
from .chunks import (
    DENSITY_GRID,
    MIN_RAYS_PER_THREAD,
    N_CORES,
    centre_counts,
    chunk_ids,
    count_chunks,
    from_one_point,
    map_on_threads,
    plan_chunks,
    splits_triangles,
)
from .compiling import watch
from .contracts import (
    FLOAT,
    INDEX,
    RAYSPACE,
    STAT_NAMES,
    STAT_RAYS,
    STAT_TRIANGLES,
    STRATEGY_CODES,
    Counts,
    HitList,
    Hits,
    Nearest,
    Occlusion,
)
from .leaf import NO_HIT
from .query import (
    ALL_HITS,
    ALL_MASKS,
    ANY_HIT,
    COLLECT,
    COUNT,
    CULL_FLAGS,
    FIXED_ORIGIN,
    MASKED,
    STRATEGY_SHIFT,
    QueryArrays,
)
from .rays import new_records, pack_rays, uniform_origin, unpack_best_t
from .rayspace import trace_ray_space
from .results import finish_closest, finish_hits, unit_normals
from .traversal import split_middle, trace_object_split
from .triangles import Triangles, gather_triangles
from .validation import (
    InputError,
    check_cull,
    check_masks,
    check_max_hits,
    check_mesh,
    check_rays,
    check_strategy,
    check_threads,
    check_transform,
    explain_bad_rays,
    place_vertices,
)

#: The values of ``cull=`` and ``strategy=`` (``CULL_MODES``, ``STRATEGIES``).
Cull = Literal["none", "back", "front"]
Strategy = Literal["sampling", "sah", "middle", "rayspace"]

Traced = namedtuple("Traced", ["best_t", "arrays", "counters", "origins", "directions"])
Traced.__doc__ = """What the kernels leave of a query: each ray's best_t, the query's
``QueryArrays`` (without scratch), the counters (a dict), and the checked float32 origins and
directions."""


class Scene:
    """Triangle meshes to cast rays into.

    meshes : sequence of (vertices (V, 3) float, faces (F, 3) int) pairs; hits report a mesh by
        its position in this sequence and a triangle by its row in that mesh's faces.
    masks : None (every mesh all ones), an integer, or (n_meshes,) uint32: each mesh's mask; a
        ray sees a mesh only where ray mask & mesh mask != 0 (``mask=`` of the queries).
    transforms : None, or one entry per mesh: None (as given) or a (4, 4) row-major affine
        matrix that places the mesh, each vertex p at M[:3, :3] @ p + M[:3, 3] (in float64,
        then float32). Answers are in scene space: t, u, v along the caller's ray, normals of
        the placed triangles; prim stays the row of the mesh's own faces. The same (vertices,
        faces) arrays may be given several times, each with its own matrix and mask: instances.
    """

    def __init__(
        self,
        meshes: Iterable[tuple[ArrayLike, ArrayLike]],
        masks: ArrayLike | int | None = None,
        transforms: Sequence[ArrayLike | None] | None = None,
    ) -> None:
        watch()  # the first compile in process says so (``compiling``)
        meshes = list(meshes)
        checked = [check_mesh(i, vertices, faces) for i, (vertices, faces) in enumerate(meshes)]
        if transforms is not None:
            checked = self._placed(checked, list(transforms))
        counts = [len(faces) for _, faces in checked]
        self.n_meshes = len(checked)
        self.masks = check_masks(
            ALL_MASKS if masks is None else masks, self.n_meshes, "masks", "mesh"
        ).copy()
        self.masks.flags.writeable = False  # _row_masks is derived from it once
        self.mesh_offsets = np.zeros(self.n_meshes + 1, np.int64)
        self.mesh_offsets[1:] = np.cumsum(counts)
        self.n_triangles = int(self.mesh_offsets[-1])

        # Degenerate (zero-area) triangles never hit: they get no row, and no query sees them.
        tri_verts = np.empty((self.n_triangles, 9), FLOAT)
        tri_bounds = np.empty((self.n_triangles, 6), FLOAT)
        tri_global = np.empty(self.n_triangles, INDEX)
        corner_box = np.array([np.inf] * 3 + [-np.inf] * 3, FLOAT)
        self._box = corner_box.copy()
        n_live = 0
        for (vertices, faces), first_row in zip(checked, self.mesh_offsets):
            n_live = gather_triangles(
                vertices,
                faces,
                first_row,
                n_live,
                tri_verts,
                tri_bounds,
                tri_global,
                corner_box,
                self._box,
            )
        self._tri_verts = tri_verts[:n_live]
        self._tri_bounds = tri_bounds[:n_live]
        self._tri_global = tri_global[:n_live]
        if not n_live:
            self._box[:] = 0
        # Bounds of the referenced vertices: every corner, degenerate triangles included.
        self.bounds = corner_box.reshape(2, 3) if self.n_triangles else np.zeros((2, 3), FLOAT)

    @staticmethod
    def _placed(checked, transforms):
        """The checked meshes with their vertices placed by ``transforms`` (one per mesh)."""
        if len(transforms) != len(checked):
            raise InputError(f"transforms has {len(transforms)} entries for {len(checked)} meshes")
        placed = []
        for i, ((vertices, faces), matrix) in enumerate(zip(checked, transforms)):
            if matrix is not None:
                name = f"transforms[{i}]"
                vertices = place_vertices(vertices, check_transform(matrix, name), name)
            placed.append((vertices, faces))
        return placed

    @property
    def nbytes(self) -> int:
        """Bytes held by the scene's arrays, with those derived on demand once they exist."""
        derived = [
            self.__dict__[name]
            for name in ("_unit_normals", "_centre_counts", "_row_masks")
            if name in self.__dict__
        ]
        return int(
            self._tri_verts.nbytes
            + self._tri_bounds.nbytes
            + self._tri_global.nbytes
            + self.mesh_offsets.nbytes
            + sum(array.nbytes for array in derived)
        )

    @functools.cached_property
    def _centre_counts(self):
        """Triangle centres per cell of the DENSITY_GRID grid, for slab cuts: derived once per
        scene, on its first incoherent query on several threads."""
        return centre_counts(self._tri_bounds, self._box, DENSITY_GRID)

    @functools.cached_property
    def _unit_normals(self):
        """Each kernel row's unit normal (12 bytes a triangle), for batches of many rays:
        derived once per scene, on its first such ``closest``."""
        normals = np.empty((len(self._tri_verts), 3), FLOAT)
        unit_normals(self._tri_verts, normals)
        return normals

    @functools.cached_property
    def _row_masks(self):
        """Each kernel row's mesh mask (uint32, 4 bytes a triangle), for batches whose rays
        carry different masks: derived once per scene, on its first such query."""
        counts = np.diff(self.mesh_offsets)
        return np.ascontiguousarray(np.repeat(self.masks, counts)[self._tri_global])

    _no_normals = np.empty((0, 3), FLOAT)
    _no_masks = np.empty(0, np.uint32)

    def __repr__(self) -> str:
        return f"Scene({self.n_meshes} meshes, {self.n_triangles} triangles)"

    def closest(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        tmin: ArrayLike | float | None = None,
        tmax: ArrayLike | float | None = None,
        *,
        cull: Cull = "none",
        mask: ArrayLike | int | None = None,
        strategy: Strategy = "sampling",
        threads: int | None = None,
        stats: bool = False,
    ) -> Hits:
        """Nearest hit of each ray ``origins + t * directions`` with tmin <= t <= tmax.

        origins, directions : (n, 3) float; directions need not be unit, t is in their units
        tmin, tmax : None, a number, or (n,) float (defaults 0 and +inf)
        cull : "none", "back" (faces whose normal (p1-p0)x(p2-p0) points along the ray never
            hit) or "front" (faces whose normal points against it never hit)
        mask : None (all ones), an integer, or (n,) uint32: a ray sees a mesh only where its
            mask & the mesh's mask != 0
        strategy : one of ``dacrt.STRATEGIES``; all give the same answers
        threads : None for every core, or a positive int
        Returns ``Hits``; ties in t go to the lowest (mesh, triangle).
        """
        traced = self._trace(0, origins, directions, tmin, tmax, cull, mask, strategy, threads)
        t, counters = traced.best_t, traced.counters
        best_tri, u, v = traced.arrays.best_tri, traced.arrays.hit_u, traced.arrays.hit_v
        n = len(t)
        mesh = np.empty(n, INDEX)  # every element is written by finish_closest
        prim = np.empty(n, INDEX)
        normal = np.empty((n, 3), FLOAT)
        # A batch with at least as many rays as triangles looks up each triangle's normal,
        # derived once per scene; a smaller one derives each hit's.
        normals = self._unit_normals if n >= self.n_triangles else self._no_normals
        # In place (t, u, v are the trace's own arrays), in as many parts as the trace had threads.
        n_parts = max(1, min(check_threads(threads, N_CORES), n // MIN_RAYS_PER_THREAD))
        bounds = [k * n // n_parts for k in range(n_parts + 1)]

        def finish(k):
            part = slice(bounds[k], bounds[k + 1])
            finish_closest(
                t[part],
                best_tri[part],
                self._tri_global,
                self.mesh_offsets,
                self._tri_verts,
                normals,
                mesh[part],
                prim[part],
                normal[part],
            )

        map_on_threads(finish, n_parts, n_parts)
        return Hits(t, mesh, prim, u, v, normal, counters if stats else None)

    def occluded(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        tmin: ArrayLike | float | None = None,
        tmax: ArrayLike | float | None = None,
        *,
        cull: Cull = "none",
        mask: ArrayLike | int | None = None,
        strategy: Strategy = "sampling",
        threads: int | None = None,
        stats: bool = False,
    ) -> Occlusion:
        """Whether each ray hits anything with tmin <= t <= tmax (it stops at its first hit).

        Same arguments as ``closest``. Returns ``Occlusion``."""
        traced = self._trace(
            ANY_HIT, origins, directions, tmin, tmax, cull, mask, strategy, threads
        )
        return Occlusion(traced.arrays.best_tri != NO_HIT, traced.counters if stats else None)

    def hits(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        tmin: ArrayLike | float | None = None,
        tmax: ArrayLike | float | None = None,
        *,
        max_hits: int = 16,
        cull: Cull = "none",
        mask: ArrayLike | int | None = None,
        strategy: Strategy = "sampling",
        threads: int | None = None,
        stats: bool = False,
    ) -> HitList:
        """Every hit of each ray with tmin <= t <= tmax, nearest first, at most ``max_hits``.

        Same arguments as ``closest``, and max_hits (a positive int). A ray through an edge or
        vertex shared by two triangles crosses one of them, not both (``count``). Returns
        ``HitList``: ray i's hits are rows offsets[i]:offsets[i + 1], sorted by (t, mesh, prim);
        truncated[i] where it had more than max_hits, of which the nearest are kept."""
        max_hits = check_max_hits(max_hits)
        # One entry beyond max_hits tells a truncated list from a full one; a ray has no more
        # hits than the scene has triangles.
        list_size = min(max_hits, len(self._tri_verts)) + 1
        traced = self._trace(
            ALL_HITS, origins, directions, tmin, tmax, cull, mask, strategy, threads, list_size
        )
        answer = traced.arrays
        n_held = answer.n_hits
        n_rays = len(n_held)
        offsets = np.zeros(n_rays + 1, np.int64)
        np.cumsum(np.minimum(n_held, max_hits), out=offsets[1:])
        n = int(offsets[-1])
        t = np.empty(n, FLOAT)
        mesh = np.empty(n, INDEX)
        prim = np.empty(n, INDEX)
        u = np.empty(n, FLOAT)
        v = np.empty(n, FLOAT)
        normal = np.empty((n, 3), FLOAT)
        normals = self._unit_normals if n >= self.n_triangles else self._no_normals
        finish_hits(
            answer.list_t,
            answer.list_tri,
            offsets,
            traced.origins,
            traced.directions,
            self._tri_global,
            self.mesh_offsets,
            self._tri_verts,
            normals,
            t,
            mesh,
            prim,
            u,
            v,
            normal,
        )
        truncated = n_held > max_hits
        counters = traced.counters if stats else None
        return HitList(offsets, t, mesh, prim, u, v, normal, truncated, counters)

    def count(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        tmin: ArrayLike | float | None = None,
        tmax: ArrayLike | float | None = None,
        *,
        cull: Cull = "none",
        mask: ArrayLike | int | None = None,
        strategy: Strategy = "sampling",
        threads: int | None = None,
        stats: bool = False,
    ) -> Counts:
        """How many triangles each ray crosses with tmin <= t <= tmax.

        Same arguments as ``closest``. A crossing through an edge or vertex shared by several
        triangles counts once (``geometry.crossing``): from outside a closed mesh a ray counts an
        even number, from inside an odd one. Returns ``Counts``."""
        traced = self._trace(COUNT, origins, directions, tmin, tmax, cull, mask, strategy, threads)
        return Counts(traced.arrays.n_hits, traced.counters if stats else None)

    def nearest(
        self,
        points: ArrayLike,
        max_distance: float | None = None,
        *,
        mask: ArrayLike | int | None = None,
        threads: int | None = None,
        stats: bool = False,
    ) -> Nearest:
        """The closest point on any triangle to each of ``points``.

        points : (n, 3) float (converted to float32)
        max_distance : None (no limit) or a number >= 0: a point farther from every triangle
            gets none (distance inf, prim -1)
        mask, threads : as for ``closest``; every thread count gives the same answers
        Returns ``Nearest``; the distance is exact in float64, then rounded to float32, and ties
        go to the lowest (mesh, triangle)."""
        return point_queries.nearest_query(self, points, max_distance, mask, threads, stats)

    def contains(
        self,
        points: ArrayLike,
        nsamples: int = 1,
        *,
        mask: ArrayLike | int | None = None,
        threads: int | None = None,
    ) -> np.ndarray:
        """(n,) bool: whether each point is inside, by the parity of the crossings (``count``,
        exact at edges and vertices) of rays from it along ``nsamples`` (odd) fixed directions
        (``dacrt.points.sample_directions``), the majority of them. A point on the surface may
        go either way."""
        return point_queries.contains_query(self, points, nsamples, mask, threads)

    def signed_distance(
        self,
        points: ArrayLike,
        nsamples: int = 1,
        max_distance: float | None = None,
        *,
        mask: ArrayLike | int | None = None,
        threads: int | None = None,
    ) -> np.ndarray:
        """(n,) float32: ``nearest``'s distance, negative where ``contains``; 0 on a triangle,
        +-inf beyond max_distance."""
        return point_queries.signed_distance_query(
            self, points, nsamples, max_distance, mask, threads
        )

    def _scene_triangles(self) -> point_queries.SceneTriangles:
        """The scene-space triangles, for the point queries: the one place they read the
        scene's internals."""
        return point_queries.SceneTriangles(
            self._tri_verts, self._tri_global, self.mesh_offsets, self._row_masks
        )

    def _visible_rows(self, ray_masks):
        """How a batch's masks are traced: (flags, tri_ids, tri_masks). A batch whose rays
        share one mask (or carry none) sees a fixed set of meshes: tri_ids (int32) holds their
        kernel rows, or is None for every row, and the kernels check no mask. Otherwise the
        MASKED flag and every row's mesh mask (``_row_masks``)."""
        uniform = ray_masks is None or not len(ray_masks) or (ray_masks == ray_masks[0]).all()
        if not uniform:
            return MASKED, None, self._row_masks
        ray_mask = ALL_MASKS if ray_masks is None or not len(ray_masks) else ray_masks[0]
        seen = (self.masks & ray_mask) != 0
        if seen.all():
            return 0, None, self._no_masks
        return 0, np.flatnonzero(self._row_masks & ray_mask).astype(INDEX), self._no_masks

    def _trace(
        self, flags, origins, directions, tmin, tmax, cull, mask, strategy, threads, list_size=0
    ):
        """Run the kernels with ``flags`` (``dacrt.query``) and the query's options; returns
        ``Traced``. ``list_size`` is the length of each ray's list of hits (ALL_HITS)."""
        strategy = check_strategy(strategy)
        threads = check_threads(threads, N_CORES)
        flags |= CULL_FLAGS[check_cull(cull)]
        origins, directions, tmin, tmax = check_rays(origins, directions, tmin, tmax)
        n_rays = len(origins)
        ray_masks = None if mask is None else check_masks(mask, n_rays, "mask", "ray")
        mask_flags, visible_rows, tri_masks = self._visible_rows(ray_masks)
        flags |= mask_flags
        best_t = tmax.copy()  # the records' best_t, scattered back after the trace
        lists = (n_rays, list_size) if flags & ALL_HITS else (0, 0)
        answer = QueryArrays(
            best_tri=np.full(n_rays, NO_HIT, INDEX),
            hit_u=np.zeros(n_rays, FLOAT),
            hit_v=np.zeros(n_rays, FLOAT),
            ray_masks=ray_masks if mask_flags else self._no_masks,
            tri_masks=tri_masks,
            n_hits=np.zeros(n_rays if flags & COLLECT else 0, INDEX),
            list_t=np.empty(lists, FLOAT),
            list_tri=np.empty(lists, INDEX),
            hit_mask=None,
            tri_bins=None,
            stats=None,
        )
        counters = dict.fromkeys(STAT_NAMES, 0)
        counters["rays"] = n_rays
        counters["triangles"] = self.n_triangles
        n_live = len(self._tri_verts) if visible_rows is None else len(visible_rows)
        if n_rays == 0 or n_live == 0:
            explain_bad_rays(origins, directions, tmin, tmax)  # no kernel will check them
            return Traced(best_t, answer, counters, origins, directions)
        code = STRATEGY_CODES[strategy]
        flags |= code << STRATEGY_SHIFT
        ray_space = code == RAYSPACE
        if not ray_space and not flags & COLLECT and splits_triangles(n_rays, n_live, threads):
            per_half = self._trace_halves(
                flags, origins, directions, tmin, tmax, visible_rows, answer, best_t
            )
            return Traced(best_t, answer, add_counters(counters, per_half), origins, directions)
        # The values are not checked yet (each chunk checks its own): a bad ray may make
        # the choice of chunks poor, never wrong.
        with np.errstate(invalid="ignore", over="ignore"):
            coherent = from_one_point(origins, self._box)
            n_chunks = count_chunks(n_rays, n_live, threads, coherent)
            # rayspace splits the rays by origin and direction itself: it keeps the input order.
            plan = plan_chunks(
                origins, n_chunks, coherent or ray_space, self._box, lambda: self._centre_counts
            )

        def run(chunk):
            ray_ids = chunk_ids(plan, n_rays, n_chunks, chunk)
            rays = new_records(len(ray_ids))
            if not pack_rays(origins, directions, tmin, tmax, ray_ids, rays):
                return None  # a bad ray: no kernel traces this chunk
            chunk_flags = flags | (FIXED_ORIGIN if uniform_origin(rays, len(ray_ids)) else 0)
            tri_ids = (
                np.arange(n_live, dtype=INDEX) if visible_rows is None else visible_rows.copy()
            )
            tris = Triangles(self._tri_verts, self._tri_bounds, tri_ids)
            chunk_stats = np.zeros(len(STAT_NAMES), np.int64)
            arrays = answer._replace(
                hit_mask=np.empty(len(ray_ids), np.bool_),
                tri_bins=np.empty(n_live, np.uint8),
                stats=chunk_stats,
            )
            if ray_space:
                trace_ray_space(chunk_flags, tris, self._box, rays, ray_ids, arrays)
            else:
                trace_object_split(
                    chunk_flags, tris, self._box, rays, ray_ids, 0, len(ray_ids), 0, n_live, arrays
                )
            unpack_best_t(rays, ray_ids, best_t)
            return chunk_stats

        per_chunk = map_on_threads(run, n_chunks, min(threads, n_chunks))
        if any(chunk_stats is None for chunk_stats in per_chunk):
            explain_bad_rays(origins, directions, tmin, tmax)
            raise InputError("the batch holds an invalid ray")  # explain_bad_rays names it
        return Traced(best_t, answer, add_counters(counters, per_chunk), origins, directions)

    def _trace_halves(self, flags, origins, directions, tmin, tmax, visible_rows, answer, best_t):
        """Trace a closest or occlusion batch on two threads, each with every ray against one
        half of the triangles (split at the middle of the scene's box); then each ray keeps the
        better of its two answers, the smaller (t, row), as one trace would. Writes best_t and
        ``answer``'s best_tri, hit_u and hit_v; returns each half's stats."""
        n_rays = len(origins)
        tri_ids = (
            np.arange(len(self._tri_verts), dtype=INDEX)
            if visible_rows is None
            else visible_rows.copy()
        )
        tris = Triangles(self._tri_verts, self._tri_bounds, tri_ids)
        boxes = np.empty((3, 6), FLOAT)  # the halves' boxes, and scratch for split_middle
        _, tri_mid = split_middle(tris, 0, len(tri_ids), self._box, boxes)
        rays = new_records(n_rays)
        ray_ids = np.arange(n_rays, dtype=INDEX)
        if not pack_rays(origins, directions, tmin, tmax, ray_ids, rays):
            explain_bad_rays(origins, directions, tmin, tmax)
            raise InputError("the batch holds an invalid ray")  # explain_bad_rays names it
        if uniform_origin(rays, n_rays):
            flags |= FIXED_ORIGIN
        records = (rays, rays.copy())  # each half permutes its own

        def run(half):
            half_rays = records[half]
            half_ids = ray_ids.copy()
            arrays = answer._replace(
                best_tri=answer.best_tri if half == 0 else np.full(n_rays, NO_HIT, INDEX),
                hit_u=answer.hit_u if half == 0 else np.zeros(n_rays, FLOAT),
                hit_v=answer.hit_v if half == 0 else np.zeros(n_rays, FLOAT),
                hit_mask=np.empty(n_rays, np.bool_),
                tri_bins=np.empty(len(tri_ids), np.uint8),
                stats=np.zeros(len(STAT_NAMES), np.int64),
            )
            lo, hi = (0, tri_mid) if half == 0 else (tri_mid, len(tri_ids))
            trace_object_split(
                flags, tris, boxes[half], half_rays, half_ids, 0, n_rays, lo, hi, arrays
            )
            t = np.empty(n_rays, FLOAT)
            unpack_best_t(half_rays, half_ids, t)
            return t, arrays

        (t0, first), (t1, second) = map_on_threads(run, 2, 2)
        # Where the second half's (t, row) is smaller, it is the answer.
        take = (t1 < t0) | ((t1 == t0) & (second.best_tri < first.best_tri))
        best_t[:] = np.where(take, t1, t0)
        for name in ("best_tri", "hit_u", "hit_v"):
            np.copyto(getattr(answer, name), getattr(second, name), where=take)
        return [first.stats, second.stats]


def add_counters(counters, per_chunk):
    """``counters`` with the sums of the kernels' stats arrays (the deepest node's depth for
    max_depth), one per chunk of the batch."""
    totals = np.sum(per_chunk, axis=0)
    for i, name in enumerate(STAT_NAMES):
        if i not in (STAT_RAYS, STAT_TRIANGLES):
            counters[name] = int(totals[i])
    counters["max_depth"] = int(max(c[STAT_NAMES.index("max_depth")] for c in per_chunk))
    return counters
