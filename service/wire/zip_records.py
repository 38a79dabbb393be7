"""The fixed-size records of a zip file that the .npz reader and writer handle themselves.

Field names and order follow PKWARE's APPNOTE.TXT (sections 4.3.7, 4.3.12 and 4.3.16); every
number is little-endian. The writer makes uncompressed members with no extra fields, no comments
and no dates, as ``np.savez`` would with zipfile's defaults.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, fields
from typing import ClassVar

#: 1980-01-01, the earliest DOS date, as zip tools write for "no date".
NO_DATE = (1 << 5) | 1
#: Version 2.0 of the format: deflate, folders; what zipfile writes for a plain member.
VERSION_20 = 20


class Record:
    """A record packed and unpacked field by field, in declaration order, by ``LAYOUT``."""

    LAYOUT: ClassVar[struct.Struct]

    def pack(self) -> bytes:
        return self.LAYOUT.pack(*(getattr(self, f.name) for f in fields(self)))

    @classmethod
    def unpack(cls, data: bytes):
        values = cls.LAYOUT.unpack(data)
        return cls(**{f.name: value for f, value in zip(fields(cls), values)})


@dataclass(frozen=True, kw_only=True)
class LocalFileHeader(Record):
    """The header before each member's data."""

    LAYOUT: ClassVar = struct.Struct("<4s2B4HL2L2H")

    signature: bytes = b"PK\x03\x04"
    version_needed: int = VERSION_20
    system_needed: int = 0
    flags: int = 0
    compression: int = 0  #: 0 stored
    modified_time: int = 0
    modified_date: int = NO_DATE
    crc32: int
    compressed_size: int
    uncompressed_size: int
    name_length: int
    extra_length: int = 0


@dataclass(frozen=True, kw_only=True)
class CentralDirectoryHeader(Record):
    """A member's entry in the central directory at the end of the file."""

    LAYOUT: ClassVar = struct.Struct("<4s4B4HL2L5H2L")

    signature: bytes = b"PK\x01\x02"
    version_made_by: int = VERSION_20
    system_made_by: int = 0
    version_needed: int = VERSION_20
    system_needed: int = 0
    flags: int = 0
    compression: int = 0  #: 0 stored
    modified_time: int = 0
    modified_date: int = NO_DATE
    crc32: int
    compressed_size: int
    uncompressed_size: int
    name_length: int
    extra_length: int = 0
    comment_length: int = 0
    disk_number: int = 0
    internal_attributes: int = 0
    external_attributes: int = 0
    local_header_offset: int


@dataclass(frozen=True, kw_only=True)
class EndOfCentralDirectory(Record):
    """The last record: where the central directory is and how many entries it has."""

    LAYOUT: ClassVar = struct.Struct("<4s4H2LH")

    signature: bytes = b"PK\x05\x06"
    disk_number: int = 0
    directory_disk: int = 0
    entries_on_disk: int
    entries_total: int
    directory_size: int
    directory_offset: int
    comment_length: int = 0
