"""Admission: a budget of bytes that the requests in flight may hold at their peak.

Every request holds a ``Ticket`` from its start to the last byte of its answer. Before a request
reads its body or builds its answer it says how many bytes it will hold at its peak
(``service.footprint`` estimates them from what it asks); the ticket is admitted when those bytes
fit in DACRT_MAX_INFLIGHT_BYTES beside what the other requests hold. Requests wait in arrival
order, at most DACRT_ADMISSION_WAIT seconds in all however many times they ask, then get 503
with Retry-After; a request that would not fit in the whole budget is 413. A small request (at
most SMALL_BYTES, and 1/64 of the budget) that fits goes ahead of those waiting: a cheap query is
not held up behind heavy ones, which it delays by no more than its own bytes for its own short
time. So N concurrent heavy requests hold at most the budget, never the machine's memory.

Tickets are taken and changed on the event loop only (between the work done in threads), so the
budget needs no lock.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections import deque
from collections.abc import Callable
from pathlib import Path

from .errors import Overloaded, TooLarge

#: Share of the machine's memory (or of its cgroup's limit) that requests may hold by default.
DEFAULT_SHARE = 0.25
#: The most bytes a request may hold to go ahead of those waiting (when it fits): a 1-ray query
#: needs about 3 KB, 20,000 rays about 1 MiB.
SMALL_BYTES = 1 << 20


def machine_memory() -> int:
    """Bytes of memory this process may use: the machine's, or its cgroup's limit if lower."""
    physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(limit_file).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            physical = min(physical, int(text))
    return physical


def default_budget() -> int:
    """DACRT_MAX_INFLIGHT_BYTES when it is not set: a quarter of the machine's memory."""
    return int(machine_memory() * DEFAULT_SHARE)


class Ticket:
    """The bytes one request holds in the budget (0 until it asks for some)."""

    def __init__(self, admission: Admission) -> None:
        self.admission = admission
        self.nbytes = 0
        #: when the request's waiting ends (event loop time), set when it first waits
        self.deadline: float | None = None
        #: whether its bytes were admitted in its turn, not ahead of others as a small request
        self.in_turn = False
        #: bytes the request holds whatever its size (its work on a scene's triangles), for the
        #: advice of a 413
        self.least = 0
        #: the advice of a 413 for a load too heavy, where smaller batches do not apply
        self.advice: str | None = None

    async def hold(self, nbytes: int, what: str) -> None:
        """Hold ``nbytes`` in all from now on (more or fewer than before): waits in line for
        them, then 503; 413 if they exceed the whole budget. ``what`` names the request's load
        in the caller's terms (``"1048576 rays of closest as npz"``)."""
        await self.admission.resize(self, int(nbytes), what)

    def check(self, nbytes: int, what: str) -> None:
        """413 if ``nbytes`` exceed the whole budget, without holding them."""
        self.admission.check(int(nbytes), what, self.least, self.advice)

    def shrink(self, nbytes: int) -> None:
        """Hold only ``nbytes`` (no more than it holds) from now on."""
        self.admission.resize_now(self, min(int(nbytes), self.nbytes))

    def release(self) -> None:
        self.admission.resize_now(self, 0)


class Place:
    """A request's place in line: what it holds, what more it needs, whether it waits ahead of
    those not yet admitted, and the future it waits on."""

    def __init__(self, held: int, extra: int, ahead: bool, turn: asyncio.Future) -> None:
        self.held = held
        self.extra = extra
        self.ahead = ahead
        self.turn = turn


class Admission:
    """The in-flight budget of one app."""

    def __init__(self, budget: int, wait: float) -> None:
        self.budget = budget  #: DACRT_MAX_INFLIGHT_BYTES
        self.wait = wait  #: DACRT_ADMISSION_WAIT
        self.held = 0  #: bytes held by admitted tickets
        self.on_refused: Callable[[], None] = lambda: None  #: called for each 503 (metrics)
        self._line: deque[Place] = deque()

    def ticket(self) -> Ticket:
        return Ticket(self)

    async def resize(self, ticket: Ticket, nbytes: int, what: str) -> None:
        extra = nbytes - ticket.nbytes
        if extra <= 0:
            self.resize_now(ticket, nbytes)
            return
        self.check(nbytes, what, ticket.least, ticket.advice)
        fits = self.held + extra <= self.budget
        # A request admitted in its turn that needs more goes ahead of those not admitted yet
        # (they may be waiting for what it holds), after others like it; one that went ahead
        # as small waits its turn as a new request does.
        ahead = ticket.in_turn and ticket.nbytes > 0
        n_ahead = sum(place.ahead for place in self._line)  # they wait at the front
        small = extra <= min(SMALL_BYTES, self.budget // 64)
        if fits and (not self._line or (ahead and not n_ahead) or small):
            ticket.in_turn = ticket.in_turn or not self._line
            self.resize_now(ticket, nbytes)
            return
        loop = asyncio.get_running_loop()
        if ticket.deadline is None:
            ticket.deadline = loop.time() + self.wait
        place = Place(ticket.nbytes, extra, ahead, loop.create_future())
        self._line.insert(n_ahead if ahead else len(self._line), place)
        self._wake()  # the line may be stuck now that this request's bytes wait in it
        try:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout_at(ticket.deadline):
                    while not (self._goes(place) or self._refused_at_once(place)):
                        await asyncio.shield(place.turn)
                        if place.turn.done():
                            place.turn = loop.create_future()
            admitted = ticket.in_turn = self._goes(place)
        finally:
            self._line.remove(place)
            self._wake()
        if not admitted:
            self.on_refused()
            raise Overloaded(
                f"the server is busy: {what} needs about {amount(nbytes)} of memory and the "
                f"requests in flight hold {amount(self.held)} of {amount(self.budget)} "
                f"(DACRT_MAX_INFLIGHT_BYTES); retry after {Overloaded.headers['Retry-After']} s"
            )
        self.resize_now(ticket, nbytes)

    def check(self, nbytes: int, what: str, least: int = 0, advice: str | None = None) -> None:
        """413 if ``nbytes`` exceed the whole budget: they would never be admitted. ``least``:
        what the request holds whatever its size (over the budget, no smaller load helps);
        ``advice``: how to lighten it, where smaller batches do not apply."""
        if nbytes <= self.budget:
            return
        advice = advice or "send it in smaller batches (or .npy/.npz rather than JSON)"
        if least > self.budget:
            advice = (
                f"its work on the scene's triangles alone holds about {amount(least)}, whatever "
                "its size: raise DACRT_MAX_INFLIGHT_BYTES, or use a scene of fewer triangles"
            )
        raise TooLarge(
            f"{what} would hold about {amount(nbytes)} of server memory, over the budget of "
            f"{amount(self.budget)} for all requests in flight (DACRT_MAX_INFLIGHT_BYTES); "
            f"{advice}"
        )

    def resize_now(self, ticket: Ticket, nbytes: int) -> None:
        """Change a ticket's bytes without waiting (a release, or bytes known to fit)."""
        freed = ticket.nbytes > nbytes
        self.held += nbytes - ticket.nbytes
        ticket.nbytes = nbytes
        if freed:
            self._wake()

    def _stuck(self) -> bool:
        """Whether every byte held is held by requests waiting in line: none is freed until
        one of them goes or is refused."""
        return bool(self._line) and self.held == sum(place.held for place in self._line)

    def _fits(self, place: Place) -> bool:
        return self.held + place.extra <= self.budget

    def _goes(self, place: Place) -> bool:
        """Whether the request at ``place`` is admitted now: it fits, and it is first in line
        or the line is stuck (then any that fits goes, and frees its bytes when done)."""
        return self._fits(place) and (self._line[0] is place or self._stuck())

    def _refused_at_once(self, place: Place) -> bool:
        """Whether the request at ``place`` is refused without waiting out its deadline: the
        line is stuck, none in it fits, and it holds the most bytes (the first such in line),
        which its refusal frees for the others."""
        if not self._stuck() or any(self._fits(other) for other in self._line):
            return False
        return place is max(self._line, key=lambda other: other.held)

    def _wake(self) -> None:
        """Tell those in line to look again: bytes were freed, or the line moved. The first in
        line looks, or every one where the line is stuck."""
        for place in list(self._line)[: len(self._line) if self._stuck() else 1]:
            if not place.turn.done():
                place.turn.set_result(None)


def amount(nbytes: int) -> str:
    """``nbytes`` for a message: in MiB, or below a MiB in KiB or bytes (never ``0.0 MiB``)."""
    if nbytes >= 2**20:
        return f"{nbytes / 2**20:.1f} MiB"
    if nbytes >= 2**10:
        return f"{nbytes / 2**10:.1f} KiB"
    return f"{nbytes} bytes"


class AdmissionMiddleware:
    """ASGI middleware: each HTTP request gets a ticket (``scope["state"]["ticket"]``), released
    once its answer is sent or it fails."""

    def __init__(self, app, admission: Admission) -> None:
        self.app = app
        self.admission = admission

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        ticket = self.admission.ticket()
        scope.setdefault("state", {})["ticket"] = ticket
        try:
            await self.app(scope, receive, send)
        finally:
            ticket.release()
