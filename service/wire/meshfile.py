"""Mesh files (OBJ, PLY, STL, GLB, OFF) as triangles: geometry only, read strictly.

Rules
-----
* Only vertex positions and faces are read. Textures, images, materials, colours, normals and
  texture coordinates are ignored and never decoded: GLB images, OBJ ``mtllib``/``usemtl``, PLY
  ``TextureFile`` comments and colour properties, OFF colours.
* Vertices and winding are as in the file (trimesh's ``process=False``). A polygon of n vertices
  becomes n - 2 triangles, a fan from its first vertex. All objects of a file are merged into one
  mesh with their scene transforms applied (GLB nodes).
* Refused with 400 (``BadBody``), naming the problem: an empty or unparseable file; a header that
  disagrees with the body (PLY element counts, binary STL triangle count, GLB chunk lengths, OFF
  counts); a PLY header without ``end_header``; a GLB whose buffers are outside the file (a
  ``uri``) or that needs a compression extension; an OFF face that lists fewer indices than it
  declares; a file with no triangles.
* Refused with 422 (``Invalid``): a face index out of range (OBJ and OFF name the line; OBJ
  indices start at 1, negative ones count back from the last vertex defined before the face), a
  face of fewer than 3 vertices; non-finite vertices (``wire.check_vertices``).
* The work is bounded by the body: nothing is allocated from a count a header declares before the
  body is checked to hold that much, and a GLB may decode (its buffer views, its accessors, its
  instanced triangles) to at most ``EXPANSION`` times its size, else 413 (``TooLarge``).

OBJ and OFF are read here with NumPy, because trimesh (5.2) reads the OBJ index 0 as the first
vertex, resolves negative OBJ indices from the end of the file instead of from the face's line,
and reads the OFF face ``1000000 0 1 2`` as a triangle. So is an ASCII PLY whose faces are its
face element's leading list (trimesh's reader holds tens of times the body), and a binary PLY
whose faces differ in length (trimesh reads only rows as long as the first). The other PLYs,
STL and GLB are read by trimesh after their headers are checked here. The text readers find
their lines with NumPy over the whole body (``_Lines``), never as a Python object a line.
"""

from __future__ import annotations

import io
import re
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import BadBody, Invalid, TooLarge
from .decoders import parse_json

Buffer = bytes | memoryview

#: A GLB may decode to at most this many times its size (buffer views, accessors, and the
#: instanced mesh as float32 vertices and int32 faces).
EXPANSION = 8


#: Formats whose body starts with a line of text (a binary STL's 80-byte header does not count:
#: its first bytes may be anything).
TEXT_HEADED = ("obj", "off", "ply")
UTF8_BOM = b"\xef\xbb\xbf"


def read_mesh_file(body: Buffer, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float32 (V, 3), faces int64 (F, 3)) of all triangles of a mesh file, merged.

    Face indices of OBJ and OFF are checked here (naming the line); the caller checks the others
    against V (``wire.check_faces``) and that the vertices are finite.
    """
    data = bytes(body)
    if fmt in TEXT_HEADED:  # a BOM (Windows editors write one) would hide the first line
        data = data.removeprefix(UTF8_BOM)
    if not data.strip():
        raise BadBody(f"the {fmt.upper()} body is empty")
    if fmt == "obj":
        vertices, faces = read_obj(data)
    elif fmt == "off":
        vertices, faces = read_off(data)
    else:
        try:
            layout = {"ply": check_ply, "stl": check_stl, "glb": check_glb}[fmt](data)
            read = None if layout is None else read_ply_by_hand(data, layout)
        except BadBody as exc:
            raise BadBody(f"body cannot be read as {fmt.upper()}: {exc.detail}") from None
        if fmt == "stl" and not data.isascii() and is_ascii_stl(data):
            data = data.translate(_ASCII_ONLY)  # only names and comments hold such bytes
        vertices, faces = _read_with_trimesh(data, fmt) if read is None else read
    if len(faces) == 0:
        raise BadBody(f"no triangles found in the {fmt.upper()} body; is it really {fmt.upper()}?")
    if vertices.ndim != 2 or vertices.shape[1] != 3:  # a glTF POSITION of another type
        raise BadBody(
            f"the {fmt.upper()} body's vertex positions have shape {vertices.shape}: "
            "3 coordinates a vertex are needed"
        )
    return vertices, faces


def _read_with_trimesh(data: bytes, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    import trimesh  # only these formats need it, and it is slow to import

    try:
        scene = trimesh.load_scene(
            io.BytesIO(data), file_type=fmt, process=False, skip_materials=True
        )
        _check_instances(scene, len(data), fmt)
        mesh = scene.to_mesh()
    except TooLarge:
        raise
    except KeyError as exc:  # a property or a key the file does not have (a PLY without z)
        raise BadBody(f"body cannot be read as {fmt.upper()}: it lacks {exc}") from None
    except Exception as exc:  # trimesh raises anything from its parsers: all mean "unreadable"
        raise BadBody(
            f"body cannot be read as {fmt.upper()}: {type(exc).__name__}: {exc}"
        ) from None
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int64)


def _check_instances(scene, size: int, fmt: str) -> None:
    """413 if the scene's nodes instance its meshes into more than EXPANSION x the file."""
    vertices = triangles = 0
    for node in scene.graph.nodes_geometry:
        geometry = scene.geometry.get(scene.graph[node][1])
        if geometry is not None and hasattr(geometry, "faces"):
            vertices += len(geometry.vertices)
            triangles += len(geometry.faces)
    decoded = 12 * (vertices + triangles)  # float32 (V, 3) and int32 (F, 3)
    if decoded > EXPANSION * size:
        raise TooLarge(
            f"the {fmt.upper()} body instances its meshes into {triangles} triangles "
            f"and {vertices} vertices ({decoded} bytes), over {EXPANSION} times its "
            f"{size} bytes; send the instances flattened, or as .npz"
        )


# --------------------------------------------------------------------------------------------
# OBJ: ``v x y z [w | r g b]`` and ``f i[/t][/n] ...`` lines; every other line is ignored


_SPACE = np.zeros(256, bool)
_SPACE[list(b" \t\n\r\v\f")] = True


def read_obj(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float32 (V, 3), faces int64 (F, 3)) of an OBJ, indices checked. The lines are
    found and cut with NumPy over the whole body, never as a Python object a line."""
    data = _plain_lines(data)
    lines = _Lines(data)
    v_at = lines.starting_with(b"v")
    f_at = lines.starting_with(b"f")
    vertices = _vertex_rows(lines.text(v_at, skip=2).splitlines(), v_at + 1, "OBJ", lines)
    if not len(f_at):
        return vertices, np.zeros((0, 3), np.int64)
    counts, indices = _obj_face_indices(lines.text(f_at, skip=2), len(f_at))
    if counts is None:  # something is not an integer: find the line to name it
        for i in f_at:
            for token in lines[i][2:].split():
                if not re.fullmatch(rb"[+-]?\d+", token.split(b"/", 1)[0]):
                    raise BadBody(
                        f"OBJ line {i + 1} ({_show(lines[i])}): {_show(token)} is "
                        "not a vertex index (an integer, optionally /texture/normal)"
                    )
        raise BadBody("OBJ face lines cannot be read")  # pragma: no cover - the loop names one
    short = np.flatnonzero(counts < 3)
    if short.size:
        i = f_at[short[0]]
        raise Invalid(
            f"OBJ line {i + 1} ({_show(lines[i])}): a face needs at least 3 vertices, "
            f"this one has {counts[short[0]]}; {short.size} of {len(counts)} faces "
            "have fewer than 3"
        )
    # A negative index counts back from the last vertex defined before the face's line.
    before = np.repeat(np.searchsorted(v_at, f_at), counts)
    resolved = np.where(indices > 0, indices - 1, before + indices)
    bad = (indices == 0) | (resolved < 0) | (resolved >= len(vertices))
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        face = int(np.searchsorted(np.cumsum(counts), first, side="right"))
        n_bad = np.unique(np.repeat(np.arange(len(counts)), counts)[bad]).size
        i, index = f_at[face], int(indices[first])
        if index == 0:
            why = "but OBJ indices start at 1 (negative ones count back from the last vertex)"
        elif index < 0:
            why = f"but only {int(before[first])} vertices are defined before it"
        else:
            why = f"but there are {len(vertices)} vertices (OBJ indices start at 1)"
        shown = index if abs(index) < 2**63 - 1 else "a number beyond int64"  # read clamped
        raise Invalid(
            f"OBJ line {i + 1} ({_show(lines[i])}) refers to vertex {shown}, {why}; "
            f"{n_bad} of {len(counts)} faces are out of range"
        )
    del before, indices, bad
    return vertices, fan(counts, resolved)


def _plain_lines(data: bytes, continued: bool = True) -> bytes:
    """An OBJ's or OFF's text with its lines plain: continued lines joined, every line ended by
    ``\\n``, comments and leading blanks removed (each a copy only when the body needs it)."""
    if continued:  # an OBJ's line ending in a backslash goes on on the next
        data = data.replace(b"\\\r\n", b" ").replace(b"\\\n", b" ")
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    if b"#" in data:
        data = re.sub(rb"#[^\n]*", b"", data)
    if re.search(rb"(?m)^[ \t]", data):
        data = re.sub(rb"(?m)^[ \t]+", b"", data)
    return data if data.endswith(b"\n") else data + b"\n"


class _Lines:
    """The lines of a text whose every line ends in ``\\n``, as the offsets where each starts
    and ends."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.buf = np.frombuffer(data, np.uint8)
        self.ends = np.flatnonzero(self.buf == ord("\n"))
        self.starts = np.append(0, self.ends[:-1] + 1)

    def __getitem__(self, i: int) -> bytes:
        return self.data[self.starts[i] : self.ends[i]]

    def starting_with(self, letter: bytes) -> np.ndarray:
        """int64 numbers of the lines that start with ``letter`` and a blank (``v 1 2 3``)."""
        padded = np.append(self.buf, np.zeros(2, np.uint8))
        first, second = padded[self.starts], padded[self.starts + 1]
        return np.flatnonzero((first == letter[0]) & ((second == 32) | (second == 9)))

    def text(self, at: np.ndarray, skip: int) -> bytes:
        """Lines ``at`` without their first ``skip`` bytes, each with its newline."""
        kept = _in_spans(len(self.buf), self.starts[at] + skip, self.ends[at] + 1)
        return self.buf[kept].tobytes()


def _vertex_rows(rows: list[bytes], numbers, fmt: str, lines) -> np.ndarray:
    """float32 (V, 3): the first three numbers of each of ``rows``, the text of line
    ``numbers[k]`` (1-based) of ``lines`` after its keyword (an OBJ line's ``v``)."""
    if not len(rows):
        return np.zeros((0, 3), np.float32)
    if all(row and not row.isspace() for row in rows):  # loadtxt would skip a blank row
        try:
            return np.loadtxt(rows, dtype=np.float32, usecols=(0, 1, 2), ndmin=2, comments=None)
        except ValueError:
            pass
    for number, row in zip(numbers, rows):  # name the first line loadtxt could not read
        words = row.split()
        line = _show(lines[number - 1])
        try:
            [float(x) for x in words[:3]]
        except ValueError:
            raise BadBody(f"{fmt} line {number} ({line}): a vertex must be numbers x y z") from None
        if len(words) < 3:
            raise BadBody(f"{fmt} line {number} ({line}): a vertex needs 3 coordinates x y z")
    raise BadBody(f"{fmt} vertex lines cannot be read")  # pragma: no cover - the loop names one


def _obj_face_indices(text: bytes, n_rows: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(vertex references per face line int64 (L,), the references as written int64 (R,)) of
    the ``n_rows`` lines of ``text``, or (None, None) if a reference is not an integer.
    Texture and normal indices are dropped."""
    if b"/" in text:
        if re.search(rb"(^|\s)/", text):  # a reference without its vertex index
            return None, None
        text = _without_slash_parts(text)
    return integer_rows(text, n_rows)


def _without_slash_parts(text: bytes) -> bytes:
    """``text`` without the ``/...`` part of each whitespace-separated token."""
    buf = np.frombuffer(text, np.uint8)
    slashes = np.flatnonzero(buf == ord("/"))
    spaces = np.append(np.flatnonzero(_SPACE[buf]), len(buf))
    ends, first = np.unique(spaces[np.searchsorted(spaces, slashes)], return_index=True)
    return buf[~_in_spans(len(buf), slashes[first], ends)].tobytes()


def _in_spans(n: int, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """bool (n,): the positions in [starts[k], stops[k]) for spans that do not overlap (a span
    may start where another stops), marked with one int8 a position."""
    inside = np.zeros(n + 1, np.int8)
    inside[starts] = 1
    inside[stops] -= 1  # after the +1s: a span may start where another stops
    return np.cumsum(inside[:-1], dtype=np.int8) > 0


_INTEGER_START = np.zeros(256, bool)
_INTEGER_START[list(b"+-0123456789")] = True


def integer_rows(text: bytes, n_rows: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(how many numbers each of the ``n_rows`` lines of ``text`` holds int64 (n_rows,), all the
    numbers int64 (N,)), or (None, None) if one is not an integer."""
    buf = np.frombuffer(text, np.uint8)
    space = _SPACE[buf]
    starts = np.flatnonzero(~space & np.concatenate(([True], space[:-1])))
    rows = np.searchsorted(np.flatnonzero(buf == ord("\n")), starts)
    counts = np.bincount(rows, minlength=n_rows)
    if not len(starts):
        return counts, np.zeros(0, np.int64)
    if not _INTEGER_START[buf[starts]].all():
        return None, None
    try:  # fromstring stops at a token it cannot read, which the count check below catches
        values = np.fromstring(text, dtype=np.int64, sep=" ")
    except ValueError:
        return None, None
    return (counts, values) if len(values) == len(starts) else (None, None)


def _show(line: bytes, limit: int = 60) -> str:
    """A line or token for a message: `f 0 1 2`, cut to ``limit`` characters."""
    text = line.decode("utf-8", "replace").strip()
    return f"`{text if len(text) <= limit else text[:limit] + '...'}`"


def fan(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """int64 (sum(counts - 2), 3): polygons of ``counts[i]`` vertices each (concatenated in
    ``indices``) as triangle fans from their first vertex, in order. Written column by column
    into the answer, so that few temporaries of a triangle each are alive at once."""
    n_triangles = counts - 2
    starts = np.cumsum(counts) - counts
    total = int(n_triangles.sum())
    faces = np.empty((total, 3), np.int64)
    faces[:, 0] = np.repeat(indices[starts], n_triangles)
    # triangle k of a polygon takes its corners k + 1 and k + 2
    corner = np.repeat(starts + 1 - (np.cumsum(n_triangles) - n_triangles), n_triangles)
    corner += np.arange(total)
    faces[:, 1] = indices[corner]
    corner += 1
    faces[:, 2] = indices[corner]
    return faces


# --------------------------------------------------------------------------------------------
# OFF: ``[C][N]OFF``, ``V F E``, V lines ``x y z ...``, F lines ``n i1 .. in [colour]``


_OFF_KEYWORD = re.compile(rb"(ST)?C?N?OFF")


def read_off(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float32 (V, 3), faces int64 (F, 3)) of an OFF, indices checked."""
    lines = _Lines(_plain_lines(data, continued=False))
    at = np.flatnonzero(lines.ends > lines.starts)  # the non-blank lines
    if not len(at):
        raise BadBody("the OFF body holds only comments")
    header = lines[at[0]].split()
    if not _OFF_KEYWORD.fullmatch(header[0]):
        raise BadBody(
            f"OFF line {at[0] + 1}: the file must start with OFF (or COFF, NOFF, "
            f"CNOFF, STOFF), not {_show(header[0])}; 4OFF and nOFF are not read"
        )
    if len(header) == 1:  # the counts are on the next line
        at = at[1:]
        if not len(at):
            raise BadBody("OFF has no counts line `vertices faces edges`")
        header = [b"OFF", *lines[at[0]].split()]
    counts_line = at[0] + 1
    try:
        n_vertices, n_faces = (int(t) for t in header[1:3])
    except ValueError:
        raise BadBody(
            f"OFF line {counts_line}: the counts must be integers "
            f"`vertices faces edges`, got {_show(lines[at[0]])}"
        ) from None
    if n_vertices < 0 or n_faces < 0:
        raise BadBody(f"OFF line {counts_line}: the counts must not be negative")
    v_at, f_at = at[1 : 1 + n_vertices], at[1 + n_vertices :]
    if len(v_at) != n_vertices or len(f_at) != n_faces:
        raise BadBody(
            f"OFF line {counts_line} declares {n_vertices} vertices and {n_faces} "
            f"faces ({n_vertices + n_faces} lines), but {len(at) - 1} lines follow"
        )
    vertices = _vertex_rows(lines.text(v_at, skip=0).splitlines(), v_at + 1, "OFF", lines)
    counts, values = integer_rows(lines.text(f_at, skip=0), len(f_at))
    if counts is None:
        for i in f_at:
            if not all(re.fullmatch(rb"[+-]?\d+", t) for t in lines[i].split()):
                raise BadBody(
                    f"OFF line {i + 1} ({_show(lines[i])}): a face must be integers "
                    "`n i1 .. in` (an integer colour may follow)"
                )
        raise BadBody("OFF face lines cannot be read")  # pragma: no cover - the loop names one
    firsts = np.cumsum(counts) - counts
    sizes = values[firsts]
    listed = counts - 1
    for rows, problem, error in (
        (sizes < 3, "a face needs at least 3 vertices, this one declares {size}", Invalid),
        (listed < sizes, "declares a face of {size} vertices but lists {listed} indices", BadBody),
        (
            listed > sizes + 4,
            "declares a face of {size} vertices but lists {listed} values "
            "(its indices and a colour of at most 4)",
            BadBody,
        ),
    ):
        if rows.any():
            face = int(np.flatnonzero(rows)[0])
            i = f_at[face]
            raise error(
                f"OFF line {i + 1} ({_show(lines[i])}): "
                + problem.format(size=sizes[face], listed=listed[face])
            )
    # a line's indices are the `size` values after its first (a colour may follow them)
    indices = values[_in_spans(len(values), firsts + 1, firsts + 1 + sizes)]
    del values
    bad = (indices < 0) | (indices >= n_vertices)
    if bad.any():
        face = int(np.searchsorted(np.cumsum(sizes), np.flatnonzero(bad)[0], side="right"))
        i = f_at[face]
        n_bad = np.unique(np.repeat(np.arange(len(sizes)), sizes)[bad]).size
        raise Invalid(
            f"OFF line {i + 1} ({_show(lines[i])}) refers to vertex "
            f"{indices[bad][0]}, but there are {n_vertices} vertices (OFF indices "
            f"start at 0); {n_bad} of {n_faces} faces are out of range"
        )
    return vertices, fan(sizes, indices)


# --------------------------------------------------------------------------------------------
# PLY, STL, GLB: headers checked before trimesh reads them


#: NumPy codes of the PLY types
_PLY_NUMPY = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
#: Bytes of each PLY type
_PLY_TYPES = {name: np.dtype(code).itemsize for name, code in _PLY_NUMPY.items()}
_PLY_FLOATS = tuple(name for name, code in _PLY_NUMPY.items() if code[0] == "f")
_PLY_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")


def check_ply(data: bytes) -> PlyLayout | None:
    """400 unless the header is complete, its lists hold integers, and the body holds what it
    declares (in ASCII, each row of an element with a list as many values as its counts say).
    Returns the layout of an ASCII PLY, or of a binary PLY whose rows differ in length (which
    trimesh does not read), for ``read_ply_by_hand``; else None."""
    end = re.search(rb"(?m)^end_header[ \t]*\r?$\n?", data)
    if end is None:
        raise BadBody("PLY header has no `end_header` line; the header must end with one")
    header = data[: end.start()].decode("ascii", "replace").splitlines()
    if not header or header[0].strip() != "ply":
        raise BadBody("a PLY file must start with the line `ply`")
    encoding, elements = None, []
    for number, line in enumerate(header[1:], 2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) == 3 and words[1] in _PLY_FORMATS:
            encoding = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append(_PlyElement(words[1], int(words[2])))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in _PLY_TYPES:
            elements[-1].types.append((words[1],))
            elements[-1].names.append(words[2])
        elif (
            words[0] == "property"
            and elements
            and len(words) == 5
            and words[1] == "list"
            and words[2] in _PLY_TYPES
            and words[3] in _PLY_TYPES
        ):
            if words[2] in _PLY_FLOATS or words[3] in _PLY_FLOATS:
                raise BadBody(
                    f"PLY header line {number} ({_show(line.encode())}): a list's count "
                    "and items must be of integer types (its items are vertex indices)"
                )
            elements[-1].types.append((words[2], words[3]))
            elements[-1].names.append(words[4])
        else:
            raise BadBody(
                f"PLY header line {number} ({_show(line.encode())}) is not a format, "
                "element, property or comment line"
            )
    if encoding is None:
        raise BadBody(
            "PLY header has no `format ascii|binary_little_endian|binary_big_endian 1.0` line"
        )
    for element in elements:
        if element.count and not element.lists:
            raise BadBody(
                f"PLY element {element.name} declares {element.count} items but no properties"
            )
    rest = len(data) - end.end()
    declared = ", ".join(f"{e.count} {e.name}" for e in elements)
    if encoding == "ascii":
        lines = data.count(b"\n", end.end()) + (not data.endswith(b"\n"))
        needed = sum(e.count for e in elements)
        if lines < needed:
            raise BadBody(
                f"PLY header declares {declared} ({needed} lines), but the body holds "
                f"only {lines} lines after end_header"
            )
        header_lines = data.count(b"\n", 0, end.end())
        lines, parsed = _check_ascii_lists(data, end.end(), header_lines, elements)
        return PlyLayout(end.end(), "ascii", elements, header_lines, lines, parsed)
    else:
        needed = sum(e.count * e.least_row_bytes for e in elements)
        if rest < needed:
            raise BadBody(
                f"PLY header declares {declared} (at least {needed} bytes), but the "
                f"body holds only {rest} bytes after end_header"
            )
        order = "<" if encoding.endswith("little_endian") else ">"
        if not _check_binary_lists(data, end.end(), order, elements):
            return PlyLayout(end.end(), order, elements)
    return None


@dataclass
class _PlyElement:
    """A PLY element as its header declares it: its properties' names and types, in order."""

    name: str
    count: int
    types: list[tuple[str, ...]] = field(default_factory=list)  #: (type,) or (count, item)
    names: list[str] = field(default_factory=list)

    @property
    def lists(self) -> list[bool]:
        """Which of the properties are lists."""
        return [len(kind) == 2 for kind in self.types]

    @property
    def least_row_bytes(self) -> int:
        """A binary row's bytes with every list empty: its scalars and its lists' counts."""
        return sum(_PLY_TYPES[kind[0]] for kind in self.types)


def _check_binary_lists(data: bytes, at: int, order: str, elements: list) -> bool:
    """400 when a binary element's first row has a list whose count is negative or holds more
    than the body; False when the rows are not all as long as the first (trimesh reads every
    row of an element as long as its first)."""
    for element in elements:
        row = 0
        for kind in element.types:
            if len(kind) == 1:
                row += _PLY_TYPES[kind[0]]
                continue
            count_type, item_type = kind
            count_at = at + row
            if element.count == 0 or count_at + _PLY_TYPES[count_type] > len(data):
                return True  # nothing to read here; the length checks of check_ply hold
            count = int(np.frombuffer(data, order + _PLY_NUMPY[count_type], 1, count_at)[0])
            if count < 0:
                raise BadBody(f"PLY element {element.name}'s first list declares {count} items")
            row += _PLY_TYPES[count_type] + count * _PLY_TYPES[item_type]
        if element.count * row > len(data) - at:
            raise BadBody(
                f"PLY element {element.name}: {element.count} rows as long as its first "
                f"({row} bytes) need {element.count * row} bytes, but {len(data) - at} follow"
            )
        at += element.count * row
        if element is elements[-1] and any(element.lists) and at != len(data):
            return False
    return True


@dataclass
class PlyLayout:
    """Where a PLY's rows start, its byte order (``<``, ``>``) or ``ascii``, and its elements;
    for an ASCII PLY also its header's lines, its body's lines, and the rows its check parsed
    (an element's name: its (counts, values) as ``integer_rows`` gives them)."""

    start: int
    order: str
    elements: list[_PlyElement]
    header_lines: int = 0
    lines: _Lines | None = None
    parsed: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


def read_ply_by_hand(data: bytes, layout: PlyLayout) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices, faces) of the PLYs trimesh reads slowly or not at all, or None to let it."""
    if layout.order == "ascii":
        return read_ascii_ply(data, layout)
    return read_binary_ply(data, layout)


def read_ascii_ply(data: bytes, layout: PlyLayout) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices float32 (V, 3), faces int64 (F, 3)) of an ASCII PLY whose vertex element
    holds x, y, z among its scalars and whose face element starts with its list of integer
    indices, read with NumPy over the whole body (trimesh's reader of short face rows peaks at
    53 times the body); None for any other layout."""
    lines = layout.lines
    vertices = faces = None
    row = 0
    for element in layout.elements:
        rows = np.arange(row, row + element.count)
        row += element.count
        if element.name == "vertex":
            if any(element.lists) or not {"x", "y", "z"} <= set(element.names):
                return None
            columns = [element.names.index(axis) for axis in "xyz"]
            try:
                vertices = np.loadtxt(
                    lines.text(rows, skip=0).splitlines(),
                    dtype=np.float32,
                    usecols=columns,
                    ndmin=2,
                    comments=None,
                )
            except ValueError:
                return None  # trimesh names what it cannot read
        elif element.name == "face":
            if element.lists[:1] != [True] or any(element.lists[1:]):
                return None
            parsed = layout.parsed.get(element.name)
            counts, values = parsed or integer_rows(lines.text(rows, skip=0), element.count)
            if counts is None or len(counts) != element.count or (counts == 0).any():
                return None
            firsts = np.cumsum(counts) - counts
            sizes = values[firsts]
            short = np.flatnonzero(sizes < 3)
            if short.size:
                raise Invalid(
                    f"PLY line {layout.header_lines + row - element.count + short[0] + 1}: a face "
                    f"needs at least 3 vertices, this one lists {sizes[short[0]]}"
                )
            faces = fan(sizes, values[_in_spans(len(values), firsts + 1, firsts + 1 + sizes)])
    if vertices is None or faces is None:
        return None
    return vertices, faces


def read_binary_ply(data: bytes, layout: PlyLayout) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float32 (V, 3), faces int64 (F, 3)) of a binary PLY whose faces differ in
    length, row by row: the vertex element's x, y, z, and the face element's vertex_indices
    (or vertex_index) fanned into triangles."""
    at, vertices, counts, indices = layout.start, None, None, None
    for element in layout.elements:
        if not any(element.lists):
            dtype = np.dtype(
                [(n, layout.order + _PLY_NUMPY[t[0]]) for n, t in zip(element.names, element.types)]
            )
            if at + element.count * dtype.itemsize > len(data):
                raise BadBody(f"PLY element {element.name} runs past the end of the body")
            rows = np.frombuffer(data, dtype, element.count, at)
            at += element.count * dtype.itemsize
            if element.name == "vertex":
                if not {"x", "y", "z"} <= set(element.names):
                    raise BadBody("PLY element vertex needs properties x, y and z")
                vertices = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float32)
            continue
        at, lists = _list_rows(data, at, layout.order, element)
        if element.name == "face":
            for name in ("vertex_indices", "vertex_index"):
                if name in lists:
                    counts, indices = lists[name]
    if vertices is None or counts is None:
        raise BadBody("a PLY needs a vertex element and a face element with vertex_indices")
    short = np.flatnonzero(counts < 3)
    if short.size:
        raise Invalid(
            f"PLY face {short[0]} has {counts[short[0]]} vertices; a face needs at least 3 "
            f"({short.size} faces have fewer)"
        )
    return vertices, fan(counts, indices)


def _list_rows(data: bytes, at: int, order: str, element: _PlyElement) -> tuple[int, dict]:
    """Read ``element``'s rows from byte ``at`` one by one: (where they end, each list
    property's (counts int64 (rows,), items int64 (sum of counts,)))."""
    counts = {
        n: np.zeros(element.count, np.int64)
        for n, k in zip(element.names, element.types)
        if len(k) == 2
    }
    items = {n: [] for n in counts}
    for row in range(element.count):
        for name, kind in zip(element.names, element.types):
            if len(kind) == 1:
                at += _PLY_TYPES[kind[0]]
                continue
            count_code, item_code = _PLY_NUMPY[kind[0]], _PLY_NUMPY[kind[1]]
            if at + _PLY_TYPES[kind[0]] > len(data):
                raise BadBody(f"PLY element {element.name} runs past the end of the body")
            n = int(np.frombuffer(data, order + count_code, 1, at)[0])
            at += _PLY_TYPES[kind[0]]
            if n < 0 or at + n * _PLY_TYPES[kind[1]] > len(data):
                raise BadBody(
                    f"PLY element {element.name}, row {row}: its list {name} of {n} items "
                    "runs past the end of the body"
                )
            counts[name][row] = n
            items[name].append(np.frombuffer(data, order + item_code, n, at))
            at += n * _PLY_TYPES[kind[1]]
    joined = {n: np.concatenate(items[n] or [np.zeros(0)]).astype(np.int64) for n in counts}
    return at, {n: (counts[n], joined[n]) for n in counts}


def _check_ascii_lists(
    data: bytes, start: int, header_lines: int, elements: list
) -> tuple[_Lines, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """400 naming the line where an ASCII row of an element with a list holds other than its
    counts say (``3 0 1 2``: a count, then that many integers), as trimesh reads what it finds.
    Returns the body's lines and the rows of each element of one list it parsed whole."""
    body = data[start:]
    lines = _Lines(body if body.endswith(b"\n") else body + b"\n")
    parsed = {}
    first = 0
    for element in elements:
        rows = np.arange(first, first + element.count)
        first += element.count
        if not any(element.lists):
            continue
        if element.lists == [True]:  # the usual face element: one list alone
            counts, values = integer_rows(lines.text(rows, skip=0), element.count)
            if counts is not None and len(values):
                heads = np.cumsum(counts) - counts
                held = np.where(counts > 0, values[np.minimum(heads, len(values) - 1)] + 1, -1)
                if (held == counts).all():
                    parsed[element.name] = counts, values
                    continue
        for k in rows:
            _check_ascii_row(lines[k], element, header_lines + k + 1)
    return lines, parsed


def _check_ascii_row(row: bytes, element: _PlyElement, number: int) -> None:
    words, at = row.split(), 0
    for is_list in element.lists:
        if not is_list:
            at += 1
            continue
        if at >= len(words) or not _PLY_INTEGER.fullmatch(words[at]) or int(words[at]) < 0:
            break
        items = words[at + 1 : at + 1 + int(words[at])]
        if len(items) < int(words[at]) or not all(_PLY_INTEGER.fullmatch(i) for i in items):
            break
        at += 1 + len(items)
    else:
        if at == len(words):
            return
    raise BadBody(
        f"PLY line {number} ({_show(row)}) does not hold what its {element.name} element "
        "declares: each list is a count, then that many integers"
    )


_PLY_INTEGER = re.compile(rb"[+-]?\d+")


_STL_HEADER, _STL_TRIANGLE = 84, 50


def check_stl(data: bytes) -> None:
    """400 unless the body is a binary STL of exactly the length its count gives, or ASCII."""
    if is_ascii_stl(data):
        _check_ascii_facets(data)
        return
    if len(data) < _STL_HEADER:
        raise BadBody(
            f"STL body is {len(data)} bytes: shorter than the 84-byte header of a "
            "binary STL, and not an ASCII STL (`solid` ... `endsolid`)"
        )
    if _stl_length(data) != len(data):
        count = struct.unpack_from("<I", data, 80)[0]
        raise BadBody(
            f"binary STL header declares {count} triangles ({_stl_length(data)} bytes), "
            f"but the body is {len(data)} bytes"
        )


def is_ascii_stl(data: bytes) -> bool:
    """Whether an STL body is ASCII (``solid`` ... ``endsolid``, not the length of a binary STL,
    which may also start with "solid")."""
    if data[:1024].lstrip()[:5].lower() != b"solid" or b"endsolid" not in data[-1024:].lower():
        return False
    return len(data) < _STL_HEADER or _stl_length(data) != len(data)


#: Every byte past ASCII to "?": trimesh reads an ASCII STL as Python text, which takes 4 bytes a
#: character for all of it once one character is past Latin-1.
_ASCII_ONLY = bytes(range(128)) + b"?" * 128


def _check_ascii_facets(data: bytes) -> None:
    """400 naming the first facet of an ASCII STL that holds other than 3 vertices (trimesh
    would cut the vertices into triangles wherever they fall)."""
    text = data.lower()
    ends = np.array([m.start() for m in re.finditer(rb"\bendfacet\b", text)], np.int64)
    vertices = np.array([m.start() for m in re.finditer(rb"\bvertex\b", text)], np.int64)
    held = np.bincount(np.searchsorted(ends, vertices), minlength=len(ends) + 1)
    bad = np.flatnonzero(held[: len(ends)] != 3)
    if bad.size:
        line = text.count(b"\n", 0, ends[bad[0]]) + 1
        raise BadBody(
            f"ASCII STL facet {bad[0] + 1} (ending on line {line}) holds {held[bad[0]]} "
            f"vertices, not 3; {bad.size} of {len(ends)} facets do"
        )
    if held[-1]:
        raise BadBody(f"ASCII STL has {held[-1]} vertices after its last endfacet")


def _stl_length(data: bytes) -> int:
    return _STL_HEADER + _STL_TRIANGLE * struct.unpack_from("<I", data, 80)[0]


_GLB_JSON, _GLB_BIN = 0x4E4F534A, 0x004E4942
_GLTF_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_GLTF_ITEM_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_GLTF_UNREAD = ("KHR_draco_mesh_compression", "EXT_meshopt_compression")


def check_glb(data: bytes) -> None:
    """400 unless the GLB is self-contained and its chunks and JSON are consistent; 413 if its
    buffer views or accessors add up to more than EXPANSION x the file."""
    if len(data) < 20:
        raise BadBody(f"GLB body is {len(data)} bytes: shorter than a GLB header and JSON chunk")
    magic, version, length = struct.unpack_from("<4sII", data)
    if magic != b"glTF" or version != 2:
        raise BadBody(f"GLB must start with `glTF` and version 2, not {magic!r} version {version}")
    if length != len(data):
        raise BadBody(f"GLB header declares {length} bytes, but the body is {len(data)} bytes")
    chunks, offset = [], 12
    while offset < len(data):
        if len(data) - offset < 8:
            raise BadBody(f"GLB has {len(data) - offset} stray bytes after its last chunk")
        size, kind = struct.unpack_from("<II", data, offset)
        if size > len(data) - offset - 8:
            raise BadBody(
                f"GLB chunk {len(chunks)} declares {size} bytes, but only "
                f"{len(data) - offset - 8} follow"
            )
        chunks.append((kind, data[offset + 8 : offset + 8 + size]))
        offset += 8 + size
    if chunks[0][0] != _GLB_JSON:
        raise BadBody("GLB's first chunk must be its JSON")
    doc = parse_json(chunks[0][1], "GLB JSON chunk", unique_keys=False)
    if not isinstance(doc, dict):
        raise BadBody("GLB JSON chunk must be an object")
    buffers = _list(doc, "buffers")
    for i, buffer in enumerate(buffers):
        if not isinstance(buffer, dict) or "uri" in buffer:
            uri = buffer.get("uri") if isinstance(buffer, dict) else buffer
            raise BadBody(
                f"GLB buffer {i} refers to {str(uri)[:60]!r}: only a self-contained "
                "GLB is accepted (every buffer inside the file, in its BIN chunk)"
            )
    if len(buffers) > sum(kind == _GLB_BIN for kind, _ in chunks):
        raise BadBody(
            f"GLB declares {len(buffers)} buffers but holds "
            f"{sum(kind == _GLB_BIN for kind, _ in chunks)} BIN chunks"
        )
    used = set()
    for key in ("extensionsUsed", "extensionsRequired"):
        for i, name in enumerate(_list(doc, key)):
            if not isinstance(name, str):
                raise BadBody(f"GLB JSON {key}[{i}] must be an extension's name (a string)")
            used.add(name)
    for name in _GLTF_UNREAD:
        if name in used:
            raise BadBody(f"GLB uses {name}, which is not read; send it uncompressed")
    views = sum(
        _natural(
            v.get("byteLength") if isinstance(v, dict) else None, f"bufferViews[{i}].byteLength"
        )
        for i, v in enumerate(_list(doc, "bufferViews"))
    )
    accessors, items = 0, []
    for i, accessor in enumerate(_list(doc, "accessors")):
        # JSON may put a list or an object where a name or a number belongs: not a dict key
        if (
            not isinstance(accessor, dict)
            or not isinstance(accessor.get("type"), str)
            or accessor["type"] not in _GLTF_COMPONENTS
            or type(accessor.get("componentType")) is not int
            or accessor["componentType"] not in _GLTF_ITEM_BYTES
        ):
            raise BadBody(f"GLB accessors[{i}] needs a known type and componentType")
        items.append(
            _natural(accessor.get("count"), f"accessors[{i}].count")
            * _GLTF_COMPONENTS[accessor["type"]]
        )
        accessors += items[-1] * _GLTF_ITEM_BYTES[accessor["componentType"]]
    decoded = _primitive_bytes(doc, items)
    for what, size in (
        ("buffer views declare", views),
        ("accessors declare", accessors),
        ("meshes' primitives decode to", decoded),
    ):
        if size > EXPANSION * len(data):
            raise TooLarge(
                f"GLB {what} {size} bytes, over {EXPANSION} times the file's {len(data)} bytes"
            )
    bin_sizes = [len(payload) for kind, payload in chunks if kind == _GLB_BIN]
    _check_glb_references(doc, bin_sizes)


def _check_glb_references(doc: dict, bin_sizes: list[int]) -> None:
    """400 naming the JSON key where a glTF reference is out of range: a buffer view beyond its
    BIN chunk, an accessor beyond its view, a primitive without POSITION, an index of a view,
    accessor, mesh or node that does not exist (trimesh would fail on each, naming itself)."""
    views, accessors = _list(doc, "bufferViews"), _list(doc, "accessors")
    meshes, nodes = _list(doc, "meshes"), _list(doc, "nodes")
    view_sizes = []
    for i, view in enumerate(views):
        buffer = _reference(view.get("buffer"), len(bin_sizes), f"bufferViews[{i}].buffer")
        offset = _natural(view.get("byteOffset", 0), f"bufferViews[{i}].byteOffset")
        if offset + view["byteLength"] > bin_sizes[buffer]:
            raise BadBody(
                f"GLB bufferViews[{i}] ends at byte {offset + view['byteLength']} of a BIN "
                f"chunk of {bin_sizes[buffer]} bytes"
            )
        stride = view.get("byteStride")
        if stride is not None and (type(stride) is not int or not 4 <= stride <= 252):
            raise BadBody(f"GLB bufferViews[{i}].byteStride must be an integer in [4, 252]")
        view_sizes.append((view["byteLength"], stride))
    for i, accessor in enumerate(accessors):
        if "sparse" in accessor:
            raise BadBody(f"GLB accessors[{i}] is sparse, which is not read")
        if accessor.get("bufferView") is None:
            continue  # all zeros, as glTF says
        v = _reference(accessor["bufferView"], len(views), f"accessors[{i}].bufferView")
        length, stride = view_sizes[v]
        item = _GLTF_COMPONENTS[accessor["type"]] * _GLTF_ITEM_BYTES[accessor["componentType"]]
        offset = _natural(accessor.get("byteOffset", 0), f"accessors[{i}].byteOffset")
        count = accessor["count"]
        end = offset + (count - 1) * (stride or item) + item if count else offset
        if end > length:
            raise BadBody(
                f"GLB accessors[{i}] ({count} x {accessor['type']}) ends at byte {end} of "
                f"bufferViews[{v}], which holds {length}"
            )
    for m, mesh in enumerate(meshes):
        if not isinstance(mesh, dict):
            raise BadBody(f"GLB meshes[{m}] must be an object")
        for p, primitive in enumerate(mesh.get("primitives", [])):
            at = f"meshes[{m}].primitives[{p}]"
            attributes = primitive.get("attributes") if isinstance(primitive, dict) else None
            if not isinstance(attributes, dict) or "POSITION" not in attributes:
                raise BadBody(f"GLB {at} needs attributes with a POSITION")
            for name, accessor in attributes.items():
                _reference(accessor, len(accessors), f"{at}.attributes.{name}")
            if primitive.get("indices") is not None:
                _reference(primitive["indices"], len(accessors), f"{at}.indices")
    for n, node in enumerate(nodes):
        if not isinstance(node, dict):
            raise BadBody(f"GLB nodes[{n}] must be an object")
        if node.get("mesh") is not None:
            _reference(node["mesh"], len(meshes), f"nodes[{n}].mesh")
        for c, child in enumerate(_list(node, "children", f"nodes[{n}].children")):
            _reference(child, len(nodes), f"nodes[{n}].children[{c}]")
    scenes = _list(doc, "scenes")
    for i, scene in enumerate(scenes):
        if not isinstance(scene, dict):
            raise BadBody(f"GLB scenes[{i}] must be an object")
        for k, node in enumerate(_list(scene, "nodes", f"scenes[{i}].nodes")):
            _reference(node, len(nodes), f"scenes[{i}].nodes[{k}]")
    if doc.get("scene") is not None:
        _reference(doc["scene"], len(scenes), "scene")


def _reference(value: Any, n: int, name: str) -> int:
    """``value`` as an index of one of ``n`` things, else 400 naming ``name``."""
    if type(value) is not int or not 0 <= value < n:
        raise BadBody(f"GLB {name} is {str(value)[:40]}, but there are {n} to refer to")
    return value


def _primitive_bytes(doc: dict, items: list[int]) -> int:
    """Bytes the meshes' primitives decode to: every accessor a primitive uses, once for each
    primitive that uses it (a shared accessor is decoded again for each mesh), as float64 or
    int64 items; strips and fans as up to one triangle an index."""
    total = 0
    for m, mesh in enumerate(_list(doc, "meshes")):
        primitives = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        if not isinstance(primitives, list):
            raise BadBody(f"GLB meshes[{m}].primitives must be a list")
        for primitive in primitives:
            if not isinstance(primitive, dict):
                continue  # trimesh refuses it: 400
            attributes = primitive.get("attributes")
            used = list(attributes.values()) if isinstance(attributes, dict) else []
            index_items = _items(items, primitive.get("indices"))
            per_index = 8 if primitive.get("mode", 4) == 4 else 24
            total += index_items * per_index + 8 * sum(_items(items, a) for a in used)
    return total


def _items(items: list[int], accessor: Any) -> int:
    """Items (components) of accessor number ``accessor``; 0 for a reference that is not one."""
    if type(accessor) is int and 0 <= accessor < len(items):
        return items[accessor]
    return 0


def _list(doc: dict, key: str, name: str | None = None) -> list:
    value = doc.get(key, [])
    if not isinstance(value, list):
        raise BadBody(f"GLB JSON {name or key} must be a list")
    return value


def _natural(value: Any, name: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 0:
        raise BadBody(f"GLB {name} must be an integer >= 0, got {str(value)[:40]}")
    return value
