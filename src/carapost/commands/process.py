"""Process-menu steps: blob detection, calibration brim, Initialize 3D, bundle.

Every step follows the recipe of :mod:`carapost.commands.recipe`:
``prepare_*(project, ...) -> Job`` (calling thread: validation and a snapshot of plain
arrays), ``job.compute(progress) -> Result`` (worker thread, no project) and
``ApplyResult(result)`` (one undoable step). The classes named after the menu items
(``DetectBlobs(project, ...)``, ``Initialize3D(project, ...)``, ...) do all three at
once for scripts: they are ``ApplyResult`` s of the computed result.

Bad input raises :class:`~carapost.commands.stack.CommandError` with a message that is
also logged on the ``carapost.process`` logger; the project is then unchanged.

Brim points are ``KIND_BRIM`` points whose ``positions`` hold the brim model in every
frame (the brim is rigid in its own frame, which is the world frame); a brim solve
attaches them to detections and marks them ``RECON_TRIANGULATED`` at the solved frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import CameraIntrinsics
from carapost.algorithms.multiview import ray_residual
from carapost.algorithms.params import from_mapping
from carapost.commands.recipe import ApplyResult, Job, Progress, Result
from carapost.commands.results import DetectionsResult
from carapost.commands.stack import Command, CommandError, Journal
from carapost.model.project import (
    KIND_BRIM,
    KIND_FACE,
    RECON_NONE,
    RECON_TRIANGULATED,
    SOURCE_BLOB,
    Project,
)
from carapost.model.rig import caddies

log = logging.getLogger("carapost.process")

__all__ = [
    "BundleCurrentFrame",
    "DetectBlobs",
    "ImportBrimSvg",
    "Initialize3D",
    "InitializeDefaultBrim",
    "SetBrimModel",
    "SolveBrimAuto",
    "SolveBrimManual",
    "prepare_bundle_frame",
    "prepare_detect_blobs",
    "prepare_initialize_3d",
    "prepare_solve_brim",
    "prepare_solve_brim_auto",
    "prepare_solve_brim_manual",
    "set_cameras",
]


def refuse(message: str) -> CommandError:
    """A :class:`CommandError` for ``message``, logged as an error on ``carapost.process``.

    Processing commands ``raise refuse(...)`` so the reason reaches the Log pane even when
    the caller (a batch script) only catches the exception.
    """
    log.error("%s", message)
    return CommandError(message)


def check_frame(project: Project, frame: int | None, what: str) -> int:
    """The frame index ``frame`` (the current frame when None), refused with a logged
    message when it is outside the take."""
    f = project.current_frame if frame is None else int(frame)
    if not 0 <= f < project.n_frames:
        raise refuse(f"{what}: frame {f} is outside the take (0-{project.n_frames - 1})")
    return f


def require_intrinsics(project: Project, what: str,
                       remedy: str = "import an XCP file for the intrinsics",
                       ) -> CameraIntrinsics:
    """The project's camera intrinsics; refuses ``what`` when there are none for this take.

    ``remedy`` completes the message "the project has no camera calibration (...)".
    """
    intr = project.calibration.intrinsics
    if intr is None:
        raise refuse(f"{what}: the project has no camera calibration ({remedy})")
    if intr.n_cameras != project.n_cameras:
        raise refuse(f"{what}: the calibration has {intr.n_cameras} cameras, the take "
                      f"{project.n_cameras}")
    return intr


def _frame_detections(project: Project, frame: int) -> list[NDArray[np.float64]]:
    return [project.detections.centres(frame, c).astype(np.float64)
            for c in range(project.n_cameras)]


def _brim(project: Project, frame: int, what: str) -> tuple[NDArray[np.intp], NDArray]:
    """Columns of the brim points and the brim model (B, 3)."""
    cols = np.flatnonzero(project.points.kind == KIND_BRIM)
    if cols.size == 0:
        raise refuse(f"{what}: the project has no calibration brim (Initialize Default "
                      "Calibration Brim or Import Calibration Brim [SVG] first)")
    model = project.points.positions[frame, cols].astype(np.float64)
    if not np.all(np.isfinite(model)):
        raise refuse(f"{what}: the brim model has points without a position")
    return cols, model


def set_cameras(journal: Journal, project: Project, frames: int | slice, R: NDArray,
                t: NDArray) -> None:
    """Set (undoably) the solved cameras of one frame or of a block of frames.

    ``R`` and ``t`` are ``(C, 3, 3)`` and ``(C, 3)`` for one frame, ``(n, C, 3, 3)`` and
    ``(n, C, 3)`` for a slice of ``n`` frames; those frames become solved.
    """
    journal.calibration(frames)
    cal = project.calibration
    cal.R[frames] = R
    cal.t[frames] = t
    cal.solved[frames] = True


def _gather(dets: list[NDArray], det: NDArray[np.intp]) -> NDArray[np.float64]:
    """Observations (P, C, 2) of detection indices ``det`` (P, C); -1 -> NaN."""
    obs = np.full(det.shape + (2,), np.nan)
    for c in range(det.shape[1]):
        m = det[:, c] >= 0
        obs[m, c] = dets[c][det[m, c]]
    return obs


def _frame_arrays(X: NDArray, det: NDArray, residual: NDArray, dets: list[NDArray]
                  ) -> dict[str, NDArray]:
    """The per-point arrays of one frame for 3D positions X and blob observations."""
    C = det.shape[1]
    obs = np.full((len(det), C, 2), np.nan, dtype=np.float32)
    for c in range(C):
        m = det[:, c] >= 0
        obs[m, c] = dets[c][det[m, c]]
    return {
        "positions": X[None],
        "recon": np.where(np.isfinite(X).all(1), RECON_TRIANGULATED, RECON_NONE)[None],
        "residual": np.asarray(residual)[None],
        "obs": obs[None],
        "source": np.where(det >= 0, SOURCE_BLOB, 0)[None],
        "detection": det[None],
        "quality": np.where(det >= 0, 1.0, 0.0)[None],
        "keyframe": False,
    }


# ------------------------------------------------------------------------------------------
# Detect Blobs
# ------------------------------------------------------------------------------------------
class DetectBlobsJob(Job):
    """Blob detection of some images (snapshot: image keys, parameters, image source)."""

    def __init__(self, keys: list[tuple[int, int]], params: Any,
                 get_image: Callable[[int, int], NDArray], workers: int, description: str,
                 processes: bool | None = None):
        self.keys, self.params, self.get_image = keys, params, get_image
        self.workers, self.description = workers, description
        self.processes = processes

    def compute(self, progress: Progress = None) -> DetectionsResult:
        from carapost.algorithms.blobs import detect_blobs_batch

        get_image = self.get_image
        result = detect_blobs_batch(lambda k: get_image(*k), list(self.keys), self.params,
                                    workers=self.workers, progress=progress,
                                    processes=self.processes)
        if not result:
            raise refuse("Detect Blobs: cancelled before any image was finished")
        images = [k for k in self.keys if k in result]
        tables = [result[k]._asdict() for k in images]
        cancelled = len(images) < len(self.keys)
        desc = self.description
        msg = (f"{desc}: {len(images)} images, {sum(len(t['centre']) for t in tables)} "
               f"detections" + (" (cancelled: finished images kept)" if cancelled else ""))
        log.info("%s", msg)
        return DetectionsResult(images, tables, desc, cancelled=cancelled, message=msg)


def prepare_detect_blobs(project: Project, frames: tuple[int, int] | None = None,
                         cameras: Sequence[int] | None = None,
                         get_image: Callable[[int, int], NDArray] | None = None,
                         workers: int = 2, description: str | None = None,
                         processes: bool | None = None) -> DetectBlobsJob:
    """Detect Blobs [Active Range] / [Current Frame] with the project's Blob Parameters.

    Parameters
    ----------
    project : Project
    frames : (int, int), optional
        Inclusive frame range (default: the current frame).
    cameras : sequence of int, optional
        Cameras to process; default: the explicitly selected cameras, or all.
    get_image : callable (frame, camera) -> ndarray [H, W]
        The grey image of one camera at one frame (called on the worker thread).
    workers : int
        Detector processes or threads.
    description : str, optional
        The History entry (default "Detect Blobs [frames a-b]").
    processes : bool, optional
        Detect in the detector processes (True) or on threads (False); default: processes
        for large batches (:func:`carapost.algorithms.blobs.detect_blobs_batch`). A
        window asks for processes even for one frame: threads would hold the GIL
        and stall its drawing.
    """
    what = "Detect Blobs"
    from carapost.algorithms.blobs import BlobParameters

    if get_image is None:
        raise refuse(f"{what}: no image source (the take has no camera videos)")
    a, b = frames if frames is not None else (project.current_frame,) * 2
    a, b = check_frame(project, a, what), check_frame(project, b, what)
    if a > b:
        a, b = b, a
    cams = (project.processing_cameras() if cameras is None
            else np.array(sorted(set(int(c) for c in cameras)), dtype=np.intp))
    if cams.size == 0 or cams.min() < 0 or cams.max() >= project.n_cameras:
        raise refuse(f"{what}: no such camera in {list(cams)}")
    try:
        params = from_mapping(BlobParameters, project.properties)
    except ValueError as exc:
        raise refuse(f"{what}: {exc}") from None
    keys: list[Hashable] = [(f, int(c)) for f in range(a, b + 1) for c in cams]
    desc = description or (f"{what} [frames {a}-{b}]" if b > a else f"{what} [frame {a}]")
    return DetectBlobsJob(keys, params, get_image, workers, desc,  # type: ignore[arg-type]
                          processes)


class DetectBlobs(ApplyResult):
    """Detect Blobs in one call: ``ApplyResult(prepare_detect_blobs(...).compute(progress))``.

    Parameters are those of :func:`prepare_detect_blobs` plus ``progress``
    (``(done, total) -> bool``; False cancels and keeps the images finished so far).
    """

    def __init__(self, project: Project, frames: tuple[int, int] | None = None,
                 cameras: Sequence[int] | None = None,
                 get_image: Callable[[int, int], NDArray] | None = None,
                 progress: Progress = None, workers: int = 2):
        job = prepare_detect_blobs(project, frames, cameras, get_image, workers)
        super().__init__(job.compute(progress))


# ------------------------------------------------------------------------------------------
# Brim models
# ------------------------------------------------------------------------------------------
class SetBrimModel(Command):
    """Replace the brim points by a brim model: labels and positions (B, 3) in mm.

    Built as ``SetBrimModel(labels, xyz)``: the model is data (read from a file or the
    default table), the project is not needed to validate it.
    """

    def __init__(self, labels: Sequence[str], xyz: NDArray,
                 description: str = "Set Calibration Brim"):
        super().__init__()
        self.labels = list(labels)
        self.xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        if len(self.labels) != len(self.xyz) or len(self.xyz) < 4:
            raise refuse(f"{description}: a brim needs at least 4 dots with one label each "
                          f"(got {len(self.xyz)} dots, {len(self.labels)} labels)")
        if not np.all(np.isfinite(self.xyz)):
            raise refuse(f"{description}: a brim dot position is not finite")
        self.description = description

    def apply(self, project: Project, journal: Journal) -> None:
        old = np.flatnonzero(project.points.kind == KIND_BRIM)
        if old.size:
            journal.remove_points(old)
        cols = journal.append_points(len(self.xyz), labels=self.labels, kind=KIND_BRIM)
        project.points.positions[:, cols] = self.xyz.astype(np.float32)[None]


class InitializeDefaultBrim(SetBrimModel):
    """Initialize Default Calibration Brim [v1.0 / v1.1 / v2.0] (replaces any brim)."""

    def __init__(self, project: Project, version: str = "v2.0"):
        from carapost.io.brim_svg import default_brim

        try:
            labels, xyz = default_brim(version)
        except ValueError as exc:
            raise refuse(f"Initialize Default Calibration Brim: {exc}") from None
        super().__init__(labels, xyz,
                         f"Initialize Default Calibration Brim [{version.strip().lower()}]")
        log.info("%s: %d brim dots", self.description, len(xyz))


class ImportBrimSvg(SetBrimModel):
    """Import Calibration Brim [SVG]: a planar custom brim (replaces any brim)."""

    def __init__(self, project: Project, path: str | Path):
        from carapost.io.brim_svg import read_brim_svg
        from carapost.io.errors import CaraFileError

        try:
            labels, xyz = read_brim_svg(path)
        except CaraFileError as exc:
            raise refuse(f"Import Calibration Brim [SVG]: {exc}") from exc  # shown in a box
        super().__init__(labels, xyz, f"Import Calibration Brim [SVG] {Path(path).name}")
        self.path = str(Path(path).absolute())
        log.info("%s: %d brim dots", self.description, len(xyz))

    def apply(self, project: Project, journal: Journal) -> None:
        super().apply(project, journal)
        # View > Show Calibration Brim SVG shows the file the brim came from
        meta = {**project.take.metadata, "brim_svg": self.path}
        journal.setattr(project.take, "metadata", meta, "cameras")


# ------------------------------------------------------------------------------------------
# Brim solves
# ------------------------------------------------------------------------------------------
class BrimSolveResult(Result):
    """A brim solve: cameras of the frame, brim points attached to detections."""

    def __init__(self, frame: int, ids: NDArray, R: NDArray, t: NDArray, matches: NDArray,
                 model: NDArray, residual: NDArray, dets: list[NDArray], description: str,
                 message: str):
        self.frame, self.ids = frame, ids
        self.R, self.t, self.matches = R, t, matches
        self.model, self.residual, self.dets = model, residual, dets
        self.description, self.message = description, message

    def write(self, project: Project, journal: Journal) -> None:
        f = self.frame
        cols = project.points.index_of(self.ids)
        det = self.matches
        arrays = _frame_arrays(self.model, det, self.residual, self.dets)
        unseen = ~(det >= 0).any(1)
        arrays["recon"][0, unseen] = RECON_NONE
        arrays["residual"] = arrays["residual"].copy()
        arrays["residual"][0, unseen] = np.nan
        journal.write_points(f, cols, arrays)
        set_cameras(journal, project, f, self.R, self.t)


class BrimSolveJob(Job):
    """A manual or automatic brim solve of one frame (snapshot of its detections)."""

    def __init__(self, mode: str, frame: int, dets: list[NDArray], model: NDArray,
                 intr: CameraIntrinsics, ids: NDArray, description: str, *,
                 correspondences: Mapping[int, Sequence[tuple[int, int]]] | None = None,
                 R_ref: NDArray | None = None, t_ref: NDArray | None = None):
        self.mode, self.frame, self.dets, self.model = mode, frame, dets, model
        self.intr, self.ids, self.description = intr, ids, description
        self.correspondences, self.R_ref, self.t_ref = correspondences, R_ref, t_ref

    def compute(self, progress: Progress = None) -> BrimSolveResult:
        from carapost.algorithms.brim import solve_brim_auto, solve_brim_manual

        if self.mode == "manual":
            res = solve_brim_manual(self.dets, self.correspondences, self.model, self.intr)
        else:
            res = solve_brim_auto(self.dets, self.model, self.intr, self.R_ref, self.t_ref)
        if not res.success:
            raise refuse(res.message)
        R, t, matches = res.R.copy(), res.t.copy(), res.matches.copy()
        residual = ray_residual(self.model, _gather(self.dets, matches), R, t, self.intr)
        return BrimSolveResult(self.frame, self.ids, R, t, matches, self.model, residual,
                               self.dets, self.description, res.message)


def prepare_solve_brim_manual(project: Project, frame: int | None = None,
                              correspondences: Mapping[int, Sequence[tuple[int, int]]]
                              | None = None) -> BrimSolveJob:
    """Solve Calibration Brim [Manual].

    Parameters
    ----------
    project : Project
    frame : int
    correspondences : mapping camera -> sequence of (brim_index, detection_index), optional
        ``brim_index`` counts the brim points in project order. Default: the detections
        attached to brim points at ``frame`` (at least 4 in every camera).
    """
    what = "Solve Calibration Brim [Manual]"
    f = check_frame(project, frame, what)
    intr = require_intrinsics(project, what)
    cols, model = _brim(project, f, what)
    if correspondences is None:
        det = project.points.detection[f, cols]  # (B, C)
        correspondences = {c: [(int(b), int(det[b, c])) for b in np.flatnonzero(
            det[:, c] >= 0)] for c in range(project.n_cameras)}
    return BrimSolveJob("manual", f, _frame_detections(project, f), model, intr.copy(),
                        project.points.ids[cols].copy(), f"{what} [frame {f}]",
                        correspondences=correspondences)


def prepare_solve_brim_auto(project: Project, frame: int | None = None) -> BrimSolveJob:
    """Solve the brim with no hand matches, using the rig geometry of the XCP calibration.

    The cameras of ``frame`` (or of the first solved frame) give the rig's relative
    geometry; only their relation to each other is used.
    """
    what = "Solve Calibration Brim [Automatic]"
    f = check_frame(project, frame, what)
    intr = require_intrinsics(project, what)
    cols, model = _brim(project, f, what)
    cal = project.calibration
    if not cal.solved.any():
        raise refuse(f"{what}: needs the rig geometry of an XCP calibration (import one) "
                      "or a solved frame")
    ref = f if cal.solved[f] else int(np.flatnonzero(cal.solved)[0])
    return BrimSolveJob("auto", f, _frame_detections(project, f), model, intr.copy(),
                        project.points.ids[cols].copy(), f"{what} [frame {f}]",
                        R_ref=cal.R[ref].copy(), t_ref=cal.t[ref].copy())


def prepare_solve_brim(project: Project, frame: int | None = None) -> BrimSolveJob:
    """Process > Solve Calibration Brim: manual when brim points are attached to
    detections at the frame, else automatic (needs an XCP calibration)."""
    f = project.current_frame if frame is None else int(frame)
    brim = np.flatnonzero(project.points.kind == KIND_BRIM)
    if len(brim) and 0 <= f < project.n_frames and np.any(
            project.points.detection[f, brim] >= 0):
        return prepare_solve_brim_manual(project, f)
    return prepare_solve_brim_auto(project, f)


class SolveBrimManual(ApplyResult):
    """Solve Calibration Brim [Manual] in one call (see :func:`prepare_solve_brim_manual`)."""

    def __init__(self, project: Project, frame: int | None = None,
                 correspondences: Mapping[int, Sequence[tuple[int, int]]] | None = None):
        super().__init__(prepare_solve_brim_manual(project, frame, correspondences).compute())


class SolveBrimAuto(ApplyResult):
    """Solve Calibration Brim [Automatic] in one call (see :func:`prepare_solve_brim_auto`)."""

    def __init__(self, project: Project, frame: int | None = None):
        super().__init__(prepare_solve_brim_auto(project, frame).compute())


# ------------------------------------------------------------------------------------------
# Initialize 3D and bundle
# ------------------------------------------------------------------------------------------
class Init3DResult(Result):
    """Face points of one frame: seeds updated (by id), new points appended."""

    def __init__(self, frame: int, seed_ids: NDArray, points: NDArray, detections: NDArray,
                 R: NDArray, t: NDArray, cameras_changed: bool, residual: NDArray,
                 dets: list[NDArray], description: str, message: str):
        self.frame, self.seed_ids, self.points, self.detections = (frame, seed_ids, points,
                                                                   detections)
        self.R, self.t, self.cameras_changed = R, t, cameras_changed
        self.residual, self.dets = residual, dets
        self.description, self.message = description, message

    def write(self, project: Project, journal: Journal) -> None:
        f = self.frame
        n_old = len(self.seed_ids)
        old_cols = project.points.index_of(self.seed_ids) if n_old else np.zeros(0, np.intp)
        new_cols = journal.append_points(len(self.points) - n_old, kind=KIND_FACE)
        cols = np.concatenate([old_cols, new_cols]).astype(np.intp)
        if self.cameras_changed:
            set_cameras(journal, project, f, self.R, self.t)
        journal.write_points(f, cols, _frame_arrays(self.points, self.detections,
                                                    self.residual, self.dets))


@dataclass
class Init3DJob(Job):
    """Initialize 3D on the snapshot of one frame (see :func:`prepare_initialize_3d`).

    ``dets`` are the frame's detection centres per camera (float64 px), ``exclude`` the
    detections to leave out per camera, ``seed_rows`` per-seed detection indices per
    camera and ``seed_ids`` the ids of the seed points (updated, not duplicated).
    """

    frame: int
    dets: list[NDArray]
    R: NDArray
    t: NDArray
    intr: CameraIntrinsics
    caddies: tuple[tuple[int, int], ...]
    seed_rows: list[list[int]]
    exclude: list[NDArray]
    params: Any
    brim_model: NDArray | None
    brim_det: NDArray | None
    seed_ids: NDArray
    description: str

    def compute(self, progress: Progress = None) -> Init3DResult:
        from carapost.algorithms.init3d import initialize_3d

        what = "Initialize 3D"
        try:
            res = initialize_3d(self.dets, self.R, self.t, self.intr, caddies=self.caddies,
                                seeds=self.seed_rows or None, exclude_mask=self.exclude,
                                params=self.params, brim_model=self.brim_model,
                                brim_detections=self.brim_det)
        except ValueError as exc:
            raise refuse(f"{what}: {exc}") from None
        if not res.success:
            raise refuse(res.message)
        changed = not (np.array_equal(res.R, self.R) and np.array_equal(res.t, self.t))
        # residual in mm with the final cameras
        residual = ray_residual(res.points, _gather(self.dets, res.detections), res.R,
                                 res.t, self.intr)
        return Init3DResult(self.frame, self.seed_ids, res.points, res.detections, res.R,
                            res.t, changed, residual, self.dets, self.description,
                            res.message)


def prepare_initialize_3d(project: Project, frame: int | None = None,
                          seeds: Sequence[Sequence[int]] | None = None) -> Init3DJob:
    """Initialize 3D: face points from the detections of one frame.

    Seeds are the face points of the frame attached to detections in two or more cameras
    (matched by hand) unless ``seeds`` gives per-camera detection index tuples; with none
    at all, seeds are found automatically. Seed points keep their ids and are updated;
    new points are appended. Uses the Initialize 3D Parameters of the project.
    """
    from carapost.algorithms.brim import brim_exclusion_mask
    from carapost.algorithms.init3d import Init3DParameters

    what = "Initialize 3D"
    f = check_frame(project, frame, what)
    intr = require_intrinsics(project, what)
    cal = project.calibration
    if not cal.solved[f]:
        raise refuse(f"{what}: the cameras of frame {f} are not solved (Solve "
                      "Calibration Brim first)")
    pts = project.points
    C = project.n_cameras
    dets = _frame_detections(project, f)
    if not any(len(d) for d in dets):
        raise refuse(f"{what}: frame {f} has no detections (run Detect Blobs)")
    R, t = cal.R[f].copy(), cal.t[f].copy()
    # detections already taken by points stay out; brim ones and the brim region too
    exclude = [np.zeros(len(d), dtype=bool) for d in dets]
    attached = pts.detection[f]  # (P, C)
    for c in range(C):
        k = attached[:, c]
        exclude[c][k[(k >= 0) & (k < len(dets[c]))]] = True
    brim_cols = np.flatnonzero(pts.kind == KIND_BRIM)
    brim_model = brim_det = None
    if brim_cols.size:
        brim_model = pts.positions[f, brim_cols].astype(np.float64)
        if np.all(np.isfinite(brim_model)):
            region = brim_exclusion_mask(dets, brim_model, R, t, intr)
            brim_det = pts.detection[f, brim_cols].astype(np.intp)
            for c in range(C):
                exclude[c] |= region[c]
        else:
            brim_model = None
    seed_cols = np.zeros(0, dtype=np.intp)
    if seeds is None:
        face = np.flatnonzero(pts.kind == KIND_FACE)
        nviews = (attached[face] >= 0).sum(1)
        seed_cols = face[nviews >= 2]
        seed_rows = [list(attached[c]) for c in seed_cols]
        for c in range(C):  # seed detections are theirs to use
            exclude[c][attached[seed_cols, c][attached[seed_cols, c] >= 0]] = False
    else:
        seed_rows = [list(s) for s in seeds]
    try:
        params = from_mapping(Init3DParameters, project.properties)
    except (TypeError, ValueError) as exc:
        raise refuse(f"{what}: {exc}") from None
    return Init3DJob(frame=f, dets=dets, R=R, t=t, intr=intr.copy(),
                     caddies=caddies(C, project.take.metadata),
                     seed_rows=seed_rows, exclude=exclude, params=params,
                     brim_model=brim_model, brim_det=brim_det,
                     seed_ids=pts.ids[seed_cols].copy(), description=f"{what} [frame {f}]")


class Initialize3D(ApplyResult):
    """Initialize 3D in one call (see :func:`prepare_initialize_3d`)."""

    def __init__(self, project: Project, frame: int | None = None,
                 seeds: Sequence[Sequence[int]] | None = None):
        super().__init__(prepare_initialize_3d(project, frame, seeds).compute())


class FrameBundleResult(Result):
    """Refined cameras of one frame and positions of its face points."""

    def __init__(self, frame: int, ids: NDArray, points: NDArray, R: NDArray, t: NDArray,
                 residual: NDArray, description: str, message: str):
        self.frame, self.ids, self.points, self.R, self.t = frame, ids, points, R, t
        self.residual, self.description, self.message = residual, description, message

    def write(self, project: Project, journal: Journal) -> None:
        f = self.frame
        set_cameras(journal, project, f, self.R, self.t)
        if len(self.ids):
            journal.write_points(f, project.points.index_of(self.ids), {
                "positions": self.points[None], "recon": RECON_TRIANGULATED,
                "residual": self.residual[None]})


@dataclass
class FrameBundleJob(Job):
    """Bundle adjustment of one frame (see :func:`prepare_bundle_frame`).

    ``obs`` (n, C, 2) and ``X0`` (n, 3) are the observations and positions of the
    points taking part, ``brim`` marks the fixed brim points among them and ``ids``
    the ids of the others (the face points refined).
    """

    frame: int
    obs: NDArray
    X0: NDArray
    R: NDArray
    t: NDArray
    intr: CameraIntrinsics
    brim: NDArray
    ids: NDArray
    description: str

    def compute(self, progress: Progress = None) -> FrameBundleResult:
        from carapost.algorithms.bundle import bundle_frame

        what, f = "Bundle Current Frame [Unconstrained]", self.frame
        obs, X0, brim = self.obs, self.X0.copy(), self.brim
        # face points without a 3D position get one from their rays first
        need = ~np.isfinite(X0).all(1)
        if need.any():
            from carapost.algorithms.triangulation import (
                TriangulationParameters,
                triangulate,
            )

            tri = triangulate(obs[need][None], self.R, self.t, self.intr,
                              TriangulationParameters(minimum_cameras=2))
            X0[need] = tri.points[0]
        res = bundle_frame(obs, X0, self.R, self.t, self.intr, fixed_points_mask=brim)
        if not (res.success or np.isfinite(res.rms_after)):
            raise refuse(f"{what}: the adjustment failed ({res.message})")
        points = res.points[~brim]
        residual = ray_residual(points, obs[~brim], res.R, res.t, self.intr)
        message = (f"{what}: frame {f}, {len(obs)} points, RMS {res.rms_before:.3f} -> "
                   f"{res.rms_after:.3f} px")
        log.info("%s", message)
        return FrameBundleResult(f, self.ids, points, res.R, res.t, residual,
                                 self.description, message)


def prepare_bundle_frame(project: Project, frame: int | None = None) -> FrameBundleJob:
    """Bundle Current Frame [Unconstrained]: refine the frame's cameras and face points.

    Brim points with a model position are kept fixed (they define the frame); every point
    with two or more observations takes part.
    """
    what = "Bundle Current Frame [Unconstrained]"
    f = check_frame(project, frame, what)
    intr = require_intrinsics(project, what)
    cal = project.calibration
    if not cal.solved[f]:
        raise refuse(f"{what}: the cameras of frame {f} are not solved")
    pts = project.points
    obs = pts.obs[f].astype(np.float64)  # (P, C, 2)
    nview = np.isfinite(obs).all(-1).sum(1)
    brim = pts.kind == KIND_BRIM
    X = pts.positions[f].astype(np.float64)
    use = (nview >= 2) & (brim | np.isfinite(X).all(1))
    use |= brim & (nview >= 1) & np.isfinite(X).all(1)
    face = use & ~brim
    if not face.any() and not (use & brim).any():
        raise refuse(f"{what}: no point of frame {f} has observations in two cameras")
    cols = np.flatnonzero(use)
    return FrameBundleJob(frame=f, obs=obs[cols], X0=X[cols], R=cal.R[f].copy(),
                          t=cal.t[f].copy(), intr=intr.copy(), brim=brim[cols],
                          ids=pts.ids[cols[~brim[cols]]].copy(),
                          description=f"{what} [frame {f}]")


class BundleCurrentFrame(ApplyResult):
    """Bundle Current Frame [Unconstrained] in one call (see :func:`prepare_bundle_frame`)."""

    def __init__(self, project: Project, frame: int | None = None):
        super().__init__(prepare_bundle_frame(project, frame).compute())
