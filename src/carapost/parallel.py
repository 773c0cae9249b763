"""Run one task function over many numpy arrays on worker processes or threads.

A generic worker pool: it knows nothing about what the task computes. The arrays are
fetched one at a time on the calling thread (so a sequential reader, such as a video
decoder, needs no locking), handed to ``workers`` worker processes or threads, and the
results come back as a dict keyed like the inputs. Progress is reported on the calling
thread after every finished array, and the progress callback can cancel.

Worker processes (:class:`ProcessPool`) are started on first use and kept for later
batches: a new process costs ~0.3-0.5 s to import numpy, OpenCV and the task's module.
On Linux they are forked from a ``forkserver`` that has imported the ``preload``
modules once (they start in ~10 ms and never inherit the caller's threads, e.g. a GUI
toolkit's); elsewhere they are spawned. Arrays travel to the processes through one
shared-memory block with a slot per array in flight (a copy of ~0.1 ms instead of
~0.5 ms of pickling and pipe writes per 1280x720 image); an array larger than a slot
(another camera size) is pickled instead. Task functions and their arguments must be
picklable (module-level functions).

Worker processes never outlive the program: each one asks the kernel for SIGKILL when
its parent ends (Linux ``PR_SET_PDEATHSIG``) and watches its parent's pid (every
platform), so even a program killed with SIGKILL leaves no process behind; the
forkserver ends by itself when the program's end closes its pipe. A pool with no work
for ``idle_s`` seconds stops its processes, so a window left open does not hold their
memory (~120 MB each); the next batch starts new ones.

Examples
--------
>>> import numpy as np
>>> from carapost.parallel import map_arrays
>>> arrays = {k: np.full((4, 4), k) for k in range(5)}
>>> out = map_arrays(arrays.__getitem__, list(arrays), np.sum, workers=2)
>>> sorted((k, int(v)) for k, v in out.items())
[(0, 0), (1, 16), (2, 32), (3, 48), (4, 64)]
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import (
    FIRST_COMPLETED,
    Future,
    ProcessPoolExecutor,
    ThreadPoolExecutor,
    wait,
)
from multiprocessing.shared_memory import SharedMemory
from typing import Any, TypeVar

import numpy as np

__all__ = ["IDLE_SHUTDOWN_S", "ProcessPool", "lifeline", "map_arrays", "start_forkserver"]

K = TypeVar("K", bound=Hashable)
log = logging.getLogger("carapost.parallel")

#: Seconds without work after which a pool stops its worker processes.
IDLE_SHUTDOWN_S = 120.0
_PR_SET_PDEATHSIG = 1


def lifeline(parent: int | None = None, every_s: float = 0.5, *,
             pdeathsig: bool = True) -> None:
    """End this process as soon as its parent process ends.

    Called at the start of every worker process. On Linux the kernel sends SIGKILL
    when the parent ends (``prctl(PR_SET_PDEATHSIG)``; it is safe here because worker
    processes are forked by their parent's main thread); a daemon thread also checks
    every ``every_s`` seconds that the parent is still the one the process started with
    (any platform, and the case of a parent that died before the call).

    Parameters
    ----------
    parent : int, optional
        Pid of the parent to follow (default: the current parent).
    every_s : float
        Polling period of the watchdog thread (seconds).
    pdeathsig : bool
        Also ask the kernel (Linux); only valid when the parent's thread that started
        this process lives as long as the parent does.
    """
    parent = os.getppid() if parent is None else int(parent)
    if pdeathsig and sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no libc prctl
            pass
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(every_s)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="carapost-lifeline", daemon=True).start()


# The program sets this to its pid before it starts a forkserver; the forkserver imports
# this module (preload) and so follows the program with a watchdog. (No parent-death
# signal there: the forkserver may be started from a worker thread, and the kernel
# sends that signal when the starting *thread* ends.)
_PARENT_ENV = PARENT_PID_ENV = "CARAPOST_PARENT_PID"
#: True in the forkserver of the program's pools (and in a spawned worker where there is
#: no forkserver), and so also in every worker forked from it, which inherits the
#: module's state: a preload module may prepare there what every worker inherits.
IN_POOL_SERVER = os.environ.get(_PARENT_ENV) == str(os.getppid())
if IN_POOL_SERVER:
    lifeline(os.getppid(), pdeathsig=False)


def _init_worker(initializer: Callable[[], None] | None) -> None:
    """Initialiser of every pool process: the lifeline, then the pool's own."""
    lifeline()
    if initializer is not None:
        initializer()


class ProcessPool:
    """Worker processes kept from one batch to the next.

    Parameters
    ----------
    initializer : callable () -> None, optional
        Run once in every new worker process (module-level function), e.g. to set the
        number of library threads or to load compiled kernels.
    preload : sequence of str
        Modules the forkserver imports before it forks the workers (Linux). The
        forkserver is one per program: the preload list of the first pool started wins.

    Examples
    --------
    >>> import numpy as np
    >>> from carapost.parallel import ProcessPool, map_arrays
    >>> pool = ProcessPool(preload=["numpy"])
    >>> out = map_arrays(lambda k: np.arange(k + 1.0), range(3), np.sum, pool=pool)
    >>> sorted((k, float(v)) for k, v in out.items())
    [(0, 0.0), (1, 1.0), (2, 3.0)]
    >>> pool.shutdown()
    """

    def __init__(self, initializer: Callable[[], None] | None = None,
                 preload: Sequence[str] = (), idle_s: float | None = IDLE_SHUTDOWN_S
                 ) -> None:
        self._initializer = initializer
        self._preload = list(preload)
        self._lock = threading.Lock()
        self._executor: ProcessPoolExecutor | None = None
        self._workers = 0
        self.idle_s = idle_s
        self._users = 0  # batches running on the executor
        self._idle_timer: threading.Timer | None = None

    @property
    def running(self) -> bool:
        """Whether worker processes are up."""
        return self._executor is not None

    def pids(self) -> list[int]:
        """Pids of the worker processes (empty when none run)."""
        with self._lock:
            procs = getattr(self._executor, "_processes", None) or {}
            return sorted(int(p) for p in procs)

    def acquire(self, workers: int) -> ProcessPoolExecutor:
        """`executor` for one batch; call `release` when the batch is done (the idle
        shutdown counts from the last release)."""
        with self._lock:
            self._users += 1
            if self._idle_timer is not None:
                self._idle_timer.cancel()
                self._idle_timer = None
        try:
            return self.executor(workers)
        except BaseException:
            self.release()   # not acquired: the idle shutdown must still come
            raise

    def release(self) -> None:
        """A batch is done: stop the processes after ``idle_s`` seconds without work."""
        with self._lock:
            self._users = max(self._users - 1, 0)
            if self._users or self.idle_s is None or self._executor is None:
                return
            if self._idle_timer is not None:
                self._idle_timer.cancel()
            self._idle_timer = threading.Timer(self.idle_s, self._shutdown_if_idle)
            self._idle_timer.daemon = True
            self._idle_timer.start()

    def _shutdown_if_idle(self) -> None:
        with self._lock:
            if self._users or self._executor is None:
                return
            executor, self._executor = self._executor, None
            self._idle_timer = None
        executor.shutdown(wait=True, cancel_futures=True)

    def executor(self, workers: int) -> ProcessPoolExecutor:
        """The executor with ``workers`` processes: the running one, or a new one when
        none runs, the number of workers changed or a worker died."""
        with self._lock:
            if self._executor is not None and (
                    self._workers != workers or getattr(self._executor, "_broken", False)):
                self._executor.shutdown(wait=False, cancel_futures=True)
                self._executor = None
            if self._executor is None:
                ctx = _context(self._preload)
                self._executor = ProcessPoolExecutor(max_workers=workers, mp_context=ctx,
                                                     initializer=_init_worker,
                                                     initargs=(self._initializer,))
                self._workers = workers
            return self._executor

    def start(self, workers: int) -> threading.Thread:
        """Start ``workers`` processes in the background (a warm start), so that the
        next batch finds them ready instead of waiting for them to start.

        Returns at once; the returned (daemon) thread ends when every process has
        started and run its initialiser. The idle shutdown counts from then, as after a
        batch. Starting a pool that already runs ``workers`` processes only restarts its
        idle countdown.
        """
        def work() -> None:
            try:
                executor = self.acquire(workers)
            except Exception:  # not acquired: nothing to release; the next batch reports
                log.debug("warm start of the worker processes failed", exc_info=True)
                return
            try:
                # One short task per process: a submit that finds no idle process
                # starts one, and each task outlasts the next submit.
                wait([executor.submit(time.sleep, 0.05) for _ in range(workers)])
            except Exception:  # the next batch reports a broken pool
                log.debug("warm start of the worker processes failed", exc_info=True)
            finally:
                self.release()

        thread = threading.Thread(target=work, name="carapost-pool-start", daemon=True)
        thread.start()
        return thread

    def shutdown(self) -> None:
        """Stop the worker processes (a later batch starts new ones)."""
        with self._lock:
            if self._idle_timer is not None:
                self._idle_timer.cancel()
                self._idle_timer = None
            if self._executor is not None:
                self._executor.shutdown(wait=True, cancel_futures=True)
                self._executor = None


def _context(preload: Sequence[str]) -> Any:
    """The multiprocessing context of pool processes: the forkserver, importing
    ``preload`` (Linux), else spawn."""
    os.environ[_PARENT_ENV] = str(os.getpid())
    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(["carapost.parallel", *preload])
        return ctx
    return mp.get_context("spawn")


def start_forkserver(preload: Sequence[str]) -> bool:
    """Launch the program's forkserver, which then imports the ``preload`` modules in
    its own process (returns once it is launched; False where pool processes are
    spawned, not forked, or it could not be launched).

    The forkserver's imports are most of a worker's start-up (for the blob detector
    ~1.3 s of a core: numpy, OpenCV, numba and its compiled kernels) and are paid once
    per program; workers forked from it later start in milliseconds. A program calls
    this when it starts, before there is work the start-up would slow down. The
    forkserver is one per program: the ``preload`` of the first launch wins, so it
    must be the one of the pool that will use it. Nothing is imported here.
    """
    if "forkserver" not in mp.get_all_start_methods():
        return False
    try:
        from multiprocessing import forkserver

        _context(preload)
        forkserver.ensure_running()
    except Exception:  # the first batch starts it, and reports what fails
        log.debug("starting the forkserver failed", exc_info=True)
        return False
    return True


#: Shared-memory blocks this worker process has attached (name -> SharedMemory).
_ATTACHED: dict[str, SharedMemory] = {}


def _attach(item: np.ndarray | tuple) -> np.ndarray:
    """The array of one work item in a worker process: the array itself, or a view of
    (shared-memory block name, byte offset, shape, dtype) that the caller copied."""
    if not isinstance(item, tuple):
        return item
    name, offset, shape, dtype = item
    shm = _ATTACHED.get(name)
    if shm is None:
        # A new batch: let go of the previous batch's block (already unlinked).
        for old in _ATTACHED.values():
            try:
                old.close()
            except BufferError:  # pragma: no cover - no array refers to it here
                pass
        _ATTACHED.clear()
        shm = _ATTACHED[name] = SharedMemory(name=name)
    return np.ndarray(shape, dtype, buffer=shm.buf, offset=offset)


def _run_items(task: Callable[..., Any], items: list, args: tuple) -> list:
    """Run ``task(array, *args)`` on the arrays of one process task, in order."""
    return [task(_attach(item), *args) for item in items]


def map_arrays(
    get_array: Callable[[K], np.ndarray],
    keys: Sequence[K],
    task: Callable[..., Any],
    args: tuple = (),
    *,
    workers: int = 2,
    pool: ProcessPool | None = None,
    chunk: int = 1,
    check: Callable[[np.ndarray], None] | None = None,
    progress: Callable[[int, int], bool] | None = None,
    thread_name_prefix: str = "carapost",
) -> dict[K, Any]:
    """``task(get_array(key), *args)`` for every key, on worker processes or threads.

    Parameters
    ----------
    get_array : callable key -> ndarray
        Called on the calling thread only, in the order of ``keys``.
    keys : sequence of hashable
    task : callable (array, *args) -> result
        Module-level (picklable) when ``pool`` is given.
    args : tuple
        Further arguments of every call (pickled with every process task).
    workers : int
        Number of worker processes or threads; at least 1.
    pool : ProcessPool, optional
        Run on its processes; default: on ``workers`` threads started for this call.
    chunk : int
        Arrays per process task: each task costs the caller's executor threads ~0.5 ms
        of CPU (pipes, wake-ups), so tasks of several arrays amortise it. Threads take
        one array per task.
    check : callable (array) -> None, optional
        Called on the calling thread before an array is sent to a process, to raise a
        clear error there (a bad array otherwise fails in the worker).
    progress : callable (done, total) -> bool, optional
        Called on the calling thread after each finished array, and before each array
        is read (with the count unchanged, so a Cancel is seen while slow reads fill
        the queue); returning False cancels: no new arrays are read or started, the
        ones in flight finish, and what is done is returned.
    thread_name_prefix : str
        Name of the worker threads.

    Returns
    -------
    dict key -> result
        Finished arrays only (all of them unless cancelled), in order of completion.

    Raises
    ------
    ValueError
        If ``workers`` or ``chunk`` is below 1.
    Exception
        The first error of ``get_array``, ``check`` or ``task``, after the arrays in
        flight have finished.
    """
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    if chunk < 1:
        raise ValueError(f"chunk must be at least 1, got {chunk}")
    keys = list(keys)
    total = len(keys)
    results: dict[K, Any] = {}
    if total == 0:
        return results
    processes = pool is not None
    cancelled = False
    # Keep a bounded number of tasks in flight so memory stays flat on long batches.
    chunk = chunk if processes else 1
    max_in_flight = 2 * workers
    thread_pool = None
    shm = None
    if pool is not None:
        executor = pool.acquire(workers)
        free_slots: list[int] = list(range(max_in_flight * chunk))
        slot_of: dict[Future, list[int]] = {}
        slot_bytes = 0
    else:
        executor = thread_pool = ThreadPoolExecutor(max_workers=workers,
                                                    thread_name_prefix=thread_name_prefix)
    pending: dict[Future, list[K]] = {}
    try:
        it = iter(keys)
        exhausted = False
        while True:
            while not exhausted and not cancelled and len(pending) < max_in_flight:
                task_keys: list[K] = []
                items: list[np.ndarray | tuple] = []
                slots: list[int] = []
                while len(task_keys) < chunk:
                    # reading an image can be slow (a decode, a network share): a
                    # Cancel pressed while the queue fills stops it here, not after
                    # every image in flight has been read and processed
                    if progress is not None and progress(len(results), total) is False:
                        cancelled = True
                        break
                    try:
                        key = next(it)
                    except StopIteration:
                        exhausted = True
                        break
                    arr = get_array(key)
                    task_keys.append(key)
                    if not processes:
                        items.append(arr)
                        continue
                    if check is not None:
                        check(arr)
                    if not isinstance(arr, np.ndarray):
                        items.append(arr)
                        continue
                    if shm is None:
                        slot_bytes = max(arr.nbytes, 1)
                        shm = SharedMemory(create=True,
                                           size=max_in_flight * chunk * slot_bytes)
                    if arr.nbytes <= slot_bytes:
                        slot = free_slots.pop()
                        view = np.ndarray(arr.shape, arr.dtype, buffer=shm.buf,
                                          offset=slot * slot_bytes)
                        view[...] = arr
                        del view  # no array may refer to the block when it is closed
                        items.append((shm.name, slot * slot_bytes, arr.shape, arr.dtype.str))
                        slots.append(slot)
                    else:
                        items.append(arr)
                if not task_keys:
                    break
                if processes:
                    fut = executor.submit(_run_items, task, items, args)
                    slot_of[fut] = slots
                else:
                    fut = executor.submit(task, items[0], *args)
                pending[fut] = task_keys
            if not pending:
                break
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                task_keys = pending.pop(fut)
                if processes:
                    free_slots.extend(slot_of.pop(fut))
                    found = fut.result()
                else:
                    found = [fut.result()]
                for key, res in zip(task_keys, found, strict=True):
                    results[key] = res
                    if progress is not None and not cancelled:
                        if progress(len(results), total) is False:
                            cancelled = True
    finally:
        if thread_pool is not None:
            thread_pool.shutdown(wait=True)
        elif pending:
            # An error: let the arrays in flight finish before the pool is reused.
            wait(pending)
        if shm is not None:
            shm.close()
            shm.unlink()
        if pool is not None:
            pool.release()
    return results
