"""Slow and stalled clients are cut off, and connections beyond the bound are refused.

A server of its own with short deadlines (DACRT_HEADER_TIMEOUT, DACRT_BODY_TIMEOUT) and a small
DACRT_MAX_CONNECTIONS; raw sockets play the stalling clients, all at once.
"""

from __future__ import annotations

import socket
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import httpx
import pytest
from server_process import ServerProcess

HEADER_TIMEOUT, BODY_TIMEOUT, MAX_CONNECTIONS = 1.0, 2.0, 8
MARGIN = 1.0  # seconds a cut-off may come after its deadline on a busy machine
GIVE_UP = 6.0  # a client still connected after this long was never cut off
TRICKLE_EVERY = 0.3  # seconds between the bytes of a trickling client


@pytest.fixture(scope="module")
def process():
    process = ServerProcess(
        {
            "DACRT_HEADER_TIMEOUT": str(HEADER_TIMEOUT),
            "DACRT_BODY_TIMEOUT": str(BODY_TIMEOUT),
            "DACRT_MAX_CONNECTIONS": str(MAX_CONNECTIONS),
        }
    )
    try:
        process.wait_ready()
        yield process
    finally:
        process.stop()


@pytest.fixture
def server(process) -> str:
    return process.url


@dataclass
class Stall:
    """What a stalling client sends at once, then one byte at a time, and its deadline."""

    sends: bytes
    trickles: bytes
    deadline: float


HEAD = b"POST /v1/trace HTTP/1.1\r\nHost: test\r\nContent-Type: application/x-npz\r\n"
GET_HEALTH = b"GET /health HTTP/1.1\r\nHost: test\r\n\r\n"
STALLS = {
    "nothing": Stall(b"", b"", HEADER_TIMEOUT),
    "partial headers": Stall(HEAD, b"", HEADER_TIMEOUT),
    "trickled headers": Stall(b"", HEAD * 10, HEADER_TIMEOUT),
    "second request's partial headers": Stall(
        GET_HEALTH + b"GET /health HTTP/1.1\r\n", b"", HEADER_TIMEOUT
    ),
    "body shorter than its Content-Length": Stall(
        HEAD + b"Content-Length: 1000\r\n\r\nPK", b"", BODY_TIMEOUT
    ),
    "trickled body": Stall(HEAD + b"Content-Length: 1000\r\n\r\n", b"x" * 1000, BODY_TIMEOUT),
    "trickled body the app never reads": Stall(
        b"GET /health HTTP/1.1\r\nHost: test\r\nContent-Length: 1000\r\n\r\n",
        b"x" * 1000,
        BODY_TIMEOUT,
    ),
}


def stall(url: str, plan: Stall) -> tuple[float, bytes, bool]:
    """Play ``plan`` until the server closes the connection or GIVE_UP: (seconds the connection
    lived, bytes received, whether it was closed)."""
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port))) as sock:
        start, received, sent = time.monotonic(), b"", 0
        sock.sendall(plan.sends)
        sock.settimeout(TRICKLE_EVERY)
        while time.monotonic() - start < GIVE_UP:
            try:
                if sent < len(plan.trickles):
                    sock.sendall(plan.trickles[sent : sent + 1])
                    sent += 1
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
    setting = "DACRT_BODY_TIMEOUT" if plan.deadline == BODY_TIMEOUT else "DACRT_HEADER_TIMEOUT"
    last = answers[-1] if answers else b""
    if not (
        last.startswith(b"408 ")
        and b"connection: close" in last.lower()
        and last.endswith(f'({setting})"}}'.encode())
    ):
        return f"no 408 naming {setting}: {received[-300:]!r}"
    return None


def test_connections_beyond_the_bound_are_refused_with_503(server):
    host, port = server.removeprefix("http://").split(":")
    idle = [socket.create_connection((host, int(port))) for _ in range(MAX_CONNECTIONS)]
    try:
        time.sleep(0.2)  # let the server accept them all
        refused = httpx.get(f"{server}/health", timeout=5)
    finally:
        for sock in idle:
            sock.close()
    assert refused.status_code == 503 and refused.headers["retry-after"] == "1"
    assert refused.headers["connection"] == "close"
    assert "DACRT_MAX_CONNECTIONS" in refused.json()["detail"]
    time.sleep(0.2)  # let the server see them closed
    assert httpx.get(f"{server}/health", timeout=5).status_code == 200
