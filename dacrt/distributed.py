"""Ray batches traced on a dask.distributed cluster: ``DistributedScene``.

client = distributed.Client("tcp://scheduler:8786")
scene = DistributedScene(client, meshes)   # the triangles go to every worker, once
hits = scene.closest(origins, directions)  # the same arguments and answers as Scene

The meshes are checked here and sent to every worker once (``Client.scatter(broadcast=True)``);
each worker process builds its ``dacrt.Scene`` from them on its first shard and keeps it, by the
scattered key, while that key lives on the worker. A batch is cut into shards of consecutive rays
(``shard_bounds``); each shard is scattered to a worker and traced there on one of the worker's
threads; the answers are joined in input order. A shard whose rays or answer are lost with their
worker is sent again, up to ``retries`` times; past that, when the cluster is gone, or when the
scene's ``timeout`` passes (every call to the scheduler or the workers is bounded by it, so a
scheduler or worker that stops answering without closing its connection costs no more), the
query raises ``ClusterError``: never a partial answer.

Needs the ``dask`` extra (``pip install ".[dask]"``); ``import dacrt`` does not import this module.
"""

from __future__ import annotations

import math
import threading
import time
from contextlib import suppress

import numpy as np

from .config import MAX_SHARD_RAYS, MIN_SHARD_RAYS, SHARD_RETRIES
from .contracts import STAT_NAMES, Counts, HitList, Hits, Occlusion
from .scene import Scene, check_scene_arguments
from .validation import (
    InputError,
    check_cull,
    check_masks,
    check_max_hits,
    check_rays,
    check_strategy,
    check_threads,
    check_time,
    explain_bad_rays,
    hide_rays,
)

try:
    import distributed
except ImportError as exc:  # pragma: no cover - the message is the point
    raise ImportError('dacrt.distributed needs dask.distributed: pip install ".[dask]"') from exc


_QUERIES = ("closest", "occluded", "hits", "count")


class ClusterError(RuntimeError):
    """A batch the cluster could not finish (its workers or scheduler are gone): no answer."""


def _within(client, seconds, method, *args, **kwargs):
    """``method(*args, **kwargs)``, a method of ``client``, or ``distributed.TimeoutError`` after
    ``seconds`` (None: no limit). It runs on the client's event loop, where dask's methods
    answer coroutines, under ``Client.sync``'s ``callback_timeout``: the only limit that holds
    when the other end keeps its connection open but stops answering."""
    return client.sync(method, *args, callback_timeout=seconds, **kwargs)


def _seconds_left(deadline):
    """Seconds until ``deadline`` (``time.monotonic``; None: no limit), or
    ``distributed.TimeoutError`` once it has passed."""
    if deadline is None:
        return None
    left = deadline - time.monotonic()
    if left <= 0:
        raise distributed.TimeoutError("the deadline passed")
    return left


def shard_bounds(n_rays, n_threads, min_rays=MIN_SHARD_RAYS, max_rays=MAX_SHARD_RAYS):
    """Bounds (n_shards + 1,) of the shards of a batch of ``n_rays`` for a cluster with
    ``n_threads`` threads in all: a multiple of n_threads shards (every thread busy, the same
    number of shards each), each of at most ``max_rays`` rays and at least ``min_rays`` (fewer
    shards, so some threads idle, rather than small ones); one shard for an empty batch."""
    n_threads = max(1, n_threads)
    n_shards = n_threads * max(1, math.ceil(n_rays / (n_threads * max_rays)))
    n_shards = max(1, min(n_shards, n_rays // min_rays))
    return [k * n_rays // n_shards for k in range(n_shards + 1)]


# ---- on the workers

_SCENES: dict[str, Scene] = {}
_SCENES_LOCK = threading.Lock()


def _held_keys():
    """Keys whose data this worker holds (empty outside a worker)."""
    try:
        return distributed.get_worker().data
    except ValueError:
        return {}


def _worker_scene(key, payload):
    """This worker's Scene of the scattered ``payload`` under ``key``: built once per worker.
    Scenes whose key the worker no longer holds (released by their client) are dropped."""
    with _SCENES_LOCK:
        scene = _SCENES.get(key)
        if scene is None:
            held = _held_keys()
            for old in [k for k in _SCENES if k not in held]:
                del _SCENES[old]
            scene = _SCENES[key] = Scene(*payload)  # ``SceneArguments``
        return scene


def _build(key, payload):
    _worker_scene(key, payload)


def _trace_shard(key, payload, query, shard, kwargs):
    """One shard's answer and the seconds its trace took (on a worker)."""
    origins, directions, tmin, tmax, mask, times = shard
    scene = _worker_scene(key, payload)
    start = time.perf_counter()
    answer = getattr(scene, query)(origins, directions, tmin, tmax, mask=mask, time=times, **kwargs)
    return answer, time.perf_counter() - start


def _forget(key):
    """Drop this worker's Scene of ``key`` (run on every worker by ``DistributedScene.close``)."""
    with _SCENES_LOCK:
        return _SCENES.pop(key, None) is not None


# ---- on the client


class DistributedScene:
    """Triangle meshes traced on the workers of a ``distributed.Client``.

    client : a connected ``distributed.Client``
    meshes, masks, transforms, order, transforms_end, vertices_end : as ``dacrt.Scene``, checked
        here as ``Scene`` checks them
    retries : times a shard lost with its worker is sent again before ``ClusterError``
    min_shard_rays, max_shard_rays : the bounds of a shard's size (``shard_bounds``)
    timeout : seconds a batch may take on the cluster (None: no limit), then ``ClusterError``;
        it also bounds sending the triangles (here and by ``close``)

    ``closest``, ``occluded``, ``hits`` and ``count`` take ``Scene``'s arguments (``time`` and
    ``device`` too: each worker traces its shards on its own device) and answer its types, bit
    for bit the same; ``threads`` is the engine threads of each shard on its worker (None: 1,
    each of a worker's threads tracing its own shard). With ``stats``, the counters are summed
    over the shards (max_depth: the deepest). ``close()`` (or the end of a ``with``) drops the
    triangles from the cluster; so does dropping the last reference to the scene. The point
    queries, ``with_changes`` and the sensors are ``Scene``'s only.
    """

    def __init__(
        self,
        client,
        meshes,
        masks=None,
        transforms=None,
        order="auto",
        transforms_end=None,
        vertices_end=None,
        *,
        retries=SHARD_RETRIES,
        timeout=None,
        min_shard_rays=MIN_SHARD_RAYS,
        max_shard_rays=MAX_SHARD_RAYS,
    ):
        _, arguments = check_scene_arguments(
            meshes, masks, transforms, order, transforms_end, vertices_end
        )
        for name, value in (("min_shard_rays", min_shard_rays), ("max_shard_rays", max_shard_rays)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise InputError(f"{name} must be a positive integer, got {value!r}")
        checked = arguments.meshes
        n_meshes = len(checked)
        self.client = client
        self.retries = retries
        self.shard_rays = (min_shard_rays, max_shard_rays)
        self.resent = 0  #: shards sent again after their worker was lost, over every query
        #: the last query's shards, seconds scattering its rays (``send``), seconds of the
        #: workers' traces summed over shards (``trace``) and on the caller's clock (``wall``)
        self.last_query = {}
        self.timeout = timeout
        self.n_meshes = n_meshes
        self.n_triangles = sum(len(faces) for _, faces in checked)
        self.payload_bytes = sum(v.nbytes + f.nbytes for v, f in checked)
        # The triangles stay here too: the cluster may lose them with a worker (dask's memory
        # manager keeps one copy of what was broadcast), and then they are sent again.
        self._triangles = arguments
        try:
            self._send_triangles()
        except (OSError, distributed.TimeoutError) as exc:  # no workers, or no scheduler
            raise ClusterError(
                f"the triangles could not reach the cluster: {type(exc).__name__}: {exc}"
            ) from exc

    def _send_triangles(self, seconds=None):
        """Scatter the triangles to every worker, within ``seconds`` (None: the scene's
        ``timeout``); workers that join later fetch them from a peer when a shard lands on them.
        The workers' Scenes are keyed by the scattered key."""
        seconds = self.timeout if seconds is None else seconds
        client = self.client
        [self._payload] = _within(
            client, seconds, client.scatter, [self._triangles], broadcast=True, hash=False
        )
        self.key = self._payload.key

    def __repr__(self):
        return f"DistributedScene({self.n_meshes} meshes, {self.n_triangles} triangles)"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self, forget=True):
        """Drop the triangles from the cluster, and (``forget``) the workers' Scenes of them at
        once; else each worker drops its Scene when it next builds one."""
        payload, self._payload = getattr(self, "_payload", None), None
        if payload is None:
            return
        payload.release()
        if forget and self.client.status == "running":
            try:
                self.client.run(_forget, self.key, callback_timeout=self.timeout)
            except OSError:  # gone or not answering (TimeoutError): nothing more to do there
                pass

    def build(self):
        """Build the Scene on every worker now rather than on its first shard; answers the
        seconds it took."""
        start = time.perf_counter()
        client = self.client
        futures = [
            client.submit(_build, self.key, self._payload, workers=[worker], pure=False)
            for worker in client.nthreads(callback_timeout=self.timeout)
        ]
        _within(client, self.timeout, client.gather, futures)
        return time.perf_counter() - start

    def threads(self):
        """Threads of the cluster's workers, in all."""
        return sum(self.client.nthreads(callback_timeout=self.timeout).values())

    def closest(self, origins, directions, tmin=None, tmax=None, **options):
        """``Scene.closest`` on the cluster."""
        return self._query("closest", origins, directions, tmin, tmax, options)

    def occluded(self, origins, directions, tmin=None, tmax=None, **options):
        """``Scene.occluded`` on the cluster."""
        return self._query("occluded", origins, directions, tmin, tmax, options)

    def hits(self, origins, directions, tmin=None, tmax=None, **options):
        """``Scene.hits`` on the cluster."""
        return self._query("hits", origins, directions, tmin, tmax, options)

    def count(self, origins, directions, tmin=None, tmax=None, **options):
        """``Scene.count`` on the cluster."""
        return self._query("count", origins, directions, tmin, tmax, options)

    def _query(self, query, origins, directions, tmin, tmax, options):
        known = {"cull", "mask", "strategy", "threads", "stats", "max_hits", "time", "device"}
        unknown = set(options) - known
        if unknown or ("max_hits" in options and query != "hits"):
            name = sorted(unknown or {"max_hits"})[0]
            raise TypeError(f"{query}() got an unexpected keyword argument {name!r}")
        if self._payload is None:
            raise ClusterError("this DistributedScene is closed")
        deadline = None if self.timeout is None else time.monotonic() + self.timeout
        # The checks Scene makes, here: a bad argument fails before anything is sent.
        check_strategy(options.get("strategy", "sampling"))
        check_cull(options.get("cull", "none"))
        options["threads"] = check_threads(options.get("threads"), 1)
        if query == "hits":
            options["max_hits"] = check_max_hits(options.get("max_hits", 16))
        origins, directions, tmin, tmax, empty = check_rays(origins, directions, tmin, tmax)
        n = len(origins)
        mask = options.pop("mask", None)
        if mask is not None:
            checked = check_masks(mask, n, "mask", "ray")  # counts the batch's rays
            mask = checked if np.ndim(mask) else np.asarray(mask, np.uint32)
        if empty is not None:
            mask = hide_rays(None if mask is None else np.broadcast_to(mask, (n,)), empty, n)
        times = check_time(options.pop("time", None), n)
        try:
            nthreads = self.client.nthreads(callback_timeout=_seconds_left(deadline))
        except Exception as exc:  # the client closed, its scheduler gone or not answering
            raise ClusterError(f"the cluster is unreachable: {type(exc).__name__}: {exc}") from exc
        bounds = shard_bounds(n, sum(nthreads.values()), *self.shard_rays)
        shards = [
            (
                origins[a:b],
                directions[a:b],
                tmin[a:b],
                tmax[a:b],
                mask if mask is None or not mask.ndim else mask[a:b],
                None if times is None else times[a:b],
            )
            for a, b in zip(bounds[:-1], bounds[1:])
        ]
        try:
            answers = self._map(query, shards, options, bounds, nthreads, deadline)
        except ValueError:
            explain_bad_rays(origins, directions, tmin, tmax)  # names the batch's first bad ray
            raise
        return join(answers)

    def _map(self, query, shards, options, bounds, nthreads, deadline):
        """Each shard's answer, in order, by ``deadline`` (``time.monotonic``; None: no limit);
        lost shards are sent again."""
        client = self.client
        if client.status != "running":
            raise ClusterError(f"the dask client is {client.status}, not connected")
        answers = [None] * len(shards)
        tries = [0] * len(shards)
        clock = {"shards": len(shards), "send": 0.0, "trace": 0.0, "wall": time.perf_counter()}
        sent = {}  # future -> (shard index, the scattered rays it holds on to)
        done = distributed.as_completed(loop=client.loop, timeout=_seconds_left(deadline))

        # One slot per worker thread, the workers taking turns: shard i goes to slot i.
        slots = [
            w for k in range(max(nthreads.values(), default=0)) for w in nthreads if nthreads[w] > k
        ]

        def lost(i, failure):
            """Count a failed try of shard i; ClusterError past the retries."""
            tries[i] += 1
            if tries[i] > self.retries:
                raise ClusterError(
                    f"rays {bounds[i]}:{bounds[i + 1]} failed on the cluster "
                    f"({tries[i]} of {self.retries + 1} tries), last: "
                    f"{type(failure).__name__}: {failure}"
                ) from failure
            self.resent += 1

        def send(i):
            """Scatter shard i and trace it there: each shard is traced as soon as it has
            arrived, while the next ones are sent. A shard sent again goes wherever the
            scheduler likes (its slot's worker may be gone)."""
            if self._payload.status != "finished":
                self._send_triangles(_seconds_left(deadline))  # their only copy went with a worker
            while True:
                start = time.perf_counter()
                workers = [slots[i % len(slots)]] if slots and not tries[i] else None
                try:
                    [rays] = _within(
                        client,
                        _seconds_left(deadline),
                        client.scatter,
                        [shards[i]],
                        workers=workers,
                        hash=False,
                    )
                    break
                except distributed.TimeoutError:  # the deadline: no time to send it again
                    raise
                except (OSError, KeyError) as exc:  # that worker went away
                    lost(i, exc)
                    time.sleep(0.1 * tries[i])  # the scheduler has yet to notice
                finally:
                    clock["send"] += time.perf_counter() - start
            future = client.submit(
                _trace_shard, self.key, self._payload, query, rays, options, pure=False
            )
            sent[future] = (i, rays)
            done.add(future)

        try:
            for i in range(len(shards)):
                send(i)
            for future in done:
                i, _ = sent.pop(future)
                if future.status == "finished":
                    try:
                        answers[i], seconds = future.result()
                        clock["trace"] += seconds
                        continue
                    except Exception as exc:  # the answer went with its worker
                        failure = exc
                elif future.status == "error":
                    failure = future.exception()
                    if isinstance(failure, (ValueError, TypeError)):
                        raise failure  # the rays or the arguments: sending again will not help
                else:
                    failure = RuntimeError(f"shard {future.status}")
                lost(i, failure)
                send(i)
        except distributed.TimeoutError as exc:
            waited = time.perf_counter() - clock["wall"]
            if deadline is not None and time.monotonic() >= deadline:
                raise ClusterError(f"the batch took over {self.timeout} s on the cluster") from exc
            # not the batch's clock: a worker or the scheduler stopped answering mid-batch
            raise ClusterError(
                f"the cluster stopped answering after {waited:.1f} s: {type(exc).__name__}: {exc}"
            ) from exc
        except OSError as exc:
            raise ClusterError(f"the cluster is unreachable: {type(exc).__name__}: {exc}") from exc
        finally:
            for future in sent:
                with suppress(Exception):  # a closed client cannot cancel: the error above stands
                    future.cancel()
        clock["wall"] = time.perf_counter() - clock["wall"]
        self.last_query = clock
        return answers


def join(answers):
    """One answer from the answers of consecutive shards (HitList: offsets shifted)."""
    first = answers[0]
    stats = _merged_stats([a.stats for a in answers]) if first.stats is not None else None
    if len(answers) == 1:
        return first
    if isinstance(first, Hits):
        cat = {name: np.concatenate([getattr(a, name) for a in answers]) for name in HITS_FIELDS}
        return Hits(**cat, stats=stats)
    if isinstance(first, Occlusion):
        return Occlusion(np.concatenate([a.occluded for a in answers]), stats)
    if isinstance(first, Counts):
        return Counts(np.concatenate([a.count for a in answers]), stats)
    if isinstance(first, HitList):
        starts = np.cumsum([0] + [int(a.offsets[-1]) for a in answers[:-1]])
        offsets = np.concatenate(
            [answers[0].offsets[:1]] + [a.offsets[1:] + s for a, s in zip(answers, starts)]
        )
        cat = {name: np.concatenate([getattr(a, name) for a in answers]) for name in HITLIST_ROWS}
        return HitList(offsets, **cat, stats=stats)
    raise TypeError(f"cannot join answers of type {type(first).__name__}")


HITS_FIELDS = ("t", "mesh", "prim", "u", "v", "normal")
HITLIST_ROWS = ("t", "mesh", "prim", "u", "v", "normal", "truncated")


def _merged_stats(parts):
    """Counters of shards as one query's: summed, but triangles (the scene's) and max_depth."""
    merged = dict(parts[0])
    for part in parts[1:]:
        for name in STAT_NAMES:
            if name == "max_depth":
                merged[name] = max(merged[name], part[name])
            elif name != "triangles":
                merged[name] += part[name]
    return merged


__all__ = ["DistributedScene", "ClusterError", "shard_bounds"]
