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


# ---- sensor bodies with one bad value

#: A pose whose rotation part is sheared, not a rotation.
SHEARED = [[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]]
LIDAR = {"pose": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]], "model": "VLP-16"}
PINHOLE = {
    "width": 4,
    "height": 3,
    "fx": 2,
    "fy": 2,
    "cx": 1.5,
    "cy": 1,
    "pose": [[1, 0, 0, 0], [0, 0, 1, -7], [0, -1, 0, 1], [0, 0, 0, 1]],
}
LOOK_AT = {"width": 4, "height": 3, "eye": [8, 6, 8], "target": [0, 1.5, 0]}
NAN, INF = float("nan"), float("inf")


def with_entry(rows: list, row: int, column: int, value: float) -> list:
    """A copy of a list of lists with ``rows[row][column] = value``."""
    copy = [list(r) for r in rows]
    copy[row][column] = value
    return copy


#: (route, body, a phrase of the 422 detail that names the request's key) for values that are
#: non-finite, beyond float32 (the rays are float32), negative, out of order, or focal lengths so
#: small (subnormal, zero) that the rays overflow. json.dumps writes NaN and Infinity.
BAD_SENSOR_VALUES = [
    ("lidar", {**LIDAR, "pose": with_entry(LIDAR["pose"], 0, 3, 1e39)}, "pose[0][3]: 1e+39"),
    ("lidar", {**LIDAR, "pose": with_entry(LIDAR["pose"], 1, 3, 3.5e38)}, "pose[1][3]: 3.5e+38"),
    ("lidar", {**LIDAR, "pose": with_entry(LIDAR["pose"], 0, 0, 1e39)}, "pose[0][0]: 1e+39"),
    ("lidar", {**LIDAR, "pose": with_entry(LIDAR["pose"], 2, 3, NAN)}, "pose[2][3]: Input should"),
    ("lidar", {**LIDAR, "pose": with_entry(LIDAR["pose"], 2, 1, INF)}, "pose[2][1]: Input should"),
    ("lidar", {**LIDAR, "min_range": 1e39}, "min_range: 1e+39"),
    ("lidar", {**LIDAR, "max_range": 1e39}, "max_range: 1e+39"),
    ("lidar", {**LIDAR, "min_range": NAN}, "min_range: Input should be a finite number"),
    ("lidar", {**LIDAR, "max_range": INF}, "max_range: Input should be"),
    ("lidar", {**LIDAR, "min_range": -1}, "min_range: Input should be greater than or equal to 0"),
    ("lidar", {**LIDAR, "max_range": -1}, "max_range: Input should be greater than 0"),
    ("lidar", {**LIDAR, "min_range": 5, "max_range": 2}, "max_range (2.0) must be greater than"),
    (
        "lidar",
        {"pose": LIDAR["pose"], "vertical_angles_deg": [0, 1e39]},
        "vertical_angles_deg[1]: Input should be less than or equal to 90",
    ),
    ("camera", {**PINHOLE, "fx": 1e-300}, "fx: 1e-300 is too small for cx 1.5"),
    ("camera", {**PINHOLE, "fy": 5e-324}, "fy: 5e-324 is too small for cy 1"),
    ("camera", {**PINHOLE, "fx": 1e-39, "cx": 10.0}, "fx: 1e-39 is too small for cx 10.0"),
    ("camera", {**PINHOLE, "fx": 0}, "fx: Input should be greater than 0"),
    ("camera", {**PINHOLE, "fy": -500}, "fy: Input should be greater than 0"),
    ("camera", {**PINHOLE, "fx": 1e39}, "fx: 1e+39"),
    ("camera", {**PINHOLE, "fx": NAN}, "fx: Input should be a finite number"),
    ("camera", {**PINHOLE, "cx": 1e39}, "cx: 1e+39"),
    ("camera", {**PINHOLE, "cy": -INF}, "cy: Input should be a finite number"),
    ("camera", {**PINHOLE, "pose": with_entry(PINHOLE["pose"], 2, 3, -1e39)}, "pose[2][3]: -1e+39"),
    ("camera", {**PINHOLE, "near": 1e39}, "near: 1e+39"),
    ("camera", {**PINHOLE, "far": 1e39}, "far: 1e+39"),
    ("camera", {**PINHOLE, "near": -1}, "near: Input should be greater than or equal to 0"),
    ("camera", {**PINHOLE, "near": 5, "far": 2}, "far (2.0) must be greater than near (5.0)"),
    ("camera", {**LOOK_AT, "eye": [1e39, 0, 0]}, "eye[0]: 1e+39"),
    ("camera", {**LOOK_AT, "fov_deg": 5e-324}, "fov_deg: 5e-324 is too small"),
    ("render", {**LOOK_AT, "fov_deg": NAN}, "fov_deg: Input should be a finite number"),
    ("render", {**LOOK_AT, "eye": [0, 1e39, 0]}, "eye[1]: 1e+39"),
    ("render", {**LOOK_AT, "target": [0, 0, INF]}, "target[2]: Input should be a finite number"),
    ("render", {**LOOK_AT, "up": [0, -3.5e38, 0]}, "up[1]: -3.5e+38"),
    ("render", {**LOOK_AT, "fov_deg": 5e-324}, "fov_deg: 5e-324 is too small"),
    ("render", {**LOOK_AT, "fov_deg": 0}, "fov_deg: Input should be greater than 0"),
    # the lidar's physics (API.md "Lidar physics"), by the body's own key
    ("lidar", {**LIDAR, "return_mode": "both"}, "return_mode: Input should be 'first'"),
    ("lidar", {**LIDAR, "beam_divergence_deg": -1}, "beam_divergence_deg must be >= 0"),
    ("lidar", {**LIDAR, "beam_divergence_deg": 180}, "beam_divergence_deg must be < 180"),
    ("lidar", {**LIDAR, "beam_divergence_deg": NAN}, "beam_divergence_deg: Input should be"),
    ("lidar", {**LIDAR, "beam_samples": 0}, "beam_samples must be >= 1 and <= 64"),
    ("lidar", {**LIDAR, "beam_samples": 65}, "beam_samples must be >= 1 and <= 64"),
    ("lidar", {**LIDAR, "beam_samples": 2.5}, "beam_samples: Input should be a valid integer"),
    ("lidar", {**LIDAR, "range_resolution": -0.1}, "range_resolution must be >= 0"),
    ("lidar", {**LIDAR, "range_resolution": 1e39}, "range_resolution: 1e+39"),
    ("lidar", {**LIDAR, "attenuation": -1}, "attenuation must be >= 0"),
    ("lidar", {**LIDAR, "attenuation": INF}, "attenuation: Input should be a finite number"),
    ("lidar", {**LIDAR, "noise": {"range_sigma": -1}}, "noise.range_sigma must be >= 0"),
    ("lidar", {**LIDAR, "noise": {"range_sigma": NAN}}, "noise.range_sigma: Input should be"),
    ("lidar", {**LIDAR, "noise": {"range_sigma_per_m": -1e-3}}, "noise.range_sigma_per_m must"),
    ("lidar", {**LIDAR, "noise": {"angle_sigma_deg": 1e39}}, "noise.angle_sigma_deg: 1e+39"),
    ("lidar", {**LIDAR, "noise": {"seed": -1}}, "noise.seed must be >= 0"),
    ("lidar", {**LIDAR, "noise": {"seed": 1.5}}, "noise.seed: Input should be a valid integer"),
    ("lidar", {**LIDAR, "noise": [0.1]}, "noise: Input should be"),
    ("lidar", {**LIDAR, "dropout": {"rate": 1.5}}, "dropout.rate must be <= 1"),
    ("lidar", {**LIDAR, "dropout": {"min_intensity": -1}}, "dropout.min_intensity must be >= 0"),
    ("lidar", {**LIDAR, "dropout": {"seed": -2}}, "dropout.seed must be >= 0"),
    ("lidar", {**LIDAR, "non_hits": "fill"}, "non_hits: Input should be 'drop' or 'keep'"),
    ("lidar", {**LIDAR, "period_s": 5e-324}, "period_s must be >= 1e-06, got 5e-324"),
    ("lidar", {**LIDAR, "organized": 1}, "organized: Input should be a valid boolean"),
    ("lidar", {"pose": LIDAR["pose"], "pattern": "no-such"}, "pattern: no pattern 'no-such'"),
    ("lidar", {"pose": LIDAR["pose"], "pattern": "a b"}, "pattern: String should match"),
    (
        "sensors",
        {"sensors": {"roof": {"kind": "lidar", **LIDAR, "noise": {"range_sigma": -1}}}},
        "sensors.roof: noise.range_sigma must be >= 0",
    ),
    (
        "sensors",
        {"sensors": {"roof": {"kind": "lidar", **LIDAR, "beam_samples": True}}},
        "sensors.roof.beam_samples: Input should be a valid integer",
    ),
    (
        "sensors",
        {"sensors": {"front": {"kind": "camera", **PINHOLE, "fx": 0}}},
        "sensors.front.fx: Input should be greater than 0",
    ),
    (
        "sensors",
        {"sensors": {"x": {"kind": "radar", **LIDAR}}},
        "sensors.x: kind 'radar' is not 'lidar' or 'camera'",
    ),
    (
        "sensors",
        {"sensors": {"a b": {"kind": "lidar", **LIDAR}}},
        "sensors: sensor name 'a b' must be 1-64 characters of A-Z a-z 0-9 _ - .",
    ),
    (
        "sensors",
        {"sensors": {"x" * 100: {"kind": "lidar", **LIDAR}}},
        f"sensor name {'x' * 80!r}... (100 characters) must be",
    ),
    # a check of the whole sensor: named by the sensor, not by the kind's tag
    (
        "sensors",
        {"sensors": {"roof": {"kind": "lidar", **LIDAR, "pose_end": LIDAR["pose"]}}},
        "sensors: sensors.roof: pose_end needs period_s",
    ),
    (
        "sensors",
        {"sensors": {"front": {"kind": "camera", **PINHOLE, "near": 2, "far": 1}}},
        "sensors: sensors.front: far (1.0) must be greater than near (2.0)",
    ),
    ("sensors", {"sensors": {}}, "sensors: Dictionary should have at least 1 item"),
    (
        "sensors",
        {"sensors": {"roof": {"kind": "lidar", "pose": LIDAR["pose"], "pattern": "no-such"}}},
        "sensors.roof: pattern: no pattern 'no-such'",
    ),
    (
        "sensors",
        {
            "sensors": {
                "front": {"kind": "lidar", **LIDAR, "period_s": 0.1},
                "roof": {"kind": "lidar", **LIDAR, "period_s": 0.1, "pose_end": SHEARED},
            }
        },
        "sensors.roof: pose_end[:3, :3] must be a rotation",
    ),
]
#: (route with its query, headers kind, body, status, a phrase of the detail that names the
#: request's key) for point queries: values the engine refuses, JSON that is not numbers, keys
#: that are not ``points``, and query values out of range.
BAD_POINT_REQUESTS = [
    (
        "nearest",
        "npy",
        npy_bytes(np.array([[0, 0, 0], [np.inf, 0, 0]], np.float32)),
        422,
        "points[1]",
    ),
    ("nearest", "json", b'{"points": [[NaN, 0, 0]]}', 422, "points[0]"),
    ("nearest", "json", b'{"points": [[1e39, 0, 0]]}', 422, "points[0]"),
    ("nearest", "json", b'{"points": [["0", 0, 0]]}', 422, "points must be numbers"),
    ("nearest", "json", b'{"points": [[true, 0, 0]]}', 422, "points must be numbers"),
    ("nearest", "json", b'{"points": [[1' + b"0" * 400 + b", 0, 0]]}", 422, "int too large"),
    ("nearest", "json", b'{"points": [[0, 0, 0]], "origins": []}', 400, "unknown keys 'origins'"),
    ("nearest", "npy", npy_bytes(np.zeros((4, 6), np.float32)), 422, "points must have shape"),
    (
        "nearest?max_distance=-1",
        "npy",
        npy_bytes(np.zeros((1, 3), np.float32)),
        422,
        "max_distance",
    ),
    (
        "nearest?max_distance=nan",
        "npy",
        npy_bytes(np.zeros((1, 3), np.float32)),
        422,
        "max_distance",
    ),
    ("nearest?nsamples=4", "npy", npy_bytes(np.zeros((1, 3), np.float32)), 422, "nsamples"),
    ("nearest?nsamples=-1", "npy", npy_bytes(np.zeros((1, 3), np.float32)), 422, "nsamples"),
]
#: What a sensor's error must never name: the engine's arrays, which are not the request's keys.
INTERNAL_NAMES = r"\b(origins|directions|tmin|tmax)\b"
