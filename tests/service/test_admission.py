"""Admission: the requests in flight hold at most DACRT_MAX_INFLIGHT_BYTES at their peak.

The budget itself (``service.admission``) in process: who waits, in what order, who is refused.
Then a real server with a small budget: concurrent requests of the largest legal size all answer,
none a 5xx, and the server's peak RSS stays under its idle RSS + the budget + MARGIN; the same
requests on a server with no effective budget go past it (what the budget prevents).
"""

from __future__ import annotations

import asyncio
import io
import json
import threading
import tracemalloc
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import hostile_bodies
import httpx
import in_process
import numpy as np
import pytest
from server_process import ServerProcess
from service_helpers import grid

from service import admission as admission_module
from service import footprint
from service.admission import Admission
from service.errors import Overloaded, TooLarge
from service.settings import Settings

MiB = 2**20
NPY = "application/x-npy"
JSON = {"content-type": "application/json"}

# ---- the budget


def run(coroutine):
    return asyncio.run(coroutine)


def test_tickets_within_the_budget_are_admitted_at_once():
    async def scenario():
        admission = Admission(100, wait=0)
        first, second = admission.ticket(), admission.ticket()
        await first.hold(60, "first")
        await second.hold(40, "second")
        assert admission.held == 100
        await first.hold(10, "first, less")  # giving back never waits
        assert admission.held == 50
        first.release()
        second.release()
        assert admission.held == 0

    run(scenario())


@pytest.mark.parametrize(
    "first_bytes, wanted, first_keeps, held", [(80, 50, 0, 50), (90, 20, 80, 100)]
)
def test_a_waiting_ticket_is_admitted_once_it_fits(first_bytes, wanted, first_keeps, held):
    """It waits until the holder releases its bytes, or gives back just enough that the waiting
    ticket fills the budget exactly."""

    async def scenario():
        admission = Admission(100, wait=5)
        first, second = admission.ticket(), admission.ticket()
        await first.hold(first_bytes, "first")
        waiting = asyncio.create_task(second.hold(wanted, "second"))
        await asyncio.sleep(0)
        assert not waiting.done() and admission.held == first_bytes
        if first_keeps:
            await first.hold(first_keeps, "first, less")
        else:
            first.release()
        await asyncio.wait_for(waiting, 5)
        assert admission.held == held

    run(scenario())


def test_waiting_tickets_are_admitted_in_arrival_order():
    """A small request does not pass a large one waiting before it (no starvation)."""

    async def scenario():
        admission = Admission(100, wait=5)
        holder, large, small = admission.ticket(), admission.ticket(), admission.ticket()
        order = []
        await holder.hold(90, "holder")

        async def hold(ticket, nbytes, name):
            await ticket.hold(nbytes, name)
            order.append(name)

        tasks = [asyncio.create_task(hold(large, 80, "large"))]
        await asyncio.sleep(0)
        tasks.append(asyncio.create_task(hold(small, 5, "small")))
        await asyncio.sleep(0)
        assert order == []  # small would fit (95 <= 100), but large came first
        holder.release()
        await asyncio.wait_for(asyncio.gather(*tasks), 5)
        assert order == ["large", "small"] and admission.held == 85

    run(scenario())


def test_a_small_ticket_that_fits_goes_ahead_of_a_large_one_waiting():
    """1 MiB at most, and 1/64 of the budget: a cheap query is not held up behind heavy ones."""

    async def scenario():
        admission = Admission(256 * MiB, wait=5)
        holder, large, small = admission.ticket(), admission.ticket(), admission.ticket()
        await holder.hold(200 * MiB, "holder")
        waiting = asyncio.create_task(large.hold(100 * MiB, "large"))
        await asyncio.sleep(0)
        await asyncio.wait_for(small.hold(3000, "one ray"), 1)  # at once, though large waits
        assert not waiting.done() and admission.held == 200 * MiB + 3000
        with pytest.raises(TimeoutError):  # 2 MiB is not small: it waits in line, behind large
            await asyncio.wait_for(admission.ticket().hold(2 * MiB, "two MiB"), 0.05)
        holder.release()
        await asyncio.wait_for(waiting, 5)
        assert admission.held == 100 * MiB + 3000

    run(scenario())


def test_a_ticket_that_holds_bytes_and_needs_more_goes_first_in_line():
    """A request admitted at its body's estimate that needs more once its body is decoded does
    not wait behind those waiting for what it holds (they would wait for each other until the
    wait ran out): it grows at once where it fits, else first in line."""

    async def scenario():
        admission = Admission(100, wait=5)
        grower, other, waiter = admission.ticket(), admission.ticket(), admission.ticket()
        await grower.hold(70, "grower")
        await other.hold(15, "other")
        waiting = asyncio.create_task(waiter.hold(60, "waiter"))
        await asyncio.sleep(0)
        await asyncio.wait_for(grower.hold(80, "grower, decoded"), 1)  # fits: at once
        growing = asyncio.create_task(grower.hold(90, "grower, more"))  # 105: waits, first
        await asyncio.sleep(0)
        assert not growing.done() and not waiting.done()
        other.release()
        await asyncio.wait_for(growing, 1)
        assert not waiting.done() and admission.held == 90
        grower.release()
        await asyncio.wait_for(waiting, 1)
        assert admission.held == 60

    run(scenario())


def test_requests_that_grow_keep_their_turn():
    """Sensors hold their small body, then their rays' peak once it is known. One admitted in
    its turn goes ahead of a query not yet admitted; one that went ahead as small waits behind
    that query, so a stream of sensors keeps arrival order and starves no one."""

    async def scenario():
        admission = Admission(100, wait=5)
        order = []
        a, b, query, c = (admission.ticket() for _ in range(4))

        async def hold(ticket, name, *amounts):
            for nbytes in amounts:
                await ticket.hold(nbytes, name)
            order.append(name)

        await hold(a, "a", 1, 60)  # the line is empty: in turn
        b_grows = asyncio.create_task(hold(b, "b", 1, 60))  # in turn, then waits ahead
        await asyncio.sleep(0)
        query_waits = asyncio.create_task(hold(query, "query", 60))
        await asyncio.sleep(0)
        c_grows = asyncio.create_task(hold(c, "c", 1, 60))  # small: goes ahead, then waits
        await asyncio.sleep(0)
        assert order == ["a"] and c.nbytes == 1 and admission.held == 62
        for ticket, task in ((a, b_grows), (b, query_waits), (query, c_grows)):
            ticket.release()
            await asyncio.wait_for(task, 1)
        assert order == ["a", "b", "query", "c"]

    run(scenario())


def test_requests_that_wait_for_each_others_bytes_are_not_left_to_their_deadline():
    """Two admitted requests that each need more than the other leaves wait for each other:
    a request behind them that fits goes, then the one holding most is refused at once, not
    after DACRT_ADMISSION_WAIT, and the other goes as soon as its bytes are freed."""

    async def scenario():
        admission = Admission(100, wait=30)
        refusals = []
        admission.on_refused = lambda: refusals.append(1)
        first, second, newcomer = admission.ticket(), admission.ticket(), admission.ticket()
        await first.hold(50, "first")
        await second.hold(40, "second")
        first_grows = asyncio.create_task(first.hold(70, "first, decoded"))
        joining = asyncio.create_task(newcomer.hold(5, "newcomer"))  # 95 of 100: fits
        await asyncio.sleep(0)
        assert not first_grows.done() and not joining.done()  # the second runs: it frees
        second_grows = asyncio.create_task(second.hold(60, "second, decoded"))
        await asyncio.wait_for(joining, 1)  # the line is stuck: what fits goes
        assert admission.held == 95 and not first_grows.done() and not second_grows.done()
        newcomer.release()
        done, _ = await asyncio.wait(
            [first_grows, second_grows], timeout=1, return_when="FIRST_COMPLETED"
        )
        assert done == {first_grows} and refusals == [1]
        with pytest.raises(Overloaded, match="first, decoded"):
            first_grows.result()
        first.release()  # the refused request ends
        await asyncio.wait_for(second_grows, 1)
        assert admission.held == 60 and second.nbytes == 60

    run(scenario())


def test_a_request_waits_at_most_the_wait_in_all_however_many_times_it_asks():
    """One deadline a request, set when it first waits: a later hold does not wait afresh."""

    async def scenario():
        admission = Admission(100, wait=0.1)
        holder, ticket = admission.ticket(), admission.ticket()
        await holder.hold(90, "holder")
        await ticket.hold(10, "its body")  # fits: no wait, no deadline
        assert ticket.deadline is None
        with pytest.raises(Overloaded):
            await ticket.hold(20, "its answer")
        deadline = ticket.deadline
        assert deadline is not None and deadline <= asyncio.get_running_loop().time()
        with pytest.raises(Overloaded):  # its wait is spent: refused without a new one
            await ticket.hold(30, "its answer, again")
        assert ticket.deadline == deadline and ticket.nbytes == 10

    run(scenario())


def test_a_ticket_that_waits_too_long_is_refused_and_holds_nothing():
    async def scenario():
        admission = Admission(100, wait=0.05)
        refusals = []
        admission.on_refused = lambda: refusals.append(1)
        first, second = admission.ticket(), admission.ticket()
        await first.hold(70, "first")
        with pytest.raises(Overloaded, match="DACRT_MAX_INFLIGHT_BYTES") as refused:
            await second.hold(50, "POST /v1/scenes/s/closest of 9 rays")
        assert "POST /v1/scenes/s/closest of 9 rays" in refused.value.detail
        assert refused.value.headers["Retry-After"]
        assert admission.held == 70 and second.nbytes == 0 and refusals == [1]
        first.release()
        await second.hold(50, "again")  # the line is empty again
        assert admission.held == 50

    run(scenario())


def test_a_ticket_over_the_whole_budget_is_413():
    async def scenario():
        admission = Admission(100, wait=5)
        with pytest.raises(TooLarge, match=r"over the budget .*\(DACRT_MAX_INFLIGHT_BYTES\)"):
            await admission.ticket().hold(101, "a body of 101 bytes")
        assert admission.held == 0

    run(scenario())


def test_amounts_below_a_mib_are_given_in_kib_or_bytes():
    async def scenario():
        admission = Admission(1000, wait=5)
        with pytest.raises(TooLarge) as refused:
            await admission.ticket().hold(2048, "a body of 100 bytes")
        assert "about 2.0 KiB of server memory, over the budget of 1000 bytes" in str(refused.value)

    run(scenario())


# ---- the smallest budget DACRT_MAX_INFLIGHT_BYTES takes, in process


@pytest.fixture(scope="module")
def smallest_budget_app():
    budget = footprint.MIN_BUDGET_BYTES
    settings = Settings(token=None, load_demo=False, max_inflight_bytes=budget)
    with in_process.serve(settings) as client:
        wall = {"vertices": [[5, -5, -5], [5, 5, -5], [5, 0, 5]], "faces": [[0, 1, 2]]}
        client.put("/v1/scenes/s/meshes/wall", json=wall).raise_for_status()
        yield client


@pytest.mark.parametrize(
    "query, body",
    [
        ("closest", {"origins": [[0, 0, 0]], "directions": [[1, 0, 0]]}),
        ("occluded", {"origins": [[0, 0, 0]], "directions": [[1, 0, 0]]}),
        ("hits", {"origins": [[0, 0, 0]], "directions": [[1, 0, 0]]}),
        ("count", {"origins": [[0, 0, 0]], "directions": [[1, 0, 0]]}),
        ("nearest?sign=true&nsamples=5", {"points": [[0, 0, 0]]}),
    ],
)
def test_the_smallest_budget_serves_a_one_ray_query_answered_in_json(
    smallest_budget_app, query, body
):
    answer = smallest_budget_app.post(f"/v1/scenes/s/{query}", json=body, headers=JSON)
    assert answer.status_code == 200, answer.text
    assert answer.headers["content-type"].startswith("application/json")


# ---- a compressed .npz in process: held at what it inflates to before it is inflated


@pytest.fixture(scope="module")
def small_budget_app():
    settings = Settings(token=None, load_demo=False, max_inflight_bytes=64 * MiB)
    with in_process.serve(settings) as client:
        yield client


@pytest.mark.parametrize(
    "method, path",
    [("POST", "/v1/trace"), ("PUT", "/v1/scenes/npz/meshes/m"), ("POST", "/v1/scenes/npz/frame")],
)
def test_a_compressed_npz_is_held_at_what_it_inflates_to_before_inflating(
    small_budget_app, method, path
):
    """An .npz of about 100 KiB whose member inflates to 100 MiB, on a budget of 64 MiB: 413
    naming the budget, without inflating it."""
    body = hostile_bodies.honest_big_zip(100 * MiB)
    assert len(body) < MiB
    tracemalloc.start()
    try:
        answer = small_budget_app.request(
            method, path, content=body, headers={"content-type": "application/x-npz"}
        )
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert answer.status_code == 413, answer.text
    assert "DACRT_MAX_INFLIGHT_BYTES" in answer.json()["detail"]
    assert peak < 16 * MiB, f"{peak / MiB:.0f} MiB allocated"


#: JSON dense in lists, objects and keys, the most its text's factor undercounts (33 x its
#: bytes against 17 x), and the plain ray bodies clients send.
DENSE_JSON = ["[{}]", '{"":{}}', "[[[[]]]]", '{"":0}', "[]", '"ab"', "1e1"]
PLAIN_JSON = ["[0.5,-1.25,3]", "[12.345678,-0.000123,98765.4321]"]


@pytest.mark.parametrize("item", DENSE_JSON + PLAIN_JSON)
def test_a_json_body_parses_within_what_is_held_for_it(item):
    """``decode_bytes`` and ``structure_bytes`` together bound the parse's peak (tracemalloc)
    for bodies of every shape; a plain body of rays adds nothing to ``decode_bytes``."""
    from service.wire.decoders import parse_json

    body = ('{"origins":[' + ",".join([item] * 200_000) + "]}").encode()
    held = footprint.decode_bytes(len(body), "json") + footprint.structure_bytes(body, "json")
    tracemalloc.start()
    try:
        parse_json(body, "body")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < held, f"{item}: {peak / len(body):.1f} x the body, held {held / len(body):.1f}"
    if item in PLAIN_JSON:
        assert footprint.structure_bytes(body, "json") == 0


@pytest.mark.parametrize(
    "method, path",
    [
        ("POST", "/v1/trace"),
        ("PUT", "/v1/scenes/dense/meshes/m"),
        ("POST", "/v1/scenes/dense/frame"),
    ],
)
def test_a_json_body_dense_in_containers_is_held_at_its_parse_before_parsing(
    small_budget_app, method, path
):
    """2.5 MB of ``[{}]`` rows (17 x its bytes fit the 64 MiB budget, its parse does not):
    413 naming the budget, without parsing it."""
    body = ('{"origins":[' + ",".join(["[{}]"] * 500_000) + "]}").encode()
    assert footprint.decode_bytes(len(body), "json") < 64 * MiB
    tracemalloc.start()
    try:
        answer = small_budget_app.request(method, path, content=body, headers=JSON)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert answer.status_code == 413, answer.text
    assert "DACRT_MAX_INFLIGHT_BYTES" in answer.json()["detail"]
    assert peak < 16 * MiB, f"{peak / MiB:.0f} MiB allocated"


def test_a_frame_of_the_most_meshes_and_its_scene_list_are_held_at_their_peak(small_budget_app):
    """A JSON frame of DACRT_MAX_MESHES_PER_SCENE instances, then the scene's info: each
    allocates less than it holds; one mesh more is 413 naming the setting, and changes nothing."""
    most = Settings().max_meshes_per_scene
    doc = {"src.vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "src.faces": [[0, 1, 2]]}
    doc.update({f"i{i}.instance_of": "src" for i in range(most - 1)})
    body = json.dumps(doc, separators=(",", ":")).encode()
    for method, path, content, held in [
        ("POST", "/v1/scenes/many/frame", body, footprint.frame_bytes(len(body), "json", 0, most)),
        ("GET", "/v1/scenes", None, footprint.scene_info_bytes(most)),
    ]:
        tracemalloc.start()
        try:
            answer = small_budget_app.request(method, path, content=content, headers=JSON)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert answer.status_code == 200, answer.text
        assert peak < held, f"{method} {path}: {peak / MiB:.1f} MiB, held {held / MiB:.1f} MiB"
    assert len(answer.json()["scenes"][0]["meshes"]) == most
    more = json.dumps({"one.instance_of": "src"}).encode()
    refused = small_budget_app.post("/v1/scenes/many/frame", content=more, headers=JSON)
    assert refused.status_code == 413
    assert f"over the limit of {most} (DACRT_MAX_MESHES_PER_SCENE" in refused.json()["detail"]
    scene = small_budget_app.get("/v1/scenes/many").json()
    assert len(scene["meshes"]) == most and scene["version"] == 1


# ---- a real server

#: Largest legal request of the servers below: DACRT_MAX_RAYS_PER_REQUEST rays.
MAX_RAYS = 1 << 21
BUDGET = 320 * MiB  # one such closest request (about 256 MiB estimated) at a time
CONCURRENT = 6
#: What the allocator and the event loop may hold beyond the budget at the peak (bytes a
#: finished request freed but the allocator keeps, a socket's buffers).
MARGIN = 160 * MiB
SCENE = Path(__file__).resolve().parents[3] / "shared" / "scenes" / "sibenik.npz"


def rss(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024
    raise KeyError(key)


def reset_peak(pid: int) -> None:
    """Start VmHWM again from the current RSS (Linux, /proc/PID/clear_refs)."""
    try:
        Path(f"/proc/{pid}/clear_refs").write_text("5")
    except OSError as error:
        pytest.skip(f"cannot reset the server's peak RSS: {error}")


def rays_body(n_rays: int = MAX_RAYS) -> bytes:
    """An .npy body of ``n_rays`` rays from the middle of Sibenik's nave: nearly all hit."""
    rng = np.random.default_rng(7)
    origins = np.zeros((n_rays, 3), np.float32)
    directions = rng.normal(size=(n_rays, 3)).astype(np.float32)
    buffer = io.BytesIO()
    np.save(buffer, np.hstack([origins, directions]))
    return buffer.getvalue()


def server_with(budget: int, wait: float) -> ServerProcess:
    return ServerProcess(
        {
            "DACRT_MAX_RAYS_PER_REQUEST": str(MAX_RAYS),
            "DACRT_MAX_INFLIGHT_BYTES": str(budget),
            "DACRT_ADMISSION_WAIT": str(wait),
            "DACRT_THREADS": "2",
            "DACRT_LOAD_DEMO": "true",
            "DACRT_DEMO_SCENE": str(SCENE),
        }
    )


@pytest.fixture(scope="module")
def servers():
    if not SCENE.is_file():
        pytest.skip(f"needs {SCENE} (the shared folder beside the repository)")
    # one first: with a cold kernel cache it compiles, and the others then load what it filed
    processes = {"budget": server_with(BUDGET, wait=120)}
    try:
        processes["budget"].wait_ready()
        processes["refusing"] = server_with(BUDGET, wait=0)
        processes["unbounded"] = server_with(64 * 2**30, wait=0)
        for process in processes.values():
            process.wait_ready()
        yield processes
    finally:
        for process in processes.values():
            process.stop()


def concurrent_closest(server: ServerProcess, body: bytes) -> tuple[list[httpx.Response], int]:
    """CONCURRENT closest requests of ``body`` at once: their answers, and the server's peak RSS
    over its RSS before them."""
    url = f"{server.url}/v1/scenes/demo/closest"
    with httpx.Client(timeout=300) as client:  # one warm request: nothing lazy is left
        warm = client.post(url, content=rays_body(1024), headers={"content-type": NPY})
        assert warm.status_code == 200
    idle = rss(server.process.pid, "VmRSS")
    reset_peak(server.process.pid)

    def post(_):
        with httpx.Client(timeout=300) as client:
            return client.post(url, content=body, headers={"content-type": NPY})

    with ThreadPoolExecutor(CONCURRENT) as pool:
        answers = list(pool.map(post, range(CONCURRENT)))
    return answers, rss(server.process.pid, "VmHWM") - idle


def test_concurrent_largest_requests_stay_within_the_budget(servers):
    body = rays_body()
    answers, peak = concurrent_closest(servers["budget"], body)
    print(f"budget {BUDGET / MiB:.0f} MiB: peak RSS +{peak / MiB:.0f} MiB over idle")
    assert [a.status_code for a in answers] == [200] * CONCURRENT
    first = np.load(io.BytesIO(answers[0].content))
    assert len(first["t"]) == MAX_RAYS and np.isfinite(first["t"]).mean() > 0.99
    assert all(a.content == answers[0].content for a in answers)
    assert peak <= BUDGET + MARGIN, f"peak RSS +{peak / MiB:.0f} MiB over idle"


def test_without_the_budget_the_same_requests_go_past_it(servers):
    """What the budget prevents: the same load on a server whose budget admits everything."""
    answers, peak = concurrent_closest(servers["unbounded"], rays_body())
    print(f"no budget: peak RSS +{peak / MiB:.0f} MiB over idle")
    assert [a.status_code for a in answers] == [200] * CONCURRENT
    assert peak > BUDGET + MARGIN, f"peak RSS +{peak / MiB:.0f} MiB over idle"


def test_requests_beyond_the_budget_are_503_with_retry_after(servers):
    answers, peak = concurrent_closest(servers["refusing"], rays_body())
    statuses = sorted(a.status_code for a in answers)
    assert set(statuses) <= {200, 503} and statuses[0] == 200 and statuses[-1] == 503
    for refused in (a for a in answers if a.status_code == 503):
        assert refused.headers["retry-after"]
        assert "DACRT_MAX_INFLIGHT_BYTES" in refused.json()["detail"]
    assert peak <= BUDGET + MARGIN
    metrics = httpx.get(f"{servers['refusing'].url}/metrics").text
    refused = statuses.count(503)
    assert f"dacrt_admission_refused_total {float(refused)}" in metrics
    assert "dacrt_inflight_bytes 0.0" in metrics


#: A small budget that admits one request of HEAVY_RAYS rays at a time.
SMALL_BUDGET = 48 * MiB
HEAVY_RAYS = 200_000
#: What the allocator may keep beyond the budget once many threads have each served such a
#: request (one arena of freed heap a thread, uncapped, held 28-93 MiB more).
SMALL_MARGIN = 16 * MiB


def grid_mesh(n: int = 60) -> bytes:
    """An npz of a flat n x n grid of squares on z = 0 from -n/2 to n/2 (2 n**2 triangles)."""
    ticks = np.arange(n + 1, dtype=np.float32) - n / 2
    x, y = np.meshgrid(ticks, ticks, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size, np.float32)])
    corner = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    quads = np.column_stack([corner, corner + n + 1, corner + n + 2, corner + 1])
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]).astype(np.int32)
    buffer = io.BytesIO()
    np.savez(buffer, vertices=vertices.astype(np.float32), faces=faces)
    return buffer.getvalue()


def npy(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def test_many_threads_serving_heavy_requests_keep_rss_within_the_budget():
    """24 clients, 6 heavy requests each: every request thread that served one would keep its
    peak in its own allocator arena, and the server would hold several while the budget admits
    one. The server caps the arenas (service.allocator)."""
    server = ServerProcess(
        {"DACRT_MAX_INFLIGHT_BYTES": str(SMALL_BUDGET), "DACRT_ADMISSION_WAIT": "1"}
    )
    try:
        url = server.wait_ready()
        put = httpx.put(
            f"{url}/v1/scenes/grid/meshes/g",
            content=grid_mesh(),
            headers={"content-type": "application/x-npz"},
        )
        assert put.status_code in (200, 201)
        rng = np.random.default_rng(5)
        rays = np.zeros((HEAVY_RAYS, 6), np.float32)
        rays[:, :2] = rng.uniform(-29, 29, (HEAVY_RAYS, 2))
        rays[:, 2], rays[:, 5] = 5, -1
        body, closest = npy(rays), f"{url}/v1/scenes/grid/closest?fields=t"
        warm = httpx.post(closest, content=npy(rays[:16]), headers={"content-type": NPY})
        assert warm.status_code == 200
        pid = server.process.pid
        idle = rss(pid, "VmRSS")
        reset_peak(pid)

        def client(_):
            with httpx.Client(timeout=120) as http:
                return [
                    http.post(closest, content=body, headers={"content-type": NPY})
                    for _ in range(6)
                ]

        with ThreadPoolExecutor(24) as pool:
            answers = [a for answers in pool.map(client, range(24)) for a in answers]
        peak = rss(pid, "VmHWM") - idle
    finally:
        server.stop()
    statuses = [a.status_code for a in answers]
    print(f"{statuses.count(200)} served, {statuses.count(503)} refused: +{peak / MiB:.0f} MiB")
    assert set(statuses) <= {200, 503} and 200 in statuses
    served = next(a for a in answers if a.status_code == 200)
    assert np.array_equal(np.load(io.BytesIO(served.content))["t"], np.full(HEAVY_RAYS, 5, "f4"))
    assert peak <= SMALL_BUDGET + SMALL_MARGIN, f"peak RSS +{peak / MiB:.0f} MiB over idle"


def test_a_request_over_the_whole_budget_is_413_before_its_body_is_read(servers):
    """A JSON body of 40 MiB would cost about 17 times its size to parse: over the budget."""
    url = f"{servers['budget'].url}/v1/scenes/demo/closest"
    body = b'{"origins": [' + b"[0,0,0]," * (5 * MiB) + b'[0,0,0]], "directions": []}'
    answer = httpx.post(url, content=body, headers={"content-type": "application/json"})
    assert answer.status_code == 413
    assert "DACRT_MAX_INFLIGHT_BYTES" in answer.json()["detail"]
    assert "smaller batches" in answer.json()["detail"]


def layers(n_layers: int) -> bytes:
    """An npz mesh of ``n_layers`` squares of 2000 x 2000 at z = 0, 1, ...: a ray along z from
    below crosses them all."""
    corners = np.float32([[-1000, -1000], [1000, -1000], [1000, 1000], [-1000, 1000]])
    vertices = np.concatenate(
        [np.column_stack([corners, np.full(4, z, np.float32)]) for z in range(n_layers)]
    )
    base = 4 * np.arange(n_layers, dtype=np.int32)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]]).astype(np.int32)
    buffer = io.BytesIO()
    np.savez(buffer, vertices=vertices, faces=faces)
    return buffer.getvalue()


def through_layers(n_rays: int) -> bytes:
    rng = np.random.default_rng(3)
    rays = np.zeros((n_rays, 6), np.float32)
    rays[:, :2] = rng.uniform(-500, 500, (n_rays, 2))
    rays[:, 2], rays[:, 5] = -1, 1
    buffer = io.BytesIO()
    np.save(buffer, rays)
    return buffer.getvalue()


def peak_of(server: ServerProcess, method: str, path: str, **kwargs) -> tuple[httpx.Response, int]:
    """One request's answer, and the server's peak RSS over its RSS before it."""
    pid = server.process.pid
    idle = rss(pid, "VmRSS")
    reset_peak(pid)
    answer = httpx.request(method, server.url + path, timeout=300, **kwargs)
    return answer, rss(pid, "VmHWM") - idle


def test_the_hits_limit_bounds_the_real_peak(servers):
    """DACRT_MAX_HITS_BYTES counts rays x (max_hits + 1) x HIT_SLOT_BYTES: more than a hits
    query holds at its peak with every slot filled (1024 layers)."""
    server = servers["unbounded"]
    put = httpx.put(
        f"{server.url}/v1/scenes/layers/meshes/stack",
        content=layers(1024),
        headers={"content-type": "application/x-npz"},
    )
    assert put.status_code in (200, 201)
    n_rays = 4096
    answer, peak = peak_of(
        server,
        "POST",
        "/v1/scenes/layers/hits?max_hits=1024&fields=t",
        content=through_layers(n_rays),
        headers={"content-type": NPY},
    )
    assert answer.status_code == 200
    assert np.diff(np.load(io.BytesIO(answer.content))["offsets"]).min() == 1024
    counted = n_rays * 1025 * footprint.HIT_SLOT_BYTES
    assert peak <= counted, f"peak +{peak / MiB:.0f} MiB, counted {counted / MiB:.0f} MiB"


def test_a_json_answer_is_written_in_bounded_memory(servers):
    """A JSON answer is written piece by piece: its peak is the query's own plus the pieces',
    never the whole document's lists (about 460 bytes a ray)."""
    n_rays = 1 << 18
    server = servers["unbounded"]
    answer, peak = peak_of(
        server,
        "POST",
        "/v1/scenes/demo/closest",
        content=rays_body(n_rays),
        headers={"content-type": NPY, "accept": "application/json"},
    )
    assert answer.status_code == 200 and "content-length" not in answer.headers
    assert len(answer.json()["t"]) == n_rays
    bound = footprint.query_bytes(n_rays, "closest", ("t",), None) + footprint.JSON_ANSWER_BYTES
    assert peak <= 24 * n_rays + bound, f"peak +{peak / MiB:.0f} MiB"


SMALL_MESH_FILES = {
    "obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    "off": b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    "ply": b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
}


@pytest.mark.parametrize(
    "fmt, body",
    [
        ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + b"1 2 3 " * 700_000 + b"\n"),
        ("obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * 500_000),
        ("off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2100000 " + b"0 1 2 " * 700_000 + b"\n"),
        (
            "ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            b"property float z\nelement face 500000\nproperty list uchar int vertex_indices\n"
            b"end_header\n0 0 0\n1 0 0\n0 1 0\n" + b"5 0 1 2 1 0\n" * 500_000,
        ),
    ],
    ids=["obj polygon fanned", "obj face lines", "off polygon fanned", "ply pentagon rows"],
)
def test_a_mesh_file_is_held_at_no_less_than_its_real_peak(servers, fmt, body):
    """An OBJ, OFF or ASCII PLY of short face rows, or one long polygon that fans into a
    triangle an index, costs tens of times its text to read: the estimate a mesh upload holds
    is more."""
    server = servers["unbounded"]
    headers = {"content-type": "model/obj" if fmt == "obj" else "text/plain"}
    warm = httpx.put(  # one small file first: nothing lazy is left
        f"{server.url}/v1/scenes/warm/meshes/{fmt}",
        content=SMALL_MESH_FILES[fmt],
        headers=headers,
        params={"format": fmt},
    )
    assert warm.status_code in (200, 201)
    answer, peak = peak_of(
        server,
        "PUT",
        f"/v1/scenes/files/meshes/{fmt}",
        content=body,
        headers=headers,
        params={"format": fmt},
    )
    assert answer.status_code in (200, 201), answer.text
    estimate = footprint.decode_bytes(len(body), fmt)
    assert peak <= estimate, f"peak {peak / len(body):.1f} x the body, held {estimate / len(body)}"


def test_a_ticket_of_exactly_the_whole_budget_is_admitted():
    async def scenario():
        admission = Admission(100, wait=0)
        ticket = admission.ticket()
        await ticket.hold(100, "a body of 100 bytes")
        assert admission.held == 100 and ticket.nbytes == 100

    run(scenario())


def test_the_default_budget_is_a_quarter_of_the_machines_memory(monkeypatch):
    monkeypatch.setattr(admission_module, "machine_memory", lambda: 8 << 30)
    assert admission_module.default_budget() == 2 << 30


# ---- the work on a scene's triangles, whatever the rays


def traced_peak(call) -> int:
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("threads", [1, 2, 4])
@pytest.mark.parametrize("n_rays", [1, 8192, 40_000])
def test_a_ray_query_holds_work_on_every_triangle_within_its_estimate(threads, n_rays):
    """A query's work on a scene's triangles (the halves' boxes, each chunk's ids and bins) is
    there whatever its rays: even one ray's peak is more than its rays' estimate alone, and the
    estimate with the scene's work bounds it (tracemalloc; a grid of 512K triangles)."""
    import dacrt

    vertices, faces = grid(512)
    scene = dacrt.Scene([(vertices, faces)])
    rng = np.random.default_rng(5)
    origins = np.column_stack([rng.uniform(0, 1, (n_rays, 2)), np.full(n_rays, 3.0)])
    origins = origins.astype(np.float32)
    directions = np.tile(np.float32([0, 0, -1]), (n_rays, 1))
    scene.closest(origins, directions, threads=threads)  # what a first query derives, once
    peak = traced_peak(lambda: scene.closest(origins, directions, threads=threads))
    rays_alone = footprint.query_bytes(n_rays, "closest", ("t",), None)
    work = footprint.scene_work_bytes(scene.n_triangles, n_rays, threads)
    assert peak > rays_alone + 8 * scene.n_triangles, f"{peak / MiB:.1f} MiB"
    assert peak <= rays_alone + work, (
        f"{peak / MiB:.1f} MiB, counted {(rays_alone + work) / MiB:.1f}"
    )


@pytest.mark.parametrize("masked", [False, True])
@pytest.mark.parametrize("threads", [1, 2, 4])
@pytest.mark.parametrize("n_points", [1, 5000])
def test_a_point_query_holds_work_on_every_triangle_within_its_estimate(n_points, threads, masked):
    """The same for ``nearest``: its rows and each chunk's (the triangles' boxes and Morton order
    are the scene's, derived once), or with a mask that hides a mesh, the visible rows' boxes,
    codes and order (a grid of 512K triangles, and a second mesh the mask hides)."""
    import dacrt

    vertices, faces = grid(512)
    hidden = grid(8)
    scene = dacrt.Scene([(vertices, faces), hidden], masks=[1, 2])
    points = np.random.default_rng(6).uniform(0, 1, (n_points, 3)).astype(np.float32)
    mask = np.ones(n_points, np.uint32) if masked else None
    scene.nearest(points, mask=mask, threads=threads)  # what a first query derives, once
    peak = traced_peak(lambda: scene.nearest(points, mask=mask, threads=threads))
    points_alone = footprint.point_query_bytes(n_points, False, 1)
    work = footprint.scene_work_bytes(scene.n_triangles, n_points, threads, True, masked)
    assert peak > points_alone + (16 if masked else 4) * scene.n_triangles, f"{peak / MiB:.1f}"
    assert peak <= points_alone + work, f"{peak / MiB:.1f} MiB, counted {work / MiB:.1f}"


@pytest.mark.parametrize("kind", ["as given", "instances", "deforming"])
def test_a_versions_first_point_query_holds_its_setup_within_its_estimate(kind):
    """The first point query on a scene version derives what point queries read: beyond what
    stays (``Scene.nbytes``, which the scene limit counts), its peak is more than a later
    query's estimate and within the first's (``setup``), with instances placed or meshes
    deforming too (tracemalloc; grids of 128K triangles)."""
    import dacrt

    vertices, faces = grid(256)
    lifted = vertices + np.float32([0, 0, 0.25])
    moved = np.eye(4)
    moved[:3, 3] = (1.5, 0, 0)
    scene = {
        "as given": lambda: dacrt.Scene([(vertices, faces)]),
        "instances": lambda: dacrt.Scene([(vertices, faces)] * 3, transforms=[None, moved, moved]),
        "deforming": lambda: dacrt.Scene([(vertices, faces)] * 2, vertices_end=[None, lifted]),
    }[kind]()
    point = np.float32([[0.5, 0.5, 1.0]])
    before = scene.nbytes
    assert not scene.derived_for_points
    peak = traced_peak(lambda: scene.nearest(point, threads=1))
    assert scene.derived_for_points
    kept = scene.nbytes - before
    first = footprint.scene_work_bytes(scene.n_triangles, 1, 1, points=True, setup=True)
    later = footprint.scene_work_bytes(scene.n_triangles, 1, 1, points=True)
    assert later < peak - kept <= first, f"{(peak - kept) / scene.n_triangles:.1f} B a triangle"


def test_a_point_query_measures_the_version_its_setup_was_held_for(monkeypatch):
    """A frame that commits while a point query waits for room makes a version that has not
    derived what point queries read: the query holds that setup before it measures the new
    version (it answers with its X-Scene-Version), never a version it holds nothing for."""
    settings = Settings(token=None, load_demo=False)
    vertices, faces = grid(64)
    held = []
    hold = admission_module.Admission.resize

    with in_process.serve(settings) as client:
        client.put(
            "/v1/scenes/s/meshes/m", json={"vertices": vertices.tolist(), "faces": faces.tolist()}
        ).raise_for_status()
        client.put("/v1/scenes/s/meshes/i", json={"instance_of": "m"}).raise_for_status()
        point = {"points": [[0.5, 0.5, 1.0]]}
        client.post("/v1/scenes/s/nearest", json=point).raise_for_status()  # version 2 derives
        store = client._transport._asgi.app.state.store

        async def resize(self, ticket, nbytes, what):
            if " points " in what and not held:  # a frame commits while the query waits
                held.append(what)
                moved = np.eye(4)
                moved[0, 3] = 0.25
                store.set_transform("s", "i", moved)
            return await hold(self, ticket, nbytes, what)

        monkeypatch.setattr(admission_module.Admission, "resize", resize)
        setups = []
        work = footprint.scene_work_bytes

        def scene_work_bytes(*args, **kwargs):
            setups.append(kwargs.get("setup"))
            return work(*args, **kwargs)

        monkeypatch.setattr(footprint, "scene_work_bytes", scene_work_bytes)
        answer = client.post("/v1/scenes/s/nearest", json=point)
    assert answer.status_code == 200, answer.text
    assert answer.headers["X-Scene-Version"] == "3"
    assert setups[-1] is True  # held for version 3's setup before it was measured


@pytest.fixture(scope="module")
def crowded_scene_app():
    """The smallest budget; a scene of one 20,000-triangle car and 49 instances of it (1M placed
    triangles, whose work alone is more than the budget), and a scene of 800 triangles."""
    settings = Settings(
        token=None, load_demo=False, max_inflight_bytes=footprint.MIN_BUDGET_BYTES, threads=2
    )
    vertices, faces = grid(100)
    with in_process.serve(settings) as client:
        client.put(
            "/v1/scenes/crowd/meshes/car",
            json={"vertices": vertices.tolist(), "faces": faces.tolist()},
        ).raise_for_status()
        for k in range(1, 50):
            client.put(
                f"/v1/scenes/crowd/meshes/car{k}", json={"instance_of": "car"}
            ).raise_for_status()
        small_vertices, small_faces = grid(20)
        client.put(
            "/v1/scenes/small/meshes/patch",
            json={"vertices": small_vertices.tolist(), "faces": small_faces.tolist()},
        ).raise_for_status()
        yield client


@pytest.mark.parametrize(
    "query, body",
    [
        ("closest", {"origins": [[0.5, 0.5, 1]], "directions": [[0, 0, -1]]}),
        ("nearest", {"points": [[0.5, 0.5, 1]]}),
        ("lidar", {"pose": np.eye(4).tolist(), "vertical_angles_deg": [0], "horizontal_steps": 4}),
    ],
)
def test_a_query_whose_work_on_the_scene_exceeds_the_budget_is_413(crowded_scene_app, query, body):
    """One ray (or point, or a lidar of four) into a million placed triangles holds more than
    the smallest budget: 413 naming the scene's triangles and the budget, and advising what can
    help (a larger budget or a smaller scene, not a smaller batch), where the same request on a
    small scene answers."""
    answer = crowded_scene_app.post(f"/v1/scenes/crowd/{query}", json=body, headers=JSON)
    assert answer.status_code == 413, answer.text
    detail = answer.json()["detail"]
    assert "1000000 triangles of scene 'crowd'" in detail and "DACRT_MAX_INFLIGHT_BYTES" in detail
    assert "fewer triangles" in detail and "smaller batches" not in detail, detail
    small = crowded_scene_app.post(f"/v1/scenes/small/{query}", json=body, headers=JSON)
    assert small.status_code == 200, small.text


def test_a_sensor_too_heavy_for_the_budget_is_advised_in_its_own_terms(crowded_scene_app):
    """A lidar whose JSON answer does not fit the smallest budget: 413 advising fewer rays or an
    .npz answer (a sensor's body is no batch), and the same lidar answered in .npz is 200."""
    body = {"pose": np.eye(4).tolist(), "model": "HDL-64E", "horizontal_steps": 200}
    answer = crowded_scene_app.post("/v1/scenes/small/lidar", json=body)
    assert answer.status_code == 413, answer.text
    detail = answer.json()["detail"]
    assert "fewer horizontal_steps" in detail and "Accept: application/x-npz" in detail, detail
    assert "batches" not in detail, detail
    npz = crowded_scene_app.post(
        "/v1/scenes/small/lidar", json=body, headers={"Accept": "application/x-npz"}
    )
    assert npz.status_code == 200, npz.text


def test_concurrent_small_queries_on_a_large_scene_are_each_served_in_turn():
    """Twelve one-ray JSON queries at once into a million placed triangles, on a budget that
    holds two of them: each is held with its work on the scene's triangles from before its body
    is read, so those waiting hold nothing, and all twelve answer (none waits for the others
    until its wait runs out)."""
    scene_work = footprint.scene_work_bytes(CROWD_TRIANGLES, 1, 2)
    budget = 2 * (footprint.JSON_ANSWER_BYTES + scene_work + MiB)
    body = {"origins": [[0.5, 0.5, 1]], "directions": [[0, 0, -1]]}
    answers = posted_together_on_a_crowd(budget, 20, "closest", body, {}, 12)
    assert [a.status_code for a in answers] == [200] * 12, [a.text for a in answers]


def test_concurrent_sensors_that_fit_alone_are_each_served_in_turn():
    """Three lidars at once into a million placed triangles, on a budget that holds one of them
    at its peak: a sensor holds its work on the scene once its body says how many rays it makes,
    not before, so two admitted bodies never wait for each other's bytes, and all three answer
    in turn (none is refused for want of the room another is about to free)."""
    n_rays = 64 * 1024
    body = {"pose": np.eye(4).tolist(), "model": "HDL-64E", "horizontal_steps": n_rays // 64}
    one = footprint.sensor_bytes(n_rays) + footprint.scene_work_bytes(CROWD_TRIANGLES, n_rays, 2)
    budget = int(1.5 * one)
    assert 2 * footprint.scene_work_bytes(CROWD_TRIANGLES, 1, 2) < budget  # two bodies' worth
    npz = {"Accept": "application/x-npz"}
    answers = posted_together_on_a_crowd(budget, 30, "lidar", body, npz, 3)
    assert [a.status_code for a in answers] == [200] * 3, [a.text for a in answers]


#: Placed triangles of scene ``crowd``: a 20,000-triangle grid and 49 instances of it.
CROWD_TRIANGLES = 50 * 20_000


def posted_together_on_a_crowd(
    budget: int, wait: int, route: str, body: dict, headers: dict, n: int
) -> list[httpx.Response]:
    """The answers of ``n`` POSTs of ``body`` to ``route`` of scene ``crowd`` sent at once, to
    a server of two threads with ``budget`` and ``wait`` (after one alone, so that nothing lazy
    is left)."""
    server = ServerProcess(
        {
            "DACRT_MAX_INFLIGHT_BYTES": str(budget),
            "DACRT_ADMISSION_WAIT": str(wait),
            "DACRT_THREADS": "2",
        }
    )
    try:
        server.wait_ready()
        vertices, faces = grid(100)
        mesh = {"vertices": vertices.tolist(), "faces": faces.tolist()}
        httpx.put(f"{server.url}/v1/scenes/crowd/meshes/car", json=mesh).raise_for_status()
        for k in range(1, 50):
            httpx.put(
                f"{server.url}/v1/scenes/crowd/meshes/car{k}", json={"instance_of": "car"}
            ).raise_for_status()
        url = f"{server.url}/v1/scenes/crowd/{route}"
        alone = httpx.post(url, json=body, headers=headers, timeout=120)
        assert alone.status_code == 200, alone.text
        together = threading.Barrier(n)

        def post(_):
            with httpx.Client(timeout=120) as client:
                together.wait()
                return client.post(url, json=body, headers=headers)

        with ThreadPoolExecutor(n) as pool:
            return list(pool.map(post, range(n)))
    finally:
        server.stop()
