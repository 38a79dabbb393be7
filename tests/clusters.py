"""The dask LocalCluster that the cluster tests run on."""

import logging
import sys

import distributed


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
