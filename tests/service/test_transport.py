"""The client's httpx transport on urllib3 (service/transport.py): connection reuse, stale
keep-alive connections, chunked uploads, errors as httpx exceptions, threads sharing one client.
Against the real uvicorn server, and against tiny socket servers for what uvicorn will not do
on demand (close an idle connection, never answer)."""

from __future__ import annotations

import socket
import threading
from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np
import pytest
from service_helpers import TOKEN, down_rays, grid, quad

from service import wire
from service.client import APIError, Client
from service.transport import PooledTransport


def joined(parts) -> bytes:
    return b"".join(bytes(memoryview(part).cast("B")) for part in parts)


def idle_connections(client: Client) -> list:
    transport = client.http._transport
    assert isinstance(transport, PooledTransport)
    pools = [transport.pool.pools[key] for key in transport.pool.pools.keys()]
    return [c for pool in pools for c in list(pool.pool.queue) if c is not None and c.sock]


def test_one_connection_carries_consecutive_requests(client, scene_name):
    client.put_mesh(scene_name, "quad", *quad(0, 1, 0, 1, 9))
    [connection] = idle_connections(client)
    sock = connection.sock
    for _ in range(3):
        answer = client.closest(scene_name, *down_rays([[0.25, 0.25]]))
        assert answer.t[0] == pytest.approx(1.0)
    [connection] = idle_connections(client)
    assert connection.sock is sock


def test_big_answer_is_read_whole_and_the_connection_reused(client, scene_name):
    vertices, faces = grid(8, z=9.0)
    client.put_mesh(scene_name, "grid", vertices, faces)
    rng = np.random.default_rng(3)
    xy = rng.uniform(0.01, 0.99, (300_000, 2))  # a 36 MB answer with every field
    answer = client.closest(scene_name, *down_rays(xy))
    assert answer.t.shape == (300_000,) and np.all(answer.t == np.float32(1.0))
    assert np.all(answer.normal[:, 2] == np.float32(1.0))
    assert len(idle_connections(client)) == 1


def test_a_chunked_upload_arrives_whole(client, scene_name):
    vertices, faces = grid(3)
    body = joined(wire.npz_parts({"vertices": vertices, "faces": faces}))
    pieces = (
        body[i : i + 100] for i in range(0, len(body), 100)
    )  # no length: Transfer-Encoding: chunked
    response = client.http.put(
        f"/v1/scenes/{scene_name}/meshes/grid", content=pieces, headers={"Content-Type": wire.NPZ}
    )
    assert response.status_code == 201, response.text
    assert response.json()["triangles"] == len(faces)


def test_a_response_left_unread_closes_its_connection(client, scene_name):
    client.put_mesh(scene_name, "quad", *quad(0, 1, 0, 1, 9))
    rays = np.hstack(down_rays(np.full((100_000, 2), 0.25))).astype(np.float32)
    with client.http.stream(
        "POST",
        f"/v1/scenes/{scene_name}/closest",
        content=joined(wire.npy_parts({"rays": rays})),
        headers={"Content-Type": wire.NPY},
    ) as response:
        next(response.iter_bytes())  # the first piece only
    assert idle_connections(client) == []
    assert client.closest(scene_name, *down_rays([[0.25, 0.25]])).t[0] == pytest.approx(1.0)


def test_threads_share_one_client(client, scene_name):
    vertices, faces = grid(4, z=9.0)
    client.put_mesh(scene_name, "grid", vertices, faces)
    xy = np.random.default_rng(5).uniform(0.01, 0.99, (20_000, 2))
    expected = client.closest(scene_name, *down_rays(xy))

    def query(_):
        answer = client.closest(scene_name, *down_rays(xy))
        return all(np.array_equal(answer[key], expected[key]) for key in expected)

    with ThreadPoolExecutor(4) as pool:
        assert all(pool.map(query, range(16)))
    assert 1 <= len(idle_connections(client)) <= 4


class OneShotServer:
    """A socket server that answers each connection's first request with ``reply`` (then keeps
    or closes the connection), or never answers when ``reply`` is None."""

    def __init__(self, reply: bytes | None, close_after: bool) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.listener.getsockname()[1]}"
        self.reply, self.close_after = reply, close_after
        self.connections = 0
        self.open: list[socket.socket] = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                connection, _ = self.listener.accept()
            except OSError:
                return
            self.connections += 1
            self.open.append(connection)
            data = b""
            while b"\r\n\r\n" not in data:
                chunk = connection.recv(65536)
                if not chunk:
                    break
                data += chunk
            if self.reply is not None:
                connection.sendall(self.reply)
                if self.close_after:
                    connection.close()

    def client(self, timeout: float) -> httpx.Client:
        return httpx.Client(base_url=self.url, transport=PooledTransport(), timeout=timeout)

    def __enter__(self) -> OneShotServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.listener.close()
        for connection in self.open:
            connection.close()


KEEP_ALIVE_REPLY = (
    b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\nContent-Type: application/json\r\n\r\n{}"
)


def test_a_connection_the_server_closed_while_idle_is_not_reused():
    # The server answers with keep-alive, then closes: the next request needs a new connection.
    with OneShotServer(KEEP_ALIVE_REPLY, close_after=True) as server, server.client(10) as http:
        for _ in range(3):
            assert http.get("/").json() == {}
            threading.Event().wait(0.05)  # let the close arrive
        assert server.connections == 3


def test_a_server_that_never_answers_is_a_read_timeout():
    with (
        OneShotServer(None, close_after=False) as server,
        server.client(0.3) as http,
        pytest.raises(httpx.ReadTimeout),
    ):
        http.get("/")


def test_a_closed_port_is_a_connect_error():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # nothing listens once the probe is closed
    with (
        httpx.Client(transport=PooledTransport(), timeout=5) as http,
        pytest.raises(httpx.ConnectError),
    ):
        http.get(f"http://127.0.0.1:{port}/")


def test_a_cut_answer_is_a_protocol_error():
    cut = b"HTTP/1.1 200 OK\r\nContent-Length: 100\r\n\r\nonly this"
    with (
        OneShotServer(cut, close_after=True) as server,
        server.client(5) as http,
        pytest.raises(httpx.RemoteProtocolError),
    ):
        http.get("/")


def test_a_413_before_a_big_body_is_read_reaches_the_client(secure_server, scene_name):
    # The server refuses by Content-Length before reading 9.6 MB of rays.
    with Client(secure_server, token=TOKEN) as client:
        client.put_mesh(scene_name, "quad", *quad(0, 1, 0, 1, 9))
        with pytest.raises(APIError) as caught:
            client.closest(scene_name, np.zeros((400_000, 6), np.float32))
        assert caught.value.status == 413 and "DACRT_MAX_BODY_BYTES" in caught.value.detail
        assert client.closest(scene_name, *down_rays([[0.25, 0.25]])).t[0] == pytest.approx(1.0)
