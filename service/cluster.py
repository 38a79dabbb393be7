"""The dask cluster of DACRT_DASK_SCHEDULER: large queries traced on its workers.

``Cluster`` hands ``tracing.trace`` an engine scene on the cluster for a query of at least
DACRT_DASK_MIN_RAYS rays (``engine_for``), and describes the cluster for /health and
/v1/capabilities (``describe``). A scene version's triangles are sent to the workers once, by its
first large query, and dropped from the cluster when a newer version of the scene is queried or
when the version's snapshot is gone.

A request never waits on the scheduler to learn the cluster's state: a monitor thread connects
to the scheduler, asks it for its workers every ``poll_seconds`` (within ``probe_seconds``) and
keeps the answer, which ``describe`` and ``engine_for`` read. Each call a query makes to the
cluster (sending the triangles, its batch) has DACRT_DASK_TIMEOUT seconds; a query the cluster
does not answer in time, or cannot answer, is traced in process. While the cluster is
unreachable, queries are traced in process without asking it: the monitor tries a new connection
at most every ``retry_seconds``; after a call went unanswered (a scheduler or worker that stopped
answering without closing its connection) it gives every worker a task first, and connects anew
once they all answer (the old connection may still hold what the unanswered calls sent).

Needs the ``dask`` extra; without it the service answers every query in process and /health says
why the cluster is unavailable.
"""

from __future__ import annotations

import functools
import logging
import os
import threading
import time
import weakref
from contextlib import suppress
from typing import Any

from .store import Snapshot

log = logging.getLogger("service")

#: Seconds the monitor waits between two questions to the scheduler.
POLL_SECONDS = 2.0
#: Longest the monitor waits for the scheduler's (or the workers') answer; DACRT_DASK_TIMEOUT
#: where that is shorter.
PROBE_SECONDS = 5.0


class Cluster:
    """The connection to one dask scheduler, and the scene versions sent to its workers."""

    def __init__(
        self,
        address: str,
        min_rays: int,
        timeout: float = 30.0,
        *,
        connect_timeout: float = 5.0,
        retry_seconds: float = 10.0,
        poll_seconds: float = POLL_SECONDS,
    ) -> None:
        self.address = address
        self.min_rays = min_rays
        self.timeout = timeout  #: DACRT_DASK_TIMEOUT: seconds for each call a query makes
        self.probe_seconds = min(PROBE_SECONDS, timeout)
        self.connect_timeout = connect_timeout
        self.retry_seconds = retry_seconds
        self.poll_seconds = poll_seconds
        self._client: Any = None
        # held to read or change the fields below, never during a call to the cluster; reentrant:
        # a snapshot's last reference may go (and _gone run) in a thread that holds it
        self._lock = threading.RLock()
        self._error: str | None = "connecting"  #: why the cluster is not used; None: it is
        self._suspect = False  #: a call went unanswered: check the workers, then connect anew
        self._workers: dict[str, int] = {}  #: threads per worker, at the last answer
        self._stop = threading.Event()
        self._monitor: threading.Thread | None = None
        self._last_attempt = -float("inf")
        # scene name -> (version, client, engine scene on the cluster, weak ref to the snapshot)
        self._sent: dict[str, tuple] = {}
        self._sending: set[str] = set()  #: scenes whose triangles a query is sending

    # ---- connection and state

    def start(self) -> None:
        """Start the monitor: it connects in the background."""
        self._monitor = threading.Thread(target=self._watch, name="dacrt-dask-monitor", daemon=True)
        self._monitor.start()

    def close(self) -> None:
        """Stop the monitor, drop every scene from the cluster and disconnect."""
        self._stop.set()
        if self._monitor is not None:
            self._monitor.join(2 * self.connect_timeout + 3 * self.probe_seconds + 5.0)
        with self._lock:
            sent, self._sent = self._sent, {}
            client, self._client = self._client, None
            answering = self._error is None
        for _, _, engine, _ in sent.values():
            # the workers' Scenes are dropped at once only from a cluster that answers
            engine.scene.close(forget=answering)
        if client is not None:
            with suppress(Exception):  # gone or not answering: closing is all that is left
                client.close(timeout=self.probe_seconds)

    def _set(self, error: str | None, suspect: bool | None = None) -> None:
        with self._lock:
            self._error = error
            if suspect is not None:
                self._suspect = suspect

    def _watch(self) -> None:
        """The monitor: connect, then ask the scheduler for its workers every poll_seconds."""
        while not self._stop.is_set():
            try:
                self._step()
            except Exception as exc:  # the monitor outlives any surprise; the state says it
                self._set(f"{type(exc).__name__}: {exc}", suspect=True)
                log.exception("the dask monitor failed a step")
            self._stop.wait(self.poll_seconds)

    def _step(self) -> None:
        client = self._client
        if client is None or client.status != "running":
            if client is not None:
                self._set(f"the connection to the scheduler is {client.status}")
            if time.monotonic() - self._last_attempt >= self.retry_seconds:
                client = self._connect()
                if client is not None:
                    self._check(client)
        else:
            self._check(client)

    def _connect(self) -> Any:
        """A new client of the scheduler, in place of the old one (closed), or None (recorded
        as the error)."""
        self._last_attempt = time.monotonic()
        try:
            from distributed import Client

            client = Client(self.address, timeout=self.connect_timeout, set_as_default=False)
        except ImportError:
            self._set('dask.distributed is not installed (pip install ".[dask]")')
            return None
        except Exception as exc:  # OSError, TimeoutError, a bad address: all mean unreachable
            self._set(f"{type(exc).__name__}: {exc}")
            log.warning("dask scheduler %s is unreachable: %s", self.address, self._error)
            return None
        with self._lock:
            old, self._client, self._suspect = self._client, client, False
            # the old client's scenes are sent again, through the new one, when next queried
            dropped = [s for s, entry in self._sent.items() if entry[1] is old]
            engines = [self._sent.pop(s)[2] for s in dropped]
        for engine in engines:
            engine.scene.close(forget=False)
        if old is not None:
            with suppress(Exception):  # gone or not answering: closing is all that is left
                old.close(timeout=self.probe_seconds)
        log.info("connected to the dask scheduler %s", self.address)
        return client

    def _check(self, client: Any) -> None:
        """Ask the scheduler for its workers (and, after a call went unanswered, each worker
        for a task), each within probe_seconds, and record the answer or why there is none."""
        try:
            nthreads = client.nthreads(callback_timeout=self.probe_seconds)
        except Exception as exc:
            self._set(self._why("the scheduler", exc), suspect=True)
            return
        if not nthreads:
            self._set("the scheduler has no worker")
            return
        if self._suspect:
            try:
                self._ask_workers(client, list(nthreads))
            except Exception as exc:
                self._set(self._why("a worker", exc))
                return
            if self._connect() is None:
                return
        with self._lock:
            self._workers = nthreads
            if not self._suspect:  # else a query failed meanwhile: its error stands
                self._error = None

    def _ask_workers(self, client: Any, workers: list[str]) -> None:
        """Run a task on each worker, within probe_seconds: a worker that stopped answering
        keeps its place at the scheduler until dask's worker-ttl (5 minutes) passes."""
        futures = [client.submit(os.getpid, workers=[w], pure=False) for w in workers]
        client.sync(client.gather, futures, callback_timeout=self.probe_seconds)

    def _why(self, who: str, exc: Exception) -> str:
        if isinstance(exc, TimeoutError):
            return f"{who} did not answer within {self.probe_seconds:g} s"
        return f"{type(exc).__name__}: {exc}"

    def describe(self) -> dict[str, Any]:
        """The cluster for /health and /v1/capabilities, as the monitor last saw it (no call to
        the cluster): status ``ok`` (with its workers and threads) or ``unreachable`` (with why)."""
        info: dict[str, Any] = {
            "scheduler": self.address,
            "min_rays": self.min_rays,
            "timeout": self.timeout,
        }
        with self._lock:
            error, workers, scenes = self._error, self._workers, len(self._sent)
        if error is not None:
            return {**info, "status": "unreachable", "detail": error}
        return {
            **info,
            "status": "ok",
            "workers": len(workers),
            "threads": sum(workers.values()),
            "scenes": scenes,
        }

    # ---- queries

    def engine_for(self, snapshot: Snapshot, n_rays: int, build) -> Any:
        """The engine scene of ``snapshot`` on the cluster for a query of ``n_rays`` rays, or None
        to trace it in process (a smaller query, no cluster, or another query sending this
        scene's triangles). ``build(snapshot, scene_type)`` makes an engine scene
        (``tracing.EngineScene``) from the snapshot's meshes; sending them has DACRT_DASK_TIMEOUT
        (``ClusterError`` past it)."""
        if n_rays < self.min_rays:
            return None
        with self._lock:
            client = self._client
            if self._error is not None or self._suspect or client is None:
                return None
            entry = self._sent.get(snapshot.scene)
            if entry is not None:
                version, sent_client, engine, ref = entry
                if version == snapshot.version and sent_client is client and ref() is snapshot:
                    return engine
                if version > snapshot.version:
                    return None  # a late query on an old version: not worth sending it
            if snapshot.scene in self._sending:
                return None  # waiting for another query's sending could take its whole timeout
            self._sending.add(snapshot.scene)
        try:
            from dacrt.distributed import DistributedScene

            engine = build(
                snapshot, functools.partial(DistributedScene, client, timeout=self.timeout)
            )
            with self._lock:
                old = self._sent.get(snapshot.scene)
                self._sent[snapshot.scene] = (
                    snapshot.version,
                    client,
                    engine,
                    weakref.ref(snapshot, functools.partial(self._gone, snapshot.scene)),
                )
        finally:
            with self._lock:
                self._sending.discard(snapshot.scene)
        if old is not None:
            old[2].scene.close()  # DistributedScene.close has the timeout too
        return engine

    def _gone(self, scene: str, ref: weakref.ref) -> None:
        """A sent snapshot was garbage collected (deleted or replaced): release its triangles.
        Only a release here (no call to the workers: this may run in any thread)."""
        with self._lock:
            entry = self._sent.get(scene)
            if entry is None or entry[3] is not ref:
                return
            del self._sent[scene]
        entry[2].scene.close(forget=False)

    def failed(self, error: Exception) -> None:
        """A query the cluster could not answer (it is traced in process instead): the cluster
        is not used again before the monitor has seen every worker answer."""
        self._set(f"{type(error).__name__}: {error}", suspect=True)
        log.warning("a query fell back to in-process tracing: %s", self._error)
