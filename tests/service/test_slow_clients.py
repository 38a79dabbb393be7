"""Slow and stalled clients are cut off, connections beyond the bounds are refused, and /health and
/metrics answer whatever the other clients hold.

Three servers of their own: ``stalls`` with short deadlines (DACRT_HEADER_TIMEOUT,
DACRT_BODY_IDLE_TIMEOUT, DACRT_BODY_TIMEOUT), where raw sockets play the stalling clients, all at
once; ``bounds`` with a small DACRT_MAX_CONNECTIONS and DACRT_MAX_CONNECTIONS_PER_CLIENT, where
idle sockets from other loopback addresses (127.0.0.2, ...: all of 127/8 is loopback on Linux) fill
the bounds; ``budget`` with a small DACRT_MAX_INFLIGHT_BYTES, where a slow body declares a large
Content-Length.
"""

from __future__ import annotations

import io
import socket
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass

import httpx
import numpy as np
import pytest
from server_process import ServerProcess
from service_helpers import metric_sample

from service.deps import BODY_STEP

HEADER_TIMEOUT, BODY_IDLE_TIMEOUT, BODY_TIMEOUT = 1.0, 1.5, 3.0
MAX_CONNECTIONS, MAX_PER_CLIENT = 8, 4  # of the ``bounds`` server
MiB = 2**20
BUDGET = 64 * MiB  # of the ``budget`` server
STALLED_BODIES = 100  # the ``stalls`` server keeps the default DACRT_MAX_CONNECTIONS, 100
MARGIN = 1.0  # seconds a cut-off may come after its deadline on a busy machine
GIVE_UP = 7.0  # a client still connected after this long was never cut off
TRICKLE_EVERY = 0.3  # seconds between the bytes of a trickling client
WAIT = 10.0  # seconds a poll waits for the server to see sockets open or closed


@pytest.fixture(scope="module")
def servers():
    processes = {
        "stalls": ServerProcess(
            {
                "DACRT_HEADER_TIMEOUT": str(HEADER_TIMEOUT),
                "DACRT_BODY_IDLE_TIMEOUT": str(BODY_IDLE_TIMEOUT),
                "DACRT_BODY_TIMEOUT": str(BODY_TIMEOUT),
                "DACRT_MAX_CONNECTIONS": str(STALLED_BODIES),
                "DACRT_MAX_CONNECTIONS_PER_CLIENT": str(2 * STALLED_BODIES),
            }
        ),
        "bounds": ServerProcess(
            {
                "DACRT_MAX_CONNECTIONS": str(MAX_CONNECTIONS),
                "DACRT_MAX_CONNECTIONS_PER_CLIENT": str(MAX_PER_CLIENT),
            }
        ),
        "budget": ServerProcess({"DACRT_MAX_INFLIGHT_BYTES": str(BUDGET)}),
    }
    try:
        for process in processes.values():  # they warm up side by side
            process.wait_ready()
        yield processes
    finally:
        for process in processes.values():
            process.stop()


@pytest.fixture(scope="module")
def process(servers) -> ServerProcess:
    return servers["stalls"]


@pytest.fixture
def server(process) -> str:
    return process.url


@pytest.fixture
def bounded(servers) -> str:
    return servers["bounds"].url


@dataclass
class Stall:
    """What a stalling client sends at once, then one byte at a time, and the deadline (seconds
    from the connection) that its setting makes."""

    sends: bytes
    trickles: bytes
    deadline: float
    setting: str


HEAD = b"POST /v1/trace HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/x-npz\r\n"
GET_HEALTH = b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
HEADERS = "DACRT_HEADER_TIMEOUT"
STALLS = {
    "nothing": Stall(b"", b"", HEADER_TIMEOUT, HEADERS),
    "partial headers": Stall(HEAD, b"", HEADER_TIMEOUT, HEADERS),
    "trickled headers": Stall(b"", HEAD * 10, HEADER_TIMEOUT, HEADERS),
    "second request's partial headers": Stall(
        GET_HEALTH + b"GET /health HTTP/1.1\r\n", b"", HEADER_TIMEOUT, HEADERS
    ),
    "body shorter than its Content-Length": Stall(
        HEAD + b"Content-Length: 1000\r\n\r\nPK", b"", BODY_IDLE_TIMEOUT, "DACRT_BODY_IDLE_TIMEOUT"
    ),
    # bytes at 0, 0.3 and 0.6 s, then nothing: idle from the last byte
    "body that stalls after three bytes": Stall(
        HEAD + b"Content-Length: 1000\r\n\r\n",
        b"PK\x03",
        2 * TRICKLE_EVERY + BODY_IDLE_TIMEOUT,
        "DACRT_BODY_IDLE_TIMEOUT",
    ),
    "trickled body": Stall(
        HEAD + b"Content-Length: 1000\r\n\r\n", b"x" * 1000, BODY_TIMEOUT, "DACRT_BODY_TIMEOUT"
    ),
    "trickled body the app never reads": Stall(
        b"GET /health HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000\r\n\r\n",
        b"x" * 1000,
        BODY_TIMEOUT,
        "DACRT_BODY_TIMEOUT",
    ),
}


def stall(
    url: str, plan: Stall, sent: threading.Barrier | None = None
) -> tuple[float, bytes, bool]:
    """Play ``plan`` until the server closes the connection or GIVE_UP: (seconds the connection
    lived, bytes received, whether it was closed). ``sent`` is waited on once ``plan.sends`` is
    sent."""
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port))) as sock:
        start, received, trickled = time.monotonic(), b"", 0
        sock.sendall(plan.sends)
        if sent is not None:
            sent.wait()
        sock.settimeout(TRICKLE_EVERY)
        while time.monotonic() - start < GIVE_UP:
            try:
                if trickled < len(plan.trickles):
                    sock.sendall(plan.trickles[trickled : trickled + 1])
                    trickled += 1
                data = sock.recv(65536)
            except TimeoutError:
                continue
            except ConnectionError:  # closed while bytes of ours were unread: a reset
                return time.monotonic() - start, received, True
            if not data:
                return time.monotonic() - start, received, True
            received += data
        return time.monotonic() - start, received, False


def test_stalled_connections_are_closed_at_their_deadline(server, process):
    with ThreadPoolExecutor(len(STALLS)) as pool:
        outcomes = dict(zip(STALLS, pool.map(lambda plan: stall(server, plan), STALLS.values())))
    problems = [
        f"{name}: {problem}"
        for name, outcome in outcomes.items()
        if (problem := check_stall(STALLS[name], *outcome, answered=ANSWERED.get(name)))
    ]
    assert not problems, "\n".join(problems)
    assert httpx.get(f"{server}/health", timeout=5).status_code == 200
    assert "Traceback" not in process.output(last=10**6)  # cut-off bodies are no server errors


#: The stalls answered before their deadline (the rest get nothing or a 408 at it).
ANSWERED = {"trickled body the app never reads": b"200 "}


def check_stall(
    plan: Stall, seconds: float, received: bytes, closed: bool, answered: bytes | None
) -> str | None:
    """What is wrong with how the server treated a stalling client, or None."""
    if not closed:
        return f"still open after {seconds:.1f} s"
    if not plan.deadline - 0.1 <= seconds <= plan.deadline + MARGIN:
        return f"closed after {seconds:.2f} s, deadline {plan.deadline} s"
    answers = received.split(b"HTTP/1.1 ")[1:]
    if answered is not None:
        return None if answers and answers[0].startswith(answered) else f"answers {answers}"
    if not plan.sends and not plan.trickles:
        return None if received == b"" else f"answered {received!r} though nothing was asked"
    last = answers[-1] if answers else b""
    if not (
        last.startswith(b"408 ")
        and b"connection: close" in last.lower()
        and last.endswith(f'({plan.setting})"}}'.encode())
    ):
        return f"no 408 naming {plan.setting}: {received[-300:]!r}"
    return None


def requests_counted(url: str, route: str, status: int) -> float:
    text = httpx.get(f"{url}/metrics", timeout=5).text
    return metric_sample(
        text, f'dacrt_requests_total{{method="POST",route="{route}",status="{status}"}}'
    )


@pytest.mark.parametrize("name", ["body shorter than its Content-Length", "trickled body"])
def test_a_body_cut_off_is_counted_and_logged_as_the_408_sent(server, process, name):
    """The app sees a client gone, but the client was answered 408: /metrics counts a 408 (not
    a 499) and the log says what was answered."""
    before = {status: requests_counted(server, "/v1/trace", status) for status in (408, 499)}
    _, received, _ = stall(server, STALLS[name])
    assert received.startswith(b"HTTP/1.1 408 "), received[:200]
    deadline = time.monotonic() + WAIT  # the app's task ends a little after the answer
    while requests_counted(server, "/v1/trace", 408) == before[408]:
        assert time.monotonic() < deadline, "the 408 was never counted"
        time.sleep(0.1)
    assert requests_counted(server, "/v1/trace", 408) == before[408] + 1
    assert requests_counted(server, "/v1/trace", 499) == before[499]
    assert "POST /v1/trace answered 408: request body" in process.output(last=10**6)


def test_a_hundred_stalled_bodies_are_cut_off_while_health_answers(server, process):
    """The issue's attack: as many sockets as DACRT_MAX_CONNECTIONS send their headers
    (Content-Length: 1000) and one body byte. Each is closed with a 408 at the idle timeout, and
    /health and /metrics answer 200 throughout, while other requests find the server full."""
    plan = Stall(
        HEAD + b"Content-Length: 1000\r\n\r\nP", b"", BODY_IDLE_TIMEOUT, "DACRT_BODY_IDLE_TIMEOUT"
    )
    all_sent = threading.Barrier(STALLED_BODIES + 1)
    with ThreadPoolExecutor(STALLED_BODIES) as pool:
        stalls = [pool.submit(stall, server, plan, all_sent) for _ in range(STALLED_BODIES)]
        all_sent.wait(timeout=WAIT)
        probes, others = [], []
        while not all(s.done() for s in stalls):
            probes += [httpx.get(f"{server}{path}", timeout=5) for path in ("/health", "/metrics")]
            others.append(httpx.get(f"{server}/v1/scenes", timeout=5))
        outcomes = [s.result() for s in stalls]
    problems = {problem for outcome in outcomes if (problem := check_stall(plan, *outcome, None))}
    assert not problems, "\n".join(sorted(problems))
    assert probes and all(probe.status_code == 200 for probe in probes), [
        (probe.url.path, probe.status_code, probe.text[:200]) for probe in probes
    ]
    full = [other for other in others if other.status_code == 503]
    assert full and "DACRT_MAX_CONNECTIONS" in full[0].json()["detail"]
    assert "Traceback" not in process.output(last=10**6)


def client(address: str) -> httpx.Client:
    """An httpx client whose connections come from ``address`` (one of 127/8)."""
    # no keep-alive: a connection made before the bound was reached would stay under it
    transport = httpx.HTTPTransport(
        local_address=address, limits=httpx.Limits(max_keepalive_connections=0)
    )
    return httpx.Client(transport=transport, timeout=5)


@contextmanager
def idle_sockets(url: str, addresses: list[str]):
    """One open connection that sends nothing from each of ``addresses``, closed on exit."""
    host, port = url.removeprefix("http://").split(":")
    with ExitStack() as stack:
        for address in addresses:
            stack.enter_context(
                socket.create_connection((host, int(port)), source_address=(address, 0))
            )
        yield


def first(call: Callable[[], httpx.Response], wanted: int) -> httpx.Response:
    """Call until an answer has status ``wanted`` (the server sees sockets open and close a little
    later than the client); fail after WAIT seconds."""
    deadline = time.monotonic() + WAIT
    while True:
        response = call()
        if response.status_code == wanted or time.monotonic() > deadline:
            assert response.status_code == wanted, (response.status_code, response.text)
            return response


def test_connections_beyond_the_bound_get_503_but_health_and_metrics_answer(bounded):
    others = [f"127.0.0.{2 + i // MAX_PER_CLIENT}" for i in range(MAX_CONNECTIONS)]
    with client("127.0.0.1") as http:
        with idle_sockets(bounded, others):
            refused = first(lambda: http.get(f"{bounded}/v1/scenes"), 503)
            assert refused.headers["retry-after"] == "1"
            assert refused.headers["connection"] == "close"
            assert "(DACRT_MAX_CONNECTIONS)" in refused.json()["detail"]
            posted = http.post(f"{bounded}/v1/trace", content=b"{}", headers={"Accept": "*/*"})
            assert posted.status_code == 503
            for path in ("/health", "/metrics"):
                answer = http.get(f"{bounded}{path}")
                assert answer.status_code == 200, answer.text
                assert answer.headers["connection"] == "close"  # the reserve is not held
        first(lambda: http.get(f"{bounded}/v1/scenes"), 200)


def test_refusals_over_the_connection_bound_are_counted(bounded):
    """A 503 of a connection over a bound is counted under route "protocol"; the probes it
    still answers are counted under their routes."""

    def counted(method: str, route: str, status: int) -> float:
        text = httpx.get(f"{bounded}/metrics", timeout=5).text
        labels = f'method="{method}",route="{route}",status="{status}"'
        return metric_sample(text, f"dacrt_requests_total{{{labels}}}")

    refusals, probes = counted("GET", "protocol", 503), counted("HEAD", "/health", 200)
    with client("127.0.0.4") as crowded:
        with idle_sockets(bounded, ["127.0.0.4"] * MAX_PER_CLIENT):
            refused = first(lambda: crowded.get(f"{bounded}/v1/scenes"), 503)
            assert "DACRT_MAX_CONNECTIONS_PER_CLIENT" in refused.json()["detail"]
            assert crowded.head(f"{bounded}/health").status_code == 200
    assert counted("GET", "protocol", 503) > refusals  # ``first`` may have met one more
    assert counted("HEAD", "/health", 200) == probes + 1


def test_connections_per_client_address_are_bounded(bounded):
    with client("127.0.0.2") as crowded, client("127.0.0.3") as other:
        with idle_sockets(bounded, ["127.0.0.2"] * MAX_PER_CLIENT):
            refused = first(lambda: crowded.get(f"{bounded}/v1/scenes"), 503)
            detail = refused.json()["detail"]
            assert "127.0.0.2" in detail and "DACRT_MAX_CONNECTIONS_PER_CLIENT" in detail
            assert refused.headers["retry-after"] == "1"
            assert crowded.get(f"{bounded}/health").status_code == 200
            assert other.get(f"{bounded}/v1/scenes").status_code == 200
        first(lambda: crowded.get(f"{bounded}/v1/scenes"), 200)


def test_a_slow_body_holds_what_it_has_sent_not_its_declared_length(servers):
    """A client declares a JSON body whose estimate (17 x its length, for parsing) is nearly the
    whole budget, sends a few bytes of it and stalls: it keeps only those bytes and a step, and a
    one-ray lidar, which needs 16 MiB for its JSON answer, is served beside it."""
    url = servers["budget"].url
    ground = np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], np.float32)
    buffer = io.BytesIO()
    np.savez(buffer, vertices=ground, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32))
    put = httpx.put(
        f"{url}/v1/scenes/slow/meshes/ground",
        content=buffer.getvalue(),
        headers={"content-type": "application/x-npz"},
    )
    assert put.status_code in (200, 201), put.text
    declared, sent = int(3.5 * MiB), b'{"sensors": {'  # its estimate: 59.5 MiB of the 64
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port))) as slow:
        slow.sendall(
            b"POST /v1/scenes/slow/sensors HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            b"Content-Type: application/json\r\n"
            + f"Content-Length: {declared}\r\n\r\n".encode()
            + sent
        )
        deadline = time.monotonic() + WAIT
        while inflight(url) == 0:  # until the server has the slow request
            assert time.monotonic() < deadline, "the slow request never arrived"
            time.sleep(0.05)
        pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.5], [0, 0, 0, 1]]
        lidar = {"pose": pose, "vertical_angles_deg": [-10.0], "horizontal_steps": 1}
        answer = httpx.post(f"{url}/v1/scenes/slow/lidar", json=lidar, timeout=30)
        assert answer.status_code == 200, answer.text
        # 0.5 above the ground, 10 degrees down: the ground is 0.5 / sin(10 deg) away
        assert np.allclose(answer.json()["range"], [0.5 / np.sin(np.radians(10))], rtol=1e-5)
        held = inflight(url)  # the slow body's alone, still in flight
        assert BODY_STEP <= held <= len(sent) + BODY_STEP, f"{held / MiB:.1f} MiB held"


def inflight(url: str) -> float:
    """Bytes the requests in flight hold (/metrics)."""
    return metric_sample(httpx.get(f"{url}/metrics", timeout=5).text, "dacrt_inflight_bytes")
