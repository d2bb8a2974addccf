"""render core (no Drake)."""

import numba as _numba

# Compiled kernels run on OpenMP threads first (thread-safe for concurrent callers, e.g.
# dask workers); numba would otherwise try TBB first and warn about the older TBB that
# other wheels (Open3D) load into the process.
_numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
