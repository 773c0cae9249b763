"""The local Dask cluster of `carapost.batch`: workers forked from a fork server that
has imported a take's modules, one thread each, the batch starting on the first worker.

See `carapost.batch` (this is its machinery, in a module of its own for size).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

log = logging.getLogger("carapost.batch")

__all__ = ["LOCAL_CLUSTER_CONFIG", "WORKER_PRELOAD", "WORKER_START_TIMEOUT",
           "WORKER_THREADS_ENV", "local_cluster", "start_fork_server", "stop_fork_server"]


#: Modules a take imports (the pipeline imports its machinery lazily, so that
#: ``carapost --help`` stays instant), imported once by the fork server the workers are
#: forked from instead of by each worker's first take: about 1.5 s of CPU per worker.
#: A name that no longer exists is skipped by the fork server.
#: (`scipy.signal` and `scipy.stats`, with the `scipy.integrate` and `scipy.interpolate`
#: they import, are not among them: no stage of a take uses them, and they were 0.3-0.5 s
#: of the fork server's CPU, on the start-up's critical path.)
WORKER_PRELOAD = (
    "carapost.parallel", "distributed", "numpy", "cv2", "av", "lxml.etree", "numba",
    "scipy.fft", "scipy.linalg", "scipy.ndimage", "scipy.optimize", "scipy.sparse",
    "scipy.special", "scipy.spatial",
    "carapost.batch", "carapost.pipeline", "carapost.session", "carapost.io.cara",
    "carapost.io.c3d", "carapost.io.fbx", "carapost.io.take_import", "carapost.io.decode",
    "carapost.io.video", "carapost.commands.process", "carapost.commands.tracking",
    "carapost.commands.stabilise", "carapost.algorithms.blobs.detect",
    "carapost.algorithms.tracking.take", "carapost.algorithms.init3d",
    "carapost.algorithms.bundle", "carapost.algorithms.gapfill",
    "carapost.algorithms.uncertainty", "carapost.algorithms.stabilise_auto",
    "carapost.algorithms.brim", "carapost.algorithms.cleanup", "carapost.algorithms.labelling",
    "carapost.algorithms.rom", "carapost.algorithms.spurious",
    "carapost.algorithms.target_track", "carapost.commands.quality",
    "carapost.model.properties", "threadpoolctl",
)
#: The environment numeric libraries read when they load: one thread each in a worker,
#: whose parallelism is its neighbours' takes (oversubscribed cores slow every take).
WORKER_THREADS_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                      "OPENBLAS_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1",
                      "VECLIB_MAXIMUM_THREADS": "1", "NUMEXPR_NUM_THREADS": "1"}
#: Dask settings of the batch's own LocalCluster, beyond those `_local_cluster` needs
#: for its retries and scheduling. A take is one task of seconds to minutes on a
#: single-threaded worker, so the machinery Dask keeps for many short tasks only takes
#: CPU from the takes: with the defaults, a worker running a take used 15-28 % more CPU
#: than the take's own thread (the statistical profiler sampling the task's stack every
#: 10 ms, about half of it; the 20 ms event-loop tick and the 0.1-0.5 s system and
#: memory monitors, the other half), and 3-4 % with these; the scheduler's process
#: (scheduler and nannies) went from 3.4 % to 0.8 % of a core (docs/benchmarks.md).
#: Nothing of a batch reads the profiles or the dashboard's fine-grained series; the
#: memory monitor still stops a worker past its memory limit, within a second.
LOCAL_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
    # one take per worker at a time, queued on the scheduler: nothing to steal
    "distributed.scheduler.work-stealing": False,
}
#: Seconds to wait for the first local worker.
WORKER_START_TIMEOUT = 120.0


def _start_method() -> str:
    """How local workers start: forked from a fork server where it exists (POSIX),
    else spawned (each worker then imports everything itself)."""
    import multiprocessing

    return "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() \
        else "spawn"


def start_fork_server() -> bool:
    """Start the fork server of local batch workers now, if there is none yet.

    It imports `WORKER_PRELOAD` in the background with `WORKER_THREADS_ENV` set (the
    libraries size their thread pools when they load, so the environment must be right
    in the server, not later in each worker), while this process goes on. Every worker
    forked from it starts with the take's modules imported. The fork server is one per
    program (`carapost.parallel` pools use it too; it follows the program with their
    watchdog): when one already runs, it is used as it is. Returns True when this call
    started it (False also where there is no fork server: the workers are spawned).
    """
    if _start_method() != "forkserver":
        return False
    import multiprocessing
    from multiprocessing import forkserver

    from carapost import parallel

    if getattr(forkserver._forkserver, "_forkserver_pid", None) is not None:
        return False  # running: the preload of whoever started it stays
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(WORKER_PRELOAD))
    os.environ[parallel.PARENT_PID_ENV] = str(os.getpid())
    saved = {k: os.environ.get(k) for k in WORKER_THREADS_ENV}
    os.environ.update(WORKER_THREADS_ENV)
    try:
        forkserver.ensure_running()
    finally:  # this process keeps its own settings
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return True


def stop_fork_server() -> None:
    """Stop the fork server `start_fork_server` started, before any worker was forked
    from it (a batch with bad input or nothing to do); at once, even mid-preload.

    Its preload is no use then, and would otherwise run to its end (~1 s of CPU) after
    the batch has returned or the program has printed its error. Uses the private
    stop of `multiprocessing.forkserver` (as its own tests do) after a SIGKILL, so the
    wait for the process does not wait for its imports.
    """
    import signal
    from multiprocessing import forkserver

    server = forkserver._forkserver
    pid = getattr(server, "_forkserver_pid", None)
    if pid is None:
        return
    try:
        os.kill(pid, signal.SIGKILL)
    except OSError:  # already gone
        pass
    try:
        server._stop()
    except OSError as exc:  # its socket file already removed
        log.debug("stopping the fork server: %s", exc)


def _local_cluster(workers: int, wait: bool = True) -> tuple[Any, Any, Any]:
    """An in-process cluster of single-threaded worker processes.

    The workers are forked from a fork server that has already imported the pipeline
    (`start_fork_server`), so a worker is up in a fraction of a second and its first
    take does not pay the imports; where there is no fork server they are spawned. The
    cluster starts with no worker and asks for ``workers``; this returns as soon as the
    first one has joined (``wait``; else at once: call `wait_for_first_worker` once the
    takes are submitted, so that the first worker to join starts one without a round
    trip), and takes start while the others are still starting.
    Returns the cluster, its client and the Dask settings held while it lives (for
    `_close`).

    The scheduler is told that a task whose worker dies has failed at once (allowed
    failures 0): `run` then resubmits it itself, so ``retries`` means the same on a
    LocalCluster and on an external cluster. Each worker is given one take at a time
    (worker saturation 1.0): a take waiting on a worker that dies is not counted as
    having died with it, and the takes, which last seconds to minutes, go to the
    worker that is free first.
    """
    start_fork_server()
    import dask
    from distributed import Client, LocalCluster

    _quiet_distributed()
    # held while the cluster lives: workers start (and restart) after this returns, and
    # each reads the start method then
    config = dask.config.set({**LOCAL_CLUSTER_CONFIG,
                              "distributed.scheduler.allowed-failures": 0,
                              "distributed.scheduler.worker-saturation": 1.0,
                              "distributed.worker.multiprocessing-method": _start_method()})
    cluster = client = None
    try:
        # ":0": the HTTP server (dashboard, health checks) on a free port, so two batches
        # on one machine never contend for 8787
        cluster = LocalCluster(n_workers=0, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR,
                               env=dict(WORKER_THREADS_ENV))
        cluster.scale(workers)
        _quiet_distributed()
        client = Client(cluster, set_as_default=False)
        if wait:
            wait_for_first_worker(client)
    except BaseException as exc:
        _close((cluster, client, config))
        if isinstance(exc, TimeoutError | OSError):
            raise _no_worker(exc) from None
        raise
    return cluster, client, config


def wait_for_first_worker(client: Any) -> None:
    """Return once a worker has joined the client's cluster.

    Raises
    ------
    BatchError
        None joined within `WORKER_START_TIMEOUT` seconds (the caller closes the
        cluster).
    """
    try:
        client.wait_for_workers(1, timeout=WORKER_START_TIMEOUT)
    except (TimeoutError, OSError) as exc:
        raise _no_worker(exc) from None


def _no_worker(exc: BaseException) -> Exception:
    from carapost.batch import BatchError

    return BatchError(f"no local Dask worker started in {WORKER_START_TIMEOUT:.0f} s "
                      f"({' '.join(str(exc).split()) or type(exc).__name__})")


@contextmanager
def local_cluster(workers: int) -> Iterator[Any]:
    """``with local_cluster(2) as client:``: the LocalCluster `run` makes for itself
    (see `_local_cluster`), to share between several `run` calls; closed on exit."""
    own = _local_cluster(workers)
    try:
        yield own[1]
    finally:
        _close(own)


def _quiet_distributed() -> None:
    """The scheduler runs in this process: its INFO lines would drown the progress bar."""
    for name in list(logging.root.manager.loggerDict):
        if name == "distributed" or name.startswith("distributed."):
            logging.getLogger(name).setLevel(logging.WARNING)


def _close(own: tuple[Any, ...] | None) -> None:
    """Close a client and the cluster it was made with (either may be None), then
    restore the Dask settings held for it."""
    if own is None:
        return
    cluster, client, *config = own
    try:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    except Exception as exc:  # closing must not hide the outcome
        log.debug("closing the Dask cluster: %s", exc)
    finally:
        for c in config:
            c.__exit__(None, None, None)
