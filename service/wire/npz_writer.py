"""The .npz writer: an uncompressed zip of answer arrays, sent as headers around their memory."""

from __future__ import annotations

import io
from collections.abc import Iterator, Mapping

import numpy as np

from .formats import Buffer
from .npy import array_bytes, npy_header
from .zip_records import CentralDirectoryHeader, EndOfCentralDirectory, LocalFileHeader

try:  # ISA-L's CRC-32 is much faster than zlib's, and the CRCs are most of an answer's encoding
    from isal.isal_zlib import crc32
except ImportError:  # pragma: no cover - isal is a dependency, but the wire format works without it
    from zlib import crc32


class NpzBody:
    """An uncompressed .npz of ``arrays``: zip headers around each array's own memory, as the
    parts to send in order (iterate) and their total ``length``, known before any is made.

    A member's CRC-32 goes in its header, before its data, and the CRCs are most of an answer's
    encoding; so each is taken only when its header is reached, while the member before is still
    on its way to the client.
    """

    def __init__(self, arrays: Mapping[str, np.ndarray]) -> None:
        self._members = [
            (f"{key}.npy".encode(), npy_header(array.dtype, array.shape), array_bytes(array))
            for key, array in arrays.items()
        ]
        members = sum(
            LocalFileHeader.LAYOUT.size + len(name) + len(header) + len(data)
            for name, header, data in self._members
        )
        directory = sum(
            CentralDirectoryHeader.LAYOUT.size + len(name) for name, _, _ in self._members
        )
        self._saved = None
        if members + directory >= 2**32 - 1 or len(self._members) > 0xFFFF:
            # needs zip64 (its sizes, or its count of members): let zipfile write it
            out = io.BytesIO()
            np.savez(out, **arrays)
            self._saved = out.getbuffer()
        self.length = (
            len(self._saved)
            if self._saved is not None
            else members + directory + EndOfCentralDirectory.LAYOUT.size
        )

    def __iter__(self) -> Iterator[Buffer]:
        if self._saved is not None:
            yield self._saved
            return
        central, offset = [], 0
        for name, header, data in self._members:
            crc, length = crc32(data, crc32(header)), len(header) + len(data)
            sizes = {"compressed_size": length, "uncompressed_size": length}
            local = LocalFileHeader(crc32=crc, name_length=len(name), **sizes)
            yield local.pack() + name + header
            yield data
            entry = CentralDirectoryHeader(
                crc32=crc, name_length=len(name), local_header_offset=offset, **sizes
            )
            central.append(entry.pack() + name)
            offset += LocalFileHeader.LAYOUT.size + len(name) + length
        directory = b"".join(central)
        end = EndOfCentralDirectory(
            entries_on_disk=len(central),
            entries_total=len(central),
            directory_size=len(directory),
            directory_offset=offset,
        )
        yield directory + end.pack()


def npz_parts(arrays: Mapping[str, np.ndarray]) -> list[Buffer]:
    """An uncompressed .npz of ``arrays`` as a list of buffers: zip headers and the arrays'
    memory."""
    return list(NpzBody(arrays))
