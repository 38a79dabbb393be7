"""The wire format in-process: every body kind parses, every answer kind round-trips, and each
bad body gets the status and message the module docstring promises."""

from __future__ import annotations

import io
import json
import re
import tracemalloc
import zipfile
import zlib

import hostile_bodies
import numpy as np
import pytest
from service_helpers import grid, npy_bytes, npz_bytes, quad

from dacrt import InputError
from service import wire
from service.errors import BadBody, Invalid, NotAcceptable, TooLarge, UnsupportedMediaType


def rays6(n: int = 5) -> np.ndarray:
    rng = np.random.default_rng(n)
    return rng.normal(size=(n, 6)).astype(np.float32)


# ---- which format a body is in


@pytest.mark.parametrize(
    "content_type, fmt",
    [
        ("application/x-npy", "npy"),
        ("application/npy", "npy"),
        ("application/x-npz", "npz"),
        ("application/json; charset=utf-8", "json"),
        ("APPLICATION/JSON", "json"),
        ("model/obj", "obj"),
        ("application/ply", "ply"),
        ("model/stl", "stl"),
        ("model/gltf-binary", "glb"),
        ("model/off", "off"),
    ],
)
def test_content_type_picks_the_format(content_type, fmt):
    assert wire.resolve_format(content_type, None, wire.MESH_FORMATS + ("npy",)) == fmt


@pytest.mark.parametrize(
    "head, fmt",
    [
        (npy_bytes(rays6()), "npy"),
        (npz_bytes(a=np.zeros(1)), "npz"),
        (b'  {"a": 1}', "json"),
        (b"glTF\x02\x00\x00\x00", "glb"),
        (b"ply\nformat", "ply"),
        (b"OFF\n", "off"),
    ],
)
@pytest.mark.parametrize("content_type", [None, "application/octet-stream"])
def test_format_is_sniffed_without_a_content_type(head, fmt, content_type):
    assert wire.resolve_format(content_type, None, wire.MESH_FORMATS + ("npy",), head) == fmt


def test_format_parameter_overrides_content_type():
    assert wire.resolve_format("application/octet-stream", "OBJ", wire.MESH_FORMATS) == "obj"


@pytest.mark.parametrize("format", [" JSON ", "Json"])
def test_format_parameter_is_read_in_any_case_and_without_spaces(format):
    assert wire.resolve_format(None, format, wire.RAY_FORMATS, b"{}") == "json"


def test_an_empty_format_parameter_is_as_absent():
    """docs/API.md: the format then comes from Content-Type, else from the body's first bytes."""
    assert wire.resolve_format("application/json", "", wire.RAY_FORMATS) == "json"
    assert wire.resolve_format(None, "", wire.RAY_FORMATS, b"\x93NUMPY") == "npy"


@pytest.mark.parametrize(
    "content_type, format, accepted",
    [
        ("text/plain;charset=UTF-8", "json", wire.FRAME_FORMATS),
        ("application/x-www-form-urlencoded", "npz", wire.RAY_FORMATS),
        ("multipart/form-data; boundary=x", "json", wire.MESH_FORMATS),
        ("text/plain", "glb", wire.MESH_FORMATS),
        ("application/x-npy", "json", wire.RAY_FORMATS),
    ],
)
def test_a_content_type_other_than_the_format_named_is_415(content_type, format, accepted):
    """Pages on any site may send text/plain or form bodies without asking (CORS-safelisted):
    ``?format=`` never reads one as npy, npz or JSON, nor a body declared as another format."""
    with pytest.raises(UnsupportedMediaType, match="is not the format"):
        wire.resolve_format(content_type, format, accepted, b'{"a": 1}')


@pytest.mark.parametrize(
    "content_type, format",
    [("text/plain", "obj"), ("text/plain", "ply"), ("application/zip", "npz"), ("x/y", "json")],
)
def test_format_parameter_reads_a_text_file_or_an_unknown_type(content_type, format):
    assert wire.resolve_format(content_type, format, wire.MESH_FORMATS) == format


@pytest.mark.parametrize(
    "content_type, format, body",
    [
        ("text/plain", None, b"1 2 3"),
        ("application/x-www-form-urlencoded", None, b"a=1"),
        ("model/obj", None, b"v 0 0 0"),  # a known format this endpoint does not read
        (None, "xyz", b""),
        (None, None, b"v 0 0 0\nf 1 2 3"),  # OBJ cannot be sniffed
    ],
)
def test_unreadable_format_is_415_listing_the_choices(content_type, format, body):
    with pytest.raises(UnsupportedMediaType, match="application/x-npy"):
        wire.resolve_format(content_type, format, wire.RAY_FORMATS, body)


# ---- .npy and .npz


def test_npy_is_viewed_in_place():
    rays = rays6(7)
    body = npy_bytes(rays)
    array = wire.read_npy(body)
    assert np.array_equal(array, rays) and not array.flags.owndata and not array.flags.writeable
    assert np.shares_memory(array, np.frombuffer(body, np.uint8))


def test_npy_header_is_parsed_once_per_distinct_header():
    wire.npy._npy_header.cache_clear()
    for n in (3, 3, 4, 3):
        assert wire.read_npy(npy_bytes(rays6(n))).shape == (n, 6)
    assert (
        wire.npy._npy_header.cache_info().misses == 2
        and wire.npy._npy_header.cache_info().hits == 2
    )


def test_fortran_order_npy_keeps_its_values():
    rays = np.asfortranarray(rays6(4))
    assert np.array_equal(wire.read_npy(npy_bytes(rays)), rays)


def npy_with_header(header: str) -> bytes:
    header += " " * (63 - len(header) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + bytes(24)


def unclosed_header_npy() -> bytes:
    """A version 1.0 .npy whose header's dict is never closed (numpy's tokenizer fails on it)."""
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 6), "
    header += " " * (63 - len(header) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + bytes(24)


@pytest.mark.parametrize(
    "body, message",
    [
        (b"", "not a readable .npy"),
        (b"\x93NUMPY\x01\x00garbage", "not a readable .npy"),
        (npy_bytes(rays6(3))[:-5], "truncated"),
        (npy_bytes(rays6(3)) + b"xx", "longer than its header says"),
        (b"not an npy at all", "magic string is not correct"),
        (b"\x93NUMPY\x09\x00" + npy_bytes(rays6(3))[8:], r"unsupported .npy version \(9, 0\)"),
        (
            b"\x93NUMPY\x02\x00\xff\xff\xff\x7f" + npy_bytes(rays6(3))[10:],
            "header claims 2147483659 bytes",
        ),
        (unclosed_header_npy(), "not a readable .npy"),
        (
            npy_with_header("{'descr': '<f4', 'fortran_order': False, 'shape': (2**62, 6), }"),
            "not a readable .npy: its header holds an expression, not literals",
        ),
        # consistent headers (no elements, no data) whose shape numpy cannot make
        (hostile_bodies.npy_with_header("<f4", (2**62, 0)), "too big for an array"),
        (hostile_bodies.npy_with_header("<f8", (0, 2**60)), "too big for an array"),
        (hostile_bodies.npy_with_header("<f4", (0,) * 65), "65 axes, over the 64"),
    ],
)
def test_unreadable_npy_is_400(body, message):
    with pytest.raises(BadBody, match=message):
        wire.read_npy(body)


def test_object_array_is_422_and_never_unpickled():
    body = npy_bytes(np.array([{"a": 1}, None], dtype=object))
    with pytest.raises(Invalid, match="Python objects"):
        wire.read_npy(body)
    with pytest.raises(Invalid, match="Python objects"):
        wire.decode_rays(body, "npy")


@pytest.mark.parametrize("compressed", [False, True])
def test_npz_members_are_read(compressed):
    arrays = {"origins": rays6(4)[:, :3].copy(), "tmin": np.float32(0.5)}
    body = npz_bytes(compressed, **arrays)
    got = wire.read_npz(body)
    assert set(got) == set(arrays)
    assert all(np.array_equal(got[k], v) for k, v in arrays.items())
    # stored members are views of the body, deflated ones are decompressed once
    assert np.shares_memory(got["origins"], np.frombuffer(body, np.uint8)) != compressed


@pytest.mark.parametrize("expected", [None, 0, 10, 23, 24, 40])
def test_body_buffer_holds_the_chunks_in_order_whatever_the_expected_size(expected):
    chunks = [bytes(range(k, k + 8)) for k in (0, 8, 16)]  # 24 bytes
    body = wire.BodyBuffer(expected)
    for chunk in chunks:
        body.add(chunk)
    view = body.finish()
    assert bytes(view) == b"".join(chunks) and body.size == 24
    assert view.readonly  # views of it (rays, vertices) cannot be written, as views of bytes


@pytest.mark.parametrize("compressed", [False, True])
def test_npz_in_a_body_buffer_is_read_in_place(compressed):
    arrays = {"origins": rays6(4)[:, :3].copy(), "tmin": np.float32(0.5)}
    raw = npz_bytes(compressed, **arrays)
    body = wire.BodyBuffer(len(raw))
    for start in range(0, len(raw), 100):
        body.add(raw[start : start + 100])
    view = body.finish()
    got = wire.read_npz(view)
    assert all(np.array_equal(got[k], v) for k, v in arrays.items())
    assert np.shares_memory(got["origins"], np.asarray(view)) != compressed


def test_garbage_npz_is_400():
    with pytest.raises(BadBody, match="npz"):
        wire.read_npz(b"PK\x03\x04 not really a zip")


def test_npz_needing_a_newer_zip_version_is_400():
    body = bytearray(npz_bytes(False, origins=rays6(2)[:, :3].copy()))
    directory = body.rfind(b"PK\x01\x02")
    body[directory + 6] = 0x9F  # "version needed to extract": 15.9
    with pytest.raises(BadBody, match="not a readable .npz"):
        wire.read_npz(bytes(body))


def test_npz_over_the_size_limit_when_decompressed_is_413():
    body = npz_bytes(True, big=np.zeros(100_000, np.float32))
    assert len(body) < 10_000
    with pytest.raises(TooLarge, match="DACRT_MAX_BODY_BYTES"):
        wire.read_npz(body, max_bytes=10_000)


# ---- rays


@pytest.mark.parametrize("columns", [6, 8])
def test_npy_rays(columns):
    array = np.random.default_rng(0).uniform(0, 1, (9, columns)).astype(np.float32)
    rays = wire.decode_rays(npy_bytes(array), "npy")
    assert len(rays) == 9
    assert np.array_equal(rays.origins, array[:, :3]) and np.array_equal(
        rays.directions, array[:, 3:6]
    )
    if columns == 8:
        assert np.array_equal(rays.tmin, array[:, 6]) and np.array_equal(rays.tmax, array[:, 7])
    else:
        assert rays.tmin is None and rays.tmax is None


def test_npz_rays_with_one_tmax_for_the_batch():
    o, d = rays6(3)[:, :3], rays6(3)[:, 3:]
    rays = wire.decode_rays(npz_bytes(origins=o, directions=d, tmax=np.float32(2.5)), "npz")
    assert rays.tmax == 2.5 and rays.tmin is None and np.array_equal(rays.origins, o)


def test_json_rays_with_null_as_infinity():
    body = json.dumps(
        {
            "origins": [[0, 0, 0], [1, 1, 1]],
            "directions": [[0, 0, 1], [1, 0, 0]],
            "tmin": 0.5,
            "tmax": [2, None],
        }
    ).encode()
    rays = wire.decode_rays(body, "json")
    assert rays.origins.dtype == np.float32 and rays.tmin == 0.5
    assert rays.tmax.tolist() == [2.0, np.inf]


@pytest.mark.parametrize(
    "fmt, body",
    [
        ("npy", npy_bytes(np.zeros((0, 6), np.float32))),
        (
            "npz",
            npz_bytes(
                origins=np.zeros((0, 3), np.float32), directions=np.zeros((0, 3), np.float32)
            ),
        ),
        ("json", b'{"origins": [], "directions": []}'),
    ],
)
def test_empty_batch_is_valid(fmt, body):
    rays = wire.decode_rays(body, fmt)
    assert len(rays) == 0 and rays.origins.shape == (0, 3) and rays.directions.shape == (0, 3)


@pytest.mark.parametrize(
    "fmt, body, error, message",
    [
        (
            "npy",
            npy_bytes(np.zeros((4, 5), np.float32)),
            Invalid,
            r"\(N, 6\) or \(N, 8\), got \(4, 5\)",
        ),
        ("npy", npy_bytes(np.zeros((4, 6), np.float64)), Invalid, "float32, got <f8"),
        ("npy", npy_bytes(np.zeros((4, 6), ">f4")), Invalid, "little-endian float32, got >f4"),
        ("npz", npz_bytes(origins=np.zeros((2, 3), np.float32)), BadBody, "lacks 'directions'"),
        (
            "npz",
            npz_bytes(
                origins=np.zeros((2, 3), np.float32),
                directions=np.ones((2, 3), np.float32),
                weights=np.ones(2, np.float32),
            ),
            BadBody,
            "unknown keys 'weights'",
        ),
        (
            "npz",
            npz_bytes(origins=np.zeros((2, 3), np.float32), directions=np.ones((3, 3), np.float32)),
            Invalid,
            "origins has 2 rays but directions has 3",
        ),
        (
            "npz",
            npz_bytes(
                origins=np.zeros((2, 3), np.float32),
                directions=np.ones((2, 3), np.float32),
                tmax=np.ones(5, np.float32),
            ),
            Invalid,
            "tmax has 5 values but there are 2 rays",
        ),
        ("json", b'{"origins": [[0, 0]], "directions": [[0, 0, 1]]}', Invalid, r"shape \(N, 3\)"),
        ("json", b'{"origins": [[0, 0, "x"]], "directions": [[0, 0, 1]]}', Invalid, "numbers"),
        ("json", b"[1, 2]", BadBody, "must be an object"),
        ("json", b'{"origins": ', BadBody, "not valid JSON"),
    ],
)
def test_bad_ray_bodies(fmt, body, error, message):
    with pytest.raises(error, match=message):
        wire.decode_rays(body, fmt)


@pytest.mark.parametrize("fmt", ["npy", "json"])
def test_too_many_rays_is_413_naming_the_limit(fmt):
    body = (
        npy_bytes(rays6(11))
        if fmt == "npy"
        else json.dumps(
            {"origins": rays6(11)[:, :3].tolist(), "directions": rays6(11)[:, 3:].tolist()}
        ).encode()
    )
    with pytest.raises(TooLarge, match="11 rays .* limit of 10 .*DACRT_MAX_RAYS_PER_REQUEST"):
        wire.decode_rays(body, fmt, max_rays=10)


# ---- meshes


def test_npz_mesh_with_uint32_faces_becomes_int32_without_copy():
    vertices, faces = grid(3)
    mesh = wire.decode_mesh(npz_bytes(vertices=vertices, faces=faces.astype(np.uint32)), "npz")
    assert mesh.faces.dtype == np.int32 and np.array_equal(mesh.faces, faces)
    assert not mesh.faces.flags.owndata


def test_json_mesh():
    vertices, faces = quad(0, 1, 0, 1, 2)
    mesh = wire.decode_mesh(
        json.dumps({"vertices": vertices.tolist(), "faces": faces.tolist()}).encode(), "json"
    )
    assert np.array_equal(mesh.vertices, vertices) and np.array_equal(mesh.faces, faces)
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int32


def test_empty_mesh_is_valid():
    mesh = wire.decode_mesh(b'{"vertices": [], "faces": []}', "json")
    assert mesh.vertices.shape == (0, 3) and mesh.faces.shape == (0, 3)


def test_face_out_of_range_names_the_face_and_the_vertex_count():
    vertices = np.zeros((90000, 3), np.float32)
    faces = np.zeros((2000, 3), np.int32)
    faces[1043] = [5, 90211, 7]
    faces[1500] = [-1, 0, 0]
    with pytest.raises(InputError) as caught:  # the engine's words: 422 (errors.install)
        wire.decode_mesh(npz_bytes(vertices=vertices, faces=faces), "npz")
    assert str(caught.value) == (
        "faces[1043] refers to vertex 90211, but there are 90000 "
        "vertices; 2 of 2000 faces are out of range"
    )


def test_non_finite_vertex_names_the_vertex():
    vertices, faces = grid(2)
    vertices[4, 1] = np.nan
    vertices[7, 0] = np.inf
    with pytest.raises(InputError, match=r"vertices\[4\] is not finite .*2 of 9 vertices"):
        wire.decode_mesh(npz_bytes(vertices=vertices, faces=faces), "npz")


@pytest.mark.parametrize(
    "arrays, message",
    [
        (
            {"vertices": np.zeros((3, 3)), "faces": np.zeros((1, 3), np.int32)},
            "vertices must be little-endian float32",
        ),
        (
            {"vertices": np.zeros((3, 3), np.float32), "faces": np.zeros((1, 3), np.int64)},
            "faces must be little-endian int32 or uint32",
        ),
        (
            {"vertices": np.zeros((3, 2), np.float32), "faces": np.zeros((1, 3), np.int32)},
            r"vertices must have shape \(N, 3\)",
        ),
        (
            {"vertices": np.zeros((3, 3), np.float32), "faces": np.zeros((3,), np.int32)},
            r"faces must have shape \(F, 3\)",
        ),
    ],
)
def test_wrong_dtype_or_shape_is_422(arrays, message):
    with pytest.raises(Invalid, match=message):
        wire.decode_mesh(npz_bytes(**arrays), "npz")


def test_json_faces_must_be_integers():
    with pytest.raises(Invalid, match="faces must be integers"):
        wire.decode_mesh(b'{"vertices": [[0,0,0],[1,0,0],[0,1,0]], "faces": [[0, 1, 2.5]]}', "json")


def test_mesh_body_with_wrong_keys_is_400():
    with pytest.raises(BadBody, match="lacks 'faces'"):
        wire.decode_mesh(npz_bytes(vertices=np.zeros((3, 3), np.float32)), "npz")


def _two_object_scene():
    import trimesh

    box = trimesh.creation.box()
    sphere = trimesh.creation.icosphere(subdivisions=1)
    sphere.apply_translation([3, 0, 0])
    return trimesh.Scene({"box": box, "sphere": sphere}), len(box.faces) + len(sphere.faces)


@pytest.mark.parametrize("fmt", ["obj", "ply", "stl", "glb", "off"])
def test_mesh_files_are_read_and_merged(fmt):
    import trimesh

    scene, n_faces = _two_object_scene()
    if fmt == "off":  # trimesh writes OFF for one mesh only
        data = scene.to_mesh().export(file_type="off")
    else:
        data = scene.export(file_type=fmt)
    body = data.encode() if isinstance(data, str) else data
    mesh = wire.decode_mesh(body, fmt)
    assert len(mesh.faces) == n_faces
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int32
    np.testing.assert_allclose(mesh.vertices.min(0), [-0.5, -1, -1], atol=1e-5)
    np.testing.assert_allclose(mesh.vertices.max(0), [4, 1, 1], atol=1e-5)
    assert isinstance(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), trimesh.Trimesh)


@pytest.mark.parametrize(
    "fmt, body",
    [("obj", b"this is not an obj"), ("ply", b"garbage"), ("glb", b"glTF-garbage"), ("stl", b"")],
)
def test_unreadable_mesh_file_is_400(fmt, body):
    with pytest.raises(BadBody, match=fmt.upper()):
        wire.decode_mesh(body, fmt)


# ---- vertices, frames, one-shot


@pytest.mark.parametrize("fmt", ["npy", "npz", "json"])
def test_vertices_bodies(fmt):
    vertices = grid(2)[0]
    body = {
        "npy": lambda: npy_bytes(vertices),
        "npz": lambda: npz_bytes(vertices=vertices),
        "json": lambda: json.dumps({"vertices": vertices.tolist()}).encode(),
    }[fmt]()
    assert np.array_equal(wire.decode_vertices(body, fmt), vertices)


def test_frame_keys_split_at_the_last_dot():
    v, f = quad(0, 1, 0, 1, 0)
    frame = wire.decode_frame(
        npz_bytes(**{"car.body.vertices": v, "car.body.faces": f, "wheel.vertices": v}), "npz"
    )
    assert set(frame) == {"car.body", "wheel"}
    assert np.array_equal(frame["car.body"][1], f) and frame["wheel"][1] is None


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"car.faces": quad(0, 1, 0, 1, 0)[1]}, "car.faces but no car.vertices"),
        ({"car.normals": np.zeros((1, 3), np.float32)}, "not MESH.vertices or MESH.faces"),
        ({"vertices": np.zeros((1, 3), np.float32)}, "not MESH.vertices or MESH.faces"),
        ({}, "no MESH.vertices"),
    ],
)
def test_bad_frames_are_400(arrays, message):
    with pytest.raises(BadBody, match=message):
        wire.decode_frame(npz_bytes(**arrays), "npz")


def test_frame_faces_checked_against_their_vertices():
    v, f = quad(0, 1, 0, 1, 0)
    with pytest.raises(InputError, match=r"car.faces\[1\] refers to vertex 9, but there are 4"):
        wire.decode_frame(
            npz_bytes(**{"car.vertices": v, "car.faces": f + np.int32([[0, 0, 0], [0, 0, 6]])}),
            "npz",
        )


def test_one_shot_body():
    v, f = quad(0, 1, 0, 1, 0)
    o, d = rays6(2)[:, :3], rays6(2)[:, 3:]
    mesh, rays = wire.decode_trace(npz_bytes(vertices=v, faces=f, origins=o, directions=d), "npz")
    assert np.array_equal(mesh.faces, f) and np.array_equal(rays.directions, d)
    with pytest.raises(BadBody, match="lacks 'faces'"):
        wire.decode_trace(npz_bytes(vertices=v, origins=o, directions=d), "npz")


# ---- answers


@pytest.mark.parametrize(
    "accept, request_format, fmt",
    [
        (None, "npy", "npz"),
        ("", "json", "json"),
        ("*/*", "npz", "npz"),
        ("*/*", "json", "json"),
        ("application/*", "npy", "npz"),
        ("application/json", "npy", "json"),
        ("application/x-npy", "json", "npy"),
        ("application/x-npz;q=0.5, application/json", "npy", "json"),
        ("text/html, application/x-npz;q=0.9, */*;q=0.1", "json", "npz"),
        ("application/json;q=0, */*", "npy", "npz"),
        ("application/json;q=0, */*", "json", "npz"),
        ("application/x-npz;q=0, application/*", "npy", "npy"),
        ("application/x-npz;q=0, application/x-npy;q=0, */*;q=0.1", "npz", "json"),
        ("application/*;q=0, application/json;q=0.2", "json", "json"),
    ],
)
def test_accept_negotiation(accept, request_format, fmt):
    assert wire.negotiate(accept, request_format) == fmt


@pytest.mark.parametrize(
    "accept",
    [
        "application/json;q=0, application/x-npz;q=0, application/x-npy;q=0, */*",
        "application/*;q=0, */*",
        "*/*;q=0",
    ],
)
def test_a_type_refused_with_q_0_is_not_admitted_by_a_wildcard(accept):
    # RFC 9110 12.5.1: the most specific range that matches a type gives its quality
    with pytest.raises(NotAcceptable):
        wire.negotiate(accept, "json")


def test_check_accepts_takes_the_quality_of_the_most_specific_range():
    for accept in ("image/png;q=0, */*;q=0.1", "image/*;q=0, */*", "image/png;Q=0.0, image/*"):
        with pytest.raises(NotAcceptable, match="does not admit image/png"):
            wire.check_accepts(accept, "image/png")
    for accept in ("image/png;q=0.5, */*;q=0", "image/*, */*;q=0", "text/html, */*;q=0.1"):
        wire.check_accepts(accept, "image/png")


def test_unacceptable_accept_is_406():
    with pytest.raises(NotAcceptable, match="application/x-npz"):
        wire.negotiate("text/csv", "npy")


def test_a_406_lists_only_the_formats_of_its_answer():
    with pytest.raises(NotAcceptable, match="use application/x-npz or application/json$"):
        wire.negotiate("application/x-npy", "json", ("npz", "json"))
    lidar = "use application/x-npz, application/x-npy, application/json or application/x-pcd$"
    with pytest.raises(NotAcceptable, match=lidar):
        wire.negotiate("text/csv", "json", ("npz", "npy", "json", "pcd"))


def _answer(n: int = 6) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(n)
    t = rng.uniform(0, 10, n).astype(np.float32)
    t[::3] = np.inf
    normal = rng.normal(size=(n, 3)).astype(np.float32)
    return {
        "t": t,
        "mesh": np.where(np.isinf(t), -1, 2).astype(np.int32),
        "normal": normal[:, ::-1],
    }


@pytest.mark.parametrize("n", [0, 1, 6])
def test_npz_answer_is_a_valid_zip_that_numpy_reads(n):
    arrays = _answer(n)
    parts, length, media = wire.encode_answer(arrays, "npz")
    parts = list(parts)
    body = b"".join(parts)
    assert media == wire.NPZ and body == b"".join(wire.npz_parts(arrays)) and len(body) == length
    assert (
        any(
            isinstance(p, memoryview) and np.shares_memory(np.frombuffer(p, np.uint8), arrays["t"])
            for p in parts
        )
        or n == 0
    )  # the answer arrays are sent from their own memory
    assert zipfile.ZipFile(io.BytesIO(body)).testzip() is None  # every CRC is right
    with np.load(io.BytesIO(body), allow_pickle=False) as got:
        assert list(got.keys()) == list(arrays)
        for key, array in arrays.items():
            assert got[key].dtype == array.dtype and np.array_equal(got[key], array)


def test_npy_answer_single_field_and_structured():
    arrays = _answer()
    single = np.load(io.BytesIO(b"".join(wire.npy_parts({"t": arrays["t"]}))))
    assert np.array_equal(single, arrays["t"])
    record = np.load(io.BytesIO(b"".join(wire.npy_parts(arrays))))
    assert record.dtype.names == ("t", "mesh", "normal")
    assert all(np.array_equal(record[k], v) for k, v in arrays.items())


def test_json_answer_round_trips_float32_with_null_for_inf():
    arrays = _answer()
    document = json.loads(wire.encode_json(arrays))
    assert document["t"][0] is None and document["mesh"][0] == -1
    t = np.array([np.inf if x is None else x for x in document["t"]], np.float32)
    assert np.array_equal(t, arrays["t"])
    assert np.array_equal(np.array(document["normal"], np.float32), arrays["normal"])
    assert b"0.30000001" not in wire.encode_json({"t": np.float32([0.3])})  # shortest form


def test_npz_body_takes_each_crc_when_its_member_is_reached(monkeypatch):
    taken = []
    monkeypatch.setattr(
        wire.npz_writer,
        "crc32",
        lambda data, value=0: taken.append(len(data)) or zlib.crc32(data, value),
    )
    arrays = _answer(1000)
    body = wire.NpzBody(arrays)
    assert taken == []  # the length is known without any CRC
    parts = iter(body)
    first = next(parts)  # the first member's local header: its CRC, over its .npy header and data
    assert taken == [len(wire.npy_header(np.dtype(np.float32), (1000,))), 4000]
    whole = b"".join([first, *parts])
    assert len(taken) == 2 * len(arrays)
    assert whole == b"".join(wire.npz_parts(arrays)) and body.length == len(whole)


def test_npz_body_of_more_than_65535_members_reads_back():
    """A zip's end record counts members in 16 bits: more take zip64, as numpy writes it."""
    arrays = {f"s{i}.range": np.array([i], np.float32) for i in range(0x10000 + 2)}
    body = wire.NpzBody(arrays)
    whole = b"".join(body)
    assert body.length == len(whole)
    with np.load(io.BytesIO(whole)) as back:
        assert len(back.files) == len(arrays)
        assert back["s65537.range"][0] == 65537


def test_encode_answer_names_the_content_type_and_length():
    parts, length, media = wire.encode_answer({"occluded": np.array([True])}, "json")
    assert (b"".join(parts), length, media) == (b'{"occluded":[true]}', None, wire.JSON)
    parts, length, media = wire.encode_answer({"occluded": np.array([True])}, "npy")
    assert media == wire.NPY and length == sum(map(len, parts)) == 129


# ---- hostile .npy and .npz: a clear 4xx, at a cost bounded by the body limit


@pytest.mark.parametrize(
    "descr, shape, error, message",
    [
        ("<f4", (-2, -3), BadBody, "negative length"),
        ("<f4", (-1, -6), BadBody, "negative length"),
        ("<f4", (2**32, 2**32), BadBody, "truncated"),
        ("<f4", (2**62, 8), BadBody, "truncated"),
        ("<f4", (2**64, 6), BadBody, "truncated"),
        ("|V0", (3,), Invalid, "only plain numeric arrays"),
        (("<f4", (6,)), (2,), Invalid, "only plain numeric arrays"),
        ([("a", "<f4"), ("b", "<f4")], (2,), Invalid, "only plain numeric arrays"),
    ],
)
def test_forged_npy_headers_are_4xx(descr, shape, error, message):
    with pytest.raises(error, match=message):
        wire.read_npy(hostile_bodies.npy_with_header(descr, shape, bytes(48)))


def test_a_member_inflating_past_its_declared_size_is_400_at_bounded_cost():
    body = hostile_bodies.zip_bomb(inflated=256 << 20, declared=1024)
    tracemalloc.start()
    with pytest.raises(BadBody, match="inflates to more than the 1024 bytes"):
        wire.read_npz(body, max_bytes=64 << 20)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1 << 20


def test_an_honest_member_over_the_limit_is_413_before_inflating():
    body = hostile_bodies.honest_big_zip(64 << 20)
    tracemalloc.start()
    with pytest.raises(TooLarge, match="DACRT_MAX_BODY_BYTES"):
        wire.read_npz(body, max_bytes=16 << 20)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1 << 20


def test_an_honest_deflated_member_is_read_once_within_its_size():
    body = hostile_bodies.honest_big_zip(8 << 20)
    tracemalloc.start()
    got = wire.read_npz(body, max_bytes=16 << 20)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert got["origins"].shape == (2 << 20,) and not got["origins"].any()
    assert peak < (8 << 20) + (1 << 20)


@pytest.mark.parametrize(
    "build, error, message",
    [
        (hostile_bodies.overlapping_zip, BadBody, "overlaps the member before it"),
        (hostile_bodies.duplicate_zip, BadBody, "holds member 'origins' twice"),
        (hostile_bodies.encrypted_zip, BadBody, "is encrypted"),
        (hostile_bodies.bzip2_zip, BadBody, "compression method 12"),
    ],
)
def test_malformed_zips_are_400(build, error, message):
    with pytest.raises(error, match=message):
        wire.read_npz(build(), max_bytes=1 << 20)


def test_a_truncated_or_corrupted_deflated_member_is_400():
    data = npy_bytes(np.zeros((4, 3), np.float32))
    member = {
        "name": "origins.npy",
        "payload": hostile_bodies.deflate(data),
        "method": 8,
        "size": len(data),
        "crc": zlib.crc32(data),
    }
    with pytest.raises(BadBody, match="CRC-32"):
        wire.read_npz(hostile_bodies.raw_zip([{**member, "crc": 1}]))
    with pytest.raises(BadBody, match="truncated"):
        wire.read_npz(hostile_bodies.raw_zip([{**member, "payload": member["payload"][:-4]}]))
    with pytest.raises(BadBody, match="truncated"):
        wire.read_npz(hostile_bodies.raw_zip([{**member, "size": len(data) + 8}]))


def test_too_many_members_is_400_before_zipfile_lists_them():
    data = npy_bytes(np.zeros(1, np.float32))
    body = hostile_bodies.raw_zip(
        [{"name": "a.npy", "payload": data}], [{"member": 0, "name": f"a{i}"} for i in range(5000)]
    )
    with pytest.raises(BadBody, match="5000 members"):
        wire.read_npz(body)


# ---- hostile JSON: a clear 4xx, never a RecursionError or a silent conversion


@pytest.mark.parametrize(
    "body, error, message",
    [
        (hostile_bodies.deep_json("origins", 100_000), BadBody, "nested too deeply"),
        (hostile_bodies.deep_json("origins", 900), Invalid, "found a list nested too deeply"),
        (
            b'{"origins": [[0, 0, 0]], "directions": [[0, 0, 1]], "origins": [[1, 1, 1]]}',
            BadBody,
            "body gives the key 'origins' twice in one object",
        ),
        (
            b'{"origins": [[1' + b"0" * 400 + b', 0, 0]], "directions": [[0, 0, 1]]}',
            Invalid,
            "int too large",
        ),
        (
            b'{"origins": [[1' + b"0" * 5000 + b', 0, 0]], "directions": [[0, 0, 1]]}',
            Invalid,
            r"body's origins\[0\]\[0\] is an integer of 5001 digits",
        ),
        (
            b'{"origins": [[0, 0, 0]], "directions": [[0, 0, 1]], "tmax": 1' + b"0" * 400 + b"}",
            Invalid,
            "int too large",
        ),
        (b'{"origins": [["0.5", 0, 0]], "directions": [[0, 0, 1]]}', Invalid, "the string '0.5'"),
        (b'{"origins": [[true, 0, 0]], "directions": [[0, 0, 1]]}', Invalid, "found true"),
        (
            b'{"origins": [[0, 0, 0]], "directions": [[0, 0, 1]], "tmin": [false]}',
            Invalid,
            "found false",
        ),
        (b'{"origins": [{"x": 0}], "directions": [[0, 0, 1]]}', Invalid, "found an object"),
    ],
)
def test_hostile_json_rays_are_4xx(body, error, message):
    with pytest.raises(error, match=message):
        wire.decode_rays(body, "json")


@pytest.mark.parametrize(
    "faces, message",
    [
        ("[[true, 1, 2]]", "faces must be integers, found true"),
        ("[[0.0, 1, 2]]", "found the number 0.0"),
        ('[["0", 1, 2]]', "the string '0'"),
        ("[[1" + "0" * 400 + ", 1, 2]]", "faces holds an integer beyond int64"),
        ("[[0, 1, 9223372036854775808]]", "faces holds an integer beyond int64"),
        ("[[0, 1, -9223372036854775809]]", "faces holds an integer beyond int64"),
    ],
)
def test_json_faces_refuse_booleans_floats_strings_and_huge_integers(faces, message):
    body = b'{"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": ' + faces.encode() + b"}"
    with pytest.raises(Invalid, match=re.escape(message)):
        wire.decode_mesh(body, "json")


@pytest.mark.parametrize("n", [0, 1, 5, 6, 7, 20])
def test_json_answer_in_pieces_is_the_whole_document(monkeypatch, n):
    """A JSON answer is written JSON_PIECE_ITEMS values at a time (bounded memory), and the
    pieces make the same document as encoding it whole: empty, one piece, several, a piece
    boundary."""
    monkeypatch.setattr(wire.answers, "JSON_PIECE_ITEMS", 3)
    rng = np.random.default_rng(n)
    t = rng.uniform(0, 10, n).astype(np.float32)
    t[::4] = np.inf
    arrays = {
        "t": t,
        "mesh": rng.integers(-1, 5, n).astype(np.int32),
        "normal": rng.normal(size=(n, 3)).astype(np.float32),
        "occluded": rng.random(n) < 0.5,
    }
    pieces = list(wire.encode_answer(arrays, "json")[0])
    # per key: its name, "[", its pieces (of 3 values: 3 rows, or 1 of a normal), "]"; then "}"
    assert len(pieces) == 3 * (3 + -(-n // 3)) + (3 + n) + 1
    assert b"".join(pieces) == wire.encode_json(arrays)
    assert json.loads(b"".join(pieces))["mesh"] == arrays["mesh"].tolist()


@pytest.mark.parametrize("shape", [(4, 5), (3, 2, 3), (2, 2, 5), (1, 7), (0, 4, 3), (2, 0)])
def test_json_pieces_of_images_hold_a_bounded_count_of_values(monkeypatch, shape):
    """An image's (height, width[, 3]) arrays are cut into pieces of at most JSON_PIECE_ITEMS
    values too, inside a row where one row holds more (a 2048 x 2048 camera was one piece)."""
    monkeypatch.setattr(wire.answers, "JSON_PIECE_ITEMS", 3)
    rng = np.random.default_rng(len(shape))
    depth = rng.uniform(0, 10, shape).astype(np.float32)
    depth.reshape(-1)[::5] = np.inf
    arrays = {"depth": depth, "mesh": rng.integers(-1, 5, shape).astype(np.int32)}
    pieces = list(wire.answers.json_pieces(arrays))
    assert b"".join(pieces) == wire.encode_json(arrays)
    for piece in pieces:
        text = piece.decode().removeprefix(",")
        if text in ("", "[", "]", "{", "}") or text.endswith(":"):
            continue
        values = np.array(json.loads(f"[{text}]"), dtype=object).reshape(-1)
        assert len(values) <= 3, text


@pytest.mark.parametrize("compressed", [False, True])
def test_bodies_with_random_bytes_changed_are_read_or_refused_as_4xx(compressed):
    """Seeded mutations of valid .npz and .npy bodies: each is read, or refused with BadBody,
    Invalid or TooLarge (4xx), never another exception (a 500)."""
    rng = np.random.default_rng(7)
    valid_npz = npz_bytes(compressed, **{"car.transform": np.eye(4), "a.vertices": rays6(5)})
    valid_npy = npy_bytes(rays6(5))
    refused = 0
    for body in [valid_npz] * 3000 + [valid_npy] * 1000:
        mutated = bytearray(body)
        for at in rng.integers(0, len(body), rng.integers(1, 5)):
            mutated[at] = rng.integers(0, 256)
        try:
            if body is valid_npz:
                wire.read_npz(bytes(mutated), 1 << 20)
            else:
                wire.read_npy(bytes(mutated))
        except (BadBody, Invalid, TooLarge):
            refused += 1
    assert refused > 100  # the mutations did reach the readers' refusals


def test_npz_members_adding_up_to_one_byte_over_the_limit_are_413():
    body = npz_bytes(True, big=np.zeros(1000, np.float32))
    total = len(npy_bytes(np.zeros(1000, np.float32)))  # the member's inflated size
    assert set(wire.read_npz(body, max_bytes=total)) == {"big"}
    with pytest.raises(TooLarge, match=f"add up to {total} bytes, over the limit of {total - 1}"):
        wire.read_npz(body, max_bytes=total - 1)


def test_a_stored_member_whose_two_sizes_differ_is_400():
    data = npy_bytes(np.zeros((4, 3), np.float32))
    body = hostile_bodies.raw_zip([{"name": "origins.npy", "payload": data, "size": 1}])
    with pytest.raises(BadBody, match="stored but its two sizes differ"):
        wire.read_npz(body)


def test_one_member_over_the_most_an_npz_may_list_is_400():
    data = npy_bytes(np.zeros(1, np.float32))
    n = wire.MAX_NPZ_MEMBERS + 1
    body = hostile_bodies.raw_zip(
        [{"name": "a.npy", "payload": data}], [{"member": 0, "name": f"a{i}"} for i in range(n)]
    )
    with pytest.raises(BadBody, match=f"lists {n} members, over the {wire.MAX_NPZ_MEMBERS} read"):
        wire.read_npz(body)


@pytest.mark.parametrize("n", [wire.MAX_NPZ_MEMBERS + 1, 60_000])
def test_a_directory_of_more_entries_than_its_end_record_says_is_400(n):
    """zipfile reads every entry in the directory's byte span, whatever the end record's count:
    the entries are counted as they are read, at a cost bounded by the member limit."""
    data = npy_bytes(np.zeros(1, np.float32))
    body = bytearray(
        hostile_bodies.raw_zip(
            [{"name": "a.npy", "payload": data}], [{"member": 0, "name": "a.npy"}] * n
        )
    )
    body[-22 + 8 : -22 + 12] = (1).to_bytes(2, "little") * 2  # the end record says 1 entry
    body = bytes(body)
    tracemalloc.start()
    try:
        with pytest.raises(BadBody, match=f"more than {wire.MAX_NPZ_MEMBERS} entries"):
            wire.read_npz(body)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20, f"{peak} bytes allocated"


def test_a_deflated_member_whose_stream_never_ends_is_400():
    data = npy_bytes(np.zeros((4, 3), np.float32))
    deflater = zlib.compressobj(9, zlib.DEFLATED, -zlib.MAX_WBITS)
    unended = deflater.compress(data) + deflater.flush(zlib.Z_SYNC_FLUSH)  # no final block
    body = hostile_bodies.raw_zip(
        [
            {
                "name": "origins.npy",
                "payload": unended,
                "method": 8,
                "size": len(data),
                "crc": zlib.crc32(data),
            }
        ]
    )
    with pytest.raises(BadBody, match="truncated"):
        wire.read_npz(body)


def test_json_ray_masks_take_the_whole_uint32_range():
    body = {"origins": [[0, 0, 0]] * 2, "directions": [[0, 0, 1]] * 2}
    rays = wire.decode_rays(json.dumps({**body, "mask": [0, 4294967295]}).encode(), "json")
    assert rays.mask.dtype == np.uint32 and rays.mask.tolist() == [0, 0xFFFFFFFF]
    rays = wire.decode_rays(json.dumps({**body, "mask": 4294967295}).encode(), "json")
    assert rays.mask == 0xFFFFFFFF


def test_a_face_index_equal_to_the_vertex_count_is_refused():
    vertices = np.zeros((3, 3), np.float32)
    faces = np.array([[0, 1, 2], [0, 1, 3]], np.int32)
    with pytest.raises(InputError, match=r"faces\[1\] refers to vertex 3, but there are 3"):
        wire.decode_mesh(npz_bytes(vertices=vertices, faces=faces), "npz")


@pytest.mark.parametrize("fmt", ["npy", "json"])
def test_too_many_points_is_413_naming_the_limit(fmt):
    def body(n):
        points = np.random.default_rng(n).normal(size=(n, 3)).astype(np.float32)
        return (
            npy_bytes(points) if fmt == "npy" else json.dumps({"points": points.tolist()}).encode()
        )

    assert wire.decode_points(body(10), fmt, max_points=10).shape == (10, 3)
    with pytest.raises(TooLarge, match="11 points .* limit of 10 .*DACRT_MAX_RAYS_PER_REQUEST"):
        wire.decode_points(body(11), fmt, max_points=10)


@pytest.mark.parametrize("value", [0, 0.0, np.array([0.0], np.float32), 1, 0.25])
def test_reflectivity_takes_both_ends_of_its_range(value):
    expected = float(np.asarray(value).ravel()[0])
    assert wire.parse_reflectivity(value, "car.reflectivity") == expected


INTEGER = "must be an integer (an array of dtype uint32, say)"


@pytest.mark.parametrize(
    "parse, key, value, message",
    [
        (wire.parse_label, "car.label", np.float32([5]), f"{INTEGER}, got float32"),
        (wire.parse_label, "car.label", np.array(5.0), f"{INTEGER}, got float64"),
        (wire.parse_label, "car.label", np.uint32([5, 6]), "must be one value, got 2 values"),
        (wire.parse_mask, "car.mask", np.float32([1]), f"{INTEGER}, got float32; a mask is"),
        (wire.parse_mask, "car.mask", np.uint32([1, 2]), "must be one value, got 2 values"),
        (
            wire.parse_reflectivity,
            "car.reflectivity",
            np.array(["0.5"]),
            "must be a number (an array of dtype float32, say), got <U3",
        ),
        (wire.parse_reflectivity, "car.reflectivity", np.zeros(0), "must be one value, got 0"),
    ],
)
def test_a_one_value_array_of_a_wrong_dtype_or_size_is_422_saying_which(parse, key, value, message):
    """A frame's one-value keys: a float label is one number of the wrong dtype, and the message
    says so; a size other than one is told apart."""
    with pytest.raises(Invalid, match=re.escape(f"{key} {message}")):
        parse(value, key)


def test_a_frame_naming_more_meshes_than_a_scene_holds_is_413_before_its_meshes_are_made():
    instances = {f"i{i}.instance_of": "src" for i in range(100)}
    body = json.dumps({"src.vertices": [[0, 0, 0]], **instances}).encode()
    with pytest.raises(TooLarge, match="frame names 101 meshes, over the limit of 100 meshes"):
        wire.decode_frame(body, "json", max_meshes=100)
    with pytest.raises(TooLarge, match=r"names at least \d+ meshes, .*DACRT_MAX_MESHES_PER_SCENE"):
        wire.decode_frame(body, "json", max_meshes=9)  # by its keys alone
    assert len(wire.decode_frame(body, "json", max_meshes=101)) == 101
