"""Mesh files in-process: geometry only (textures never decoded), and every malformed or hostile
file refused with a 4xx error naming the problem (``BadBody`` 400, ``Invalid`` or the engine's
``InputError`` 422, ``TooLarge`` 413). The hostile files are built by ``mesh_files``."""

from __future__ import annotations

import io
import json
import random
import struct
import tracemalloc

import numpy as np
import pytest
from mesh_files import (
    OBJ_TRIANGLE,
    OFF_TRIANGLE,
    PLY_TRIANGLE_HEADER,
    TRIANGLE,
    glb,
    ply,
    png,
    stl,
    triangle_doc,
    triangle_glb,
)

from dacrt import InputError
from service import footprint, wire
from service.errors import BadBody, Invalid, ServiceError, TooLarge


def decode(body: bytes, fmt: str) -> wire.MeshArrays:
    return wire.decode_mesh(body, fmt)


# ---- textures and materials are never decoded


def _peak_rss_growth_mb(work) -> float:
    """How much ``work()`` raises this process's peak RSS, in MB (Linux)."""

    def status(key: str) -> int:
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith(key)) // 1024

    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")  # resets VmHWM to the current RSS
    except OSError:
        pytest.skip("needs /proc/self/clear_refs to measure peak RSS")
    before = status("VmRSS")
    work()
    return status("VmHWM") - before


def test_glb_textures_are_never_decoded(monkeypatch):
    image = png(8000, 8000)  # 192 MB once decoded
    body = triangle_glb(images=[image, image])
    assert len(body) < 500_000
    import PIL.Image

    opened = []
    real_open = PIL.Image.open
    monkeypatch.setattr(PIL.Image, "open", lambda *a, **k: opened.append(1) or real_open(*a, **k))
    decode(triangle_glb(), "glb")  # imports and first-call costs before measuring
    growth = _peak_rss_growth_mb(lambda: decode(body, "glb"))
    assert growth < 50, f"decoding a {len(body)}-byte GLB raised the peak RSS by {growth} MB"
    assert opened == []


def test_obj_material_library_and_ply_texture_file_are_ignored():
    obj = b"mtllib /etc/passwd\nusemtl x\n" + OBJ_TRIANGLE + b"vt 0 0\nf 1/1 2/1 3/1\n"
    assert decode(obj, "obj").faces.tolist() == [[0, 1, 2]]
    body = ply(
        ["comment TextureFile /etc/passwd", *PLY_TRIANGLE_HEADER], b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    assert decode(body, "ply").faces.tolist() == [[0, 1, 2]]


# ---- OBJ


def test_obj_polygons_relative_indices_and_texture_normal_references():
    body = (
        b"o a\n" + OBJ_TRIANGLE + b"v 1 1 0\nvt 0 0\nvn 0 0 1\n"
        b"f 1/1/1 2/1/1 4/1/1 3/1/1\n"  # a quad: two triangles, a fan from its first
        b"  f\t1//1 2//1 3//1  # comment\n"  # leading blanks, tab, comment
        b"o b\nv 5 0 0\nv 6 0 0\nv 5 1 0\nf -3 -2 -1\n"  # relative to the lines above
        b"v 9 9 9\n"
    )
    mesh = decode(body, "obj")
    assert mesh.faces.tolist() == [[0, 1, 3], [0, 3, 2], [0, 1, 2], [4, 5, 6]]
    assert mesh.vertices.shape == (8, 3) and mesh.faces.dtype == np.int32


@pytest.mark.parametrize(
    "body",
    [
        b"v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3",  # old Mac line ends, no last newline
        b"v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3\r\n",
        b"# made by hand\n  v 0 0 0 # origin\n\tv 1 0 0\nv 0 1 \\\n0\n\nf 1 2 \\\r\n3 # tri\n",
        b"\xef\xbb\xbfv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",  # a UTF-8 BOM (a Windows editor's)
    ],
    ids=["cr", "crlf", "comments blanks and continued lines", "byte-order mark"],
)
def test_obj_line_forms(body):
    mesh = decode(body, "obj")
    assert mesh.faces.tolist() == [[0, 1, 2]]
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])


@pytest.mark.parametrize(
    "body, error, message",
    [
        (
            OBJ_TRIANGLE + b"f 1 2 3\nf ",
            Invalid,
            "OBJ line 5 (`f`): a face needs at least 3 vertices, this one has 0",
        ),
        (
            OBJ_TRIANGLE + b"f 0 1 2\n",
            Invalid,
            "OBJ line 4 (`f 0 1 2`) refers to vertex 0, but OBJ indices start at 1",
        ),
        (
            OBJ_TRIANGLE + b"f 1 2 3\nf 1 2 9\n",
            Invalid,
            "line 5 (`f 1 2 9`) refers to vertex 9, but there are 3 vertices",
        ),
        (
            b"v 0 0 0\nf -1 -2 -3\n" + OBJ_TRIANGLE,
            Invalid,
            "refers to vertex -2, but only 1 vertices are defined before it",
        ),
        (
            OBJ_TRIANGLE + b"f 1 2 99999999999999999999\n",
            Invalid,
            "refers to vertex a number beyond int64, but there are 3 vertices",
        ),
        (OBJ_TRIANGLE + b"f 1 2\n", Invalid, "a face needs at least 3 vertices, this one has 2"),
        (OBJ_TRIANGLE + b"f 1 2 x\n", BadBody, "OBJ line 4 (`f 1 2 x`): `x` is not a vertex index"),
        (OBJ_TRIANGLE + b"f 1 2 3.5\n", BadBody, "`3.5` is not a vertex index"),
        (OBJ_TRIANGLE + b"f 1 2 /3\n", BadBody, "`/3` is not a vertex index"),
        (
            b"v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            BadBody,
            "OBJ line 1 (`v 0 0`): a vertex needs 3 coordinates",
        ),
        (
            b"v 0 0 zero\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
            BadBody,
            "OBJ line 1 (`v 0 0 zero`): a vertex must be numbers",
        ),
        (b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", InputError, "vertices[0] is not finite"),
        (b"v 1e39 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", InputError, "vertices[0] is not finite"),
        (OBJ_TRIANGLE, BadBody, "no triangles found in the OBJ body"),
        (b"\n  \n", BadBody, "the OBJ body is empty"),
        (b"", BadBody, "the OBJ body is empty"),
    ],
)
def test_bad_obj(body, error, message):
    with pytest.raises(error) as caught:
        decode(body, "obj")
    assert message in str(caught.value)


# ---- OFF


def test_off_polygons_comments_colours_and_counts_on_the_keyword_line():
    body = b"# a square\nCOFF 4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3 255 0 0\n3 0 1 2\n"
    assert decode(body, "off").faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 2]]


@pytest.mark.parametrize(
    "body, error, message",
    [
        (
            OFF_TRIANGLE + b"1000000 0 1 2\n",
            BadBody,
            "OFF line 6 (`1000000 0 1 2`): declares a face of 1000000 vertices but lists 3 indices",
        ),
        (
            OFF_TRIANGLE + b"3 0 1 7\n",
            Invalid,
            "OFF line 6 (`3 0 1 7`) refers to vertex 7, but there are 3 vertices",
        ),
        (OFF_TRIANGLE + b"3 0 -1 2\n", Invalid, "refers to vertex -1, but there are 3 vertices"),
        (
            OFF_TRIANGLE + b"2 0 1\n",
            Invalid,
            "a face needs at least 3 vertices, this one declares 2",
        ),
        (OFF_TRIANGLE + b"3 0 1 2 1 2 3 4 5\n", BadBody, "lists 8 values"),
        (OFF_TRIANGLE + b"3 0 1 x\n", BadBody, "OFF line 6 (`3 0 1 x`): a face must be integers"),
        (
            b"OFF\n1000000000 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
            BadBody,
            "declares 1000000000 vertices and 1 faces (1000000001 lines), but 4 lines follow",
        ),
        (
            OFF_TRIANGLE + b"3 0 1 2\n3 0 1 2\n",
            BadBody,
            "declares 3 vertices and 1 faces (4 lines), but 5 lines follow",
        ),
        (b"OFF\nthree 1 0\n", BadBody, "the counts must be integers"),
        (
            b"4OFF\n3 1 0\n0 0 0 0\n1 0 0 0\n0 1 0 0\n3 0 1 2\n",
            BadBody,
            "4OFF and nOFF are not read",
        ),
        (
            b"OFF\n3 1 0\n0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
            BadBody,
            "OFF line 3 (`0 0`): a vertex needs 3 coordinates",
        ),
        (b"OFF\n3 1 0\ninf 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", InputError, "vertices[0] is not finite"),
        (b"OFF\n# nothing\n", BadBody, "no counts line"),
        (b"OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n", BadBody, "no triangles found in the OFF body"),
    ],
)
def test_bad_off(body, error, message):
    with pytest.raises(error) as caught:
        decode(body, "off")
    assert message in str(caught.value)


# ---- PLY


@pytest.mark.parametrize(
    "encoding, data",
    [
        ("ascii", b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
        (
            "binary_little_endian",
            TRIANGLE.tobytes() + b"\x03" + np.array([0, 1, 2], "<i4").tobytes(),
        ),
    ],
)
def test_ply(encoding, data):
    assert decode(ply(PLY_TRIANGLE_HEADER, data, encoding), "ply").faces.tolist() == [[0, 1, 2]]


def _mixed_faces_ply(order: str = "<", extra: bool = False) -> bytes:
    """A binary PLY of a triangle and a quad (rows of two lengths, which trimesh does not
    read), with an extra vertex property and a face flag after the list if ``extra``."""
    vertex_props = ["property float x", "property float y", "property float z"]
    face_props = ["property list uchar int vertex_indices"]
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], order + "f4")
    if extra:
        vertex_props.insert(1, "property uchar red")
        face_props.append("property short flags")
    header = [f"element vertex {len(vertices)}", *vertex_props, "element face 2", *face_props]
    rows = b""
    for vertex in vertices:
        rows += vertex[:1].tobytes() + (b"\x07" if extra else b"") + vertex[1:].tobytes()
    for face in ([0, 1, 2], [0, 1, 3, 2]):
        rows += bytes([len(face)]) + np.array(face, order + "i4").tobytes()
        rows += np.array([5], order + "i2").tobytes() if extra else b""
    encoding = "binary_little_endian" if order == "<" else "binary_big_endian"
    return ply(header, rows, encoding)


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("extra", [False, True])
def test_binary_ply_with_triangles_and_quads(order, extra):
    """Rows of several lengths are read row by row (trimesh reads only rows as long as the
    first), the quad fanned as an OBJ's polygon is."""
    mesh = decode(_mixed_faces_ply(order, extra), "ply")
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 1, 3], [0, 3, 2]]
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])


def _ascii_ply_variants() -> dict[str, bytes]:
    import trimesh

    sphere = trimesh.creation.icosphere(2)
    plain = sphere.export(file_type="ply", encoding="ascii")
    sphere.visual.vertex_colors = [200, 100, 50, 255]
    _ = sphere.vertex_normals  # computed: written with the vertices
    dressed = sphere.export(file_type="ply", encoding="ascii")
    header = ["element vertex 4", *PLY_TRIANGLE_HEADER[1:4], "element face 2"]
    square = b"0 0 0\n1 0 0\n0 1 0\n1 1 0\n"
    flagged = ply(
        [*header, "property list uchar int vertex_indices", "property int flags"],
        square + b"3 0 1 2 7\n4 0 1 3 2 8\n",
    )
    quality = ply(
        [*header, "property list uchar int vertex_indices", "property float quality"],
        square + b"3 0 1 2 0.5\n4 0 1 3 2 0.25\n",
    )
    return {"plain": plain, "colours and normals": dressed, "flags": flagged, "quality": quality}


@pytest.mark.parametrize("variant", ["plain", "colours and normals", "flags", "quality"])
def test_ascii_ply_reads_as_trimesh_does(variant):
    """The service's ASCII PLY reader (NumPy over the whole body) gives trimesh's vertices
    and faces, extra vertex properties and face properties after the list included (a float
    one goes to trimesh itself)."""
    import trimesh

    body = _ascii_ply_variants()[variant]
    mesh = decode(body, "ply")
    theirs = trimesh.load(io.BytesIO(body), file_type="ply", process=False)
    np.testing.assert_array_equal(mesh.vertices, np.asarray(theirs.vertices, np.float32))
    if variant == "flags":  # trimesh starts a quad's second triangle at another corner here:
        # the same triangle, its corners turned (the orientation kept)
        np.testing.assert_array_equal(
            _turned_to_lowest(mesh.faces), _turned_to_lowest(theirs.faces)
        )
    else:
        np.testing.assert_array_equal(mesh.faces, theirs.faces)


def _turned_to_lowest(faces) -> np.ndarray:
    """Each triangle's corners turned to start at its lowest index, the order kept."""
    faces = np.asarray(faces)
    first = np.argmin(faces, axis=1)[:, None]
    return np.take_along_axis(faces, (first + np.arange(3)) % 3, axis=1)


BILLION_VERTICES = ["element vertex 1000000000", *PLY_TRIANGLE_HEADER[1:]]


@pytest.mark.parametrize(
    "body, error, message",
    [
        (
            ply(BILLION_VERTICES, encoding="binary_little_endian"),
            BadBody,
            "PLY header declares 1000000000 vertex, 1 face (at least 12000000001 bytes), "
            "but the body holds only 0 bytes",
        ),
        (
            ply(BILLION_VERTICES),
            BadBody,
            "declares 1000000000 vertex, 1 face (1000000001 lines), "
            "but the body holds only 0 lines",
        ),
        (
            ply(PLY_TRIANGLE_HEADER, b"0 0 0\n1 0 0\n"),
            BadBody,
            "(4 lines), but the body holds only 2 lines",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            b"0 0\n1 0\n0 1\n3 0 1 2\n",
            BadBody,
            "body cannot be read as PLY: it lacks 'z'",
        ),
        (
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n",
            BadBody,
            "PLY header has no `end_header` line",
        ),
        (
            ply(["element vertex 3", "property float128 x"]),
            BadBody,
            "line 4 (`property float128 x`) is not a format, element",
        ),
        (ply(["element vertex -3"]), BadBody, "(`element vertex -3`) is not a format, element"),
        (
            ply(PLY_TRIANGLE_HEADER, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"),
            InputError,
            "faces[0] refers to vertex 7, but there are 3 vertices",
        ),
        (
            ply(PLY_TRIANGLE_HEADER, b"nan 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
            InputError,
            "vertices[0] is not finite",
        ),
        (
            b"ply\nend_header\n",
            BadBody,
            "has no `format ascii|binary_little_endian|binary_big_endian 1.0` line",
        ),
        (b"obj\nformat ascii 1.0\nend_header\n", BadBody, "must start with the line `ply`"),
        (
            ply(PLY_TRIANGLE_HEADER, b"0 0 0\n1 0 0\n0 1 0\n200 0 1 2\n"),
            BadBody,
            "PLY line 13 (`200 0 1 2`) does not hold what its face element declares",
        ),
        (
            ply(PLY_TRIANGLE_HEADER, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2 5\n"),
            BadBody,
            "PLY line 13 (`3 0 1 2 5`) does not hold what its face element declares",
        ),
        (
            ply(PLY_TRIANGLE_HEADER, b"0 0 0\n1 0 0\n0 1 0\n3 0 1.7 2\n"),
            BadBody,
            "PLY line 13 (`3 0 1.7 2`) does not hold what its face element declares",
        ),
        (
            ply(
                [*PLY_TRIANGLE_HEADER, "property uchar red"],
                b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
            ),
            BadBody,
            "PLY line 14 (`3 0 1 2`) does not hold what its face element declares",
        ),
        (
            ply(
                [*PLY_TRIANGLE_HEADER[:-1], "property list uchar float vertex_indices"],
                TRIANGLE.tobytes() + b"\x03" + np.array([0, 1, 2.7], "<f4").tobytes(),
                "binary_little_endian",
            ),
            BadBody,
            "line 8 (`property list uchar float vertex_indices`): a list's count and items "
            "must be of integer types",
        ),
        (
            ply(
                [*PLY_TRIANGLE_HEADER[:-1], "property list int int vertex_indices"],
                TRIANGLE.tobytes() + np.array([2**31 - 1, 0, 1, 2], "<i4").tobytes(),
                "binary_little_endian",
            ),
            BadBody,
            "PLY element face: 1 rows as long as its first (8589934592 bytes) need 8589934592 "
            "bytes, but 16 follow",
        ),
        (
            ply(
                [*PLY_TRIANGLE_HEADER[:-1], "property list int int vertex_indices"],
                TRIANGLE.tobytes() + np.array([-3, 0, 1, 2], "<i4").tobytes(),
                "binary_little_endian",
            ),
            BadBody,
            "PLY element face's first list declares -3 items",
        ),
        (
            _mixed_faces_ply()[:-3],
            BadBody,
            "PLY element face, row 1: its list vertex_indices of 4 items runs past the end",
        ),
        (
            ply(["element vertex 99999999999999", "element face 1", *PLY_TRIANGLE_HEADER[5:]]),
            BadBody,
            "PLY element vertex declares 99999999999999 items but no properties",
        ),
    ],
)
def test_bad_ply(body, error, message):
    with pytest.raises(error) as caught:
        decode(body, "ply")
    assert message in str(caught.value)


# ---- STL


def test_binary_stl_starting_with_solid_is_read_as_binary():
    body = stl(TRIANGLE[None], header=b"solid but binary")
    assert decode(body, "stl").faces.tolist() == [[0, 1, 2]]


def _ascii_stl(vertices_a_facet: list[int]) -> bytes:
    """An ASCII STL whose facets hold these many vertices (3 in a well-formed one)."""
    facets = [
        "facet normal 0 0 1\nouter loop\n"
        + "".join(f"vertex {k} {k % 2} 0\n" for k in range(n))
        + "endloop\nendfacet\n"
        for n in vertices_a_facet
    ]
    return ("solid x\n" + "".join(facets) + "endsolid x\n").encode()


def test_ascii_stl():
    mesh = decode(_ascii_stl([3, 3]), "stl")
    assert mesh.faces.shape == (2, 3) and mesh.vertices.shape[1] == 3


def _stl_peak(name: str) -> tuple[int, int]:
    """(tracemalloc's peak, body bytes) of reading an ASCII STL of 40,000 facets named ``name``."""
    facet = b"facet\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendfacet\n"
    body = f"solid {name}\n".encode() + facet * 40_000 + b"endsolid\n"
    tracemalloc.start()
    try:
        mesh = decode(body, "stl")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert mesh.faces.shape == (40_000, 3)
    return peak, len(body)


@pytest.mark.parametrize("name", ["\U0001f600", "b\u00e4r \u6587"])
def test_an_ascii_stl_costs_the_same_whatever_its_name(name):
    """trimesh reads an ASCII STL as Python text: one character past Latin-1 in its name made
    every character 4 bytes (20 x the body, where a plain name costs 11 x); it is read as "?"."""
    decode(_ascii_stl([3]), "stl")  # trimesh imported: its modules are not the body's cost
    plain, n_body = _stl_peak("x")
    named, _ = _stl_peak(name)
    assert named < plain + 2 * n_body, f"{named / n_body:.1f} x the body, {plain / n_body:.1f}"
    assert named < footprint.decode_bytes(n_body, "stl")


@pytest.mark.parametrize(
    "body, error, message",
    [
        (
            stl(TRIANGLE[None], count=100_000_000),
            BadBody,
            "binary STL header declares 100000000 triangles (5000000084 bytes), "
            "but the body is 134 bytes",
        ),
        (
            stl(TRIANGLE[None])[:-1],
            BadBody,
            "declares 1 triangles (134 bytes), but the body is 133 bytes",
        ),
        (b"\x01" * 50, BadBody, "shorter than the 84-byte header of a binary STL"),
        (stl(np.full((1, 3, 3), np.nan, np.float32)), InputError, "is not finite"),
        (stl(np.zeros((0, 3, 3), np.float32)), BadBody, "no triangles found in the STL body"),
        (b"solid x\nendsolid x\n", BadBody, "no triangles found in the STL body"),
        (
            _ascii_stl([3, 2, 3]),
            BadBody,
            "ASCII STL facet 2 (ending on line 14) holds 2 vertices, not 3; 1 of 3 facets do",
        ),
        (
            _ascii_stl([4, 3]),
            BadBody,
            "ASCII STL facet 1 (ending on line 9) holds 4 vertices, not 3; 1 of 2 facets do",
        ),
    ],
)
def test_bad_stl(body, error, message):
    with pytest.raises(error) as caught:
        decode(body, "stl")
    assert message in str(caught.value)


# ---- GLB


def test_glb_nodes_are_merged_with_their_transforms():
    doc = triangle_doc(nodes=2)
    mesh = decode(glb(doc, TRIANGLE.tobytes() + np.array([0, 1, 2], np.uint32).tobytes()), "glb")
    assert mesh.faces.tolist() == [[0, 1, 2], [3, 4, 5]]
    assert mesh.vertices[:, 0].max() == 2


def test_a_glb_json_repeating_a_key_reads_as_its_readers_read_it():
    """A request body may not give a key twice (400), but a GLB is a file from elsewhere: its
    JSON is read as trimesh and other readers read it, the last value winning."""
    text = json.dumps(triangle_doc()).replace('"scene": 0', '"scene": 5, "scene": 0').encode()
    binary = TRIANGLE.tobytes() + np.array([0, 1, 2], np.uint32).tobytes()
    mesh = decode(glb(text, binary), "glb")
    assert mesh.faces.tolist() == [[0, 1, 2]]


def _many_instances() -> bytes:
    """One 1000-triangle mesh (12 KB of indices) instanced by 1000 nodes."""
    indices = np.tile(np.array([0, 1, 2], np.uint32), 1000)
    doc = triangle_doc(binary_length=36 + indices.nbytes, nodes=1000)
    doc["bufferViews"][1]["byteLength"] = indices.nbytes
    doc["accessors"][1]["count"] = indices.size
    return glb(doc, TRIANGLE.tobytes() + indices.tobytes())


def _many_meshes() -> bytes:
    """2000 meshes that share one 60,000-index uint8 accessor (60 KB), one of them placed:
    trimesh decodes the accessor once a mesh."""
    indices = np.tile(np.array([0, 1, 2], np.uint8), 20_000)
    doc = triangle_doc(binary_length=36 + indices.nbytes)
    doc["bufferViews"][1]["byteLength"] = indices.nbytes
    doc["accessors"][1].update(count=indices.size, componentType=5121)
    doc["meshes"] = doc["meshes"] * 2000
    return glb(doc, TRIANGLE.tobytes() + indices.tobytes())


def _huge_integer_glb() -> bytes:
    """TRIANGLE's GLB with an accessor count of 5000 digits (json.dumps would refuse to write
    it, as json.loads refuses to read it)."""
    text = json.dumps(triangle_doc()).replace('"count": 3', '"count": ' + "9" * 5000, 1).encode()
    return glb(text, TRIANGLE.tobytes() + np.array([0, 1, 2], np.uint32).tobytes())


def _set(path: str, value):
    """An edit of a glTF document: set ``value`` at a dotted path (list indices as numbers)."""

    def edit(doc):
        *parents, last = path.split(".")
        for key in parents:
            doc = doc[int(key)] if key.isdigit() else doc[key]
        doc[int(last) if last.isdigit() else last] = value

    return edit


@pytest.mark.parametrize(
    "body, error, message",
    [
        (
            triangle_glb(edit=_set("buffers.0.uri", "model.bin")),
            BadBody,
            "GLB buffer 0 refers to 'model.bin': only a self-contained GLB is accepted",
        ),
        (
            triangle_glb(edit=_set("buffers.0.uri", "data:application/octet-stream;base64,AAAA")),
            BadBody,
            "only a self-contained GLB is accepted",
        ),
        (
            glb(triangle_doc(), json_length=2**31),
            BadBody,
            "GLB chunk 0 declares 2147483648 bytes, but only",
        ),
        (triangle_glb()[:-4], BadBody, "GLB header declares"),
        (
            b"glTF" + struct.pack("<II", 2, 24) + struct.pack("<I", 4) + b"JSON{{{{",
            BadBody,
            "GLB JSON chunk is not valid JSON",
        ),
        (glb([1, 2]), BadBody, "GLB JSON chunk must be an object"),
        (b"glTF" + struct.pack("<II", 1, 20) + b"\0" * 8, BadBody, "version 2"),
        (b"glTF", BadBody, "shorter than a GLB header"),
        (
            triangle_glb(
                edit=lambda doc: doc["accessors"].append(  # no bufferView: zeros
                    {"componentType": 5126, "count": 10**9, "type": "VEC3"}
                )
            ),
            TooLarge,
            "GLB accessors declare 12000000048 bytes, over 8 times",
        ),
        (
            triangle_glb(edit=_set("bufferViews.1.byteLength", 10**12)),
            TooLarge,
            "GLB buffer views declare",
        ),
        (
            triangle_glb(edit=_set("accessors.0.count", -3)),
            BadBody,
            "accessors[0].count must be an integer >= 0",
        ),
        (
            triangle_glb(edit=_set("accessors.0.type", "VEC7")),
            BadBody,
            "accessors[0] needs a known type",
        ),
        (
            triangle_glb(edit=_set("accessors.0.type", ["VEC3"])),
            BadBody,
            "accessors[0] needs a known type",
        ),
        (
            triangle_glb(edit=_set("accessors.1.type", {"a": 1})),
            BadBody,
            "accessors[1] needs a known type",
        ),
        (
            triangle_glb(edit=_set("accessors.0.componentType", [5126])),
            BadBody,
            "accessors[0] needs a known type and componentType",
        ),
        (
            triangle_glb(edit=_set("accessors.0.componentType", 5126.0)),
            BadBody,
            "accessors[0] needs a known type and componentType",
        ),
        (
            triangle_glb(edit=_set("extensionsUsed", [{"name": "x"}, ["y"]])),
            BadBody,
            "GLB JSON extensionsUsed[0] must be an extension's name (a string)",
        ),
        (
            triangle_glb(edit=_set("accessors.0.type", "VEC2")),
            BadBody,
            "vertex positions have shape (3, 2): 3 coordinates a vertex are needed",
        ),
        (
            triangle_glb(edit=lambda doc: doc["accessors"][0].update(type="SCALAR", count=9)),
            BadBody,
            "vertex positions have shape (9, 1): 3 coordinates a vertex are needed",
        ),
        (
            triangle_glb(edit=_set("extensionsRequired", ["KHR_draco_mesh_compression"])),
            BadBody,
            "uses KHR_draco_mesh_compression, which is not read",
        ),
        (_many_instances(), TooLarge, "instances its meshes into 1000000 triangles"),
        (
            triangle_glb(edit=_set("bufferViews.1.byteOffset", 40)),
            BadBody,
            "GLB bufferViews[1] ends at byte 52 of a BIN chunk of 48 bytes",
        ),
        (
            triangle_glb(edit=_set("bufferViews.0.byteStride", 2)),
            BadBody,
            "GLB bufferViews[0].byteStride must be an integer in [4, 252]",
        ),
        (
            triangle_glb(edit=_set("accessors.0.count", 10)),
            BadBody,
            "GLB accessors[0] (10 x VEC3) ends at byte 120 of bufferViews[0], which holds 36",
        ),
        (
            triangle_glb(edit=_set("accessors.1.bufferView", 7)),
            BadBody,
            "GLB accessors[1].bufferView is 7, but there are 2 to refer to",
        ),
        (
            triangle_glb(edit=_set("meshes.0.primitives.0.attributes", {"NORMAL": 0})),
            BadBody,
            "GLB meshes[0].primitives[0] needs attributes with a POSITION",
        ),
        (
            triangle_glb(edit=_set("meshes.0.primitives.0.indices", 5)),
            BadBody,
            "GLB meshes[0].primitives[0].indices is 5, but there are 2 to refer to",
        ),
        (triangle_glb(edit=_set("nodes.0", [0])), BadBody, "GLB nodes[0] must be an object"),
        (
            triangle_glb(edit=_set("nodes.0.mesh", 3)),
            BadBody,
            "GLB nodes[0].mesh is 3, but there are 1 to refer to",
        ),
        (
            triangle_glb(edit=_set("nodes.0.children", 4)),
            BadBody,
            "GLB JSON nodes[0].children must be a list",
        ),
        (
            triangle_glb(edit=_set("scenes.0.nodes", [0, 9])),
            BadBody,
            "GLB scenes[0].nodes[1] is 9, but there are 1 to refer to",
        ),
        (triangle_glb(edit=_set("scene", 2)), BadBody, "GLB scene is 2, but there are 1 to"),
        (
            _huge_integer_glb(),
            Invalid,
            "GLB JSON chunk's accessors[0].count is an integer of 5000 digits",
        ),
        (_many_meshes(), TooLarge, "GLB meshes' primitives decode to 960144000 bytes, over 8"),
        (
            triangle_glb(indices=(0, 1, 7)),
            InputError,
            "faces[0] refers to vertex 7, but there are 3 vertices",
        ),
        (triangle_glb(edit=_set("accessors.1.count", 300)), BadBody, "body cannot be read as GLB"),
    ],
)
def test_bad_glb(body, error, message):
    with pytest.raises(error) as caught:
        decode(body, "glb")
    assert message in str(caught.value)


# ---- anything else: never a 5xx


def _valid_files() -> dict[str, bytes]:
    import trimesh

    box = trimesh.creation.box()
    files = {fmt: box.export(file_type=fmt) for fmt in ("obj", "ply", "stl", "glb", "off")}
    files["ply_ascii"] = box.export(file_type="ply", encoding="ascii")
    files["stl_ascii"] = box.export(file_type="stl_ascii")
    return {fmt: data.encode() if isinstance(data, str) else data for fmt, data in files.items()}


@pytest.mark.parametrize("fmt", ["obj", "ply", "ply_ascii", "stl", "stl_ascii", "glb", "off"])
def test_mutated_files_give_only_4xx_errors(fmt):
    original = _valid_files()[fmt]
    rng = random.Random(fmt)
    for _ in range(150):
        body = bytearray(original)
        for _ in range(rng.randint(1, 4)):
            at = rng.randrange(len(body))
            action = rng.random()
            if action < 0.4:
                body[at] = rng.randrange(256)
            elif action < 0.6:
                body[at : at + rng.randint(1, 8)] = b""
            elif action < 0.8:
                body[at:at] = rng.choice([b"0", b"-1", b" ", b"\n", b"/", b"999999999", b"#"])
            else:
                del body[at:]
        try:
            decode(bytes(body), fmt.split("_")[0])
        except (ServiceError, InputError) as exc:  # InputError: the engine's 422
            assert isinstance(exc, (BadBody, Invalid, TooLarge, InputError)) and str(exc)


@pytest.mark.parametrize(
    "fmt, body",
    [
        ("off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
        (
            "ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
            b"end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        ),
    ],
)
def test_a_byte_order_mark_before_a_text_header_is_skipped(fmt, body):
    plain = decode(body, fmt)
    marked = decode(b"\xef\xbb\xbf" + body, fmt)
    assert marked.faces.tolist() == plain.faces.tolist() == [[0, 1, 2]]
    np.testing.assert_array_equal(marked.vertices, plain.vertices)
