"""Tests for carapost.parallel (the generic worker pool) and carapost._runtime."""

from __future__ import annotations

import numpy as np
import pytest

from carapost import parallel
from carapost._runtime import keep_freed_memory


@pytest.fixture(scope="module")
def pool():
    p = parallel.ProcessPool(preload=["numpy"])
    yield p
    p.shutdown()


def _arrays(n: int) -> dict[int, np.ndarray]:
    # Every third array is larger than the first one (the slot size): it is pickled
    # instead of copied into shared memory.
    return {k: np.full((8, 8) if k % 3 == 2 else (4, 4), float(k)) for k in range(n)}


@pytest.mark.parametrize("processes", [False, True])
def test_results_progress_and_order_of_fetching(pool, processes):
    arrays = _arrays(11)
    fetched, seen = [], []

    def get(k):
        fetched.append(k)
        return arrays[k]

    out = parallel.map_arrays(get, list(arrays), np.sum, workers=2,
                              pool=pool if processes else None, chunk=3,
                              progress=lambda done, total: seen.append((done, total)))
    assert fetched == list(arrays)  # on the calling thread, in order
    assert {k: float(v) for k, v in out.items()} == {k: float(a.sum())
                                                      for k, a in arrays.items()}
    # once per finished array, and again (same count) before each read
    assert seen == sorted(seen) and seen[-1] == (11, 11)
    assert sorted(set(seen)) == [(i, 11) for i in range(12)]


def test_task_arguments_reach_the_workers(pool):
    out = parallel.map_arrays(lambda k: np.arange(4.0) + k, range(5), np.round, (1,),
                              pool=pool)
    assert sorted(out) == list(range(5))
    np.testing.assert_array_equal(out[3], [3.0, 4.0, 5.0, 6.0])


def test_cancel_keeps_finished_arrays():
    calls = []

    def progress(done, total):
        calls.append(done)
        return done < 3

    out = parallel.map_arrays(lambda k: np.zeros(3), range(50), np.sum, workers=2,
                              progress=progress)
    assert 3 <= len(out) < 50
    assert calls[-1] == 3  # no progress after the cancel


def test_errors_of_check_and_task_reach_the_caller(pool):
    def check(a):
        if a.ndim != 2:
            raise ValueError("not 2-D")

    with pytest.raises(ValueError, match="not 2-D"):
        parallel.map_arrays(lambda k: np.zeros(3), range(3), np.sum, pool=pool, check=check)
    with pytest.raises(np.linalg.LinAlgError):
        parallel.map_arrays(lambda k: np.zeros((2, 3)), range(3), np.linalg.inv, pool=pool)
    # The pool still works after the errors.
    out = parallel.map_arrays(lambda k: np.ones((2, 2)), range(3), np.sum, pool=pool)
    assert {float(v) for v in out.values()} == {4.0}


def test_empty_and_bad_arguments():
    assert parallel.map_arrays(lambda k: None, [], np.sum) == {}
    with pytest.raises(ValueError, match="workers"):
        parallel.map_arrays(lambda k: None, [1], np.sum, workers=0)
    with pytest.raises(ValueError, match="chunk"):
        parallel.map_arrays(lambda k: None, [1], np.sum, chunk=0)


def test_pool_restarts_with_another_number_of_workers(pool):
    first = pool.executor(2)
    assert pool.executor(2) is first
    assert pool.executor(1) is not first
    out = parallel.map_arrays(lambda k: np.ones(2), range(4), np.sum, workers=1, pool=pool)
    assert len(out) == 4


def test_keep_freed_memory_is_applied_once():
    first = keep_freed_memory()
    assert keep_freed_memory() is first


@pytest.mark.parametrize("module", ["carapost.parallel", "carapost._runtime"])
def test_examples_of_the_docstrings(module):
    # These modules are outside the doctest paths of the pytest configuration.
    import doctest
    import importlib

    res = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS)
    assert res.attempted > 0 and res.failed == 0


def test_cancel_while_slow_reads_fill_the_queue_stops_reading():
    """A Cancel that comes while images are still being read (a slow decoder) stops
    the reading: not every image in flight is read first."""
    import time

    fetched = []
    state = {"cancel": False}

    def slow_get(k):
        fetched.append(k)
        if k == 2:
            state["cancel"] = True  # pressed while the third image is read
        time.sleep(0.01)
        return np.zeros(3)

    out = parallel.map_arrays(slow_get, range(40), np.sum, workers=2,
                              progress=lambda done, total: not state["cancel"])
    assert fetched == [0, 1, 2] and sorted(out) == [0, 1, 2]


def test_start_warms_the_processes_in_the_background_and_the_idle_shutdown_follows():
    import time

    pool = parallel.ProcessPool(preload=["numpy"], idle_s=1.0)
    try:
        t0 = time.perf_counter()
        thread = pool.start(2)
        assert time.perf_counter() - t0 < 0.5  # the caller does not wait for them
        thread.join(60)
        assert not thread.is_alive() and len(pool.pids()) == 2
        pids = pool.pids()
        out = parallel.map_arrays(lambda k: np.ones(3), range(4), np.sum, workers=2,
                                  pool=pool)
        assert out == {k: 3.0 for k in range(4)} and pool.pids() == pids  # the warm ones
        deadline = time.perf_counter() + 30
        while pool.running and time.perf_counter() < deadline:
            time.sleep(0.05)
        assert not pool.running  # stopped after idle_s without work
    finally:
        pool.shutdown()



_SERVER_CHILD = """
import multiprocessing.forkserver as fs
import os
from carapost import parallel
if __name__ == "__main__":
    pool = parallel.ProcessPool(preload=["numpy"], idle_s=None)
    assert fs._forkserver._forkserver_pid is None
    assert parallel.start_forkserver(["numpy"]) is True
    server = fs._forkserver._forkserver_pid
    os.kill(server, 0)  # launched, and alive
    # the workers come from that forkserver: their parent is it
    print(server, pool.executor(1).submit(os.getppid).result())
    pool.shutdown()
"""


@pytest.mark.skipif("forkserver" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="the forkserver is Linux's")
def test_start_server_launches_the_forkserver_the_workers_come_from(tmp_path):
    """`start_forkserver` launches the forkserver before any batch (a fresh program:
    the forkserver is one per program), and a pool with that preload forks its workers
    from it."""
    import subprocess
    import sys

    script = tmp_path / "child.py"
    script.write_text(_SERVER_CHILD)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()
    assert out[0] == out[1]
