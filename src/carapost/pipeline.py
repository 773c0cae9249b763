"""Headless processing of a whole take: ``carapost process TAKE -o OUT.cara``.

Import the camera files, detect blobs in every frame, solve the brim automatically with
the take's XCP rig geometry, initialise the face (from a ROM, or automatically with no
seeds), track forwards over the whole take, save the project and export. Nothing is
filled where no camera saw a marker.

The brim model comes from ``--brim`` (CSV ``label,x,y,z`` in mm, or a custom-brim SVG),
else from ``<take>_brim.csv`` beside the take, else it is triangulated from the take
itself: the points that stay fixed relative to the cameras over frames spread through
the take, with the XCP cameras (a rig whose brim nobody measured still works).

Every input is checked before any work, and every output is written atomically after
all processing, so bad input leaves nothing half-written.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.io.atomic import check_output_path
from carapost.io.errors import CaraFileError
from carapost.model.project import KIND_BRIM, KIND_FACE, Project

log = logging.getLogger("carapost.pipeline")

__all__ = ["process_take", "brim_from_take"]


def _check_output(path: str | Path, suffix: str) -> Path:
    p = Path(path)
    if p.suffix.lower() != suffix:
        raise CaraFileError(p, f"the output must be a {suffix} file")
    return check_output_path(p)


def brim_from_take(project: Project, frames: NDArray[np.intp] | None = None, *,
                   max_px: float = 2.0, max_spread_mm: float = 1.0,
                   min_points: int = 6) -> tuple[list[str], NDArray[np.float64]]:
    """Triangulate a brim model from the take: points fixed relative to the cameras.

    The XCP cameras (frame 0's) triangulate every marker seen by >= 3 cameras in 32
    frames spread through the take; the points that appear in all of them within
    ``max_spread_mm`` are on the rig (the face moves and slips, the brim does not).

    Returns
    -------
    labels : list of str
    xyz : ndarray, shape (B, 3)

    Raises
    ------
    ValueError
        When too few fixed points are found.
    """
    from carapost.algorithms.camera import pixels_to_normalised
    from carapost.algorithms.multiview import multiview_tracks, triangulate_tracks

    intr = project.calibration.intrinsics
    cal = project.calibration
    F, C = project.n_frames, project.n_cameras
    ref = int(np.flatnonzero(cal.solved)[0]) if cal.solved.any() else 0
    R, t = cal.R[ref], cal.t[ref]
    if frames is None:
        # 32 frames: the rig flex averages out (brim error 0.18 mm with 8 frames, 0.08 with
        # 32 on a synthetic take; more frames gave nothing)
        frames = np.unique(np.linspace(0, F - 1, min(F, 32)).round().astype(np.intp))
    clouds = []
    for f in frames:
        dets_n = []
        for c in range(C):
            cen = project.detections.centres(int(f), c).astype(np.float64)
            full = np.full((len(cen), C, 2), np.nan)
            full[:, c] = cen
            dets_n.append(pixels_to_normalised(full, intr)[:, c] if len(cen)
                          else np.zeros((0, 2)))
        tracks, _ = multiview_tracks(dets_n, R, t, intr.focal, max_px, min_views=3)
        if len(tracks) == 0:
            clouds.append(np.zeros((0, 3)))
            continue
        X, _, _ = triangulate_tracks(tracks, dets_n, R, t, intr.focal)
        clouds.append(X[np.isfinite(X).all(-1)])
    if not clouds or len(clouds[0]) == 0:
        raise ValueError("no marker is seen by three cameras in the first frame")
    from scipy.spatial import cKDTree

    # a rig point is found at the same place (within max_spread_mm: the rig flexes a
    # little) in most sampled frames; face markers move and slip between them
    base = clouds[0]
    hits = np.zeros(len(base), dtype=np.intp)
    acc = np.zeros_like(base)
    for X in clouds:
        if len(X) == 0:
            continue
        d, j = cKDTree(X).query(base)
        near = d <= max_spread_mm
        hits += near
        acc[near] += X[j[near]]
    keep = hits >= max(2, int(np.ceil(0.6 * len(clouds))))
    xyz = acc[keep] / hits[keep, None]
    if len(xyz) < min_points:
        raise ValueError(f"only {len(xyz)} markers stay fixed relative to the cameras "
                         f"(need {min_points} for a brim); give the brim model with --brim")
    labels = [f"Brim{i + 1:02d}" for i in range(len(xyz))]
    return labels, xyz


def process_take(
    take_path: str | Path,
    *,
    output: str | Path,
    rom: str | Path | None = None,
    brim: str | Path | None = None,
    c3d: str | Path | None = None,
    fbx: str | Path | None = None,
    progress: Callable[[int, int], bool] | None = None,
    patch_tracking: bool = False,
) -> dict[str, Any]:
    """Process a take headlessly: import, detect, solve, initialise, track, save, export.

    Parameters
    ----------
    take_path : str or Path
        One camera file of the take, its ``.json``/``.xcp``, or its folder.
    output : str or Path
        ``.cara`` project to write.
    rom : str or Path, optional
        ROM ``.cara`` to initialise from (also gives the calibration when the take has no
        XCP).
    brim : str or Path, optional
        Brim model: ``.csv`` (label,x,y,z in mm, optional header) or ``.svg``.
    c3d, fbx : str or Path, optional
        Also export the face points here.
    progress : callable, optional
        ``progress(done, total)`` over the detection and tracking frames; False cancels
        (raises ``RuntimeError``, nothing written).
    patch_tracking : bool
        Give the tracker the images, so a point-camera without a blob is patch tracked
        (Patch Match Size / Threshold). Off by default: every image is decoded again
        while tracking, both passes, which makes the whole run about 2.5x slower for
        +0.1 % coverage and +0.05 mm RMSE on the rendered speech takes
        (docs/benchmarks.md).

    Returns
    -------
    dict
        ``project``, ``c3d``, ``fbx`` (paths written or None), ``frames``, ``cameras``,
        ``points`` (face points), ``brim_points``, ``initialised`` (face points at the
        first frame), ``tracked_fraction`` (face point-frames with 3D / point-frames),
        ``brim_source``, ``seconds`` per stage.

    Raises
    ------
    CaraFileError
        Missing or unreadable inputs, unwritable outputs.
    ValueError
        The take cannot be processed (no XCP and no ROM, no markers found, brim not
        solvable, nothing initialised); the message says which stage and why.
    """
    from carapost.commands.process import (
        DetectBlobs,
        ImportBrimSvg,
        Initialize3D,
        SetBrimModel,
        SolveBrimAuto,
    )
    from carapost.commands.stack import CommandError, CommandStack
    from carapost.commands.tracking import InitializeFromRom, LoadRom, TrackTakeCommand
    from carapost.io.cara import save_project
    from carapost.io.take_import import import_take, read_brim_csv
    from carapost.io.video import TakeFrames

    # ---- check every input and output before any work -----------------------------------
    take_path = Path(take_path)
    if not take_path.exists():
        raise CaraFileError(take_path, "no such file or folder")
    out = _check_output(output, ".cara")
    c3d_path = _check_output(c3d, ".c3d") if c3d else None
    fbx_path = _check_output(fbx, ".fbx") if fbx else None
    rom_path = Path(rom) if rom else None
    if rom_path is not None:
        if not rom_path.is_file():
            raise CaraFileError(rom_path, "ROM project not found")
        if rom_path.suffix.lower() != ".cara":
            raise CaraFileError(rom_path, "a ROM must be a .cara project")
    brim_model: tuple[list[str], NDArray] | None = None
    brim_svg: Path | None = None
    brim_source = "take"
    if brim is not None:
        bp = Path(brim)
        if not bp.is_file():
            raise CaraFileError(bp, "brim model not found")
        if bp.suffix.lower() == ".csv":
            brim_model = read_brim_csv(bp)
        elif bp.suffix.lower() == ".svg":
            brim_svg = bp
        else:
            raise CaraFileError(bp, "a brim model must be a .csv or .svg file")
        brim_source = str(bp)

    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    project = import_take(take_path)
    stack = CommandStack(project)
    seconds["import"] = time.perf_counter() - t0
    if project.calibration.intrinsics is None and rom_path is None:
        raise ValueError(f"{take_path}: the take has no XCP calibration and no ROM was given; "
                         "the cameras cannot be solved (add <take>.xcp or --rom ROM.cara)")
    F, C = project.n_frames, project.n_cameras
    if brim_model is None and brim_svg is None and project.take.metadata.get("brim_file"):
        brim_model = read_brim_csv(project.take.metadata["brim_file"])
        brim_source = str(project.take.metadata["brim_file"])

    frames = TakeFrames(project.take, strict=True)
    try:
        def stage_progress(offset: int, total: int) -> Callable[[int, int], bool] | None:
            if progress is None:
                return None
            return lambda d, n: progress(offset + d, total)

        total = 3 * F  # detection, then the forward and backward tracking passes
        # ---- detect blobs in every frame ----------------------------------------------
        t0 = time.perf_counter()
        try:
            cmd = DetectBlobs(project, (0, F - 1), cameras=range(C),
                              get_image=frames.get,
                              progress=(None if progress is None else
                                        (lambda d, n: progress(d * F // max(n, 1), total))))
        except CommandError as exc:
            raise ValueError(f"Detect Blobs: {exc}") from None
        if getattr(cmd, "cancelled", False):
            raise RuntimeError("cancelled during blob detection; nothing was written")
        stack.push(cmd)
        seconds["detect"] = time.perf_counter() - t0
        if project.detections.total == 0:
            raise ValueError(f"{take_path}: no markers were found in any image (check the "
                             "Blob Parameters or the videos)")

        # ---- ROM, calibration and brim --------------------------------------------------
        t0 = time.perf_counter()
        if rom_path is not None:
            try:
                stack.push(LoadRom(project, rom_path))
            except CommandError as exc:
                raise ValueError(str(exc)) from None
        if project.calibration.intrinsics is not None and rom_path is None:
            if brim_svg is not None:
                stack.push(ImportBrimSvg(project, brim_svg))
            else:
                if brim_model is None:
                    try:
                        brim_model = brim_from_take(project)
                    except ValueError as exc:
                        raise ValueError(f"brim: {exc}") from None
                    brim_source = "triangulated from the take"
                cmd = SetBrimModel(*brim_model, description="Set Calibration Brim")
                stack.push(cmd)
            try:
                stack.push(SolveBrimAuto(project, frame=0))
            except CommandError as exc:
                raise ValueError(f"Solve Calibration Brim [Automatic]: {exc}") from None
        seconds["brim"] = time.perf_counter() - t0

        # ---- initialise ---------------------------------------------------------------
        t0 = time.perf_counter()
        project.set_current_frame(0)
        try:
            if rom_path is not None:
                stack.push(InitializeFromRom(project, frame=0))
            else:
                stack.push(Initialize3D(project, frame=0))
        except CommandError as exc:
            raise ValueError(f"initialisation: {exc}") from None
        face = project.points.kind == KIND_FACE
        n_init = int(np.isfinite(project.points.positions[0, face, 0]).sum())
        if n_init == 0:
            raise ValueError("initialisation found no face marker at frame 0")
        seconds["initialise"] = time.perf_counter() - t0

        # ---- track the whole take (forwards, finding missed markers, then backwards) ----
        t0 = time.perf_counter()
        project.set_active_range((0, F - 1))
        if F > 1:
            try:
                cmd = TrackTakeCommand(project, 0, progress=stage_progress(F, total),
                                       get_image=frames.get if patch_tracking else None)
            except CommandError as exc:
                raise ValueError(f"tracking: {exc}") from None
            if cmd.computation.cancelled:
                raise RuntimeError("cancelled during tracking; nothing was written")
            stack.push(cmd)
        seconds["track"] = time.perf_counter() - t0
    finally:
        frames.close()

    # ---- write everything (each file atomically) -----------------------------------------
    from carapost import api

    written = save_project(project, out)
    result: dict[str, Any] = {"project": str(written), "c3d": None, "fbx": None}
    if c3d_path is not None:
        result["c3d"] = str(api.export_c3d(project, c3d_path))
    if fbx_path is not None:
        result["fbx"] = str(api.export_fbx(project, fbx_path))
    face = project.points.kind == KIND_FACE
    has = np.isfinite(project.points.positions[:, face, 0])
    result.update({
        "frames": F, "cameras": C, "points": int(face.sum()),
        "brim_points": int((project.points.kind == KIND_BRIM).sum()),
        "initialised": n_init,
        "tracked_fraction": float(has.mean()) if has.size else 0.0,
        "brim_source": brim_source if rom_path is None else "ROM",
        "seconds": {k: round(v, 2) for k, v in seconds.items()},
    })
    log.info("Processed %s: %s", take_path, result)
    return result
