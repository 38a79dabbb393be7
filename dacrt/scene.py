"""The public query surface: ``Scene`` and its queries ``closest``, ``occluded``, ``hits`` and
``count``; the point queries ``nearest``, ``contains`` and ``signed_distance`` are ``points``'.

This is the only module that checks and converts input. A Scene keeps its triangles packed for
the kernels (``packed``: gathered corners and boxes, O(F) and cheap to make): its untransformed
meshes as one base level, each placed mesh once in its own space, traced as instances
(``instances``); its first point query derives what point queries read (the triangles placed
in scene space, their boxes and Morton order: ``points``). Every query partitions rays (or
points) and triangles from scratch and keeps nothing afterwards. ``Scene.with_changes`` makes a
new version that shares every unchanged mesh's packed arrays. How a batch is cut into chunks and
spread over threads is ``chunks``.
"""

import functools
import threading
from collections import namedtuple
from collections.abc import Iterable, Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from . import points as point_queries
from .chunks import (
    MIN_RAYS_PER_THREAD,
    N_CORES,
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
    MISS,
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
from .deforming import corners_at_times
from .instances import (
    box_corners,
    fill_rays_reaching,
    group_boxes,
    mark_rays_reaching,
    merge_closest,
    merge_hit_lists,
    origins_near_box,
    placed_instances,
    placed_normals,
    placed_points,
    rays_to_mesh_space,
    rays_to_mesh_space_at,
)
from .leaf import NO_HIT
from .packed import (
    ORDERS,
    Packed,
    as_given,
    centred,
    every_face,
    live_box,
    pack_deforming,
    pack_mesh,
    pack_meshes,
    pack_placed_mesh,
    union_box,
)
from .query import (
    ALL_HITS,
    ALL_MASKS,
    ANY_HIT,
    COLLECT,
    COUNT,
    CULL_BACK,
    CULL_FLAGS,
    CULL_FRONT,
    FIXED_ORIGIN,
    MASKED,
    STRATEGY_SHIFT,
    QueryArrays,
)
from .ranges import NO_TREE, node_rows, range_tree
from .rays import new_records, pack_rays, uniform_origin, unpack_best_t
from .rayspace import trace_ray_space
from .results import finish_closest, finish_hits, unit_normals
from .traversal import split_middle, trace_object_split
from .triangles import Triangles
from .validation import (
    InputError,
    MeshSpaceError,
    as_float_rows,
    check_cull,
    check_hits,
    check_int_rows,
    check_masks,
    check_max_hits,
    check_mesh,
    check_rays,
    check_row_count,
    check_strategy,
    check_threads,
    check_time,
    check_transforms,
    check_unplaced,
    check_vertices_end,
    explain_bad_rays,
    finite_vertices,
    float64_points,
    hide_rays,
    mesh_pairs,
    place_vertices,
    vertex_array,
)

#: The values of ``cull=`` and ``strategy=`` (``CULL_MODES``, ``STRATEGIES``).
Cull = Literal["none", "back", "front"]
Strategy = Literal["sampling", "sah", "middle", "rayspace"]
Device = Literal["cpu", "cuda"]
DEVICES = ("cpu", "cuda")

HitTriangles = namedtuple("HitTriangles", ["verts", "ids"])
HitTriangles.__doc__ = """One row a hit, for ``Scene._finish_hits``: (k, 9) float32 corners (a
deforming triangle's at its ray's time) and (k,) int32 global triangle ids."""

Traced = namedtuple("Traced", ["best_t", "arrays", "stats"])
Traced.__doc__ = """What the kernels leave of one level's trace: each ray's best_t, the
``QueryArrays`` (without scratch), and the stats arrays of its chunks (a list)."""

Query = namedtuple(
    "Query",
    ["flags", "origins", "directions", "tmin", "tmax", "ray_masks", "threads", "times", "tracer"],
)
Query.__doc__ = """A checked query: its flags word (kind, culling, strategy), float32 origins,
directions, tmin and tmax, its (n,) uint32 ray masks or None, its thread count, its rays'
times (n,) float32, or None where every ray is at 0 or nothing in the scene moves, and what
traces each of its levels (``Scene._trace_level``, or the GPU's ``dacrt.cuda.level_tracer``)."""


InstanceTraced = namedtuple(
    "InstanceTraced", ["best_t", "arrays", "stats", "origins", "directions", "cofactors"]
)
InstanceTraced.__doc__ = """``Traced`` of an instance, with the rays it traced in mesh space:
(k, 3) float32 origins and directions, and the placement's cofactor (the normals' map) per ray
(k, 3, 3), or (1, 3, 3) for all."""

#: The start placement of a mesh given an end placement and none at the start.
IDENTITY = np.eye(4)
#: Rows placed at a time for the point queries (``_placed_triangles``): their float64 corners
#: take about 1.2 MB.
PLACING_BLOCK_ROWS = 16384

BaseRows = namedtuple("BaseRows", ["lo", "hi", "box", "corner_box"])
BaseRows.__doc__ = """Where an untransformed mesh lies in the scene's base level: rows lo:hi,
their box, and the box of its corners (``Packed``)."""


class Scene:
    """Triangle meshes to cast rays into.

    meshes : sequence of (vertices (V, 3) float, faces (F, 3) int) pairs; hits report a mesh by
        its position in this sequence and a triangle by its row in that mesh's faces. The
        scene keeps copies of them (and of ``vertices_end``): the caller may reuse its buffers.
    masks : None (every mesh all ones), an integer, or (n_meshes,) uint32: each mesh's mask; a
        ray sees a mesh only where ray mask & mesh mask != 0 (``mask=`` of the queries).
    transforms : None, or one entry per mesh: None (as given) or a (4, 4) row-major affine
        matrix that places the mesh, each vertex p at M[:3, :3] @ p + M[:3, 3]. Answers are in
        scene space: t, u, v along the caller's ray, normals of the placed triangles (the
        inverse transpose of M's linear part, times its determinant's sign, applied to the
        mesh's (p1-p0)x(p2-p0), normalised); prim stays the row of the mesh's own faces. The
        same (vertices, faces) arrays may be given several times, each with its own matrix and
        mask: instances, which share one packing of the mesh.
    order : how each mesh's triangles are stored for the kernels, which never changes an
        answer: "auto" (default) along a Morton curve of their centres when the faces come in
        an incoherent order (shuffled, or as some scanners write them), else as given;
        "morton" always (worth its packing, about 60 ns a triangle, for a scene kept for many
        queries or versions: ``with_changes``); "file" as given.

    transforms_end : None, or one entry per mesh: None (static) or a (4, 4) affine matrix, the
        mesh's placement at the end of the frame's interval (a mesh with an end and no start
        transform is placed by the identity at the start). At time tau in [0, 1] (``time=`` of
        the queries) each vertex is at (1 - tau) p0 + tau p1, its placed positions at 0 and 1:
        the mesh is placed by (1 - tau) M0 + tau M1 (Embree's linear motion). Point queries
        (``nearest``, ...) see the meshes at time 0.

    A placed mesh is an instance, traced in its own space: the rays that reach it go into mesh
    space (rounded to float32; relative to the mesh's box centre where the mesh lies far from
    its own origin), rather than its vertices into scene space. Its answers are therefore those
    of the mesh placed in float64 and rounded to float32 up to that rounding, which grows with
    the condition number of M's 3x3 part: up to about 10, the same hits and misses but for rays
    within a few ulps of a triangle's edges or silhouette, t within a few ulps and normals within
    about 1e-6 (docs/engine.md, "How answers differ from placed copies", has the measured
    figures). Each instance is watertight on its own.
    """

    def __init__(
        self,
        meshes: Iterable[tuple[ArrayLike, ArrayLike]],
        masks: ArrayLike | int | None = None,
        transforms: Sequence[ArrayLike | None] | None = None,
        order: str = "auto",
        transforms_end: Sequence[ArrayLike | None] | None = None,
        vertices_end: Sequence[ArrayLike | None] | None = None,
    ) -> None:
        watch()  # the first compile in process says so (``compiling``)
        given, args = check_scene_arguments(
            meshes, masks, transforms, order, transforms_end, vertices_end
        )
        self._order = args.order
        matrices, ends = args.transforms, args.transforms_end
        # Instances of the same (vertices, faces) arrays share one packing.
        packings = {}
        packs = {}
        for i, (vertices, faces) in enumerate(given):
            if matrices[i] is not None or ends[i] is not None:
                key = (id(vertices), id(faces))
                if key not in packings:
                    packings[key] = pack_placed_mesh(*args.meshes[i], self._order)
                packs[i] = packings[key]
        deformed = {i: end for i, end in enumerate(args.vertices_end) if end is not None}
        self._assemble(args.meshes, args.masks.copy(), matrices, ends, deformed, packs, None, set())

    def _assemble(self, checked, masks, matrices, ends, deformed, packs, old, changed):
        """Set up the scene from its checked meshes, masks (n,) uint32, matrices and ends (None
        or (4, 4) float64 each: placements at the start and end of the interval), ``deformed``
        (mesh index: its checked vertices at the end of the interval, for each deforming mesh)
        and ``packs`` (mesh index: ``Packed`` of each placed mesh, one with a start or an end).
        With ``old``, a scene of the same faces: its base level is shared when no untransformed
        mesh changed (``changed``: the meshes given new vertices or vertices_end), else its rows
        are copied for those that did not; so is its deforming level."""
        self.n_meshes = len(checked)
        self._meshes = checked
        self._matrices = matrices
        self._ends = ends
        self._vertices_end = deformed
        self.masks = masks
        self.masks.flags.writeable = False  # _row_masks is derived from it once
        self._points_lock = threading.Lock()
        self._point_triangles = None  # what point queries read, derived on the first
        if old is None:
            counts = [len(faces) for _, faces in checked]
            # writable for the kernels (a read-only array is another type to compile them for)
            self._mesh_offsets = np.zeros(self.n_meshes + 1, np.int64)
            self._mesh_offsets[1:] = np.cumsum(counts)
            # every version of the scene shares them: callers get a read-only view
            self.mesh_offsets = self._mesh_offsets.view()
            self.mesh_offsets.flags.writeable = False
        else:
            self._mesh_offsets, self.mesh_offsets = old._mesh_offsets, old.mesh_offsets
        self.n_triangles = int(self.mesh_offsets[-1])
        base_meshes = [i for i in range(self.n_meshes) if i not in packs and i not in deformed]
        self._base_meshes = np.array(base_meshes, np.int64)
        self._assemble_deforming(old, changed)
        if (
            old is not None
            and list(old._base_meshes) == base_meshes
            and not changed & set(base_meshes)
        ):
            self._base = old._base
            self._parts = {i: old._parts[i] for i in base_meshes}
            if "_row_masks" in old.__dict__ and np.array_equal(
                old.masks[self._base_meshes], masks[self._base_meshes]
            ):  # each base row's mesh mask, as the old scene derived it
                self.__dict__["_row_masks"] = old.__dict__["_row_masks"]
        else:
            self._base, self._parts = self._pack_base(base_meshes, old, changed)
        placed = sorted(packs)
        starts = [IDENTITY if matrices[i] is None else matrices[i] for i in placed]
        check_placements(
            [
                (i, packs[i], matrix, name)
                for i, start in zip(placed, starts)
                for matrix, name in ((start, "transforms"), (ends[i], "transforms_end"))
                if matrix is not None
            ]
        )
        self._parts.update(packs)
        instance_of = {}
        for i in placed:
            kept = old is not None and i in old._instance_of and old._parts[i] is packs[i]
            if (
                kept
                and _same_matrix(old._matrices[i], matrices[i])
                and _same_matrix(old._ends[i], ends[i])
            ):
                instance_of[i] = old._instance_of[i]
        new = [k for k, i in enumerate(placed) if i not in instance_of and len(packs[placed[k]])]
        for instance in placed_instances(
            [placed[k] for k in new],
            [packs[placed[k]] for k in new],
            [starts[k] for k in new],
            [ends[placed[k]] for k in new],
        ):
            instance_of[instance.mesh] = instance
        instances = [instance_of[i] for i in placed if i in instance_of]
        self._instances = instances
        self._instance_of = {instance.mesh: instance for instance in instances}
        # Only a scene with a moving instance or a deforming mesh reads the rays' times.
        self._moving = self._deforming is not None or any(i.moving for i in instances)

    def _assemble_deforming(self, old, changed):
        """The deforming level (``DeformingPacked``, ids global) of the meshes with vertices at
        the end, or None for none: ``old``'s when it has the same deforming meshes and none of
        them is in ``changed``."""
        meshes = sorted(self._vertices_end)
        self._deforming_meshes = np.array(meshes, np.int64)
        if not meshes:
            self._deforming = None
            self._deforming_corner_boxes = np.empty((0, 6), FLOAT)
            return
        if old is not None and list(old._deforming_meshes) == meshes and not changed & set(meshes):
            self._deforming = old._deforming
            self._deforming_corner_boxes = old._deforming_corner_boxes
            return
        self._deforming, self._deforming_corner_boxes = pack_deforming(
            [(self._meshes[i][0], self._vertices_end[i], self._meshes[i][1]) for i in meshes],
            [self.mesh_offsets[i] for i in meshes],
        )

    def _pack_base(self, base_meshes, old, changed):
        """The base level (``Packed``, ids global) of the untransformed ``base_meshes``, and
        each one's ``BaseRows``: packed afresh, or from ``old``'s packed arrays for the meshes
        not in ``changed`` (rows copied, in mesh order, so rows still rise with ids)."""
        first_rows = [self.mesh_offsets[i] for i in base_meshes]
        if old is None:
            packed, live, boxes, corner_boxes = pack_meshes(
                [self._meshes[i] for i in base_meshes], first_rows, self._order
            )
            parts = {
                i: BaseRows(live[k], live[k + 1], boxes[k], corner_boxes[k])
                for k, i in enumerate(base_meshes)
            }
            return packed, parts
        pieces = []
        for i, first_row in zip(base_meshes, first_rows):
            part = old._parts.get(i)  # none for a mesh that deformed in ``old``
            if i in changed:
                piece = pack_mesh(*self._meshes[i], *old._kept_order(i))
                pieces.append(
                    (
                        piece.verts,
                        piece.bounds,
                        piece.ids + INDEX(first_row),
                        piece.box,
                        piece.corner_box,
                    )
                )
            elif isinstance(part, Packed):  # placed before, as given now
                part = as_given(part)
                pieces.append(
                    (
                        part.verts,
                        part.bounds,
                        part.ids + INDEX(first_row),
                        part.box,
                        part.corner_box,
                    )
                )
            else:
                rows = slice(part.lo, part.hi)
                base = old._base
                pieces.append(
                    (base.verts[rows], base.bounds[rows], base.ids[rows], part.box, part.corner_box)
                )
        lengths = [len(piece[0]) for piece in pieces]
        live = np.zeros(len(pieces) + 1, np.int64)
        np.cumsum(lengths, out=live[1:])
        parts = {
            i: BaseRows(live[k], live[k + 1], piece[3], piece[4])
            for k, (i, piece) in enumerate(zip(base_meshes, pieces))
        }
        packed = Packed(
            _joined([p[0] for p in pieces], np.empty((0, 9), FLOAT)),
            _joined([p[1] for p in pieces], np.empty((0, 6), FLOAT)),
            _joined([p[2] for p in pieces], np.empty(0, INDEX)).astype(INDEX, copy=False),
            live_box(union_box([p[3] for p in pieces])),
            union_box([p[4] for p in pieces]),
        )
        return packed, parts

    def with_changes(
        self,
        transforms: dict[int, ArrayLike | None] | None = None,
        vertices: dict[int, ArrayLike] | None = None,
        masks: dict[int, int] | None = None,
        transforms_end: dict[int, ArrayLike | None] | None = None,
        vertices_end: dict[int, ArrayLike | None] | None = None,
    ) -> "Scene":
        """A new Scene: this one with some meshes moved, deformed or masked; this one is left
        as it is, and keeps answering as before.

        transforms : {mesh index: (4, 4) affine matrix, or None for as given}
        vertices : {mesh index: (V, 3) float}, the mesh's new vertices (as many as before; its
            faces stay)
        masks : {mesh index: mask}, an integer in [0, 2**32)
        transforms_end : {mesh index: (4, 4) affine matrix, its placement at the end of the
            interval, or None for static}; a mesh not named keeps its end (``Scene``)
        vertices_end : {mesh index: (V, 3) float, the mesh's vertices at the end of the
            interval, or None for static}; a mesh not named keeps its end, also when given new
            ``vertices`` (``Scene``)
        Every other mesh keeps its packed arrays, shared with this scene: a placed mesh costs
        nothing to move, and a deformed one is packed again alone. A change to the meshes as
        given (the base level: new vertices, or a mesh placed or put back as given) copies the
        base level's arrays once (about 64 bytes a triangle of those meshes). Answers are those
        of a new Scene of the same meshes, bit for bit. Raises InputError naming the argument
        (``vertices[3]``, ...) and changes nothing."""
        transforms = self._by_mesh(transforms, "transforms")
        vertices = self._by_mesh(vertices, "vertices")
        masks = self._by_mesh(masks, "masks")
        transforms_end = self._by_mesh(transforms_end, "transforms_end")
        vertices_end = self._by_mesh(vertices_end, "vertices_end")
        matrices = list(self._matrices)
        given = changed_transforms(transforms, "transforms")
        for i in transforms:
            matrices[i] = given.get(i)  # None: as given
        ends = list(self._ends)
        given = changed_transforms(transforms_end, "transforms_end")
        for i in transforms_end:
            ends[i] = given.get(i)  # None: static
        checked = list(self._meshes)
        copies = {}  # one copy of an array given to several meshes (instances)
        for i, new in vertices.items():
            checked[i] = (self._checked_vertices(i, new, copies), checked[i][1])
        new_masks = self.masks.copy()
        for i, mask in masks.items():
            new_masks[i] = check_masks(mask, 1, f"masks[{i}]", "mesh")[0]
        deformed = dict(self._vertices_end)
        for i, end in vertices_end.items():
            deformed.pop(i, None)
            if end is not None:
                deformed[i] = end
        for i in sorted(deformed):
            if i in vertices_end:
                deformed[i] = check_vertices_end(
                    i, deformed[i], checked[i][0], matrices[i], ends[i]
                )
            elif i in transforms or i in transforms_end:  # a kept end: already checked
                check_unplaced(i, matrices[i], ends[i])
        # A mesh that starts or stops deforming, or deforms anew, is packed again.
        changed = set(vertices) | set(vertices_end)
        packings = {}
        packs = {}
        for i, (matrix, end) in enumerate(zip(matrices, ends)):
            if matrix is None and end is None:
                continue
            if i not in changed and isinstance(self._parts[i], Packed):
                packs[i] = self._parts[i]
            elif i not in changed:  # as given before, placed now: its rows of the base level
                packs[i] = self._packed_from_base(i)
            else:
                part = self._parts.get(i)
                # Instances of one packing given the same new vertices share one packing again.
                shared = i in vertices and part is not None
                key = (id(vertices[i]), id(part)) if shared else ("mesh", i)
                if key not in packings:
                    packings[key] = pack_placed_mesh(*checked[i], *self._kept_order(i))
                packs[i] = packings[key]
        scene = object.__new__(Scene)
        scene._order = self._order
        scene._assemble(checked, new_masks, matrices, ends, deformed, packs, self, changed)
        return scene

    def _by_mesh(self, changes, name):
        """``changes`` (None or a dict keyed by mesh index) as a dict with int keys."""
        if changes is None:
            return {}
        if not isinstance(changes, dict):
            raise InputError(
                f"{name} must be a dict {{mesh index: value}}, got {type(changes).__name__}"
            )
        checked = {}
        for key, value in changes.items():
            if isinstance(key, bool) or not isinstance(key, int | np.integer):
                raise InputError(f"{name} has key {key!r}: keys must be mesh indices (integers)")
            if not 0 <= key < self.n_meshes:
                raise InputError(
                    f"{name}[{key}]: there is no mesh {key} (the scene has {self.n_meshes})"
                )
            checked[int(key)] = value
        return checked

    def _checked_vertices(self, i, new, copies):
        """Mesh i's new vertices as float32 (V, 3), V as before, finite, ``owned``: the entry
        of ``copies`` (id of the given array: its checked copy) for an array checked before."""
        name = f"vertices[{i}]"
        if id(new) in copies:
            checked = copies[id(new)]
        else:
            checked = as_float_rows(vertex_array(new, name), name, check_finite=False)
        n_before = len(self._meshes[i][0])
        if len(checked) != n_before:
            raise InputError(f"{name} has {len(checked)} rows; mesh {i} has {n_before} vertices")
        if id(new) not in copies:
            copies[id(new)] = finite_vertices(checked, new, name)
        return copies[id(new)]

    def _kept_order(self, i):
        """(order, kept order) for ``pack_mesh`` to pack new vertices of mesh i's faces in the
        order its rows are stored (a refit): "file" for rows in face order, else every face
        row in its rows' order (``packed.every_face``); the scene's order for a mesh of the
        deforming level, which has none."""
        if i not in self._parts:
            return self._order, None
        rows = self._face_rows(i)
        if np.all(rows[1:] > rows[:-1]):  # face order, perhaps without degenerate faces
            return "file", None
        return self._order, every_face(rows, len(self._meshes[i][1]))

    def _face_rows(self, i):
        """Mesh i's face rows in the order its rows are stored (its ``Packed``'s ids, or its
        rows of the base level less the mesh's offset)."""
        part = self._parts[i]
        if isinstance(part, Packed):
            return part.ids
        return self._base.ids[part.lo : part.hi] - INDEX(self.mesh_offsets[i])

    def _packed_from_base(self, i):
        """Mesh i's rows of the base level as a placed mesh's ``Packed`` of its own (ids its
        face rows, relative to its frame centre: ``centred``)."""
        part = self._parts[i]
        rows = slice(part.lo, part.hi)
        return centred(
            Packed(
                self._base.verts[rows].copy(),
                self._base.bounds[rows].copy(),
                self._face_rows(i),
                part.box if part.box[0] <= part.box[3] else np.zeros(6, FLOAT),
                part.corner_box,
            )
        )

    @functools.cached_property
    def bounds(self):
        """(2, 3) float32: the box of every corner the faces refer to (degenerate triangles
        included), placed meshes' corners placed in float64 then rounded (a moving mesh's at
        the start and at the end of the interval, a deforming mesh's at both too); zeros for no
        faces. Derived on first use, read-only (every later call answers this array)."""
        boxes = [self._parts[i].corner_box for i in self._base_meshes]
        boxes += list(self._deforming_corner_boxes)
        for i, (matrix, end) in enumerate(zip(self._matrices, self._ends)):
            if (matrix is None and end is None) or not len(self._meshes[i][1]):
                continue
            vertices, faces = self._meshes[i]
            used = vertices[np.unique(faces)]
            # A moving mesh's box at every instant: its placed corners at 0 and at 1.
            placements = [("transforms", IDENTITY if matrix is None else matrix)]
            placements += [] if end is None else [("transforms_end", end)]
            for name, placement in placements:
                corners = place_vertices(used, placement, f"{name}[{i}]")
                boxes.append(np.concatenate([corners.min(axis=0), corners.max(axis=0)]))
        bounds = union_box(boxes).reshape(2, 3) if self.n_triangles else np.zeros((2, 3), FLOAT)
        bounds.flags.writeable = False
        return bounds

    @property
    def _box(self):
        """The base level's box (6,) float32."""
        return self._base.box

    @property
    def nbytes(self) -> int:
        """Bytes held by the scene's packed arrays (each shared one once), with those derived
        on demand once they exist: the rows' masks, and what point queries read (the placed
        triangles beyond the base level's own, their boxes and order)."""
        held = {id(self._base): self._base}
        held.update((id(i.packed), i.packed) for i in self._instances)
        if self._deforming is not None:
            held[id(self._deforming)] = self._deforming
        arrays = {id(self.mesh_offsets): self.mesh_offsets}
        derived = self.__dict__.get("_row_masks")
        if derived is not None:
            arrays[id(derived)] = derived
        placed = self._point_triangles
        if placed is not None:  # those that are not the base level's own
            packed_arrays = {id(a) for a in (self._base.verts, self._base.ids, self._base.bounds)}
            arrays.update(
                (id(a), a)
                for a in (placed.verts, placed.global_ids, placed.row_masks, placed.bounds)
                + tuple(placed.seeds)
                if id(a) not in packed_arrays
            )
        return int(
            sum(packed.nbytes for packed in held.values()) + sum(a.nbytes for a in arrays.values())
        )

    @property
    def _centre_counts(self):
        """The base level's triangle centres per cell of the DENSITY_GRID grid (``Packed``)."""
        return self._base.centre_counts

    @functools.cached_property
    def _deforming_row_masks(self):
        """Each deforming row's mesh mask (``_row_masks`` of the deforming level)."""
        meshes = np.searchsorted(self.mesh_offsets, self._deforming.ids, side="right") - 1
        return np.ascontiguousarray(self.masks[meshes])

    @functools.cached_property
    def _row_masks(self):
        """Each base row's mesh mask (uint32, 4 bytes a triangle), for batches whose rays
        carry different masks: derived once per scene, on its first such query."""
        meshes = np.searchsorted(self.mesh_offsets, self._base.ids, side="right") - 1
        return np.ascontiguousarray(self.masks[meshes])

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
        time: ArrayLike | float | None = None,
        device: Device = "cpu",
    ) -> Hits:
        """Nearest hit of each ray ``origins + t * directions`` with tmin <= t <= tmax.

        origins, directions : (n, 3) float; directions need not be unit, t is in their units
        tmin, tmax : None, a number, or (n,) float (defaults 0 and +inf); a hit has
            tmin <= t <= tmax for the bounds as given (``validation.ray_window``)
        cull : "none", "back" (faces whose normal (p1-p0)x(p2-p0) points along the ray never
            hit) or "front" (faces whose normal points against it never hit)
        mask : None (all ones), an integer, or (n,) uint32: a ray sees a mesh only where its
            mask & the mesh's mask != 0
        strategy : one of ``dacrt.STRATEGIES``; all give the same answers
        threads : None for every core, or a positive int
        time : None (every ray at 0), a number, or (n,) float in [0, 1]: the instant of each
            ray in the frame's interval, where meshes move (``transforms_end``)
        device : "cpu", or "cuda" (``dacrt.cuda``: the same answers on an NVIDIA GPU; no
            deforming meshes or ``stats`` yet; strategy and threads do not apply)
        Returns ``Hits``; ties in t go to the lowest (mesh, triangle).
        """
        if check_device(device, stats, strategy, threads) == "cuda":
            from . import cuda

            return cuda.closest(
                self, origins, directions, tmin, tmax, cull=cull, mask=mask, time=time
            )
        return self._closest(
            origins, directions, tmin, tmax, cull, mask, strategy, threads, stats, time
        )

    def _closest(
        self, origins, directions, tmin, tmax, cull, mask, strategy, threads, stats, time,
        tracer=None,
    ):  # fmt: skip
        """``closest`` with its levels traced by ``tracer`` (None: ``_trace_level``)."""
        query, traced = self._trace(
            0, origins, directions, tmin, tmax, cull, mask, strategy, threads, time=time,
            tracer=tracer,
        )  # fmt: skip
        t = traced.best_t
        best_tri, u, v = traced.arrays.best_tri, traced.arrays.hit_u, traced.arrays.hit_v
        n = len(t)
        mesh = np.empty(n, INDEX)  # every element is written by finish_closest
        prim = np.empty(n, INDEX)
        normal = np.empty((n, 3), FLOAT)
        base = self._base
        # A batch with at least as many rays as triangles looks up each triangle's normal,
        # derived once per scene; a smaller one derives each hit's.
        normals = base.unit_normals if n >= self.n_triangles else self._no_normals
        # In place (t, u, v are the trace's own arrays), in as many parts as the trace had threads.
        n_parts = max(1, min(query.threads, n // MIN_RAYS_PER_THREAD))
        bounds = [k * n // n_parts for k in range(n_parts + 1)]

        def finish(k):
            part = slice(bounds[k], bounds[k + 1])
            finish_closest(
                t[part],
                best_tri[part],
                base.ids,
                self._mesh_offsets,
                base.verts,
                normals,
                mesh[part],
                prim[part],
                normal[part],
            )

        map_on_threads(finish, n_parts, n_parts)
        per_level = [traced.stats]
        if self._deforming is not None and n:
            found = self._trace_deforming(query, np.where(mesh != MISS, t, query.tmax))
            self._merge_deforming_closest(found, query, t, mesh, prim, u, v, normal)
            per_level.append(found.stats)
        if self._instances and n:
            # The base level's best t bounds each ray's segment into the instances.
            limit = np.where(mesh != MISS, t, query.tmax)
            for instance, ids, found in self._trace_instances(query, limit, 0):
                merge_closest(
                    ids,
                    found.best_t,
                    found.arrays.best_tri,
                    found.arrays.hit_u,
                    found.arrays.hit_v,
                    instance.packed.verts,
                    instance.packed.ids,
                    instance.mesh,
                    found.cofactors,
                    t,
                    mesh,
                    prim,
                    u,
                    v,
                    normal,
                    limit,
                )
                per_level.append(found.stats)
        return Hits(t, mesh, prim, u, v, normal, self._counters(n, per_level) if stats else None)

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
        time: ArrayLike | float | None = None,
        device: Device = "cpu",
    ) -> Occlusion:
        """Whether each ray hits anything with tmin <= t <= tmax (it stops at its first hit).

        Same arguments as ``closest``. Returns ``Occlusion``."""
        if check_device(device, stats, strategy, threads) == "cuda":
            from . import cuda

            return cuda.occluded(
                self, origins, directions, tmin, tmax, cull=cull, mask=mask, time=time
            )
        return self._occluded(
            origins, directions, tmin, tmax, cull, mask, strategy, threads, stats, time
        )

    def _occluded(
        self, origins, directions, tmin, tmax, cull, mask, strategy, threads, stats, time,
        tracer=None,
    ):  # fmt: skip
        """``occluded`` with its levels traced by ``tracer`` (None: ``_trace_level``)."""
        query, traced = self._trace(
            ANY_HIT, origins, directions, tmin, tmax, cull, mask, strategy, threads, time=time,
            tracer=tracer,
        )  # fmt: skip
        occluded = traced.arrays.best_tri != NO_HIT
        per_level = [traced.stats]
        open_rays = np.flatnonzero(~occluded) if self._deforming is not None else []
        if len(open_rays):
            found = self._trace_deforming(query, query.tmax[open_rays], open_rays)
            occluded[open_rays[found.arrays.best_tri != NO_HIT]] = True
            per_level.append(found.stats)
        if self._instances and len(occluded):
            # An occluded ray goes no further: -inf reaches no box.
            limit = np.where(occluded, -np.inf, query.tmax).astype(FLOAT)
            for _, ids, found in self._trace_instances(query, limit, ANY_HIT):
                blocked = ids[found.arrays.best_tri != NO_HIT]
                occluded[blocked] = True
                limit[blocked] = -np.inf
                per_level.append(found.stats)
        return Occlusion(occluded, self._counters(len(occluded), per_level) if stats else None)

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
        time: ArrayLike | float | None = None,
        device: Device = "cpu",
    ) -> HitList:
        """Every hit of each ray with tmin <= t <= tmax, nearest first, at most ``max_hits``.

        Same arguments as ``closest``, and max_hits (a positive int). A ray through an edge or
        vertex shared by two triangles crosses one of them, not both (``count``). Returns
        ``HitList``: ray i's hits are rows offsets[i]:offsets[i + 1], sorted by (t, mesh, prim);
        truncated[i] where it had more than max_hits, of which the nearest are kept.
        With device="cuda" each ray holds min(max_hits, triangles) + 1 8-byte keys in device
        memory: a batch needing over 2 GiB for them is traced in chunks of rays that fit."""
        if check_device(device, stats, strategy, threads) == "cuda":
            from . import cuda

            return cuda.hits(
                self, origins, directions, tmin, tmax, max_hits=max_hits, cull=cull, mask=mask,
                time=time,
            )  # fmt: skip
        return self._hits(
            origins, directions, tmin, tmax, max_hits, cull, mask, strategy, threads, stats, time
        )

    def _hits(
        self, origins, directions, tmin, tmax, max_hits, cull, mask, strategy, threads, stats,
        time, tracer=None,
    ):  # fmt: skip
        """``hits`` with its levels traced by ``tracer`` (None: ``_trace_level``)."""
        max_hits = check_max_hits(max_hits)
        # One entry beyond max_hits tells a truncated list from a full one; a ray has no more
        # hits than the level has triangles.
        list_size = min(max_hits, len(self._base)) + 1
        query, traced = self._trace(
            ALL_HITS, origins, directions, tmin, tmax, cull, mask, strategy, threads, list_size,
            time, tracer,
        )  # fmt: skip
        n_rays = len(query.origins)
        # With instances or deforming meshes, each level keeps its max_hits + 1 nearest, merged
        # below.
        levels = bool(self._instances) or self._deforming is not None
        kept = max_hits + 1 if levels else max_hits
        offsets, t, mesh, prim, u, v, normal = self._finish_hits(
            traced, query.origins, query.directions, self._base, self._mesh_offsets, kept
        )
        n_held = traced.arrays.n_hits
        truncated = n_held > max_hits
        per_level = [traced.stats]
        if levels and n_rays:
            parts = [(np.repeat(np.arange(n_rays), np.diff(offsets)), t, mesh, prim, u, v, normal)]
            if self._deforming is not None:
                deforming_hits, deforming_stats = self._deforming_hits(query, max_hits)
                parts.append(deforming_hits)
                per_level.append(deforming_stats)
            limit = np.require(query.tmax, FLOAT, ["C", "W"])
            for instance, ids, found in self._trace_instances(query, limit, ALL_HITS, max_hits):
                packed = instance.packed
                face_offsets = np.array([0, len(self._meshes[instance.mesh][1])], np.int64)
                i_offsets, i_t, _, i_prim, i_u, i_v, i_normal = self._finish_hits(
                    found, found.origins, found.directions, packed, face_offsets, max_hits + 1
                )
                # The placed normals, from the held kernel rows in the lists' order.
                n_held = found.arrays.n_hits
                rows = found.arrays.list_tri[
                    np.arange(found.arrays.list_tri.shape[1]) < n_held[:, None]
                ]
                cofactors = found.cofactors
                if len(cofactors) > 1:  # a moving instance's, one per ray: one per hit
                    cofactors = np.ascontiguousarray(
                        np.repeat(cofactors, np.diff(i_offsets), axis=0)
                    )
                placed_normals(packed.verts, rows, cofactors, i_normal)
                i_rays = np.repeat(ids.astype(np.int64), np.diff(i_offsets))
                i_mesh = np.full(len(i_t), instance.mesh, INDEX)
                parts.append((i_rays, i_t, i_mesh, i_prim, i_u, i_v, i_normal))
                per_level.append(found.stats)
            offsets, t, mesh, prim, u, v, normal, truncated = merge_hit_lists(
                n_rays, parts, max_hits
            )
        counters = self._counters(n_rays, per_level) if stats else None
        return HitList(offsets, t, mesh, prim, u, v, normal, truncated, counters)

    def _finish_hits(self, traced, origins, directions, level, mesh_offsets, kept):
        """A level's lists as CSR arrays (offsets, t, mesh, prim, u, v, normal), at most
        ``kept`` a ray (``results.finish_hits``, with ``origins`` and ``directions`` in the
        level's space)."""
        answer = traced.arrays
        n_rays = len(answer.n_hits)
        offsets = np.zeros(n_rays + 1, np.int64)
        np.cumsum(np.minimum(answer.n_hits, kept), out=offsets[1:])
        n = int(offsets[-1])
        t = np.empty(n, FLOAT)
        mesh = np.empty(n, INDEX)
        prim = np.empty(n, INDEX)
        u = np.empty(n, FLOAT)
        v = np.empty(n, FLOAT)
        normal = np.empty((n, 3), FLOAT)
        # An instance's normals are placed afterwards (``placed_normals``): none looked up here.
        looked_up = level is self._base and n >= self.n_triangles
        normals = level.unit_normals if looked_up else self._no_normals
        finish_hits(
            answer.list_t,
            answer.list_tri,
            offsets,
            origins,
            directions,
            level.ids,
            mesh_offsets,
            level.verts,
            normals,
            t,
            mesh,
            prim,
            u,
            v,
            normal,
        )
        return offsets, t, mesh, prim, u, v, normal

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
        time: ArrayLike | float | None = None,
        device: Device = "cpu",
    ) -> Counts:
        """How many triangles each ray crosses with tmin <= t <= tmax.

        Same arguments as ``closest``. A crossing through an edge or vertex shared by several
        triangles counts once (``geometry.crossing``): from outside a closed mesh a ray counts an
        even number, from inside an odd one. Returns ``Counts``."""
        if check_device(device, stats, strategy, threads) == "cuda":
            from . import cuda

            return cuda.count(
                self, origins, directions, tmin, tmax, cull=cull, mask=mask, time=time
            )
        return self._count(
            origins, directions, tmin, tmax, cull, mask, strategy, threads, stats, time
        )

    def _count(
        self, origins, directions, tmin, tmax, cull, mask, strategy, threads, stats, time,
        tracer=None, from_box=False,
    ):  # fmt: skip
        """``count`` with its levels traced by ``tracer`` (None: ``_trace_level``); with
        ``from_box`` (the inside test: tmin 0, no tmax) a ray that would leave float32 in a
        placed mesh's space starts there before that mesh's box (``_trace_instances``)."""
        query, traced = self._trace(
            COUNT, origins, directions, tmin, tmax, cull, mask, strategy, threads, time=time,
            tracer=tracer,
        )  # fmt: skip
        counts = traced.arrays.n_hits
        per_level = [traced.stats]
        if self._deforming is not None and len(counts):
            found = self._trace_deforming(query, query.tmax)
            counts += found.arrays.n_hits
            per_level.append(found.stats)
        if self._instances and len(counts):
            limit = np.require(query.tmax, FLOAT, ["C", "W"])
            for _, ids, found in self._trace_instances(query, limit, COUNT, from_box=from_box):
                counts[ids] += found.arrays.n_hits
                per_level.append(found.stats)
        return Counts(counts, self._counters(len(counts), per_level) if stats else None)

    def _inside_counts(self, origins, directions, mask, threads):
        """(n,) int32: the crossings of the inside test's rays (``contains``), as ``count``
        counts them from t = 0; a ray that would leave float32 in a placed mesh's space (a
        point far from a mesh placed small) starts there before that mesh's box."""
        counts = self._count(
            origins, directions, None, None, "none", mask, "sampling", threads, False, None,
            from_box=True,
        )  # fmt: skip
        return counts.count

    def _trace_deforming(self, query, tmax, rays=None, list_size=0):
        """Trace the deforming level with the query's kind and options: its rays ``rays`` (ids,
        None for all) with ``tmax`` (float32, one per traced ray), each at its time (0 where the
        query gives none). Returns ``Traced``, by the traced rays' order."""
        n_rays = len(query.origins)
        times = np.zeros(n_rays, FLOAT) if query.times is None else query.times
        origins, directions, tmin = query.origins, query.directions, query.tmin
        ray_masks = query.ray_masks
        if rays is not None:
            origins, directions, tmin, times = (a[rays] for a in (origins, directions, tmin, times))
            ray_masks = None if ray_masks is None else ray_masks[rays]
        mask_flags, visible_rows, tri_masks = self._visible_rows(ray_masks, deforming=True)
        return self._trace_level(
            self._deforming,
            query.flags | mask_flags,
            origins,
            directions,
            tmin,
            np.require(tmax, FLOAT, ["C", "W"]),
            ray_masks if mask_flags else self._no_masks,
            visible_rows,
            tri_masks,
            query.threads,
            list_size,
            np.require(times, FLOAT, ["C", "W"]),
        )

    def _hit_mesh_prim(self, ids):
        """(mesh, prim) int32 of global triangle ids."""
        mesh = np.searchsorted(self.mesh_offsets, ids, side="right") - 1
        return mesh.astype(INDEX), (ids - self.mesh_offsets[mesh]).astype(INDEX)

    def _merge_deforming_closest(self, traced, query, t, mesh, prim, u, v, normal):
        """Merge the deforming level's closest hits (``traced``, every ray of ``query``) into
        the answers by the tie rule (smaller t, then lower (mesh, prim)); a winner's normal is
        its triangle's at the ray's time (``corners_at_times``, then ``unit_normals``, the
        static level's arithmetic)."""
        level = self._deforming
        rays = np.flatnonzero(traced.arrays.best_tri != NO_HIT)
        rows = traced.arrays.best_tri[rays]
        hit_t = traced.best_t[rays] + FLOAT(0.0)  # -0.0 (a hit at the origin) as +0.0
        hit_mesh, hit_prim = self._hit_mesh_prim(level.ids[rows])
        was_t, was_mesh, was_prim = t[rays], mesh[rays], prim[rays]
        lower_key = (hit_mesh < was_mesh) | ((hit_mesh == was_mesh) & (hit_prim < was_prim))
        better = (hit_t < was_t) | ((hit_t == was_t) & lower_key)
        rays, rows = rays[better], rows[better]
        t[rays] = hit_t[better]
        mesh[rays] = hit_mesh[better]
        prim[rays] = hit_prim[better]
        u[rays] = traced.arrays.hit_u[rays]
        v[rays] = traced.arrays.hit_v[rays]
        times = np.zeros(len(rays), FLOAT) if query.times is None else query.times[rays]
        corners = corners_at_times(level.verts, level.verts_end, rows, times)
        normals = np.empty((len(rows), 3), FLOAT)
        unit_normals(corners, normals)
        normal[rays] = normals

    def _deforming_hits(self, query, max_hits):
        """The deforming level's hits of a ``hits`` query, at most max_hits + 1 a ray: (ray, t,
        mesh, prim, u, v, normal) arrays, one entry a hit (``merge_hit_lists``' part), and the
        trace's stats. u, v and normals come from each hit's triangle at its ray's time
        (``corners_at_times``), by ``results.finish_hits``, the static level's arithmetic."""
        level = self._deforming
        n_rays = len(query.origins)
        traced = self._trace_deforming(query, query.tmax, list_size=min(max_hits, len(level)) + 1)
        arrays = traced.arrays
        held = np.minimum(arrays.n_hits, max_hits + 1)
        listed = np.arange(arrays.list_tri.shape[1]) < held[:, None]
        rows = arrays.list_tri[listed]
        hit_rays = np.repeat(np.arange(n_rays), held)
        times = np.zeros(n_rays, FLOAT) if query.times is None else query.times
        # Each hit gets a row of its own: its triangle at its ray's time.
        at_times = HitTriangles(
            corners_at_times(level.verts, level.verts_end, rows, times[hit_rays]),
            np.ascontiguousarray(level.ids[rows]),
        )
        list_tri = np.zeros_like(arrays.list_tri)
        list_tri[listed] = np.arange(len(rows), dtype=INDEX)
        offsets, t, mesh, prim, u, v, normal = self._finish_hits(
            traced._replace(arrays=arrays._replace(list_tri=list_tri)),
            query.origins,
            query.directions,
            at_times,
            self._mesh_offsets,
            max_hits + 1,
        )
        ray_of_hit = np.repeat(np.arange(n_rays), np.diff(offsets))
        return (ray_of_hit, t, mesh, prim, u, v, normal), traced.stats

    def _counters(self, n_rays, per_level):
        """The counters of a query (a dict): the kernels' stats summed over every chunk of every
        level (the deepest node's depth for max_depth)."""
        counters = dict.fromkeys(STAT_NAMES, 0)
        counters["rays"] = n_rays
        counters["triangles"] = self.n_triangles
        per_chunk = [chunk_stats for level in per_level for chunk_stats in level]
        return add_counters(counters, per_chunk) if per_chunk else counters

    def _uniform_mask(self, ray_masks):
        """The one mask every ray of the batch carries (all ones for none), or None when they
        differ."""
        if ray_masks is None or not len(ray_masks):
            return ALL_MASKS
        return ray_masks[0] if (ray_masks == ray_masks[0]).all() else None

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
        Returns ``Nearest``; the distance is measured in float64 (a thin triangle's face as
        accurately as any other's), then rounded to float32, and ties go to the lowest (mesh,
        triangle)."""
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

    @property
    def moving(self) -> bool:
        """Whether a mesh of the scene moves during the interval (``transforms_end`` or
        ``vertices_end``)."""
        return self._moving

    def motion(
        self,
        mesh: ArrayLike,
        points: ArrayLike,
        time: ArrayLike | float | None = None,
        *,
        prim: ArrayLike | None = None,
        u: ArrayLike | None = None,
        v: ArrayLike | None = None,
    ) -> np.ndarray:
        """(n, 3) float64: how fast each of ``points`` (n, 3), on mesh ``mesh[i]`` (-1 for
        none) at time ``time[i]``, moves, in scene units per interval: d/dtau of
        M(tau) p = (M1 - M0) applied to p's mesh-space point inv(M(tau)) x; on a deforming mesh
        (``vertices_end``), of the point (1-u-v) p0 + u p1 + v p2 of triangle ``prim[i]``, so
        (1-u-v) (p0' - p0) + u (p1' - p1) + v (p2' - p2), its corners' ends less their starts
        (``prim``, ``u`` and ``v`` are then required: a hit's). Zero on a static mesh and for
        mesh -1 (divide by the interval's seconds for a velocity)."""
        mesh = check_int_rows(mesh, "mesh")
        if ((mesh < -1) | (mesh >= len(self._meshes))).any():
            raise InputError(f"mesh must hold -1 or indices below {len(self._meshes)}")
        points = float64_points(points, "points")
        if len(points) != len(mesh):
            raise InputError(f"points has {len(points)} rows but mesh has {len(mesh)}")
        n = len(mesh)
        times = check_time(time, n)
        times = np.zeros(n) if times is None else times.astype(np.float64)
        velocity = np.zeros((n, 3))
        for i, end in self._vertices_end.items():
            rows = np.flatnonzero(mesh == i)
            if not len(rows):
                continue
            if prim is None or u is None or v is None:
                raise InputError(f"motion on the deforming mesh {i} needs prim, u and v")
            hit_prim, hit_u, hit_v = check_hits(prim, u, v, n)
            faces_of = self._meshes[i][1]
            if ((hit_prim[rows] < 0) | (hit_prim[rows] >= len(faces_of))).any():
                raise InputError(f"prim must hold triangles of mesh {i}: 0 to {len(faces_of) - 1}")
            faces = faces_of[hit_prim[rows]]
            change = end.astype(np.float64) - self._meshes[i][0].astype(np.float64)
            hit_u, hit_v = hit_u[rows, None], hit_v[rows, None]
            velocity[rows] = (
                (1.0 - hit_u - hit_v) * change[faces[:, 0]]
                + hit_u * change[faces[:, 1]]
                + hit_v * change[faces[:, 2]]
            )
        for instance in self._instances:
            rows = np.flatnonzero(mesh == instance.mesh)
            if not instance.moving or not len(rows):
                continue
            tau = times[rows, None, None]
            m = (1.0 - tau) * instance.matrix + tau * instance.matrix_end  # (k, 4, 4)
            # a flat placement shows nothing at that instant: no point of it moves
            shown = np.linalg.det(m[:, :3, :3]) != 0
            rows, m = rows[shown], m[shown]
            local = np.linalg.solve(
                m[:, :3, :3], (points[rows] - m[:, :3, 3])[:, :, None]
            )  # (k, 3, 1)
            change = instance.matrix_end - instance.matrix
            velocity[rows] = (change[:3, :3] @ local)[:, :, 0] + change[:3, 3]
        return velocity

    @property
    def derived_for_points(self) -> bool:
        """Whether the scene holds what its point queries read (``nearest``, ``contains``,
        ``signed_distance``): its first point query derives it, once, and ``nbytes`` counts it
        from then on."""
        return self._point_triangles is not None

    def _scene_triangles(self, threads=None) -> point_queries.SceneTriangles:
        """The scene-space triangles, for the point queries (``_placed_triangles``), derived on
        the first one (on its ``threads``) under the scene's own lock: two first queries at
        once derive them once, and other scenes' queries do not wait for them."""
        with self._points_lock:
            if self._point_triangles is None:
                self._point_triangles = self._placed_triangles(threads)
            return self._point_triangles

    def _placed_triangles(self, threads=None) -> point_queries.SceneTriangles:
        """The base level's rows, then the deforming level's at time 0 and each instance's
        triangles placed in scene space (in float64, then float32, as placed copies), less
        those degenerate there: distances are not kept by a non-rigid placement, so point
        queries read placed triangles. Placed block by block into arrays of their final size,
        so that deriving them holds little beyond what is kept."""
        base = self._base
        if self._deforming is None and not self._instances:  # the base level's own arrays
            return point_queries.scene_triangles(
                base.verts, base.ids, self.mesh_offsets, self._row_masks, base.bounds, base.box,
                threads,
            )  # fmt: skip
        level = self._deforming
        n_rows = len(base) + (0 if level is None else len(level))
        n_rows += sum(len(instance.packed) for instance in self._instances)
        verts = np.empty((n_rows, 9), FLOAT)
        ids = np.empty(n_rows, INDEX)
        masks = np.empty(n_rows, np.uint32)
        n = len(base)
        verts[:n], ids[:n], masks[:n] = base.verts, base.ids, self._row_masks

        def add(block_verts, block_ids, block_masks):
            """The rows of a block that span a triangle, after those added before."""
            nonlocal n
            live = live_rows(block_verts)
            end = n + len(live)
            verts[n:end], ids[n:end] = block_verts[live], block_ids[live]
            masks[n:end] = block_masks if np.isscalar(block_masks) else block_masks[live]
            n = end

        if level is not None:  # at time 0, less the rows degenerate then (as the static packing)
            for lo in range(0, len(level), PLACING_BLOCK_ROWS):
                rows = slice(lo, lo + PLACING_BLOCK_ROWS)
                add(level.verts[rows], level.ids[rows], self._deforming_row_masks[rows])
        for instance in self._instances:
            packed, matrix = instance.packed, instance.matrix
            offset = self.mesh_offsets[instance.mesh]
            for lo in range(0, len(packed), PLACING_BLOCK_ROWS):
                rows = slice(lo, lo + PLACING_BLOCK_ROWS)
                # The mesh's own corners (exact: the frame centre is added back in float64).
                corners = packed.verts[rows].reshape(-1, 3).astype(np.float64) + instance.centre
                placed = corners @ matrix[:3, :3].T + matrix[:3, 3]
                # less the rows whose float32 corners the placement collapses, as a placed copy's
                add(placed.astype(FLOAT).reshape(-1, 9), packed.ids[rows] + offset,
                    self.masks[instance.mesh])  # fmt: skip
        for array in (verts, ids, masks):  # less the degenerate rows' room, in place
            array.resize((n, *array.shape[1:]), refcheck=False)
        return point_queries.scene_triangles(verts, ids, self.mesh_offsets, masks, threads=threads)

    def _visible_rows(self, ray_masks, deforming=False):
        """How a batch's masks are traced on the base level (or the deforming level):
        (flags, tri_ids, tri_masks). A batch whose rays share one mask (or carry none) sees a
        fixed set of meshes: tri_ids (int32) holds their kernel rows, or is None for every row,
        and the kernels check no mask. Otherwise the MASKED flag and every row's mesh mask
        (``_row_masks``, ``_deforming_row_masks``)."""
        meshes = self._deforming_meshes if deforming else self._base_meshes
        row_masks = (lambda: self._deforming_row_masks) if deforming else (lambda: self._row_masks)
        ray_mask = self._uniform_mask(ray_masks)
        if ray_mask is None:
            return MASKED, None, row_masks()
        seen = (self.masks[meshes] & ray_mask) != 0
        if seen.all():
            return 0, None, self._no_masks
        return 0, np.flatnonzero(row_masks() & ray_mask).astype(INDEX), self._no_masks

    def _trace(
        self,
        flags,
        origins,
        directions,
        tmin,
        tmax,
        cull,
        mask,
        strategy,
        threads,
        list_size=0,
        time=None,
        tracer=None,
    ):
        """Check a query and trace its base level with ``flags`` (``dacrt.query``) and its
        options; returns (``Query``, ``Traced``). ``list_size`` is the length of each ray's
        list of hits (ALL_HITS); ``time`` the rays' instants (``check_time``); ``tracer``
        traces each level (None: ``_trace_level``)."""
        strategy = check_strategy(strategy)
        threads = check_threads(threads, N_CORES)
        flags |= CULL_FLAGS[check_cull(cull)] | STRATEGY_CODES[strategy] << STRATEGY_SHIFT
        origins, directions, tmin, tmax, empty = check_rays(origins, directions, tmin, tmax)
        n_rays = len(origins)
        ray_masks = None if mask is None else check_masks(mask, n_rays, "mask", "ray")
        ray_masks = hide_rays(ray_masks, empty, n_rays)
        times = check_time(time, n_rays)
        if not self._moving or (times is not None and not times.any()):
            times = None  # every ray at 0, or nothing moves: the static trace, bit for bit
        tracer = tracer or self._trace_level
        query = Query(flags, origins, directions, tmin, tmax, ray_masks, threads, times, tracer)
        mask_flags, visible_rows, tri_masks = self._visible_rows(ray_masks)
        traced = tracer(
            self._base,
            flags | mask_flags,
            origins,
            directions,
            tmin,
            tmax,
            ray_masks if mask_flags else self._no_masks,
            visible_rows,
            tri_masks,
            threads,
            list_size,
        )
        if not traced.stats and n_rays:
            explain_bad_rays(origins, directions, tmin, tmax)  # no kernel checked them
        return query, traced

    def _trace_instances(self, query, limit, kind, max_hits=0, from_box=False):
        """Trace the query's rays into each instance they can reach: yields (instance, ray ids
        (k,) int32, ``InstanceTraced`` with ``origins`` and ``directions`` in mesh space), in
        the order of the instances (a moving instance may yield twice: its rays where its
        placement is mirrored at their time, and the others, when the query culls). A ray goes
        in when its segment [tmin, limit] reaches the instance's box (a moving one's over the
        whole interval, when the rays carry times) and its mask sees the instance; ``limit``
        (n,) float32 is read once, before the instances are traced side by side on the query's
        threads, one thread each (the caller merges their answers afterwards, in any order: the
        tie rule decides). With ``from_box`` (a count of rays from tmin 0) a static ray whose
        origin leaves float32 in mesh space starts there before the mesh's box instead
        (``origins_near_box``): no crossing lies before it."""
        # Writable and contiguous, as the kernels are compiled for (one signature).
        origins = np.require(query.origins, FLOAT, ["C", "W"])
        directions = np.require(query.directions, FLOAT, ["C", "W"])
        tmin = np.require(query.tmin, FLOAT, ["C", "W"])
        uniform = self._uniform_mask(query.ray_masks)
        ray_masks = (
            self._no_masks if uniform is not None else np.require(query.ray_masks, None, ["C", "W"])
        )
        seen = [i for i in self._instances if uniform is None or uniform & self.masks[i.mesh]]
        if not seen:
            return
        timed = query.times is not None
        boxes = [i.box if timed else i.box_start for i in seen]
        ray_ids = self._rays_reaching(
            seen, boxes, origins, directions, tmin, limit, ray_masks, query.threads
        )
        flags = query.flags & ~(ANY_HIT | COLLECT) | kind
        # The instances with most rays start first; one alone takes every thread.
        work = sorted(
            (k for k in range(len(seen)) if len(ray_ids[k])), key=lambda k: -len(ray_ids[k])
        )
        if not work:
            return

        def trace(instance, mesh_rays, mirrored, threads):
            """Trace rays given in mesh space into ``instance``'s mesh: ``Traced``."""
            list_size = min(max_hits, len(instance.packed)) + 1 if kind & ALL_HITS else 0
            try:
                return query.tracer(
                    instance.packed,
                    instance.flags(flags, mirrored),
                    *mesh_rays,
                    self._no_masks,
                    None,
                    self._no_masks,
                    threads,
                    list_size,
                )
            except InputError:
                placement = f"transforms[{instance.mesh}]"
                if instance.moving:
                    placement += f" to transforms_end[{instance.mesh}], at the rays' times"
                raise MeshSpaceError(
                    f"a ray of the batch leaves the float32 range in the space of mesh "
                    f"{instance.mesh} ({placement})",
                    instance.mesh,
                ) from None

        def to_mesh_space(k):
            """Instance k's rays in its mesh's space: [(k, ids, mesh rays, mirrored,
            cofactors)], two parts where culling traces its mirrored instants apart."""
            instance = seen[k]
            ids = ray_ids[k]
            n = len(ids)
            mesh_rays = (
                np.empty((n, 3), FLOAT),
                np.empty((n, 3), FLOAT),
                np.empty(n, FLOAT),
                np.empty(n, FLOAT),
            )
            if not (timed and instance.moving):
                rays_to_mesh_space(
                    origins, directions, tmin, limit, ids, instance.to_mesh, *mesh_rays
                )
                far = ~np.isfinite(mesh_rays[0]).all(axis=1) if from_box else None
                if from_box and far.any():
                    mesh_rays[0][far] = origins_near_box(
                        origins[ids[far]], directions[ids[far]], instance.to_mesh,
                        instance.packed.box,
                    )  # fmt: skip
                return [(k, ids, mesh_rays, None, instance.cofactors)]
            cofactors = np.empty((n, 3, 3))
            signs = np.empty(n, np.int8)
            rays_to_mesh_space_at(
                origins, directions, tmin, limit, ids, query.times, instance.to_mesh,
                instance.cofactor, -1 if instance.mirrored else 1, instance.matrix,
                instance.matrix_end, instance.centre, *mesh_rays, cofactors, signs,
            )  # fmt: skip
            # Rays at an instant where the placement is singular see nothing of it; culling
            # swaps faces where it is mirrored, so those rays are traced apart.
            culls = query.flags & (CULL_BACK | CULL_FRONT)
            groups = [signs != 0] if not culls else [signs > 0, signs < 0]
            parts = []
            for group, keep in enumerate(groups):
                if not keep.any():
                    continue
                every = keep.all()
                arrays = (ids, cofactors, *mesh_rays)
                part_ids, part_cofactors, *part_rays = (
                    a if every else np.ascontiguousarray(a[keep]) for a in arrays
                )
                mirrored = None if not culls else group == 1
                parts.append((k, part_ids, part_rays, mirrored, part_cofactors))
            return parts

        parts = [part for k in work for part in to_mesh_space(k)]
        # The parts of one mesh under the same flags are one batch: one trace for every
        # instance of a mesh, however many (a ray's answer does not depend on its batch).
        batches = {}
        for part in parts:
            instance = seen[part[0]]
            key = (id(instance.packed), instance.flags(flags, part[3]))
            batches.setdefault(key, []).append(part)
        batches = sorted(batches.values(), key=lambda b: -sum(len(p[1]) for p in b))
        if not batches:  # every ray reaching a box met its placement flat at its instant
            return
        inner_threads = query.threads if len(batches) == 1 else 1

        def run(batch):
            """[(k, ids, ``InstanceTraced``)] of one batch's parts."""
            instance = seen[batch[0][0]]
            if len(batch) == 1:
                rays = batch[0][2]
            else:
                rays = [np.concatenate([p[2][f] for p in batch]) for f in range(4)]
            try:
                found = trace(instance, rays, batch[0][3], inner_threads)
            except InputError:
                if len(batch) == 1:
                    raise
                for k, _, mesh_rays, mirrored, _ in batch:  # name the instance it was
                    trace(seen[k], mesh_rays, mirrored, inner_threads)
                raise
            out = []
            lo = 0
            for n_part, (k, ids, mesh_rays, _, cofactors) in enumerate(batch):
                part = slice(lo, lo + len(ids))
                lo += len(ids)
                out.append((k, ids, InstanceTraced(
                    found.best_t[part],
                    sliced_arrays(found.arrays, part),
                    found.stats if n_part == 0 else [],
                    *mesh_rays[:2],
                    cofactors,
                )))  # fmt: skip
            return out

        traced = map_on_threads(
            lambda j: run(batches[j]), len(batches), min(query.threads, len(batches))
        )
        for k, ids, found in sorted(
            (item for batch in traced for item in batch), key=lambda item: item[0]
        ):
            yield seen[k], ids, found

    def _rays_reaching(
        self, instances, boxes, origins, directions, tmin, limit, ray_masks, threads
    ):
        """For each of ``instances`` (with its box in ``boxes``), the ids (int32, increasing)
        of the rays whose segment [tmin, limit] reaches that box and whose mask (``ray_masks``,
        or none) sees it: a pass over the rays per thread marks each ray's boxes in a bit set
        and counts them (``mark_rays_reaching``), one more writes the ids
        (``fill_rays_reaching``)."""
        boxes = np.array(boxes, FLOAT)
        order, group_lo, groups = group_boxes(boxes)
        boxes = np.ascontiguousarray(boxes[order])
        box_masks = np.ascontiguousarray(self.masks[[instances[k].mesh for k in order]])
        n_rays = len(origins)
        n_parts = max(1, min(threads, n_rays // MIN_RAYS_PER_THREAD))
        bounds = [k * n_rays // n_parts for k in range(n_parts + 1)]
        bits = np.empty((-(-len(boxes) // 64), n_rays), np.uint64)

        def mark(k):
            counts = np.zeros(len(boxes), np.int64)
            mark_rays_reaching(
                origins, directions, tmin, limit, ray_masks, box_masks, boxes, groups, group_lo,
                bounds[k], bounds[k + 1], bits, counts,
            )  # fmt: skip
            return counts

        counts = np.array(map_on_threads(mark, n_parts, n_parts))  # (parts, boxes)
        per_box = counts.sum(axis=0)
        box_start = np.zeros(len(boxes) + 1, np.int64)
        np.cumsum(per_box, out=box_start[1:])
        starts = box_start[:-1] + np.cumsum(counts, axis=0) - counts
        ids = np.empty(max(1, int(box_start[-1])), INDEX)

        def fill(k):
            fill_rays_reaching(bits, bounds[k], bounds[k + 1], ids, starts[k].copy())

        if box_start[-1]:
            map_on_threads(fill, n_parts, n_parts)
        by_instance = [None] * len(instances)
        for b, k in enumerate(order):
            by_instance[k] = ids[box_start[b] : box_start[b + 1]]
        return by_instance

    def _trace_level(
        self,
        level,
        flags,
        origins,
        directions,
        tmin,
        tmax,
        ray_masks,
        visible_rows,
        tri_masks,
        threads,
        list_size,
        times=None,
    ):
        """Run the kernels on one level (a ``Packed``) with ``flags`` (``dacrt.query``, the
        strategy's code included); ``ray_masks`` and ``tri_masks`` as ``QueryArrays`` holds
        them, ``visible_rows`` the rows traced (None for all); ``times`` (n,) float32, each
        ray's instant, for the deforming level (``DeformingPacked``), else None. Returns
        ``Traced``, whose stats list is empty when no kernel ran (no rays or no rows) or a ray
        is invalid (then the rays were not traced)."""
        n_rays = len(origins)
        best_t = tmax.copy()  # the records' best_t, scattered back after the trace
        lists = (n_rays, list_size) if flags & ALL_HITS else (0, 0)
        answer = QueryArrays(
            best_tri=np.full(n_rays, NO_HIT, INDEX),
            hit_u=np.zeros(n_rays, FLOAT),
            hit_v=np.zeros(n_rays, FLOAT),
            ray_masks=ray_masks,
            tri_masks=tri_masks,
            tri_keys=level.ids,
            n_hits=np.zeros(n_rays if flags & COLLECT else 0, INDEX),
            list_t=np.empty(lists, FLOAT),
            list_tri=np.empty(lists, INDEX),
            hit_mask=None,
            tri_bins=None,
            stats=None,
        )
        n_live = len(level) if visible_rows is None else len(visible_rows)
        if n_rays == 0 or n_live == 0:
            return Traced(best_t, answer, [])
        ray_space = (flags >> STRATEGY_SHIFT) & 3 == RAYSPACE
        # The halves of the storage order serve a trace of every row.
        tree = NO_TREE
        if not ray_space and visible_rows is None:
            tree = range_tree(level.bounds, lambda f, n: map_on_threads(f, n, threads))
        if not ray_space and not flags & COLLECT and splits_triangles(n_rays, n_live, threads):
            per_half = self._trace_halves(
                level, flags, origins, directions, tmin, tmax, visible_rows, answer, best_t, times,
                tree,
            )  # fmt: skip
            return Traced(best_t, answer, per_half)
        # The values are not checked yet (each chunk checks its own): a bad ray may make
        # the choice of chunks poor, never wrong.
        with np.errstate(invalid="ignore", over="ignore"):
            coherent = from_one_point(origins, level.box)
            n_chunks = count_chunks(n_rays, n_live, threads, coherent)
            # rayspace splits the rays by origin and direction itself: it keeps the input order.
            plan = plan_chunks(
                origins, n_chunks, coherent or ray_space, level.box, lambda: level.centre_counts
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
            tris = level_triangles(level, tri_ids, times)
            chunk_stats = np.zeros(len(STAT_NAMES), np.int64)
            arrays = answer._replace(
                hit_mask=np.empty(len(ray_ids), np.bool_),
                tri_bins=np.empty(n_live, np.uint8),
                stats=chunk_stats,
            )
            if ray_space:
                trace_ray_space(chunk_flags, tris, level.box, rays, ray_ids, arrays)
            else:
                trace_object_split(
                    chunk_flags, tris, tree, level.box, rays, ray_ids, 0, len(ray_ids), 0, n_live,
                    arrays,
                )  # fmt: skip
            unpack_best_t(rays, ray_ids, best_t)
            return chunk_stats

        per_chunk = map_on_threads(run, n_chunks, min(threads, n_chunks))
        if any(chunk_stats is None for chunk_stats in per_chunk):
            explain_bad_rays(origins, directions, tmin, tmax)
            raise InputError("the batch holds an invalid ray")  # explain_bad_rays names it
        return Traced(best_t, answer, per_chunk)

    def _trace_halves(
        self, level, flags, origins, directions, tmin, tmax, visible_rows, answer, best_t, times,
        tree,
    ):  # fmt: skip
        """Trace a closest or occlusion batch on two threads, each with every ray against one
        half of the level's triangles (the halves of ``tree``, its nodes 2 and 3, or else split
        at the middle of the level's box); then each ray keeps the better of its two answers,
        the smaller (t, tie key), as one trace would. Writes best_t and ``answer``'s best_tri,
        hit_u and hit_v; returns each half's stats."""
        n_rays = len(origins)
        tri_ids = (
            np.arange(len(level), dtype=INDEX) if visible_rows is None else visible_rows.copy()
        )
        tris = level_triangles(level, tri_ids, times)
        boxes = np.empty((3, 6), FLOAT)  # the halves' boxes, and scratch for split_middle
        trees = (NO_TREE, NO_TREE)
        if tree.depth > 0:
            tri_mid = node_rows(3, tree.n_rows)[0]
            boxes[:2] = tree.boxes[2:4]
            trees = (tree._replace(root=2), tree._replace(root=3))
        else:
            _, tri_mid = split_middle(tris, 0, len(tri_ids), level.box, boxes)
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
                flags, tris, trees[half], boxes[half], half_rays, half_ids, 0, n_rays, lo, hi,
                arrays,
            )  # fmt: skip
            t = np.empty(n_rays, FLOAT)
            unpack_best_t(half_rays, half_ids, t)
            return t, arrays

        (t0, first), (t1, second) = map_on_threads(run, 2, 2)
        # Where the second half's (t, tie key) is smaller, it is the answer.
        take = (t1 < t0) | ((t1 == t0) & (tie_keys(level, second) < tie_keys(level, first)))
        best_t[:] = np.where(take, t1, t0)
        for name in ("best_tri", "hit_u", "hit_v"):
            np.copyto(getattr(answer, name), getattr(second, name), where=take)
        return [first.stats, second.stats]


SceneArguments = namedtuple(
    "SceneArguments", ["meshes", "masks", "transforms", "order", "transforms_end", "vertices_end"]
)
SceneArguments.__doc__ = """``Scene``'s arguments checked, as ``Scene`` takes them: meshes as
(float32 vertices, int32 or int64 faces) pairs, masks (n,) uint32, transforms and transforms_end
one None or (4, 4) float64 a mesh, vertices_end one None or (V, 3) float32 a mesh."""


def check_scene_arguments(meshes, masks, transforms, order, transforms_end, vertices_end):
    """The (vertices, faces) pairs as given and ``SceneArguments``: ``Scene``'s checks, which a
    ``DistributedScene`` makes too before it sends anything. InputError naming the argument."""
    if not isinstance(order, str) or order not in ORDERS:
        raise InputError(f"order must be one of {', '.join(ORDERS)}; got {order!r}")
    given = [pair for _, pair in mesh_pairs(meshes)]
    by_arrays = {}  # instances of the same arrays share one checked copy
    for i, (vertices, faces) in enumerate(given):
        if (id(vertices), id(faces)) not in by_arrays:
            by_arrays[id(vertices), id(faces)] = check_mesh(i, vertices, faces)
    checked = [by_arrays[id(vertices), id(faces)] for vertices, faces in given]
    check_row_count(sum(len(faces) for _, faces in checked), "the scene", "triangles")
    matrices = checked_transforms(transforms, len(checked), "transforms")
    ends = checked_transforms(transforms_end, len(checked), "transforms_end")
    ends_given = one_per_mesh(vertices_end, len(checked), "vertices_end", "a (V, 3) array or None")
    deformed = [
        None if end is None else check_vertices_end(i, end, checked[i][0], matrices[i], ends[i])
        for i, end in enumerate(ends_given)
    ]
    mesh_masks = check_masks(ALL_MASKS if masks is None else masks, len(checked), "masks", "mesh")
    return given, SceneArguments(checked, mesh_masks, matrices, order, ends, deformed)


def checked_transforms(transforms, n_meshes, name):
    """``transforms`` (None, or one None or matrix per mesh) as a list of None or checked
    (4, 4) float64 matrices; InputError naming ``name`` or its entry."""
    matrices = one_per_mesh(transforms, n_meshes, name, "a (4, 4) matrix or None")
    given = changed_transforms(dict(enumerate(matrices)), name)
    return [given.get(i) for i in range(n_meshes)]


def changed_transforms(transforms, name):
    """{mesh index: matrix} as {mesh index: checked (4, 4) float64} for the matrices that are
    not None, checked at once (``check_transforms``); InputError naming ``name[i]``."""
    given = [(i, matrix) for i, matrix in transforms.items() if matrix is not None]
    checked = check_transforms([matrix for _, matrix in given], lambda k: f"{name}[{given[k][0]}]")
    return {i: matrix for (i, _), matrix in zip(given, checked)}


def check_placements(placements):
    """InputError naming ``name[i]`` for the first of ``placements``, (i, packed, matrix, name)
    each, whose matrix places mesh i's packed corners beyond the float32 range."""
    boxed = [p for p in placements if p[1].corner_box[0] <= p[1].corner_box[3]]
    if not boxed:
        return
    centres = np.stack([packed.centre for _, packed, _, _ in boxed]).astype(np.float64)
    corners = np.stack([packed.corner_box for _, packed, _, _ in boxed]) + np.tile(centres, 2)
    placed = placed_points(box_corners(corners), np.stack([p[2] for p in boxed]))
    beyond = ~(np.abs(placed) <= np.finfo(FLOAT).max).all(axis=(1, 2))
    for i, _, _, name in (p for p, out in zip(boxed, beyond) if out):
        raise InputError(f"{name}[{i}] places mesh {i} beyond the float32 range")


def one_per_mesh(values, n_meshes, name, what):
    """``values`` (None, or a sequence of one entry a mesh) as a list of ``n_meshes`` entries
    (None for none); InputError naming ``name``, with ``what`` an entry is, otherwise."""
    if values is None:
        return [None] * n_meshes
    try:
        values = list(values)
    except TypeError:
        raise InputError(
            f"{name} must be a sequence with {what} for each mesh, got {type(values).__name__}"
        ) from None
    if len(values) != n_meshes:
        raise InputError(f"{name} has {len(values)} entries for {n_meshes} meshes")
    return values


def check_device(device, stats, strategy, threads):
    """``device`` ("cpu" or "cuda"), or InputError; stats are counted on the CPU only, and the
    GPU's query checks ``strategy`` and ``threads`` as the CPU's does though neither applies."""
    if not isinstance(device, str) or device not in DEVICES:
        raise InputError(f"unknown device {device!r}; use one of {', '.join(DEVICES)}")
    if device == "cuda":
        if stats:
            raise InputError("device='cuda' does not support stats=True yet")
        check_strategy(strategy)
        check_threads(threads, 1)
    return device


def level_triangles(level, tri_ids, times):
    """The kernels' record of a level's rows ``tri_ids``: ``Triangles``, with a
    ``DeformingPacked``'s end corners and ``times`` (each ray's instant) when given."""
    if times is None:
        return Triangles(level.verts, level.bounds, tri_ids)
    return Triangles(level.verts, level.bounds, tri_ids, level.verts_end, times)


def live_rows(verts):
    """(k,) int64: the rows of ``verts`` (F, 9) float32 whose corners span a triangle, their
    cross product in float64 not zero (the others are degenerate: never an answer)."""
    corners = verts.reshape(-1, 3, 3).astype(np.float64)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return np.flatnonzero(normals.any(axis=1))


def _joined(arrays, empty):
    """The ``arrays`` one after another: the one itself when alone (packed arrays are never
    written, so a level may share them), ``empty`` for none."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays or [empty])


def _same_matrix(a, b):
    """Whether two placements (None or (4, 4)) are the same."""
    return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))


def sliced_arrays(arrays, part):
    """``QueryArrays`` of the rays ``part`` (a slice) of a trace: its per-ray answers only."""
    per_ray = ("best_tri", "hit_u", "hit_v", "n_hits", "list_t", "list_tri")
    return arrays._replace(
        **{name: getattr(arrays, name)[part] for name in per_ray if len(getattr(arrays, name))}
    )


def tie_keys(level, arrays):
    """Each ray's tie key (``QueryArrays.tri_keys``) of its best row of ``level``, NO_HIT for
    none."""
    found = arrays.best_tri != NO_HIT
    return np.where(found, level.ids[np.where(found, arrays.best_tri, 0)], NO_HIT)


def add_counters(counters, per_chunk):
    """``counters`` with the sums of the kernels' stats arrays (the deepest node's depth for
    max_depth), one per chunk of the batch."""
    totals = np.sum(per_chunk, axis=0)
    for i, name in enumerate(STAT_NAMES):
        if i not in (STAT_RAYS, STAT_TRIANGLES):
            counters[name] = int(totals[i])
    counters["max_depth"] = int(max(c[STAT_NAMES.index("max_depth")] for c in per_chunk))
    return counters
