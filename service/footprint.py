"""What a request holds in server memory at its peak, estimated from what it asks.

``service.admission`` admits a request only when this estimate fits in the in-flight budget. The
estimates are upper bounds of peaks measured on a real server (peak RSS over idle, one request at
a time, two threads; docs/limits.md gives the figures): each constant is the measured bytes with a
margin. A body counts its own bytes, what decoding it costs (a parsed JSON document or mesh file is
many times its text), and what the work and the answer hold per ray, pixel or hit.
"""

from __future__ import annotations

import numpy as np

from dacrt.chunks import MIN_RAYS_PER_THREAD, MIN_RAYS_TO_SPLIT_TRIANGLES, N_CORES
from dacrt.points import vote_rays_at_once
from dacrt.scene import PLACING_BLOCK_ROWS

#: Bytes per ray of a query's work beyond its body: the checked copies of origins, directions,
#: tmin and tmax, and the engine's ray ids and bounds (measured 32-48).
RAY_WORK_BYTES = 48
#: Bytes per ray of each answer key as the engine returns it.
FIELD_BYTES = {
    "t": 4,
    "mesh": 4,
    "prim": 4,
    "u": 4,
    "v": 4,
    "normal": 12,
    "occluded": 1,
    "count": 4,
    "offsets": 8,
    "truncated": 1,
}
#: Bytes per slot of a hits query, rays x (max_hits + 1) slots: the engine's lists (t and a
#: triangle) and every answer key of a filled slot (measured 40.1 with every slot filled).
HIT_SLOT_BYTES = 48
#: Bytes per ray or pixel of a sensor (rays made, traced, the answer's arrays; measured 94 for a
#: picture, 118 for a depth camera, 149 for one lidar return).
SENSOR_RAY_BYTES = 192
#: Bytes per sensor beyond its rays (its model, arrays and answer's keys: measured 6.4 KB a
#: one-ray lidar in a rig of 150,000).
SENSOR_BYTES = 8 * 1024
#: Bytes per beam and slot of a lidar's organized answer or kept non-hits beyond SENSOR_RAY_BYTES
#: (every field filled for every beam, then the points placed: measured 125 with noise, one slot).
FILLED_POINT_BYTES = 160
#: Bytes per mesh a frame names while it is decoded and applied (its keys parsed, its change, the
#: new mesh: measured 840 in process for a JSON frame of 4,096 instances) ...
FRAME_MESH_BYTES = 1024
#: ... and the fewest body bytes that name a mesh (``"a.mask":0,`` in JSON).
MIN_FRAME_MESH_BYTES = 10
#: Bytes per mesh of a scene info answer while it is built and written (its dicts and text:
#: measured 2.7 KB in process).
MESH_INFO_BYTES = 4096
#: Bytes of engine scene per triangle (corners, box, row, normal, mask) ...
TRIANGLE_BYTES = 80
#: ... and per placed triangle of a stored scene, once a point query has derived what it reads:
#: the triangles placed in scene space (corners, id and mask; none in a scene without instances
#: or deforming meshes, which reads its own rows), their boxes and Morton order (measured 83.8
#: for the street world with 40 placed cars, 16 for one without instances).
POINT_TRIANGLE_BYTES = 88
#: Peak bytes per body byte while a JSON body is parsed (measured 3.7-15.5: a digit is an 8-byte
#: list slot, a float a 24-byte object).
JSON_PARSE_FACTOR = 16
#: Peak bytes per body byte while a mesh file is read through trimesh (measured 7.6-16.4 for
#: STL and GLB) ...
MESH_FILE_FACTOR = 20
#: ... and by the service's own OBJ, OFF and PLY readers, whose short face rows (`f 1 2 3`,
#: `3 0 1 2`, or one long polygon fanned into a triangle an index) become int64 rows
#: (measured 14-24.5 with tracemalloc, 9-37 as a server's RSS, which holds the body's copies
#: too; a binary PLY read by trimesh less).
MESH_TEXT_FACTOR = 47
#: A bound of JSON parsing's peak by the body's structure, for the bodies dense in containers and
#: keys that JSON_PARSE_FACTOR does not cover (``[[{}],...]`` peaks at 33 x its bytes): bytes per
#: body byte (a number, measured 8.3-9.1) ...
JSON_TEXT_BYTES = 11
#: ... per ``"`` (half a string's object and slot: ``"ab"`` measured 64.5) ...
JSON_QUOTE_BYTES = 32
#: ... per ``[`` (a list and its slot, measured 64 for one of ``[[[[]]]]``) ...
JSON_LIST_BYTES = 64
#: ... per ``{`` (a dict and the pairs the key check builds, measured 76 for ``{}``) ...
JSON_OBJECT_BYTES = 128
#: ... and per ``:`` (a key's entry and its value's slot, measured 55-102 for ``"":0``).
JSON_KEY_BYTES = 96
#: Peak bytes per body byte of a binary (npy, npz) array body: the body and owned copies.
ARRAY_FACTOR = 2
#: Bytes held by a JSON answer while it is written: it is written in pieces of this many bytes of
#: arrays at the most (``wire.JSON_PIECE_ITEMS``), each piece's text and lists at about 600 bytes
#: an item (measured 456-605).
JSON_ANSWER_BYTES = 16 * 2**20
#: The smallest in-flight budget (DACRT_MAX_INFLIGHT_BYTES) that serves every request at its
#: smallest: a JSON answer's JSON_ANSWER_BYTES and a MiB for a small body, its work and answer.
MIN_BUDGET_BYTES = JSON_ANSWER_BYTES + 2**20
#: Bytes per point of a point query (``/nearest``) beyond its body: the checked copy, the
#: engine's float64 answers and the float32 answer (measured 102-104).
POINT_WORK_BYTES = 128
#: ... and what ``?sign=true`` adds: per ray of one call of the crossing count (origins, directions,
#: counts, the engine's lists; measured 50-56 with 1,000-1M points) ...
VOTE_RAY_BYTES = 64
#: ... and per direction of ``?nsamples=`` (made in float64, then tiled; measured 91 a ray and
#: direction together for one point and 1M directions).
VOTE_DIRECTION_BYTES = 64
#: Bytes per placed triangle of the scene a ray query (or a sensor, or ``?sign=true``'s inside
#: test) traces, whatever its rays: the boxes of the halves of the storage order and the
#: triangles' ids (measured 11.7 on a 3.55M-triangle scene, from 1 ray to 1M) ...
RAY_QUERY_TRIANGLE_BYTES = 16
#: ... and per chunk or half traced at once (its triangle ids and bins: measured 4.7).
RAY_THREAD_TRIANGLE_BYTES = 6
#: Bytes per placed triangle of a point query, whatever its points (the rows: measured 9.0) ...
POINT_QUERY_TRIANGLE_BYTES = 12
#: ... or of one whose ?mask= hides some meshes (the visible rows' boxes, Morton codes and order:
#: measured 34.4) ...
MASKED_POINT_TRIANGLE_BYTES = 48
#: ... and per chunk measured at once (its rows: measured 4.0).
POINT_THREAD_TRIANGLE_BYTES = 4
#: Bytes per placed triangle that the first point query on a scene version holds while it
#: derives what point queries read, beyond what is kept (which the scene limit counts): the
#: rows' Morton codes and their sort (measured 24.0 without instances, 25.5-30.0 with instances
#: or deforming meshes) ...
POINT_SETUP_TRIANGLE_BYTES = 32
#: ... and per row of a block of rows placed at a time (``dacrt.scene.PLACING_BLOCK_ROWS``;
#: measured 2.2 MiB at most in all, 70 B a triangle on a scene of 32,768).
POINT_SETUP_BLOCK_ROW_BYTES = 160
#: The smallest bytes of one point in a body of each format (npz counted as stored).
MIN_POINT_BYTES = {"npy": 12, "npz": 12, "json": 8}
#: The smallest bytes of one ray in a body of each format (npz counted as stored), for the most
#: rays a body can hold before it is decoded.
MIN_RAY_BYTES = {"npy": 24, "npz": 24, "json": 16}


def decode_bytes(n_body: int, fmt: str | None) -> int:
    """Peak bytes of a body of ``n_body`` bytes in format ``fmt`` while it is decoded (with the
    body itself); None: a format not known yet (counted as binary)."""
    if fmt == "json":
        return n_body * (1 + JSON_PARSE_FACTOR)
    if fmt in ("obj", "off", "ply"):
        return n_body * (1 + MESH_TEXT_FACTOR)
    if fmt in ("stl", "glb"):
        return n_body * (1 + MESH_FILE_FACTOR)
    return n_body * ARRAY_FACTOR


#: Formats whose body is (or holds) JSON text parsed whole, and the factor ``decode_bytes``
#: counts for them.
JSON_TEXT_FACTORS = {"json": JSON_PARSE_FACTOR, "glb": MESH_FILE_FACTOR}


def structure_bytes(body, fmt: str) -> int:
    """Bytes that parsing a JSON body (or a GLB's JSON chunk, counted over the whole file) may
    hold beyond ``decode_bytes``' estimate: what its lists, objects and keys take beyond the
    text's factor (0 for other formats and for bodies not dense in them)."""
    factor = JSON_TEXT_FACTORS.get(fmt)
    if factor is None:
        return 0
    text = np.frombuffer(body, np.uint8)
    peak = (
        JSON_TEXT_BYTES * len(text)
        + JSON_QUOTE_BYTES * int(np.count_nonzero(text == ord('"')))
        + JSON_LIST_BYTES * int(np.count_nonzero(text == ord("[")))
        + JSON_OBJECT_BYTES * int(np.count_nonzero(text == ord("{")))
        + JSON_KEY_BYTES * int(np.count_nonzero(text == ord(":")))
    )
    return max(0, peak - factor * len(text))


def frame_bytes(n_body: int, fmt: str | None, n_meshes: int, max_meshes: int) -> int:
    """Peak bytes of a frame of ``n_body`` bytes sent to a scene of ``n_meshes`` meshes: its body
    decoded, the meshes it names applied, and the scene info it answers (at most ``max_meshes``
    meshes, DACRT_MAX_MESHES_PER_SCENE)."""
    named = min(max_meshes, n_body // MIN_FRAME_MESH_BYTES)
    answered = min(max_meshes, n_meshes + named)
    return decode_bytes(n_body, fmt) + named * FRAME_MESH_BYTES + scene_info_bytes(answered)


def scene_info_bytes(n_meshes: int) -> int:
    """Peak bytes of a scene info answer (or a list of them) of ``n_meshes`` meshes in all."""
    return n_meshes * MESH_INFO_BYTES


def most_rays(n_body: int, fmt: str | None, max_rays: int) -> int:
    """The most rays a body of ``n_body`` bytes can hold (a compressed npz may hold more: its
    rays are counted again once decoded)."""
    return min(max_rays, n_body // MIN_RAY_BYTES.get(fmt or "npy", 24))


def most_points(n_body: int, fmt: str | None, max_points: int) -> int:
    """The most points a body of ``n_body`` bytes can hold (counted again once decoded)."""
    return min(max_points, n_body // MIN_POINT_BYTES.get(fmt or "npy", 12))


def point_query_bytes(n_points: int, sign: bool, nsamples: int) -> int:
    """Peak bytes of a point query of ``n_points`` points and its answer; with ``sign`` the
    inside test's rays of ``nsamples`` directions, as many at once as the engine traces."""
    work = n_points * POINT_WORK_BYTES
    if not sign:
        return work
    rays = vote_rays_at_once(n_points, nsamples)
    return work + rays * VOTE_RAY_BYTES + nsamples * VOTE_DIRECTION_BYTES


def scene_work_bytes(
    n_triangles: int,
    n_items: int,
    threads: int | None,
    points: bool = False,
    masked: bool = False,
    setup: bool = False,
) -> int:
    """Peak bytes of a query of ``n_items`` rays (or points, with ``points``; with ``masked``, a
    ?mask=; with ``setup``, the version's first, which derives what point queries read) on the
    triangles of a scene of ``n_triangles`` placed triangles, beyond what its rays or points
    take, on ``threads`` engine threads (None: every core): the per-triangle work, and that of
    each chunk (or half) traced at once."""
    threads = threads or N_CORES
    if points:
        at_once = min(threads, max(1, n_items))
        per_query = MASKED_POINT_TRIANGLE_BYTES if masked else POINT_QUERY_TRIANGLE_BYTES
        per_triangle = per_query + at_once * POINT_THREAD_TRIANGLE_BYTES
        if not setup:
            return n_triangles * per_triangle
        # the setup's transient is freed before the points are measured
        block = min(n_triangles, PLACING_BLOCK_ROWS) * POINT_SETUP_BLOCK_ROW_BYTES
        return n_triangles * max(per_triangle, POINT_SETUP_TRIANGLE_BYTES) + block
    halves = 2 if threads > 1 and n_items >= MIN_RAYS_TO_SPLIT_TRIANGLES else 1
    at_once = min(threads, max(halves, n_items // MIN_RAYS_PER_THREAD))
    return n_triangles * (RAY_QUERY_TRIANGLE_BYTES + at_once * RAY_THREAD_TRIANGLE_BYTES)


def most_triangles(n_body: int) -> int:
    """The most triangles a mesh sent in a body of ``n_body`` bytes can hold (a triangle takes
    at least a face's 12 bytes)."""
    return n_body // 12


def mesh_scene_bytes(n_body: int) -> int:
    """The most bytes of engine scene a mesh sent in a body of ``n_body`` bytes can make."""
    return most_triangles(n_body) * TRIANGLE_BYTES


def answer_bytes(fmt: str) -> int:
    """Bytes held beyond the answer's arrays while it is written in ``fmt``."""
    return JSON_ANSWER_BYTES if fmt == "json" else 0


def query_bytes(n_rays: int, query: str, fields: tuple[str, ...], max_hits: int | None) -> int:
    """Peak bytes of tracing ``n_rays`` rays for ``query`` and holding its answer's ``fields``."""
    if query == "hits":
        return n_rays * (RAY_WORK_BYTES + FIELD_BYTES["offsets"] + (max_hits + 1) * HIT_SLOT_BYTES)
    per_ray = sum(FIELD_BYTES[name] for name in fields)
    if query == "closest":  # the engine writes every key, then the answer picks
        per_ray = sum(FIELD_BYTES[name] for name in ("t", "mesh", "prim", "u", "v", "normal"))
    return n_rays * (RAY_WORK_BYTES + per_ray)


def sensor_bytes(n_rays: int, max_returns: int = 1) -> int:
    """Peak bytes of a sensor of ``n_rays`` rays (pixels, or beams x steps) and its answer."""
    if max_returns > 1:
        return SENSOR_BYTES + n_rays * (SENSOR_RAY_BYTES + (max_returns + 1) * HIT_SLOT_BYTES)
    return SENSOR_BYTES + n_rays * SENSOR_RAY_BYTES
