"""Instances: meshes placed by a matrix, traced in their own space (the second level of a trace).

A placed mesh keeps its packed arrays in mesh space (``packed``), shared by all its instances and
versions, relative to its frame centre c (``packed.frame_centre``: 0 for a mesh near its origin,
its box's centre for one modelled far from it): the instance's map into that space is M's inverse
followed by the move by -c. A query traces the scene's untransformed meshes first (the base
level); then the rays are sorted into the instances whose box in scene space they reach within
[tmin, their best t] (``mark_rays_reaching``, ``fill_rays_reaching``); each instance's rays go
into mesh space (origin by that map, direction by the inverse linear part, not normalised, so t,
u and v are the parameters along the caller's ray; in float64, then rounded to float32, which c
keeps at the precision of the mesh's own size), are traced against the mesh with the same
kernels, and are merged into the answers by the tie rule (smaller t, then lower (mesh, prim)).
The kernels here are the few small steps around those traces.
"""

import numpy as np

from .config import inline, jit
from .contracts import FLOAT, INDEX
from .geometry import cull_distance, intersect_box, inverse, triangle_normal
from .leaf import NO_HIT
from .query import CULL_BACK, CULL_FRONT
from .validation import MIN_PLACEMENT_SCALE

#: An instant whose inverse placement has a larger squared Frobenius norm scales an axis below
#: about MIN_PLACEMENT_SCALE (what a static placement may not): it is flat, as a singular one.
MAX_INVERSE_NORM2 = 1.0 / (MIN_PLACEMENT_SCALE * MIN_PLACEMENT_SCALE)

# The instance's box in scene space is grown by this, relative to its size and distance from
# the origin: a ray rounded into mesh space may reach a little beyond the exact placed box.
BOX_MARGIN = 1e-5


class Instance:
    """A mesh placed by an affine matrix, as a query traces it (``placed_instances`` makes them).

    mesh : its index in the scene
    packed : its ``Packed`` arrays in mesh space (ids are its face rows), relative to its frame
        centre ``packed.centre``; centre : the same (3,) as float64
    matrix : (4, 4) float64, the placement; to_mesh : (3, 4) float64, its inverse's top rows,
        the translation less the centre: scene space to the packed coordinates
    cofactor : (3, 3) float64, det(A) A^-T of the linear part A: takes a mesh-space normal
        (p1-p0)x(p2-p0) to the placed triangle's, orientation included; cofactors : the same as
        (1, 3, 3), as the merging kernels take one per ray or one for all
    mirrored : det(A) < 0, so back and front faces swap in mesh space
    matrix_end : None (static), or (4, 4) float64, the placement at the end of the frame's
        interval: at time tau the mesh is placed by (1 - tau) matrix + tau matrix_end
    box_start : (6,) float32, a box in scene space holding the triangles placed by ``matrix``;
        box : the same for every instant of the interval (the union of the placed boxes at 0
        and 1, which holds every interpolated placement)
    """

    def __init__(
        self, mesh, packed, matrix, matrix_end, to_mesh, cofactor, mirrored, box_start, box
    ):
        self.mesh = mesh
        self.packed = packed
        self.centre = packed.centre.astype(np.float64)
        self.matrix = matrix
        self.to_mesh = np.ascontiguousarray(to_mesh)
        self.cofactor = np.ascontiguousarray(cofactor)
        self.cofactors = np.ascontiguousarray(self.cofactor[None])
        self.mirrored = mirrored
        self.matrix_end = matrix_end
        self.moving = matrix_end is not None
        self.box_start = box_start
        self.box = box

    def flags(self, flags, mirrored=None):
        """The query's ``flags`` in mesh space: culling's back and front swap when mirrored
        (``mirrored``: this instance's own placement's, unless given)."""
        if not (self.mirrored if mirrored is None else mirrored):
            return flags
        cull = flags & (CULL_BACK | CULL_FRONT)
        swapped = (CULL_FRONT if cull & CULL_BACK else 0) | (CULL_BACK if cull & CULL_FRONT else 0)
        return (flags & ~(CULL_BACK | CULL_FRONT)) | swapped


def placed_instances(meshes, packs, matrices, ends):
    """An ``Instance`` of each of ``meshes`` (mesh indices), with its ``Packed`` in ``packs``, its
    placement in ``matrices`` and its end (None: static) in ``ends``, one entry a mesh: their
    inverses, cofactors and boxes made for all at once (a frame moves many)."""
    if not meshes:
        return []
    matrix = np.stack(matrices)
    centre = np.stack([packed.centre for packed in packs]).astype(np.float64)
    to_mesh = np.linalg.inv(matrix)[:, :3]
    to_mesh[:, :, 3] -= centre
    linear = matrix[:, :3, :3]
    det = np.linalg.det(linear)
    cofactor = det[:, None, None] * np.swapaxes(np.linalg.inv(linear), 1, 2)
    # Each mesh's box in its own coordinates (exact: the centre is added back in float64).
    box = np.stack([packed.box for packed in packs]).astype(np.float64) + np.tile(centre, 2)
    box_start = placed_boxes(box, matrix)
    boxes = list(box_start)
    moving = [k for k, end in enumerate(ends) if end is not None]
    if moving:
        end_boxes = placed_boxes(box[moving], np.stack([ends[k] for k in moving]))
        for k, end_box in zip(moving, end_boxes):
            lo = np.minimum(box_start[k, :3], end_box[:3])
            boxes[k] = np.concatenate([lo, np.maximum(box_start[k, 3:], end_box[3:])])
    return [
        Instance(
            mesh,
            packs[k],
            matrices[k],
            ends[k],
            to_mesh[k],
            cofactor[k],
            bool(det[k] < 0),
            box_start[k],
            boxes[k],
        )  # fmt: skip
        for k, mesh in enumerate(meshes)
    ]


#: Which of lo (0) or hi (1) each of a box's 8 corners takes along each axis: (8, 3).
CORNER_SIDES = np.array([[k >> a & 1 for a in range(3)] for k in range(8)])


def box_corners(boxes):
    """(K, 8, 3) float64 the corners of boxes (K, 6) (lo, hi)."""
    boxes = np.asarray(boxes, np.float64)
    return np.where(CORNER_SIDES == 1, boxes[:, None, 3:], boxes[:, None, :3])


def placed_points(points, matrices):
    """Points (K, m, 3) float64 placed by affine matrices (K, 4, 4): (K, m, 3)."""
    return points @ np.swapaxes(matrices[:, :3, :3], 1, 2) + matrices[:, None, :3, 3]


def placed_boxes(boxes, matrices):
    """Float32 boxes (K, 6) in scene space holding ``boxes`` (K, 6) float placed by
    ``matrices`` (K, 4, 4), grown by BOX_MARGIN."""
    placed = placed_points(box_corners(boxes), matrices)
    p_lo, p_hi = placed.min(axis=1), placed.max(axis=1)
    margin = BOX_MARGIN * (np.max(p_hi - p_lo, axis=1) + np.max(np.abs(placed), axis=(1, 2)))
    grown = np.concatenate([p_lo - margin[:, None], p_hi + margin[:, None]], axis=1)
    rounded = grown.astype(FLOAT)
    # Round outwards: float32 must not shrink the box.
    lo, hi = rounded[:, :3], rounded[:, 3:]
    rounded[:, :3] = np.where(lo > grown[:, :3], np.nextafter(lo, -np.inf), lo)
    rounded[:, 3:] = np.where(hi < grown[:, 3:], np.nextafter(hi, np.inf), hi)
    return rounded


# Instances per group of the box filter: a ray tests a group's box, then its members' boxes.
GROUP_SIZE = 4


def group_boxes(boxes):
    """Groups of GROUP_SIZE boxes (I, 6) float32, neighbours along the axis where the boxes'
    centres spread most: (order (I,) int64, the boxes in that order; group_lo (G + 1,) int64,
    group g's members order[group_lo[g]:group_lo[g + 1]]; group_boxes (G, 6) float32)."""
    centres = (boxes[:, :3] + boxes[:, 3:]) / 2
    axis = int(np.argmax(np.ptp(centres, axis=0))) if len(boxes) else 0
    order = np.argsort(centres[:, axis], kind="stable")
    group_lo = np.arange(0, len(boxes) + GROUP_SIZE, GROUP_SIZE).clip(max=len(boxes))
    group_lo = np.unique(group_lo)
    sorted_boxes = boxes[order]
    groups = np.array(
        [
            np.concatenate([sorted_boxes[lo:hi, :3].min(0), sorted_boxes[lo:hi, 3:].max(0)])
            for lo, hi in zip(group_lo[:-1], group_lo[1:])
        ],
        FLOAT,
    ).reshape(-1, 6)
    return order, group_lo.astype(np.int64), groups


# Rays a block of the box filter: a block's fields are copied to contiguous scratch so that the
# tests vectorise, and a group's boxes are skipped when no ray of the block reaches the group.
REACH_BLOCK = 256


@jit
def mark_rays_reaching(
    origins, directions, tmin, limit, ray_masks, box_masks, boxes, groups, group_lo, lo, hi,
    bits, counts,
):  # fmt: skip
    """For rays lo:hi, set bit b % 64 of bits[b // 64, i] (uint64 (W, n), written here for
    lo:hi) when ray i's segment [tmin, limit] reaches box b of ``boxes`` (I, 6) (grouped by
    ``group_boxes``: ``groups``, ``group_lo``) and, when ``ray_masks`` is not empty, its mask
    sees ``box_masks[b]``; add each box's rays to counts[b] (I,) int64. A limit of -inf (a
    finished occlusion ray) reaches nothing."""
    masked = ray_masks.shape[0] > 0
    ox = np.empty(REACH_BLOCK, FLOAT)
    oy = np.empty(REACH_BLOCK, FLOAT)
    oz = np.empty(REACH_BLOCK, FLOAT)
    ix = np.empty(REACH_BLOCK, FLOAT)
    iy = np.empty(REACH_BLOCK, FLOAT)
    iz = np.empty(REACH_BLOCK, FLOAT)
    t_lo = np.empty(REACH_BLOCK, FLOAT)
    t_hi = np.empty(REACH_BLOCK, FLOAT)
    masks = np.zeros(REACH_BLOCK, np.uint32)
    for start in range(lo, hi, REACH_BLOCK):
        n = min(REACH_BLOCK, hi - start)
        for j in range(n):
            i = start + j
            ox[j] = origins[i, 0]
            oy[j] = origins[i, 1]
            oz[j] = origins[i, 2]
            ix[j] = inverse(directions[i, 0])
            iy[j] = inverse(directions[i, 1])
            iz[j] = inverse(directions[i, 2])
            t_lo[j] = tmin[i]
            t_hi[j] = cull_distance(limit[i])
            if masked:
                masks[j] = ray_masks[i]
        block = bits[:, start : start + n]
        block[:] = 0
        for g in range(groups.shape[0]):
            x0, y0, z0, x1, y1, z1 = groups[g]
            reached = 0
            for j in range(n):
                reached += intersect_box(
                    ox[j], oy[j], oz[j], ix[j], iy[j], iz[j], t_lo[j], t_hi[j],
                    x0, y0, z0, x1, y1, z1,
                )  # fmt: skip
            if reached == 0:
                continue
            for b in range(group_lo[g], group_lo[g + 1]):
                x0, y0, z0, x1, y1, z1 = boxes[b]
                row = block[b >> 6]
                shift = np.uint64(b & 63)
                box_mask = box_masks[b]
                n_reached = 0
                for j in range(n):
                    hit = intersect_box(
                        ox[j], oy[j], oz[j], ix[j], iy[j], iz[j], t_lo[j], t_hi[j],
                        x0, y0, z0, x1, y1, z1,
                    )  # fmt: skip
                    if masked:
                        hit = hit and (masks[j] & box_mask) != 0
                    row[j] |= np.uint64(hit) << shift
                    n_reached += hit
                counts[b] += n_reached


@jit
def fill_rays_reaching(bits, lo, hi, ids, at):
    """Write the ids of rays lo:hi marked in ``bits`` (``mark_rays_reaching``) for each box b
    to ids[at[b]], ids[at[b] + 1], ... (in increasing order), advancing at[b]."""
    for i in range(lo, hi):
        for w in range(bits.shape[0]):
            word = bits[w, i]
            b = 64 * w
            while word != 0:
                if word & np.uint64(1):
                    ids[at[b]] = i
                    at[b] += 1
                word >>= np.uint64(1)
                b += 1


@inline
def ray_to_mesh_space(origins, directions, ray, to_mesh, out_o, out_d, i):
    """Ray ``ray`` by ``to_mesh`` (3, 4) float64 into row ``i`` of ``out_o``, ``out_d``: the
    origin by the affine map, the direction by its linear part, in float64 then rounded."""
    ox = np.float64(origins[ray, 0])
    oy = np.float64(origins[ray, 1])
    oz = np.float64(origins[ray, 2])
    dx = np.float64(directions[ray, 0])
    dy = np.float64(directions[ray, 1])
    dz = np.float64(directions[ray, 2])
    for a in range(3):
        out_o[i, a] = np.float32(
            to_mesh[a, 0] * ox + to_mesh[a, 1] * oy + to_mesh[a, 2] * oz + to_mesh[a, 3]
        )
        out_d[i, a] = np.float32(to_mesh[a, 0] * dx + to_mesh[a, 1] * dy + to_mesh[a, 2] * dz)


@jit
def rays_to_mesh_space(
    origins, directions, tmin, limit, ray_ids, to_mesh, out_o, out_d, out_tmin, out_tmax
):
    """Rays ``ray_ids`` of the batch in mesh space, into the (k, 3) and (k,) float32 ``out_``
    arrays: origin by ``to_mesh`` (3, 4) float64, the inverse affine map, direction by its
    linear part, in float64 then rounded; tmin as given, tmax from ``limit``."""
    for i in range(ray_ids.shape[0]):
        ray = ray_ids[i]
        ray_to_mesh_space(origins, directions, ray, to_mesh, out_o, out_d, i)
        out_tmin[i] = tmin[ray]
        out_tmax[i] = limit[ray]


def origins_near_box(origins, directions, to_mesh, box):
    """(k, 3) float32: rays (k, 3) float32 in scene space given in mesh space (by ``to_mesh``
    (3, 4) float64, in float64) with each origin moved along its ray to before the mesh's
    ``box`` (6,) float32, then rounded: to where the ray passes closest to the box's centre,
    less the box's diagonal and the centre's largest coordinate (more than the rounding).
    Every point of the line in the box lies beyond the moved origin, so a count of crossings
    is unchanged; the inside test's rays that would leave float32 go in so."""
    o = origins.astype(np.float64) @ to_mesh[:, :3].T + to_mesh[:, 3]
    d = directions.astype(np.float64) @ to_mesh[:, :3].T
    lo, hi = box[:3].astype(np.float64), box[3:].astype(np.float64)
    centre = 0.5 * (lo + hi)
    back = np.linalg.norm(hi - lo) + np.abs(centre).max()
    length2 = np.einsum("ij,ij->i", d, d)
    start = np.einsum("ij,ij->i", centre - o, d) / length2 - back / np.sqrt(length2)
    return (o + np.maximum(start, 0.0)[:, None] * d).astype(FLOAT)


@jit
def rays_to_mesh_space_at(
    origins,
    directions,
    tmin,
    limit,
    ray_ids,
    times,
    to_mesh,
    cofactor,
    start_sign,
    matrix,
    matrix_end,
    centre,
    out_o,
    out_d,
    out_tmin,
    out_tmax,
    out_cofactors,
    out_sign,
):
    """``rays_to_mesh_space`` for a moving instance: ray ``ray_ids[i]`` at its time tau
    (``times``) goes into the space of M(tau) = (1 - tau) ``matrix`` + tau ``matrix_end`` by
    M(tau)'s inverse, less ``centre`` (3,) float64, the mesh's frame centre (float64, then
    rounded), as ``to_mesh`` maps it at tau = 0; ``out_cofactors`` (k, 3, 3) gets M(tau)'s
    cofactor (the normals' map) and ``out_sign`` (k,) int8 the sign of its determinant (-1
    mirrored, 0 flat at that instant: singular, or an axis scaled below about
    MIN_PLACEMENT_SCALE). At tau == 0 exactly it uses the instance's own
    ``to_mesh`` and ``cofactor`` (``start_sign``: -1 where mirrored, else 1), so those rays are
    the static instance's bit for bit."""
    inv = np.empty((3, 4))
    cof = np.empty((3, 3))
    for i in range(ray_ids.shape[0]):
        ray = ray_ids[i]
        tau = np.float64(times[ray])
        if tau == 0.0:
            for a in range(3):
                for b in range(4):
                    inv[a, b] = to_mesh[a, b]
                for b in range(3):
                    cof[a, b] = cofactor[a, b]
            sign = start_sign
        else:
            # M(tau)'s linear rows r0, r1, r2 and translation; its cofactor has rows
            # r1 x r2, r2 x r0, r0 x r1, and its inverse is the cofactor's transpose / det.
            m = np.empty((3, 4))
            for a in range(3):
                for b in range(4):
                    m[a, b] = (1.0 - tau) * matrix[a, b] + tau * matrix_end[a, b]
            for a in range(3):
                p = (a + 1) % 3
                q = (a + 2) % 3
                cof[a, 0] = m[p, 1] * m[q, 2] - m[p, 2] * m[q, 1]
                cof[a, 1] = m[p, 2] * m[q, 0] - m[p, 0] * m[q, 2]
                cof[a, 2] = m[p, 0] * m[q, 1] - m[p, 1] * m[q, 0]
            det = m[0, 0] * cof[0, 0] + m[0, 1] * cof[0, 1] + m[0, 2] * cof[0, 2]
            sign = 1 if det > 0.0 else (-1 if det < 0.0 else 0)
            if sign != 0:
                norm2 = 0.0
                for a in range(3):
                    for b in range(3):
                        inv[a, b] = cof[b, a] / det
                        norm2 += inv[a, b] * inv[a, b]
                if not norm2 <= MAX_INVERSE_NORM2:  # flat up to rounding (NaN too)
                    sign = 0
                for a in range(3):
                    inv[a, 3] = (
                        -(inv[a, 0] * m[0, 3] + inv[a, 1] * m[1, 3] + inv[a, 2] * m[2, 3])
                        - centre[a]
                    )
        out_sign[i] = sign
        for a in range(3):
            for b in range(3):
                out_cofactors[i, a, b] = cof[a, b]
        out_tmin[i] = tmin[ray]
        out_tmax[i] = limit[ray]
        if sign == 0:  # no placement to go into: the caller drops the ray
            for a in range(3):
                out_o[i, a] = 0.0
                out_d[i, a] = 0.0
            continue
        ray_to_mesh_space(origins, directions, ray, inv, out_o, out_d, i)


@inline
def row_times(matrix, a, x, y, z):
    """Row ``a`` of ``matrix`` (3, 3) times (x, y, z), leaving out its zero entries: their
    products are zeros whose sign would turn a -0.0 of the sum to +0.0, so that an identity,
    or any permutation, gives the bits of (x, y, z) with their signs of zero."""
    total = -0.0  # -0.0 + s is s for every s, +0.0 and -0.0 included
    if matrix[a, 0] != 0.0:
        total += matrix[a, 0] * x
    if matrix[a, 1] != 0.0:
        total += matrix[a, 1] * y
    if matrix[a, 2] != 0.0:
        total += matrix[a, 2] * z
    return total


@inline
def placed_normal(tri_verts, row, cofactor):
    """The unit normal of mesh-space row ``row`` as placed: ``cofactor`` (3, 3) times
    (p1-p0)x(p2-p0), normalised, in float64."""
    nx, ny, nz = triangle_normal(tri_verts, row)
    px = row_times(cofactor, 0, nx, ny, nz)
    py = row_times(cofactor, 1, nx, ny, nz)
    pz = row_times(cofactor, 2, nx, ny, nz)
    inv_length = 1.0 / np.sqrt(px * px + py * py + pz * pz)
    return px * inv_length, py * inv_length, pz * inv_length


@jit
def placed_normals(tri_verts, rows, cofactors, normals):
    """``normals`` (k, 3) float32: the placed unit normal (``placed_normal``) of each row, by
    ``cofactors`` (k, 3, 3), one a row, or (1, 3, 3), one for all."""
    each = cofactors.shape[0] > 1
    for k in range(rows.shape[0]):
        cofactor = cofactors[k if each else 0]
        normals[k, 0], normals[k, 1], normals[k, 2] = placed_normal(tri_verts, rows[k], cofactor)


@jit
def merge_closest(
    ray_ids,
    found_t,
    found_tri,
    found_u,
    found_v,
    tri_verts,
    face_rows,
    mesh_index,
    cofactors,
    t,
    mesh,
    prim,
    u,
    v,
    normal,
    limit,
):
    """Merge an instance's closest hits (``found_``, by the instance's ray number; found_tri
    holds rows of ``tri_verts``, NO_HIT for none) into the answers by ray id: a hit wins where
    its t is smaller, or equal with a lower (mesh, prim), the tie rule of one trace. A winner's
    t (-0.0 as +0.0), mesh, prim (``face_rows`` of its row), u, v and placed normal are written,
    and its t becomes the ray's ``limit``. ``cofactors`` (k, 3, 3) holds the placement's cofactor
    per instance ray (a moving instance's), or (1, 3, 3) one for all."""
    each = cofactors.shape[0] > 1
    for i in range(ray_ids.shape[0]):
        row = found_tri[i]
        if row == NO_HIT:
            continue
        ray = ray_ids[i]
        hit_t = found_t[i] + np.float32(0.0)
        face = face_rows[row]
        better = hit_t < t[ray] or (
            hit_t == t[ray]
            and (mesh_index < mesh[ray] or (mesh_index == mesh[ray] and face < prim[ray]))
        )
        if not better:
            continue
        t[ray] = hit_t
        limit[ray] = hit_t
        mesh[ray] = mesh_index
        prim[ray] = face
        u[ray] = found_u[i]
        v[ray] = found_v[i]
        cofactor = cofactors[i if each else 0]
        normal[ray, 0], normal[ray, 1], normal[ray, 2] = placed_normal(tri_verts, row, cofactor)


def merge_hit_lists(n_rays, parts, max_hits):
    """Every level's hits of a ``hits`` query merged, per ray, in (t, mesh, prim) order and cut
    to ``max_hits``. ``parts`` holds (ray, t, mesh, prim, u, v, normal) arrays, one entry a
    hit, each level's at most max_hits + 1 nearest of a ray. Returns (offsets, t, mesh, prim,
    u, v, normal, truncated) as ``HitList`` holds them."""
    ray, t, mesh, prim, u, v, normal = (np.concatenate(column) for column in zip(*parts))
    order = np.lexsort((prim, mesh, t, ray))
    held = np.bincount(ray, minlength=n_rays)
    first = np.zeros(n_rays + 1, np.int64)
    np.cumsum(held, out=first[1:])
    rank = np.arange(len(order)) - first[ray[order]]
    order = order[rank < max_hits]
    offsets = np.zeros(n_rays + 1, np.int64)
    np.cumsum(np.minimum(held, max_hits), out=offsets[1:])
    return (
        offsets,
        t[order],
        mesh[order].astype(INDEX),
        prim[order].astype(INDEX),
        u[order],
        v[order],
        normal[order],
        held > max_hits,
    )
