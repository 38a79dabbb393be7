"""The HTTP/1.1 protocol's bounds, on a real server driven by raw sockets: bytes between requests
start a header clock, an answer left unread ends its connection and gives back its budget, headers
and pipelines are bounded, requests that are not HTTP/1.1 are answered in JSON and in order, HEAD
is served as GET without a body, and bodies in codings the server does not read are refused."""

from __future__ import annotations

import io
import json
import re
import socket
import time

import httpx
import numpy as np
import pytest
from server_process import ServerProcess
from service_helpers import metric_sample

HEADER_TIMEOUT, ANSWER_IDLE_TIMEOUT = 1.0, 1.0
MARGIN = 2.0  # seconds a cut-off may come after its deadline on a busy machine
MAX_PIPELINED = 16  # service.protocol's
STATUS = re.compile(rb"HTTP/1\.1 (\d{3})")


@pytest.fixture(scope="module")
def server():
    process = ServerProcess(
        {
            "DACRT_HEADER_TIMEOUT": str(HEADER_TIMEOUT),
            "DACRT_ANSWER_IDLE_TIMEOUT": str(ANSWER_IDLE_TIMEOUT),
        }
    )
    try:
        process.wait_ready()
        wall = {"vertices": [[5, -5, -5], [5, 5, -5], [5, 0, 5]], "faces": [[0, 1, 2]]}
        httpx.put(f"{process.url}/v1/scenes/s/meshes/wall", json=wall).raise_for_status()
        yield process
    finally:
        process.stop()


def connect(server: ServerProcess, **options: int) -> socket.socket:
    s = socket.socket()
    for option, value in options.items():
        s.setsockopt(socket.SOL_SOCKET, getattr(socket, option), value)
    s.settimeout(30)
    s.connect(("127.0.0.1", server.port))
    return s


def read_until_closed(s: socket.socket, give_up: float) -> tuple[bytes, float]:
    """Everything the server sends until it closes (or ``give_up`` seconds), and when it closed
    (inf if it did not)."""
    start, data = time.monotonic(), b""
    s.settimeout(0.2)
    while time.monotonic() - start < give_up:
        try:
            chunk = s.recv(65536)
        except TimeoutError:
            continue
        except ConnectionResetError:
            return data, time.monotonic() - start
        if not chunk:
            return data, time.monotonic() - start
        data += chunk
    return data, float("inf")


def dechunked(stream: bytes) -> bytes:
    """The body at the start of ``stream`` in chunked transfer coding."""
    body = b""
    while True:
        size_line, stream = stream.split(b"\r\n", 1)
        size = int(size_line, 16)
        if size == 0:
            return body
        body, stream = body + stream[:size], stream[size + 2 :]


def detail(answer: bytes) -> str:
    return json.loads(answer.split(b"\r\n\r\n", 1)[1])["detail"]


def test_an_empty_line_after_an_answer_starts_the_header_clock(server):
    """An empty line between requests is allowed, but it must not stop every deadline: the
    connection ends HEADER_TIMEOUT after it, not never."""
    with connect(server) as s:
        s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert STATUS.match(s.recv(65536)).group(1) == b"200"
        s.sendall(b"\r\n")
        _, closed_after = read_until_closed(s, HEADER_TIMEOUT + 10)
    assert closed_after <= HEADER_TIMEOUT + MARGIN


def inflight_bytes(server: ServerProcess) -> float:
    text = httpx.get(f"{server.url}/metrics").text
    return float(re.search(r"^dacrt_inflight_bytes (\S+)$", text, re.M).group(1))


def test_an_answer_left_unread_ends_its_connection_and_frees_its_budget(server):
    rays = np.zeros((1_000_000, 6), np.float32)
    rays[:, 0], rays[:, 3] = -5.0, 1.0  # every ray hits the wall: a 32 MB answer
    body = io.BytesIO()
    np.save(body, rays)
    with connect(server, SO_RCVBUF=4096) as s:
        s.sendall(
            b"POST /v1/scenes/s/closest HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            b"Accept: application/x-npz\r\n"
            b"Content-Type: application/x-npy\r\nContent-Length: %d\r\n\r\n" % body.tell()
        )
        s.sendall(body.getvalue())
        deadline = time.monotonic() + 60
        while inflight_bytes(server) == 0 and time.monotonic() < deadline:
            time.sleep(0.1)  # the request holds its budget while traced and answered
        assert inflight_bytes(server) > 0
        while inflight_bytes(server) > 0 and time.monotonic() < deadline:
            time.sleep(0.2)  # ... until the answer, unread, ends the connection
        assert inflight_bytes(server) == 0
        received, _ = read_until_closed(s, 10)
    assert len(received) < 32_000_000  # cut off, not sent whole
    assert httpx.get(f"{server.url}/health").status_code == 200


def test_headers_over_the_bound_are_431_in_json(server):
    with connect(server) as s:
        s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        try:
            for _ in range(100):  # 1.6 MB of headers, sent until the server answers
                s.sendall(b"X-Filler: " + b"a" * 16_000 + b"\r\n")
        except (BrokenPipeError, ConnectionResetError):
            pass
        answer, _ = read_until_closed(s, 10)
    assert STATUS.match(answer).group(1) == b"431", answer[:200]
    assert "request line and headers over 65536 bytes" in detail(answer)


@pytest.mark.parametrize(
    "request_bytes",
    [
        b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 70_000 + b"\r\n\r\n",
        b"GET /health?" + b"a" * 66_000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
        b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n" + b"X-A: " + b"b" * 40_000 + b"\r\n" * 2,
    ],
    ids=["one header of 70 kB", "a request-target of 66 kB", "within the bound"],
)
def test_headers_over_the_bound_in_one_write_are_431(server, request_bytes):
    """The bound holds for a request whose line and headers arrive and end within one read too
    (a 70 kB header was answered 200, a 66 kB request-target 400 "User callback error")."""
    with connect(server) as s:
        s.sendall(request_bytes)
        answer, _ = read_until_closed(s, 10) if len(request_bytes) > 65536 else (s.recv(4096), 0)
    if len(request_bytes) > 65536:
        assert STATUS.match(answer).group(1) == b"431", answer[:200]
        assert "request line and headers over 65536 bytes" in detail(answer)
    else:
        assert STATUS.match(answer).group(1) == b"200", answer[:200]


def test_a_pipeline_is_bounded_and_answered_in_order(server):
    """Requests queued behind the one answered are bounded: the connection ends after answering
    MAX_PIPELINED + 1 of 200, in order; later ones go unanswered, as after any close."""
    with connect(server) as s:
        s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 200)
        answers, closed_after = read_until_closed(s, 20)
    assert closed_after < 20
    assert 1 <= answers.count(b"HTTP/1.1 200") <= MAX_PIPELINED + 1


def test_a_bad_request_behind_a_good_one_ends_the_connection_after_its_answer(server):
    with connect(server) as s:
        s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\nGARBAGE\x01 / HTTP/1.1\r\n\r\n")
        answers, closed_after = read_until_closed(s, 10)
    assert STATUS.findall(answers) == [b"200"] and closed_after < 10


def test_a_request_that_is_not_http_is_400_in_json(server):
    with connect(server) as s:
        s.sendall(
            b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            b"Content-Length: 1\r\nContent-Length: 2\r\n\r\n"
        )
        answer, _ = read_until_closed(s, 10)
    assert STATUS.match(answer).group(1) == b"400"
    assert detail(answer).startswith("the request is not valid HTTP/1.1")


@pytest.mark.parametrize("path", ["/health", "/metrics", "/", "/v1/capabilities", "/docs"])
def test_head_is_answered_as_get_without_a_body(server, path):
    got = httpx.get(server.url + path)
    head = httpx.head(server.url + path)
    assert head.status_code == got.status_code == 200
    assert head.content == b"" and head.headers["content-type"] == got.headers["content-type"]


@pytest.mark.parametrize("pieces", [1, 3])
def test_an_upgrade_not_spoken_is_answered_over_http_1_1_with_its_body(server, pieces):
    """``Upgrade: h2c`` (what ``curl --http2`` sends) is not taken: the request is answered,
    its body whole, however it arrives, and the connection serves the next request."""
    body = json.dumps({"origins": [[-5, 0, 0]], "directions": [[1, 0, 0]]}).encode()
    head = (
        b"POST /v1/scenes/s/closest HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: application/json\r\n"
        b"Connection: Upgrade, HTTP2-Settings\r\nUpgrade: h2c\r\n"
        b"HTTP2-Settings: AAMAAABkAAQAoAAAAAIAAAAA\r\nContent-Length: %d\r\n\r\n" % len(body)
    )
    request = head + body + b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    cut = [len(head) + k * len(body) // pieces for k in range(pieces)] + [len(request)]
    with connect(server) as s:
        s.sendall(request[: cut[0]])
        for lo, hi in zip(cut, cut[1:]):
            time.sleep(0.05)
            s.sendall(request[lo:hi])
        answers, _ = read_until_closed(s, 10)
    assert STATUS.findall(answers) == [b"200", b"200"], answers[:300]
    assert json.loads(dechunked(answers.split(b"\r\n\r\n", 1)[1]))["t"] == [10.0]


def test_an_upgrade_not_spoken_with_a_chunked_body_is_400_naming_it(server):
    body = json.dumps({"origins": [[-5, 0, 0]], "directions": [[1, 0, 0]]}).encode()
    with connect(server) as s:
        s.sendall(
            b"POST /v1/scenes/s/closest HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            b"Content-Type: application/json\r\n"
            b"Connection: Upgrade\r\nUpgrade: h2c\r\nTransfer-Encoding: chunked\r\n\r\n"
            + b"%x\r\n%s\r\n0\r\n\r\n"
            % (len(body), body)
        )
        answer, _ = read_until_closed(s, 10)
    assert STATUS.match(answer).group(1) == b"400"
    assert "Upgrade: h2c with a chunked body is not served" in detail(answer)


def test_a_path_or_upgrade_a_client_sends_cannot_forge_or_colour_a_log_line(server):
    """The protocol logs the answer it writes with the request's path, percent-decoded, and the
    Upgrade it refuses: a %0a cannot start a line of its own, a %1b cannot colour one, and a long
    header value is cut."""
    path = b"/x%0aINFO:%20%20%20%20%20service:%20FORGED%1b[31m"
    upgrade = b"h2c" + b"x" * 3000
    with connect(server) as s:
        s.sendall(
            b"POST " + path + b" HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: Upgrade\r\n"
            b"Upgrade: " + upgrade + b"\r\nTransfer-Encoding: chunked\r\n\r\n"
            b"5\r\nhello\r\n0\r\n\r\n"
        )
        answer, _ = read_until_closed(s, 10)
    assert STATUS.match(answer).group(1) == b"400"
    assert len(detail(answer)) < 1000
    output = server.output(last=10**6)
    [line] = [line for line in output.splitlines() if "FORGED" in line]
    assert line.startswith("INFO:     service: 127.0.0.1:")
    assert "POST /x\\nINFO:     service: FORGED\\x1b[31m answered 400: Upgrade: h2cxxx" in line
    assert "(3003 characters)" in line and len(line) < 1000
    assert "\x1b" not in output


def closest_counted(server: ServerProcess, status: int) -> float:
    text = httpx.get(f"{server.url}/metrics").text
    labels = f'method="POST",route="/v1/scenes/{{scene}}/closest",status="{status}"'
    return metric_sample(text, f"dacrt_requests_total{{{labels}}}")


def test_an_upgrade_refused_for_its_chunked_body_is_counted_as_its_400(server):
    """The app sees a client gone, but the client was answered 400: /metrics counts a 400."""
    before = {status: closest_counted(server, status) for status in (400, 499)}
    test_an_upgrade_not_spoken_with_a_chunked_body_is_400_naming_it(server)
    deadline = time.monotonic() + 10  # the app's task ends a little after the answer
    while closest_counted(server, 400) == before[400] and time.monotonic() < deadline:
        time.sleep(0.1)
    assert closest_counted(server, 400) == before[400] + 1
    assert closest_counted(server, 499) == before[499]
    assert "POST /v1/scenes/s/closest answered 400: Upgrade: h2c" in server.output(last=10**6)


@pytest.mark.parametrize(
    "headers, status, words",
    [
        ({"Content-Encoding": "gzip"}, 415, "Content-Encoding gzip is not read"),
        ({"Transfer-Encoding": "gzip, chunked"}, 501, "only chunked"),
    ],
)
def test_bodies_in_codings_the_server_does_not_read_are_refused(server, headers, status, words):
    body = json.dumps({"origins": [[-5, 0, 0]], "directions": [[1, 0, 0]]}).encode()
    if "Transfer-Encoding" in headers:
        body = b"%x\r\n%s\r\n0\r\n\r\n" % (len(body), body)
    else:
        headers = {**headers, "Content-Length": str(len(body))}
    head = "".join(f"{k}: {v}\r\n" for k, v in headers.items()).encode()
    with connect(server) as s:
        s.sendall(
            b"POST /v1/scenes/s/closest HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n"
            b"Content-Type: application/json\r\n" + head + b"\r\n" + body
        )
        answer, _ = read_until_closed(s, 10)
    assert STATUS.match(answer).group(1) == str(status).encode(), answer[:300]
    assert words in detail(answer)


def test_a_client_leaving_a_pipeline_leaves_no_error_behind(server):
    """The request being answered, and those queued behind it, on a connection that ends are
    ended as gone, not answered into the closed connection (a traceback each in the log)."""
    for _ in range(3):
        with connect(server) as s:
            s.settimeout(2)
            try:
                for _ in range(20):  # more than the server reads once it stops reading
                    s.sendall(b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 5000)
            except OSError:
                pass  # the server ended the connection, or stopped reading it
    time.sleep(2.0)
    assert httpx.get(f"{server.url}/health").status_code == 200
    assert "Traceback" not in server.output(last=200_000)


def protocol_counted(server: ServerProcess, method: str, status: int) -> tuple[float, float]:
    """Requests counted under route "protocol" with ``method`` and ``status``, and the
    requests the route's time histogram counted."""
    text = httpx.get(f"{server.url}/metrics").text
    labels = f'method="{method}",route="protocol",status="{status}"'
    return (
        metric_sample(text, f"dacrt_requests_total{{{labels}}}"),
        metric_sample(text, 'dacrt_request_seconds_count{route="protocol"}'),
    )


@pytest.mark.parametrize(
    "request_bytes, method, status, words",
    [
        (
            b"GET /v1/scenes HTTP/1.1\r\nHost: 127.0.0.1\r\n",
            "GET",
            408,
            "request headers not received",
        ),
        (
            b"GET /v1/scenes HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 70_000 + b"\r\n\r\n",
            "GET",
            431,
            "request line and headers over",
        ),
        (b"GARBAGE / HTTP/9\r\n\r\n", "unknown", 400, "the request is not valid HTTP/1.1"),
    ],
    ids=["headers too slow", "headers too large", "not HTTP"],
)
def test_answers_the_protocol_writes_are_counted_and_logged(
    server, request_bytes, method, status, words
):
    """Answers written before the app sees a request are counted under route "protocol", with
    the method read (``unknown`` before it is), and logged."""
    counted, timed = protocol_counted(server, method, status)
    with connect(server) as s:
        s.sendall(request_bytes)
        answer, _ = read_until_closed(s, HEADER_TIMEOUT + 10)
    assert STATUS.match(answer).group(1) == str(status).encode(), answer[:200]
    assert protocol_counted(server, method, status) == (counted + 1, timed + 1)
    assert f"{method} request answered {status}: {words}" in server.output(last=10**6)


@pytest.mark.parametrize(
    "headers, words",
    [
        (b"Host: attacker.example\r\n", "Host 'attacker.example' is not one this server answers"),
        (
            b"Host: 127.0.0.1\r\nOrigin: http://attacker.example\r\n",
            "from the page of another origin",
        ),
    ],
)
def test_a_rebound_name_or_a_page_elsewhere_is_403_before_the_body_is_read(server, headers, words):
    """A server on a loopback address answers only loopback names (a DNS-rebinding page's
    requests name its own host) and refuses a change from another origin's page."""
    frame = b'{"evil.vertices": [[0, 0, 0], [9, 0, 0], [0, 9, 0]], "evil.faces": [[0, 1, 2]]}'
    with connect(server) as s:
        s.sendall(
            b"POST /v1/scenes/s/frame HTTP/1.1\r\n" + headers + b"Content-Type: application/json"
            b"\r\nContent-Length: %d\r\nConnection: close\r\n\r\n" % len(frame) + frame
        )
        answer, _ = read_until_closed(s, 10)
    assert STATUS.match(answer).group(1) == b"403"
    assert words in detail(answer)
    meshes = httpx.get(f"{server.url}/v1/scenes/s").json()["meshes"]
    assert [m["mesh"] for m in meshes] == ["wall"]
