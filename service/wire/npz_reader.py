"""The .npz reader: stored members viewed in place, deflated ones inflated once, within limits."""

from __future__ import annotations

import io
import struct
import zipfile
import zlib

import numpy as np

from ..errors import BadBody, TooLarge
from .formats import Buffer
from .npy import read_npy
from .zip_records import LocalFileHeader

#: Most members an .npz may hold: zipfile makes a Python object per member before any is read.
MAX_NPZ_MEMBERS = 4096


def read_npz(buf: Buffer, max_bytes: int | None = None) -> dict[str, np.ndarray]:
    """All members of an .npz; stored members are views of ``buf``, deflated ones are inflated once.

    Inflating stops as soon as a member passes its declared size or the bytes left of
    ``max_bytes`` for the whole body, so no body costs more memory than the limit.
    """
    view = memoryview(buf).cast("B")
    infos = _directory(view, max_bytes)
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


def inflated_bytes(buf: Buffer, max_bytes: int | None = None) -> int:
    """The bytes an .npz's deflated members declare they inflate to: what reading it adds to the
    body (stored members are views of it); 413 over ``max_bytes``, 400 for a broken zip."""
    infos = _directory(memoryview(buf).cast("B"), max_bytes)
    return sum(info.file_size for info in infos if info.compress_type != zipfile.ZIP_STORED)


def _directory(view: memoryview, max_bytes: int | None) -> list[zipfile.ZipInfo]:
    """The members an .npz's central directory lists; 413 where their declared sizes add up to
    more than ``max_bytes``, 400 for a broken zip."""
    try:
        _check_member_count(view)
        infos = zipfile.ZipFile(BufferFile(view)).infolist()
    # zipfile refuses a record needing a newer zip version with NotImplementedError
    except (
        zipfile.BadZipFile,
        zipfile.LargeZipFile,
        ValueError,
        EOFError,
        struct.error,
        NotImplementedError,
    ) as exc:
        raise BadBody(f"body is not a readable .npz (zip): {exc}") from None
    total = sum(info.file_size for info in infos)
    if max_bytes is not None and total > max_bytes:
        raise TooLarge(
            f".npz members add up to {total} bytes, over the limit of {max_bytes} bytes "
            "(DACRT_MAX_BODY_BYTES)"
        )
    return infos


def _check_member_count(view: memoryview) -> None:
    """400 for an .npz whose central directory lists more than MAX_NPZ_MEMBERS members, by the
    end record's count and by its entries counted one by one (zipfile reads every entry in the
    directory's byte span, whatever the count says)."""
    end_record = zipfile._EndRecData(
        BufferFile(view)
    )  # the end record, zip64 included, as zipfile reads it
    if end_record is None:
        raise zipfile.BadZipFile("File is not a zip file")
    count = end_record[zipfile._ECD_ENTRIES_TOTAL]
    if count > MAX_NPZ_MEMBERS:
        raise BadBody(f".npz lists {count} members, over the {MAX_NPZ_MEMBERS} read")
    # where zipfile starts the directory: its byte size before the end record (and zip64's)
    size = end_record[zipfile._ECD_SIZE]
    position = end_record[zipfile._ECD_LOCATION] - size
    if end_record[zipfile._ECD_SIGNATURE] == zipfile.stringEndArchive64:
        position -= zipfile.sizeEndCentDir64 + zipfile.sizeEndCentDir64Locator
    end, entries = position + size, 0
    while 0 <= position < end and position + _ENTRY_BYTES <= len(view):
        entries += 1
        if entries > MAX_NPZ_MEMBERS:
            raise BadBody(
                f".npz's central directory holds more than {MAX_NPZ_MEMBERS} entries "
                f"(its end record says {count}), over the {MAX_NPZ_MEMBERS} read"
            )
        name, extra, comment = struct.unpack_from("<3H", view, position + _ENTRY_LENGTHS_AT)
        position += _ENTRY_BYTES + name + extra + comment


#: A central directory entry's fixed bytes, and where its name, extra and comment lengths are.
_ENTRY_BYTES, _ENTRY_LENGTHS_AT = 46, 28


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
    size = LocalFileHeader.LAYOUT.size
    data = bytes(view[max(0, info.header_offset) : info.header_offset + size])
    header = LocalFileHeader.unpack(data) if info.header_offset >= 0 and len(data) == size else None
    if header is None or header.signature != LocalFileHeader.signature:
        raise BadBody(f".npz member {info.filename!r} has a bad local header")
    return info.header_offset + size + header.name_length + header.extra_length
