"""Triangles packed for the kernels once, then shared: a mesh's packed arrays serve every
instance of it and every later version of a Scene that keeps it (``Scene.with_changes``).

A mesh's rows may be stored along a Morton curve of their box centres (``order``, config's
``COHERENCE_BITS``), whatever order its faces come in: neighbouring rows are then neighbouring
triangles, so the partitions' and leaves' reads of a node's rows stay in few cache lines.
Nothing depends on that order: ``ids`` keeps each row's face, and every tie compares ids, never
rows.

A placed mesh is packed relative to a float32 point of its own, its frame centre
(``frame_centre``): 0 for a mesh near its origin, else its box's centre, so that rays moved into
its space keep float32's precision near the mesh (``instances``).

A ``Packed`` is never written after it is made: the kernels only read it, and a new version of
a mesh gets a new ``Packed``. Its arrays stay writable because Numba compiles a read-only array
as another type, which would compile every kernel twice.
"""

import functools

import numpy as np

from . import config
from .chunks import DENSITY_GRID, centre_counts
from .config import jit
from .contracts import FLOAT, INDEX
from .points import MORTON_BITS, triangle_codes
from .results import unit_normals
from .triangles import gather_triangles

#: The storage orders of a mesh's rows (``Scene(order=)``).
ORDERS = ("auto", "morton", "file")
# The Morton codes (3 * MORTON_BITS = 30 bits) are sorted as two halves of 15 bits.
MORTON_HALF_BITS = 3 * MORTON_BITS // 2
MORTON_HALF_MASK = (1 << MORTON_HALF_BITS) - 1
# The box of no triangles: grows to the first one.
EMPTY_BOX = np.array([np.inf] * 3 + [-np.inf] * 3, FLOAT)
# The frame centre of a mesh packed in its own coordinates.
NO_CENTRE = np.zeros(3, FLOAT)


class Packed:
    """One set of triangles as the kernels read them.

    verts : (F, 9) float32, each row's corners p0, p1, p2 (degenerate triangles get no row)
    bounds : (F, 6) float32, each row's box
    ids : (F,) int32, each row's triangle: a mesh's face row, or in a scene's base level its
        global index (``Scene.mesh_offsets``); a mesh's rows go in Morton order (``morton_order``),
        the meshes in their order, and ties in t are settled by ids
    box : (6,) float32, the rows' box (zeros when there are none)
    corner_box : (6,) float32, the box of every corner the faces refer to, degenerate triangles
        included (EMPTY_BOX when there are no faces)
    centre : (3,) float32, the point the coordinates above are relative to: a corner p of the
        mesh is stored as p - centre, exactly (``frame_centre``; NO_CENTRE but for a placed
        mesh far from its origin)
    """

    def __init__(self, verts, bounds, ids, box, corner_box, centre=NO_CENTRE):
        self.verts = verts
        self.bounds = bounds
        self.ids = ids
        self.box = box
        self.corner_box = corner_box
        self.centre = centre

    def __len__(self) -> int:
        return len(self.verts)

    @functools.cached_property
    def centre_counts(self):
        """Triangle centres per cell of the DENSITY_GRID grid over ``box``, for slab cuts:
        derived on the first incoherent query on several threads that needs it."""
        return centre_counts(self.bounds, self.box, DENSITY_GRID)

    @functools.cached_property
    def unit_normals(self):
        """Each row's unit normal (12 bytes a triangle): derived on the first batch that looks
        them up (``Scene.closest``)."""
        normals = np.empty((len(self.verts), 3), FLOAT)
        unit_normals(self.verts, normals)
        return normals

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays, with the derived ones that exist."""
        derived = [self.__dict__.get(name) for name in ("centre_counts", "unit_normals")]
        held = [self.verts, self.bounds, self.ids] + [a for a in derived if a is not None]
        return int(sum(array.nbytes for array in held))


def pack_meshes(meshes, first_rows, order="auto", kept_orders=None):
    """One ``Packed`` of the checked ``meshes`` ((vertices float32, faces) pairs) in their
    order, each triangle's id being its face row plus that mesh's entry of ``first_rows``; each
    mesh's rows in the storage ``order`` ("auto", "morton" or "file": ``rows_in_order``), or in
    its entry of ``kept_orders``: every face row of an earlier packing of the same faces in its
    rows' order (``every_face``), as a refit keeps a hierarchy: new vertices are gathered in it,
    not sorted again (None to choose).

    Returns (packed, live, boxes, corner_boxes): mesh k's rows are live[k]:live[k + 1] (live:
    (n + 1,) int64), and boxes, corner_boxes (n, 6) float32 hold each mesh's box of rows and
    box of corners (EMPTY_BOX for none)."""
    n_faces = sum(len(faces) for _, faces in meshes)
    verts = np.empty((n_faces, 9), FLOAT)
    bounds = np.empty((n_faces, 6), FLOAT)
    ids = np.empty(n_faces, INDEX)
    boxes = np.tile(EMPTY_BOX, (len(meshes), 1))
    corner_boxes = boxes.copy()
    live = np.zeros(len(meshes) + 1, np.int64)
    n_live = 0
    for k, ((vertices, faces), first_row) in enumerate(zip(meshes, first_rows)):
        kept = None if kept_orders is None else kept_orders[k]
        in_order = faces if kept is None else np.take(faces, kept, axis=0)
        n_live = gather_triangles(
            vertices, in_order, first_row, n_live, verts, bounds, ids, corner_boxes[k], boxes[k]
        )
        live[k + 1] = n_live
        rows = slice(live[k], live[k + 1])
        if kept is not None:
            # A degenerate triangle gets no row: the rows' ids name positions in the kept order.
            ids[rows] = np.take(kept, ids[rows] - INDEX(first_row)) + INDEX(first_row)
            continue
        order_of = rows_in_order(bounds[rows], boxes[k], order)
        if order_of is not None:
            face_rows = np.take(ids[rows], order_of)
            # Gathered again in that order: moving the gathered rows instead reads 60 bytes a
            # row at random, several times slower. The boxes grow by nothing new.
            in_order = np.take(faces, face_rows - INDEX(first_row), axis=0)
            gather_triangles(
                vertices, in_order, first_row, live[k], verts, bounds, ids, corner_boxes[k],
                boxes[k],
            )  # fmt: skip
            ids[rows] = face_rows
    packed = Packed(
        verts[:n_live],
        bounds[:n_live],
        ids[:n_live],
        live_box(union_box(boxes)),
        union_box(corner_boxes),
    )
    return packed, live, boxes, corner_boxes


def pack_mesh(vertices, faces, order="auto", kept_order=None):
    """The ``Packed`` of one checked mesh, its ids being its face rows, in ``kept_order``
    (``pack_meshes``' kept orders) or else in the storage ``order``."""
    packed, _, _, _ = pack_meshes([(vertices, faces)], [0], order, [kept_order])
    return packed


def pack_placed_mesh(vertices, faces, order="auto", kept_order=None):
    """``pack_mesh`` of a mesh placed by a matrix (an instance's): relative to its frame
    centre (``centred``)."""
    return centred(pack_mesh(vertices, faces, order, kept_order))


def frame_centre(corner_box):
    """(3,) float32: the point a placed mesh with corners in ``corner_box`` (6,) is packed
    relative to. On each axis where the box's centre lies farther than config.FAR_SIDES times
    its largest side from 0, that centre rounded to float32 (a point of the box), else 0;
    NO_CENTRE for no corners."""
    lo, hi = corner_box[:3].astype(np.float64), corner_box[3:].astype(np.float64)
    if not (lo <= hi).all():
        return NO_CENTRE
    middle = (lo + hi) / 2  # exact: the float32 sides' halves and sum fit float64
    far = np.abs(middle) > config.FAR_SIDES * np.max(hi - lo)
    return np.where(far, middle, 0.0).astype(FLOAT)


def centred(packed):
    """``packed`` (one mesh's, in its own coordinates) moved to be relative to its frame centre
    (``frame_centre`` of its corner box): a new ``Packed`` sharing its ids, or ``packed`` itself
    where the centre is 0. Every moved corner is exact, so its triangles are the mesh's, moved."""
    centre = frame_centre(packed.corner_box)
    if not centre.any():
        return packed
    return moved_by(packed, -centre, centre)


def as_given(packed):
    """``packed`` in the mesh's own coordinates (centre 0): ``centred``'s inverse, exact."""
    if not packed.centre.any():
        return packed
    return moved_by(packed, packed.centre, NO_CENTRE)


def moved_by(packed, shift, centre):
    """A ``Packed`` of ``packed``'s rows moved by ``shift`` (3,) float32 (in float32, exact for
    a shift to or from the frame centre), relative to ``centre``; its ids shared."""
    box = packed.box if not len(packed) else packed.box + np.tile(shift, 2)  # zeros for none
    return Packed(
        packed.verts + np.tile(shift, 3),
        packed.bounds + np.tile(shift, 2),
        packed.ids,
        box,
        packed.corner_box + np.tile(shift, 2),
        centre,
    )


def every_face(live_rows, n_faces):
    """``live_rows`` (int32: a packing's ids, the faces with a row, in their rows' order), then
    the faces of degenerate triangles in order: every face row once."""
    if len(live_rows) == n_faces:
        return live_rows
    degenerate = np.ones(n_faces, np.bool_)
    degenerate[live_rows] = False
    return np.concatenate([live_rows, np.flatnonzero(degenerate).astype(INDEX)])


def rows_in_order(bounds, box, order):
    """The rows of ``bounds`` (F, 6) float32 in Morton order of their box centres over ``box``
    (``morton_order``), or None to keep them as they are: ``order`` "file", or "auto" for
    faces that come coherent (``COHERENCE_BITS``) in a mesh of fewer than AUTO_MORTON_ROWS."""
    if order == "file" or len(bounds) < 2:
        return None
    codes = triangle_codes(bounds, np.arange(len(bounds), dtype=INDEX), box)
    if order == "auto" and len(bounds) < config.AUTO_MORTON_ROWS:
        cells = codes >> (3 * MORTON_BITS - config.COHERENCE_BITS)
        if np.count_nonzero(cells[1:] != cells[:-1]) <= config.INCOHERENT_JUMPS * len(codes):
            return None
    return morton_order(codes)


@jit
def morton_order(codes):
    """The indices (int32) that sort ``codes`` (F,) int64, 30-bit Morton codes, stably: two
    counting passes over 15-bit digits, the low digit, then the high one."""
    n = codes.shape[0]
    by_low = np.empty(n, INDEX)
    order = np.empty(n, INDEX)
    starts = np.empty((1 << MORTON_HALF_BITS) + 1, np.int64)
    for shift in (0, MORTON_HALF_BITS):
        source = by_low if shift else order
        target = order if shift else by_low
        starts[:] = 0
        for i in range(n):
            starts[((codes[i] >> shift) & MORTON_HALF_MASK) + 1] += 1
        for d in range(1 << MORTON_HALF_BITS):
            starts[d + 1] += starts[d]
        for j in range(n):
            i = source[j] if shift else j
            d = (codes[i] >> shift) & MORTON_HALF_MASK
            target[starts[d]] = i
            starts[d] += 1
    return order


def union_box(boxes):
    """The box (6,) float32 holding the (n, 6) ``boxes`` (EMPTY_BOX for none)."""
    boxes = np.asarray(boxes, FLOAT).reshape(-1, 6)
    lo = boxes[:, :3].min(axis=0, initial=np.inf)
    hi = boxes[:, 3:].max(axis=0, initial=-np.inf)
    return np.concatenate([lo, hi]).astype(FLOAT)


def live_box(box):
    """``box`` as the kernels' root box: zeros for the box of no triangles (EMPTY_BOX)."""
    return box if box[0] <= box[3] else np.zeros(6, FLOAT)


class DeformingPacked(Packed):
    """The deforming meshes' rows, as a ``Packed`` whose bounds hold each row over the whole
    interval, with ``verts_end`` (F, 9) float32, each row's corners at the end. Every face gets a
    row (a triangle degenerate at one instant may not be at another); the leaf skips a row that
    is degenerate at the ray's instant, as the static packing drops it."""

    def __init__(self, verts, verts_end, bounds, ids, box, corner_box):
        super().__init__(verts, bounds, ids, box, corner_box)
        self.verts_end = verts_end

    @property
    def nbytes(self) -> int:
        return super().nbytes + int(self.verts_end.nbytes)


def pack_deforming(meshes, first_rows):
    """The ``DeformingPacked`` of ``meshes`` ((vertices, vertices_end, faces), checked, float32)
    in their order, each row's id its face row plus its mesh's entry of ``first_rows``.

    Returns (packed, corner_boxes): each mesh's box of the corners its faces use at 0 and at 1
    (n, 6) float32, EMPTY_BOX for none."""
    verts, verts_end, ids, corner_boxes = [], [], [], []
    for (start, end, faces), first_row in zip(meshes, first_rows):
        verts.append(start[faces].reshape(-1, 9))
        verts_end.append(end[faces].reshape(-1, 9))
        ids.append(np.arange(len(faces), dtype=np.int64) + first_row)
        both = np.concatenate([verts[-1], verts_end[-1]]).reshape(-1, 3)
        corner_boxes.append(union_box(np.hstack([both, both])))
    verts = np.ascontiguousarray(np.concatenate(verts or [np.empty((0, 9), FLOAT)]), FLOAT)
    verts_end = np.ascontiguousarray(np.concatenate(verts_end or [np.empty((0, 9), FLOAT)]), FLOAT)
    ids = np.concatenate(ids or [np.empty(0, np.int64)]).astype(INDEX)
    # A row's box over the interval: its corners' box at 0 and at 1 together.
    corners = np.concatenate([verts.reshape(-1, 3, 3), verts_end.reshape(-1, 3, 3)], axis=1)
    bounds = np.ascontiguousarray(np.concatenate([corners.min(axis=1), corners.max(axis=1)], 1))
    packed = DeformingPacked(
        verts, verts_end, bounds, ids, live_box(union_box(bounds)), union_box(corner_boxes)
    )
    return packed, np.array(corner_boxes, FLOAT).reshape(-1, 6)
