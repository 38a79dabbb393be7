"""Device-function decorator, float64 products that never fuse into FMA, and float32 bits.

NVVM contracts a*b + c into one FMA by default; the CPU engine never does, so every product of
the watertight test goes through libdevice's round-to-nearest multiply on the device. Under the
simulator (``NUMBA_ENABLE_CUDASIM=1``) the kernels are Python and a plain product is the same.
"""

from numba import config, cuda

# Small functions inlined into the kernels.
device = cuda.jit(device=True)

if config.ENABLE_CUDASIM:
    import numpy as np

    def mul(a, b):
        """a * b in float64, rounded once."""
        return a * b

    def float_bits(x):
        """The bits of float32 x (the caller keeps the low 32)."""
        return np.float32(x).view(np.uint32)

else:  # pragma: no cover - needs a GPU
    from numba.cuda import libdevice

    @device
    def mul(a, b):
        """a * b in float64, rounded once: __dmul_rn is never contracted into an FMA."""
        return libdevice.dmul_rn(a, b)

    @device
    def float_bits(x):
        """The bits of float32 x as an int32 (the caller keeps the low 32)."""
        return libdevice.float_as_int(x)
