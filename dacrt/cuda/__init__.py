"""The CUDA backend: ``closest``, ``occluded``, ``hits`` and ``count`` through Numba's CUDA
target, with the CPU engine's answers (tested under Numba's CUDA simulator only; unmeasured on
a GPU).

``dacrt.cuda.closest(scene, ...)`` is ``scene.closest(..., device="cuda")``.
"""

from numba import cuda

from .query import closest, count, hits, lacks, occluded


def is_available() -> bool:
    """Whether a CUDA GPU (or the simulator, ``NUMBA_ENABLE_CUDASIM=1``) can run the kernels."""
    try:
        return bool(cuda.is_available())
    except Exception:  # a driver that fails to load means no GPU
        return False


__all__ = ["closest", "count", "hits", "is_available", "lacks", "occluded"]
