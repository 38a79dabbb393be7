"""The dask LocalCluster that the cluster tests run on."""

import logging
import os
import signal
import socket
import subprocess
import sys
from contextlib import suppress
from pathlib import Path

import distributed
import numpy as np

REPO = Path(__file__).resolve().parent.parent


def two_worker_cluster():
    """2 worker processes of 1 thread. When this process files Numba's kernels as the service
    does (``dacrt.cache.use_cache_dir``, called by the service tests' apps), the workers do too,
    in the same folder: they load the kernels compiled here rather than compile them again."""
    cache = sys.modules.get("dacrt.cache")
    cache_dir = cache.cache_dir() if cache is not None else None
    return distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":0",  # never a fixed port: other clusters may run
        silence_logs=logging.CRITICAL,
        preload=["dacrt.cache"] if cache_dir is not None else [],
        env={"DACRT_CACHE_DIR": str(cache_dir)} if cache_dir is not None else {},
    )


class ProcessCluster:
    """A dask scheduler and one worker of one thread, each a process of its own started as
    docs/cluster.md starts them (``dask scheduler``, ``dask worker ... --nthreads 1 --preload
    dacrt.cache``; the worker without a nanny, so that its pid is the worker's), so that a test
    can stop either with SIGSTOP: a frozen host, whose connections stay open. The worker has
    built a Scene and loaded the kernels of ``closest`` once the cluster is started."""

    def __init__(self) -> None:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        self.address = f"tcp://127.0.0.1:{port}"
        cache = sys.modules.get("dacrt.cache")
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join(
                [str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])]
            ),
        }
        if cache is not None:
            env["DACRT_CACHE_DIR"] = str(cache.cache_dir())
        self.scheduler = _start("dask_scheduler", ["--host", "127.0.0.1", "--port", str(port)], env)
        self.worker = _start(
            "dask_worker",
            [self.address, "--nthreads", "1", "--no-nanny", "--preload", "dacrt.cache"],
            env,
        )
        try:
            self._warm_up()
        except BaseException:
            self.close()
            raise

    def _warm_up(self) -> None:
        from dacrt.distributed import DistributedScene

        vertices = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
        faces = np.int32([[0, 1, 2]])
        with distributed.Client(self.address, timeout=60, set_as_default=False) as client:
            client.wait_for_workers(1, timeout=120)
            with DistributedScene(client, [(vertices, faces)]) as scene:
                scene.closest(np.float32([[0.2, 0.2, 1]]), np.float32([[0, 0, -1]]))

    def close(self) -> None:
        for process in (self.worker, self.scheduler):
            with suppress(ProcessLookupError):
                process.send_signal(signal.SIGCONT)
                process.terminate()
        for process in (self.worker, self.scheduler):
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def _start(program: str, arguments: list[str], env: dict[str, str]) -> subprocess.Popen:
    """``dask scheduler`` or ``dask worker`` (``program``: its module in ``distributed.cli``)."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            f"distributed.cli.{program}",
            *arguments,
            "--dashboard-address",
            ":0",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        cwd=REPO,
    )
