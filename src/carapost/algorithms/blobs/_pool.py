"""Where the detector processes come from, without importing the detector: the
forkserver's preload, and its launch (`start_server`), which a window calls when it
starts (importing the detector there would hold the window's GIL for ~0.6 s).
"""

from __future__ import annotations

from carapost import parallel

__all__ = ["PRELOAD", "start_server"]

#: What the detector processes' forkserver imports besides `carapost.parallel`: the
#: detector, then `carapost.algorithms.blobs._preload`, which loads its kernels there.
PRELOAD = ("carapost.algorithms.blobs.detect", "carapost.algorithms.blobs._preload")


def start_server() -> bool:
    """Launch the detector processes' forkserver, which loads the detector (~1.3 s of a
    core) in its own process, so that ``start_workers`` later forks ready processes in
    milliseconds. Nothing of the detector is imported here; False where processes are
    spawned (not Linux).

    Examples
    --------
    >>> isinstance(start_server(), bool)
    True
    """
    return parallel.start_forkserver(PRELOAD)
