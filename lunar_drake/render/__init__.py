"""render core (no Drake)."""

import os as _os

import numba as _numba

# Compiled kernels run on OpenMP threads first (thread-safe for concurrent callers, e.g.
# dask workers); numba would otherwise try TBB first and warn about the older TBB that
# other wheels (Open3D) load into the process.
_numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]


def _load_openmp_with_sleeping_idle_threads() -> None:
    """Loads numba's OpenMP runtime now, with ``OMP_WAIT_POLICY=PASSIVE`` set for that
    moment only (unless the environment sets it): its idle threads then sleep instead of
    spinning.

    GNU OpenMP's default keeps an idle thread spinning for ~300k ``pause`` loops after
    every parallel region: several ms on AMD Zen, where ``pause`` is slow. A camera frame
    runs a handful of parallel kernels with Python work between them, and on a machine
    shared with other jobs the spinning thread took the core that the rest of the frame
    (or the other thread) needed: a 1280 x 960 frame cost 25-35 % more CPU time
    (docs/lighting.md). libgomp reads the variable once, when it is loaded; importing
    numba's OpenMP module loads it without starting any thread (fork-safe as before).
    Other OpenMP runtimes in the process (Drake's own copy of libgomp) keep their
    settings. No effect where numba's libgomp was loaded before this import."""
    key = "OMP_WAIT_POLICY"
    if key in _os.environ:
        return
    _os.environ[key] = "PASSIVE"
    try:
        from numba.np.ufunc import omppool  # noqa: F401
    except ImportError:  # no OpenMP layer: numba uses another
        pass
    finally:
        _os.environ.pop(key, None)


_load_openmp_with_sleeping_idle_threads()
