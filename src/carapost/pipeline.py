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
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from carapost.export import check_output
from carapost.io.errors import CaraFileError
from carapost.model.project import KIND_BRIM, KIND_FACE, Project

if TYPE_CHECKING:
    from carapost.session import Session

log = logging.getLogger("carapost.pipeline")

__all__ = [
    "PROCESS_EXPORT",
    "PROCESS_FBX_EXPORT",
    "TakeInputs",
    "brim_from_take",
    "calibrate",
    "check_take_inputs",
    "detect_all",
    "initialise",
    "process_take",
    "track_all",
    "write_outputs",
]


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


#: What ``carapost process`` exports: every frame, face points only, not stabilized, Y
#: up, no cameras or sticks (its outputs before the Export properties existed; a batch
#: run should not depend on the Properties a take was imported with).
PROCESS_EXPORT: dict[str, Any] = {"frame_range": "all", "include_brim": False,
                                  "stabilized": False}
PROCESS_FBX_EXPORT: dict[str, Any] = {**PROCESS_EXPORT, "up_axis": "y",
                                      "include_cameras": False, "include_sticks": False}


@dataclass
class TakeInputs:
    """The checked inputs of one `process_take` run (see `check_take_inputs`)."""

    take: Path
    output: Path
    c3d: Path | None = None
    fbx: Path | None = None
    rom: Path | None = None
    brim_model: tuple[list[str], NDArray[np.float64]] | None = None
    brim_svg: Path | None = None
    brim_source: str = "take"


def check_take_inputs(take_path: str | Path, *, output: str | Path,
                      rom: str | Path | None = None, brim: str | Path | None = None,
                      c3d: str | Path | None = None,
                      fbx: str | Path | None = None) -> TakeInputs:
    """Check every input and output of `process_take` before any work.

    Raises
    ------
    CaraFileError
        A missing take, ROM or brim file, a brim model that cannot be read, or an
        output that cannot be written (wrong extension, missing folder).
    """
    from carapost.io.take_import import read_brim_csv

    take = Path(take_path)
    if not take.exists():
        raise CaraFileError(take, "no such file or folder")
    inputs = TakeInputs(take=take, output=check_output(output, ".cara"),
                        c3d=check_output(c3d, ".c3d") if c3d else None,
                        fbx=check_output(fbx, ".fbx") if fbx else None,
                        rom=Path(rom) if rom else None)
    if inputs.rom is not None:
        if not inputs.rom.is_file():
            raise CaraFileError(inputs.rom, "ROM project not found")
        if inputs.rom.suffix.lower() != ".cara":
            raise CaraFileError(inputs.rom, "a ROM must be a .cara project")
    if brim is not None:
        bp = Path(brim)
        if not bp.is_file():
            raise CaraFileError(bp, "brim model not found")
        if bp.suffix.lower() == ".csv":
            inputs.brim_model = read_brim_csv(bp)
        elif bp.suffix.lower() == ".svg":
            inputs.brim_svg = bp
        else:
            raise CaraFileError(bp, "a brim model must be a .csv or .svg file")
        inputs.brim_source = str(bp)
    return inputs


def _stage(what: str, call: Callable[[], Any]) -> Any:
    """Run one Session call; a refusal becomes ``ValueError("<what>: reason")``."""
    from carapost.commands.stack import CommandError

    try:
        return call()
    except CommandError as exc:
        raise ValueError(f"{what}: {exc}" if what else str(exc)) from None


def detect_all(session: Session, progress: Callable[[int, int], bool] | None = None, *,
               workers: int = 2) -> None:
    """Stage: Detect Blobs in every frame of every camera (on ``workers`` detector
    processes; 1 detects in the calling process, as a batch worker does).

    Raises
    ------
    ValueError
        Detection refused, or no marker found anywhere.
    RuntimeError
        Cancelled through ``progress``.
    """
    project = session.project
    cmd = _stage("Detect Blobs", lambda: session.detect_blobs(
        "all", cameras=range(project.n_cameras), progress=progress, workers=workers))
    if cmd is None or cmd.cancelled:  # None: cancelled at once
        raise RuntimeError("cancelled during blob detection; nothing was written")
    if project.detections.total == 0:
        raise ValueError(f"{project.take.metadata.get('take_folder') or project.take.name}: "
                         "no markers were found in any image (check the Blob Parameters "
                         "or the videos)")


def calibrate(session: Session, inputs: TakeInputs) -> str:
    """Stage: load the ROM, or set the brim model and solve it at frame 0.

    Returns where the brim model came from (``inputs.brim_source`` or "triangulated
    from the take").
    """
    project = session.project
    source = inputs.brim_source
    if inputs.rom is not None:
        _stage("", lambda: session.load_rom(inputs.rom))
    if project.calibration.intrinsics is not None and inputs.rom is None:
        if inputs.brim_svg is not None:
            session.import_brim(inputs.brim_svg)
        else:
            model = inputs.brim_model
            if model is None:
                try:
                    model = brim_from_take(project)
                except ValueError as exc:
                    raise ValueError(f"brim: {exc}") from None
                source = "triangulated from the take"
            session.set_brim_model(*model, description="Set Calibration Brim")
        _stage("Solve Calibration Brim [Automatic]",
               lambda: session.solve_brim(frame=0, method="automatic"))
    return source


def initialise(session: Session, inputs: TakeInputs) -> int:
    """Stage: Initialize from ROM or Initialize 3D at frame 0; returns the face points
    initialised."""
    project = session.project
    session.current_frame = 0
    if inputs.rom is not None:
        _stage("initialisation", lambda: session.initialize_from_rom(frame=0))
    else:
        _stage("initialisation", lambda: session.initialize_3d(frame=0))
    face = project.points.kind == KIND_FACE
    n_init = int(np.isfinite(project.points.positions[0, face, 0]).sum())
    if n_init == 0:
        raise ValueError("initialisation found no face marker at frame 0")
    return n_init


def track_all(session: Session, *, patch_tracking: bool = False,
              progress: Callable[[int, int], bool] | None = None) -> None:
    """Stage: track the whole take from frame 0 (forwards finding missed markers, then
    backwards), over an active range set to the whole take."""
    F = session.project.n_frames
    session.set_active_range(0, F - 1)
    if F > 1:
        cmd = _stage("tracking", lambda: session.track_take(
            frame=0, use_images=patch_tracking, progress=progress))
        if cmd is None or cmd.cancelled:  # None: cancelled before the first frame
            raise RuntimeError("cancelled during tracking; nothing was written")


def write_outputs(session: Session, inputs: TakeInputs) -> dict[str, str | None]:
    """Stage: save the project, then the exports (each file atomically)."""
    written = session.save(inputs.output)
    result: dict[str, str | None] = {"project": str(written), "c3d": None, "fbx": None}
    if inputs.c3d is not None:
        result["c3d"] = str(session.export_c3d(inputs.c3d, **PROCESS_EXPORT))
    if inputs.fbx is not None:
        result["fbx"] = str(session.export_fbx(inputs.fbx, **PROCESS_FBX_EXPORT))
    return result


def _mean_residual(residual: NDArray[np.float32]) -> float:
    """Mean of the finite residuals (mm); NaN when there is none."""
    r = residual[np.isfinite(residual)]
    return float(r.mean()) if r.size else float("nan")


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
    workers: int = 2,
) -> dict[str, Any]:
    """Process a take headlessly: import, detect, solve, initialise, track, save, export.

    Each stage is one function of this module over a `carapost.Session` (so a batch
    runner can reuse them): `check_take_inputs`, `Session.import_take`, `detect_all`,
    `calibrate`, `initialise`, `track_all`, `write_outputs`.

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
        Also export the face points here (every frame, `PROCESS_EXPORT`).
    progress : callable, optional
        ``progress(done, total)`` over the detection and tracking frames; False cancels
        (raises ``RuntimeError``, nothing written).
    patch_tracking : bool
        Give the tracker the images, so a point-camera without a blob is patch tracked
        (Patch Match Size / Threshold). Off by default: every image is decoded again
        while tracking, both passes, which makes the whole run about 2.5x slower for
        +0.1 % coverage and +0.05 mm RMSE on the rendered speech takes
        (docs/benchmarks.md).
    workers : int
        Blob detector processes (1: detect in this process; a batch worker, whose
        parallelism is the takes, passes 1).

    Returns
    -------
    dict
        ``project``, ``c3d``, ``fbx`` (paths written or None), ``frames``, ``cameras``,
        ``points`` (face points), ``brim_points``, ``initialised`` (face points at the
        first frame), ``tracked_fraction`` (face point-frames with 3D / point-frames),
        ``mean_residual`` (mm, over the measured face samples; NaN when none),
        ``brim_source``, ``seconds`` per stage.

    Raises
    ------
    CaraFileError
        Missing or unreadable inputs, unwritable outputs.
    ValueError
        The take cannot be processed (no XCP and no ROM, no markers found, brim not
        solvable, nothing initialised); the message says which stage and why.
    """
    from carapost.io.take_import import read_brim_csv
    from carapost.session import Session

    inputs = check_take_inputs(take_path, output=output, rom=rom, brim=brim, c3d=c3d,
                               fbx=fbx)
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    # the brim model is chosen below (--brim, the take's, or triangulated), not at import
    session = Session.import_take(inputs.take, take_brim=False)
    project = session.project
    seconds["import"] = time.perf_counter() - t0
    if project.calibration.intrinsics is None and inputs.rom is None:
        raise ValueError(f"{inputs.take}: the take has no XCP calibration and no ROM was "
                         "given; the cameras cannot be solved (add <take>.xcp or --rom "
                         "ROM.cara)")
    F, C = project.n_frames, project.n_cameras
    brim_file = project.take.metadata.get("brim_file")
    if inputs.brim_model is None and inputs.brim_svg is None and brim_file:
        inputs.brim_model = read_brim_csv(brim_file)
        inputs.brim_source = str(brim_file)

    total = 3 * F  # detection, then the forward and backward tracking passes

    def detect_progress(d: int, n: int) -> bool:
        return progress(d * F // max(n, 1), total)  # type: ignore[misc]

    def track_progress(d: int, n: int) -> bool:
        return progress(F + d, total)  # type: ignore[misc]

    with session:  # closes the videos before anything is written
        t0 = time.perf_counter()
        detect_all(session, None if progress is None else detect_progress, workers=workers)
        seconds["detect"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        brim_source = calibrate(session, inputs)
        seconds["brim"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        n_init = initialise(session, inputs)
        seconds["initialise"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        track_all(session, patch_tracking=patch_tracking,
                  progress=None if progress is None else track_progress)
        seconds["track"] = time.perf_counter() - t0

    result: dict[str, Any] = dict(write_outputs(session, inputs))
    face = project.points.kind == KIND_FACE
    has = np.isfinite(project.points.positions[:, face, 0])
    result.update({
        "frames": F, "cameras": C, "points": int(face.sum()),
        "brim_points": int((project.points.kind == KIND_BRIM).sum()),
        "initialised": n_init,
        "tracked_fraction": float(has.mean()) if has.size else 0.0,
        "mean_residual": _mean_residual(project.points.residual[:, face]),
        "brim_source": brim_source if inputs.rom is None else "ROM",
        "seconds": {k: round(v, 2) for k, v in seconds.items()},
    })
    log.info("Processed %s: %s", inputs.take, result)
    return result
