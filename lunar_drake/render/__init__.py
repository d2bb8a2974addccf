"""render core (no Drake)."""

import os as _os

import numba as _numba

# Compiled kernels run on OpenMP threads first (thread-safe for concurrent callers, e.g.
# dask workers); numba would otherwise try TBB first and warn about the older TBB that
# other wheels (Open3D) load into the process.
_numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]

# Idle OpenMP threads sleep instead of spinning (GNU OpenMP's default spins ~300k `pause`
# loops after every parallel region, several ms on AMD Zen, where `pause` is slow). A
# frame runs a handful of parallel kernels with Python work between them: on a machine
# shared with other jobs the spinning thread took the core that the rest of the frame (or
# the other thread) needed, and a 1280 x 960 camera frame ran 25-35 % slower (measured on
# 2 busy cores). Read when numba first loads libgomp (its first parallel kernel); an
# explicit setting in the environment wins. See docs/lighting.md.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
