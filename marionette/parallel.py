"""Loops shared among threads: a numba kernel compiled with ``nogil=True``, run on a pool of threads.

Why not ``prange``: numba compiles a ``prange`` loop's body twice (as a plain function and again inside
the parallel loop), and the parallel-loop passes are slow on large bodies: on a fresh install that
compilation would be most of the first run's time (``docs/benchmarks/first_run.md``). A ``nogil`` kernel
compiles once and runs as fast, its items dealt out here.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

__all__ = ["CHUNK", "chunks", "parallel_for"]

#: Elements per item of an element-wise loop: each thread writes whole runs of rows (no two threads share a
#: cache line but at a run's ends), and two threads still get many items each.
CHUNK = 1024

_pool: ThreadPoolExecutor | None = None
_pool_size = 0
_pool_lock = threading.Lock()


def _reset_after_fork() -> None:
    global _pool, _pool_size
    _pool, _pool_size = None, 0  # a forked child has none of the pool's threads


os.register_at_fork(after_in_child=_reset_after_fork)


def _workers(count: int) -> ThreadPoolExecutor:
    """A pool of at least ``count`` threads (grown, never shrunk: idle threads cost nothing)."""
    global _pool, _pool_size
    with _pool_lock:
        if _pool is None or _pool_size < count:
            _pool, _pool_size = ThreadPoolExecutor(max_workers=count, thread_name_prefix="marionette"), count
        return _pool


def chunks(n: int, size: int = CHUNK) -> int:
    """How many items of ``size`` elements cover ``n`` elements (item ``c``: ``c size .. min(n, (c + 1) size) - 1``)."""
    return (n + size - 1) // size


def parallel_for(kernel, n: int, *args) -> None:
    """Run ``kernel(first, step, n, *args)`` once per thread: thread ``i`` of ``threads`` does items
    ``i, i + threads, i + 2 threads, ...`` of ``0 .. n - 1``.

    ``threads`` is ``numba.get_num_threads()`` (``NUMBA_NUM_THREADS``, ``numba.set_num_threads``), at
    most ``n``. Interleaving spreads neighbouring items, which tend to cost alike (tiles of one object,
    chunks of one region), over the threads. The calling thread does share 0; the kernel must release
    the GIL (``nogil=True``) and the shares must write disjoint outputs, so the result does not depend
    on the thread count.
    """
    threads = max(1, min(numba.get_num_threads(), n))
    if threads == 1:
        kernel(0, 1, n, *args)
        return
    pool = _workers(threads - 1)
    futures = [pool.submit(kernel, i, threads, n, *args) for i in range(1, threads)]
    try:
        kernel(0, threads, n, *args)
    finally:
        for future in futures:
            future.result()
