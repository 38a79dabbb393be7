"""One decorator policy for every kernel, and the engine's tuning constants.

Kernels are compiled with ``cache=True`` (compiled once per machine), ``nogil=True`` (ray chunks
run on Python threads side by side) and ``error_model="numpy"`` (division by zero gives inf, no
exception check). No fastmath: the slab test relies on IEEE infinities, and contraction into FMA
could give one ray-triangle pair two different ``t`` in two call sites, which would break the
promise that every strategy gives the same answer.
"""

import numba

jit = numba.njit(cache=True, nogil=True, boundscheck=False, error_model="numpy")
inline = numba.njit(cache=True, nogil=True, boundscheck=False, error_model="numpy", inline="always")

# Binned splits: 16 bins (Nabata et al. 2013, Sec. 5: 32): most binned nodes hold few triangles,
# and each pays per bin.
N_BINS = 16
# Ray sampling: 100 sample rays (the paper's count), only when more than 5,000 rays are active
# (the paper: 1,000): below that, a node's sample box tests cost more than the better split saves.
N_SAMPLE_RAYS = 100
MIN_RAYS_TO_SAMPLE = 5000
# ... and for occlusion rays only above 10,000: a ray that stops at its first hit does less work
# below a node than the sampled cost counts.
MIN_OCCLUSION_RAYS_TO_SAMPLE = 10000
# Fewer sample rays choose the split axis: it needs three means, not every candidate's counts.
AXIS_SAMPLE_RAYS = 32
# Afra's rule: use the cost function only when rays / triangles exceeds this, else split in the
# middle.
RAYS_PER_TRIANGLE_FOR_COST = 1.5
# Leaves: brute force a node of R rays and T triangles when R*T <= LEAF_C_R*R + LEAF_C_T*T, its
# R*T tests against what going on would cost, counted in tests: filtering each ray, binning and
# partitioning each triangle. Always so at T <= LEAF_C_R or R <= LEAF_C_T.
LEAF_C_R = 4
LEAF_C_T = 16
# Ray-space hierarchy termination R*G < C_r*R + C_g*G.
RAYSPACE_C_R = 16.0
RAYSPACE_C_G = 16.0
# A ray-space leaf with more triangles than this goes on with object splits instead.
RAYSPACE_LEAF_TRIANGLES = 64
# ... and so does a node, at this depth or deeper, whose frustum kept more than this fraction of
# its parent's triangles (rays too incoherent for ray-space splits to pay).
RAYSPACE_MIN_DEPTH_TO_GIVE_UP = 8
RAYSPACE_KEPT_TO_GIVE_UP = 0.8
# ... at any depth when the rays' origins spread over more than this fraction of the scene
# (secondary and random rays): each hand-off re-partitions the triangles, so hand off early.
RAYSPACE_ORIGIN_SPREAD_TO_GIVE_UP = 0.1
# Cost of a ray-box test over a ray-triangle test (C_bv / C_tri of Eq. 5), as measured here: a
# vectorised filter step against a watertight triangle test.
BOX_TO_TRIANGLE_COST = 0.25
# Deepest node; below it a node is brute-forced (keeps the explicit stack small and bounded).
MAX_DEPTH = 64
# SAH constants (C_T: node, C_I: triangle), as ratios.
SAH_C_T = 1.0
SAH_C_I = 1.0
# A box is culled only when its entry is beyond the ray's best t by more than this (relative):
# keeps culling conservative with respect to the rounding of triangle t.
CULL_MARGIN = 1e-5
# pbrt's robust slab test: grow the exit distance by 1 + 2*gamma(3) for float32.
SLAB_GROWTH = 1.0 + 2.0 * (3 * 2.0**-24) / (1 - 3 * 2.0**-24)
