"""The wire format: how request bodies become arrays, and answers become bodies.

This docstring is the spec of every body the service reads and writes; API.md is the contract it
implements. Everything here is plain NumPy (mesh files are read by ``meshfile``), so the
client uses the same code to write requests and read answers.

Body formats
------------
The format of a body is chosen by ``?format=`` if given, else by ``Content-Type``:

=========  ==============================================  =========================================
format     Content-Type                                    read with
=========  ==============================================  =========================================
``npy``    ``application/x-npy`` (or ``application/npy``)  a header parse, then ``np.frombuffer``
``npz``    ``application/x-npz`` (``application/npz``,     ``zipfile``; stored members are viewed in
           ``application/zip``)                            place, deflated ones decompressed once
``json``   ``application/json``                            ``json.loads``
``obj``    ``model/obj``                                   ``meshfile`` (NumPy)
``ply``    ``application/ply`` (``model/ply``)             ``meshfile``: trimesh (binary or ASCII)
``stl``    ``model/stl`` (``application/sla``)             ``meshfile``: trimesh (binary or ASCII)
``glb``    ``model/gltf-binary``                           ``meshfile``: trimesh
``off``    ``model/off`` (``application/off``)             ``meshfile`` (NumPy)
=========  ==============================================  =========================================

With no ``Content-Type`` or ``application/octet-stream`` the format is sniffed from the first bytes
(``\\x93NUMPY`` npy, ``PK`` npz, ``glTF`` glb, ``ply`` ply, ``OFF`` off, ``{`` json); anything else
is 415, as is a known format the endpoint does not read.

Binary arrays must be little-endian with exactly the dtype below; a wrong dtype or shape is 422
with the fix in the message (the binary path never converts behind the caller's back: that would
be a hidden copy). ``allow_pickle`` is never on: an object array is 422 and is never unpickled.
A ``.npy`` body whose data is shorter or longer than its header says, or whose shape has a
negative length, is 400; a structured, subarray or void dtype is 422. An ``.npz`` whose members
add up to more than ``max_bytes`` once decompressed is 413; its members must be stored or
deflated, unencrypted, each named once, and must not overlap (400 otherwise), at most
``MAX_NPZ_MEMBERS`` of them. A deflated member is inflated piece by piece and refused as soon as
it passes its declared size, so no body costs more than the limit in memory.

JSON values are read as JSON types: numbers where numbers are expected (a string such as
``"0.5"`` or a boolean is 422), JSON nested too deeply for the parser or an integer of over 4300
digits is 400.

Rays (``decode_rays``; formats npy, npz, json)
    npy  float32 (N, 6) ``[ox, oy, oz, dx, dy, dz]`` or (N, 8) ``[..., tmin, tmax]``.
    npz  ``origins`` float32 (N, 3), ``directions`` float32 (N, 3); optional ``tmin``, ``tmax``
         float32 of shape (N,) or () (one value for the batch). No other keys.
    json ``{"origins": [[x, y, z], ...], "directions": [...], "tmin": number | [..] | null,
         "tmax": number | [..] | null}``; a null field means the default, a null element +inf.
    Defaults: tmin 0, tmax +inf. More than ``max_rays`` rays is 413. Values (finite, non-zero
    directions, tmin <= tmax) are checked by the engine, which names the first bad ray.

Meshes (``decode_mesh``; formats npz, json, obj, ply, stl, glb, off)
    npz  ``vertices`` float32 (V, 3) and ``faces`` int32 or uint32 (F, 3). No other keys.
    json ``{"vertices": [[x, y, z], ...], "faces": [[i, j, k], ...]}`` (faces must be integers).
    A mesh file gives its geometry only, never decoding textures or materials; vertices and
    winding are as in the file; all its objects are merged into one mesh with their scene
    transforms applied; a file with no triangles is 400 (``meshfile`` states the rules). Every
    vertex must be finite and every face index in ``[0, V)``: otherwise 422 naming the first bad
    row (for OBJ and OFF, the line) and how many there are.

Vertices (``decode_vertices``; formats npy, npz, json)
    npy float32 (V, 3); npz key ``vertices``; json ``{"vertices": [[x, y, z], ...]}``.

Frames (``decode_frame``; formats npz, json)
    Keys ``MESH.vertices`` and optionally ``MESH.faces`` for any number of meshes (a mesh name may
    itself contain dots: the suffix after the last dot is the array). JSON uses the same flat keys.

One-shot trace (``decode_trace``; formats npz, json)
    The keys of a mesh (``vertices``, ``faces``) and of rays (``origins``, ``directions``,
    ``tmin``, ``tmax``) in one body.

Answers (``negotiate`` and ``encode_answer``)
    ``Accept`` picks ``application/x-npz``, ``application/x-npy`` or ``application/json`` (q-values
    honoured); absent, ``*/*`` or ``application/*`` gives JSON for a JSON request and npz for any
    other; naming none of these is 406.
    npz  one uncompressed member per field (``t``, ``mesh``, ...); the body is sent as zip headers
         around the answer arrays' own memory, never joined into one copy.
    npy  a single field is a plain array; several fields are one structured array with a named
         field each (``a["t"]``, ``a["normal"]`` of shape (N, 3)).
    json ``{"t": [...], ...}``; float32 values in their shortest round-trip form, so
         ``np.float32(json_value)`` gives back the binary answer bit for bit; inf (and nan) are
         null.
"""

from __future__ import annotations

import functools
import io
import itertools
import json
import math
import struct
import zipfile
import zlib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import BadBody, Invalid, NotAcceptable, TooLarge, UnsupportedMediaType

try:  # ISA-L's CRC-32 is about 10x zlib's; the .npz answer's CRCs are most of its encode time
    from isal.isal_zlib import crc32
except ImportError:  # pragma: no cover - isal is a dependency, but the wire format works without it
    from zlib import crc32

NPY, NPZ, JSON = "application/x-npy", "application/x-npz", "application/json"
Buffer = bytes | memoryview  #: a part of a body

#: Content-Type (lower case, no parameters) -> format.
CONTENT_TYPES: dict[str, str] = {
    NPY: "npy",
    "application/npy": "npy",
    NPZ: "npz",
    "application/npz": "npz",
    "application/zip": "npz",
    JSON: "json",
    "model/obj": "obj",
    "application/ply": "ply",
    "model/ply": "ply",
    "model/stl": "stl",
    "application/sla": "stl",
    "model/gltf-binary": "glb",
    "model/off": "off",
    "application/off": "off",
}
#: The preferred Content-Type of each format (for messages and for the client).
MEDIA_TYPES: dict[str, str] = {
    "npy": NPY,
    "npz": NPZ,
    "json": JSON,
    "obj": "model/obj",
    "ply": "application/ply",
    "stl": "model/stl",
    "glb": "model/gltf-binary",
    "off": "model/off",
}
MESH_FILE_FORMATS = ("obj", "ply", "stl", "glb", "off")

RAY_FORMATS = ("npy", "npz", "json")
MESH_FORMATS = ("npz", "json", *MESH_FILE_FORMATS)
VERTEX_FORMATS = ("npy", "npz", "json")
FRAME_FORMATS = ("npz", "json")
TRACE_FORMATS = ("npz", "json")
ANSWER_FORMATS = ("npz", "npy", "json")

_SNIFF = (
    (b"\x93NUMPY", "npy"),
    (b"PK\x03\x04", "npz"),
    (b"PK\x05\x06", "npz"),
    (b"glTF", "glb"),
    (b"ply", "ply"),
    (b"OFF", "off"),
)
_F32, _I32, _U32 = np.dtype("<f4"), np.dtype("<i4"), np.dtype("<u4")

# Fixed parts of an uncompressed zip: local header, central directory entry, end record.
_LOCAL = struct.Struct("<4s2B4HL2L2H")
_CENTRAL = struct.Struct("<4s4B4HL2L5H2L")
_END = struct.Struct("<4s4H2LH")
_DOS_DATE = (1 << 5) | 1  # 1980-01-01, as zip tools write for "no date"


@dataclass(frozen=True)
class Rays:
    """A ray batch as the engine takes it; arrays may be read-only strided views of the body."""

    origins: np.ndarray  #: (N, 3) float32
    directions: np.ndarray  #: (N, 3) float32
    tmin: np.ndarray | float | None  #: (N,) float32, one value, or None (0)
    tmax: np.ndarray | float | None  #: (N,) float32, one value, or None (+inf)

    def __len__(self) -> int:
        return len(self.origins)


@dataclass(frozen=True)
class MeshArrays:
    """A checked triangle mesh: finite vertices, every face index in [0, V)."""

    vertices: np.ndarray  #: (V, 3) float32
    faces: np.ndarray  #: (F, 3) int32


# --------------------------------------------------------------------------------------------
# Which format a body is in


def resolve_format(
    content_type: str | None,
    format: str | None,
    accepted: Iterable[str],
    body: Buffer = b"",
    what: str = "this endpoint",
) -> str:
    """The format of a body from ``?format=``, else ``Content-Type``, else its first bytes.

    Raises UnsupportedMediaType (415) naming what ``what`` accepts.
    """
    accepted = tuple(accepted)
    choices = ", ".join(f"{MEDIA_TYPES[f]} (?format={f})" for f in accepted)
    if format:
        fmt = format.strip().lower()
        if fmt not in accepted:
            raise UnsupportedMediaType(
                f"?format={format} is not read by {what}; use one of: {choices}"
            )
        return fmt
    media = (content_type or "").split(";", 1)[0].strip().lower()
    if media in ("", "application/octet-stream"):
        head = bytes(body[:8]).lstrip()
        fmt = next(
            (f for magic, f in _SNIFF if head.startswith(magic)),
            "json" if head.startswith(b"{") else None,
        )
        if fmt is None or fmt not in accepted:
            raise UnsupportedMediaType(
                f"cannot tell the body's format from Content-Type {media or '(none)'!s}; "
                f"set Content-Type to one of: {choices}"
            )
        return fmt
    fmt = CONTENT_TYPES.get(media)
    if fmt is None or fmt not in accepted:
        raise UnsupportedMediaType(
            f"Content-Type {media} is not read by {what}; use one of: {choices}"
        )
    return fmt


# --------------------------------------------------------------------------------------------
# Reading .npy, .npz and JSON


class BodyBuffer:
    """A body filled chunk by chunk into one read-only NumPy buffer (server requests and client
    answers alike).

    For big bodies NumPy asks the kernel for huge pages, so filling a 24 MB body costs a dozen
    page faults instead of the six thousand of joining its chunks into one ``bytes``: about 9 ms
    of a 1M-ray request on each side (docs/benchmarks.md, HTTP). The expected size (Content-Length)
    is allocated up front; its pages cost nothing until written.
    """

    def __init__(self, expected: int | None = None) -> None:
        self._buffer = np.empty(expected or 0, np.uint8)
        self._extra: list[bytes] = []  # what arrives beyond the expected size (or without one)
        self.size = 0

    def add(self, chunk: bytes) -> None:
        if not self._extra and self.size + len(chunk) <= len(self._buffer):
            self._buffer[self.size : self.size + len(chunk)] = np.frombuffer(chunk, np.uint8)
        else:
            self._extra.append(chunk)
        self.size += len(chunk)

    def finish(self) -> memoryview:
        """The body; views of it (rays, vertices, answers) are read-only, as views of bytes are."""
        filled = self.size - sum(map(len, self._extra))
        buffer = self._buffer[:filled]
        if self._extra:
            buffer = np.concatenate([buffer, *(np.frombuffer(c, np.uint8) for c in self._extra)])
        buffer.flags.writeable = False
        return memoryview(buffer)


#: The longest .npy header read (numpy itself refuses headers over 10,000 bytes).
MAX_NPY_HEADER_BYTES = 65536 + 16


def read_npy(buf: bytes | memoryview, name: str = "body", structured: bool = False) -> np.ndarray:
    """View a whole .npy held in ``buf`` as an array without copying its data (read-only).

    Requests hold plain numeric arrays; answers (``structured``) may hold a record per ray.
    """
    view = memoryview(buf)
    prefix = bytes(view[:12])
    try:
        # Magic string, version, then the header's length: 2 bytes in version 1.0, 4 after.
        version = np.lib.format.read_magic(io.BytesIO(prefix))
        if version not in ((1, 0), (2, 0), (3, 0)):
            raise ValueError(f"unsupported .npy version {version}")
        size = (
            10 + int.from_bytes(prefix[8:10], "little")
            if version == (1, 0)
            else 12 + int.from_bytes(prefix[8:12], "little")
        )
        if size > MAX_NPY_HEADER_BYTES:
            raise ValueError(
                f"its header claims {size} bytes, over the {MAX_NPY_HEADER_BYTES} read"
            )
        shape, fortran, dtype = _npy_header(bytes(view[:size]))
        if any(length < 0 for length in shape):
            raise ValueError(f"its shape {shape} has a negative length")
    except (ValueError, SyntaxError, TypeError, OverflowError, RecursionError) as exc:
        raise BadBody(f"{name} is not a readable .npy: {exc}") from None
    if dtype.hasobject:
        raise Invalid(
            f"{name} holds Python objects ({dtype}); only numeric arrays are accepted "
            "(they are never unpickled)"
        )
    plain = dtype.fields is None and dtype.subdtype is None and dtype.kind in "biufc"
    if not (plain or structured and dtype.fields and dtype.itemsize):
        raise Invalid(
            f"{name} has dtype {dtype!s}; only plain "
            "numeric arrays (no structured, subarray or void dtypes) are accepted"
        )
    offset = size
    count = math.prod(shape)  # Python integers: a hostile shape cannot overflow
    expected = count * dtype.itemsize
    if len(view) - offset != expected:
        problem = "truncated" if len(view) - offset < expected else "longer than its header says"
        raise BadBody(
            f"{name} is {problem}: its header promises {dtype} {shape} = {expected} "
            f"bytes of data, but {len(view) - offset} follow"
        )
    array = np.frombuffer(view, dtype=dtype, count=count, offset=offset)
    return array.reshape(shape, order="F" if fortran else "C")


@functools.lru_cache(maxsize=256)
def _npy_header(header: bytes) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, Fortran order, dtype) of a whole .npy header, magic string included.

    numpy evaluates the header as a Python literal (30 us); batches of one size repeat the same
    header, so each is parsed once."""
    stream = io.BytesIO(header)
    if np.lib.format.read_magic(stream) == (1, 0):
        return np.lib.format.read_array_header_1_0(stream)
    return np.lib.format.read_array_header_2_0(stream)


#: Most members an .npz may hold: zipfile makes a Python object per member before any is read.
MAX_NPZ_MEMBERS = 4096


def read_npz(buf: Buffer, max_bytes: int | None = None) -> dict[str, np.ndarray]:
    """All members of an .npz; stored members are views of ``buf``, deflated ones are inflated once.

    Inflating stops as soon as a member passes its declared size or the bytes left of
    ``max_bytes`` for the whole body, so no body costs more memory than the limit.
    """
    view = memoryview(buf).cast("B")
    try:
        file = BufferFile(view)
        _check_member_count(file)
        archive = zipfile.ZipFile(file)
        infos = archive.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError, struct.error) as exc:
        raise BadBody(f"body is not a readable .npz (zip): {exc}") from None
    total = sum(info.file_size for info in infos)
    if max_bytes is not None and total > max_bytes:
        raise TooLarge(
            f".npz members add up to {total} bytes, over the limit of {max_bytes} bytes "
            "(DACRT_MAX_BODY_BYTES)"
        )
    spans = _member_spans(view, infos)
    arrays: dict[str, np.ndarray] = {}
    for info, (start, end) in zip(infos, spans):
        key = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
        if key in arrays:
            raise BadBody(f".npz holds member {key!r} twice")
        if info.flag_bits & 0x1:
            raise BadBody(f".npz member {key!r} is encrypted; send it unencrypted")
        if info.compress_type == zipfile.ZIP_STORED:
            if info.compress_size != info.file_size:
                raise BadBody(
                    f".npz member {key!r} is stored but its two sizes differ "
                    f"({info.compress_size} and {info.file_size})"
                )
            member = view[start:end]
        elif info.compress_type == zipfile.ZIP_DEFLATED:
            member = _inflate(view[start:end], info, key)
        else:
            raise BadBody(
                f".npz member {key!r} uses zip compression method {info.compress_type}; "
                "only stored and deflated members are read (np.savez, "
                "np.savez_compressed)"
            )
        arrays[key] = read_npy(member, name=f".npz member {key!r}")
    return arrays


def _check_member_count(file: BufferFile) -> None:
    """400 for an .npz whose central directory lists more than MAX_NPZ_MEMBERS members."""
    end_record = zipfile._EndRecData(file)  # the end record, zip64 included, as zipfile reads it
    if end_record is None:
        raise zipfile.BadZipFile("File is not a zip file")
    count = end_record[zipfile._ECD_ENTRIES_TOTAL]
    if count > MAX_NPZ_MEMBERS:
        raise BadBody(f".npz lists {count} members, over the {MAX_NPZ_MEMBERS} read")


def _member_spans(view: memoryview, infos: list[zipfile.ZipInfo]) -> list[tuple[int, int]]:
    """[start, end) of each member's data in the body; 400 where members overlap or overrun it."""
    spans, last_end = [], 0
    for info in infos:
        start = _member_data_offset(view, info)
        spans.append((start, start + info.compress_size))
    for index in sorted(range(len(infos)), key=lambda i: infos[i].header_offset):
        start, end = spans[index]
        name = infos[index].filename
        if infos[index].header_offset < last_end:
            raise BadBody(f".npz member {name!r} overlaps the member before it")
        if end > len(view):
            raise BadBody(
                f".npz member {name!r} is truncated: its {infos[index].compress_size} "
                f"bytes run past the end of the body"
            )
        last_end = end
    return spans


#: Bytes inflated, and compressed bytes fed, at a time: a member costs its own size and a piece.
_INFLATE_PIECE, _FEED_PIECE = 1 << 18, 1 << 16


def _inflate(data: memoryview, info: zipfile.ZipInfo, key: str) -> memoryview:
    """A deflated member's bytes, refused as soon as they pass the member's declared size."""
    out = np.empty(info.file_size, np.uint8)
    inflater, filled, fed, pending = zlib.decompressobj(-zlib.MAX_WBITS), 0, 0, b""
    try:
        while not inflater.eof:
            if not pending:  # small feeds keep the copies of unconsumed_tail small
                pending, fed = data[fed : fed + _FEED_PIECE], fed + _FEED_PIECE
                if not pending:
                    break
            piece = inflater.decompress(pending, _INFLATE_PIECE)
            pending = inflater.unconsumed_tail
            if filled + len(piece) > info.file_size:
                raise BadBody(
                    f".npz member {key!r} inflates to more than the {info.file_size} "
                    "bytes its zip entry declares"
                )
            out[filled : filled + len(piece)] = np.frombuffer(piece, np.uint8)
            filled += len(piece)
    except zlib.error as exc:
        raise BadBody(f".npz member {key!r} cannot be inflated: {exc}") from None
    if filled < info.file_size or not inflater.eof:
        raise BadBody(
            f".npz member {key!r} is truncated: it inflates to {filled} of the "
            f"{info.file_size} bytes its zip entry declares"
        )
    if zlib.crc32(out) != info.CRC:
        raise BadBody(f".npz member {key!r} fails its CRC-32 check")
    out.flags.writeable = False
    return memoryview(out)


class BufferFile(io.RawIOBase):
    """A read-only, seekable file over any buffer, for zipfile: ``io.BytesIO`` would copy a
    buffer that is not ``bytes`` (the service's bodies are NumPy buffers)."""

    def __init__(self, buf: Buffer) -> None:
        self._view = memoryview(buf).cast("B")
        self._position = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, target) -> int:
        count = max(0, min(len(target), len(self._view) - self._position))
        target[:count] = self._view[self._position : self._position + count]
        self._position += count
        return count

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._position, io.SEEK_END: len(self._view)}[whence]
        self._position = max(0, base + offset)
        return self._position

    def tell(self) -> int:
        return self._position


def _member_data_offset(view: memoryview, info: zipfile.ZipInfo) -> int:
    """Where a member's bytes start: after its local header, name and extra field."""
    header = bytes(view[max(0, info.header_offset) : info.header_offset + _LOCAL.size])
    if (
        info.header_offset < 0
        or len(header) < _LOCAL.size
        or _LOCAL.unpack(header)[0] != b"PK\x03\x04"
    ):
        raise BadBody(f".npz member {info.filename!r} has a bad local header")
    name_length, extra_length = _LOCAL.unpack(header)[10:12]
    return info.header_offset + _LOCAL.size + name_length + extra_length


def read_json(buf: Buffer, expected: str) -> dict[str, Any]:
    """A JSON object; anything else is 400 naming the ``expected`` keys."""
    try:
        doc = json.loads(buf if isinstance(buf, (bytes, bytearray)) else bytes(buf))
    except RecursionError:
        raise BadBody("body is not valid JSON: it is nested too deeply") from None
    except ValueError as exc:  # JSONDecodeError, bad UTF-8, integers of over 4300 digits
        raise BadBody(f"body is not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise BadBody(f"JSON body must be an object with {expected}, got {type(doc).__name__}")
    return doc


def read_mapping(
    body: Buffer, fmt: str, expected: str, max_bytes: int | None = None
) -> dict[str, Any]:
    """The key -> value mapping of an npz or JSON body."""
    if fmt == "npz":
        return read_npz(body, max_bytes)
    if fmt == "json":
        return read_json(body, expected)
    raise UnsupportedMediaType(f"{fmt} bodies hold no keys; send {expected} as .npz or JSON")


def check_keys(
    mapping: Mapping[str, Any], required: Iterable[str], optional: Iterable[str] = ()
) -> None:
    """400 for missing or unknown keys, listing what is expected."""
    required, optional = tuple(required), tuple(optional)
    expected = ", ".join(required) + (f" (optional: {', '.join(optional)})" if optional else "")
    missing = [k for k in required if k not in mapping]
    unknown = [k for k in mapping if k not in required and k not in optional]
    if missing:
        raise BadBody(f"body lacks {', '.join(map(repr, missing))}; expected keys {expected}")
    if unknown:
        raise BadBody(
            f"body has unknown keys {', '.join(map(repr, unknown))}; expected keys {expected}"
        )


# --------------------------------------------------------------------------------------------
# Arrays: dtype and shape rules, with messages that say how to fix the input


def float_array(value: Any, name: str, columns: int | None) -> np.ndarray:
    """A float32 array of shape (N, columns), or (N,)/() when ``columns`` is None."""
    if isinstance(value, np.ndarray):
        if value.dtype != _F32:
            raise Invalid(
                f"{name} must be little-endian float32, got {value.dtype.str} "
                f"({value.dtype}); convert with .astype('<f4')"
            )
        array = value
    else:
        check_json_numbers(
            value, name, (int, float, type(None)) if columns is None else (int, float)
        )
        try:
            array = np.asarray(nulls_to_inf(value), dtype=np.float32)
        except (TypeError, ValueError, OverflowError) as exc:
            raise Invalid(f"{name} must be numbers in nested lists: {exc}") from None
    if columns is not None:
        if array.size == 0 and array.ndim == 1:
            array = array.reshape(0, columns)
        if array.ndim != 2 or array.shape[1] != columns:
            raise Invalid(f"{name} must have shape (N, {columns}), got {array.shape}")
    elif array.ndim > 1:
        raise Invalid(f"{name} must be one value or shape (N,), got {array.shape}")
    return array


def check_json_numbers(value: Any, name: str, kinds: tuple[type, ...]) -> None:
    """422 unless ``value`` is one of ``kinds``, or a list of them, or a list of such lists.

    JSON strings and booleans are not numbers, whatever NumPy would make of them.
    """
    items = value if isinstance(value, list) else [value]
    if items and all(type(item) is list for item in items):
        items = list(itertools.chain.from_iterable(items))
    if set(map(type, items)) <= set(kinds):  # exact types: bool is an int subclass
        return
    bad = next(item for item in items if type(item) not in kinds)
    wanted = "integers" if kinds == (int,) else "numbers"
    raise Invalid(f"{name} must be {wanted}, found {_json_kind(bad)}")


def _json_kind(value: Any) -> str:
    """How a JSON value is named in a message (never its whole text: it may be huge or deep)."""
    if isinstance(value, bool):
        return json.dumps(value)
    if isinstance(value, str):
        return f"the string {value[:32]!r}"
    if isinstance(value, (list, dict)):
        return "a list nested too deeply" if isinstance(value, list) else "an object"
    return "null" if value is None else f"the number {value!r:.32}"


def nulls_to_inf(value: Any) -> Any:
    """A JSON list with null elements (+inf) made numeric; anything else unchanged."""
    if isinstance(value, list) and any(x is None for x in value):
        return [np.inf if x is None else x for x in value]
    return value


def index_array(value: Any, name: str) -> np.ndarray:
    """An (F, 3) integer array: int32/uint32 when binary, any integers when from JSON."""
    if isinstance(value, np.ndarray):
        if value.dtype not in (_I32, _U32):
            raise Invalid(
                f"{name} must be little-endian int32 or uint32, got {value.dtype.str} "
                f"({value.dtype}); convert with .astype('<i4')"
            )
        array = value
    else:
        check_json_numbers(value, name, (int,))
        try:
            array = np.asarray(value)
        except (TypeError, ValueError) as exc:
            raise Invalid(f"{name} must be integers in nested lists: {exc}") from None
        if array.size == 0:
            array = (
                array.astype(np.int32).reshape(0, 3) if array.ndim == 1 else array.astype(np.int32)
            )
        elif array.dtype.kind not in "iu":
            raise Invalid(f"{name} must be integers, got {array.dtype} values")
    if array.ndim != 2 or array.shape[1] != 3:
        raise Invalid(f"{name} must have shape (F, 3), got {array.shape}")
    return array


def check_vertices(vertices: np.ndarray, name: str = "vertices") -> np.ndarray:
    """422 unless every vertex is finite; names the first bad row and how many there are."""
    if np.isfinite(
        vertices
    ).all():  # one flat pass; by rows only to name a bad one (1.6 ms on Sponza)
        return vertices
    rows = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    raise Invalid(
        f"{name}[{rows[0]}] is not finite ({vertices[rows[0]].tolist()}); "
        f"{rows.size} of {len(vertices)} vertices are not finite"
    )


def check_faces(faces: np.ndarray, n_vertices: int, name: str = "faces") -> np.ndarray:
    """422 unless every index is in [0, n_vertices); the answer is int32 (a view when possible)."""
    if faces.size and (faces.min() < 0 or faces.max() >= n_vertices):
        bad = ((faces < 0) | (faces >= n_vertices)).any(axis=1)
        rows = np.flatnonzero(bad)
        row = faces[rows[0]]
        value = row[(row < 0) | (row >= n_vertices)][0]
        raise Invalid(
            f"{name}[{rows[0]}] refers to vertex {value}, but there are {n_vertices} "
            f"vertices; {rows.size} of {len(faces)} faces are out of range"
        )
    if faces.dtype == _I32:
        return faces
    if faces.dtype == _U32:
        return faces.view(_I32)  # every index is below n_vertices < 2**31: same bits
    return faces.astype(np.int32)


def mesh_arrays(vertices: Any, faces: Any, prefix: str = "") -> MeshArrays:
    """Check a (vertices, faces) pair from any body kind."""
    v = check_vertices(float_array(vertices, f"{prefix}vertices", 3), f"{prefix}vertices")
    f = check_faces(index_array(faces, f"{prefix}faces"), len(v), f"{prefix}faces")
    return MeshArrays(v, f)


# --------------------------------------------------------------------------------------------
# Decoding request bodies


def decode_rays(
    body: Buffer, fmt: str, max_rays: int | None = None, max_bytes: int | None = None
) -> Rays:
    """A ray batch from an npy, npz or JSON body (see the module docstring)."""
    if fmt == "npy":
        array = read_npy(body, "rays body")
        if array.ndim != 2 or array.shape[1] not in (6, 8):
            raise Invalid(f"a .npy ray body must have shape (N, 6) or (N, 8), got {array.shape}")
        _check_ray_count(len(array), max_rays)
        array = float_array(array, "rays", array.shape[1])
        has_t = array.shape[1] == 8
        return Rays(
            array[:, 0:3],
            array[:, 3:6],
            array[:, 6] if has_t else None,
            array[:, 7] if has_t else None,
        )
    mapping = read_mapping(body, fmt, "origins, directions", max_bytes)
    check_keys(mapping, ("origins", "directions"), ("tmin", "tmax"))
    return rays_from_mapping(mapping, max_rays)


def rays_from_mapping(mapping: Mapping[str, Any], max_rays: int | None) -> Rays:
    """Rays from the keys origins, directions, tmin, tmax of an npz or JSON body."""
    origins = mapping["origins"]
    n = (
        origins.shape[0]
        if isinstance(origins, np.ndarray) and origins.ndim
        else (len(origins) if isinstance(origins, list) else 0)
    )
    _check_ray_count(n, max_rays)
    origins = float_array(origins, "origins", 3)
    directions = float_array(mapping["directions"], "directions", 3)
    if len(directions) != len(origins):
        raise Invalid(f"origins has {len(origins)} rays but directions has {len(directions)}")
    bounds = []
    for key in ("tmin", "tmax"):
        value = mapping.get(key)
        if value is not None:
            value = float_array(value, key, None)
            if value.ndim == 0:
                value = float(value)
            elif len(value) != len(origins):
                raise Invalid(f"{key} has {len(value)} values but there are {len(origins)} rays")
        bounds.append(value)
    return Rays(origins, directions, *bounds)


def _check_ray_count(n: int, max_rays: int | None) -> None:
    if max_rays is not None and n > max_rays:
        raise TooLarge(
            f"{n} rays in one request, over the limit of {max_rays} "
            "(DACRT_MAX_RAYS_PER_REQUEST); split the batch"
        )


def decode_mesh(body: Buffer, fmt: str, max_bytes: int | None = None) -> MeshArrays:
    """A checked mesh from an npz, JSON or mesh-file body."""
    if fmt in MESH_FILE_FORMATS:
        from .meshfile import read_mesh_file  # imports trimesh, which is slow to import

        vertices, faces = read_mesh_file(body, fmt)
        vertices = check_vertices(vertices)
        return MeshArrays(vertices, check_faces(faces, len(vertices)))
    mapping = read_mapping(body, fmt, "vertices, faces", max_bytes)
    check_keys(mapping, ("vertices", "faces"))
    return mesh_arrays(mapping["vertices"], mapping["faces"])


def decode_vertices(body: Buffer, fmt: str, max_bytes: int | None = None) -> np.ndarray:
    """Checked (V, 3) float32 vertex positions from an npy, npz or JSON body."""
    if fmt == "npy":
        value = read_npy(body, "vertices body")
    else:
        mapping = read_mapping(body, fmt, "vertices", max_bytes)
        check_keys(mapping, ("vertices",))
        value = mapping["vertices"]
    return check_vertices(float_array(value, "vertices", 3))


def decode_frame(
    body: Buffer, fmt: str, max_bytes: int | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """mesh name -> (vertices, faces or None) from ``MESH.vertices`` / ``MESH.faces`` keys.

    Only shapes and dtypes are checked here; face indices are checked against the vertex count
    of the mesh they end up with (``check_faces``) by the store.
    """
    mapping = read_mapping(body, fmt, "MESH.vertices (and optionally MESH.faces) keys", max_bytes)
    parts: dict[str, dict[str, Any]] = {}
    for key, value in mapping.items():
        mesh, _, kind = key.rpartition(".")
        if not mesh or kind not in ("vertices", "faces"):
            raise BadBody(f"frame key {key!r} is not MESH.vertices or MESH.faces")
        parts.setdefault(mesh, {})[kind] = value
    if not parts:
        raise BadBody("frame body holds no MESH.vertices keys")
    frame = {}
    for mesh, arrays in parts.items():
        if "vertices" not in arrays:
            raise BadBody(f"frame has {mesh}.faces but no {mesh}.vertices")
        vertices = check_vertices(
            float_array(arrays["vertices"], f"{mesh}.vertices", 3), f"{mesh}.vertices"
        )
        faces = arrays.get("faces")
        if faces is not None:
            faces = check_faces(index_array(faces, f"{mesh}.faces"), len(vertices), f"{mesh}.faces")
        frame[mesh] = (vertices, faces)
    return frame


def decode_trace(
    body: Buffer, fmt: str, max_rays: int | None = None, max_bytes: int | None = None
) -> tuple[MeshArrays, Rays]:
    """The mesh and the rays of a one-shot trace body."""
    mapping = read_mapping(body, fmt, "vertices, faces, origins, directions", max_bytes)
    check_keys(mapping, ("vertices", "faces", "origins", "directions"), ("tmin", "tmax"))
    rays = rays_from_mapping(mapping, max_rays)
    return mesh_arrays(mapping["vertices"], mapping["faces"]), rays


# --------------------------------------------------------------------------------------------
# Encoding answers


def negotiate(accept: str | None, request_format: str) -> str:
    """The answer format for an ``Accept`` header: npz, npy or json (406 if none fits)."""
    default = "json" if request_format == "json" else "npz"
    if not accept or not accept.strip():
        return default
    ranked = []
    for position, part in enumerate(accept.split(",")):
        media, *params = [p.strip() for p in part.split(";")]
        q = 1.0
        for param in params:
            name, _, value = param.partition("=")
            if name.strip().lower() == "q":
                try:
                    q = float(value)
                except ValueError:
                    q = 0.0
        if q > 0:
            ranked.append((-q, position, media.lower()))
    for _, _, media in sorted(ranked):
        if media in ("*/*", "application/*"):
            return default
        fmt = CONTENT_TYPES.get(media)
        if fmt in ANSWER_FORMATS:
            return fmt
    raise NotAcceptable(
        f"Accept: {accept} names no answer format this service writes; use {NPZ}, {NPY} or {JSON}"
    )


def encode_answer(arrays: Mapping[str, np.ndarray], fmt: str) -> tuple[Iterable[Buffer], int, str]:
    """(body as buffers to send in order, its length, Content-Type) of an answer: npz, npy or json.

    The buffers of npy and npz bodies are mostly the answer arrays' own memory: nothing is copied.
    An npz body takes each member's CRC as it is sent (``NpzBody``).
    """
    if fmt == "npz":
        body = NpzBody(arrays)
        return body, body.length, NPZ
    if fmt == "npy":
        parts, media = npy_parts(arrays), NPY
    elif fmt == "json":
        parts, media = [encode_json(arrays)], JSON
    else:
        raise ValueError(f"unknown answer format {fmt!r}")
    return parts, sum(len(part) for part in parts), media


def npy_header(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    """The .npy header (format 1.0, C order) of an array of ``dtype`` and ``shape``."""
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        out, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape}
    )
    return out.getvalue()


def array_bytes(array: np.ndarray) -> Buffer:
    """The bytes of an array in C order: a view of its memory when it is C-contiguous."""
    array = np.ascontiguousarray(array)
    return memoryview(array.reshape(-1)).cast("B") if array.size else b""


def npy_parts(arrays: Mapping[str, np.ndarray]) -> list[Buffer]:
    """One .npy: the array itself if there is one field, else a structured array of all of them."""
    if len(arrays) == 1:
        (array,) = arrays.values()
        return [npy_header(array.dtype, array.shape), array_bytes(array)]
    n = len(next(iter(arrays.values()))) if arrays else 0
    records = np.empty(n, dtype=[(k, a.dtype, a.shape[1:]) for k, a in arrays.items()])
    for key, array in arrays.items():
        records[key] = array
    return [npy_header(records.dtype, records.shape), array_bytes(records)]


class NpzBody:
    """An uncompressed .npz of ``arrays``: zip headers around each array's own memory, as the
    parts to send in order (iterate) and their total ``length``, known before any is made.

    The zip writes each member's CRC-32 in the header before its data, and the CRCs are most of
    the cost of an answer's encoding (1M-ray closest answer: 1.0 ms for 32 MB). So a member's CRC
    is taken only when its header is reached: a server sending the parts takes the next CRC while
    the member before is still on its way to the client.
    """

    def __init__(self, arrays: Mapping[str, np.ndarray]) -> None:
        self._members = [
            (f"{key}.npy".encode(), npy_header(array.dtype, array.shape), array_bytes(array))
            for key, array in arrays.items()
        ]
        members = sum(
            _LOCAL.size + len(name) + len(header) + len(data)
            for name, header, data in self._members
        )
        directory = sum(_CENTRAL.size + len(name) for name, _, _ in self._members)
        self._saved = None
        if members + directory >= 2**32 - 1:  # needs zip64: let zipfile write it
            out = io.BytesIO()
            np.savez(out, **arrays)
            self._saved = out.getbuffer()
        self.length = (
            len(self._saved) if self._saved is not None else members + directory + _END.size
        )

    def __iter__(self) -> Iterator[Buffer]:
        if self._saved is not None:
            yield self._saved
            return
        central, offset = [], 0
        for name, header, data in self._members:
            crc, length = crc32(data, crc32(header)), len(header) + len(data)
            yield (
                _LOCAL.pack(
                    b"PK\x03\x04", 20, 0, 0, 0, 0, _DOS_DATE, crc, length, length, len(name), 0
                )
                + name
                + header
            )
            yield data
            central.append(
                _CENTRAL.pack(
                    b"PK\x01\x02",
                    20,
                    0,
                    20,
                    0,
                    0,
                    0,
                    0,
                    _DOS_DATE,
                    crc,
                    length,
                    length,
                    len(name),
                    0,
                    0,
                    0,
                    0,
                    0,
                    offset,
                )
                + name
            )
            offset += _LOCAL.size + len(name) + length
        directory = b"".join(central)
        yield directory + _END.pack(
            b"PK\x05\x06", 0, 0, len(central), len(central), len(directory), offset, 0
        )


def npz_parts(arrays: Mapping[str, np.ndarray]) -> list[Buffer]:
    """An uncompressed .npz of ``arrays`` as a list of buffers: zip headers and the arrays'
    memory."""
    return list(NpzBody(arrays))


def encode_npz(arrays: Mapping[str, np.ndarray]) -> bytes:
    """An uncompressed .npz of ``arrays`` in one bytes object."""
    return b"".join(npz_parts(arrays))


def encode_npy(arrays: Mapping[str, np.ndarray]) -> bytes:
    """One .npy (see ``npy_parts``) in one bytes object."""
    return b"".join(npy_parts(arrays))


def encode_json(arrays: Mapping[str, np.ndarray]) -> bytes:
    """``{"key": [...], ...}`` with float32 in shortest round-trip form and null for inf/nan."""
    return json.dumps(
        {key: json_ready(array) for key, array in arrays.items()},
        separators=(",", ":"),
        allow_nan=False,
    ).encode()


def json_ready(array: np.ndarray) -> Any:
    """Nested lists for ``json.dumps``: shortest float32 repr, None where not finite."""
    if array.dtype.kind != "f":
        return array.tolist()
    shortest = array.astype(str).astype(np.float64)  # '0.1' for float32(0.1), not 0.10000000149
    finite = np.isfinite(array)
    if finite.all():
        return shortest.tolist()
    values = shortest.astype(object)
    values[~finite] = None
    return values.tolist()
