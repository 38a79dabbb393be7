"""Which format a body is in: Content-Type and ``?format=`` names, and sniffing by first bytes."""

from __future__ import annotations

from collections.abc import Iterable

from ..errors import UnsupportedMediaType

NPY, NPZ, JSON = "application/x-npy", "application/x-npz", "application/json"
PCD = "application/x-pcd"  #: a lidar's answer only
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
    PCD: "pcd",
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
    "pcd": PCD,
}
MESH_FILE_FORMATS = ("obj", "ply", "stl", "glb", "off")

RAY_FORMATS = ("npy", "npz", "json")
POINT_FORMATS = ("npy", "npz", "json")
MESH_FORMATS = ("npz", "json", *MESH_FILE_FORMATS)
VERTEX_FORMATS = ("npy", "npz", "json")
FRAME_FORMATS = ("npz", "json")
TRACE_FORMATS = ("npz", "json")
PATTERN_FORMATS = ("npz", "json")
ANSWER_FORMATS = ("npz", "npy", "json")

#: Content-Types a web page may send to any site without asking it first (CORS-safelisted): a body
#: in one is read only as a text mesh file, never as npy, npz or JSON, even with ``?format=``.
CROSS_SITE_TYPES = ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data")
#: The formats a text/plain body may hold (with ``?format=``).
TEXT_FILE_FORMATS = ("obj", "off", "ply", "stl")
_SNIFF = (
    (b"\x93NUMPY", "npy"),
    (b"PK\x03\x04", "npz"),
    (b"PK\x05\x06", "npz"),
    (b"glTF", "glb"),
    (b"ply", "ply"),
    (b"OFF", "off"),
)


def declared_format(content_type: str | None) -> str | None:
    """The format a ``Content-Type`` names (None if it names none we know)."""
    return CONTENT_TYPES.get((content_type or "").split(";", 1)[0].strip().lower())


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
        media = (content_type or "").split(";", 1)[0].strip().lower()
        cross_site = media in CROSS_SITE_TYPES and fmt not in TEXT_FILE_FORMATS
        if cross_site or CONTENT_TYPES.get(media, fmt) != fmt:
            raise UnsupportedMediaType(
                f"Content-Type {media} is not the format ?format={fmt} names; send the body "
                f"as {MEDIA_TYPES[fmt]} (or application/octet-stream)"
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
