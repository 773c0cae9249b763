"""Blob detection in whole images: one image, the preview, and batches of many images
on worker processes or threads (:mod:`carapost.parallel`).

Examples
--------
>>> import numpy as np, cv2
>>> from carapost.algorithms.blobs import BlobParameters, detect_blobs_batch
>>> img = np.full((64, 64), 200, np.uint8)
>>> _ = cv2.circle(img, (32, 30), 6, 20, -1)
>>> out = detect_blobs_batch(lambda key: img, ["a", "b"], BlobParameters())
>>> sorted(out), [len(d) for d in out.values()]
(['a', 'b'], [1, 1])
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable, Sequence

import cv2
import numpy as np

from carapost import parallel
from carapost._runtime import keep_freed_memory
from carapost.algorithms.blobs._pool import PRELOAD
from carapost.algorithms.blobs.candidates import blob_candidates
from carapost.algorithms.blobs.detections import BLACK, WHITE, BlobDetections
from carapost.algorithms.blobs.image import as_uint8, check_mask, noise_sigma
from carapost.algorithms.blobs.params import BlobParameters

__all__ = ["PROCESS_MIN_IMAGES", "PROCESS_CHUNK", "detect_blobs", "preview_blobs",
           "detect_blobs_batch", "warm_up", "start_workers", "shutdown_workers"]


def _detect8(image8: np.ndarray, params: BlobParameters, mask: np.ndarray | None
             ) -> BlobDetections:
    """Detections of a validated 8-bit image (both colours as ``params`` asks)."""
    parts = []
    noise = noise_sigma(image8)
    for colour, on, lo, hi, th in (
        (BLACK, params.find_black_blobs, params.black_min_radius, params.black_max_radius,
         params.black_threshold),
        (WHITE, params.find_white_blobs, params.white_min_radius, params.white_max_radius,
         params.white_threshold),
    ):
        if not on:
            continue
        c = blob_candidates(image8, colour, lo, hi, mask=mask, noise=noise)
        p = c.score
        sel = (p >= th) & ~c.saturated
        m = int(sel.sum())
        parts.append(BlobDetections(
            centre=c.centre[sel].astype(np.float32),
            axes=c.axes[sel].astype(np.float32),
            angle=c.angle[sel].astype(np.float32),
            colour=np.full(m, colour, np.int8),
            score=p[sel].astype(np.float32),
        ))
    return BlobDetections.concatenate(parts)


def detect_blobs(
    image: np.ndarray, params: BlobParameters, *, mask: np.ndarray | None = None
) -> BlobDetections:
    """Detect black and/or white blobs in one grey image.

    Parameters
    ----------
    image : ndarray [H, W] uint8 or uint16
        Grey camera image (uint16 is reduced to its 8 most significant used bits).
    params : BlobParameters
    mask : ndarray [H, W], optional
        Region of interest: blobs whose centre falls on a zero pixel are dropped.

    Returns
    -------
    BlobDetections
        Black detections first, then white ones.

    Raises
    ------
    TypeError, ValueError
        For an image that is not a 2-D uint8/uint16 array or a mask of another shape.

    Examples
    --------
    >>> import numpy as np, cv2
    >>> img = np.full((64, 64), 200, np.uint8)
    >>> _ = cv2.circle(img, (32, 30), 6, 20, -1)
    >>> det = detect_blobs(img, BlobParameters())
    >>> len(det), np.round(det.centre[0]).tolist()
    (1, [32.0, 30.0])
    """
    if not isinstance(params, BlobParameters):
        raise TypeError(f"params must be BlobParameters, got {type(params).__name__}")
    image8 = as_uint8(image)
    keep_freed_memory()
    return _detect8(image8, params, check_mask(mask, image8.shape))


def preview_blobs(image: np.ndarray, params: BlobParameters) -> BlobDetections:
    """What Detect Blobs would find on this image with these parameters (no side effects).

    The same detector as :func:`detect_blobs` (so the preview never disagrees with the
    real run); it is fast enough for interactive scrubbing (a few ms at 1280x720).

    Examples
    --------
    >>> import numpy as np, cv2
    >>> img = np.full((64, 64), 200, np.uint8)
    >>> _ = cv2.circle(img, (20, 40), 5, 30, -1)
    >>> np.round(preview_blobs(img, BlobParameters()).centre).tolist()
    [[20.0, 40.0]]
    """
    return detect_blobs(image, params)


#: Batches of at least this many images run in worker processes when ``workers > 1``
#: (see :func:`detect_blobs_batch`); smaller ones (Detect Blobs [Current Frame]) run in
#: threads, which start instantly.
PROCESS_MIN_IMAGES = 16
#: Images per task of the worker processes.
PROCESS_CHUNK = 4


def _worker_init() -> None:
    """Initialise a detector process: OpenCV single-threaded (the parallelism is the
    processes; OpenCV's own threads would only compete with them) and the malloc
    settings of :func:`carapost._runtime.keep_freed_memory`."""
    cv2.setNumThreads(1)
    keep_freed_memory()
    warm_up()


def warm_up() -> None:
    """Load (or, on the first run after installation, compile: ~3 s) the detector's
    compiled kernels, so the first detection does not pay for it. Detector processes do
    this when they start; a GUI may call it in the background at start-up.

    Examples
    --------
    >>> warm_up()
    """
    from scipy.spatial import cKDTree  # noqa: F401 - imported on first use otherwise

    img = np.full((24, 24), 200, np.uint8)
    cv2.circle(img, (12, 12), 4, 30, -1)
    _detect8(img, BlobParameters(), None)


#: The detector processes, started on the first large batch and kept for the next ones;
#: the forkserver imports this module once, so a new process starts in ~10 ms.
_POOL = parallel.ProcessPool(initializer=_worker_init, preload=PRELOAD)


def start_workers(workers: int = 2) -> threading.Thread:
    """Start the detector processes in the background (returns at once), so that the
    first batch on processes, even a small one (Detect Blobs [Current Frame] with
    ``processes=True``), does not wait for them. A window calls this when a take opens.
    They stop after :data:`carapost.parallel.IDLE_SHUTDOWN_S` without work, as after a
    batch. Returns the (daemon) thread that starts them.

    Examples
    --------
    >>> start_workers(1).join()
    >>> shutdown_workers()
    """
    return _POOL.start(workers)


def shutdown_workers() -> None:
    """Stop the detector processes started by :func:`detect_blobs_batch` (they are
    otherwise kept for the next batch and stopped when the program exits)."""
    _POOL.shutdown()


def _detect_in_thread(image: np.ndarray, params: BlobParameters, mask: np.ndarray | None
                      ) -> BlobDetections:
    """One image of a batch on a worker thread: :func:`detect_blobs`."""
    return detect_blobs(image, params, mask=mask)


def _detect_in_process(image: np.ndarray, params: BlobParameters, mask: np.ndarray | None
                       ) -> BlobDetections:
    """One image of a batch in a detector process (initialised by ``_worker_init``; the
    caller has checked the image's shape and the mask)."""
    return _detect8(as_uint8(image), params, mask)


def detect_blobs_batch(
    get_image: Callable[[Hashable], np.ndarray],
    keys: Sequence[Hashable],
    params: BlobParameters,
    *,
    workers: int = 2,
    progress: Callable[[int, int], bool] | None = None,
    mask: np.ndarray | None = None,
    processes: bool | None = None,
) -> dict[Hashable, BlobDetections]:
    """Detect blobs in many images in parallel (e.g. all frames x cameras of a range).

    Images are fetched with ``get_image(key)`` on the calling thread, in the order of
    ``keys`` (so a sequential video reader needs no locking), and detected by
    ``workers`` worker processes (batches of :data:`PROCESS_MIN_IMAGES` images or more)
    or threads (smaller batches). Processes scale with the cores: the detector's numpy
    steps hold Python's GIL for much of their time, so two threads reach only ~1.2x
    one thread's rate. The processes are started on the first large batch and kept
    for the next ones (:func:`shutdown_workers` stops them).

    Parameters
    ----------
    get_image : callable key -> ndarray [H, W] uint8/uint16
        Called on the calling thread only.
    keys : sequence of hashable
        For example ``(frame, camera)`` tuples.
    params : BlobParameters
    workers : int
        Number of detector processes or threads (default 2, the number of cores of a
        typical laptop); 1 detects on one worker thread.
    progress : callable (done, total) -> bool, optional
        Called on the calling thread after each finished image; returning False
        cancels: no new images are started, the ones in flight finish, and what is done
        is returned.
    mask : ndarray [H, W], optional
        Region of interest applied to every image.
    processes : bool, optional
        Force worker processes (True) or threads (False); default: processes for
        batches of at least PROCESS_MIN_IMAGES images when ``workers > 1``.

    Returns
    -------
    dict key -> BlobDetections
        Finished images only (all of them unless cancelled).
    """
    if not isinstance(params, BlobParameters):
        raise TypeError(f"params must be BlobParameters, got {type(params).__name__}")
    keys = list(keys)  # map_arrays checks ``workers`` and returns {} for no keys
    if processes is None:
        processes = workers > 1 and len(keys) >= PROCESS_MIN_IMAGES
    if not processes:
        return parallel.map_arrays(get_image, keys, _detect_in_thread, (params, mask),
                                   workers=workers, progress=progress,
                                   thread_name_prefix="blobs")

    def check(img: np.ndarray) -> None:
        # Validate here, so a bad image fails as it would in one process.
        if not isinstance(img, np.ndarray) or img.ndim != 2:
            as_uint8(img)
        if mask is not None:
            check_mask(mask, img.shape)

    mask8 = None if mask is None else np.ascontiguousarray(np.asarray(mask) != 0)
    # a small batch (the current frame) is shared among all the processes
    chunk = max(1, min(PROCESS_CHUNK, -(-len(keys) // (2 * max(int(workers), 1)))))
    return parallel.map_arrays(get_image, keys, _detect_in_process, (params, mask8),
                               workers=workers, pool=_POOL, chunk=chunk,
                               check=check, progress=progress)
