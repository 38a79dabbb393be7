"""Hostile request bodies built by hand: zip bombs, forged .npy headers, deep or odd JSON.

Shared by the in-process wire tests and the corpus run against a real server.
"""

from __future__ import annotations

import functools
import zlib

import numpy as np
from service_helpers import npy_bytes

from service.wire.zip_records import (
    CentralDirectoryHeader,
    EndOfCentralDirectory,
    LocalFileHeader,
)

STORED, DEFLATED, BZIP2 = 0, 8, 12
ENCRYPTED = 0x1


def npy_with_header(descr, shape, data: bytes = b"") -> bytes:
    """A version 1.0 .npy whose header says ``descr`` and ``shape``, followed by ``data``."""
    header = f"{{'descr': {descr!r}, 'fortran_order': False, 'shape': {shape!r}, }}"
    header += " " * (63 - len(header) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + data


def raw_zip(members: list[dict], directory: list[dict] | None = None) -> bytes:
    """A zip written field by field, so that its fields can lie.

    ``members``: dicts with ``name``, ``payload`` (the bytes as stored), and optionally
    ``method``, ``size`` (declared inflated size), ``crc`` and ``flags``. ``directory``: the
    central directory entries, by default one per member; an entry may point at any member's
    local header with ``member`` (an index) and carry its own ``name``.
    """
    body, offsets = b"", []
    for m in members:
        name = m["name"].encode()
        offsets.append(len(body))
        header = LocalFileHeader(
            flags=m.get("flags", 0),
            compression=m.get("method", STORED),
            crc32=m.get("crc", zlib.crc32(m["payload"])),
            compressed_size=len(m["payload"]),
            uncompressed_size=m.get("size", len(m["payload"])),
            name_length=len(name),
        )
        body += header.pack() + name + m["payload"]
    entries = directory if directory is not None else [{"member": i} for i in range(len(members))]
    central = b""
    for entry in entries:
        m = members[entry["member"]]
        name = entry.get("name", m["name"]).encode()
        record = CentralDirectoryHeader(
            flags=m.get("flags", 0),
            compression=m.get("method", STORED),
            crc32=m.get("crc", zlib.crc32(m["payload"])),
            compressed_size=len(m["payload"]),
            uncompressed_size=m.get("size", len(m["payload"])),
            name_length=len(name),
            local_header_offset=offsets[entry["member"]],
        )
        central += record.pack() + name
    end = EndOfCentralDirectory(
        entries_on_disk=len(entries),
        entries_total=len(entries),
        directory_size=len(central),
        directory_offset=len(body),
    )
    return body + central + end.pack()


def raw_deflater():
    return zlib.compressobj(9, zlib.DEFLATED, -zlib.MAX_WBITS)


def deflate_zeros(compressor, size: int) -> bytes:
    """The rest of ``compressor``'s stream after ``size`` more zero bytes (about 1/1000 of it)."""
    chunk = bytes(min(size, 16 << 20))
    parts = [
        compressor.compress(chunk[: min(len(chunk), size - done)])
        for done in range(0, size, len(chunk))
    ]
    return b"".join(parts) + compressor.flush()


@functools.lru_cache(maxsize=4)
def deflated_zeros(size: int) -> bytes:
    """A raw deflate stream that inflates to ``size`` zero bytes."""
    return deflate_zeros(raw_deflater(), size)


def deflate(data: bytes) -> bytes:
    compressor = raw_deflater()
    return compressor.compress(data) + compressor.flush()


def ray_npy(n: int = 2) -> bytes:
    rays = np.tile(np.array([0.5, 0.5, 10, 0, 0, -1], np.float32), (n, 1))
    return npy_bytes(rays)


def zip_bomb(inflated: int, declared: int = 1024) -> bytes:
    """One member that declares ``declared`` bytes but inflates to ``inflated``."""
    return raw_zip(
        [
            {
                "name": "origins.npy",
                "payload": deflated_zeros(inflated),
                "method": DEFLATED,
                "size": declared,
            }
        ]
    )


def overlapping_zip(entries: int = 50) -> bytes:
    """One deflate stream behind many central-directory entries, each a valid small .npy."""
    data = ray_npy(2)
    member = {
        "name": "origins.npy",
        "payload": deflate(data),
        "method": DEFLATED,
        "size": len(data),
        "crc": zlib.crc32(data),
    }
    return raw_zip([member], [{"member": 0, "name": f"m{i}.npy"} for i in range(entries)])


def duplicate_zip() -> bytes:
    data = npy_bytes(np.zeros((1, 3), np.float32))
    return raw_zip(
        [{"name": "origins.npy", "payload": data}, {"name": "origins.npy", "payload": data}]
    )


def encrypted_zip() -> bytes:
    data = npy_bytes(np.zeros((1, 3), np.float32))
    return raw_zip([{"name": "origins.npy", "payload": data, "flags": ENCRYPTED}])


def bzip2_zip() -> bytes:
    data = npy_bytes(np.zeros((1, 3), np.float32))
    return raw_zip([{"name": "origins.npy", "payload": data, "method": BZIP2}])


def honest_big_zip(inflated: int) -> bytes:
    """A well-formed .npz of one float32 member of ``inflated`` bytes of zeros, deflated."""
    size = inflated // 4 * 4
    header = npy_with_header("<f4", (size // 4,))
    compressor = raw_deflater()
    stream = compressor.compress(header) + deflate_zeros(compressor, size)
    crc = zlib.crc32(bytes(size), zlib.crc32(header))
    return raw_zip(
        [
            {
                "name": "origins.npy",
                "payload": stream,
                "method": DEFLATED,
                "size": len(header) + size,
                "crc": crc,
            }
        ]
    )


def deep_json(key: str, depth: int) -> bytes:
    """``{key: [[[...]]], ...}`` nested ``depth`` lists deep, with the other ray key valid."""
    other = "directions" if key == "origins" else "origins"
    return (f'{{"{key}": ' + "[" * depth + "]" * depth + f', "{other}": [[0, 0, 1]]}}').encode()
