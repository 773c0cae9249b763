"""Writing a synthetic take folder: videos, calibration, labels, brim, metadata, truth."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing as mp
import os
import tempfile
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from carapost.io.errors import CaraFileError
from carapost.io.xcp import XcpCalibration, write_xcp
from carapost.synth.face import MODES
from carapost.synth.render import prepare, render_frame
from carapost.synth.scene import SynthConfig, SynthScene, build_scene

__all__ = ["generate_take", "write_truth", "SynthCancelled", "video_extension", "TRUTH_FILE"]

TRUTH_FILE = "truth.npz"
_FOURCC = {"ffv1": ("FFV1", ".mkv"), "mp4v": ("mp4v", ".mp4")}


class SynthCancelled(Exception):
    """Raised by `generate_take` when its progress callback returned False.

    Nothing of the take is left behind (partial videos are deleted)."""


def video_extension(codec: str) -> str:
    """File extension of the camera videos for a codec (``".mkv"`` or ``".mp4"``)."""
    return _FOURCC[codec][1]


def _atomic_bytes(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_truth(path: str | os.PathLike[str], scene: SynthScene) -> None:
    """Write the ground truth of a scene as a ``.npz`` file (atomically).

    Keys: ``points3d`` (F, M, 3), ``brim3d`` (B, 3), ``labels`` (M,), ``brim_labels``,
    ``visible`` (F, M, C), ``uv`` (F, M, C, 2), ``brim_visible``, ``brim_uv``, ``cam_R``
    (F, C, 3, 3), ``cam_t`` (F, C, 3), ``K`` (C, 3, 3), ``radial`` (C, 3) (k1, k2, k3 of
    VICON_RADIAL2), ``distortion_centre`` (C, 2), ``image_size`` (C, 2), ``channels``,
    ``marker_radius_mm``, ``marker_normals``, ``brim_normals``, ``brim_radius_mm``,
    ``eyelid``, ``activations`` (F, K) with ``modes``, ``head_R``, ``head_t``,
    ``camera_lag`` (C,), ``merge_pair`` (2,) (-1 when absent), ``fps``, ``seed``; with
    partial occlusion also ``cover_dir`` (F, M, 3), ``cover_offset`` (F, M) (inf: nothing
    covered), ``visible_points3d`` (F, M, 3) and ``visible_uv`` (F, M, C, 2) (the visible
    part's centroid); with missed markers ``contrast`` (F, M) and ``missed`` (F, M).
    """
    import io

    intr = scene.intrinsics
    buf = io.BytesIO()
    optional = {k: getattr(scene, k) for k in ("cover_dir", "cover_offset", "visible_points3d",
                                              "visible_uv", "contrast", "missed")
                if getattr(scene, k) is not None}
    np.savez_compressed(
        buf,
        points3d=scene.points3d, brim3d=scene.brim3d, labels=np.array(scene.labels),
        brim_labels=np.array(scene.brim_labels), visible=scene.visible, uv=scene.uv,
        brim_visible=scene.brim_visible, brim_uv=scene.brim_uv, cam_R=scene.cam_R,
        cam_t=scene.cam_t, K=intr.K(), radial=intr.radial,
        distortion_centre=intr.distortion_centre, image_size=intr.image_size,
        channels=np.array(intr.names), marker_radius_mm=scene.marker_radius_mm,
        marker_normals=scene.marker_normals, brim_normals=scene.brim_normals,
        brim_radius_mm=scene.brim_radius_mm, eyelid=scene.eyelid,
        activations=scene.activations, modes=np.array(MODES), head_R=scene.head_R,
        head_t=scene.head_t, camera_lag=scene.camera_lag,
        merge_pair=np.array(scene.merge_pair if scene.merge_pair else (-1, -1)),
        fps=np.float64(scene.config.fps), seed=np.int64(scene.config.seed), **optional,
    )
    _atomic_bytes(Path(path), buf.getvalue())


def _metadata(scene: SynthScene, videos: list[str]) -> dict:
    cfg = scene.config
    n_left = (scene.n_cameras + 1) // 2
    return {
        "fps": float(cfg.fps),
        "frames": int(scene.n_frames),
        "timecode_start": cfg.timecode_start,
        "logger": {"name": "carapost-synth", "id": f"synth-{cfg.seed}"},
        "rig": {
            "cameras": list(scene.intrinsics.names),
            "caddies": [list(range(n_left)), list(range(n_left, scene.n_cameras))],
            "image_size": [int(cfg.size[0]), int(cfg.size[1])],
        },
        "videos": videos,
        "synth": {
            "preset": cfg.preset, "markers": cfg.markers, "seed": int(cfg.seed),
            "noise": cfg.noise, "blur": cfg.blur, "motion_blur": cfg.motion_blur,
            "highlights": cfg.highlights, "merge_pair": list(scene.merge_pair or []),
            "out_of_sync_camera": cfg.out_of_sync_camera, "codec": cfg.codec,
            **({"partial_occlusion": True} if cfg.partial_occlusion else {}),
            **({"missed_markers": int(cfg.missed_markers)} if cfg.missed_markers else {}),
            "truth": TRUTH_FILE,
        },
    }


# Rendering is pure-Python-heavy (many small numpy calls), so threads contend for the GIL;
# several cameras render in parallel in worker processes instead. Each worker gets the
# scene without its caches and rebuilds what it needs for its own cameras.
_WORKER: dict = {}


def _write_camera(scene: SynthScene, c: int, path: Path, fourcc: str,
                  tick: Callable[[], bool]) -> bool:
    """Render and encode one camera's video; ``tick()`` after each image returns False to
    stop. Returns False if stopped."""
    w, h = scene.size
    if fourcc == "FFV1":
        # Every frame a keyframe (FFV1's archival setting): a jump anywhere in the take
        # decodes one frame per camera (OpenCV's writer puts a keyframe every 12).
        from carapost.io.encode import FFV1Writer

        with FFV1Writer(path, (w, h), float(scene.config.fps)) as ffv1:
            for f in range(scene.n_frames):
                ffv1.write(render_frame(scene, f, c))
                if not tick():
                    return False
        return True
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc),
                             float(scene.config.fps), (w, h), False)
    if not writer.isOpened():
        raise CaraFileError(path, f"OpenCV cannot open a {scene.config.codec} video writer")
    try:
        for f in range(scene.n_frames):
            writer.write(render_frame(scene, f, c))
            if not tick():
                return False
    finally:
        writer.release()
    return True


def _pool_init(scene: SynthScene, counter: Any, cancel: Any) -> None:
    cv2.setNumThreads(1)
    _WORKER.update(scene=scene, counter=counter, cancel=cancel)


def _pool_task(c: int, path: str, fourcc: str) -> bool:
    counter, cancel = _WORKER["counter"], _WORKER["cancel"]

    def tick() -> bool:
        with counter.get_lock():
            counter.value += 1
        return not cancel.is_set()

    return _write_camera(_WORKER["scene"], c, Path(path), fourcc, tick)


def _render_in_pool(scene: SynthScene, partials: list[Path], fourcc: str,
                    progress: Callable[[int, int], bool] | None, total: int, workers: int
                    ) -> bool:
    """Render cameras in worker processes; True if cancelled."""
    ctx = mp.get_context("spawn")
    counter = ctx.Value("i", 0)
    cancel = ctx.Event()
    light = dataclasses.replace(scene, cache={})
    with ProcessPoolExecutor(max_workers=min(workers, len(partials)), mp_context=ctx,
                             initializer=_pool_init, initargs=(light, counter, cancel)) as pool:
        futures = [pool.submit(_pool_task, c, str(p), fourcc) for c, p in enumerate(partials)]
        pending = set(futures)
        while pending:
            finished, pending = wait(pending, timeout=0.25)
            if any(fut.exception() is not None for fut in finished):
                cancel.set()
            if progress is not None and not cancel.is_set():
                if progress(int(counter.value), total) is False:
                    cancel.set()
        results = [fut.result() for fut in futures]  # re-raises a worker's error
    if progress is not None and not cancel.is_set():
        progress(int(counter.value), total)
    return cancel.is_set() or not all(results)


def _render_in_process(scene: SynthScene, partials: list[Path], fourcc: str,
                       progress: Callable[[int, int], bool] | None, total: int) -> bool:
    """Render cameras one after the other in this process; True if cancelled."""
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # OpenCV's own threads only add overhead on these small operations
    done = [0]

    def tick() -> bool:
        done[0] += 1
        return progress is None or progress(done[0], total) is not False

    try:
        prepare(scene)
        return not all(_write_camera(scene, c, p, fourcc, tick) for c, p in enumerate(partials))
    finally:
        cv2.setNumThreads(threads)


def generate_take(outdir: str | os.PathLike[str], config: SynthConfig | None = None, *,
                  progress: Callable[[int, int], bool] | None = None,
                  scene: SynthScene | None = None, workers: int = 2) -> Path:
    """Render a synthetic take into a folder.

    Writes ``<take>_<channel>.mkv`` (or ``.mp4``) per camera, ``<take>.xcp`` (frame-0
    calibration), ``<take>_labels.txt``, ``<take>_brim.csv``, ``truth.npz`` and, last,
    ``<take>.json``: a folder without the JSON is an interrupted take.

    Parameters
    ----------
    outdir : str or PathLike
        Take folder (created if needed; files of the same take are replaced).
    config : SynthConfig, optional
        Defaults to ``SynthConfig()`` (300 frames, 4 cameras, 1280x720, speech).
    progress : callable, optional
        ``progress(done, total) -> bool`` called with rendered image counts; returning
        False cancels.
    scene : SynthScene, optional
        A scene already built from ``config`` (saves building it twice).
    workers : int
        Threads rendering cameras in parallel.

    Returns
    -------
    Path
        The take's ``<take>.json`` file.

    Raises
    ------
    ValueError
        For a bad configuration parameter.
    CaraFileError
        If a file cannot be written.
    SynthCancelled
        If ``progress`` returned False (partial files are removed).
    """
    config = scene.config if scene is not None else (config or SynthConfig())
    config.validate()
    out = Path(outdir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CaraFileError(out, f"cannot create the take folder ({exc.strerror})") from exc
    take = config.take_name
    json_path = out / f"{take}.json"
    json_path.unlink(missing_ok=True)  # the take is incomplete until the JSON is back
    if scene is None:
        scene = build_scene(config)
    F, C = scene.n_frames, scene.n_cameras
    w, h = scene.size
    fourcc, ext = _FOURCC[config.codec]
    channels = list(scene.intrinsics.names)
    finals = [out / f"{take}_{ch}{ext}" for ch in channels]
    partials = [out / f".{take}_{ch}.partial{ext}" for ch in channels]

    def cleanup() -> None:
        for p in partials:
            p.unlink(missing_ok=True)

    total = F * C
    try:
        if workers <= 1 or C == 1:
            cancelled = _render_in_process(scene, partials, fourcc, progress, total)
        else:
            cancelled = _render_in_pool(scene, partials, fourcc, progress, total, workers)
        if cancelled:
            raise SynthCancelled(f"generating {json_path} was cancelled")
        for p, q in zip(partials, finals, strict=True):
            os.replace(p, q)
        calib = XcpCalibration.from_arrays(scene.intrinsics, scene.cam_R[0], scene.cam_t[0])
        write_xcp(out / f"{take}.xcp", calib)
        _atomic_bytes(out / f"{take}_labels.txt", ("\n".join(scene.labels) + "\n").encode())
        rows = ["label,x,y,z"] + [f"{lab},{x:.6f},{y:.6f},{z:.6f}"
                                  for lab, (x, y, z) in zip(scene.brim_labels, scene.brim3d,
                                                            strict=True)]
        _atomic_bytes(out / f"{take}_brim.csv", ("\n".join(rows) + "\n").encode())
        write_truth(out / TRUTH_FILE, scene)
        meta = _metadata(scene, [q.name for q in finals])
        _atomic_bytes(json_path, (json.dumps(meta, indent=2) + "\n").encode())
    except OSError as exc:
        cleanup()
        raise CaraFileError(out, f"cannot write the take ({exc})") from exc
    except BaseException:
        cleanup()
        raise
    return json_path
