"""Device-function decorator and float64 products that never fuse into FMA.

NVVM contracts a*b + c into one FMA by default; the CPU engine never does, so every product of
the watertight test goes through libdevice's round-to-nearest multiply on the device. Under the
simulator (``NUMBA_ENABLE_CUDASIM=1``) the kernels are Python and a plain product is the same.
"""

from numba import config, cuda

# Small functions inlined into the kernels.
device = cuda.jit(device=True)

if config.ENABLE_CUDASIM:

    def mul(a, b):
        """a * b in float64, rounded once."""
        return a * b

else:  # pragma: no cover - needs a GPU
    from numba.cuda import libdevice

    @device
    def mul(a, b):
        """a * b in float64, rounded once: __dmul_rn is never contracted into an FMA."""
        return libdevice.dmul_rn(a, b)
