"""The dask LocalCluster that the cluster tests run on."""

import logging
import sys

import distributed


def two_worker_cluster():
    """2 worker processes of 1 thread. When this process files Numba's kernels as the service
    does (``service.cache``, imported by the service tests), the workers do too: they load the
    kernels compiled here rather than compile them again."""
    return distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        dashboard_address=":0",  # never a fixed port: other clusters may run
        silence_logs=logging.CRITICAL,
        preload=["service"] if "service" in sys.modules else [],
    )
