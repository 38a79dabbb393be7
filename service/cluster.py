"""The dask cluster of DACRT_DASK_SCHEDULER: large queries traced on its workers.

``Cluster`` connects to the scheduler in the background (the service starts and answers whether or
not the scheduler does), hands ``tracing.trace`` an engine scene on the cluster for a query of at
least DACRT_DASK_MIN_RAYS rays (``engine_for``), and describes the cluster for /health and
/v1/capabilities (``describe``). A scene version's triangles are sent to the workers once, by its
first large query, and dropped from the cluster when a newer version of the scene is queried or
when the version's snapshot is gone. While the scheduler is unreachable (or has no worker) queries
are traced in process and the connection is tried again in the background, at most every
``retry_seconds``.

Needs the ``dask`` extra; without it the service answers every query in process and /health says
why the cluster is unavailable.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
import weakref
from typing import Any

from .store import Snapshot

log = logging.getLogger("service")

#: Seconds a batch may take on the cluster before the query is traced in process instead.
BATCH_TIMEOUT = 600.0


class Cluster:
    """The connection to one dask scheduler, and the scene versions sent to its workers."""

    def __init__(
        self,
        address: str,
        min_rays: int,
        *,
        connect_timeout: float = 5.0,
        retry_seconds: float = 10.0,
    ) -> None:
        self.address = address
        self.min_rays = min_rays
        self.connect_timeout = connect_timeout
        self.retry_seconds = retry_seconds
        self._client: Any = None
        self._error: str | None = "connecting"
        self._lock = threading.Lock()
        self._connecting = False
        self._connector: threading.Thread | None = None
        self._closed = False
        self._last_attempt = -float("inf")
        # scene name -> (version, client, engine scene on the cluster, weak ref to the snapshot)
        self._sent: dict[str, tuple] = {}

    # ---- connection

    def start(self) -> None:
        """Connect in the background."""
        self._connect_soon(force=True)

    def close(self) -> None:
        """Drop every scene from the cluster and disconnect, once a connection attempt under
        way has ended (it would otherwise outlive the service, retrying in the background)."""
        with self._lock:
            self._closed = True
            connector = self._connector
        if connector is not None:
            connector.join(self.connect_timeout + 5.0)
        with self._lock:
            sent, self._sent = self._sent, {}
            client, self._client = self._client, None
        for _, _, engine, _ in sent.values():
            engine.scene.close()
        if client is not None:
            client.close()

    def _connect_soon(self, force: bool = False) -> None:
        with self._lock:
            now = time.monotonic()
            recent = now - self._last_attempt < self.retry_seconds
            if self._closed or self._connecting or (not force and recent):
                return
            self._connecting, self._last_attempt = True, now
            self._connector = threading.Thread(
                target=self._connect, name="dacrt-dask-connect", daemon=True
            )
            self._connector.start()

    def _connect(self) -> None:
        try:
            from distributed import Client

            client = Client(self.address, timeout=self.connect_timeout, set_as_default=False)
        except ImportError:
            self._error = 'dask.distributed is not installed (pip install ".[dask]")'
        except Exception as exc:  # OSError, TimeoutError, a bad address: all mean unreachable
            self._error = f"{type(exc).__name__}: {exc}"
            log.warning("dask scheduler %s is unreachable: %s", self.address, self._error)
        else:
            with self._lock:
                old, self._client, self._error = self._client, client, None
            if old is not None:
                old.close()
            log.info("connected to the dask scheduler %s", self.address)
        finally:
            self._connecting = False

    def _running_client(self) -> Any:
        """The client while it is connected, else None (and a new connection is tried)."""
        client = self._client
        if client is not None and client.status == "running":
            return client
        if client is not None and self._error is None:
            self._error = f"the connection to the scheduler is {client.status}"
        self._connect_soon()
        return None

    def _threads(self, client: Any) -> dict[str, int] | None:
        """Threads per worker, or None (recorded as the error) when the scheduler does not say."""
        try:
            nthreads = client.nthreads()
        except Exception as exc:
            self._error = f"{type(exc).__name__}: {exc}"
            return None
        if not nthreads:
            self._error = "the scheduler has no worker"
            return None
        return nthreads

    def describe(self) -> dict[str, Any]:
        """The cluster for /health and /v1/capabilities: status ``ok`` (with its workers and
        threads) or ``unreachable`` (with why)."""
        info: dict[str, Any] = {"scheduler": self.address, "min_rays": self.min_rays}
        client = self._running_client()
        nthreads = None if client is None else self._threads(client)
        if nthreads is None:
            return {**info, "status": "unreachable", "detail": self._error or "connecting"}
        with self._lock:
            scenes = len(self._sent)
        return {
            **info,
            "status": "ok",
            "workers": len(nthreads),
            "threads": sum(nthreads.values()),
            "scenes": scenes,
        }

    # ---- queries

    def engine_for(self, snapshot: Snapshot, n_rays: int, build) -> Any:
        """The engine scene of ``snapshot`` on the cluster for a query of ``n_rays`` rays, or None
        to trace it in process (a smaller query, or no cluster). ``build(snapshot, scene_type)``
        makes an engine scene (``tracing.EngineScene``) from the snapshot's meshes."""
        if n_rays < self.min_rays:
            return None
        client = self._running_client()
        if client is None or self._threads(client) is None:
            return None
        with self._lock:
            entry = self._sent.get(snapshot.scene)
            if entry is not None:
                version, sent_client, engine, ref = entry
                if version == snapshot.version and sent_client is client and ref() is snapshot:
                    return engine
                if version > snapshot.version:
                    return None  # a late query on an old version: not worth sending it
            from dacrt.distributed import DistributedScene

            engine = build(
                snapshot,
                functools.partial(DistributedScene, client, timeout=BATCH_TIMEOUT),
            )
            self._sent[snapshot.scene] = (
                snapshot.version,
                client,
                engine,
                weakref.ref(snapshot, functools.partial(self._gone, snapshot.scene)),
            )
        if entry is not None:
            entry[2].scene.close()
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
        """A query the cluster could not answer (it is traced in process instead)."""
        self._error = f"{type(error).__name__}: {error}"
        log.warning("a query fell back to in-process tracing: %s", self._error)
