"""marionette.parallel: every item once, on any thread count, errors raised, and a forked child still runs."""

import multiprocessing

import numba
import numpy as np
import pytest

from marionette.parallel import CHUNK, chunks, parallel_for


@numba.njit(nogil=True)
def _mark(first, step, n, visits, share):
    for i in range(first, n, step):
        visits[i] += 1
        share[i] = first


@numba.njit(nogil=True)
def _fail_on(first, step, n, bad):
    for i in range(first, n, step):
        if i == bad:
            raise ValueError("item failed")


@pytest.fixture
def threads():
    def use(count):
        numba.set_num_threads(count)
    before = numba.get_num_threads()
    yield use
    numba.set_num_threads(before)


@pytest.mark.parametrize("n", [0, 1, 2, 5, 64])
def test_every_item_is_visited_once_whatever_the_thread_count(threads, n):
    for count in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
        threads(count)
        visits, share = np.zeros(n, np.int64), np.full(n, -1, np.int64)
        parallel_for(_mark, n, visits, share)
        assert np.all(visits == 1)
        used = min(count, max(n, 1))
        assert np.array_equal(share, np.arange(n) % used)  # interleaved: thread i takes i, i + used, ...


def test_an_error_in_any_share_is_raised(threads):
    threads(min(2, numba.config.NUMBA_NUM_THREADS))
    for bad in (0, 1):  # the calling thread's share, then the other's (when there are two)
        with pytest.raises(ValueError, match="item failed"):
            parallel_for(_fail_on, 8, bad)


def _in_child(queue):
    visits, share = np.zeros(10, np.int64), np.zeros(10, np.int64)
    parallel_for(_mark, 10, visits, share)
    queue.put(int(visits.sum()))


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="no fork on this platform")
def test_a_forked_child_gets_a_pool_of_its_own(threads):
    threads(min(2, numba.config.NUMBA_NUM_THREADS))
    parallel_for(_mark, 10, np.zeros(10, np.int64), np.zeros(10, np.int64))  # the parent's pool exists
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_in_child, args=(queue,))
    child.start()
    child.join(timeout=60)
    assert child.exitcode == 0 and queue.get(timeout=1) == 10


def test_chunks_cover_the_elements():
    assert [chunks(n) for n in (0, 1, CHUNK, CHUNK + 1)] == [0, 1, 1, 2]
    assert chunks(130, 64) == 3
