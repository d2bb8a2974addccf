"""Dynamic scheduling of the compiled render kernels' rows over numba's threads.

A ``prange`` over the image rows hands each thread one fixed, contiguous share of the rows
(numba's OpenMP layer: static chunks, one per thread). On a machine shared with other jobs
the thread whose core is also running another process then finishes last and the frame
waits for it, while the other thread idles. The kernels here instead start one worker per
thread (``prange(nwork)``, ``nwork = workers()``) and each worker takes the next few rows
from a shared atomic counter until none are left, so a thread that gets less of its core simply
renders fewer rows.

A row's result never depends on which worker renders it (the workers share no state but
the counter), so frames stay bit-identical whatever the thread count or the load.

Usage: the caller passes ``nwork = workers()`` to a ``@numba.njit(parallel=True)`` kernel
that does::

    counter = np.zeros(1, np.int64)
    for _w in numba.prange(nwork):
        ...  # the worker's row buffers, allocated once
        row = -1
        end = 0
        while True:
            row += 1
            if row >= end:  # the next CHUNK rows
                row = fetch_add(counter, CHUNK)
                end = min(row + CHUNK, height)
            if row >= height:
                break
            ...  # one row (reset the buffers it reads before writing)
"""

from __future__ import annotations

import numba
from numba.core import types
from numba.extending import intrinsic

__all__ = ["fetch_add", "workers"]


@intrinsic
def fetch_add(typingctx, counter, n):
    """``old = counter[0]; counter[0] += n; return old`` as one atomic operation
    (``counter``: a C-contiguous int64 array; relaxed ordering, enough for a work
    counter: the rows' results are published by the end of the parallel region)."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64):
        return None
    if not isinstance(n, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        arr, v = args
        ary = context.make_array(signature.args[0])(context, builder, value=arr)
        v = context.cast(builder, v, signature.args[1], types.int64)
        return builder.atomic_rmw("add", ary.data, v, "monotonic")

    return types.int64(counter, n), codegen


def workers() -> int:
    """The number of workers a kernel should start: numba's thread count for the calling
    thread (at least 1). Passed in from Python: calling ``numba.get_num_threads`` in a
    kernel would keep numba from caching it."""
    return max(int(numba.get_num_threads()), 1)
