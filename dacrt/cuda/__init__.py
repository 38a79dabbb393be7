"""The CUDA backend: ``closest``, ``occluded``, ``hits`` and ``count`` through Numba's CUDA
target, with the CPU engine's answers (tested under Numba's CUDA simulator only; unmeasured on
a GPU).

``dacrt.cuda.closest(scene, ...)`` is ``scene.closest(..., device="cuda")``.
"""

from .query import closest, count, hits, is_available, lacks, occluded

__all__ = ["closest", "count", "hits", "is_available", "lacks", "occluded"]
