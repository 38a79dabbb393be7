"""A corpus of hostile requests against a real server: each gets its 4xx with a JSON detail that
names the problem, within a stated time, while the server's peak memory stays under a stated
bound; afterwards the server is healthy, its scenes are unchanged, and no request reached the
catch-all 500."""

from __future__ import annotations

import json
import re
import socket
import time
from pathlib import Path

import hostile_bodies as hostile
import httpx
import numpy as np
from mesh_files import BAD_MESH_FILES, GLB, png, triangle_glb
from service_helpers import NPY, NPZ, down_rays, npy_bytes, npz_bytes, quad

JSON = {"Content-Type": "application/json"}
#: Each case must be answered within this many seconds (a 1 GiB zip bomb took 2-5 s unchecked).
CASE_SECONDS = 3.0
#: Peak memory the whole corpus may add to the server: its body limit and 64 MiB.
MEMORY_BOUND = (4 << 20) + (64 << 20)
RAYS = np.hstack(down_rays([[0.5, 0.5], [0.2, 0.7]])).astype(np.float32)
TRIANGLE = '"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 2]]'


def json_with(**fields: str) -> bytes:
    """A JSON object from raw JSON texts, so that fields can hold what ``json.dumps`` would not."""
    return ("{" + ", ".join(f'"{key}": {text}' for key, text in fields.items()) + "}").encode()


# (name, method, path under /v1/scenes/{scene}, headers, body, status, a phrase of the detail);
# bodies are built lazily: some take a second to make.
CORPUS = [
    # zip bombs of each kind
    (
        "npz member inflating to 1 GiB",
        "POST",
        "closest",
        NPZ,
        lambda: hostile.zip_bomb(1 << 30),
        400,
        "inflates to more than the 1024 bytes",
    ),
    (
        "honest npz member of 512 MiB",
        "POST",
        "closest",
        NPZ,
        lambda: hostile.honest_big_zip(512 << 20),
        413,
        "DACRT_MAX_BODY_BYTES",
    ),
    (
        "1000 entries over one deflate stream",
        "POST",
        "closest",
        NPZ,
        lambda: hostile.overlapping_zip(1000),
        400,
        "overlaps the member before it",
    ),
    ("npz member twice", "POST", "closest", NPZ, hostile.duplicate_zip, 400, "twice"),
    ("encrypted npz member", "POST", "closest", NPZ, hostile.encrypted_zip, 400, "encrypted"),
    ("bzip2 npz member", "POST", "closest", NPZ, hostile.bzip2_zip, 400, "compression method"),
    (
        "zip bomb as a mesh",
        "PUT",
        "meshes/bomb",
        NPZ,
        lambda: hostile.zip_bomb(1 << 30),
        400,
        "inflates to more than",
    ),
    (
        "zip bomb as a frame",
        "POST",
        "frame",
        NPZ,
        lambda: hostile.zip_bomb(1 << 30),
        400,
        "inflates to more than",
    ),
    (
        "zip bomb as a one-shot trace",
        "POST",
        "/v1/trace",
        NPZ,
        lambda: hostile.zip_bomb(1 << 30),
        400,
        "inflates to more than",
    ),
    # forged .npy headers
    *[
        (
            f"npy shape {shape}",
            "POST",
            "closest",
            NPY,
            lambda shape=shape: hostile.npy_with_header("<f4", shape, bytes(48)),
            400,
            problem,
        )
        for shape, problem in [
            ((-2, -3), "negative length"),
            ((-1, -6), "negative length"),
            ((2**32, 2**32), "truncated"),
            ((2**62, 8), "truncated"),
            ((2**64, 6), "truncated"),
        ]
    ],
    *[
        (
            f"npy shape {name} and no data",
            method,
            path,
            NPY,
            lambda shape=shape: hostile.npy_with_header("<f4", shape),
            400,
            problem,
        )
        for name, shape, problem in [
            ("(2**62, 0)", (2**62, 0), "too big for an array"),
            ("of 65 zeros", (0,) * 65, "65 axes"),
        ]
        for method, path in [("POST", "closest"), ("POST", "nearest")]
    ],
    (
        "npy dtype |V0",
        "POST",
        "closest",
        NPY,
        lambda: hostile.npy_with_header("|V0", (2, 6)),
        422,
        "only plain numeric arrays",
    ),
    (
        "npy subarray dtype",
        "POST",
        "closest",
        NPY,
        lambda: hostile.npy_with_header(("<f4", (6,)), (2,), bytes(48)),
        422,
        "only plain numeric",
    ),
    (
        "npy vertices of shape (-1, 3)",
        "PUT",
        "meshes/m/vertices",
        NPY,
        lambda: hostile.npy_with_header("<f4", (-1, 3)),
        400,
        "negative length",
    ),
    # JSON: deep, huge numbers, strings and booleans
    (
        "rays nested 100,000 deep",
        "POST",
        "closest",
        JSON,
        lambda: hostile.deep_json("origins", 100_000),
        400,
        "nested too deeply",
    ),
    (
        "rays nested 1,000 deep",
        "POST",
        "closest",
        JSON,
        lambda: hostile.deep_json("directions", 1000),
        400,
        "nested too deeply",
    ),
    (
        "mesh nested 5,000 deep",
        "PUT",
        "meshes/deep",
        JSON,
        lambda: json_with(vertices="[" * 5000 + "]" * 5000, faces="[]"),
        400,
        "nested too deeply",
    ),
    (
        "frame nested 5,000 deep",
        "POST",
        "frame",
        JSON,
        lambda: json_with(**{"m.vertices": "[" * 5000 + "]" * 5000}),
        400,
        "nested too deeply",
    ),
    (
        "origin of 10**400",
        "POST",
        "closest",
        JSON,
        lambda: json_with(origins="[[1" + "0" * 400 + ", 0, 0]]", directions="[[0, 0, 1]]"),
        422,
        "int too large",
    ),
    (
        "origin of 5,000 digits",
        "POST",
        "closest",
        JSON,
        lambda: json_with(origins="[[1" + "0" * 5000 + ", 0, 0]]", directions="[[0, 0, 1]]"),
        422,
        "origins[0][0] is an integer of 5001 digits",
    ),
    (
        "tmax of 10**400",
        "POST",
        "occluded",
        JSON,
        lambda: json_with(origins="[[0, 0, 0]]", directions="[[0, 0, 1]]", tmax="1" + "0" * 400),
        422,
        "int too large",
    ),
    (
        "vertex of 10**400",
        "PUT",
        "meshes/big",
        JSON,
        lambda: json_with(
            vertices="[[1" + "0" * 400 + ", 0, 0], [1, 0, 0], [0, 1, 0]]", faces="[[0, 1, 2]]"
        ),
        422,
        "int too large",
    ),
    (
        "coordinates as strings",
        "POST",
        "closest",
        JSON,
        lambda: json_with(origins='[["0.5", 0, 0]]', directions="[[0, 0, 1]]"),
        422,
        "the string",
    ),
    (
        "coordinates as booleans",
        "PUT",
        "meshes/m/vertices",
        JSON,
        lambda: json_with(vertices="[[true, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]"),
        422,
        "found true",
    ),
    (
        "a face index as a boolean",
        "PUT",
        "meshes/b",
        JSON,
        lambda: json_with(vertices="[[0, 0, 0], [1, 0, 0], [0, 1, 0]]", faces="[[true, 1, 2]]"),
        422,
        "found true",
    ),
    (
        "a one-shot trace with string rays",
        "POST",
        "/v1/trace",
        JSON,
        lambda: (
            "{" + TRIANGLE + ', "origins": [["a", 0, 0]], "directions": [[0, 0, 1]]}'
        ).encode(),
        422,
        "the string 'a'",
    ),
    # bodies that are not what they say
    (
        "an empty zip as rays",
        "POST",
        "closest",
        NPZ,
        lambda: b"PK\x05\x06" + bytes(18),
        400,
        "lacks 'origins'",
    ),
    ("binary as JSON", "POST", "closest", JSON, lambda: b"\xff\xfe\x00{", 400, "not valid JSON"),
    (
        "a JSON integer of 5000 digits",
        "POST",
        "closest",
        JSON,
        lambda: b'{"origins": [[' + b"9" * 5000 + b', 0, 0]], "directions": [[0, 0, 1]]}',
        422,
        "body's origins[0][0] is an integer of 5000 digits, out of every range",
    ),
    (
        "an npy of 2 GiB promised, 48 bytes sent",
        "POST",
        "closest",
        NPY,
        lambda: hostile.npy_with_header("<f4", (2**28, 2)),
        400,
        "truncated",
    ),
    (
        "unknown query parameter",
        "POST",
        "closest?feilds=t",
        NPY,
        lambda: npy_bytes(RAYS),
        422,
        "unknown query parameter 'feilds' (did you mean 'fields'?)",
    ),
    (
        "a query parameter given twice",
        "POST",
        "closest?fields=t&fields=mesh",
        NPY,
        lambda: npy_bytes(RAYS),
        422,
        "query parameter 'fields' is given 2 times ('t', 'mesh'); give it once",
    ),
    # malformed or hostile mesh files
    *[
        (f"mesh file: {phrase}", "PUT", "meshes/m", headers, lambda body=body: body, status, phrase)
        for body, headers, status, phrase in BAD_MESH_FILES
    ],
    # sensors: a bad value is named by the request's key, never by the engine's arrays
    *[
        (
            f"{route}: {phrase}",
            "POST",
            route,
            JSON,
            lambda body=body: json.dumps(body).encode(),
            422,
            phrase,
        )
        for route, body, phrase in hostile.BAD_SENSOR_VALUES
    ],
    # point queries: a bad value or key is named by the request's key
    *[
        (
            f"{route}: {phrase}",
            "POST",
            route,
            {"npy": NPY, "json": JSON}[kind],
            lambda body=body: body,
            status,
            phrase,
        )
        for route, kind, body, status, phrase in hostile.BAD_POINT_REQUESTS
    ],
    (
        "zip bomb as points",
        "POST",
        "nearest",
        NPZ,
        lambda: hostile.zip_bomb(1 << 30),
        400,
        "inflates to more than",
    ),
    (
        "an npy of 2 GiB of points promised, 48 bytes sent",
        "POST",
        "nearest",
        NPY,
        lambda: hostile.npy_with_header("<f4", (2**28, 3), bytes(48)),
        400,
        "truncated",
    ),
]


def peak_and_reset(pid: int) -> tuple[int, int]:
    """(peak RSS since the last reset, RSS now) of a process, in bytes; resets the peak."""
    status = Path(f"/proc/{pid}/status").read_text()
    rss = {
        key: int(value) * 1024 for key, value in re.findall(r"(VmHWM|VmRSS):\s+(\d+) kB", status)
    }
    Path(f"/proc/{pid}/clear_refs").write_text("5")  # Linux: reset VmHWM to the current RSS
    return rss["VmHWM"], rss["VmRSS"]


def server_state(http: httpx.Client, scene: str) -> dict:
    """What no rejected request may change: health, the scene list, one scene and an answer."""
    health = http.get("/health").json()
    answer = http.post(
        f"/v1/scenes/{scene}/closest?fields=t,prim",
        content=npy_bytes(RAYS),
        headers={**NPY, "Accept": "application/json"},
    ).json()
    return {
        "health": {k: v for k, v in health.items() if k != "warmup_seconds"},
        "scenes": http.get("/v1/scenes").json(),
        "answer": answer,
    }


def test_hostile_corpus_gets_4xx_at_bounded_cost_and_changes_nothing(hostile_server):
    with httpx.Client(base_url=hostile_server.url, timeout=60) as http:
        scene = "target"
        assert http.put(
            f"/v1/scenes/{scene}/meshes/m",
            content=npz_bytes(vertices=quad(0, 1, 0, 1, 0)[0], faces=quad(0, 1, 0, 1, 0)[1]),
            headers=NPZ,
        ).is_success
        before = server_state(http, scene)
        bodies = [(case, case[4]()) for case in CORPUS]  # built before the memory is watched
        peak_and_reset(hostile_server.process.pid)
        _, rss_before = peak_and_reset(hostile_server.process.pid)
        failures = []
        for (name, method, path, headers, _, status, phrase), body in bodies:
            url = path if path.startswith("/") else f"/v1/scenes/{scene}/{path}"
            start = time.perf_counter()
            response = http.request(method, url, content=body, headers=headers)
            seconds = time.perf_counter() - start
            detail = (
                response.json().get("detail", "")
                if response.headers.get("content-type") == "application/json"
                else response.text
            )
            if (
                response.status_code != status
                or not isinstance(detail, str)
                or phrase not in detail
                or seconds > CASE_SECONDS
            ):
                failures.append(
                    f"{name}: {response.status_code} in {seconds:.2f} s: {detail[:200]}"
                )
        peak, _ = peak_and_reset(hostile_server.process.pid)
        assert not failures, "\n".join(failures)
        assert peak - rss_before < MEMORY_BOUND, f"peak RSS rose by {(peak - rss_before) >> 20} MiB"
        assert server_state(http, scene) == before
        metrics = http.get("/metrics").text
        assert not re.search(r'status="500"', metrics), "a request reached the catch-all 500"


def test_rejected_uploads_create_no_scene(hostile_server):
    with httpx.Client(base_url=hostile_server.url, timeout=60) as http:
        scenes = http.get("/v1/scenes").json()
        response = http.put(
            "/v1/scenes/never-made/meshes/m",
            headers=JSON,
            content=json_with(vertices="[[true, 0, 0]]", faces="[[0, 0, 0]]"),
        )
        assert response.status_code == 422
        assert http.get("/v1/scenes/never-made").status_code == 404
        assert http.get("/v1/scenes").json() == scenes


def test_a_client_leaving_mid_body_is_counted_apart_from_server_errors(hostile_server):
    vertices, faces = quad(0, 1, 0, 1, 0)
    put = httpx.put(
        f"{hostile_server.url}/v1/scenes/left/meshes/m",
        content=npz_bytes(vertices=vertices, faces=faces),
        headers=NPZ,
    )
    assert put.is_success  # a scene of its own: the query reads its body, not a 404
    host, port = hostile_server.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=5) as raw:
        raw.sendall(
            b"POST /v1/scenes/left/closest HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            b"Content-Type: application/x-npy\r\nContent-Length: 100000\r\n\r\n" + bytes(1000)
        )
    # the server reads the headers and the 1000 bytes before the end of the stream; it counts the
    # request once its handler has seen the client leave
    deadline = time.monotonic() + 5
    metrics = httpx.get(f"{hostile_server.url}/metrics").text
    while 'status="499"' not in metrics and time.monotonic() < deadline:
        metrics = httpx.get(f"{hostile_server.url}/metrics").text
    assert re.search(r'route="/v1/scenes/\{scene\}/closest",status="499"\} [1-9]', metrics)
    assert not re.search(r'status="500"', metrics)
    assert "Traceback" not in hostile_server.output()


def test_textures_in_a_mesh_file_are_never_decoded(hostile_server):
    image = png(8000, 8000)  # 192 MB decoded, 190 KB compressed
    body = triangle_glb(images=[image, image])
    with httpx.Client(base_url=hostile_server.url, timeout=60) as http:
        _, rss_before = peak_and_reset(hostile_server.process.pid)
        response = http.put("/v1/scenes/textured/meshes/m", content=body, headers=GLB)
        peak, _ = peak_and_reset(hostile_server.process.pid)
        http.delete("/v1/scenes/textured")
    assert response.status_code == 201 and response.json()["triangles"] == 1
    assert peak - rss_before < 64 << 20, f"peak RSS rose by {(peak - rss_before) >> 20} MiB"
