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
    "drop_empty_points",
    "initialise",
    "label_from_template",
    "process_take",
    "remove_spurious",
    "stabilise_take",
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


def label_from_template(session: Session, template: str | Path,
                        progress: Callable[[int, int], bool] | None = None) -> list[str]:
    """Stage: Label From Template on the tracked take; returns the template labels left
    unassigned (logged as a warning)."""
    pts = session.project.points
    face = np.flatnonzero(pts.kind == KIND_FACE)
    todo = [c for c in face if not pts.labels[c] and np.isfinite(pts.positions[:, c, 0]).any()]
    if not todo:  # a ROM labelled every point already
        log.info("Label From Template: every face point of the take is labelled")
        return []
    cmd = _stage("Label From Template",
                 lambda: session.label_from_template(template, progress=progress))
    result = getattr(cmd, "result", None)
    if result is None:
        return []
    if result.unassigned:
        log.warning("%s", result.message)
    else:
        log.info("%s", result.message)
    return list(result.unassigned)


def drop_empty_points(session: Session) -> int:
    """Stage: delete the unlabelled face points that have no 3D in any frame (ROM points
    this take never showed); returns how many. Labelled ones stay, so the marker set in
    the exports is complete."""
    pts = session.project.points
    face = np.flatnonzero(pts.kind == KIND_FACE)
    if face.size == 0:
        return 0
    empty = ~np.isfinite(pts.positions[:, face, 0]).any(0)
    drop = [int(pts.ids[c]) for c, e in zip(face, empty, strict=True)
            if e and not pts.labels[c]]
    if drop:
        session.delete_selected(drop)
        log.info("Removed %d face points that were never found in this take", len(drop))
    return len(drop)


def remove_spurious(session: Session) -> list[dict[str, str]]:
    """Stage: Remove Spurious Points (tracked face points that are not markers) before
    anything is written; returns ``{"label", "reason"}`` of each removed point (logged)."""
    cmd = session.remove_spurious_points(quiet=True)
    removed = [] if cmd is None else [{"label": lab, "reason": why}
                                      for lab, why in cmd.removed]  # type: ignore[attr-defined]
    for r in removed:
        log.warning("Removed point %s: %s", r["label"], r["reason"])
    return removed


def stabilise_take(session: Session, mode: str) -> str:
    """Stage: Stabilize Data over the whole take, without a selection.

    ``mode`` "auto" is Stabilize Data [Automatic]; "assisted" seeds Stabilize Data
    [Assisted] with the automatically chosen stable points and base frame 0 (the
    frame the take was initialised at). Returns the log line with the errors.

    Raises
    ------
    ValueError
        Unknown mode, or the take cannot be stabilised (too few points).
    """
    from carapost.algorithms.params import from_mapping
    from carapost.algorithms.stabilise import StabilizationParameters, choose_stable_points

    project = session.project
    session.set_active_range(0, project.n_frames - 1)
    if mode == "auto":
        cmd = _stage("Stabilize Data [Automatic]", lambda: session.stabilize("auto"))
    elif mode == "assisted":
        params = from_mapping(StabilizationParameters, project.properties)
        face = project.points.kind == KIND_FACE
        cand = face | ((project.points.kind == KIND_BRIM)
                       & params.stabilization_use_brim_points)
        X = project.points.positions
        try:
            seed = choose_stable_points(X, fraction=params.stable_points_percent,
                                        candidates=cand)
        except ValueError as exc:
            raise ValueError(f"Stabilize Data [Assisted]: {exc}") from None
        # the seeds must be gap-free over the take, as an artist's selection is
        full = np.isfinite(X[:, seed, 0]).all(0)
        ids = project.points.ids[seed[full]][:6]
        if len(ids) < 3:
            raise ValueError("Stabilize Data [Assisted]: fewer than 3 stable points are "
                             "tracked in every frame; use --stabilize auto")
        cmd = _stage("", lambda: session.stabilize("assisted", ids.tolist(), base_frame=0))
    else:
        raise ValueError(f"stabilize must be 'auto' or 'assisted', got {mode!r}")
    return cmd.message if cmd is not None else ""


def write_outputs(session: Session, inputs: TakeInputs, *, stabilized: bool = False
                  ) -> dict[str, str | None]:
    """Stage: save the project, then the exports (each file atomically; stabilised
    coordinates when ``stabilized``)."""
    written = session.save(inputs.output)
    result: dict[str, str | None] = {"project": str(written), "c3d": None, "fbx": None,
                                     "sigma_csv": None}
    if inputs.c3d is not None:
        from carapost.export import export_sigma_csv
        from carapost.io.sigma_csv import sidecar_path

        result["c3d"] = str(session.export_c3d(inputs.c3d, **{**PROCESS_EXPORT,
                                                              "stabilized": stabilized}))
        result["sigma_csv"] = str(export_sigma_csv(
            session.project, sidecar_path(inputs.c3d),
            frame_range=PROCESS_EXPORT["frame_range"],
            include_brim=PROCESS_EXPORT["include_brim"], stabilized=stabilized))
    if inputs.fbx is not None:
        result["fbx"] = str(session.export_fbx(inputs.fbx, **{**PROCESS_FBX_EXPORT,
                                                              "stabilized": stabilized}))
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
    stabilize: str | None = None,
    label_template: str | Path | None = None,
    stages: Callable[[str], Callable[[int, int], bool]] | None = None,
    workers: int = 2,
) -> dict[str, Any]:
    """Process a take headlessly: import, detect, solve, initialise, track, (stabilise,)
    save, export.

    Each stage is one function of this module over a `carapost.Session` (so a batch
    runner can reuse them): `check_take_inputs`, `Session.import_take`, `detect_all`,
    `calibrate`, `initialise`, `track_all`, `stabilise_take`, `write_outputs`.

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
    label_template : str or Path, optional
        A labelled ``.cara`` take of the same marker set: after tracking, Label From
        Template gives the unlabelled face points its labels (`label_from_template`).
    stages : callable, optional
        ``stages(name)`` is called as each stage starts and returns that stage's
        ``progress(done, total)`` (one console bar per stage, `carapost.progress`);
        used instead of ``progress`` when given.
    patch_tracking : bool
        Give the tracker the images, so a point-camera without a blob is patch tracked
        (Patch Match Size / Threshold). Off by default: every image is decoded again
        while tracking, both passes, which makes the whole run about 2.5x slower for
        +0.1 % coverage and +0.05 mm RMSE on the rendered speech takes
        (docs/benchmarks.md).
    stabilize : {"auto", "assisted"}, optional
        Stabilise the tracked take (`stabilise_take`); the C3D/FBX exports are then
        stabilised coordinates.
    workers : int
        Blob detector processes (1: detect in this process; a batch worker, whose
        parallelism is the takes, passes 1).

    Returns
    -------
    dict
        ``project``, ``c3d``, ``fbx``, ``sigma_csv`` (the C3D's per-sample uncertainty
        sidecar, `carapost.io.sigma_csv`) (paths written or None), ``frames``, ``cameras``,
        ``points`` (face points), ``brim_points``, ``initialised`` (face points at the
        first frame), ``tracked_fraction`` (face point-frames with 3D / point-frames),
        ``mean_residual`` (mm, over the measured face samples; NaN when none),
        ``brim_source``, ``removed_points`` (``{"label", "reason"}`` of each point Remove
        Spurious Points deleted), ``seconds`` per stage, ``labelled`` (face points with
        3D and a label) and ``unassigned`` (template labels Label From Template left out).

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

    if stabilize is not None and stabilize not in ("auto", "assisted"):
        raise ValueError(f"stabilize must be 'auto' or 'assisted', got {stabilize!r}")
    inputs = check_take_inputs(take_path, output=output, rom=rom, brim=brim, c3d=c3d,
                               fbx=fbx)
    template = Path(label_template) if label_template else None
    if template is not None and not template.is_file():
        raise CaraFileError(template, "label template not found")
    if template is not None and template.suffix.lower() != ".cara":
        raise CaraFileError(template, "a label template must be a .cara project")

    def stage(name: str, fallback: Callable[[int, int], bool] | None
              ) -> Callable[[int, int], bool] | None:
        return stages(name) if stages is not None else fallback
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
        detect_all(session, stage("Detect blobs",
                                  None if progress is None else detect_progress),
                   workers=workers)
        seconds["detect"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        brim_source = calibrate(session, inputs)
        seconds["brim"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        n_init = initialise(session, inputs)
        seconds["initialise"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        track_all(session, patch_tracking=patch_tracking,
                  progress=stage("Track", None if progress is None else track_progress))
        seconds["track"] = time.perf_counter() - t0
        removed = remove_spurious(session)
    unassigned: list[str] = []
    if template is not None:
        t0 = time.perf_counter()
        unassigned = label_from_template(session, template, stage("Label", None))
        seconds["label"] = time.perf_counter() - t0
    drop_empty_points(session)
    stab_message = None
    if stabilize is not None:
        t0 = time.perf_counter()
        stab_message = stabilise_take(session, stabilize)
        seconds["stabilize"] = time.perf_counter() - t0
    if stages is not None:
        stages("Save and export")

    result: dict[str, Any] = dict(write_outputs(session, inputs,
                                                stabilized=stabilize is not None))
    face = project.points.kind == KIND_FACE
    has = np.isfinite(project.points.positions[:, face, 0])
    result.update({
        "frames": F, "cameras": C, "points": int(face.sum()),
        "brim_points": int((project.points.kind == KIND_BRIM).sum()),
        "initialised": n_init,
        "tracked_fraction": float(has.mean()) if has.size else 0.0,
        "mean_residual": _mean_residual(project.points.residual[:, face]),
        "brim_source": brim_source if inputs.rom is None else "ROM",
        "removed_points": removed,
        "labelled": int(sum(1 for j, c in enumerate(np.flatnonzero(face))
                            if project.points.labels[c] and has[:, j].any())),
        "unassigned": unassigned,
        "seconds": {k: round(v, 2) for k, v in seconds.items()},
        "stabilization": stab_message,
    })
    log.info("Processed %s: %s", inputs.take, result)
    return result
