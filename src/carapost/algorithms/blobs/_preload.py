"""Forkserver preload of the detector processes: the compiled kernels loaded once there.

Every detector process forked from the forkserver starts with the kernels loaded, so a
process started after the pool's idle shutdown is ready in milliseconds, not after
loading them again (~0.3 s, seconds on a busy machine). Imported anywhere else (outside
:data:`carapost.parallel.IN_POOL_SERVER`) this module does nothing.

Nothing here may start a thread: a process forked from a parent with threads inherits
their locks but not the threads. OpenCV is made single-threaded first (as each detector
process makes it anyway), because its thread pool starts on the first parallel call and
a forked child that touches the pool would wait forever for it; the numba kernels have
no threads of their own (``nogil``, not ``parallel``).
"""

from __future__ import annotations

from carapost import parallel

if parallel.IN_POOL_SERVER:
    import cv2

    cv2.setNumThreads(1)
    try:
        from carapost.algorithms.blobs.detect import warm_up

        warm_up()
    except Exception:  # the detector reports real problems when it is used
        pass
