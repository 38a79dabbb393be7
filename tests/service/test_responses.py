"""BuffersResponse sends its parts in order, and makes each on a worker thread: a large answer
made as it is sent (a JSON answer's pieces, an npz's CRCs) does not hold the event loop, which
serves every other request. Small parts go out joined, in few writes; large ones as they are."""

from __future__ import annotations

import threading

import anyio
import numpy as np

from service.responses import WRITE_BYTES, BuffersResponse


def sent_bodies(parts, sent_on: list | None = None) -> list:
    """The bodies of the messages a BuffersResponse of ``parts`` sends after its start; the
    thread of each send is added to ``sent_on``."""
    sent = []

    async def send(message):
        sent.append(message)
        if sent_on is not None:
            sent_on.append(threading.get_ident())

    async def run():
        response = BuffersResponse(parts, None, "application/json", {})
        await response({"type": "http"}, None, send)

    anyio.run(run)
    assert sent[0]["type"] == "http.response.start" and sent[0]["status"] == 200
    more = [message.get("more_body", False) for message in sent[1:]]
    assert more == [True] * (len(sent) - 2) + [False]  # the last, and only the last, ends it
    return [message["body"] for message in sent[1:]]


def test_parts_are_made_off_the_event_loop_and_sent_in_order():
    made_on, sent_on = [], []

    def parts():
        for k in range(5):
            made_on.append(threading.get_ident())
            yield b"" if k == 2 else f"part{k};".encode()

    bodies = sent_bodies(parts(), sent_on)
    assert len(made_on) == 5 and not set(sent_on) & set(made_on)
    assert bodies == [b"part0;part1;part3;part4;", b""]  # the empty part adds nothing


def test_many_small_parts_are_sent_in_few_writes():
    """A rig's JSON answer: tens of thousands of parts of a few bytes each."""
    rng = np.random.default_rng(3)
    parts = [bytes(rng.integers(0, 256, rng.integers(0, 20), np.uint8)) for _ in range(50_000)]
    expected = b"".join(parts)
    bodies = sent_bodies(iter(parts))
    assert b"".join(bodies) == expected
    assert len(bodies) <= len(expected) // WRITE_BYTES + 2, f"{len(bodies)} writes"
    assert all(len(body) >= WRITE_BYTES for body in bodies[:-2])  # each write full but the last


def test_a_large_part_is_sent_as_it_is_after_the_small_ones_before_it():
    """An answer array's memory is written without a copy; the headers around it are joined."""
    array = np.arange(WRITE_BYTES, dtype=np.float32)
    data = memoryview(array).cast("B")
    parts = [b"head", b"er", data, b"tail", b"", b"end"]
    bodies = sent_bodies(iter(parts))
    assert bodies[0] == b"header" and bodies[1] is data and bodies[2:] == [b"tailend", b""]
    assert b"".join(bytes(body) for body in bodies) == b"".join(bytes(part) for part in parts)
