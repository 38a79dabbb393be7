"""Compile every dacrt.cuda kernel to PTX for sm_90 without a GPU (numba-cuda with its NVVM,
``pip install "numba-cuda[cu12]"``) and check that no float64 product was fused into an FMA:
the device then computes the watertight test with the CPU engine's roundings. Prints one line
a kernel and ``ok``; exits 1 on a fused product."""

import re
import sys
import types

import numba.cuda.dispatcher as dispatcher
from numba import cuda
from numba import types as nt

# Device functions compile for the current device's capability: with no GPU, say sm_90.
dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=(9, 0))

from dacrt.cuda import kernels  # noqa: E402


def array(dtype, ndim=1):
    return nt.Array(dtype, ndim, "C")


I8, I32, I64, U8, U32, U64 = (
    array(t) for t in (nt.int8, nt.int32, nt.int64, nt.uint8, nt.uint32, nt.uint64)
)
U64_2 = array(nt.uint64, 2)
F32, F32_2 = array(nt.float32), array(nt.float32, 2)
TRI = (I32, I32, I8, I64, I64, I32, F32)
RAY_LEAF = (I32, I32, I8, I64, I64, I32, F32_2, F32_2, F32, F32, F32_2)
SIGNATURES = {
    "count_first_side": (*TRI, F32_2, I64),
    "child_boxes": (*TRI, F32_2, F32_2, F32_2),
    "count_child_rays": (I32, I32, I8, F32_2, F32_2, F32, F32, F32_2, I8, I64),
    "scatter_triangles": (*TRI, F32_2, I64, I64, I64, I32, I32),
    "scatter_rays": (I32, I32, I8, I64, I64, I64, I32, I32),
    "leaf_closest": (*RAY_LEAF, I32, U32, U32, nt.float64, U64),
    "leaf_any": (*RAY_LEAF, U32, U32, nt.float64, U8),
    "leaf_crossings": (*RAY_LEAF, I32, U32, U32, nt.float64, I32, U64_2),
    "finish_best": (U64, I32, F32_2, F32_2, F32_2, nt.int64, F32, I32, F32, F32),
}


def main():
    fused = 0
    for name, signature in SIGNATURES.items():
        ptx, _ = cuda.compile_ptx(getattr(kernels, name).py_func, signature, cc=(9, 0))
        n_fma = len(re.findall(r"fma\.rn\.f64", ptx))
        n_mul = len(re.findall(r"mul\.rn\.f64", ptx))
        print(f"{name}: compiled, {n_mul} unfused float64 products, {n_fma} float64 FMAs")
        fused += n_fma
    if fused:
        sys.exit(1)
    print("ok")


if __name__ == "__main__":
    main()
