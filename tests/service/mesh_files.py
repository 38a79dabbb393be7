"""Builders of mesh files for the tests, hostile ones included: GLB (with PNG textures), PLY,
binary STL, and the smallest OBJ and OFF triangles."""

from __future__ import annotations

import json
import struct
import zlib

import numpy as np

TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)


def png(width: int, height: int) -> bytes:
    """A black RGB PNG: 8000 x 8000 is 192 MB decoded, about 190 KB compressed."""

    def chunk(kind: bytes, payload: bytes) -> bytes:
        return (
            struct.pack(">I", len(payload))
            + kind
            + payload
            + struct.pack(">I", zlib.crc32(kind + payload))
        )

    compressor, row = zlib.compressobj(9), bytes(1 + 3 * width)  # filter byte 0, then pixels
    idat = b"".join(compressor.compress(row) for _ in range(height)) + compressor.flush()
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")
    )


def glb(doc: dict | bytes, binary: bytes = b"", json_length: int | None = None) -> bytes:
    """A GLB of a JSON document (or its text as given, which json.dumps could not write) and one
    BIN chunk; ``json_length`` overrides the declared one."""
    text = doc if isinstance(doc, bytes) else json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    declared = len(text) if json_length is None else json_length
    chunks = struct.pack("<II", declared, 0x4E4F534A) + text
    if binary:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks


def triangle_doc(binary_length: int = 48, nodes: int = 1) -> dict:
    """A glTF document of TRIANGLE (float32 positions at 0, uint32 indices at 36)."""
    return {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": binary_length}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 12},
        ],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": 3,
                "type": "VEC3",
                "min": [0, 0, 0],
                "max": [1, 1, 0],
            },
            {"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0, "translation": [i, 0, 0]} for i in range(nodes)],
        "scenes": [{"nodes": list(range(nodes))}],
        "scene": 0,
    }


def triangle_glb(indices=(0, 1, 2), edit=None, images=()) -> bytes:
    """TRIANGLE as a GLB; ``images`` (PNG bytes) become textures of its material."""
    binary = TRIANGLE.tobytes() + np.array(indices, np.uint32).tobytes()
    doc = triangle_doc()
    for image in images:
        doc["bufferViews"].append(
            {"buffer": 0, "byteOffset": len(binary), "byteLength": len(image)}
        )
        doc.setdefault("images", []).append(
            {"bufferView": len(doc["bufferViews"]) - 1, "mimeType": "image/png"}
        )
        binary += image + b"\0" * (-len(image) % 4)
    if images:
        doc["textures"] = [{"source": i} for i in range(len(images))]
        doc["materials"] = [
            {
                "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}},
                "emissiveTexture": {"index": len(images) - 1},
            }
        ]
        doc["meshes"][0]["primitives"][0]["material"] = 0
        doc["buffers"][0]["byteLength"] = len(binary)
    if edit:
        edit(doc)
    return glb(doc, binary)


OBJ_TRIANGLE = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"
OFF_TRIANGLE = b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n"


def ply(header_lines: list[str], data: bytes = b"", encoding: str = "ascii") -> bytes:
    return (
        "\n".join(["ply", f"format {encoding} 1.0", *header_lines, "end_header"]) + "\n"
    ).encode() + data


PLY_TRIANGLE_HEADER = [
    "element vertex 3",
    "property float x",
    "property float y",
    "property float z",
    "element face 1",
    "property list uchar int vertex_indices",
]


def stl(triangles: np.ndarray, count: int | None = None, header: bytes = b"") -> bytes:
    """A binary STL of (T, 3, 3) triangles; ``count`` overrides the declared count."""
    records = np.zeros(
        len(triangles), [("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attributes", "<u2")]
    )
    records["vertices"] = triangles
    declared = len(triangles) if count is None else count
    return header.ljust(80, b"\0") + struct.pack("<I", declared) + records.tobytes()


OBJ, OFF, PLY, STL, GLB = (
    {"Content-Type": t}
    for t in ("model/obj", "model/off", "application/ply", "model/stl", "model/gltf-binary")
)
BILLION_VERTICES = ["element vertex 1000000000", *PLY_TRIANGLE_HEADER[1:]]


#: Malformed or hostile mesh files: (body, headers, status, a phrase of the detail).
BAD_MESH_FILES = [
    (
        OBJ_TRIANGLE + b"f 0 1 2\n",
        OBJ,
        422,
        "OBJ line 4 (`f 0 1 2`) refers to vertex 0, but OBJ indices start at 1",
    ),
    (OBJ_TRIANGLE + b"f 1 2 9\n", OBJ, 422, "refers to vertex 9, but there are 3 vertices"),
    (OBJ_TRIANGLE + b"f 1 2\n", OBJ, 422, "a face needs at least 3 vertices"),
    (
        OFF_TRIANGLE + b"1000000 0 1 2\n",
        OFF,
        400,
        "declares a face of 1000000 vertices but lists 3 indices",
    ),
    (
        OFF_TRIANGLE + b"3 0 1 7\n",
        OFF,
        422,
        "OFF line 6 (`3 0 1 7`) refers to vertex 7, but there are 3 vertices",
    ),
    (
        ply(BILLION_VERTICES, encoding="binary_little_endian"),
        PLY,
        400,
        "declares 1000000000 vertex",
    ),
    (b"ply\nformat ascii 1.0\nelement vertex 3\n", PLY, 400, "no `end_header` line"),
    (stl(TRIANGLE[None], count=10**8), STL, 400, "binary STL header declares 100000000 triangles"),
    (
        triangle_glb(edit=lambda doc: doc["buffers"][0].update(uri="model.bin")),
        GLB,
        400,
        "only a self-contained GLB is accepted",
    ),
    (triangle_glb()[:20] + b"{{{{", GLB, 400, "GLB header declares"),
    (
        triangle_glb(
            edit=lambda doc: doc["accessors"].append(
                {"componentType": 5126, "count": 10**9, "type": "VEC3"}
            )
        ),
        GLB,
        413,
        "GLB accessors declare",
    ),
    (
        triangle_glb(indices=(0, 1, 7)),
        GLB,
        422,
        "faces[0] refers to vertex 7, but there are 3 vertices",
    ),
    (b"", OBJ, 400, "the OBJ body is empty"),
]
