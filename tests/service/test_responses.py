"""BuffersResponse sends its parts in order, and makes each on a worker thread: a large answer
made as it is sent (a JSON answer's pieces, an npz's CRCs) does not hold the event loop, which
serves every other request."""

from __future__ import annotations

import threading

import anyio

from service.responses import BuffersResponse


def test_parts_are_made_off_the_event_loop_and_sent_in_order():
    made_on = []

    def parts():
        for k in range(5):
            made_on.append(threading.get_ident())
            yield b"" if k == 2 else f"part{k};".encode()

    sent = []

    async def send(message):
        sent.append(message)

    async def run():
        loop_thread = threading.get_ident()
        response = BuffersResponse(parts(), None, "application/json", {})
        await response({"type": "http"}, None, send)
        return loop_thread

    loop_thread = anyio.run(run)
    assert len(made_on) == 5 and loop_thread not in made_on
    assert sent[0]["type"] == "http.response.start" and sent[0]["status"] == 200
    bodies = [message["body"] for message in sent[1:]]
    assert bodies == [b"part0;", b"part1;", b"part3;", b"part4;", b""]  # the empty part skipped
    assert [message.get("more_body", False) for message in sent[1:]] == [True] * 4 + [False]
