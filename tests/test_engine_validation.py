"""Invalid input raises ValueError, and the message names the first bad index and how many there
are.

Bad rows are placed at FIRST_BAD and after it, N_BAD of them in all; numbers chosen so that they
cannot appear in a message by accident.
"""

from __future__ import annotations

import re
import sys

import numpy as np
import procedural as pg
import pytest

import dacrt
from dacrt.validation import MAX_ROWS, check_row_count

N_RAYS = 400
FIRST_BAD = 137
N_BAD = 11
BAD_ROWS = np.r_[
    FIRST_BAD,
    np.random.default_rng(0).choice(np.arange(FIRST_BAD + 1, N_RAYS), N_BAD - 1, replace=False),
]


def _mesh():
    return pg.triangle_soup(1500, np.random.default_rng(1))


def _rays():
    return pg.mixed_rays([[0, 0, 0], [1, 1, 1]], N_RAYS, np.random.default_rng(2))


def _mentions(message, *numbers):
    for number in numbers:
        assert re.search(rf"(?<![\d.]){re.escape(str(number))}(?![\d.])", message), (
            f"{number} not in message: {message!r}"
        )


def _run(query, meshes, origins, directions, tmin=None, tmax=None, **kwargs):
    """Build the scene and run the query (validation may happen at either step)."""
    scene = dacrt.Scene(meshes)
    return getattr(scene, query)(origins, directions, tmin, tmax, **kwargs)


QUERIES = ["closest", "occluded"]


# ---------------------------------------------------------------------------------------------
# Rays
# ---------------------------------------------------------------------------------------------


def _with_bad_rows(array, value, column=1):
    array = array.copy()
    array[BAD_ROWS, column] = value
    return array


RAY_CASES = {
    "origin_nan": lambda o, d: (_with_bad_rows(o, np.nan), d, None, None),
    "origin_inf": lambda o, d: (_with_bad_rows(o, np.inf, 2), d, None, None),
    "origin_too_large_for_float32": lambda o, d: (
        _with_bad_rows(o.astype(np.float64), 1e39),
        d,
        None,
        None,
    ),
    "direction_nan": lambda o, d: (o, _with_bad_rows(d, np.nan, 0), None, None),
    "direction_neg_inf": lambda o, d: (o, _with_bad_rows(d, -np.inf), None, None),
    "direction_zero": lambda o, d: (
        o,
        _with_bad_rows(_with_bad_rows(_with_bad_rows(d, 0.0, 0), 0.0, 1), 0.0, 2),
        None,
        None,
    ),
    "tmin_gt_tmax": lambda o, d: (
        o,
        d,
        _with_bad_rows(np.zeros((N_RAYS, 2), np.float32), 2.0)[:, 1],
        np.ones(N_RAYS, np.float32),
    ),
    "tmin_nan": lambda o, d: (
        o,
        d,
        _with_bad_rows(np.zeros((N_RAYS, 2), np.float32), np.nan)[:, 1],
        None,
    ),
    "tmax_nan": lambda o, d: (
        o,
        d,
        None,
        _with_bad_rows(np.ones((N_RAYS, 2), np.float32), np.nan)[:, 1],
    ),
}


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize("case", sorted(RAY_CASES))
def test_bad_rays_name_first_index_and_count(case, query):
    origins, directions = _rays()
    o, d, tmin, tmax = RAY_CASES[case](origins, directions)
    with pytest.raises(ValueError) as info:
        _run(query, [_mesh()], o, d, tmin, tmax)
    _mentions(str(info.value), FIRST_BAD, N_BAD)


LAST_CHUNK_BAD = 39_871  # in the last of the chunks of a 40,000-ray batch on 2 threads


@pytest.mark.parametrize("strategy", dacrt.STRATEGIES)
@pytest.mark.parametrize("rays", ["camera", "mixed"])
@pytest.mark.parametrize("query", QUERIES)
def test_a_bad_ray_in_one_chunk_of_many_is_named(query, rays, strategy):
    """Each chunk checks its own rays as it packs them: one bad ray in the last chunk of a
    batch cut in several (camera rays: bands in input order; mixed rays: slabs of origins)
    still fails the whole query, naming it."""
    box = [[0, 0, 0], [1, 1, 1]]
    if rays == "camera":
        origins, directions = pg.camera_rays(box, 200, 200)
    else:
        origins, directions = pg.mixed_rays(box, 40_000, np.random.default_rng(3))
    origins, directions = origins[:40_000].copy(), directions[:40_000].copy()
    directions[LAST_CHUNK_BAD] = 0.0
    with pytest.raises(ValueError) as info:
        _run(query, [_mesh()], origins, directions, threads=2, strategy=strategy)
    _mentions(str(info.value), LAST_CHUNK_BAD, 1)
    assert "zero" in str(info.value)


@pytest.mark.parametrize("position", [0, 31, 32, 383, 384, N_RAYS - 1])
@pytest.mark.parametrize("query", QUERIES)
def test_a_single_bad_ray_is_found_anywhere_in_a_chunk(query, position):
    """The rays are packed and checked in blocks (32 rays): a lone bad ray at a block's first
    or last place, or in the short block at the end of the chunk, still fails the query."""
    origins, directions = _rays()
    origins = origins.copy()
    origins[position, 0] = np.nan
    with pytest.raises(ValueError) as info:
        _run(query, [_mesh()], origins, directions, threads=1)
    _mentions(str(info.value), position, 1)


@pytest.mark.parametrize("query", QUERIES)
def test_bad_rays_are_named_on_a_scene_without_triangles(query):
    origins, directions = _rays()
    o, d, _, _ = RAY_CASES["origin_nan"](origins, directions)
    empty = (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    with pytest.raises(ValueError) as info:
        _run(query, [empty], o, d)
    _mentions(str(info.value), FIRST_BAD, N_BAD)


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize("tmin,tmax", [(2.0, 1.0), (np.nan, None), (None, np.nan), (0.0, -1.0)])
def test_bad_scalar_ranges(tmin, tmax, query):
    origins, directions = _rays()
    with pytest.raises(ValueError):
        _run(query, [_mesh()], origins, directions, tmin, tmax)


def _shape_cases():
    o, d = _rays()
    return {
        "origins_2_columns": (o[:, :2], d, None, None),
        "origins_4_columns": (np.c_[o, o[:, :1]], d, None, None),
        "origins_1d": (o[0], d[:1], None, None),
        "origins_3d": (o[:, :, None], d, None, None),
        "directions_fewer_rows": (o, d[:-1], None, None),
        "tmin_wrong_length": (o, d, np.zeros(N_RAYS - 1, np.float32), None),
        "tmax_2d": (o, d, None, np.ones((N_RAYS, 1), np.float32)),
        "origins_complex": (o.astype(np.complex64), d, None, None),
        "directions_strings": (o, np.full((N_RAYS, 3), "x"), None, None),
    }


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize("case", sorted(_shape_cases()))
def test_bad_ray_shapes_and_dtypes(case, query):
    o, d, tmin, tmax = _shape_cases()[case]
    with pytest.raises(ValueError):
        _run(query, [_mesh()], o, d, tmin, tmax)


# ---------------------------------------------------------------------------------------------
# Meshes
# ---------------------------------------------------------------------------------------------


def _bad_vertices(value):
    """A soup whose vertices FIRST_BAD and N_BAD - 1 later ones (all referenced) are ``value``."""
    v, f = _mesh()
    v = v.copy()
    v[BAD_ROWS, 0] = value
    return v, f


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize("mesh_index", [0, 1])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_vertices_name_first_index_and_count(value, mesh_index, query):
    meshes = [_mesh(), _mesh()]
    meshes[mesh_index] = _bad_vertices(value)
    origins, directions = _rays()
    with pytest.raises(ValueError) as info:
        _run(query, meshes, origins, directions)
    _mentions(str(info.value), FIRST_BAD, N_BAD)


BAD_FACE = 1043
BAD_FACES = (BAD_FACE, 1044, 1200, 1300, 1499)  # 5 bad faces


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize("bad_vertex", [90211, 4500, -5])  # far out, one past the end, negative
def test_face_indices_out_of_range_name_face_and_vertex(bad_vertex, query):
    v, f = _mesh()  # 4500 vertices, 1500 faces
    f = f.copy()
    f[list(BAD_FACES), 1] = bad_vertex
    origins, directions = _rays()
    with pytest.raises(ValueError) as info:
        _run(query, [(v, f)], origins, directions)
    _mentions(str(info.value), BAD_FACE, bad_vertex, len(BAD_FACES))


@pytest.mark.parametrize("query", QUERIES)
def test_bad_face_in_second_mesh(query):
    v, f = _mesh()
    bad = f.copy()
    bad[BAD_FACE, 2] = len(v)
    origins, directions = _rays()
    with pytest.raises(ValueError) as info:
        _run(query, [(v, f), (v, bad)], origins, directions)
    _mentions(str(info.value), BAD_FACE, len(v))


def _mesh_shape_cases():
    v, f = _mesh()
    return {
        "vertices_2_columns": (v[:, :2], f[f.max(axis=1) < len(v)]),
        "vertices_1d": (v.ravel(), f),
        "faces_4_columns": (v, np.c_[f, f[:, :1]]),
        "faces_1d": (v, f.ravel()),
        "faces_float": (v, f.astype(np.float32)),
        "faces_float64_integral": (v, f.astype(np.float64)),
        "faces_complex": (v, f.astype(np.complex64)),
        "vertices_complex": (v.astype(np.complex64), f),
    }


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize("case", sorted(_mesh_shape_cases()))
def test_bad_mesh_shapes_and_dtypes(case, query):
    mesh = _mesh_shape_cases()[case]
    origins, directions = _rays()
    with pytest.raises(ValueError):
        _run(query, [mesh], origins, directions)


# ---------------------------------------------------------------------------------------------
# Options
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize("strategy", ["bogus", ""])
def test_unknown_strategy(strategy, query):
    origins, directions = _rays()
    with pytest.raises(ValueError) as info:
        _run(query, [_mesh()], origins, directions, strategy=strategy)
    assert repr(strategy) in str(info.value) or strategy in str(info.value)


@pytest.mark.parametrize("query", QUERIES)
@pytest.mark.parametrize("threads", [0, -1, -8])
def test_threads_below_one(threads, query):
    origins, directions = _rays()
    with pytest.raises(ValueError) as info:
        _run(query, [_mesh()], origins, directions, threads=threads)
    _mentions(str(info.value), threads)


@pytest.mark.parametrize("query", QUERIES)
def test_valid_edge_values_are_accepted(query):
    """Not errors: tmin == tmax, tmax = inf, threads above the core count."""
    origins, directions = _rays()
    scene = dacrt.Scene([_mesh()])
    getattr(scene, query)(origins, directions, 0.5, 0.5)
    getattr(scene, query)(origins, directions, 0.0, np.inf)
    getattr(scene, query)(origins, directions, threads=64)


def _hit_at_one(query, tmin, tmax, **options):
    """Whether ``query`` sees the single triangle from (0.2, 0.2, 1) straight down, at t = 1
    exactly, with float64 rays and the window ``tmin``, ``tmax``."""
    scene = dacrt.Scene([pg.single_triangle()])
    o, d = np.array([[0.2, 0.2, 1.0]]), np.array([[0.0, 0.0, -1.0]])
    answer = getattr(scene, query)(o, d, tmin, tmax, **options)
    if query == "closest":
        return bool(answer.mesh[0] == 0 and answer.t[0] == 1)
    if query == "occluded":
        return bool(answer.occluded[0])
    return bool((answer.count if query == "count" else answer.counts)[0] == 1)


@pytest.mark.parametrize("query", ["closest", "occluded", "count", "hits"])
def test_float64_bounds_round_inward_so_t_stays_within_them(query):
    """A hit counts if tmin <= t <= tmax for the bounds as given: a float64 bound that float32
    cannot hold rounds inward (tmin up, tmax down), not to the nearest float32 (t = 1 there);
    a window that holds no float32 sees nothing; float32 bounds are taken as they are."""
    assert _hit_at_one(query, 1.0, 1.0)  # inclusive at both ends
    assert _hit_at_one(query, 0.99999999, 1.00000001)
    assert not _hit_at_one(query, 1.00000001, None)
    assert not _hit_at_one(query, None, 0.99999999)
    assert not _hit_at_one(query, np.array([1.00000001]), np.array([2.0]))
    assert not _hit_at_one(query, np.array([0.5]), np.array([0.99999999]))
    assert not _hit_at_one(query, 1.00000001, 1.00000002)  # no float32 between them
    assert not _hit_at_one(query, 1.00000001, 1.00000001, mask=[7])
    assert _hit_at_one(query, np.float32(1.00000001), np.float32(0.99999999))  # both 1.0
    with pytest.raises(dacrt.InputError, match="tmin"):
        _hit_at_one(query, 1.00000002, 1.00000001)  # tmin > tmax as given


def test_a_window_that_holds_no_float32_hides_only_its_ray():
    scene = dacrt.Scene([pg.single_triangle()])
    o = np.array([[0.2, 0.2, 1.0]] * 3)
    d = np.array([[0.0, 0.0, -1.0]] * 3)
    tmin = np.array([0.0, 1.00000001, 0.5])
    tmax = np.array([2.0, 1.00000002, 1.5])
    np.testing.assert_array_equal(scene.closest(o, d, tmin, tmax).mesh, [0, -1, 0])
    np.testing.assert_array_equal(scene.closest(o, d, tmin, tmax, mask=[1, 1, 0]).mesh, [0, -1, -1])


def _triangle_scene():
    return dacrt.Scene([pg.single_triangle()])


ORIGIN, DOWN = [[0.2, 0.2, 1.0]], [[0.0, 0.0, -1.0]]
MALFORMED = {
    "ragged origins": (lambda s: s.closest([[0, 0, 1], [0, 0]], DOWN * 2), "origins must be an"),
    "ragged directions": (lambda s: s.hits(ORIGIN * 2, [[0, 0, -1], [0, 0]]), "directions must be"),
    "ragged tmin": (lambda s: s.count(ORIGIN * 2, DOWN * 2, [[0], [0, 1]]), "tmin must be"),
    "ragged mask": (lambda s: s.occluded(ORIGIN * 2, DOWN * 2, mask=[[1], [1, 2]]), "mask must be"),
    "ragged points": (lambda s: s.nearest([[0, 0, 1], [0, 0]]), "points must be an"),
    "ragged vertices": (
        lambda s: dacrt.Scene([([[0, 0, 0], [1, 0]], [[0, 1, 0]])]),
        "mesh 0: vertices must be",
    ),
    "ragged faces": (
        lambda s: dacrt.Scene([(pg.single_triangle()[0], [[0, 1, 2], [0, 1]])]),
        "mesh 0: faces must be",
    ),
    "ragged new vertices": (
        lambda s: s.with_changes(vertices={0: [[0, 0, 0], [1, 0], [0, 1, 0]]}),
        r"vertices\[0\] must be",
    ),
    "cull array": (
        lambda s: s.closest(ORIGIN, DOWN, cull=np.array(["none", "back"])),
        "unknown cull",
    ),
    "strategy array": (
        lambda s: s.closest(ORIGIN, DOWN, strategy=np.array(["sah", "middle"])),
        "unknown strategy",
    ),
    "device array": (
        lambda s: s.count(ORIGIN, DOWN, device=np.array(["cpu", "cuda"])),
        "unknown device",
    ),
    "order array": (
        lambda s: dacrt.Scene([pg.single_triangle()], order=np.array(["auto", "file"])),
        "order must be one of",
    ),
    "transforms a number": (
        lambda s: dacrt.Scene([pg.single_triangle()], transforms=5),
        "transforms must be a sequence with a",
    ),
    "transforms_end a number": (
        lambda s: dacrt.Scene([pg.single_triangle()], transforms_end=5),
        "transforms_end must be a sequence with a",
    ),
    "vertices_end a number": (
        lambda s: dacrt.Scene([pg.single_triangle()], vertices_end=5),
        "vertices_end must be a sequence with a",
    ),
    "max_distance below float64's range": (
        lambda s: s.nearest(ORIGIN, -(10**400)),
        "max_distance must be >= 0",
    ),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_arguments_are_input_errors_naming_them(case):
    """Ragged lists, arrays for a name, a number for a sequence: InputError, not NumPy's or
    Python's own error."""
    call, words = MALFORMED[case]
    with pytest.raises(dacrt.InputError, match=words):
        call(_triangle_scene())


@pytest.mark.parametrize("mask", [-1, 2**32])
def test_a_scalar_mask_out_of_range_is_named_as_given(mask):
    scene = _triangle_scene()
    with pytest.raises(dacrt.InputError) as error:
        scene.with_changes(masks={0: mask})
    assert str(error.value) == f"masks[0] is {mask}, outside the uint32 range [0, 2**32)"
    with pytest.raises(dacrt.InputError, match=rf"^mask is {mask}, outside"):
        scene.closest(ORIGIN, DOWN, mask=mask)


def _compiled_signatures():
    """{kernel: signatures compiled} over every Numba dispatcher of dacrt's modules."""
    import numba

    counts = {}
    for name, module in list(sys.modules.items()):
        if name != "dacrt" and not name.startswith("dacrt."):
            continue
        for attr, value in vars(module).items():
            if isinstance(value, numba.core.registry.CPUDispatcher):
                counts[f"{value.py_func.__module__}.{attr}"] = len(value.signatures)
    return counts


def _read_only(array):
    array = np.array(array)
    array.flags.writeable = False
    return array


def _layouts(origins, directions):
    """The ray layouts callers hand the engine: (name, origins, directions, tmin, tmax, mask)."""
    n = len(origins)
    tmax = np.full(n, 50.0, np.float32)
    masks = np.where(np.arange(n) % 3 == 0, 1, 3).astype(np.uint32)  # mixed: the MASKED path
    wide = np.hstack([origins, directions, np.zeros((n, 1)), tmax[:, None]]).astype(np.float32)
    body = _read_only(wide)  # a server's (n, 8) npy body: read-only, columns in place
    return [
        ("arrays", origins, directions, None, None, None),
        ("read-only arrays", _read_only(origins), _read_only(directions), 0.0, 50.0, 3),
        ("columns", wide[:, :3], wide[:, 3:6], wide[:, 6], wide[:, 7], masks),
        ("read-only columns", body[:, :3], body[:, 3:6], body[:, 6], body[:, 7], None),
        (
            "read-only bounds and masks",
            origins,
            directions,
            _read_only(np.zeros(n, np.float32)),
            _read_only(tmax),
            _read_only(masks),
        ),
        (
            "float64, int64 masks",
            origins.astype(np.float64),
            directions.astype(np.float64),
            None,
            tmax.astype(np.float64),
            masks.astype(np.int64),
        ),
    ]


def _plain(value):
    """``value`` as a writable C-contiguous array of its own (None and scalars as they are)."""
    return value if value is None or np.ndim(value) == 0 else np.array(value, order="C")


@pytest.mark.parametrize("faces_as", ["int32", "int64", "uint16", "read-only int32"])
def test_every_input_layout_gives_the_same_answers_and_compiles_nothing(faces_as):
    """The checks hand the kernels one layout (C-contiguous and writable, float32, int32 or
    int64 faces, uint32 masks): after dacrt.warmup(), meshes and rays in every layout callers use
    compile no kernel (a server's bodies are read-only column views; a kernel compiled for them
    on a first request takes minutes), and each layout gives the answers of plain arrays of the
    same values."""
    dacrt.warmup()
    before = _compiled_signatures()
    vertices, faces = _mesh()
    faces = _read_only(faces) if faces_as == "read-only int32" else faces.astype(faces_as)
    scene = dacrt.Scene([(vertices, faces), (_read_only(vertices), faces)], masks=[1, 2])
    origins, directions = _rays()
    for query in ("closest", "occluded", "hits", "count"):
        for name, *arguments in _layouts(origins, directions):
            o, d, tmin, tmax, mask = arguments
            got = getattr(scene, query)(o, d, tmin, tmax, mask=mask, threads=1)
            plain = [_plain(value) for value in arguments]
            want = getattr(scene, query)(*plain[:4], mask=plain[4], threads=1)
            for key, value in vars(want).items():
                if isinstance(value, np.ndarray):
                    np.testing.assert_array_equal(getattr(got, key), value, err_msg=f"{name} {key}")
    after = _compiled_signatures()
    compiled = {k: n - before.get(k, 0) for k, n in after.items() if n != before.get(k, 0)}
    assert not compiled, f"kernels compiled for a layout the warm-up did not cover: {compiled}"


@pytest.mark.parametrize(
    "meshes, words",
    [
        (None, r"meshes must be a sequence of \(vertices, faces\) pairs, got NoneType"),
        ([None], r"meshes\[0\] must be a \(vertices, faces\) pair, got NoneType"),
        ([({"v": 1})], r"meshes\[0\] must be a \(vertices, faces\) pair, got dict"),
        ([pg.single_triangle() + (np.zeros((1, 3)),)], r"meshes\[0\] .* pair, got tuple"),
    ],
)
def test_a_mesh_entry_that_is_not_a_pair_is_named(meshes, words):
    with pytest.raises(dacrt.InputError, match=words):
        dacrt.Scene(meshes)


@pytest.mark.parametrize("index", [2**63, 2**64 - 1, 2**32 + 1, 3])
def test_an_unsigned_face_index_is_shown_as_given(index):
    """uint64 indices from 2**63 wrap to negative int64: the message shows the caller's value."""
    vertices, _ = pg.single_triangle()
    faces = np.array([[0, 1, index]], np.uint64)
    with pytest.raises(dacrt.InputError, match=rf"faces\[0\] refers to vertex {index},"):
        dacrt.Scene([(vertices, faces)])


def _huge(row, n):
    """(n, 3) rows all equal to ``row``, a view of 3 numbers (nothing of size n is allocated)."""
    return np.broadcast_to(np.asarray(row), (n, 3))


def test_more_rays_or_triangles_than_int32_indexes_are_refused_before_any_copy():
    """Rays, points and triangles are int32 indices in the kernels: 2**31 of them would wrap,
    so the call is refused naming the argument (the arrays here are views of one row)."""
    vertices, faces = pg.single_triangle()
    scene = dacrt.Scene([(vertices, faces)])
    too_many = 2**31
    origins = _huge(np.zeros(3, np.float32), too_many)
    directions = _huge(np.array([0, 0, 1], np.float32), too_many)
    for query in ("closest", "occluded", "count"):
        with pytest.raises(dacrt.InputError, match=r"origins has 2,147,483,648 rows; .* int32"):
            getattr(scene, query)(origins, directions)
    with pytest.raises(dacrt.InputError, match=r"points has 2,147,483,648 rows"):
        scene.nearest(origins)
    with pytest.raises(dacrt.InputError, match=r"mesh 0: faces has 2,147,483,648 triangles"):
        dacrt.Scene([(vertices, _huge(np.array([0, 1, 2], np.int32), too_many))])


def test_a_scene_of_more_triangles_than_int32_indexes_is_refused(monkeypatch):
    """The bound is on the scene's total, each mesh alone within it (the bound made small)."""
    monkeypatch.setattr(dacrt.validation, "MAX_ROWS", 10)
    vertices, faces = pg.triangle_soup(6, np.random.default_rng(4))
    assert dacrt.Scene([(vertices, faces)]).n_triangles == 6
    with pytest.raises(dacrt.InputError, match="the scene has 12 triangles; .* at most 10"):
        dacrt.Scene([(vertices, faces), (vertices, faces)])


def test_max_rows_is_the_most_rows_accepted():
    """MAX_ROWS rows are indexable by int32; one more is not."""
    check_row_count(MAX_ROWS, "a batch", "rays")
    with pytest.raises(dacrt.InputError, match="a batch has 2,147,483,648 rays"):
        check_row_count(MAX_ROWS + 1, "a batch", "rays")


@pytest.mark.parametrize("where", ["vertices", "with_changes", "vertices_end"])
def test_a_vertex_too_large_for_float32_is_named_with_its_value_as_given(where):
    """A finite float64 beyond float32's range is refused as rays' are: the argument, the row
    and the caller's value (not the inf it would round to)."""
    v, f = _mesh()
    big = v.astype(np.float64)
    big[FIRST_BAD, 1] = 1e39
    names = {
        "vertices": r"mesh 0: vertices",
        "with_changes": r"vertices\[0\]",
        "vertices_end": r"vertices_end\[0\]",
    }
    message = rf"{names[where]}\[{FIRST_BAD}\] is not finite \(or too large for float32\)"
    with pytest.raises(dacrt.InputError, match=message) as info:
        if where == "vertices":
            dacrt.Scene([(big, f)])
        elif where == "with_changes":
            dacrt.Scene([(v, f)]).with_changes(vertices={0: big})
        else:
            dacrt.Scene([(v, f)], vertices_end=[big])
    assert "1e+39" in str(info.value) and not re.search(r"\binf\b", str(info.value))


@pytest.mark.parametrize("vertices", [[], np.empty(0), np.empty((0, 3), np.float32)])
def test_an_empty_mesh_may_be_given_as_empty_lists(vertices):
    """No vertices written as ``[]`` is an empty mesh, as ``faces=[]`` is no faces."""
    scene = dacrt.Scene([(vertices, []), pg.single_triangle()])
    assert scene.n_triangles == 1 and scene.mesh_offsets.tolist() == [0, 0, 1]
    origins, directions = np.float32([[0.25, 0.25, 1.0]]), np.float32([[0.0, 0.0, -1.0]])
    hit = scene.closest(origins, directions)
    assert hit.mesh.tolist() == [1] and hit.t.tolist() == [1.0]
    moved = scene.with_changes(vertices={0: []}, vertices_end={0: []})
    assert moved.closest(origins, directions).mesh.tolist() == [1]
