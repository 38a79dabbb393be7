"""Input checks of the public API: shapes, dtypes and values, each error naming the first bad
index and how many there are. Everything past here assumes clean float32/int32 arrays; a ray
batch's values are checked as the kernels pack them (``rays.pack_rays``), and a bad batch is
named here (``explain_bad_rays``) before any answer is returned.

The checked arrays come in one layout, whatever the caller's were (``contracts.kernel_input``):
C-contiguous, aligned and writable, float32, int32 or int64 faces and uint32 masks, so that each
kernel compiles once (twice for faces)."""

import numpy as np

from .contracts import FLOAT, INDEX, STRATEGIES, kernel_input
from .query import CULL_MODES
from .triangles import all_finite, faces_in_range


class InputError(ValueError):
    """Input the engine refuses: the message names the argument (and the first bad index), in
    the caller's terms. A ``ValueError``, so callers that catch that keep working."""


class MeshSpaceError(InputError):
    """A ray that leaves float32's range moved into a placed mesh's space; ``mesh`` is that
    mesh's index in the scene (a caller with its own names for meshes can say which)."""

    def __init__(self, message: str, mesh: int) -> None:
        super().__init__(message)
        self.mesh = mesh


def _first_bad(bad, what, reason, total_label):
    """Raise InputError for a boolean mask ``bad`` if any entry is set."""
    bad_rows = np.flatnonzero(bad)
    if len(bad_rows):
        raise InputError(f"{what}[{bad_rows[0]}] {reason} ({len(bad_rows)} {total_label})")


#: The most rays (or points) of one call and triangles of one scene: both are int32 indices.
MAX_ROWS = 2**31 - 1


def check_row_count(n, name, what):
    """InputError naming ``name`` when it has more than MAX_ROWS ``what``."""
    if n > MAX_ROWS:
        raise InputError(
            f"{name} has {n:,} {what}; the engine indexes them in int32, so at most "
            f"{MAX_ROWS:,}: split them"
        )


def numeric_array(value, message):
    """``np.asarray(value)``, or InputError(``message``) where NumPy cannot make one array of
    it (ragged lists)."""
    try:
        return np.asarray(value)
    except (TypeError, ValueError, OverflowError):
        raise InputError(message) from None


def as_float_rows(array, name, width=3, check_finite=True, indexed=False):
    """``array`` as a float32 (n, width) array (``kernel_input``); finite values required;
    at most MAX_ROWS rows when ``indexed`` (rays and points), checked before any copy."""
    array = numeric_array(array, f"{name} must be an (n, {width}) array of numbers")
    if array.ndim != 2 or array.shape[1] != width:
        raise InputError(f"{name} must have shape (n, {width}), got {array.shape}")
    if indexed:
        check_row_count(len(array), name, "rows")
    if array.dtype.kind not in "fiu" or array.dtype.kind == "b":
        raise InputError(f"{name} must be a float array, got dtype {array.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):
        converted = kernel_input(array, FLOAT)
    if check_finite:
        _first_bad(
            ~np.isfinite(converted).all(axis=1),
            name,
            "has a non-finite value (or one too large for float32)",
            "rows are not finite",
        )
    return converted


def float64_points(points, name):
    """``points`` as a float64 (n, 3) array, each row finite; InputError naming ``name``."""
    array = numeric_array(points, f"{name} must be an (n, 3) array of numbers")
    if array.dtype.kind not in "fiu" or array.dtype.kind == "b":
        raise InputError(f"{name} must be an (n, 3) array of numbers, got dtype {array.dtype}")
    if array.ndim != 2 or array.shape[1] != 3:
        raise InputError(f"{name} must have shape (n, 3), got {array.shape}")
    array = array.astype(np.float64)
    _first_bad(~np.isfinite(array).all(axis=1), name, "is not finite", "rows are not finite")
    return array


def mesh_pairs(meshes):
    """(i, (vertices, faces)) of each entry of ``meshes``; InputError naming ``meshes`` when it
    is not a sequence, ``meshes[i]`` when an entry is not a pair."""
    try:
        entries = list(meshes)
    except TypeError:
        raise InputError(
            f"meshes must be a sequence of (vertices, faces) pairs, got {type(meshes).__name__}"
        ) from None
    pairs = []
    for i, entry in enumerate(entries):
        try:
            vertices, faces = entry
        except (TypeError, ValueError):
            raise InputError(
                f"meshes[{i}] must be a (vertices, faces) pair, got {type(entry).__name__}"
            ) from None
        pairs.append((i, (vertices, faces)))
    return pairs


def check_int_rows(values, name):
    """``values`` as a flat int64 array; InputError naming ``name`` unless integers."""
    array = numeric_array(values, f"{name} must be integers")
    if array.dtype.kind not in "iu":
        raise InputError(f"{name} must be integers, got {array.dtype}")
    return array.astype(np.int64).reshape(-1)


def check_hits(prim, u, v, n):
    """A hit's ``prim`` (int64) and ``u``, ``v`` (float64), flat, of ``n`` entries each;
    InputError naming the one that is not."""
    arrays = [check_int_rows(prim, "prim")]
    for values, name in ((u, "u"), (v, "v")):
        try:
            arrays.append(np.asarray(values, np.float64).reshape(-1))
        except (TypeError, ValueError):
            raise InputError(f"{name} must be numbers") from None
    for array, name in zip(arrays, ("prim", "u", "v"), strict=True):
        if len(array) != n:
            raise InputError(f"{name} has {len(array)} entries for {n} points")
    return arrays


def check_mesh(index, vertices, faces):
    """Validate one mesh; returns (vertices float32 (V, 3), faces int32 or int64 (F, 3)), as
    ``kernel_input`` gives them and ``owned``: never the caller's arrays."""
    label = f"mesh {index}"
    given_vertices, given_faces = vertices, faces
    vertices = vertex_array(vertices, f"{label}: vertices")
    faces = numeric_array(faces, f"{label}: faces must be an (F, 3) array of integers")
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(f"{label}: vertices must have shape (V, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        if faces.size == 0:
            faces = faces.reshape(0, 3)
        else:
            raise InputError(f"{label}: faces must have shape (F, 3), got {faces.shape}")
    check_row_count(len(faces), f"{label}: faces", "triangles")
    if faces.dtype.kind not in "iu":
        if faces.size == 0:
            faces = faces.astype(np.int64)
        else:
            raise InputError(f"{label}: faces must be an integer array, got dtype {faces.dtype}")
    converted = as_float_rows(vertices, f"{label}: vertices", check_finite=False)
    vertices = finite_vertices(converted, given_vertices, f"{label}: vertices")
    if faces.dtype == np.uint64 and faces.size and faces.max() >= len(vertices):
        explain_bad_faces(faces, len(vertices), f"{label}: faces")  # before int64 wraps them
    # Kernels take int32 and int64 faces (narrowing int64 would copy on every Scene); other
    # integer types become int64.
    faces = kernel_input(faces, None if faces.dtype in (INDEX, np.int64) else np.int64)
    if not faces_in_range(faces, len(vertices)):
        explain_bad_faces(faces, len(vertices), f"{label}: faces")
    return vertices, owned(faces, given_faces)


def vertex_array(vertices, name):
    """``vertices`` as an ndarray (``numeric_array``); an empty one as (0, 3), no vertices, as
    an empty ``faces`` is no faces."""
    array = numeric_array(vertices, f"{name} must be a (V, 3) array of numbers")
    return array.reshape(0, 3) if array.size == 0 else array


def finite_vertices(converted, given, name):
    """``converted`` (float32 (V, 3), checked from the caller's ``given``) as ``owned``, or
    InputError naming the first of its vertices that is not finite (``explain_bad_vertices``)."""
    if not all_finite(converted):
        explain_bad_vertices(converted, name, given=given)
    return owned(converted, given)


def owned(array, given):
    """``array``, checked from the caller's ``given``, as an array of its own: a copy where it
    may still be ``given``'s memory (``kernel_input`` keeps an array already in its layout), so
    that the caller may reuse its buffers while a Scene keeps reading the arrays."""
    if isinstance(given, list | tuple) or not np.may_share_memory(array, given):
        return array  # NumPy made it afresh
    return array.copy()


def explain_bad_vertices(vertices, name="vertices", given=None):
    """Raise ValueError naming the first row of ``vertices`` (V, 3) float that is not finite,
    with its values as the caller's ``given`` array (None: ``vertices``) holds them (a finite
    float64 may be too large for float32), and how many there are (a slow path, for an array
    known to hold one); does nothing if all are finite."""
    rows = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if len(rows):
        shown = vertices if given is None else np.asarray(given).reshape(vertices.shape)
        raise InputError(
            f"{name}[{rows[0]}] is not finite (or too large for float32): "
            f"{shown[rows[0]].tolist()}; {rows.size} of {len(vertices)} vertices are not finite"
        )


def explain_bad_faces(faces, n_vertices, name="faces"):
    """Raise ValueError naming the first row of ``faces`` (F, 3) integer with an index outside
    [0, n_vertices), that index, and how many rows there are (a slow path, for an array known to
    hold one); does nothing if every index is in range."""
    rows = np.flatnonzero(((faces < 0) | (faces >= n_vertices)).any(axis=1))
    if len(rows):
        row = faces[rows[0]]
        value = row[(row < 0) | (row >= n_vertices)][0]
        raise InputError(
            f"{name}[{rows[0]}] refers to vertex {value}, but there are {n_vertices} "
            f"vertices; {rows.size} of {len(faces)} faces are out of range"
        )


# The kernels' tmax for "no limit": a t that rounds to inf in float32 (a hit beyond float32's
# range, as from a direction of subnormal length) is then a miss, never a hit at t = inf.
LARGEST_T = np.finfo(FLOAT).max


def check_rays(origins, directions, tmin, tmax):
    """Check a ray batch's shapes and dtypes; returns float32 origins, directions, tmin, tmax
    (``kernel_input``: the columns of one (n, 6) array are copied) and ``empty``: None, or
    (n,) bool, the rays whose window holds no float32 (``ray_window``), which must see nothing
    (``hide_rays``). The values are checked as the kernels pack them (``rays.pack_rays``);
    ``explain_bad_rays`` then names a bad one."""
    origins = as_float_rows(origins, "origins", check_finite=False, indexed=True)
    directions = as_float_rows(directions, "directions", check_finite=False, indexed=True)
    n = len(origins)
    if len(directions) != n:
        raise InputError(f"origins has {n} rows but directions has {len(directions)}")
    tmin, tmax, empty = ray_window(tmin, tmax, n)
    if (tmax > LARGEST_T).any():
        tmax = np.minimum(tmax, LARGEST_T)  # a copy: the caller's array stays as it was
    return origins, directions, tmin, tmax, empty


def ray_window(tmin, tmax, n):
    """Each ray's [tmin, tmax] as float32 (n,) arrays, rounded inward where float32 cannot hold
    a bound (tmin up, tmax down), so that every float32 t within it is within the bounds as
    given, and ``empty``: None, or (n,) bool, the rays whose window, tmin <= tmax as given,
    holds no float32 (both bounds between the same two neighbours); their float32 window is
    [tmax, tmax], and they must see nothing (``hide_rays``)."""
    lo = _ray_range(tmin, 0.0, n, "tmin", toward=np.inf)
    hi = _ray_range(tmax, LARGEST_T, n, "tmax", toward=-np.inf)
    crossed = lo > hi
    if not crossed.any():
        return lo, hi, None
    given_lo = 0.0 if tmin is None else np.asarray(tmin, np.float64)
    given_hi = np.inf if tmax is None else np.asarray(tmax, np.float64)
    # else tmin > tmax as given, or tmin beyond float32's range: refused
    empty = crossed & (given_lo <= given_hi) & np.isfinite(lo)
    if not empty.any():
        return lo, hi, None
    return np.where(empty, hi, lo), hi, empty


def hide_rays(ray_masks, empty, n):
    """The rays' masks (None: all ones) with 0 for the rays ``empty`` (None: none), so that
    they see nothing; None where no ray is hidden and none was given."""
    if empty is None:
        return ray_masks
    masks = np.full(n, 0xFFFFFFFF, np.uint32) if ray_masks is None else ray_masks.copy()
    masks[empty] = 0
    return masks


def explain_bad_rays(origins, directions, tmin, tmax):
    """Raise ValueError naming the first bad ray of a batch and how many there are (a slow
    path, for a batch known to hold one); does nothing for a valid batch."""
    as_float_rows(origins, "origins")
    as_float_rows(directions, "directions")
    _first_bad(~directions.any(axis=1), "directions", "is zero", "zero directions")
    _first_bad(~np.isfinite(tmin), "tmin", "is not finite", "non-finite tmin")
    _first_bad(np.isnan(tmax), "tmax", "is NaN", "NaN tmax")
    _first_bad(tmin > tmax, "tmin", "is greater than tmax", "rays with tmin > tmax")


def _ray_range(value, default, n, name, toward=None):
    """A scalar or (n,) bound as a float32 (n,) array, each value rounded to the nearest float32
    or, with ``toward`` (inf or -inf), to the next one that way: a window's bounds round inward,
    so that a t within the float32 window is within the caller's."""
    if value is None:
        return np.full(n, default, FLOAT)
    value = numeric_array(value, f"{name} must be a number or a float array")
    if value.dtype.kind not in "fiu" or value.dtype.kind == "b":
        raise InputError(f"{name} must be a number or a float array, got dtype {value.dtype}")
    if value.ndim != 0 and value.shape != (n,):
        raise InputError(f"{name} must be a scalar or have shape ({n},), got {value.shape}")
    with np.errstate(over="ignore"):
        bound = np.full(n, value, FLOAT) if value.ndim == 0 else kernel_input(value, FLOAT)
    if toward is None or np.can_cast(value.dtype, FLOAT):  # float32 holds every value as given
        return bound
    given = value.astype(np.float64)
    rounded_out = bound < given if toward > 0 else bound > given  # NaN is neither
    if rounded_out.any():
        bound = np.where(rounded_out, np.nextafter(bound, FLOAT(toward)), bound)
    return bound


def check_time(time, n):
    """Each ray's instant in the frame's interval: None (every ray at 0), a number, or (n,)
    float, finite and in [0, 1]; returns float32 (n,) or None. InputError naming ``time``."""
    if time is None:
        return None
    times = _ray_range(time, 0.0, n, "time")
    # the range is that of the values given: one just outside [0, 1] may round into it
    given = np.broadcast_to(np.asarray(time, np.float64), (n,))
    bad = np.flatnonzero(~((given >= 0) & (given <= 1)))  # NaN fails both
    if len(bad):
        raise InputError(
            f"time[{bad[0]}] is {given[bad[0]]}: each time must be finite and in [0, 1] "
            f"({len(bad)} rays)"
        )
    return times


def check_strategy(strategy):
    if not isinstance(strategy, str) or strategy not in STRATEGIES:
        raise InputError(f"unknown strategy {strategy!r}; use one of {', '.join(STRATEGIES)}")
    return strategy


def check_threads(threads, n_cores):
    if threads is None:
        return n_cores
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise InputError(f"threads must be a positive integer or None, got {threads!r}")
    return int(threads)


def check_vertices_end(i, end, vertices, matrix, matrix_end):
    """Mesh i's vertices at the end of the interval as float32 (V, 3), ``owned``: as many rows
    as its ``vertices``, finite, on a mesh with no placement (``check_unplaced``). InputError
    naming ``vertices_end[i]``."""
    name = f"vertices_end[{i}]"
    check_unplaced(i, matrix, matrix_end)
    if end is None or isinstance(end, str | bytes):
        raise InputError(f"{name} must be a (V, 3) array of numbers")
    try:
        converted = as_float_rows(vertex_array(end, name), name, check_finite=False)
    except (TypeError, ValueError) as error:
        if isinstance(error, InputError):
            raise
        raise InputError(f"{name} must be a (V, 3) array of numbers") from None
    if len(converted) != len(vertices):
        raise InputError(f"{name} has {len(converted)} rows; mesh {i} has {len(vertices)} vertices")
    return finite_vertices(converted, end, name)


def check_unplaced(i, matrix, matrix_end):
    """InputError naming ``vertices_end[i]`` unless mesh i has no placement (``matrix``,
    ``matrix_end``: its transforms, None for none): a deforming mesh is given in scene space."""
    if matrix is not None or matrix_end is not None:
        raise InputError(
            f"vertices_end[{i}]: mesh {i} is placed (transforms[{i}] or transforms_end[{i}]); a "
            f"deforming mesh takes no placement, give its vertices in scene space"
        )


#: The least scale a placement may have along any axis: rays move into a mesh's space by its
#: inverse, which would put ordinary coordinates beyond float32's range.
MIN_PLACEMENT_SCALE = 1e-12


def check_transform(matrix, name="matrix"):
    """A 4x4 row-major affine placement as float64 (4, 4): finite, last row exactly
    [0, 0, 0, 1], its 3x3 part invertible and scaling no axis below MIN_PLACEMENT_SCALE.
    ValueError naming ``name`` otherwise."""
    try:
        matrix = np.asarray(matrix)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a 4x4 array of numbers") from None
    if matrix.dtype.kind not in "fiu":  # complex, text, objects: no real number to take
        raise InputError(f"{name} must be a 4x4 array of real numbers, got dtype {matrix.dtype}")
    matrix = matrix.astype(np.float64)
    if matrix.shape != (4, 4):
        raise InputError(f"{name} must have shape (4, 4), got {matrix.shape}")
    if not np.isfinite(matrix).all():
        raise InputError(f"{name} has a non-finite entry")
    if not np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"{name} is not affine: its last row must be [0, 0, 0, 1]")
    linear = matrix[:3, :3]
    # Singular up to rounding: the determinant against the scale of the rows.
    scale = np.prod(np.linalg.norm(linear, axis=1))
    det = abs(np.linalg.det(linear))
    if not det > 1e-12 * scale:
        raise InputError(f"{name} is singular: its 3x3 part has no inverse")
    # The least singular value is at least det / (the sum of squares): an SVD only below that.
    if det >= MIN_PLACEMENT_SCALE * (linear * linear).sum():
        return matrix
    smallest = np.linalg.svd(linear, compute_uv=False)[-1]
    if not smallest >= MIN_PLACEMENT_SCALE:
        raise InputError(
            f"{name} scales an axis by {smallest:.3g}, under {MIN_PLACEMENT_SCALE:g}: rays moved "
            "into its mesh's space would leave float32's range"
        )
    return matrix


def check_transforms(matrices, name_of):
    """``check_transform`` of each of ``matrices`` (a list), made for all at once (a frame
    places many): a list of float64 (4, 4); the error names ``name_of(k)`` for the k-th."""
    checked = np.empty((len(matrices), 4, 4))
    n_read = len(matrices)  # those before the first one that is no (4, 4) array of numbers
    for k, matrix in enumerate(matrices):
        if isinstance(matrix, np.ndarray) and matrix.shape == (4, 4) and matrix.dtype.kind in "fiu":
            checked[k] = matrix
            continue
        try:
            checked[k] = check_transform(matrix, name_of(k))
        except InputError:
            n_read = k  # named below, unless one before it is bad too
            break
    stack = checked[:n_read]
    linear = stack[:, :3, :3]
    with np.errstate(all="ignore"):  # a bad matrix is named by check_transform below
        scale = np.prod(np.linalg.norm(linear, axis=2), axis=1)
        det = np.abs(np.linalg.det(linear))
        good = (
            np.isfinite(stack).all(axis=(1, 2))
            & (stack[:, 3] == (0.0, 0.0, 0.0, 1.0)).all(axis=1)
            & (det > 1e-12 * scale)
            & (det >= MIN_PLACEMENT_SCALE * (linear * linear).sum(axis=(1, 2)))
        )
    for k in np.flatnonzero(~good):
        stack[k] = check_transform(matrices[k], name_of(k))  # raises, or passes the SVD's test
    if n_read < len(matrices):
        check_transform(matrices[n_read], name_of(n_read))  # raises
    return list(checked)


def place_vertices(vertices, matrix, name):
    """``vertices`` (V, 3) moved by the affine ``matrix`` (``check_transform``) in float64,
    as float32; ValueError naming ``name`` if a placed vertex leaves the float32 range."""
    placed = vertices.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
    with np.errstate(over="ignore"):
        placed = placed.astype(FLOAT)
    bad = np.flatnonzero(~np.isfinite(placed).all(axis=1))
    if len(bad):
        raise InputError(
            f"{name} places vertex {bad[0]} beyond the float32 range ({len(bad)} vertices)"
        )
    return placed


#: The most hits a ray's list keeps (its count, one more, is an int32).
MAX_HITS = 2**31 - 2
#: The most sample directions of an inside test (``nsamples``).
MAX_NSAMPLES = 2**24 - 1


def check_max_hits(max_hits):
    """``max_hits`` as an int: a positive integer, not a bool; more than MAX_HITS keeps every
    hit as MAX_HITS does (a ray crosses fewer triangles than a scene can hold)."""
    if isinstance(max_hits, bool) or not isinstance(max_hits, int | np.integer) or max_hits < 1:
        raise InputError(f"max_hits must be a positive integer, got {max_hits!r}")
    return min(int(max_hits), MAX_HITS)


def check_cull(cull):
    if not isinstance(cull, str) or cull not in CULL_MODES:
        raise InputError(f"unknown cull {cull!r}; use one of {', '.join(CULL_MODES)}")
    return cull


def check_masks(masks, n, name, what):
    """A mask per item as a uint32 (n,) array: ``masks`` an integer scalar (every item) or (n,)
    integer array with values in [0, 2**32); ``what`` names the items in the error."""
    masks = numeric_array(masks, f"{name} must be an integer (uint32) array")
    if masks.dtype.kind not in "iu":
        raise InputError(f"{name} must be an integer (uint32) array, got dtype {masks.dtype}")
    if masks.ndim == 0:
        if not 0 <= int(masks) <= 0xFFFFFFFF:
            raise InputError(f"{name} is {int(masks)}, outside the uint32 range [0, 2**32)")
        masks = np.full(n, masks)
    if masks.shape != (n,):
        raise InputError(
            f"{name} must be a scalar or have shape ({n},), one per {what}, got {masks.shape}"
        )
    if masks.dtype != np.uint32:
        _first_bad(
            (masks < 0) | (masks > 0xFFFFFFFF),
            name,
            "is outside the uint32 range [0, 2**32)",
            "out of range",
        )
    return kernel_input(masks, np.uint32)


def check_points(points):
    """Query points as a writable float32 (n, 3) C-contiguous array, each row finite; a
    read-only one (a server's body) is copied, so the kernels have one signature."""
    points = as_float_rows(points, "points", indexed=True)
    return points if points.flags.writeable else points.copy()


def check_max_distance(max_distance):
    """``max_distance`` as a float: None (no limit: inf) or a number >= 0."""
    if max_distance is None:
        return np.inf
    if isinstance(max_distance, bool) or not isinstance(max_distance, int | float | np.number):
        raise InputError(f"max_distance must be a number or None, got {max_distance!r}")
    try:
        limit = float(max_distance)
    except OverflowError:  # an integer beyond float64's range
        limit = np.inf if max_distance > 0 else -np.inf
    if not limit >= 0:  # NaN too
        raise InputError(f"max_distance must be >= 0, got {max_distance!r}")
    # distances are float32: beyond its largest number a limit is no limit
    return limit if limit <= float(LARGEST_T) else np.inf


def check_nsamples(nsamples):
    """``nsamples`` as an int: a positive odd integer (a majority of votes always exists) up to
    MAX_NSAMPLES."""
    if (
        isinstance(nsamples, bool)
        or not isinstance(nsamples, int | np.integer)
        or not 1 <= nsamples <= MAX_NSAMPLES
        or nsamples % 2 == 0
    ):
        raise InputError(
            f"nsamples must be a positive odd integer up to {MAX_NSAMPLES}, got {nsamples!r}"
        )
    return int(nsamples)
